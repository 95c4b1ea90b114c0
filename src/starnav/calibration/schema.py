"""Bench description (``BENCH`` YAML file) owned by :mod:`starnav.calibration`.

One frozen model per part of the hardware-in-the-loop bench (screen, collimator, misalignments
of the assembly) and per calibration step; units in the key names, unknown keys rejected.
Defaults are the paper's TinyV3RSE bench where the paper gives a number (screen height 65 mm,
180 mm doublet, Table 2's spot radii, the stated 10 deg field of eq. 2); the screen's pixels
and emittance, the collimator's transmission and distortion are **representative**, not
measured; misalignments are zero. Sources and trust of each: docs/calibration.md, "The bench
file". The camera, detector and scene come from an embedded
:class:`~starnav.config.Scenario` (key ``scenario``).

Index
-----
:class:`BenchConfig`, :func:`load_bench`, :func:`bench_from_dict`, :func:`bench_to_dict`;
:class:`ScreenConfig`, :class:`ScreenEmittanceConfig`, :func:`representative_emittance`,
:func:`photopic_efficiency`, :class:`CollimatorConfig`, :class:`MisalignmentConfig`,
:class:`AcquisitionConfig`, :class:`GeometricCalibrationConfig`, :class:`RadiometricConfig`,
:class:`ScalingConfig`, :class:`CheckConfig`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from starnav.config import Scenario, load_scenario
from starnav.config_base import StrictModel, model_from_mapping, read_yaml_file
from starnav.errors import ConfigError
from starnav.fields import FiniteFloat, NonNegativeFloat, PositiveFloat, PositiveFraction

#: Luminous efficacy of radiation at 555 nm [lm/W] (CIE).
KM_LM_PER_W = 683.0
#: Rec. 709 / sRGB luminance shares of the red, green and blue primaries of a white [-].
REC709_LUMINANCE_SHARES = (0.2126, 0.7152, 0.0722)
#: Representative primaries: (peak nm, FWHM nm) of a white-LED LCD / RGB OLED panel.
REPRESENTATIVE_PRIMARIES_NM = ((615.0, 35.0), (535.0, 45.0), (455.0, 25.0))
#: Representative full-white luminance of the screen [cd/m^2].
REPRESENTATIVE_WHITE_CD_M2 = 500.0


# --------------------------------------------------------------------------- the screen
def photopic_efficiency(wavelength_nm: np.ndarray) -> np.ndarray:
    """CIE photopic luminous efficiency V(lambda), Gaussian approximation [-].

    ``V = 1.019 exp(-285.4 (lambda_um - 0.559)^2)`` (a common single-Gaussian fit of the CIE
    1924 curve, a few percent off in the wings). Only used to size the *representative* screen.
    """
    lam = np.asarray(wavelength_nm, float) * 1e-3
    return 1.019 * np.exp(-285.4 * (lam - 0.559) ** 2)


def representative_emittance(white_luminance_cd_m2: float = REPRESENTATIVE_WHITE_CD_M2,
                             gamma: float = 2.2) -> ScreenEmittanceConfig:
    """A representative per-channel spectral radiance of an RGB screen at full count.

    Three Gaussian primaries (:data:`REPRESENTATIVE_PRIMARIES_NM`: red 615/35 nm, green
    535/45 nm, blue 455/25 nm, peak/FWHM), each scaled so that its luminance is its Rec. 709 share
    of a ``white_luminance_cd_m2`` white (``Lv = 683 integral L V dlambda``). This is *not* a
    measurement of the TinyV3RSE screen (the paper measured its screen with a power meter). The
    500 cd/m^2 white (a typical panel; ~2.0 W m^-2 sr^-1) was chosen before comparing with the
    paper, and lands where the paper did: the screen is ~19 times too dim for the Moon at
    rho = 0.12, and the k = 13 333 case peaks at count 13, the paper's maximum count for full
    frames. A plausibility check, not a calibration.
    """
    wl = np.arange(380.0, 780.0 + 0.5, 5.0)
    v = photopic_efficiency(wl)
    chans = []
    for (peak, fwhm), share in zip(REPRESENTATIVE_PRIMARIES_NM, REC709_LUMINANCE_SHARES,
                                   strict=True):
        s = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
        shape = np.exp(-0.5 * ((wl - peak) / s) ** 2)
        lv_unit = KM_LM_PER_W * float(np.trapezoid(shape * v, wl))
        amp = share * white_luminance_cd_m2 / lv_unit
        chans.append(tuple(float(f"{x:.6g}") for x in amp * shape))
    return ScreenEmittanceConfig(
        wavelengths_nm=tuple(float(x) for x in wl), red_w_m2_sr_nm=chans[0],
        green_w_m2_sr_nm=chans[1], blue_w_m2_sr_nm=chans[2], gamma=(gamma, gamma, gamma),
        source=f"representative: Gaussian primaries, {white_luminance_cd_m2:g} cd/m^2 white, "
               f"gamma {gamma:g} (not measured)")


class ScreenEmittanceConfig(StrictModel):
    """Spectral radiance of each screen channel at full count, and its transfer curve.

    A channel at count ``n`` emits ``L_c(lambda) [b + (1 - b) (n / n_max)^gamma_c]`` with ``b``
    the black level. Measured data (spectroradiometer or power meter behind filters, the
    paper's step 1) replace the tables; the default is :func:`representative_emittance`.
    """

    wavelengths_nm: tuple[FiniteFloat, ...] = Field(
        description="sample wavelengths, strictly increasing [nm]")
    red_w_m2_sr_nm: tuple[NonNegativeFloat, ...] = Field(
        description="red channel spectral radiance at full count [W m^-2 sr^-1 nm^-1]")
    green_w_m2_sr_nm: tuple[NonNegativeFloat, ...] = Field(
        description="green channel spectral radiance at full count [W m^-2 sr^-1 nm^-1]")
    blue_w_m2_sr_nm: tuple[NonNegativeFloat, ...] = Field(
        description="blue channel spectral radiance at full count [W m^-2 sr^-1 nm^-1]")
    gamma: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (2.2, 2.2, 2.2), description="display gamma of red, green, blue [-]")
    black_level_fraction: Annotated[float, Field(ge=0, lt=0.5, allow_inf_nan=False)] = Field(
        0.0, description="radiance at count 0 / radiance at full count [-] (0: OLED; ~1e-3 "
        "for an LCD)")
    source: str = Field("measured", description="where the tables come from (free text)")

    @model_validator(mode="after")
    def _tables(self) -> ScreenEmittanceConfig:
        n = len(self.wavelengths_nm)
        if n < 2:
            raise ValueError(f"wavelengths_nm has {n} sample(s): the emittance needs at least 2 "
                             "wavelength samples (no emittance data)")
        for name in ("red_w_m2_sr_nm", "green_w_m2_sr_nm", "blue_w_m2_sr_nm"):
            m = len(getattr(self, name))
            if m != n:
                raise ValueError(f"{name} has {m} values; expected {n} (one per wavelength)")
        if any(b <= a for a, b in zip(self.wavelengths_nm, self.wavelengths_nm[1:],
                                      strict=False)):
            raise ValueError("wavelengths_nm must be strictly increasing")
        if not any(any(v > 0 for v in getattr(self, c)) for c in
                   ("red_w_m2_sr_nm", "green_w_m2_sr_nm", "blue_w_m2_sr_nm")):
            raise ValueError("every channel is zero: the screen emits nothing (no emittance data)")
        return self

    def channels(self) -> np.ndarray:
        """``(3, n)`` spectral radiance of red, green, blue at full count [W m^-2 sr^-1 nm^-1]."""
        return np.array([self.red_w_m2_sr_nm, self.green_w_m2_sr_nm, self.blue_w_m2_sr_nm])


class ScreenConfig(StrictModel):
    """The stimulating screen: pixel grid, physical size, counts, spectral emittance.

    Screen pixel axes are defined as seen by the camera through the collimator (column index
    along the camera's +x, row index along +y): the mirror flip of a real collimator is a
    display setting. Pixels are square; their pitch is ``height_mm / height_px``.
    """

    width_px: Annotated[int, Field(ge=2)] = Field(
        3840, description="columns [px] (representative 4K panel)")
    height_px: Annotated[int, Field(ge=2)] = Field(
        2160, description="rows [px] (representative 4K panel)")
    height_mm: PositiveFloat = Field(65.0, description="active height h_s [mm] (seed paper)")
    bit_depth: Annotated[int, Field(ge=1, le=16)] = Field(
        8, description="bits per channel; counts run 0 .. 2^bits - 1")
    emittance: ScreenEmittanceConfig | None = Field(
        default_factory=representative_emittance,
        description="per-channel spectral radiance and gamma; null = not measured (the "
        "radiometric steps then refuse to run)")

    @property
    def pitch_mm(self) -> float:
        """Pixel pitch [mm]."""
        return self.height_mm / self.height_px

    @property
    def width_mm(self) -> float:
        """Active width [mm]."""
        return self.width_px * self.pitch_mm

    @property
    def max_count(self) -> int:
        """Largest digital count [-]."""
        return 2**self.bit_depth - 1


# --------------------------------------------------------------------------- the collimator
class CollimatorConfig(StrictModel):
    """The collimating lens between the screen and the camera.

    The aberration spot (seed paper Table 2, Zemax) is given as RMS radius on the AA-STR
    detector; it is an angular blur of the collimated beam, so it is stored with the IFOV it was
    expressed in and rescaled to any camera. Between and beyond the table the RMS radius follows
    ``spot_model``: ``quadratic`` (least-squares ``r = a + b theta^2``, the growth of field
    curvature/astigmatism; 0.49 + 0.0178 theta_deg^2 px fits Table 2 within 0.05 px) or
    ``linear`` (piecewise linear, constant beyond the last field).
    """

    focal_length_mm: Annotated[float, Field(ge=1, le=1e5)] = Field(
        180.0, description="f_coll [mm] (seed paper), 1 mm to 100 m")
    transmission: PositiveFraction = Field(
        0.96, description="transmission of the doublet [-] (representative, AR-coated)")
    nd_optical_density: NonNegativeFloat = Field(
        0.0, description="neutral-density filter in the beam, optical density [-] "
        "(transmission 10^-OD); dims a screen that is too bright for the exposure")
    spot_field_deg: tuple[NonNegativeFloat, ...] = Field(
        (0.0, 3.67, 7.32, 9.61), description="field angles of the spot table [deg] (Table 2)")
    spot_rms_radius_px: tuple[NonNegativeFloat, ...] = Field(
        (0.49, 0.72, 1.49, 2.13), description="spot RMS radius on the detector [px] (Table 2)")
    spot_reference_ifov_arcsec: PositiveFloat = Field(
        73.2301, description="IFOV of the pixels of spot_rms_radius_px [arcsec] (AA-STR: "
        "18 um / 50.7 mm)")
    spot_model: Literal["quadratic", "linear"] = Field(
        "quadratic", description="interpolation of the spot table over the field")
    distortion_k1: Annotated[float, Field(ge=-10, le=10)] = Field(
        0.1, description="radial distortion of the screen-to-angle map t_d = t (1 + k1 |t|^2 "
        "+ k2 |t|^4), t = tangent of the field angle [-] (representative: +0.33 % at 10 deg); "
        "|k1| <= 10: 31 % at 10 deg already")
    distortion_k2: Annotated[float, Field(ge=-100, le=100)] = Field(
        0.0, description="see distortion_k1 [-]; |k2| <= 100: 9.6 % at 10 deg")
    clear_aperture_mm: PositiveFloat | None = Field(
        None, description="clear aperture diameter [mm]; null: no vignetting modelled (the "
        "paper chose a support that does not vignette)")
    pupil_distance_mm: NonNegativeFloat = Field(
        50.0, description="distance from the collimator to the camera's entrance pupil [mm] "
        "(used with clear_aperture_mm)")

    @model_validator(mode="after")
    def _spot_table(self) -> CollimatorConfig:
        f, r = self.spot_field_deg, self.spot_rms_radius_px
        if len(f) != len(r) or len(f) < 1:
            raise ValueError(f"spot_field_deg ({len(f)} values) and spot_rms_radius_px "
                             f"({len(r)} values) must have the same length >= 1")
        if any(b <= a for a, b in zip(f, f[1:], strict=False)):
            raise ValueError("spot_field_deg must be strictly increasing")
        if self.spot_model == "quadratic" and len(f) < 2:
            raise ValueError("spot_model 'quadratic' needs at least 2 spot table rows")
        return self


class MisalignmentConfig(StrictModel):
    """How the assembled bench departs from the nominal one (the emulated truth).

    The screen is rolled about its normal, then tilted about its column (x) and row (y) axes,
    then shifted in its plane and along the axis (``screen_defocus_mm``, positive towards the
    lens). The camera is rotated with respect to the collimator axis by ``camera_tilt_deg``
    (about its x then y axes) and ``camera_roll_deg`` (about its boresight).
    """

    screen_shift_mm: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="in-plane shift of the screen (x, y) [mm]")
    screen_roll_deg: FiniteFloat = Field(0.0, description="screen rotation about its normal [deg]")
    screen_tilt_deg: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="screen tilt about its x and y axes [deg] (keystone, defocus)")
    screen_defocus_mm: FiniteFloat = Field(
        0.0, description="screen distance from the focal plane, + towards the lens [mm]")
    camera_tilt_deg: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="camera rotation about its x and y axes w.r.t. the "
        "collimator axis [deg]")
    camera_roll_deg: FiniteFloat = Field(0.0, description="camera rotation about its boresight "
                                         "[deg]")
    collimator_focal_length_error: Annotated[float, Field(gt=-0.1, lt=0.1)] = Field(
        0.0, description="as-built collimator focal length / design value - 1 [-] (the "
        "calibration knows the design value to geometric.collimator_focal_length_sigma)")
    collimator_k1_error: Annotated[float, Field(gt=-1.0, lt=1.0)] = Field(
        0.0, description="as-built collimator radial distortion - collimator.distortion_k1 [-] "
        "(known to geometric.collimator_k1_sigma)")
    camera_focal_length_error: Annotated[float, Field(gt=-0.1, lt=0.1)] = Field(
        0.0, description="the camera's true focal length / its datasheet value - 1 [-] (what "
        "the camera calibration estimates)")
    camera_principal_point_offset_px: tuple[FiniteFloat, FiniteFloat] = Field(
        (0.0, 0.0), description="the camera's true principal point - its datasheet value [px]")
    camera_k1_error: Annotated[float, Field(gt=-1.0, lt=1.0)] = Field(
        0.0, description="the camera's true k1 - its datasheet value [-]")

    @field_validator("screen_tilt_deg", "camera_tilt_deg")
    @classmethod
    def _small(cls, v: tuple[float, float]) -> tuple[float, float]:
        if any(abs(x) > 10.0 for x in v):
            raise ValueError(f"tilts must be within +-10 deg, got {v}")
        return v


# --------------------------------------------------------------------------- knobs
class AcquisitionConfig(StrictModel):
    """Emulated acquisition (screen -> collimator -> camera)."""

    psf_levels: Annotated[int, Field(ge=1, le=32)] = Field(
        6, description="Gaussian widths blended to emulate the field-varying collimator spot")
    include_spot_psf: bool = Field(True, description="blur by the collimator spot and defocus")


class GeometricCalibrationConfig(StrictModel):
    """Dot-pattern geometric calibration (seed paper, "Geometric Calibration")."""

    polynomial_order: Annotated[int, Field(ge=1, le=8)] = Field(
        4, description="total degree of the 2-D calibration polynomials")
    dot_grid: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] = Field(
        (17, 17), description="calibration dots along (x, y)")
    validation_grid: tuple[Annotated[int, Field(ge=1)], Annotated[int, Field(ge=1)]] = Field(
        (12, 12), description="closed-loop validation dots along (x, y), placed between the "
        "calibration dots")
    dot_margin_px: NonNegativeFloat = Field(
        24.0, description="distance of the outer dots from the detector edge [px]")
    dot_sigma_screen_px: PositiveFloat = Field(
        1.5, description="Gaussian dot radius on the screen (anti-aliased, sub-pixel placed) "
        "[screen px]")
    holdout_fraction: Annotated[float, Field(ge=0, lt=0.9)] = Field(
        0.25, description="share of the dots kept out of the fit to measure its residual")
    dot_peak_fraction: PositiveFraction = Field(
        0.5, description="auto exposure: charge of the brightest dot pixel in a preview "
        "acquisition, as a fraction of the full well")
    exposure_ms: PositiveFloat | None = Field(None, description="dot exposure [ms]; null: auto")
    centroid_half_window_px: Annotated[int, Field(ge=2, le=32)] = Field(
        7, description="half size of the centroid window [px]")
    detection_threshold_sigma: PositiveFloat = Field(
        10.0, description="detection threshold above the dark-subtracted background [noise "
        "sigma]")
    subtract_dark_frame: bool = Field(True, description="acquire a black screen and subtract it")
    mount_tilt_sigma_deg: PositiveFloat = Field(
        0.1, description="camera intrinsics: 1-sigma tilt of the camera on its bench mount "
        "about x and y [deg] (prior that separates a tilt from a principal-point shift)")
    collimator_focal_length_sigma: PositiveFloat = Field(
        1e-3, description="camera intrinsics: 1-sigma relative knowledge of the collimator's "
        "focal length [-] (a measured one; an unmeasured achromat's datasheet tolerance is "
        "+-1 %); a consider parameter of the camera's focal length")
    collimator_k1_sigma: PositiveFloat = Field(
        0.01, description="camera intrinsics: 1-sigma knowledge of the collimator's radial "
        "distortion coefficient [-]; a consider parameter of the camera's k1")
    screen_shift_sigma_mm: PositiveFloat = Field(
        0.3, description="camera intrinsics: 1-sigma in-plane placement of the screen on the "
        "collimator axis [mm] (consider parameter)")
    screen_tilt_sigma_deg: PositiveFloat = Field(
        0.5, description="camera intrinsics: 1-sigma screen tilt about x and y [deg] "
        "(consider parameter)")
    screen_defocus_sigma_mm: PositiveFloat = Field(
        0.05, description="camera intrinsics: 1-sigma screen distance from the collimator's "
        "focal plane [mm] (consider parameter)")


class RadiometricConfig(StrictModel):
    """Radiometric calibration and stimulus synthesis."""

    quantization: Literal["dither", "nearest"] = Field(
        "dither", description="counts from radiance: nearest level, or random dithering between "
        "the two neighbouring levels (unbiased in radiance)")
    headroom_fraction: PositiveFraction = Field(
        0.9, description="the stimulus peak uses at most this fraction of the screen's "
        "maximum radiance")
    disc_margin_px: Annotated[int, Field(ge=0, le=64)] = Field(
        8, description="dilation of the Moon mask for disc-integrated comparisons [px]")


class ScalingConfig(StrictModel):
    """Albedo-exposure scaling (seed paper, "Scaling between exposure time and albedo")."""

    render_exposure_ms: PositiveFloat = Field(
        0.015, description="exposure of the rendered (in-orbit) image [ms] (paper: 0.015)")
    bench_exposure_ms: PositiveFloat | None = Field(
        None, description="exposure on the bench [ms]; null: the shortest the readout allows")
    readout: Literal["full_frame", "windows"] = Field(
        "full_frame", description="readout the bench exposure must allow (full frame: 200 ms, "
        "paper eq. 1)")
    ks_k_multiples: tuple[PositiveFloat, ...] = Field(
        (1.0, 2.0, 4.0), description="KS experiment: factors k as multiples of the smallest k "
        "the screen allows")
    control_product_factor: PositiveFloat = Field(
        1.25, description="control sample: albedo x exposure off by this factor")
    ks_alpha: Annotated[float, Field(gt=0, lt=0.5)] = Field(
        0.01, description="significance of each two-sample KS test (false-alarm rate)")

    @field_validator("control_product_factor")
    @classmethod
    def _not_one(cls, v: float) -> float:
        if abs(v - 1.0) < 1e-3:
            raise ValueError("control_product_factor must differ from 1 (it breaks the product)")
        return v


class CheckConfig(StrictModel):
    """Optical-stimulator condition (seed paper eq. 2)."""

    stated_camera_fov_deg: PositiveFloat | None = Field(
        10.0, description="camera FoV the paper put in eq. 2 [deg]; reported next to the FoV "
        "derived from the camera (null: skip)")


class RadiometricTruthConfig(StrictModel):
    """How the real screen and collimator depart radiometrically from their datasheets (the
    emulated truth; :mod:`starnav.calibration.radiometric_truth`).

    The magnitudes are declared here; the departures themselves are drawn from the bench seed
    (``truth_seed`` offsets it), so every seeded bench is a different, reproducible panel.
    Sources: docs/facts.md section 7.
    """

    enabled: bool = Field(True, description="false: the truth screen is the datasheet one "
                          "(every departure below is zero)")
    angular_exponent: tuple[NonNegativeFloat, NonNegativeFloat, NonNegativeFloat] = Field(
        (1.6, 2.0, 2.6), description="radiance of red, green, blue falls as cos^n of the "
        "emission angle from the screen normal [-] (0: Lambertian; assumed values, measure "
        "them)")
    smooth_nonuniformity_rms: Annotated[float, Field(ge=0, le=0.2)] = Field(
        0.03, description="rms of the smooth large-scale luminance field over the screen [-]")
    pixel_nonuniformity_rms: Annotated[float, Field(ge=0, le=0.2)] = Field(
        0.01, description="rms of the pixel-to-pixel luminance scatter [-]")
    warmup_amplitude: Annotated[float, Field(ge=0, le=0.5)] = Field(
        0.04, description="relative luminance deficit at power-on, relaxing exponentially [-]")
    warmup_time_constant_min: PositiveFloat = Field(
        15.0, description="warm-up time constant [min]")
    drift_per_hour: Annotated[float, Field(ge=0, le=0.1)] = Field(
        0.002, description="1-sigma linear luminance drift after warm-up [1/h]")
    gamma_sigma: Annotated[float, Field(ge=0, le=0.5)] = Field(
        0.05, description="1-sigma departure of each channel's gamma from the nominal [-]")
    black_level_fraction: Annotated[float, Field(ge=0, lt=0.1)] = Field(
        1e-3, description="true black level / full white [-] (an LCD of contrast 1000:1)")
    ambient_fraction: Annotated[float, Field(ge=0, lt=0.1)] = Field(
        2e-4, description="stray light inside the enclosure reaching the camera / full white "
        "[-] (assumed)")
    transmission_tolerance: Annotated[float, Field(ge=0, lt=0.2)] = Field(
        0.02, description="as-built collimator transmission / collimator.transmission - 1 is "
        "drawn uniform in +-this [-] (two AR-coated faces at < 1 % reflectance each)")
    power_on_min: NonNegativeFloat = Field(
        45.0, description="time from power-on to the start of the radiometric calibration "
        "[min]")
    truth_seed: Annotated[int, Field(ge=0)] = Field(
        0, description="offset of the seed of the drawn departures (seed + truth_seed)")


class ReferenceInstrumentConfig(StrictModel):
    """The calibrated spectroradiometer the radiometric calibration is made against
    (:class:`~starnav.calibration.radiometric_truth.ReferenceInstrument`).

    Defaults are a display spectroradiometer's published specification (docs/facts.md
    section 7): luminance accuracy +-2 % (100-5000 cd/m^2), +-3 % (0.2-100), +-4 %
    (0.05-0.2); repeatability (2 sigma) 0.2 / 0.5 / 0.8 %; wavelength reproducibility +-1 nm;
    380-780 nm; acceptance +-1 deg. Accuracies are read as 2-sigma bounds.
    """

    band_nm: tuple[PositiveFloat, PositiveFloat] = Field(
        (380.0, 780.0), description="wavelength range of the instrument [nm]")
    level_bounds_cd_m2: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (0.05, 0.2, 100.0), description="luminance class bounds [cd/m^2]: below the first "
        "the reading is out of range")
    accuracy_2sigma: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (0.04, 0.03, 0.02), description="absolute accuracy (2 sigma) of the three classes, "
        "lowest first [-]")
    repeatability_2sigma: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (0.008, 0.005, 0.002), description="repeatability (2 sigma) of the three classes [-]")
    wavelength_2sigma_nm: NonNegativeFloat = Field(
        1.0, description="wavelength-scale error (2 sigma) [nm]")
    spectral_tilt_2sigma: NonNegativeFloat = Field(
        0.02, description="relative responsivity error, linear across the band, end to end "
        "(2 sigma) [-] (assumed)")
    acceptance_deg: PositiveFloat = Field(
        1.0, description="half-angle of the measuring field [deg]")
    aperture_mm: PositiveFloat = Field(
        10.0, description="diameter of the instrument's entrance aperture [mm] (receptor "
        "size)")


class RadiometricLabConfig(StrictModel):
    """The lab's radiometric calibration against the reference instrument, and its
    validation (:mod:`starnav.calibration.radiometric_lab`)."""

    lut_counts: tuple[Annotated[int, Field(ge=0)], ...] | None = Field(
        None, description="grey counts read on axis to make the screen LUT, from 0 to the "
        "full count; null: 0, 4, 8, 16, ... (powers of two up to half the levels), 3/4 of the "
        "levels and the full count (8 bit: 0 4 8 16 32 64 128 192 255)")
    flat_grid: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] = Field(
        (5, 5), description="field points (x, y) read at full white for the field factor")
    flat_margin_px: NonNegativeFloat = Field(
        40.0, description="distance of the outer field points from the detector edge [px]")
    readings_per_point: Annotated[int, Field(ge=1, le=100)] = Field(
        3, description="reference readings averaged per calibration point")
    reading_time_s: PositiveFloat = Field(
        10.0, description="time one reference reading takes [s] (warm-up drift during the "
        "session)")
    model_field: bool = Field(True, description="measure the field factor (angular emission, "
                              "smooth non-uniformity); false: assume a uniform screen")
    through_collimator: bool = Field(
        True, description="read the screen through the collimator; false: read the bare "
        "screen and apply collimator.transmission (the datasheet)")
    measure_lut: bool = Field(True, description="read the LUT counts; false: nominal gamma "
                              "scaled by the full-white reading")
    monitor: bool = Field(True, description="re-read full white on axis when the bench is "
                          "used and rescale (tracks warm-up and drift)")
    validation_counts: tuple[Annotated[int, Field(ge=1)], ...] | None = Field(
        None, description="hold-out grey counts of the validation (not in lut_counts); null: "
        "13 24 48 100 220 on an 8-bit screen, the same fractions of the levels on another")
    validation_exposures_ms: tuple[PositiveFloat, ...] = Field(
        (0.5, 7.7, 200.0), description="hold-out exposures [ms] (200: the paper's full frame, "
        "7.7: its fictitious exposure); each count is acquired at the longest one that keeps "
        "the patch below 90 % of the full well")
    validation_grid: tuple[Annotated[int, Field(ge=2)], Annotated[int, Field(ge=2)]] = Field(
        (4, 4), description="hold-out field points (x, y), placed between the flat_grid points")
    validation_delay_min: NonNegativeFloat = Field(
        60.0, description="time from the end of the calibration to the validation and the "
        "Moon stimuli on the truth bench [min]")
    patch_half_px: Annotated[int, Field(ge=1, le=64)] = Field(
        8, description="half size of the tracker patch averaged at each field point [px]")
    emission_exponent_sigma: NonNegativeFloat = Field(
        2.0, description="1-sigma of the screen's angular emission exponent (radiance ~ "
        "cos^p) the lab assumes for an uncharacterised panel [-]: with the reference's "
        "aperture smaller than the camera's pupil, the two average different emission cones")
    tolerance: PositiveFraction = Field(
        0.02, description="the paper's use: bench DN within this share of what the "
        "calibration predicts [-]")
    coverage_k: PositiveFloat = Field(
        2.0, description="coverage factor of the stated expanded uncertainty [-]")

    @model_validator(mode="after")
    def _counts(self) -> RadiometricLabConfig:
        c = self.lut_counts
        if c is not None and (len(c) < 3 or c[0] != 0
                              or any(b <= a for a, b in zip(c, c[1:], strict=False))):
            raise ValueError(f"lut_counts {list(c)}: expected >= 3 strictly increasing counts "
                             "starting at 0")
        if c is not None and self.validation_counts is not None and \
                set(self.validation_counts) & set(c):
            raise ValueError(f"validation_counts {list(self.validation_counts)} share "
                             f"{sorted(set(self.validation_counts) & set(c))} with lut_counts: "
                             "a hold-out must not be a calibration point")
        return self

    def counts_for(self, max_count: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """``(lut_counts, validation_counts)`` for a screen whose full count is ``max_count``
        (the defaults scaled to its levels).

        Raises
        ------
        ConfigError
            The LUT does not end at ``max_count``, a hold-out count is above it, or the
            derived counts collide.
        """
        levels = max_count + 1
        lut = self.lut_counts
        if lut is None:
            pw = [2**k for k in range(2, 64) if 2**k <= levels // 2]
            lut = tuple(sorted({0, *pw, 3 * levels // 4, max_count}))
        if lut[-1] != max_count:
            raise ConfigError("radiometric_lab.lut_counts", list(lut),
                              f"counts ending at the screen's full count {max_count}")
        val = self.validation_counts
        if val is None:
            val = tuple(sorted({max(1, round(f * levels / 256)) for f in
                                (13, 24, 48, 100, 220)} - set(lut)))
        bad = [v for v in val if v > max_count]
        if bad:
            raise ConfigError("radiometric_lab.validation_counts", bad,
                              f"counts <= the screen's full count {max_count}")
        if set(val) & set(lut):
            raise ConfigError("radiometric_lab.validation_counts", list(val),
                              f"hold-outs that are not calibration counts {list(lut)}")
        return tuple(int(x) for x in lut), tuple(int(x) for x in val)


class BenchConfig(StrictModel):
    """A hardware-in-the-loop bench: screen, collimator, assembly errors, camera, knobs."""

    screen: ScreenConfig = Field(default_factory=ScreenConfig)
    collimator: CollimatorConfig = Field(default_factory=CollimatorConfig)
    misalignment: MisalignmentConfig = Field(default_factory=MisalignmentConfig)
    acquisition: AcquisitionConfig = Field(default_factory=AcquisitionConfig)
    geometric: GeometricCalibrationConfig = Field(default_factory=GeometricCalibrationConfig)
    radiometric: RadiometricConfig = Field(default_factory=RadiometricConfig)
    scaling: ScalingConfig = Field(default_factory=ScalingConfig)
    check: CheckConfig = Field(default_factory=CheckConfig)
    radiometric_truth: RadiometricTruthConfig = Field(default_factory=RadiometricTruthConfig)
    reference_instrument: ReferenceInstrumentConfig = Field(
        default_factory=ReferenceInstrumentConfig)
    radiometric_lab: RadiometricLabConfig = Field(default_factory=RadiometricLabConfig)
    scenario: Scenario = Field(
        default_factory=Scenario, description="camera, sensor response, detector, Moon and Sun "
        "(a mapping, or a scenario file path relative to the bench file)")
    seed: Annotated[int, Field(ge=0)] = Field(
        7, description="seed of the bench's random streams (dithering, hold-out split, noise)")


# --------------------------------------------------------------------------- loading
def bench_from_dict(data: dict[str, Any] | None, overrides: list[str] | tuple[str, ...] = (),
                    base_dir: str | os.PathLike[str] | None = None) -> BenchConfig:
    """Validate a bench mapping (plus ``a.b=value`` overrides).

    ``scenario`` may be a mapping or the path of a scenario YAML (relative to ``base_dir``).

    Raises
    ------
    ConfigError
        Naming the first offending field, its value and what was expected.
    DataFileError
        The referenced scenario file does not exist.
    """
    def scenario_file(d: dict[str, Any]) -> dict[str, Any]:
        sc = d.get("scenario")
        if not isinstance(sc, str | os.PathLike):
            return d
        p = Path(sc)
        if not p.is_absolute() and base_dir is not None:
            p = Path(base_dir) / p
        return {**d, "scenario": load_scenario(p)}

    return model_from_mapping(BenchConfig, data, overrides, root="<bench root>",
                              expected="a mapping of bench sections", prepare=scenario_file)


def load_bench(path: str | os.PathLike[str] | None,
               overrides: list[str] | tuple[str, ...] = ()) -> BenchConfig:
    """Read and validate a bench YAML; ``None`` gives the paper's TinyV3RSE defaults."""
    if path is None:
        return bench_from_dict({}, overrides)
    p = Path(path)
    data = read_yaml_file(p, "bench file")
    return bench_from_dict(data or {}, overrides, base_dir=p.parent)


def bench_to_dict(bench: BenchConfig) -> dict[str, Any]:
    """JSON/YAML-safe dict of the fully resolved bench."""
    return bench.model_dump(mode="json")
