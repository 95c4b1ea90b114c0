#!/usr/bin/env python
"""Diagnose the fly-by estimator on the *development* fly-bys, never on a scoring one: which
measurement or model part makes it inconsistent (docs/navigation.md, "A large body: why the
filter was overconfident on Eros").

Each development fly-by (``starnav.navigation.trn.scoring.DEVELOPMENT_FLYBYS``, Monte Carlo
seed 29) runs with the released defaults and with one part changed at a time: the exact map
instead of the coarse one, features alone (no silhouette), the silhouette alone (no
landmarks), the model's scale known. Printed per variant: the time-averaged ANEES with its
band, the fraction of epochs inside their 95 % band, the position and velocity NEES, and the
ANEES of each third of the pass.

Usage::

    PYTHONPATH=src flock /tmp/starnav-heavy.lock python tools/diagnose_flyby.py [--runs 4]
"""

from __future__ import annotations

import argparse

import numpy as np

from starnav.batch.flyby_synthetic import case_monte_carlo
from starnav.navigation.trn.scoring import DEVELOPMENT_FLYBYS, score

#: (label, filter keys, shape-model keys) of each variant.
VARIANTS = (
    ("released defaults", {}, {}),
    ("exact map", {}, {"map": "exact"}),
    ("features alone", {"use_centroid": False, "use_radius": False}, {}),
    ("silhouette alone", {"max_landmarks": 0}, {}),
    ("scale known", {}, {"scale_sigma": 0.0, "estimate_scale": False}),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=4)
    args = ap.parse_args()
    for case in DEVELOPMENT_FLYBYS:
        for label, filt, shape in VARIANTS:
            mc, cpu = case_monte_carlo(case, args.runs, seed=29, filter_overrides=filt,
                                       shape_overrides=shape)
            r = score(mc, case, cpu)
            thirds = [float(np.nanmean(mc.nees[:, i]))
                      for i in np.array_split(np.arange(mc.nees.shape[1]), 3)]
            lo, hi = r["anees_band"]
            print(f"{case.name:14s} {label:18s} ANEES {r['anees_mean']:6.2f} "
                  f"[{lo:.2f}, {hi:.2f}] in band {r['epochs_in_band']:.0%}; position "
                  f"{r['position_nees']['mean']:.2f}, velocity {r['velocity_nees']['mean']:.2f}; "
                  "thirds " + ", ".join(f"{x:.1f}" for x in thirds), flush=True)


if __name__ == "__main__":
    main()
