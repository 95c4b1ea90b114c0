r"""Circular restricted three-body problem: equations, Jacobi constant, L2 halo orbits.

Halo orbits by single-shooting differential correction (Howell 1984), in the non-dimensional
rotating frame (Earth at ``(-mu, 0, 0)``, Moon at ``(1 - mu, 0, 0)``):

1. start perpendicular on the x-z plane, ``(x, 0, z, 0, vy, 0)``;
2. integrate state and STM to the next x-z crossing;
3. with ``z`` fixed, correct ``(x, vy)`` by Newton so that ``vx = vz = 0`` there, the crossing
   time moving too:
   ``[d vx; d vz] = ([Phi_41 Phi_45; Phi_61 Phi_65] - [ax; az] [Phi_21 Phi_25] / vy) [dx; dvy]``;
4. repeat to ``tol``; far amplitudes by natural-parameter continuation in ``z``.

References
----------
K. C. Howell (1984), *Three-dimensional, periodic, 'halo' orbits*, Celestial Mechanics 32,
53-71. V. Szebehely (1967), *Theory of Orbits*, Academic Press (Jacobi integral).

Index
-----
:func:`l2_halo`, :func:`correct_halo`, :class:`HaloOrbit`, :data:`REFERENCE_HALO`,
:func:`propagate_cr3bp`, :func:`cr3bp_rhs`, :func:`cr3bp_rhs_stm`, :func:`cr3bp_gradient`,
:func:`jacobi_constant`, :func:`l2_position`, :class:`ConvergenceError`, :data:`MU_EARTH_MOON`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp

from starnav.errors import ConfigError, StarnavError
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Earth-Moon mass parameter of the CR3BP (docs/facts.md s4).
MU_EARTH_MOON = 0.01215058560962404
#: Length unit [m] (docs/facts.md s4).
LU = 384_400e3
#: Time unit [s] (docs/facts.md s4).
TU = 375_699.88
#: docs/facts.md s4 southern L2 halo: x0 [LU], z0 [LU], vy0 [LU/TU], period [TU].
REFERENCE_HALO = (1.176195936921, -0.065, -0.176332597349, 3.3801837666)

#: DOP853 tolerances used for every CR3BP integration.
RTOL = 1e-13
ATOL = 1e-13


class ConvergenceError(StarnavError, RuntimeError):
    """An iterative solver (differential correction, multiple shooting) did not converge."""


# --------------------------------------------------------------------------- equations
def cr3bp_rhs(t: float, x: FloatArray, mu: float = MU_EARTH_MOON) -> FloatArray:
    """Time derivative of a CR3BP state ``(x, y, z, vx, vy, vz)`` [LU, LU/TU]."""
    px, py, pz, vx, vy, vz = x[:6]
    d1 = math.sqrt((px + mu) ** 2 + py * py + pz * pz)
    d2 = math.sqrt((px - 1.0 + mu) ** 2 + py * py + pz * pz)
    c1 = (1.0 - mu) / d1**3
    c2 = mu / d2**3
    ax = 2.0 * vy + px - c1 * (px + mu) - c2 * (px - 1.0 + mu)
    ay = -2.0 * vx + py - c1 * py - c2 * py
    az = -c1 * pz - c2 * pz
    return np.array([vx, vy, vz, ax, ay, az])


def cr3bp_gradient(x: FloatArray, mu: float = MU_EARTH_MOON) -> FloatArray:
    """Hessian of the pseudo-potential ``Omega`` w.r.t. position, ``(3, 3)``."""
    px, py, pz = x[:3]
    r1 = np.array([px + mu, py, pz])
    r2 = np.array([px - 1.0 + mu, py, pz])
    d1, d2 = np.linalg.norm(r1), np.linalg.norm(r2)
    H = np.diag([1.0, 1.0, 0.0])
    for gm, r, d in ((1.0 - mu, r1, d1), (mu, r2, d2)):
        H = H - gm * (np.eye(3) / d**3 - 3.0 * np.outer(r, r) / d**5)
    return H


def cr3bp_rhs_stm(t: float, y: FloatArray, mu: float = MU_EARTH_MOON) -> FloatArray:
    """Right-hand side of the state plus the row-major 6x6 STM (42 values)."""
    f = cr3bp_rhs(t, y, mu)
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    A[3:, :3] = cr3bp_gradient(y, mu)
    A[3, 4], A[4, 3] = 2.0, -2.0
    P = y[6:].reshape(6, 6)
    return np.concatenate([f, (A @ P).ravel()])


def jacobi_constant(x: ArrayLike, mu: float = MU_EARTH_MOON) -> FloatArray:
    """Jacobi constant ``C = 2 Omega - v^2`` with
    ``Omega = (x^2 + y^2)/2 + (1 - mu)/r1 + mu/r2`` (Szebehely 1967), for states ``(..., 6)``."""
    x = np.asarray(x, dtype=float)
    px, py, pz = x[..., 0], x[..., 1], x[..., 2]
    r1 = np.sqrt((px + mu) ** 2 + py**2 + pz**2)
    r2 = np.sqrt((px - 1.0 + mu) ** 2 + py**2 + pz**2)
    omega = 0.5 * (px**2 + py**2) + (1.0 - mu) / r1 + mu / r2
    v2 = np.sum(x[..., 3:6] ** 2, axis=-1)
    return 2.0 * omega - v2


def propagate_cr3bp(x0: ArrayLike, times: ArrayLike, mu: float = MU_EARTH_MOON) -> FloatArray:
    """CR3BP states ``(k, 6)`` at non-dimensional ``times`` (from 0) by DOP853 (RTOL, ATOL)."""
    ts = np.asarray(times, dtype=float)
    if ts.size == 0:
        return np.empty((0, 6))
    t_end = float(ts.max()) if ts.max() > 0 else float(ts.min())
    if t_end == 0.0:
        return np.repeat(np.asarray(x0, float)[None], ts.size, 0)
    sol = solve_ivp(cr3bp_rhs, (0.0, t_end), np.asarray(x0, float), method="DOP853",
                    rtol=RTOL, atol=ATOL, args=(mu,), dense_output=True)
    return sol.sol(ts).T


# --------------------------------------------------------------------------- halo
@dataclass(frozen=True)
class HaloOrbit:
    """A periodic CR3BP halo orbit (non-dimensional units).

    Parameters
    ----------
    state0 : (6,) array
        State on the x-z plane ``(x, 0, z, 0, vy, 0)`` [LU, LU/TU].
    period : float
        Period [TU].
    mu : float
        Mass parameter [-].
    iterations : int
        Newton iterations used by the correction.
    """

    state0: FloatArray
    period: float
    mu: float = MU_EARTH_MOON
    iterations: int = 0

    @property
    def jacobi(self) -> float:
        """Jacobi constant of the orbit [-]."""
        return float(jacobi_constant(self.state0, self.mu))

    def states(self, times: ArrayLike) -> FloatArray:
        """States ``(k, 6)`` at ``times`` [TU] (any values: reduced modulo the period)."""
        ts = np.mod(np.asarray(times, dtype=float), self.period)
        return propagate_cr3bp(self.state0, ts, self.mu)

    def closure(self) -> float:
        """``max |x(T) - x(0)|`` over the six components after one period [LU, LU/TU]."""
        sol = solve_ivp(cr3bp_rhs, (0.0, self.period), self.state0, method="DOP853",
                        rtol=RTOL, atol=ATOL, args=(self.mu,))
        return float(np.max(np.abs(sol.y[:, -1] - self.state0)))


def _half_period_crossing(x0: FloatArray, mu: float, t_guess: float) -> tuple[float, FloatArray]:
    """Integrate state + STM to the x-z plane crossing after ~``t_guess`` [TU]."""

    def event(t: float, y: FloatArray, mu: float) -> float:
        return y[1]

    event.direction = 0.0  # type: ignore[attr-defined]
    y0 = np.concatenate([x0, np.eye(6).ravel()])
    # skip the start (y = 0 there), then catch the first crossing
    t_skip = 0.5 * t_guess
    s1 = solve_ivp(cr3bp_rhs_stm, (0.0, t_skip), y0, method="DOP853", rtol=RTOL, atol=ATOL,
                   args=(mu,))
    s2 = solve_ivp(cr3bp_rhs_stm, (t_skip, 4.0 * t_guess), s1.y[:, -1], method="DOP853",
                   rtol=RTOL, atol=ATOL, args=(mu,), events=event)
    if s2.t_events[0].size == 0:
        raise ConvergenceError("halo correction: no x-z plane crossing found after "
                               f"{4 * t_guess:.3f} TU; the initial guess is not near a halo")
    return float(s2.t_events[0][0]), s2.y_events[0][0]


def correct_halo(x0: float, z0: float, vy0: float, mu: float = MU_EARTH_MOON,
                 period_guess: float = REFERENCE_HALO[3], tol: float = 1e-12,
                 max_iter: int = 30) -> HaloOrbit:
    """Halo orbit through ``(x0, 0, z0)`` by differential correction with ``z0`` fixed.

    Parameters
    ----------
    x0, z0, vy0 : float
        Initial guess on the x-z plane [LU, LU/TU]; ``z0`` is kept.
    mu : float
        Mass parameter.
    period_guess : float
        Approximate period [TU] (to find the half-period crossing).
    tol : float
        Convergence threshold on ``|vx|, |vz|`` at the crossing [LU/TU].
    max_iter : int
        Newton iterations allowed.

    Returns
    -------
    HaloOrbit

    Raises
    ------
    ConvergenceError
    """
    x, vy = float(x0), float(vy0)
    t_half = 0.5 * period_guess
    for it in range(1, max_iter + 1):
        s0 = np.array([x, 0.0, z0, 0.0, vy, 0.0])
        t_half, y = _half_period_crossing(s0, mu, t_half)
        st, P = y[:6], y[6:].reshape(6, 6)
        err = np.array([st[3], st[5]])
        if np.max(np.abs(err)) < tol:
            log.debug("halo converged in %d iterations, residual %.2e", it, np.max(np.abs(err)))
            return HaloOrbit(state0=s0, period=2.0 * t_half, mu=mu, iterations=it)
        acc = cr3bp_rhs(0.0, st, mu)
        M = np.array([[P[3, 0], P[3, 4]], [P[5, 0], P[5, 4]]]) \
            - np.outer([acc[3], acc[5]], [P[1, 0], P[1, 4]]) / st[4]
        dx, dvy = np.linalg.solve(M, -err)
        x, vy = x + dx, vy + dvy
    raise ConvergenceError(f"halo correction did not converge in {max_iter} iterations "
                           f"(z0 = {z0}, last residual {np.max(np.abs(err)):.2e} LU/TU)")


def l2_halo(z0: float = REFERENCE_HALO[1], mu: float = MU_EARTH_MOON,
            max_step: float = 0.005) -> HaloOrbit:
    """Southern/northern L2 halo with out-of-plane amplitude ``z0`` at the x-z crossing [LU].

    Starts from the docs/facts.md orbit and continues in ``z0`` by steps of at most
    ``max_step`` [LU] (natural-parameter continuation), correcting at each step.

    Raises
    ------
    ConfigError
        ``z0`` outside the range this continuation is known to cover (|z0| in 0.01..0.15 LU,
        same sign as the reference for a southern halo).
    """
    if not (math.isfinite(z0) and 0.01 <= abs(z0) <= 0.15):
        raise ConfigError("trajectory.halo_z0_km", z0 * LU / 1e3,
                          f"|z0| between {0.01 * LU / 1e3:.0f} and {0.15 * LU / 1e3:.0f} km")
    xr, zr, vyr, Tr = REFERENCE_HALO
    sign = 1.0 if z0 * zr > 0 else -1.0
    # the northern family is the mirror image z -> -z of the southern one
    orbit = correct_halo(xr, zr, vyr, mu, Tr)
    z_cur = zr
    target = sign * z0
    while abs(target - z_cur) > 1e-15:
        z_next = z_cur + math.copysign(min(max_step, abs(target - z_cur)), target - z_cur)
        s = orbit.state0
        orbit = correct_halo(s[0], z_next, s[4], mu, orbit.period)
        z_cur = z_next
    if sign < 0:
        s = orbit.state0.copy()
        s[2] = -s[2]
        orbit = HaloOrbit(state0=s, period=orbit.period, mu=mu, iterations=orbit.iterations)
    return orbit


def l2_position(mu: float = MU_EARTH_MOON) -> float:
    """x coordinate of the L2 point [LU]: root of ``dOmega/dx = 0`` beyond the Moon."""
    from scipy.optimize import brentq

    def dodx(x: float) -> float:
        return x - (1.0 - mu) / (x + mu) ** 2 - mu / (x - 1.0 + mu) ** 2

    return float(brentq(dodx, 1.0 - mu + 1e-6, 2.0, xtol=1e-15))
