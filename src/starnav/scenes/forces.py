"""Truth dynamics richer than the filter's: planets, solar radiation pressure with eclipses, J2.

The navigation filter integrates Earth, Moon and Sun point masses
(:class:`~starnav.scenes.dynamics.PointMassModel`); the truth a scenario renders may add what a
real spacecraft feels and the filter does not model, each a switch of ``trajectory.forces``:

1. planets (DE421 barycentres) as point masses, with their indirect term;
2. cannonball solar radiation pressure (``spacecraft`` section), times the lit fraction;
3. conical eclipses by the Earth and the Moon (:func:`shadow_fraction`);
4. J2 of the Earth and the Moon (:func:`j2_acceleration`).

The variational equations keep the point masses' Jacobian only (slower Newton convergence, same
converged arc). The formulas and their magnitudes: docs/methods.md, "starnav.scenes.forces".

References
----------
O. Montenbruck, E. Gill, *Satellite Orbits*, Springer (2000), ss. 3.2 (geopotential, J2),
3.3 (third bodies), 3.4 (solar radiation pressure, conical shadow model).
N. K. Pavlis et al., "The development and evaluation of the Earth Gravitational Model 2008
(EGM2008)", J. Geophys. Res. 117 (2012), B04406: Earth ``J2 = 1.08263e-3``, ``R = 6378.1363
km``.
A. S. Konopliv et al., "The JPL lunar gravity field to spherical harmonic degree 660 from the
GRAIL Primary Mission", J. Geophys. Res. Planets 118 (2013), 1415-1434: lunar ``J2 = -C20
sqrt(5) = 2.0321e-4`` (normalised ``C20 = -9.0880e-5``), ``R = 1738 km``.
G. Kopp, J. L. Lean, "A new, lower value of total solar irradiance", Geophys. Res. Lett. 38
(2011), L01706; IAU 2015 Resolution B3 (nominal 1361 W/m^2).

Index
-----
:class:`TruthForceModel`, :class:`SrpParameters`, :func:`shadow_fraction`,
:func:`j2_acceleration`, :func:`unmodelled_acceleration_psd`, :data:`PLANETS`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError
from starnav.scenes.dynamics import PointMassModel, _norm3
from starnav.scenes.ephemeris import Ephemeris
from starnav.typing import FloatArray

#: Speed of light [m/s] (exact, SI).
SPEED_OF_LIGHT = 299_792_458.0
#: IAU 2015 nominal total solar irradiance at 1 AU [W/m^2] (Resolution B3).
SOLAR_IRRADIANCE_1AU = 1361.0
#: Solar radiation pressure at 1 AU on an absorbing surface [N/m^2].
SOLAR_PRESSURE_1AU = SOLAR_IRRADIANCE_1AU / SPEED_OF_LIGHT
#: IAU 2015 nominal solar radius [m] (Resolution B3).
SUN_RADIUS = 6.957e8
#: Earth: J2 and its reference radius [m] (EGM2008, Pavlis et al. 2012).
EARTH_J2, EARTH_J2_RADIUS = 1.08263e-3, 6_378_136.3
#: Moon: J2 and its reference radius [m] (GRAIL GL0660B, Konopliv et al. 2013).
MOON_J2, MOON_J2_RADIUS = 2.0321e-4, 1_738_000.0
#: Earth's mean equatorial radius for its shadow [m] (the J2 reference radius).
EARTH_SHADOW_RADIUS = EARTH_J2_RADIUS

#: DE421 series of the planets' (system) barycentres, SSB-centred, and their GM constants.
PLANETS: dict[str, tuple[str, str]] = {
    "mercury": ("mercury", "GM1"), "venus": ("venus", "GM2"), "mars": ("mars", "GM4"),
    "jupiter": ("jupiter", "GM5"), "saturn": ("saturn", "GM6"), "uranus": ("uranus", "GM7"),
    "neptune": ("neptune", "GM8"),
}


@dataclass(frozen=True)
class SrpParameters:
    """Cannonball SRP: ``area`` facing the Sun [m^2], ``mass`` [kg], ``reflectivity`` ``C_r``
    [-] (1 absorbing, 2 a face-on mirror)."""

    area: float
    mass: float
    reflectivity: float

    def __post_init__(self) -> None:
        for name, lo in (("area", 0.0), ("mass", 0.0), ("reflectivity", 0.0)):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > lo):
                raise ConfigError(f"spacecraft.{name}", v, "a finite value > 0")

    @property
    def acceleration_1au(self) -> float:
        """SRP acceleration in full Sun at 1 AU, ``P C_r A / m`` [m/s^2]."""
        return SOLAR_PRESSURE_1AU * self.reflectivity * self.area / self.mass


def shadow_fraction(r: ArrayLike, r_sun: ArrayLike, r_body: ArrayLike,
                    body_radius: float) -> FloatArray:
    """Lit fraction of the solar disc seen from ``r`` past a spherical body at ``r_body`` of
    radius ``body_radius`` (module step 3; positions in one frame [m], broadcast over leading
    axes): 1 in full Sun, 0 in the umbra."""
    r = np.asarray(r, float)
    s = np.asarray(r_sun, float) - r
    d = np.asarray(r_body, float) - r
    ns = np.linalg.norm(s, axis=-1)
    nd = np.linalg.norm(d, axis=-1)
    a = np.arcsin(np.clip(SUN_RADIUS / ns, -1.0, 1.0))
    b = np.arcsin(np.clip(body_radius / nd, -1.0, 1.0))
    c = np.arccos(np.clip(np.sum(s * d, axis=-1) / (ns * nd), -1.0, 1.0))
    nu = np.ones(np.broadcast(a, b, c).shape)
    behind = np.sum(s * d, axis=-1) > 0  # the body is on the Sun's side
    umbra = behind & (c <= b - a)
    annular = behind & (c <= a - b) & ~umbra
    partial = behind & (c < a + b) & ~umbra & ~annular
    nu = np.where(umbra, 0.0, nu)
    nu = np.where(annular, 1.0 - (b / a) ** 2, nu)
    if np.any(partial):
        cc = np.where(partial, c, 1.0)
        x = (cc * cc + a * a - b * b) / (2.0 * cc)
        y = np.sqrt(np.clip(a * a - x * x, 0.0, None))
        area = (a * a * np.arccos(np.clip(x / a, -1.0, 1.0))
                + b * b * np.arccos(np.clip((cc - x) / b, -1.0, 1.0)) - cc * y)
        nu = np.where(partial, 1.0 - area / (math.pi * a * a), nu)
    return nu


def j2_acceleration(rho: ArrayLike, pole: ArrayLike, gm: float, j2: float,
                    radius: float) -> FloatArray:
    """J2 acceleration [m/s^2] at ``rho`` from the body's centre [m], ``pole`` its unit
    spin axis (module step 4)."""
    rho = np.asarray(rho, float)
    p = np.asarray(pole, float)
    n2 = np.sum(rho * rho, axis=-1)[..., None]
    z = np.sum(rho * p, axis=-1)[..., None]
    k = -1.5 * j2 * gm * radius**2 / (n2 * n2 * np.sqrt(n2))
    return k * ((1.0 - 5.0 * z * z / n2) * rho + 2.0 * z * p)


#: Correlation time of the accelerations the filter does not model [s]: SRP, tides and J2
#: keep their direction for a day or more, so their effect on the velocity over the filter's
#: memory grows like ``a t``; a white acceleration noise of density ``q`` grows like
#: ``sqrt(q t)``: equal at ``t = tau`` for ``q = a^2 tau`` (:func:`unmodelled_acceleration_psd`).
UNMODELLED_CORRELATION_TIME = 86_400.0


def unmodelled_acceleration_psd(model: TruthForceModel, epochs: ArrayLike,
                                positions: ArrayLike,
                                correlation_time: float = UNMODELLED_CORRELATION_TIME
                                ) -> tuple[float, float]:
    """RMS over ``epochs`` [TDB s] of the acceleration ``model`` adds to the filter's point
    masses at EMB-centred ``positions`` ``(K, 3)`` [m], and the white acceleration noise
    density it is worth, ``q = a_rms^2 tau`` [m/s^2, m^2/s^3]
    (:data:`UNMODELLED_CORRELATION_TIME`): the documented estimate behind
    ``navigation.filter.accel_psd_m2_s3``."""
    t = np.asarray(epochs, float).ravel()
    r = np.asarray(positions, float).reshape(-1, 3)
    a2 = [float(np.sum(np.sum(list(model.force_breakdown(float(tk), rk).values()), axis=0)
                       ** 2)) if model.extra else 0.0 for tk, rk in zip(t, r, strict=True)]
    rms = math.sqrt(float(np.mean(a2))) if a2 else 0.0
    return rms, rms * rms * float(correlation_time)


class TruthForceModel(PointMassModel):
    """Earth, Moon and Sun point masses plus planets, SRP with eclipses and J2 (module
    docstring); the truth arc's force model, a :class:`PointMassModel` to the propagators.

    Parameters
    ----------
    ephemeris : Ephemeris, optional
        Default the shared DE421.
    planets : sequence of str
        Names of :data:`PLANETS` to add as point masses.
    srp : SrpParameters, optional
        Cannonball SRP; None: none.
    eclipses : bool
        Earth and Moon shadows on the SRP.
    j2 : bool
        Earth and Moon J2.
    """

    def __init__(self, ephemeris: Ephemeris | None = None, *, planets: Sequence[str] = (),
                 srp: SrpParameters | None = None, eclipses: bool = True,
                 j2: bool = False) -> None:
        super().__init__(ephemeris)
        unknown = [p for p in planets if p not in PLANETS]
        if unknown:
            raise ConfigError("trajectory.forces.planets", unknown[0],
                              f"one of {', '.join(PLANETS)}")
        self.planets = tuple(dict.fromkeys(planets))
        c = self.ephemeris.constants
        gm_unit = self.ephemeris.au**3 / 86400.0**2
        self.gm_planets = np.array([c[PLANETS[p][1]] * gm_unit for p in self.planets])
        self.srp = srp
        self.eclipses = bool(eclipses)
        self.j2 = bool(j2)
        self._gm_all = np.concatenate([self._gm, self.gm_planets])

    def __repr__(self) -> str:
        return (f"TruthForceModel({self.ephemeris.name}, planets={self.planets}, "
                f"srp={self.srp}, eclipses={self.eclipses}, j2={self.j2})")

    def key(self) -> dict[str, object]:
        k = super().key()
        k.update({"planets": list(self.planets),
                  "srp": None if self.srp is None else [self.srp.area, self.srp.mass,
                                                        self.srp.reflectivity],
                  "eclipses": self.eclipses, "j2": self.j2})
        return k

    @property
    def extra(self) -> bool:
        """Whether anything beyond the filter's point masses is on."""
        return bool(self.planets) or self.srp is not None or self.j2

    # ------------------------------------------------------------------ environment
    def body_positions(self, t: ArrayLike) -> FloatArray:
        """EMB-centred Earth, Moon, Sun, the planets [m], then (with J2) the Moon's pole as a
        unit vector, shape ``(..., 3 + planets [+ 1], 3)``."""
        base = self.ephemeris.positions_emb(t)
        rows = [base]
        if self.planets:
            emb, _ = self.ephemeris.emb_ssb(t)
            rows.append(np.stack([self.ephemeris._chebyshev(PLANETS[p][0], t)[0] * 1e3 - emb
                                  for p in self.planets], axis=-2))
        if self.j2:
            rows.append(self.ephemeris.moon_orientation(t)[..., None, :, 2])
        return np.concatenate(rows, axis=-2)

    def frame_acceleration_from(self, bodies: FloatArray) -> FloatArray:
        a = super().frame_acceleration_from(bodies[..., :3, :])
        if self.planets:
            f = self.moon_fraction
            rE, rM = bodies[..., 0:1, :], bodies[..., 1:2, :]
            rp = bodies[..., 3:3 + len(self.planets), :]
            dE, dM = rE - rp, rM - rp
            w = self.gm_planets[:, None]
            a = a - np.sum(w * ((1.0 - f) * dE / _norm3(dE) + f * dM / _norm3(dM)), axis=-2)
        return a

    # ------------------------------------------------------------------ kernels
    def extra_acceleration(self, r: FloatArray, bodies: FloatArray) -> FloatArray:
        """SRP and J2 at EMB-centred ``r`` [m] (the point masses apart) [m/s^2]."""
        a = np.zeros(np.broadcast_shapes(r.shape, bodies[..., 0, :].shape))
        rE, rM, rS = bodies[..., 0, :], bodies[..., 1, :], bodies[..., 2, :]
        if self.srp is not None:
            d = r - rS
            nd = np.linalg.norm(d, axis=-1)[..., None]
            scale = self.srp.acceleration_1au * (self.ephemeris.au / nd) ** 2
            nu = 1.0
            if self.eclipses:
                nu = (shadow_fraction(r, rS, rE, EARTH_SHADOW_RADIUS)
                      * shadow_fraction(r, rS, rM, MOON_RADIUS))[..., None]
            a = a + nu * scale * d / nd
        if self.j2:
            a = a + j2_acceleration(r - rE, np.array([0.0, 0.0, 1.0]), self.gm_earth,
                                    EARTH_J2, EARTH_J2_RADIUS)
            a = a + j2_acceleration(r - rM, bodies[..., -1, :], self.gm_moon, MOON_J2,
                                    MOON_J2_RADIUS)
        return a

    def _point_masses(self, r: FloatArray, bodies: FloatArray) -> tuple[FloatArray, FloatArray,
                                                                        FloatArray]:
        n = 3 + len(self.planets)
        d = r[..., None, :] - bodies[..., :n, :]
        n2 = np.einsum("...bk,...bk->...b", d, d)
        w = self._gm_all / (n2 * np.sqrt(n2))
        return d, n2, w

    def _accel(self, r: FloatArray, bodies: FloatArray, a_frame: FloatArray) -> FloatArray:
        d, _, w = self._point_masses(r, bodies)
        a = -np.einsum("...b,...bk->...k", w, d) - a_frame
        return a + self.extra_acceleration(r, bodies) if (self.srp or self.j2) else a

    def _accel_jac(self, r: FloatArray, bodies: FloatArray,
                   a_frame: FloatArray) -> tuple[FloatArray, FloatArray]:
        d, n2, w = self._point_masses(r, bodies)
        a = -np.einsum("...b,...bk->...k", w, d) - a_frame
        if self.srp or self.j2:
            a = a + self.extra_acceleration(r, bodies)
        J = 3.0 * np.einsum("...b,...bi,...bj->...ij", w / n2, d, d)
        J = J - w.sum(-1)[..., None, None] * np.eye(3)
        return a, J

    def force_breakdown(self, t: float, r: ArrayLike) -> dict[str, FloatArray]:
        """Each force this model adds to the filter's, at EMB-centred ``r`` [m] and ``t`` [TDB
        s] [m/s^2]: ``planet:<name>`` (its pull on the spacecraft less its pull on the
        barycentre), ``srp``, ``j2_earth``, ``j2_moon``."""
        r = np.asarray(r, float)
        b = self.body_positions(float(t))
        out: dict[str, FloatArray] = {}
        f = self.moon_fraction
        for i, p in enumerate(self.planets):
            rp = b[3 + i]
            gm = self.gm_planets[i]
            on_sc = -gm * (r - rp) / _norm3(r - rp)
            on_emb = -gm * ((1.0 - f) * (b[0] - rp) / _norm3(b[0] - rp)
                            + f * (b[1] - rp) / _norm3(b[1] - rp))
            out[f"planet:{p}"] = on_sc - on_emb
        if self.srp is not None:
            only = TruthForceModel(self.ephemeris, srp=self.srp, eclipses=self.eclipses)
            out["srp"] = only.extra_acceleration(r, self.ephemeris.positions_emb(float(t)))
        if self.j2:
            out["j2_earth"] = j2_acceleration(r - b[0], np.array([0.0, 0.0, 1.0]),
                                              self.gm_earth, EARTH_J2, EARTH_J2_RADIUS)
            out["j2_moon"] = j2_acceleration(r - b[1], b[-1], self.gm_moon, MOON_J2,
                                             MOON_J2_RADIUS)
        return out
