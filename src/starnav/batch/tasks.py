"""The three kinds of sweep task: render a frame, expose and process it, filter a point.

A sweep of ``P`` points, ``R`` runs and ``F`` frames is the graph ``render(group, frame)`` (one
per render group and frame) -> ``expose(point, frame)`` (every run: acquisitions, on-board
chain, limb errors) -> ``filter(point)`` (every run: the EKF over the fixes). Only small
objects travel between workers and no task needs a shared file system.

Randomness, all through :mod:`starnav.seeding` (a result does not depend on its worker): the
render ``seed_u32(seed, STAGE_RENDER, frame)`` as datasets; the acquisitions of run ``r``
:func:`starnav.simulate.acquire.acquisition_seed` (run 0 = the dataset's); RANSAC of frame
``k`` in run ``r`` ``generator(seed, STAGE_NAVIGATION, r, k)``; the filter's initial error of
run ``r`` ``generator(seed, STAGE_NAVIGATION, r)``.

Index
-----
:func:`render_task`, :class:`RenderedFrame`, :func:`expose_task`, :func:`expose_sequence_task`,
:class:`FrameResult`, :class:`LimbPointRecord`, :func:`filter_task`, :class:`PointResult`,
:func:`attitude_columns`, :data:`TIMED_STAGES`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.batch.cluster import quiet_logger
from starnav.batch.runs import over_runs, run_ids
from starnav.cache import BoundedCache
from starnav.config import scenario_from_dict
from starnav.errors import ConfigError
from starnav.navigation.dynamics import PointMassDynamics
from starnav.navigation.metrics import NavMetrics, limb_point_errors
from starnav.navigation.pipeline import (
    FrameMeasurement,
    initial_error_normal,
    process_frame,
    run_filter,
)
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate import simulator_for
from starnav.simulate.attitude import (
    StarAttitudeTracker,
    StarSolver,
    assumed_covariance,
    frame_attitude_summary,
    uses_star_attitude,
    with_attitude,
)
from starnav.simulate.build import chain_options
from starnav.stars.attitude import ARCSEC, error_rotation
from starnav.typing import FloatArray

#: Timed stages, in order, each a column ``time_<stage>_s`` of the table.
TIMED_STAGES: tuple[str, ...] = ("render", "detector", "plan", "limb", "ransac", "refine",
                                 "fix", "ekf")


# ============================================================================ results
@dataclass(frozen=True)
class RenderedFrame:
    """A rendered frame, cropped to its non-zero box.

    Attributes
    ----------
    index : int
    geometry : FrameGeometry
    shape : (rows, cols)
    box : (row0, col0)
        Top-left pixel of the crop.
    Le : (h, w) float32
        Electron radiance in the box [e- s^-1 m^-2 sr^-1].
    render_s : float
        Wall time of the render [s].
    variant : str
        Mitsuba variant.
    """

    index: int
    geometry: Any
    shape: tuple[int, int]
    box: tuple[int, int]
    Le: NDArray[np.float32]
    render_s: float
    variant: str

    def electron_radiance(self, factor: float = 1.0) -> NDArray[np.float32]:
        """Full-size electron radiance times ``factor`` [e- s^-1 m^-2 sr^-1]."""
        out = np.zeros(self.shape, np.float32)
        r0, c0 = self.box
        h, w = self.Le.shape
        le = self.Le if factor == 1.0 else self.Le * np.float32(factor)
        out[r0:r0 + h, c0:c0 + w] = le
        return out


@dataclass(frozen=True)
class FrameResult:
    """One frame of one run of one point, after the on-board chain.

    Attributes
    ----------
    index, run : int
    epoch_tdb : float
        [TDB s past J2000].
    status : str
        Navigation status (``ok`` or why there is no fix).
    position, covariance : arrays or None
        Moon-relative fix, J2000 [m] and its covariance [m^2].
    limb_errors_px : (N,) float32
        Signed distance of the used limb points to the true limb [px] (> 0 outside).
    saturated_pixels, dn_max : int
    feasible : bool
        Both acquisitions satisfy the readout law.
    plan_status : str
        Window plan status (``skipped`` without windows).
    n_windows : int
    truth_emb : (6,) array or None
        EMB-centred truth [m, m/s].
    range_m : float
        Camera to Moon-centre distance [m].
    timings_s : dict
        Stage wall times for this frame [s].
    points : LimbPointRecord or None
        The used limb points' uncertainties (for consistency studies).
    common_jacobian, white_covariance : (3, 3) arrays or None
        The fix's sensitivity to the errors its points share [m per unit of disc radius] and
        its covariance from the pixels' noise and the attitude alone [m^2].
    consider_jacobian, consider_covariance : arrays or None
        As :class:`~starnav.navigation.pipeline.FrameMeasurement`'s.
    attitude : dict or None
        With ``stars.enabled``: the attitude the fix used (``source``, its error and
        predicted 1-sigma, camera axes [rad]) and what the navigation frame's own stars give
        (``frame_*``: :func:`starnav.simulate.attitude.frame_attitude_summary`).
    """

    index: int
    run: int
    epoch_tdb: float
    status: str
    position: FloatArray | None
    covariance: FloatArray | None
    limb_errors_px: NDArray[np.float32]
    saturated_pixels: int
    dn_max: int
    feasible: bool
    plan_status: str
    n_windows: int
    truth_emb: FloatArray | None
    range_m: float
    timings_s: dict[str, float] = field(default_factory=dict)
    points: LimbPointRecord | None = None
    common_jacobian: FloatArray | None = None
    white_covariance: FloatArray | None = None
    attitude: dict[str, Any] | None = None
    consider_jacobian: FloatArray | None = None
    consider_covariance: FloatArray | None = None
    common_scale: float = 1.0


@dataclass(frozen=True)
class LimbPointRecord:
    """The uncertainties of one frame's used limb points, in the order of
    :attr:`FrameResult.limb_errors_px` [px].

    Attributes
    ----------
    refined : bool
        Subpixel points from windows (else pixel-level points from segments).
    radius_px : float
        Apparent radius of the coarse limb circle [px].
    sigma_px : (N,) float32
        Each point's 1-sigma as the fix uses it.
    fit_sigma_px : (N,) float32
        Its part from the pixels' noise (refined points; else ``sigma_px``).
    saturated : (N,) bool
        The point's window held saturated pixels.
    common_var_px2 : (N,) float32
        Variance [px^2] each point shares with the rest of its frame, along its normal
        (``x^T C x``, ``x = (1, cos phi, sin phi)``, ``C`` the refinement's common covariance).
    phase_rad : float
        True phase angle of the frame [rad].
    sun_angle_rad : (N,) float32
        Angle ``phi`` of each point's limb normal from the Sun's direction in the image [rad].
    mode_error : (3,) array or None
        The fix's error against the truth in the three shared modes (along the normals,
        towards the Sun, across it), ``G^-1 (r - r_true)`` [units of the disc radius].
    mode_noise : (3, 3) array or None
        Its covariance from the points' own errors and the attitude, ``G^-1 P_own G^-T``.
    mode_white : (3, 3) array or None
        Its covariance from the pixels' noise and the attitude alone.
    overexposure : (N,) float32 or None
        Each refined point's window: fitted edge step over the headroom to saturation (0
        well exposed).
    """

    refined: bool
    radius_px: float
    sigma_px: NDArray[np.float32]
    fit_sigma_px: NDArray[np.float32]
    saturated: NDArray[np.bool_]
    common_var_px2: NDArray[np.float32]
    phase_rad: float = math.nan
    sun_angle_rad: NDArray[np.float32] | None = None
    mode_error: FloatArray | None = None
    mode_noise: FloatArray | None = None
    mode_white: FloatArray | None = None
    overexposure: NDArray[np.float32] | None = None

    @classmethod
    def of(cls, m: Any, phase_rad: float = math.nan,
           truth_position: Any = None) -> LimbPointRecord | None:
        """From a :class:`~starnav.navigation.pipeline.FrameMeasurement` (None without
        points) and the true Moon-relative position [m, J2000]."""
        lp = m.refined if m.refined is not None else m.limb
        if lp is None or m.points_used.size == 0:
            return None
        if m.refined is None:
            sig = lp.sigma_px[m.inliers] if m.inliers is not None else lp.sigma_px
            return cls(False, float(lp.radius_px), sig.astype(np.float32),
                       sig.astype(np.float32), np.zeros(sig.size, bool),
                       np.zeros(sig.size, np.float32), float(phase_rad))
        fit = lp.fit_sigma_px if lp.fit_sigma_px is not None else lp.sigma_px
        sat = lp.saturated if lp.saturated is not None else np.zeros(len(lp), bool)
        rel = lp.uv - np.asarray(lp.centre_px, float)
        ang = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - math.atan2(
            float(lp.sun_dir_image[1]), float(lp.sun_dir_image[0])))))
        C = (np.zeros((3, 3)) if lp.common_covariance_px2 is None
             else np.asarray(lp.common_covariance_px2, float))
        x = np.column_stack([np.ones(ang.size), np.cos(ang), np.sin(ang)])
        cvar = np.einsum("ij,jk,ik->i", x, C, x)
        me = mn = mw = None
        if (truth_position is not None and m.common_jacobian is not None
                and m.position is not None):
            Gi = np.linalg.inv(m.common_jacobian)
            me = Gi @ (np.asarray(m.position) - np.asarray(truth_position, float))
            mn = Gi @ m.noise_covariance @ Gi.T
            if m.white_covariance is not None:
                mw = Gi @ m.white_covariance @ Gi.T
        return cls(True, float(lp.radius_px), lp.sigma_px.astype(np.float32),
                   np.asarray(fit, np.float32), np.asarray(sat, bool),
                   cvar.astype(np.float32), float(phase_rad), ang.astype(np.float32), me, mn,
                   mw, None if lp.overexposure is None
                   else np.asarray(lp.overexposure, np.float32))


@dataclass(frozen=True)
class PointResult:
    """Everything a point's filter task returns.

    Attributes
    ----------
    point : int
    rows : list of dict
        One table row per run (columns of :mod:`starnav.batch.table`).
    epochs : (K,) array
    errors : (R, K, 6) array or None
        Estimation errors [m, m/s] per run.
    sigma3 : (R, K, 6) array or None
        3-sigma bounds [m, m/s] per run.
    limb_errors_px : (N,) float32
        Limb errors of every run, pooled.
    nees, nis : (R, K) arrays or None
        NEES of the 6 position-velocity states and NIS of each fix (NaN without one), per
        run and step.
    nees_position, nees_velocity : (R, K) arrays or None
        NEES of the position and of the velocity alone (3 dof each), per run and step.
    """

    point: int
    rows: list[dict[str, Any]]
    epochs: FloatArray
    errors: FloatArray | None
    sigma3: FloatArray | None
    limb_errors_px: NDArray[np.float32]
    nees: FloatArray | None = None
    nis: FloatArray | None = None
    nees_position: FloatArray | None = None
    nees_velocity: FloatArray | None = None


# ============================================================================ caches
_SCENARIOS: BoundedCache[str, Any] = BoundedCache(64)


def _key(config: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()


def _scenario(config: dict[str, Any]) -> Any:
    return _SCENARIOS.get_or_make(_key(config), lambda: scenario_from_dict(config))


# ============================================================================ tasks
def render_task(config: dict[str, Any], index: int) -> RenderedFrame:
    """Render frame ``index`` of the render configuration ``config`` (worker side).

    The renderer and the scene are built once per worker process and configuration
    (:func:`starnav.simulate.simulator_for`).
    """
    maker = simulator_for(config)
    t0 = time.perf_counter()
    geom, img = maker.render(int(index))
    dt = time.perf_counter() - t0
    le = np.asarray(img.Le, np.float32)
    nz_r = np.flatnonzero(le.any(axis=1))
    nz_c = np.flatnonzero(le.any(axis=0))
    if nz_r.size:
        r0, r1, c0, c1 = int(nz_r[0]), int(nz_r[-1]) + 1, int(nz_c[0]), int(nz_c[-1]) + 1
    else:
        r0 = r1 = c0 = c1 = 0
    return RenderedFrame(int(index), geom, tuple(le.shape), (r0, c0),  # type: ignore[arg-type]
                         np.ascontiguousarray(le[r0:r1, c0:c1]), dt,
                         str(img.meta.get("render", {}).get("variant", "")))


def expose_task(config: dict[str, Any], rendered: RenderedFrame, runs: int, windows: str,
                albedo_factor: float, first_run: int = 0) -> list[FrameResult]:
    """Every run of one point on one rendered frame (worker side; module docstring).

    Parameters
    ----------
    config : dict
        The point's resolved scenario (``navigation.attitude.source: assumed``; with
        ``stars`` the frames depend on each other: :func:`expose_sequence_task`).
    rendered : RenderedFrame
    runs : int
        Monte Carlo runs.
    windows : {"second", "same", "none"}
        Windows acquisition (:mod:`starnav.simulate.acquire`).
    albedo_factor : float
        Radiance multiplier of this point (downstream ``moon.albedo_scale``).
    first_run : int
        Number of the first run (runs ``first_run .. first_run + runs - 1``: a run's streams
        depend on its number only).
    """
    x = _Exposer(config, windows)
    if uses_star_attitude(x.sc):
        raise ConfigError("navigation.attitude.source", "stars", "expose_sequence_task (the "
                          "attitude of a frame depends on the frames before it)")
    le = rendered.electron_radiance(albedo_factor)
    return over_runs(lambda r: x.frame(le, rendered, r), run_ids(int(runs), int(first_run)))


def expose_sequence_task(config: dict[str, Any], rendered: list[RenderedFrame], runs: int,
                         windows: str, albedo_factor: float, first_run: int = 0
                         ) -> list[list[FrameResult]]:
    """Every run of one point on all its frames in time order (worker side): the task of a
    ``navigation.attitude.source: stars`` point, whose frame attitude comes from the star
    tracker of its run (:class:`~starnav.simulate.attitude.StarAttitudeTracker`: star
    acquisitions on the schedule, the navigation frame's stars, the gyro between them).

    Parameters are those of :func:`expose_task`, with ``rendered`` every frame of the point.

    Returns
    -------
    list (frames, in ``rendered`` order) of list (runs) of FrameResult
    """
    x = _Exposer(config, windows)
    ids = run_ids(int(runs), int(first_run))
    trackers = dict(zip(ids, over_runs(lambda r: StarAttitudeTracker(x.sim, r, x.sc), ids),
                        strict=True)) if uses_star_attitude(x.sc) else {}
    order = sorted(range(len(rendered)), key=lambda i: rendered[i].index)
    out: list[list[FrameResult]] = [[] for _ in rendered]
    for i in order:
        le = rendered[i].electron_radiance(albedo_factor)
        out[i] = over_runs(lambda r, i=i, le=le: x.frame(le, rendered[i], r, trackers.get(r)),
                           ids)
    return out


class _Exposer:
    """One point's per-frame work: acquisitions, the frame's attitude, the on-board chain."""

    def __init__(self, config: dict[str, Any], windows: str) -> None:
        self.sc = sc = _scenario(config)
        self.sim = simulator_for(config)
        self.windows = windows
        chain = chain_options(sc)
        self.chain = dataclasses.replace(chain,
                                         use_windows=chain.use_windows and windows != "none")
        self.solver = StarSolver(self.sim.camera, sc) if sc.stars.enabled else None
        # an emulated bench calibration per run (navigation.camera_calibration: bench)
        self.bench = sc.navigation.camera_calibration == "bench"
        self._calibrations: dict[int, Any] = {}

    def frame(self, le: NDArray[np.float32], rendered: RenderedFrame, r: int,
              tracker: StarAttitudeTracker | None = None) -> FrameResult:
        sc, sim, cam, g = self.sc, self.sim, self.sim.camera, rendered.geometry
        acq, frame = sim.observe(le, g, run=r, windows=self.windows)
        chain, att = self.chain, None
        if self.bench:
            if r not in self._calibrations:
                self._calibrations[r] = sc.navigation.calibration(sc, r)
            chain = dataclasses.replace(chain, calibration=self._calibrations[r])
        t0 = time.perf_counter()
        if tracker is not None:
            rec = tracker.step(le, g, acq, chain)
            frame, chain = with_attitude(frame, chain, rec)
            src, err, P = rec.source, rec.error_rad, rec.covariance_rad2
        else:
            src = "assumed"
            err = error_rotation(frame.R_cam_to_inertial_measured, g.R_cam_to_inertial)
            P = assumed_covariance(chain)
        if self.solver is not None:  # the attitude side of the exposure trade-off
            fa = frame_attitude_summary(self.solver.solve(acq.segments_exposure.dn, g), g)
            sig = np.sqrt(np.diag(P))
            att = {"source": src, **{f"frame_{k}": v for k, v in fa.items()},
                   **{f"error_{a}": float(e) for a, e in zip("xy", err[:2], strict=True)},
                   "error_roll": float(err[2]), "sigma_x": float(sig[0]),
                   "sigma_y": float(sig[1]), "sigma_roll": float(sig[2]),
                   "nees": float(err @ np.linalg.solve(P, err))}
        t_stars = time.perf_counter() - t0
        m = process_frame(frame, cam, options=chain,
                          rng=generator(sc.seed, STAGE_NAVIGATION, r, g.index))
        pts = m.points_used
        errs = (limb_point_errors(pts, cam, g, chain.fix.radii_m).astype(np.float32)
                if pts.size else np.empty(0, np.float32))
        e0 = acq.segments_exposure
        tm = {"render": rendered.render_s, "detector": acq.timings_s["detector"],
              "plan": acq.timings_s["plan"]}
        tm.update({k: float(v) for k, v in m.timings_s.items()})
        if att is not None:
            tm["stars"] = t_stars
        feasible = e0.feasible and (acq.windows_exposure is None or acq.windows_exposure.feasible)
        return FrameResult(
            index=int(g.index), run=r, epoch_tdb=float(g.epoch_tdb), status=m.status,
            position=m.position, covariance=m.covariance, limb_errors_px=errs,
            saturated_pixels=int(np.count_nonzero(
                e0.electrons >= sc.detector.saturation.full_well_e)),
            dn_max=int(e0.dn.max()) if e0.dn.size else 0, feasible=bool(feasible),
            plan_status=acq.plan_status, n_windows=len(acq.windows),
            truth_emb=None if g.camera_state_emb is None else np.asarray(g.camera_state_emb),
            range_m=float(g.range), timings_s=tm,
            points=LimbPointRecord.of(m, float(g.phase_angle), g.camera_position),
            common_jacobian=m.common_jacobian, white_covariance=m.white_covariance,
            attitude=att, consider_jacobian=m.consider_jacobian,
            consider_covariance=m.consider_covariance, common_scale=m.common_scale)


def attitude_columns(fr: list[FrameResult]) -> dict[str, Any]:
    """The attitude columns of one run (:data:`starnav.batch.table.STAR_COLUMNS`) from its
    frames' :attr:`FrameResult.attitude` [arcsec]; empty without stars."""
    a = [f.attitude for f in fr if f.attitude is not None]
    if not a or len(a) != len(fr):
        return {}

    def col(k: str) -> NDArray[np.float64]:
        return np.array([x[k] for x in a], float) / ARCSEC

    solved = np.array([x["frame_solved"] for x in a], bool)
    fx, fy, fr_ = col("frame_error_x"), col("frame_error_y"), col("frame_error_roll")
    sx, sy, sr = col("frame_sigma_x"), col("frame_sigma_y"), col("frame_sigma_roll")
    ex, ey, er = col("error_x"), col("error_y"), col("error_roll")

    def rms(x: NDArray[np.float64]) -> float:
        return float(np.sqrt(np.mean(x * x))) if x.size else math.nan

    return {
        "attitude_source": a[0]["source"] if all(x["source"] == "assumed" for x in a)
        else "stars",
        "attitude_solved_fraction": float(np.mean([x["source"] in ("star-frame",
                                                                    "navigation-frame")
                                                   for x in a])),
        "attitude_error_cross_rms_arcsec": rms(np.hypot(ex, ey)),
        "attitude_error_roll_rms_arcsec": rms(er),
        "attitude_sigma_cross_arcsec": float(np.mean(np.hypot(col("sigma_x"),
                                                              col("sigma_y")))),
        "attitude_sigma_roll_arcsec": float(np.mean(col("sigma_roll"))),
        "attitude_nees_mean": float(np.mean([x["nees"] for x in a])),
        "stars_detected_median": float(np.median([x["frame_stars_detected"] for x in a])),
        "stars_identified_median": float(np.median([x["frame_stars_identified"]
                                                    for x in a])),
        "frame_attitude_solved_fraction": float(np.mean(solved)),
        "frame_attitude_sigma_cross_arcsec": _median(list(np.hypot(sx, sy)[solved])),
        "frame_attitude_sigma_roll_arcsec": _median(list(sr[solved])),
        "frame_attitude_error_cross_rms_arcsec": rms(np.hypot(fx, fy)[solved]),
        "frame_attitude_error_roll_rms_arcsec": rms(fr_[solved]),
        "time_stars_s": _median([f.timings_s.get("stars", math.nan) for f in fr]),
    }


def _stats(x: NDArray[Any]) -> tuple[float, float, float, int]:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan, math.nan, 0
    std = float(x.std(ddof=1)) if x.size > 1 else 0.0
    return float(x.mean()), std, float(np.sqrt(np.mean(x * x))), int(x.size)


def _median(values: list[float]) -> float:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    return float(np.median(v)) if v.size else math.nan


def filter_task(config: dict[str, Any], point: int, frames: list[list[FrameResult]],
                runs: int) -> PointResult:
    """The EKF of every run of one point and its table rows (worker side).

    Parameters
    ----------
    config : dict
        The point's resolved scenario.
    point : int
        Point index.
    frames : list (frames) of list (runs) of FrameResult
    runs : int
    """
    sc = _scenario(config)
    nav = sc.navigation
    frames = sorted(frames, key=lambda fr: fr[0].index)
    K = len(frames)
    epochs = np.array([fr[0].epoch_tdb for fr in frames])
    has_truth = all(fr[0].truth_emb is not None for fr in frames)
    truth = np.array([fr[0].truth_emb for fr in frames]) if has_truth else None
    dyn = PointMassDynamics(step_s=nav.filter.rk4_step_s) if has_truth else None
    P0 = nav.initial_covariance()
    L0 = np.linalg.cholesky(P0)

    def one_run(r: int) -> tuple[dict[str, Any], NDArray[np.float32], list[FloatArray] | None]:
        """Run ``r``'s row, limb-point errors and filter series (errors, 3-sigma, NEES, NIS,
        position and velocity NEES; None without truth)."""
        fr_r = [fr[r] for fr in frames]
        limb = np.concatenate([f.limb_errors_px for f in fr_r]) if fr_r else np.empty(0)
        bias, std, rms, n_pts = _stats(limb)
        row: dict[str, Any] = {
            "point": int(point), "run": r, "frames": K,
            "fixes": sum(f.status == "ok" for f in fr_r),
            "windows_planned_fraction": float(np.mean([f.plan_status == "ok" for f in fr_r]))
            if fr_r else math.nan,
            "saturated_pixels_median": _median([float(f.saturated_pixels) for f in fr_r]),
            "dn_max": max((f.dn_max for f in fr_r), default=0),
            "readout_feasible": all(f.feasible for f in fr_r),
            "limb_points": n_pts, "limb_bias_px": bias, "limb_std_px": std,
            "limb_rms_px": rms,
        }
        nav_cols = dict.fromkeys(
            ("accepted", "final_position_error_m", "final_velocity_error_m_s",
             "final_position_error_pct_range", "final_velocity_error_pct_speed",
             "rms_position_error_m", "rms_velocity_error_m_s", "final_position_3sigma_m",
             "final_velocity_3sigma_m_s", "nees_mean", "nees_position_mean",
             "nees_velocity_mean"), math.nan)
        ekf_times: list[float] = []
        series = None
        if has_truth and dyn is not None and truth is not None and K:
            meas = [FrameMeasurement(f.index, f.epoch_tdb, f.status, position=f.position,
                                     covariance=f.covariance, common_jacobian=f.common_jacobian,
                                     white_covariance=f.white_covariance,
                                     consider_jacobian=f.consider_jacobian,
                                     consider_covariance=f.consider_covariance,
                                     common_scale=f.common_scale) for f in fr_r]
            x0 = truth[0] + L0 @ initial_error_normal(sc.seed, r)
            with quiet_logger("starnav.navigation.ekf"):
                res = run_filter(meas, dynamics=dyn, moon=dyn, t0=float(epochs[0]), x0=x0,
                                 P0=P0, options=nav.filter.to_si(),
                                 priors=nav.ekf_priors(nav.calibration(sc, r),
                                                       float(sc.detector.exposure_time_s)))
            series = [res.errors(truth), res.sigma3(), res.nees(truth), res.nis,
                      res.nees_position(truth), res.nees_velocity(truth)]
            ekf_times = [float(t) for t in res.timings_s]
            nm = NavMetrics.of(res, truth, fr_r[-1].range_m)
            nav_cols.update({k: getattr(nm, k) for k in nav_cols})
        row.update(nav_cols)
        row.update(attitude_columns(fr_r))
        for stage in TIMED_STAGES:
            vals = ekf_times if stage == "ekf" else [f.timings_s.get(stage, math.nan)
                                                     for f in fr_r]
            row[f"time_{stage}_s"] = _median(vals)
        return row, limb.astype(np.float32), series

    done = over_runs(one_run, run_ids(int(runs)))
    rows = [d[0] for d in done]
    limb_all = [d[1] for d in done]
    errs_all, s3_all, nees_all, nis_all, nees_p_all, nees_v_all = (
        [d[2][j] for d in done if d[2] is not None] for j in range(6))
    return PointResult(
        point=int(point), rows=rows, epochs=epochs,
        errors=np.array(errs_all) if errs_all else None,
        sigma3=np.array(s3_all) if s3_all else None,
        limb_errors_px=np.concatenate(limb_all) if limb_all else np.empty(0, np.float32),
        nees=np.array(nees_all) if nees_all else None,
        nis=np.array(nis_all) if nis_all else None,
        nees_position=np.array(nees_p_all) if nees_p_all else None,
        nees_velocity=np.array(nees_v_all) if nees_v_all else None)
