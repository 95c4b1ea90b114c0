"""Fly-by front end: per-frame cost of each stage (issue 16, item 7).

Renders a short Itokawa fly-by (the scenario of tests/navigation/test_trn_frontend.py, at
256 x 256 and at 512 x 512 px), runs the front end on its segments and windows, and prints
one JSON document: machine, date, and per stage (segments analysis, window planning,
detection, tracking, outlier rejection) the median and max per frame [ms], the windows and
tracks per frame. Rendering and the detector are timed apart (not front-end stages). Usage::

    export DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1
    .venv/bin/python benchmarks/flyby.py
"""

from __future__ import annotations

import datetime
import json
import logging
import os
import platform
import time

import numpy as np


def scenario(width: int, focal_mm: float, frames: int) -> dict:
    return {"camera": {"width": width, "height": width, "focal_length_mm": focal_mm},
            "render": {"spp": 4},
            "target": {"kind": "shape_model", "model": "itokawa"},
            "trajectory": {"source": "flyby", "cadence_s": 0.05, "frames": frames,
                           "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.25,
                                     "phase_at_ca_deg": 70.0, "start_s": -0.6}},
            "pointing": {"moon_offset": "fixed", "roll": "fixed"},
            "detector": {"exposure_time_s": 3e-5}}


def main() -> None:
    from starnav.config import scenario_from_dict
    from starnav.navigation.trn.frontend import STAGES
    from starnav.navigation.trn.options import FrontEndOptions
    from starnav.simulate import Simulator
    from starnav.simulate.trn import track_flyby

    logging.basicConfig(level=logging.WARNING)
    out: dict = {"machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cores",
                 "date": datetime.date.today().isoformat(), "cases": {}}
    for label, width, focal, n_win in (("256 px, 8 windows", 256, 30.0, 8),
                                       ("512 px, 16 windows", 512, 60.0, 16)):
        sim = Simulator(scenario_from_dict(scenario(width, focal, 10)))
        t0 = time.perf_counter()
        renders = [sim.render(i) for i in range(len(sim))]
        t_render = (time.perf_counter() - t0) / len(renders)
        t0 = time.perf_counter()
        steps = track_flyby(sim, renders=renders, options=FrontEndOptions(n_windows=n_win))
        t_total = (time.perf_counter() - t0) / len(steps)
        per = {s: np.array([st.frame.timings_s[s] for st in steps[1:]]) * 1e3 for s in STAGES}
        fe = np.sum([per[s] for s in STAGES], axis=0)
        out["cases"][label] = {
            "frames": len(steps),
            "render_s_per_frame (with JIT warm-up)": round(t_render, 3),
            "detector + front end, s per frame": round(t_total, 4),
            "front end ms per frame (median, max)": [round(float(np.median(fe)), 2),
                                                     round(float(fe.max()), 2)],
            "stages ms (median, max)": {s: [round(float(np.median(v)), 3),
                                            round(float(v.max()), 3)] for s, v in per.items()},
            "windows per frame": [len(st.frame.measurement.windows) for st in steps],
            "window pixels per frame": [st.frame.window_pixels for st in steps],
            "tracks per frame": [len(st.frame.measurement.features) for st in steps],
        }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
