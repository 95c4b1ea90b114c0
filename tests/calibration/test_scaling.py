"""Albedo-exposure scaling: the choice of k (the paper's 13 333), KS equivalence of scaled
acquisitions with a control sample that breaks the product, and the end-to-end case."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.calibration.bench import Bench
from starnav.calibration.geometric import TrueMapping
from starnav.calibration.scaling import (
    albedo_exposure_experiment,
    bench_min_exposure,
    end_to_end,
    plan_scaling,
)
from starnav.calibration.schema import bench_from_dict
from starnav.errors import ConfigError

from .conftest import ALPHA, MOON_PLACEMENT_GOAL_PX, RADIOMETRIC_GOAL


def test_papers_case_gives_k_13333_and_a_peak_near_count_13(paper_bench):
    peak = 2.72e19   # rendered Lambert Moon, rho 0.12, phase 30 deg [e- s^-1 m^-2 sr^-1]
    t_min = bench_min_exposure(paper_bench)             # full frame, paper eq. 1
    assert t_min == pytest.approx(0.2)
    p = plan_scaling(peak, 1.5e-5, paper_bench.radiometry, bench_min_exposure_s=t_min)
    assert p.k == pytest.approx(0.2 / 1.5e-5, rel=1e-12)   # 13 333.3
    assert p.albedo_factor == pytest.approx(7.5e-5)
    assert p.bench_exposure_s == pytest.approx(0.2)
    # the paper set its maximum count to 13 for full frames; the representative screen gives
    # about the same (a regression on the modelling choice, not a measurement)
    assert 10 <= p.peak_count <= 16
    assert p.k_screen == pytest.approx(peak / (0.9 * paper_bench.radiometry.le_max))
    assert any("too dim" in n for n in p.notes)


def test_windows_readout_and_imposed_exposures(paper_bench):
    # eq. 1: 8 ms + 0.17 ms per 1000 px
    assert bench_min_exposure(paper_bench, "windows", 10_000) == pytest.approx(9.7e-3)
    rad = paper_bench.radiometry
    p = plan_scaling(2.72e19, 1.5e-5, rad, bench_exposure_s=0.05)
    assert p.k == pytest.approx(0.05 / 1.5e-5)
    with pytest.raises(ConfigError) as err:
        plan_scaling(2.72e19, 1.5e-5, rad, bench_exposure_s=1e-4)   # k = 6.7 < 21
    assert "scaling.bench_exposure_ms" in str(err.value)


def test_ks_cannot_tell_scaled_acquisitions_apart_and_detects_the_control(small_render):
    # alpha = 0.01 per test (false-alarm rate <= 1 % each, conservative: see the slow test)
    cam, img, _ = small_render
    bench = Bench(bench_from_dict({}), camera=cam)
    exp = albedo_exposure_experiment(bench, img, 1.5e-5, TrueMapping(bench.geometry))
    assert exp.alpha == ALPHA
    assert [round(c.k / exp.k_screen) for c in exp.cases] == [1, 2, 4]
    assert all(c.product_ratio == 1.0 for c in exp.cases)
    for c in exp.cases[1:]:
        assert c.p_value > ALPHA, c
    assert exp.control.product_ratio == 1.25
    assert exp.control.p_value < 1e-6
    assert exp.scaled_equivalent and exp.control_detected


def test_end_to_end_15us_render_vs_k_13333_acquisition(calibration_result, misaligned_bench,
                                                       full_render):
    # geometric calibration (fitted) + radiometric calibration + albedo-exposure scaling
    _, img, _ = full_render
    e2e = end_to_end(misaligned_bench, img, calibration_result.calibration)
    assert e2e.plan.k == pytest.approx(13333.33, rel=1e-6)
    m = e2e.comparison.metrics()
    assert m["saturated_pixels_orbit"] == 0 and m["saturated_pixels_bench"] == 0
    assert m["peak_count"] <= 16
    assert abs(m["disc_ratio"] - 1.0) < RADIOMETRIC_GOAL
    assert m["centroid_offset_px"] < MOON_PLACEMENT_GOAL_PX
    # unlike the scaled cases (all on the bench), orbit and bench differ by the collimator
    # spot, which widens the limb: a KS test on ~23 000 pixels may see it (p was 0.05-0.4 in
    # our runs), so the test bounds the effect size, not the p-value
    assert e2e.ks_statistic < 0.03


@pytest.mark.slow
def test_renderer_is_linear_in_albedo_so_le_over_k_is_the_scaled_render(render_fn):
    from .conftest import small_camera

    cam = small_camera()
    a, _ = render_fn(cam, 1.3e8, 1.0, seed=3)
    b, _ = render_fn(cam, 1.3e8, 1.0 / 13333.0, seed=3)
    np.testing.assert_allclose(b.Le * 13333.0, a.Le, rtol=1e-5, atol=1e-6 * float(a.Le.max()))


@pytest.mark.slow
def test_ks_false_alarm_rate_and_power_over_seeds(small_render):
    # 20 benches (seeds) x 2 scaled comparisons at alpha = 0.05: under the null the number of
    # rejections is <= Binomial(40, 0.05) (the test is conservative); P(X >= 7) = 0.9 %, so
    # this test's own false-alarm rate is < 1 %. The control must be detected every time.
    cam, img, _ = small_render
    rejections = 0
    for seed in range(20):
        bench = Bench(bench_from_dict({"seed": seed, "scaling": {"ks_alpha": 0.05}}), camera=cam)
        exp = albedo_exposure_experiment(bench, img, 1.5e-5, TrueMapping(bench.geometry))
        rejections += sum(not c.equivalent for c in exp.cases[1:])
        assert exp.control_detected
    assert rejections <= 6
