"""The Moon's limb as the terrain makes it: how far the apparent limb departs from the sphere.

For a view direction ``v`` and an image-plane direction ``e``, the apparent radius is the
highest terrain near the limb plane, ``r(e) = max_theta (R + h(cos(theta) e + sin(theta) v))
cos(theta)``; its departure from ``R``, the *limb height*, is what a limb-based fix reads as
noise (its spread) and bias (its mean). :func:`limb_topography` samples it over random views
and position angles of a DEM. The navigation chain (:mod:`starnav.navigation.refine`) takes
the spread over one window's arc as a refined point's model error, and the part shared by the
whole lit limb as a range error of the fix. Its values on LOLA LDEM_4: docs/dem.md.

Index
-----
:func:`limb_topography`, :func:`limb_topography_for`, :class:`LimbTopography`,
:func:`limb_heights`, :data:`ARC_WIDTHS_RAD`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from starnav.cache import BoundedCache
from starnav.constants import MOON_RADIUS
from starnav.dem.grid import DemGrid, body_to_selenographic
from starnav.dem.load import as_dem_config, load_dem

#: Arc widths [rad of position angle] at which the averaged limb-height spread is tabulated.
ARC_WIDTHS_RAD = tuple(math.radians(d) for d in (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0,
                                                   128.0, 180.0))


@dataclass(frozen=True)
class LimbTopography:
    """Statistics of the limb height over random views (units in the names).

    ``std_arc_m[k]`` is the spread of the limb height *averaged over an arc* of
    ``ARC_WIDTHS_RAD[k]`` of position angle: what an edge fit over a window of that arc reads
    (the fit's offset at the window centre, with a free tilt, is the window's mean edge).
    """

    mean_m: float
    std_m: float
    p05_m: float
    p95_m: float
    samples: int
    radius_m: float
    std_arc_m: tuple[float, ...] = ()
    std_arc_local_m: tuple[float, ...] = ()
    common_std_m: float = 0.0

    @property
    def sigma_fraction(self) -> float:
        """``std / R``: the point-limb model error as a fraction of the disc radius [-]."""
        return self.std_m / self.radius_m

    @property
    def common_fraction(self) -> float:
        """``std / R`` of the limb height averaged over a half circle (the lit limb): the part
        every point of a frame shares, an error of the disc's apparent radius [-]."""
        return self.common_std_m / self.radius_m

    def sigma_fraction_over(self, arc_rad: float, *, local: bool = True) -> float:
        """``std / R`` of the limb height averaged over ``arc_rad`` of position angle (log-log
        interpolation in :data:`ARC_WIDTHS_RAD`, clamped at its ends); ``local``: of its part
        that departs from the half-circle mean (what is independent from window to window)."""
        table = self.std_arc_local_m if local else self.std_arc_m
        if not table:
            return self.sigma_fraction
        x = np.log(np.asarray(ARC_WIDTHS_RAD))
        y = np.log(np.maximum(np.asarray(table), 1e-3))
        return float(np.exp(np.interp(math.log(max(arc_rad, 1e-9)), x, y))) / self.radius_m


def limb_heights(dem: DemGrid, view_dirs: np.ndarray, n_position_angles: int = 90,
                 radius_m: float = MOON_RADIUS) -> np.ndarray:
    """Limb heights [m], ``(len(view_dirs), n_position_angles)``: the apparent radius in each
    image-plane direction minus ``radius_m`` (module formula), for body-fixed unit view
    directions (towards the observer)."""
    v = np.asarray(view_dirs, float).reshape(-1, 3)
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    lo, hi = (float(x) for x in dem.value_range)
    theta_max = math.sqrt(2.0 * max(hi - lo, 1.0) / radius_m)
    step = math.radians(1.0 / dem.pixels_per_degree)   # one DEM cell
    theta = np.arange(-theta_max, theta_max + step, step)
    # an orthonormal image-plane basis per view
    a = np.where(np.abs(v[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(v, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(v, e1)
    psi = np.linspace(0.0, 2.0 * math.pi, n_position_angles, endpoint=False)
    e = (np.cos(psi)[None, :, None] * e1[:, None, :]
         + np.sin(psi)[None, :, None] * e2[:, None, :])             # (V, P, 3)
    p = (np.cos(theta)[None, None, :, None] * e[:, :, None, :]
         + np.sin(theta)[None, None, :, None] * v[:, None, None, :])  # (V, P, T, 3)
    lat, lon, _ = body_to_selenographic(p.reshape(-1, 3), radius=1.0)
    h = np.asarray(dem.sample(lat, lon), float).reshape(p.shape[:3])
    r = (radius_m + h) * np.cos(theta)[None, None, :]
    return r.max(axis=2) - radius_m


def limb_topography(dem: DemGrid, n_views: int = 60, n_position_angles: int = 720,
                    seed: int = 0, radius_m: float = MOON_RADIUS) -> LimbTopography:
    """Mean, spread and percentiles of the limb height over ``n_views`` view directions
    uniform on the sphere (seeded) and ``n_position_angles`` per view, and the spread of its
    circular moving average over each of :data:`ARC_WIDTHS_RAD`."""
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((n_views, 3))
    h = limb_heights(dem, v, n_position_angles, radius_m)
    step = 2.0 * math.pi / n_position_angles

    def moving_mean(x: np.ndarray, width: float) -> np.ndarray:
        # centred circular moving average over ``width`` of position angle
        k = max(1, int(round(width / step)))
        c = np.cumsum(np.concatenate([x, x[:, :k]], axis=1), axis=1)
        return np.roll((c[:, k:] - c[:, :-k]) / k, k // 2, axis=1)

    common = moving_mean(h, math.pi)          # the half-circle mean around each direction
    local = h - common
    arc = [float(moving_mean(h, w).std()) for w in ARC_WIDTHS_RAD]
    arc_local = [float(moving_mean(local, w).std()) for w in ARC_WIDTHS_RAD]
    f = h.ravel()
    return LimbTopography(mean_m=float(f.mean()), std_m=float(f.std()),
                          p05_m=float(np.percentile(f, 5)), p95_m=float(np.percentile(f, 95)),
                          samples=int(f.size), radius_m=float(radius_m), std_arc_m=tuple(arc),
                          std_arc_local_m=tuple(arc_local), common_std_m=float(common.std()))


#: Statistics per DEM configuration (small records; a DEM is loaded to measure them).
_BY_CONFIG: BoundedCache[str, LimbTopography] = BoundedCache(16)


def limb_topography_for(dem_config: object) -> LimbTopography:
    """:func:`limb_topography` of the DEM a scenario's ``moon.dem`` section loads (cached per
    configuration; the packaged LOLA LDEM_4 by default)."""
    cfg = as_dem_config(dem_config)  # type: ignore[arg-type]
    return _BY_CONFIG.get_or_make(cfg.model_dump_json(), lambda: limb_topography(load_dem(cfg)))
