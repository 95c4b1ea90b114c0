"""Monte Carlo of the fly-by estimator on synthetic measurements, and a sweep over the fly-by.

Technique
---------
1. The truth geometry of the fly-by is computed once
   (:func:`~starnav.navigation.trn.synthetic.flyby_truth`).
2. Run ``r`` of ``runs`` draws its own measurements (pixel noise, track births and lifetimes,
   attitude errors, centroid and radius noise) and its own initial error from ``P0``, from the
   streams of :mod:`starnav.navigation.trn.synthetic` keyed by ``(seed, r)``: a run is the same
   whatever the number of runs.
3. Consistency (Bar-Shalom et al. 2001, 5.4.2; the limb case's
   :func:`starnav.batch.consistency.consistency_metrics`): the NEES of the 6 states averaged
   over the ``R`` runs is, for a consistent filter, ``chi2(6 R) / R`` at each frame (the
   fraction of frames inside its 95 % band is reported). The verdict is its mean over the
   frames against the two-sided ``probability`` band of ``R K / tau`` effective samples, ``tau``
   the NEES series' integrated autocorrelation time
   (:func:`~starnav.navigation.metrics.anees_statistics`); the NEES at CA alone has the exact
   band of an ``R``-run mean.
4. Accuracy: the position error at CA over the range, per run (median, max).

:func:`flyby_sweep` runs this over a grid of v_inf, CA distance and Sun phase.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.camera import Camera
from starnav.config_base import SIView
from starnav.errors import ConfigError
from starnav.navigation.metrics import anees_statistics, chi2_band
from starnav.navigation.trn.body_model import estimator_model
from starnav.navigation.trn.filter import FlybyRun, ShapeBodyLike, run_filter
from starnav.navigation.trn.metrics import FlybyMetrics, closest_approach_index
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
from starnav.typing import FloatArray


@dataclass
class FlybyMonteCarlo:
    """Runs of one fly-by and their verdict.

    Attributes
    ----------
    truth : FlybyTruth
    runs : list of FlybyRun
    metrics : list of FlybyMetrics
        One per run.
    nees : (R, K) array
    summary : dict
        ``runs``, ``probability``, ``nees_mean``, ``nees_band``, ``verdict``
        (``consistent`` / ``overconfident`` / ``pessimistic``), ``nees_ca``,
        ``nees_ca_band``, ``ca_error_pct_range_median`` / ``_max``, ``nees_per_frame``.
    """

    truth: FlybyTruth
    runs: list[FlybyRun]
    metrics: list[FlybyMetrics]
    nees: FloatArray
    summary: dict[str, Any]


def flyby_monte_carlo(truth: FlybyTruth, camera: Camera, body: ShapeBodyLike, runs: int,
                      initial_covariance: ArrayLike, *, seed: int = 0,
                      synthetic: SyntheticOptions | None = None,
                      options: SIView | None = None,
                      probability: float = 0.99, shape_model: Any = None) -> FlybyMonteCarlo:
    """``runs`` filter runs on synthetic measurements of ``truth`` (module essay).
    ``shape_model``: a :class:`~starnav.navigation.schema.TrnShapeModelConfig`; the filter of
    run ``r`` then navigates on :func:`~starnav.navigation.trn.body_model.estimator_model`
    of ``body`` with the unit draw of stream ``(seed, STAGE_FLYBY_SYNTHETIC, r,
    STREAM_SHAPE_SCALE)`` (``run.info["shape_model"]``); default the truth's own shape."""
    if runs < 2:
        raise ConfigError("runs", runs, ">= 2 Monte Carlo runs (consistency needs several)")
    P0 = np.asarray(initial_covariance, float)
    out_runs, out_metrics = [], []
    for r in range(runs):
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
        out_runs.append(res)
        out_metrics.append(FlybyMetrics.of(res, meas, truth.states, truth.epoch_ca))
    summary = summarise_runs(out_runs, out_metrics, truth.states, truth.epochs,
                             truth.epoch_ca, probability)
    nees = np.array([res.nees(truth.states) for res in out_runs])
    return FlybyMonteCarlo(truth, out_runs, out_metrics, nees, summary)


def summarise_runs(runs: Sequence[FlybyRun], metrics: Sequence[FlybyMetrics],
                   truth: ArrayLike | Sequence[ArrayLike], epochs: ArrayLike, epoch_ca: float,
                   probability: float = 0.99) -> dict[str, Any]:
    """The Monte Carlo verdict of ``runs`` of one fly-by (module steps 3-4): the per-frame
    NEES averaged over the runs, its mean against the two-sided ``probability`` band of its
    effective samples (module step 3), the NEES at CA, the CA position error over range (median,
    max), the filter's divergence resets summed over the runs. ``truth``: the (K, 6) true
    states shared by every run, or one (K, 6) per run (runs of dispersed fly-bys, same
    epochs); ``epochs`` (K,) [TDB s]."""
    X = np.asarray(truth, float)
    if X.ndim == 3:
        if X.shape[0] != len(runs):
            raise ConfigError("truth", X.shape, f"one (K, 6) array per run ({len(runs)})")
        nees = np.array([res.nees(x) for res, x in zip(runs, X, strict=True)])
    else:
        nees = np.array([res.nees(X) for res in runs])
    st = anees_statistics(nees, 6, probability)
    per_frame = np.asarray(st["per_epoch"], float)
    R = len(runs)
    ca_band = chi2_band(6, R, probability)
    k = closest_approach_index(epochs, epoch_ca)
    ca = np.array([x.ca_position_error_pct_range for x in metrics])
    return {
        "runs": R, "probability": probability, "nees_mean": st["mean"],
        "nees_band": st["band"], "verdict": st["verdict"],
        "nees_band_independent": st["band_independent"],
        "nees_autocorrelation_time": st["autocorrelation_time"],
        "nees_frames_in_band": st["epochs_in_band"],
        "nees_ca": float(per_frame[k]), "nees_ca_band": list(ca_band),
        "ca_error_pct_range_median": float(np.median(ca)),
        "ca_error_pct_range_max": float(np.max(ca)),
        "resets": int(sum(len(res.info.get("resets", ())) for res in runs)),
        "nees_per_frame": per_frame.tolist()}


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
    rows = []
    for v, d, ph in itertools.product(v_inf_km_s, closest_approach_km, phase_deg):
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
        rows.append(row)
    return rows
