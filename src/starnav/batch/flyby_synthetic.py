"""Monte Carlo of the fly-by estimator on synthetic measurements: one fly-by, a grid, a score.

1. The truth geometry of the fly-by is computed once
   (:func:`~starnav.navigation.trn.synthetic.flyby_truth`).
2. Run ``r`` of ``runs`` (:func:`starnav.batch.runs.over_runs`) draws its own measurements
   (pixel noise, track births and lifetimes, attitude errors, centroid and radius noise) and
   its own initial error from ``P0``, from the streams of
   :mod:`starnav.navigation.trn.synthetic` keyed by ``(seed, r)``: a run is the same whatever
   the number of runs.
3. The verdict over the runs: :func:`starnav.navigation.trn.metrics.summarise_runs`
   (Bar-Shalom et al. 2001, 5.4.2).

:func:`flyby_sweep` runs this at every point of a grid of v_inf, CA distance and Sun phase;
:func:`case_monte_carlo` and :func:`score_case` on the calibration and scoring fly-bys of
:mod:`starnav.navigation.trn.scoring`.

Index
-----
:func:`flyby_monte_carlo`, :func:`flyby_sweep`, :func:`case_monte_carlo`, :func:`score_case`.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.batch.runs import over_points, over_runs, run_ids
from starnav.bodies.schema import ShapeModelConfig
from starnav.bodies.small_body import ShapeModelBody
from starnav.camera import Camera
from starnav.config_base import SIView
from starnav.errors import ConfigError
from starnav.navigation.schema import TrnFilterConfig, TrnShapeModelConfig
from starnav.navigation.trn.body_model import estimator_model
from starnav.navigation.trn.filter import FlybyRun, ShapeBodyLike, run_filter
from starnav.navigation.trn.metrics import FlybyMetrics, FlybyMonteCarlo, summarise_runs
from starnav.navigation.trn.scoring import SYNTHETIC, SYNTHETIC_FILTER, FlybyCase, score
from starnav.navigation.trn.synthetic import (
    STREAM_SHAPE_SCALE,
    FlybyTruth,
    SyntheticOptions,
    flyby_truth,
    initial_estimate,
    run_measurements,
)
from starnav.scenes.flyby import flyby_from_config
from starnav.scenes.schema import FlybyConfig
from starnav.seeding import STAGE_FLYBY_SYNTHETIC, generator


def flyby_monte_carlo(truth: FlybyTruth, camera: Camera, body: ShapeBodyLike, runs: int,
                      initial_covariance: ArrayLike, *, seed: int = 0,
                      synthetic: SyntheticOptions | None = None,
                      options: SIView | None = None,
                      probability: float = 0.99, shape_model: Any = None) -> FlybyMonteCarlo:
    """``runs`` filter runs on synthetic measurements of ``truth`` (module steps 1-3).
    ``shape_model``: a :class:`~starnav.navigation.schema.TrnShapeModelConfig`; the filter of
    run ``r`` then navigates on :func:`~starnav.navigation.trn.body_model.estimator_model`
    of ``body`` with the unit draw of stream ``(seed, STAGE_FLYBY_SYNTHETIC, r,
    STREAM_SHAPE_SCALE)`` (``run.info["shape_model"]``); default the truth's own shape."""
    ids = run_ids(runs, minimum=2)
    P0 = np.asarray(initial_covariance, float)

    def one_run(r: int) -> tuple[FlybyRun, FlybyMetrics]:
        meas = run_measurements(truth, seed, r, synthetic)
        x0 = initial_estimate(truth, P0, seed, r)
        model_body, prior, info = body, None, None
        if shape_model is not None:
            draw = generator(seed, STAGE_FLYBY_SYNTHETIC, r, STREAM_SHAPE_SCALE).standard_normal()
            model = estimator_model(body, shape_model, float(draw))  # type: ignore[arg-type]
            model_body, prior, info = model.body, model.prior, model.info
        res = run_filter(meas, camera, model_body, x0, P0, options,
                         sun_direction=truth.sun_direction, prior=prior)
        if info is not None:
            res.info["shape_model"] = info
        return res, FlybyMetrics.of(res, meas, truth.states, truth.epoch_ca)

    done = over_runs(one_run, ids)
    out_runs = [res for res, _ in done]
    out_metrics = [m for _, m in done]
    summary = summarise_runs(out_runs, out_metrics, truth.states, truth.epochs,
                             truth.epoch_ca, probability)
    nees = np.array([res.nees(truth.states) for res in out_runs])
    return FlybyMonteCarlo(truth, out_runs, out_metrics, nees, summary)


def flyby_sweep(body: ShapeBodyLike, camera: Camera, *, v_inf_km_s: Sequence[float],
                closest_approach_km: Sequence[float], phase_deg: Sequence[float],
                span_s: float, cadence_s: float, runs: int, initial_covariance: ArrayLike,
                seed: int = 0, synthetic: SyntheticOptions | None = None,
                options: SIView | None = None,
                base: FlybyConfig | None = None) -> list[dict[str, Any]]:
    """A Monte Carlo at every point of the grid ``v_inf x CA distance x phase`` on synthetic
    measurements, frames every ``cadence_s`` from ``-span_s`` to ``+span_s`` about CA; one row
    per point: the grid values, the Monte Carlo summary (without the per-frame NEES) and the
    median of each run's :class:`~starnav.navigation.trn.metrics.FlybyMetrics`."""
    if not (span_s > 0 and cadence_s > 0):
        raise ConfigError("span_s / cadence_s", (span_s, cadence_s), "> 0 [s]")
    for name, vals in (("v_inf_km_s", v_inf_km_s), ("closest_approach_km", closest_approach_km),
                       ("phase_deg", phase_deg)):
        if len(vals) == 0:
            raise ConfigError(name, list(vals), "at least one value")
    base = base if base is not None else FlybyConfig()
    epochs = np.arange(-span_s, span_s + 1e-9 * span_s, cadence_s)

    def point(v: float, d: float, ph: float) -> dict[str, Any]:
        cfg = base.model_copy(update={"v_inf_km_s": float(v), "closest_approach_km": float(d),
                                      "phase_at_ca_deg": float(ph)})
        cfg = FlybyConfig.model_validate(cfg.model_dump())
        fb = flyby_from_config(cfg, epoch_ca=0.0, gm=float(getattr(body, "gm", 0.0)))
        truth = flyby_truth(fb, body, camera, epochs, synthetic, seed)
        mc = flyby_monte_carlo(truth, camera, body, runs, initial_covariance, seed=seed,
                               synthetic=synthetic, options=options)
        row: dict[str, Any] = {"v_inf_km_s": float(v), "closest_approach_km": float(d),
                               "phase_deg": float(ph)}
        row.update({k: val for k, val in mc.summary.items() if k != "nees_per_frame"})
        for key, val in FlybyMetrics.__dataclass_fields__.items():
            if val.type in ("float", "int"):
                row[f"median_{key}"] = float(np.nanmedian([getattr(x, key) for x in mc.metrics]))
        return row

    return over_points(point, list(itertools.product(v_inf_km_s, closest_approach_km,
                                                     phase_deg)))


def case_monte_carlo(case: FlybyCase, runs: int, seed: int = 11, *,
                     filter_overrides: dict[str, Any] | None = None,
                     shape_overrides: dict[str, Any] | None = None
                     ) -> tuple[FlybyMonteCarlo, float]:
    """``runs`` synthetic runs of ``case`` on the coarse model
    (:mod:`starnav.navigation.trn.scoring`), and the CPU time of the filter runs per frame and
    run [s] (the synthetic truth's excluded); ``filter_overrides`` and ``shape_overrides``
    change the scored defaults' filter and shape-model keys (a diagnosis, never a score)."""
    body = ShapeModelBody(ShapeModelConfig(model=case.body))
    cam = Camera.preset("aa-str")
    fl = flyby_from_config(FlybyConfig(v_inf_km_s=case.v_inf / 1e3,
                                       closest_approach_km=case.closest_approach / 1e3,
                                       phase_at_ca_deg=math.degrees(case.phase_at_ca)),
                           epoch_ca=0.0, gm=body.gm)
    half = case.start_ca_ranges * case.closest_approach / case.v_inf
    epochs = np.arange(-half, half + 1e-9, case.cadence)
    truth = flyby_truth(fl, body, cam, epochs, SYNTHETIC, seed=1)
    cfg = TrnFilterConfig(**{**SYNTHETIC_FILTER, **(filter_overrides or {})})
    t0 = time.process_time()
    mc = flyby_monte_carlo(truth, cam, body, runs, cfg.initial_covariance(), seed=seed,
                           synthetic=SYNTHETIC, options=cfg.to_si(),
                           shape_model=TrnShapeModelConfig(
                               **{"map": "coarse", **(shape_overrides or {})}))
    return mc, (time.process_time() - t0) / (runs * epochs.size)


def score_case(case: FlybyCase, runs: int = 20, seed: int = 11) -> dict[str, Any]:
    """Run and score one case."""
    mc, cpu = case_monte_carlo(case, runs, seed)
    return score(mc, case, cpu)
