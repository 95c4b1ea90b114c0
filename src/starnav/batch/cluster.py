"""Dask runners: a local cluster on 127.0.0.1, an existing scheduler, or this process.

:func:`open_runner` is the one entry point: ``workers=0`` runs in this process (no Dask),
``workers=N`` starts a :class:`distributed.LocalCluster` of ``N`` single-threaded worker
processes bound to 127.0.0.1, warmed by the preload :mod:`starnav.batch.warm` before they take
work (nannies restart a worker that dies; the scheduler re-runs its tasks, up to
``distributed.scheduler.allowed-failures`` = 3 deaths per task), and
``scheduler="tcp://host:port"`` connects to a running cluster (the scheduler and the workers
must have starnav installed, the scheduler because it unpickles the task graph; for datasets
the workers share the output file system; ``dask worker --preload starnav.batch.warm`` warms
them: docs/sweep.md, "A real cluster").

Errors are immediate and clear: a malformed address, or a scheduler that does not answer
within ``connect_timeout_s``, raises :class:`ClusterError` before any work starts.

Example
-------
>>> from starnav.batch.cluster import open_runner
>>> with open_runner(workers=2) as runner:                          # doctest: +SKIP
...     h = runner.submit(pow, 2, 10, key="pow-2-10")
...     [r for _, r in runner.as_completed([h])]
[1024]
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import re
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from starnav.dataset.runner import InProcessRunner, TaskRunner
from starnav.errors import ConfigError, StarnavError

log = logging.getLogger(__name__)

#: How long to wait for a scheduler to answer [s].
CONNECT_TIMEOUT_S = 5.0
#: Extra time the handshake may take after the connection [s].
HANDSHAKE_GRACE_S = 2.0
#: The preload that warms a worker process before it takes work (:mod:`starnav.batch.warm`;
#: empty: none, as ``benchmarks/sweep.py --cold`` measures).
WORKER_PRELOAD = "starnav.batch.warm"
_ADDRESS_RE = re.compile(r"^(tcp|tls|ws|wss|inproc)://[^\s/:]+(:\d{1,5})?$")


class ClusterError(StarnavError, ConnectionError):
    """The Dask scheduler cannot be reached or the cluster cannot start."""


class DaskRunner:
    """A :class:`~starnav.dataset.runner.TaskRunner` on a ``distributed.Client``."""

    def __init__(self, client: Any, description: str) -> None:
        self.client = client
        self.description = description
        info = client.scheduler_info()
        self.workers = len(info.get("workers", {}))

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> Any:
        return self.client.submit(fn, *args, key=key, pure=False)

    def as_completed(self, handles: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
        """Results as they finish; a task that killed every worker it ran on (Dask's
        ``KilledWorker``) is a :class:`ClusterError` naming it."""
        from distributed import KilledWorker, as_completed

        try:
            yield from as_completed(list(handles), loop=self.client.loop, with_results=True)
        except KilledWorker as err:
            raise ClusterError(
                f"task {err.task!r} killed {err.allowed_failures + 1} workers (the last at "
                f"{getattr(err.last_worker, 'address', err.last_worker)}); the scheduler "
                "stopped re-running it (distributed.scheduler.allowed-failures = "
                f"{err.allowed_failures}): see the workers' logs (out of memory? a crash in a "
                "native library?)") from None


@contextlib.contextmanager
def quiet_logger(name: str, level: int = logging.ERROR) -> Iterator[None]:
    """Raise logger ``name`` to ``level`` for the block (per-run filter chatter in batch mode:
    the table carries what matters, e.g. ``accepted``)."""
    lg = logging.getLogger(name)
    old = lg.level
    lg.setLevel(max(level, old))
    try:
        yield
    finally:
        lg.setLevel(old)


def check_address(address: str) -> str:
    """Validate a scheduler address (``tcp://host:port``)."""
    a = str(address).strip()
    m = _ADDRESS_RE.match(a)
    if not m:
        raise ConfigError("--scheduler", address, "a Dask scheduler address such as "
                          "tcp://10.0.0.5:8786")
    if m.group(2) and not 1 <= int(m.group(2)[1:]) <= 65535:
        raise ConfigError("--scheduler", address, "a TCP port from 1 to 65535 (Dask's "
                          "default: 8786)")
    return a


def scheduler_file_address(path: str | os.PathLike[str]) -> str:
    """The address in a scheduler file (``dask scheduler --scheduler-file PATH`` writes one:
    JSON with an ``address`` field), checked as :func:`check_address` does."""
    p = Path(path)
    try:
        info = json.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError("--scheduler-file", str(p), "the file `dask scheduler "
                          "--scheduler-file` writes (it does not exist: is the scheduler "
                          "running, and is the file on a shared file system?)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ConfigError("--scheduler-file", str(p), f"a readable JSON scheduler file "
                          f"({type(err).__name__}: {err})") from None
    address = info.get("address") if isinstance(info, dict) else None
    if not isinstance(address, str):
        raise ConfigError("--scheduler-file", str(p), "a scheduler file with an \"address\" "
                          "field, as `dask scheduler --scheduler-file` writes")
    return check_address(address)


def resolve_scheduler(scheduler: str | None,
                      scheduler_file: str | os.PathLike[str] | None) -> str | None:
    """The scheduler address of ``--scheduler`` or ``--scheduler-file`` (at most one), or None."""
    if scheduler and scheduler_file:
        raise ConfigError("--scheduler-file", str(scheduler_file), "either --scheduler or "
                          "--scheduler-file, not both")
    if scheduler_file:
        return scheduler_file_address(scheduler_file)
    return scheduler


def _probe(address: str, timeout_s: float) -> BaseException | None:
    """Connect and shake hands with ``address`` on a private event loop in a daemon thread;
    the error, or None when a Dask scheduler answered (module docstring of :func:`connect`)."""
    from distributed.comm import connect as comm_connect  # lazy: distributed (heavy)

    async def attempt() -> None:
        comm = await asyncio.wait_for(comm_connect(address, timeout=timeout_s),
                                      timeout_s + HANDSHAKE_GRACE_S)
        await comm.close()

    outcome: dict[str, BaseException] = {}

    def run() -> None:
        try:
            asyncio.run(attempt())
        except BaseException as err:  # noqa: BLE001 - reported by the caller, whatever it is
            outcome["error"] = err

    thread = threading.Thread(target=run, name="starnav-probe", daemon=True)
    thread.start()
    thread.join(timeout_s + 2.0 * HANDSHAKE_GRACE_S)
    if thread.is_alive():
        return TimeoutError("no handshake")
    return outcome.get("error")


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Any:
    """A ``distributed.Client`` on ``address``, or :class:`ClusterError` within about
    ``timeout_s + 2 HANDSHAKE_GRACE_S``.

    ``distributed.Client``'s own timeout covers the TCP connection, not the handshake: a
    service that accepts the connection and then waits (an HTTP server) holds the client
    forever, and one that answers with other bytes makes it read a frame length of exabytes.
    The address is therefore first probed with Dask's own comm connect and handshake on a
    private event loop, under a hard deadline (:func:`_probe`), so that a failed attempt
    leaves nothing behind in this process's shared Dask event loop; only a scheduler that
    answered gets a ``Client``.
    """
    from distributed import Client  # lazy: distributed (heavy)

    a = check_address(address)
    err = _probe(a, timeout_s)
    if isinstance(err, ConnectionRefusedError) or (
            isinstance(err, OSError) and "refused" in str(err).lower()):
        raise ClusterError(f"the Dask scheduler at {a} does not answer (waited {timeout_s:g} s:"
                           f" {type(err).__name__}); start it with `dask scheduler` or use "
                           "--workers N for a local cluster") from None
    if err is not None:
        raise ClusterError(f"{a} does not answer as a Dask scheduler ({type(err).__name__}); "
                           "is it another service? Start one with `dask scheduler` or use "
                           "--workers N for a local cluster") from None
    try:
        return Client(a, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError) as err2:
        raise ClusterError(f"the Dask scheduler at {a} does not answer (waited {timeout_s:g} s:"
                           f" {type(err2).__name__})") from None


def default_workers() -> int:
    """Local workers when none is asked for: the number of CPUs (at least 1)."""
    return max(1, os.cpu_count() or 1)


#: Local worker processes allowed per CPU: the tasks are CPU-bound, so more processes than this
#: only add memory (each holds its own renderer and scene) and start-up time, no throughput.
WORKERS_PER_CPU = 4


def check_workers(workers: int) -> int:
    """``workers`` if the host can run that many local worker processes, else a
    :class:`ConfigError` with the bound (:data:`WORKERS_PER_CPU` per CPU)."""
    cpus = max(1, os.cpu_count() or 1)
    cap = WORKERS_PER_CPU * cpus
    if isinstance(workers, bool) or not 0 <= int(workers) <= cap:
        raise ConfigError("--workers", workers, f"0 (this process) to {cap} processes "
                          f"({WORKERS_PER_CPU} per CPU, {cpus} CPUs here: the tasks are "
                          "CPU-bound, more processes only add memory and start-up time)")
    return int(workers)


#: Environment variable that, when set, leaves the workers' statistical profiler to Dask's
#: own configuration (:func:`local_worker_config`).
PROFILE_ENV = "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED"


def local_worker_config() -> dict[str, Any]:
    """Dask configuration of the workers of the local clusters :func:`open_runner` starts.

    Dask's statistical profiler is off: every 10 ms it takes the GIL to walk the running
    task's stack. It feeds only the dashboard's profile page, which these clusters do not
    serve (``dashboard_address=None``); with it on, two workers do measurably more work than
    one for the same tasks (``benchmarks/sweep.py``, docs/performance.md). Setting
    ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED`` in the environment keeps Dask's own
    choice. For workers started with ``dask worker``, set that variable to ``False`` in their
    environment for the same saving (docs/sweep.md, "A real cluster")."""
    if PROFILE_ENV in os.environ:
        return {}
    return {"distributed.worker.profile.enabled": False}


@contextlib.contextmanager
def open_runner(workers: int | None = None, scheduler: str | None = None, *,
                connect_timeout_s: float = CONNECT_TIMEOUT_S) -> Iterator[TaskRunner]:
    """The runner for ``workers`` / ``scheduler`` (module docstring); closed on exit.

    Parameters
    ----------
    workers : int, optional
        0: this process; N >= 1: a local cluster of N processes; default the CPU count.
        An error with ``scheduler`` (whose own workers run the tasks).
    scheduler : str, optional
        Address of an existing scheduler.
    connect_timeout_s : float
        How long to wait for ``scheduler`` [s].
    """
    if scheduler and workers:
        raise ConfigError("--workers", workers, "no --workers with --scheduler (the "
                          "scheduler's own workers run the tasks; start them with `dask worker "
                          f"{scheduler}`)")
    if scheduler:
        client = connect(scheduler, connect_timeout_s)
        try:
            yield DaskRunner(client, f"scheduler {check_address(scheduler)}")
        finally:
            client.close()
        return
    n = default_workers() if workers is None else check_workers(workers)
    if n == 0:
        yield InProcessRunner()
        return
    import dask
    from distributed import Client, LocalCluster

    quiet = contextlib.ExitStack()  # the scheduler runs here: keep its INFO lines out
    quiet.enter_context(quiet_logger("distributed", logging.WARNING))
    try:
        # the nannies hand this configuration to their worker processes
        with dask.config.set(local_worker_config()):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None,
                                   silence_logs=logging.ERROR,
                                   preload=[WORKER_PRELOAD] if WORKER_PRELOAD else [])
    except Exception as err:  # noqa: BLE001 - any start-up failure is reported the same way
        quiet.close()
        raise ClusterError(f"could not start a local Dask cluster of {n} workers: {err} (worker "
                           "processes are spawned: a script that starts a sweep must guard its "
                           "code with `if __name__ == '__main__':`)") from None
    client = Client(cluster, set_as_default=False)
    try:
        yield DaskRunner(client, f"local cluster, {n} worker process(es)")
    finally:
        client.close()
        cluster.close()
        quiet.close()
