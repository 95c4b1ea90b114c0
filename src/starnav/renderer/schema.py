"""Schema of the ``moon`` and ``render`` sections of a scenario (owned by the renderer).

``moon`` says what is drawn (shape, photometric model and its parameters, albedo as a number or
a map, the DEM for ``shape: dem``); ``render`` how (samples per pixel, Mitsuba variants, crop,
AOVs, sampler, spectral grid). :mod:`starnav.simulate` turns them into the renderer's SI
objects (:class:`~starnav.renderer.render.MoonModel`,
:class:`~starnav.renderer.render.RenderSettings`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator

from starnav.config_base import StrictModel
from starnav.dem.schema import DemConfig
from starnav.fields import NonNegativeFloat, PositiveCount, PositiveFloat, UnitInterval
from starnav.photometry import PHOTOMETRIC_MODELS, get_model, hapke_preset

#: Samples per interior pixel of the adaptive render when ``render.interior_spp`` is unset (at
#: most ``spp``): the fewest of 1, 2, 4 whose interior noise on the full-field real Moon is at
#: most that of a 16-spp render with the wavelengths drawn by the sensor response (the table
#: in :func:`starnav.renderer.render.adaptive_sample_counts`).
DEFAULT_INTERIOR_SPP = 2


class PhotometryConfig(StrictModel):
    """Photometric model of the lunar surface and its parameters.

    ``model``: ``hapke`` (Hapke 2012, the default), ``lambert``, ``lommel_seeliger`` or
    ``lunar_lambert`` (McEwen). ``preset`` picks Hapke's parameter set: ``rolo-calibrated`` (the
    phase-function and opposition parameters fitted to the ROLO model with the real albedo map,
    :mod:`starnav.lunar_calibration`) or ``sato2014`` (Sato et al. 2014 as published);
    ``params`` overrides single values (``b``, ``c``, ``bs0``, ``hs``, ``bc0``, ``hc``,
    ``theta_bar_deg``). ``spectral_shape``: ``rolo`` gives the reflectance the Moon's colour
    (ROLO's A(lambda) relative to 550 nm), ``grey`` a flat one (the analytic test cases).
    ``clark2002`` is the S-type asteroid set of the small bodies
    (:data:`starnav.photometry.HAPKE_S_TYPE_CLARK2002`).
    """

    model: str = Field(
        "hapke", description=f"photometric model of the surface, one of: "
        f"{', '.join(PHOTOMETRIC_MODELS)} (hapke: Hapke 2012; lunar_lambert: McEwen)")
    preset: Literal["rolo-calibrated", "sato2014", "clark2002"] = Field(
        "rolo-calibrated", description="Hapke parameter set (ignored by the other models)")
    params: dict[str, float] = Field(
        default_factory=dict, description="single parameter overrides of the model, name: value "
        "(Hapke: b, c, bs0, hs, bc0, hc, theta_bar_deg); empty: the preset's")
    spectral_shape: Literal["rolo", "grey"] = Field(
        "rolo", description="reflectance colour: ROLO lunar reddening (1 at 550 nm) or flat")

    @model_validator(mode="after")
    def _known_model(self) -> PhotometryConfig:
        try:
            get_model(self.model).check_params(dict(self.params))
        except (KeyError, ValueError) as err:
            raise ValueError(str(err)) from None
        return self

    def resolved_params(self) -> dict[str, float]:
        """The model's parameters: the preset (Hapke) with ``params`` on top."""
        base = hapke_preset(self.preset) if self.model == "hapke" else {}
        return get_model(self.model).check_params({**base, **self.params})


class AlbedoMapConfig(StrictModel):
    """Single-channel albedo map over selenographic longitude (columns, -180..180 deg from the
    left edge) and latitude (rows, +90 deg at the top), equirectangular. ``quantity``: the
    values are normal albedos (any model) or Hapke single-scattering albedos (Hapke only)."""

    path: Path = Field(
        description="equirectangular single-channel albedo map file (longitude -180..180 deg from "
        "the left edge, +90 deg latitude at the top)")
    scale: PositiveFloat = Field(1.0, description="multiplier applied to the decoded map [-]")
    quantity: Literal["normal_albedo", "hapke_w"] = Field(
        "normal_albedo", description="what the map's values are")


def _default_real_moon() -> DemConfig:
    """LOLA LDEM_4 terrain with the LROC WAC albedo map, both shipped with starnav."""
    return DemConfig(source="lola", albedo={"source": "lroc"})


class MoonConfig(StrictModel):
    """The Moon: shape, photometry and albedo.

    ``albedo`` is the **normal albedo** at 550 nm (:mod:`starnav.photometry`: every model derives
    its own parameter from it): a number (a uniform Moon, or the mean of a relative albedo map
    such as the default LROC one) or a map file (``shape: sphere``). ``None`` (the default) is the
    ROLO-calibrated mean normal albedo of the real Moon.
    """

    shape: Literal["sphere", "mesh", "dem"] = Field(
        "dem", description="exact sphere, icosphere mesh, or DEM mesh (starnav.dem; default: "
        "the real Moon, LOLA terrain and LROC albedo)"
    )
    radius_km: PositiveFloat = Field(1737.4, description="reference sphere radius [km]")
    mesh_subdivisions: Annotated[int, Field(ge=0, le=9)] = Field(
        7, description="icosphere subdivisions for shape=mesh (7 -> 327 680 triangles)"
    )
    photometry: PhotometryConfig = Field(
        default_factory=PhotometryConfig, description="photometric model of the surface and its "
        "parameters")
    albedo: NonNegativeFloat | AlbedoMapConfig | None = Field(
        None, description="normal albedo at 550 nm [-]: a number, a map, or None for the "
        "ROLO-calibrated real Moon"
    )
    albedo_scale: PositiveFloat = Field(
        1.0, description="global radiance multiplier (albedo-exposure scaling studies) [-]"
    )
    dem: DemConfig = Field(
        default_factory=_default_real_moon,
        description="DEM and albedo sources and meshing for shape=dem (starnav.dem.schema)"
    )

    @field_validator("dem", mode="before")
    @classmethod
    def _real_moon_defaults(cls, v: Any) -> Any:
        """Keys missing from a given ``dem`` section take the real-Moon defaults (as
        ``starnav init`` shows them), not the bare DemConfig's: ``source: lola``, and an albedo
        map that goes with the source (``lroc`` for ``lola``, the procedural map for
        ``procedural``, none for a user's file). An explicit ``albedo: null`` is kept."""
        if not isinstance(v, dict):
            return v
        v = dict(v)
        source = v.setdefault("source", "lola")
        default_albedo = {"lola": "lroc", "procedural": "procedural"}.get(source)
        if "albedo" not in v:
            if default_albedo is not None:
                v["albedo"] = {"source": default_albedo}
        elif isinstance(v["albedo"], dict) and "source" not in v["albedo"]:
            v["albedo"] = {"source": default_albedo or "procedural", **v["albedo"]}
        return v

    @field_validator("albedo", mode="before")
    @classmethod
    def _albedo_sign(cls, v: Any) -> Any:
        if isinstance(v, int | float) and not isinstance(v, bool):
            if v < 0:
                raise ValueError(f"the normal albedo must be >= 0, got {v}")
            if v > 1:
                raise ValueError(f"a normal albedo is at most 1 (the Moon's is ~0.12), got {v}")
        return v


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
