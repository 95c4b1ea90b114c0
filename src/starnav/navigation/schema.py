"""Scenario section ``navigation`` (owned by :mod:`starnav.navigation`).

Units are in the key names (``_px``, ``_km``, ``_arcsec``, ``_days``). Each knob is declared
once, on its field (description, unit, range); a section whose algorithm reads it as it is is
declared beside that algorithm and reads its SI view (``to_si()``): ``limb``
(:class:`~starnav.navigation.limb.LimbConfig`), ``refine``
(:class:`~starnav.navigation.refine.RefineConfig`), ``ransac``
(:class:`~starnav.navigation.ransac.RansacConfig`), ``filter``
(:class:`~starnav.navigation.ekf.FilterConfig`), ``trn.front_end``
(:class:`~starnav.navigation.trn.options.TrnFrontEndConfig`) and ``trn.filter``
(:class:`~starnav.navigation.trn.filter.TrnFilterConfig`). :meth:`NavigationConfig.
chain_options` and :meth:`NavigationConfig.ekf_priors` resolve what the knobs and the scenario
give (the detector's noise and blur, the terrain, the attitude knowledge, the calibrations).

Example (YAML)::

    navigation:
      limb: {max_points: 600, min_sun_cos: 0.1}
      refine: {enabled: true, n_windows: 16, window_size_px: 11}
      ransac: {model: christian-robinson, threshold_px: 1.5}
      fix: {attitude_sigma_arcsec: 5}
      filter: {bias_model: range-scale, range_scale_sigma: 0.01, bias_tau_days: 5,
               initial_position_sigma_km: 100, initial_velocity_sigma_m_s: 1}
      runs: 20
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from starnav.camera import camera_from_config
from starnav.camera_calibration import CameraCalibration, bench_calibration, read_calibration
from starnav.config_base import StrictModel
from starnav.constants import MOON_RADIUS
from starnav.dem.limb import limb_topography_for
from starnav.errors import ConfigError
from starnav.fields import NonNegativeFloat, PositiveFloat
from starnav.navigation.christian_robinson import ChristianRobinsonOptions
from starnav.navigation.ekf import EkfPriors, FilterConfig
from starnav.navigation.limb import LimbConfig
from starnav.navigation.pipeline import ChainOptions
from starnav.navigation.psf import estimated_psf
from starnav.navigation.ransac import RansacConfig
from starnav.navigation.refine import (
    EdgeSpread,
    PixelNoise,
    RefineConfig,
    RefineModels,
    packaged_model_error,
)
from starnav.navigation.trn.filter import TrnFilterConfig
from starnav.navigation.trn.options import TrnFrontEndConfig


class FixConfig(StrictModel):
    """Christian-Robinson fix (starnav.navigation.christian_robinson)."""

    moon_radii_km: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = Field(
        None, description="Moon semi-axes (a, b, c) [km]; null: the sphere of the moon section")
    attitude_sigma_arcsec: (NonNegativeFloat
                            | tuple[NonNegativeFloat, NonNegativeFloat, NonNegativeFloat]
                            | None) = Field(
        None, description="attitude knowledge 1-sigma [arcsec]: one value, or (x, y, z) about "
        "the camera axes (z = roll); null: the scenario's pointing knowledge (cross, cross, "
        "roll), 0 without a scenario")


class AttitudeSourceConfig(StrictModel):
    """Where the fix's attitude comes from (docs/stars.md, "Navigation with the solved attitude";
    :mod:`starnav.simulate.attitude`)."""

    source: Literal["assumed", "stars"] = Field(
        "assumed", description="assumed: the pointing section's knowledge error and the fix's "
        "attitude_sigma_arcsec; stars: the tracker's own attitude solved from star acquisitions "
        "(needs stars.enabled), propagated by the gyro between them, with its covariance")
    star_exposure_s: PositiveFloat = Field(
        0.2, description="exposure of the star acquisitions [s] (the unmodified tracker: 200 ms)")
    schedule_every: Annotated[int, Field(ge=1)] = Field(
        1, description="a star acquisition at every k-th navigation frame (frames 0, k, 2k, ...);"
        " the attitude of the others is propagated from the last solution")
    navigation_frames: bool = Field(
        True, description="also try the navigation frame's own stars (at its exposure) when no "
        "star acquisition is scheduled or its solve failed, before propagating")
    gyro_arw_deg_rt_h: NonNegativeFloat = Field(
        0.005, description="gyro angle random walk per axis [deg/sqrt(h)] (default: an "
        "assumption of the order of a space fibre-optic gyro)")
    gyro_bias_deg_h: NonNegativeFloat = Field(
        0.01, description="1-sigma of the gyro's uncalibrated rate bias per axis, a random "
        "constant per run [deg/h] (assumption, as the ARW)")


class TrnShapeModelConfig(StrictModel):
    """The body model the fly-by estimator navigates on (the truth always renders the full
    shape model of ``target``)."""

    map: Literal["exact", "coarse"] = Field(
        "exact", description="exact: the rendered mesh itself (an idealised map, the former "
        "behaviour); coarse: a decimated, smoothed model of it whose scale is drawn per run "
        "(starnav.bodies.shape.coarse_shape_model): what a mission has before the fly-by")
    faces: Annotated[int, Field(ge=4)] = Field(
        500, description="triangles of the coarse model (quadric decimation)")
    smoothing_iterations: Annotated[int, Field(ge=0, le=1000)] = Field(
        10, description="Taubin smoothing passes of the coarse model")
    scale_sigma: Annotated[float, Field(ge=0, lt=0.5)] = Field(
        0.02, description="1-sigma of the coarse model's scale error, drawn per Monte Carlo "
        "run [-] (the filter's shape-scale state starts with it when estimate_scale)")
    estimate_scale: bool = Field(
        True, description="carry the scale error as a filter state (filter step 4e); false: "
        "the filter takes the drawn model's scale as exact")
    height_sigma_ratio: Annotated[float, Field(ge=0, le=100)] = Field(
        2.15, description="the coarse model's height error at a landmark, 1-sigma, over the "
        "model's rms height error against the truth (its stated accuracy; the packaged "
        "bodies' at 500 faces: docs/navigation.md) [-]; the landmark height sigma is the "
        "larger of this and filter.landmark_height_sigma_m")
    birth_sigma_fraction: Annotated[float, Field(ge=0)] = Field(
        0.3, description="no landmark is born on the coarse model while the position's "
        "largest 1-sigma exceeds this fraction of the mean radius [-] (filter step 7a; "
        "filter.birth_position_sigma_m, when set, takes precedence; 0: always)")


class TrnConfig(StrictModel):
    """Asteroid fly-by terrain-relative navigation (starnav.navigation.trn)."""

    shape_model: TrnShapeModelConfig = Field(
        default_factory=TrnShapeModelConfig, description="the body model the estimator "
        "navigates on")

    front_end: TrnFrontEndConfig = Field(
        default_factory=TrnFrontEndConfig, description="windows and feature tracking")
    filter: TrnFilterConfig = Field(
        default_factory=TrnFilterConfig, description="the estimator: EKF with landmark states")
    dispersion: Literal["none", "orientation"] = Field(
        "none", description="what the Monte Carlo runs draw besides detector noise, attitude "
        "knowledge and initial error: none (one geometry rendered once, every run re-exposes "
        "it) or orientation (each run draws the fly-by's orientation relative to the body "
        "uniformly and renders its own frames: the silhouette model error the filter's bias "
        "states stand for is then sampled, not one draw shared by all runs)")


#: Most Monte Carlo runs: at 10^4 runs the NEES band of the consistency test is already within
#: +-2 % of its mean (chi-square, 6 x 10^4 degrees of freedom), and each run repeats the chain.
MAX_RUNS = 10_000


class NavigationConfig(StrictModel):
    """Navigation chain settings (see :mod:`starnav.navigation`)."""

    limb: LimbConfig = Field(
        default_factory=LimbConfig, description="pixel-level limb points from the segments "
        "readout")
    refine: RefineConfig = Field(
        default_factory=RefineConfig, description="sub-pixel limb refinement in the windows "
        "readout")
    ransac: RansacConfig = Field(
        default_factory=RansacConfig, description="outlier rejection among the limb points")
    fix: FixConfig = Field(
        default_factory=FixConfig, description="Christian-Robinson position fix from the limb")
    filter: FilterConfig = Field(
        default_factory=FilterConfig, description="extended Kalman filter over the fixes")
    attitude: AttitudeSourceConfig = Field(
        default_factory=AttitudeSourceConfig, description="the fix's attitude: assumed "
        "knowledge error, or solved from the stars and propagated by the gyro")
    trn: TrnConfig = Field(
        default_factory=TrnConfig, description="asteroid fly-by terrain-relative navigation "
        "from windows (front end and estimator)")
    camera_calibration: Literal["bench"] | Path | None = Field(
        "bench", description="the camera the chain navigates with (the truth still renders "
        "with the camera section's): bench: the default tracker as an emulated HIL bench "
        "calibrated it, one seeded bench per run (starnav.camera_calibration."
        "bench_calibration; other cameras are known exactly); a path: a camera calibration "
        "file (e.g. `starnav hil geometric`'s camera_calibration.json); null: the camera "
        "section's camera, known exactly (perfect knowledge, an analysis option). With a "
        "calibration, the attitude is the one a star solve through the calibrated camera "
        "gives, and the calibration's parameters are the filter's consider states")
    runs: Annotated[int, Field(ge=1, le=MAX_RUNS)] = Field(
        1, description="Monte Carlo runs of `starnav navigate` (>= 2: each over its own "
        "detector noise, attitude knowledge error and initial error, with the consistency "
        f"verdict), at most {MAX_RUNS}")

    # ---------------------------------------------------------------- conversions
    def chain_options(self, moon_radius_m: float | None = None, *,
                      scenario: Any | None = None,
                      radii_m: tuple[float, float, float] | None = None) -> ChainOptions:
        """The SI :class:`~starnav.navigation.pipeline.ChainOptions` of this section.

        ``moon_radius_m`` is the sphere used when ``fix.moon_radii_km`` is null (default the
        LOLA reference radius). ``scenario`` (a :class:`starnav.config.Scenario`, e.g. the one a
        dataset records) supplies what the frames were made with: the detector's per-pixel
        noise (``refine.noise_model``), the terrain's limb-height spread
        (``refine.terrain_model_error``, DEM Moons only) and the pointing knowledge error
        (``fix.attitude_sigma_arcsec: null``). ``radii_m``: the target body's reference
        ellipsoid (``starnav.simulate.chain_options`` passes it), used when
        ``fix.moon_radii_km`` is null.
        """
        Rf, F = self.refine, self.fix
        Fsi = F.to_si()
        r = MOON_RADIUS if moon_radius_m is None else float(moon_radius_m)
        if Fsi.moon_radii is not None:
            radii = tuple(Fsi.moon_radii)
        elif radii_m is not None:
            radii = tuple(float(x) for x in radii_m)
        else:
            radii = (r, r, r)
        noise, terrain, spread = None, None, None
        att: float | tuple[float, float, float] = 0.0
        if Fsi.attitude_sigma is not None:
            a = Fsi.attitude_sigma
            att = a if isinstance(a, float) else tuple(a)
        if scenario is not None:
            if Rf.noise_model:
                noise = PixelNoise.from_detector(scenario.detector)
            if (Rf.edge_model in ("auto", "detector-psf")
                    and scenario.detector.optics.aberration.enabled):
                aberration = None
                if Rf.psf_knowledge == "estimated":
                    aberration = estimated_psf(scenario.detector,
                                               camera_from_config(scenario.camera)).aberration
                spread = EdgeSpread.from_detector(scenario.detector, aberration=aberration)
            on_moon = getattr(scenario, "target", None) is None or scenario.target.kind == "moon"
            if Rf.terrain_model_error and on_moon and scenario.moon.shape == "dem":
                terrain = limb_topography_for(_coarser(scenario.moon.dem, Rf.terrain_model_ppd))
            if Fsi.attitude_sigma is None:
                att = scenario.pointing.knowledge_sigma
        refine = Rf.to_si()
        edge_model = RefineModels(spread=spread).edge_model(refine)
        table = None
        if edge_model == "detector-psf":
            table = packaged_model_error().for_exposure(
                None if scenario is None else float(scenario.detector.exposure_time_s))
        # the fix's radius error when no refined points carry their own (pixel-level points)
        if terrain is None:
            radius_fraction = 0.0
        elif Rf.terrain_error_scale is None and table is not None:
            radius_fraction = math.sqrt(table.common_covariance[0][0])
        else:
            k = 1.0 if Rf.terrain_error_scale is None else Rf.terrain_error_scale
            radius_fraction = k * terrain.common_fraction
        return ChainOptions(
            limb=self.limb.to_si(),
            ransac=self.ransac.to_si(),
            refine=refine,
            refine_models=RefineModels(noise=noise, spread=spread, limb_topography=terrain,
                                       model_error_table=table),
            use_windows=Rf.enabled,
            fix=ChristianRobinsonOptions(
                radii_m=radii,  # type: ignore[arg-type]
                attitude_sigma_rad=att,
                radius_sigma_fraction=radius_fraction),
            calibration=self.calibration(scenario),
        )

    def calibration(self, scenario: Any | None = None, run: int = 0) -> CameraCalibration | None:
        """The camera as the chain knows it (None: the camera section's, exactly): the file of
        ``camera_calibration``, checked against ``scenario``'s detector (size and pixel
        pitch); for ``bench``, run ``run``'s emulated bench calibration of ``scenario``'s
        camera (None without a scenario, or for a camera the packaged benches were not made
        for)."""
        if self.camera_calibration is None:
            return None
        if self.camera_calibration == "bench":
            if scenario is None:
                return None
            return bench_calibration(camera_from_config(scenario.camera), int(scenario.seed),
                                     int(run))
        cal = read_calibration(self.camera_calibration)
        if scenario is not None:
            cam = camera_from_config(scenario.camera)
            if not cal.matches(cam):
                raise ConfigError("navigation.camera_calibration",
                                  str(self.camera_calibration),
                                  f"a calibration of the scenario's {cam.width} x "
                                  f"{cam.height} px detector with its pixel pitch")
        return cal

    def ekf_priors(self, calibration: CameraCalibration | None = None,
                   exposure_s: float | None = None) -> EkfPriors:
        """What the filter (its section's SI view, ``filter.to_si()``) needs besides its
        knobs: the ``limb-common`` bias states' covariance for frames exposed ``exposure_s``
        [s] (None: the well-exposed terms), and with the chain's camera ``calibration`` its
        parameters as consider states, with the calibration's covariance."""
        common = consider = None
        if self.filter.bias_model == "limb-common":
            # the states carry what the fix's own covariance carries besides its pixels and
            # the attitude: the calibrated slowly varying fix error in the three limb modes
            # (ModelErrorCalibration.fix_covariance), not the points' shared error
            # (common_covariance, half of it: the filter was overconfident wherever the
            # attitude's sigma no longer hid the difference, docs/stars.md); in the blooming
            # regime every frame saturates, so its states carry the saturated fix's terms
            base = packaged_model_error()
            table = base.for_exposure(exposure_s)
            C = table.fix_covariance if table is base else table.fix_covariance_saturated
            common = tuple(tuple(float(x) for x in r) for r in C)
        if calibration is not None and calibration.parameters:
            consider = tuple(tuple(float(x) for x in r)
                             for r in np.asarray(calibration.covariance, float))
        return EkfPriors(common_covariance=common, consider_covariance=consider)

    def initial_covariance(self) -> NDArray[np.float64]:
        """Diagonal initial covariance (6 x 6) [m^2, m^2/s^2] from the filter's sigmas."""
        si = self.filter.to_si()
        sp, sv = si.initial_position_sigma, si.initial_velocity_sigma
        return np.diag([sp * sp] * 3 + [sv * sv] * 3)


def _coarser(dem: Any, ppd: float | None) -> Any:
    """The DEM section ``dem`` area-averaged to at most ``ppd`` [px/deg] (None: as it is)."""
    if ppd is None:
        return dem
    cap = dem.max_pixels_per_degree
    return dem.model_copy(update={"max_pixels_per_degree": ppd if cap is None else min(cap, ppd)})

