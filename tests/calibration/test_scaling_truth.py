"""The albedo-exposure equivalence experiment on the truth bench: each case's counts chosen with
the lab's radiometric calibration (against the reference instrument) and shown on the truth
screen, so the cases sit at different counts where the truth departs from the LUT.

Seeds (written down before any run): development 6200-6219; scoring 7500-7539 (the default run
uses 7500-7507). The truth and the instrument are drawn from ``generator(seed, 6, 7)`` and
``generator(seed, 6, 8)`` as in test_moon_stimulus.py, the dither from ``generator(seed, 6,
10)``.

The k range reaches the seed paper's: multiples 1, 16, 128 and 640 of the screen-limited k
(about 21) put the last case at k ~ 13 300, peak count ~ 13, where the screen's steps and its
black pedestal matter. The Moon is the analytic Lambert disc of conftest at the seed paper's
albedo 0.12 (no renderer).
"""

from __future__ import annotations

import pytest
from scipy import stats

from starnav.calibration.bench import Bench, IdealDetector
from starnav.calibration.geometric import TrueMapping
from starnav.calibration.radiometric_lab import calibrate_radiometry
from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen
from starnav.calibration.scaling import RATIO_TERMS, albedo_exposure_experiment, end_to_end
from starnav.calibration.schema import bench_from_dict
from starnav.seeding import generator

from .conftest import small_camera
from .test_moon_stimulus import _moon

T_RENDER = 1.5e-5
#: Multiples of the screen-limited k, up to the seed paper's k = 13 333.
MULTIPLES = [1, 16, 128, 640]
SCORING_SEEDS = 7500
#: Probability that a correct budget's Bonferroni check fails (the experiment's family rate).
FAMILY_ALPHA = 0.01


def _bench(truth: dict | None = None) -> Bench:
    return Bench(bench_from_dict({"scaling": {"ks_k_multiples": MULTIPLES},
                                  "radiometric_truth": truth or {}}), camera=small_camera(128))


def _lab(bench: Bench, seed: int, cache: dict | None = None):
    tr = TruthScreen(bench, generator(seed, 6, 7), cache)
    inst = ReferenceInstrument(bench, tr, generator(seed, 6, 8))
    return tr, inst, calibrate_radiometry(bench, tr, inst)


def _experiment(bench: Bench, img, seed: int, lab=None, detector=None):
    det = detector if detector is not None else IdealDetector(bench.camera)
    kw = {} if lab is None else {"truth": lab[0], "instrument": lab[1], "calibration": lab[2]}
    return albedo_exposure_experiment(bench, img, T_RENDER, TrueMapping(bench.geometry), det,
                                      generator(seed, 6, 10), **kw)


def test_on_the_truth_bench_equivalent_cases_are_within_their_budget_and_the_control_is_not():
    """Over 8 seeded truth benches (noise-free detector: the error is the bench's): the scaled
    cases' disc DN over the first case's is within the Bonferroni bound of its budget on all
    but as many benches as a correct budget allows (binomial, false-alarm rate <= 1 %), and
    is not exactly 1 (the truth is not the LUT: the nominal bench's identity does not hold);
    the control (product x 1.25) is off by 0.25, far outside, and once divided by 1.25 it is
    within its budget (it fails by what the broken product predicts); the KS test rejects the
    control (alpha 0.01) with a statistic several times the largest scaled case's. (The KS test
    may also reject a scaled case here: noise-free, a ~1 % shift from the LUT's error between
    counts is visible on ~4000 pixels; the ratio and its budget are the equivalence's test.)"""
    bench = _bench()
    img = _moon(bench.camera)
    cache: dict = {}
    failed = 0
    departures = []
    for seed in range(SCORING_SEEDS, SCORING_SEEDS + 8):
        exp = _experiment(bench, img, seed, _lab(bench, seed, cache))
        assert exp.truth_bench
        assert [c.peak_count for c in exp.cases][-1] <= 16
        failed += not exp.ratios_consistent
        departures += [abs(c.ratio_error) for c in exp.cases[1:]]
        ctrl = exp.control
        assert abs(ctrl.ratio_error) > 5 * exp.z_crit * ctrl.ratio_sigma
        assert not exp.ratio_within_budget(ctrl)
        assert abs(ctrl.disc_ratio / ctrl.product_ratio - 1.0) <= exp.z_crit * ctrl.ratio_sigma
        assert exp.control_detected
        assert ctrl.statistic > 4 * max(c.statistic for c in exp.cases)
        for c in exp.cases[1:]:
            assert set(c.ratio_budget) == set(RATIO_TERMS) and c.ratio_sigma > 0
    assert failed <= stats.binom.ppf(0.99, 8, FAMILY_ALPHA)
    assert max(departures) > 1e-3


def test_the_truth_path_is_used():
    """The truth panel's gamma moving by +0.1 after the calibration (the LUT no longer fits)
    dims the low-count cases relative to the first (``(n / N)^0.1`` falls with n): the k ~ 13 300
    case's ratio drops by far more than its budget and the experiment is no longer consistent.
    The nominal path (no truth given; regression) keeps its LUT terms at zero: the table that
    chooses the counts displays them."""
    bench = _bench()
    img = _moon(bench.camera)
    seed = SCORING_SEEDS + 10
    lab = _lab(bench, seed)
    before = _experiment(bench, img, seed, lab)
    assert before.ratios_consistent
    lab[0].gamma = lab[0].gamma + 0.1
    after = _experiment(bench, img, seed, lab)
    last_b, last_a = before.cases[-1], after.cases[-1]
    assert last_a.disc_ratio < last_b.disc_ratio - 10 * last_b.ratio_sigma
    assert not after.ratios_consistent
    two = Bench(bench_from_dict({"scaling": {"ks_k_multiples": [1, 640]}}),
                camera=small_camera(128))
    nominal = _experiment(two, img, seed)
    assert not nominal.truth_bench
    lut = ("reference absolute", "reference repeatability", "reference spectral",
           "LUT interpolation")
    assert all(nominal.cases[-1].ratio_budget[t] == 0.0 for t in lut)
    assert abs(nominal.cases[-1].ratio_error) <= nominal.z_crit * nominal.cases[-1].ratio_sigma


def test_end_to_end_on_the_truth_bench():
    """The seed paper's end-to-end case (0.015 ms in orbit, 200 ms on the bench, k = 13 333)
    given the truth bench goes through the lab's calibration and the truth screen: consistent
    with its budget; the truth panel's gamma moving by +0.1 after the calibration dims the
    count-13 stimulus by ~(13 / 255)^0.1 - 1 = -26 % (closed form at the peak count), far
    outside it."""
    bench = _bench()
    img = _moon(bench.camera)
    seed = SCORING_SEEDS + 12
    lab = _lab(bench, seed)
    kw = {"truth": lab[0], "instrument": lab[1], "calibration": lab[2]}

    def run():
        return end_to_end(bench, img, TrueMapping(bench.geometry), IdealDetector(bench.camera),
                          render_exposure_s=T_RENDER, bench_exposure_s=0.2,
                          rng=generator(seed, 6, 11), **kw)

    e2e = run()
    assert e2e.plan.k == pytest.approx(0.2 / T_RENDER)
    d = e2e.to_dict()
    assert d["truth_bench"] and d["metrics"]["truth_bench"]
    assert e2e.truth is not None and e2e.truth.consistent
    assert d["metrics"]["sigma"]["disc_ratio"] > 0
    lab[0].gamma = lab[0].gamma + 0.1
    bad = run().truth
    assert bad is not None and not bad.consistent
    # every displayed pixel dims by (n / N)^0.1 at its count n <= the peak's: at least by the
    # peak's factor, and by little more (the disc's counts sit near the peak's but the limb)
    n, n_max = d["metrics"]["peak_count"], bench.config.screen.max_count
    predicted = (1.0 + e2e.truth.errors()["disc_ratio"]) * (n / n_max) ** 0.1 - 1.0
    assert predicted - 0.04 < bad.errors()["disc_ratio"] < predicted + 1e-3
