"""HIL bench emulation: timings and the headline numbers of issue 7.

Runs, on the paper's bench with injected misalignments (the test-suite's), the collimator check,
the geometric calibration, the displayed-Moon check, the radiometric validation, the
albedo-exposure KS experiment and the end-to-end k = 13 333 case, and prints one JSON
document. Usage::

    export DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1
    .venv/bin/python benchmarks/calibration.py
"""

from __future__ import annotations

import json
import logging
import time

MISALIGNMENT = {"screen_shift_mm": [0.3, -0.2], "screen_roll_deg": 0.4,
                "screen_tilt_deg": [0.5, -0.3], "camera_tilt_deg": [0.1, 0.05],
                "camera_roll_deg": -0.2}


def main() -> None:
    from starnav.calibration import Bench, bench_from_dict, check_bench
    from starnav.calibration.geometric import NominalMapping, calibrate_geometry
    from starnav.calibration.radiometric import compare_stimulus
    from starnav.calibration.scaling import albedo_exposure_experiment, end_to_end
    from starnav.calibration.workflows import render_reference

    logging.basicConfig(level=logging.WARNING)
    out: dict = {"timing_s": {}}
    t = out["timing_s"]
    for label, cfg in (("paper bench", bench_from_dict({})),
                       ("misaligned bench", bench_from_dict({"misalignment": MISALIGNMENT}))):
        bench = Bench(cfg)
        t0 = time.perf_counter()
        chk = check_bench(bench)
        t[f"check ({label})"] = time.perf_counter() - t0
        out[f"check ({label})"] = {"verdict": chk.verdict,
                                   "conditions": [c.sentence() for c in chk.conditions]}
    t0 = time.perf_counter()
    res = calibrate_geometry(bench)
    t["geometric calibration (5 full frames)"] = time.perf_counter() - t0
    out["geometric"] = res.summary()
    t0 = time.perf_counter()
    img = render_reference(cfg.model_copy(update={"scenario": cfg.scenario.model_copy(
        update={"geometry": cfg.scenario.geometry.model_copy(
            update={"moon_offset_px": (180.0, -120.0)})})}))
    t["render 60 000 km frame"] = time.perf_counter() - t0
    tr = cfg.scaling.render_exposure_ms * 1e-3
    t0 = time.perf_counter()
    cal = compare_stimulus(bench, img, tr, res.calibration, frame_base=500)
    t["stimulus + 4 exposures"] = time.perf_counter() - t0
    unc = compare_stimulus(bench, img, tr, NominalMapping(bench.geometry.nominal()),
                           frame_base=510)
    out["moon_placement_px"] = {"calibrated": cal.metrics()["centroid_offset_px"],
                                "uncalibrated": unc.metrics()["centroid_offset_px"]}
    out["radiometric_validation"] = cal.metrics()
    t0 = time.perf_counter()
    ks = albedo_exposure_experiment(bench, img, tr, res.calibration)
    t["KS experiment"] = time.perf_counter() - t0
    out["ks"] = ks.to_dict()
    t0 = time.perf_counter()
    e2e = end_to_end(bench, img, res.calibration)
    t["end to end"] = time.perf_counter() - t0
    out["end_to_end"] = e2e.to_dict()
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
