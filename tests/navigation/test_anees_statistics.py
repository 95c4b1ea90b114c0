"""The Monte Carlo consistency statistics (Bar-Shalom, Li & Kirubarajan 2001, s. 5.4.2):
per-epoch ANEES band against its closed form, and the time-averaged band whose degrees of
freedom come from the measured autocorrelation, scored on simulated chi-square series of known
correlation (not on the filter: these tests check the statistics, not a navigation model)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from starnav.navigation.metrics import (
    anees_statistics,
    autocorrelation,
    chi2_band,
    integrated_autocorrelation_time,
)

#: Two-sided false-alarm rate of each binomial coverage test below.
FALSE_ALARM = 1e-3
TRIALS = 400


def chi2_cdf_even(x: float, k: int) -> float:
    """CDF of chi2(k), k even: ``1 - exp(-x/2) sum_{j<k/2} (x/2)^j / j!`` (Abramowitz &
    Stegun 1964, 26.4.21)."""
    h = x / 2.0
    return 1.0 - math.exp(-h) * sum(h**j / math.factorial(j) for j in range(k // 2))


def ar1_nees(rng: np.random.Generator, runs: int, epochs: int, phi: float,
             dof: int = 6) -> np.ndarray:
    """``runs`` x ``epochs`` NEES of a consistent filter whose errors are Gaussian AR(1) with
    coefficient ``phi`` per component, started stationary: chi2(``dof``) at every epoch, with
    the autocorrelation ``phi^(2k)`` at lag ``k``."""
    z = np.empty((runs, epochs, dof))
    z[:, 0] = rng.standard_normal((runs, dof))
    s = math.sqrt(1.0 - phi * phi)
    for k in range(1, epochs):
        z[:, k] = phi * z[:, k - 1] + s * rng.standard_normal((runs, dof))
    return np.sum(z * z, axis=2)


def true_tau(phi: float, epochs: int) -> float:
    r = phi * phi
    return 1.0 + 2.0 * sum((1.0 - k / epochs) * r**k for k in range(1, epochs))


@pytest.mark.parametrize(("dof", "runs"), [(6, 20), (3, 20), (6, 1), (2, 7)])
def test_per_epoch_band_is_the_chi2_of_the_run_sum(dof, runs):
    """The per-epoch band of an R-run mean is chi2(dof R) / R: its edges sit at the 2.5 % and
    97.5 % points of the closed-form CDF (even dof R) and of scipy.stats.chi2."""
    x = np.full((runs, 5), float(dof))
    st = anees_statistics(x, dof, epoch_probability=0.95)
    lo, hi = st["per_epoch_band"][0]
    assert (lo, hi) == pytest.approx(chi2_band(dof, runs, 0.95), rel=1e-12)
    k = dof * runs
    assert chi2.cdf(lo * runs, k) == pytest.approx(0.025, abs=1e-9)
    assert chi2.cdf(hi * runs, k) == pytest.approx(0.975, abs=1e-9)
    if k % 2 == 0:
        assert chi2_cdf_even(lo * runs, k) == pytest.approx(0.025, abs=1e-9)
        assert chi2_cdf_even(hi * runs, k) == pytest.approx(0.975, abs=1e-9)
    # 20 runs of 6 dof: the band of issue-style reports, [4.19, 8.18] at 99 %
    if (dof, runs) == (6, 20):
        assert chi2_band(6, 20, 0.99) == pytest.approx((4.19, 8.18), abs=0.005)


def test_autocorrelation_of_an_ar1_nees_series():
    """phi = 0.8 per error component: the NEES autocorrelation is phi^(2k) (0.64, 0.41 at lags
    1, 2); over 200 runs x 60 epochs its sampling error is ~0.01. The integrated time over
    1000 runs has a relative sampling error sqrt(2 (2M + 1) / N) ~ 4 % (Sokal 1997, eq. 3.19;
    M ~ 22, N = 60000): within 15 % (~4 sigma)."""
    rng = np.random.default_rng(11)
    rho = autocorrelation(ar1_nees(rng, 200, 60, 0.8))
    assert rho[0] == 1.0
    assert rho[1] == pytest.approx(0.64, abs=0.04)
    assert rho[2] == pytest.approx(0.4096, abs=0.04)
    tau, window = integrated_autocorrelation_time(ar1_nees(rng, 1000, 60, 0.8))
    assert tau == pytest.approx(true_tau(0.8, 60), rel=0.15)
    assert 5.0 * tau <= window + 1


def test_independent_epochs_give_a_unit_autocorrelation_time():
    rng = np.random.default_rng(3)
    tau, _ = integrated_autocorrelation_time(rng.chisquare(6, (50, 40)))
    assert tau == pytest.approx(1.0, abs=0.15)


@pytest.mark.parametrize(("runs", "epochs", "phi"), [(20, 13, 0.9), (20, 40, 0.9), (10, 60, 0.7)])
def test_corrected_band_covers_the_mean_at_its_rate(runs, epochs, phi):
    """Over 400 seeded arcs of a consistent filter with AR(1)-correlated NEES, the
    time-averaged ANEES falls inside its corrected 95 % band as often as a binomial(400, 0.95)
    count allows (two-sided, false-alarm rate 1e-3); the band of R K independent samples
    under-covers (its count is below that binomial's lower limit)."""
    rng = np.random.default_rng(20 + epochs)
    inside = naive = 0
    for _ in range(TRIALS):
        st = anees_statistics(ar1_nees(rng, runs, epochs, phi), 6, probability=0.95)
        inside += st["band"][0] <= st["mean"] <= st["band"][1]
        naive += st["band_independent"][0] <= st["mean"] <= st["band_independent"][1]
    lo = binom.ppf(FALSE_ALARM / 2, TRIALS, 0.95)
    hi = binom.isf(FALSE_ALARM / 2, TRIALS, 0.95)
    assert lo <= inside <= hi, (inside, lo, hi)
    assert naive < lo, (naive, lo)


def test_verdicts_and_missing_samples():
    """An overconfident filter (errors 1.5x its sigma: NEES x 2.25) is called overconfident, a
    pessimistic one (0.6x) pessimistic; NaN samples (a NIS without a fix) are left out, and an
    epoch's band follows its own number of samples."""
    rng = np.random.default_rng(5)
    x = ar1_nees(rng, 20, 30, 0.5, dof=3)
    assert anees_statistics(x, 3)["verdict"] == "consistent"
    assert anees_statistics(2.25 * x, 3)["verdict"] == "overconfident"
    assert anees_statistics(2.25 * x, 3)["epochs_above"] > 0.5
    assert anees_statistics(0.36 * x, 3)["verdict"] == "pessimistic"
    y = x.copy()
    y[:5, 3] = np.nan
    st = anees_statistics(y, 3)
    assert st["per_epoch"][3] == pytest.approx(np.mean(x[5:, 3]))
    assert st["per_epoch_band"][3] == pytest.approx(list(chi2_band(3, 15, 0.95)))
    assert st["mean"] == pytest.approx(np.nanmean(y))
