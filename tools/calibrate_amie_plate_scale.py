#!/usr/bin/env python
"""Calibrate the SMART-1 AMIE's in-flight plate scale once, on the packaged Moon frames; writes
``src/starnav/data/amie/plate_scale.json``.

The method is :func:`starnav.reference.amie.plate_scale.calibrate_plate_scale` (its module
docstring): the navigation chain's range on each real frame with the nominal focal length
against the label's, averaged per epoch, then over the epochs; the standard error and a
frame's predictive 1-sigma from the epochs' scatter; leave-one-epoch-out errors.

Usage::

    .venv/bin/python tools/calibrate_amie_plate_scale.py            # measure, print, write
    .venv/bin/python tools/calibrate_amie_plate_scale.py --dry-run  # measure and print only
"""

from __future__ import annotations

import argparse
from pathlib import Path

from starnav.reference.amie.plate_scale import calibrate_plate_scale, write_plate_scale

OUT = Path(__file__).resolve().parents[1] / "src/starnav/data/amie/plate_scale.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dry-run", action="store_true", help="print only, do not write")
    args = ap.parse_args()
    cal = calibrate_plate_scale()
    print(f"focal scale {cal.focal_scale:.5f} +- {cal.focal_scale_sigma:.5f} "
          f"(f = {cal.focal_length_m * 1e3:.2f} +- {cal.focal_length_sigma_m * 1e3:.2f} mm); "
          f"a frame's range 1-sigma {100 * cal.frame_range_sigma_fraction:.2f} %")
    for e, k in sorted(cal.epochs.items()):
        print(f"  epoch {e}: k = {k:.5f}")
    for name, f in sorted(cal.frames.items()):
        print(f"  {name}: k = {f['k']:.5f}; range error nominal "
              f"{f['range_error_nominal_pct']:+.2f} %, calibrated "
              f"{f['range_error_calibrated_pct']:+.2f} %, other epochs "
              f"{f['range_error_other_epochs_pct']:+.2f} %")
    if not args.dry_run:
        print("wrote", write_plate_scale(cal, OUT))


if __name__ == "__main__":
    main()
