"""Negative control of the consistency statistics: a truth with every dynamics mismatch on
(DE421 planets, SRP of the default 12U CubeSat with eclipses, Earth and Moon J2) navigated by
the filter's point-mass model declared with perfect knowledge (no process noise) is called
overconfident; the released process noise (navigation.filter.accel_psd_m2_s3) is not.

Simulated position fixes with known white noise (300 m per axis, every hour for 1.5 days,
near L2) isolate the dynamics mismatch from the imaging chain; the truth is propagated with
starnav.scenes.forces.TruthForceModel, the filter with starnav.scenes.dynamics.PointMassModel.
"""

from __future__ import annotations

import numpy as np
import pytest

from starnav.navigation.dynamics import PointMassDynamics
from starnav.navigation.ekf import FilterConfig
from starnav.navigation.metrics import anees_statistics
from starnav.navigation.pipeline import FrameMeasurement, run_filter
from starnav.scenes.ephemeris import Ephemeris, parse_epoch
from starnav.scenes.forces import SrpParameters, TruthForceModel

RUNS, STEPS, DT, SIGMA = 5, 36, 3600.0, 300.0
P0 = np.diag([10e3**2] * 3 + [0.1**2] * 3)


@pytest.fixture(scope="module")
def arc():
    eph = Ephemeris.default()
    t0 = parse_epoch("2027-03-01T00:00:00 TDB")
    truth = PointMassDynamics(TruthForceModel(
        eph, planets=["venus", "mars", "jupiter", "saturn"],
        srp=SrpParameters(area=0.6, mass=22.0, reflectivity=1.3), eclipses=True, j2=True))
    m = eph.state("moon", t0)
    x0 = np.concatenate([1.15 * m[:3], 1.15 * m[3:]])  # near L2, co-moving
    X, T, x = [], [], x0.copy()
    for k in range(STEPS):
        x, _ = truth.propagate(t0 + k * DT, x, t0 + (k + 1) * DT)
        X.append(x)
        T.append(t0 + (k + 1) * DT)
    return t0, x0, np.array(T), np.array(X)


def _nees(arc, accel_psd: float) -> np.ndarray:
    t0, x0, T, X = arc
    filt = PointMassDynamics()
    rng = np.random.default_rng(17)
    L = np.linalg.cholesky(P0)
    out = []
    for _ in range(RUNS):
        meas = [FrameMeasurement(k, float(T[k]), "ok",
                                 position=X[k, :3] - filt.moon_state(T[k])[:3]
                                 + SIGMA * rng.standard_normal(3),
                                 covariance=np.eye(3) * SIGMA**2) for k in range(STEPS)]
        res = run_filter(meas, dynamics=filt, moon=filt, t0=t0, x0=x0 + L @ rng.standard_normal(6),
                         P0=P0, options=FilterConfig(accel_psd_m2_s3=accel_psd).to_si())
        out.append(res.nees(X))
    return np.array(out)


def test_perfect_knowledge_filter_is_called_overconfident(arc):
    """No process noise against ~1.7e-7 m/s^2 of unmodelled acceleration: the time-averaged
    ANEES is well above its corrected band and most epochs are above their per-epoch band."""
    st = anees_statistics(_nees(arc, 0.0), 6)
    assert st["verdict"] == "overconfident", st["mean"]
    assert st["mean"] > 2 * st["band"][1]
    assert st["epochs_above"] > 0.5


def test_released_process_noise_covers_the_mismatch(arc):
    """The released accel_psd_m2_s3 (a_rms^2 tau of the same forces): not overconfident."""
    st = anees_statistics(_nees(arc, FilterConfig().accel_psd_m2_s3), 6)
    assert st["verdict"] != "overconfident", (st["mean"], st["band"])
    assert st["epochs_above"] < 0.1
