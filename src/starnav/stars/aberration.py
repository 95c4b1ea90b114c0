"""Stellar aberration: the apparent directions of the stars seen by a moving tracker.

1. Observer velocity (:func:`observer_velocity`): the tracker's barycentric velocity from
   DE421 (EMB about the SSB, Moon about the EMB) plus the camera's velocity relative to the
   Moon; a fly-by's body is given the Moon's barycentric motion.
2. Apparent direction (:func:`apparent_directions`): special-relativistic aberration in the
   form of ERFA's ``eraAb`` without its solar-potential term; exact, ``|u'| = 1``.
3. Not included: light deflection by the Sun, stellar parallax, the body's own aberration.

The sky is drawn at apparent directions when ``stars.aberration`` is on, and the tracker
corrects its catalogue with its own velocity knowledge (``stars.aberration_correction``).
Magnitudes of what is and is not modelled: docs/stars.md, "Stellar aberration".

References
----------
ERFA/SOFA ``eraAb`` (IAU SOFA Board, "SOFA Astrometry Tools", 2021, section 3.2).
P. K. Seidelmann (ed.), *Explanatory Supplement to the Astronomical Almanac* (1992), 3.252.

Index
-----
:func:`apparent_directions`, :func:`aberration_shift`, :func:`observer_velocity`,
:data:`MAX_OBSERVER_SPEED`, :data:`ABERRATION_MARGIN`.
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
