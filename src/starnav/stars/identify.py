"""Star identification: lost in space (triangles in a sorted pair table, verified), and tracking.

Each step, the false-match bound and the aberration allowance in full: docs/methods.md,
"starnav.stars.identify".

Technique
---------
1. Index: every catalogue pair brighter than ``index_v_limit`` within the field's diagonal,
   sorted by separation (:func:`star_index`, cached per process).
2. Triangles of the brightest detections matched side by side in the pair table, sense
   checked (no mirror images).
3. Verification: a candidate attitude is accepted when at least ``k`` further detections are
   confirmed, ``k`` the smallest with ``N_hyp P(Poisson(lambda) >= k) <= alpha``
   (:func:`required_confirmations`); two verified attitudes: ambiguous, none.
4. Refinement with all confirmed stars.
5. Tracking: with a prior attitude, step 3's match directly (``N_hyp = 1``).
6. Aberration: with ``observer_velocity`` the catalogue stars are moved to their apparent
   directions (:mod:`starnav.stars.aberration`).

The knobs are :class:`IdentifyOptions`.

References
----------
D. Mortari, M. A. Samaan, C. Bruccoleri and J. L. Junkins, "The pyramid star identification
technique", Navigation 51 (2004) 171-183. D. Mortari, "Search-less algorithm for star pattern
recognition", J. Astronaut. Sci. 45 (1997) 179-194 (k-vector).

Index
-----
:func:`identify_lost_in_space`, :func:`identify_tracking`, :class:`Identification`,
:class:`IdentifyOptions`, :func:`star_index`, :class:`StarIndex`,
:func:`required_confirmations`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree
from scipy.stats import poisson

from starnav.constants import SPEED_OF_LIGHT
from starnav.errors import ConfigError
from starnav.stars.aberration import ABERRATION_MARGIN, apparent_directions
from starnav.stars.catalogue import StarCatalogue, hipparcos
from starnav.typing import FloatArray

#: One arcsecond [rad].
ARCSEC = math.pi / (180.0 * 3600.0)


@dataclass(frozen=True)
class IdentifyOptions:
    """Knobs of the identification (module table)."""

    index_v_limit: float = 6.0
    verify_v_limit: float = 7.0
    n_brightest: int = 12
    n_sigma: float = 5.0
    catalogue_tol_arcsec: float = 10.0
    match_radius_arcsec: float = 300.0
    refine_n_sigma: float = 5.0
    false_match_probability: float = 1e-9
    max_hypotheses: int = 2000
    min_confirmed: int = 3

    def __post_init__(self) -> None:
        if self.n_brightest < 3:
            raise ConfigError("identify.n_brightest", self.n_brightest, "an integer >= 3")
        if not 0 < self.false_match_probability < 1:
            raise ConfigError("identify.false_match_probability", self.false_match_probability,
                              "a probability in (0, 1)")
        for name in ("n_sigma", "catalogue_tol_arcsec", "match_radius_arcsec", "refine_n_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"identify.{name}", v, "a finite value > 0")


@dataclass(frozen=True)
class StarIndex:
    """Pair table of :func:`star_index` (module step 1)."""

    directions: FloatArray      # (n, 3) unit vectors at the index epoch
    rows: NDArray[np.int64]     # catalogue rows of the index stars
    pair_a: NDArray[np.int32]   # index-star numbers of each pair (both orders)
    pair_b: NDArray[np.int32]
    angle: FloatArray           # sorted separations [rad]


@lru_cache(maxsize=4)
def _index(cat_id: int, v_limit: float, max_sep: float, epoch_jyear: float,
           cat: StarCatalogue) -> StarIndex:
    rows = np.nonzero(cat.v <= v_limit)[0]
    d = cat.directions(epoch_jyear, rows)
    tree = cKDTree(d)
    pairs = tree.query_pairs(2.0 * math.sin(0.5 * max_sep), output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", d[a], d[b]), -1.0, 1.0))
    a2, b2, ang2 = np.concatenate([a, b]), np.concatenate([b, a]), np.concatenate([ang, ang])
    order = np.argsort(ang2, kind="stable")
    return StarIndex(d, rows, a2[order].astype(np.int32), b2[order].astype(np.int32),
                     ang2[order])


def star_index(catalogue: StarCatalogue, v_limit: float, max_separation_rad: float,
               epoch_jyear: float) -> StarIndex:
    """The pair table (cached per process; the epoch is rounded to the year: proper motions
    move a star by at most 10 arcsec in half a year, inside the tolerance)."""
    return _index(id(catalogue), round(float(v_limit), 3), round(float(max_separation_rad), 4),
                  float(round(epoch_jyear)), catalogue)


class MatchResult:
    """``ok`` and ``n_matched`` of a result with a ``status`` and matched ``detection_index``."""

    status: str
    detection_index: NDArray[np.int64]

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def n_matched(self) -> int:
        return int(self.detection_index.size)


@dataclass(frozen=True)
class Identification(MatchResult):
    """Matched detections and catalogue stars.

    Attributes
    ----------
    status, reason : str
        ``"ok"`` / ``"unidentified"`` / ``"ambiguous"`` and why.
    detection_index : (m,) int array
        Rows of the detections matched.
    catalogue_row : (m,) int array
        Their catalogue rows; ``hip`` their Hipparcos numbers.
    directions : (m, 3) array
        Their catalogue unit vectors at the epoch.
    n_required : int
        Confirmations the count rule demanded; ``lam`` the Poisson mean of random ones.
    hypotheses : int
        Candidate triangles tried.
    """

    status: str
    reason: str
    detection_index: NDArray[np.int64]
    catalogue_row: NDArray[np.int64]
    hip: NDArray[np.int64]
    directions: FloatArray
    n_required: int = 0
    lam: float = 0.0
    hypotheses: int = 0


def _fail(status: str, reason: str, hyp: int = 0) -> Identification:
    z = np.zeros(0, np.int64)
    return Identification(status, reason, z, z, z, np.zeros((0, 3)), 0, 0.0, hyp)


@lru_cache(maxsize=4096)
def required_confirmations(n_det: int, n_cat: int, match_radius: float, field_radius: float,
                           n_hypotheses: int, alpha: float, min_confirmed: int
                           ) -> tuple[int, float]:
    """Smallest ``k`` with ``n_hypotheses P(Poisson(lambda) >= k) <= alpha`` (module step 3)
    and ``lambda``."""
    omega_match = 2.0 * math.pi * (1.0 - math.cos(match_radius))
    omega_field = 2.0 * math.pi * (1.0 - math.cos(field_radius))
    lam = max(n_det, 0) * min(1.0, n_cat * omega_match / omega_field)
    k = max(int(min_confirmed), 1)
    while n_hypotheses * poisson.sf(k - 1, lam) > alpha and k < 10_000:
        k += 1
    return k, lam


def _candidate_triangles(aij: NDArray[np.int32], bij: NDArray[np.int32],
                         aik: NDArray[np.int32], bik: NDArray[np.int32], dirs: FloatArray,
                         ajk: float, tol_jk: float, sense: float
                         ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Catalogue triangles ``(si, sj, sk)`` for one detection triangle (module step 2): the
    pairs ``(si, sj)`` of side ``ij`` and ``(si, sk)`` of side ``ik`` joined on the star of
    ``i``, kept when ``sj != sk``, the third side is within ``tol_jk`` of the measured ``ajk``
    and the sense (sign of ``si . (sj x sk)``) is that of the detections. Ordered by ``si``,
    then by the order of ``sj`` in ``ij`` and of ``sk`` in ``ik``."""
    oj = np.argsort(aij, kind="stable")
    ok = np.argsort(aik, kind="stable")
    sa_j, sa_k = aij[oj], aik[ok]
    lo = np.searchsorted(sa_k, sa_j, "left")
    cnt = np.searchsorted(sa_k, sa_j, "right") - lo
    n = int(cnt.sum())
    if n == 0:
        z = np.zeros(0, np.int64)
        return z, z, z
    rep = np.repeat(np.arange(cnt.size), cnt)
    start = np.cumsum(cnt) - cnt
    kpos = np.repeat(lo - start, cnt) + np.arange(n)
    si = sa_j[rep].astype(np.int64)
    sj = bij[oj][rep].astype(np.int64)
    sk = bik[ok][kpos].astype(np.int64)
    dj, dk = dirs[sj], dirs[sk]
    ang = np.arccos(np.minimum(1.0, np.einsum("ij,ij->i", dj, dk)))
    keep = (sj != sk) & (np.abs(ang - ajk) <= tol_jk)
    keep &= np.einsum("ij,ij->i", dirs[si], np.cross(dj, dk)) * sense > 0
    return si[keep], sj[keep], sk[keep]


def _svd3(b: FloatArray, r: FloatArray) -> FloatArray:
    U, _, Vt = np.linalg.svd(b.T @ r)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)]) @ Vt


def _match(b: FloatArray, A: FloatArray, tree: cKDTree, radius: FloatArray | float
           ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Detections (rows of ``b``) whose sky direction ``A^T b`` has a catalogue star within
    ``radius`` [rad], one-to-one (a catalogue star keeps its closest detection)."""
    sky = b @ A  # rows: A^T b
    dist, idx = tree.query(sky, k=1)
    ang = 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))
    ok = ang <= radius
    det = np.nonzero(ok)[0]
    cat = idx[ok]
    order = np.argsort(ang[ok], kind="stable")
    _, first = np.unique(cat[order], return_index=True)
    keep = np.sort(order[first])
    return det[keep], cat[keep]


def _field(cat: StarCatalogue, A: FloatArray, epoch: float, radius: float, v_limit: float,
           velocity: FloatArray | None):
    sel_rows = _cone_rows(cat, A[2], radius, epoch, v_limit)
    d = cat.directions(epoch, sel_rows)
    if velocity is not None:
        d = apparent_directions(d, velocity)  # module step 6
    return sel_rows, d


def _cone_rows(cat: StarCatalogue, centre: FloatArray, radius: float, epoch: float,
               v_limit: float) -> NDArray[np.int64]:
    cand = np.asarray(cat._tree.query_ball_point(
        centre, 2.0 * math.sin(0.5 * (radius + ABERRATION_MARGIN) + 1e-4)), np.int64)
    return cand[cat.v[cand] <= v_limit]


def _refine(b: FloatArray, sig: FloatArray, A: FloatArray, cat: StarCatalogue, epoch: float,
            field_radius: float, opt: IdentifyOptions, radius0: float,
            velocity: FloatArray | None
            ) -> tuple[FloatArray, NDArray[np.int64], NDArray[np.int64], FloatArray, int]:
    rows, d = _field(cat, A, epoch, field_radius * 1.05, opt.verify_v_limit, velocity)
    if rows.size == 0:
        return A, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), 0
    tree = cKDTree(d)
    det, ci = _match(b, A, tree, radius0)
    for _ in range(3):
        if det.size < 3:
            break
        A = _svd3(b[det] / sig[det, None], d[ci] / sig[det, None])
        w = 1.0 / sig[det] ** 2
        P_scale = 1.0 / math.sqrt(float(w.sum()))  # cross-boresight attitude 1-sigma
        rad = opt.refine_n_sigma * np.sqrt(sig**2 + (10.0 * P_scale) ** 2) \
            + opt.catalogue_tol_arcsec * ARCSEC
        det, ci = _match(b, A, tree, rad)
    return A, det, rows[ci], d[ci], int(rows.size)


def identify_lost_in_space(b: FloatArray, sigma_rad: FloatArray,
                           catalogue: StarCatalogue | None, epoch_jyear: float,
                           fov_diagonal_rad: float, *,
                           options: IdentifyOptions | None = None,
                           observer_velocity: ArrayLike | None = None) -> Identification:
    """Identify detections (camera unit vectors ``b``, brightest first, 1-sigma ``sigma_rad``)
    without an attitude (module steps 1-4); with ``observer_velocity`` [m/s, barycentric, ICRF]
    against the apparent catalogue (step 6), else the astrometric one. Never raises for the
    content of ``b``."""
    opt = options or IdentifyOptions()
    vel = None if observer_velocity is None else np.asarray(observer_velocity, float)
    beta = 0.0 if vel is None else float(np.linalg.norm(vel)) / SPEED_OF_LIGHT
    cat = catalogue if catalogue is not None else hipparcos()
    n = b.shape[0]
    if n < 3:
        return _fail("unidentified", f"{n} detections: a triangle needs 3")
    idx = star_index(cat, opt.index_v_limit, fov_diagonal_rad, epoch_jyear)
    m = min(n, opt.n_brightest)
    tol_cat = opt.catalogue_tol_arcsec * ARCSEC
    field_radius = 0.5 * fov_diagonal_rad
    r_match = opt.match_radius_arcsec * ARCSEC

    def cand(i: int, j: int) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
        dij = math.acos(min(1.0, max(-1.0, float(b[i] @ b[j]))))
        tol = (opt.n_sigma * math.hypot(sigma_rad[i], sigma_rad[j]) + tol_cat
               + 2.0 * beta * math.tan(0.5 * dij))
        lo, hi = np.searchsorted(idx.angle, [dij - tol, dij + tol])
        return idx.pair_a[lo:hi], idx.pair_b[lo:hi]

    accepted: list[tuple[FloatArray, NDArray, NDArray, FloatArray, int, float]] = []
    hyp = 0
    k_req, lam = 0, 0.0
    for i, j, k in _triangle_order(m):
        if hyp >= opt.max_hypotheses:
            break
        aij, bij = cand(i, j)
        aik, bik = cand(i, k)
        if aij.size == 0 or aik.size == 0:
            continue
        ajk_d = math.acos(min(1.0, max(-1.0, float(b[j] @ b[k]))))
        tol_jk = (opt.n_sigma * math.hypot(sigma_rad[j], sigma_rad[k]) + tol_cat
                  + 2.0 * beta * math.tan(0.5 * ajk_d))
        sense = float(b[i] @ np.cross(b[j], b[k]))
        si_all, sj_all, sk_all = _candidate_triangles(aij, bij, aik, bik, idx.directions,
                                                      ajk_d, tol_jk, sense)
        for si, sj, sk in zip(si_all.tolist(), sj_all.tolist(), sk_all.tolist(), strict=True):
            if hyp >= opt.max_hypotheses:
                break
            hyp += 1
            A = _svd3(b[[i, j, k]], idx.directions[[si, sj, sk]])
            rows, d = _field(cat, A, epoch_jyear, field_radius, opt.verify_v_limit, vel)
            if rows.size < 3:
                continue
            det, _ = _match(b, A, cKDTree(d), r_match)
            k_req, lam = required_confirmations(
                n - 3, int(rows.size), r_match, field_radius, opt.max_hypotheses,
                opt.false_match_probability, opt.min_confirmed)
            extra = int(np.setdiff1d(det, [i, j, k]).size)
            if extra >= k_req:
                A2, det2, crow, cdir, _ = _refine(b, sigma_rad, A, cat, epoch_jyear,
                                                  field_radius, opt, r_match, vel)
                if not accepted:
                    accepted.append((A2, det2, crow, cdir, k_req, lam))
                elif _angle(accepted[0][0], A2) > 10 * r_match:
                    return _fail("ambiguous", "two different attitudes both verify", hyp)
        if accepted:
            break
    if not accepted:
        return _fail("unidentified", f"no triangle of the {m} brightest detections verified "
                     f"({hyp} candidates tried; {k_req} confirmations needed)", hyp)
    A, det, crow, cdir, k_req, lam = accepted[0]
    return Identification("ok", "", det.astype(np.int64), crow.astype(np.int64),
                          cat.hip[crow], cdir, k_req, lam, hyp)


def identify_tracking(b: FloatArray, sigma_rad: FloatArray, catalogue: StarCatalogue | None,
                      epoch_jyear: float, fov_diagonal_rad: float, prior: FloatArray,
                      prior_sigma_rad: float, *, options: IdentifyOptions | None = None,
                      observer_velocity: ArrayLike | None = None) -> Identification:
    """Identify detections by nearest neighbour around the prior attitude ``prior`` (camera
    -> inertial) of 1-sigma ``prior_sigma_rad`` [rad] (module step 5); ``observer_velocity``
    as in :func:`identify_lost_in_space`."""
    opt = options or IdentifyOptions()
    vel = None if observer_velocity is None else np.asarray(observer_velocity, float)
    cat = catalogue if catalogue is not None else hipparcos()
    n = b.shape[0]
    if n < 3:
        return _fail("unidentified", f"{n} detections: tracking needs 3")
    A0 = np.asarray(prior, float).T
    field_radius = 0.5 * fov_diagonal_rad
    r0 = opt.match_radius_arcsec * ARCSEC + 3.0 * float(prior_sigma_rad) * 1.5
    A, det, crow, cdir, ncat = _refine(b, sigma_rad, A0, cat, epoch_jyear, field_radius, opt,
                                       r0, vel)
    k_req, lam = required_confirmations(n, ncat, r0, field_radius, 1,
                                        opt.false_match_probability, opt.min_confirmed + 3)
    if det.size < k_req:
        return _fail("unidentified", f"{det.size} detections matched around the prior, "
                     f"{k_req} needed", 1)
    return Identification("ok", "", det.astype(np.int64), crow.astype(np.int64), cat.hip[crow],
                          cdir, k_req, lam, 1)


def _angle(A1: FloatArray, A2: FloatArray) -> float:
    c = 0.5 * (float(np.trace(A1 @ A2.T)) - 1.0)
    return math.acos(min(1.0, max(-1.0, c)))


def _triangle_order(m: int):
    """Triangles of ``m`` detections, those of the brightest first (``k`` then ``j`` grow)."""
    return sorted(itertools.combinations(range(m), 3), key=lambda t: (t[2], t[1], t[0]))
