"""Charge stage: shot noise statistics, PRNU, dark current, DSNU, hot pixels, temperature."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.detector.charge import (
    dark_pattern,
    dark_rate_at,
    hot_pixel_mask,
    prnu_map,
    shot_noise,
)

#: Two-sided z threshold: false-alarm rate 6.3e-5 per check for a correct implementation.
Z_MAX = 4.0


def _variance_z(x: np.ndarray, mu: float) -> float:
    """z-score of the sample variance of Poisson(mu) draws against mu.

    Var(s^2) = 2 mu^2 / (n - 1) + kappa_4 / n with kappa_4 = mu for the Poisson law.
    """
    n = x.size
    s2 = float(x.astype(np.float64).var(ddof=1))
    return (s2 - mu) / math.sqrt(2 * mu * mu / (n - 1) + mu / n)


@pytest.mark.parametrize("mu", [0.3, 7.0, 250.0, 5000.0])
def test_shot_noise_variance_equals_mean(mu):
    """Poisson statistics: mean = variance = mu (Gaussian branch above 1000 e- included)."""
    n = 200_000
    x = shot_noise(np.full((400, n // 400), mu, np.float32), np.random.default_rng(11))
    z_mean = (float(x.mean(dtype=np.float64)) - mu) / math.sqrt(mu / n)
    assert abs(z_mean) < Z_MAX
    assert abs(_variance_z(x, mu)) < Z_MAX


def test_shot_noise_is_exact_poisson_at_low_counts():
    """P(0) = exp(-mu) for mu = 0.5 (checks the law itself, not just two moments)."""
    n = 200_000
    x = shot_noise(np.full((n,), 0.5, np.float32).reshape(400, -1), np.random.default_rng(5))
    p0 = math.exp(-0.5)
    z = (float((x == 0).mean()) - p0) / math.sqrt(p0 * (1 - p0) / n)
    assert abs(z) < Z_MAX
    assert np.all(x == np.round(x))


def test_prnu_map_is_frozen_per_sensor_and_has_the_set_rms():
    a = prnu_map(7, (256, 256), 0.02)
    b = prnu_map(7, (256, 256), 0.02)
    c = prnu_map(8, (256, 256), 0.02)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert float(a.mean()) == pytest.approx(1.0, abs=5 * 0.02 / 256)
    assert float(a.std()) == pytest.approx(0.02, rel=0.02)


def test_dark_current_doubles_every_doubling_temperature():
    assert dark_rate_at(590.0, 27.0, 20.0, 7.0) == pytest.approx(1180.0, rel=1e-12)
    assert dark_rate_at(590.0, 6.0, 20.0, 7.0) == pytest.approx(147.5, rel=1e-12)


def test_dsnu_and_hot_pixels():
    shape = (512, 512)
    d = dark_pattern(3, shape, 0.013, 1e-4, 100.0)
    hot = hot_pixel_mask(3, shape, 1e-4)
    assert hot.sum() == round(1e-4 * 512 * 512)
    assert np.all(d[hot] == 100.0)
    normal = d[~hot]
    assert float(normal.std()) == pytest.approx(0.013, rel=0.02)
    assert float(normal.mean()) == pytest.approx(1.0, abs=1e-4)
    assert np.array_equal(d, dark_pattern(3, shape, 0.013, 1e-4, 100.0))
