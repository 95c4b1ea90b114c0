"""Fly-by: per-frame cost of each stage, front end and estimator (issue 16, item 7).

Renders a short Itokawa fly-by (the scenario of tests/navigation/test_trn_frontend.py, at
256 x 256 and at 512 x 512 px), runs the front end on its segments and windows, and prints
one JSON document: machine, date, and per stage (segments analysis, window planning,
detection, tracking, outlier rejection) the median and max per frame [ms], the windows and
tracks per frame. Rendering and the detector are timed apart (not front-end stages). Then the
estimator on synthetic measurements (:func:`bench_filter`). Usage::

    export DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1
    .venv/bin/python benchmarks/flyby.py                 # everything
    .venv/bin/python benchmarks/flyby.py --closed-loop   # the closed loop and the budget
    .venv/bin/python benchmarks/flyby.py --scoring       # the scoring fly-bys vs targets
    .venv/bin/python benchmarks/flyby.py --aastr         # the preset about CA, both maps
"""

from __future__ import annotations

import datetime
import json
import logging
import math
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


def bench_front_end() -> None:
    from starnav.config import scenario_from_dict
    from starnav.navigation.trn.frontend import STAGES
    from starnav.navigation.trn.options import TrnFrontEndConfig
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
        steps = track_flyby(sim, renders=renders,
                            options=TrnFrontEndConfig(n_windows=n_win).to_si())
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


def bench_filter(runs: int = 3) -> None:
    """The estimator on synthetic measurements of Itokawa at 10 km, 1 km/s, 61 frames."""
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
        run = run_filter(meas, cam, body, x0, P0, cfg.to_si(),
                         sun_direction=truth.sun_direction)
        per_frame.append((time.process_time() - t0) / epochs.size)
    print(f"synthetic truth geometry: {1e3 * t_truth:.1f} ms CPU per frame")
    print(f"filter ({syn.max_features} tracks, <= {cfg.max_landmarks} landmarks, "
          f"{int(run.landmarks.max())} reached): {1e3 * np.median(per_frame):.1f} ms CPU "
          "per frame (median of runs)")


def main() -> None:
    import sys

    if "--closed-loop" in sys.argv:
        bench_closed_loop()
        return
    if "--scoring" in sys.argv:
        bench_scoring()
        return
    if "--aastr" in sys.argv:
        bench_aastr()
        return
    bench_front_end()
    bench_filter()
    bench_closed_loop()


def bench_closed_loop(runs: int = 3) -> None:
    """Per-frame cost of the closed loop on rendered frames: render (once per frame), detector
    (segments + windows exposures), front end, filter (mean over the runs); then the tracker's
    budget (front end + filter scaled desktop -> MCU against 650 ms; peak traced memory of a
    re-run of run 0 under tracemalloc against 900 kB)."""
    from starnav.batch.flyby import flyby_closed_loop, flyby_run
    from starnav.config import scenario_from_dict
    from starnav.navigation.trn.metrics import tracker_budget
    from starnav.simulate import Simulator
    from starnav.simulate.flyby import render_flyby

    sc = scenario(256, 30.0, 21)
    sc["trajectory"].update({"cadence_s": 0.2})
    sc["trajectory"]["flyby"].update({"v_inf_km_s": 0.5, "phase_at_ca_deg": 60.0,
                                      "start_s": -2.0})
    sim = Simulator(scenario_from_dict(sc))
    renders, t_render = render_flyby(sim)
    loop = flyby_closed_loop(sim, runs, renders=renders)
    loop.timings_s["render"] = t_render
    mem = flyby_run(sim, renders, 0, memory=True).memory_bytes
    print(json.dumps({"machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cores",
                      "date": datetime.date.today().isoformat(),
                      "closed_loop_ms_per_frame": {k: round(1e3 * v, 2)
                                                   for k, v in loop.timings_s.items()},
                      "tracker_budget": tracker_budget(loop.timings_s, mem),
                      "load": os.getloadavg()}, indent=1))


def bench_aastr(runs: int = 4, half_s: float = 5.0) -> None:
    """The fly-by preset (the AA-STR) cut to ``-half_s .. +half_s`` about CA, rendered once,
    ``runs`` runs on the exact and on the coarse map: per-frame stage times, the per-epoch
    and time-averaged ANEES, the CA error per run."""
    from starnav.batch.flyby import flyby_closed_loop
    from starnav.batch.presets import flyby_scenario
    from starnav.config import scenario_from_dict
    from starnav.navigation.metrics import anees_statistics
    from starnav.simulate import Simulator
    from starnav.simulate.flyby import render_flyby

    renders = None
    for kind in ("exact", "coarse"):
        d = flyby_scenario()
        d["trajectory"]["flyby"].update(start_s=-half_s, end_s=half_s)
        d["navigation"]["trn"]["shape_model"]["map"] = kind
        sim = Simulator(scenario_from_dict(d))
        t_render = float("nan")
        if renders is None:
            renders, t_render = render_flyby(sim)
        loop = flyby_closed_loop(sim, runs, renders=renders)
        st = anees_statistics(np.array([r.filter.nees(loop.truth) for r in loop.runs]), 6)
        print(json.dumps({
            "map": kind, "frames": len(renders), "runs": runs, "render_s": t_render,
            "ms_per_frame": {k: round(1e3 * v, 1) for k, v in loop.timings_s.items()},
            "anees": st["mean"], "band": st["band"], "verdict": st["verdict"],
            "epochs_in_band": st["epochs_in_band"],
            "ca_error_pct_range": [round(r.metrics.ca_position_error_pct_range, 3)
                                   for r in loop.runs],
            "load": os.getloadavg()}, default=float))


def bench_scoring(runs: int = 20) -> None:
    """The scoring fly-bys (``navigation.trn.scoring.SCORING_FLYBYS``: Itokawa outside the
    calibration envelope and Eros), ``runs`` dispersed synthetic runs each on the coarse map,
    against the targets; the packaged record (tools/score_flyby.py) beside each number."""
    from starnav.batch.flyby_synthetic import score_case
    from starnav.navigation.trn.scoring import (
        SCORING_FLYBYS,
        SCORING_SEED,
        TARGETS,
        read_record,
    )

    rec = read_record()["scoring"]
    lo, hi = TARGETS["epochs_in_band"]
    rows = (("epochs inside the per-epoch 95 % band", "epochs_in_band", f"{lo:.2f} - {hi:.2f}"),
            ("time-averaged ANEES (6 states)", "anees_mean", "in band"),
            ("position NEES (3)", ("position_nees", "mean"), "in band"),
            ("velocity NEES (3)", ("velocity_nees", "mean"), "in band"),
            ("CA position error, median [% range]", "ca_position_pct_median",
             f"<= {TARGETS['ca_position_pct_median']}"),
            ("CA position error, 95th pct [% range]", "ca_position_pct_p95",
             f"<= {TARGETS['ca_position_pct_p95']}"),
            ("CA velocity error, 95th pct [% v_inf]", "ca_velocity_pct_v_inf_p95",
             f"< {TARGETS['ca_velocity_pct_v_inf']}"),
            ("filter CPU per frame, desktop [ms]", "filter_cpu_ms_per_frame", "-"),
            ("filter per frame, MCU estimate [ms]", "filter_mcu_ms_estimate",
             f"<= {TARGETS['mcu_budget_ms']:.0f} (front end not included)"))

    def get(d, key):
        return d[key[0]][key[1]] if isinstance(key, tuple) else d[key]

    for case in SCORING_FLYBYS:
        s = score_case(case, runs, SCORING_SEED)
        print(f"\n{case.name}: {case.body}, v_inf {case.v_inf / 1e3} km/s, CA "
              f"{case.closest_approach / 1e3} km, phase {math.degrees(case.phase_at_ca):.0f} "
              f"deg, {s['frames']} "
              f"frames, {runs} runs (ANEES band {s['anees_band'][0]:.2f} - "
              f"{s['anees_band'][1]:.2f})")
        print(f"  {'metric':40s} {'now':>9s} {'recorded':>9s}  target")
        for label, key, target in rows:
            print(f"  {label:40s} {get(s, key):9.3f} {get(rec[case.name], key):9.3f}  {target}")
        print(f"  targets met: {s['targets_met']}")


if __name__ == "__main__":
    main()
