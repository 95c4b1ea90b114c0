"""Test-only dynamics: two-body gravity about a Moon moving uniformly about the origin (EMB).

``a = -GM (r - r_M(t)) / |r - r_M(t)|^3`` with ``r_M(t) = r_M0 + v_M (t - t_ref)``; RK4 with the
variational equations (the same scheme as starnav.scenes.dynamics, on a model simple enough to
check by hand). It satisfies both navigation protocols (Dynamics, MoonEphemeris).
"""

from __future__ import annotations

import math

import numpy as np

#: Lunar GM [m^3/s^2] (DE421 value to 6 digits; only consistency matters here).
GM_MOON = 4.902800e12


class MovingMoonTwoBody:
    def __init__(self, gm: float = GM_MOON, r_m0=(3.8e8, 0.0, 0.0), v_m=(0.0, 1.0e3, 0.0),
                 t_ref: float = 0.0, step: float = 60.0) -> None:
        self.gm = gm
        self.r_m0 = np.asarray(r_m0, float)
        self.v_m = np.asarray(v_m, float)
        self.t_ref = t_ref
        self.step = step

    def moon_state(self, t: float) -> np.ndarray:
        return np.concatenate([self.r_m0 + self.v_m * (t - self.t_ref), self.v_m])

    def acceleration(self, t: float, r: np.ndarray) -> np.ndarray:
        d = r - self.moon_state(t)[:3]
        return -self.gm * d / np.linalg.norm(d) ** 3

    def jacobian(self, t: float, r: np.ndarray) -> np.ndarray:
        d = r - self.moon_state(t)[:3]
        n = np.linalg.norm(d)
        return -self.gm * (np.eye(3) / n**3 - 3.0 * np.outer(d, d) / n**5)

    def _f(self, t: float, x: np.ndarray, Phi: np.ndarray):
        A = np.zeros((6, 6))
        A[:3, 3:] = np.eye(3)
        A[3:, :3] = self.jacobian(t, x[:3])
        return np.concatenate([x[3:], self.acceleration(t, x[:3])]), A @ Phi

    def propagate(self, t0: float, x0, t1: float):
        x = np.asarray(x0, float).copy()
        Phi = np.eye(6)
        span = t1 - t0
        if span == 0:
            return x, Phi
        n = max(1, math.ceil(abs(span) / self.step - 1e-9))
        h = span / n
        t = t0
        for _ in range(n):
            k1, K1 = self._f(t, x, Phi)
            k2, K2 = self._f(t + h / 2, x + h / 2 * k1, Phi + h / 2 * K1)
            k3, K3 = self._f(t + h / 2, x + h / 2 * k2, Phi + h / 2 * K2)
            k4, K4 = self._f(t + h, x + h * k3, Phi + h * K3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            Phi = Phi + h / 6 * (K1 + 2 * K2 + 2 * K3 + K4)
            t += h
        return x, Phi


def circular_state(dyn: MovingMoonTwoBody, radius: float, t: float = 0.0,
                   incl: float = 0.4) -> np.ndarray:
    """EMB-centred state on a circular orbit of ``radius`` [m] about the moving Moon."""
    v = math.sqrt(dyn.gm / radius)
    r_rel = radius * np.array([1.0, 0.0, 0.0])
    v_rel = v * np.array([0.0, math.cos(incl), math.sin(incl)])
    return dyn.moon_state(t) + np.concatenate([r_rel, v_rel])


def fix_covariance(rel: np.ndarray, sigma_range: float, sigma_lateral: float) -> np.ndarray:
    """A fix-like covariance: ``sigma_range`` along the line of sight, ``sigma_lateral`` across."""
    u = rel / np.linalg.norm(rel)
    return sigma_lateral**2 * np.eye(3) + (sigma_range**2 - sigma_lateral**2) * np.outer(u, u)
