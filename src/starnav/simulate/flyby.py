"""The asteroid fly-by closed loop on rendered frames (model in the loop, as the seed paper).

A fly-by scenario (``target.kind: shape_model``, ``trajectory.source: flyby``) end to end:

1. Render every frame once (:func:`render_flyby`); every Monte Carlo run reuses the radiance.
2. Per run ``r`` (the same whatever the number of runs): a. the measured attitude (run 0 the
   frame's own draw, ``r >= 1`` a fresh one); b. the tracker's acquisitions and the front end
   (:func:`starnav.simulate.trn.track_flyby`); c. the estimator
   (:func:`~starnav.navigation.trn.filter.run_filter`) from the truth plus a draw of the
   initial covariance; d. the metrics against the truth; e. with
   ``navigation.trn.dispersion: orientation`` the run first draws the fly-by's orientation
   relative to the body and renders its own frames (:func:`flyby_dispersed_runs`).
3. Consistency over the runs (:func:`~starnav.navigation.trn.montecarlo.summarise_runs`).

Why the orientation is dispersed (the silhouette's model error is a function of the aspect):
docs/navigation.md.

Index
-----
:func:`flyby_closed_loop`, :class:`FlybyClosedLoop`, :func:`flyby_run`,
:class:`FlybyRunResult`, :func:`render_flyby`, :func:`initial_state`, :func:`dispersed_flyby`,
:func:`flyby_dispersed_runs`; :func:`navigate_flyby`, :func:`plot_overlays`,
:func:`segments_image`; the sweep :func:`flyby_rendered_sweep`, :func:`flyby_sweep_points`,
:func:`flyby_sweep_row`, :func:`write_flyby_sweep`, :data:`SWEEP_AXES`;
:func:`is_flyby_scenario`, :func:`check_flyby_scenario`.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import json
import logging
import math
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path, atomic_write_text
from starnav.bodies.base import TargetBody
from starnav.bodies.small_body import ShapeModelBody
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import SIView, set_dotted
from starnav.errors import ConfigError, GeometryError
from starnav.geometry import FrameGeometry
from starnav.navigation.trn.body_model import EstimatorModel, estimator_model
from starnav.navigation.trn.filter import FlybyRun, run_filter
from starnav.navigation.trn.frontend import FlybyFrontEnd
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
    tracker_budget,
    write_report,
)
from starnav.navigation.trn.montecarlo import summarise_runs
from starnav.navigation.trn.truth import BODY_AOVS
from starnav.navigation.trn.windows import WindowReader
from starnav.radiance import RadianceImage
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate.build import body_from_scenario
from starnav.simulate.frames import Simulator
from starnav.simulate.trn import FlybyStep, flyby_exposures, flyby_frame_budget, track_flyby
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Last key of a run's initial-error stream ``(seed, STAGE_NAVIGATION, run, 0, 17)`` (never
#: change; 16 is the front end's RANSAC, :data:`starnav.simulate.trn.TRN_STREAM`).
INITIAL_ERROR_STREAM = 17
#: Last key of a run's orientation draw ``(seed, STAGE_NAVIGATION, run, 0, 18)`` under
#: ``navigation.trn.dispersion: orientation`` (never change).
DISPERSION_STREAM = 18
#: Last key of a run's draw of the coarse shape model's scale error ``(seed,
#: STAGE_NAVIGATION, run, 0, 19)`` under ``navigation.trn.shape_model.map: coarse`` (never
#: change).
SHAPE_SCALE_STREAM = 19

Renders = Sequence[tuple[FrameGeometry, RadianceImage]]
#: The render channels the closed loop reads besides the radiance: the body mask and the
#: body-fixed surface points of the feature truth.
KEPT_AOVS = ("mask", *BODY_AOVS)


def is_flyby_scenario(sc: Scenario) -> bool:
    """Whether ``sc`` asks for a fly-by (``trajectory.source: flyby``): the scenarios the
    fly-by paths take (closed loop, fly-by sweep, fly-by dataset), where
    :func:`check_flyby_scenario` then demands what the closed loop needs, a shape model. A
    small body on any other trajectory is a limb scenario."""
    return sc.trajectory is not None and sc.trajectory.source == "flyby"


def check_flyby_scenario(sc: Scenario) -> None:
    """A fly-by closed loop needs a small body on a fly-by; anything else is one clear error,
    before any rendering."""
    flyby = sc.trajectory is not None and sc.trajectory.source == "flyby"
    small = sc.target is not None and sc.target.kind == "shape_model"
    if not flyby:
        src = None if sc.trajectory is None else sc.trajectory.source
        raise ConfigError("trajectory.source", src,
                          "'flyby' (with target.kind: shape_model) for the fly-by navigation; a "
                          "Moon scenario is navigated from its dataset (starnav dataset, then "
                          "starnav navigate DATASET)")
    if not small:
        raise ConfigError("target.kind", None if sc.target is None else sc.target.kind,
                          "'shape_model' (a small body's shape model) for the fly-by "
                          "navigation: the Moon is navigated from its limb")
    flyby_frame_budget(sc)     # a cadence the readout law refuses, under policy enforce


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
        True ``(r, v)`` relative to the body, J2000 [m, m/s] (of the first run when the
        orientation is dispersed: each run's own is in ``run_truths``).
    runs : list of FlybyRunResult
    summary : dict
        :func:`~starnav.navigation.trn.montecarlo.summarise_runs` (for >= 2 runs), else the
        single run's NEES.
    timings_s : dict
        Per-frame wall time of each stage, mean over frames and runs [s]: ``render`` (once
        per frame, or per frame and run when dispersed), ``detector``, ``front_end``,
        ``filter``.
    dispersion : str
        ``navigation.trn.dispersion`` of the runs (``none`` or ``orientation``).
    run_truths : list of (K, 6) arrays, optional
        Each run's true states when the orientation is dispersed (J2000, its own fly-by).
    draws : list of dict, optional
        Each run's drawn orientation (:func:`dispersed_flyby`).
    run_axes : list of (3, 3) arrays, optional
        Rows ``x, y, z`` of each run's fly-by frame in J2000 (CA direction, CA velocity,
        plane normal) when dispersed: the frame its errors are plotted in.
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


def render_flyby(sim: Simulator, progress: Callable[[int, int], None] | None = None
                 ) -> tuple[list[tuple[FrameGeometry, RadianceImage]], float]:
    """Module step 1: every frame rendered once; returns the renders and the mean render
    time per frame [s]. Each frame keeps only what the loop reads (the radiance, the mask and
    the body-fixed points of the truth: :data:`KEPT_AOVS`), 6 of the render's 15 channels:
    every frame of the pass is held."""
    check_flyby_scenario(sim.scenario)
    out = []
    t0 = time.perf_counter()
    for i in range(len(sim)):
        geom, img = sim.render(i)
        out.append((geom, dataclasses.replace(
            img, aovs={k: v for k, v in img.aovs.items() if k in KEPT_AOVS})))
        if progress is not None:
            progress(i + 1, len(sim))
    return out, (time.perf_counter() - t0) / max(len(sim), 1)


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

    Returns
    -------
    FlybyClosedLoop
    """
    check_flyby_scenario(sim.scenario)
    check_estimator_body(sim.scenario)
    if runs < 1:
        raise ConfigError("runs", runs, ">= 1 Monte Carlo run")
    if not 0.0 < probability < 1.0:
        raise ConfigError("probability", probability, "in (0, 1)")
    if sim.scenario.navigation.trn.dispersion == "orientation":
        if renders is not None:
            raise ConfigError("navigation.trn.dispersion", "orientation",
                              "'none' when the frames are given (a dataset's, or rendered "
                              "once): a dispersed run renders its own fly-by")
        return flyby_dispersed_runs(sim.scenario, runs, front_end=front_end,
                                    filter_options=filter_options,
                                    initial_covariance=initial_covariance,
                                    probability=probability, first_run=first_run,
                                    progress=progress)
    t_render = float("nan")
    if renders is None:
        renders, t_render = render_flyby(
            sim, None if progress is None else (lambda d, n: progress("render", d, n)))
    elif len(renders) != len(sim):
        raise ConfigError("renders", len(renders), f"every frame of the scenario ({len(sim)})")
    body = body_from_scenario(sim.scenario)
    out = []
    for k, r in enumerate(range(first_run, first_run + runs)):
        out.append(flyby_run(sim, renders, r, front_end=front_end,
                             filter_options=filter_options,
                             initial_covariance=initial_covariance, body=body))
        if progress is not None:
            progress("runs", k + 1, runs)
    flyby = sim.scene.flyby
    assert flyby is not None
    X = sim.scene.relative_states
    epochs = np.asarray(sim.scene.epochs, float)
    summary = summarise_runs([r.filter for r in out], [r.metrics for r in out], X, epochs,
                             float(flyby.epoch_ca), probability)
    summary["dispersion"] = "none"
    K = len(renders)
    timings = {"render": t_render}
    for stage in ("detector", "front_end", "filter"):
        timings[stage] = float(np.mean([r.timings_s[stage] for r in out])) / K
    return FlybyClosedLoop(epochs, float(flyby.epoch_ca), X, out, summary, timings)


def dispersed_flyby(base: Scenario, run: int) -> tuple[Scenario, dict[str, float]]:
    """Run ``run``'s fly-by under ``navigation.trn.dispersion: orientation`` (module step 2e):
    ``base`` with the fly-by's orientation relative to the body drawn uniformly over the
    rotations from ``generator(seed, STAGE_NAVIGATION, run, 0, DISPERSION_STREAM)``,
    ``u ~ U(0, 1)^3``: the CA velocity direction uniform on the sphere
    (``velocity_ra_deg = 360 u1``, ``velocity_dec_deg = asin(2 u2 - 1)``) and the B-plane
    angle uniform (``ca_angle_deg = 360 u3``). v_inf, CA distance, phase at CA and the Sun's
    azimuth are the base's. Returns the run's scenario (built and checked; a concrete
    fly-by, its ``navigation.trn.dispersion`` set to ``none``) and the three drawn values
    [deg]."""
    g = generator(int(base.seed), STAGE_NAVIGATION, int(run), 0, DISPERSION_STREAM)
    u = g.random(3)
    draw = {"velocity_ra_deg": 360.0 * float(u[0]),
            "velocity_dec_deg": math.degrees(math.asin(2.0 * float(u[1]) - 1.0)),
            "ca_angle_deg": 360.0 * float(u[2])}
    d = scenario_to_dict(base)
    for k, v in draw.items():
        set_dotted(d, f"trajectory.flyby.{k}", v)
    set_dotted(d, "navigation.trn.dispersion", "none")
    try:
        sc = scenario_from_dict(d)
    except ConfigError as err:
        raise ConfigError(f"dispersed run {run} {draw}: {err.field}", err.value,
                          err.expected) from None
    return sc, draw


def flyby_dispersed_runs(base: Scenario, runs: int, *,
                         front_end: SIView | None = None,
                         filter_options: SIView | None = None,
                         initial_covariance: FloatArray | None = None,
                         probability: float = 0.99, first_run: int = 0,
                         progress: Callable[[str, int, int], None] | None = None
                         ) -> FlybyClosedLoop:
    """The closed loop with the orientation dispersed (module step 2e): run ``r`` renders
    its own fly-by (:func:`dispersed_flyby`) and runs step 2 on it with its own noise,
    measured attitude and initial error; the consistency of step 3 is then judged over
    independent draws of the silhouette's model error. ``flyby_closed_loop`` dispatches here
    for ``navigation.trn.dispersion: orientation``; the arguments are its own. Every run's
    scenario is built before the first render (a bad draw is one error naming the run)."""
    check_flyby_scenario(base)
    scenarios = [dispersed_flyby(base, r) for r in range(first_run, first_run + runs)]
    out, truths, axes, draws = [], [], [], []
    first: tuple[Simulator, Renders] | None = None
    t_render = 0.0
    n_frames = 0
    for k, (r, (sc, draw)) in enumerate(zip(range(first_run, first_run + runs), scenarios,
                                            strict=True)):
        sim = Simulator(sc)
        renders, t = render_flyby(sim)
        t_render += t * len(renders)
        n_frames += len(renders)
        out.append(flyby_run(sim, renders, r, front_end=front_end,
                             filter_options=filter_options,
                             initial_covariance=initial_covariance))
        fb = sim.scene.flyby
        assert fb is not None  # check_flyby_scenario
        truths.append(np.asarray(sim.scene.relative_states, float))
        axes.append(np.array([fb.x_hat, fb.y_hat, fb.z_hat], float))
        draws.append(draw)
        if first is None:
            first = (sim, renders)
        if progress is not None:
            progress("runs", k + 1, runs)
    assert first is not None
    sim0 = first[0]
    fb0 = sim0.scene.flyby
    assert fb0 is not None
    epochs = np.asarray(sim0.scene.epochs, float)
    summary = summarise_runs([r.filter for r in out], [r.metrics for r in out], truths,
                             epochs, float(fb0.epoch_ca), probability)
    summary["dispersion"] = "orientation"
    K = len(first[1])
    timings = {"render": t_render / max(n_frames, 1)}
    for stage in ("detector", "front_end", "filter"):
        timings[stage] = float(np.mean([r.timings_s[stage] for r in out])) / K
    return FlybyClosedLoop(epochs, float(fb0.epoch_ca), truths[0], out, summary, timings,
                           dispersion="orientation", run_truths=truths, draws=draws,
                           run_axes=axes, first=first)


def segments_image(sim: Simulator, render: tuple[FrameGeometry, RadianceImage], run: int = 0,
                   front_end: SIView | None = None) -> NDArray[np.float32]:
    """The segments DN of one frame of run ``run`` (0 where no run was read): the first
    acquisition again, with the same noise stream as the closed loop's, so the very image its
    front end read (the runs keep no image)."""
    geom, img = render
    fe = FlybyFrontEnd(sim.camera, front_end if front_end is not None
                       else sim.scenario.navigation.trn.front_end.to_si())
    e0, _, _, _ = flyby_exposures(sim, img, geom, fe, run=run)
    return WindowReader.from_exposures(e0).segments_image()


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
    :func:`starnav.dataset.flyby.navigate_flyby_dataset`); the render time is then NaN.
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


# ----------------------------------------------------------------------------- rendered sweep
#: Axes of the rendered fly-by sweep: keys of ``trajectory.flyby``.
SWEEP_AXES = ("v_inf_km_s", "closest_approach_km", "phase_at_ca_deg")


def flyby_sweep_points(base: Scenario, axes: dict[str, Sequence[float]]
                       ) -> list[tuple[dict[str, float], Scenario]]:
    """Every point of the product of ``axes`` (``trajectory.flyby`` keys of
    :data:`SWEEP_AXES`; an axis not given keeps the base scenario's value), the last axis
    varying fastest: its grid values and its scenario, each one built and its scene checked
    (geometry, pointing) before anything is rendered; a bad point is one ConfigError naming
    it."""
    check_flyby_scenario(base)
    for k in axes:
        if k not in SWEEP_AXES:
            raise ConfigError("sweep axis", k, f"one of {', '.join(SWEEP_AXES)}")
    flyby = base.trajectory.flyby if base.trajectory is not None else None
    assert flyby is not None  # check_flyby_scenario
    grid = {k: [float(v) for v in axes.get(k, [getattr(flyby, k)])] for k in SWEEP_AXES}
    data = scenario_to_dict(base)
    points = []
    for combo in itertools.product(*grid.values()):
        d = json.loads(json.dumps(data))
        values = dict(zip(SWEEP_AXES, combo, strict=True))
        for k, v in values.items():
            set_dotted(d, f"trajectory.flyby.{k}", v)
        try:
            sc = scenario_from_dict(d)
            Simulator(sc)
        except ConfigError as err:
            raise ConfigError(f"sweep point {values}: {err.field}", err.value,
                              err.expected) from None
        points.append((values, sc))
    return points


def flyby_sweep_row(values: dict[str, float], scenario: Scenario | dict[str, Any],
                    runs: int, probability: float = 0.99) -> dict[str, Any]:
    """One sweep point: the closed loop of ``scenario`` (rendered once, ``runs`` runs) as a
    row of :func:`flyby_rendered_sweep`. A pure function of its arguments (a batch task: the
    scenario may be given as its dict)."""
    sc = scenario if isinstance(scenario, Scenario) else scenario_from_dict(dict(scenario))
    sim = Simulator(sc)
    loop = flyby_closed_loop(sim, runs, probability=probability)
    ms = [r.metrics for r in loop.runs]
    row: dict[str, Any] = dict(values)
    row["runs"] = runs
    row["ca_range_m"] = ms[0].ca_range_m
    pct = [m.ca_position_error_pct_range for m in ms]
    row["ca_error_pct_range_median"] = float(np.median(pct))
    row["ca_error_pct_range_max"] = float(np.max(pct))
    if runs >= 2:
        row["nees_mean"] = float(loop.summary["nees_mean"])
        row["nees_band_lo"], row["nees_band_hi"] = (float(x) for x in loop.summary["nees_band"])
        row["verdict"] = loop.summary["verdict"]
    else:
        row["nees_mean"] = ms[0].nees_mean
        row["nees_band_lo"] = row["nees_band_hi"] = float("nan")
        row["verdict"] = "-"
    for key in ("mean_tracks_per_frame", "mean_track_length_frames", "feature_error_rms_px"):
        row[f"median_{key}"] = float(np.nanmedian([getattr(m, key) for m in ms]))
    for stage in ("detector", "front_end", "filter"):
        row[f"{stage}_s_per_frame"] = float(loop.timings_s[stage])
    return row


def flyby_rendered_sweep(base: Scenario, axes: dict[str, Sequence[float]], runs: int = 2, *,
                         probability: float = 0.99,
                         progress: Callable[[int, int], None] | None = None
                         ) -> list[dict[str, Any]]:
    """The closed loop (:func:`flyby_closed_loop`, render once per point) at every point of
    :func:`flyby_sweep_points` ``(base, axes)``, ``runs`` Monte Carlo runs per point, in this
    process (``starnav sweep`` runs the same rows, :func:`flyby_sweep_row`, on the batch
    runner: :func:`starnav.batch.flyby_sweep.run_flyby_sweep`).

    Returns one row per point (the last axis varying fastest): the grid values,
    ``ca_range_m``, ``ca_error_pct_range_median`` / ``_max`` over the runs, ``nees_mean``
    with ``nees_band_lo`` / ``_hi`` (two-sided ``probability`` band of the runs' and frames'
    effective samples, :func:`starnav.navigation.metrics.anees_statistics`) and ``verdict``
    (runs >= 2; else run 0's mean NEES and no band), the medians
    over runs of ``mean_tracks_per_frame``, ``mean_track_length_frames``,
    ``feature_error_rms_px``, and the per-frame wall time of the tracker's stages
    (``detector_s_per_frame``, ``front_end_s_per_frame``, ``filter_s_per_frame``).
    """
    if runs < 1:
        raise ConfigError("runs", runs, ">= 1 Monte Carlo run")
    points = flyby_sweep_points(base, axes)
    rows = []
    for i, (values, sc) in enumerate(points):
        row = flyby_sweep_row(values, sc, runs, probability)
        rows.append(row)
        log.info("fly-by sweep point %d/%d %s: CA error median %.3g %% of range, NEES %.3g",
                 i + 1, len(points), values, row["ca_error_pct_range_median"],
                 row["nees_mean"])
        if progress is not None:
            progress(i + 1, len(points))
    return rows


#: Columns of the sweep's markdown table: (row key, heading, format).
SWEEP_COLUMNS = (
    ("v_inf_km_s", "v_inf [km/s]", "{:g}"), ("closest_approach_km", "CA [km]", "{:g}"),
    ("phase_at_ca_deg", "phase [deg]", "{:g}"),
    ("ca_error_pct_range_median", "CA error median [% range]", "{:.3f}"),
    ("ca_error_pct_range_max", "CA error max [% range]", "{:.3f}"),
    ("nees_mean", "mean NEES", "{:.2f}"), ("nees_band_lo", "band lo", "{:.2f}"),
    ("nees_band_hi", "band hi", "{:.2f}"), ("verdict", "verdict", "{}"),
    ("median_mean_tracks_per_frame", "tracks/frame", "{:.1f}"),
    ("median_mean_track_length_frames", "track length [frames]", "{:.1f}"),
    ("median_feature_error_rms_px", "feature err rms [px]", "{:.2f}"))


def write_flyby_sweep(rows: Sequence[dict[str, Any]], out: str | Path, *, plots: bool = True
                      ) -> dict[str, Path]:
    """The sweep's ``sweep.csv`` (every key of the rows), ``sweep.md`` (the table of
    :data:`SWEEP_COLUMNS`, linking the figure) and ``sweep.png`` (per point: the median and
    max CA error over the range; the mean NEES with its band), atomically."""
    if not rows:
        raise ConfigError("rows", 0, "at least one sweep point")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    paths = {"csv": atomic_write_text(out / "sweep.csv", buf.getvalue())}
    lines = ["# Fly-by sweep on rendered frames", "",
             f"{len(rows)} point(s) x {rows[0]['runs']} run(s).", "",
             "| " + " | ".join(h for _, h, _ in SWEEP_COLUMNS) + " |",
             "|" + "---|" * len(SWEEP_COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(
            "-" if isinstance(r[k], float) and not np.isfinite(r[k]) else f.format(r[k])
            for k, _, f in SWEEP_COLUMNS) + " |")
    if plots:
        paths["figure"] = _plot_sweep(rows, out / "sweep.png")
        lines += ["", "![sweep](sweep.png)"]
    paths["table"] = atomic_write_text(out / "sweep.md", "\n".join(lines) + "\n")
    return paths


def _plot_sweep(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots(2, 1, sharex=True)
    x = np.arange(len(rows))
    ax[0].plot(x, [r["ca_error_pct_range_median"] for r in rows], "o", label="median")
    ax[0].plot(x, [r["ca_error_pct_range_max"] for r in rows], "v", color="C3", label="max")
    ax[0].set_ylabel("position error at CA [% range]")
    ax[0].legend(loc="upper right")
    ax[1].semilogy(x, [r["nees_mean"] for r in rows], "o", color="k", label="mean NEES")
    lo = np.array([r["nees_band_lo"] for r in rows], float)
    hi = np.array([r["nees_band_hi"] for r in rows], float)
    if np.all(np.isfinite(lo)):
        ax[1].vlines(x, lo, hi, color="C3", lw=3, alpha=0.4, label="band")
    ax[1].axhline(6.0, color="C2", lw=0.8)
    ax[1].set_ylabel("mean NEES (6 states)")
    ax[1].legend(loc="upper right")
    ax[1].set_xticks(x, [f"{r['v_inf_km_s']:g} km/s\n{r['closest_approach_km']:g} km\n"
                         f"{r['phase_at_ca_deg']:g} deg" for r in rows], fontsize=7)
    ax[1].set_xlabel("v_inf, CA distance, phase at CA")
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120)
    return path
