"""A ``--scheduler`` address where something else answers (issue 15): a clear error within
10 s, never a hang or a MemoryError; ``--workers`` with ``--scheduler`` is refused."""

from __future__ import annotations

import socket
import socketserver
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import pytest


def _serve(server) -> str:
    threading.Thread(target=server.serve_forever, daemon=True).start()
    host, port = server.server_address[:2]
    return f"tcp://127.0.0.1:{port}"


class _Spew(socketserver.BaseRequestHandler):
    def handle(self) -> None:  # answers every connection with bytes Dask reads as a huge frame
        self.request.sendall(b"\xff" * 64)
        time.sleep(30)


@pytest.mark.parametrize("kind", ["http", "spew"])
def test_a_service_that_is_not_dask_fails_fast_and_clearly(kind):
    import distributed  # noqa: F401  (its import time is not the connection's)

    from starnav.batch.cluster import ClusterError, connect

    server = (ThreadingHTTPServer(("127.0.0.1", 0), SimpleHTTPRequestHandler) if kind == "http"
              else socketserver.ThreadingTCPServer(("127.0.0.1", 0), _Spew))
    server.daemon_threads = True
    address = _serve(server)
    t0 = time.monotonic()
    try:
        with pytest.raises(ClusterError, match="does not answer as a Dask scheduler"):
            connect(address)
    finally:
        server.shutdown()
    assert time.monotonic() - t0 < 10.0


def test_a_closed_port_is_reported_as_no_scheduler():
    from starnav.batch.cluster import ClusterError, connect

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ClusterError, match="does not answer"):
        connect(f"tcp://127.0.0.1:{port}", timeout_s=2.0)


def test_workers_and_scheduler_are_exclusive():
    from starnav.batch.cluster import open_runner
    from starnav.errors import ConfigError

    runner = open_runner(2, "tcp://127.0.0.1:1")
    with pytest.raises(ConfigError, match="no --workers with --scheduler"):
        runner.__enter__()  # refused before any connection is tried


def _kill_own_process() -> None:
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def test_a_task_that_kills_every_worker_is_a_clear_error():
    """Dask gives up on a task after ``allowed-failures`` + 1 dead workers (set to 0 here: the
    first death); the runner says which task and why, as a ClusterError (one ``error:`` line
    on the command line), instead of Dask's KilledWorker."""
    import dask

    from starnav.batch.cluster import ClusterError, open_runner

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            open_runner(workers=1) as runner:
        h = runner.submit(_kill_own_process, key="doomed-task")
        with pytest.raises(ClusterError, match=r"task 'doomed-task' killed 1 workers .*"
                           r"allowed-failures = 0"):
            list(runner.as_completed([h]))
