"""The procedural Moon: cratered terrain, fractal roughness and a maria/highlands albedo map.

When no DEM is given, starnav makes a seeded Moon with the statistics that matter to a
navigation camera; the same seed gives the same world at any resolution (a finer grid adds
smaller craters and shorter wavelengths). The laws and their sources in full: docs/methods.md,
"starnav.dem.procedural".

Technique
---------
1. Crater catalogue: truncated power-law cumulative size-frequency distribution, drawn per
   diameter octave from its own seeded stream.
2. Morphology: Pike (1977) depth, rim and floor laws; parabolic simple craters, complex ones
   with a flat floor and central peak; ejecta thinning as ``(r/R)^-3``.
3. Maria: near-side basins plus noise, thresholded to ``mare_fraction``; older craters stamped,
   plains flooded, younger craters stamped.
4. Roughness: octaves of 3-D value noise on the sphere, RMS ``~ lambda^H``.
5. Albedo: highlands and maria blended by the mare mask, a texture, bright young ejecta.

The knobs are :class:`~starnav.dem.schema.ProceduralDemConfig`.

References
----------
R. J. Pike, "Size-dependence in the shape of fresh impact craters on the Moon", in *Impact and
Explosion Cratering* (1977) 489-509. H. J. Melosh, *Impact Cratering* (1989), ch. 6, 8, 10.
G. Neukum, B. A. Ivanov and W. K. Hartmann, Space Sci. Rev. 96 (2001) 55-86.
T. R. McGetchin, M. Settle and J. W. Head, EPSL 20 (1973) 226.
M. A. Rosenburg et al., J. Geophys. Res. 116 (2011) E02001.

Index
-----
:func:`procedural_moon`, :class:`ProceduralMoon`; :func:`crater_catalogue`,
:class:`CraterCatalogue`, :class:`CraterMorphology`, :func:`stamp_craters`,
:func:`sample_power_law`, :func:`power_law_slope_mle`; :func:`value_noise_3d`,
:func:`gradient_noise_3d`, :func:`fractal_field`, :func:`mare_mask`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from starnav.cache import BoundedCache
from starnav.constants import MOON_RADIUS
from starnav.dem.grid import HALF_PI, AlbedoGrid, DemGrid
from starnav.dem.schema import ProceduralDemConfig
from starnav.seeding import WORLD_BASINS, WORLD_CRATERS, WORLD_FRACTAL, generator, seed_u64
from starnav.typing import FloatArray

logger = logging.getLogger(__name__)

#: Smallest diameter octave edge [m]; octaves are ``CRATER_OCTAVE_BASE * 2^k``.
CRATER_OCTAVE_BASE = 500.0
#: Default smallest crater, in grid cells.
MIN_CRATER_CELLS = 3.0
#: Ejecta taper: from ``EJECTA_TAPER[0]`` to ``EJECTA_TAPER[1]`` crater radii [-].
EJECTA_TAPER = (2.5, 4.0)
#: Shortest roughness wavelength, in grid cells.
MIN_ROUGHNESS_CELLS = 4.0
#: Fraction of the old relief kept at the floor of a mare (ghost craters) [-].
MARE_GHOST = 0.1
#: Longest wavelength of the albedo texture [m].
ALBEDO_TEXTURE_MAX_WAVELENGTH = 200_000.0
#: Fraction of craters (the youngest) with bright ejecta [-].
FRESH_FRACTION = 0.02


# ------------------------------------------------------------------------- morphology
@dataclass(frozen=True)
class CraterMorphology:
    """Fresh-crater shape laws (Pike 1977), diameters in metres inside.

    Parameters
    ----------
    transition_diameter : float
        Simple-to-complex transition [m].
    simple_depth_ratio : float
        Simple craters: rim-crest-to-floor depth / diameter [-].
    complex_depth_coeff_km, complex_depth_exponent : float
        Complex craters: ``d[km] = coeff * D[km]^exponent``.
    ejecta_exponent : float
        Ejecta thickness ``~ (r/R)^-exponent`` [-].
    central_peak_fraction : float
        Central peak height / depth for complex craters [-].
    """

    transition_diameter: float = 15_000.0
    simple_depth_ratio: float = 0.196
    complex_depth_coeff_km: float = 1.044
    complex_depth_exponent: float = 0.301
    ejecta_exponent: float = 3.0
    central_peak_fraction: float = 0.3

    @classmethod
    def from_config(cls, cfg: ProceduralDemConfig) -> CraterMorphology:
        return cls(transition_diameter=cfg.transition_diameter_km * 1e3,
                   simple_depth_ratio=cfg.simple_depth_ratio,
                   complex_depth_coeff_km=cfg.complex_depth_coeff_km,
                   complex_depth_exponent=cfg.complex_depth_exponent,
                   ejecta_exponent=cfg.ejecta_exponent)

    def is_complex(self, diameter: float) -> bool:
        return diameter > self.transition_diameter

    def depth(self, diameter: float) -> float:
        """Rim-crest-to-floor depth [m] of a crater of ``diameter`` [m]."""
        if self.is_complex(diameter):
            return 1e3 * self.complex_depth_coeff_km * (diameter / 1e3) ** \
                self.complex_depth_exponent
        return self.simple_depth_ratio * diameter

    def rim_height(self, diameter: float) -> float:
        """Rim height above the surroundings [m] (Pike 1977), capped at 0.8 x depth."""
        dk = diameter / 1e3
        h = 0.236 * dk**0.399 if self.is_complex(diameter) else 0.036 * dk**1.014
        return min(1e3 * h, 0.8 * self.depth(diameter))

    def floor_diameter(self, diameter: float) -> float:
        """Flat-floor diameter [m]: 0 for simple craters, ``0.187 D^1.249`` km (<= 0.8 D)."""
        if not self.is_complex(diameter):
            return 0.0
        return min(1e3 * 0.187 * (diameter / 1e3) ** 1.249, 0.8 * diameter)

    def profile(self, r: FloatArray, diameter: float) -> FloatArray:
        """Height [m] relative to the pre-impact level at distance ``r`` [m] from the centre.

        Inside the rim: floor at ``h_rim - d``, parabolic wall up to ``h_rim`` at ``r = R``;
        outside: ejecta ``h_rim (r/R)^-n`` tapered to 0 between 2.5 R and 4 R.
        """
        R = 0.5 * diameter
        d = self.depth(diameter)
        h = self.rim_height(diameter)
        rf = 0.5 * self.floor_diameter(diameter)
        r = np.asarray(r, dtype=float)
        out = np.empty_like(r)
        inside = r <= R
        ri = r[inside]
        t = np.clip((ri - rf) / (R - rf), 0.0, 1.0)
        wall = (h - d) + d * t * t
        if rf > 0.0:
            sig = 0.05 * diameter
            wall = wall + self.central_peak_fraction * d * np.exp(-0.5 * (ri / sig) ** 2)
        out[inside] = wall
        ro = r[~inside] / R
        t0, t1 = EJECTA_TAPER
        s = np.clip((t1 - ro) / (t1 - t0), 0.0, 1.0)
        taper = s * s * (3.0 - 2.0 * s)
        out[~inside] = h * ro ** (-self.ejecta_exponent) * taper
        return out


# ------------------------------------------------------------------------- catalogue
@dataclass(frozen=True)
class CraterCatalogue:
    """Craters of a procedural Moon, in stamping order (oldest first).

    Attributes
    ----------
    lat, lon : (n,) arrays
        Centres [rad].
    diameter : (n,) array
        Rim-crest diameters [m].
    post_mare : (n,) bool array
        Younger than the mare flooding.
    age_rank : (n,) array
        0 = oldest ... 1 = youngest [-].
    """

    lat: FloatArray
    lon: FloatArray
    diameter: FloatArray
    post_mare: NDArray[np.bool_]
    age_rank: FloatArray

    def __len__(self) -> int:
        return int(self.diameter.size)


def sample_power_law(rng: np.random.Generator, n: int, d_lo: float, d_hi: float,
                     slope: float) -> FloatArray:
    """``n`` diameters with cumulative distribution ``N(>=D) ~ D^-slope`` on ``[d_lo, d_hi)``.

    Inverse-CDF sampling of the truncated Pareto law (any length unit).
    """
    u = rng.random(n)
    r = (d_lo / d_hi) ** slope
    return d_lo * (1.0 - u * (1.0 - r)) ** (-1.0 / slope)


def power_law_slope_mle(d: FloatArray, d_lo: float, d_hi: float) -> float:
    """Maximum-likelihood cumulative slope ``b`` of diameters drawn on ``[d_lo, d_hi)``.

    Solves the score equation of the truncated Pareto law (Aban, Meerschaert & Panorska 2006,
    JASA 101, 270) by bracketing; its standard error is about ``b / sqrt(n)``.
    """
    from scipy.optimize import brentq

    d = np.asarray(d, dtype=float)
    n = d.size
    s = float(np.sum(np.log(d / d_lo)))
    lr = math.log(d_lo / d_hi)  # < 0

    def score(b: float) -> float:
        rb = math.exp(b * lr)
        return n / b - s + n * rb * lr / (1.0 - rb)

    return float(brentq(score, 1e-3, 20.0))


def crater_catalogue(cfg: ProceduralDemConfig, d_min: float,
                     radius: float = MOON_RADIUS) -> CraterCatalogue:
    """Draw the crater population of the procedural Moon for diameters ``>= d_min`` [m].

    Each diameter octave ``[0.5 km 2^k, 0.5 km 2^(k+1))`` has its own random stream (seeded by
    ``cfg.seed`` and ``k``), so the craters above any ``d_min`` do not depend on ``d_min``.
    """
    d_max = cfg.crater_max_diameter_km * 1e3
    b = cfg.sfd_slope
    n1 = cfg.crater_density_1km_km2  # per km^2, for D in km
    area_km2 = 4.0 * math.pi * (radius / 1e3) ** 2
    base = CRATER_OCTAVE_BASE
    if d_min < base:
        base = base * 2.0 ** math.floor(math.log2(d_min / base))
    p_post = (min(1.0, cfg.mare_crater_density_1km_km2 / n1) if n1 > 0 else 0.0)
    parts: list[tuple[FloatArray, ...]] = []
    k = 0
    while base * 2**k < d_max and n1 > 0:
        lo, hi = base * 2**k, min(base * 2 ** (k + 1), d_max)
        k_id = round(math.log2(lo / CRATER_OCTAVE_BASE) * 16)  # stable id of the octave
        k += 1
        if hi <= d_min:
            continue
        rng = generator(cfg.seed, WORLD_CRATERS, k_id + 10_000)
        mean = n1 * area_km2 * ((lo / 1e3) ** -b - (hi / 1e3) ** -b)
        n = int(rng.poisson(mean))
        diam = sample_power_law(rng, n, lo, hi, b)
        lat = np.arcsin(2.0 * rng.random(n) - 1.0)
        lon = 2.0 * math.pi * rng.random(n) - math.pi
        post = rng.random(n) < p_post
        age = rng.random(n)
        keep = diam >= d_min
        parts.append((lat[keep], lon[keep], diam[keep], post[keep], age[keep]))
    if parts:
        lat, lon, diam, post, age = (np.concatenate(p) for p in zip(*parts, strict=True))
    else:
        lat = lon = diam = age = np.zeros(0)
        post = np.zeros(0, dtype=bool)
    # stamping order: pre-mare oldest first, then post-mare oldest first
    order = np.lexsort((age, post))
    return CraterCatalogue(lat=lat[order], lon=lon[order], diameter=diam[order],
                           post_mare=post[order].astype(bool), age_rank=age[order])


# ------------------------------------------------------------------------- noise
_M1 = np.uint64(0x9E3779B185EBCA87)
_M2 = np.uint64(0xC2B2AE3D27D4EB4F)
_M3 = np.uint64(0x165667B19E3779F9)
_S1 = np.uint64(0xBF58476D1CE4E5B9)
_S2 = np.uint64(0x94D049BB133111EB)


def _hash_unit(ix: NDArray[np.int64], iy: NDArray[np.int64], iz: NDArray[np.int64],
               seed: np.uint64) -> FloatArray:
    """Deterministic value in [-1, 1) per integer lattice point (splitmix64 finaliser)."""
    with np.errstate(over="ignore"):
        h = (ix.view(np.uint64) * _M1) ^ (iy.view(np.uint64) * _M2) ^ \
            (iz.view(np.uint64) * _M3) ^ seed
        h ^= h >> np.uint64(30)
        h *= _S1
        h ^= h >> np.uint64(27)
        h *= _S2
        h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) * (2.0 / 2.0**53) - 1.0


def value_noise_3d(p: FloatArray, seed: int) -> FloatArray:
    """Smooth 3-D value noise at points ``p`` ``(..., 3)`` in lattice units; RMS ~ 0.3.

    Trilinear interpolation of hashed lattice values with the quintic fade
    ``6t^5 - 15t^4 + 10t^3`` (Perlin 2002), so the field is C2.
    """
    s = np.uint64(seed)
    f = np.floor(p)
    i = f.astype(np.int64)
    t = p - f
    w = t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
    out = np.zeros(p.shape[:-1])
    for dx in (0, 1):
        wx = w[..., 0] if dx else 1.0 - w[..., 0]
        for dy in (0, 1):
            wy = w[..., 1] if dy else 1.0 - w[..., 1]
            for dz in (0, 1):
                wz = w[..., 2] if dz else 1.0 - w[..., 2]
                out += wx * wy * wz * _hash_unit(i[..., 0] + dx, i[..., 1] + dy,
                                                 i[..., 2] + dz, s)
    return out


#: Perlin's (2002) gradient set: the 12 cube-edge directions, 4 of them twice (16 entries, so
#: that 4 hash bits pick one without a modulo).
_GRADIENTS = np.array([[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0], [1, 0, 1], [-1, 0, 1],
                       [1, 0, -1], [-1, 0, -1], [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1],
                       [1, 1, 0], [-1, 1, 0], [0, -1, 1], [0, -1, -1]], dtype=np.float32)
_GX, _GY, _GZ = (np.ascontiguousarray(_GRADIENTS[:, k]) for k in range(3))


def gradient_noise_3d(p: FloatArray, seed: int) -> NDArray[np.float32]:
    """Perlin gradient noise at points ``p`` ``(n, 3)`` in lattice units; RMS ~ 0.27, |value|
    <= 2 (float32).

    Perlin's (2002) "improved noise": a gradient hashed per lattice point (the splitmix64
    finaliser of :func:`value_noise_3d`, 4 bits pick one of :data:`_GRADIENTS`), dotted with the
    offset and blended with the quintic fade. Unlike value noise it is zero at the lattice
    points and its 3-D spectrum vanishes at zero frequency (:mod:`starnav.dem.detail` builds
    its band-limited octaves on it). The lattice cell is found in float64; the blend is done in
    float32 (1e-6 of the RMS; a quarter faster).
    """
    s = np.uint64(seed)
    f = np.floor(p)
    i = f.astype(np.int64)
    t = (p - f).astype(np.float32)
    w = t * t * t * (t * (t * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))
    one = np.uint64(1)
    with np.errstate(over="ignore"):
        ix, iy, iz = (i[:, k].view(np.uint64) for k in range(3))
        hx = (ix * _M1, (ix + one) * _M1)
        hy = (iy * _M2, (iy + one) * _M2)
        hz = ((iz * _M3) ^ s, ((iz + one) * _M3) ^ s)
    tx, ty, tz = (np.ascontiguousarray(t[:, k]) for k in range(3))
    w0 = [np.ascontiguousarray(w[:, k]) for k in range(3)]
    w1 = [np.float32(1.0) - wk for wk in w0]
    out = np.zeros(p.shape[0], dtype=np.float32)
    for dx in (0, 1):
        ux = tx - np.float32(dx)
        for dy in (0, 1):
            wxy = (w0[0] if dx else w1[0]) * (w0[1] if dy else w1[1])
            uy = ty - np.float32(dy)
            hxy = hx[dx] ^ hy[dy]
            for dz in (0, 1):
                with np.errstate(over="ignore"):
                    h = hxy ^ hz[dz]
                    h ^= h >> np.uint64(30)
                    h *= _S1
                    h ^= h >> np.uint64(27)
                    h *= _S2
                    h ^= h >> np.uint64(31)
                k = (h >> np.uint64(60)).astype(np.intp)
                wz = wxy * (w0[2] if dz else w1[2])
                out += wz * (_GX[k] * ux + _GY[k] * uy + _GZ[k] * (tz - np.float32(dz)))
    return out


_NOISE_RMS: float | None = None


def _noise_rms() -> float:
    """RMS of :func:`value_noise_3d` (measured once on 200 000 points, fixed seed)."""
    global _NOISE_RMS
    if _NOISE_RMS is None:
        p = np.random.default_rng(12345).random((200_000, 3)) * 1000.0
        _NOISE_RMS = float(np.std(value_noise_3d(p, 7)))
    return _NOISE_RMS


def _grid_unit_vectors(lat: FloatArray, lon: FloatArray) -> FloatArray:
    cl = np.cos(lat)[:, None]
    return np.stack(np.broadcast_arrays(cl * np.cos(lon)[None, :], cl * np.sin(lon)[None, :],
                                        np.sin(lat)[:, None]), axis=-1)


def _upsample_bilinear(a: NDArray[np.float32], shape: tuple[int, int]) -> NDArray[np.float32]:
    """Cell-centred bilinear resampling of a global grid to ``shape`` (longitude wraps)."""
    n_lat, n_lon = a.shape
    m_lat, m_lon = shape
    y = (np.arange(m_lat) + 0.5) * n_lat / m_lat - 0.5
    y = np.clip(y, 0.0, n_lat - 1.0)
    y0 = np.minimum(np.floor(y).astype(np.int64), n_lat - 1)
    y1 = np.minimum(y0 + 1, n_lat - 1)
    fy = (y - y0).astype(np.float32)[:, None]
    rows = a[y0] * (1 - fy) + a[y1] * fy
    x = (np.arange(m_lon) + 0.5) * n_lon / m_lon - 0.5
    x0 = np.floor(x).astype(np.int64)
    fx = (x - x0).astype(np.float32)[None, :]
    x0 %= n_lon
    x1 = (x0 + 1) % n_lon
    return (rows[:, x0] * (1 - fx) + rows[:, x1] * fx).astype(np.float32)


def fractal_field(shape: tuple[int, int], seed: int, key: int, wavelengths: FloatArray,
                  amplitudes: FloatArray, radius: float = MOON_RADIUS) -> NDArray[np.float32]:
    """Sum of value-noise octaves on a global equirectangular grid of ``shape``.

    Octave ``k`` (wavelength ``wavelengths[k]`` [m], RMS ``amplitudes[k]``) is evaluated on the
    coarsest grid with at least 4 samples per wavelength and added after bilinear resampling,
    so the cost is about 1.3 evaluations per cell whatever the number of octaves. Evaluated in
    row blocks (memory ~100 MB whatever the grid).
    """
    n_lat, n_lon = shape
    cell = math.pi * radius / n_lat
    norm = 1.0 / _noise_rms()
    # group octaves by the level they are evaluated on
    levels: dict[int, list[int]] = {}
    for k, lam in enumerate(wavelengths):
        lev = max(0, int(math.floor(math.log2(lam / (4.0 * cell)))))
        while lev > 0 and (n_lat >> lev) < 4:
            lev -= 1
        levels.setdefault(lev, []).append(k)
    acc: NDArray[np.float32] | None = None
    for lev in range(max(levels, default=0), -1, -1):
        shp = (max(2, n_lat >> lev), max(4, n_lon >> lev))
        if acc is not None:
            acc = _upsample_bilinear(acc, shp)
        else:
            acc = np.zeros(shp, dtype=np.float32)
        ks = levels.get(lev, [])
        if not ks:
            continue
        lat = HALF_PI - (np.arange(shp[0]) + 0.5) * math.pi / shp[0]
        lon = -math.pi + (np.arange(shp[1]) + 0.5) * 2.0 * math.pi / shp[1]
        block = max(1, 400_000 // shp[1])
        for r0 in range(0, shp[0], block):
            u = _grid_unit_vectors(lat[r0:r0 + block], lon)
            part = np.zeros(u.shape[:2])
            for k in ks:
                lam = float(wavelengths[k])
                s = seed_u64(seed, WORLD_FRACTAL, key, round(math.log2(lam) * 64))
                part += (amplitudes[k] * norm) * value_noise_3d(u * (2.0 * radius / lam), s)
            acc[r0:r0 + block] += part.astype(np.float32)
    assert acc is not None
    if acc.shape != shape:
        acc = _upsample_bilinear(acc, shape)
    return acc


# ------------------------------------------------------------------------- stamping
class _Stamper:
    """Stamps craters into a global grid in place (windows around each crater)."""

    def __init__(self, h: NDArray[np.float32], morph: CraterMorphology, radius: float) -> None:
        self.h = h
        self.morph = morph
        self.radius = radius
        n_lat, n_lon = h.shape
        self.dlat = math.pi / n_lat
        self.dlon = 2.0 * math.pi / n_lon
        self.lat = HALF_PI - (np.arange(n_lat) + 0.5) * self.dlat
        self.lon = -math.pi + (np.arange(n_lon) + 0.5) * self.dlon
        self.sin_lat, self.cos_lat = np.sin(self.lat), np.cos(self.lat)

    def window(self, lat0: float, lon0: float, ang: float
               ) -> tuple[slice, NDArray[np.int64], FloatArray]:
        """Rows, columns and great-circle distance [rad] of cells within ``ang`` of a point."""
        n_lat, n_lon = self.h.shape
        i0 = max(0, int(math.floor((HALF_PI - (lat0 + ang)) / self.dlat)))
        i1 = min(n_lat, int(math.ceil((HALF_PI - (lat0 - ang)) / self.dlat)) + 1)
        cmin = math.cos(min(HALF_PI, abs(lat0) + ang))
        if abs(lat0) + ang >= HALF_PI or ang / max(cmin, 1e-12) >= math.pi:
            cols = np.arange(n_lon)
        else:
            half = ang / cmin
            j0 = int(math.floor((lon0 - half + math.pi) / self.dlon))
            j1 = int(math.ceil((lon0 + half + math.pi) / self.dlon)) + 1
            cols = np.arange(j0, j1) % n_lon
        rows = slice(i0, i1)
        cosd = (self.sin_lat[rows, None] * math.sin(lat0)
                + self.cos_lat[rows, None] * math.cos(lat0)
                * np.cos(self.lon[cols][None, :] - lon0))
        return rows, cols, np.arccos(np.clip(cosd, -1.0, 1.0))

    def stamp(self, lat0: float, lon0: float, diameter: float) -> None:
        R = 0.5 * diameter
        ang = EJECTA_TAPER[1] * R / self.radius
        rows, cols, dist = self.window(lat0, lon0, ang)
        r = dist * self.radius
        old = self.h[rows][:, cols].astype(np.float64)
        inside = r <= R
        if not inside.any():  # crater smaller than a cell: its centre cell only
            inside = r <= r.min()
        ref = float(old[inside].mean())
        prof = self.morph.profile(r, diameter)
        keep = np.clip(r / R, 0.0, 1.0) ** 4  # old relief kept near the wall
        new = np.where(inside, ref + prof + (old - ref) * keep, old + prof)
        self.h[rows][:, cols] = new.astype(np.float32)  # h[rows] is a view: writes through


def stamp_craters(h: NDArray[np.float32], lat: FloatArray, lon: FloatArray,
                  diameter: FloatArray, morph: CraterMorphology,
                  radius: float = MOON_RADIUS) -> None:
    """Stamp craters (centres [rad], diameters [m]) into a global height grid ``h`` [m] in
    place, in the given order (oldest first)."""
    st = _Stamper(h, morph, radius)
    for la, lo, d in zip(lat, lon, diameter, strict=True):
        st.stamp(float(la), float(lo), float(d))


# ------------------------------------------------------------------------- maria
def mare_mask(shape: tuple[int, int], cfg: ProceduralDemConfig,
              radius: float = MOON_RADIUS) -> NDArray[np.float32]:
    """Soft mare mask in [0, 1] on a global grid: 1 on the mare plains.

    Gaussian basins (angular radius 4-14 deg) biased to the near side (longitude ~ N(0, 45 deg),
    latitude ~ N(+8, 25 deg)) plus long-wavelength noise; thresholded at the area quantile that
    gives ``cfg.mare_fraction``, with a soft edge.
    """
    n_lat, n_lon = shape
    if cfg.mare_fraction <= 0.0:
        return np.zeros(shape, np.float32)
    # evaluate on a coarse grid (<= 0.5 deg) and resample: the mask is smooth
    c_lat = min(n_lat, 360)
    cs = (c_lat, 2 * c_lat)
    rng = generator(cfg.seed, WORLD_BASINS)
    n_basins = 28
    blat = np.radians(np.clip(rng.normal(8.0, 25.0, n_basins), -75.0, 75.0))
    blon = np.radians(rng.normal(0.0, 45.0, n_basins))
    bsig = np.radians(rng.uniform(4.0, 14.0, n_basins))
    bamp = rng.uniform(0.6, 1.0, n_basins)
    lat = HALF_PI - (np.arange(cs[0]) + 0.5) * math.pi / cs[0]
    lon = -math.pi + (np.arange(cs[1]) + 0.5) * 2.0 * math.pi / cs[1]
    u = _grid_unit_vectors(lat, lon)
    f = np.zeros(cs)
    for la, lo, sg, am in zip(blat, blon, bsig, bamp, strict=True):
        c = np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
        ang = np.arccos(np.clip(u @ c, -1.0, 1.0))
        f += am * np.exp(-0.5 * (ang / sg) ** 2)
    lam = np.array([1.2e6, 6e5, 3e5])
    f += fractal_field(cs, cfg.seed, 7, lam, np.array([0.25, 0.15, 0.08]), radius)
    w = np.repeat(np.cos(lat)[:, None], cs[1], axis=1).ravel()
    order = np.argsort(f.ravel())[::-1]
    cum = np.cumsum(w[order]) / w.sum()
    thr = f.ravel()[order][min(np.searchsorted(cum, cfg.mare_fraction), order.size - 1)]
    edge = 0.08
    s = np.clip((f - thr) / edge + 0.5, 0.0, 1.0)
    m = (s * s * (3.0 - 2.0 * s)).astype(np.float32)
    return _upsample_bilinear(m, shape) if cs != shape else m


# ------------------------------------------------------------------------- the world
@dataclass(frozen=True)
class ProceduralMoon:
    """A procedural Moon: heights, albedo, its crater catalogue and mare mask."""

    dem: DemGrid
    albedo: AlbedoGrid
    craters: CraterCatalogue
    mare: NDArray[np.float32]
    config: ProceduralDemConfig


#: Procedural worlds kept in memory (each holds global grids of ``4 * 64800 * ppd^2`` bytes).
_CACHE_SIZE = 2
_CACHE: BoundedCache[tuple[str, float], ProceduralMoon] = BoundedCache(_CACHE_SIZE)


def procedural_moon(cfg: ProceduralDemConfig | None = None,
                    radius: float = MOON_RADIUS) -> ProceduralMoon:
    """Make (or fetch from the in-memory cache) the procedural Moon of ``cfg``.

    Parameters
    ----------
    cfg : ProceduralDemConfig
        Seed, resolution and model parameters (defaults if None).
    radius : float
        Reference sphere radius [m].

    Returns
    -------
    ProceduralMoon
        ``dem`` (heights [m], global, western edge at -180 deg), ``albedo`` (quantity
        ``albedo``), the crater catalogue and the mare mask.
    """
    cfg = cfg or ProceduralDemConfig()
    key = (cfg.model_dump_json(), float(radius))
    return _CACHE.get_or_make(key, lambda: _make_moon(cfg, radius))


def _make_moon(cfg: ProceduralDemConfig, radius: float) -> ProceduralMoon:
    t0 = time.perf_counter()
    n_lat = max(4, round(180.0 * cfg.pixels_per_degree))
    shape = (n_lat, 2 * n_lat)
    cell = math.pi * radius / n_lat
    morph = CraterMorphology.from_config(cfg)
    d_min = (cfg.crater_min_diameter_km * 1e3 if cfg.crater_min_diameter_km
             else MIN_CRATER_CELLS * cell)
    cat = crater_catalogue(cfg, d_min, radius)
    mare = mare_mask(shape, cfg, radius)
    h = np.zeros(shape, dtype=np.float32)
    st = _Stamper(h, morph, radius)
    n_pre = int(np.count_nonzero(~cat.post_mare))
    for i in range(n_pre):
        st.stamp(float(cat.lat[i]), float(cat.lon[i]), float(cat.diameter[i]))
    # mare flooding: plains at -mare_depth with ghosts of the older relief
    level = -cfg.mare_depth_m
    h[:] = h * (1.0 - mare) + mare * (level + MARE_GHOST * (h - level))
    for i in range(n_pre, len(cat)):
        st.stamp(float(cat.lat[i]), float(cat.lon[i]), float(cat.diameter[i]))
    # fractal roughness, halved on the maria
    lam = _roughness_wavelengths(cfg, cell)
    if cfg.roughness_rms_m > 0 and lam.size:
        amp = cfg.roughness_rms_m * (lam / (cfg.roughness_ref_wavelength_km * 1e3)) ** \
            cfg.hurst_exponent
        h += fractal_field(shape, cfg.seed, 1, lam, amp, radius) * (1.0 - 0.5 * mare)
    dem = DemGrid(h, reference_radius=radius,
                  source=f"procedural:seed={cfg.seed}:ppd={cfg.pixels_per_degree:g}")
    albedo = _albedo(cfg, shape, mare, cat, radius)
    logger.info("procedural Moon %s: %d craters, heights %.0f..%.0f m, %.2f s", shape,
                len(cat), *dem.height_range, time.perf_counter() - t0)
    return ProceduralMoon(dem=dem, albedo=albedo, craters=cat, mare=mare, config=cfg)


def _roughness_wavelengths(cfg: ProceduralDemConfig, cell: float) -> FloatArray:
    return _octaves(cfg.roughness_max_wavelength_km * 1e3, cell)


def _octaves(lam_max: float, cell: float) -> FloatArray:
    """Wavelengths ``lam_max / 2^k`` [m] down to :data:`MIN_ROUGHNESS_CELLS` cells."""
    out = []
    lam = lam_max
    while lam >= MIN_ROUGHNESS_CELLS * cell:
        out.append(lam)
        lam /= 2.0
    return np.asarray(out)


def _albedo(cfg: ProceduralDemConfig, shape: tuple[int, int], mare: NDArray[np.float32],
            cat: CraterCatalogue, radius: float) -> AlbedoGrid:
    a = (cfg.highland_albedo * (1.0 - mare) + cfg.mare_albedo * mare).astype(np.float32)
    cell = math.pi * radius / shape[0]
    if cfg.albedo_noise > 0:
        lam = _octaves(ALBEDO_TEXTURE_MAX_WAVELENGTH, cell)
        if lam.size:
            amp = np.full(lam.size, cfg.albedo_noise / math.sqrt(lam.size))
            a *= 1.0 + fractal_field(shape, cfg.seed, 2, lam, amp, radius)
    if cfg.fresh_ejecta_brightening > 0 and len(cat):
        young = np.flatnonzero(cat.age_rank >= 1.0 - FRESH_FRACTION)
        young = young[cat.diameter[young] >= 2.0 * MIN_CRATER_CELLS * cell]
        bright = np.zeros(shape, np.float32)
        st = _Stamper(bright, CraterMorphology(), radius)
        for i in young:
            R = 0.5 * float(cat.diameter[i])
            rows, cols, dist = st.window(float(cat.lat[i]), float(cat.lon[i]), 4.0 * R / radius)
            rr = np.maximum(dist * radius / R, 1.0)
            add = cfg.fresh_ejecta_brightening * rr**-3 * np.clip((4.0 - rr) / 1.5, 0.0, 1.0)
            view = bright[rows]
            view[:, cols] = np.maximum(view[:, cols], add.astype(np.float32))
        a += bright
    np.clip(a, 0.005, 1.0, out=a)
    return AlbedoGrid(a, quantity="normal_albedo",
                      source=f"procedural-albedo:seed={cfg.seed}:ppd={cfg.pixels_per_degree:g}")
