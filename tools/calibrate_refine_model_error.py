#!/usr/bin/env python
"""Calibrate the model-error terms of the subpixel limb refinement on *calibration arcs*,
never on the arcs that score it; writes ``src/starnav/data/navigation/refine_model_error.json``
(read by ``NavigationConfig.chain_options`` with the ``detector-psf`` edge model).

Why: the refinement's per-point sigma from the pixels' noise alone is ~0.015 px at 0.015 ms,
while the points scatter by ~0.1 px on the real Moon: the edge model does not follow a real
limb profile exactly, a saturated window's edge is also shaped by blooming and inter-pixel
capacitance, and the lit limb departs from the sphere by the terrain (the DEM's silhouette,
``starnav.dem.limb``) and by the shadows near the terminator, which the silhouette model does
not see; part of it is shared by the whole frame (the disc looks smaller, its centre pulled
towards the Sun). The terms and how each is measured:
``starnav.batch.consistency.calibrate_model_error`` and
``starnav.navigation.refine.ModelErrorCalibration``.

Procedure: the demo scenario (AA-STR, real Moon, 8 spp) on five arcs of 14 frames one day
apart (halo phase 60, 240, 120, 300 and 30 deg, epochs 2027-03-06, 03-26, 04-16, 05-06 and
05-26, seeds 4242-4246: Sun phase from crescent to gibbous, a different limb in every frame);
each arc rendered as the real Moon and as a smooth sphere; exposed at 0.015 ms (segments at
200 DN) and, the smooth arcs, at 0.18 ms (segments at 2048 DN, the exposure study's
threshold); two noise runs each. Two passes: the first, with no model error, gives the
per-point terms (edge model error and saturated extra per bin of phase, terrain scale); the
second re-exposes the same renders with them (the real Moon also at 0.18 ms) and gives,
from the fixes, the covariance of the errors the frame shares and that of everything slowly
varying (all but the pixels' noise and the attitude).
The tests score the result on three other arcs (tests/navigation/test_consistency.py: the
demo arc, halo phase 0, 2027-03-01, seed 20250101, and two more).

``--blooming`` calibrates, with the packaged terms, those of a limb far past the full well
(the paper's 7.7 ms, segments at 2048 DN; ``ModelErrorCalibration.blooming``) on the same
real-Moon arcs, 2 noise runs each, phase bins 0-60-90-120-180 deg (the fix's error changes
fastest between a gibbous and a quarter Moon there): pass 1, no blooming terms, gives a
saturated window's extra per bin from the residuals of each frame's three-mode fit
(``starnav.batch.consistency.saturated_extra_by_phase``); pass 2, with it, gives from the
fixes their slowly varying covariance (pooled, by maximum likelihood:
``starnav.batch.consistency.shared_covariance_mle``; scaled to a mean NEES of 3) and its factor
per bin. No window is dropped for its fitted over-exposure there.

``--phase-scales`` runs the second pass alone on the real-Moon arcs with the packaged terms
and writes only the factors per bin of phase on the pooled fix covariance
(``starnav.batch.consistency.fix_phase_scales``): the shared limb errors grow towards the
crescent, and one pooled covariance is too small there and too large near full.

Usage::

    .venv/bin/python tools/calibrate_refine_model_error.py            # calibrate, write
    .venv/bin/python tools/calibrate_refine_model_error.py --dry-run  # print only
    .venv/bin/python tools/calibrate_refine_model_error.py --phase-scales
    .venv/bin/python tools/calibrate_refine_model_error.py --blooming
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
from pathlib import Path

import numpy as np

from starnav.batch.consistency import SATURATED, WELL_EXPOSED
from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES

OUT = Path(__file__).resolve().parents[1] / "src/starnav/data/navigation/refine_model_error.json"
ARCS = (["trajectory.halo_phase_deg=60", "trajectory.epoch=2027-03-06T00:00:00 TDB",
         "seed=4242"],
        ["trajectory.halo_phase_deg=240", "trajectory.epoch=2027-03-26T00:00:00 TDB",
         "seed=4243"],
        ["trajectory.halo_phase_deg=120", "trajectory.epoch=2027-04-16T00:00:00 TDB",
         "seed=4244"],
        ["trajectory.halo_phase_deg=300", "trajectory.epoch=2027-05-06T00:00:00 TDB",
         "seed=4245"],
        ["trajectory.halo_phase_deg=30", "trajectory.epoch=2027-05-26T00:00:00 TDB",
         "seed=4246"])
COMMON = ["trajectory.duration_days=13.2", "trajectory.cadence_s=86400", "render.spp=8"]
RUNS = 2
#: No model error at all: the first pass.
#: The blooming regime's calibration exposure and its detector settings: the demo's second
#: exposure (the paper's 7.7 ms, segments at 2048 DN), its filter's settings aside; and the
#: regime's bins of phase [deg].
BLOOMING = next((t, tuple(o for o in ov if not o.startswith("navigation.")))
                for t, ov in DEMO_EXPOSURE_OVERRIDES)
BLOOMING_EDGES = (0.0, 60.0, 90.0, 120.0, 180.0)
UNCALIBRATED = {"phase_edges_deg": [0.0, 180.0], "edge_model_error_px": [0.0],
                "saturated_model_error_px": [0.0], "terrain_scale": 1.0,
                "common_covariance": [[0.0] * 3] * 3}


def _merge(tables: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One table of several arcs' (frame numbers made distinct: arc i adds 1000 i)."""
    out = {k: np.concatenate([t[k] for t in tables]) for k in tables[0]}
    out["frame"] = np.concatenate([t["frame"] + 1000 * i for i, t in enumerate(tables)])
    return out


def _use(doc: dict, path: Path) -> None:
    """Make ``doc`` the packaged calibration the chain reads from now on."""
    from starnav.atomic import atomic_write_text
    from starnav.navigation.refine import packaged_model_error

    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    packaged_model_error.cache_clear()


def main() -> None:
    from starnav.batch.consistency import (
        calibrate_model_error,
        limb_point_records,
        modelled_sigma,
        render_arc,
        total_sigma,
    )
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict
    from starnav.dem.limb import limb_topography_for
    from starnav.navigation.refine import ModelErrorCalibration

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dry-run", action="store_true", help="print, restore the packaged file")
    ap.add_argument("--phase-scales", action="store_true",
                    help="the fix covariance's factors per bin of phase alone (second pass)")
    ap.add_argument("--blooming", action="store_true",
                    help="the blooming regime's terms alone (7.7 ms)")
    args = ap.parse_args()
    if args.blooming:
        blooming(args.dry_run)
        return
    if args.phase_scales:
        phase_scales(args.dry_run)
        return
    before = OUT.read_text() if OUT.exists() else None
    base = demo_scenario()
    sc = scenario_from_dict(base)
    topo = limb_topography_for(sc.moon.dem)
    win = sc.navigation.refine.window_size_px
    configs = {(i, shape): scenario_to_dict(scenario_from_dict(
        base, [*arc, *COMMON, f"moon.shape={shape}"]))
        for i, arc in enumerate(ARCS) for shape in ("sphere", "dem")}
    renders = {k: render_arc(c) for k, c in configs.items()}
    print("rendered", sum(len(r) for r in renders.values()), "frames", flush=True)
    try:
        # pass 1: the points' own errors
        _use(UNCALIBRATED, OUT)
        smooth, smooth_sat, terrain = [], [], []
        for (i, shape), cfg in configs.items():
            cases = (WELL_EXPOSED, SATURATED) if shape == "sphere" else (WELL_EXPOSED,)
            rec = limb_point_records(cfg, RUNS, cases, renders[(i, shape)])
            if shape == "sphere":
                smooth.append(rec[WELL_EXPOSED[0]]["points"])
                smooth_sat.append(rec[SATURATED[0]]["points"])
            else:
                terrain.append(rec[WELL_EXPOSED[0]]["points"])
        first = calibrate_model_error(_merge(smooth + smooth_sat), _merge(terrain), None, topo,
                                      win)
        print("pass 1:", {k: first[k] for k in ("edge_model_error_px",
                                                "saturated_model_error_px", "terrain_scale")},
              flush=True)
        # pass 2: the shared errors, from the fixes made with the points' whole own errors
        _use({k: first[k] for k in UNCALIBRATED}, OUT)
        fixes, terrain2, smooth_fixes = [], [], []
        for (i, shape), cfg in configs.items():
            if shape == "dem":
                rec = limb_point_records(cfg, RUNS, (WELL_EXPOSED, SATURATED),
                                         renders[(i, shape)])
                fixes += [rec[WELL_EXPOSED[0]]["fixes"], rec[SATURATED[0]]["fixes"]]
                terrain2.append(rec[WELL_EXPOSED[0]]["points"])
            else:
                rec = limb_point_records(cfg, RUNS, (WELL_EXPOSED,), renders[(i, shape)])
                smooth_fixes.append(rec[WELL_EXPOSED[0]]["fixes"])
        res = calibrate_model_error(_merge(smooth + smooth_sat), _merge(terrain),
                                    _merge(fixes), topo, win,
                                    smooth_fixes=_merge(smooth_fixes))
    finally:
        if before is not None:
            OUT.write_text(before)
    cal = ModelErrorCalibration.from_dict(res)
    doc = {**res, "calibration_arcs": [a + COMMON for a in ARCS], "runs": RUNS,
           "exposures_s": [WELL_EXPOSED[0], SATURATED[0]],
           "method": "starnav.batch.consistency.calibrate_model_error (method of moments)",
           "written": _dt.date.today().isoformat(),
           "tool": "tools/calibrate_refine_model_error.py"}
    doc["in_sample_rms_z"] = {}
    for name, tabs, tp in (("smooth 0.015 ms", smooth, None), ("smooth 0.18 ms", smooth_sat, None),
                           ("real Moon 0.015 ms", terrain, topo)):
        zs = []
        for t in tabs:
            z = t["error"] / modelled_sigma(t, cal, tp, win)
            zs.append(float(np.sqrt(np.mean(z * z))))
        doc["in_sample_rms_z"][name] = zs
        print(name, "rms(e / sigma) per arc:", ", ".join(f"{z:.3f}" for z in zs), flush=True)
    # the second pass's own record, with the pass-1 terms but no shared part yet: for the record
    doc["in_sample_rms_z"]["real Moon 0.015 ms, pass 2, own sigma only"] = [
        float(np.sqrt(np.mean((t["error"] / total_sigma(t)) ** 2))) for t in terrain2]
    print(json.dumps({k: doc[k] for k in ("edge_model_error_px", "saturated_model_error_px",
                                          "terrain_scale", "moments")}, indent=1))
    if not args.dry_run:
        _use(doc, OUT)
        print("wrote", OUT)


def phase_scales(dry_run: bool) -> None:
    """The second pass on the real-Moon arcs with the packaged terms: the factors per bin of
    phase on its pooled fix covariances."""
    from starnav.batch.consistency import fix_phase_scales, limb_point_records
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict
    from starnav.navigation.refine import ModelErrorCalibration

    doc = json.loads(OUT.read_text())
    doc.pop("fix_scale_by_phase", None)
    doc.pop("fix_scale_saturated_by_phase", None)
    _use(doc, OUT)     # the pooled covariance alone while the fixes are made
    cal = ModelErrorCalibration.from_dict(doc)
    fixes = []
    for arc in ARCS:
        cfg = scenario_to_dict(scenario_from_dict(demo_scenario(), [*arc, *COMMON]))
        rec = limb_point_records(cfg, RUNS, (WELL_EXPOSED, SATURATED))
        fixes += [rec[WELL_EXPOSED[0]]["fixes"], rec[SATURATED[0]]["fixes"]]
        print("arc", arc, "done", flush=True)
    tab = _merge(fixes)
    sat = tab["saturated"].astype(bool)
    edges = np.asarray(cal.phase_edges_deg)
    b = np.clip(np.searchsorted(edges, np.degrees(tab["phase"]), "right") - 1, 0,
                edges.size - 2)
    doc["fix_scale_by_phase"] = fix_phase_scales(tab, np.asarray(cal.fix_covariance), False,
                                                 tuple(edges))
    doc["fix_scale_saturated_by_phase"] = fix_phase_scales(
        tab, np.asarray(cal.fix_covariance_saturated), True, tuple(edges))
    doc["fix_scale_fixes_per_bin"] = {
        "well_exposed": [int(((b == k) & ~sat).sum()) for k in range(edges.size - 1)],
        "saturated": [int(((b == k) & sat).sum()) for k in range(edges.size - 1)]}
    doc["fix_scale_written"] = _dt.date.today().isoformat()
    print(json.dumps({k: doc[k] for k in ("fix_scale_by_phase", "fix_scale_saturated_by_phase",
                                          "fix_scale_fixes_per_bin")}), flush=True)
    if not dry_run:
        _use(doc, OUT)
        print("wrote", OUT)


def blooming(dry_run: bool) -> None:
    """The blooming regime's terms (module docstring, ``--blooming``)."""
    from starnav.batch.consistency import (
        fix_phase_scales,
        limb_point_records,
        render_arc,
        saturated_extra_by_phase,
        scaled_to_nees,
        shared_covariance_mle,
    )
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict
    from starnav.dem.limb import limb_topography_for
    from starnav.navigation.refine import ModelErrorCalibration

    doc = json.loads(OUT.read_text())
    before = json.dumps(doc, indent=1) + "\n"
    doc.pop("blooming", None)
    nb = len(BLOOMING_EDGES) - 1
    section = {"min_exposure_s": math.sqrt(SATURATED[0] * BLOOMING[0]),
               "exposure_s": BLOOMING[0], "phase_edges_deg": list(BLOOMING_EDGES),
               "saturated_model_error_px": [0.0] * nb,
               "fix_covariance_saturated": [[0.0] * 3] * 3}
    base = demo_scenario()
    sc = scenario_from_dict(base)
    topo = limb_topography_for(sc.moon.dem)
    win = sc.navigation.refine.window_size_px
    configs = [scenario_to_dict(scenario_from_dict(base, [*arc, *COMMON])) for arc in ARCS]
    renders = [render_arc(c) for c in configs]
    print("rendered", sum(len(r) for r in renders), "frames", flush=True)
    try:
        # pass 1: a saturated window's own extra
        _use({**doc, "blooming": section}, OUT)
        cal = ModelErrorCalibration.from_dict({**doc, "blooming": section}).blooming
        recs = [limb_point_records(c, RUNS, (SATURATED, BLOOMING), r)
                for c, r in zip(configs, renders, strict=True)]
        for t, what in ((SATURATED[0], "saturated terms, over-exposed windows dropped"),
                        (BLOOMING[0], "blooming, every window kept")):
            p = _merge([rec[t]["points"] for rec in recs])
            sat = p["saturated"].astype(bool)
            n_fix = sum(rec[t]["fixes"]["error"].shape[0] for rec in recs)
            n_all = sum(rec[t]["fix_nees"].size for rec in recs)
            print(f"{t * 1e3:g} ms ({what}): saturated points {p['error'][sat].mean():+.3f} "
                  f"px outside the limb (std {p['error'][sat].std():.3f} px), median fitted "
                  f"over-exposure {np.median(p['overexposure'][sat]):.1f}; {n_fix} of {n_all} "
                  "fixes from refined points", flush=True)
        points = _merge([rec[BLOOMING[0]]["points"] for rec in recs])
        section["saturated_model_error_px"] = saturated_extra_by_phase(
            points, cal, topo, win, BLOOMING_EDGES)
        print("pass 1:", section["saturated_model_error_px"], flush=True)
        # pass 2: the fixes' slowly varying error
        _use({**doc, "blooming": section}, OUT)
        tab = _merge([limb_point_records(c, RUNS, (BLOOMING,), r)[BLOOMING[0]]["fixes"]
                      for c, r in zip(configs, renders, strict=True)])
    finally:
        OUT.write_text(before)
    sat = tab["saturated"].astype(bool)
    C = scaled_to_nees(shared_covariance_mle(tab, sat), tab, sat)
    section["fix_covariance_saturated"] = C.tolist()
    section["fix_scale_saturated_by_phase"] = fix_phase_scales(tab, C, True, BLOOMING_EDGES)
    edges = np.asarray(BLOOMING_EDGES)
    b = np.clip(np.searchsorted(edges, np.degrees(tab["phase"]), "right") - 1, 0, nb - 1)
    section["fixes_per_bin"] = [int(((b == k) & sat).sum()) for k in range(nb)]
    section["calibration_arcs"] = [a + COMMON for a in ARCS]
    section["runs"] = RUNS
    section["detector"] = list(BLOOMING[1])
    section["written"] = _dt.date.today().isoformat()
    sd = np.sqrt(np.diag(C))
    section["sigma_km_equivalent"] = (sd * 1737.4).tolist()
    print(json.dumps(section), flush=True)
    if not dry_run:
        _use({**doc, "blooming": section}, OUT)
        print("wrote", OUT)


if __name__ == "__main__":
    main()
