#!/usr/bin/env python
"""Score the released navigation defaults once, on arcs and seeds that tuned nothing.

The protocol (docs/navigation.md, "Tuning apart from scoring"):

- **Tuning set** (what calibrated the defaults; never scored): the refinement's model errors on
  the five arcs of ``tools/calibrate_refine_model_error.py`` (halo phases 60, 240, 120, 300 and
  30 deg, March to May 2027, seeds 4242-4246), the bias states and process noise on the two
  arcs of ``tools/tune_bias_states.py`` (phases 60 and 240 deg, March 2027, seeds 4242-4243),
  the PSF estimate on the star frames of ``tools/estimate_psf.py`` (seeds 9100-9103), the
  camera's bench calibrations (``tools/calibrate_camera_bench.py``, bench seeds 9500-9539),
  the fix covariance's factors per bin of phase (the refinement's arcs again).
- **Scoring set** (:data:`SCORING_ARCS`): another season (March and June 2029), halo phases
  (130 and 290 deg) apart from the tuning phases and the spent scoring sets (:data:`SPENT`),
  Sun phases 32-48 deg (the gibbous side, below the tuning arcs' 50 deg) and 127-130 deg,
  ranges 54 500-60 600 and 69 700-72 200 km, seeds 9409-9410 (chosen from the geometry alone,
  before any run); the truth with every mismatch on (planets, solar radiation pressure with
  eclipses and J2 in the truth only; PSF estimated from stars; terrain statistics from a
  coarser DEM than the rendered one; the camera known as one emulated bench calibrated it),
  each run on its own terrain, detector noise, attitude knowledge error, initial error and
  bench.

The record (``src/starnav/data/navigation/scores.json``) keeps the scores, the scoring set, the
commit scored and the fingerprint of every default the score depends on
(``starnav.batch.scores.defaults_fingerprint``); ``tests/navigation/test_scores.py`` fails
when a default changes after its score, and then it is scored again on a new scoring set
(change :data:`SCORING_ARCS`' seeds and season; the note of the commit says so).

Usage::

    .venv/bin/python tools/score_navigation.py            # score, print, write the record
    .venv/bin/python tools/score_navigation.py --runs 4 --dry-run
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "src/starnav/data/navigation/scores.json"
FIGURE = ROOT / "docs/figures/anees_scoring.png"
SCORING_ARCS = (["trajectory.halo_phase_deg=130", "trajectory.epoch=2029-03-14T00:00:00 TDB",
                 "seed=9409"],
                ["trajectory.halo_phase_deg=290", "trajectory.epoch=2029-06-20T00:00:00 TDB",
                 "seed=9410"])
#: Scoring sets already spent (each saw a released default once; never scored again).
SPENT = ((["trajectory.halo_phase_deg=150", "trajectory.epoch=2027-08-10T00:00:00 TDB",
           "seed=9301"],
          ["trajectory.halo_phase_deg=330", "trajectory.epoch=2027-10-05T00:00:00 TDB",
           "seed=9302"]),
         (["trajectory.halo_phase_deg=100", "trajectory.epoch=2027-12-08T00:00:00 TDB",
           "seed=9401"],
          ["trajectory.halo_phase_deg=200", "trajectory.epoch=2028-01-05T00:00:00 TDB",
           "seed=9402"]),
         (["trajectory.halo_phase_deg=20", "trajectory.epoch=2028-02-16T00:00:00 TDB",
           "seed=9403"],
          ["trajectory.halo_phase_deg=280", "trajectory.epoch=2028-04-19T00:00:00 TDB",
           "seed=9404"]),
         (["trajectory.halo_phase_deg=170", "trajectory.epoch=2028-06-14T00:00:00 TDB",
           "seed=9405"],
          ["trajectory.halo_phase_deg=350", "trajectory.epoch=2028-09-20T00:00:00 TDB",
           "seed=9406"]),
         (["trajectory.halo_phase_deg=80", "trajectory.epoch=2028-11-01T00:00:00 TDB",
           "seed=9407"],
          ["trajectory.halo_phase_deg=260", "trajectory.epoch=2029-01-17T00:00:00 TDB",
           "seed=9408"]))
ARC = ["trajectory.duration_days=1.0", "trajectory.cadence_s=7200", "render.spp=8"]
RUNS = 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=RUNS)
    ap.add_argument("--dry-run", action="store_true")
    args = ap.parse_args()
    from scipy.stats import chi2

    from starnav.atomic import atomic_write_text
    from starnav.batch.consistency import filter_consistency, noise_monte_carlo, terrain_renders
    from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES, demo_scenario
    from starnav.batch.scores import EXPOSURES, defaults_fingerprint
    from starnav.config import scenario_from_dict, scenario_to_dict

    t0 = time.perf_counter()
    scores = []
    for arc in SCORING_ARCS:
        cfg = scenario_to_dict(scenario_from_dict(demo_scenario(), arc + ARC))
        per_run = terrain_renders(cfg, args.runs)
        for exposure in EXPOSURES:
            over = [f"detector.exposure_time_s={exposure!r}",
                    *dict(DEMO_EXPOSURE_OVERRIDES).get(exposure, ())]
            c = scenario_to_dict(scenario_from_dict(cfg, over))
            r = filter_consistency(noise_monte_carlo(c, args.runs, per_run=per_run))
            st = r["nees"]
            row = {"arc": arc, "exposure_s": exposure, "runs": args.runs,
                   "epochs": st["epochs"],
                   "epochs_in_band": st["epochs_in_band"],
                   "epochs_above": st["epochs_above"],
                   "nees_mean": r["nees_mean"], "nees_band": list(r["nees_band"]),
                   "verdict": r["verdict"],
                   "nees_position_mean": r["nees_position"]["mean"],
                   "nees_velocity_mean": r["nees_velocity"]["mean"],
                   "final_position_error_pct_range":
                       r["final_position_error_pct_range"]["median"],
                   "per_epoch_nees": r["nees_per_step"],
                   "per_epoch_band": [list(chi2.ppf([0.025, 0.975], 6 * args.runs) / args.runs)]
                   * len(r["nees_per_step"])}
            scores.append(row)
            print(json.dumps({k: v for k, v in row.items() if not k.startswith("per_")}),
                  flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    doc = {"tool": "tools/score_navigation.py", "commit": commit,
           "date": _dt.date.today().isoformat(), "scoring_arcs": [list(a) for a in SCORING_ARCS],
           "spent_scoring_sets": [[list(a) for a in sset] for sset in SPENT],
           "arc": ARC, "defaults_fingerprint": defaults_fingerprint(), "scores": scores}
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    if not args.dry_run:
        atomic_write_text(OUT, json.dumps(doc, indent=1) + "\n")
        print(f"wrote {OUT}")
        figure(doc, FIGURE)
        print(f"wrote {FIGURE}")


def figure(doc: dict, path: Path) -> None:
    """Per-epoch ANEES of every scored arc and exposure against its 95 % band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = doc["scores"]
    fig, axes = plt.subplots(len(rows), 1, figsize=(7.0, 1.9 * len(rows)), sharex=True)
    for ax, r in zip(np.atleast_1d(axes), rows, strict=True):
        v = np.array(r["per_epoch_nees"], float)
        b = np.array(r["per_epoch_band"], float)
        t = np.arange(v.size) * 2.0
        ax.fill_between(t, b[:, 0], b[:, 1], color="C0", alpha=0.2, lw=0)
        ax.axhline(6.0, color="C2", lw=0.8)
        ax.plot(t, v, "o-", ms=3, color="k")
        ax.set_ylabel("ANEES")
        ax.set_title(f"{r['arc'][1].split('=')[1][:10]}, halo {r['arc'][0].split('=')[1]} deg, "
                     f"{r['exposure_s'] * 1e3:g} ms: {100 * r['epochs_in_band']:.0f} % of "
                     f"epochs in the 95 % band", fontsize=8)
    np.atleast_1d(axes)[-1].set_xlabel("hours from the first frame")
    fig.suptitle(f"Scoring set, {rows[0]['runs']} runs, every mismatch on", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
