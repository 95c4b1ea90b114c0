"""The record of the released navigation defaults' scores on their scoring set.

``tools/score_navigation.py`` scores the defaults once, on arcs and seeds apart from every
tuning set (the protocol is in docs/navigation.md, "Tuning apart from scoring"), and writes
:data:`SCORES_FILE` with the fingerprint of the defaults it scored (:func:`defaults_fingerprint`).
A default changed after its score no longer matches the record: it is scored again, on a new
scoring set.

Index
-----
:func:`defaults_fingerprint`, :func:`recorded_scores`, :func:`scored_line`, :data:`EXPOSURES`,
:data:`TARGETS`.
"""

from __future__ import annotations

import hashlib
import json

from starnav.batch.presets import demo_scenario
from starnav.config import scenario_from_dict
from starnav.data import packaged_path

#: The record (written by ``tools/score_navigation.py``).
SCORES_FILE = "navigation/scores.json"
#: The exposures scored [s]: the limb segments' 0.015 ms and the exposure study's 7.7 ms.
EXPOSURES = (1.5e-5, 7.7e-3)
#: What a released default must show on its scoring set: the fraction of epochs whose
#: run-averaged NEES is inside its 95 % band, and the final position error at 0.015 ms in % of
#: range (the paper's HIL figure, 0.5 %).
TARGETS = {"epochs_in_band": (0.90, 0.99), "final_position_error_pct_range_0.015ms": 0.5}
#: Packaged files the scores depend on (the calibrations the navigation reads).
_CALIBRATIONS = ("navigation/refine_model_error.json", "navigation/bias_tuning.json",
                 "navigation/psf_estimate.json", "navigation/camera_bench.json")


def defaults_fingerprint() -> str:
    """A short SHA-256 of everything a score depends on: the demo scenario's navigation
    section (with its tuned bias states; the fly-by's ``trn`` part aside), its truth forces
    and spacecraft, and the packaged calibrations the navigation reads."""
    sc = scenario_from_dict(demo_scenario(), [])
    nav = sc.navigation.model_dump(mode="json")
    nav.pop("trn", None)  # the fly-by's settings: scored on their own
    doc = {"navigation": nav,
           "forces": sc.trajectory.forces.model_dump(mode="json"),
           "spacecraft": sc.spacecraft.model_dump(mode="json") if hasattr(sc, "spacecraft")
           else None,
           "calibrations": {k: hashlib.sha256(packaged_path(k).read_bytes()).hexdigest()
                            for k in _CALIBRATIONS}}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def recorded_scores() -> dict:
    """The record :data:`SCORES_FILE`."""
    return json.loads(packaged_path(SCORES_FILE).read_text())


def scored_line() -> str:
    """One sentence for reports: the released defaults' recorded score per exposure (epochs
    inside their 95 % band, pooled over the scoring arcs, each run on its own terrain)."""
    rec = recorded_scores()
    parts = []
    for t in EXPOSURES:
        rows = [r for r in rec["scores"] if r["exposure_s"] == t]
        n = sum(r["epochs"] for r in rows)
        k = round(sum(r["epochs_in_band"] * r["epochs"] for r in rows))
        parts.append(f"{t * 1e3:g} ms {k}/{n}")
    seeds = ", ".join(a.split("=", 1)[1] for arc in rec["scoring_arcs"] for a in arc
                      if a.startswith("seed="))
    return (f"Over terrain draws, on arcs that tuned nothing (seeds {seeds}, each run on its "
            f"own terrain), the released defaults have their epochs inside the 95 % band at "
            f"{', '.join(parts)} (`starnav/data/navigation/scores.json`; docs/navigation.md, "
            f"\"Tuning apart from scoring\").")
