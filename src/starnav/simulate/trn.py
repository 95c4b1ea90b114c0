"""The fly-by front end on rendered frames: acquisitions in the tracker's order, then truth.

For each frame of a fly-by scenario:

1. render (radiance with the body-fixed AOVs);
2. **acquisition 0, segments**, handed to :meth:`FlybyFrontEnd.plan
   <starnav.navigation.trn.frontend.FlybyFrontEnd.plan>` with the frame's *measured* attitude;
3. **acquisition 1, windows**: a second exposure of the same radiance reads the planned
   windows (readout law checked on the window pixels);
4. :meth:`~starnav.navigation.trn.frontend.FlybyFrontEnd.track` on the two readout
   *products* (never the full DN frame);
5. truth from the AOVs (:class:`~starnav.navigation.trn.truth.FeatureTruthBook`).

Frame budget (:func:`flyby_frame_budget`): two acquisitions, each an exposure then its readout
(seed paper eq. 1), without overlap: a cadence ``T`` is allowed when
``2 t_exp + t_segments + t_windows(n_windows x max_window_px^2) <= T``.

Noise streams: :func:`starnav.simulate.acquire.acquisition_seed`; RANSAC:
``generator(seed, STAGE_NAVIGATION, run, 0, TRN_STREAM)`` for the whole (stateful) sequence.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from starnav.camera import camera_from_config
from starnav.config_base import SIView
from starnav.detector import Exposure, expose
from starnav.detector.readout import ReadoutTiming, min_exposure
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.navigation.trn.frontend import FlybyFrontEnd, FrontEndFrame
from starnav.navigation.trn.truth import FeatureTruthBook
from starnav.navigation.trn.windows import WindowReader
from starnav.radiance import RadianceImage
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate.acquire import acquisition_seed, quiet_timing, sensor_seed_of
from starnav.simulate.frames import Simulator

#: Last key of the fly-by front end's RANSAC stream (never change).
TRN_STREAM = 16


@dataclass(frozen=True)
class FrameBudget:
    """The tracker's time budget of one fly-by frame (module essay), SI.

    Attributes
    ----------
    cadence : float
        Time between frames [s].
    exposure : float
        One acquisition's exposure [s] (both acquisitions use it).
    segments_readout : float
        The readout law's time of the segments scan of the whole array [s].
    windows_readout : float
        The readout law's time of the largest windows read the front end may plan:
        ``n_windows`` windows of ``max_window_px`` squared [s].
    n_windows, max_window_px : int
    """

    cadence: float
    exposure: float
    segments_readout: float
    windows_readout: float
    n_windows: int
    max_window_px: int

    @property
    def frame_time(self) -> float:
        """Both acquisitions, exposure then readout each, at the most windows [s]."""
        return 2.0 * self.exposure + self.segments_readout + self.windows_readout

    @property
    def fits(self) -> bool:
        return self.frame_time <= self.cadence * (1.0 + 1e-12)

    def to_dict(self) -> dict[str, float | int | bool]:
        return {"cadence_s": self.cadence, "exposure_s": self.exposure,
                "segments_readout_s": self.segments_readout,
                "windows_readout_max_s": self.windows_readout, "n_windows": self.n_windows,
                "max_window_px": self.max_window_px, "frame_time_s": self.frame_time,
                "fits": self.fits}


def flyby_frame_budget(sc: Any) -> FrameBudget:
    """The frame budget of fly-by scenario ``sc`` (module essay); with the readout law's
    policy ``enforce`` a cadence shorter than the frame time is one :class:`ConfigError`."""
    det = sc.detector
    timing = det.readout.timing
    fe = sc.navigation.trn.front_end
    cam = camera_from_config(sc.camera)
    shape = (cam.height, cam.width)
    budget = FrameBudget(
        cadence=float(sc.trajectory.cadence_s), exposure=float(det.exposure_time_s),
        segments_readout=min_exposure(shape[0] * shape[1], timing, full_frame=True),
        windows_readout=min_exposure(fe.n_windows * fe.max_window_px**2, timing),
        n_windows=int(fe.n_windows), max_window_px=int(fe.max_window_px))
    if timing.policy == "enforce" and not budget.fits:
        raise ConfigError("trajectory.cadence_s", budget.cadence,
                          f">= {budget.frame_time:.4g} s, the tracker's frame time (2 exposures "
                          f"of {budget.exposure:.3g} s, segments {budget.segments_readout:.4g} "
                          f"s, {budget.n_windows} windows {budget.windows_readout:.4g} s)")
    return budget


@dataclass(frozen=True)
class FlybyStep:
    """One frame of :func:`track_flyby`.

    Attributes
    ----------
    frame : FrontEndFrame
        The front end's output; ``frame.measurement.truth`` is filled.
    readout : tuple of ReadoutTiming
        Readout-law check of the segments and (when windows were read) windows acquisitions.
    geometry : FrameGeometry
        The frame's truth.
    timings_s : dict
        Wall time of the frame's ``detector`` (both acquisitions) and ``front_end`` (plan
        and track) [s].
    """

    frame: FrontEndFrame
    readout: tuple[ReadoutTiming, ...]
    geometry: FrameGeometry
    timings_s: dict[str, float] = field(default_factory=dict)


def flyby_exposures(sim: Simulator, img: RadianceImage, geom: FrameGeometry, front_end:
                    FlybyFrontEnd, *, run: int = 0, R_measured: Any = None,
                    timings: dict[str, float] | None = None
                    ) -> tuple[Exposure, Exposure | None, Any, WindowReader]:
    """Acquisitions 0 and 1 of one frame (module steps 2-3): ``(segments exposure, windows
    exposure or None, plan, reader)``; the reader holds the segments and the windows read
    (their readout products only) and records every pixel the front end took from it.
    ``R_measured``: the tracker's measured attitude (default the frame's own knowledge draw);
    ``timings``: filled with the ``detector`` and ``plan`` wall times [s]."""
    sc = sim.scenario
    cfg = quiet_timing(sc.detector).model_copy(update={"sensor_seed": sensor_seed_of(sc)})
    cfg0 = cfg.model_copy(update={"readout": cfg.readout.model_copy(
        update={"windows": (), "modes": ("segments",)})})
    index = int(geom.index)
    R = geom.R_cam_to_inertial_known if R_measured is None else R_measured
    t0 = time.perf_counter()
    e0 = expose(img, sim.camera, cfg0, seed=acquisition_seed(sc.seed, run, 0),
                frame_index=index, windows=())
    t1 = time.perf_counter()
    reader = WindowReader.from_exposures(e0)
    plan = front_end.plan(reader, index=index, epoch_tdb=geom.epoch_tdb,
                          R_cam_to_inertial=R, attitude_sigma=sc.pointing.knowledge_sigma)
    t2 = time.perf_counter()
    e1 = None
    if plan.windows:
        cfg1 = cfg.model_copy(update={"readout": cfg.readout.model_copy(
            update={"modes": ("windows",), "windows": ()})})
        e1 = expose(img, sim.camera, cfg1, seed=acquisition_seed(sc.seed, run, 1),
                    frame_index=index, windows=plan.windows)
        reader = reader.with_windows(e1.windows)
    if timings is not None:
        timings["detector"] = (t1 - t0) + (time.perf_counter() - t2)
        timings["plan"] = t2 - t1
    return e0, e1, plan, reader


def track_flyby(sim: Simulator, frames: Iterable[int] | None = None, *,
                options: SIView | None = None, run: int = 0,
                renders: Sequence[tuple[FrameGeometry, RadianceImage]] | None = None,
                attitude: Callable[[FrameGeometry], Any] | None = None
                ) -> list[FlybyStep]:
    """Run the fly-by front end over frames of ``sim``'s scenario (module steps 1-5).

    Parameters
    ----------
    sim : Simulator
        A fly-by scenario (``target.kind: shape_model``, ``trajectory.source: flyby``).
    frames : iterable of int, optional
        Frame indices in time order; default every frame.
    options : SIView, optional
        Front-end settings (a ``TrnFrontEndConfig``'s ``to_si()``); default the scenario's
        ``navigation.trn.front_end``.
    run : int
        Monte Carlo run (detector noise streams).
    renders : sequence of (FrameGeometry, RadianceImage), optional
        Frames already rendered (``frames`` is then ignored).
    attitude : callable, optional
        ``attitude(geometry) -> (3, 3)`` the tracker's measured attitude of a frame (a Monte
        Carlo run's draw); default the frame's own knowledge draw.

    Returns
    -------
    list of FlybyStep
    """
    sc = sim.scenario
    opts = options if options is not None else sc.navigation.trn.front_end.to_si()
    fe = FlybyFrontEnd(sim.camera, opts,
                       rng=generator(sc.seed, STAGE_NAVIGATION, run, 0, TRN_STREAM))
    book = FeatureTruthBook(sim.camera)
    if renders is None:
        idx = range(len(sim)) if frames is None else frames
        source: Iterable[tuple[FrameGeometry, RadianceImage]] = (sim.render(i) for i in idx)
    else:
        source = renders
    out = []
    for geom, img in source:
        tm: dict[str, float] = {}
        e0, e1, plan, reader = flyby_exposures(
            sim, img, geom, fe, run=run, timings=tm,
            R_measured=None if attitude is None else attitude(geom))
        t0 = time.perf_counter()
        res = fe.track(reader, plan)
        tm["front_end"] = tm.pop("plan") + time.perf_counter() - t0
        meas = book.annotate(res.measurement, geom, img.aovs, img.mask)
        res = FrontEndFrame(meas, res.status, res.counts, res.timings_s, res.window_pixels)
        timing = tuple(e0.timing) + (tuple(e1.timing) if e1 is not None else ())
        out.append(FlybyStep(res, timing, geom, tm))
    return out
