"""Plate solving of any star camera's frame: lost in space with the focal length only roughly known.

Unlike the tracker pipeline (:mod:`starnav.stars.attitude`), every setting here follows the
user's camera and frame. Each step in full: docs/methods.md, "starnav.stars.plate".

Technique
---------
1. Detections (:func:`starnav.stars.centroid.find_stars`, in DN).
2. Settings from the camera (:func:`plate_settings`): index depth from the field's solid
   angle (and, when the frame states it, no deeper than the camera can reach), tolerances
   from the pixel scale.
3. Scale-free triangles matched to catalogue pairs within the focal-length tolerance.
4. Screening and verification: a count rule with a false acceptance below ``alpha`` per frame;
   two verified attitudes: ambiguous.
5. Refinement of attitude, focal length and ``k1`` by least squares on the pixel residuals.
6. Covariance ``s^2 (J^T J)^-1`` of the final fit.

Conventions: RA, Dec of the principal point's direction; roll the angle of celestial north
from the image's up, counter-clockwise (as tetra3 and cedar-solve). The knobs are
:class:`PlateOptions`.

References
----------
D. Mortari et al., "The pyramid star identification technique", Navigation 51 (2004) 171-183.
F. L. Markley, J. Astronaut. Sci. 36 (1988) 245 (SVD attitude).
D. Lang et al., "Astrometry.net: blind astrometric calibration of arbitrary astronomical
images", AJ 139 (2010) 1782.

Index
-----
:func:`solve_plate`, :class:`PlateSolution`, :class:`PlateOptions`, :func:`plate_settings`,
:class:`PlateSettings`, :func:`pattern_index`, :func:`field_solid_angle`, :func:`ra_dec_roll`,
:func:`index_cache_dir`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import itertools
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.special import pdtrc

from starnav.atomic import atomic_write_bytes
from starnav.cache import BoundedCache
from starnav.camera import Camera
from starnav.errors import ConfigError
from starnav.scenes.trajectory import default_cache_dir
from starnav.stars.catalogue import StarCatalogue, hipparcos
from starnav.stars.centroid import CentroidOptions, Centroids, find_stars
from starnav.stars.identify import MatchResult, StarIndex, _index
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: One arcsecond [rad].
ARCSEC = math.pi / (180.0 * 3600.0)
#: Version of the on-disk pattern index (bump when its content changes).
INDEX_FORMAT = 1
#: Pattern indexes kept in memory (one per camera field, catalogue and epoch year).
_INDEXES: BoundedCache[tuple, StarIndex] = BoundedCache(4)
#: k-d trees of the indexes' star directions and catalogue magnitude quantiles (keyed by the
#: array's id, checked by identity).
_TREES: BoundedCache[object, tuple] = BoundedCache(8)


@dataclass(frozen=True)
class PlateOptions:
    """Knobs of :func:`solve_plate` (module steps; lengths in pixels of the frame).

    Attributes
    ----------
    focal_tolerance : float
        Relative focal-length uncertainty searched (step 3) [-].
    stars_per_field : float
        Mean number of index stars in the field, over the sky (step 2).
    index_v_max : float
        Faintest index star [mag] whatever the field (Hipparcos is complete to V ~ 8-9).
    n_brightest : int
        Detections forming triangles (fewer when fewer are detected).
    n_sigma, floor_px : float
        Pair-angle tolerance in centroid sigmas; centroid sigma floor (seeing, unmodelled
        distortion, blends) [px].
    catalogue_tol_arcsec : float
        Catalogue, proper-motion and refraction allowance of a pair angle.
    match_px : float
        Verification radius [px] (plus the scale's own uncertainty at the field's edge).
    refine_n_sigma : float
        Refinement keeps stars within this many residual rms.
    false_match_probability : float
        Per frame (step 4).
    max_hypotheses, screen_stars : int
        Candidate attitudes verified at most; further bright detections scoring a candidate.
    k1_min_stars, min_stars : int
        Fewest well-spread matched stars to fit ``k1``; fewest detections to try.
    verify_v_limit : float
        Faintest catalogue star used by verification and refinement [mag].
    """

    focal_tolerance: float = 0.05
    stars_per_field: float = 25.0
    index_v_max: float = 9.0
    n_brightest: int = 15
    n_sigma: float = 5.0
    floor_px: float = 0.3
    catalogue_tol_arcsec: float = 10.0
    match_px: float = 3.0
    refine_n_sigma: float = 4.0
    false_match_probability: float = 1e-9
    max_hypotheses: int = 2000
    screen_stars: int = 8
    k1_min_stars: int = 20
    min_stars: int = 4
    verify_v_limit: float = 10.0
    centroid: CentroidOptions = dataclasses.field(
        default_factory=lambda: CentroidOptions(weight_sigma_px=1.0, detect_bin=2))

    def __post_init__(self) -> None:
        if not 0.0 <= self.focal_tolerance < 0.5:
            raise ConfigError("plate.focal_tolerance", self.focal_tolerance,
                              "a relative tolerance in [0, 0.5)")
        if self.n_brightest < 3 or self.min_stars < 3:
            raise ConfigError("plate.n_brightest", (self.n_brightest, self.min_stars),
                              "n_brightest and min_stars >= 3")
        for name in ("stars_per_field", "n_sigma", "floor_px", "catalogue_tol_arcsec",
                     "match_px", "refine_n_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"plate.{name}", v, "a finite value > 0")
        if not 0 < self.false_match_probability < 1:
            raise ConfigError("plate.false_match_probability", self.false_match_probability,
                              "a probability in (0, 1)")


@dataclass(frozen=True)
class PlateSettings:
    """The settings :func:`plate_settings` derives from a camera (module step 2)."""

    field_solid_angle_sr: float
    index_v_limit: float
    pixel_rad: float
    match_radius_rad: float
    pair_tol_floor_rad: float

    def as_dict(self) -> dict[str, float]:
        return {"field_solid_angle_deg2": self.field_solid_angle_sr * (180 / math.pi) ** 2,
                "index_v_limit": self.index_v_limit,
                "pixel_arcsec": self.pixel_rad / ARCSEC,
                "match_radius_arcsec": self.match_radius_rad / ARCSEC,
                "pair_tolerance_floor_arcsec": self.pair_tol_floor_rad / ARCSEC}


def field_solid_angle(camera: Camera) -> float:
    """Solid angle of the detector's rectangular field [sr]: ``4 asin(sin a sin b)``."""
    a, b = 0.5 * camera.fov_x, 0.5 * camera.fov_y
    return 4.0 * math.asin(math.sin(a) * math.sin(b))


def _nth_brightest_v(catalogue: StarCatalogue, n: int) -> float:
    """V of the catalogue's ``n``-th brightest star (from 0), the partition kept per
    catalogue and ``n``."""
    key = ("v", id(catalogue.v), n)
    hit = _TREES.get(key)
    if hit is None or hit[0] is not catalogue.v:
        hit = (catalogue.v, float(np.partition(catalogue.v, n)[n]))
        _TREES.put(key, hit)
    return hit[1]


def plate_settings(camera: Camera, catalogue: StarCatalogue,
                   options: PlateOptions | None = None,
                   limiting_v: float | None = None) -> PlateSettings:
    """Index depth and tolerances of ``camera`` (module step 2); ``limiting_v``: the faintest
    V the camera can show in the frame (an upper bound, :func:`solve_plate`), which caps the
    index (fainter stars cannot be among the detections)."""
    opt = options or PlateOptions()
    omega = field_solid_angle(camera)
    n_sky = int(min(len(catalogue) - 1, opt.stars_per_field * 4.0 * math.pi / omega))
    v_lim = round(min(_nth_brightest_v(catalogue, n_sky), opt.index_v_max,
                      math.inf if limiting_v is None else limiting_v), 2)
    pix = 1.0 / camera.fx
    return PlateSettings(omega, v_lim, pix, opt.match_px * pix,
                         opt.n_sigma * math.sqrt(2.0) * opt.floor_px * pix
                         + opt.catalogue_tol_arcsec * ARCSEC)


@dataclass(frozen=True)
class PlateSolution(MatchResult):
    """One frame's plate solution, or why there is none.

    Attributes
    ----------
    status, reason : str
        ``"ok"``, ``"too-few-stars"``, ``"unidentified"`` or ``"ambiguous"``, and why.
    centroids : Centroids
        The detections (brightest first).
    camera : Camera
        The refined camera (focal length, ``k1``); the nominal one when not solved.
    R_cam_to_inertial : (3, 3) array or None
    covariance_rad2 : (3, 3) array or None
        Attitude error covariance, camera axes (``z`` roll) [rad^2].
    focal_length_sigma_m, k1_sigma : float
        1-sigma of the refined focal length [m] and ``k1`` (nan when ``k1`` is not fitted).
    detection_index, catalogue_row, hip : (m,) int arrays
        Matched detections and their catalogue rows and Hipparcos numbers.
    v_mag : (m,) array
    residual_px : (m, 2) array
        Detection minus projected catalogue star [px].
    settings : PlateSettings
    n_required, lam, hypotheses :
        The count rule's ``k``, ``lambda`` and the candidates verified.
    time_extract_s, time_solve_s : float
    """

    status: str
    reason: str
    centroids: Centroids
    camera: Camera
    settings: PlateSettings
    R_cam_to_inertial: FloatArray | None = None
    covariance_rad2: FloatArray | None = None
    focal_length_sigma_m: float = math.nan
    k1_sigma: float = math.nan
    detection_index: NDArray[np.int64] = dataclasses.field(
        default_factory=lambda: np.zeros(0, np.int64))
    catalogue_row: NDArray[np.int64] = dataclasses.field(
        default_factory=lambda: np.zeros(0, np.int64))
    hip: NDArray[np.int64] = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    v_mag: FloatArray = dataclasses.field(default_factory=lambda: np.zeros(0))
    residual_px: FloatArray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    n_required: int = 0
    lam: float = 0.0
    hypotheses: int = 0
    time_extract_s: float = 0.0
    time_solve_s: float = 0.0

    @property
    def boresight(self) -> FloatArray:
        """Unit vector of the principal point's direction, ICRS."""
        return np.asarray(self.R_cam_to_inertial)[:, 2]

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float]:
        """RA, Dec of the boresight and roll (module conventions) [deg]."""
        return ra_dec_roll(np.asarray(self.R_cam_to_inertial))

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """Camera -> ICRS rotation as a scalar-last unit quaternion."""
        return Rotation.from_matrix(np.asarray(self.R_cam_to_inertial)).as_quat()

    @property
    def sigma_arcsec(self) -> FloatArray:
        if self.covariance_rad2 is None:
            return np.full(3, np.nan)
        return np.sqrt(np.diag(self.covariance_rad2)) / ARCSEC

    @property
    def residual_arcsec(self) -> FloatArray:
        """Residual length of each matched star [arcsec]."""
        return np.hypot(*self.residual_px.T) / self.camera.fx / ARCSEC

    @property
    def rms_arcsec(self) -> float:
        r = self.residual_arcsec
        return float(np.sqrt(np.mean(r**2))) if r.size else math.nan

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(self.camera.fov_x)


def ra_dec_roll(R: FloatArray) -> tuple[float, float, float]:
    """RA, Dec [deg] of ``R[:, 2]`` and the roll [deg] of celestial north from the image's up,
    counter-clockwise on the displayed image (``R`` camera -> ICRS; camera x right, y down)."""
    z = R[:, 2]
    ra = math.degrees(math.atan2(z[1], z[0])) % 360.0
    dec = math.degrees(math.asin(max(-1.0, min(1.0, z[2]))))
    n_cam = R.T @ np.array([0.0, 0.0, 1.0])  # celestial pole in camera axes
    roll = math.degrees(math.atan2(-n_cam[0], -n_cam[1])) % 360.0
    return ra, dec, roll


# --------------------------------------------------------------------------- helpers
def _normalized(uv: FloatArray, camera: Camera) -> FloatArray:
    return camera.pixel_to_normalized(uv, undistort=camera.has_distortion)


def _vectors(xy: FloatArray, scale: float = 1.0) -> FloatArray:
    d = np.concatenate([xy / scale, np.ones((xy.shape[0], 1))], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _vectors_batch(xy: FloatArray, scales: FloatArray) -> FloatArray:
    """Unit vectors of ``xy`` (n, 2) for each focal-length scale: (len(scales), n, 3)."""
    d = np.empty((scales.size, xy.shape[0], 3))
    d[..., :2] = xy[None] / scales[:, None, None]
    d[..., 2] = 1.0
    return d / np.linalg.norm(d, axis=2, keepdims=True)


def _dedupe(c: Centroids, min_sep_px: float = 1.0) -> Centroids:
    if len(c) < 2:
        return c
    tree = cKDTree(c.uv)
    drop = set()
    for i, j in sorted(tree.query_pairs(min_sep_px)):
        drop.add(max(i, j))  # brightest first: keep the brighter
    keep = [k for k in range(len(c)) if k not in drop]
    return c.subset(np.asarray(keep, np.int64))


def _svd_batch(b: FloatArray, r: FloatArray) -> FloatArray:
    """Attitudes ``A`` (``b ~ A r``) of ``n`` triangles at once: ``b``, ``r`` are (n, 3, 3)
    with the vectors as rows."""
    B = np.einsum("nki,nkj->nij", b, r)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    D = np.zeros_like(B)
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    return U @ D @ Vt


def _project(A: FloatArray, r: FloatArray, camera: Camera, scale: float = 1.0
             ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Pixels of inertial unit vectors ``r`` for attitude ``A`` (inertial -> camera) with the
    focal length scaled by ``scale``; and whether each is in front and on the detector."""
    c = r @ A.T
    front = c[:, 2] > 1e-6
    z = np.where(front, c[:, 2], 1.0)
    xy = c[:, :2] / z[:, None]
    cam = dataclasses.replace(camera, focal_length=camera.focal_length * scale)
    uv = cam.project(np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1),
                     distort=cam.has_distortion)
    inside = front & (uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5) \
        & (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5)
    return uv, inside


def _field_stars(cat: StarCatalogue, A: FloatArray, camera: Camera, scale: float,
                 epoch: float, v_limit: float, n_max: int
                 ) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """The ``n_max`` brightest catalogue stars (``V <= v_limit``) on the detector for the
    attitude ``A`` and the scale: rows, directions, pixels."""
    radius = min(0.5 * camera.fov_diagonal / scale * 1.05 + 1e-3, math.pi)
    cand = np.asarray(cat._tree.query_ball_point(A[2], 2.0 * math.sin(0.5 * radius)), np.int64)
    cand = cand[cat.v[cand] <= v_limit]
    if cand.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2))
    cand = cand[np.argsort(cat.v[cand], kind="stable")]  # brightest first
    d = cat.directions(epoch, cand)
    uv, inside = _project(A, d, camera, scale)
    ix = np.nonzero(inside)[0][:n_max]
    return cand[ix], d[ix], uv[ix]


def _match_px(uv_det: FloatArray, uv_cat: FloatArray, radius_px: float | FloatArray
              ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """One-to-one nearest matches of detections to catalogue pixels within ``radius_px``."""
    if uv_cat.shape[0] == 0 or uv_det.shape[0] == 0:
        z = np.zeros(0, np.int64)
        return z, z
    dist, idx = cKDTree(uv_cat).query(uv_det, k=1)
    ok = dist <= radius_px
    det = np.nonzero(ok)[0]
    cat = idx[ok]
    order = np.argsort(dist[ok], kind="stable")
    _, first = np.unique(cat[order], return_index=True)
    keep = np.sort(order[first])
    return det[keep].astype(np.int64), cat[keep].astype(np.int64)


def _required(n_det: int, n_cat: int, omega_match: float, omega_field: float,
              n_hyp: int, alpha: float) -> tuple[int, float]:
    lam = max(n_det, 0) * min(1.0, n_cat * omega_match / omega_field)
    return _poisson_count(lam, alpha / n_hyp), lam


def _poisson_count(lam: float, q: float) -> int:
    """Smallest ``k >= 3`` with ``P(X >= k) <= q`` for ``X`` Poisson of mean ``lam``
    (``P(X >= k) = pdtrc(k - 1, lam)``, the Poisson upper tail)."""
    if lam <= 0:
        return 3
    hi = int(lam + 12.0 * math.sqrt(lam) + 60.0)
    while True:
        ks = np.arange(1, hi + 1)
        ok = pdtrc(ks - 1, lam) <= q
        if ok.any():
            return max(int(ks[np.argmax(ok)]), 3)
        hi *= 2


# --------------------------------------------------------------------------- index
def index_cache_dir() -> Path:
    """``STARNAV_CACHE_DIR``, else ``$XDG_CACHE_HOME/starnav``, else ``~/.cache/starnav``
    (the trajectory cache's place; every file there may be deleted at any time)."""
    return default_cache_dir()


def _catalogue_fingerprint(cat: StarCatalogue) -> str:
    h = hashlib.sha256()
    for a in (cat.hip, cat.v, cat.ra, cat.dec, cat.pm_ra_cosdec, cat.pm_dec):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def pattern_index(cat: StarCatalogue, v_limit: float, max_separation_rad: float,
                  epoch_jyear: float, cache_dir: Path | bool | None = None) -> StarIndex:
    """The pair table of the stars brighter than ``v_limit`` up to ``max_separation_rad``,
    built once per camera field (and catalogue, epoch year): kept in memory and, unless
    ``cache_dir`` is False, as ``.npz`` in :func:`index_cache_dir` (or ``cache_dir``), where it
    is read back instead of rebuilt. An unreadable cache file is rebuilt."""
    v = round(float(v_limit), 3)
    sep = round(float(max_separation_rad), 4)
    year = float(round(epoch_jyear))
    mem_key = (id(cat), len(cat), v, sep, year)
    hit = _INDEXES.get(mem_key)
    if hit is not None:
        return hit
    path = None
    if cache_dir is not False:
        base = index_cache_dir() if cache_dir is None or cache_dir is True else Path(cache_dir)
        key = hashlib.sha256(json.dumps(
            [INDEX_FORMAT, _catalogue_fingerprint(cat), v, sep, year]).encode()).hexdigest()
        path = base / f"star_index_{key[:20]}.npz"
    idx = _load_index(path) if path is not None and path.is_file() else None
    if idx is None:
        idx = _index.__wrapped__(id(cat), v, sep, year, cat)
        if path is not None:
            try:
                buf = io.BytesIO()
                np.savez(buf, directions=idx.directions, rows=idx.rows, pair_a=idx.pair_a,
                         pair_b=idx.pair_b, angle=idx.angle)
                path.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_bytes(path, buf.getvalue())
            except OSError as err:  # a cache that cannot be written is no error
                log.warning("star index not cached at %s (%s)", path, err)
    _INDEXES.put(mem_key, idx)
    return idx


def _index_tree(idx: StarIndex) -> cKDTree:
    """The k-d tree of an index's star directions, built once per index."""
    key = id(idx.directions)
    hit = _TREES.get(key)
    if hit is None or hit[0] is not idx.directions:
        hit = (idx.directions, cKDTree(idx.directions))
        _TREES.put(key, hit)
    return hit[1]


def _load_index(path: Path) -> StarIndex | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            return StarIndex(z["directions"], z["rows"], z["pair_a"], z["pair_b"], z["angle"])
    except (OSError, ValueError, KeyError, EOFError) as err:
        log.warning("ignoring unreadable star index cache %s (%s)", path, err)
        return None


# --------------------------------------------------------------------------- step 3
def _scaled_triangles(idx: StarIndex, b: FloatArray, i: int, j: int, k: int, tol: FloatArray,
                      t: float) -> tuple[NDArray[np.int64], ...]:
    m = np.array([math.acos(min(1.0, float(b[i] @ b[j]))),
                  math.acos(min(1.0, float(b[i] @ b[k]))),
                  math.acos(min(1.0, float(b[j] @ b[k])))])

    def window(a: float, tl: float):
        lo, hi = np.searchsorted(idx.angle, [a / (1.0 + t) - tl, a / (1.0 - t) + tl])
        return idx.pair_a[lo:hi], idx.pair_b[lo:hi], idx.angle[lo:hi]

    aij, bij, cij_w = window(m[0], tol[0])
    aik, bik, cik_w = window(m[1], tol[1])
    z = np.zeros(0, np.int64)
    if aij.size == 0 or aik.size == 0:
        return z, z, z, np.zeros(0)
    # stable sorts of the star numbers: a radix sort when they fit in 16 bits
    key = np.uint16 if idx.directions.shape[0] <= 65536 else np.int64
    oj = np.argsort(aij.astype(key), kind="stable")
    ok_ = np.argsort(aik.astype(key), kind="stable")
    sa_j, sa_k = aij[oj], aik[ok_]
    # the scales the two joined sides allow, m / c +- tol / c, must overlap (a necessary
    # condition of the common-scale test below, on the table's stored angles): for a first
    # side of angle c_ij the second's angle lies in [(m1 - tol1) c_ij / (m0 + tol0),
    # (m1 + tol1) c_ij / (m0 - tol0)], searched within each star's block of the second
    # window (sorted by star, then angle) on the key star + angle / span
    cs_k = cik_w[ok_]
    span = 2.0 * float(cik_w.max()) + 1e-12  # angle / span <= 0.5
    key_k = sa_k + cs_k / span
    cj = cij_w[oj]
    lo_c = (m[1] - tol[1]) * cj / (m[0] + tol[0]) * (1.0 - 1e-9)
    hi_c = (np.where(m[0] > tol[0], (m[1] + tol[1]) * cj / max(m[0] - tol[0], 1e-300),
                     np.inf) * (1.0 + 1e-9))
    lo = np.searchsorted(key_k, sa_j + np.clip(lo_c / span, 0.0, 0.75), "left")
    hi = np.searchsorted(key_k, sa_j + np.clip(hi_c / span, 0.0, 0.75), "right")
    cnt = np.maximum(hi - lo, 0)
    n = int(cnt.sum())
    if n == 0:
        return z, z, z, np.zeros(0)
    rep = np.repeat(np.arange(cnt.size), cnt)
    start = np.cumsum(cnt) - cnt
    kpos = np.repeat(lo - start, cnt) + np.arange(n)
    jrow = oj[rep]
    krow = ok_[kpos]
    cij = cij_w[jrow]
    cik = cik_w[krow]
    keep = np.abs(m[0] / cij - m[1] / cik) <= tol[0] / cij + tol[1] / cik
    jrow, krow = jrow[keep], krow[keep]
    si = aij[jrow].astype(np.int64)
    sj = bij[jrow].astype(np.int64)
    sk = bik[krow].astype(np.int64)
    cij, cik = cij[keep], cik[keep]
    keep = sj != sk
    si, sj, sk, cij, cik = si[keep], sj[keep], sk[keep], cij[keep], cik[keep]
    d = idx.directions
    # the third side within its window (a necessary condition, on cosines: no arccos for
    # the many that fail)
    cos_jk = np.einsum("ij,ij->i", d[sj], d[sk])
    lo_a = max((m[2] - tol[2]) / (1.0 + t), 0.0)
    hi_a = min((m[2] + tol[2]) / (1.0 - t), math.pi)
    keep = (cos_jk <= math.cos(lo_a) + 1e-12) & (cos_jk >= math.cos(hi_a) - 1e-12)
    si, sj, sk, cij, cik = si[keep], sj[keep], sk[keep], cij[keep], cik[keep]
    cjk = np.arccos(np.minimum(1.0, cos_jk[keep]))
    s = m.sum() / np.maximum(cij + cik + cjk, 1e-12)
    keep = np.abs(s - 1.0) <= t + 1e-12
    keep &= np.abs(m[0] - s * cij) <= tol[0]
    keep &= np.abs(m[1] - s * cik) <= tol[1]
    keep &= np.abs(m[2] - s * cjk) <= tol[2]
    si, sj, sk, s = si[keep], sj[keep], sk[keep], s[keep]
    sense = float(b[i] @ np.cross(b[j], b[k]))
    keep = np.einsum("ij,ij->i", d[si], np.cross(d[sj], d[sk])) * sense > 0
    return si[keep], sj[keep], sk[keep], s[keep]


@functools.lru_cache(maxsize=8)
def _triangle_order(m: int) -> list[tuple[int, int, int]]:
    return sorted(itertools.combinations(range(m), 3), key=lambda t: (t[2], t[1], t[0]))


def _rotvec_matrix(w: FloatArray) -> FloatArray:
    """Rotation matrix of the rotation vector ``w`` (Rodrigues)."""
    th = math.sqrt(float(w @ w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * K + (1.0 - math.cos(th)) * (K @ K)


def _fit_plate(uv: FloatArray, dirs: FloatArray, R: FloatArray, cam: Camera, fit_k1: bool,
               iterations: int = 20) -> tuple[FloatArray, Camera, FloatArray, FloatArray]:
    """Gauss-Newton over the small rotation ``w`` (camera axes), ``log f`` and ``k1`` of the
    pixel residuals ``uv - project(R^T d)`` (module step 5), re-linearised about the current
    estimate at each step: the analytic Jacobian of :meth:`Camera.project` (pinhole, the
    camera's Brown-Conrady terms; ``d c / d w = [c]_x`` for ``c -> Rot(w)^T c``). Returns the
    refined ``R`` (camera -> inertial) and camera, the residuals (n, 2) and the Jacobian of
    the last linearisation (2n, 4 or 5) [px per parameter]."""
    n_p = 5 if fit_k1 else 4
    last = False
    for it in range(iterations + 1):
        last = last or it == iterations
        c = dirs @ R  # camera axes
        x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
        xy = np.stack([x, y], axis=1)
        xd = cam.distort(xy) if cam.has_distortion else xy
        f = np.array([cam.fx, cam.fy])
        res = uv - (xd * f + np.array([cam.cx, cam.cy]))
        # d(x, y)/dw of the pinhole through dc/dw = [c]_x, in closed form:
        # dx/dw = (x y, -(1 + x^2), y), dy/dw = (1 + y^2, -x y, -x)
        dxy_dw = np.empty((c.shape[0], 2, 3))
        xy_ = x * y
        dxy_dw[:, 0, 0] = xy_
        dxy_dw[:, 0, 1] = -1.0 - x * x
        dxy_dw[:, 0, 2] = y
        dxy_dw[:, 1, 0] = 1.0 + y * y
        dxy_dw[:, 1, 1] = -xy_
        dxy_dw[:, 1, 2] = -x
        if cam.has_distortion:
            dxy_dw = cam.distortion_jacobian(xy) @ dxy_dw
        J = np.empty((c.shape[0], 2, n_p))
        J[:, :, :3] = f[None, :, None] * dxy_dw
        J[:, :, 3] = f * xd
        if fit_k1:
            J[:, :, 4] = f * xy * (x * x + y * y)[:, None]
        J = J.reshape(-1, n_p)
        if last:
            break
        # normal equations (a handful of parameters); least squares if they are singular
        try:
            step = np.linalg.solve(J.T @ J, J.T @ res.ravel())
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(J, res.ravel(), rcond=None)[0]
        R = R @ _rotvec_matrix(step[:3])
        cam = dataclasses.replace(cam, focal_length=cam.focal_length * math.exp(step[3]),
                                  k1=cam.k1 + (float(step[4]) if fit_k1 else 0.0))
        # converged: one more pass for the residuals and the Jacobian at the solution
        # (quadratic convergence: the step after one below 1e-8 rad is some 1e-11 rad)
        last = bool(np.all(np.abs(step[:4]) < 1e-8) and (not fit_k1 or abs(step[4]) < 1e-6))
    return R, cam, res, J


# --------------------------------------------------------------------------- step 5
def _refine(uv: FloatArray, A: FloatArray, scale: float, camera: Camera, cat: StarCatalogue,
            epoch: float, opt: PlateOptions, n_cat: int, radius_px: float,
            verified: tuple | None = None):
    """Least squares over attitude, focal length (and k1); returns the refined camera, the
    attitude, the matches and the covariance pieces (module steps 5-6). ``verified``: the
    verification's field stars (rows, directions) and matches at ``A``, ``scale`` and
    ``radius_px`` (the first pass's own), not recomputed."""
    if verified is None:
        rows, dirs, _ = _field_stars(cat, A, camera, scale, epoch, opt.verify_v_limit, n_cat)
    else:
        rows, dirs, det0, ci0 = verified
    cam = dataclasses.replace(camera, focal_length=camera.focal_length * scale)
    R0 = A.T  # camera -> inertial
    half_diag = 0.5 * math.hypot(camera.width, camera.height)
    centre = np.array([camera.cx, camera.cy])
    det = np.zeros(0, np.int64)
    ci = np.zeros(0, np.int64)
    fit_k1 = False
    result = None
    radius = radius_px
    for it in range(3):
        prev = (det, ci)
        if it == 0 and verified is not None:
            det, ci = det0, ci0
        else:
            uvc, inside = _project(R0.T, dirs, cam)
            det, ci = _match_px(uv, np.where(inside[:, None], uvc, 1e9), radius)
        if det.size < 3:
            break
        if result is not None and np.array_equal(det, prev[0]) and np.array_equal(ci, prev[1]):
            break  # the same matches: the same fit
        r_det = np.hypot(*(uv[det] - centre).T)
        fit_k1 = bool(det.size >= opt.k1_min_stars
                      and np.count_nonzero(r_det > 0.5 * half_diag) >= 5)

        R0, cam, r, J = _fit_plate(uv[det], dirs[ci], R0, cam, fit_k1)
        result = (r, J)
        rms = float(np.sqrt(np.mean(r**2)))
        radius = max(opt.refine_n_sigma * rms * math.sqrt(2.0), 0.5)
    if result is None or det.size < 3:
        return None
    # final matches with the final model, then the covariance of the last fit's parameters
    uvc, inside = _project(R0.T, dirs, cam)
    det, ci = _match_px(uv, np.where(inside[:, None], uvc, 1e9), radius)
    q, _ = _project(R0.T, dirs[ci], cam)
    res = uv[det] - q
    r, J = result
    dof = max(J.shape[0] - J.shape[1], 1)
    s2 = float(np.sum(r**2)) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.full((J.shape[1], J.shape[1]), np.nan)
    return cam, R0, det, rows[ci], res, cov, fit_k1


# --------------------------------------------------------------------------- solver
def solve_plate(dn: ArrayLike, camera: Camera, *, epoch_jyear: float,
                saturation_dn: float | None = None, catalogue: StarCatalogue | None = None,
                options: PlateOptions | None = None,
                index_cache: Path | bool | None = None,
                limiting_v: float | None = None) -> PlateSolution:
    """Lost-in-space plate solution of one frame (module steps 1-6).

    Parameters
    ----------
    dn : (H, W) array
        The frame (any linear grey levels; DN).
    camera : Camera
        The nominal camera (focal length known to ``focal_tolerance``; the frame's size).
    epoch_jyear : float
        Epoch of the star positions [Julian year].
    saturation_dn : float, optional
        Pixels at or above are saturated; default the integer type's top code (or none).
    catalogue : StarCatalogue, optional
        Default Hipparcos.
    options : PlateOptions, optional
    index_cache : path or bool, optional
        Where the pattern index is cached on disk (:func:`pattern_index`); False: memory only.
    limiting_v : float, optional
        Faintest V the camera can show in this exposure (an upper bound): the index and the
        verification go no fainter, and a field holding on average fewer than ``min_stars``
        such stars is reported ``"too-few-stars"`` rather than ``"unidentified"``.

    Returns
    -------
    PlateSolution
        Never raises for frame content: ``status`` says what happened.

    Raises
    ------
    ConfigError
        The frame's size is not the camera's, or the epoch is not finite.
    """
    opt = options or PlateOptions()
    cat = catalogue if catalogue is not None else hipparcos()
    a = np.asarray(dn)
    if a.ndim != 2 or a.shape != (camera.height, camera.width):
        raise ConfigError("camera.width/height", (camera.width, camera.height),
                          f"the frame's size {a.shape[::-1] if a.ndim == 2 else a.shape}")
    if not math.isfinite(epoch_jyear):
        raise ConfigError("epoch", epoch_jyear, "a finite Julian year")
    if saturation_dn is None:
        saturation_dn = (float(np.iinfo(a.dtype).max) if np.issubdtype(a.dtype, np.integer)
                         else math.inf)
    settings = plate_settings(camera, cat, opt, limiting_v)
    verify_v = opt.verify_v_limit if limiting_v is None else min(opt.verify_v_limit, limiting_v)
    t0 = time.perf_counter()
    cents = _dedupe(find_stars(a, gain_e_per_dn=1.0, saturation_dn=saturation_dn,
                               options=opt.centroid))
    t1 = time.perf_counter()

    def fail(status: str, reason: str, **kw) -> PlateSolution:
        return PlateSolution(status, reason, cents, camera, settings, time_extract_s=t1 - t0,
                             time_solve_s=time.perf_counter() - t1, **kw)

    n = len(cents)
    if n < opt.min_stars:
        return fail("too-few-stars", f"{n} star candidates detected, {opt.min_stars} needed")
    xy = _normalized(cents.uv, camera)
    b = _vectors(xy)
    sig = np.sqrt(0.5 * (cents.sigma_px**2).sum(axis=1) + opt.floor_px**2) / camera.fx
    idx = pattern_index(cat, settings.index_v_limit,
                        camera.fov_diagonal * (1 + opt.focal_tolerance), epoch_jyear,
                        cache_dir=index_cache)
    idx_tree = _index_tree(idx)
    m = min(n, opt.n_brightest)
    t = opt.focal_tolerance
    tol_cat = opt.catalogue_tol_arcsec * ARCSEC
    r_edge = 0.5 * camera.fov_diagonal
    n_screen = opt.screen_stars
    hyp = 0
    best = (-1, 0)  # most confirmations any candidate reached, and the number it needed
    accepted: list[tuple] = []
    k_req, lam = 0, 0.0
    for i, j, k in _triangle_order(m):
        if hyp >= opt.max_hypotheses:
            break
        # the vertex shared by the two shortest sides is joined on: the pair windows grow
        # with the angle squared (density x width), the join with their product
        sides = {(i, j): b[i] @ b[j], (i, k): b[i] @ b[k], (j, k): b[j] @ b[k]}
        longest = min(sides, key=sides.get)
        i, j, k = next(x for x in (i, j, k) if x not in longest), *longest
        tol = np.array([opt.n_sigma * math.hypot(sig[p], sig[q]) + tol_cat
                        for p, q in ((i, j), (i, k), (j, k))])
        si, sj, sk, s = _scaled_triangles(idx, b, i, j, k, tol, t)
        if si.size == 0:
            continue
        # step 4: batch attitudes at each candidate's scale, screened by further detections
        bs = _vectors_batch(xy[[i, j, k]], s)
        rs = np.stack([idx.directions[si], idx.directions[sj], idx.directions[sk]], axis=1)
        As = _svd_batch(bs, rs)
        others = np.array([p for p in range(min(n, m + n_screen)) if p not in (i, j, k)]
                          [:n_screen], np.int64)
        s_err = float(tol.max()) / max(float(np.arccos(min(1.0, b[i] @ b[j]))), 1e-6)
        if others.size:
            r_scr = settings.match_radius_rad + 2.0 * s_err * r_edge
            bo = _vectors_batch(xy[others], s)  # (c, o, 3)
            sky = bo @ As  # A^T b
            chord = 2.0 * math.sin(0.5 * r_scr)
            # beyond the screening radius no nearest star is needed (a distance of inf)
            dist, near = idx_tree.query(sky.reshape(-1, 3), k=1,
                                        distance_upper_bound=chord * (1.0 + 1e-9))
            hit = dist.reshape(len(s), -1) <= chord
            near = near.reshape(len(s), -1)
            hits = hit.sum(axis=1)
        else:
            hit = np.zeros((len(s), 0), bool)
            near = np.zeros((len(s), 0), np.int64)
            hits = np.zeros(len(s), int)
        h_min = max(min(2, int(others.size)), math.ceil(0.4 * others.size))
        order = np.argsort(-hits, kind="stable")
        order = order[hits[order] >= h_min]
        for c in order:
            if hyp >= opt.max_hypotheses:
                break
            if accepted and 2 * hits[c] < accepted[0][3]:
                break  # the rest explain too few detections to rival the accepted attitude
            hyp += 1
            # the fit stars: the triangle and the screening hits (one-to-one), scale from
            # all their mutual angles, attitude by SVD; confirmations are counted among
            # the other detections only
            used = [i, j, k] + others[hit[c]].tolist()
            stars = [int(si[c]), int(sj[c]), int(sk[c])] + near[c][hit[c]].tolist()
            if len(set(stars)) < len(stars):
                used, stars = [i, j, k], stars[:3]
            bu, ru = b[used], idx.directions[stars]
            iu, ju = np.triu_indices(len(used), 1)
            mu = np.arccos(np.minimum(1.0, np.einsum("ij,ij->i", bu[iu], bu[ju])))
            cu = np.arccos(np.minimum(1.0, np.einsum("ij,ij->i", ru[iu], ru[ju])))
            sc = float(mu.sum() / cu.sum())
            A = _svd_batch(_vectors(xy[used], sc)[None], ru[None])[0]
            s_fit = float(tol.max()) / max(float(cu.max()), 1e-6) / math.sqrt(len(used) - 2)
            rows, dirs, uvc = _field_stars(cat, A, camera, sc, epoch_jyear, verify_v, n)
            if rows.size < 3:
                continue
            r_px = opt.match_px + 2.0 * s_fit * r_edge * camera.fx
            det, ci = _match_px(cents.uv, uvc, r_px)
            omega_match = math.pi * (r_px / camera.fx) ** 2
            k_req, lam = _required(n - len(used), int(rows.size), omega_match,
                                   settings.field_solid_angle_sr, opt.max_hypotheses,
                                   opt.false_match_probability)
            extra = int(np.setdiff1d(det, used).size)
            if extra > best[0]:
                best = (extra, k_req)
            if extra < k_req:
                continue
            ref = _refine(cents.uv, A, sc, camera, cat, epoch_jyear, opt, n, r_px,
                          (rows, dirs, det, ci))
            if ref is None:
                continue
            if not accepted:
                accepted.append((ref, k_req, lam, int(hits[c])))
            else:
                R_a = accepted[0][0][1]
                ang = Rotation.from_matrix(R_a.T @ ref[1]).magnitude()
                if ang > 10 * settings.match_radius_rad:
                    return fail("ambiguous", "two different attitudes both verify",
                                hypotheses=hyp)
        if accepted:
            break
    if not accepted and limiting_v is not None:
        n_sky = int(np.count_nonzero(cat.v <= limiting_v))
        mean = n_sky * settings.field_solid_angle_sr / (4.0 * math.pi)
        if mean < opt.min_stars:
            tried = f"none of the {hyp} candidate patterns" if hyp else "no candidate pattern"
            return fail("too-few-stars",
                        f"the camera reaches V {limiting_v:.1f} at most in this exposure: the "
                        f"sky holds {n_sky} stars that bright, {mean:.2f} per field of "
                        f"{math.degrees(camera.fov_x):.2f} x {math.degrees(camera.fov_y):.2f} "
                        f"deg on average, {opt.min_stars} needed; {tried} among the {n} "
                        "detections verified",
                        hypotheses=hyp)
    if not accepted:
        return fail("unidentified",
                    f"no triangle of the {m} brightest of {n} detections verified ({hyp} "
                    f"candidates tried, the best confirmed by "
                    f"{max(best[0], 0)} other detections of {best[1]} needed; focal length "
                    f"searched within +-{100 * t:.0f} %, index V <= "
                    f"{settings.index_v_limit:.2f})", hypotheses=hyp)
    (cam, R, det, crow, res, cov, fit_k1), k_req, lam, _ = accepted[0]
    if det.size < opt.min_stars:
        return fail("unidentified", f"{det.size} stars matched after refinement, "
                    f"{opt.min_stars} needed", hypotheses=hyp)
    return PlateSolution(
        "ok", "", cents, cam, settings, R, 0.5 * (cov[:3, :3] + cov[:3, :3].T),
        float(math.sqrt(cov[3, 3]) * cam.focal_length),
        float(math.sqrt(cov[4, 4])) if fit_k1 else math.nan,
        det.astype(np.int64), crow.astype(np.int64), cat.hip[crow], cat.v[crow], res,
        k_req, lam, hyp, t1 - t0, time.perf_counter() - t1)
