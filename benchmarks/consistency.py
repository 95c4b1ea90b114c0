"""Navigation consistency on rendered frames: the numbers docs/navigation.md quotes.

Prints, on arcs never used by the calibration or the tuning (the CI tests in
tests/navigation/test_consistency.py check the same quantities against their criteria):

1. refined limb points: rms(error / sigma) at 0.015 ms and 0.18 ms, bias and spread, on three
   test arcs (30 frames 1.5 days apart, real Moon, 8 spp);
2. fixes: mean NEES (3 dof) against the truth on the same frames;
3. the filter on the demo's arc (4 frames 2 h apart) and on the first scoring arc of
   tools/score_navigation.py (13 frames 2 h apart), 20 Monte Carlo runs each on its own
   terrain, detector noise, attitude knowledge error and initial error, every mismatch on
   (the defaults: the truth's planets, SRP and J2, the PSF estimated from stars, the terrain
   statistics from a coarser DEM): the time-averaged NEES against its 99 % band of effective
   samples (starnav.navigation.metrics.anees_statistics), the fraction of epochs whose
   run-averaged NEES is inside its 95 % band, position and velocity NEES, NIS, errors inside
   the 3-sigma bounds, final position error, at 0.015 ms (limb-common states) and 7.7 ms
   (range scale + 3-axis shift); the demo arc's filter without states; and a smooth Moon at
   0.015 ms without states (noise runs only).

Run::

    .venv/bin/python benchmarks/consistency.py        # ~8 minutes on 2 cores
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import chi2

from starnav.batch.consistency import SATURATED, WELL_EXPOSED

TEST_ARCS = ([], ["trajectory.halo_phase_deg=180", "trajectory.epoch=2027-06-15T00:00:00 TDB",
                  "seed=777"],
             ["trajectory.halo_phase_deg=90", "trajectory.epoch=2027-07-20T00:00:00 TDB",
              "seed=778"])
ARC = ["trajectory.duration_days=13.5", "trajectory.cadence_s=129600", "render.spp=8"]
SHORT_ARC = ["trajectory.duration_days=0.25", "trajectory.cadence_s=7200", "render.spp=8"]
RUNS = 20


def main() -> None:
    from starnav.batch.consistency import (
        filter_consistency,
        limb_point_records,
        noise_monte_carlo,
        refinement_consistency,
        terrain_renders,
    )
    from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES, demo_scenario
    from starnav.batch.scores import recorded_scores
    from starnav.config import scenario_from_dict, scenario_to_dict

    t0 = time.perf_counter()
    recs = [limb_point_records(scenario_to_dict(scenario_from_dict(demo_scenario(), a + ARC)),
                               1, (WELL_EXPOSED, SATURATED)) for a in TEST_ARCS]
    print("== refined points and fixes, three test arcs (30 frames)")
    for t in (WELL_EXPOSED[0], SATURATED[0]):
        pts = [r[t]["points"] for r in recs]
        tab = {k: np.concatenate([p[k] for p in pts]) for k in pts[0]}
        res = refinement_consistency(tab)
        nees = np.concatenate([r[t]["fix_nees"] for r in recs])
        lo, hi = chi2.ppf([0.005, 0.995], 3 * nees.size) / nees.size
        a = res["all"]
        print(f"{t * 1e3:g} ms: {a['points']} points, rms(e/sigma) {a['rms_z']:.3f}, bias "
              f"{a['bias_px']:+.3f} px, std {a['std_px']:.3f} px (saturated windows: "
              f"{res['saturated']['points']}); fixes: {nees.size}, mean NEES "
              f"{nees.mean():.2f} (99 % band {lo:.2f}-{hi:.2f})")
    # the demo arc and the first scoring arc (tools/score_navigation.py), every mismatch on
    # (the defaults: truth forces, estimated PSF, coarser terrain statistics)
    arcs = {"demo arc": SHORT_ARC,
            # the current scoring set's first arc, from its record (re-run, never tuned on)
            "scoring arc 1": recorded_scores()["scoring_arcs"][0] + ["trajectory.duration_days=1.0",
                                            "trajectory.cadence_s=7200", "render.spp=8"]}
    cases = {"0.015 ms, limb-common": [],
             "7.7 ms, range scale + shift": ["detector.exposure_time_s=0.0077",
                                             *dict(DEMO_EXPOSURE_OVERRIDES)[7.7e-3]]}
    for arc_name, arc in arcs.items():
        print(f"== filter, {arc_name}, {RUNS} runs (terrain, noise, attitude, initial error)")
        cfg = scenario_to_dict(scenario_from_dict(demo_scenario(), arc))
        per_run = terrain_renders(cfg, RUNS)
        for name, over in cases.items():
            c = scenario_to_dict(scenario_from_dict(cfg, over))
            _report(f"{arc_name}, {name}",
                    filter_consistency(noise_monte_carlo(c, RUNS, per_run=per_run)))
    c = scenario_to_dict(scenario_from_dict(demo_scenario(), SHORT_ARC + [
        "navigation.filter.bias_model=none"]))
    _report("demo arc, 0.015 ms, no states", filter_consistency(noise_monte_carlo(
        c, RUNS, per_run=terrain_renders(c, RUNS))))
    smooth = scenario_to_dict(scenario_from_dict(demo_scenario(), [
        "trajectory.duration_days=0.3", "trajectory.cadence_s=3600", "render.spp=8",
        "moon.shape=sphere", "navigation.filter.bias_model=none"]))
    _report("smooth Moon, 0.015 ms, no states (noise runs)",
            filter_consistency(noise_monte_carlo(smooth, RUNS)))
    print(f"wall time {time.perf_counter() - t0:.0f} s")


def _report(name: str, r: dict) -> None:
    fin = r["final_position_error_pct_range"]
    st, pos, vel = r["nees"], r["nees_position"], r["nees_velocity"]
    print(f"{name}: NEES {r['nees_mean']:.2f} (band {r['nees_band'][0]:.2f}-"
          f"{r['nees_band'][1]:.2f}, tau {st['autocorrelation_time']:.2f} epochs, "
          f"{r['verdict']}), epochs in the 95 % band {100 * st['epochs_in_band']:.0f} % (above "
          f"{100 * st['epochs_above']:.0f} %), position NEES {pos['mean']:.2f} "
          f"({pos['verdict']}), velocity {vel['mean']:.2f} ({vel['verdict']}), NIS "
          f"{r.get('nis_mean', float('nan')):.2f} (band {r['nis_band'][0]:.2f}-"
          f"{r['nis_band'][1]:.2f}), inside 3-sigma {100 * r['within_3sigma']['all']:.2f} %, "
          f"final position error {fin['median']:.3f} % of range (p90 {fin['p90']:.3f} %)",
          flush=True)


if __name__ == "__main__":
    main()
