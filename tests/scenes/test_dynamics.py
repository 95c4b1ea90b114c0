"""Point-mass model about the EMB: Jacobian, STM, EMB acceleration, RK4 against DOP853."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from starnav.constants import DAY
from starnav.errors import ConfigError
from starnav.scenes.dynamics import PointMassModel, propagate, propagate_many
from starnav.scenes.ephemeris import parse_epoch

T0 = parse_epoch("2027-03-01T00:00:00 TDB")


def _states(eph, t):
    """Test states: 60 000 km beyond the Moon (L2 side, co-moving); 20 000 km off the Moon out
    of plane on a near-circular lunar orbit; in LEO (7000 km from the geocentre); half-way to
    the Moon."""
    moon = eph.state("moon", t, center="emb")
    earth = eph.state("earth", t, center="emb")
    u = moon[:3] / np.linalg.norm(moon[:3])
    out = [moon + np.concatenate([6e7 * u, 0.18 * moon[3:]])]
    out.append(moon + np.array([0.0, 0.0, 2e7, 495.0, 0.0, 0.0]))  # ~circular about the Moon
    out.append(earth + np.array([7e6, 0.0, 0.0, 0.0, 7546.0, 0.0]))
    out.append(0.5 * (earth + moon))
    return out


def test_jacobian_matches_central_differences(model, eph):
    for x in _states(eph, T0):
        r = x[:3]
        J = model.jacobian(T0, r)
        h = 1e3  # 1 km: truncation ~ h^2 |d3a/dr3| and rounding ~ eps |a| / h both negligible
        Jfd = np.empty((3, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            Jfd[:, k] = (model.acceleration(T0, r + e) - model.acceleration(T0, r - e)) / (2 * h)
        assert np.allclose(J, Jfd, rtol=1e-6, atol=1e-6 * np.max(np.abs(J)))
        assert np.allclose(J, J.T, rtol=0, atol=1e-12 * np.max(np.abs(J)))  # gradient field


def test_leo_acceleration_is_keplerian(model, eph):
    # 7000 km from the geocentre, in the EMB frame: a = -GM_E rho/rho^3 plus the Earth's own
    # acceleration about the EMB, GM_M (r_M - r_E)/d^3 (3.3e-5 m/s^2), up to the lunisolar
    # tides across 7000 km (2 GM_M rho/d^3 + 2 GM_S rho/AU^3 < 2e-6 m/s^2)
    b = eph.positions_emb(T0)
    earth, moon = b[0], b[1]
    rho = np.array([7e6, 0.0, 0.0])
    a = model.acceleration(T0, earth + rho)
    kepler = -eph.gm_earth * rho / 7e6**3
    d = moon - earth
    earth_about_emb = eph.gm_moon * d / np.linalg.norm(d) ** 3
    assert np.linalg.norm(a - kepler - earth_about_emb) < 2e-6
    assert np.linalg.norm(a - kepler) > 2e-5  # the frame term is really there
    assert np.linalg.norm(kepler) == pytest.approx(8.1347, rel=1e-4)


def test_emb_acceleration_matches_the_ephemeris(model, eph):
    # The frame's acceleration derived in the module docstring must be the acceleration of the
    # DE421 EMB (second difference of its SSB position) up to the planets' pull, < 1e-6 m/s^2
    # (Jupiter at >= 4.2 AU: 3.2e-7; Venus at >= 0.26 AU: 2e-7 m/s^2).
    for t in T0 + np.array([0.0, 91.3, 182.6, 273.9]) * DAY:
        h = 600.0
        p = [eph.emb_ssb(t + k * h)[0] for k in (-1, 0, 1)]
        a_fd = (p[0] - 2 * p[1] + p[2]) / h**2
        a_b = model.frame_acceleration(t)
        assert np.linalg.norm(a_b) == pytest.approx(5.9e-3, rel=0.05)  # GM_S / (1 AU)^2
        assert np.linalg.norm(a_b - a_fd) < 1e-6


def test_indirect_term_forms_agree_to_the_tidal_bound(eph):
    # exact barycentric form vs docs/facts.md s4 (GM_S r_S/|r_S|^3): they differ only at second
    # order in d_EM/|r_S|, bounded by 3 GM_S f (1 - f) d_EM^2 / |r_S|^4 (module docstring)
    exact = PointMassModel(eph)
    approx = PointMassModel(eph, emb_indirect="sun-at-emb")
    f = exact.moon_fraction
    for t in T0 + np.linspace(0, 30, 7) * DAY:
        b = exact.body_positions(t)
        d = np.linalg.norm(b[1] - b[0])
        rs = np.linalg.norm(b[2])
        bound = 3 * eph.gm_sun * f * (1 - f) * d**2 / rs**4
        diff = np.linalg.norm(exact.frame_acceleration(t) - approx.frame_acceleration(t))
        assert diff <= 1.001 * bound
        assert diff > 0.2 * bound  # the two forms really differ (the test can fail)
    assert bound == pytest.approx(1.4e-9, rel=0.15)


def test_rk4_matches_dop853_over_five_days(model, eph):
    x0 = _states(eph, T0)[0]
    t1 = T0 + 5 * DAY
    x1, _ = propagate(model, T0, x0, t1, step=300.0)
    sol = solve_ivp(model.derivative, (T0, t1), x0, method="DOP853", rtol=1e-13, atol=1e-7)
    # docs/facts.md s4: RK4 at 300 s is mm-accurate over a period (here: 5 days, < 1 cm)
    assert np.linalg.norm(x1[:3] - sol.y[:3, -1]) < 1e-2
    assert np.linalg.norm(x1[3:] - sol.y[3:, -1]) < 1e-6


def test_stm_matches_finite_differences(model, eph):
    x0 = _states(eph, T0)[0]
    t1 = T0 + DAY
    x1, Phi = propagate(model, T0, x0, t1, with_stm=True)
    scale = np.array([1e3] * 3 + [1e-2] * 3)  # 1 km, 1 cm/s perturbations
    Pfd = np.empty((6, 6))
    for k in range(6):
        e = np.zeros(6)
        e[k] = scale[k]
        xp, _ = propagate(model, T0, x0 + e, t1)
        xm, _ = propagate(model, T0, x0 - e, t1)
        Pfd[:, k] = (xp - xm) / (2 * scale[k])
    for k in range(6):
        assert np.allclose(Phi[:, k], Pfd[:, k], rtol=1e-5, atol=1e-7 * np.abs(Pfd[:, k]).max())
    # symplectic-like check: det(Phi) = 1 (Liouville; divergence-free flow)
    assert np.linalg.det(Phi) == pytest.approx(1.0, abs=1e-8)


def test_stm_integrated_with_scipy(model, eph):
    x0 = _states(eph, T0)[1]
    t1 = T0 + 2 * DAY
    _, Phi = propagate(model, T0, x0, t1, step=300.0, with_stm=True)
    y0 = np.concatenate([x0, np.eye(6).ravel()])
    sol = solve_ivp(model.derivative_with_stm, (T0, t1), y0, method="DOP853", rtol=1e-12,
                    atol=1e-9)
    Pref = sol.y[6:, -1].reshape(6, 6)
    assert np.allclose(Phi, Pref, rtol=1e-6, atol=1e-9 * np.abs(Pref).max())


def test_backward_propagation_returns_to_start(model, eph):
    x0 = _states(eph, T0)[0]
    x1, P1 = propagate(model, T0, x0, T0 + 3 * DAY, with_stm=True)
    x2, P2 = propagate(model, T0 + 3 * DAY, x1, T0, with_stm=True)
    assert np.linalg.norm(x2[:3] - x0[:3]) < 1e-3
    assert np.allclose(P2 @ P1, np.eye(6), atol=1e-6)


def test_propagate_many_lands_on_samples(model, eph):
    x0 = _states(eph, T0)[0]
    times = T0 + np.array([0.0, 450.0, 3600.0, 7200.0, 86400.0])
    X, P = propagate_many(model, T0, x0, times, with_stm=True)
    assert X.shape == (5, 6) and P.shape == (5, 6, 6)
    assert np.array_equal(X[0], x0) and np.allclose(P[0], np.eye(6))
    for k in range(1, 5):
        xk, Pk = propagate(model, T0, x0, times[k], with_stm=True)
        assert np.linalg.norm(X[k, :3] - xk[:3]) < 1e-3  # different step splits: < 1 mm
        assert np.allclose(P[k], Pk, rtol=1e-6, atol=1e-9)
    with pytest.raises(ConfigError):
        propagate_many(model, T0, x0, T0 + np.array([100.0, 50.0]))


def test_bad_inputs(model, eph):
    with pytest.raises(ConfigError, match="x0"):
        propagate(model, T0, np.zeros(5), T0 + 1)
    with pytest.raises(ConfigError, match="step"):
        propagate(model, T0, np.ones(6) * 1e8, T0 + 1, step=-1.0)
    with pytest.raises(ConfigError, match="gm_moon"):
        PointMassModel(eph, gm_moon=-1.0)
    with pytest.raises(ConfigError, match="emb_indirect"):
        PointMassModel(eph, emb_indirect="none")  # type: ignore[arg-type]
    assert math.isclose(model.gm[1], eph.gm_moon)


def test_filter_rk4_step_default_is_converged_near_l2():
    """Regression of the integrator against itself at a 30 x finer step (not a validation):
    the filter's default RK4 step (navigation.filter.rk4_step_s) moves a day's L2 arc by less
    than a centimetre and its STM by less than 1e-6 relative."""
    import numpy as np

    from starnav.navigation.schema import FilterConfig
    from starnav.scenes.dynamics import PointMassModel, propagate
    from starnav.scenes.ephemeris import Ephemeris

    step = FilterConfig().rk4_step_s
    m = PointMassModel(Ephemeris.default())
    t0 = 8.5e8
    x0 = np.array([4.4e8, 3.0e7, -2.0e7, -80.0, 1000.0, 50.0])
    ref, Pr = propagate(m, t0, x0, t0 + 86400.0, step=step / 30, with_stm=True)
    x, P = propagate(m, t0, x0, t0 + 86400.0, step=step, with_stm=True)
    assert np.linalg.norm(x[:3] - ref[:3]) < 0.01
    assert np.abs(P - Pr).max() / np.abs(Pr).max() < 1e-6


def test_single_trajectory_kernel_is_the_grid_kernel(model, eph):
    # regression test of rk4_stm (the filter's step) against rk4_grid with the STM, the same
    # RK4 on the same stages: equal to rounding (1e-12 relative), forwards, backwards, one and
    # several steps; a subclass's forces are refused, not silently dropped
    from starnav.navigation.dynamics import PointMassDynamics
    from starnav.scenes.dynamics import rk4_grid, rk4_stm, step_grid
    from starnav.scenes.forces import TruthForceModel

    for x0 in _states(eph, T0):
        for span, step in ((1800.0, 1800.0), (-3000.0, 1800.0), (7200.0, 1000.0)):
            grid = step_grid(T0, T0 + span, step)
            x1, Phi = rk4_stm(model, grid, x0)
            x_ref, Phi_ref = rk4_grid(model, grid, x0, with_stm=True)
            assert np.allclose(x1, x_ref, rtol=1e-12, atol=1e-6)
            assert np.allclose(Phi, Phi_ref, rtol=1e-12, atol=1e-12 * np.abs(Phi_ref).max())
            dyn = PointMassDynamics(model, step_s=step)
            xd, Pd = dyn.propagate(T0, x0, T0 + span)
            assert np.array_equal(xd, x1) and np.array_equal(Pd, Phi)
    with pytest.raises(ConfigError, match="PointMassModel"):
        rk4_stm(TruthForceModel.__new__(TruthForceModel), step_grid(T0, T0 + 60.0), x0)
