"""A dataset navigated over Monte Carlo runs: are the filter's 3-sigma bounds true?

``starnav navigate DATASET --runs N`` (N >= 2): a filter's consistency can only be judged over
independent realisations of what it does not know, and a dataset holds one.

1. Every frame's radiance and truth are read back (:func:`rendered_from_dataset`; nothing is
   rendered again).
2. Run ``r`` re-exposes every frame with its own temporal noise, draws a fresh attitude
   knowledge error and initial error, and runs the chain and the filter through the sweep's own
   tasks (:mod:`starnav.batch.tasks`); run 0 keeps the dataset's acquisitions and attitude.
3. :func:`~starnav.batch.consistency.consistency_metrics` judges the covariance (NEES, NIS and
   the 3-sigma fraction against their bands).

Outputs (:func:`write`): ``metrics.json``, ``runs.csv``, ``consistency.png``,
``position_error.png``, ``velocity_error.png``, ``report.md`` (the verdict line first).

Index
-----
:func:`navigate_runs`, :func:`rendered_from_dataset`, :func:`filter_runs` (the filter alone
re-run on one run's measurements), :func:`verdict_line`, :func:`write`.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.atomic import atomic_write_text
from starnav.batch.consistency import consistency_metrics
from starnav.batch.runs import over_runs, run_ids
from starnav.batch.table import to_csv
from starnav.batch.tasks import RenderedFrame, expose_sequence_task, expose_task, filter_task
from starnav.config import scenario_to_dict
from starnav.config_base import SIView
from starnav.errors import ConfigError, DataFileError
from starnav.navigation import plots as P
from starnav.navigation.dynamics import Dynamics, MoonEphemeris
from starnav.navigation.ekf import EkfPriors
from starnav.navigation.pipeline import (
    FilterResult,
    FrameMeasurement,
    initial_error_normal,
    run_filter,
)
from starnav.simulate.attitude import uses_star_attitude


def rendered_from_dataset(dataset: Any) -> list[RenderedFrame]:
    """Each frame of a dataset as a :class:`~starnav.batch.tasks.RenderedFrame` (electron
    radiance from ``radiance.exr``, geometry from ``truth.json``), before any work on them."""
    frames = list(dataset)
    missing = [f.index for f in frames if not (f.directory / "radiance.exr").is_file()]
    if missing:
        raise DataFileError(
            f"dataset {str(dataset.path)!r}: frames {missing[:5]} have no radiance.exr; "
            "--runs re-exposes the rendered radiance (make the dataset with radiance)")
    out = []
    for f in frames:
        img = f.radiance()
        le = np.asarray(img.Le, np.float32)
        out.append(RenderedFrame(int(f.index), f.truth, tuple(le.shape), (0, 0),  # type: ignore[arg-type]
                                 le, 0.0, str(img.meta.get("render", {}).get("variant", ""))))
    return out


def navigate_runs(dataset: Any, runs: int, *, scenario: Any | None = None,
                  probability: float = 0.99) -> dict[str, Any]:
    """Navigate ``dataset`` (at its selected exposure) over ``runs`` Monte Carlo runs (module
    steps 1-3).

    Parameters
    ----------
    dataset : starnav.dataset.Dataset
    runs : int
        Number of runs (>= 2).
    scenario : Scenario, optional
        What to re-expose and navigate with; default the dataset's own at its exposure.
    probability : float
        Two-sided probability of the NEES and NIS bands.

    Returns
    -------
    dict
        ``metrics`` (:func:`~starnav.batch.consistency.consistency_metrics` plus the limb
        error and timing), ``result`` (the :class:`~starnav.batch.tasks.PointResult`),
        ``epochs``.
    """
    if not (isinstance(runs, int) and runs >= 2):
        raise ConfigError("runs", runs, "an integer >= 2 (one run says nothing about "
                          "consistency)")
    sc = scenario if scenario is not None else dataset.scenario()
    cfg = scenario_to_dict(sc)
    cfg["detector"]["exposure_time_s"] = float(dataset.exposure_time)
    windows = str(dataset.manifest.get("options", {}).get("windows", "second"))
    t0 = time.perf_counter()
    rendered = rendered_from_dataset(dataset)
    if uses_star_attitude(sc):  # the tracker's attitude of a frame needs the frames before
        frames = expose_sequence_task(cfg, rendered, runs, windows, 1.0)
    else:
        frames = [expose_task(cfg, r, runs, windows, 1.0) for r in rendered]
    res = filter_task(cfg, 0, frames, runs)
    m = consistency_metrics(res, probability)
    le = res.limb_errors_px.astype(float)
    m["limb_error_px"] = {"bias": float(le.mean()) if le.size else None,
                          "std": float(le.std()) if le.size else None, "points": int(le.size)}
    m["exposure_s"] = float(dataset.exposure_time)
    m["frames"] = len(rendered)
    m["wall_time_s"] = time.perf_counter() - t0
    return {"metrics": m, "result": res, "epochs": res.epochs}


def filter_runs(measurements: Sequence[FrameMeasurement], truth: ArrayLike, *,
                dynamics: Dynamics, moon: MoonEphemeris, P0: ArrayLike, runs: int,
                seed: int = 0, options: SIView | None = None,
                priors: EkfPriors | None = None) -> list[FilterResult]:
    """The filter re-run ``runs`` times (runs 1..runs) on the same measurements from
    ``x0 ~ N(truth[0], P0)``, run ``r``'s initial error from
    :func:`~starnav.navigation.pipeline.initial_error_normal` ``(seed, r)``: the Monte Carlo of
    the filter alone (what :func:`~starnav.navigation.report.write_outputs` reports as
    ``monte_carlo``). ``truth``: EMB-centred ``(K, 6)`` at the measurement epochs [m, m/s]."""
    ids = run_ids(runs, 1)
    X = np.asarray(truth, float)
    P = np.asarray(P0, float)
    L = np.linalg.cholesky(P)
    t0 = float(measurements[0].epoch_tdb)
    return over_runs(lambda r: run_filter(
        measurements, dynamics=dynamics, moon=moon, t0=t0,
        x0=X[0] + L @ initial_error_normal(seed, r), P0=P, options=options, priors=priors),
        ids)


def verdict_line(m: dict[str, Any]) -> str:
    """One sentence: are the bounds true, and how accurate (the report's first line): the
    time-averaged ANEES against its band corrected for the NEES series' autocorrelation, the
    per-epoch ANEES's fraction of epochs inside its 95 % band, position and velocity NEES."""
    if "nees_mean" not in m:
        return "No truth in the dataset: no consistency verdict."
    lo, hi = m["nees_band"]
    st = m.get("nees", {})
    w = m["within_3sigma"]["all"]
    fin = m["final_position_error_pct_range"]
    tau = (f", {st['effective_samples']:.0f} effective samples of {m['runs']} runs x "
           f"{st['epochs']} epochs" if "effective_samples" in st else "")
    blocks = "".join(
        f"; {name} NEES {m[key]['mean']:.2f} for 3 ({m[key]['verdict']})"
        for key, name in (("nees_position", "position"), ("nees_velocity", "velocity"))
        if key in m and "mean" in m[key])
    return (f"**{m['verdict'].capitalize()}** over {m['runs']} runs: time-averaged NEES "
            f"{m['nees_mean']:.2f} for 6 states (two-sided {100 * m['probability']:.0f} % band "
            f"{lo:.2f}-{hi:.2f}{tau}){blocks}; run-averaged NEES inside its 95 % band at "
            f"{100 * m['nees_steps_in_band']:.0f} % of the epochs (consistent: 95 %); "
            f"{100 * w:.2f} % of the errors inside their 3-sigma bounds "
            f"(a consistent filter: 99.73 %); final position error {fin['median']:.3g} % of "
            f"range (median; 90 % of runs below {fin['p90']:.3g} %).")


def write(out_dir: str | os.PathLike[str], nav: dict[str, Any], *,
          plots: bool = True) -> dict[str, Path]:
    """Write the outputs of :func:`navigate_runs` into ``out_dir`` (the module lists them)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    m, res = nav["metrics"], nav["result"]
    paths = {"metrics": out / "metrics.json", "runs": out / "runs.csv",
             "report": out / "report.md"}
    atomic_write_text(paths["metrics"], json.dumps(_clean(m), indent=2, allow_nan=False)
                      + "\n")
    cols = [c for c in res.rows[0] if c not in ("point",)] if res.rows else []
    atomic_write_text(paths["runs"], to_csv(res.rows, cols))
    if plots and res.errors is not None and res.sigma3 is not None:
        paths["consistency"] = P.plot_consistency(
            nav["epochs"], np.asarray(m["nees_per_step"]),
            np.asarray(m.get("nis_per_step", [math.nan] * len(nav["epochs"]))),
            out / "consistency.png", m["runs"])
        for kind in ("position", "velocity"):
            paths[f"{kind}_error"] = P.plot_state_errors(
                nav["epochs"], res.errors[0], res.sigma3[0], out / f"{kind}_error.png", kind,
                list(res.errors[1:]))
    L = ["# Navigation over Monte Carlo runs", "", verdict_line(m), "",
         f"- dataset exposure: {m['exposure_s'] * 1e3:.4g} ms, {m['frames']} frames, "
         f"{m['runs']} runs (detector noise, attitude knowledge error, initial error)",
         f"- limb points: bias {_fmt(m['limb_error_px']['bias'], '+.3f')} px, std "
         f"{_fmt(m['limb_error_px']['std'], '.3f')} px"]
    if "nis_mean" in m:
        L.append(f"- NIS: mean {m['nis_mean']:.2f} for 3 dof over {m['nis_fixes']} fixes "
                 f"(band {m['nis_band'][0]:.2f}-{m['nis_band'][1]:.2f}, {m['nis']['verdict']}; "
                 f"epochs inside the per-epoch 95 % band "
                 f"{100 * m['nis'].get('epochs_in_band', math.nan):.0f} %)")
    if "nees_steps_in_band" in m:
        w = m["within_3sigma"]
        L += [f"- steps whose run-averaged NEES is inside its 95 % band: "
              f"{100 * m['nees_steps_in_band']:.0f} % (above "
              f"{100 * m['nees'].get('epochs_above', math.nan):.0f} %, below "
              f"{100 * m['nees'].get('epochs_below', math.nan):.0f} %)",
              f"- NEES autocorrelation time {m['nees'].get('autocorrelation_time', math.nan):.2g}"
              f" epochs (window {m['nees'].get('window', 0)}): the time average is worth "
              f"{m['nees'].get('effective_samples', math.nan):.0f} independent samples; the band "
              f"of independent epochs would be {m['nees']['band_independent'][0]:.2f}-"
              f"{m['nees']['band_independent'][1]:.2f}",
              f"- inside the 3-sigma bounds: position {100 * w['position']:.2f} %, velocity "
              f"{100 * w['velocity']:.2f} %"]
    L += ["", "Figures: `consistency.png`, `position_error.png`, `velocity_error.png`; "
          "every number in `metrics.json`, every run in `runs.csv`.", ""]
    atomic_write_text(paths["report"], "\n".join(L))
    return paths


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _clean(x: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
