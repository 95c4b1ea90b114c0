"""Saturation and blooming: charge balance, full-well ceiling, geometry of each mode, registry."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.detector.blooming import BLOOMING_MODES, bloom
from starnav.detector.schema import BloomingConfig
from starnav.errors import UnknownNameError

#: Relative tolerance of the charge balance (float32 output of float64 book-keeping).
BALANCE_RTOL = 1e-6


def _scene(n: int = 96, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = (rng.random((n, n)) * 5e4).astype(np.float32)
    v, u = np.mgrid[0:n, 0:n]
    q[(u - 40) ** 2 + (v - 50) ** 2 < 12**2] = 3e6          # interior disc
    q[(u - 90) ** 2 + (v - 5) ** 2 < 6**2] = 2e7             # near a corner: spills out
    q[70:72, 10:30] = 4e5                                    # a bar
    return q


@pytest.mark.parametrize("mode", sorted(BLOOMING_MODES))
@pytest.mark.parametrize("spill", [1e-3, 0.3, 1.0])
def test_charge_balance_and_full_well(mode, spill):
    q = _scene()
    r = bloom(q, 1e5, mode, spill, max_margin=1024)
    total_in = q.sum(dtype=np.float64)
    total_out = r.charge.sum(dtype=np.float64) + r.drained + r.left_array
    assert total_out == pytest.approx(total_in, rel=BALANCE_RTOL)
    assert r.charge.max() <= 1e5 * (1 + 1e-6)
    excess = float(np.maximum(q.astype(np.float64) - 1e5, 0).sum())
    if mode == "drain":
        assert r.drained == pytest.approx(excess, rel=1e-9)
        assert r.left_array == 0.0
    else:
        assert r.drained == pytest.approx((1 - spill) * excess, rel=1e-9)
        assert r.left_array > 0.0          # the corner source spills off the array


def test_no_saturation_is_identity():
    q = (np.random.default_rng(1).random((32, 32)) * 9e4).astype(np.float32)
    for mode in BLOOMING_MODES:
        r = bloom(q, 1e5, mode, 1.0)
        assert np.array_equal(r.charge, q) and r.drained == 0.0 and r.left_array == 0.0


def test_isotropic_spill_fills_nearest_shells_symmetrically():
    """A point with 5 F of excess fills itself and its 4 nearest neighbours (distance 1)."""
    q = np.zeros((15, 15), np.float32)
    q[7, 7] = 6.0
    r = bloom(q, 1.0, "isotropic", 1.0)
    expect = np.zeros_like(q)
    expect[7, 7] = expect[6, 7] = expect[8, 7] = expect[7, 6] = expect[7, 8] = 1.0
    expect[6, 6] = expect[6, 8] = expect[8, 6] = expect[8, 8] = 0.25   # sqrt(2) shell, 1 e- left
    np.testing.assert_allclose(r.charge, expect, atol=1e-6)
    np.testing.assert_allclose(r.charge, r.charge.T, atol=1e-7)
    np.testing.assert_allclose(r.charge, r.charge[::-1], atol=1e-7)


def test_column_bleed_stays_in_its_column_and_is_symmetric():
    q = np.zeros((41, 9), np.float32)
    q[20, 4] = 11.0
    r = bloom(q, 1.0, "column", 1.0)
    np.testing.assert_allclose(r.charge[:, [0, 1, 2, 3, 5, 6, 7, 8]], 0.0)
    col = r.charge[:, 4]
    np.testing.assert_allclose(col[15:26], 1.0)
    assert col.sum() == pytest.approx(11.0)
    np.testing.assert_allclose(col, col[::-1])


def test_column_bleed_off_the_top_leaves_the_array():
    q = np.zeros((20, 3), np.float32)
    q[1, 1] = 9.0          # fills rows 0..? upward 1 row only before the edge
    r = bloom(q, 1.0, "column", 1.0)
    # 8 e- spill: rows 0 and 2 (d=1), then row 3 and virtual row -1 (d=2), ...
    assert r.left_array == pytest.approx(3.0)   # virtual rows -1, -2, -3
    assert r.charge[:, 1].sum() == pytest.approx(6.0)


def test_unknown_blooming_mode_lists_known_names():
    with pytest.raises(UnknownNameError, match="column.*drain.*isotropic"):
        bloom(np.zeros((4, 4), np.float32), 1.0, "sideways")
    with pytest.raises(ValueError, match="unknown blooming mode 'sideways'"):
        BloomingConfig(mode="sideways")
