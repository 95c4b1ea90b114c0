"""A real Dask deployment (issue 18): a scheduler and two workers started as separate processes
(``dask scheduler``, ``dask worker`` with a nanny, a scheduler file), a sweep and a dataset run
through ``--scheduler``, one worker process SIGKILLed mid-run, and the outputs equal to those
of ``--workers 0``.

The kill is deterministic: before the run, a function installed on every worker
(``client.run``) makes the first worker that reaches a fixed point of the work (the navigation
chain of frame 2 in a sweep, the DN image of frame 2 in a dataset) SIGKILL its own process,
once for the whole cluster (an ``O_EXCL`` marker file). The nanny starts a fresh worker process,
which is not armed; the scheduler re-runs the lost tasks. Nothing is timed: every wait has a
generous deadline that only a broken deployment reaches.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import psutil
import pytest
import yaml
from typer.testing import CliRunner

from starnav import spectra
from starnav.batch.cluster import WORKER_PRELOAD
from starnav.batch.table import read_table
from starnav.dataset import format as F
from tests.faults import die_once

from .conftest import SMALL, deterministic

#: Frames of the scenario, and the one at which the doomed worker dies.
FRAMES = 3
DOOMED_FRAME = 1
#: Deadline for the cluster to come up and for a restarted worker to rejoin [s]: far above what
#: a healthy deployment needs on a loaded 2-core machine.
START_DEADLINE_S = 180.0
GRID = "detector.exposure_time_s=1.5e-5,7.7e-3"
ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Deployment:
    """A scheduler and its workers, started as processes of their own."""

    address: str
    scheduler_file: Path
    client: object
    procs: list[subprocess.Popen] = field(default_factory=list)
    logs: list[Path] = field(default_factory=list)

    def worker_pids(self) -> set[int]:
        return set(self.client.run(os.getpid).values())  # type: ignore[attr-defined]

    def warm(self) -> list[bool]:
        """Per worker: its preload has loaded Mitsuba, the tasks, the solar spectrum and the
        lost-in-space pair table (before any task)."""
        return list(self.client.run(_is_warm).values())  # type: ignore[attr-defined]


def _is_warm() -> bool:
    from starnav.stars import identify

    return ({"mitsuba", "starnav.batch.tasks"} <= set(sys.modules)
            and spectra._astm_g173.cache_info().currsize == 1
            and identify._index.cache_info().currsize >= 1)


def _env() -> dict[str, str]:
    """The test's environment for the cluster: this checkout's starnav (and these tests, for
    the functions installed with ``client.run``) first on the path."""
    import starnav

    env = dict(os.environ)
    src = str(Path(starnav.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, str(ROOT), env.get("PYTHONPATH", "")])
    env.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    return env


def _tail(paths: list[Path], n: int = 30) -> str:
    out = []
    for p in paths:
        with contextlib.suppress(OSError):
            out.append(f"--- {p.name}\n" + "\n".join(p.read_text().splitlines()[-n:]))
    return "\n".join(out)


def _processes(procs: list[subprocess.Popen]) -> dict[int, psutil.Process]:
    """The started processes and every descendant (the nannies' worker processes), as psutil
    handles (which know their start time: a pid reused later is not mistaken for them)."""
    out = {}
    for p in procs:
        with contextlib.suppress(psutil.NoSuchProcess):
            top = psutil.Process(p.pid)
            for q in [top, *top.children(recursive=True)]:
                out[q.pid] = q
    return out


def _alive(seen: dict[int, psutil.Process]) -> set[int]:
    alive = set()
    for pid, q in seen.items():
        with contextlib.suppress(psutil.NoSuchProcess):
            if q.is_running() and q.status() != psutil.STATUS_ZOMBIE:
                alive.add(pid)
    return alive


@contextlib.contextmanager
def deployment(tmp: Path, seen: dict[int, psutil.Process],
               forced: set[int]) -> Iterator[Deployment]:
    """Start ``dask scheduler`` and two ``dask worker`` (nanny, 1 process, 1 thread each);
    stop them all on exit with SIGTERM, workers first. ``seen`` collects every process the
    deployment had; ``forced`` the ones that had to be SIGKILLed because SIGTERM did not
    stop them (so that nothing is left even when a test fails)."""
    from distributed import Client

    tmp.mkdir(parents=True, exist_ok=True)
    sfile = tmp / "scheduler.json"
    env = _env()
    procs: list[subprocess.Popen] = []
    logs: list[Path] = []

    def start(name: str, args: list[str]) -> None:
        log = tmp / f"{name}.log"
        logs.append(log)
        with open(log, "wb") as fh:
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", *args], env=env,
                                          stdout=fh, stderr=subprocess.STDOUT, cwd=tmp,
                                          start_new_session=True))

    client = None
    try:
        start("scheduler", ["scheduler", "--host", "127.0.0.1", "--port", "0",
                            "--no-dashboard", "--scheduler-file", str(sfile),
                            "--idle-timeout", "600s"])
        t0 = time.monotonic()
        while not (sfile.is_file() and sfile.stat().st_size):
            assert procs[0].poll() is None, "the scheduler exited:\n" + _tail(logs)
            assert time.monotonic() - t0 < START_DEADLINE_S, "no scheduler file\n" + _tail(logs)
            time.sleep(0.2)
        address = json.loads(sfile.read_text())["address"]
        for name in ("worker-a", "worker-b"):
            start(name, ["worker", "--scheduler-file", str(sfile), "--nworkers", "1",
                         "--nthreads", "1", "--nanny", "--no-dashboard", "--host",
                         "127.0.0.1", "--name", name, "--local-directory", str(tmp / name),
                         "--death-timeout", "120s", "--preload", WORKER_PRELOAD])
        client = Client(address, set_as_default=False, timeout="60s")
        try:
            client.wait_for_workers(2, timeout=START_DEADLINE_S)
        except TimeoutError:
            raise AssertionError("the workers did not join\n" + _tail(logs)) from None
        dep = Deployment(address, sfile, client, procs, logs)
        seen.update(_processes(procs))
        yield dep
        seen.update(_processes(procs))
    finally:
        seen.update(_processes(procs))
        if client is not None:
            client.close()
        for p in reversed(procs):  # workers first (their nannies stop their processes)
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                forced.add(p.pid)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)  # its own session: only what it started
                p.wait(timeout=30)
        if _wait_gone(seen, 30.0):  # a worker process its nanny did not stop
            for pid in _alive(seen):
                forced.add(pid)
                with contextlib.suppress(psutil.NoSuchProcess):
                    seen[pid].kill()


def _wait_gone(seen: dict[int, psutil.Process], deadline_s: float) -> set[int]:
    t0 = time.monotonic()
    while _alive(seen) and time.monotonic() - t0 < deadline_s:
        time.sleep(0.2)
    return _alive(seen)


# ------------------------------------------------------------------ functions run on workers
def _arm_sweep_death(marker: str) -> None:
    """Installed on every worker: the first navigation chain of frame ``DOOMED_FRAME`` on the
    cluster kills its worker process (SIGKILL), once (the marker)."""
    import starnav.batch.tasks as tasks

    real = tasks.process_frame

    def dying_process_frame(frame, *args, **kwargs):
        if int(frame.index) == DOOMED_FRAME:
            die_once(marker, f"expose of frame {frame.index} in pid {os.getpid()}")
        return real(frame, *args, **kwargs)

    tasks.process_frame = dying_process_frame


def _arm_dataset_death(marker: str) -> None:
    """Installed on every worker: the first writer of frame ``DOOMED_FRAME``'s DN image on the
    cluster kills its worker process (SIGKILL) with the frame half written, once (the
    marker)."""
    import starnav.dataset.writer as w

    real = w.write_dn_png

    def dying_write(image, path, *args, **kwargs):
        frame_tmp = Path(path).parent.parent.name
        if frame_tmp.startswith(f"{F.TMP_PREFIX}{F.frame_dirname(DOOMED_FRAME)}-"):
            die_once(marker, frame_tmp)
        return real(image, path, *args, **kwargs)

    w.write_dn_png = dying_write


# ------------------------------------------------------------------ helpers
def _scenario_file(tmp: Path, frames: int = FRAMES) -> Path:
    data = {k: dict(v) for k, v in SMALL.items()}
    data["trajectory"]["frames"] = frames
    path = tmp / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _invoke(args: list[str]):
    from starnav.cli.main import app

    r = CliRunner().invoke(app, args, env={"COLUMNS": "50"})
    assert r.exit_code == 0, r.output + repr(r.exception)
    return r


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ test
@pytest.mark.slow
def test_sweep_and_dataset_on_a_deployed_cluster_survive_a_killed_worker(tmp_path):
    """One deployment, two runs, one worker process killed in each; outputs equal to
    ``--workers 0`` (the sweep's table without its wall-clock columns, the dataset byte for
    byte); every process of the deployment gone afterwards."""
    scen = _scenario_file(tmp_path)
    sweep = ["sweep", str(scen), "--grid", GRID, "--runs", "2", "--no-figures"]
    dataset = ["dataset", str(scen), "--exposures", "7.7ms"]
    _invoke([*sweep, "--out", str(tmp_path / "sweep-ref"), "--workers", "0"])
    _invoke([*dataset, "--out", str(tmp_path / "ds-ref"), "--workers", "0"])
    seen: dict[int, psutil.Process] = {}
    forced: set[int] = set()
    with deployment(tmp_path / "cluster", seen, forced) as dep:
        assert dep.warm() == [True, True]  # the preload ran before the workers registered
        # the sweep: a worker dies in the navigation chain of frame DOOMED_FRAME
        marker = tmp_path / "sweep-killed-once"
        before = dep.worker_pids()
        dep.client.run(_arm_sweep_death, str(marker))  # type: ignore[attr-defined]
        r = _invoke([*sweep, "--out", str(tmp_path / "sweep"), "--scheduler", dep.address])
        assert marker.read_text().startswith(f"expose of frame {DOOMED_FRAME}"), \
            "no worker was killed"
        dep.client.wait_for_workers(2, timeout=START_DEADLINE_S)  # type: ignore[attr-defined]
        after = dep.worker_pids()
        assert len(before - after) == 1 and len(after - before) == 1  # one process replaced
        seen.update(_processes(dep.procs))
        # the dataset (the address from the scheduler file): a worker dies with frame
        # DOOMED_FRAME half written
        marker = tmp_path / "dataset-killed-once"
        dep.client.run(_arm_dataset_death, str(marker))  # type: ignore[attr-defined]
        _invoke([*dataset, "--out", str(tmp_path / "ds"), "--scheduler-file",
                 str(dep.scheduler_file)])
        assert marker.read_text().startswith(F.TMP_PREFIX + F.frame_dirname(DOOMED_FRAME)), \
            "no worker was killed"
        dep.client.wait_for_workers(2, timeout=START_DEADLINE_S)  # type: ignore[attr-defined]
        assert len(after - dep.worker_pids()) == 1
        address = dep.address
    assert forced == set(), "SIGTERM did not stop every process of the deployment"
    assert _alive(seen) == set(), "processes left behind"
    assert len(seen) >= 7  # scheduler, 2 nannies, 2 worker processes, 2 replacements

    assert f"runner: scheduler {address}" in r.output.replace("\n", "")
    ref, dist = tmp_path / "sweep-ref", tmp_path / "sweep"
    a, b = read_table(ref / "results.parquet"), read_table(dist / "results.parquet")
    assert len(a) == 4 and deterministic(b) == deterministic(a)
    for name in ("scenario.resolved.yaml", "points/point_000.yaml", "points/point_001.yaml"):
        assert (dist / name).read_bytes() == (ref / name).read_bytes(), name
    info = json.loads((dist / "sweep.json").read_text())
    assert info["runner"] == f"scheduler {address}"
    assert info["tasks"] == {"render": FRAMES, "expose": 2 * FRAMES, "filter": 2}

    ref_ds, ds = _tree(tmp_path / "ds-ref"), _tree(tmp_path / "ds")
    assert len(ref_ds) > 20 and sorted(ref_ds) == sorted(ds)
    assert [k for k in ref_ds if ref_ds[k] != ds[k]] == []  # the manifest and every frame file
