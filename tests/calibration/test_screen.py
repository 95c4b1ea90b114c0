"""Screen radiometry: counts <-> radiance at the camera, quantisation, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.calibration.schema import (
    BenchConfig,
    CollimatorConfig,
    ScreenConfig,
    bench_from_dict,
    representative_emittance,
)
from starnav.calibration.screen import ScreenRadiometry, gaussian_dots
from starnav.constants import PLANCK_H, SPEED_OF_LIGHT
from starnav.errors import ConfigError
from starnav.spectra import sensor_response


@pytest.fixture(scope="module")
def rad() -> ScreenRadiometry:
    b = BenchConfig()
    return ScreenRadiometry.from_config(b.screen, b.collimator, sensor_response())


def test_full_white_is_the_emittance_convolved_with_the_camera_response(rad):
    # independent quadrature on a 0.05 nm grid of L(lambda) T QE lambda / (h c)
    em = representative_emittance()
    wl = np.arange(380.0, 780.0, 0.05)
    white = sum(np.interp(wl, em.wavelengths_nm, ch) for ch in em.channels())
    edges = np.arange(425.0, 1026.0, 50.0)
    qe = np.array([.35, .43, .46, .45, .42, .37, .30, .23, .16, .09, .04, .02])
    tr = np.array([.41, .687, .915, .954, .967, .977, .979, .982, .984, .987, .989, .992])
    band = np.clip(np.searchsorted(edges, wl, side="right") - 1, 0, 11)
    resp = np.where((wl >= 425) & (wl <= 1025), qe[band] * tr[band], 0.0)
    le = np.trapezoid(white * resp * wl * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT), wl) * 0.96
    assert rad.le_max == pytest.approx(le, rel=2e-3)
    assert rad.throughput == 0.96


def test_gamma_curve_and_black_level():
    b = bench_from_dict({"screen": {"emittance": representative_emittance().model_dump()
                                    | {"gamma": [2.4, 2.4, 2.4], "black_level_fraction": 1e-3}}})
    r = ScreenRadiometry.from_config(b.screen, b.collimator, sensor_response())
    n = np.arange(256)
    expected = r.le_max * (1e-3 + (1 - 1e-3) * (n / 255.0) ** 2.4)
    np.testing.assert_allclose(r.le_lut, expected, rtol=1e-12)
    assert r.le_min == pytest.approx(1e-3 * r.le_max)


def test_nd_filter_divides_every_level():
    b = BenchConfig()
    r0 = ScreenRadiometry.from_config(b.screen, b.collimator, sensor_response())
    r2 = ScreenRadiometry.from_config(b.screen, CollimatorConfig(nd_optical_density=2.0),
                                      sensor_response())
    np.testing.assert_allclose(r2.le_lut, r0.le_lut / 100.0, rtol=1e-12)


@pytest.mark.parametrize("bad", [256, -1, 300])
def test_counts_above_max_or_negative_are_refused_with_field_and_range(rad, bad):
    c = np.zeros((4, 4), np.int32)
    c[2, 1] = bad
    with pytest.raises(ConfigError) as err:
        rad.electron_radiance(c)
    msg = str(err.value)
    assert "screen counts" in msg and str(bad) in msg and "[0, 255]" in msg


def test_non_integer_counts_are_refused(rad):
    with pytest.raises(ConfigError, match="integer counts"):
        rad.electron_radiance(np.array([1.5]))


def test_radiance_above_full_white_names_the_scaling_fix(rad):
    with pytest.raises(ConfigError) as err:
        rad.counts_for(np.array([0.0, 2.0 * rad.le_max]))
    assert "albedo-exposure factor k" in str(err.value)
    assert rad.counts_for(np.array([2.0 * rad.le_max]), clip=True)[0] == 255


def test_nearest_picks_the_closest_level_in_radiance(rad):
    x = np.linspace(0, rad.le_max, 5000)
    c = rad.counts_for(x, "nearest")
    err = np.abs(rad.le_lut[c] - x)
    others = np.abs(rad.le_lut[None, :] - x[:, None]).min(axis=1)
    np.testing.assert_allclose(err, others, rtol=0, atol=1e-6 * rad.le_max)


def test_dither_is_unbiased_in_radiance(rad):
    # count n or n+1 with P(n+1) = t: mean radiance = target; 4-sigma bound (false alarm 6e-5)
    rng = np.random.default_rng(11)
    n_draw = 200_000
    for target in (0.37 * rad.le_lut[3] + 0.63 * rad.le_lut[4], 0.5 * rad.le_max):
        c = rad.counts_for(np.full(n_draw, target), "dither", rng)
        lo = int(c.min())
        step = rad.le_lut[lo + 1] - rad.le_lut[lo]
        t = (target - rad.le_lut[lo]) / step
        sigma_mean = step * math.sqrt(t * (1 - t) / n_draw)
        assert abs(rad.le_lut[c].mean() - target) < 4 * sigma_mean


def test_dither_needs_a_generator(rad):
    with pytest.raises(ConfigError, match="Generator"):
        rad.counts_for(np.array([1.0]), "dither")
    with pytest.raises(ConfigError, match="quantization"):
        rad.counts_for(np.array([1.0]), "floyd")


def test_screen_without_emittance_data_is_a_clear_error():
    b = bench_from_dict({"screen": {"emittance": None}})
    with pytest.raises(ConfigError) as err:
        ScreenRadiometry.from_config(b.screen, b.collimator, sensor_response())
    assert "screen.emittance" in str(err.value) and "None" in str(err.value)


@pytest.mark.parametrize("emittance, needle", [
    ({"wavelengths_nm": [], "red_w_m2_sr_nm": [], "green_w_m2_sr_nm": [],
      "blue_w_m2_sr_nm": []}, "no emittance data"),
    ({"wavelengths_nm": [400, 500], "red_w_m2_sr_nm": [0, 0], "green_w_m2_sr_nm": [0, 0],
      "blue_w_m2_sr_nm": [0, 0]}, "emits nothing"),
    ({"wavelengths_nm": [400, 500, 600], "red_w_m2_sr_nm": [0, 1], "green_w_m2_sr_nm": [0, 1, 0],
      "blue_w_m2_sr_nm": [1, 0, 0]}, "expected 3"),
])
def test_broken_emittance_tables_are_refused_at_load(emittance, needle):
    with pytest.raises(ConfigError) as err:
        bench_from_dict({"screen": {"emittance": emittance}})
    assert "screen.emittance" in str(err.value) and needle in str(err.value)


def test_emittance_outside_the_camera_band_is_refused():
    s = ScreenConfig(emittance={"wavelengths_nm": [1100, 1200], "red_w_m2_sr_nm": [1, 1],
                                "green_w_m2_sr_nm": [1, 1], "blue_w_m2_sr_nm": [1, 1]})
    with pytest.raises(ConfigError, match="camera band"):
        ScreenRadiometry.from_config(s, CollimatorConfig(), sensor_response())


def test_gaussian_dot_radiance_centroid_is_the_subpixel_position(rad):
    centre = (40.3, 25.8)
    c = gaussian_dots((64, 96), [centre], 1.5, rad.le_max, rad)
    le = rad.le_lut[c]
    v, u = np.indices(le.shape)
    cu, cv = (le * u).sum() / le.sum(), (le * v).sum() / le.sum()
    # 8-bit quantisation of the wings moves it by < 0.01 screen px
    assert abs(cu - centre[0]) < 0.01 and abs(cv - centre[1]) < 0.01
