"""The asteroid fly-by closed loop on rendered frames over Monte Carlo runs (model in the loop).

1. Render every frame once (:func:`starnav.simulate.flyby.render_flyby`); every run reuses
   the radiance.
2. Per run ``r`` (:func:`flyby_run`, through :func:`starnav.batch.runs.over_runs`): the
   measured attitude (run 0 the frame's own draw), the tracker's acquisitions and front end
   (:func:`starnav.simulate.trn.track_flyby`), the estimator
   (:func:`~starnav.navigation.trn.filter.run_filter`) from the truth plus an initial draw,
   the metrics against the truth. With ``navigation.trn.dispersion: orientation`` each run
   draws the fly-by's orientation and renders its own frames (:func:`flyby_dispersed_runs`).
3. Consistency over the runs (:func:`~starnav.navigation.trn.metrics.summarise_runs`).

The sweep over fly-by geometries is :mod:`starnav.batch.flyby_sweep`.

Index
-----
:func:`flyby_closed_loop`, :class:`FlybyClosedLoop`, :func:`flyby_run`,
:class:`FlybyRunResult`, :func:`initial_state`, :func:`estimator_body`,
:func:`flyby_dispersed_runs`; :func:`navigate_flyby`, :func:`navigate_flyby_dataset`,
:func:`plot_overlays`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from starnav.atomic import atomic_write_text
from starnav.batch.runs import over_runs, run_ids
from starnav.bodies.base import TargetBody
from starnav.bodies.small_body import ShapeModelBody
from starnav.config import Scenario
from starnav.config_base import SIView
from starnav.dataset.flyby import read_flyby
from starnav.errors import ConfigError, GeometryError
from starnav.navigation.trn.body_model import EstimatorModel, estimator_model
from starnav.navigation.trn.filter import FlybyRun, run_filter
from starnav.navigation.trn.measurements import FlybyMeasurement
from starnav.navigation.trn.metrics import (
    FLYBY_AXES,
    FlybyMetrics,
    closest_approach_index,
    errors_in_flyby_frame,
    plot_flyby_errors,
    plot_flyby_nees,
    plot_frame_overlay,
    plot_tracks,
    predicted_silhouette,
    summarise_runs,
    tracker_budget,
    write_report,
)
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate.build import body_from_scenario
from starnav.simulate.flyby import (
    Renders,
    check_flyby_scenario,
    dispersed_flyby,
    render_flyby,
    segments_image,
)
from starnav.simulate.frames import Simulator
from starnav.simulate.trn import FlybyStep, flyby_frame_budget, track_flyby
from starnav.typing import FloatArray

#: Last key of a run's initial-error stream ``(seed, STAGE_NAVIGATION, run, 0, 17)`` (never
#: change; 16 is the front end's RANSAC, :data:`starnav.simulate.trn.TRN_STREAM`).
INITIAL_ERROR_STREAM = 17


#: Last key of a run's draw of the coarse shape model's scale error ``(seed,
#: STAGE_NAVIGATION, run, 0, 19)`` under ``navigation.trn.shape_model.map: coarse`` (never
#: change).
SHAPE_SCALE_STREAM = 19


@dataclass
class FlybyRunResult:
    """One Monte Carlo run of the closed loop.

    Attributes
    ----------
    run : int
    filter : FlybyRun
    measurements : list of FlybyMeasurement
        The front end's output, truth attached (metrics only).
    metrics : FlybyMetrics
    steps : list of FlybyStep
        The front end's book-keeping per frame (counts, readout checks, geometry).
    timings_s : dict
        Wall time of this run per stage summed over the frames [s]: ``detector``,
        ``front_end``, ``filter``.
    memory_bytes : dict or None
        With ``memory=True``: the peak traced Python heap [bytes] of ``front_end`` (the
        acquisitions and the front end of every frame, detector included) and ``filter``
        over the pass, above what was allocated before (an upper bound of one frame's).
    """

    run: int
    filter: FlybyRun
    measurements: list[FlybyMeasurement]
    metrics: FlybyMetrics
    steps: list[FlybyStep]
    timings_s: dict[str, float]
    memory_bytes: dict[str, float] | None = None


@dataclass
class FlybyClosedLoop:
    """The closed loop of a fly-by scenario over its Monte Carlo runs.

    Attributes
    ----------
    epochs : (K,) array [TDB s]
    epoch_ca : float [TDB s]
    truth : (K, 6) array
        True ``(r, v)`` relative to the body, J2000 [m, m/s] (the first run's when dispersed).
    runs : list of FlybyRunResult
    summary : dict
        :func:`~starnav.navigation.trn.metrics.summarise_runs` (for >= 2 runs), else the
        single run's NEES.
    timings_s : dict
        Per-frame wall time of each stage (``render``, ``detector``, ``front_end``,
        ``filter``), mean over frames and runs [s].
    dispersion : str
        ``navigation.trn.dispersion`` of the runs (``none`` or ``orientation``).
    run_truths, draws, run_axes : lists, optional
        When dispersed: each run's true states (J2000), drawn orientation
        (:func:`dispersed_flyby`) and fly-by frame (rows: CA direction, CA velocity, normal).
    first : (Simulator, renders), optional
        The first run's simulator and frames when dispersed (overlays, memory budget).
    """

    epochs: FloatArray
    epoch_ca: float
    truth: FloatArray
    runs: list[FlybyRunResult]
    summary: dict[str, Any]
    timings_s: dict[str, float] = field(default_factory=dict)
    dispersion: str = "none"
    run_truths: list[FloatArray] | None = None
    draws: list[dict[str, float]] | None = None
    run_axes: list[FloatArray] | None = None
    first: tuple[Simulator, Renders] | None = None

    @property
    def time_from_ca(self) -> FloatArray:
        """Frame epochs relative to closest approach [s]."""
        return self.epochs - self.epoch_ca

    def truth_of(self, k: int) -> FloatArray:
        """True states ``(K, 6)`` of the ``k``-th run in :attr:`runs` [m, m/s]."""
        return self.truth if self.run_truths is None else self.run_truths[k]


def estimator_body(sc: Scenario, run: int, truth: ShapeModelBody) -> EstimatorModel:
    """Run ``run``'s body model (``navigation.trn.shape_model``,
    :func:`~starnav.navigation.trn.body_model.estimator_model`): the scale error's unit draw
    is on the stream ``generator(seed, STAGE_NAVIGATION, run, 0, SHAPE_SCALE_STREAM)``."""
    g = generator(int(sc.seed), STAGE_NAVIGATION, int(run), 0, SHAPE_SCALE_STREAM)
    return estimator_model(truth, sc.navigation.trn.shape_model, float(g.standard_normal()))


def check_estimator_body(sc: Scenario) -> None:
    """Build the estimator's body model once (``navigation.trn.shape_model``; cached), so that
    a setting it refuses is one error before any rendering."""
    truth = body_from_scenario(sc)
    if isinstance(truth, ShapeModelBody):
        estimator_body(sc, 0, truth)


def initial_state(truth0: FloatArray, P0: FloatArray, seed: int, run: int) -> FloatArray:
    """Run ``run``'s initial estimate: the first true state plus a draw from ``P0`` (module
    step 2c)."""
    L = np.linalg.cholesky(np.asarray(P0, float))
    g = generator(int(seed), STAGE_NAVIGATION, int(run), 0, INITIAL_ERROR_STREAM)
    return np.asarray(truth0, float) + L @ g.standard_normal(6)


def flyby_run(sim: Simulator, renders: Renders, run: int, *,
              front_end: SIView | None = None,
              filter_options: SIView | None = None,
              initial_covariance: FloatArray | None = None,
              body: TargetBody | None = None, memory: bool = False) -> FlybyRunResult:
    """One run of the closed loop on frames already rendered (module step 2); ``body``: the
    truth's body (default read from the scenario; the estimator's own model is
    :func:`estimator_body`); with ``memory`` the peak traced memory of the front end and of
    the filter (tracemalloc: slower, the run's timings are then not representative)."""
    sc = sim.scenario
    check_flyby_scenario(sc)
    trn = sc.navigation.trn
    fe = front_end if front_end is not None else trn.front_end.to_si()
    fo = filter_options if filter_options is not None else trn.filter.to_si()
    P0 = (trn.filter.initial_covariance() if initial_covariance is None
          else np.asarray(initial_covariance, float))
    body = body if body is not None else body_from_scenario(sc)
    assert isinstance(body, ShapeModelBody)  # check_flyby_scenario
    model = estimator_body(sc, run, body)
    truth = sim.scene.relative_states
    flyby = sim.scene.flyby
    assert flyby is not None  # check_flyby_scenario
    sun = np.asarray(flyby.sun_direction, float)
    mem: dict[str, float] | None = None
    if memory:
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
    steps = track_flyby(sim, renders=renders, options=fe, run=run,
                        attitude=lambda g: sim.measured_attitude(g, run))
    if memory:
        cur, peak = tracemalloc.get_traced_memory()
        mem = {"front_end": float(peak - base)}
        tracemalloc.reset_peak()
        base = cur
    meas = [dataclasses.replace(s.frame.measurement, sun_direction=sun.copy()) for s in steps]
    idx = [int(s.geometry.index) for s in steps]
    X = truth[idx]
    x0 = initial_state(X[0], P0, sc.seed, run)
    t0 = time.perf_counter()
    res = run_filter(meas, sim.camera, model.body, x0, P0, fo, prior=model.prior)
    res.info["shape_model"] = model.info
    t_filter = time.perf_counter() - t0
    if memory:
        assert mem is not None
        mem["filter"] = float(tracemalloc.get_traced_memory()[1] - base)
        tracemalloc.stop()
    metrics = FlybyMetrics.of(res, meas, X, float(flyby.epoch_ca))
    timings = {"detector": float(sum(s.timings_s["detector"] for s in steps)),
               "front_end": float(sum(s.timings_s["front_end"] for s in steps)),
               "filter": t_filter}
    return FlybyRunResult(run, res, meas, metrics, steps, timings, mem)


def flyby_closed_loop(sim: Simulator, runs: int = 1, *, renders: Renders | None = None,
                      front_end: SIView | None = None,
                      filter_options: SIView | None = None,
                      initial_covariance: FloatArray | None = None,
                      probability: float = 0.99, first_run: int = 0,
                      progress: Callable[[str, int, int], None] | None = None
                      ) -> FlybyClosedLoop:
    """The fly-by closed loop of ``sim``'s scenario over ``runs`` Monte Carlo runs (module
    essay): render once (unless ``renders`` are given), then runs ``first_run ...
    first_run + runs - 1``.

    Parameters
    ----------
    sim : Simulator
        A fly-by scenario.
    runs : int
        Monte Carlo runs (>= 1; consistency is judged from 2 on).
    renders : sequence of (FrameGeometry, RadianceImage), optional
        Every frame of the scenario already rendered, in order.
    front_end, filter_options : optional
        Default the scenario's ``navigation.trn`` sections.
    initial_covariance : (6, 6) array, optional
        Default ``navigation.trn.filter.initial_covariance()``.
    probability : float
        Two-sided probability of the NEES band.
    progress : callable, optional
        ``progress(stage, done, total)`` with stage ``render`` or ``runs``.
    """
    check_flyby_scenario(sim.scenario)
    check_estimator_body(sim.scenario)
    ids = run_ids(runs, first_run)
    if not 0.0 < probability < 1.0:
        raise ConfigError("probability", probability, "in (0, 1)")
    runs_progress = None if progress is None else (lambda d, n: progress("runs", d, n))
    if sim.scenario.navigation.trn.dispersion == "orientation":
        if renders is not None:
            raise ConfigError("navigation.trn.dispersion", "orientation",
                              "'none' when the frames are given (a dataset's, or rendered "
                              "once): a dispersed run renders its own fly-by")
        return flyby_dispersed_runs(sim.scenario, ids, front_end=front_end,
                                    filter_options=filter_options,
                                    initial_covariance=initial_covariance,
                                    probability=probability, progress=runs_progress)
    t_render = float("nan")
    if renders is None:
        renders, t_render = render_flyby(
            sim, None if progress is None else (lambda d, n: progress("render", d, n)))
    elif len(renders) != len(sim):
        raise ConfigError("renders", len(renders), f"every frame of the scenario ({len(sim)})")
    body = body_from_scenario(sim.scenario)
    out = over_runs(lambda r: flyby_run(sim, renders, r, front_end=front_end,
                                        filter_options=filter_options,
                                        initial_covariance=initial_covariance, body=body),
                    ids, progress=runs_progress)
    return _closed_loop(sim, len(renders), out, sim.scene.relative_states, t_render,
                        probability)


def _closed_loop(sim: Simulator, K: int, out: list[FlybyRunResult],
                 truth: FloatArray | list[FloatArray], t_render: float, probability: float,
                 **dispersed: Any) -> FlybyClosedLoop:
    """The runs ``out`` of ``sim``'s fly-by (``K`` frames each; ``truth`` shared or one per
    run) as a :class:`FlybyClosedLoop`: the verdict (module step 3) and the per-frame timings
    (``t_render`` per frame [s]); ``dispersed``: the dispersed runs' fields."""
    flyby = sim.scene.flyby
    assert flyby is not None  # check_flyby_scenario
    epochs = np.asarray(sim.scene.epochs, float)
    summary = summarise_runs([r.filter for r in out], [r.metrics for r in out], truth, epochs,
                             float(flyby.epoch_ca), probability)
    summary["dispersion"] = dispersed.get("dispersion", "none")
    timings = {"render": t_render}
    for stage in ("detector", "front_end", "filter"):
        timings[stage] = float(np.mean([r.timings_s[stage] for r in out])) / K
    X = truth[0] if dispersed else truth
    return FlybyClosedLoop(epochs, float(flyby.epoch_ca), X, out, summary,  # type: ignore[arg-type]
                           timings, **dispersed)


def flyby_dispersed_runs(base: Scenario, runs: range, *,
                         front_end: SIView | None = None,
                         filter_options: SIView | None = None,
                         initial_covariance: FloatArray | None = None,
                         probability: float = 0.99,
                         progress: Callable[[int, int], None] | None = None
                         ) -> FlybyClosedLoop:
    """The closed loop with the orientation dispersed (module step 2e) over the run numbers
    ``runs`` (:func:`~starnav.batch.runs.run_ids`): run ``r`` renders its own fly-by
    (:func:`~starnav.simulate.flyby.dispersed_flyby`) and runs step 2 on it with its own
    noise, measured attitude and initial error; the consistency of step 3 is then judged over
    independent draws of the silhouette's model error. ``flyby_closed_loop`` dispatches here
    for ``navigation.trn.dispersion: orientation``. Every run's scenario is built before the
    first render (a bad draw is one error naming the run)."""
    check_flyby_scenario(base)
    scenarios = dict(zip(runs, over_runs(lambda r: dispersed_flyby(base, r), runs), strict=True))

    kept: list[tuple[Simulator, Renders]] = []  # the first run's frames only

    def one_run(r: int) -> tuple[FlybyRunResult, FloatArray, FloatArray, float, int]:
        sim = Simulator(scenarios[r][0])
        renders, t = render_flyby(sim)
        res = flyby_run(sim, renders, r, front_end=front_end, filter_options=filter_options,
                        initial_covariance=initial_covariance)
        fb = sim.scene.flyby
        assert fb is not None  # check_flyby_scenario
        if not kept:
            kept.append((sim, renders))
        return (res, np.asarray(sim.scene.relative_states, float),
                np.array([fb.x_hat, fb.y_hat, fb.z_hat], float), t * len(renders), len(renders))

    done = over_runs(one_run, runs, progress=progress)
    out = [d[0] for d in done]
    truths = [d[1] for d in done]
    axes = [d[2] for d in done]
    draws = [scenarios[r][1] for r in runs]
    t_render = sum(d[3] for d in done) / max(sum(d[4] for d in done), 1)
    return _closed_loop(kept[0][0], len(kept[0][1]), out, truths, t_render, probability,
                        dispersion="orientation", run_truths=truths, draws=draws,
                        run_axes=axes, first=kept[0])


#: Frames of the overlay figures: ``(file label, title)``; the frame is the first, the one
#: nearest closest approach, the last.
OVERLAY_FRAMES = (("first", "first frame"), ("ca", "closest approach"), ("last", "last frame"))


def plot_overlays(sim: Simulator, renders: Renders, loop: FlybyClosedLoop, out: str | Path,
                  run: int = 0) -> list[Path]:
    """The overlay figure (:func:`~starnav.navigation.trn.metrics.plot_frame_overlay`) of
    run ``run`` (its position in ``loop.runs``) at the first frame, closest approach and the
    last frame (one figure per distinct frame: ``overlay_first.png``, ``overlay_ca.png``,
    ``overlay_last.png``); the predicted centroid is the lit silhouette seen from the run's
    estimate after the frame's update."""
    res = loop.runs[run]
    K = len(res.measurements)
    picks = dict(zip((k for k, _ in OVERLAY_FRAMES),
                     (0, closest_approach_index(res.filter.epochs, loop.epoch_ca), K - 1),
                     strict=True))
    body = body_from_scenario(sim.scenario)
    t = res.filter.epochs - loop.epoch_ca
    paths, done = [], set()
    for label, title in OVERLAY_FRAMES:
        k = picks[label]
        if k in done:
            continue
        done.add(k)
        m = res.measurements[k]
        idx = int(res.steps[k].geometry.index)
        try:
            pred = predicted_silhouette(sim.camera, body, res.filter.states[k, :3], m).centroid_uv
        except GeometryError:
            pred = None
        img = segments_image(sim, renders[idx], res.run)
        paths.append(plot_frame_overlay(
            img, m, Path(out) / f"overlay_{label}.png", pred,
            f"{title}: frame {idx}, t - t_CA = {t[k]:+.1f} s, run {res.run}"))
    return paths


def navigate_flyby(sim: Simulator, out: str | Path, runs: int = 1, *, plots: bool = True,
                   probability: float = 0.99, renders: Renders | None = None,
                   progress: Callable[[str, int, int], None] | None = None) -> dict[str, Any]:
    """``starnav navigate SCENARIO.yaml`` for a fly-by: the closed loop over ``runs`` runs,
    then ``metrics.json`` (run 0's :class:`FlybyMetrics` flat keys, the per-frame timings, the
    tracker's budget (:func:`~starnav.navigation.trn.metrics.tracker_budget`: desktop time of
    the front end and filter per frame scaled to the MCU against its 650 ms, and their peak
    memory from a traced re-run of run 0) and, for >= 2 runs, the Monte Carlo summary), the
    figures (position and velocity errors with 3-sigma against time from CA, runs in grey;
    NEES with its band; tracks; run 0's frame overlays, :func:`plot_overlays`) and
    ``report.md``, every file written atomically. ``renders``: every frame already rendered
    (a fly-by dataset's frames read back, ``starnav navigate DATASET``:
    :func:`navigate_flyby_dataset`); the render time is then NaN.
    Returns the metrics dict."""
    check_flyby_scenario(sim.scenario)
    check_estimator_body(sim.scenario)
    dispersed = sim.scenario.navigation.trn.dispersion == "orientation"
    if renders is not None and dispersed:
        raise ConfigError("navigation.trn.dispersion", "orientation",
                          "'none' for frames already rendered (a fly-by dataset's): a "
                          "dispersed run renders its own fly-by, navigate the scenario YAML")
    if renders is not None and len(renders) != len(sim):
        raise ConfigError("renders", len(renders), f"every frame of the scenario ({len(sim)})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_render = float("nan")
    if renders is None and not dispersed:
        renders, t_render = render_flyby(
            sim, None if progress is None else (lambda d, n: progress("render", d, n)))
    loop = flyby_closed_loop(sim, runs, renders=renders, probability=probability,
                             progress=progress)
    if loop.first is not None:        # dispersed: run 0's own fly-by
        sim, renders = loop.first
    else:
        loop.timings_s["render"] = t_render
    assert renders is not None
    r0 = loop.runs[0]
    t = loop.time_from_ca
    metrics: dict[str, Any] = dict(r0.metrics.as_dict())
    # render: null when the frames were given (a dataset's), not a JSON NaN
    metrics["timing_s_per_frame"] = {k: (float(v) if np.isfinite(v) else None)
                                     for k, v in loop.timings_s.items()}
    mem = flyby_run(sim, renders, r0.run, memory=True).memory_bytes
    metrics["tracker_budget"] = budget = tracker_budget(loop.timings_s, mem)
    metrics["frame_budget"] = flyby_frame_budget(sim.scenario).to_dict()
    mc = None
    if runs >= 2:
        mc = {k: v for k, v in loop.summary.items() if k != "nees_per_frame"}
        metrics["monte_carlo"] = mc
    if loop.draws is not None:
        metrics["dispersion"] = {"kind": loop.dispersion, "draws_deg": loop.draws}
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1, default=float) + "\n")
    figures: list[str] = []
    if plots:
        errs, sig3 = [], []
        for k, r in enumerate(loop.runs):
            e = r.filter.errors(loop.truth_of(k))
            s3 = r.filter.sigma3()
            if loop.run_axes is not None:   # each run its own fly-by: plot in its frame
                e, s3 = errors_in_flyby_frame(e, r.filter.covariances, loop.run_axes[k])
            errs.append(e)
            sig3.append(s3)
        frame = ({"frame": "fly-by frame", "axis_names": FLYBY_AXES}
                 if loop.run_axes is not None else {})
        for kind in ("position", "velocity"):
            figures.append(str(plot_flyby_errors(t, errs[0], sig3[0], out / f"{kind}.png",
                                                 kind, errs[1:], **frame)))
        figures.append(str(plot_flyby_nees(t, loop.summary["nees_per_frame"],
                                           out / "nees.png", runs=runs,
                                           probability=probability)))
        figures.append(str(plot_tracks(t, r0.measurements, r0.filter, out / "tracks.png")))
        figures += [str(p) for p in plot_overlays(sim, renders, loop, out)]
    write_report(out / "report.md", r0.metrics, mc, figures, budget)
    return metrics


def navigate_flyby_dataset(path: str | os.PathLike[str], out: str | os.PathLike[str],
                           runs: int | None = None, *, overrides: Sequence[str] = (),
                           plots: bool = True, probability: float = 0.99,
                           progress: Callable[[str, int, int], None] | None = None
                           ) -> dict[str, Any]:
    """``starnav navigate DATASET`` for a fly-by dataset (read by
    :func:`starnav.dataset.flyby.read_flyby`): the closed loop of :func:`navigate_flyby` over
    ``runs`` runs (default ``navigation.runs``) on the stored frames; writes its
    ``metrics.json``, figures and ``report.md`` in ``out`` and returns the metrics dict."""
    sim, renders = read_flyby(path, overrides)
    n = sim.scenario.navigation.runs if runs is None else int(runs)
    return navigate_flyby(sim, out, n, plots=plots, probability=probability, renders=renders,
                          progress=progress)
