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
@pytest.mark.slow
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


@pytest.mark.slow
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


def test_the_scheduler_file_gives_the_address_or_a_clear_error(tmp_path):
    from starnav.batch.cluster import resolve_scheduler, scheduler_file_address
    from starnav.errors import ConfigError

    good = tmp_path / "sched.json"
    good.write_text('{"type": "Scheduler", "id": "Scheduler-1", '
                    '"address": "tcp://127.0.0.1:8786", "services": {}}')
    assert scheduler_file_address(good) == "tcp://127.0.0.1:8786"
    assert resolve_scheduler(None, good) == "tcp://127.0.0.1:8786"
    assert resolve_scheduler("tcp://10.0.0.5:8786", None) == "tcp://10.0.0.5:8786"
    with pytest.raises(ConfigError, match="not both"):
        resolve_scheduler("tcp://10.0.0.5:8786", good)
    cases = {"missing.json": (None, "does not exist"),
             "garbage.json": ("{not json", "JSONDecodeError"),
             "noaddr.json": ('{"type": "Scheduler"}', "\"address\" field"),
             "badaddr.json": ('{"address": "10.0.0.5"}', "tcp://10.0.0.5:8786")}
    for name, (text, match) in cases.items():
        if text is not None:
            (tmp_path / name).write_text(text)
        with pytest.raises(ConfigError, match=match) as info:
            scheduler_file_address(tmp_path / name)
        assert name in str(info.value) or "10.0.0.5" in str(info.value)


@pytest.mark.parametrize("command", ["sweep", "dataset"])
def test_the_commands_refuse_a_missing_scheduler_file_before_any_work(tmp_path, command):
    from typer.testing import CliRunner

    from starnav.cli.main import app

    out = tmp_path / "out"
    args = ([command, "--grid", "seed=1,2"] if command == "sweep" else [command])
    r = CliRunner().invoke(app, [*args, "--out", str(out), "--scheduler-file",
                                 str(tmp_path / "nope.json")], env={"COLUMNS": "50"})
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines[0].startswith("error: --scheduler-file") and "nope.json" in r.output
    assert "Traceback" not in r.output and not out.exists()
