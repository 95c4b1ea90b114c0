"""The released navigation defaults are scored once, on a scoring set apart from every tuning
set, and the record says what was scored (src/starnav/data/navigation/scores.json, written by
tools/score_navigation.py; the protocol: docs/navigation.md, "Tuning apart from scoring")."""

from __future__ import annotations

import json

import pytest
from scipy.stats import binom

from starnav.batch.scores import (
    EXPOSURES,
    TARGETS,
    defaults_fingerprint,
    recorded_scores,
)
from starnav.data import packaged_path
from starnav.scenes.ephemeris import parse_epoch

#: Two-sided false-alarm rate of the binomial test on the epochs inside their 95 % band.
ALPHA = 0.01


def _arcs(rel: str) -> list[list[str]]:
    return json.loads(packaged_path(rel).read_text())["calibration_arcs"]


def _key(arc: list[str], name: str) -> str:
    return next(a.split("=", 1)[1] for a in arc if a.startswith(name + "="))


def test_record_scores_the_defaults_as_released():
    """A default changed after its score must be scored again (on a new scoring set):
    tools/score_navigation.py."""
    assert recorded_scores()["defaults_fingerprint"] == defaults_fingerprint(), (
        "the navigation defaults changed after they were scored: run tools/score_navigation.py "
        "on a new scoring set")


def test_scoring_set_is_apart_from_every_tuning_set():
    """No scoring arc shares a seed, a halo phase or a day with an arc that tuned a default,
    nor a seed or an epoch with a scoring set already spent on an earlier default."""
    rec = recorded_scores()
    tuning = _arcs("navigation/refine_model_error.json") + _arcs("navigation/bias_tuning.json")
    spans = []
    for a in tuning:
        t0 = parse_epoch(_key(a, "trajectory.epoch"), "epoch")
        spans.append((t0, t0 + 86400.0 * float(_key(a, "trajectory.duration_days"))))
    psf_seed = json.loads(packaged_path("navigation/psf_estimate.json").read_text())["seed"]
    bench_seeds = {b["seed"] for b in json.loads(packaged_path(
        "navigation/camera_bench.json").read_text())["benches"]}
    spent = [a for s in rec.get("spent_scoring_sets", []) for a in s]
    assert spent, "the record lists the scoring sets already spent"
    for arc in rec["scoring_arcs"]:
        full = arc + rec["arc"]
        assert _key(full, "seed") not in {_key(a, "seed") for a in tuning + spent}
        assert int(_key(full, "seed")) not in range(psf_seed, psf_seed + 16)
        assert int(_key(full, "seed")) not in bench_seeds
        assert _key(full, "trajectory.epoch") not in {_key(a, "trajectory.epoch") for a in spent}
        assert _key(full, "trajectory.halo_phase_deg") not in {
            _key(a, "trajectory.halo_phase_deg") for a in tuning}
        t0 = parse_epoch(_key(full, "trajectory.epoch"), "epoch")
        t1 = t0 + 86400.0 * float(_key(full, "trajectory.duration_days"))
        assert all(t1 < s0 - 86400.0 or t0 > s1 + 86400.0 for s0, s1 in spans)


#: Exposures whose released defaults miss their targets on the scoring set (the record;
#: docs/navigation.md, "Tuning apart from scoring"): strict xfails until scored again.
MISSED = {7.7e-3: "7.7 ms: 21 of 26 epochs in band (the gibbous arc 13 of 13; the 127-130 deg "
                  "arc 8 of 13, the others just below, ANEES 4.82, no epoch above): the "
                  "blooming fix's covariance is on the generous side towards the crescent"}


@pytest.mark.parametrize("exposure", [
    pytest.param(e, marks=pytest.mark.xfail(strict=True, reason=MISSED[e])) if e in MISSED
    else e for e in EXPOSURES])
def test_released_defaults_meet_their_targets_on_the_scoring_set(exposure):
    """Per exposure, pooled over the scoring arcs: the epochs inside their 95 % band are as
    many as a consistent filter gives (binomial, two-sided 1 %, and at least the target's
    90 %), no arc is overconfident, and at 0.015 ms the final position error is under 0.5 % of
    range (the paper's HIL figure)."""
    rows = recorded_scores()["scores"]
    assert {r["exposure_s"] for r in rows} == set(EXPOSURES)
    mine = [r for r in rows if r["exposure_s"] == exposure]
    n = sum(r["epochs"] for r in mine)
    k = round(sum(r["epochs_in_band"] * r["epochs"] for r in mine))
    assert k >= TARGETS["epochs_in_band"][0] * n, (exposure, k, n)
    # P(X <= k) and P(X >= k) of binomial(n, 0.95) both above ALPHA / 2
    assert binom.cdf(k, n, 0.95) > ALPHA / 2 and binom.sf(k - 1, n, 0.95) > ALPHA / 2, \
        (exposure, k, n)
    assert all(r["verdict"] != "overconfident" for r in mine), mine
    if exposure == 1.5e-5:
        assert all(r["final_position_error_pct_range"]
                   < TARGETS["final_position_error_pct_range_0.015ms"] for r in mine)
