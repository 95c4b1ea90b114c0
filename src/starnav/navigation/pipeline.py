"""The limb-based VBN chain end to end: segments -> limb -> RANSAC -> fix -> EKF.

1. :func:`process_frame`, one frame to one position fix: a. the Moon's rough image position and
   the Sun's direction in the image from the measured attitude; b. pixel-level limb points
   (:mod:`~starnav.navigation.limb`); c. RANSAC (:mod:`~starnav.navigation.ransac`); d. with
   windows, subpixel points (:mod:`~starnav.navigation.refine`) screened by their residual to
   a first fix; e. the Christian-Robinson fix with its covariance
   (:mod:`~starnav.navigation.christian_robinson`). A frame without a usable limb returns a
   measurement with a ``status`` and a message instead of raising, so a sequence goes on.
2. :func:`run_filter`: the EKF (:mod:`~starnav.navigation.ekf`) over the measurements.
3. :func:`navigate`: both over a dataset, each frame prepared (:func:`prepare_frame`: read,
   its edge tables built) then processed once on the clock; on request the peak heap.
   Monte Carlo runs repeat these in :mod:`starnav.batch` (:mod:`starnav.batch.runs`).

Index
-----
:func:`process_frame`, :func:`prepare_frame`, :class:`FrameMeasurement`, :class:`ChainOptions`,
:func:`camera_consider_jacobian`, :func:`run_filter`, :class:`FilterResult`,
:func:`navigate`, :class:`NavigationRun`, :func:`initial_error_normal`, :func:`truth_states`,
:data:`STAGES`.
"""

from __future__ import annotations

import copy
import logging
import math
import time
import tracemalloc
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.camera import Camera
from starnav.camera_calibration import CameraCalibration, star_alignment
from starnav.config_base import SIView
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.navigation.christian_robinson import (
    ChristianRobinsonOptions,
    FixError,
    LimbFix,
    christian_robinson,
    christian_robinson_centres,
)
from starnav.navigation.dynamics import Dynamics, MoonEphemeris
from starnav.navigation.ekf import EkfPriors, NavigationEkf
from starnav.navigation.frames import NavDataset, NavFrame
from starnav.navigation.limb import (
    LimbConfig,
    LimbNotFoundError,
    LimbPoints,
    fit_circle_kasa,
    limb_points_from_segments,
    phase_angle_from_image,
    segments_centroid,
    sun_geometry_in_image,
)
from starnav.navigation.metrics import NavMetrics, limb_point_errors, nees
from starnav.navigation.ransac import RansacConfig, RansacError, RansacResult, ransac_limb
from starnav.navigation.refine import (
    RefineConfig,
    RefineModels,
    prepare_edge_tables,
    refine_limb,
)
from starnav.navigation.refine import warm_up as refine_warm_up
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Stages timed by :func:`process_frame` and :func:`navigate`, in order.
STAGES = ("limb", "ransac", "refine", "fix", "ekf")


@dataclass(frozen=True)
class ChainOptions:
    """Options of every stage of :func:`process_frame`.

    Attributes
    ----------
    limb, ransac, refine :
        The SI views of the stages' scenario sections (:class:`~starnav.navigation.limb.
        LimbConfig`, :class:`~starnav.navigation.ransac.RansacConfig`,
        :class:`~starnav.navigation.refine.RefineConfig`: its ``outlier_px`` drops refined
        points whose residual to a first fix exceeds it).
    refine_models : RefineModels
        What the builder resolved for the refinement (noise, blur, terrain, calibration).
    fix : ChristianRobinsonOptions
        The fix's shape and attitude knowledge.
    use_windows : bool
        Refine with the frame's windows when it has some (the builder sets it from
        ``refine.enabled``; a caller switches it off for the pixel-level chain).
    calibration : CameraCalibration, optional
        The camera as a calibration estimated it: the chain navigates with its camera
        (whatever camera the caller passes) and adds its covariance to each fix as consider
        parameters, ``J C J^T`` (:func:`camera_consider_jacobian`). None: the caller's
        camera, known exactly.
    """

    limb: SIView = field(default_factory=lambda: LimbConfig().to_si())
    ransac: SIView = field(default_factory=lambda: RansacConfig().to_si())
    refine: SIView = field(default_factory=lambda: RefineConfig().to_si())
    refine_models: RefineModels = field(default_factory=RefineModels)
    fix: ChristianRobinsonOptions = field(default_factory=ChristianRobinsonOptions)
    use_windows: bool = True
    calibration: CameraCalibration | None = None


@dataclass(frozen=True)
class FrameMeasurement:
    """Output of :func:`process_frame` for one frame.

    Attributes
    ----------
    index, epoch_tdb : int, float
        Frame number and epoch [TDB s past J2000].
    status : str
        ``ok`` or why there is no fix (module docstring).
    message : str
        Human-readable reason (empty when ``ok``).
    limb : LimbPoints or None
        Pixel-level limb points.
    inliers : (N,) bool array or None
        RANSAC consensus among ``limb``.
    refined : LimbPoints or None
        Subpixel points from the windows (those used in the fix).
    fix : LimbFix or None
        Christian-Robinson fix (camera frame).
    position : (3,) array or None
        Camera position relative to the Moon centre, J2000 [m].
    covariance : (3, 3) array or None
        Its covariance [m^2] (point noise, attitude knowledge, and the errors all points
        share).
    common_jacobian : (3, 3) array or None
        Sensitivity of ``position`` to the three errors refined points share (along the limb
        normals, a shift towards the Sun in the image, one across it), per unit of the disc's
        apparent radius [m, J2000] (the ``limb-common`` bias model's ``G``).
    noise_covariance : (3, 3) array or None
        The fix's covariance from its points' own errors and the attitude (without what they
        share) [m^2].
    white_covariance : (3, 3) array or None
        From the pixels' noise and the attitude alone: what changes from frame to frame
        (the ``limb-common`` filter's measurement noise) [m^2]; ``covariance`` is this plus
        ``s G C G^T``, ``C`` the calibrated slowly varying part and ``s`` its factor at the
        frame's phase (``common_scale``), and the camera calibration's share.
    consider_jacobian : (3, n) array or None
        ``J = d position / d theta`` of the camera calibration's parameters [m per unit]
        (:func:`camera_consider_jacobian`); None without a calibration.
    consider_covariance : (3, 3) array or None
        ``J C J^T`` of the calibration's covariance ``C`` [m^2], included in ``covariance``
        (the fix on its own); a filter with the parameters as consider states takes it out.
    common_scale : float
        ``s``: the factor at this frame's phase on the slowly varying limb errors'
        covariance (:meth:`~starnav.navigation.refine.RefineModels.fix_scale`); the
        ``limb-common`` filter's states are those errors over ``sqrt(s)``, seen through
        ``sqrt(s) G``.
    timings_s : dict
        Wall time of each stage [s].
    """

    index: int
    epoch_tdb: float
    status: str
    message: str = ""
    limb: LimbPoints | None = None
    inliers: NDArray[np.bool_] | None = None
    refined: LimbPoints | None = None
    fix: LimbFix | None = None
    position: FloatArray | None = None
    covariance: FloatArray | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    common_jacobian: FloatArray | None = None
    noise_covariance: FloatArray | None = None
    white_covariance: FloatArray | None = None
    consider_jacobian: FloatArray | None = None
    consider_covariance: FloatArray | None = None
    common_scale: float = 1.0

    @property
    def usable(self) -> bool:
        """True when the frame gives a position fix."""
        return self.status == "ok"

    @property
    def points_used(self) -> FloatArray:
        """The limb points the fix was computed from [px] (empty without a fix)."""
        if self.refined is not None:
            return self.refined.uv
        if self.limb is not None and self.inliers is not None:
            return self.limb.uv[self.inliers]
        return np.empty((0, 2))


def _fail(frame: NavFrame, status: str, message: str, timings: dict[str, float],
          **kw: object) -> FrameMeasurement:
    log.info("frame %s: no fix (%s): %s", frame.index, status, message)
    return FrameMeasurement(int(frame.index), float(frame.epoch_tdb), status, message,
                            timings_s=timings, **kw)  # type: ignore[arg-type]


def process_frame(
    frame: NavFrame,
    camera: Camera,
    *,
    options: ChainOptions | None = None,
    rng: np.random.Generator | None = None,
) -> FrameMeasurement:
    """One frame through the image processing and the Christian-Robinson fix (module step 1).

    Parameters
    ----------
    frame : NavFrame
        Segments, windows, measured attitude, Sun direction (see
        :mod:`starnav.navigation.frames`).
    camera : Camera
        Camera model.
    options : ChainOptions, optional
        Per-stage options.
    rng : numpy.random.Generator, optional
        For RANSAC; default ``default_rng(frame.index)`` (reproducible per frame).

    Returns
    -------
    FrameMeasurement
        ``status == "ok"`` with ``position`` and ``covariance`` [m, m^2] in J2000, or the
        reason there is none. Never raises for bad frame content.
    """
    opt = options or ChainOptions()
    rng = rng if rng is not None else np.random.default_rng(int(frame.index))
    tm: dict[str, float] = {}
    R_measured = np.asarray(frame.R_cam_to_inertial_measured, float)
    declared = camera
    camera, R_ci, R_mi, R_body_to_cam = _chain_camera(frame, camera, opt)

    front = _limb_and_ransac(frame, camera, opt, rng, R_ci, R_body_to_cam, tm)
    if isinstance(front, FrameMeasurement):
        return front
    limb, rr, sdir = front
    inl = rr.inliers

    refined = None
    if opt.use_windows and frame.windows:
        t = time.perf_counter()
        centre, radius = _coarse_circle(limb, rr)
        try:
            phase = phase_angle_from_image(camera, R_ci, frame.sun_direction_inertial, centre)
            refined = refine_limb(frame.windows, centre, radius, sun_dir_image=sdir,
                                  options=opt.refine, models=opt.refine_models, camera=camera,
                                  phase_rad=phase)
        except LimbNotFoundError as err:
            log.info("frame %s: subpixel refinement failed (%s); pixel-level points used",
                     frame.index, err)
        tm["refine"] = time.perf_counter() - t

    t = time.perf_counter()
    try:
        if refined is not None:
            fix = christian_robinson(refined.uv, camera, sigma_px=refined.sigma_px,
                                     R_body_to_cam=R_body_to_cam, options=opt.fix)
            bad = np.abs(fix.residual_px) > opt.refine.outlier_px
            if np.any(bad) and (~bad).sum() >= 3:
                keep = ~bad
                refined = refined.subset(keep)
                fix = christian_robinson(refined.uv, camera, sigma_px=refined.sigma_px,
                                         R_body_to_cam=R_body_to_cam, options=opt.fix)
        else:
            fix = christian_robinson(limb.uv[inl], camera, sigma_px=limb.sigma_px[inl],
                                     R_body_to_cam=R_body_to_cam, options=opt.fix)
    except FixError as err:
        tm["fix"] = time.perf_counter() - t
        return _fail(frame, "fix-failed", str(err), tm, limb=limb, inliers=inl,
                     refined=refined)
    pos = fix.position_inertial(R_ci)
    # the errors the points share (the terrain's half-circle mean, the lit limb's pull towards
    # the Sun): the refinement's own estimate for this frame, else the configured radius error
    G = noise = white = None
    scale = 1.0
    if refined is not None and refined.common_covariance_px2 is not None:
        noise = fix.covariance_inertial(R_ci, opt.fix.attitude_sigma_rad)
        Gpx = _common_jacobian(fix, refined, camera, R_ci, R_body_to_cam, opt.fix)
        G = Gpx * float(refined.radius_px)
        saturated = refined.saturated is not None and bool(np.any(refined.saturated))
        scale = opt.refine_models.fix_scale(opt.refine, phase, saturated)
        if refined.fix_covariance_px2 is not None and refined.fit_sigma_px is not None:
            # the pixels' noise and the attitude, and the calibrated slowly varying rest
            # the same points as the fix: its Jacobian with the fit's own sigmas
            white = fix.with_sigma(refined.fit_sigma_px).covariance_inertial(
                R_ci, opt.fix.attitude_sigma_rad)
            cov = white + Gpx @ np.asarray(refined.fix_covariance_px2, float) @ Gpx.T
        else:
            cov = noise + Gpx @ np.asarray(refined.common_covariance_px2, float) @ Gpx.T
    else:
        cov = fix.covariance_inertial(R_ci, opt.fix.attitude_sigma_rad,
                                      opt.fix.radius_sigma_fraction)
    J = JCJ = None
    if opt.calibration is not None and opt.calibration.parameters:
        used = refined.uv if refined is not None else limb.uv[inl]
        J = camera_consider_jacobian(opt.calibration, used, pos, R_measured, R_mi, declared,
                                     opt.fix, fix)
        C = np.asarray(opt.calibration.covariance, float)
        JCJ = J @ C @ J.T
        cov = cov + JCJ
    tm["fix"] = time.perf_counter() - t
    return FrameMeasurement(int(frame.index), float(frame.epoch_tdb), "ok", "", limb, inl,
                            refined, fix, pos, cov, tm, G, noise, white, J, JCJ, scale)



def _chain_camera(frame: NavFrame, camera: Camera, opt: ChainOptions
                  ) -> tuple[Camera, FloatArray, FloatArray | None, FloatArray | None]:
    """The camera the chain navigates with and the attitudes through it: ``(camera,
    R_cam_to_inertial, R_body_to_inertial or None, R_body_to_cam or None)``."""
    R_ci = np.asarray(frame.R_cam_to_inertial_measured, float)
    if opt.calibration is not None:
        # the attitude a star solve through the calibrated camera gives (star_alignment)
        declared, camera = camera, opt.calibration.camera
        R_ci = R_ci @ _alignment(declared, camera).T
    R_mi = getattr(frame, "R_body_to_inertial", None)
    R_body_to_cam = None if R_mi is None else R_ci.T @ np.asarray(R_mi, float)
    return camera, R_ci, R_mi, R_body_to_cam


def prepare_frame(frame: NavFrame, camera: Camera, *, options: ChainOptions | None = None,
                  rng: np.random.Generator | None = None) -> None:
    """What the tracker holds before a frame comes, made ahead of :func:`process_frame`: the
    frame read (its segments and windows), and the ``detector-psf`` edge model's tables of
    the field cells and edge directions its windows fall in (built once and cached: a
    tracker carries them; :meth:`~starnav.navigation.refine.EdgeSpread.tables_along`).

    The cells come from the coarse limb circle, so the limb scan and RANSAC run here on
    ``rng`` (pass a copy of the stream :func:`process_frame` will use); nothing is refined,
    fixed or filtered."""
    opt = options or ChainOptions()
    windows = frame.windows
    if (frame.segments is None or not (opt.use_windows and windows)
            or opt.refine_models.edge_model(opt.refine) != "detector-psf"):
        return
    rng = rng if rng is not None else np.random.default_rng(int(frame.index))
    cam, R_ci, _, R_body_to_cam = _chain_camera(frame, camera, opt)
    front = _limb_and_ransac(frame, cam, opt, rng, R_ci, R_body_to_cam, {})
    if not isinstance(front, FrameMeasurement):
        centre, radius = _coarse_circle(front[0], front[1])
        prepare_edge_tables(windows, centre, radius, options=opt.refine,
                            models=opt.refine_models, camera=cam)


def _limb_and_ransac(frame: NavFrame, camera: Camera, opt: ChainOptions,
                     rng: np.random.Generator, R_ci: FloatArray,
                     R_body_to_cam: FloatArray | None, tm: dict[str, float]
                     ) -> FrameMeasurement | tuple[LimbPoints, RansacResult, FloatArray]:
    """Steps 1a-c of :func:`process_frame`: the limb points, RANSAC's consensus and the Sun's
    direction in the image, or the failed frame's measurement (stage times into ``tm``)."""
    t = time.perf_counter()
    seg = frame.segments
    if seg is None:
        tm["limb"] = time.perf_counter() - t
        return _fail(frame, "no-segments", "the frame has no segments readout", tm)
    try:
        centre0 = segments_centroid(seg, opt.limb.min_level) if len(seg) else None
        if centre0 is None:
            raise LimbNotFoundError("segments: the readout has no run above threshold (no Moon "
                                    "in the frame, or an exposure too short for the threshold)",
                                    "no-moon")
        sdir, phase0 = sun_geometry_in_image(camera, R_ci, frame.sun_direction_inertial,
                                             centre0)
        if phase0 > opt.limb.max_phase:
            raise LimbNotFoundError(
                f"phase angle {math.degrees(phase0):.0f} deg > limb.max_phase_deg "
                f"{math.degrees(opt.limb.max_phase):.0f} deg: a crescent this thin shows "
                "too short a lit limb for a trustworthy fix (its errors are beyond the "
                "calibrated model)", "thin-crescent")
        limb = limb_points_from_segments(seg, sdir, options=opt.limb)
    except LimbNotFoundError as err:
        tm["limb"] = time.perf_counter() - t
        return _fail(frame, err.reason, str(err), tm)
    tm["limb"] = time.perf_counter() - t

    t = time.perf_counter()
    try:
        rr = ransac_limb(limb.uv, camera, rng=rng, options=opt.ransac, fix_options=opt.fix,
                         R_body_to_cam=R_body_to_cam)
    except RansacError as err:
        tm["ransac"] = time.perf_counter() - t
        return _fail(frame, "ransac-failed", str(err), tm, limb=limb)
    tm["ransac"] = time.perf_counter() - t
    return limb, rr, sdir



def _coarse_circle(limb: LimbPoints, rr: RansacResult) -> tuple[FloatArray, float]:
    """The coarse limb circle the windows are refined about: centre [px] and radius [px]."""
    if rr.model == "circle":
        return rr.params[:2], float(rr.params[2])
    return fit_circle_kasa(limb.uv[rr.inliers])


def camera_consider_jacobian(calibration: CameraCalibration, uv: FloatArray,
                             position: FloatArray, R_measured: FloatArray,
                             R_body_to_inertial: FloatArray | None, declared: Camera,
                             options: ChristianRobinsonOptions,
                             fix: LimbFix | None = None) -> FloatArray:
    """``J = d position / d theta`` [m per unit, J2000] of the calibrated parameters
    ``theta``: the fix's covariance gains ``J C J^T`` of the calibration's ``C``.

    The parameters are *considered*, not estimated: a limb fix cannot tell a focal-length
    error from a range error (both scale the disc). The filter carries them as Schmidt
    states (:class:`~starnav.navigation.ekf.NavigationEkf`, step 7), one constant error for
    every fix of the arc. Each parameter is moved by its 1-sigma ``h`` either way, with the
    attitude re-solved through the moved camera
    (:func:`~starnav.camera_calibration.star_alignment` from ``declared``, the camera of the
    frame's attitude ``R_measured``): a principal-point error moves the stars as it moves the
    Moon.

    With ``fix`` (the fix of ``uv`` through the calibrated camera, solved with its point
    Jacobian) the fix's change is first order and needs no new solve: the moved camera reads
    pixel ``uv`` as the calibrated one reads ``uv' = project(unproject'(uv))``, so the centre
    moves by ``sum_i G_i (uv'_i - uv_i)``, ``G`` the fix's point Jacobian. Without it, the
    fix is re-solved through each moved camera. Either way each column is a central
    difference over +-h: the principal point's effect on the Moon and on the stars nearly
    cancel, and what is left is of the size of a one-sided difference's own error."""
    J = np.zeros((3, len(calibration.parameters)))
    G = None if fix is None else fix.point_jacobian
    steps, shifts, alignments = _moved_cameras(calibration, declared)
    if G is not None and fix is not None:
        # every moved camera's pixel shift at the points at once: (N, moved cameras, 2), and
        # its fix's position through its own attitude, all moved cameras at once
        dc = np.einsum("nij,nkj->ki", G, shifts(uv))
        R_moved = R_measured @ alignments.transpose(0, 2, 1)
        at = -(R_moved @ (fix.centre_camera + dc)[..., None])[..., 0]
        for k, (i, h, _) in enumerate(steps):
            J[:, i] = (at[2 * k] - at[2 * k + 1]) / (2.0 * h)
        return J
    for i, h, moved in steps:
        pos = []
        for cam, A in moved:
            R_moved = R_measured @ A.T
            R_bc = None if R_body_to_inertial is None else R_moved.T @ np.asarray(
                R_body_to_inertial, float)
            pos.append(christian_robinson(uv, cam, R_body_to_cam=R_bc,
                                          options=options).position_inertial(R_moved))
        J[:, i] = (pos[0] - pos[1]) / (2.0 * h)
    return J


_MOVED: dict[tuple[int, int], tuple[object, ...]] = {}


def _alignment(declared: Camera, known: Camera) -> FloatArray:
    """:func:`~starnav.camera_calibration.star_alignment`, made once per pair of cameras."""
    key = (id(declared), -id(known))
    hit = _MOVED.get(key)
    if hit is not None and hit[0] is declared and hit[1] is known:
        return hit[2]  # type: ignore[return-value]
    A = star_alignment(declared, known)
    if len(_MOVED) >= 16:
        _MOVED.clear()
    _MOVED[key] = (declared, known, A)
    return A


#: Spacing of the grid on which each moved camera's pixel shift is tabulated [px].
SHIFT_GRID_PX = 16.0


def _pixel_shifts(known: Camera, moved: Sequence[Camera]
                  ) -> Callable[[FloatArray], FloatArray]:
    """``uv (N, 2) -> (N, len(moved), 2)``: for each moved camera, ``project_known(
    unproject_moved(uv)) - uv`` [px], where the calibrated camera reads the pixel the moved
    one reads at ``uv``. Smooth fields over the detector (each camera differs by one
    parameter), tabulated once on a grid of :data:`SHIFT_GRID_PX` and interpolated
    bilinearly (extrapolated linearly outside the grid)."""
    from scipy.interpolate import RegularGridInterpolator

    u = np.linspace(-0.5, known.width - 0.5, int(np.ceil(known.width / SHIFT_GRID_PX)) + 1)
    v = np.linspace(-0.5, known.height - 0.5, int(np.ceil(known.height / SHIFT_GRID_PX)) + 1)
    grid = np.stack(np.meshgrid(u, v, indexing="ij"), -1)
    d = np.stack([known.project(cam.unproject(grid)) - grid for cam in moved], axis=2)
    f = RegularGridInterpolator((u, v), d, method="linear", bounds_error=False,
                                fill_value=None)
    return lambda uv: f(np.asarray(uv, float))


def _moved_cameras(calibration: CameraCalibration, declared: Camera
                   ) -> tuple[list[tuple[int, float, list[tuple[Camera, FloatArray]]]],
                              Callable[[FloatArray], FloatArray], FloatArray]:
    """Per calibrated parameter with a 1-sigma ``h > 0``: ``(index, h, [(camera, its star
    alignment from declared)] with the parameter moved by +h and by -h)``, the moved
    cameras' pixel shifts in that order (:func:`_pixel_shifts`) and their alignments stacked
    ``(moved cameras, 3, 3)``. The same for every frame of a calibration, so made once per
    (calibration, declared camera) pair."""
    key = (id(calibration), id(declared))
    hit = _MOVED.get(key)
    if hit is not None and hit[0] is calibration and hit[1] is declared:
        return hit[2]  # type: ignore[return-value]
    out = []
    for i, name in enumerate(calibration.parameters):
        h = calibration.sigma(name)
        if h <= 0:
            continue
        moved = []
        for sign in (1.0, -1.0):
            d = np.zeros(len(calibration.parameters))
            d[i] = sign * h
            cam = calibration.camera_with(d)
            moved.append((cam, star_alignment(declared, cam)))
        out.append((i, h, moved))
    res = (out, _pixel_shifts(calibration.camera, [c for _, _, m in out for c, _ in m]),
           np.array([A for _, _, m in out for _, A in m], float).reshape(-1, 3, 3))
    if len(_MOVED) >= 16:
        _MOVED.clear()
    _MOVED[key] = (calibration, declared, res)
    return res


def _common_jacobian(fix: LimbFix, refined: LimbPoints, camera: Camera, R_ci: FloatArray,
                     R_body_to_cam: FloatArray | None,
                     options: ChristianRobinsonOptions) -> FloatArray:
    """The fix's sensitivity ``G`` [m/px, J2000] to the errors all refined points share
    (:attr:`LimbPoints.common_covariance_px2`: along the limb normals, a shift towards the
    Sun's direction in the image, one across it), by re-solving with every point moved by
    1 px of each (exact for the fix; linear at these sizes): the fix's covariance gains
    ``G C G^T``. On a half-lit limb the fix is most sensitive to them: an error that grows
    towards the cusps is a smaller disc *and* a centre pulled towards the Sun."""
    d = np.asarray(refined.sun_dir_image, float)
    nd = float(np.linalg.norm(d))
    d = d / nd if nd > 0 else np.array([1.0, 0.0])
    rel = refined.uv - np.asarray(refined.centre_px, float)
    normals = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    moves = np.stack([normals, np.broadcast_to(d, rel.shape),
                      np.broadcast_to(np.array([-d[1], d[0]]), rel.shape)])
    moved = christian_robinson_centres(refined.uv + moves, camera, R_body_to_cam=R_body_to_cam,
                                       options=options)
    return -R_ci @ (moved - fix.centre_camera).T


# ----------------------------------------------------------------------------- filter
@dataclass(frozen=True)
class FilterResult:
    """EKF history at the measurement epochs (posterior after each frame).

    Attributes
    ----------
    epochs : (K,) array
        [TDB s past J2000].
    states : (K, n) array
        EMB-centred J2000 position [m], velocity [m/s], bias states.
    covariances : (K, n, n) array
    has_fix : (K,) bool array
        The frame gave a fix.
    accepted : (K,) bool array
        The fix passed the gate (or was forced).
    nis : (K,) array
        NIS of each fix (NaN without one).
    bias_model : str
    timings_s : (K,) array
        Wall time of each predict + update [s].
    """

    epochs: FloatArray
    states: FloatArray
    covariances: FloatArray
    has_fix: NDArray[np.bool_]
    accepted: NDArray[np.bool_]
    nis: FloatArray
    bias_model: str
    timings_s: FloatArray

    def errors(self, truth: ArrayLike) -> FloatArray:
        """Position and velocity errors ``(K, 6)`` [m, m/s] against EMB-centred truth ``(K, 6)``.

        Origin-free: a Moon-centred truth gives the same errors if the Moon's state is added to
        it first (see :func:`truth_states`)."""
        return self.states[:, :6] - np.asarray(truth, float)

    def sigma3(self) -> FloatArray:
        """3-sigma bounds of position and velocity ``(K, 6)`` [m, m/s]."""
        return 3.0 * np.sqrt(np.einsum("kii->ki", self.covariances[:, :6, :6]))

    def nees(self, truth: ArrayLike) -> FloatArray:
        """NEES of the 6 position-velocity states ``(K,)`` [-]."""
        return np.asarray(nees(self.errors(truth), self.covariances[:, :6, :6]))

    def nees_position(self, truth: ArrayLike) -> FloatArray:
        """NEES of the position alone ``(K,)`` (its marginal 3x3 covariance; chi2(3)) [-]."""
        return np.asarray(nees(self.errors(truth)[:, :3], self.covariances[:, :3, :3]))

    def nees_velocity(self, truth: ArrayLike) -> FloatArray:
        """NEES of the velocity alone ``(K,)`` (its marginal 3x3 covariance; chi2(3)) [-]."""
        return np.asarray(nees(self.errors(truth)[:, 3:6], self.covariances[:, 3:6, 3:6]))


def run_filter(
    measurements: Sequence[FrameMeasurement],
    *,
    dynamics: Dynamics,
    moon: MoonEphemeris,
    t0: float,
    x0: ArrayLike,
    P0: ArrayLike,
    options: SIView | None = None,
    priors: EkfPriors | None = None,
) -> FilterResult:
    """Run the EKF over a sequence of frame measurements (module step 2).

    Parameters
    ----------
    measurements : sequence of FrameMeasurement
        In time order; frames without a fix only propagate.
    dynamics : Dynamics
        6-state propagator with STM.
    moon : MoonEphemeris
        Moon state relative to the EMB.
    t0 : float
        Epoch of ``x0`` [TDB s].
    x0 : (6,) array
        Initial EMB-centred J2000 state [m, m/s].
    P0 : (6, 6) array
        Its covariance.
    options, priors :
        The filter's section (SI view of :class:`~starnav.navigation.ekf.FilterConfig`) and
        resolved covariances (:class:`~starnav.navigation.ekf.EkfPriors`); default theirs.

    Returns
    -------
    FilterResult
    """
    rec = _FilterRecorder(NavigationEkf(dynamics, moon, t0, x0, P0, options=options,
                                        priors=priors), len(measurements))
    for k, m in enumerate(measurements):
        rec.step(k, m)
    return rec.result()


class _FilterRecorder:
    """The filter over a sequence of frames, recording the posterior after each: the one loop
    behind :func:`run_filter` (measurements ready) and :func:`navigate` (measurements made
    frame by frame, with timings)."""

    def __init__(self, ekf: NavigationEkf, K: int) -> None:
        self.ekf = ekf
        n = ekf.n
        self.epochs, self.X, self.P = np.empty(K), np.empty((K, n)), np.empty((K, n, n))
        self.has, self.acc = np.zeros(K, bool), np.zeros(K, bool)
        self.nis = np.full(K, np.nan)
        self.times = np.empty(K)

    def step(self, k: int, m: FrameMeasurement) -> float:
        """Predict to frame ``k`` and update with its fix; returns the wall time [s]."""
        t = time.perf_counter()
        ekf = self.ekf
        ekf.predict(m.epoch_tdb)
        if m.usable and m.position is not None and m.covariance is not None:
            self.has[k] = True
            lc = (ekf.bias_model == "limb-common" and m.common_jacobian is not None
                  and m.white_covariance is not None)
            # with limb-common states the slowly varying limb errors are states: the fix's
            # pixel noise and attitude alone are its measurement noise
            R = m.white_covariance if lc else m.covariance
            G = m.common_jacobian * math.sqrt(m.common_scale) if lc else None
            J = m.consider_jacobian
            if J is not None and ekf.n_consider:
                # the calibration's error is a consider state: constant over the arc
                if not lc:
                    R = R - m.consider_covariance
                info = ekf.update(m.position, R, G, J)
            else:
                if J is not None and lc:
                    R = R + m.consider_covariance
                info = ekf.update(m.position, R, G)
            self.acc[k] = info.accepted
            self.nis[k] = info.nis
        self.times[k] = dt = time.perf_counter() - t
        self.epochs[k], self.X[k], self.P[k] = ekf.t, ekf.x, ekf.P
        return dt

    def result(self) -> FilterResult:
        return FilterResult(self.epochs, self.X, self.P, self.has, self.acc, self.nis,
                            self.ekf.bias_model, self.times)


def initial_error_normal(seed: int, run: int) -> FloatArray:
    """Standard normal 6-vector of run ``run``'s initial state error (``x0 = truth + L z``,
    ``L L^T = P0``): stream ``generator(seed, STAGE_NAVIGATION, run)``, the same for
    :func:`navigate` and the Monte Carlo runs of :mod:`starnav.batch`."""
    return generator(int(seed), STAGE_NAVIGATION, int(run)).standard_normal(6)


def truth_states(frames: Iterable[NavFrame], moon: MoonEphemeris) -> FloatArray | None:
    """EMB-centred J2000 truth ``(K, 6)`` [m, m/s] from the frames' Moon-centred truth, or None
    if any frame has none."""
    out = []
    for f in frames:
        g: FrameGeometry | None = f.truth
        if g is None:
            return None
        out.append(moon.moon_state(f.epoch_tdb)
                   + np.concatenate([g.camera_position, g.camera_velocity]))
    return np.array(out) if out else None


# ----------------------------------------------------------------------------- navigate
@dataclass(frozen=True)
class NavigationRun:
    """Everything :func:`navigate` produced.

    Attributes
    ----------
    measurements : list of FrameMeasurement
    filter : FilterResult
    truth : (K, 6) array or None
        EMB-centred truth at the frame epochs [m, m/s].
    limb_errors : list of arrays
        Per frame, the signed distance of the used limb points to the true limb [px].
    stage_times_s : (K, len(STAGES)) array
        Wall time per stage (:data:`STAGES`) [s]; NaN for a stage not run.
    cpu_times_s : (K,) array
        Process CPU time of the whole chain per frame, the filter's step included [s]; what
        the tracker holds before the frame comes is made outside it (:func:`prepare_frame`).
    peak_memory_bytes : (K,) array or None
        Peak traced Python heap (numpy arrays included) of the chain per frame [bytes]
        (``measure_memory``; measured in a separate pass so the timings are untraced).
    truth_range_m : (K,) array
        True camera-Moon distance per frame [m] (NaN without truth).
    """

    measurements: list[FrameMeasurement]
    filter: FilterResult
    truth: FloatArray | None
    limb_errors: list[FloatArray]
    stage_times_s: FloatArray
    cpu_times_s: FloatArray
    peak_memory_bytes: FloatArray | None
    truth_range_m: FloatArray

    def metrics(self) -> NavMetrics:
        """Accuracy and consistency of the filter against the truth (:class:`NavMetrics`)."""
        return NavMetrics.of(self.filter, self.truth, float(self.truth_range_m[-1]))


def navigate(
    dataset: NavDataset | Sequence[NavFrame],
    *,
    camera: Camera | None = None,
    dynamics: Dynamics,
    moon: MoonEphemeris,
    P0: ArrayLike,
    x0: ArrayLike | None = None,
    t0: float | None = None,
    chain: ChainOptions | None = None,
    ekf: SIView | None = None,
    ekf_priors: EkfPriors | None = None,
    seed: int = 0,
    run: int = 0,
    measure_memory: bool = False,
    chains: Sequence[ChainOptions] | None = None,
) -> NavigationRun:
    """Process every frame and filter the fixes (module step 3).

    Parameters
    ----------
    dataset : NavDataset or sequence of NavFrame
        Frames in time order (a NavDataset also gives the camera).
    camera : Camera, optional
        Required when ``dataset`` is a plain sequence.
    dynamics, moon :
        Filter dynamics and Moon ephemeris.
    P0 : (6, 6) array
        Initial covariance [m^2, m^2/s, m^2/s^2].
    x0 : (6,) array, optional
        Initial EMB-centred state at ``t0``; default: the truth of the first frame plus an
        error drawn from ``P0`` (stream ``generator(seed, STAGE_NAVIGATION, run)``).
    t0 : float, optional
        Epoch of ``x0``; default the first frame's epoch.
    chain : ChainOptions, optional
        The chain's options.
    ekf, ekf_priors :
        The filter's section (SI view of :class:`~starnav.navigation.ekf.FilterConfig`) and
        resolved covariances (:class:`~starnav.navigation.ekf.EkfPriors`).
    seed, run : int
        The scenario's seed and the Monte Carlo run: the initial error comes from
        ``generator(seed, STAGE_NAVIGATION, run)`` and frame ``i``'s RANSAC from
        ``generator(seed, STAGE_NAVIGATION, run, i)`` (:mod:`starnav.seeding`), the streams
        of the sweep's run ``run``: a dataset navigated here and the same scenario's sweep
        give the same estimates.
    measure_memory : bool
        Trace the peak Python heap of each frame's chain (slower).
    chains : sequence of ChainOptions, optional
        Per-frame options instead of ``chain`` (one per frame): a solved attitude's own
        covariance in each frame's fix (:mod:`starnav.simulate.attitude`).

    Returns
    -------
    NavigationRun
    """
    frames = list(dataset)
    if not frames:
        raise ConfigError("dataset", "0 frames", "at least one frame")
    cam = camera if camera is not None else getattr(dataset, "camera", None)
    if cam is None:
        raise ConfigError("camera", None, "a Camera (the dataset does not carry one)")
    chain = chain or ChainOptions()
    if chains is not None and len(chains) != len(frames):
        raise ConfigError("chains", f"{len(chains)} options",
                          f"one ChainOptions per frame ({len(frames)})")
    per_frame = list(chains) if chains is not None else [chain] * len(frames)
    truth = truth_states(frames, moon)
    P0 = np.asarray(P0, float)
    t0 = float(frames[0].epoch_tdb) if t0 is None else float(t0)
    if x0 is None:
        if truth is None:
            raise ConfigError("x0", None, "an initial state (the frames carry no truth)")
        x0 = truth[0] + np.linalg.cholesky(P0) @ initial_error_normal(seed, run)
    frame_rngs = [generator(seed, STAGE_NAVIGATION, run, int(f.index)) for f in frames]
    K = len(frames)
    rec = _FilterRecorder(NavigationEkf(dynamics, moon, t0, x0, P0, options=ekf,
                                        priors=ekf_priors), K)
    stage = np.full((K, len(STAGES)), np.nan)
    cpu = np.empty(K)
    peak = np.empty(K) if measure_memory else None
    meas: list[FrameMeasurement] = []
    errs: list[FloatArray] = []
    if any(c.use_windows for c in per_frame):
        refine_warm_up()  # static tables, built once: not per-frame working memory
    for k, f in enumerate(frames):
        # what the tracker holds before a frame comes (the readout in memory, the edge
        # model's tables of the field cells and directions its windows fall in) is made
        # first, outside the clock and the traced heap (prepare_frame); then the frame is
        # processed once, on the clock
        prepare_frame(f, cam, options=per_frame[k], rng=copy.deepcopy(frame_rngs[k]))
        if peak is not None:
            # the heap is traced on a pass of its own after the timed one (tracing slows the
            # chain): the same frame and RANSAC stream, a copy of the filter before its step
            shadow = _FilterRecorder(copy.deepcopy(rec.ekf), K)
            rng_traced = copy.deepcopy(frame_rngs[k])
        c0 = time.process_time()
        m = process_frame(f, cam, options=per_frame[k], rng=frame_rngs[k])
        dt = rec.step(k, m)
        cpu[k] = time.process_time() - c0
        if peak is not None:
            tracemalloc.start()
            tracemalloc.reset_peak()
            shadow.step(k, process_frame(f, cam, options=per_frame[k], rng=rng_traced))
            peak[k] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            del shadow
        for j, s in enumerate(STAGES[:-1]):
            if s in m.timings_s:
                stage[k, j] = m.timings_s[s]
        stage[k, -1] = dt
        meas.append(m)
        if f.truth is not None and m.points_used.size:
            errs.append(limb_point_errors(m.points_used, cam, f.truth,
                                          per_frame[k].fix.radii_m))
        else:
            errs.append(np.empty(0))
    res = rec.result()
    log.info("navigate: %d frames, %d fixes, %d accepted", K, int(res.has_fix.sum()),
             int(res.accepted.sum()))
    ranges = np.array([f.truth.range if f.truth is not None else np.nan for f in frames])
    return NavigationRun(meas, res, truth, errs, stage, cpu, peak, ranges)

