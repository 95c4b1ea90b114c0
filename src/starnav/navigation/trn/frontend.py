"""The fly-by front end: from a frame's segments and windows to a :class:`FlybyMeasurement`.

The seed paper's third algorithm (STAR Nav, asteroid fly-by, inspired by HERA) tracks features
on the asteroid among *windows* readings of the star tracker, frame by frame in the order the
tracker acquires:

1. :meth:`FlybyFrontEnd.plan` (segments acquisition): the lit body's centroid and apparent
   radius, each live track's predicted position, up to 16 windows
   (:mod:`~starnav.navigation.trn.windows`).
2. The caller's windows acquisition reads the planned windows.
3. :meth:`FlybyFrontEnd.track`: pyramidal LK from the previous frame's window, forward-backward
   check, epipolar RANSAC with the tracker's attitude (:mod:`~starnav.navigation.trn.features`),
   deaths and Shi-Tomasi births.

The front end sees the frame only through a
:class:`~starnav.navigation.trn.windows.WindowReader`; truth is attached afterwards
(:class:`~starnav.navigation.trn.truth.FeatureTruthBook`) and never read here. The knobs are
:class:`~starnav.navigation.trn.options.TrnFrontEndConfig` (calibrated ones:
``tools/calibrate_flyby_model_error.py``).

Index
-----
:class:`FlybyFrontEnd`, :class:`WindowPlan`, :class:`FrontEndFrame`,
:class:`Track`, :data:`STAGES`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from starnav.camera import Camera
from starnav.config_base import SIView
from starnav.navigation.trn.features import (
    detect_corners,
    epipolar_ransac,
    to_8bit,
    track_patch,
)
from starnav.navigation.trn.measurements import FeatureObservation, FlybyMeasurement
from starnav.navigation.trn.options import (
    BLOCK_PX,
    MIN_BODY_AREA_PX,
    RANSAC_ITERATIONS,
    TrnFrontEndConfig,
    patch_half_px,
    template_store_half_px,
)
from starnav.navigation.trn.windows import (
    BodyFix,
    WindowAccessError,
    WindowReader,
    WindowRect,
    analyse_segments,
    plan_windows,
)
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Front-end stages timed per frame (benchmarks/flyby.py).
STAGES = ("segments", "plan", "detect", "track", "reject")


@dataclass
class Track:
    """A live track (front-end state)."""

    track_id: int
    uv: FloatArray
    window: int
    age: int = 0
    step_rel: FloatArray = field(default_factory=lambda: np.zeros(2))
    turned: float = 0.0
    predicted: FloatArray | None = None
    patch: NDArray[np.uint16] | None = None
    patch_corner: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class WindowPlan:
    """What :meth:`FlybyFrontEnd.plan` decided for one frame."""

    index: int
    epoch_tdb: float
    R_cam_to_inertial: FloatArray
    attitude_sigma: FloatArray
    body: BodyFix | None
    windows: tuple[WindowRect, ...]
    status: str
    timings_s: dict[str, float]


@dataclass(frozen=True)
class FrontEndFrame:
    """One frame of the front end: the measurement and its book-keeping.

    Attributes
    ----------
    measurement : FlybyMeasurement
    status : str
        ``ok``, ``no-body`` (no lit body in the segments: empty measurement, every track
        ended) or ``no-windows``.
    counts : dict
        ``tracked``, ``born``, and deaths by cause (``lost`` LK/forward-backward, ``left``
        the window, ``limb``, ``outlier`` epipolar, ``aged`` past ``max_track_turn``).
    timings_s : dict
        Wall time of each stage of :data:`STAGES` [s].
    window_pixels : int
        Pixels of the windows readout (its ``N_pix`` in the readout law).
    """

    measurement: FlybyMeasurement
    status: str
    counts: dict[str, int]
    timings_s: dict[str, float]
    window_pixels: int


class FlybyFrontEnd:
    """Stateful fly-by front end (module docstring): call :meth:`plan` then :meth:`track` for
    every frame, in time order.

    Parameters
    ----------
    camera : Camera
        For the lines of sight of the epipolar test.
    options : SIView, optional
        The SI view of a :class:`~starnav.navigation.trn.options.TrnFrontEndConfig`
        (``to_si()``); default its defaults.
    rng : numpy Generator, optional
        RANSAC draws (default ``default_rng(0)``).
    """

    def __init__(self, camera: Camera, options: SIView | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.camera = camera
        self.options = options if options is not None else TrnFrontEndConfig().to_si()
        self._patch_half = patch_half_px(self.options)
        self._store_half = template_store_half_px(self.options)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.tracks: list[Track] = []
        self._next_id = 0
        self._prev_body: BodyFix | None = None
        self._prev_R: FloatArray | None = None
        self._centroid_step = np.zeros(2)

    # ------------------------------------------------------------------ plan
    def plan(self, reader: WindowReader, *, index: int, epoch_tdb: float,
             R_cam_to_inertial: FloatArray, attitude_sigma: FloatArray | None = None
             ) -> WindowPlan:
        """Segments analysis and window plan of frame ``index`` (module step 1).

        ``R_cam_to_inertial`` is the tracker's *measured* attitude, ``attitude_sigma`` its
        1-sigma about the camera axes [rad].
        """
        o = self.options
        t0 = time.perf_counter()
        body = analyse_segments(reader, block_px=BLOCK_PX, min_area_px=MIN_BODY_AREA_PX)
        t1 = time.perf_counter()
        sig = np.zeros(3) if attitude_sigma is None else np.asarray(attitude_sigma, float)
        R = np.asarray(R_cam_to_inertial, float)
        if body is None:
            return WindowPlan(index, float(epoch_tdb), R, sig, None, (), "no-body",
                              {"segments": t1 - t0, "plan": 0.0})
        # predicted positions: centroid motion + the track's last motion relative to it
        step_c = (body.centroid_uv - self._prev_body.centroid_uv
                  if self._prev_body is not None else np.zeros(2))
        groups: dict[int, list[FloatArray]] = {}
        for tr in self.tracks:
            tr.predicted = tr.uv + step_c + tr.step_rel
            groups.setdefault(tr.window, []).append(tr.predicted)
        self._centroid_step = step_c
        order = sorted(groups)
        rects = plan_windows(body, [np.array(groups[k]) for k in order],
                             n_windows=o.n_windows, core_px=o.core_px,
                             patch_half_px=self._patch_half, limb_margin_px=o.limb_margin_px,
                             max_window_px=o.max_window_px)
        t2 = time.perf_counter()
        return WindowPlan(index, float(epoch_tdb), R, sig, body, tuple(rects),
                          "ok" if rects else "no-windows",
                          {"segments": t1 - t0, "plan": t2 - t1})

    # ------------------------------------------------------------------ track
    def _crop_patch(self, reader: WindowReader, uv: FloatArray, h: int
                    ) -> tuple[NDArray[np.uint16], tuple[int, int]] | None:
        u0, v0 = int(round(uv[0])) - h, int(round(uv[1])) - h
        try:
            return reader.crop(v0, u0, 2 * h + 1, 2 * h + 1), (v0, u0)
        except WindowAccessError:  # the patch left the windows read
            return None

    def _window_of(self, windows: tuple[WindowRect, ...], uv: FloatArray) -> int:
        h = self._store_half
        for k, (r0, c0, hh, ww) in enumerate(windows):
            # the rounded centre keeps the whole stored template inside the window
            if (c0 + h + 0.5 <= uv[0] <= c0 + ww - 1.5 - h
                    and r0 + h + 0.5 <= uv[1] <= r0 + hh - 1.5 - h):
                return k
        return -1

    def track(self, reader: WindowReader, plan: WindowPlan) -> FrontEndFrame:
        """Track, reject, end and start tracks in this frame's windows (module step 3)."""
        o = self.options
        counts = {"tracked": 0, "born": 0, "lost": 0, "left": 0, "limb": 0, "outlier": 0,
                  "aged": 0}
        timings = dict(plan.timings_s)
        body = plan.body
        windows = reader.windows
        if body is None or not windows:
            counts["lost"] = len(self.tracks)
            self.tracks = []
            self._prev_body, self._prev_R = body, plan.R_cam_to_inertial
            for s in STAGES[2:]:
                timings[s] = 0.0
            meas = self._measurement(plan, body, windows, reader)
            return FrontEndFrame(meas, "no-body" if body is None else "no-windows", counts,
                                 timings, reader.window_pixels())
        lo_hi = body.dn_range
        # ---- LK from the previous frame's patches
        t0 = time.perf_counter()
        moved: list[tuple[Track, FloatArray]] = []
        for tr in self.tracks:
            assert tr.predicted is not None and tr.patch is not None
            got = self._crop_patch(reader, tr.predicted, self._patch_half)
            if got is None:
                counts["left"] += 1
                continue
            nxt, (nr0, nc0) = got
            # the stored template, padded (edge copies, outside the LK window) to the size of
            # the search patch: OpenCV's LK takes two images of one size
            pad = self._patch_half - self._store_half
            prev = cv2.copyMakeBorder(to_8bit(tr.patch, lo_hi), pad, pad, pad, pad,
                                      cv2.BORDER_REPLICATE)
            pr0, pc0 = tr.patch_corner
            p_prev = tr.uv - [pc0 - pad, pr0 - pad]
            p_init = tr.predicted - [nc0, nr0]
            p, _, _ = track_patch(prev, to_8bit(nxt, lo_hi), p_prev, p_init,
                                  template_half_px=o.template_half_px, fb_max_px=o.fb_max_px)
            if p is None:
                counts["lost"] += 1
                continue
            moved.append((tr, p + [nc0, nr0]))
        t1 = time.perf_counter()
        # ---- epipolar RANSAC with the measured attitudes
        survivors: list[Track] = []
        if moved:
            uv_prev = np.array([tr.uv for tr, _ in moved])
            uv_cur = np.array([p for _, p in moved])
            assert self._prev_R is not None
            R = plan.R_cam_to_inertial.T @ self._prev_R
            turn = math.acos(min(max((np.trace(R) - 1.0) / 2.0, -1.0), 1.0))
            inl, _ = epipolar_ransac(self.camera.unproject(uv_prev), self.camera.unproject(uv_cur),
                                     R, o.epipolar_px / self.camera.fx, RANSAC_ITERATIONS,
                                     self.rng)
            for (tr, p), ok in zip(moved, inl, strict=True):
                if not ok:
                    counts["outlier"] += 1
                    continue
                k = self._window_of(windows, p)
                if k < 0:
                    counts["left"] += 1
                    continue
                if body.clearance[int(round(p[1])), int(round(p[0]))] < o.limb_margin_px:
                    counts["limb"] += 1
                    continue
                if tr.turned + turn > o.max_track_turn:
                    counts["aged"] += 1
                    continue
                step = p - tr.uv
                tr.step_rel = step - self._centroid_step
                tr.uv, tr.window, tr.age, tr.turned = p, k, tr.age + 1, tr.turned + turn
                survivors.append(tr)
        t2 = time.perf_counter()
        counts["tracked"] = len(survivors)
        # ---- births in windows with too few tracks
        per_window = np.zeros(len(windows), int)
        for tr in survivors:
            per_window[tr.window] += 1
        h = self._patch_half
        for k, (r0, c0, hh, ww) in enumerate(windows):
            need = o.max_tracks_per_window - per_window[k]
            if per_window[k] >= o.min_tracks_per_window or need <= 0:
                continue
            dn = reader.crop(r0, c0, hh, ww)
            allowed = np.zeros((hh, ww), bool)
            allowed[h:hh - h, h:ww - h] = True
            allowed &= body.clearance[r0:r0 + hh, c0:c0 + ww] >= o.limb_margin_px + 1.0
            for tr in survivors:
                if tr.window == k:
                    du, dv = tr.uv[0] - c0, tr.uv[1] - r0
                    vv, uu = np.ogrid[0:hh, 0:ww]
                    allowed &= (uu - du) ** 2 + (vv - dv) ** 2 >= o.min_distance_px ** 2
            pts = detect_corners(dn, allowed, max_corners=int(need), quality=o.quality,
                                 min_distance_px=o.min_distance_px, block_px=BLOCK_PX)
            for q in pts:
                survivors.append(Track(self._next_id, q + [c0, r0], k))
                self._next_id += 1
                counts["born"] += 1
        t3 = time.perf_counter()
        # ---- keep this frame's patches (read now: the next frame has other windows)
        for tr in survivors:
            got = self._crop_patch(reader, tr.uv, self._store_half)
            assert got is not None  # inside its window by construction
            tr.patch, tr.patch_corner = got
        self.tracks = survivors
        self._prev_body, self._prev_R = body, plan.R_cam_to_inertial
        timings.update({"detect": t3 - t2, "track": t1 - t0, "reject": t2 - t1})
        meas = self._measurement(plan, body, windows, reader)
        return FrontEndFrame(meas, "ok", counts, timings, reader.window_pixels())

    def _measurement(self, plan: WindowPlan, body: BodyFix | None,
                     windows: tuple[WindowRect, ...], reader: WindowReader) -> FlybyMeasurement:
        o = self.options
        feats = tuple(FeatureObservation(
            track_id=tr.track_id, uv=np.array(tr.uv, float),
            sigma_px=o.correlation_factor * math.hypot(o.sigma_detect_px,
                                                       o.drift_px_per_rad * tr.turned),
            window=tr.window) for tr in self.tracks)
        H, W = reader.shape
        return FlybyMeasurement(
            frame_index=plan.index, epoch_tdb=plan.epoch_tdb,
            R_cam_to_inertial=plan.R_cam_to_inertial, attitude_sigma=plan.attitude_sigma,
            features=feats,
            centroid_uv=None if body is None else body.centroid_uv.copy(),
            centroid_sigma_px=(1.0 if body is None
                               else max(o.centroid_sigma_fraction * body.radius_px, 0.1)),
            apparent_radius_px=None if body is None else body.radius_px,
            apparent_radius_sigma_px=(1.0 if body is None
                                      else max(o.radius_sigma_fraction * body.radius_px, 0.1)),
            windows=tuple(windows),
            pixels_read=int(H * W + reader.window_pixels()))
