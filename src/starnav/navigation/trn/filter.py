"""Fly-by estimator: an EKF with body-fixed landmark states, fed by tracked features, the
tracker's own attitude, and the lit silhouette's centroid and apparent size.

It estimates the position and velocity relative to the body's centre (J2000, m and m/s) with
their covariance: the body's known size fixes the range, the lit centroid its direction, the
features the relative motion. Why landmark states, the observability argument and each step
in full: docs/methods.md, "starnav.navigation.trn.filter".

Technique, per frame
--------------------
1. Predict ``(r, v)``: constant velocity plus the body's point-mass gravity, white-acceleration
   process noise; the silhouette bias states decay as first-order Gauss-Markov processes, in
   time or (1a) in the aspect: the rotation of the view and of the Sun relative to the body
   (:func:`aspect_change`), which is what a shape model's silhouette error follows.
2. Drop the landmarks whose track is absent from the frame (marginalised).
3. Append the frame's attitude error ``dtheta`` (camera axes) to the state.
4. Measurements: features, lit centroid and apparent radius, with analytic Jacobians; 4a the
   bias sigmas follow the geometry and the model's own map error, and its centroid bias stays
   one image offset when the Sun's image direction turns; 4b shared feature error; 4c the
   silhouette's offset; 4d the bias's mean; 4e the model's scale as a consider state.
5. Gate each measurement on its own innovation; 5a re-open the state after ``reset_after``
   rejected silhouettes in a row.
6. Update with every accepted measurement at once (Joseph form); record the NIS.
7. Birth new landmarks by casting their pixel rays onto the shape model (EKF-SLAM
   augmentation); 7a none while the position's largest 1-sigma exceeds
   ``birth_position_sigma``.
8. Marginalise ``dtheta``; record the state, covariance, NIS and counts.

The knobs are the scenario section :class:`TrnFilterConfig`; what the body model adds,
:class:`ShapePrior`.

References
----------
A. Gelb (ed.), "Applied optimal estimation", MIT Press (1974): 4.4 (Gauss-Markov processes).
Y. Bar-Shalom, X. R. Li and T. Kirubarajan, "Estimation with applications to tracking and
navigation", Wiley (2001): 5.4 (NEES, NIS), 6.2.2 (white-noise acceleration model).
S. C. Nardone and V. J. Aidala, "Observability criteria for bearings-only target motion
analysis", IEEE Trans. AES 17 (1981) 162-166.
A. J. Davison, I. D. Reid, N. D. Molton and O. Stasse, "MonoSLAM: real-time single camera
SLAM", IEEE Trans. PAMI 29 (2007) 1052-1067.

Index
-----
:func:`run_filter` (the estimator), :class:`TrnFilterConfig`, :class:`ShapePrior`,
:class:`FlybyRun`;
measurement models :func:`features_model`, :func:`centroid_model`,
:func:`radius_model`, :func:`silhouette_scale`, :func:`shape_error_term`,
:func:`crescent_term`, :func:`map_error_factor`, :func:`silhouette_offset`;
:func:`propagate`, :func:`landmark_births`, :func:`gate_rows`, :func:`validate_inputs`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field, model_validator
from scipy.stats import chi2

from starnav.camera import Camera
from starnav.config_base import SIView, StrictModel
from starnav.errors import ConfigError, GeometryError
from starnav.fields import NonNegativeFloat, PositiveFloat
from starnav.navigation.trn.body_view import BodyInCamera, lit_silhouette, raycast
from starnav.navigation.trn.measurements import FlybyMeasurement
from starnav.typing import FloatArray

#: Longest prediction sub-step [s] (the gravity-gradient transition is first order in it).
MAX_STEP = 10.0
#: Position change [m] below which the iterated update stops.
ITERATION_TOLERANCE = 1e-3
#: Most relinearisations of the iterated update (1: the plain EKF).
ITERATIONS = 4
#: Orthonormality tolerance of a measured attitude matrix [-].
ROTATION_TOLERANCE = 1e-6
#: States before the landmarks: ``r`` (3), ``v`` (3), the centroid's model-error state
#: (along and across the Sun's image direction, 2) [px], the radius's (1) [-] and the shape
#: model's scale correction (1) [-]: the body is the model times ``1 + s``.
CORE = 10
BIAS = slice(6, 9)
SCALE = 9


#: Phase below which the terminator-shift law is held at its value [rad]: near zero phase the
#: terminator leaves the view and what remains (the limb's threshold) is not phase-driven.
PHASE_FLOOR = math.radians(15.0)


def silhouette_scale(radius_px: float, phase: float, options: SIView) -> FloatArray:
    """Factors ``(centroid along, centroid across, radius)`` by which the silhouette's
    model-error sigmas at the calibration geometry (``options.silhouette_reference_radius_px``,
    ``reference_phase``) scale at apparent radius ``radius_px`` [px] and Sun phase ``phase``
    [rad] (module step 4a); ones for ``silhouette_scaling = "constant"``; for ``"shape"`` the
    law of a shape model's own error (:func:`shape_error_term`), the across-Sun centroid's
    times the crescent factor ``hypot(1, kappa (1 - f) / f)`` (:func:`crescent_term`) over its
    value at the reference phase.

    Two mechanisms, each a closed form on a sphere of apparent radius ``rho`` at phase
    ``alpha``, whose lit area is ``A = pi rho^2 (1 + cos alpha) / 2`` with its centroid
    ``c = 4 rho (1 - cos alpha) / (3 pi)`` from the disc centre towards the Sun (the half disc
    plus the half ellipse of semi-axis ``rho cos alpha``):

    * *terminator shift*: what the lit-facet model leaves out near the terminator (cast
      shadows, the segments' threshold on the dim pixels there) moves the effective
      terminator by a small angle ``delta``, about the same at every geometry (a band of
      incidence angles near 90 deg). It moves the centroid by ``4 rho sin(alpha) delta /
      (3 pi)`` [px] and the equivalent radius ``sqrt(A / pi)`` by the fraction
      ``-tan(alpha / 2) delta / 2``;
    * *limb blur*: the detector's PSF spreads the lit limb (a half circle, ``pi rho`` long)
      outwards by ``w`` px above the threshold: ``dA = pi rho w``, a radius fraction
      ``w / (rho (1 + cos alpha))``.

    The centroid's factor is ``(rho / rho_ref) (sin alpha / sin alpha_ref)`` (the terminator
    term; the limb blur moves it little); the radius's is the ratio of
    ``hypot(w / (rho (1 + cos alpha)), tan(alpha / 2) delta / 2)`` to its reference value
    (``w = options.silhouette_limb_blur_px``, ``delta = options.silhouette_terminator_shift``;
    the two have opposite signs, the sigma takes their root sum square: it never vanishes where
    they cancel).
    On the calibration fly-by (phase 35 - 66 deg) the centroid error over ``rho sin alpha``
    stays within 0.030 - 0.033 and the radius error follows the two terms
    (tools/calibrate_flyby_model_error.py).

    Phases below :data:`PHASE_FLOOR` are held at it.
    """
    if options.silhouette_scaling == "constant":
        return np.ones(3)
    if options.silhouette_scaling == "shape":
        p0 = options.silhouette_reference_phase
        m = shape_error_term(phase, options) / shape_error_term(p0, options)
        c = m * radius_px / options.silhouette_reference_radius_px
        kappa = options.silhouette_crescent_gain
        g = (math.hypot(1.0, kappa * crescent_term(phase))
             / math.hypot(1.0, kappa * crescent_term(p0))) if kappa > 0 else 1.0
        return np.array([c, c * g, m])
    a = max(float(phase), PHASE_FLOOR)
    a0 = max(float(options.silhouette_reference_phase), PHASE_FLOOR)
    rho, rho0 = float(radius_px), options.silhouette_reference_radius_px
    c = (rho / rho0) * (math.sin(a) / math.sin(a0))
    r = radius_model_term(rho, a, options) / radius_model_term(rho0, a0, options)
    return np.array([c, c, r])


def shape_error_term(phase: float, options: SIView) -> float:
    """The phase law of a shape model's silhouette error, ``hypot(q, sin(alpha / 2))`` [-]
    (``q = options.silhouette_shape_error_floor``), for ``silhouette_scaling = "shape"``.

    An empirical form. A model whose surface departs from the truth by heights ``dh`` moves
    the lit outline by about ``dh`` where the outline is the limb (at every phase: ``q``, what
    is left at phase 0) and by more where it is the terminator, where a height error also
    moves the shading boundary; the terminator's share of the lit outline grows with the
    phase (its half-ellipse departs from the limb by ``rho (1 - cos alpha) = 2 rho
    sin^2(alpha / 2)``). The centroid's error [px] is the law times the apparent radius
    ``rho`` (the same shape error, magnified), the radius's fraction the law alone. Its
    constants are fitted on the calibration fly-bys (tools/calibrate_flyby_coarse_map.py).
    """
    return math.hypot(options.silhouette_shape_error_floor, math.sin(0.5 * float(phase)))


def crescent_term(phase: float) -> float:
    """The crescent's lever on the lit centroid, ``(1 - f) / f = tan^2(alpha / 2)`` [-], with
    ``f = (1 + cos alpha) / 2`` the lit fraction of a sphere's disc at phase ``alpha`` [rad]
    (``silhouette_scaling = "shape"``: the across-Sun centroid's factor ``hypot(1, kappa
    (1 - f) / f)``, ``kappa = options.silhouette_crescent_gain``).

    On a disc of apparent radius ``rho`` centred at the body's centre the lit part (area
    ``f pi rho^2``) and the dark part the terminator cuts away (``(1 - f) pi rho^2``) have
    first moments that cancel: the lit centroid lies at ``(1 - f) / f`` times the dark
    part's centroid, on the other side (on a sphere ``4 rho (1 - cos alpha) / (3 pi)`` towards
    the Sun against ``4 rho (1 + cos alpha) / (3 pi)`` away from it). A model error that
    moves the dark part's centroid (where the terminator and the horns fall on the model's
    surface) moves the lit centroid by that lever times it: 1 at phase 90 deg, 3 at 120 deg,
    7.5 at 140 deg. Along the Sun the shape law's ``sin(alpha / 2)`` already follows the
    terminator; across it, the crescent's horns carry the error. ``inf`` at phase 180 deg.
    """
    c = math.cos(float(phase))
    return math.inf if c <= -1.0 else (1.0 - c) / (1.0 + c)


def map_error_factor(prior: ShapePrior, options: SIView) -> float:
    """The factor on the silhouette's model-error sigmas for the model navigated on (module
    step 4a): the model's rms height error over its mean radius (``prior.height_fraction``)
    over that of the model they were calibrated on
    (``options.silhouette_reference_height_fraction``); 1 when either is 0.

    A shape model whose surface departs from the truth by heights ``dh`` moves the lit
    outline by about ``dh`` (:func:`shape_error_term`), which is ``rho dh / R`` px at an
    apparent radius ``rho`` of a body of radius ``R``: the silhouette's error over the
    apparent radius is proportional to the model's relative height error, so sigmas fitted
    on one body's model carry over to another's through this ratio, not unchanged."""
    ref = float(options.silhouette_reference_height_fraction)
    if ref <= 0 or prior.height_fraction <= 0:
        return 1.0
    return float(prior.height_fraction) / ref


def aspect_change(u0: ArrayLike, s0: ArrayLike, u1: ArrayLike, s1: ArrayLike) -> float:
    """The aspect change [rad] between two views (module step 1a): ``hypot`` of the angle
    between the body-fixed view directions ``u0, u1`` (body centre -> spacecraft, unit) and of
    the angle between the body-fixed Sun directions ``s0, s1`` (unit; the body's spin turns
    its illumination). A silhouette computed from a shape model differs from the truth's by a
    function of these two directions only (and of the apparent size, which scales it), so its
    error decorrelates with the aspect, not with time."""
    a = math.acos(min(max(float(np.dot(u0, u1)), -1.0), 1.0))
    b = math.acos(min(max(float(np.dot(s0, s1)), -1.0), 1.0))
    return math.hypot(a, b)


def radius_model_term(radius_px: float, phase: float, options: SIView) -> float:
    """``hypot(w / (rho (1 + cos alpha)), tan(alpha / 2) delta / 2)`` of
    :func:`silhouette_scale` [-] (``alpha`` already floored)."""
    w, d = options.silhouette_limb_blur_px, options.silhouette_terminator_shift
    return math.hypot(w / (radius_px * (1.0 + math.cos(phase))),
                      0.5 * d * math.tan(phase / 2.0))


@dataclass(frozen=True)
class SilhouetteOffset:
    """The deterministic part of the lit silhouette's model error at one position (module
    step 4c, :func:`silhouette_offset`).

    Attributes
    ----------
    centroid_px : float
        Lit centroid's offset along the Sun's image direction [px].
    centroid_grad : (3,) array
        Its gradient with respect to ``r`` [px/m].
    radius_px : float
        Apparent radius's offset [px].
    radius_grad : (3,) array
        Its gradient with respect to ``r`` [px/m].
    """

    centroid_px: float
    centroid_grad: FloatArray
    radius_px: float
    radius_grad: FloatArray


def silhouette_offset(r: ArrayLike, sun: ArrayLike | None, k: float,
                      options: SIView) -> SilhouetteOffset:
    """Predicted offset of the rendered lit silhouette from the lit-facet model seen from ``r``
    (body-centred J2000 [m]) under the Sun direction ``sun`` (body -> Sun unit vector; None:
    phase 0), with the lit facets' radius constant ``k = rho |r|`` [px m] (module step 4c).

    The two mechanisms of :func:`silhouette_scale`, now as offsets, not sigmas: at apparent
    radius ``rho = k / |r|`` and phase ``alpha`` (``cos alpha = r.sun / |r|``),

    * centroid: ``c rho sin(alpha)`` along the Sun's image direction (``c =
      options.silhouette_centroid_offset_fraction``; a terminator shift
      ``delta_c = 3 pi c / 4``);
    * radius: ``w / (1 + cos alpha) - rho tan(alpha / 2) delta / 2`` [px] (limb blur ``w =
      options.silhouette_limb_blur_px``, terminator shift
      ``delta = options.silhouette_terminator_shift``).

    Gradients are analytic (``k`` held, as in :func:`radius_model`); at phase 0 (and without a
    Sun) the phase's gradient is taken as zero (``sin alpha`` has a kink there).
    """
    r = np.asarray(r, float)
    rn = float(np.linalg.norm(r))
    u = r / rn
    rho = k / rn
    drho = -rho * u / rn
    if sun is None:
        c, dc = 1.0, np.zeros(3)
    else:
        s = np.asarray(sun, float)
        c = min(max(float(u @ s), -1.0), 1.0)
        dc = (s - c * u) / rn
    sa = math.sqrt(max(1.0 - c * c, 0.0))
    if sa > 1e-9:
        dsa = -c / sa * dc
        t, dt = sa / (1.0 + c), -dc / ((1.0 + c) * sa)
    else:
        dsa, t, dt = np.zeros(3), 0.0, np.zeros(3)
    kc = options.silhouette_centroid_offset_fraction
    w, d = options.silhouette_limb_blur_px, options.silhouette_terminator_shift
    return SilhouetteOffset(
        centroid_px=kc * rho * sa, centroid_grad=kc * (sa * drho + rho * dsa),
        radius_px=w / (1.0 + c) - 0.5 * d * rho * t,
        radius_grad=-w / (1.0 + c) ** 2 * dc - 0.5 * d * (t * drho + rho * dt))


class ShapeBodyLike(Protocol):
    """What the filter reads of a body (:class:`~starnav.bodies.small_body.ShapeModelBody`)."""

    shape: Any          # .vertices (V, 3) [m], .faces (F, 3)
    gm: float

    def orientation(self, epochs_tdb: ArrayLike, ephemeris: Any = None) -> FloatArray: ...


class TrnFilterConfig(StrictModel):
    """Scenario section ``navigation.trn.filter``: the fly-by estimator, an EKF with body-fixed
    landmark states (:func:`run_filter` reads its SI view, ``to_si()``)."""

    accel_psd_m2_s3: NonNegativeFloat = Field(
        1e-8, description="white-acceleration PSD of the relative motion [m^2/s^3]")
    gravity: bool = Field(True, description="the body's point-mass gravity in the prediction")
    gate_probability: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.9999, description="chi-square gate of each feature, centroid and radius [-]")
    max_landmarks: Annotated[int, Field(ge=0)] = Field(
        40, description="most landmark (feature) states at once")
    max_incidence_deg: Annotated[float, Field(gt=0, lt=90)] = Field(
        75.0, description="steepest angle between a new landmark's ray and the surface normal "
        "[deg]")
    landmark_height_sigma_m: NonNegativeFloat = Field(
        1.0, description="shape-model height error at a new landmark, 1-sigma [m]")
    centroid_model_sigma_px: NonNegativeFloat = Field(
        1.27, description="lit-centroid model error added in quadrature [px] (calibrated on "
        "rendered frames: tools/calibrate_flyby_model_error.py)")
    radius_model_fraction: NonNegativeFloat = Field(
        0.025, description="apparent-radius model error as a fraction of the radius [-] "
        "(calibrated)")
    silhouette_bias_time_s: NonNegativeFloat = Field(
        19.0, description="correlation time of the silhouette's model errors, first-order "
        "Gauss-Markov bias states [s] (calibrated; 0 with silhouette_bias_angle_deg 0: white, "
        "added to each frame's noise)")
    silhouette_bias_angle_deg: Annotated[float, Field(ge=0, le=180)] = Field(
        0.0, description="correlation angle of the silhouette's model errors in the aspect "
        "(the rotation of the view and of the Sun relative to the body, filter step 1a) "
        "[deg]; > 0 replaces silhouette_bias_time_s (a shape model's error follows the "
        "aspect, not the time)")
    centroid_sun_share: Annotated[float, Field(ge=0, le=1)] = Field(
        0.962, description="share of the centroid model error's variance along the Sun's "
        "image direction [-] (calibrated; 0.5: isotropic)")
    silhouette_scaling: Literal["geometry", "shape", "constant"] = Field(
        "geometry", description="how the silhouette model-error sigmas follow the geometry: "
        "geometry (centroid ~ apparent radius x sin(phase); radius fraction: limb blur and "
        "terminator shift, filter.silhouette_scale; relative to the reference below; chosen "
        "by the calibration, tools/calibrate_flyby_model_error.py), shape (a shape model's "
        "own error: centroid ~ apparent radius x hypot(q, sin(phase / 2)), radius fraction ~ "
        "hypot(q, sin(phase / 2)); filter.shape_error_term) or constant")
    silhouette_shape_error_floor: PositiveFloat = Field(
        0.2, description="q of the shape law: the limb's share of a shape model's silhouette "
        "error, left at phase 0 [-] (silhouette_scaling: shape; calibrated)")
    silhouette_crescent_gain: NonNegativeFloat = Field(
        0.0, description="kappa of the shape law's crescent term: the across-Sun centroid "
        "sigma is multiplied by hypot(1, kappa (1 - f) / f), f = (1 + cos phase) / 2 the lit "
        "fraction, relative to its value at the reference phase (silhouette_scaling: shape; "
        "filter.crescent_term; calibrated: tools/calibrate_flyby_coarse_map.py); 0: off")
    silhouette_reference_radius_px: PositiveFloat = Field(
        48.95, description="apparent radius at which the model-error sigmas were calibrated "
        "[px] (the calibration fly-by's CA)")
    silhouette_reference_phase_deg: Annotated[float, Field(ge=0, lt=180)] = Field(
        50.0, description="Sun phase at which the model-error sigmas were calibrated [deg]")
    silhouette_reference_height_fraction: Annotated[float, Field(ge=0, lt=0.5)] = Field(
        0.0, description="rms height error over the mean radius of the shape model on which "
        "the silhouette model-error sigmas were calibrated [-]; > 0: they scale with the "
        "navigated model's own (ShapePrior.height_fraction) over this (filter."
        "map_error_factor); 0: not scaled")
    silhouette_limb_blur_px: NonNegativeFloat = Field(
        1.85, description="outward spread of the lit limb above the segments threshold [px] "
        "(the radius model error's limb term; calibrated)")
    silhouette_terminator_shift_deg: NonNegativeFloat = Field(
        4.12, description="shift of the effective terminator against the lit-facet model "
        "[deg] (the radius model error's terminator term; calibrated)")
    feature_correlation: Annotated[float, Field(ge=0, lt=1)] = Field(
        0.25, description="correlation of the tracked features' errors within a frame [-]: N "
        "features count as N / (1 + (N - 1) c) independent ones (calibrated)")
    silhouette_offset: bool = Field(
        False, description="put the deterministic part of the silhouette's model error (the "
        "centroid offset law below, the radius's limb-blur and terminator terms) into the "
        "predicted measurement; the bias states then carry the residual (filter step 4c; off: "
        "measured worse at phase 70 deg, docs/navigation.md)")
    silhouette_centroid_offset_fraction: Annotated[float, Field(gt=-0.5, lt=0.5)] = Field(
        0.0374, description="lit-centroid offset along the Sun's image direction over apparent "
        "radius x sin(phase) [-] (calibrated; used with silhouette_offset)")
    silhouette_bias_mean: tuple[float, float, Annotated[float, Field(gt=-0.5, lt=0.5)]] = Field(
        (0.0, 0.0, 0.0), description="mean of the silhouette's model errors at the reference "
        "geometry: centroid along and across the Sun's image direction [px], radius fraction "
        "[-]; scaled with the geometry like the sigmas, which are then the scatter about it "
        "(filter step 4d; calibrated)")
    reset_after: Annotated[int, Field(ge=0)] = Field(
        3, description="frames in a row with the silhouette's centroid or radius rejected by "
        "the gate after which the filter re-opens its relative state (filter step 5a; 0: "
        "never)")
    birth_position_sigma_m: NonNegativeFloat = Field(
        0.0, description="no landmark is born while the position's largest 1-sigma exceeds "
        "this [m] (filter step 7a: a landmark cast from a loose position is a poor "
        "linearisation, which makes the shape-scale state inconsistent); 0: always")
    use_centroid: bool = Field(True, description="use the lit silhouette's centroid")
    use_radius: bool = Field(True, description="use the lit silhouette's apparent radius")
    initial_position_sigma_km: PositiveFloat = Field(
        1.0, description="initial 1-sigma of the relative position, per axis [km]")
    initial_velocity_sigma_m_s: PositiveFloat = Field(
        5.0, description="initial 1-sigma of the relative velocity, per axis [m/s]")

    def initial_covariance(self) -> NDArray[np.float64]:
        """The diagonal initial covariance (6, 6) [m^2, m^2/s^2]."""
        si = self.to_si()
        return np.diag([si.initial_position_sigma**2] * 3 + [si.initial_velocity_sigma**2] * 3)

    @model_validator(mode="after")
    def _radius_terms(self) -> TrnFilterConfig:
        si = self.to_si()
        if not (si.silhouette_limb_blur_px > 0 or si.silhouette_terminator_shift > 0):
            raise ValueError("silhouette_limb_blur_px or silhouette_terminator_shift_deg must "
                             "be > 0 (the radius model error's two terms)")
        return self


#: The section's defaults, SI.
_DEFAULT = TrnFilterConfig().to_si()


@dataclass(frozen=True)
class ShapePrior:
    """What the filter knows of the body model it navigates on, beyond its section (resolved
    by :func:`~starnav.navigation.trn.body_model.estimator_model`; the default: the model is
    the body, exactly).

    Attributes
    ----------
    scale_sigma : float
        1-sigma of the shape model's scale error [-] (step 4e): a random-constant state
        ``s`` (the body is the model times ``1 + s``) in the silhouette's size and centroid
        and in every landmark born on the model; 0: the model's scale is taken as exact.
    scale_consider : bool
        Keep the scale state out of the update (a Schmidt consider state: its uncertainty
        and correlations are carried, its value stays at the model's); False: estimated.
    height_sigma : float
        The model's height error at a landmark, 1-sigma [m]; a new landmark's height sigma is
        the larger of this and the section's ``landmark_height_sigma``.
    birth_sigma : float
        The birth threshold of step 7a the model sets [m], used when the section's
        ``birth_position_sigma`` is 0 (0: always).
    height_fraction : float
        The model's rms height error over its mean radius [-] (its stated accuracy; 0: not
        stated). The silhouette's model-error sigmas scale by its ratio to the section's
        ``silhouette_reference_height_fraction`` (step 4a, :func:`map_error_factor`).
    """

    scale_sigma: float = 0.0
    scale_consider: bool = True
    height_sigma: float = 0.0
    birth_sigma: float = 0.0
    height_fraction: float = 0.0

    def __post_init__(self) -> None:
        for name, ok, want in (("scale_sigma", 0 <= self.scale_sigma < 0.5, "in [0, 0.5) [-]"),
                               ("height_sigma", self.height_sigma >= 0, ">= 0 [m]"),
                               ("birth_sigma", self.birth_sigma >= 0, ">= 0 [m]"),
                               ("height_fraction", 0 <= self.height_fraction < 0.5,
                                "in [0, 0.5) [-]")):
            if not ok:
                raise ConfigError(f"shape_prior.{name}", getattr(self, name), want)


@dataclass
class FlybyRun:
    """One run of the fly-by filter, one entry per frame.

    Attributes
    ----------
    epochs : (K,) array
        [TDB s].
    states : (K, 6) array
        Estimated ``(r, v)`` relative to the body centre, J2000 [m, m/s], after the update.
    covariances : (K, 6, 6) array
    nis : (K,) array
        NIS of the frame's stacked accepted innovation (NaN: nothing used).
    nis_dof : (K,) int array
        Its degrees of freedom.
    features_used, features_rejected, landmarks, landmarks_born : (K,) int arrays
        Feature updates accepted / rejected by the gate, landmark states after the frame,
        landmarks initialised in the frame.
    centroid_used, radius_used : (K,) bool arrays
    info : dict
        Diagnostics: ``bias``/``bias_sigma`` (K, 3), ``shape_scale``/``shape_scale_sigma``
        (K,) (step 4e), ``landmark_first``/``landmark_last`` (track id -> body-fixed
        estimate (3,) [m] and covariance (3, 3) after its first / latest frame), ``resets``,
        ``nis_by_kind``.
    """

    epochs: FloatArray
    states: FloatArray
    covariances: FloatArray
    nis: FloatArray
    nis_dof: NDArray[np.int64]
    features_used: NDArray[np.int64]
    features_rejected: NDArray[np.int64]
    landmarks: NDArray[np.int64]
    landmarks_born: NDArray[np.int64]
    centroid_used: NDArray[np.bool_]
    radius_used: NDArray[np.bool_]
    info: dict[str, Any] = field(default_factory=dict)

    def errors(self, truth: ArrayLike) -> FloatArray:
        """Estimate minus truth ``(K, 6)`` [m, m/s] for the true states ``(K, 6)``."""
        return self.states - _truth(truth, len(self.epochs))

    def sigma3(self) -> FloatArray:
        """3-sigma bounds per state ``(K, 6)``."""
        return 3.0 * np.sqrt(np.einsum("kii->ki", self.covariances))

    def nees(self, truth: ArrayLike) -> FloatArray:
        """NEES of the 6 states per frame ``(K,)``."""
        e = self.errors(truth)
        return np.einsum("ki,ki->k", e, np.linalg.solve(self.covariances, e[..., None])[..., 0])


def _truth(truth: ArrayLike, k: int) -> FloatArray:
    t = np.asarray(truth, float)
    if t.shape != (k, 6):
        raise ConfigError("truth", t.shape, f"({k}, 6) true states [m, m/s]")
    return t


def skew(a: ArrayLike) -> FloatArray:
    """Cross-product matrix ``[a]x`` (``[a]x b = a x b``)."""
    x, y, z = np.asarray(a, float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


# ----------------------------------------------------------------------------- validation
def validate_inputs(measurements: Sequence[FlybyMeasurement], initial_state: ArrayLike,
                    initial_covariance: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Check everything :func:`run_filter` reads, before any work; return ``(x0, P0)``."""
    if len(measurements) == 0:
        raise ConfigError("measurements", [], "at least one FlybyMeasurement")
    x0 = np.asarray(initial_state, float)
    if x0.shape != (6,) or not np.all(np.isfinite(x0)):
        raise ConfigError("initial_state", x0.shape if x0.shape != (6,) else x0.tolist(),
                          "6 finite values (position [m], velocity [m/s]) relative to the body")
    P0 = np.asarray(initial_covariance, float)
    if P0.shape != (6, 6):
        raise ConfigError("initial_covariance", P0.shape, "a (6, 6) covariance [m^2, m^2/s^2]")
    if not np.allclose(P0, P0.T, rtol=1e-9, atol=0.0) or np.any(np.linalg.eigvalsh(
            0.5 * (P0 + P0.T)) <= 0):
        raise ConfigError("initial_covariance", "not symmetric positive definite",
                          "a symmetric positive-definite (6, 6) covariance")
    prev = -math.inf
    for k, m in enumerate(measurements):
        where = f"measurements[{k}]"
        if not isinstance(m, FlybyMeasurement):
            raise ConfigError(where, type(m).__name__, "a FlybyMeasurement")
        if not math.isfinite(m.epoch_tdb) or m.epoch_tdb <= prev:
            raise ConfigError(f"{where}.epoch_tdb", m.epoch_tdb,
                              f"finite and later than the previous frame's ({prev})")
        prev = m.epoch_tdb
        R = np.asarray(m.R_cam_to_inertial, float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=ROTATION_TOLERANCE):
            raise ConfigError(f"{where}.R_cam_to_inertial", R.shape if R.shape != (3, 3)
                              else "not orthonormal", "a (3, 3) rotation matrix")
        s = np.asarray(m.attitude_sigma, float)
        if s.shape != (3,) or np.any(~np.isfinite(s)) or np.any(s < 0):
            raise ConfigError(f"{where}.attitude_sigma", s.tolist(),
                              "3 non-negative values [rad] (camera x, y, z)")
        for j, f in enumerate(m.features):
            uv = np.asarray(f.uv, float)
            if uv.shape != (2,) or not np.all(np.isfinite(uv)):
                raise ConfigError(f"{where}.features[{j}].uv", uv.tolist(), "(u, v) [px]")
            if not (f.sigma_px > 0 and math.isfinite(f.sigma_px)):
                raise ConfigError(f"{where}.features[{j}].sigma_px", f.sigma_px, "> 0 [px]")
        if m.centroid_uv is not None:
            c = np.asarray(m.centroid_uv, float)
            if c.shape != (2,) or not np.all(np.isfinite(c)):
                raise ConfigError(f"{where}.centroid_uv", c.tolist(), "(u, v) [px] or None")
            if not m.centroid_sigma_px > 0:
                raise ConfigError(f"{where}.centroid_sigma_px", m.centroid_sigma_px, "> 0 [px]")
        if m.apparent_radius_px is not None:
            if not (math.isfinite(m.apparent_radius_px) and m.apparent_radius_px > 0):
                raise ConfigError(f"{where}.apparent_radius_px", m.apparent_radius_px,
                                  "> 0 [px] or None")
            if not m.apparent_radius_sigma_px > 0:
                raise ConfigError(f"{where}.apparent_radius_sigma_px",
                                  m.apparent_radius_sigma_px, "> 0 [px]")
    return x0, P0


# ----------------------------------------------------------------------------- models
def propagate(x: FloatArray, dt: float, gm: float, q: float) -> tuple[FloatArray, FloatArray,
                                                                      FloatArray]:
    """``(r, v)`` after ``dt`` [s] under constant velocity plus point-mass gravity ``gm``:
    the new state, its transition matrix (6, 6) and process noise (6, 6) (module step 1)."""
    n = max(1, int(math.ceil(abs(dt) / MAX_STEP)))
    h = dt / n
    Phi = np.eye(6)
    Q = np.zeros((6, 6))
    x = np.array(x[:6], float)
    I3 = np.eye(3)
    Qs = q * np.block([[h**3 / 3 * I3, h**2 / 2 * I3], [h**2 / 2 * I3, h * I3]])
    for _ in range(n):
        r, v = x[:3], x[3:]
        rn = float(np.linalg.norm(r))
        if gm > 0 and rn > 0:
            a = -gm * r / rn**3
            G = -gm / rn**3 * (I3 - 3.0 * np.outer(r, r) / rn**2)
        else:
            a, G = np.zeros(3), np.zeros((3, 3))
        x = np.r_[r + v * h + 0.5 * a * h * h, v + a * h]
        F = np.block([[I3 + 0.5 * G * h * h, h * I3], [G * h, I3]])
        Phi = F @ Phi
        Q = F @ Q @ F.T + Qs
    return x, Phi, Q


def rotation_vector_matrix(w: ArrayLike) -> FloatArray:
    """Rotation matrix ``exp([w]x)`` of a rotation vector [rad] (Rodrigues)."""
    w = np.asarray(w, float)
    a = float(np.linalg.norm(w))
    W = skew(w)
    if a < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + math.sin(a) / a * W + (1.0 - math.cos(a)) / a**2 * (W @ W)


def features_model(camera: Camera, r: FloatArray, landmarks: FloatArray, R_m: FloatArray,
                   R_bi: FloatArray, dtheta: FloatArray
                   ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Predicted pixels of body-fixed landmarks ``(N, 3)`` (module step 4): pixels (N, 2),
    Jacobians (N, 2, 3) with respect to ``r``, the landmark and the attitude error ``dtheta``,
    and whether each landmark is in front of the camera (a landmark behind gets a dummy
    prediction)."""
    E = rotation_vector_matrix(-np.asarray(dtheta, float))
    C = E @ R_m.T
    p = (landmarks @ R_bi.T - r) @ C.T
    front = p[:, 2] > 0
    p = np.where(front[:, None], p, np.array([0.0, 0.0, 1.0]))
    J = camera.project_jacobian(p)
    sk = np.zeros((p.shape[0], 3, 3))
    sk[:, 0, 1], sk[:, 0, 2], sk[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
    sk[:, 1, 0], sk[:, 2, 0], sk[:, 2, 1] = p[:, 2], -p[:, 1], p[:, 0]
    return camera.project(p), -J @ C, J @ (C @ R_bi), J @ sk, front


def centroid_model(camera: Camera, r: FloatArray, offset: FloatArray, R_m: FloatArray,
                   dtheta: FloatArray | None = None
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted lit centroid ``project(exp(-[dtheta]x) R_m^T (offset - r))`` [px] and its
    Jacobians with respect to ``r`` and ``dtheta`` (module step 4; ``offset`` the frozen point
    D, J2000, body-centred [m])."""
    dth = np.zeros(3) if dtheta is None else np.asarray(dtheta, float)
    E = rotation_vector_matrix(-dth)
    p = E @ R_m.T @ (offset - r)
    J = camera.project_jacobian(p)
    return camera.project(p), -J @ E @ R_m.T, J @ skew(p)


def radius_model(r: FloatArray, k: float) -> tuple[float, FloatArray]:
    """Apparent radius ``k / |r|`` [px] and its gradient with respect to ``r`` (1, 3)."""
    rn = float(np.linalg.norm(r))
    return k / rn, (-k * r / rn**3)[None, :]


@dataclass(frozen=True)
class LandmarkBirth:
    """A new landmark from a pixel ray (module step 7).

    Attributes
    ----------
    point_body : (3,) array
        Body-fixed surface point [m].
    J_r, J_theta : (3, 3) arrays
        Its Jacobians with respect to ``r`` (J2000) and the attitude error (camera axes).
    J_uv : (3, 2) array
        With respect to the pixel.
    J_h : (3,) array
        Per metre of shape-model height error along the facet normal.
    normal_body : (3,) array
        The facet's unit normal, body-fixed.
    cos_incidence : float
        Cosine of the angle between the ray and the facet normal.
    """

    point_body: FloatArray
    J_r: FloatArray
    J_theta: FloatArray
    J_uv: FloatArray
    J_h: FloatArray
    normal_body: FloatArray
    cos_incidence: float


def landmark_births(camera: Camera, r: FloatArray, R_true: FloatArray, R_bi: FloatArray,
                    uv: ArrayLike, body: BodyInCamera | None = None, shape: Any = None
                    ) -> list[LandmarkBirth | None]:
    """Body-fixed points of pixel rays cast from ``r`` under the attitude ``R_true`` (camera
    -> J2000) onto the shape (module step 7), ``None`` where a ray misses. ``body``: the shape
    already placed in this camera frame (else ``shape``'s vertices and faces are placed)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    if body is None:
        body = BodyInCamera.place(shape.vertices, shape.faces, R_true.T @ R_bi,
                                  R_true.T @ (-r))
    d_c = camera.unproject(uv)
    t, face = raycast(body, d_c)
    Ju = camera.unproject_jacobian(uv)
    out: list[LandmarkBirth | None] = []
    for i in range(uv.shape[0]):
        if face[i] < 0:
            out.append(None)
            continue
        d_i = R_true @ d_c[i]
        n_i = R_true @ body.normals[face[i]]
        nd = float(n_i @ d_i)
        A = np.eye(3) - np.outer(d_i, n_i) / nd
        tA = R_bi.T @ (float(t[i]) * A)
        out.append(LandmarkBirth(
            point_body=R_bi.T @ (r + float(t[i]) * d_i), J_r=R_bi.T @ A,
            J_theta=tA @ (-R_true @ skew(d_c[i])), J_uv=tA @ R_true @ Ju[i],
            J_h=R_bi.T @ d_i / nd, normal_body=R_bi.T @ n_i, cos_incidence=-nd))
    return out


# ----------------------------------------------------------------------------- the filter
def run_filter(measurements: Sequence[FlybyMeasurement], camera: Camera, body: ShapeBodyLike,
               initial_state: ArrayLike, initial_covariance: ArrayLike,
               options: SIView | None = None, *,
               sun_direction: ArrayLike | None = None,
               prior: ShapePrior | None = None) -> FlybyRun:
    """Estimate ``(r, v)`` relative to the body over a fly-by (module essay).

    Parameters
    ----------
    measurements : sequence of FlybyMeasurement
        One per frame, epochs strictly increasing.
    camera : Camera
    body : ShapeModelBody
        Shape (body-fixed metres), spin (``orientation``: body -> J2000) and ``gm``.
    initial_state : (6,) array
        ``(r, v)`` at the first epoch, body-centred J2000 [m, m/s].
    initial_covariance : (6, 6) array
    options : SIView, optional
        The SI view of a :class:`TrnFilterConfig` (``to_si()``); default its defaults.
    sun_direction : (3,) array, optional
        Body -> Sun unit vector (J2000) over the fly-by; a measurement's own
        ``sun_direction`` takes precedence for its frame. Without either the centroid and
        radius are predicted from the whole silhouette (phase 0), and the phase bias must be
        covered by ``centroid_model_sigma_px`` / ``radius_model_fraction``.
    prior : ShapePrior, optional
        What the body model adds (scale state, height error, birth threshold); default none.
    """
    opt = options if options is not None else _DEFAULT
    pri = prior if prior is not None else ShapePrior()
    height_sigma = max(opt.landmark_height_sigma, pri.height_sigma)
    birth_sigma = opt.birth_position_sigma or pri.birth_sigma
    x0, P0 = validate_inputs(measurements, initial_state, initial_covariance)
    sun = None if sun_direction is None else _unit_sun(sun_direction, "sun_direction")
    frame_sun = [None if m.sun_direction is None else
                 _unit_sun(m.sun_direction, f"measurements[{k}].sun_direction")
                 for k, m in enumerate(measurements)]
    shape = body.shape
    gm = float(body.gm) if opt.gravity else 0.0
    gate = {d: float(chi2.ppf(opt.gate_probability, d)) for d in (1, 2)}
    cos_max = math.cos(opt.max_incidence)

    K = len(measurements)
    out = FlybyRun(
        epochs=np.array([m.epoch_tdb for m in measurements]), states=np.zeros((K, 6)),
        covariances=np.zeros((K, 6, 6)), nis=np.full(K, np.nan),
        nis_dof=np.zeros(K, np.int64), features_used=np.zeros(K, np.int64),
        features_rejected=np.zeros(K, np.int64), landmarks=np.zeros(K, np.int64),
        landmarks_born=np.zeros(K, np.int64), centroid_used=np.zeros(K, bool),
        radius_used=np.zeros(K, bool))
    nis_kind = {kd: np.zeros(K) for kd in ("feature", "centroid", "radius")}
    dof_kind = {kd: np.zeros(K, np.int64) for kd in ("feature", "centroid", "radius")}
    out.info["nis_by_kind"], out.info["nis_dof_by_kind"] = nis_kind, dof_kind
    tau = opt.silhouette_bias_time
    angle = opt.silhouette_bias_angle
    bias_on = tau > 0 or angle > 0           # bias states (else white model error)
    share = np.array([opt.centroid_sun_share, 1.0 - opt.centroid_sun_share])
    f_map = map_error_factor(pri, opt)        # 4a the navigated model's own map error
    centroid_model_sigma = f_map * opt.centroid_model_sigma_px
    radius_model_fraction = f_map * opt.radius_model_fraction
    sig_b = (np.r_[centroid_model_sigma * np.sqrt(2.0 * share),
                   radius_model_fraction] if tau > 0 else np.zeros(3))
    mu = np.asarray(opt.silhouette_bias_mean, float)    # the bias's calibrated mean (step 4d)
    x = np.r_[x0, np.zeros(CORE - 6)]
    P = np.zeros((CORE, CORE))
    P[:6, :6], P[BIAS, BIAS] = P0, np.diag(sig_b**2)
    P[SCALE, SCALE] = pri.scale_sigma**2
    out.info["shape_scale"] = np.zeros(K)
    out.info["landmark_first"], out.info["landmark_last"] = {}, {}
    out.info["shape_scale_sigma"] = np.zeros(K)
    streak = 0                                # frames in a row whose silhouette was rejected
    out.info["resets"] = []
    out.info["bias"] = np.zeros((K, 3))
    out.info["bias_sigma"] = np.zeros((K, 3))
    out.info["silhouette_scale"] = np.ones((K, 3))
    scale = np.ones(3)                        # the bias sigmas' geometry factor (step 4a)
    ids: list[int] = []                       # track id of each landmark, in state order
    banned: set[int] = set()
    t_prev = measurements[0].epoch_tdb
    aspect_prev: tuple[FloatArray, FloatArray] | None = None   # (view, Sun), body-fixed
    axes_prev: FloatArray | None = None      # the centroid bias's image axes, last frame

    for k, m in enumerate(measurements):
        # 1 predict
        dt = m.epoch_tdb - t_prev
        t_prev = m.epoch_tdb
        if dt > 0:
            xs, Phi, Q = propagate(x[:6], dt, gm, opt.accel_psd)
            x[:6] = xs
            P[:6, :] = Phi @ P[:6, :]
            P[:, :6] = P[:, :6] @ Phi.T
            P[:6, :6] += Q
            if bias_on:
                if angle > 0:                 # 1a the aspect's change, not the time's
                    view = aspect_of(x[:3], body, m.epoch_tdb,
                                     frame_sun[k] if frame_sun[k] is not None else sun)
                    d_asp = aspect_change(*aspect_prev, *view) if aspect_prev else 0.0
                    aspect_prev = view
                    a = math.exp(-d_asp / angle)
                else:
                    a = math.exp(-dt / tau)
                x[BIAS] *= a
                P[BIAS, :] *= a
                P[:, BIAS] *= a
                P[BIAS, BIAS] += np.diag((sig_b * scale) ** 2 * (1.0 - a * a))
        if angle > 0 and aspect_prev is None:  # 1a the first frame's aspect
            aspect_prev = aspect_of(x[:3], body, m.epoch_tdb,
                                    frame_sun[k] if frame_sun[k] is not None else sun)
        # 2 drop the landmarks whose track ended
        seen = {f.track_id for f in m.features}
        keep = [j for j, tid in enumerate(ids) if tid in seen]
        if len(keep) != len(ids):
            idx = np.r_[np.arange(CORE), _slots(keep)]
            x, P = x[idx], P[np.ix_(idx, idx)]
            ids = [ids[j] for j in keep]
        # 3 the frame's attitude error
        n = x.size
        th = slice(n, n + 3)
        sig = np.asarray(m.attitude_sigma, float)
        x = np.r_[x, np.zeros(3)]
        P = np.block([[P, np.zeros((n, 3))], [np.zeros((3, n)), np.diag(sig**2)]])
        n += 3
        R_m = np.asarray(m.R_cam_to_inertial, float)
        R_bi = np.asarray(body.orientation(m.epoch_tdb), float)
        r = x[:3]
        # 4 measurements: (kind, z, R, track id, model parameter)
        rows: list[tuple[str, FloatArray, FloatArray, int, Any]] = []
        slot = {tid: j for j, tid in enumerate(ids)}
        tracked = [(f, slot[f.track_id]) for f in m.features if f.track_id in slot]
        # 4b the frame's features share part of their error (feature_correlation): N of
        # them carry the information of N / (1 + (N - 1) c) independent ones
        share = 1.0 + max(len(tracked) - 1, 0) * opt.feature_correlation
        for f, j in tracked:
            rows.append(("feature", np.asarray(f.uv, float), np.eye(2) * f.sigma_px**2 * share,
                         f.track_id, CORE + 3 * j))
        need_sil = ((opt.use_centroid and m.centroid_uv is not None)
                    or (opt.use_radius and m.apparent_radius_px is not None))
        s_k = frame_sun[k] if frame_sun[k] is not None else sun
        sil_cache: dict[bytes, tuple[FloatArray, FloatArray, float] | None] = {}

        def silhouette_at(ri: FloatArray, R_m: FloatArray = R_m, R_bi: FloatArray = R_bi,
                          s_k: FloatArray | None = s_k,
                          cache: dict[bytes, Any] = sil_cache
                          ) -> tuple[FloatArray, FloatArray, float] | None:
            """The lit silhouette's frozen point D, bias axes and radius constant K seen
            from ``ri`` (module step 4), None when nothing lit faces the camera."""
            key = ri.tobytes()
            if key not in cache:
                centre_cam = R_m.T @ (-ri)
                placed = BodyInCamera.place(shape.vertices, shape.faces, R_m.T @ R_bi,
                                            centre_cam)
                sun_cam = R_m.T @ s_k if s_k is not None else -centre_cam
                try:
                    sil = lit_silhouette(placed, sun_cam, camera)
                except GeometryError:
                    cache[key] = None
                    return None
                ray = camera.unproject(sil.centroid_uv)
                D = R_m @ (ray * (centre_cam[2] / ray[2])) + ri
                # the Sun's direction in the image at the body (the bias states' axes)
                e_s = camera.project_jacobian(centre_cam) @ sun_cam
                ne = float(np.linalg.norm(e_s))
                e_s = e_s / ne if ne > 1e-12 else np.array([1.0, 0.0])
                E_b = np.column_stack([e_s, [-e_s[1], e_s[0]]])
                cache[key] = (D, E_b, sil.radius_px * float(np.linalg.norm(ri)))
            return cache[key]

        sil0 = silhouette_at(r.copy()) if need_sil else None
        if sil0 is not None and bias_on and opt.silhouette_scaling == "shape":
            # 4a a shape model's centroid error is an offset in the image, set by the aspect;
            # the bias axes (the Sun's image direction) turn with the geometry, by up to 180
            # deg in a frame near phase 0: carry the offset over. (The terminator's error of
            # the other laws lies along the Sun's direction and turns with it.)
            if axes_prev is not None:
                T = sil0[1].T @ axes_prev
                x[6:8] = T @ x[6:8]
                P[6:8, :] = T @ P[6:8, :]
                P[:, 6:8] = P[:, 6:8] @ T.T
            axes_prev = sil0[1]
        # 4a the bias states follow the geometry: b <- (s_k / s_k-1) b (silhouette_scale)
        if sil0 is not None and bias_on:
            rn = float(np.linalg.norm(r))
            phase = (math.acos(min(max(float(r @ s_k) / rn, -1.0), 1.0)) if s_k is not None
                     else 0.0)
            s_new = silhouette_scale(sil0[2] / rn, phase, opt)
            f = s_new / scale
            x[BIAS] *= f
            P[BIAS, :] *= f[:, None]
            P[:, BIAS] *= f
            scale = s_new
        out.info["silhouette_scale"][k] = scale
        if sil0 is not None and opt.use_centroid and m.centroid_uv is not None:
            var = m.centroid_sigma_px**2 + (0.0 if bias_on else centroid_model_sigma**2)
            rows.append(("centroid", np.asarray(m.centroid_uv, float), np.eye(2) * var, -1,
                         sil0))
        if sil0 is not None and opt.use_radius and m.apparent_radius_px is not None:
            var = m.apparent_radius_sigma_px**2 + (0.0 if bias_on else (
                radius_model_fraction * sil0[2] / float(np.linalg.norm(r))) ** 2)
            rows.append(("radius", np.array([m.apparent_radius_px]), np.array([[var]]), -1,
                         sil0))

        def predict_all(rs: list[tuple[str, FloatArray, FloatArray, int, Any]],
                        xi: FloatArray, n: int = n, th: slice = th, R_m: FloatArray = R_m,
                        R_bi: FloatArray = R_bi, s_k: FloatArray | None = s_k,
                        mu_k: FloatArray = mu * scale
                        ) -> tuple[list[FloatArray], list[FloatArray], list[bool]]:
            """Predicted measurement and Jacobian of every row at ``xi`` (features batched);
            ``False`` where a landmark is behind the camera."""
            hs: list[FloatArray] = []
            Hs: list[FloatArray] = []
            ok: list[bool] = []
            feat = [i for i, rw in enumerate(rs) if rw[0] == "feature"]
            if feat:
                slots = np.array([rs[i][4] for i in feat])
                Lm = xi[slots[:, None] + np.arange(3)]
                hf, Hr, Hl, Ht, front = features_model(camera, xi[:3], Lm, R_m, R_bi, xi[th])
            fi = 0
            sil_i = None
            if any(rw[0] != "feature" for rw in rs):
                sil_i = silhouette_at(xi[:3].copy())
            for rw in rs:
                kind, par = rw[0], rw[4]
                if kind != "feature" and sil_i is not None:
                    par = sil_i
                H = np.zeros((rw[1].size, n))
                good = True
                if kind == "feature":
                    h = hf[fi]
                    H[:, :3], H[:, par:par + 3], H[:, th] = Hr[fi], Hl[fi], Ht[fi]
                    good = bool(front[fi])
                    fi += 1
                elif kind == "centroid":
                    # 4e the frozen point of the model scaled by 1 + s about the centre
                    h, Hc, Htc = centroid_model(camera, xi[:3], par[0] * (1.0 + xi[SCALE]),
                                                R_m, xi[th])
                    H[:, SCALE] = -Hc @ par[0]
                    h = h + par[1] @ (mu_k[:2] + xi[6:8])
                    if opt.silhouette_offset:   # 4c the deterministic offset
                        off = silhouette_offset(xi[:3], s_k, par[2], opt)
                        h = h + off.centroid_px * par[1][:, 0]
                        Hc = Hc + np.outer(par[1][:, 0], off.centroid_grad)
                    H[:, :3], H[:, th], H[:, 6:8] = Hc, Htc, par[1]
                else:
                    rho, Hrr = radius_model(xi[:3], par[2] * (1.0 + xi[SCALE]))
                    H[0, SCALE] = par[2] / float(np.linalg.norm(xi[:3]))
                    if opt.silhouette_offset:
                        off = silhouette_offset(xi[:3], s_k, par[2], opt)
                        rho, Hrr = rho + off.radius_px, Hrr + off.radius_grad[None, :]
                    g = 1.0 + mu_k[2] + xi[8]
                    h = np.array([rho * g])
                    H[:, :3], H[0, 8] = Hrr * g, rho
                    H[0, SCALE] *= g
                hs.append(h)
                Hs.append(H)
                ok.append(good)
            return hs, Hs, ok

        # 5 gate
        gated = gate_rows(rows, predict_all(rows, x), P, gate)
        sil = [g for g in gated if g[0][0] != "feature"]
        if sil:
            streak = streak + 1 if not all(g[2] for g in sil) else 0
        if opt.reset_after and streak >= opt.reset_after:
            # 5a divergence: the silhouette rejected reset_after frames in a row; re-open
            # the relative state, restart the bias states, drop the landmarks (they were
            # placed from the diverged position) and gate again
            idx = np.r_[np.arange(CORE), np.arange(n - 3, n)]
            x, P = x[idx], P[np.ix_(idx, idx)]
            ids, n, th = [], CORE + 3, slice(CORE, CORE + 3)
            P[:6, :6] += P0
            x[BIAS] = 0.0
            P[BIAS, :] = 0.0
            P[:, BIAS] = 0.0
            P[BIAS, BIAS] = np.diag((sig_b * scale) ** 2)
            rows = [rw for rw in rows if rw[0] != "feature"]
            gated = gate_rows(rows, predict_all(rows, x, n, th), P, gate)
            streak = 0
            out.info["resets"].append(k)
        accepted = []
        for row, d2, ok, dof in gated:
            kind, tid = row[0], row[3]
            nis_kind[kind][k] += d2
            dof_kind[kind][k] += dof
            if ok:
                accepted.append(row)
                out.centroid_used[k] |= kind == "centroid"
                out.radius_used[k] |= kind == "radius"
                out.features_used[k] += kind == "feature"
            elif kind == "feature":
                out.features_rejected[k] += 1
                banned.add(tid)
        # 6 update: iterated EKF (Gauss-Newton on the measurements; Bell & Cathey 1993)
        if accepted:
            z = np.concatenate([a[1] for a in accepted])
            Rn = _block_diag([a[2] for a in accepted])
            xi = x.copy()
            for it in range(ITERATIONS):
                hl, Hl_, okl = predict_all(accepted, xi, n, th)
                if not all(okl):
                    break
                h = np.concatenate(hl)
                H = np.vstack(Hl_)
                S = H @ P @ H.T + Rn
                S = 0.5 * (S + S.T)
                if it == 0:
                    nu0, S0 = z - h, S
                Kg = np.linalg.solve(S, H @ P).T
                if pri.scale_consider:
                    Kg[SCALE] = 0.0           # 4e Schmidt: the scale is considered, not updated
                step = x + Kg @ (z - h - H @ (x - xi))
                done = np.max(np.abs(step[:3] - xi[:3])) < ITERATION_TOLERANCE
                xi = step
                if done:
                    break
            x = xi
            IKH = np.eye(n) - Kg @ H
            P = IKH @ P @ IKH.T + Kg @ Rn @ Kg.T
            P = 0.5 * (P + P.T)
            out.nis[k] = float(nu0 @ np.linalg.solve(S0, nu0))
            out.nis_dof[k] = nu0.size
        # drop the landmarks of rejected tracks
        if banned & set(ids):
            keep = [j for j, tid in enumerate(ids) if tid not in banned]
            idx = np.r_[np.arange(CORE), _slots(keep),
                        np.arange(n - 3, n)]
            x, P = x[idx], P[np.ix_(idx, idx)]
            ids = [ids[j] for j in keep]
            n = x.size
            th = slice(n - 3, n)
        # 7 new landmarks
        room = opt.max_landmarks - len(ids)
        if (birth_sigma > 0 and np.linalg.eigvalsh(P[:3, :3])[-1]
                > birth_sigma**2):
            room = 0                          # 7a no births while the position is this loose
        new = [f for f in m.features if f.track_id not in ids and f.track_id not in banned]
        if room > 0 and new:
            r = x[:3]
            R_true = R_m @ rotation_vector_matrix(x[th])
            s_est = 1.0 + float(x[SCALE])
            placed = BodyInCamera.place(shape.vertices * s_est, shape.faces, R_true.T @ R_bi,
                                        R_true.T @ (-r))
            Js, Gs, Ns, ls, born = [], [], [], [], []
            cands = new[:room]
            try:
                births = landmark_births(camera, r, R_true, R_bi,
                                         np.array([f.uv for f in cands]), body=placed)
            except GeometryError:
                # the estimate is so far off that the body reaches behind the camera: no ray
                # can be cast from it, and no landmark is born this frame
                births = [None] * len(cands)
            for f, b in zip(cands, births, strict=True):
                if b is None or b.cos_incidence < cos_max:
                    continue
                J = np.zeros((3, n))
                J[:, :3], J[:, th] = b.J_r, b.J_theta
                # 4e the facet plane's offset scales with the model: a height of
                # n . p / (1 + s) per unit of s
                J[:, SCALE] = b.J_h * float(b.normal_body @ b.point_body) / s_est
                Js.append(J)
                Gs.append(np.column_stack([b.J_uv, b.J_h]))
                Ns.append(np.diag([f.sigma_px**2, f.sigma_px**2, height_sigma**2]))
                ls.append(b.point_body)
                born.append(f.track_id)
            if born:
                J = np.vstack(Js)
                GNG = _block_diag([G @ N @ G.T for G, N in zip(Gs, Ns, strict=True)])
                PJ = P @ J.T
                P = np.block([[P, PJ], [PJ.T, J @ PJ + GNG]])
                x = np.r_[x, np.concatenate(ls)]
                ids.extend(born)
                out.landmarks_born[k] = len(born)
        # 8 marginalise the attitude error
        n = x.size
        idx = np.r_[np.arange(th.start), np.arange(th.stop, n)]
        x, P = x[idx], P[np.ix_(idx, idx)]
        out.states[k] = x[:6]
        out.info["bias"][k] = x[BIAS]
        out.info["bias_sigma"][k] = np.sqrt(np.diag(P)[BIAS])
        for j, tid in enumerate(ids):     # each landmark's estimate: first and latest
            blk = slice(CORE + 3 * j, CORE + 3 * j + 3)
            est = (x[blk].copy(), P[blk, blk].copy())
            out.info["landmark_first"].setdefault(tid, est)
            out.info["landmark_last"][tid] = est
        out.info["shape_scale"][k] = x[SCALE]
        out.info["shape_scale_sigma"][k] = math.sqrt(max(P[SCALE, SCALE], 0.0))
        out.covariances[k] = P[:6, :6]
        out.landmarks[k] = len(ids)
    return out


def aspect_of(r: FloatArray, body: ShapeBodyLike, epoch: float, sun: FloatArray | None
              ) -> tuple[FloatArray, FloatArray]:
    """The body-fixed view direction (centre -> spacecraft at ``r``, J2000 [m]) and Sun
    direction at ``epoch`` [TDB s] (module step 1a; no Sun: the view's, phase 0)."""
    R_bi = np.asarray(body.orientation(epoch), float).reshape(3, 3)
    u = R_bi.T @ (np.asarray(r, float) / float(np.linalg.norm(r)))
    return u, (R_bi.T @ sun if sun is not None else u)


def gate_rows(rows: list, predicted: tuple[list[FloatArray], list[FloatArray], list[bool]],
              P: FloatArray, gate: dict[int, float]) -> list[tuple[Any, float, bool, int]]:
    """Module step 5: ``(row, d2, accepted, dof)`` of every row whose prediction is valid,
    ``d2 = nu^T S^-1 nu`` against the chi-square ``gate`` of its dof."""
    out = []
    for row, h1, H1, ok1 in zip(rows, *predicted, strict=True):
        if not ok1:
            continue
        nu = row[1] - h1
        S = H1 @ P @ H1.T + row[2]
        d2 = float(nu @ np.linalg.solve(S, nu))
        out.append((row, d2, d2 <= gate[nu.size], nu.size))
    return out


def _unit_sun(value: ArrayLike, name: str) -> FloatArray:
    """A Sun direction checked and normalised (before any work)."""
    s = np.asarray(value, float)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or not np.linalg.norm(s) > 0:
        raise ConfigError(name, np.ravel(s).tolist(), "a (3,) finite non-zero vector (J2000)")
    return s / np.linalg.norm(s)


def _slots(landmarks: list[int]) -> NDArray[np.int64]:
    """State indices of the landmarks ``landmarks`` (their positions in the landmark list)."""
    j = np.asarray(landmarks, np.int64)
    return (CORE + 3 * np.repeat(j, 3) + np.tile(np.arange(3), j.size)).astype(np.int64)


def _block_diag(blocks: list[FloatArray]) -> FloatArray:
    n = sum(b.shape[0] for b in blocks)
    M = np.zeros((n, n))
    i = 0
    for b in blocks:
        m = b.shape[0]
        M[i:i + m, i:i + m] = b
        i += m
    return M
