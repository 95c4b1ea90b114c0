"""Benchmark: dataset generation end to end, and sweep scaling with 1 and 2 local workers.

Measures, on the full AA-STR (1024 x 1024) along the LUMIO-like halo arc:

1. ``starnav.dataset.generate`` frames per second (render 16 spp with AOVs, EXR, segments
   acquisition, window plan, windows acquisition, PNG and JSON, manifest), in this process and
   on a local Dask cluster of 2 workers; set-up (trajectory, backend, manifest) reported apart.
2. ``starnav.batch.run_sweep`` wall time of the paper's four exposures x ``--runs`` on 1 and 2
   local workers (cluster start-up included, as a user sees it) and the speed-up.

Usage::

    DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1 python benchmarks/dataset.py \
        [--frames 12] [--sweep-frames 12] [--runs 2]

Numbers depend on the machine's load; the DESIGN.md budget is >= 1 frame/s end to end.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--sweep-frames", type=int, default=12)
    ap.add_argument("--runs", type=int, default=2)
    a = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="starnav-bench-"))
    try:
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
