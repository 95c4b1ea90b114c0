"""Optical-stimulator condition (seed paper eq. 2), bench coverage verdicts, the Table 2 spot
model and the vignetting overlap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.calibration.bench import Bench, check_bench
from starnav.calibration.collimator import (
    SpotModel,
    disc_overlap_fraction,
    implied_fov_deg,
    stimulator_condition,
)
from starnav.calibration.schema import CollimatorConfig, bench_from_dict
from starnav.errors import ConfigError

#: AA-STR derived full FoV: 2 atan(9.216 / 50.7) [deg] (docs/facts.md s1).
AA_STR_FOV_DEG = 2 * math.degrees(math.atan(9.216 / 50.7))


def test_eq2_with_the_papers_stated_fov_gives_the_papers_verdict():
    # seed paper: h_s = 65 mm, FoV_STR = 10 deg -> the 180 mm doublet is acceptable
    v = stimulator_condition(10.0, 65.0, 180.0)
    assert v.satisfied
    # closed form h / (2 tan 5 deg) = 371.48 mm
    assert v.max_focal_length_mm == pytest.approx(65.0 / (2 * math.tan(math.radians(5))), 1e-12)
    assert v.max_focal_length_mm == pytest.approx(371.48, abs=0.01)


def test_eq2_with_the_derived_fov_says_the_180mm_collimator_misses_by_07_percent():
    v = stimulator_condition(AA_STR_FOV_DEG, 65.0, 180.0)
    assert not v.satisfied
    assert v.max_focal_length_mm == pytest.approx(65.0 * 50.7 / (2 * 9.216), 1e-9)  # 178.79
    assert v.shortfall_mm == pytest.approx(2 * 180 * 9.216 / 50.7 - 65.0, 1e-9)  # 0.439 mm
    assert "does NOT fill" in v.sentence()
    # the paper's own bound f_coll <= 180.07 mm corresponds to a 20.46 deg FoV, not 10 deg
    assert implied_fov_deg(65.0, 180.07) == pytest.approx(20.46, abs=0.01)


def test_bench_check_reports_both_verdicts_and_the_unstimulated_rows(paper_bench):
    chk = check_bench(paper_bench)
    by_src = {c.fov_source: c for c in chk.conditions}
    assert by_src["stated by the paper, vs screen height"].satisfied
    assert not by_src["derived, vertical, vs screen height"].satisfied
    assert by_src["derived, horizontal, vs screen width"].satisfied
    assert not chk.fills_field
    # the screen is 0.44 mm short over 65.44 mm: ~3.3 rows at each edge on an ideal bench,
    # fewer with the k1 = +0.1 collimator distortion (it stretches the screen's field)
    assert 1 <= chk.unstimulated_rows["top"] <= 4
    assert 1 <= chk.unstimulated_rows["bottom"] <= 4
    assert chk.unstimulated_rows["left"] == chk.unstimulated_rows["right"] == 0
    assert 0.0 < 1.0 - chk.stimulated_fraction < 0.01
    assert chk.edge_margin_mm["top"] < 0 and chk.edge_margin_mm["left"] > 20
    assert "does NOT fill" in chk.verdict
    # a screen pixel is 30.1 um / 180 mm * 50.7 mm / 18 um = 0.471 camera px
    assert chk.screen_pixel_camera_px == pytest.approx(65 / 2160 / 180 * 50.7 / 0.018, 1e-9)


def test_a_long_collimator_is_reported_and_refused():
    bench = Bench(bench_from_dict({"collimator": {"focal_length_mm": 250.0,
                                                  "distortion_k1": 0.0}}))
    chk = check_bench(bench)
    assert not chk.fills_field
    # closed form: rows with |v - cy| <= fy * 32.5 / 250 see the screen
    H = bench.camera.height
    half = bench.camera.fy * 32.5 / 250.0
    expected = 1.0 - (2 * half) / H
    assert 1.0 - chk.stimulated_fraction == pytest.approx(expected, abs=2.0 / H)
    with pytest.raises(ConfigError) as err:
        chk.raise_if_unfit(250.0)
    msg = str(err.value)
    assert "collimator.focal_length_mm" in msg and "250" in msg and "178.8" in msg


def test_a_short_collimator_fills_the_field():
    bench = Bench(bench_from_dict({"collimator": {"focal_length_mm": 170.0}}))
    chk = check_bench(bench)
    assert chk.fills_field and chk.stimulated_fraction == 1.0
    assert all(c.satisfied for c in chk.conditions)
    chk.raise_if_unfit(170.0)  # no error


def test_quadratic_spot_model_reproduces_table_2():
    cfg = CollimatorConfig()
    spot = SpotModel.from_config(cfg)
    px = math.radians(73.2301 / 3600)
    table = np.array([0.49, 0.72, 1.49, 2.13])
    model = spot.rms_radius_at(np.radians([0.0, 3.67, 7.32, 9.61])) / px
    assert np.max(np.abs(model - table)) < 0.06  # r = 0.49 + 0.0178 theta_deg^2 fits to 0.05 px
    assert spot.sigma_at(0.1) == pytest.approx(spot.rms_radius_at(0.1) / math.sqrt(2))
    lin = SpotModel.from_config(CollimatorConfig(spot_model="linear"))
    np.testing.assert_allclose(lin.rms_radius_at(np.radians([0.0, 3.67, 7.32, 9.61])) / px,
                               table, rtol=1e-12)
    assert lin.rms_radius_at(math.radians(14.0)) == pytest.approx(2.13 * px)  # held beyond


def test_disc_overlap_matches_closed_forms():
    assert disc_overlap_fraction(2.0, 1.0, [0.0, 0.9])[0] == 1.0
    assert disc_overlap_fraction(1.0, 2.0, [0.0])[0] == pytest.approx(0.25)
    assert disc_overlap_fraction(1.0, 1.0, [2.5])[0] == 0.0
    # two unit discs at distance d: lens area 2 acos(d/2) - (d/2) sqrt(4 - d^2)
    d = 1.0
    lens = 2 * math.acos(d / 2) - d / 2 * math.sqrt(4 - d * d)
    assert disc_overlap_fraction(1.0, 1.0, [d])[0] == pytest.approx(lens / math.pi, 1e-12)
