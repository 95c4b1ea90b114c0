"""Signal chain to DN (photon transfer curve), readout modes (segments, windows), timing law,
and clear errors on bad input."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from pydantic import ValidationError

from starnav.config import scenario_from_dict
from starnav.detector import DetectorConfig, expose
from starnav.detector.readout import (
    adc,
    extract_segments,
    min_exposure,
    read_windows,
    readout_timing,
    thresholded,
)
from starnav.detector.schema import ReadoutTimingConfig, WindowSpec
from starnav.errors import ConfigError

from .conftest import quiet_config, small_camera

#: Photon-transfer-curve tolerances required by issue 5.
PTC_GAIN_RTOL = 0.02
PTC_READ_NOISE_RTOL = 0.05


def _ptc(cfg: DetectorConfig, n: int = 256, roi: int = 192) -> tuple[float, float]:
    """Gain [e-/DN] and read noise [e-] from the mean-variance line of flat-field pairs.

    For each level two frames of one sensor (same seed, frames 2k and 2k+1) are differenced:
    the fixed pattern (PRNU, DSNU) cancels and var(diff)/2 = S/g^2 + sigma_r^2/g^2 + 1/12
    (quantisation) [DN^2] with S the mean signal [e-].
    """
    cam = small_camera(n)
    t = 1e-3
    levels_e = np.geomspace(300.0, 8e4, 12)
    means, variances = [], []
    s = slice((n - roi) // 2, (n + roi) // 2)
    for k, level in enumerate(levels_e):
        le = np.full((n, n), level / (t * cam.etendue), np.float32)
        a = expose(le, cam, cfg, seed=99, frame_index=2 * k, exposure_time=t).dn[s, s]
        b = expose(le, cam, cfg, seed=99, frame_index=2 * k + 1, exposure_time=t).dn[s, s]
        a, b = a.astype(np.float64), b.astype(np.float64)
        means.append(0.5 * (a.mean() + b.mean()) - cfg.adc.offset_dn)
        variances.append((a - b).var() / 2.0)
    m, v = np.array(means), np.array(variances)
    sigma_v = v * math.sqrt(2.0 / roi**2)           # std of a sample variance
    slope, intercept = np.polyfit(m, v, 1, w=1.0 / sigma_v)
    gain = 1.0 / slope
    read_noise = gain * math.sqrt(max(intercept - 1.0 / 12.0, 0.0))
    return gain, read_noise


def _ptc_config(**over) -> DetectorConfig:
    """AA-STR defaults with every effect on, except the non-linearity (a PTC is measured in the
    linear range) and IPC (it correlates neighbours' shot noise: see the next test)."""
    data = {"readout": {"timing": {"policy": "ignore"}},
            "signal": {"nonlinearity": {"enabled": False}, "ipc": {"enabled": False}}}
    data.update(over)
    return DetectorConfig.model_validate(data)


def test_photon_transfer_curve_gives_back_gain_and_read_noise():
    cfg = _ptc_config()
    gain, read_noise = _ptc(cfg)
    assert cfg.gain_e_per_dn == pytest.approx(100_000 / 4095)       # 24.42 e-/DN
    assert gain == pytest.approx(cfg.gain_e_per_dn, rel=PTC_GAIN_RTOL)
    assert read_noise == pytest.approx(100.0, rel=PTC_READ_NOISE_RTOL)


def test_ipc_biases_the_ptc_gain_by_the_kernel_power():
    """IPC smooths shot noise: variance x sum(k^2) (Moore et al. 2006), gain / sum(k^2)."""
    cfg = DetectorConfig.model_validate(
        {"readout": {"timing": {"policy": "ignore"}},
         "signal": {"nonlinearity": {"enabled": False}, "read_noise": {"enabled": False},
                    "ipc": {"nearest_fraction": 0.03, "diagonal_fraction": 0.005}}})
    k2 = (1 - 4 * 0.035) ** 2 + 4 * 0.03**2 + 4 * 0.005**2
    gain, _ = _ptc(cfg)
    assert gain == pytest.approx(cfg.gain_e_per_dn / k2, rel=PTC_GAIN_RTOL)


def test_adc_gain_offset_rounding_and_clipping():
    s = np.array([[-5000.0, 0.0, 24.42 * 10.4, 24.42 * 10.6, 1e6]], np.float32)
    dn = adc(s, 24.42, 100.0, 12)
    assert dn.dtype == np.uint16
    assert dn.tolist() == [[0, 100, 110, 111, 4095]]


def test_nonlinearity_full_well_deficit():
    from starnav.detector.readout import nonlinearity

    s = np.array([0.0, 5e4, 1e5], np.float32)
    out = nonlinearity(s, 1e5, 0.01)
    assert out[2] == pytest.approx(0.99e5, rel=1e-6)
    assert out[1] == pytest.approx(5e4 / (1 + 0.5 * 0.01 / 0.99), rel=1e-6)


# ---------------------------------------------------------------------------- segments
def _dn_frame(seed: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    dn = rng.integers(80, 130, (48, 70)).astype(np.uint16)
    v, u = np.mgrid[0:48, 0:70]
    disc = (u - 30) ** 2 + (v - 24) ** 2 < 18**2
    dn[disc] = rng.integers(150, 4095, int(disc.sum()))
    dn[5, 60:] = 4095        # a run touching the right edge
    dn[47, :3] = 300         # and the bottom-left corner
    return dn


def test_segments_round_trip_to_the_thresholded_frame_exactly():
    dn = _dn_frame()
    th = (200, 1000, 3000)
    seg = extract_segments(dn, th)
    assert not seg.truncated
    assert np.array_equal(seg.to_image(), thresholded(dn, 200))
    assert seg.n_pixels == int((dn >= 200).sum())
    edges = np.array(th + (65536,))
    for k in range(len(seg)):
        vals = seg.run_values(k).astype(int)
        lev = int(seg.level[k])
        assert np.all(vals >= edges[lev]) and np.all(vals < edges[lev + 1])
    # runs are maximal: two runs that touch in a row have different levels
    for k in range(1, len(seg)):
        if seg.row[k] == seg.row[k - 1] and \
                seg.col_start[k] == seg.col_start[k - 1] + seg.length[k - 1]:
            assert seg.level[k] != seg.level[k - 1]


def test_segments_limits_truncate_in_raster_order():
    dn = _dn_frame()
    full = extract_segments(dn, (200,))
    cut = extract_segments(dn, (200,), max_runs=10)
    assert cut.truncated and len(cut) == 10
    assert np.array_equal(cut.row, full.row[:10]) and np.array_equal(cut.length,
                                                                      full.length[:10])
    cap = int(full.length[:7].sum()) + 1
    cut = extract_segments(dn, (200,), max_pixels=cap)
    assert cut.truncated and len(cut) == 7 and cut.n_pixels <= cap
    rows_done = np.unique(cut.row)[:-1]
    assert np.array_equal(cut.to_image()[rows_done], thresholded(dn, 200)[rows_done])


def test_segments_through_expose_match_the_dn_frame(cam64):
    cfg = quiet_config(readout={"segments": {"thresholds_dn": [150, 900]}})
    v, u = np.mgrid[0:64, 0:64]
    le = np.where((u - 30) ** 2 + (v - 33) ** 2 < 15**2, 4e18, 0.0).astype(np.float32)
    frame = expose(le, cam64, cfg, exposure_time=1e-4)
    assert frame.segments is not None and len(frame.segments) > 0
    assert np.array_equal(frame.segments.to_image(), thresholded(frame.dn, 150))


# ---------------------------------------------------------------------------- windows
def test_windows_hold_exactly_the_dn_of_their_region():
    dn = _dn_frame()
    specs = [(0, 0, 5, 7), (40, 60, 8, 10), WindowSpec(row0=10, col0=20, height=1, width=1),
             {"row0": 3, "col0": 4, "height": 45, "width": 66}]
    wins = read_windows(dn, specs)
    for w in wins:
        assert np.array_equal(w.dn, dn[w.slices])
        assert w.dn.dtype == np.uint16
    assert wins[1].row0 == 40 and wins[1].col0 == 60 and wins[1].dn.shape == (8, 10)


def test_windows_through_expose(cam64):
    frame = expose(np.full((64, 64), 1e17, np.float32), cam64, DetectorConfig(),
                   seed=3, windows=[(10, 12, 8, 9), (50, 0, 14, 64)], exposure_time=1e-2)
    assert len(frame.windows) == 2
    for w in frame.windows:
        assert np.array_equal(w.dn, frame.dn[w.slices])


# ---------------------------------------------------------------------------- timing law
def test_readout_law_numbers():
    t = ReadoutTimingConfig()
    assert min_exposure(1024 * 1024, t) == pytest.approx((8 + 0.17 * 1048.576) * 1e-3)
    assert min_exposure(1024 * 1024, t, full_frame=True) == pytest.approx(0.2)
    w = [WindowSpec(row0=0, col0=0, height=32, width=32)] * 16
    r = readout_timing("windows", (1024, 1024), 0.010, t, w)
    assert r.n_pixels == 16384
    assert r.min_exposure == pytest.approx((8 + 0.17 * 16.384) * 1e-3)   # 10.785 ms
    assert not r.feasible
    assert readout_timing("segments", (1024, 1024), 0.2, t).feasible


def test_timing_policy_warn_flags_and_logs(cam64, caplog):
    with caplog.at_level(logging.WARNING, logger="starnav.detector.readout"):
        frame = expose(np.zeros((64, 64), np.float32), cam64, DetectorConfig(), seed=0)
    assert not frame.feasible
    assert frame.timing[0].mode == "segments"
    # segments scan the whole array: the paper's 200 ms full-frame floor applies
    assert "segments readout of 4096 px needs an exposure >= 200 ms" in caplog.text
    with caplog.at_level(logging.WARNING, logger="starnav.detector.readout"):
        frame = expose(np.zeros((64, 64), np.float32), cam64, DetectorConfig(), seed=0,
                       windows=[(0, 0, 10, 10)])
    assert "windows readout of 100 px needs an exposure >= 8.017 ms" in caplog.text


# ---------------------------------------------------------------------------- bad input
def _enforcing(**kw) -> DetectorConfig:
    return DetectorConfig.model_validate({"readout": {"timing": {"policy": "enforce"},
                                                      "modes": ["full_frame"]}, **kw})


def test_negative_exposure_is_rejected(cam64):
    le = np.zeros((64, 64), np.float32)
    with pytest.raises(ConfigError, match=r"exposure_time_s = -0\.001: expected a finite "
                                          r"exposure time > 0 s"):
        expose(le, cam64, DetectorConfig(), exposure_time=-1e-3)
    with pytest.raises(ConfigError, match="detector.exposure_time_s = -1"):
        scenario_from_dict({"detector": {"exposure_time_s": -1}})


def test_exposure_below_the_full_frame_minimum_is_rejected():
    cam = small_camera(1024)
    le = np.zeros((1024, 1024), np.float32)
    with pytest.raises(ConfigError, match=r"exposure_time_s = 0\.15: expected .*full_frame "
                                          r"readout of 1048576 px needs an exposure >= 200 ms"):
        expose(le, cam, _enforcing(), exposure_time=0.15)
    frame = expose(le, cam, _enforcing(), exposure_time=0.2)
    assert frame.feasible


def test_seventeen_windows_are_rejected(cam64):
    w = [(0, 0, 2, 2)] * 17
    with pytest.raises(ConfigError, match=r"readout.windows = '17 windows': expected at most "
                                          r"16 windows"):
        expose(np.zeros((64, 64), np.float32), cam64, DetectorConfig(), windows=w)
    with pytest.raises(ValidationError, match="at most 16 windows"):
        DetectorConfig.model_validate({"readout": {"windows": [
            {"row0": 0, "col0": 0, "height": 1, "width": 1}] * 17}})
    with pytest.raises(ConfigError, match="detector.readout.windows"):
        scenario_from_dict({"detector": {"readout": {"windows": [
            {"row0": 0, "col0": 0, "height": 1, "width": 1}] * 17}}})


def test_window_outside_the_array_is_rejected(cam64):
    with pytest.raises(ConfigError, match=r"readout.windows\[1\] = \(60, 10, 8, 8\): expected a "
                                          r"window inside the 64 x 64 array"):
        expose(np.zeros((64, 64), np.float32), cam64, DetectorConfig(),
               windows=[(0, 0, 4, 4), (60, 10, 8, 8)])
    with pytest.raises(ConfigError, match=r"readout.windows\[0\]"):
        expose(np.zeros((64, 64), np.float32), cam64, DetectorConfig(), windows=[(-1, 0, 4, 4)])


def test_nan_or_negative_radiance_is_rejected(cam64):
    le = np.ones((64, 64), np.float32)
    le[7, 9] = np.nan
    with pytest.raises(ConfigError, match=r"radiance.Le = '1 non-finite pixel\(s\), first nan "
                                          r"at \(row 7, col 9\)': expected finite"):
        expose(le, cam64, DetectorConfig())
    le[7, 9] = -3.0
    with pytest.raises(ConfigError, match=r"radiance.Le .*expected electron radiance >= 0"):
        expose(le, cam64, DetectorConfig())
    with pytest.raises(ConfigError, match=r"radiance.Le = 'shape \(32, 64\)'"):
        expose(np.ones((32, 64), np.float32), cam64, DetectorConfig())


def test_nonlinearity_in_place_equals_the_formula_bit_for_bit():
    """``S / (1 + beta/F max(S, 0))`` built in place gives the formula's float32 (and, for a
    float64 frame, float64-then-rounded) numbers exactly (seeded comparison)."""
    from starnav.detector.readout import nonlinearity

    rng = np.random.default_rng(6)
    beta = 0.03 / (1.0 - 0.03)
    for s in (rng.normal(2e4, 4e4, (50, 70)).astype(np.float32), rng.normal(5e4, 3e4, (9, 4))):
        ref = (s / (1.0 + np.float32(beta / 1e5) * np.maximum(s, 0.0))).astype(np.float32)
        out = nonlinearity(s, 1e5, 0.03)
        assert out.dtype == np.float32 and np.array_equal(out, ref)
