"""Fly-by of a small body: the spacecraft's motion relative to the body, the Sun, the epochs.

Each step and why the straight line is the default: docs/methods.md, "starnav.scenes.flyby".

Technique
---------
1. Fly-by frame: ``y`` the relative velocity at closest approach (CA), ``x`` the body-to-
   spacecraft direction at CA turned by the B-plane angle ``ca_angle_deg``, ``z = x cross y``.
2. Relative motion ``t`` seconds from CA: ``straight`` (default, ``r = d x + v t y``) or the
   Kepler ``hyperbolic`` orbit of the body's ``GM`` (:func:`hyperbola_in_plane`); the
   deflection between them is :func:`deflection_angle` (``~2 GM / (d v^2)``, negligible for the
   packaged bodies).
3. Sun: a fixed inertial direction from the phase at CA and ``sun_azimuth_deg``.
4. Epochs every ``trajectory.cadence_s`` from ``CA + start_s`` to ``CA + end_s``.

The knobs are :class:`~starnav.scenes.schema.FlybyConfig`.

References
----------
D. A. Vallado, *Fundamentals of Astrodynamics and Applications*, 4th ed. (2013), section 2.2.

Index
-----
:class:`Flyby`, :func:`flyby_from_config`, :func:`hyperbola_in_plane`, :func:`deflection_angle`,
:func:`unit_vector_radec`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import AU
from starnav.errors import ConfigError
from starnav.scenes.schema import FlybyConfig
from starnav.typing import FloatArray

#: Newton iterations of the hyperbolic Kepler equation (quadratic convergence from the
#: asinh start: 30 is far more than any double needs).
KEPLER_ITERATIONS = 30


def unit_vector_radec(ra: float, dec: float) -> FloatArray:
    """Unit vector of right ascension ``ra`` and declination ``dec`` [rad] (J2000)."""
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def deflection_angle(gm: float, closest_approach: float, v_inf: float) -> float:
    """Turn of the relative velocity between the asymptotes of the hyperbola [rad]:
    ``2 asin(1 / e)``, ``e = 1 + d v_inf^2 / GM`` (0 for ``GM = 0``)."""
    if gm <= 0:
        return 0.0
    e = 1.0 + closest_approach * v_inf**2 / gm
    return 2.0 * math.asin(1.0 / e)


@dataclass(frozen=True)
class Flyby:
    """A fly-by in SI (module docstring).

    Attributes
    ----------
    epoch_ca : float
        Closest-approach epoch [TDB s past J2000].
    closest_approach : float
        CA distance [m].
    v_inf : float
        Relative speed (straight line) or hyperbolic excess speed [m/s].
    x_hat, y_hat : (3,) float
        Unit vectors: body -> spacecraft at CA, velocity at CA (J2000).
    sun_direction : (3,) float
        Unit vector body -> Sun (J2000), fixed over the fly-by.
    sun_distance : float
        Body-Sun distance [m].
    gm : float
        Body's gravitational parameter [m^3 s^-2] (used by ``hyperbolic``).
    dynamics : {"straight", "hyperbolic"}
    """

    epoch_ca: float
    closest_approach: float
    v_inf: float
    x_hat: FloatArray
    y_hat: FloatArray
    sun_direction: FloatArray
    sun_distance: float = AU
    gm: float = 0.0
    dynamics: str = "straight"

    def __post_init__(self) -> None:
        if self.dynamics not in ("straight", "hyperbolic"):
            raise ConfigError("trajectory.flyby.dynamics", self.dynamics,
                              "'straight' or 'hyperbolic'")
        if self.dynamics == "hyperbolic" and self.gm <= 0:
            raise ConfigError("target.gm_m3_s2", self.gm,
                              "GM > 0 for a hyperbolic fly-by (or dynamics: straight)")

    @property
    def z_hat(self) -> FloatArray:
        """Normal of the fly-by plane, ``x cross y``."""
        return np.cross(self.x_hat, self.y_hat)

    @property
    def sun_position(self) -> FloatArray:
        """Body -> Sun [m] (J2000)."""
        return self.sun_distance * self.sun_direction

    def states(self, epochs_tdb: ArrayLike) -> FloatArray:
        """Spacecraft states relative to the body ``(n, 6)`` [m, m/s], J2000 axes."""
        t = np.atleast_1d(np.asarray(epochs_tdb, float)) - self.epoch_ca
        if self.dynamics == "straight":
            xs = np.full_like(t, self.closest_approach)
            ys = self.v_inf * t
            vx = np.zeros_like(t)
            vy = np.full_like(t, self.v_inf)
        else:
            xs, ys, vx, vy = hyperbola_in_plane(t, self.gm, self.closest_approach, self.v_inf)
        pos = xs[:, None] * self.x_hat + ys[:, None] * self.y_hat
        vel = vx[:, None] * self.x_hat + vy[:, None] * self.y_hat
        return np.hstack([pos, vel])

    def frame_epochs(self, start: float, end: float, cadence: float,
                     frames: int | None = None) -> FloatArray:
        """Epochs ``CA + start + k cadence <= CA + end`` [TDB s], at most ``frames``."""
        n = int(math.floor((end - start) / cadence + 1e-9)) + 1
        if frames is not None:
            n = min(n, int(frames))
        return self.epoch_ca + start + cadence * np.arange(n, dtype=float)

    def phase_angles(self, epochs_tdb: ArrayLike) -> FloatArray:
        """Phase angle at the body centre: between the directions to the Sun and to the
        spacecraft [rad]."""
        r = self.states(epochs_tdb)[:, :3]
        c = (r @ self.sun_direction) / np.linalg.norm(r, axis=1)
        return np.arccos(np.clip(c, -1.0, 1.0))


def hyperbola_in_plane(t: FloatArray, gm: float, rp: float, v_inf: float
                       ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Position and velocity on the Kepler hyperbola in its perifocal axes (periapsis on +x,
    motion towards +y) at times ``t`` [s] from periapsis: ``(x, y, vx, vy)`` [m, m/s]."""
    a = gm / v_inf**2                      # |a|
    e = 1.0 + rp * v_inf**2 / gm
    n = math.sqrt(gm / a**3)
    M = n * np.asarray(t, float)
    H = np.arcsinh(M / e)                  # start: exact when e >> 1
    for _ in range(KEPLER_ITERATIONS):
        f = e * np.sinh(H) - H - M
        H = H - f / (e * np.cosh(H) - 1.0)
    # x = |a| (e - cosh H), written without the cancellation of e - cosh H for e >> 1
    x = rp - a * 2.0 * np.sinh(H / 2.0) ** 2
    q = a * math.sqrt((e - 1.0) * (e + 1.0))
    y = q * np.sinh(H)
    Hdot = n / (e * np.cosh(H) - 1.0)
    return x, y, -a * np.sinh(H) * Hdot, q * np.cosh(H) * Hdot


def flyby_from_config(cfg: FlybyConfig, epoch_ca: float, gm: float = 0.0) -> Flyby:
    """The :class:`Flyby` of a ``trajectory.flyby`` section with CA at ``epoch_ca`` [TDB s]
    and the body's ``gm`` [m^3 s^-2]."""
    si = cfg.to_si()
    y = unit_vector_radec(si.velocity_ra, si.velocity_dec)
    ref = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x0 = ref - (ref @ y) * y
    x0 /= np.linalg.norm(x0)
    z0 = np.cross(x0, y)
    th = si.ca_angle
    x = math.cos(th) * x0 + math.sin(th) * z0
    z = np.cross(x, y)
    a, b = si.phase_at_ca, si.sun_azimuth
    s = math.cos(a) * x + math.sin(a) * (math.cos(b) * y + math.sin(b) * z)
    return Flyby(epoch_ca=float(epoch_ca), closest_approach=si.closest_approach,
                 v_inf=si.v_inf, x_hat=x, y_hat=y, sun_direction=s / np.linalg.norm(s),
                 sun_distance=si.sun_distance, gm=float(gm), dynamics=cfg.dynamics)
