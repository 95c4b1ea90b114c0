"""The Earth's shadow on the Moon: the fraction of the solar disc a surface point sees.

1. Apparent radii ``a = asin(R_sun / |S - P|)`` and ``b = asin(R_shadow / |E - P|)`` and their
   separation ``d``, seen from the surface point ``P``.
2. Flat-sky circles (error ~ ``a^2`` ~ 2e-5): ``d >= a + b`` none occulted; ``d <= b - a`` all;
   otherwise the lens ``A = a^2 acos((d^2 + a^2 - b^2) / (2 d a)) + b^2 acos((d^2 + b^2 -
   a^2) / (2 d b)) - sqrt((-d + a + b)(d + a - b)(d - a + b)(d + a + b)) / 2`` and the
   fraction seen ``1 - A / (pi a^2)`` (uniform disc).
3. Limb-darkened Sun ``I(mu) = 1 - u (1 - mu)``: the occulted light integrated over rings of
   radius ``r``, each inside the Earth's disc over ``2 acos((r^2 + d^2 - b^2) / (2 r d))``
   (Gauss-Legendre in ``r``).

``R_shadow`` is the Earth's mean radius enlarged by Danjon's 1/85 (the almanacs' umbra and
penumbra). Not modelled: the light refracted into the umbra by the Earth's atmosphere (of
order 1e-4 of full brightness); the umbra is black.

References
----------
* A. Danjon (1951), "Les eclipses de Lune par la penombre en 1951", L'Astronomie 65.
* J. Meeus (1998), *Astronomical Algorithms*, 2nd ed., ch. 54 (the shadow radii and the 1/85
  enlargement).
* The circle-circle overlap: e.g. E. W. Weisstein, "Circle-Circle Intersection", MathWorld.

Index
-----
:func:`disc_fraction_visible`, :func:`sunlit_fraction`, :func:`disc_mean_sunlit_fraction`,
:func:`could_be_eclipsed` (the whole body outside the penumbra).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import SUN_RADIUS
from starnav.errors import ConfigError
from starnav.typing import FloatArray

#: Mean radius of the Earth [m] (IUGG; Moritz 2000, Geodetic Reference System 1980).
EARTH_MEAN_RADIUS = 6_371_008.8
#: The shadow's radius: the mean radius enlarged by 1/85 (Danjon 1951; Meeus 1998 ch. 54) [m].
EARTH_SHADOW_RADIUS = EARTH_MEAN_RADIUS * (1.0 + 1.0 / 85.0)
#: Gauss-Legendre nodes over the solar radius for a limb-darkened Sun.
LIMB_DARKENING_NODES = 64


def _lens_area(a: FloatArray, b: FloatArray, d: FloatArray) -> FloatArray:
    """Overlap area of circles of radii ``a`` and ``b`` at centre distance ``d`` (any units)."""
    a, b, d = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float),
                                  np.asarray(d, float))
    out = np.zeros(a.shape)
    full = d <= np.abs(b - a)
    out[full] = math.pi * np.minimum(a, b)[full] ** 2
    part = ~full & (d < a + b)
    if np.any(part):
        ap, bp, dp = a[part], b[part], d[part]
        c1 = np.clip((dp**2 + ap**2 - bp**2) / (2.0 * dp * ap), -1.0, 1.0)
        c2 = np.clip((dp**2 + bp**2 - ap**2) / (2.0 * dp * bp), -1.0, 1.0)
        k = (-dp + ap + bp) * (dp + ap - bp) * (dp - ap + bp) * (dp + ap + bp)
        out[part] = (ap**2 * np.arccos(c1) + bp**2 * np.arccos(c2)
                     - 0.5 * np.sqrt(np.maximum(k, 0.0)))
    return out


def disc_fraction_visible(sun_radius: ArrayLike, occulter_radius: ArrayLike,
                          separation: ArrayLike, limb_darkening: float = 0.0) -> FloatArray:
    """Fraction of the solar disc's light not hidden by an occulting disc (module steps 2-3).

    Parameters
    ----------
    sun_radius, occulter_radius : array_like
        Apparent radii of the Sun and of the occulter [rad] (> 0).
    separation : array_like
        Angle between their centres [rad].
    limb_darkening : float
        Linear limb-darkening coefficient ``u`` of the Sun in ``[0, 1]`` (0: uniform disc).

    Returns
    -------
    ndarray
        In ``[0, 1]``: 1 outside the penumbra, 0 in the umbra.
    """
    u = float(limb_darkening)
    if not 0.0 <= u <= 1.0:
        raise ConfigError("sun limb darkening u", limb_darkening, "a coefficient in [0, 1]")
    a, b, d = np.broadcast_arrays(np.asarray(sun_radius, float),
                                  np.asarray(occulter_radius, float),
                                  np.asarray(separation, float))
    if u == 0.0:
        return np.clip(1.0 - _lens_area(a, b, d) / (math.pi * a**2), 0.0, 1.0)
    # rings of the solar disc: r = a x, weight I(mu) 2 pi r dr, share inside the occulter
    x, w = np.polynomial.legendre.leggauss(LIMB_DARKENING_NODES)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    ar, br, dr = a[..., None], b[..., None], d[..., None]
    r = ar * x
    with np.errstate(divide="ignore", invalid="ignore"):
        c = (r**2 + dr**2 - br**2) / (2.0 * r * dr)
    inside = np.where(dr <= 0.0, np.where(r < br, 1.0, 0.0),
                      np.arccos(np.clip(np.nan_to_num(c, nan=1.0), -1.0, 1.0)) / math.pi)
    intensity = 1.0 - u * (1.0 - np.sqrt(np.clip(1.0 - x**2, 0.0, 1.0)))
    total = np.sum(w * intensity * x)                        # int_0^1 I(x) x dx
    hidden = np.sum(w * intensity * x * inside, axis=-1)
    return np.clip(1.0 - hidden / total, 0.0, 1.0)


def sunlit_fraction(points: ArrayLike, sun_position: ArrayLike, earth_position: ArrayLike,
                    limb_darkening: float = 0.0,
                    shadow_radius: float = EARTH_SHADOW_RADIUS) -> FloatArray:
    """Fraction of the solar irradiance each point receives past the Earth (module docstring).

    Parameters
    ----------
    points : (..., 3) array_like
        Surface points [m], in the frame of the two positions (e.g. Moon-centred inertial).
    sun_position, earth_position : (3,) array_like
        Centres of the Sun and the Earth in that frame [m].
    limb_darkening : float
        The Sun's linear limb-darkening coefficient (0: uniform disc).
    shadow_radius : float
        Radius of the occulting Earth [m] (default :data:`EARTH_SHADOW_RADIUS`).

    Returns
    -------
    ndarray, shape ``points.shape[:-1]``
        In ``[0, 1]``.
    """
    p = np.asarray(points, float)
    to_sun = np.asarray(sun_position, float) - p
    to_earth = np.asarray(earth_position, float) - p
    ds = np.linalg.norm(to_sun, axis=-1)
    de = np.linalg.norm(to_earth, axis=-1)
    a = np.arcsin(np.clip(SUN_RADIUS / ds, 0.0, 1.0))
    b = np.arcsin(np.clip(shadow_radius / de, 0.0, 1.0))
    cosd = np.einsum("...i,...i->...", to_sun, to_earth) / (ds * de)
    sind = np.linalg.norm(np.cross(to_sun, to_earth), axis=-1) / (ds * de)
    sep = np.arctan2(sind, cosd)
    return disc_fraction_visible(a, b, sep, limb_darkening)


def could_be_eclipsed(body_radius: float, sun_position: ArrayLike, earth_position: ArrayLike,
                      shadow_radius: float = EARTH_SHADOW_RADIUS) -> bool:
    """False when every point within ``body_radius`` of the origin (the body's centre) is
    outside the Earth's penumbra: a cheap, conservative test at the centre (from any point of
    the body the Earth's direction moves by at most ``asin(R / |E|)``, its apparent radius and
    the Sun's by less)."""
    s = np.asarray(sun_position, float)
    e = np.asarray(earth_position, float)
    de = float(np.linalg.norm(e))
    if de <= body_radius + shadow_radius:
        return True
    ds = float(np.linalg.norm(s))
    a = math.asin(min(SUN_RADIUS / (ds - body_radius), 1.0))
    b = math.asin(min(shadow_radius / (de - body_radius), 1.0))
    sep = math.atan2(float(np.linalg.norm(np.cross(s, e))), float(s @ e))
    shift = math.asin(min(body_radius / de, 1.0)) + math.asin(min(body_radius / ds, 1.0))
    return sep - shift < a + b


def visible_disc_points(camera_position: ArrayLike, radius: float, n: int = 48
                        ) -> FloatArray:
    """Points of the sphere of ``radius`` about the origin seen from ``camera_position``, one
    per cell of an ``n x n`` grid over the apparent disc (orthographic: uniform in projected
    area) [m], shape ``(m, 3)``."""
    c = np.asarray(camera_position, float)
    v = c / np.linalg.norm(c)
    e1 = np.cross(v, [0.0, 0.0, 1.0] if abs(v[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(v, e1)
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(g, g)
    keep = x**2 + y**2 < 1.0
    x, y = x[keep], y[keep]
    z = np.sqrt(1.0 - x**2 - y**2)
    return radius * (x[:, None] * e1 + y[:, None] * e2 + z[:, None] * v)


def disc_mean_sunlit_fraction(camera_position: ArrayLike, radius: float,
                              sun_position: ArrayLike, earth_position: ArrayLike,
                              limb_darkening: float = 0.0) -> float:
    """The sunlit fraction averaged over the body's visible disc (uniform in projected area;
    the whole disc, lit or not): 1 outside the penumbra, 0 with the disc in the umbra. The
    eclipse figure a frame's truth carries."""
    if not could_be_eclipsed(radius, sun_position, earth_position):
        return 1.0
    pts = visible_disc_points(camera_position, radius)
    return float(np.mean(sunlit_fraction(pts, sun_position, earth_position, limb_darkening)))
