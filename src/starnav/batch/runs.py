"""The one driver of Monte Carlo runs and grid points: every loop over runs or points is here.

A run is a pure function of its number (its random streams are keyed by it in
:mod:`starnav.seeding`), and a grid point of its values: the driver takes that function and
maps it, so a run or a point is the same whatever the number of runs, the order or the worker.
``simulate`` makes a run's frames and ``navigation`` estimates on them; the loops that repeat
them live in ``batch`` (``tests/test_architecture.py`` fails on a loop over runs elsewhere).

1. :func:`run_ids`: the run numbers ``first_run .. first_run + runs - 1`` (checked).
2. :func:`over_runs`: ``per_run(r)`` for every run, in order, in this process.
3. :func:`over_points`: ``per_point(*args)`` for every point's arguments, in this process or one
   task per point on a :class:`~starnav.dataset.runner.TaskRunner`; results in point order.

Index
-----
:func:`run_ids`, :func:`over_runs`, :func:`over_points`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from starnav.dataset.runner import TaskRunner
from starnav.errors import ConfigError

T = TypeVar("T")
Progress = Callable[[int, int], None]


def run_ids(runs: int, first_run: int = 0, *, minimum: int = 1) -> range:
    """The run numbers ``first_run .. first_run + runs - 1``; ``runs`` must be an integer
    ``>= minimum`` (a consistency verdict needs 2)."""
    if isinstance(runs, bool) or not isinstance(runs, int | float) or int(runs) != runs \
            or runs < minimum:
        raise ConfigError("runs", runs, f"an integer >= {minimum}")
    if isinstance(first_run, bool) or int(first_run) != first_run or first_run < 0:
        raise ConfigError("first_run", first_run, "an integer >= 0")
    return range(int(first_run), int(first_run) + int(runs))


def over_runs(per_run: Callable[[int], T], runs: int | range, *, first_run: int = 0,
              progress: Progress | None = None) -> list[T]:
    """``[per_run(r) for r in runs]`` (module step 2): ``runs`` a count (runs ``first_run``
    on) or the :func:`run_ids` themselves; ``progress(done, total)`` after each run."""
    ids = runs if isinstance(runs, range) else run_ids(runs, first_run)
    out = []
    for r in ids:
        out.append(per_run(r))
        if progress is not None:
            progress(len(out), len(ids))
    return out


def over_points(per_point: Callable[..., T], points: Sequence[tuple[Any, ...]], *,
                runner: TaskRunner | None = None, label: str = "point",
                progress: Progress | None = None) -> list[T]:
    """``per_point(*args)`` for every ``args`` of ``points`` (module step 3), in order.

    Without ``runner`` in this process, one point after the other; with one, a task per point
    (``per_point`` and its arguments must then pickle), collected as they finish. The results
    are in point order either way; ``progress(done, total)`` from 0."""
    n = len(points)
    if progress is not None:
        progress(0, n)
    if runner is None:
        out = []
        for args in points:
            out.append(per_point(*args))
            if progress is not None:
                progress(len(out), n)
        return out
    stamp = f"{os.getpid()}-{time.monotonic_ns()}"
    handles = {runner.submit(per_point, *args, key=f"{label}-{i}-{stamp}"): i
               for i, args in enumerate(points)}
    got: dict[int, T] = {}
    for h, res in runner.as_completed(list(handles)):
        got[handles[h]] = res
        if progress is not None:
            progress(len(got), n)
    return [got[i] for i in range(n)]
