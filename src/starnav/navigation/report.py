"""Summary and outputs of a navigation run: estimates (CSV), metrics (JSON), figures (PNG).

:func:`summarize` condenses a :class:`~starnav.navigation.pipeline.NavigationRun` (and optional
Monte Carlo runs) into plain numbers; :func:`write_outputs` writes, into one directory,

=====================  ========================================================================
file                   content
=====================  ========================================================================
``estimates.csv``      per frame: epoch, status, fix, estimate, 1-sigma, errors, NIS, timings
``metrics.json``       :func:`summarize` (limb error bias/std, final errors, consistency,
                       timing and memory statistics)
``limb_error_pdf.png``  figure 8/22/25 of the paper
``position_error.png``  figure 9a/23a/26a
``velocity_error.png``  figure 9b/23b/26b
``consistency.png``    NEES and NIS
``resources.png``      figure 10/24/27 (CPU time, peak memory)
``overlay_NNNNNN.png``  the first, middle and last frame with a limb: segments DN, windows,
                       limb points (RANSAC inliers and outliers), fitted and true limb
``report.md``          the run in words and numbers, linking every figure
=====================  ========================================================================

Every file is written to a temporary name and renamed (nothing half-written).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from starnav.atomic import atomic_write_text
from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError
from starnav.navigation import plots as P
from starnav.navigation.dynamics import MoonEphemeris, PointMassDynamics
from starnav.navigation.frames import NavDataset
from starnav.navigation.metrics import ErrorSummary, anees_statistics
from starnav.navigation.pipeline import STAGES, FilterResult, NavigationRun, navigate
from starnav.navigation.schema import NavigationConfig

#: The tracker's processing budgets (the seed paper's processor-in-the-loop figures).
BUDGET_MS = 5.0
TRACKER_MEMORY_KB = 900.0


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def summarize(run: NavigationRun, mc: Sequence[FilterResult] = ()) -> dict[str, Any]:
    """Plain-number summary of a run: :class:`~starnav.navigation.metrics.NavMetrics` (the
    vocabulary shared with the sweep table) plus statuses, limb-point errors, the Monte Carlo
    re-runs of the filter ``mc`` (:func:`starnav.batch.montecarlo.filter_runs`), timings and
    memory (module docstring)."""
    f = run.filter
    statuses: dict[str, int] = {}
    for m in run.measurements:
        statuses[m.status] = statuses.get(m.status, 0) + 1
    out: dict[str, Any] = {**run.metrics().as_dict(), "status_counts": statuses,
                           "bias_model": f.bias_model}
    le = np.concatenate(run.limb_errors) if run.limb_errors else np.empty(0)
    out["limb_error_px"] = ErrorSummary.of(le).as_dict()
    if run.truth is not None and mc:
        # per-epoch ANEES over the runs and the time average with its band corrected for the
        # NEES series' autocorrelation (metrics.anees_statistics; docs/navigation.md)
        fin = np.array([np.linalg.norm(r.errors(run.truth)[-1, :3]) for r in mc])
        out["monte_carlo"] = {
            "runs": len(mc),
            **{name: _statistics(np.array([getattr(r, name)(run.truth) for r in mc]), dof)
               for name, dof in (("nees", 6), ("nees_position", 3), ("nees_velocity", 3))},
            "nis": _statistics(np.array([r.nis for r in mc]), 3),
            "final_position_error_rms_m": float(np.sqrt(np.mean(fin**2))),
        }
    st = run.stage_times_s * 1e3
    out["timing_ms"] = {
        "stage_median": {s: _finite(np.nanmedian(st[:, j])) if np.any(np.isfinite(st[:, j]))
                         else None for j, s in enumerate(STAGES)},
        "chain_cpu_median": float(np.median(run.cpu_times_s) * 1e3),
        "chain_cpu_p95": float(np.percentile(run.cpu_times_s, 95) * 1e3),
        "budget": BUDGET_MS,
    }
    if run.peak_memory_bytes is not None:
        out["memory_kb"] = {"peak_max": float(np.max(run.peak_memory_bytes) / 1024.0),
                            "peak_median": float(np.median(run.peak_memory_bytes) / 1024.0),
                            "tracker_budget": TRACKER_MEMORY_KB}
    return out


def _statistics(values: np.ndarray, dof: int) -> dict[str, Any]:
    """:func:`~starnav.navigation.metrics.anees_statistics` of ``(runs, epochs)`` values,
    JSON-safe and without the per-epoch bands."""
    st = anees_statistics(values, dof)
    st.pop("per_epoch_band", None)
    return {k: (_finite(v) if isinstance(v, float) else
                [_finite(x) for x in v] if isinstance(v, list) else v) for k, v in st.items()}


def estimates_csv(run: NavigationRun) -> str:
    """The ``estimates.csv`` text (one row per frame; SI units, names carry them)."""
    f = run.filter
    buf = io.StringIO()
    w = csv.writer(buf)
    head = ["index", "epoch_tdb_s", "status", "fix_x_m", "fix_y_m", "fix_z_m",
            "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s",
            "sx_m", "sy_m", "sz_m", "svx_m_s", "svy_m_s", "svz_m_s", "accepted", "nis"]
    if run.truth is not None:
        head += ["ex_m", "ey_m", "ez_m", "evx_m_s", "evy_m_s", "evz_m_s", "nees"]
    head += [f"t_{s}_ms" for s in STAGES] + ["cpu_ms"]
    w.writerow(head)
    sig = np.sqrt(np.einsum("kii->ki", f.covariances[:, :6, :6]))
    err = f.errors(run.truth) if run.truth is not None else None
    ne = f.nees(run.truth) if run.truth is not None else None
    for k, m in enumerate(run.measurements):
        fix = m.position if m.position is not None else [math.nan] * 3
        row: list[Any] = [m.index, f"{f.epochs[k]:.3f}", m.status]
        row += [f"{v:.3f}" for v in fix]
        row += [f"{v:.6f}" for v in f.states[k, :6]]
        row += [f"{v:.6g}" for v in sig[k]]
        row += [int(f.accepted[k]), f"{f.nis[k]:.6g}"]
        if err is not None and ne is not None:
            row += [f"{v:.6f}" for v in err[k]] + [f"{ne[k]:.6g}"]
        row += [f"{v * 1e3:.4f}" for v in run.stage_times_s[k]]
        row += [f"{run.cpu_times_s[k] * 1e3:.4f}"]
        w.writerow(row)
    return buf.getvalue()


def overlay_frames(run: NavigationRun, count: int = 3) -> list[int]:
    """Indices (positions in ``run.measurements``) of the frames shown as overlays: the first,
    the middle and the last of those with limb points (fewer when fewer have them)."""
    have = [k for k, m in enumerate(run.measurements) if m.limb is not None and len(m.limb.uv)]
    if not have:
        return []
    pick = [have[0], have[len(have) // 2], have[-1]][:count] if count >= 3 else have[:count]
    return sorted(dict.fromkeys(pick))


def write_outputs(run: NavigationRun, out_dir: str | os.PathLike[str],
                  mc: Sequence[FilterResult] = (), plots: bool = True,
                  frames: Sequence[Any] = (), camera: Any | None = None,
                  radii_m: Sequence[float] | None = None) -> dict[str, Path]:
    """Write the files of the module table into ``out_dir``; returns their paths by name.
    ``frames`` (the run's :class:`~starnav.navigation.frames.NavFrame`, in order), ``camera``
    and ``radii_m`` [m] are needed for the overlay figures (none without them)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    paths["estimates"] = out / "estimates.csv"
    atomic_write_text(paths["estimates"], estimates_csv(run))
    summary = summarize(run, mc)
    paths["metrics"] = out / "metrics.json"
    atomic_write_text(paths["metrics"], json.dumps(summary, indent=2, allow_nan=False) + "\n")
    if not plots:
        return paths
    le = np.concatenate(run.limb_errors) if run.limb_errors else np.empty(0)
    paths["limb_error_pdf"] = P.plot_limb_error_pdf(le, out / "limb_error_pdf.png")
    f = run.filter
    if run.truth is not None:
        e = f.errors(run.truth)
        mce = [r.errors(run.truth) for r in mc]
        paths["position_error"] = P.plot_state_errors(f.epochs, e, f.sigma3(),
                                                      out / "position_error.png", "position",
                                                      mce)
        paths["velocity_error"] = P.plot_state_errors(f.epochs, e, f.sigma3(),
                                                      out / "velocity_error.png", "velocity",
                                                      mce)
        if mc:
            ne = np.mean([r.nees(run.truth) for r in mc], axis=0)
            nis = np.nanmean([r.nis for r in mc], axis=0)
            runs = len(mc)
        else:
            ne, nis, runs = f.nees(run.truth), f.nis, 1
        paths["consistency"] = P.plot_consistency(f.epochs, ne, nis, out / "consistency.png",
                                                  runs)
    paths["resources"] = P.plot_resources(run.cpu_times_s, run.peak_memory_bytes,
                                          out / "resources.png", BUDGET_MS, TRACKER_MEMORY_KB)
    if frames and camera is not None:
        r = tuple(radii_m) if radii_m is not None else (MOON_RADIUS,) * 3
        for k in overlay_frames(run):
            m = run.measurements[k]
            paths[f"overlay_{m.index:06d}"] = P.plot_limb_overlay(
                frames[k], m, camera, out / f"overlay_{m.index:06d}.png", radii_m=r)
    return paths


def write_report(out_dir: str | os.PathLike[str], summary: dict[str, Any],
                 paths: dict[str, Path]) -> Path:
    """``report.md`` of a single navigation run: the numbers of :func:`summarize` with their
    units, the budget check, and every figure linked (paths relative to ``out_dir``)."""
    out = Path(out_dir)
    le = summary["limb_error_px"]
    tm = summary["timing_ms"]
    L = ["# Navigation run", "",
         f"- frames {summary['frames']}, fixes {summary['fixes']}, accepted by the filter "
         f"{summary['accepted']}",
         f"- limb points vs the true limb: bias {_f(le.get('bias'), '+.3f')} px, std "
         f"{_f(le.get('std'), '.3f')} px ({le.get('count', '-')} points)"]
    if summary.get("final_position_error_m") is not None:
        L.append(f"- final position error {summary['final_position_error_m'] / 1e3:.3g} km "
                 f"({summary['final_position_error_pct_range']:.3g} % of range), velocity "
                 f"{summary['final_velocity_error_m_s']:.3g} m/s; mean NEES "
                 f"{summary['nees_mean']:.3g} (6 states, 6 expected)")
    L.append(f"- chain CPU time: median {tm['chain_cpu_median']:.3g} ms, 95th percentile "
             f"{tm['chain_cpu_p95']:.3g} ms; budget {tm['budget']:g} ms")
    if budget_warning(summary):
        L.append(f"- **{budget_warning(summary)}**")
    L += ["", "## Figures", ""]
    over = sorted(k for k in paths if k.startswith("overlay_"))
    if over:
        L += ["### The frames as the chain saw them", "",
              "Segments readout (DN, asinh stretch), windows (orange rectangles), pixel-level "
              "limb points (green: RANSAC inliers, red crosses: outliers), refined points "
              "(cyan), the limb of the fix (blue) and the true limb (magenta, dashed); axes in "
              "pixels. The first, middle and last frame with a limb.", ""]
        for k in over:
            L += [f"![frame {int(k.split('_')[1])}: limb points, windows, fitted and true limb]"
                  f"({paths[k].name})", ""]
    for key, what in (("limb_error_pdf", "limb-point error PDF"),
                      ("position_error", "position error and 3-sigma bounds"),
                      ("velocity_error", "velocity error and 3-sigma bounds"),
                      ("consistency", "NEES and NIS"),
                      ("resources", "CPU time and peak memory per frame")):
        if key in paths:
            L += [f"![{what}]({paths[key].name})", ""]
    L += ["Per-frame numbers: `estimates.csv`; every metric: `metrics.json`.", ""]
    p = out / "report.md"
    atomic_write_text(p, "\n".join(L))
    return p


def budget_warning(summary: dict[str, Any]) -> str | None:
    """One line when the median chain CPU time exceeds the tracker's budget
    (:data:`BUDGET_MS`), else None."""
    tm = summary.get("timing_ms") or {}
    med, budget = tm.get("chain_cpu_median"), tm.get("budget", BUDGET_MS)
    if med is None or not med > budget:
        return None
    return (f"warning: the chain's median CPU time {med:.3g} ms exceeds the tracker's "
            f"{budget:g} ms budget (Python on the machine that ran it; see resources.png)")


def _f(x: Any, spec: str) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "-"
    return format(v, spec) if math.isfinite(v) else "-"


def navigate_dataset(
    dataset: Any,
    out_dir: str | os.PathLike[str],
    *,
    config: Any | None = None,
    seed: int | None = None,
    dynamics: Any | None = None,
    measure_memory: bool = True,
    plots: bool = True,
    scenario: Any | None = None,
    frames: Sequence[Any] | None = None,
    chains: Sequence[Any] | None = None,
) -> dict[str, Any]:
    """Navigate over a dataset and write every output (the library side of ``starnav navigate``):
    the nominal run (run 0). Its Monte Carlo runs are :mod:`starnav.batch.montecarlo`'s:
    ``navigate_runs`` re-exposes the frames, ``filter_runs`` re-runs the filter on this run's
    measurements (:func:`write_outputs` takes those).

    Parameters
    ----------
    dataset : NavDataset
        Frames with segments, windows, attitude, Sun direction and truth
        (:mod:`starnav.navigation.frames`).
    out_dir : path
        Output directory (created).
    config : NavigationConfig, optional
        The ``navigation`` section; default its defaults.
    seed : int, optional
        Seed of the initial errors and of RANSAC (:func:`~starnav.navigation.pipeline.navigate`);
        default the scenario's.
    dynamics : Dynamics and MoonEphemeris, optional
        Default :class:`~starnav.navigation.dynamics.PointMassDynamics` with the configured step.
    measure_memory : bool
        Trace the peak memory per frame.
    plots : bool
        Write the PNG figures.
    scenario : Scenario, optional
        What the frames were made with (the chain's noise, terrain and attitude models);
        default ``dataset.scenario()`` when the dataset has one.
    frames, chains : sequences, optional
        The dataset's frames as the chain is to see them and the chain options of each (the
        tracker's own attitude and its covariance:
        :func:`starnav.dataset.attitude.star_attitude_frames`); default the dataset's frames
        and one chain.

    Returns
    -------
    dict
        The :func:`summarize` metrics, plus ``"paths"``.
    """
    if not isinstance(dataset, NavDataset):
        missing = [a for a in ("camera", "__len__", "__iter__") if not hasattr(dataset, a)]

        raise ConfigError("dataset", type(dataset).__name__,
                          "a NavDataset (camera, len(), iteration over NavFrame); missing "
                          + ", ".join(missing))
    cfg = config if config is not None else NavigationConfig()
    dyn = dynamics if dynamics is not None else PointMassDynamics(step_s=cfg.filter.rk4_step_s)
    if not isinstance(dyn, MoonEphemeris):
        raise ConfigError("dynamics", type(dyn).__name__, "an object with moon_state(t)")
    P0 = cfg.initial_covariance()
    if scenario is None and callable(getattr(dataset, "scenario", None)):
        scenario = dataset.scenario()
    if seed is None:
        seed = int(scenario.seed) if scenario is not None else 0
    if (frames is None) != (chains is None) or (frames is not None and chains is not None
                                                 and len(frames) != len(chains)):
        raise ConfigError("frames/chains", None, "both or neither, one chain per frame")
    chain = cfg.chain_options(scenario=scenario)
    run = navigate(dataset if frames is None else frames, camera=dataset.camera,
                   dynamics=dyn, moon=dyn, P0=P0, chain=chain, chains=chains,
                   ekf=cfg.filter.to_si(), ekf_priors=cfg.ekf_priors(
                       chain.calibration, None if scenario is None
                       else float(scenario.detector.exposure_time_s)),
                   seed=seed, measure_memory=measure_memory)
    shown = list(dataset) if plots else []
    paths = write_outputs(run, out_dir, plots=plots, frames=shown,
                          camera=dataset.camera, radii_m=chain.fix.radii_m)
    out = Path(out_dir)
    atomic_write_text(out / "navigation_config.json",
                       json.dumps(cfg.model_dump(mode="json"), indent=2) + "\n")
    paths["config"] = out / "navigation_config.json"
    summary = summarize(run)
    paths["report"] = write_report(out, summary, paths)
    summary["paths"] = {k: str(v) for k, v in paths.items()}
    return summary
