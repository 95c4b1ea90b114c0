"""Stellar aberration: the apparent directions of the stars seen by a moving tracker.

Technique
---------
1. **Observer velocity.** The tracker's velocity relative to the solar-system barycentre
   (SSB), ICRF axes, at the frame's epoch from the project's DE421 ephemeris
   (:class:`~starnav.scenes.ephemeris.Ephemeris`): the Earth-Moon barycentre about the SSB,
   plus the Moon about the EMB, plus the camera's velocity relative to the Moon
   (:attr:`~starnav.geometry.FrameGeometry.camera_velocity`):
   ``v = v_EMB/SSB(t) + v_Moon/EMB(t) + v_cam/Moon``. Static frames (epoch 0 = J2000.0, camera
   at rest relative to the Moon) get the Moon's barycentric velocity at J2000.0. A small-body
   fly-by has no orbit for its body: the body is given the Moon's barycentric motion (the
   drawing and the correction use the same velocity, so the solved attitude stays unbiased).
2. **Apparent direction.** Special-relativistic aberration of light (the Lorentz
   transformation of the photon's direction), in the form of ERFA's ``eraAb`` without its
   ``2 GM_sun / (c^2 s)`` term (a ~1e-12 rad effect of the Sun's potential on the observer's
   clock):

   ``u' = (u / gamma + (1 + (u . beta) / (1 + 1 / gamma)) beta) / (1 + u . beta)``,
   ``beta = v / c``, ``gamma = 1 / sqrt(1 - beta^2)``.

   It is exact in special relativity (``|u'| = 1`` identically); the shift towards the apex
   ``beta`` is ``dtheta`` with ``cos(theta') = (cos(theta) + beta) / (1 + beta cos(theta))``,
   ``dtheta = beta sin(theta) - (beta^2 / 4) sin(2 theta) + O(beta^3)``: at the Earth's
   29.8 km/s, ``beta = 9.94e-5`` rad = 20.5 arcsec at ``theta = 90 deg`` (the constant of
   aberration, 20.49552 arcsec, IAU 1976), the second-order term at most 1.0 mas.
3. **Not included.** Light deflection by the Sun (``4.07 mas cot(E / 2)`` at solar elongation
   ``E``: 4 mas at 90 deg, 1.75 arcsec at the limb), stellar parallax (< 0.8 arcsec,
   Proxima Cen), and the body's own aberration (the rendered Moon is drawn at its geometric
   direction: its apparent direction differs by the camera's velocity relative to the Moon,
   ``|v_cam/Moon| / c`` = 0.69 arcsec per km/s: 0.64-0.93 arcsec at LUMIO's
   0.93-1.35 km/s).

Use
---
The sky is drawn at apparent directions when ``stars.aberration`` is on (the default;
:func:`starnav.stars.field.frame_stars`), and the tracker corrects its catalogue to apparent
directions with its own knowledge of its velocity (``stars.aberration_correction``; the
solver's ``observer_velocity``). A velocity knowledge error ``dv`` leaves an attitude error of at
most ``|dv| / c`` = 0.69 arcsec per km/s; the navigation filter's velocity (m/s) gives mas.

Example
-------
>>> import numpy as np
>>> u = np.array([[1.0, 0.0, 0.0]])
>>> up = apparent_directions(u, [0.0, 29_800.0, 0.0])
>>> round(float(np.degrees(np.arccos(up[0] @ u[0]))) * 3600.0, 2)   # arcsec
20.5

Reference: ERFA/SOFA ``eraAb`` (IAU SOFA Board, "SOFA Astrometry Tools", 2021, section 3.2);
P. K. Seidelmann (ed.), *Explanatory Supplement to the Astronomical Almanac* (1992), 3.252.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import SPEED_OF_LIGHT
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.scenes.ephemeris import Ephemeris
from starnav.typing import FloatArray

#: Largest barycentric speed a star tracker in the Earth-Moon system reaches [m/s]
#: (Earth's orbit 30.3 km/s at perihelion + a few km/s of its own): the cone margin of queries.
MAX_OBSERVER_SPEED = 45_000.0
#: Aberration margin of cone queries [rad] (``MAX_OBSERVER_SPEED / c``, 31 arcsec).
ABERRATION_MARGIN = MAX_OBSERVER_SPEED / SPEED_OF_LIGHT


def _velocity(velocity: ArrayLike, field: str) -> FloatArray:
    v = np.asarray(velocity, float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(field, np.asarray(velocity).tolist(), "a finite 3-vector [m/s]")
    if float(np.linalg.norm(v)) >= 0.1 * SPEED_OF_LIGHT:
        raise ConfigError(field, v.tolist(), "a speed below 0.1 c (a spacecraft's) [m/s]")
    return v


def apparent_directions(directions: ArrayLike, velocity: ArrayLike) -> FloatArray:
    """Apparent unit vectors of catalogue (astrometric, SSB) unit vectors (module step 2).

    Parameters
    ----------
    directions : (..., 3) array
        Unit vectors towards the stars, ICRF axes [-].
    velocity : (3,) array
        The observer's barycentric velocity, ICRF axes [m/s].

    Returns
    -------
    (..., 3) array
        Unit vectors in which the moving observer sees the stars [-].
    """
    v = _velocity(velocity, "stars.observer_velocity")
    u = np.asarray(directions, float)
    beta = v / SPEED_OF_LIGHT
    b2 = float(beta @ beta)
    if b2 == 0.0:
        return u.copy()
    inv_gamma = math.sqrt(1.0 - b2)
    ub = u @ beta
    p = u * inv_gamma + (1.0 + ub / (1.0 + inv_gamma))[..., None] * beta
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def aberration_shift(theta: ArrayLike, speed: float) -> FloatArray:
    """Exact shift [rad] towards the apex of a star ``theta`` [rad] from the apex, seen at
    ``speed`` [m/s]: ``theta - acos((cos theta + beta) / (1 + beta cos theta))`` (step 2)."""
    t = np.asarray(theta, float)
    b = float(speed) / SPEED_OF_LIGHT
    return t - np.arccos(np.clip((np.cos(t) + b) / (1.0 + b * np.cos(t)), -1.0, 1.0))


def observer_velocity(geom: FrameGeometry, ephemeris: Ephemeris | None = None) -> FloatArray:
    """The camera's barycentric velocity [m/s], ICRF axes, at ``geom.epoch_tdb`` (step 1):
    ``v_EMB/SSB + v_Moon/EMB`` (DE421) ``+ geom.camera_velocity``."""
    eph = ephemeris if ephemeris is not None else Ephemeris.default()
    t = float(geom.epoch_tdb)
    _, v_emb = eph.emb_ssb(t)
    v_moon = eph.state("moon", t, center="emb")[3:]
    return np.asarray(v_emb, float).reshape(3) + v_moon + geom.camera_velocity
