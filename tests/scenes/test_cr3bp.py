"""CR3BP: the docs/facts.md L2 halo by differential correction, Jacobi constant, L2."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.errors import ConfigError
from starnav.scenes.cr3bp import (
    LU,
    MU_EARTH_MOON,
    REFERENCE_HALO,
    TU,
    ConvergenceError,
    correct_halo,
    jacobi_constant,
    l2_halo,
    l2_position,
)

KM = 1e3


@pytest.fixture(scope="module")
def halo():
    return l2_halo()


def test_halo_matches_reference_orbit(halo):
    # docs/facts.md s4: x0 = 1.176195936921, vy0 = -0.176332597349, T = 3.3801837666 TU
    x0, z0, vy0, T = REFERENCE_HALO
    assert halo.state0[0] == pytest.approx(x0, abs=1e-9)
    assert halo.state0[2] == z0
    assert halo.state0[4] == pytest.approx(vy0, abs=1e-9)
    assert halo.period == pytest.approx(T, abs=1e-8)
    assert halo.period * TU / 86400 == pytest.approx(14.70, abs=0.01)  # days


def test_halo_closes_after_one_period(halo):
    # issue 4: closure after one period < 1e-9 (CR3BP units)
    assert halo.closure() < 1e-9


def test_jacobi_constant_is_conserved(halo):
    X = halo.states(np.linspace(0.0, halo.period, 1001))
    C = jacobi_constant(X)
    assert np.ptp(C) < 1e-11
    assert C[0] == pytest.approx(halo.jacobi)


def test_halo_moon_range_band_and_south(halo):
    # docs/facts.md s4: 48 000-77 000 km from the Moon; southern: z < 0 at the x-z crossing
    X = halo.states(np.linspace(0.0, halo.period, 2001))
    r = np.linalg.norm(X[:, :3] - [1 - MU_EARTH_MOON, 0, 0], axis=1) * LU
    assert 47_500 * KM < r.min() < 49_000 * KM
    assert 76_000 * KM < r.max() < 77_500 * KM
    assert halo.state0[2] < 0 and X[:, 2].min() == pytest.approx(halo.state0[2], abs=1e-6)


def test_l2_location():
    # Koon, Lo, Marsden & Ross (2011), Dynamical Systems, the Three-Body Problem and Space
    # Mission Design, s2.5: Earth-Moon L2 at gamma_2 = 0.1678 beyond the Moon
    assert l2_position() - (1 - MU_EARTH_MOON) == pytest.approx(0.1678, abs=2e-4)


def test_continuation_to_other_amplitudes():
    north = l2_halo(0.065)  # mirror image of the southern orbit
    assert north.state0[2] == 0.065 and north.state0[0] == pytest.approx(REFERENCE_HALO[0])
    big = l2_halo(-0.08)
    assert big.closure() < 1e-9
    # larger halos have shorter periods along the L2 family (Howell 1984, Fig. 5)
    assert big.period < REFERENCE_HALO[3]


def test_bad_amplitude_and_bad_guess():
    with pytest.raises(ConfigError, match="halo_z0_km"):
        l2_halo(0.5)
    with pytest.raises(ConvergenceError):
        correct_halo(0.5, -0.065, 0.0, max_iter=3)
