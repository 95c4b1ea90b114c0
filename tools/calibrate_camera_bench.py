#!/usr/bin/env python
"""Calibrate the default tracker's camera on seeded emulated benches; write the pool navigation
draws its camera knowledge from (``src/starnav/data/navigation/camera_bench.json``).

Each bench has its screen, mount, collimator and camera departures drawn from the stated
tolerances (:func:`starnav.calibration.intrinsics.draw_as_built`, seeds 9500 onwards: no
navigation tuning or scoring seed) and is calibrated by
:func:`starnav.calibration.intrinsics.calibrate_camera` with its own centroid noise. The pool
keeps, per bench, the realised error of the estimate (estimate minus the bench's truth camera)
and the covariance the calibration stated: a navigation run's knowledge of the camera is the
truth plus one bench's error (:func:`starnav.camera_calibration.bench_calibration`), so the
Monte Carlo samples what the bench really gets wrong, not the covariance it claims.

Usage::

    .venv/bin/python tools/calibrate_camera_bench.py            # 40 benches, write the pool
    .venv/bin/python tools/calibrate_camera_bench.py --n 4 --dry-run
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import time
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "src/starnav/data/navigation/camera_bench.json"
FIRST_SEED = 9500


def main() -> None:
    import numpy as np

    from starnav.atomic import atomic_write_text
    from starnav.calibration import Bench, bench_from_dict
    from starnav.calibration.intrinsics import calibrate_camera, draw_as_built
    from starnav.camera_calibration import camera_fingerprint, parameter_values
    from starnav.config import build_camera

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args()
    g = bench_from_dict({}).geometric
    benches, nees = [], []
    names: tuple[str, ...] = ()
    datasheet = build_camera(bench_from_dict({}).scenario.camera)
    t0 = time.perf_counter()
    for seed in range(FIRST_SEED, FIRST_SEED + a.n):
        mis = draw_as_built(np.random.default_rng(seed), g)
        bench = Bench(bench_from_dict({"misalignment": mis, "seed": seed}))
        cal = calibrate_camera(bench).calibration
        names = cal.parameters
        e = cal.estimate - parameter_values(bench.camera, names)
        nees.append(float(e @ np.linalg.solve(cal.covariance, e)))
        benches.append({"seed": seed, "error": [float(x) for x in e],
                        "covariance": [[float(x) for x in r] for r in cal.covariance]})
        print(f"bench {seed}: focal length error {e[0] / bench.camera.focal_length:+.3%}, "
              f"stated {np.sqrt(cal.covariance[0, 0]) / bench.camera.focal_length:.3%}; "
              f"NEES {nees[-1]:.1f} ({len(names)} dof)", flush=True)
    err = np.array([b["error"] for b in benches])
    sig = np.array([np.sqrt(np.diag(b["covariance"])) for b in benches])
    ratio = np.sqrt(np.mean((err / sig) ** 2, axis=0))
    print("rms(error / stated sigma) per parameter:",
          dict(zip(names, np.round(ratio, 2).tolist(), strict=True)),
          f"mean NEES {np.mean(nees):.1f}; {time.perf_counter() - t0:.0f} s")
    doc = {"format": "starnav-camera-bench-pool", "version": 1,
           "tool": "tools/calibrate_camera_bench.py", "written": _dt.date.today().isoformat(),
           "camera_fingerprint": camera_fingerprint(datasheet), "parameters": list(names),
           "rms_error_over_sigma": dict(zip(names, ratio.tolist(), strict=True)),
           "mean_nees": float(np.mean(nees)), "benches": benches}
    if not a.dry_run:
        atomic_write_text(OUT, json.dumps(doc, indent=1) + "\n")
        print("wrote", OUT)


if __name__ == "__main__":
    main()
