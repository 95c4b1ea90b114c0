"""Benchmark: dataset generation end to end, and sweep scaling with 1 and 2 local workers.

Measures, on the full AA-STR (1024 x 1024) along the LUMIO-like halo arc:

1. ``starnav.dataset.generate`` frames per second (render 16 spp with AOVs, EXR, segments
   acquisition, window plan, windows acquisition, PNG and JSON, manifest), in this process and
   on a local Dask cluster of 2 workers; set-up (trajectory, backend, manifest) reported apart.
2. ``starnav.batch.run_sweep`` wall time of the paper's four exposures x ``--runs`` on 1 and 2
   local workers (cluster start-up included, as a user sees it) and the speed-up.
3. ``--demo-dataset N``: the demo dataset alone (N frames at ``make demo``'s settings) in this
   process, as ``generate`` makes it (two frames at once in threads) and one frame at a time,
   against issue 18's target of 3 frames/s, with the CPU time per frame. With
   ``--against SRC`` (another checkout's ``src/``, e.g. ``git archive`` of the commit before a
   change) the old and the new code alternate, each run in a fresh process, ``--rounds`` times.
4. ``--demo``: the main job (``make demo`` = ``starnav demo``: 25 frames, 1024 x 1024, 8 spp,
   two exposures, navigation, report) in this process and with a local cluster of 2 workers
   for its dataset: wall time, the dataset's frames/s, and the peak resident memory of this
   process and of the largest worker (``ru_maxrss`` of the reaped children).
5. ``--pipeline N``: N demo frames made by ``FrameMaker.write_frame`` alone with one thread,
   two threads in one process and two processes (half the frames each), alternately, each in
   fresh warm processes: whether the GIL limits the two frame threads.
6. The cost of durability (``--fsync``, or alone with ``--fsync-only``): ``starnav.atomic``
   fsyncs every file before its rename and its directory after it. Measured in the same run
   with and without the two fsyncs (patched out): ms per file for the sizes a dataset writes
   (JSON ~1 kB, a 16-bit DN PNG ~100 kB, a radiance EXR ~4 MB), and frames/s of a full-size
   dataset (1024 x 1024, 4 spp, 2 exposures, radiance stored).

Usage::

    DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1 python benchmarks/dataset.py \
        [--frames 12] [--sweep-frames 12] [--runs 2] [--fsync | --fsync-only] [--demo]

Numbers depend on the machine's load; the DESIGN.md budget is >= 1 frame/s end to end.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def dataset_rate(frames: int, workers: int, root: Path) -> tuple[float, float, float]:
    """(frames/s, set-up s, total s) of one dataset generation."""
    from starnav.batch.cluster import open_runner
    from starnav.config import scenario_from_dict
    from starnav.dataset import DatasetOptions, generate

    sc = scenario_from_dict({"trajectory": {"frames": frames, "cadence_s": 1800.0,
                                            "duration_days": 1.0},
                             "render": {"spp": 16}})
    out = root / f"ds_{workers}"
    t0 = time.perf_counter()
    with open_runner(workers) as runner:
        s = generate(sc, out, options=DatasetOptions(exposures_s=(1.5e-5,)), runner=runner)
    total = time.perf_counter() - t0
    shutil.rmtree(out, ignore_errors=True)
    return s.frames_per_s, s.setup_s, total


def sweep_time(frames: int, runs: int, workers: int, root: Path) -> tuple[float, int]:
    """(wall s, tasks) of the exposure study on ``workers`` local workers."""
    from starnav.batch import run_sweep
    from starnav.batch.presets import get_preset

    p = get_preset("exposure-study")
    out = root / f"sweep_{workers}"
    t0 = time.perf_counter()
    res = run_sweep(p.scenario(), p.grid, out, runs=runs, workers=workers, figures=False,
                    overrides=[f"trajectory.frames={frames}"])
    dt = time.perf_counter() - t0
    shutil.rmtree(out, ignore_errors=True)
    return dt, res.render_tasks + res.expose_tasks + res.filter_tasks


@contextlib.contextmanager
def fsync_disabled() -> Iterator[None]:
    """``starnav.atomic`` without its two fsyncs (the writes before this change)."""
    import starnav.atomic as atomic
    import starnav.dataset.writer as writer  # fsyncs the frame directories it renames

    saved = atomic.sync_file, atomic.sync_directory, writer.sync_directory
    atomic.sync_file = atomic.sync_directory = writer.sync_directory = lambda path: None
    try:
        yield
    finally:
        atomic.sync_file, atomic.sync_directory, writer.sync_directory = saved


def ms_per_file(size: int, count: int, root: Path) -> float:
    """Mean time of one ``atomic_write_bytes`` of ``size`` random bytes [ms]."""
    import numpy as np

    from starnav.atomic import atomic_write_bytes

    data = np.random.default_rng(1).bytes(size)
    d = root / f"files_{size}"
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for i in range(count):
        atomic_write_bytes(d / f"f{i:04d}.bin", data)
    dt = time.perf_counter() - t0
    shutil.rmtree(d)
    return 1e3 * dt / count


def fsync_rate(frames: int, root: Path) -> float:
    """Frames/s of a full-size dataset in this process (renderer warm)."""
    from starnav.config import scenario_from_dict
    from starnav.dataset import DatasetOptions, generate

    sc = scenario_from_dict({"trajectory": {"frames": frames, "cadence_s": 1800.0,
                                            "duration_days": 1.0}, "render": {"spp": 4}})
    out = root / "ds_fsync"
    s = generate(sc, out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)))
    shutil.rmtree(out, ignore_errors=True)
    return s.frames_per_s


def fsync_section(frames: int, root: Path) -> None:
    print("durability: atomic writes with and without fsync (file + directory)")
    for size, count in ((1_000, 200), (100_000, 100), (4_000_000, 20)):
        with fsync_disabled():
            off = ms_per_file(size, count, root)
        on = ms_per_file(size, count, root)
        print(f"  {size / 1e3:8.0f} kB file: {off:6.2f} ms without, {on:6.2f} ms with fsync")
    fsync_rate(1, root)  # warm the renderer and the trajectory
    with fsync_disabled():
        off = fsync_rate(frames, root)
    on = fsync_rate(frames, root)
    with fsync_disabled():
        off2 = fsync_rate(frames, root)  # again: load drifts on a shared machine
    print(f"  dataset, 1024 x 1024, 4 spp, 2 exposures, {frames} frames: "
          f"{off:.2f} / {off2:.2f} frames/s without, {on:.2f} frames/s with fsync")


def demo_section(root: Path) -> None:
    """``make demo``'s job in this process and on 2 local workers, with peak memory."""
    import resource

    from starnav.batch import main_job

    print(f"main job (make demo), load average {os.getloadavg()[0]:.2f}")
    for w in (0, 2):
        out = root / f"demo_{w}"
        t0 = time.perf_counter()
        res = main_job(out_dir=out, workers=w)
        dt = time.perf_counter() - t0
        me = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
        label = "in-process" if w == 0 else f"{w} local workers"
        print(f"  {label:18s}: {dt:6.1f} s, dataset {res['dataset_frames_per_s']:.2f} frames/s "
              f"({res['frames']} frames); peak RSS this process {me:.0f} MB, largest worker "
              f"{kids:.0f} MB; load {os.getloadavg()[0]:.2f}", flush=True)
        shutil.rmtree(out, ignore_errors=True)


#: Issue 18's target for the dataset at the demo settings, end to end [frames/s].
DEMO_TARGET_FPS = 3.0


def demo_dataset_rate(frames: int, root: Path, serial: bool) -> dict[str, float]:
    """The demo dataset alone (``make demo``'s settings: 1024 x 1024, 8 spp, 0.015 and 7.7 ms,
    windows, radiance and quick looks) made by ``generate`` in this process, as the imported
    code makes it (``serial``: one frame at a time, whatever the code would do). Returns
    frames/s, CPU seconds per frame (all threads, frames only: from the first progress call,
    after the set-up, to the end) and the set-up [s]."""
    import starnav.dataset.writer as writer
    from starnav.batch.mainjob import DEMO_EXPOSURE_OVERRIDES, DEMO_EXPOSURES_S
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict
    from starnav.dataset import DatasetOptions, generate

    d = demo_scenario()
    d["trajectory"]["frames"] = frames
    sc = scenario_from_dict(d)
    opts = DatasetOptions(exposures_s=tuple(DEMO_EXPOSURES_S), exposure_overrides=tuple(
        (float(t), tuple(o)) for t, o in DEMO_EXPOSURE_OVERRIDES))
    out = root / f"demo_ds_{int(serial)}"
    cpu0: list[float] = []

    def progress(done: int, total: int) -> None:
        if not cpu0:
            cpu0.append(time.process_time())

    with contextlib.ExitStack() as stack:
        if serial and hasattr(writer, "FRAME_THREADS"):   # frames made in threads
            stack.callback(setattr, writer, "FRAME_THREADS", writer.FRAME_THREADS)
            writer.FRAME_THREADS = 1
        elif serial:   # the code before: the next render ran ahead in a second thread
            saved = writer.FrameMaker.render_ahead
            stack.callback(setattr, writer.FrameMaker, "render_ahead", saved)
            writer.FrameMaker.render_ahead = (  # type: ignore[attr-defined]
                lambda self, order: contextlib.nullcontext())
        s = generate(sc, out, options=opts, progress=progress)
    cpu = (time.process_time() - cpu0[0]) / max(s.frames_made, 1)
    shutil.rmtree(out, ignore_errors=True)
    return {"fps": s.frames_per_s, "cpu": cpu, "setup": s.setup_s}


def _report(label: str, r: dict[str, float]) -> None:
    met = "met" if r["fps"] >= DEMO_TARGET_FPS else "NOT met"
    rss = f"; peak RSS {r['rss_mb']:.0f} MB" if "rss_mb" in r else ""
    print(f"  {label:22s}: {r['fps']:5.2f} frames/s vs target {DEMO_TARGET_FPS:.0f} ({met}); "
          f"CPU {r['cpu']:.3f} s per frame (all threads); set-up {r['setup']:.1f} s{rss}; "
          f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)


def demo_dataset_section(frames: int, root: Path) -> None:
    print(f"demo dataset ({frames} frames, make demo's settings), in-process; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    demo_dataset_rate(2, root, False)  # warm: Mitsuba, kernels, the arc on disk
    for serial in (False, True, False, True):
        _report("one frame at a time" if serial else "as generate does",
                demo_dataset_rate(frames, root, serial))


def _demo_dataset_child(frames: int, serial: bool) -> None:
    """One measurement in a fresh process (``--against``): warm, measure, print JSON."""
    import json
    import resource

    root = Path(tempfile.mkdtemp(prefix="starnav-bench-"))
    try:
        demo_dataset_rate(2, root, False)  # warm: Mitsuba, kernels, the arc on disk
        r = demo_dataset_rate(frames, root, serial)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    r["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print("RESULT " + json.dumps(r), flush=True)


def demo_dataset_against(frames: int, old_src: str, rounds: int) -> None:
    """The demo dataset made by the code in ``old_src`` and by this checkout's, alternately,
    each in a fresh process (import path set with PYTHONPATH), ``rounds`` times; this
    checkout also one frame at a time."""
    import json
    import subprocess
    import sys

    new_src = str(Path(__file__).resolve().parents[1] / "src")
    print(f"demo dataset ({frames} frames, make demo's settings), in-process, old = {old_src}, "
          f"new = {new_src}; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on "
          f"{os.cpu_count()} cores; each run in a fresh process, warmed by 2 frames")
    runs = [("old", old_src, False), ("new", new_src, False), ("new, 1 frame at a time",
                                                               new_src, True)]
    for r in range(rounds):
        for label, src, serial in runs:
            env = {**os.environ, "PYTHONPATH": src}
            cmd = [sys.executable, __file__, "--demo-dataset-child", str(frames)]
            if serial:
                cmd.append("--serial")
            res = subprocess.run(cmd, env=env, capture_output=True, text=True)
            line = [x for x in res.stdout.splitlines() if x.startswith("RESULT ")]
            if res.returncode or not line:
                print(f"  {label}: failed\n{res.stdout}\n{res.stderr}")
                continue
            _report(f"{label} (round {r + 1})", json.loads(line[-1][7:]))


def _demo_frame_maker(frames: int):
    """A :class:`FrameMaker` of the demo dataset's scenario and options."""
    from starnav.batch.mainjob import DEMO_EXPOSURE_OVERRIDES, DEMO_EXPOSURES_S
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict
    from starnav.dataset import DatasetOptions
    from starnav.dataset.writer import FrameMaker

    d = demo_scenario()
    d["trajectory"]["frames"] = frames
    opts = DatasetOptions(exposures_s=tuple(DEMO_EXPOSURES_S), exposure_overrides=tuple(
        (float(t), tuple(o)) for t, o in DEMO_EXPOSURE_OVERRIDES))
    return FrameMaker(scenario_from_dict(d), opts)


#: Frames of the demo arc used by ``--pipeline`` (the last two warm a process up).
_PIPE_ARC = 24


def _pipeline_child(mode: str, first: int, count: int, go: str, ready: str) -> None:
    """``--pipeline`` worker: warm a FrameMaker, signal ``ready``, wait for ``go``, make frames
    ``first .. first + count - 1`` (``mode``: ``serial`` or ``threads``), print the wall time."""
    fm = _demo_frame_maker(_PIPE_ARC)
    root = Path(tempfile.mkdtemp(prefix="starnav-bench-"))
    try:
        for i in (_PIPE_ARC - 1, _PIPE_ARC - 2):
            fm.write_frame(i, root)
        Path(ready).touch()
        while not Path(go).exists():
            time.sleep(0.005)
        order = list(range(first, first + count))
        t0 = time.perf_counter()
        with (fm.making_ahead(order, root, 2) if mode == "threads"
              else contextlib.nullcontext()):
            for i in order:
                fm.write_frame(i, root)
        print(f"WALL {time.perf_counter() - t0}", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def pipeline_section(frames: int, rounds: int) -> None:
    """Frames of the demo dataset made by ``FrameMaker.write_frame`` (no manifest, no final
    verification): one thread, two threads in one process (``making_ahead``), and two
    processes each making half the frames one at a time (no shared GIL), alternately, each
    in fresh warm processes. If two threads come close to two processes, the GIL is not what
    limits the threads."""
    import subprocess
    import sys

    print(f"frame pipeline, {frames} demo frames per run: 1 thread / 2 threads / 2 processes; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on "
          f"{os.cpu_count()} cores")

    def run(parts: list[tuple[str, int, int]]) -> float:
        d = Path(tempfile.mkdtemp(prefix="starnav-bench-"))
        go = d / "go"
        procs = [subprocess.Popen([sys.executable, __file__, "--pipeline-child", mode,
                                   str(first), str(count), str(go), str(d / f"ready{k}")],
                                  stdout=subprocess.PIPE, text=True)
                 for k, (mode, first, count) in enumerate(parts)]
        try:
            while not all((d / f"ready{k}").exists() for k in range(len(parts))):
                if any(p.poll() is not None for p in procs):
                    raise RuntimeError("a pipeline worker died before it was ready")
                time.sleep(0.01)
            t0 = time.perf_counter()
            go.touch()
            for p in procs:
                p.communicate()
            return time.perf_counter() - t0
        finally:
            shutil.rmtree(d, ignore_errors=True)

    half = frames // 2
    setups = [("1 thread", [("serial", 0, frames)]), ("2 threads", [("threads", 0, frames)]),
              ("2 processes", [("serial", 0, half), ("serial", half, frames - half)])]
    for _ in range(rounds):
        for label, parts in setups:
            wall = run(parts)
            print(f"  {label:12s}: {frames / wall:5.2f} frames/s ({wall:.2f} s); load "
                  f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--sweep-frames", type=int, default=12)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--fsync", action="store_true", help="also measure the cost of fsync")
    ap.add_argument("--fsync-only", action="store_true", help="only measure the cost of fsync")
    ap.add_argument("--demo", action="store_true", help="only measure the main job (make demo)")
    ap.add_argument("--demo-dataset", type=int, default=0, metavar="FRAMES",
                    help="only measure the demo dataset of FRAMES frames, as generate makes "
                    "it and one frame at a time")
    ap.add_argument("--against", metavar="SRC", default=None,
                    help="with --demo-dataset: compare with the code in SRC (a src/ "
                    "directory), alternately, each run in a fresh process")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of --against")
    ap.add_argument("--pipeline", type=int, default=0, metavar="FRAMES",
                    help="only compare 1 thread, 2 threads and 2 processes making FRAMES demo "
                    "frames (--rounds times)")
    ap.add_argument("--demo-dataset-child", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--serial", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--pipeline-child", nargs=5, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.demo_dataset_child:
        _demo_dataset_child(a.demo_dataset_child, a.serial)
        return
    if a.pipeline_child:
        mode, first, count, go, ready = a.pipeline_child
        _pipeline_child(mode, int(first), int(count), go, ready)
        return
    if a.pipeline:
        pipeline_section(a.pipeline, a.rounds)
        return
    if a.demo_dataset and a.against:
        demo_dataset_against(a.demo_dataset, a.against, a.rounds)
        return
    root = Path(tempfile.mkdtemp(prefix="starnav-bench-"))
    try:
        if a.demo_dataset:
            demo_dataset_section(a.demo_dataset, root)
            return
        if a.demo:
            demo_section(root)
            return
        if a.fsync or a.fsync_only:
            fsync_section(a.frames, root)
            if a.fsync_only:
                return
        print(f"dataset, 1024 x 1024, 16 spp + AOVs, 1 exposure, {a.frames} frames")
        for w in (0, 2):
            rate, setup, total = dataset_rate(a.frames, w, root)
            label = "in-process" if w == 0 else f"{w} local workers"
            print(f"  {label:18s}: {rate:6.2f} frames/s (set-up {setup:.1f} s, "
                  f"total {total:.1f} s incl. cluster start)")
        print(f"sweep, exposure study: 4 exposures x {a.runs} runs x {a.sweep_frames} frames")
        times = {}
        for w in (1, 2):
            dt, tasks = sweep_time(a.sweep_frames, a.runs, w, root)
            times[w] = dt
            print(f"  {w} worker(s): {dt:6.1f} s for {tasks} tasks")
        print(f"  speed-up 1 -> 2 workers: {times[1] / times[2]:.2f}x")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
