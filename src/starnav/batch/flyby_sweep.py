"""The rendered fly-by sweep: the closed loop at every point of a grid of fly-by geometries.

A fly-by point cannot be split into render, expose and filter tasks (its acquisitions are a
closed loop), so one point is one call of :func:`flyby_sweep_row` (the closed loop of
:mod:`starnav.batch.flyby`, rendered once, ``runs`` runs), mapped by
:func:`starnav.batch.runs.over_points`: in this process (:func:`flyby_rendered_sweep`,
``starnav navigate SCENARIO --sweep``) or one task per point on the batch runner
(:func:`run_flyby_sweep`, ``starnav sweep``); the table depends on neither.

1. Validate first, nothing written: a fly-by, its axes (:func:`parse_sweep_axes`, through the
   grid parser of every sweep), every point's scenario and scene (:func:`flyby_sweep_points`),
   runs, output, runner.
2. One row per point, in grid order (the last axis varying fastest).
3. Outputs (:func:`write_flyby_sweep`; staged and renamed to ``out`` by
   :func:`run_flyby_sweep`): ``sweep.csv``, ``sweep.md``, ``sweep.png``, and from
   ``starnav sweep`` ``sweep.json``, ``scenario.resolved.yaml`` (docs/sweep.md).

Index
-----
:func:`run_flyby_sweep`, :class:`FlybySweepResult`, :func:`parse_sweep_axes`,
:func:`flyby_rendered_sweep`, :func:`flyby_sweep_points`, :func:`flyby_sweep_row`,
:func:`write_flyby_sweep`, :data:`SWEEP_AXES`, :data:`SWEEP_COLUMNS`.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from starnav import __version__
from starnav.atomic import atomic_path, atomic_write_text
from starnav.batch.cluster import open_runner
from starnav.batch.flyby import flyby_closed_loop
from starnav.batch.grid import parse_axis
from starnav.batch.runs import over_points
from starnav.batch.sweep import MARKER, check_sweep_output, staging
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import set_dotted
from starnav.dataset import format as F
from starnav.dataset.runner import TaskRunner
from starnav.errors import ConfigError
from starnav.simulate.flyby import check_flyby_scenario
from starnav.simulate.frames import Simulator

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FlybySweepResult:
    """What :func:`run_flyby_sweep` produced: the rows (one per point, in grid order), the
    written files by name, the wall time [s] and the runner's description."""

    out: Path
    rows: list[dict[str, Any]]
    paths: dict[str, Path]
    elapsed_s: float
    runner: str


def parse_sweep_axes(items: Sequence[str], flag: str = "--sweep") -> dict[str, list[float]]:
    """``["v_inf_km_s=0.4,0.6", "phase_at_ca_deg=30,60"]`` -> ``{axis: values}``: the grid
    parser of every sweep (:func:`starnav.batch.grid.parse_grid`) with the fly-by's axes
    (:data:`SWEEP_AXES`, with or without ``trajectory.flyby.``) and
    numbers only; the CLI's ``navigate --sweep`` / ``sweep --grid``, named by ``flag``. A bad
    axis or value is a ConfigError naming it."""
    out: dict[str, list[float]] = {}
    for item in items:
        try:
            axis = parse_axis(item)
        except ConfigError as err:
            raise ConfigError(err.field.replace("--grid", flag, 1), err.value,
                              err.expected) from None
        key = axis.key.removeprefix("trajectory.flyby.")
        if key not in SWEEP_AXES:
            raise ConfigError(flag, item, f"AXIS=V1,V2,... with AXIS one of "
                              f"{', '.join(SWEEP_AXES)}")
        bad = [v for v in axis.values
               if isinstance(v, bool) or not isinstance(v, int | float)]
        if bad:
            raise ConfigError(f"{flag} {key}", bad[0], "comma-separated numbers")
        if key in out:
            raise ConfigError(flag, key, "each axis once (give all its values in one item)")
        out[key] = [float(v) for v in axis.values]
    return out


def run_flyby_sweep(scenario: Scenario, grid: Sequence[str], out: str | os.PathLike[str], *,
                    runs: int | None = None, workers: int | None = None,
                    scheduler: str | None = None, runner: TaskRunner | None = None,
                    probability: float = 0.99,
                    progress: Callable[[int, int], None] | None = None,
                    figures: bool = True, overwrite: bool = False,
                    connect_timeout_s: float = 5.0) -> FlybySweepResult:
    """Run the fly-by sweep (module essay) and write its outputs into ``out``.

    Parameters
    ----------
    scenario : Scenario
        A fly-by scenario (``trajectory.source: flyby``, ``target.kind: shape_model``).
    grid : sequence of str
        ``AXIS=V1,V2,...`` items (``--grid``); none: the scenario alone.
    runs : int, optional
        Monte Carlo runs per point; default ``navigation.runs``.
    workers, scheduler, runner, connect_timeout_s
        As :func:`starnav.batch.run_sweep`.
    probability : float
        Two-sided probability of the NEES band.
    progress : callable, optional
        ``progress(done, total)`` over the points.
    figures, overwrite : bool

    Raises
    ------
    ConfigError, DataFileError, ClusterError
        Before any rendering, with nothing written.
    """
    t0 = time.perf_counter()
    check_flyby_scenario(scenario)
    axes = parse_sweep_axes(list(grid), "--grid")
    n_runs = int(scenario.navigation.runs if runs is None else runs)
    if n_runs < 1:
        raise ConfigError("--runs", runs, "an integer >= 1")
    if not 0.0 < probability < 1.0:
        raise ConfigError("probability", probability, "in (0, 1)")
    out = Path(out)
    check_sweep_output(out, overwrite)
    points = flyby_sweep_points(scenario, axes)
    ctx = (contextlib.nullcontext(runner) if runner is not None
           else open_runner(workers, scheduler, connect_timeout_s=connect_timeout_s))
    with ctx as rn:
        rows = over_points(flyby_sweep_row, [(values, scenario_to_dict(sc), n_runs, probability)
                                             for values, sc in points],
                           runner=rn, label="flyby-point", progress=progress)
        desc = rn.description
    elapsed = time.perf_counter() - t0
    with staging(out) as tmp:
        written = write_flyby_sweep(rows, tmp, plots=figures)
        paths = {k: out / Path(v).name for k, v in written.items()}
        atomic_write_text(tmp / "scenario.resolved.yaml",
                          yaml.safe_dump(scenario_to_dict(scenario), sort_keys=False))
        F.write_json(tmp / MARKER, {
            "starnav": __version__, "kind": "flyby",
            "grid": [{"key": f"trajectory.flyby.{k}", "values": v} for k, v in axes.items()],
            "runs": n_runs, "points": len(points), "runner": desc, "elapsed_s": elapsed,
            "files": {k: p.name for k, p in paths.items()}})
    paths["sweep"] = out / MARKER
    log.info("fly-by sweep: %d points x %d runs in %.1f s (%s)", len(points), n_runs,
             elapsed, desc)
    return FlybySweepResult(out, rows, paths, elapsed, desc)


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
    log.info("fly-by sweep point %s: CA error median %.3g %% of range, NEES %.3g", values,
             row["ca_error_pct_range_median"], row["nees_mean"])
    return row


def flyby_rendered_sweep(base: Scenario, axes: dict[str, Sequence[float]], runs: int = 2, *,
                         probability: float = 0.99,
                         progress: Callable[[int, int], None] | None = None
                         ) -> list[dict[str, Any]]:
    """The closed loop (:func:`flyby_closed_loop`, render once per point) at every point of
    :func:`flyby_sweep_points` ``(base, axes)``, ``runs`` Monte Carlo runs per point, in this
    process (``starnav sweep`` runs the same rows, :func:`flyby_sweep_row`, on the batch
    runner: :func:`run_flyby_sweep`).

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
    return over_points(flyby_sweep_row, [(values, sc, runs, probability)
                                         for values, sc in points], progress=progress)


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
