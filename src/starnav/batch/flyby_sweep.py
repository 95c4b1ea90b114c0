"""``starnav sweep`` of a fly-by scenario: the rendered fly-by sweep on the batch runner.

A fly-by point cannot be split into render, expose and filter tasks (its acquisitions are a
closed loop), so one task is one point: :func:`starnav.simulate.flyby.flyby_sweep_row`, the
function the in-process :func:`~starnav.simulate.flyby.flyby_rendered_sweep` maps; the table
does not depend on the runner or the order.

1. Validate first, nothing written: a fly-by, its axes (:func:`parse_sweep_axes`, through the
   grid parser of every sweep), every point's scenario and scene, runs, output, runner.
2. One task per point; rows sorted by point.
3. Outputs staged and renamed to ``out``: ``sweep.csv``, ``sweep.md``, ``sweep.png``,
   ``sweep.json``, ``scenario.resolved.yaml`` (docs/sweep.md).

Index
-----
:func:`run_flyby_sweep`, :class:`FlybySweepResult`, :func:`parse_sweep_axes`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from starnav import __version__
from starnav.atomic import atomic_write_text
from starnav.batch.cluster import open_runner
from starnav.batch.grid import parse_axis
from starnav.batch.sweep import MARKER, check_sweep_output, staging
from starnav.config import Scenario, scenario_to_dict
from starnav.dataset import format as F
from starnav.dataset.runner import TaskRunner
from starnav.errors import ConfigError
from starnav.simulate.flyby import (
    SWEEP_AXES,
    check_flyby_scenario,
    flyby_sweep_points,
    flyby_sweep_row,
    write_flyby_sweep,
)

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
    (:data:`~starnav.simulate.flyby.SWEEP_AXES`, with or without ``trajectory.flyby.``) and
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
        handles = {rn.submit(flyby_sweep_row, values, scenario_to_dict(sc), n_runs, probability,
                             key=f"flyby-point-{i}-{os.getpid()}-{time.monotonic_ns()}"): i
                   for i, (values, sc) in enumerate(points)}
        got: dict[int, dict[str, Any]] = {}
        if progress is not None:
            progress(0, len(points))
        for h, row in rn.as_completed(list(handles)):
            got[handles[h]] = row
            if progress is not None:
                progress(len(got), len(points))
        desc = rn.description
    rows = [got[i] for i in range(len(points))]
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

