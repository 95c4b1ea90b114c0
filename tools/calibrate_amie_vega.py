#!/usr/bin/env python
"""Measure the SMART-1 AMIE's flat quantum efficiency and PSF core on Vega, once; writes
``src/starnav/data/amie/vega_calibration.json``.

The measurement is :func:`starnav.reference.amie.vega.stellar_calibration` (its module
docstring tells the method): aperture photometry of Vega on the 200 ms frame
``AMI_EE3_040326_00034_00200`` against the CALSPEC Vega spectrum through the AMIE aperture and
measured NONE-filter curve; a Gaussian fitted to the star's core. Only this stellar frame is
used: the Moon frames, which score the simulation, are not looked at.

Usage::

    .venv/bin/python tools/calibrate_amie_vega.py            # measure, print, write the JSON
    .venv/bin/python tools/calibrate_amie_vega.py --dry-run  # measure and print only
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from starnav.reference.amie.vega import stellar_calibration, write_calibration

OUT = Path(__file__).resolve().parents[1] / "src/starnav/data/amie/vega_calibration.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dry-run", action="store_true", help="print only, do not write")
    args = ap.parse_args()
    cal = stellar_calibration()
    print(json.dumps(asdict(cal), indent=2, sort_keys=True))
    g = [cal.growth_curve_dn[k] for k in ("5", "7", "10", "15", "20")]
    print(f"Vega: {cal.measured_dn:.1f} DN in {cal.exposure_s * 1e3:.0f} ms "
          f"(growth curve 5-20 px: {min(g):.1f}-{max(g):.1f} DN); predicted at QE = 1: "
          f"{cal.predicted_e_per_s_at_unit_qe:.4g} e-/s -> QE = {cal.quantum_efficiency:.4f}; "
          f"PSF core sigma {cal.psf_sigma_px:.3f} +- {cal.psf_sigma_err_px:.3f} px")
    if not args.dry_run:
        print("wrote", write_calibration(cal, OUT))


if __name__ == "__main__":
    main()
