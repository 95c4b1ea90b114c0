"""How independent pieces of work are run: in this process, or on a Dask cluster.

:class:`TaskRunner` is the small protocol the dataset writer and the sweeps use: ``submit``
a function (its arguments may be handles of earlier submissions, which are replaced by their
results), then iterate ``as_completed`` to collect results as they finish. The in-process
:class:`InProcessRunner` here runs each task when ``as_completed`` reaches it, in submission
order; :mod:`starnav.batch.cluster` provides the Dask implementation (local cluster or an
existing scheduler). Results never depend on the runner: every task is a pure function of its
arguments and seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class TaskRunner(Protocol):
    """Runs tasks, possibly in parallel.

    Attributes
    ----------
    workers : int
        Number of worker processes (0: this process).
    description : str
        Human-readable description (``"in-process"``, ``"local cluster, 2 workers"``, ...).
    """

    workers: int
    description: str

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> Any:
        """Schedule ``fn(*args)``; ``key`` is a unique, deterministic task name."""
        ...

    def as_completed(self, handles: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        """Yield ``(handle, result)`` as tasks finish; raises the first task error."""
        ...


@dataclass(eq=False)
class _Thunk:
    fn: Callable[..., Any]
    args: tuple[Any, ...]
    key: str
    done: bool = False
    result: Any = None


def _resolve(obj: Any) -> Any:
    if isinstance(obj, _Thunk):
        if not obj.done:
            _run(obj)
        return obj.result
    if isinstance(obj, list):
        return [_resolve(x) for x in obj]
    if isinstance(obj, tuple):
        return tuple(_resolve(x) for x in obj)
    if isinstance(obj, dict):
        return {k: _resolve(v) for k, v in obj.items()}
    return obj


def _run(t: _Thunk) -> None:
    args = _resolve(t.args)
    t.result = t.fn(*args)
    t.done = True
    t.args = ()  # release the inputs


class InProcessRunner:
    """A :class:`TaskRunner` that runs every task in this process, lazily and in order."""

    workers = 0
    description = "in-process (no Dask)"

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> _Thunk:
        return _Thunk(fn, args, key)

    def as_completed(self, handles: Iterable[_Thunk]) -> Iterator[tuple[_Thunk, Any]]:
        for h in list(handles):
            if not h.done:
                _run(h)
            yield h, h.result

    def close(self) -> None:
        """Nothing to release."""
