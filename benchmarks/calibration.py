"""HIL bench emulation: timings and the headline numbers of issue 7.

Runs, on the paper's bench with injected misalignments (the test-suite's), the collimator check,
the geometric calibration, the displayed-Moon check, the radiometric validation, the
albedo-exposure KS experiment and the end-to-end k = 13 333 case, and prints one JSON
document. ``--intrinsics N`` instead calibrates the camera on N seeded benches whose as-built
departures (screen, mount, collimator, camera) are drawn from the tolerances the calibration
states, and prints each parameter's error against the truth bench's camera with its stated
1-sigma, the NEES against its chi-square band, and the star-field hold-out of each calibrated
camera (right, and with its focal length 0.5 % off). ``--radiometric N`` calibrates the screen
against the reference instrument on N seeded truth benches and prints the calibrated against
the true full white, k = 13 333 count and too-dim factor with their 1-sigma, the hold-out
validation's error, budget and coverage, each negative control, and one bench through the
detector chain. ``--moon N`` shows the rendered Moon on N seeded truth benches with counts
from each bench's calibration and prints the disc and inner-median ratios against the orbit
exposure (mean, rms error, stated 1-sigma, share within 2 sigma, budget by term). Usage::

    .venv/bin/python benchmarks/calibration.py
    .venv/bin/python benchmarks/calibration.py --intrinsics 20
    .venv/bin/python benchmarks/calibration.py --radiometric 20
    .venv/bin/python benchmarks/calibration.py --moon 40
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


def intrinsics(n: int) -> None:
    from dataclasses import replace

    import numpy as np
    from scipy.stats import chi2

    from starnav.calibration import Bench, bench_from_dict
    from starnav.calibration.intrinsics import calibrate_camera, draw_as_built
    from starnav.calibration.star_field import (
        acquire_star_field,
        star_field_holdout,
        star_field_screen_px,
    )
    from starnav.camera_calibration import parameter_values, with_parameters

    g = bench_from_dict({}).geometric
    rows, nees = [], []
    stars: dict[str, list] = {"right": [], "focal_0.5pct": []}
    t0 = time.perf_counter()
    for seed in range(n):
        r = np.random.default_rng(seed)
        mis = draw_as_built(r, g)
        bench = Bench(bench_from_dict({"misalignment": mis, "seed": seed}))
        intr = calibrate_camera(bench)
        cal = intr.calibration
        scr, _ = star_field_screen_px(bench)
        acq = acquire_star_field(bench, scr)
        f = acq.found
        for key, c in (("right", cal), ("focal_0.5pct", replace(cal, camera=with_parameters(
                cal.camera, {"focal_length_m": cal.camera.focal_length * 1.005})))):
            h = star_field_holdout(c, intr.mount_rotation_rad, bench.geometry.design(), scr[f],
                                   acq.observed_px[f], intr.centroid_sigma_px)
            stars[key].append((h["parameter_test"]["chi2"], h["residual_test"]["chi2"],
                               h["passes"], h["residual_test"]["passes"]))
        e = cal.estimate - parameter_values(bench.camera, cal.parameters)
        sig = np.sqrt(np.diag(cal.covariance))
        rows.append((e, sig))
        nees.append(float(e @ np.linalg.solve(cal.covariance, e)))
    names = cal.parameters
    err = np.array([e for e, _ in rows])
    sig = np.array([s for _, s in rows])
    k = len(names)
    lo, hi = chi2.ppf([0.025, 0.975], k * n) / n
    out = {"benches": n, "seconds": time.perf_counter() - t0,
           "parameters": {name: {"rms_error": float(np.sqrt(np.mean(err[:, i] ** 2))),
                                 "rms_error_over_sigma": float(np.sqrt(np.mean(
                                     (err[:, i] / sig[:, i]) ** 2))),
                                 "median_sigma": float(np.median(sig[:, i])),
                                 "within_1_sigma": float(np.mean(np.abs(err[:, i])
                                                                 <= sig[:, i])),
                                 "within_2_sigma": float(np.mean(np.abs(err[:, i])
                                                                 <= 2 * sig[:, i]))}
                          for i, name in enumerate(names)},
           "focal_length_rms_error_rel": float(np.sqrt(np.mean(
               (err[:, 0] / bench.camera.focal_length) ** 2))),
           "mean_nees": float(np.mean(nees)), "median_nees": float(np.median(nees)),
           "nees_per_bench": [round(x, 2) for x in nees], "nees_dof": k,
           "mean_nees_95_band": [float(lo), float(hi)],
           "star_field_holdout": {
               key: {"parameter_chi2": [round(x[0], 2) for x in v],
                     "residual_chi2": [round(x[1], 1) for x in v],
                     "pass_rate": float(np.mean([x[2] for x in v])),
                     "residual_pass_rate": float(np.mean([x[3] for x in v]))}
               for key, v in stars.items()}}
    print(json.dumps(out, indent=1))


def seeded_lab(bench, seed: int, cache: dict):
    """One seeded truth bench as a lab sees it: ``(truth screen, reference instrument, the
    lab's radiometric calibration against it)``."""
    from starnav.calibration.radiometric_lab import calibrate_radiometry
    from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen
    from starnav.seeding import generator

    tr = TruthScreen(bench, generator(seed, 6, 7), cache)
    inst = ReferenceInstrument(bench, tr, generator(seed, 6, 8))
    return tr, inst, calibrate_radiometry(bench, tr, inst)


def radiometric(n: int) -> None:
    """The radiometric calibration against the reference instrument on ``n`` seeded truth
    benches: estimated against true parameters with their 1-sigma, the validation's error
    budget and coverage, each negative control, and one bench through the detector chain."""
    import numpy as np

    from starnav.calibration import Bench, bench_from_dict
    from starnav.calibration.radiometric_lab import (
        TERMS,
        calibrate_radiometry,
        plausibility,
        validate_radiometry,
    )
    from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen

    def run(lab: dict, seeds: range) -> dict:
        bench = Bench(bench_from_dict({"radiometric_lab": lab}))
        cache: dict = {}
        cam = bench.camera
        rows = []
        t0 = time.perf_counter()
        for i in seeds:
            tr, inst, cal = seeded_lab(bench, 5000 + i, cache)
            val = validate_radiometry(bench, cal, tr, inst)
            pl = plausibility(bench, cal, tr)
            white_true = float(tr.electron_radiance(255, np.array([[cam.cx, cam.cy]]),
                                                    cal.session_end_s)[0])
            rows.append({"white": (cal.le[-1] / white_true - 1.0,
                                   np.sqrt(cal.total_covariance[-1, -1]) / cal.le[-1]),
                         "count": (pl["k_peak_count"]["calibrated"] - pl["k_peak_count"]["truth"],
                                   pl["k_peak_count"]["sigma"]),
                         "dim": (pl["screen_too_dim"]["calibrated"] - pl["screen_too_dim"]["truth"],
                                 pl["screen_too_dim"]["sigma"]),
                         "truth_count": pl["k_peak_count"]["truth"],
                         "truth_dim": pl["screen_too_dim"]["truth"],
                         "e": [p.error for p in val.points], "s": [p.sigma for p in val.points],
                         "budget": val.budget_rms(), "consistent": val.consistent,
                         "meets": val.meets_use})
        e = np.array([r["e"] for r in rows])
        sg = np.array([r["s"] for r in rows])
        z = e / sg

        def est(key: str) -> dict:
            d = np.array([r[key][0] for r in rows])
            s_ = np.array([r[key][1] for r in rows])
            return {"rms_error": float(np.sqrt(np.mean(d**2))), "median_sigma":
                    float(np.median(s_)), "within_2_sigma": float(np.mean(np.abs(d) <= 2 * s_))}

        return {"benches": len(rows), "seconds": time.perf_counter() - t0,
                "full_white_rel": est("white"), "k13333_count": est("count"),
                "screen_too_dim": est("dim"),
                "truth_count_range": [float(min(r["truth_count"] for r in rows)),
                                      float(max(r["truth_count"] for r in rows))],
                "truth_too_dim_range": [float(min(r["truth_dim"] for r in rows)),
                                        float(max(r["truth_dim"] for r in rows))],
                "validation_rms_error": float(np.sqrt(np.mean(e**2))),
                "validation_sigma_rms": float(np.sqrt(np.mean(sg**2))),
                "fraction_abs_z_above_2": float(np.mean(np.abs(z) > 2)),
                "mean_z": float(z.mean()), "mean_z2": float(np.mean(z**2)),
                "budget_rms": {k: float(np.sqrt(np.mean([r["budget"][k] ** 2 for r in rows])))
                               for k in TERMS},
                "fraction_consistent": float(np.mean([r["consistent"] for r in rows])),
                "fraction_meets_use": float(np.mean([r["meets"] for r in rows]))}

    out = {"calibrated": run({}, range(n))}
    for name, lab in (("ignores the field (angular emission, non-uniformity)",
                       {"model_field": False}),
                      ("ignores the collimator transmission (bare screen, datasheet)",
                       {"through_collimator": False}),
                      ("ignores the gamma (datasheet curve)", {"measure_lut": False}),
                      ("no monitor (warm-up, drift)", {"monitor": False})):
        r = run(lab, range(n))
        out[name] = {k: r[k] for k in ("validation_rms_error", "validation_sigma_rms",
                                       "fraction_abs_z_above_2", "fraction_consistent")}
    bench = Bench(bench_from_dict({}))
    tr = TruthScreen(bench)
    inst = ReferenceInstrument(bench, tr)
    cal = calibrate_radiometry(bench, tr, inst)
    t0 = time.perf_counter()
    val = validate_radiometry(bench, cal, tr, inst, bench.chain_detector())
    out["one bench, detector chain"] = {"seconds": time.perf_counter() - t0,
                                       **val.summary()}
    print(json.dumps(out, indent=1))


def moon(n: int) -> None:
    """The Moon stimulus on ``n`` seeded truth benches (seeds 8400 + i): the scenario's
    rendered Moon, counts from each bench's calibration against the reference instrument, shown
    on its truth screen, acquired with the ideal detector (the error is the bench's) at the
    paper's k = 13 333 and at the screen-limited k, through the true geometric mapping (the
    radiometry alone); disc-electrons and inner-median ratios against the orbit exposure with
    their stated 1-sigma; two negative controls; one bench through the detector chain."""
    import numpy as np

    from starnav.calibration import Bench, IdealDetector, bench_from_dict
    from starnav.calibration.geometric import TrueMapping
    from starnav.calibration.moon_stimulus import METRICS, MOON_TERMS, compare_moon_stimulus
    from starnav.calibration.workflows import render_reference
    from starnav.seeding import generator

    logging.basicConfig(level=logging.WARNING)
    base = Bench(bench_from_dict({}))
    t0 = time.perf_counter()
    img = render_reference(base.config)
    out: dict = {"render_s": time.perf_counter() - t0, "seeds": f"8400..{8400 + n - 1}"}
    t_r = base.config.scaling.render_exposure_ms * 1e-3

    def run(lab: dict, t_b: float | None, seeds: range, detector: str = "ideal") -> dict:
        bench = Bench(bench_from_dict({"radiometric_lab": lab}))
        mapping = TrueMapping(bench.geometry)
        cache: dict = {}
        rows = []
        t1 = time.perf_counter()
        for i in seeds:
            tr, inst, cal = seeded_lab(bench, 8400 + i, cache)
            det = IdealDetector(bench.camera) if detector == "ideal" else bench.chain_detector()
            mc = compare_moon_stimulus(bench, img, t_r, mapping, cal, tr, inst, det,
                                       bench_exposure_s=t_b, rng=generator(8400 + i, 6, 9))
            rows.append((mc.errors(), mc.sigmas(), mc.budget, mc.consistent, mc.meets_use,
                         mc.comparison.metrics()))
        res: dict = {"benches": len(rows), "seconds": time.perf_counter() - t1,
                     "k": rows[0][5]["k"], "peak_count": rows[0][5]["peak_count"]}
        for k in METRICS:
            e = np.array([r[0][k] for r in rows])
            s_ = np.array([r[1][k] for r in rows])
            res[k] = {"mean_ratio": float(1 + e.mean()),
                      "rms_error": float(np.sqrt(np.mean(e**2))),
                      "stated_sigma_rms": float(np.sqrt(np.mean(s_**2))),
                      "within_2_sigma": float(np.mean(np.abs(e) <= 2 * s_)),
                      "mean_z2": float(np.mean((e / s_) ** 2)),
                      "budget_rms": {t: float(np.sqrt(np.mean([r[2][k][t] ** 2
                                                               for r in rows])))
                                     for t in MOON_TERMS}}
        res["fraction_consistent"] = float(np.mean([r[3] for r in rows]))
        res["fraction_meets_use"] = float(np.mean([r[4] for r in rows]))
        return res

    out["k = 13 333 (200 ms)"] = run({}, 0.2, range(n))
    out["screen-limited k"] = run({}, None, range(n))
    for name, lab in (("k = 13 333, lab ignores the field", {"model_field": False}),
                      ("k = 13 333, lab ignores the transmission (bare screen, datasheet)",
                       {"through_collimator": False})):
        r = run(lab, 0.2, range(n))
        out[name] = {"disc_ratio": {k: r["disc_ratio"][k] for k in
                                    ("mean_ratio", "rms_error", "stated_sigma_rms",
                                     "within_2_sigma")},
                     "fraction_consistent": r["fraction_consistent"]}
    out["k = 13 333, one bench, detector chain"] = run({}, 0.2, range(1), "chain")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--intrinsics", type=int, metavar="N", default=0,
                    help="calibrate the camera on N seeded benches instead")
    ap.add_argument("--radiometric", type=int, metavar="N", default=0,
                    help="radiometric calibration against the reference on N seeded benches")
    ap.add_argument("--moon", type=int, metavar="N", default=0,
                    help="the Moon stimulus on N seeded truth benches (calibrated counts, "
                    "truth screen, budget)")
    a = ap.parse_args()
    if a.moon:
        moon(a.moon)
    elif a.radiometric:
        radiometric(a.radiometric)
    elif a.intrinsics:
        intrinsics(a.intrinsics)
    else:
        main()
