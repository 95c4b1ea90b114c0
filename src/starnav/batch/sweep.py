"""What-if sweeps and Monte Carlo runs on Dask: grid -> task graph -> table, figures, report.

1. Validate everything first, nothing written: grid axes and every point's scenario
   (:mod:`starnav.batch.grid`), runs, windows mode, output directory, frames, the cluster.
2. Task graph (:mod:`starnav.batch.tasks`): render once per render group, expose per point and
   run, filter per point and run; pure functions of their inputs and of :mod:`starnav.seeding`
   keys, so the table does not depend on workers, order or re-runs.
3. Outputs written into a temporary sibling renamed to ``out`` at the end (files:
   docs/sweep.md).

Index
-----
:func:`run_sweep`, :class:`SweepResult`, :func:`summarize_points`, :func:`check_sweep_output`,
:func:`staging`, :data:`CONSISTENCY_KEYS`.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import logging
import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from starnav import __version__
from starnav.atomic import atomic_write_text, current_umask
from starnav.batch import figures as FIG
from starnav.batch.cluster import open_runner
from starnav.batch.consistency import consistency_metrics
from starnav.batch.grid import GridAxis, GridPoint, expand, parse_grid, render_config, render_groups
from starnav.batch.report import write_report
from starnav.batch.table import column_names, columns_of, write_table
from starnav.batch.tasks import (
    PointResult,
    expose_sequence_task,
    expose_task,
    filter_task,
    render_task,
)
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.dataset import format as F
from starnav.dataset.runner import TaskRunner
from starnav.dataset.writer import check_output_dir
from starnav.errors import ConfigError, DataFileError
from starnav.simulate import scene_from_scenario
from starnav.simulate.acquire import check_windows_mode
from starnav.simulate.attitude import uses_star_attitude

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]
MARKER = "sweep.json"
EXPOSURE_KEY = "detector.exposure_time_s"
_COUNTER = itertools.count()


@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` produced.

    Attributes
    ----------
    out : Path
    rows : list of dict
        The table, one dict per (point, run), sorted.
    columns : list of str
    points : list of GridPoint
    paths : dict
        Written files by name (``parquet``, ``csv``, ``report``, ``sweep``, figures...).
    elapsed_s : float
        Wall time [s].
    runner : str
    render_tasks, expose_tasks, filter_tasks : int
    series : dict
        Per point: ``epochs``, ``errors``, ``sigma3``, ``limb_errors_px`` (figures).
    """

    out: Path
    rows: list[dict[str, Any]]
    columns: list[str]
    points: list[GridPoint]
    paths: dict[str, Path]
    elapsed_s: float
    runner: str
    render_tasks: int
    expose_tasks: int
    filter_tasks: int
    series: dict[int, PointResult] = field(default_factory=dict, repr=False)


# ============================================================================ checks
def check_sweep_output(out: Path, overwrite: bool = False) -> None:
    """Raise a clear error unless ``out`` can receive a sweep (nothing is created)."""
    check_output_dir(out)
    if out.exists():
        if not out.is_dir():
            raise DataFileError(f"output {str(out)!r} exists and is not a directory")
        content = list(out.iterdir())
        if content and not overwrite:
            raise DataFileError(f"output {str(out)!r} is not empty; choose a new directory or "
                                "pass overwrite (--overwrite) to replace a previous sweep")
        if content and not (out / MARKER).is_file():
            raise DataFileError(f"output {str(out)!r} is not empty and holds no previous sweep "
                                f"({MARKER}); refusing to replace it")
        parent = out.resolve().parent
        if not os.access(parent, os.W_OK | os.X_OK):
            raise DataFileError(f"output {str(out)!r}: its parent {str(parent)!r} is not "
                                "writable (the sweep is staged next to it)")


def _frames_of(sc: Scenario) -> int:
    n = len(scene_from_scenario(sc))
    if n < 1:
        raise ConfigError("trajectory", None, "at least one frame")
    return n


@contextlib.contextmanager
def staging(out: Path) -> Iterator[Path]:
    parent = out.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=parent))
    try:
        yield tmp
        if out.exists():
            if (out / MARKER).is_file():
                shutil.rmtree(out)
            else:
                out.rmdir()  # empty (checked before)
        os.chmod(tmp, 0o777 & ~current_umask())
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# ============================================================================ sweep
def run_sweep(
    scenario: Scenario | dict[str, Any],
    grid: Sequence[str | GridAxis],
    out: str | os.PathLike[str],
    *,
    runs: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    runner: TaskRunner | None = None,
    overrides: Sequence[str] = (),
    windows: str | None = None,
    progress: Progress | None = None,
    figures: bool = True,
    overwrite: bool = False,
    title: str | None = None,
    connect_timeout_s: float = 5.0,
) -> SweepResult:
    """Run a what-if grid with Monte Carlo runs and write the table, figures and report.

    Parameters
    ----------
    scenario : Scenario or dict
        Base scenario.
    grid : sequence of ``"KEY=V1,V2"`` or GridAxis
        Axes of the grid (at least one; one value = a Monte Carlo of one scenario).
    out : path
        Output directory (new, empty, or a previous sweep with ``overwrite``).
    runs : int, optional
        Monte Carlo runs per point; default ``navigation.runs``.
    workers : int, optional
        Local Dask workers (0: this process; default the CPU count).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:port``).
    runner : TaskRunner, optional
        Use this runner instead of opening one.
    overrides : sequence of str
        ``--set`` items applied to the base scenario.
    windows : {"second", "same", "none"}, optional
        Windows acquisition; default ``second`` when ``navigation.refine.enabled``, else
        ``none`` (the pixel-level algorithm reads segments only).
    progress : callable, optional
        ``progress(done, total)`` over all tasks.
    figures : bool
        Draw the figures.
    overwrite : bool
        Replace a previous sweep in ``out``.
    title : str, optional
        Report title.
    connect_timeout_s : float
        How long to wait for ``scheduler`` [s].

    Raises
    ------
    ConfigError, DataFileError, ClusterError
        Bad grid or values, unwritable or occupied output, unreachable scheduler: raised
        before any work, with nothing written.
    """
    t_start = time.perf_counter()
    base = scenario if isinstance(scenario, Scenario) else scenario_from_dict(dict(scenario))
    axes = parse_grid(grid)
    points = expand(base, axes, overrides)
    for p in points:  # source: stars needs the stars drawn: said before any work
        uses_star_attitude(p.scenario)
    n_runs = int(base.navigation.runs if runs is None else runs)
    if n_runs < 1:
        raise ConfigError("--runs", runs, "an integer >= 1")
    if windows is not None:
        check_windows_mode(windows)
    out = Path(out)
    check_sweep_output(out, overwrite)
    groups = render_groups(points)
    n_frames = {g: _frames_of(pts[0].scenario) for g, pts in groups.items()}
    ctx = contextlib.nullcontext(runner) if runner is not None else \
        open_runner(workers, scheduler, connect_timeout_s=connect_timeout_s)
    with ctx as rn:
        results, counts = _execute(rn, points, groups, n_frames, n_runs, windows, progress)
        runner_desc = rn.description
    elapsed = time.perf_counter() - t_start
    rows, columns = _rows(points, axes, results)
    with staging(out) as tmp:
        paths = _write_outputs(tmp, out, base, axes, points, groups, n_frames, n_runs, rows,
                               columns, results, runner_desc, elapsed, counts, figures, title)
    log.info("sweep: %d points x %d runs in %.1f s (%s)", len(points), n_runs, elapsed,
             runner_desc)
    return SweepResult(out=out, rows=rows, columns=columns, points=points,
                       paths={k: out / v for k, v in paths.items()}, elapsed_s=elapsed,
                       runner=runner_desc, render_tasks=counts["render"],
                       expose_tasks=counts["expose"], filter_tasks=counts["filter"],
                       series=results)


def _token(points: Sequence[GridPoint], runs: int) -> str:
    h = hashlib.sha256(F.dumps([[p.render_key, p.values] for p in points] + [runs],
                               compact=True).encode()).hexdigest()[:8]
    return f"{h}-{os.getpid()}-{next(_COUNTER)}"


def _execute(rn: TaskRunner, points: Sequence[GridPoint], groups: dict[str, list[GridPoint]],
             n_frames: dict[str, int], runs: int, windows: str | None,
             progress: Progress | None) -> tuple[dict[int, PointResult], dict[str, int]]:
    """Submit the task graph (module step 2) and collect the filter results."""
    tok = _token(points, runs)
    handles: list[Any] = []
    filters: dict[Any, int] = {}
    counts = {"render": 0, "expose": 0, "filter": 0}
    for gi, (gkey, pts) in enumerate(groups.items()):
        cfg_r, _ = render_config(pts[0].scenario)
        renders = []
        for k in range(n_frames[gkey]):
            renders.append(rn.submit(render_task, cfg_r, k, key=f"render-{tok}-{gi}-{k}"))
        handles += renders
        counts["render"] += len(renders)
        for p in pts:
            cfg_p = scenario_to_dict(p.scenario)
            mode = windows or ("second" if p.scenario.navigation.refine.enabled else "none")
            if uses_star_attitude(p.scenario):  # a frame's attitude needs the ones before
                exps = [rn.submit(expose_sequence_task, cfg_p, renders, runs, mode,
                                  p.albedo_factor, key=f"expose-{tok}-{p.index}")]
            else:
                exps = [rn.submit(expose_task, cfg_p, renders[k], runs, mode, p.albedo_factor,
                                  key=f"expose-{tok}-{p.index}-{k}")
                        for k in range(len(renders))]
            fh = rn.submit(filter_task, cfg_p, p.index,
                           exps[0] if uses_star_attitude(p.scenario) else exps, runs,
                           key=f"filter-{tok}-{p.index}")
            handles += exps + [fh]
            filters[fh] = p.index
            counts["expose"] += len(exps)
            counts["filter"] += 1
        del renders
    total = len(handles)
    if progress:
        progress(0, total)
    results: dict[int, PointResult] = {}
    done = 0
    stream = rn.as_completed(handles)
    del handles
    for h, res in stream:
        done += 1
        if h in filters:
            results[filters.pop(h)] = res
        if progress:
            progress(done, total)
    return results, counts


def _rows(points: Sequence[GridPoint], axes: Sequence[GridAxis],
          results: dict[int, PointResult]) -> tuple[list[dict[str, Any]], list[str]]:
    keys = [k for a in axes for k in a.keys]
    rows = []
    for p in points:
        for r in results[p.index].rows:
            row = dict(r)
            row["label"] = p.label
            row["exposure_time_s"] = float(p.scenario.detector.exposure_time_s)
            row["albedo_scale"] = float(p.scenario.moon.albedo_scale)
            for k in keys:
                row[k] = p.values[k]
            rows.append(row)
    rows.sort(key=lambda r: (r["point"], r["run"]))
    return rows, column_names(keys, stars=any("attitude_source" in r for r in rows))


def _write_outputs(tmp: Path, out: Path, base: Scenario, axes: Sequence[GridAxis],
                   points: Sequence[GridPoint], groups: dict[str, list[GridPoint]],
                   n_frames: dict[str, int], runs: int, rows: list[dict[str, Any]],
                   columns: list[str], results: dict[int, PointResult], runner: str,
                   elapsed: float, counts: dict[str, int], figures: bool,
                   title: str | None) -> dict[str, str]:
    """Write every output into ``tmp`` (renamed to ``out`` by the caller); relative paths."""
    paths: dict[str, str] = {}
    tp = write_table(rows, columns, tmp)
    paths.update({k: v.name for k, v in tp.items()})
    atomic_write_text(tmp / "scenario.resolved.yaml",
                      yaml.safe_dump(scenario_to_dict(base), sort_keys=False))
    for p in points:
        atomic_write_text(tmp / "points" / f"point_{p.index:03d}.yaml",
                          yaml.safe_dump(scenario_to_dict(p.scenario), sort_keys=False))
    fig_paths: dict[str, str] = {}
    if figures:
        (tmp / "figures").mkdir(exist_ok=True)
        med = {s["point"]: s for s in summarize_points(rows)}
        FIG.plot_limb_error_pdfs([(p.label, results[p.index].limb_errors_px,
                                   med.get(p.index, {}).get("limb_bias_px", math.nan),
                                   med.get(p.index, {}).get("limb_std_px", math.nan))
                                  for p in points], tmp / "figures" / "limb_error_pdf.png")
        fig_paths["limb_error_pdf"] = "figures/limb_error_pdf.png"
        FIG.plot_error_vs_exposure(rows, [k for a in axes if EXPOSURE_KEY not in a.keys
                                          for k in a.keys],
                                   tmp / "figures" / "error_vs_exposure.png")
        fig_paths["error_vs_exposure"] = "figures/error_vs_exposure.png"
        if "attitude_source" in columns:
            FIG.plot_attitude_vs_exposure(rows, tmp / "figures" / "attitude_vs_exposure.png")
            fig_paths["attitude_vs_exposure"] = "figures/attitude_vs_exposure.png"
        for p in points:
            res = results[p.index]
            if res.errors is None or res.sigma3 is None or len(res.epochs) < 2:
                continue
            name = f"figures/error_vs_time_point_{p.index:03d}.png"
            FIG.plot_error_vs_time(res.epochs, res.errors, res.sigma3, tmp / name, p.label)
            fig_paths[f"error_vs_time_{p.index:03d}"] = name
    paths.update(fig_paths)
    consistency = ({p.index: consistency_metrics(results[p.index]) for p in points}
                   if runs >= 2 else {})
    info = {
        "starnav": __version__,
        "grid": [{"key": a.key, "values": list(a.values)} for a in axes],
        "runs": runs,
        "points": [{"index": p.index, "label": p.label, "values": p.values,
                    "render_group": list(groups).index(p.render_key),
                    "albedo_factor": p.albedo_factor} for p in points],
        "render_groups": [{"key": k, "frames": n_frames[k],
                           "points": [p.index for p in v]} for k, v in groups.items()],
        "tasks": counts,
        "runner": runner,
        "elapsed_s": elapsed,
        "columns": [{"name": c.name, "type": c.kind, "unit": c.unit,
                     "description": c.description}
                    for c in columns_of("attitude_source" in columns)],
        "files": paths,
        "consistency": {str(k): {key: v.get(key) for key in CONSISTENCY_KEYS if key in v}
                        for k, v in consistency.items()},
    }
    F.write_json(tmp / MARKER, info)
    paths["sweep"] = MARKER
    write_report(tmp / "report.md", base=base, axes=axes, points=points, rows=rows,
                 runs=runs, n_frames=n_frames, groups=groups, runner=runner, elapsed=elapsed,
                 counts=counts, figures=fig_paths, title=title, consistency=consistency)
    paths["report"] = "report.md"
    return paths


#: What ``sweep.json`` keeps of each point's consistency (the per-step lists stay out).
CONSISTENCY_KEYS = ("runs", "probability", "verdict", "nees_mean", "nees_band",
                    "nees_steps_in_band", "nees", "nees_position", "nees_velocity", "nis",
                    "within_3sigma", "final_position_error_pct_range")


def summarize_points(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per point: the median over runs of every numeric column (and the first label)."""
    by: dict[int, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(int(r["point"]), []).append(r)
    out = []
    for p, rs in sorted(by.items()):
        s: dict[str, Any] = {"point": p, "label": rs[0]["label"], "runs": len(rs)}
        for k, v in rs[0].items():
            if k in s or isinstance(v, bool) or not isinstance(v, int | float):
                continue
            vals = np.array([float(r[k]) for r in rs], float)
            vals = vals[np.isfinite(vals)]
            s[k] = float(np.median(vals)) if vals.size else math.nan
        s["readout_feasible"] = all(bool(r["readout_feasible"]) for r in rs)
        out.append(s)
    return out
