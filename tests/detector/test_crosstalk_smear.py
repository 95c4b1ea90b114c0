"""Crosstalk (IPC conservation and kernel, electrical streaks) and smear (rolling shutter, CCD)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.detector.crosstalk import electrical_crosstalk, interpixel_capacitance
from starnav.detector.smear import image_velocity, line_kernel, rolling_shutter, transfer_smear


def test_ipc_kernel_on_a_point_and_conservation_everywhere():
    q = np.zeros((9, 9), np.float32)
    q[4, 4] = 1e5
    out = interpixel_capacitance(q, 0.005, 0.0005)
    assert out[4, 4] == pytest.approx(1e5 * (1 - 4 * 0.0055), rel=1e-6)
    for r, c in ((3, 4), (5, 4), (4, 3), (4, 5)):
        assert out[r, c] == pytest.approx(500.0, rel=1e-6)
    for r, c in ((3, 3), (3, 5), (5, 3), (5, 5)):
        assert out[r, c] == pytest.approx(50.0, rel=1e-6)
    # random frame with bright edges and corners: total conserved (reflecting edges)
    rng = np.random.default_rng(2)
    q = (rng.random((64, 48)) * 1e5).astype(np.float32)
    q[0, :] = 1e5
    q[:, -1] = 1e5
    out = interpixel_capacitance(q, 0.005, 0.0005)
    assert out.sum(dtype=np.float64) == pytest.approx(q.sum(dtype=np.float64), rel=1e-6)
    assert not np.allclose(out, q)


def _ipc_whole_frame(charge, nearest, diagonal):
    """The IPC formula on the whole frame at once, float32 (the slow reference)."""
    p = np.pad(charge.astype(np.float32), 1, mode="symmetric")
    out = p[1:-1, 1:-1] * np.float32(1.0 - 4.0 * (nearest + diagonal))
    out += (((p[:-2, 1:-1] + p[2:, 1:-1]) + p[1:-1, :-2]) + p[1:-1, 2:]) * np.float32(nearest)
    out += (((p[:-2, :-2] + p[:-2, 2:]) + p[2:, :-2]) + p[2:, 2:]) * np.float32(diagonal)
    return out


@pytest.mark.parametrize("shape", [(1, 1), (70, 45), (64, 64), (33, 5)])
def test_ipc_in_row_blocks_equals_the_whole_frame_formula_bit_for_bit(shape):
    """The row-blocked IPC (for the cache) does every pixel's float32 operations in the same
    order as the whole-frame formula: equal to the last bit (seeded comparison), for sizes that
    are and are not multiples of the block."""
    q = np.random.default_rng(4).exponential(3e4, shape).astype(np.float32)
    assert np.array_equal(interpixel_capacitance(q, 0.005, 0.0005),
                          _ipc_whole_frame(q, 0.005, 0.0005))
    assert np.array_equal(interpixel_capacitance(q, 0.01, 0.0), _ipc_whole_frame(q, 0.01, 0.0))


def test_electrical_crosstalk_adds_a_row_streak():
    s = np.zeros((6, 10), np.float32)
    s[2, 3:7] = 1e5
    out = electrical_crosstalk(s, threshold=9e4, row_coefficient=2e-5, column_coefficient=0.0)
    streak = 2e-5 * 4 * 1e4
    np.testing.assert_allclose(out[2, :3], streak, rtol=1e-6)
    np.testing.assert_allclose(out[[0, 1, 3, 4, 5]], 0.0)


def test_rolling_shutter_blur_and_skew_move_a_point_as_predicted():
    """Rate about camera y: image moves along -u at f w_y px/s; row r starts at r t_row."""
    fx = 50.7e-3 / 18e-6
    w_y = math.radians(0.5)               # deg/s -> rad/s
    au, av = image_velocity((0.0, w_y), fx, fx)
    assert au == pytest.approx(-fx * w_y) and av == 0.0
    t_exp, t_row = 0.2, 174e-6
    img = np.zeros((128, 128), np.float32)
    img[100, 100] = 1000.0
    out = rolling_shutter(img, (au, av), t_exp, t_row)
    assert out.sum(dtype=np.float64) == pytest.approx(1000.0, rel=1e-5)
    u = np.arange(128)
    row = out[100].astype(np.float64)
    # centroid: start shift a r t_row plus half the blur a t_exp
    expect = 100 + au * (100 * t_row) + au * t_exp / 2
    assert (row * u).sum() / row.sum() == pytest.approx(expect, abs=0.02)
    var = (row * (u - expect) ** 2).sum() / row.sum()
    # uniform segment (a t)^2 / 12, plus the bilinear splat of the line kernel (1/6 px^2 on
    # average) and the bilinear resampling of the skew at fractional shift f (f (1 - f))
    f = (-au * 100 * t_row) % 1.0
    assert var == pytest.approx((au * t_exp) ** 2 / 12 + 1 / 6 + f * (1 - f), rel=0.03)


def test_line_kernel_has_unit_sum_and_the_right_centroid():
    k = line_kernel(7.3, -2.1).astype(np.float64)
    h = k.shape[0] // 2
    y, x = np.mgrid[-h:h + 1, -h:h + 1]
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    assert (k * x).sum() == pytest.approx(3.65, abs=1e-3)
    assert (k * y).sum() == pytest.approx(-1.05, abs=1e-3)


def test_transfer_smear_adds_the_column_sum():
    img = np.zeros((10, 4), np.float32)
    img[3, 1] = 1e6
    out = transfer_smear(img, exposure_time=1e-3, row_transfer_time=1e-6)
    np.testing.assert_allclose(out[[0, 1, 2, 4], 1], 1e3, rtol=1e-6)   # 1e6 * 1e-6 / 1e-3
    np.testing.assert_allclose(out[:, [0, 2, 3]], 0.0)
