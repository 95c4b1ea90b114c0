"""Scenes benchmark (issue 4): ephemeris, arc generation, EKF propagation step, frame geometry.

Prints: DE421 evaluation time (one epoch, and per epoch in a vectorised call); the 28-day
ephemeris halo arc (CR3BP correction + multiple shooting + arc) without cache; one 300 s RK4
step with the STM (the navigation filter's prediction, budget: part of <= 5 ms per frame); and
the time to build one FrameGeometry with random pointing (dataset budget >= 1 frame/s end to end).

Usage: .venv/bin/python benchmarks/scenes.py
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from starnav.config import scenario_from_dict
from starnav.scenes.dynamics import PointMassModel, propagate
from starnav.scenes.ephemeris import Ephemeris, parse_epoch
from starnav.scenes.trajectory import ephemeris_halo_arc
from starnav.simulate import scene_from_scenario


def timed(fn, repeat: int = 20) -> float:
    """Median wall time of ``fn()`` [s]."""
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main() -> None:
    eph = Ephemeris.default()
    t0 = parse_epoch("2027-03-01T00:00:00 TDB")
    model = PointMassModel(eph)
    eph.positions_emb(t0)  # load the series
    one = timed(lambda: eph.positions_emb(t0))
    print(f"DE421 Earth/Moon/Sun at one epoch   {one * 1e3:8.3f} ms")
    ts = t0 + 300.0 * np.arange(10_000)
    per = timed(lambda: eph.positions_emb(ts), 5) / ts.size
    print(f"DE421 vectorised, per epoch         {per * 1e6:8.3f} us")

    tic = time.perf_counter()
    arc = ephemeris_halo_arc(model, t0, 28 * 86400.0, cache_dir=False)
    print(f"28-day halo arc (no cache)          {time.perf_counter() - tic:8.3f} s "
          f"({arc.meta['shooting_iterations']} shooting iterations, defects "
          f"{arc.meta['shooting_max_position_defect_m']:.1e} m)")

    x0 = arc.states[100]
    tt = arc.times[100]
    step = timed(lambda: propagate(model, tt, x0, tt + 300.0, with_stm=True), 50)
    print(f"one 300 s RK4 step with STM         {step * 1e3:8.3f} ms")

    scene = scene_from_scenario(scenario_from_dict({"trajectory": {"frames": 50}}), eph, arc=arc)
    k = iter(range(10_000))
    per_frame = timed(lambda: scene.geometry(next(k) % len(scene)), 50)
    print(f"FrameGeometry with random pointing  {per_frame * 1e3:8.3f} ms")


if __name__ == "__main__":
    main()
