"""Scenario section ``detector`` (owned by :mod:`starnav.detector`).

One nested, frozen model per stage of the chain (see :mod:`starnav.detector.chain` for the order).
Units are in the key names (``_s``, ``_ms``, ``_us``, ``_px``, ``_e``, ``_dn``, ``_deg_s``,
``_c``, ``_k``); the chain converts to SI on entry. Every effect has an ``enabled`` switch.

Defaults are the Leonardo AA-STR MK II / HAS2 values of ``docs/facts.md`` section 1 where
that table has them; every other default is marked *assumption* in its description, with the
reasoning, because the HAS2 datasheet and the AA-STR optical prescription are not public.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from starnav.config_base import StrictModel
from starnav.detector.blooming import BLOOMING_MODES
from starnav.detector.products import MAX_WINDOWS
from starnav.errors import UnknownNameError
from starnav.fields import FiniteFloat, NonNegativeFloat, PositiveFloat, UnitInterval

#: ADC gain default: full well / (2^12 - 1) = 100 000 / 4095 [e-/DN] (docs/facts.md s1).
DEFAULT_FULL_WELL_E = 100_000.0


# --------------------------------------------------------------------------- photons (optics)
class RadiometryConfig(StrictModel):
    """Electron radiance to mean photo-electrons: ``N = t A_pupil Omega_pix Le [x cos^4]``."""

    relative_illumination: bool = Field(
        True, description="multiply by the pinhole's natural vignetting cos^4(theta) "
        "(Camera.relative_illumination); off gives exactly t A Omega Le in every pixel"
    )


class AberrationPsfConfig(StrictModel):
    """Field-varying aberration + defocus PSF: a defocus disc convolved with an elliptical
    Gaussian whose radial/tangential widths grow with the square of the normalised field radius
    rho (0 on axis, 1 in the field corner), sampled on a grid of nodes and blended bilinearly.

    Assumption (AA-STR prescription not public): the optics is "intentionally aberrated and
    defocused" (seed paper) so a star covers ~3x3 to 5x5 px; the quadratic growth matches the
    field dependence of the HIL collimator spot (docs/facts.md s5: 0.49 px RMS on axis to 2.13 px
    at 9.6 deg fits 0.49 + 0.0178 theta_deg^2)."""

    enabled: bool = Field(
        True, description="apply the field-varying aberration and defocus PSF")
    defocus_radius_px: NonNegativeFloat = Field(
        1.0, description="geometric defocus blur-circle radius on axis [px] (assumption)")
    defocus_radius_edge_px: NonNegativeFloat = Field(
        1.3, description="blur-circle radius in the field corner (field curvature) [px] "
        "(assumption)")
    sigma_px: NonNegativeFloat = Field(
        0.5, description="aberration Gaussian sigma on axis [px] (assumption)")
    sigma_radial_edge_px: NonNegativeFloat = Field(
        1.4, description="Gaussian sigma along the radial direction in the corner [px] "
        "(assumption)")
    sigma_tangential_edge_px: NonNegativeFloat = Field(
        0.9, description="Gaussian sigma along the tangential direction in the corner [px] "
        "(assumption)")
    grid_nodes: tuple[Annotated[int, Field(ge=1, le=17)], Annotated[int, Field(ge=1, le=17)]] = \
        Field((5, 5), description="PSF grid nodes along (columns, rows); 1 x 1 = invariant PSF")
    oversample: Annotated[int, Field(ge=1, le=15)] = Field(
        5, description="sub-samples per pixel used to integrate each node PSF over the pixel")


class DistortionConfig(StrictModel):
    """Brown-Conrady distortion of the :class:`~starnav.camera.Camera` (its k1..p2): resample
    the undistorted pinhole image onto the detector grid, multiplying by the pixel-area ratio.
    Skipped when the camera has no distortion coefficients."""

    enabled: bool = Field(
        True, description="resample the image through the camera's Brown-Conrady distortion "
        "(skipped when the camera has no coefficients)")


class StrayLightConfig(StrictModel):
    """In-field stray light: a wide Harvey-type halo K(r) ~ (1 + (r/r0)^2)^(slope/2), r <=
    max_radius, carrying the fraction ``total_integrated_scatter`` of the light (energy
    conserving: the direct image keeps 1 - TIS). Assumption: TIS 0.5 % (~0.05-0.1 % per
    polished, coated surface of a ~6-lens star-tracker objective), Harvey slope -2 (polished
    optics), shoulder 3 px (~1 mrad). With it the Moon at 60 000 km and 7.7 ms lifts the whole
    background by ~50 DN, at 200 ms the halo itself saturates hundreds of pixels around the
    disc (the paper's "severe saturation")."""

    enabled: bool = Field(
        True, description="add the Harvey stray-light halo")
    total_integrated_scatter: UnitInterval = Field(
        0.005, description="fraction of the light scattered into the halo [-] (assumption)")
    harvey_slope: FiniteFloat = Field(
        -2.0, description="log-log slope of the halo far from the core [-] (assumption)")
    shoulder_px: PositiveFloat = Field(
        3.0, description="Harvey roll-off radius r0 [px] (assumption, ~1 mrad)")
    max_radius_px: PositiveFloat = Field(
        1024.0, description="halo support radius [px] (one detector width)")
    core_radius_px: Annotated[int, Field(ge=1, le=64)] = Field(
        16, description="inside this radius the halo is convolved at full resolution; outside "
        "it, on a grid `binning` times coarser [px]")
    binning: Annotated[int, Field(ge=1, le=32)] = Field(
        8, description="coarse-grid factor of the far halo and of the ghosts [px]")


class GhostConfig(StrictModel):
    """One ghost: a scaled, defocused, displaced copy of the image.

    Position of a point x in the ghost: ``c + magnification (x - c) + offset`` with c the
    principal point; then blurred by a disc of ``defocus_radius_px``; it carries ``weight`` of
    the light (taken from the direct image)."""

    weight: UnitInterval = Field(5e-4, description="fraction of the light in this ghost [-]")
    magnification: FiniteFloat = Field(
        -1.0, description="linear magnification about the principal point [-] (-1: inverted)")
    defocus_radius_px: NonNegativeFloat = Field(40.0, description="defocus disc radius [px]")
    offset_px: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="displacement (du, dv) [px]")

    @field_validator("magnification")
    @classmethod
    def _nonzero(cls, v: float) -> float:
        if abs(v) < 1e-3:
            raise ValueError(f"magnification must satisfy |m| >= 1e-3, got {v}")
        return v


class GhostsConfig(StrictModel):
    """Ghost images. Assumption: one inverted, strongly defocused ghost of 5e-4 (typical of a
    double reflection between AR-coated lens surfaces); the AA-STR ghost budget is not public."""

    enabled: bool = Field(
        True, description="add the ghost images")
    ghosts: tuple[GhostConfig, ...] = Field(
        default_factory=lambda: (GhostConfig(),), description="the ghosts: each a scaled, "
        "defocused, displaced copy of the image carrying a fraction of its light")

    @model_validator(mode="after")
    def _total_weight(self) -> GhostsConfig:
        tot = sum(g.weight for g in self.ghosts)
        if tot >= 1.0:
            raise ValueError(f"ghost weights must sum to < 1, got {tot}")
        return self


class OpticsConfig(StrictModel):
    """Photon-collection stage."""

    radiometry: RadiometryConfig = Field(
        default_factory=RadiometryConfig, description="photo-electrons from radiance: pupil area, "
        "pixel solid angle, vignetting")
    aberration: AberrationPsfConfig = Field(
        default_factory=AberrationPsfConfig, description="optical PSF: defocus disc and "
        "field-varying Gaussian")
    distortion: DistortionConfig = Field(
        default_factory=DistortionConfig, description="lens distortion (the camera's "
        "Brown-Conrady coefficients)")
    stray_light: StrayLightConfig = Field(
        default_factory=StrayLightConfig, description="in-field stray light: a Harvey halo around "
        "bright sources")
    ghosts: GhostsConfig = Field(
        default_factory=GhostsConfig, description="ghost images from reflections between lens "
        "surfaces")


# --------------------------------------------------------------------------- smear
class RollingShutterConfig(StrictModel):
    """APS rolling shutter: row r integrates over [r t_row, r t_row + t_exp]; a spacecraft
    angular rate moves the image during it (motion blur) and between rows (skew)."""

    enabled: bool = Field(
        True, description="integrate row by row (rolling shutter) with the spacecraft rate")
    angular_rate_deg_s: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="spacecraft rate about the camera x and y axes [deg/s] "
        "(rotation about the boresight is not modelled); 0 = inertial pointing")
    row_time_us: PositiveFloat | None = Field(
        None, description="row-to-row start delay [us]; None: from the readout law, "
        "b x width / n_pix_unit (0.17 ms x 1024 / 1000 = 174 us)")


class TransferSmearConfig(StrictModel):
    """CCD frame-transfer smear: each pixel also collects, for ``row_transfer_time_us`` per row,
    the light of every row of its column. Off by default: the HAS2 is an APS (no transfer)."""

    enabled: bool = Field(
        False, description="add frame-transfer smear (off: the HAS2 is an APS, it has no "
        "transfer)")
    row_transfer_time_us: PositiveFloat = Field(
        1.0, description="time a charge packet spends under each row during transfer [us] "
        "(assumption, typical frame-transfer CCD)")


class SmearConfig(StrictModel):
    rolling_shutter: RollingShutterConfig = Field(
        default_factory=RollingShutterConfig, description="APS rolling shutter and motion blur "
        "from the spacecraft rate")
    transfer: TransferSmearConfig = Field(
        default_factory=TransferSmearConfig, description="CCD frame-transfer smear")


# --------------------------------------------------------------------------- charge
class PrnuConfig(StrictModel):
    """Photo-response non-uniformity: a frozen per-sensor gain map 1 + sigma N(0, 1)."""

    enabled: bool = Field(
        True, description="apply the photo-response non-uniformity gain map")
    sigma_fraction: UnitInterval = Field(0.02, description="PRNU rms [-] (ABRAM default 2 %, "
                                         "docs/facts.md s1, low trust)")


class DarkCurrentConfig(StrictModel):
    """Dark current with DSNU, hot pixels and temperature scaling
    ``D(T) = D_ref 2^((T - T_ref) / T_doubling)``."""

    enabled: bool = Field(
        True, description="add dark current (with DSNU and hot pixels)")
    rate_e_per_s: NonNegativeFloat = Field(
        590.0, description="mean dark current at the reference temperature [e-/s/px] "
        "(ABRAM default, docs/facts.md s1, low trust)")
    dsnu_fraction: UnitInterval = Field(
        0.013, description="dark-signal non-uniformity rms, relative to the mean [-] "
        "(ABRAM 1.3 %, docs/facts.md s1)")
    temperature_c: Annotated[float, Field(ge=-273.15, le=150)] = Field(
        20.0, description="detector temperature [degC], from absolute zero to 150 (above any "
        "silicon detector's rating)")
    reference_temperature_c: Annotated[float, Field(ge=-273.15, le=150)] = Field(
        20.0, description="temperature of rate_e_per_s [degC] (assumption: ABRAM gives none)")
    doubling_temperature_k: PositiveFloat = Field(
        7.0, description="temperature rise that doubles the dark current [K] (assumption, "
        "typical silicon APS 6-8 K)")
    hot_pixel_fraction: UnitInterval = Field(
        1e-4, description="fraction of hot pixels [-] (assumption: radiation-induced, ~100 px)")
    hot_pixel_factor: Annotated[float, Field(ge=1, allow_inf_nan=False)] = Field(
        100.0, description="hot-pixel dark current / mean dark current [-] (assumption)")


class ShotNoiseConfig(StrictModel):
    """Poisson shot noise on photo + dark charge."""

    enabled: bool = Field(
        True, description="draw shot noise on photo and dark charge (off: mean charge, no noise)")
    gaussian_above_e: PositiveFloat | None = Field(
        1000.0, description="above this mean [e-] draw N(mu, mu) instead of Poisson(mu) "
        "(skewness 1/sqrt(mu) < 3 %); None: exact Poisson everywhere")


class ChargeConfig(StrictModel):
    prnu: PrnuConfig = Field(
        default_factory=PrnuConfig, description="photo-response non-uniformity (a fixed gain map "
        "of the sensor)")
    dark_current: DarkCurrentConfig = Field(
        default_factory=DarkCurrentConfig, description="dark current, its non-uniformity (DSNU) "
        "and hot pixels")
    shot_noise: ShotNoiseConfig = Field(
        default_factory=ShotNoiseConfig, description="Poisson noise of the collected charge")


# --------------------------------------------------------------------------- pixel
class BloomingConfig(StrictModel):
    """What happens to charge above full well. Modes (registry
    :data:`starnav.detector.blooming.BLOOMING_MODES`): ``drain`` (anti-blooming: all excess
    removed), ``column`` (excess bleeds up and down the column), ``isotropic`` (excess spills to
    the nearest non-full pixels in every direction). In the spilling modes a fraction
    ``1 - spill_fraction`` of the excess still goes to the reset/overflow drain."""

    enabled: bool = Field(
        True, description="spread the charge above full well (off: excess charge is removed, a "
        "perfect anti-blooming drain)")
    mode: str = Field(
        "isotropic", description=f"where the excess charge goes, one of: "
        f"{', '.join(BLOOMING_MODES)}; drain removes it all (anti-blooming), column bleeds it "
        "up and down the column, isotropic spills it to the nearest non-full pixels")
    spill_fraction: UnitInterval = Field(
        5e-4, description="fraction of the excess charge that spills into neighbours [-] "
        "(assumption, tuned to the paper: a few-px halo at the 7.7 ms case and one far past "
        "the disc at 200 ms; docs/facts.md s1 says do not assume a perfect anti-blooming)")
    max_margin_px: Annotated[int, Field(ge=0)] = Field(
        1024, description="how far outside the array spilled charge is followed before it is "
        "counted as lost [px]")

    @field_validator("mode")
    @classmethod
    def _known_mode(cls, v: str) -> str:
        try:
            return BLOOMING_MODES.check(v)
        except UnknownNameError as err:  # a KeyError: pydantic reports ValueErrors only
            raise ValueError(str(err)) from None


class SaturationConfig(StrictModel):
    """Full-well saturation (switch off only for linearity studies)."""

    enabled: bool = Field(
        True, description="clip the charge at full well (off only for linearity studies)")
    full_well_e: PositiveFloat = Field(
        DEFAULT_FULL_WELL_E, description="full-well capacity [e-] (ABRAM AA-STR, docs/facts.md s1)")
    blooming: BloomingConfig = Field(
        default_factory=BloomingConfig, description="where the charge above full well goes")


# --------------------------------------------------------------------------- signal
class IpcConfig(StrictModel):
    """Inter-pixel capacitive coupling, 3 x 3 symmetric kernel, charge conserving."""

    enabled: bool = Field(
        True, description="apply inter-pixel capacitive coupling")
    nearest_fraction: Annotated[float, Field(ge=0, le=0.2, allow_inf_nan=False)] = Field(
        0.005, description="coupling to each of the 4 nearest neighbours [-] (monolithic APS "
        "~0.5 %, docs/facts.md s1)")
    diagonal_fraction: Annotated[float, Field(ge=0, le=0.05, allow_inf_nan=False)] = Field(
        0.0005, description="coupling to each of the 4 diagonal neighbours [-] (~0.05 %, "
        "docs/facts.md s1)")


class ElectricalCrosstalkConfig(StrictModel):
    """Electrical crosstalk of very bright pixels along their row (shared row/column lines):
    every pixel of row r gets ``row_coefficient * sum_c max(q - threshold, 0)`` (and likewise
    along columns). Not charge conserving: it is a signal offset (can be negative, e.g. a
    supply droop). Assumption: 2e-5 per row, i.e. a ~13 DN streak across a row crossing a
    saturated Moon of 160 px; columns 0."""

    enabled: bool = Field(
        True, description="add the electrical crosstalk of very bright pixels along rows and "
        "columns")
    row_coefficient: FiniteFloat = Field(2e-5, description="row coupling per pixel [-]")
    column_coefficient: FiniteFloat = Field(0.0, description="column coupling per pixel [-]")
    threshold_fraction: UnitInterval = Field(
        0.9, description="pixels above this fraction of full well drive the crosstalk [-]")


class NonlinearityConfig(StrictModel):
    """Charge-to-voltage non-linearity ``S' = S / (1 + beta S / FWC)`` with beta set so the
    signal at full well is short by ``full_well_deficit_fraction``."""

    enabled: bool = Field(
        True, description="apply the charge-to-voltage non-linearity")
    full_well_deficit_fraction: Annotated[float, Field(ge=0, lt=0.5, allow_inf_nan=False)] = \
        Field(0.01, description="relative signal deficit at full well [-] (assumption: 1 %)")


class ReadNoiseConfig(StrictModel):
    enabled: bool = Field(
        True, description="add Gaussian read noise")
    sigma_e: NonNegativeFloat = Field(100.0, description="read noise rms [e-] (ABRAM AA-STR, "
                                      "docs/facts.md s1)")


class SignalConfig(StrictModel):
    ipc: IpcConfig = Field(
        default_factory=IpcConfig, description="inter-pixel capacitive coupling")
    electrical_crosstalk: ElectricalCrosstalkConfig = Field(
        default_factory=ElectricalCrosstalkConfig,
        description="row and column crosstalk of very bright pixels")
    nonlinearity: NonlinearityConfig = Field(
        default_factory=NonlinearityConfig, description="charge-to-voltage non-linearity")
    read_noise: ReadNoiseConfig = Field(
        default_factory=ReadNoiseConfig, description="read-out noise")


# --------------------------------------------------------------------------- image (ADC)
class AdcConfig(StrictModel):
    """Gain, offset, quantisation (round to nearest) and clipping to [0, 2^bits - 1]."""

    bits: Annotated[int, Field(ge=1, le=16)] = Field(12, description="ADC resolution [bit] "
                                                     "(assumption, docs/facts.md s1)")
    gain_e_per_dn: PositiveFloat | None = Field(
        None, description="conversion gain [e-/DN]; None: full well / (2^bits - 1) = 24.42 "
        "(docs/facts.md s1)")
    offset_dn: NonNegativeFloat = Field(
        100.0, description="electronic offset (pedestal) [DN] (assumption: keeps the read "
        "noise of dark pixels above 0 DN)")


# --------------------------------------------------------------------------- readout
class SegmentsConfig(StrictModel):
    """Full-image compressed mode: per-row runs of pixels at or above the thresholds."""

    thresholds_dn: tuple[Annotated[int, Field(ge=0, le=65535)], ...] = Field(
        (200,), description="increasing thresholds [DN] (assumption: offset + ~24 read-noise "
        "sigma)")
    max_runs: Annotated[int, Field(ge=1)] = Field(
        4096, description="most runs one readout returns (assumption: AA-STR limit not public; "
        "sized from the < 2 MB processor memory)")
    max_pixels: Annotated[int, Field(ge=1)] = Field(
        262_144, description="most pixels one readout returns (assumption: 512 kB of 16-bit DN)")

    @field_validator("thresholds_dn")
    @classmethod
    def _increasing(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if len(v) == 0:
            raise ValueError("at least one threshold is needed")
        if any(b <= a for a, b in zip(v, v[1:], strict=False)):
            raise ValueError(f"thresholds must be strictly increasing, got {v}")
        return v


class WindowSpec(StrictModel):
    """A window of the windows mode: top-left pixel and size [px]."""

    row0: Annotated[int, Field(ge=0)] = Field(description="top row of the window [px]")
    col0: Annotated[int, Field(ge=0)] = Field(description="left column of the window [px]")
    height: Annotated[int, Field(ge=1)] = Field(description="rows of the window [px]")
    width: Annotated[int, Field(ge=1)] = Field(description="columns of the window [px]")


class ReadoutTimingConfig(StrictModel):
    """Readout law ``t_exp_min = a + b N_pix / n_pix_unit`` (seed paper eq. 1, a = 8 ms,
    b = 0.17 ms), with the full frame never below ``full_frame_min_ms``.

    The paper does not say in which unit N_pix is counted: raw pixels would make a full frame
    last 178 s. We assume thousands of pixels (0.17 us per pixel, a 5.9 Mpx/s gate array),
    which gives 186 ms for 1024 x 1024, and add the paper's statement "a lower limit of 200
    ms ... to read the entire image" as a floor for full-frame readouts (full image compressed
    scans every pixel, so it counts as a full frame)."""

    a_ms: NonNegativeFloat = Field(8.0, description="fixed part [ms] (seed paper eq. 1)")
    b_ms: NonNegativeFloat = Field(0.17, description="per-unit part [ms] (seed paper eq. 1)")
    n_pix_unit: PositiveFloat = Field(1000.0, description="pixels per unit of N_pix "
                                      "(assumption, see above)")
    full_frame_min_ms: NonNegativeFloat = Field(
        200.0, description="minimum exposure of a full-frame readout [ms] (seed paper)")
    policy: Literal["enforce", "warn", "ignore"] = Field(
        "warn", description="enforce: raise when the exposure is shorter than the readout "
        "needs; warn: log and flag it (default, because the paper's 7.7 ms and 15 us cases are "
        "fictitious exposures); ignore")


class ReadoutConfig(StrictModel):
    """Star-tracker readout modes and their timing."""

    modes: tuple[Literal["segments", "windows", "full_frame"], ...] = Field(
        ("segments", "windows"), description="readouts requested from the sensor (windows "
        "only when windows are given); the DN frame is always kept for analysis")
    segments: SegmentsConfig = Field(
        default_factory=SegmentsConfig, description="full-image compressed mode: runs of pixels "
        "above thresholds")
    windows: tuple[WindowSpec, ...] = Field(
        (), description=f"windows of the windows mode (at most {MAX_WINDOWS})")
    timing: ReadoutTimingConfig = Field(
        default_factory=ReadoutTimingConfig, description="readout time law and how a too-short "
        "exposure is handled")

    @field_validator("windows")
    @classmethod
    def _max_windows(cls, v: tuple[WindowSpec, ...]) -> tuple[WindowSpec, ...]:
        if len(v) > MAX_WINDOWS:
            raise ValueError(f"at most {MAX_WINDOWS} windows (AA-STR windows mode), got {len(v)}")
        return v


class DebugConfig(StrictModel):
    keep_stages: bool = Field(False, description="keep a copy of the frame after every effect")


class DetectorConfig(StrictModel):
    """Detector chain settings. Units in the key names; SI inside."""

    exposure_time_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = Field(
        1.5e-5, description="integration time [s] (the paper's well-exposed case: 15 us), at "
        "most an hour (the lit Moon saturates the detector in milliseconds)"
    )
    order: Literal["physical", "paper"] = Field(
        "physical", description="stage order (starnav.detector.chain.CHAIN_ORDERS): physical "
        "(Pyxel-like) or the seed paper's (PSFs, saturation, distortion, noises)")
    sensor_seed: Annotated[int, Field(ge=0)] | None = Field(
        None, description="seed of the fixed-pattern maps (PRNU, DSNU, hot pixels) of one "
        "physical sensor; None: the dataset seed")
    optics: OpticsConfig = Field(
        default_factory=OpticsConfig, description="photon collection: radiometry, PSF, "
        "distortion, stray light, ghosts")
    smear: SmearConfig = Field(
        default_factory=SmearConfig, description="image motion during the exposure and the "
        "readout")
    charge: ChargeConfig = Field(
        default_factory=ChargeConfig, description="charge generation: PRNU, dark current, shot "
        "noise")
    saturation: SaturationConfig = Field(
        default_factory=SaturationConfig, description="full well and blooming")
    signal: SignalConfig = Field(
        default_factory=SignalConfig, description="charge to voltage: coupling, crosstalk, "
        "non-linearity, read noise")
    adc: AdcConfig = Field(
        default_factory=AdcConfig, description="analogue-to-digital conversion: gain, offset, "
        "bits")
    readout: ReadoutConfig = Field(
        default_factory=ReadoutConfig, description="what the sensor sends: segments, windows, "
        "full frame, and their timing")
    debug: DebugConfig = Field(
        default_factory=DebugConfig, description="diagnostics")

    @property
    def gain_e_per_dn(self) -> float:
        """Conversion gain [e-/DN] (explicit, or full well / (2^bits - 1))."""
        if self.adc.gain_e_per_dn is not None:
            return float(self.adc.gain_e_per_dn)
        return float(self.saturation.full_well_e) / (2**self.adc.bits - 1)
