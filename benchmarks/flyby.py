"""Per-frame cost of the asteroid fly-by stages (issue 16 item 7).

Run: ``PYTHONPATH=src python benchmarks/flyby.py``. Each stage engineer adds a ``bench_*``
function called from :func:`main`; timings go to ``docs/performance.md`` (machine, date).
"""

from __future__ import annotations

import time

import numpy as np

from starnav.bodies.small_body import ShapeModelBody
from starnav.camera import Camera
from starnav.navigation.schema import TrnFilterConfig
from starnav.navigation.trn.filter import run_filter
from starnav.navigation.trn.synthetic import (
    SyntheticOptions,
    flyby_truth,
    initial_estimate,
    run_measurements,
)
from starnav.scenes.flyby import flyby_from_config
from starnav.scenes.schema import FlybyConfig


def bench_filter(runs: int = 3) -> None:
    """The estimator on synthetic measurements of Itokawa at 10 km, 1 km/s, 61 frames."""
    body = ShapeModelBody()
    cam = Camera.preset("aa-str")
    fb = flyby_from_config(FlybyConfig(v_inf_km_s=1.0, closest_approach_km=10.0), 0.0, body.gm)
    epochs = np.arange(-60.0, 60.01, 2.0)
    syn = SyntheticOptions()
    t0 = time.process_time()
    truth = flyby_truth(fb, body, cam, epochs, syn)
    t_truth = (time.process_time() - t0) / epochs.size
    cfg = TrnFilterConfig()
    P0 = cfg.initial_covariance()
    per_frame = []
    for r in range(runs):
        meas = run_measurements(truth, 0, r, syn)
        x0 = initial_estimate(truth, P0, 0, r)
        t0 = time.process_time()
        run = run_filter(meas, cam, body, x0, P0, cfg.options(),
                         sun_direction=truth.sun_direction)
        per_frame.append((time.process_time() - t0) / epochs.size)
    print(f"synthetic truth geometry: {1e3 * t_truth:.1f} ms CPU per frame")
    print(f"filter ({syn.max_features} tracks, <= {cfg.max_landmarks} landmarks, "
          f"{int(run.landmarks.max())} reached): {1e3 * np.median(per_frame):.1f} ms CPU "
          "per frame (median of runs)")


def main() -> None:
    bench_filter()


if __name__ == "__main__":
    main()
