#!/usr/bin/env python
"""Diagnose the fly-by estimator on the *development* fly-bys, never on a scoring one: which
measurement or model part makes it inconsistent (docs/navigation.md, "A large body: why the
filter was overconfident on Eros").

Each development fly-by (``starnav.navigation.trn.scoring.DEVELOPMENT_FLYBYS``, Monte Carlo
seed 29) runs with the released defaults and with one part changed at a time: the exact map
instead of the coarse one, features alone (no silhouette), the silhouette alone (no
landmarks), the model's scale known, and the shape law's crescent term at its calibrated gain
(``crescent.filter`` of ``data/navigation/flyby_coarse_map_error.json``; whether or not the
released defaults carry it). Printed per variant: the time-averaged ANEES with its
band, the fraction of epochs inside their 95 % band, the position and velocity NEES, and the
ANEES of each third of the pass, and the centroid's NIS per degree of freedom in each third
(1 when its model-error sigmas cover its error).

Usage::

    PYTHONPATH=src flock /tmp/starnav-heavy.lock python tools/diagnose_flyby.py [--runs 4]
        [--variants "released defaults" "crescent term"]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from starnav.batch.flyby_synthetic import case_monte_carlo
from starnav.data import packaged_path
from starnav.navigation.trn.scoring import DEVELOPMENT_FLYBYS, score

#: The crescent term's calibrated filter keys (tools/calibrate_flyby_coarse_map.py).
CRESCENT = json.loads(packaged_path("navigation/flyby_coarse_map_error.json").read_text())[
    "crescent"]["filter"]

#: (label, filter keys, shape-model keys) of each variant.
VARIANTS = (
    ("released defaults", {}, {}),
    ("exact map", {}, {"map": "exact"}),
    ("features alone", {"use_centroid": False, "use_radius": False}, {}),
    ("silhouette alone", {"max_landmarks": 0}, {}),
    ("scale known", {}, {"scale_sigma": 0.0, "estimate_scale": False}),
    ("crescent term", CRESCENT, {}),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--variants", nargs="+", default=[v[0] for v in VARIANTS],
                    help="labels of the variants to run (default: all)")
    args = ap.parse_args()
    labels = [v[0] for v in VARIANTS]
    unknown = [v for v in args.variants if v not in labels]
    if unknown or args.runs < 1:
        ap.error(f"--variants must be among {labels} (got {unknown}) and --runs >= 1 "
                 f"(got {args.runs})")
    for case in DEVELOPMENT_FLYBYS:
        for label, filt, shape in (v for v in VARIANTS if v[0] in args.variants):
            mc, cpu = case_monte_carlo(case, args.runs, seed=29, filter_overrides=filt,
                                       shape_overrides=shape)
            r = score(mc, case, cpu)
            thirds = [float(np.nanmean(mc.nees[:, i]))
                      for i in np.array_split(np.arange(mc.nees.shape[1]), 3)]
            cen = [np.nansum([run.info["nis_by_kind"]["centroid"][i].sum() for run in mc.runs])
                   / max(sum(run.info["nis_dof_by_kind"]["centroid"][i].sum()
                             for run in mc.runs), 1)
                   for i in np.array_split(np.arange(mc.nees.shape[1]), 3)]
            lo, hi = r["anees_band"]
            print(f"{case.name:14s} {label:18s} ANEES {r['anees_mean']:6.2f} "
                  f"[{lo:.2f}, {hi:.2f}] in band {r['epochs_in_band']:.0%}; position "
                  f"{r['position_nees']['mean']:.2f}, velocity {r['velocity_nees']['mean']:.2f}; "
                  "thirds " + ", ".join(f"{x:.1f}" for x in thirds)
                  + "; centroid NIS / dof by thirds " + ", ".join(f"{x:.2f}" for x in cen),
                  flush=True)


if __name__ == "__main__":
    main()
