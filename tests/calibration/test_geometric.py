"""Geometric calibration: polynomials, centroids, matching, recovery of an injected
misalignment + distortion to < 5 arcsec on dots not used in the fit, and a displayed Moon that
lands within 0.5 px."""

from __future__ import annotations

import json

import numpy as np
import pytest

from starnav.calibration.bench import Bench, IdealDetector
from starnav.calibration.geometric import (
    CalibrationError,
    GeometricCalibration,
    NominalMapping,
    Polynomial2D,
    TrueMapping,
    angular_residual_arcsec,
    calibrate_geometry,
    detect_dots,
    exponents,
    match_points,
    pixel_to_tangent,
)
from starnav.calibration.radiometric import compare_stimulus
from starnav.calibration.schema import bench_from_dict
from starnav.camera import Camera
from starnav.errors import ConfigError

from .conftest import (
    GEOMETRIC_RMS_GOAL_ARCSEC,
    MISALIGNMENT,
    MOON_PLACEMENT_GOAL_PX,
    lambert_disc_le,
)


def test_polynomial_fit_recovers_an_exact_polynomial_and_round_trips():
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.2, 0.2, size=(60, 2))
    y = np.stack([0.01 + 1.02 * x[:, 0] - 0.3 * x[:, 0] * x[:, 1] ** 2,
                  -0.02 + 0.99 * x[:, 1] + 0.5 * x[:, 0] ** 3], -1)
    p = Polynomial2D.fit(x, y, 3)
    xt = rng.uniform(-0.2, 0.2, size=(20, 2))
    yt = np.stack([0.01 + 1.02 * xt[:, 0] - 0.3 * xt[:, 0] * xt[:, 1] ** 2,
                   -0.02 + 0.99 * xt[:, 1] + 0.5 * xt[:, 0] ** 3], -1)
    np.testing.assert_allclose(p(xt), yt, atol=1e-13)
    q = Polynomial2D.from_dict(json.loads(json.dumps(p.to_dict())))
    np.testing.assert_array_equal(q(xt), p(xt))
    assert len(exponents(4)) == 15
    with pytest.raises(CalibrationError, match="coefficients"):
        Polynomial2D.fit(x[:5], y[:5], 3)


def test_centroids_of_noisy_gaussian_spots_are_within_their_noise_bound():
    # Gaussian spots sigma 1.5 px, flux 2e5, read noise 30: centroid sigma ~
    # sqrt(sum x^2) noise / flux ~ 0.005 px; 0.03 px is a 6-sigma bound (false alarm < 1e-8)
    rng = np.random.default_rng(2)
    truth = np.array([[20.3, 30.7], [60.55, 20.2], [45.9, 70.05]])
    v, u = np.indices((100, 100), dtype=float)
    img = np.zeros((100, 100))
    for cu, cv in truth:
        img += 2e5 / (2 * np.pi * 1.5**2) * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * 1.5**2))
    img += rng.normal(0, 30.0, img.shape)
    c, flux = detect_dots(img, 300.0, 7)
    order = np.argsort(c[:, 0])
    np.testing.assert_allclose(c[order], truth[np.argsort(truth[:, 0])], atol=0.03)
    assert np.all(np.abs(flux / 2e5 - 1) < 0.02)


def test_matching_finds_a_large_shift_of_a_finite_grid():
    g = np.stack(np.meshgrid(np.arange(8) * 50.0, np.arange(6) * 50.0), -1).reshape(-1, 2)
    rng = np.random.default_rng(4)
    obs = g + np.array([63.0, -41.0]) + rng.normal(0, 0.3, g.shape)  # more than a grid step
    drop = rng.permutation(len(obs))[:5]
    obs = np.delete(obs, drop, axis=0)
    io, ip = match_points(obs, g, 50.0)
    assert len(io) == len(obs)
    np.testing.assert_allclose(obs[io] - g[ip], [[63.0, -41.0]] * len(io), atol=1.5)


def test_injected_misalignment_and_distortion_are_recovered(calibration_result):
    res = calibration_result
    s = res.summary()
    # the emulated bench is far off before calibration (misalignments + collimator distortion)
    assert res.uncalibrated_rms_arcsec > 300.0
    assert s["dots_matched"] == s["dots_shown"]
    # dots not used in the fit: hold-out of the first fit, and the closed-loop validation dots
    assert len(res.holdout_residual_arcsec) >= 50
    assert res.holdout_rms_arcsec < GEOMETRIC_RMS_GOAL_ARCSEC
    assert s["validation_dots_matched"] >= 0.95 * len(res.validation_dots.desired_px)
    assert res.closed_loop_rms_arcsec < GEOMETRIC_RMS_GOAL_ARCSEC


def test_the_fitted_map_agrees_with_the_true_bench(calibration_result, misaligned_bench):
    # independent of the centroids: compare the polynomial with the emulated truth in the
    # interior of the field (a fit cannot be checked against its own data only)
    cal = calibration_result.calibration
    true = TrueMapping(misaligned_bench.geometry)
    cam = misaligned_bench.camera
    rng = np.random.default_rng(8)
    uv = rng.uniform(60, 960, size=(400, 2))
    t = pixel_to_tangent(cam, uv)
    ji_fit = cal.screen_for_tangent(t)
    ji_true = true.screen_for_tangent(t)
    res = angular_residual_arcsec(true.tangent_for_screen(ji_fit), t)
    assert np.sqrt(np.mean(res**2)) < GEOMETRIC_RMS_GOAL_ARCSEC
    # the same in screen pixels (1 screen px = 34 arcsec here)
    assert np.max(np.abs(ji_fit - ji_true)) < 0.5


def test_an_affine_model_is_not_enough(calibration_result):
    # degree 1 on the same dots misses the distortion and keystone by far more than 5"
    d = calibration_result.calibration_dots
    ok = d.found
    cam = Camera.preset("aa-str")
    t_obs = pixel_to_tangent(cam, d.observed_px[ok])
    s_nom = calibration_result.calibration.geometry.screen_to_nominal_tangent(d.screen_px[ok])
    q1 = Polynomial2D.fit(s_nom, t_obs, 1)
    assert np.sqrt(np.mean(angular_residual_arcsec(q1(s_nom), t_obs) ** 2)) > 20.0


def test_calibration_file_round_trip(calibration_result, misaligned_bench):
    cal = calibration_result.calibration
    back = GeometricCalibration.from_dict(json.loads(cal.to_json()), misaligned_bench.camera)
    t = np.array([[0.01, -0.05], [-0.15, 0.12]])
    np.testing.assert_allclose(back.screen_for_tangent(t), cal.screen_for_tangent(t), rtol=0,
                               atol=1e-9)
    with pytest.raises(ConfigError, match="kind"):
        GeometricCalibration.from_dict({"kind": "other"}, misaligned_bench.camera)


def test_displayed_moon_lands_within_half_a_pixel(calibration_result, misaligned_bench):
    # an off-centre Lambert disc (analytic, 163 px), 0.015 ms in orbit, through the chain
    cam = misaligned_bench.camera
    le = lambert_disc_le(cam, (690.3, 395.7), 81.5, 2.7e19)
    cal = compare_stimulus(misaligned_bench, le, 1.5e-5, calibration_result.calibration,
                           frame_base=700)
    unc = compare_stimulus(misaligned_bench, le, 1.5e-5,
                           NominalMapping(misaligned_bench.geometry.nominal()), frame_base=710)
    assert cal.metrics()["centroid_offset_px"] < MOON_PLACEMENT_GOAL_PX
    assert unc.metrics()["centroid_offset_px"] > 5.0   # what the calibration removes


def test_too_few_dots_is_a_clear_error():
    cam = Camera.preset("aa-str", width=96, height=96)
    bench = Bench(bench_from_dict({"misalignment": MISALIGNMENT}), camera=cam)
    with pytest.raises(CalibrationError, match="polynomial_order"):
        calibrate_geometry(bench, IdealDetector(cam), validate=False)


@pytest.mark.slow
def test_camera_distortion_is_not_absorbed_by_the_bench_calibration():
    # a camera with its own Brown-Conrady distortion: desired and obtained lines of sight go
    # through the camera model, so the bench calibration still reaches the goal
    cam = Camera.preset("aa-str", k1=-0.2, p1=2e-4)
    bench = Bench(bench_from_dict({"misalignment": MISALIGNMENT}), camera=cam)
    res = calibrate_geometry(bench)
    assert res.holdout_rms_arcsec < GEOMETRIC_RMS_GOAL_ARCSEC
    assert res.closed_loop_rms_arcsec < GEOMETRIC_RMS_GOAL_ARCSEC


@pytest.mark.slow
def test_rendered_moon_lands_within_half_a_pixel(calibration_result, misaligned_bench,
                                                 full_render):
    _, img, geom = full_render
    comp = compare_stimulus(misaligned_bench, img, 1.5e-5, calibration_result.calibration,
                            frame_base=720)
    m = comp.metrics()
    assert m["centroid_offset_px"] < MOON_PLACEMENT_GOAL_PX
    assert m["saturated_pixels_orbit"] == 0 and m["saturated_pixels_bench"] == 0


def test_matching_a_rotated_distorted_grid_keeps_each_dot_its_own():
    """The dots of an as-built bench (screen and camera rolled by ~1 deg together, collimator
    distortion, shifts) land 2-27 px from where the nominal bench predicts them: each lattice
    peak of the offset vote is spread over a third of a spacing. The vote must count each peak
    whole, or it picks a neighbouring lattice offset and every dot is paired with its
    neighbour (a principal point off by whole grid spacings)."""
    from starnav.calibration.geometric import NominalMapping, dot_grid, fit_dot_grid
    from starnav.calibration.intrinsics import draw_as_built

    g = bench_from_dict({}).geometric
    bench = Bench(bench_from_dict({"misalignment": draw_as_built(np.random.default_rng(9500),
                                                                 g)}))
    cam = bench.camera
    grid = fit_dot_grid(cam, g.dot_grid, g.dot_margin_px, g.centroid_half_window_px)
    desired = dot_grid(cam, grid, g.dot_margin_px)
    screen = NominalMapping(bench.geometry.nominal()).screen_for_tangent(
        pixel_to_tangent(cam, desired))
    seen = bench.geometry.screen_to_pixel(screen)
    inside = np.all((seen > 10) & (seen < cam.width - 10), axis=1)
    spread = np.ptp(seen[inside] - desired[inside], axis=0)
    assert np.all(spread > 20.0)
    spacing = (cam.width - 2 * g.dot_margin_px) / (grid[0] - 1)
    io, ip = match_points(seen[inside], desired, spacing)
    assert len(io) == inside.sum()
    assert np.array_equal(np.nonzero(inside)[0][io], ip)


@pytest.mark.parametrize("dv", [25.0, -25.0])
def test_matching_a_grid_one_row_short_takes_the_offset_nearest_the_prediction(dv):
    """An offset of 0.4 spacing pushes the last (first) row of dots off the detector:
    the grid seen is one row short, and the lattice offset one spacing the other way pairs as
    many dots as the true one. The vote must resolve the tie by the nominal prediction (the
    smaller offset), whichever its sign, not by the histogram's array order (which took the
    most negative offset and paired every dot with its neighbour)."""
    spacing = 61.0
    g = np.stack(np.meshgrid(24.0 + spacing * np.arange(17), 24.0 + spacing * np.arange(17)),
                 -1).reshape(-1, 2)
    rng = np.random.default_rng(5)
    seen = g + np.array([9.0, dv]) + rng.normal(0, 0.5, g.shape)
    inside = (seen[:, 1] > 7.5) & (seen[:, 1] < 1015.5)
    assert inside.sum() == 16 * 17
    io, ip = match_points(seen[inside], g, spacing)
    assert len(io) == inside.sum()
    assert np.array_equal(np.nonzero(inside)[0][io], ip)
