"""View-adapted lunar meshes: only what the camera can see, as finely as it can resolve it.

:func:`view_mesh` builds, for one camera position, a mesh of the visible cap only, with
triangle edges of about one pixel where it matters; a global mesh that fine would have billions
of triangles. Each step in full: docs/methods.md, "starnav.dem.mesh".

Technique
---------
1. Cap: every point that can be seen lies within ``acos(R_lo / d) + acos(R_lo / R_hi)`` of
   the sub-camera point.
2. Rings of constant angle around the sub-camera point, one vertex per ``edge_px`` pixels along
   and across them (capped by ``max_foreshortening`` at the limb), one ring on the horizon.
3. Frustum: each ring keeps the arc inside the field cone (closed form).
4. Stitching: strip triangulation between consecutive rings.
5. Heights and albedo from the DEM's mip level matching the vertex spacing, plus the
   sub-posting detail (:mod:`starnav.dem.detail`).
6. Cache: meshes kept in an LRU per quantised view key (:data:`MESH_CACHE`).

Output: a :class:`trimesh.Trimesh` in Moon body-fixed coordinates [m] with vertex normals and
the vertex attributes ``lat``, ``lon`` [rad], ``height`` [m] and optionally ``albedo``. Cached
meshes are shared: treat them as read-only. The knobs are :class:`MeshOptions`.

Index
-----
:func:`view_mesh`, :class:`MeshOptions`, :data:`MESH_CACHE`, :func:`pixel_angle`,
:func:`field_cone`, :func:`save_mesh`, :func:`check_mesh_path`, :data:`MESH_FORMATS`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.atomic import atomic_path
from starnav.cache import BoundedCache
from starnav.camera import Camera
from starnav.dem.grid import AlbedoGrid, DemGrid, EquirectangularGrid
from starnav.errors import ConfigError, GeometryError
from starnav.typing import FloatArray

if TYPE_CHECKING:
    import trimesh

    from starnav.dem.detail import SubPostingDetail
    from starnav.dem.schema import MeshConfig

logger = logging.getLogger(__name__)

IntArray = NDArray[np.int64]

#: Samples of the ring-density integral along theta.
THETA_SAMPLES = 8192
#: Fewest vertices on the first ring around the sub-camera point.
MIN_RING_VERTICES = 6
#: Range quantum of the cache key: 1/8 octave of the altitude.
RANGE_BINS_PER_OCTAVE = 8
#: Largest cell of the quantised sub-camera direction [rad] (``cache_quantum_px``).
MAX_CELL_ANGLE = math.radians(1.0)


@dataclass(frozen=True)
class MeshOptions:
    """Knobs of :func:`view_mesh`.

    Parameters
    ----------
    edge_px : float
        Target projected edge length [px].
    max_foreshortening : float
        Largest radial edge, in pixel footprints, where the surface is seen grazing [-].
    terrain_margin : bool
        Extend the cap past the sphere's horizon for terrain above it.
    frustum_margin_px : float
        Margin around the field of view [px] (used when an attitude is given).
    max_vertices : int
        Vertex budget; edges are coarsened (with a warning) above it.
    cache_size : int
        Meshes kept by the default cache.
    cache_quantum_px : float
        Quantum of the cache key [px]; 0 keys on the exact geometry.
    """

    edge_px: float = 1.0
    max_foreshortening: float = 4.0
    terrain_margin: bool = True
    frustum_margin_px: float = 16.0
    max_vertices: int = 4_000_000
    cache_size: int = 4
    cache_quantum_px: float = 0.0

    def __post_init__(self) -> None:
        for name in ("edge_px", "max_foreshortening"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"dem.mesh.{name}", v, "a finite value > 0")
        if self.max_foreshortening < 1.0:
            raise ConfigError("dem.mesh.max_foreshortening", self.max_foreshortening, ">= 1")
        if not (self.cache_quantum_px >= 0 and self.frustum_margin_px >= 0):
            raise ConfigError("dem.mesh", (self.cache_quantum_px, self.frustum_margin_px),
                              "cache_quantum_px >= 0 and frustum_margin_px >= 0")

    @classmethod
    def from_config(cls, cfg: MeshConfig) -> MeshOptions:
        return cls(**cfg.model_dump())


#: A small LRU of meshes keyed by (DEM, albedo, options, view, detail); ``maxsize <= 0`` keeps
#: none, ``hits``/``misses`` count lookups (:class:`starnav.cache.BoundedCache`).
MeshCache = BoundedCache


#: The cache :func:`view_mesh` uses unless told otherwise.
MESH_CACHE: MeshCache[tuple[Any, ...], trimesh.Trimesh] = MeshCache(4)


# ------------------------------------------------------------------------- geometry helpers
def _frame(o: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors completing ``o`` to a right-handed frame ``(e1, e2, o)``."""
    ref = np.array([0.0, 0.0, 1.0]) if abs(o[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, o)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(o, e1)
    return e1, e2


def pixel_angle(camera: Camera) -> float:
    """Smallest angle subtended by one pixel anywhere on the detector [rad] (pinhole).

    On the axis it is ``1 / max(fx, fy)``; at field angle ``t`` it shrinks by ``cos^2 t``.
    """
    corners = np.array([[-0.5, -0.5], [camera.width - 0.5, -0.5], [-0.5, camera.height - 0.5],
                        [camera.width - 0.5, camera.height - 0.5]])
    xy = np.stack([(corners[:, 0] - camera.cx) / camera.fx,
                   (corners[:, 1] - camera.cy) / camera.fy], -1)
    cos2 = 1.0 / (1.0 + float(np.max(np.sum(xy * xy, axis=1))))
    return cos2 / max(camera.fx, camera.fy)


def field_cone(camera: Camera) -> float:
    """Half-angle [rad] of the smallest cone about the boresight containing every pixel ray."""
    w, h = camera.width, camera.height
    u = np.array([-0.5, w - 0.5, -0.5, w - 0.5, camera.cx, camera.cx, -0.5, w - 0.5])
    v = np.array([-0.5, -0.5, h - 0.5, h - 0.5, -0.5, h - 0.5, camera.cy, camera.cy])
    rays = camera.unproject(np.stack([u, v], -1), undistort=True)
    return float(np.max(np.arccos(np.clip(rays[:, 2], -1.0, 1.0))))


@dataclass(frozen=True)
class _View:
    """Everything the mesh depends on (quantised when caching with a quantum)."""

    o: tuple[float, float, float]            # sub-camera direction (unit)
    d_near: float                            # range used for the spacing [m]
    d_far: float                             # range used for the cap [m]
    slack: float                             # angular slack of the quantisation [rad]
    a: float                                 # pixel angle [rad]
    boresight: tuple[float, float, float] | None
    cone: float                              # field half-angle incl. margins [rad]
    d_true_spread: float                     # |C - C'| bound within the key cell [m]


def _quantise_view(c: FloatArray, camera: Camera, cam_to_body: FloatArray | None,
                   opts: MeshOptions, radius: float, r_bound: float = 0.0) -> _View:
    d = float(np.linalg.norm(c))
    o = c / d
    a = pixel_angle(camera)
    q = opts.cache_quantum_px
    b = None if cam_to_body is None else cam_to_body[:, 2] / np.linalg.norm(cam_to_body[:, 2])
    cone = 0.0 if cam_to_body is None else field_cone(camera) + opts.frustum_margin_px * a
    if b is not None and _ball_in_cone(o, d, b, r_bound, field_cone(camera) - a):
        # the whole Moon is in the field: culling would keep every ring whole, so the mesh
        # does not depend on the attitude (and a pointing change finds it in the cache)
        b, cone = None, 0.0
    if q <= 0:
        return _View(o=tuple(np.round(o, 15)), d_near=round(d, 3), d_far=round(d, 3), slack=0.0,
                     a=a, boresight=None if b is None else tuple(np.round(b, 15)), cone=cone,
                     d_true_spread=0.0)
    alt = d - radius
    k = math.floor(math.log2(alt) * RANGE_BINS_PER_OCTAVE)
    d_near = radius + 2.0 ** (k / RANGE_BINS_PER_OCTAVE)
    d_far = radius + 2.0 ** ((k + 1) / RANGE_BINS_PER_OCTAVE)
    # q pixels at nadir, as an angle at the centre, at most MAX_CELL_ANGLE (a far Moon of a few
    # pixels would otherwise share one mesh over a large turn of the view)
    step = min(q * a * (d_near - radius) / radius, MAX_CELL_ANGLE)
    oq = np.round(o / step) * step
    oq /= np.linalg.norm(oq)
    slack = step  # |o - oq| <= step sqrt(3)/2 < step
    spread = (d_far - d_near) + d_far * slack
    bq = None
    if b is not None:
        bstep = q * a
        bq_arr = np.round(b / bstep) * bstep
        bq = tuple(bq_arr / np.linalg.norm(bq_arr))
        cone += bstep
    return _View(o=tuple(oq), d_near=d_near, d_far=d_far, slack=slack, a=a, boresight=bq,
                 cone=cone, d_true_spread=spread)


def _ball_in_cone(o: FloatArray, d: float, b: FloatArray, r_bound: float, cone: float) -> bool:
    """Whether the ball of radius ``r_bound`` [m] about the Moon centre, seen from distance
    ``d`` [m] in direction ``-o`` (``o``: unit sub-camera direction), lies inside the cone of
    half-angle ``cone`` [rad] about the unit boresight ``b``."""
    if not (0.0 < r_bound < d):
        return False
    beta = math.acos(max(-1.0, min(1.0, -float(np.dot(b, o)))))
    return beta + math.asin(r_bound / d) < cone


def _ring_thetas(view: _View, radius: float, r_lo: float, r_hi: float, edge: float,
                 opts: MeshOptions) -> tuple[FloatArray, FloatArray, float, float]:
    """Ring angles [rad], their spacing [m] along the surface, horizon and cap angles [rad]."""
    d = view.d_near
    R = radius
    theta_h = math.acos(min(1.0, R / d))
    if opts.terrain_margin:
        theta_cap = math.acos(min(1.0, r_lo / view.d_far)) + math.acos(min(1.0, r_lo / r_hi))
    else:
        theta_cap = math.acos(min(1.0, R / view.d_far))
    theta_cap = min(math.pi, theta_cap + view.slack)
    th = np.linspace(0.0, theta_cap, THETA_SAMPLES)
    if 0.0 < theta_h < theta_cap:
        th = np.unique(np.append(th, theta_h))
    D = np.sqrt(d * d + R * R - 2.0 * d * R * np.cos(th))
    foot = edge * view.a * D                                  # [m] one edge, side-on
    dalpha = np.abs(R * (d * np.cos(th) - R)) / (D * D)       # [rad image / rad theta]
    step_px = np.where(dalpha > 0, edge * view.a / np.maximum(dalpha, 1e-300), np.inf)
    step_fs = opts.max_foreshortening * foot / R
    step = np.minimum(step_px, step_fs)
    g = 1.0 / step
    if view.slack > 0:
        g = _running_max(g, th, view.slack)
    G = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(th))])
    rings = [0.0]
    bounds = [0.0, theta_h, theta_cap] if 0.0 < theta_h < theta_cap else [0.0, theta_cap]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        g_lo, g_hi = np.interp([lo, hi], th, G)
        n = max(1, math.ceil(g_hi - g_lo - 1e-9))
        targets = g_lo + (g_hi - g_lo) * np.arange(1, n + 1) / n
        t = np.interp(targets, G, th)
        t[-1] = hi
        rings.extend(t.tolist())
    thetas = np.asarray(rings)
    spacing = np.diff(thetas) * R
    spacing = np.minimum(np.append(spacing, spacing[-1:]), np.append(spacing[:1], spacing))
    return thetas, spacing, theta_h, theta_cap


def _running_max(g: FloatArray, th: FloatArray, width: float) -> FloatArray:
    from scipy.ndimage import maximum_filter1d

    dth = th[1] - th[0] if th.size > 1 else 1.0
    size = 2 * int(math.ceil(width / max(dth, 1e-300))) + 1
    return maximum_filter1d(g, size=size, mode="nearest")


def _ring_counts(view: _View, thetas: FloatArray, radius: float, edge: float) -> IntArray:
    d, R = view.d_near, radius
    D = np.sqrt(d * d + R * R - 2.0 * d * R * np.cos(thetas))
    n = np.ceil(2.0 * math.pi * R * np.sin(thetas) / (edge * view.a * D)).astype(np.int64)
    if view.slack > 0:
        th = np.linspace(0, thetas[-1], THETA_SAMPLES)
        Dth = np.sqrt(d * d + R * R - 2.0 * d * R * np.cos(th))
        nth = 2.0 * math.pi * R * np.sin(th) / (edge * view.a * Dth)
        nth = _running_max(nth, th, view.slack)
        n = np.maximum(n, np.ceil(np.interp(thetas, th, nth)).astype(np.int64))
    n = np.maximum(n, MIN_RING_VERTICES)
    n[thetas == 0.0] = 1
    return n


@dataclass
class _Ring:
    theta: float
    n: int
    full: bool
    k: IntArray          # lattice indices (unwrapped for arcs), in increasing azimuth
    offset: int          # index of the ring's first vertex


def _ring_arcs(view: _View, thetas: FloatArray, counts: IntArray, radius: float,
               e1: FloatArray, e2: FloatArray, h_abs: float) -> list[_Ring]:
    """Vertex lattice indices per ring, culled to the field cone if there is one."""
    o = np.asarray(view.o)
    rings: list[_Ring] = []
    off = 0
    b = None if view.boresight is None else np.asarray(view.boresight)
    if b is not None:
        bo = float(b @ o)
        b1, b2 = float(b @ e1), float(b @ e2)
        bperp = math.hypot(b1, b2)
        phi0 = math.atan2(b2, b1)
    for th, n in zip(thetas, counts, strict=True):
        n = int(n)
        full = True
        k = np.arange(n, dtype=np.int64)
        if b is not None:
            d = view.d_near
            D = math.sqrt(max(d * d + radius * radius - 2 * d * radius * math.cos(th), 1.0))
            beta = view.cone + (h_abs + view.d_true_spread) / D
            A = (radius * math.cos(th) - d) * bo
            B = radius * math.sin(th) * bperp
            lim = D * math.cos(min(beta, math.pi))
            if B <= 1e-9 * radius:
                kappa = -math.inf if A >= lim else math.inf
            else:
                kappa = (lim - A) / B
            if kappa > 1.0:
                continue
            if kappa > -1.0:
                w = math.acos(kappa)
                k_lo = math.floor((phi0 - w) * n / (2 * math.pi)) - 1
                k_hi = math.ceil((phi0 + w) * n / (2 * math.pi)) + 1
                if k_hi - k_lo + 1 < n:
                    full = False
                    k = np.arange(k_lo, k_hi + 1, dtype=np.int64)
        rings.append(_Ring(theta=float(th), n=n, full=full, k=k, offset=off))
        off += k.size
    return rings


def _arc(r: _Ring, lo: float, hi: float) -> tuple[IntArray, FloatArray]:
    """Vertex indices and unwrapped azimuths of ring ``r`` covering ``[lo, hi]`` (plus a step)."""
    step = 2.0 * math.pi / r.n
    if r.full:
        if not math.isfinite(lo):  # the whole closed ring, back to its first vertex
            kk = np.arange(r.n + 1, dtype=np.int64)
        else:
            kk = np.arange(math.floor(lo / step) - 1, math.ceil(hi / step) + 2, dtype=np.int64)
            if kk.size > r.n + 1:
                kk = kk[: r.n + 1]
        idx = r.offset + (kk % r.n)
        return idx, kk * step
    sel = (r.k * step >= lo - step) & (r.k * step <= hi + step)
    kk = r.k[sel]
    return r.offset + np.flatnonzero(sel), kk * step


def _stitch(ia: IntArray, aa: FloatArray, ib: IntArray, ab: FloatArray) -> IntArray:
    """Triangles joining inner arc A and outer arc B (both sorted by azimuth), outward-facing."""
    m, n = ia.size - 1, ib.size - 1
    if m < 0 or n < 0 or m + n == 0:
        return np.zeros((0, 3), np.int64)
    ang = np.concatenate([aa[1:], ab[1:]])
    is_a = np.concatenate([np.ones(m, bool), np.zeros(n, bool)])
    order = np.argsort(ang, kind="stable")
    is_a = is_a[order]
    ca = np.cumsum(is_a) - is_a
    cb = np.cumsum(~is_a) - ~is_a
    v0 = ia[ca]
    v1 = ib[cb]
    v2 = np.where(is_a, ia[np.minimum(ca + 1, m)], ib[np.minimum(cb + 1, n)])
    return np.stack([v0, v1, v2], axis=1)


def _stitch_rings(inner: _Ring, outer: _Ring) -> IntArray:
    if inner.full and outer.full:
        ia, aa = _arc(inner, -math.inf, math.inf)
        ib, ab = _arc(outer, -math.inf, math.inf)
        return _stitch(ia, aa, ib, ab)
    spans = []
    for r in (inner, outer):
        if not r.full:
            step = 2.0 * math.pi / r.n
            spans.append((r.k[0] * step, r.k[-1] * step))
    lo = max(s[0] for s in spans)
    hi = min(s[1] for s in spans)
    if hi < lo:
        return np.zeros((0, 3), np.int64)
    ia, aa = _arc(inner, lo, hi)
    ib, ab = _arc(outer, lo, hi)
    return _stitch(ia, aa, ib, ab)


def _vertex_normals(v: FloatArray, f: IntArray) -> NDArray[np.float64]:
    """Area-weighted vertex normals (unit); face normals in float32 on float64 edge vectors."""
    a = v[f[:, 0]]
    e1 = (v[f[:, 1]] - a).astype(np.float32)
    e2 = (v[f[:, 2]] - a).astype(np.float32)
    del a
    fn = np.cross(e1, e2)  # |fn| = 2 area
    del e1, e2
    idx = f.ravel()  # corners of face i at 3i, 3i+1, 3i+2
    n = np.empty(v.shape, dtype=np.float64)
    for c in range(3):
        n[:, c] = np.bincount(idx, weights=np.repeat(fn[:, c], 3), minlength=v.shape[0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    lonely = norm[:, 0] == 0  # unreferenced vertex: use its radial direction
    n[lonely] = v[lonely]
    norm[lonely] = np.linalg.norm(v[lonely], axis=1, keepdims=True)
    n /= norm
    return n


def _sample_by_level(grid: EquirectangularGrid, lat: FloatArray, lon: FloatArray,
                     spacing: FloatArray, radius: float) -> tuple[NDArray[np.float32], int]:
    """Bilinear samples, each from the finest level with cells <= the vertex spacing."""
    c0 = grid.cell_size(radius)
    lev = np.floor(np.log2(np.maximum(spacing, 1e-9) / c0))
    lev = np.clip(lev, 0, grid.max_level).astype(np.int64)
    out = np.empty(lat.shape, np.float32)
    for k in np.unique(lev):
        sel = lev == k
        out[sel] = grid.level(int(k)).sample(lat[sel], lon[sel])
    return out, int(lev.min()) if lev.size else 0


# ------------------------------------------------------------------------- public API
def view_mesh(dem: DemGrid, camera: Camera, camera_position_body_m: ArrayLike,
              albedo: AlbedoGrid | None = None, *, camera_to_body: ArrayLike | None = None,
              options: MeshOptions | None = None,
              cache: MeshCache | None = MESH_CACHE,
              detail: SubPostingDetail | None = None) -> trimesh.Trimesh:
    """The mesh of the part of the Moon visible from a camera position.

    Parameters
    ----------
    dem : DemGrid
        Terrain (heights [m] above ``dem.reference_radius``).
    camera : Camera
        Sets the pixel angle (and, with ``camera_to_body``, the field of view).
    camera_position_body_m : (3,) array_like
        Camera position in the Moon body-fixed frame [m], from the Moon centre.
    albedo : AlbedoGrid, optional
        If given, ``vertex_attributes['albedo']`` is sampled from it.
    camera_to_body : (3, 3) array_like, optional
        Rotation camera -> Moon body-fixed: only the field of view (plus margins) is built.
    options : MeshOptions, optional
    cache : MeshCache or None
        Where meshes are kept (``None``: no caching).
    detail : SubPostingDetail, optional
        Fractal relief added to the vertices finer than a DEM cell (the cap and terrain
        bounds include ``detail.max_detail_m``); a view nowhere finer than the posting gets
        the same mesh as without it.

    Returns
    -------
    trimesh.Trimesh
        Body-fixed vertices [m], outward faces, ``vertex_normals``, ``vertex_attributes``
        ``lat``/``lon`` [rad], ``height`` [m], ``albedo`` [-]; ``metadata['starnav']``.

    Raises
    ------
    GeometryError
        if the camera is not above the highest terrain.
    """
    opts = options or MeshOptions()
    c = np.asarray(camera_position_body_m, dtype=float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise GeometryError(f"camera_position_body_m must be a finite 3-vector [m], got {c!r}")
    R = dem.reference_radius
    h_min, h_max = dem.height_range
    r_lo, r_hi = R + min(h_min, h_max), R + max(h_max, h_min)
    d = float(np.linalg.norm(c))
    if d <= r_hi:
        raise GeometryError(
            f"camera at {d / 1e3:.3f} km from the Moon centre is not above the highest terrain "
            f"({r_hi / 1e3:.3f} km); expected a range > {r_hi / 1e3:.3f} km"
        )
    cam_to_body = None
    if camera_to_body is not None:
        cam_to_body = np.asarray(camera_to_body, dtype=float)
        if cam_to_body.shape != (3, 3) or not np.allclose(cam_to_body @ cam_to_body.T,
                                                          np.eye(3), atol=1e-9):
            raise GeometryError(f"camera_to_body must be a rotation matrix, got {cam_to_body!r}")
    r_bound = r_hi + (0.0 if detail is None else float(detail.max_detail_m))
    view = _quantise_view(c, camera, cam_to_body, opts, R, r_bound)
    key = (dem.uid, None if albedo is None else albedo.uid, _opts_key(opts), view,
           round(R, 3), None if detail is None else detail.key)
    if cache is not None:
        hit = cache.get(key)
        if hit is not None:
            return hit
    t0 = time.perf_counter()
    mesh = _build(dem, albedo, view, opts, R, r_lo, r_hi, max(abs(h_min), abs(h_max)), detail)
    mesh.metadata["starnav"]["seconds"] = time.perf_counter() - t0
    logger.info("view mesh: %d vertices, %d faces, cap %.3f deg, %.3f s",
                len(mesh.vertices), len(mesh.faces),
                math.degrees(mesh.metadata["starnav"]["theta_cap"]), time.perf_counter() - t0)
    if cache is not None:
        if cache.maxsize != opts.cache_size and cache is MESH_CACHE:
            cache.maxsize = opts.cache_size
        cache.put(key, mesh)
    return mesh


def _opts_key(opts: MeshOptions) -> tuple[Any, ...]:
    """Options that change the mesh (cache size excluded)."""
    return tuple(v for k, v in asdict(opts).items() if k != "cache_size")


@dataclass
class _Layout:
    edge: float                # projected edge used [px]
    rings: list[_Ring]
    ring_spacing: FloatArray   # vertex spacing on each kept ring [m]
    theta_h: float
    theta_cap: float


def _layout(view: _View, opts: MeshOptions, R: float, r_lo: float, r_hi: float, h_abs: float,
            e1: FloatArray, e2: FloatArray) -> _Layout:
    """Rings and arcs of the mesh (edges coarsened to the vertex budget)."""
    edge = opts.edge_px
    for _attempt in range(4):
        thetas, spacing, theta_h, theta_cap = _ring_thetas(view, R, r_lo, r_hi, edge, opts)
        counts = _ring_counts(view, thetas, R, edge)
        rings = _ring_arcs(view, thetas, counts, R, e1, e2, h_abs)
        nv = sum(r.k.size for r in rings)
        if nv <= opts.max_vertices:
            break
        new = edge * math.sqrt(nv / opts.max_vertices) * 1.05
        logger.warning("view mesh: %d vertices exceed max_vertices=%d; edge %.3g -> %.3g px",
                       nv, opts.max_vertices, edge, new)
        edge = new
    ring_spacing = {float(t): float(s) for t, s in zip(thetas, spacing, strict=True)}
    sp = np.array([min(ring_spacing[r.theta], 2.0 * math.pi * R * math.sin(r.theta) / r.n
                       if r.n > 1 else ring_spacing[r.theta]) for r in rings])
    return _Layout(edge, rings, sp, theta_h, theta_cap)


def _build(dem: DemGrid, albedo: AlbedoGrid | None, view: _View, opts: MeshOptions, R: float,
           r_lo: float, r_hi: float, h_abs: float,
           detail: SubPostingDetail | None = None) -> trimesh.Trimesh:
    import trimesh

    o = np.asarray(view.o)
    e1, e2 = _frame(o)
    lay = _layout(view, opts, R, r_lo, r_hi, h_abs, e1, e2)
    if detail is not None and not (lay.rings and lay.ring_spacing.min() < detail.posting):
        detail = None  # footprint nowhere finer than the posting: the mesh of the DEM alone
    if detail is not None:  # bounds widened by the largest detail, then laid out again
        r_lo, r_hi = r_lo - detail.max_detail_m, r_hi + detail.max_detail_m
        h_abs += detail.max_detail_m
        if view.d_near <= r_hi:
            raise GeometryError(
                f"camera at {view.d_near / 1e3:.3f} km from the Moon centre is not above the "
                f"highest terrain with its sub-posting detail ({r_hi / 1e3:.3f} km)")
        lay = _layout(view, opts, R, r_lo, r_hi, h_abs, e1, e2)
    rings, edge, theta_h, theta_cap = lay.rings, lay.edge, lay.theta_h, lay.theta_cap
    if not rings:
        raise GeometryError("no part of the Moon lies in the field of view (nothing to mesh)")
    # vertex directions
    th = np.concatenate([np.full(r.k.size, r.theta) for r in rings])
    phi = np.concatenate([r.k * (2.0 * math.pi / r.n) for r in rings])
    sp = np.repeat(lay.ring_spacing, [r.k.size for r in rings])
    st, ct = np.sin(th), np.cos(th)
    u = (ct[:, None] * o[None, :]
         + (st * np.cos(phi))[:, None] * e1[None, :]
         + (st * np.sin(phi))[:, None] * e2[None, :])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    lat = np.arctan2(u[:, 2], np.hypot(u[:, 0], u[:, 1]))
    lon = (np.arctan2(u[:, 1], u[:, 0]) + math.pi) % (2.0 * math.pi) - math.pi
    heights, level = _sample_by_level(dem, lat, lon, sp, R)
    n_detail = 0
    if detail is None:
        verts = u * (R + heights.astype(np.float64))[:, None]
    else:
        h64 = heights.astype(np.float64) + detail.heights(u, sp)
        n_detail = int(np.count_nonzero(sp < detail.posting))
        verts = u * (R + h64)[:, None]
        heights = h64.astype(np.float32)
    # faces
    faces = [_stitch_rings(a, b) for a, b in zip(rings[:-1], rings[1:], strict=True)]
    f = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    good = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[good]
    normals = _vertex_normals(verts, f)
    mesh = trimesh.Trimesh(vertices=verts, faces=f, vertex_normals=normals, process=False,
                           validate=False)
    mesh.vertex_attributes["lat"] = lat.astype(np.float32)
    mesh.vertex_attributes["lon"] = lon.astype(np.float32)
    mesh.vertex_attributes["height"] = heights
    if albedo is not None:
        alb, _ = _sample_by_level(albedo, lat, lon, sp, R)
        mesh.vertex_attributes["albedo"] = alb
    mesh.metadata["starnav"] = {
        "frame": "moon_body_fixed", "units": "m", "dem": dem.source, "dem_uid": dem.uid,
        "albedo": None if albedo is None else albedo.source,
        "theta_horizon": theta_h, "theta_cap": theta_cap, "rings": len(rings),
        "edge_px": edge, "dem_level": level, "sub_camera_direction": list(view.o),
        "range_m": (view.d_near, view.d_far),
    }
    if detail is not None:
        mesh.metadata["starnav"]["detail"] = {**detail.summary(), "vertices": n_detail}
    return mesh


#: The mesh file types :func:`save_mesh` writes, by suffix (none: PLY).
MESH_FORMATS = (".ply", ".obj", ".glb", ".stl", ".off")


def check_mesh_path(path: Any) -> str:
    """The file type of the mesh file ``path`` (its suffix without the dot, ``ply`` when it
    has none); a suffix :func:`save_mesh` cannot write is a :class:`ConfigError`."""
    suffix = Path(path).suffix.lower()
    if suffix and suffix not in MESH_FORMATS:
        raise ConfigError("--out", str(path), "a mesh file ending in " + ", ".join(MESH_FORMATS))
    return suffix.lstrip(".") or "ply"


def save_mesh(mesh: trimesh.Trimesh, path: Any) -> Any:
    """Write a mesh (PLY with normals and the vertex attributes as float properties) through a
    temporary file and a rename. PLY stores float32 coordinates (~0.1 m at the lunar radius)."""
    p = Path(path)
    suffix = check_mesh_path(p)
    with atomic_path(p, suffix=f".{suffix}") as tmp:
        mesh.export(str(tmp), file_type=suffix)
    return p


__all__ = ["MESH_CACHE", "MESH_FORMATS", "MeshCache", "MeshOptions", "check_mesh_path",
           "field_cone", "pixel_angle", "save_mesh", "view_mesh"]
