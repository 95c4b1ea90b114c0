"""Issue 17, "tests must show": lost-in-space identification over random pointings of the whole
sky, each frame rendered at 200 ms through the full detector chain with the default noise and
solved without a prior (:mod:`starnav.stars.survey`); with the Moon in the field, the false-star
rate. Measured numbers: docs/stars.md, "Identification over the sky"."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.stars.survey import MOON_LE, identification_survey, random_pointing


def _report(res) -> dict:
    s = res.summary()
    print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()})
    for p in res.pointings:
        if p.outcome != "correct":
            print(p.index, p.outcome, p.reason, p.stars_in_frame, p.candidates)
    return s


def test_random_pointings_are_uniform_on_the_sphere_with_a_uniform_roll():
    """2000 pointings: the boresight's z component and azimuth are uniform (mean of z within
    4 standard errors of 0, sqrt(1/3 / n) = 0.013; the fraction with z > 0.5 within 4 sigma of
    1/4) and the matrices are rotations."""
    rng = np.random.default_rng(1)
    Rs = np.array([random_pointing(rng) for _ in range(2000)])
    z = Rs[:, 2, 2]
    assert abs(z.mean()) < 4 * math.sqrt(1 / 3 / z.size)
    assert abs(np.mean(z > 0.5) - 0.25) < 4 * math.sqrt(0.25 * 0.75 / z.size)
    assert np.allclose(np.einsum("nij,nkj->nik", Rs, Rs), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(Rs), 1.0)


@pytest.mark.parametrize("n_pointings", [25, pytest.param(300, marks=pytest.mark.slow)])
def test_lost_in_space_solves_rendered_random_pointings(n_pointings):
    """Issue 17: random pointings over the sky (uniform boresight, uniform roll; seeded),
    each RENDERED at 200 ms (Hipparcos to V 6.5, field-varying PSF, shot, dark, read and ADC
    noise: the default detector) and solved lost in space from the DN frame: at least 99 % solved
    correctly (error rotation < 30 arcsec) and none wrongly; a matched catalogue star that was
    not drawn (the fainter component of a close pair) at most once per 1000 matches.

    A seeded regression of a statistical claim: the default run (25 pointings) must solve all
    25; the slow run (300) at least 297. With the survey's measured success rate (1000 of 1000,
    docs/stars.md: the rate is above 99.7 % at 95 % confidence) the chance of 4 failures in
    300 is below 3 %; a wrong solution needs about 10 chance confirmations against a Poisson
    mean of ~0.5 (the identification's count rule: < 1e-9 per frame)."""
    res = identification_survey(n_pointings, np.random.default_rng(17))
    s = _report(res)
    assert s["wrong"] == 0
    assert s["correct"] >= math.ceil(0.99 * n_pointings), s["unsolved_reasons"]
    assert s["foreign_matched"] <= max(1, 1e-3 * s["matched_total"])
    assert s["error_cross_rms_arcsec"] < 3.0


@pytest.mark.parametrize("n_pointings", [12, pytest.param(100, marks=pytest.mark.slow)])
def test_moon_in_the_field_false_stars_are_never_matched(n_pointings):
    """A saturated lunar disc (the real Moon's electron radiance, ~1e4 x the full well at
    200 ms: its blooming, stray-light halo and ghost from the chain) at a random place in each
    frame, at a random range (54-122 px radius), the stars behind it occulted; the solver gets
    the disc's and its ghost's exclusions as the tracker does. The false-star rate (candidates
    farther than 2 px from every drawn star) is reported; no false candidate is ever matched,
    no solution is wrong, and at least 99 % of the pointings are solved correctly (seeded; the
    default run must solve all 12)."""
    assert MOON_LE > 1e18  # the real Moon's radiance, not a faint stand-in
    res = identification_survey(n_pointings, np.random.default_rng(18), moon=True,
                                first_seed=1000)
    s = _report(res)
    assert s["false_matched"] == 0
    assert s["wrong"] == 0
    assert s["correct"] >= math.ceil(0.99 * n_pointings), s["unsolved_reasons"]
    assert s["rejected_per_frame"]["saturated"] + s["rejected_per_frame"]["extended"] > 1.0


@pytest.mark.slow
def test_moon_without_exclusions_is_still_never_matched():
    """Stress: the same Moon frames without the exclusion discs (the centroiding's saturation,
    hot-pixel and extent rejections and the identification's verification alone): no false
    candidate matched, no wrong attitude (40 pointings, seeded; over 200 pointings,
    benchmarks/stars.py --survey, one false candidate was matched into a correct attitude:
    docs/stars.md)."""
    res = identification_survey(40, np.random.default_rng(18), moon=True, first_seed=1000,
                                exclude_body=False)
    s = _report(res)
    assert s["false_matched"] == 0 and s["wrong"] == 0
