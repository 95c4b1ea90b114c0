"""Sub-posting detail: DEM terrain refined with fractal relief where the mesh is finer than it.

:func:`sub_posting_detail` measures how rough the DEM is at its posting and continues that
roughness below it, octave by octave, as far as the pixel footprint asks;
:func:`starnav.dem.mesh.view_mesh` adds it only to vertices finer than a DEM cell. Each step
in full: docs/methods.md, "starnav.dem.detail".

Technique
---------
1. Roughness at the posting: the structure function ``S(r)`` of the DEM's bilinear surface
   (per window with ``amplitude: regional``).
2. Hurst exponent ``H``: configured (default 0.9, Rosenburg et al. 2011) or measured.
3. Octaves of wavelength ``c / 2^k``: band-limited gradient noise minus its tangent-plane
   Laplacian stencil (little power leaks to the DEM's own scale).
4. Amplitudes ``beta S_c (lambda_k / c)^H``, ``beta`` by least squares so that the refined
   surface continues the DEM's power law; each octave's RMS slope capped.
5. Per vertex: octaves faded in by the vertex spacing, clipped at :data:`DETAIL_CLIP_SIGMA`.

References
----------
M. A. Rosenburg et al., "Global surface slopes and roughness of the Moon from the Lunar
Orbiter Laser Altimeter", J. Geophys. Res. 116 (2011) E02001.

Index
-----
:func:`sub_posting_detail`, :class:`SubPostingDetail`, :func:`band_noise`,
:func:`bilinear_structure`, :func:`measured_hurst`, :func:`roughness_map`, :func:`fit_beta`,
:func:`octave_structure`, :func:`smoothstep`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.cache import BoundedCache
from starnav.dem.grid import HALF_PI, DemGrid, EquirectangularGrid
from starnav.dem.procedural import gradient_noise_3d
from starnav.dem.schema import DetailConfig
from starnav.seeding import WORLD_DETAIL, seed_u64
from starnav.typing import FloatArray

logger = logging.getLogger(__name__)

#: RMS of the tangent-plane Laplacian of :func:`gradient_noise_3d` (stencil 1/2 lattice unit),
#: measured on 400 000 random points and planes (``tests/dem/test_detail.py`` re-measures it).
BAND_NOISE_RMS = 0.1433
#: Offset of the stencil points [lattice units].
STENCIL_OFFSET = 0.5
#: Lattice spacing of an octave / its wavelength: the octave's structure function peaks at half
#: a wavelength (its dominant period is the wavelength).
LATTICE_PER_WAVELENGTH = 1.0 / math.sqrt(2.0)
#: Regular tetrahedron (unit vectors; they sum to zero and ``sum d d^T = 4/3 I``: projected on
#: any plane, an isotropic zero-sum stencil).
TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / math.sqrt(3)
#: Structure function ``D(x) = E[(f(p + x lambda) - f(p))^2]`` of one unit-RMS octave at lags
#: ``x = 2^(j/2)``, ``j = -12 ... 4`` [-] (400 000 random points and directions); ``D -> 2``
#: beyond, ``D ~ OCTAVE_SLOPE_COEFF x^2`` below.
OCTAVE_STRUCTURE = np.array([
    0.0064, 0.0128, 0.0256, 0.0511, 0.1012, 0.1988, 0.3840, 0.7170, 1.2545, 1.9450, 2.4466,
    2.2769, 1.8804, 2.0131, 1.9988, 1.9974, 1.9982])
OCTAVE_STRUCTURE_LAGS = 2.0 ** (np.arange(-12, 5) / 2.0)
#: ``lim D(x) / x^2`` [-]: a unit octave's RMS slope is ``sqrt(2 * coeff) / lambda``.
OCTAVE_SLOPE_COEFF = 26.35
#: Detail clipped at this many times its local RMS (a unit octave's largest value in 400 000
#: samples is 3.8): bounds ``|detail|`` by :attr:`SubPostingDetail.max_detail_m`.
DETAIL_CLIP_SIGMA = 4.5
#: Lags of the amplitude fit: ``c 2^(-j/2)``, j = 2 ... 12 (c/2 to c/64).
FIT_LAG_EXPONENTS = np.arange(2, 13)
#: Points sampled to measure the DEM's bilinear structure function.
STRUCTURE_SAMPLES = 100_000
#: Points per chunk when evaluating noise (memory ~ 60 MB per chunk).
CHUNK = 1 << 18
#: Measured Hurst exponents are kept within this range [-].
HURST_RANGE = (0.05, 1.0)


def octave_structure(x: FloatArray) -> FloatArray:
    """Structure function of one unit-RMS octave at lags ``x`` [wavelengths] (interpolated in
    :data:`OCTAVE_STRUCTURE`; ``2`` beyond, quadratic below)."""
    x = np.asarray(x, dtype=float)
    lags = OCTAVE_STRUCTURE_LAGS
    lx = np.log(np.clip(x, lags[0], lags[-1]))
    out = np.interp(lx, np.log(lags), OCTAVE_STRUCTURE)
    out = np.where(x < lags[0], OCTAVE_STRUCTURE[0] * (x / lags[0]) ** 2, out)
    return np.where(x > lags[-1], 2.0, out)


def band_noise(u: FloatArray, wavelength: float, radius: float, seed: int) -> FloatArray:
    """One octave of band-limited noise, unit RMS, at unit vectors ``u`` ``(n, 3)``.

    Perlin gradient noise on the lattice ``wavelength / sqrt 2`` (on the sphere of ``radius``
    [m]) minus its mean at four tetrahedral offsets projected on the tangent plane at ``u``:
    zero mean and no power at wavelengths much longer than ``wavelength`` [m] along the surface.
    """
    u = np.asarray(u, dtype=float).reshape(-1, 3)
    scale = radius / (LATTICE_PER_WAVELENGTH * wavelength)
    out = np.empty(u.shape[0])
    for a in range(0, u.shape[0], CHUNK):
        uc = u[a:a + CHUNK]
        acc = gradient_noise_3d(uc * scale, seed)
        ud = uc @ TETRAHEDRON.T                       # (n, 4) components along u
        for j, d in enumerate(TETRAHEDRON):
            # u scale + a (d - (u.d) u): the stencil point, offset along the tangent plane
            q = uc * (scale - STENCIL_OFFSET * ud[:, j])[:, None]
            q += STENCIL_OFFSET * d
            acc -= 0.25 * gradient_noise_3d(q, seed)
        out[a:a + CHUNK] = acc / BAND_NOISE_RMS
    return out


def smoothstep(x: FloatArray) -> FloatArray:
    """``3 x^2 - 2 x^3`` on ``[0, 1]``, 0 below, 1 above."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


# ------------------------------------------------------------------------- DEM statistics
def _meridian_mean_square(values: NDArray[np.float32], lag: int, block: int = 1 << 22
                          ) -> float:
    """Mean of ``(h[i + lag, j] - h[i, j])^2`` over the grid (row blocks) [m^2]."""
    n_lat, n_lon = values.shape
    if n_lat <= lag:
        return 0.0
    rows = max(1, block // max(n_lon, 1))
    acc = 0.0
    for r0 in range(0, n_lat - lag, rows):
        r1 = min(n_lat - lag, r0 + rows)
        d = values[r0 + lag:r1 + lag].astype(np.float64) - values[r0:r1]
        acc += float(np.sum(d * d))
    return acc / ((n_lat - lag) * n_lon)


def measured_hurst(dem: DemGrid) -> float:
    """Hurst exponent of the DEM at 1 to 4 cells: slope of ``log S(r)`` vs ``log r`` [-]
    (``S``: RMS difference of cells along meridians), within :data:`HURST_RANGE`."""
    s = [math.sqrt(_meridian_mean_square(dem.values, lag)) for lag in (1, 2, 4)]
    if min(s) <= 0.0:
        return HURST_RANGE[1]
    h = float(np.polyfit(np.log([1.0, 2.0, 4.0]), np.log(s), 1)[0])
    return min(max(h, HURST_RANGE[0]), HURST_RANGE[1])


def bilinear_structure(dem: DemGrid, lags: FloatArray, n: int = STRUCTURE_SAMPLES,
                       seed: int = 0) -> FloatArray:
    """Structure function [m] of the DEM's bilinear surface along meridians at ``lags`` [m]:
    RMS of ``h(lat + r / R, lon) - h(lat, lon)`` at ``n`` random points (area-uniform, within
    the grid and 80 deg of the equator, fixed seed)."""
    R = dem.reference_radius
    lags = np.asarray(lags, dtype=float)
    rng = np.random.default_rng(seed)
    pad = 2.0 * dem.dlat + float(lags.max()) / R
    south = max(dem.south, -math.radians(80.0)) + dem.dlat
    north = min(dem.north, math.radians(80.0)) - pad
    if north <= south:  # a grid too small: use all of it
        south, north = dem.south, dem.north - float(lags.max()) / R
    lat = np.arcsin(rng.uniform(math.sin(south), math.sin(north), n))
    lon = dem.west + (dem.east - dem.west) * rng.random(n)
    h0 = dem.sample(lat, lon).astype(np.float64)
    out = np.empty(lags.size)
    for i, r in enumerate(lags):
        d = dem.sample(np.minimum(lat + r / R, HALF_PI), lon).astype(np.float64) - h0
        out[i] = math.sqrt(float(np.mean(d * d)))
    return out


def roughness_map(dem: DemGrid, window: float) -> EquirectangularGrid:
    """RMS difference of neighbouring cells along meridians [m], per window of about
    ``window`` [m] (block means of the squared differences, row blocks for memory)."""
    n_lat, n_lon = dem.shape
    b = max(1, round(window / dem.cell_size(dem.reference_radius)))
    m_lat, m_lon = max(1, (n_lat - 1) // b), max(1, n_lon // b)
    acc = np.zeros((m_lat, m_lon))
    cnt = np.zeros((m_lat, m_lon))
    rows = max(1, (1 << 22) // max(n_lon, 1))
    col_bin = np.minimum(np.arange(n_lon) * m_lon // n_lon, m_lon - 1)
    for r0 in range(0, n_lat - 1, rows):
        r1 = min(n_lat - 1, r0 + rows)
        d = dem.values[r0 + 1:r1 + 1].astype(np.float64) - dem.values[r0:r1]
        row_bin = np.minimum(np.arange(r0, r1) * m_lat // (n_lat - 1), m_lat - 1)
        sq = d * d
        for rb in np.unique(row_bin):
            part = sq[row_bin == rb]
            acc[rb] += np.bincount(col_bin, weights=part.sum(axis=0), minlength=m_lon)
            cnt[rb] += np.bincount(col_bin, minlength=m_lon) * part.shape[0]
    s = np.sqrt(acc / np.maximum(cnt, 1.0))
    if s.shape[0] < 2 or s.shape[1] < 2:  # a grid smaller than a window: one value
        s = np.full((max(2, s.shape[0]), max(2, s.shape[1])), float(np.sqrt(acc.sum()
                                                                             / cnt.sum())))
    return EquirectangularGrid(s, extent=dem.extent, source=f"{dem.source}#roughness")


# ------------------------------------------------------------------------- the model
@dataclass(frozen=True, eq=False)
class SubPostingDetail:
    """Fractal relief below a DEM's posting (see the module docstring).

    Attributes
    ----------
    posting, radius : float
        DEM cell along a meridian ``c``; reference sphere [m].
    hurst, hurst_measured : float
        Hurst exponent used; the DEM's own at 1 to 4 cells [-].
    roughness, roughness_nodes : float
        ``S_c``: global RMS height difference of the DEM's bilinear surface at lag ``c``; the
        same between neighbouring grid nodes [m].
    beta : float
        Amplitude factor of the fit: ``sigma_k = beta S_c (lambda_k / c)^H`` [-].
    wavelengths, sigma, slope_cap : (K,) arrays
        Octave wavelengths (longest first), RMS for the global ``S_c`` (capped), and the
        slope guard's largest RMS [m].
    roughness_grid : EquirectangularGrid or None
        Regional ``S_c`` [m] (``amplitude: regional``).
    max_detail_m, rms_m : float
        Bound on ``|detail|`` anywhere; RMS of the full detail (global ``S_c``) [m].
    seed : int
    key : tuple
        Identity for mesh caches.
    """

    posting: float
    radius: float
    hurst: float
    hurst_measured: float
    roughness: float
    roughness_nodes: float
    beta: float
    wavelengths: FloatArray
    sigma: FloatArray
    slope_cap: FloatArray
    roughness_grid: EquirectangularGrid | None
    max_detail_m: float
    rms_m: float
    seed: int
    key: tuple[Any, ...] = field(repr=False)

    def octave_seed(self, k: int) -> int:
        """Seed of octave ``k`` (its own ``SeedSequence`` stream)."""
        return seed_u64(self.seed, WORLD_DETAIL, k)

    def weights(self, edge: FloatArray, n_octaves: int | None = None) -> FloatArray:
        """Octave weights ``(n, K)`` for vertex spacings ``edge`` [m]: 1 for ``lambda >= 2
        edge``, 0 for ``lambda <= edge`` (and for ``edge >= posting``), smooth between; the
        first ``n_octaves`` columns only if given."""
        edge = np.asarray(edge, dtype=float).reshape(-1, 1)
        lam = self.wavelengths[:n_octaves]
        return smoothstep(np.log2(lam[None, :] / np.maximum(edge, 1e-300)))

    def octave_sigma(self, u: FloatArray) -> FloatArray:
        """Octave RMS ``(n, K)`` [m] at unit vectors ``u`` (regional roughness, slope cap)."""
        u = np.asarray(u, dtype=float).reshape(-1, 3)
        if self.roughness_grid is None or self.roughness <= 0.0:
            return np.broadcast_to(self.sigma, (u.shape[0], self.sigma.size))
        lat = np.arctan2(u[:, 2], np.hypot(u[:, 0], u[:, 1]))
        lon = np.arctan2(u[:, 1], u[:, 0])
        s = self.roughness_grid.sample(lat, lon).astype(np.float64) / self.roughness
        raw = self.beta * self.roughness * (self.wavelengths / self.posting) ** self.hurst
        return np.minimum(s[:, None] * raw[None, :], self.slope_cap[None, :])

    def heights(self, u: FloatArray, edge: FloatArray) -> FloatArray:
        """Detail [m] at unit vectors ``u`` ``(n, 3)`` for vertex spacings ``edge`` ``(n,)``
        [m]; 0 where the spacing is not finer than the posting."""
        u = np.asarray(u, dtype=float).reshape(-1, 3)
        edge = np.broadcast_to(np.asarray(edge, dtype=float), (u.shape[0],))
        out = np.zeros(u.shape[0])
        need = np.flatnonzero(edge < self.posting)
        if need.size == 0 or self.wavelengths.size == 0:
            return out
        un, en = u[need], edge[need]
        n_act = int(np.count_nonzero(self.wavelengths > en.min()))  # octaves with weight > 0
        w = self.weights(en, n_act) * self.octave_sigma(un)[:, :n_act]   # (m, K') [m]
        acc = np.zeros(need.size)
        for k, lam in enumerate(self.wavelengths[:n_act]):
            sel = np.flatnonzero(w[:, k] > 0.0)
            if sel.size:
                acc[sel] += w[sel, k] * band_noise(un[sel], float(lam), self.radius,
                                                   self.octave_seed(k))
        lim = DETAIL_CLIP_SIGMA * np.sqrt(np.sum(w * w, axis=1))
        out[need] = np.clip(acc, -lim, lim)
        return out

    def summary(self) -> dict[str, Any]:
        """The measured numbers, for logs and metadata (lengths in metres)."""
        return {"posting_m": self.posting, "roughness_at_posting_m": self.roughness,
                "roughness_nodes_m": self.roughness_nodes, "hurst": self.hurst,
                "hurst_measured": self.hurst_measured, "beta": self.beta,
                "octaves": int(self.wavelengths.size),
                "sigma_m": [round(float(s), 3) for s in self.sigma],
                "rms_m": self.rms_m, "max_detail_m": self.max_detail_m,
                "regional": self.roughness_grid is not None}


def fit_beta(q: FloatArray, lags: FloatArray, hurst: float) -> float:
    """Octave amplitude factor ``beta`` [-] (least squares, >= 0) such that
    ``q^2(r) + beta^2 sum_k (lambda_k / c)^(2H) D(r / lambda_k) = (r / c)^(2H)`` at the
    ``lags`` ``r / c`` [-], for the bilinear surface's ``q(r) = S(r) / S_c`` and the octaves
    ``lambda_k / c = 2^-k`` continued well below the smallest lag."""
    lags = np.asarray(lags, dtype=float)
    k = np.arange(int(math.ceil(-math.log2(lags.min()))) + 6)
    lam = 2.0 ** -k.astype(float)
    A = np.sum(lam[None, :] ** (2 * hurst) * octave_structure(lags[:, None] / lam[None, :]),
               axis=1)
    t = lags ** (2 * hurst)
    a, res = A / t, np.asarray(q, float) ** 2 / t - 1.0
    b2 = -float(np.sum(a * res)) / float(np.sum(a * a))
    return math.sqrt(max(b2, 0.0))


#: Measured details kept in memory (per DEM and configuration).
_CACHE_SIZE = 4
_CACHE: BoundedCache[tuple[Any, ...], SubPostingDetail] = BoundedCache(_CACHE_SIZE)


def sub_posting_detail(dem: DemGrid, cfg: DetailConfig | None = None
                       ) -> SubPostingDetail | None:
    """The sub-posting detail of ``dem`` for ``cfg`` (None when ``cfg.enabled`` is false).

    Measures the DEM (a few tenths of a second for LDEM_4; kept in a small cache per DEM and
    configuration).
    """
    cfg = cfg or DetailConfig()
    if not cfg.enabled:
        return None
    key = ("detail", dem.uid, cfg.model_dump_json())
    return _CACHE.get_or_make(key, lambda: _make(dem, cfg, key))


def _make(dem: DemGrid, cfg: DetailConfig, key: tuple[Any, ...]) -> SubPostingDetail:
    R = dem.reference_radius
    c = dem.cell_size(R)
    h_meas = measured_hurst(dem)
    hurst = h_meas if cfg.hurst_exponent == "measured" else float(cfg.hurst_exponent)
    lag_c = 2.0 ** (-FIT_LAG_EXPONENTS / 2.0)
    s = bilinear_structure(dem, np.concatenate([[c], lag_c * c]))
    s_c = float(s[0])
    s_nodes = math.sqrt(_meridian_mean_square(dem.values, 1))
    q = s[1:] / s_c if s_c > 0 else lag_c
    beta = fit_beta(q, lag_c, hurst)
    lam_min = cfg.min_wavelength_km * 1e3
    n_oct = max(0, int(math.floor(math.log2(c / lam_min) + 1e-9)) + 1)
    lam = c * 2.0 ** -np.arange(n_oct, dtype=float)
    slope_cap = (math.tan(math.radians(cfg.max_rms_slope_deg)) * lam
                 / (math.sqrt(2.0 * OCTAVE_SLOPE_COEFF) * math.sqrt(max(n_oct, 1))))
    raw = beta * s_c * (lam / c) ** hurst
    sigma = np.minimum(raw, slope_cap)
    grid = None
    s_max = s_c
    if cfg.amplitude == "regional" and s_nodes > 0:
        nodes = roughness_map(dem, cfg.roughness_window_km * 1e3)
        grid = EquirectangularGrid(nodes.values * (s_c / s_nodes), extent=dem.extent,
                                   source=nodes.source)
        s_max = float(grid.values.max())
    worst = np.minimum(raw * (s_max / s_c if s_c > 0 else 0.0), slope_cap)
    max_detail = DETAIL_CLIP_SIGMA * float(np.sqrt(np.sum(worst**2)))
    d = SubPostingDetail(
        posting=c, radius=R, hurst=hurst, hurst_measured=h_meas, roughness=s_c,
        roughness_nodes=s_nodes, beta=beta, wavelengths=lam, sigma=sigma, slope_cap=slope_cap,
        roughness_grid=grid, max_detail_m=max_detail,
        rms_m=float(np.sqrt(np.sum(sigma**2))), seed=cfg.seed, key=key)
    logger.info("sub-posting detail of %s: posting %.0f m, S_c %.1f m, H %.3g (DEM %.3g), "
                "%d octaves, RMS %.1f m, |detail| <= %.0f m", dem.source or "DEM", c, s_c,
                hurst, h_meas, n_oct, d.rms_m, max_detail)
    return d


__all__ = ["BAND_NOISE_RMS", "DETAIL_CLIP_SIGMA", "OCTAVE_STRUCTURE", "SubPostingDetail",
           "band_noise", "bilinear_structure", "fit_beta", "measured_hurst", "octave_structure",
           "roughness_map", "sub_posting_detail"]
