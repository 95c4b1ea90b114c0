"""Schema of the ``render`` section of a scenario (owned by the renderer).

``render`` says how a frame is drawn (samples per pixel, Mitsuba variants, crop, AOVs, sampler,
spectral grid); what is drawn is the target body's (:mod:`starnav.bodies.schema`).
:mod:`starnav.simulate` turns it into the renderer's
:class:`~starnav.renderer.render.RenderSettings`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from starnav.config_base import StrictModel
from starnav.fields import NonNegativeFloat, PositiveCount, UnitInterval

#: Samples per interior pixel of the adaptive render when ``render.interior_spp`` is unset (at
#: most ``spp``): the fewest of 1, 2, 4 whose interior noise on the full-field real Moon is at
#: most that of a 16-spp render with the wavelengths drawn by the sensor response (the table
#: in :func:`starnav.renderer.render.adaptive_sample_counts`).
DEFAULT_INTERIOR_SPP = 2


class RenderConfig(StrictModel):
    """Rendering settings.

    ``adaptive`` spends the ``spp`` samples only where the signal needs them (the limb, the
    terminator, shadow and albedo edges) and ``interior_spp`` in the flat interior, decided
    from the pixel-centre rays (unbiased; :func:`starnav.renderer.render.adaptive_sample_counts`
    says how and what noise it leaves); JIT variants only (the scalar variant renders ``spp``
    everywhere).
    """

    spp: PositiveCount = Field(16, description="samples per pixel")
    adaptive: bool = Field(
        True, description="adaptive samples per pixel: spp at the limb, terminator and edges, "
        "interior_spp in the flat interior (JIT variants; off: spp everywhere)")
    interior_spp: Annotated[int, Field(ge=1)] | None = Field(
        None, description="samples per interior pixel of the adaptive render (<= spp; unset: "
        f"{DEFAULT_INTERIOR_SPP} or spp if fewer, Monte Carlo noise 0.35 % per pixel on the "
        "real Moon at 2)")
    variants: tuple[str, ...] = Field(
        ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral"),
        description="Mitsuba variants in order of preference",
    )
    crop: bool = Field(True, description="trace only the Moon's bounding box (plus margin)")
    crop_margin_px: NonNegativeFloat = Field(4.0, description="margin around the disc [px]")
    aovs: bool = Field(True, description="write range/normal/lat/lon/angle/mask channels")
    sampler: Literal["multijitter", "stratified", "independent", "ldsampler"] = Field(
        "multijitter", description="Mitsuba sampler of the radiance pass"
    )
    wavelength_step_nm: Annotated[float, Field(gt=0, le=50)] = Field(
        1.0, description="grid step of the spectra handed to Mitsuba [nm]"
    )
    spectral_sampling: Literal["electrons", "response"] = Field(
        "electrons", description="how each sample's wavelengths are drawn: by the spectrum of "
        "the electrons the lit surface gives (Sun x surface colour x QE T lambda / hc: no "
        "spectral noise) or by the sensor's response alone (the solar spectrum in the weights: "
        "the reference the first is tested against)")
    earth_shadow: bool = Field(
        True, description="the Earth's shadow: each surface point's solar irradiance times the "
        "fraction of the solar disc the Earth does not hide (penumbra and umbra, from the "
        "ephemeris; frames without an Earth position, static and fly-by, are never shadowed; "
        "the umbra's refracted light is not modelled)")
    sun_limb_darkening: UnitInterval = Field(
        0.0, description="linear limb-darkening coefficient u of the solar disc in the Earth's "
        "shadow, I(mu) = 1 - u (1 - mu) (0: uniform disc; about 0.6 in the visible)")

    @model_validator(mode="after")
    def _interior_below_spp(self) -> RenderConfig:
        if self.adaptive and self.interior_spp is not None and self.interior_spp > self.spp:
            raise ValueError(f"render.interior_spp = {self.interior_spp}: expected at most "
                             f"render.spp = {self.spp} with render.adaptive on")
        return self
