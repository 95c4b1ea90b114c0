"""Pixel-accuracy limb points from star-tracker segments (the STAR Nav algorithm 2).

The star tracker's *full image compressed* readout sends runs of consecutive above-threshold
pixels ("segments", :class:`~starnav.detector.products.Segments`); this module turns them into
limb points without rebuilding the image. Each step in full: docs/methods.md,
"starnav.navigation.limb".

Technique
---------
1. First guess of the Moon: the centroid of the segment pixels.
2. The Sun's direction in the image at the Moon, from the measured attitude and the projection
   Jacobian (:func:`sun_direction_in_image`).
3. Four scans of the runs (+u, -u, +v, -v ends), no pixel expanded.
4. Four sectors split by the diagonals through a Kasa circle's centre: each scan keeps its own
   sector's ends.
5. Lit side: a point is kept if its outward normal faces the Sun (``min_sun_cos``).
6. Run ends on the detector border are dropped.
7. Points ordered by angle and thinned to ``max_points``.

A limb point is the centre of the lit-side end pixel: pixel accuracy, plus the threshold's
bias. The knobs are the scenario section :class:`LimbConfig`.

References
----------
Seed paper (STAR Nav, "What if star trackers were navigation cameras?"), section "The
pixel-accuracy limb-based navigation algorithm", steps 1-2, and its reference 5 (figure 6).
I. Kasa, "A circle fitting procedure and its error analysis", IEEE Trans. Instrum. Meas. 25
(1976) 8-14.

Index
-----
:func:`limb_points_from_segments`, :class:`LimbPoints`, :class:`LimbConfig`,
:class:`LimbNotFoundError`, :func:`segments_centroid`, :func:`sun_direction_in_image`,
:func:`phase_angle_from_image`, :func:`sun_geometry_in_image`, :func:`fit_circle_kasa`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field

from starnav.camera import Camera
from starnav.config_base import SIView, StrictModel
from starnav.detector.products import Segments
from starnav.errors import StarnavError
from starnav.fields import PositiveFloat
from starnav.linalg import solve_vectors
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Default cap on the number of limb points, as on the AA-STR processor (seed paper, PIL).
MAX_LIMB_POINTS = 600
#: Fewest limb points of a frame (three fix a circle).
MIN_POINTS = 3


class LimbNotFoundError(StarnavError, ValueError):
    """No usable limb in a frame (no segments, no Moon, or too few limb points).

    ``reason`` is a short machine-readable tag: ``no-segments``, ``no-moon``,
    ``degenerate-arc``, ``sun-on-axis`` or ``no-edge``.
    """

    def __init__(self, message: str, reason: str = "no-limb") -> None:
        super().__init__(message)
        self.reason = reason


class LimbConfig(StrictModel):
    """Scenario section ``navigation.limb``: pixel-level limb points from segments
    (:func:`limb_points_from_segments` reads its SI view, ``to_si()``)."""

    max_points: Annotated[int, Field(ge=MIN_POINTS)] = Field(
        MAX_LIMB_POINTS, description="cap on limb points")
    min_level: Annotated[int, Field(ge=0)] = Field(0, description="lowest threshold level used")
    min_run_length_px: Annotated[int, Field(ge=1)] = Field(1, description="shortest run used [px]")
    min_sun_cos: Annotated[float, Field(ge=-1, lt=1)] = Field(
        0.1, description="lit-side margin: cos of the largest limb-normal to Sun angle [-]")
    drop_border_px: Annotated[int, Field(ge=0)] = Field(1, description="border margin [px]")
    point_sigma_px: PositiveFloat = Field(0.5, description="1-sigma of a pixel-level point [px]")
    point_offset_px: float = Field(0.0, allow_inf_nan=False,
                                   description="inward shift of every point [px]")
    max_phase_deg: Annotated[float, Field(gt=0, le=180)] = Field(
        145.0, description="no fix past this Sun phase angle [deg]: a thinner crescent's lit "
        "limb is too short for a trustworthy fix (the model errors are calibrated to ~145)")


#: The defaults' SI view.
_DEFAULT = LimbConfig().to_si()


@dataclass(frozen=True)
class LimbPoints:
    """Limb points of one frame.

    Attributes
    ----------
    uv : (n, 2) array
        Pixel coordinates ``(u, v)`` of the limb points [px] (distorted, as measured).
    sigma_px : (n,) array
        1-sigma isotropic uncertainty of each point [px].
    centre_px : (2,) array
        Centre of the circle fitted to the candidates [px].
    radius_px : float
        Radius of that circle [px].
    sun_dir_image : (2,) array
        Unit direction of the Sun in the image at the Moon [-].
    n_candidates : int
        Number of candidates before the sector, lit-side and cap filters.
    source : str
        ``"segments"`` (pixel accuracy) or ``"windows"`` (subpixel refinement).
    common_covariance_px2 : (3, 3) array or None
        Covariance [px^2] of the errors every point of the frame shares: along each limb
        normal (the disc's apparent radius), and a shift of all points towards the Sun's
        direction in the image and across it; the fix carries them, ``sigma_px`` does not.
    fix_covariance_px2 : (3, 3) array or None
        Covariance [px^2] of the frame's slowly varying limb error in the same three modes:
        everything but the pixels' noise (the fix's covariance and the ``limb-common`` filter
        states carry it).
    fit_sigma_px : (n,) array or None
        The part of ``sigma_px`` that comes from the pixels' noise alone [px] (refinement).
    saturated : (n,) bool array or None
        The point's window held saturated pixels (refinement).
    overexposure : (n,) array or None
        The fitted edge step over the headroom to saturation of a saturated window, 0 for a
        well-exposed one (refinement) [-].
    """

    uv: FloatArray
    sigma_px: FloatArray
    centre_px: FloatArray
    radius_px: float
    sun_dir_image: FloatArray
    n_candidates: int
    source: str = "segments"
    common_covariance_px2: FloatArray | None = None
    fix_covariance_px2: FloatArray | None = None
    fit_sigma_px: FloatArray | None = None
    saturated: NDArray[np.bool_] | None = None
    overexposure: FloatArray | None = None

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    def subset(self, keep: NDArray[np.bool_]) -> LimbPoints:
        """The points where ``keep`` is true (everything else unchanged)."""
        return dataclasses.replace(
            self, uv=self.uv[keep], sigma_px=self.sigma_px[keep],
            fit_sigma_px=None if self.fit_sigma_px is None else self.fit_sigma_px[keep],
            saturated=None if self.saturated is None else self.saturated[keep],
            overexposure=None if self.overexposure is None else self.overexposure[keep])


# ------------------------------------------------------------------------ geometry helpers
def segments_centroid(segments: Segments, min_level: int = 0) -> FloatArray:
    """Centroid ``(u, v)`` of the pixels carried by the runs [px] (unweighted by DN)."""
    keep = segments.level >= min_level
    L = segments.length[keep].astype(float)
    if L.sum() <= 0:
        raise LimbNotFoundError("segments: no run at or above the threshold level "
                                f"{min_level}; the frame has no Moon to navigate on",
                                "no-moon")
    u = segments.col_start[keep] + (L - 1.0) / 2.0
    v = segments.row[keep].astype(float)
    return np.array([np.sum(u * L), np.sum(v * L)]) / L.sum()


def sun_direction_in_image(camera: Camera, R_cam_to_inertial: ArrayLike,
                           sun_direction_inertial: ArrayLike,
                           moon_px: ArrayLike) -> FloatArray:
    """Unit direction ``(du, dv)`` in which the Sun lies, in the image, at the Moon.

    Parameters
    ----------
    camera : Camera
        The camera model.
    R_cam_to_inertial : (3, 3) array
        Attitude (measured, on board), camera to inertial.
    sun_direction_inertial : (3,) array
        Direction from the Moon (or the spacecraft: the difference is ~1e-4 rad) to the Sun,
        inertial [-]; need not be normalised.
    moon_px : (2,) array
        Where the Moon is in the image [px].

    Returns
    -------
    (2,) array
        Unit vector; the image of the Sun's direction, ``J_pi(x_moon) @ s_cam``, normalised.

    Raises
    ------
    LimbNotFoundError
        When the Sun is along the line of sight (full or new Moon: no lit side to pick).
    """
    s_cam, x = _sun_and_line_of_sight(camera, R_cam_to_inertial, sun_direction_inertial,
                                      moon_px)
    return _sun_direction(camera, s_cam, x)


def _sun_and_line_of_sight(camera: Camera, R_cam_to_inertial: ArrayLike,
                           sun_direction_inertial: ArrayLike, moon_px: ArrayLike
                           ) -> tuple[FloatArray, FloatArray]:
    """The Sun's direction in camera axes (as given, not normalised) and the unit line of
    sight to ``moon_px``."""
    R = np.asarray(R_cam_to_inertial, float)
    s_cam = R.T @ np.asarray(sun_direction_inertial, float)
    return s_cam, camera.unproject(np.asarray(moon_px, float))


def _sun_direction(camera: Camera, s_cam: FloatArray, x: FloatArray) -> FloatArray:
    """:func:`sun_direction_in_image` from the Sun in camera axes and the line of sight."""
    s_cam = s_cam / np.linalg.norm(s_cam)
    d = camera.project_jacobian(x)[:2] @ s_cam
    nd = float(np.linalg.norm(d))
    # the Jacobian scales with 1/z = 1 for a unit x: |d| ~ fx sin(angle to the LOS)
    if nd < 1e-6 * camera.fx:
        raise LimbNotFoundError("the Sun is along the line of sight to the Moon (phase 0 or "
                                "180 deg): the lit side of the limb is undefined", "sun-on-axis")
    return d / nd


def phase_angle_from_image(camera: Camera, R_cam_to_inertial: ArrayLike,
                           sun_direction_inertial: ArrayLike, moon_px: ArrayLike) -> float:
    """The Sun-Moon-camera (phase) angle [rad] from where the Moon is in the image, the
    measured attitude and the Sun's direction (from the Moon, inertial; any length)."""
    return _phase_angle(*_sun_and_line_of_sight(camera, R_cam_to_inertial,
                                                sun_direction_inertial, moon_px))


def _phase_angle(s_cam: FloatArray, x: FloatArray) -> float:
    c = -float(s_cam @ x) / float(np.linalg.norm(s_cam) * np.linalg.norm(x))
    return math.acos(max(-1.0, min(1.0, c)))


def sun_geometry_in_image(camera: Camera, R_cam_to_inertial: ArrayLike,
                          sun_direction_inertial: ArrayLike, moon_px: ArrayLike
                          ) -> tuple[FloatArray, float]:
    """:func:`sun_direction_in_image` and :func:`phase_angle_from_image` together (one line
    of sight): ``(unit (du, dv), phase angle [rad])``."""
    s_cam, x = _sun_and_line_of_sight(camera, R_cam_to_inertial, sun_direction_inertial,
                                      moon_px)
    return _sun_direction(camera, s_cam, x), _phase_angle(s_cam, x)


def fit_circle_kasa(uv: ArrayLike) -> tuple[FloatArray, float]:
    """Algebraic least-squares circle (Kasa 1976) through points ``(n, 2)`` [px].

    Returns ``(centre (2,), radius)`` [px]. Needs >= 3 non-collinear points.
    """
    p = np.asarray(uv, float)
    if p.shape[0] < 3:
        raise LimbNotFoundError(f"a circle needs >= 3 points, got {p.shape[0]}",
                                "degenerate-arc")
    u, v = p.T.copy()   # contiguous coordinates: every sum below is one dot product
    m = np.array([u.sum() / u.size, v.sum() / v.size])   # the means, as ndarray.mean
    u -= m[0]
    v -= m[1]
    b = u * u + v * v
    # the normal equations of [u, v, 1] x = b (3 x 3, well conditioned: the points are
    # centred, so the constant column is orthogonal to the others); SVD least squares only
    # when they are singular
    Suu, Svv, Suv, Su, Sv = u @ u, v @ v, u @ v, u.sum(), v.sum()
    N = np.array([[Suu, Suv, Su], [Suv, Svv, Sv], [Su, Sv, float(u.size)]])
    if Suu * Svv - Suv * Suv > 1e-12 * Suu * Svv:
        sol = solve_vectors(N, np.array([u @ b, v @ b, b.sum()]))
    else:   # collinear points: the minimum-norm solution, rejected below if it is no circle
        sol, *_ = np.linalg.lstsq(np.column_stack([u, v, np.ones(u.size)]), b, rcond=None)
    c = sol[:2] / 2.0
    r2 = sol[2] + c @ c
    if not np.isfinite(r2) or r2 <= 0:
        raise LimbNotFoundError("degenerate arc: the limb points are collinear",
                                "degenerate-arc")
    return c + m, float(math.sqrt(r2))


def _robust_circle(uv: FloatArray) -> tuple[FloatArray, float]:
    c, r = fit_circle_kasa(uv)
    du, dv = uv[:, 0] - c[0], uv[:, 1] - c[1]
    res = np.abs(np.sqrt(du * du + dv * dv) - r)
    n = res.size   # the median, as np.median (the middle value, or the mean of the two)
    part = np.partition(res, [(n - 1) // 2, n // 2])
    mad = 0.5 * (part[(n - 1) // 2] + part[n // 2]) * 1.4826 + 0.5
    keep = res <= 3.0 * mad
    if 3 <= keep.sum() < len(uv):
        c, r = fit_circle_kasa(uv[keep])
    return c, r


# ------------------------------------------------------------------------ scans
def _row_scan(row: NDArray, c0: NDArray, c1: NDArray, right: bool) -> tuple[NDArray, NDArray]:
    """Lit-side end per row: rightmost end (``right``) or leftmost start."""
    if right:
        order = np.lexsort((c1, row))
        r = row[order]
        last = np.ones(r.size, bool)
        np.not_equal(r[1:], r[:-1], out=last[:-1])
        sel = order[last]
        return c1[sel], row[sel]
    order = np.lexsort((c0, row))
    r = row[order]
    first = np.ones(r.size, bool)
    np.not_equal(r[1:], r[:-1], out=first[1:])
    sel = order[first]
    return c0[sel], row[sel]


def _column_scan(row: NDArray, c0: NDArray, c1: NDArray, width: int,
                 down: bool) -> tuple[NDArray, NDArray]:
    """Lit-side end per column: lowest row (``down``: the largest row index) or highest row
    covering it.

    A range-max (range-min) update with point queries, as a sparse table in reverse: run
    ``[c0, c1]`` of length ``n`` is covered by the two blocks of ``2^floor(log2 n)`` columns
    starting at ``c0`` and ending at ``c1`` (the extremum does not mind the overlap), written
    with one scatter per table; the blocks are then pushed down level by level to single
    columns. O(runs + width log width) array work, no per-run Python step and no per-pixel
    expansion.
    """
    n = c1 - c0 + 1
    lvl = np.frexp(n.astype(float))[1] - 1   # floor(log2 n), exact for integers
    top = int(lvl.max()) + 1 if n.size else 1
    if down:
        op, fill = np.maximum, -1
    else:
        op, fill = np.minimum, np.iinfo(np.int64).max
    T = np.full((top, width), fill, dtype=np.int64)
    r = row.astype(np.int64)
    flat, at = T.reshape(-1), lvl.astype(np.int64) * width   # flat indices: a faster scatter
    op.at(flat, at + c0, r)
    op.at(flat, at + (c1 - (np.int64(1) << lvl) + 1), r)
    for level in range(top - 1, 0, -1):
        h = 1 << (level - 1)
        lo, hi = T[level - 1], T[level]
        op(lo, hi, out=lo)
        op(lo[h:], hi[:width - h], out=lo[h:])
    ext = T[0]
    u = np.nonzero(ext != fill)[0]
    return u, ext[u]


#: Outward direction of each scan (+u, -u, +v, -v): the image axis and its sign.
_SCAN_SIGN = np.array([1.0, -1.0, 1.0, -1.0])


def _sector_and_lit(cand: FloatArray, scan: NDArray, centre: FloatArray, d: FloatArray,
                    min_cos: float) -> NDArray[np.bool_]:
    """Keep a candidate if it lies in its scan's sector (within 45 deg of the scan direction,
    seen from ``centre``) and its outward direction faces the Sun (``n . d >= min_cos``)."""
    rel = cand - centre
    dist = np.sqrt(rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        n = rel / dist[:, None]
    along = np.where(scan < 2, n[:, 0], n[:, 1]) * _SCAN_SIGN[scan]   # n . scan direction
    return (dist > 0) & (along >= math.sqrt(0.5) - 1e-12) & (n @ d >= min_cos)


def limb_points_from_segments(
    segments: Segments,
    sun_dir_image: ArrayLike,
    *,
    options: SIView | None = None,
) -> LimbPoints:
    """Pixel-accuracy limb points from segments (steps 3-7 of the module docstring).

    Parameters
    ----------
    segments : Segments
        The full-image-compressed readout of one frame.
    sun_dir_image : (2,) array
        Direction of the Sun in the image at the Moon (:func:`sun_direction_in_image`) [-].
    options : SIView, optional
        The SI view of a :class:`LimbConfig` (``LimbConfig(...).to_si()``); default its
        defaults.

    Returns
    -------
    LimbPoints
        Points [px], ordered by angle about the fitted centre.

    Raises
    ------
    LimbNotFoundError
        No run survives the filters, or fewer than :data:`MIN_POINTS` limb points remain
        (a degenerate arc). The message says which.
    """
    opt = options if options is not None else _DEFAULT
    if segments is None or len(segments) == 0:
        raise LimbNotFoundError("segments: the readout has no run above threshold (no Moon in "
                                "the frame, or an exposure too short for the threshold)",
                                "no-segments" if segments is None else "no-moon")
    d = np.asarray(sun_dir_image, float)
    d = d / np.linalg.norm(d)
    keep = (segments.level >= opt.min_level) & (segments.length >= opt.min_run_length_px)
    if not np.any(keep):
        raise LimbNotFoundError(
            f"segments: none of the {len(segments)} runs has level >= {opt.min_level} and "
            f"length >= {opt.min_run_length_px} px", "no-moon")
    row = segments.row[keep].astype(np.int64)
    c0 = segments.col_start[keep].astype(np.int64)
    L = segments.length[keep].astype(np.int64)
    c1 = c0 + L - 1
    H, W = segments.shape
    if W <= 0 or H <= 0:
        W = int(c1.max()) + 1
        H = int(row.max()) + 1

    # four scans: right/left end of every row, bottom/top end of every column
    ur, vr = _row_scan(row, c0, c1, right=True)
    ul, vl = _row_scan(row, c0, c1, right=False)
    ub, vb = _column_scan(row, c0, c1, W, down=True)
    ut, vt = _column_scan(row, c0, c1, W, down=False)
    cand = np.concatenate([np.column_stack([ur, vr]), np.column_stack([ul, vl]),
                           np.column_stack([ub, vb]), np.column_stack([ut, vt])]).astype(float)
    # sector of each scan: outward direction the scan looks at (+u, -u, +v, -v)
    scan = np.repeat(np.arange(4), [ur.size, ul.size, ub.size, ut.size])
    b = opt.drop_border_px
    if b > 0:
        inside = ((cand[:, 0] >= b) & (cand[:, 0] <= W - 1 - b)
                  & (cand[:, 1] >= b) & (cand[:, 1] <= H - 1 - b))
        cand, scan = cand[inside], scan[inside]
    # first centre: the scans facing the Sun (limb points, a few terminator points trimmed)
    facing = (scan == (0 if d[0] >= 0 else 1)) | (scan == (2 if d[1] >= 0 else 3))
    n_cand = int(facing.sum())
    if n_cand < MIN_POINTS:
        raise LimbNotFoundError(f"degenerate arc: {n_cand} limb candidates (< "
                                f"{MIN_POINTS}) in {len(segments)} runs", "degenerate-arc")
    centre, radius = _robust_circle(cand[facing])
    ok = _sector_and_lit(cand, scan, centre, d, opt.min_sun_cos)
    if ok.sum() >= MIN_POINTS:  # second pass with the centre of the lit limb alone
        centre, radius = fit_circle_kasa(cand[ok])
        ok = _sector_and_lit(cand, scan, centre, d, opt.min_sun_cos)
    # a corner pixel can end a row and a column: unique pixels, sorted by (u, v) as
    # np.unique(axis=0) would, through one integer key (4x faster)
    ij = cand[ok].astype(np.int64)
    key = np.sort(ij[:, 0] * (int(H) + 1) + ij[:, 1])   # np.unique, without its hash table
    first = np.ones(key.size, bool)
    np.not_equal(key[1:], key[:-1], out=first[1:])
    key = key[first]
    pts = np.column_stack([key // (int(H) + 1), key % (int(H) + 1)]).astype(float)
    if pts.shape[0] < MIN_POINTS:
        raise LimbNotFoundError(
            f"degenerate arc: {pts.shape[0]} lit limb points (< {MIN_POINTS}) out of "
            f"{n_cand} candidates; the lit limb is too short or outside the field",
            "degenerate-arc")
    ang = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    # order along the arc: start the angle at the side opposite to the Sun
    a0 = math.atan2(-d[1], -d[0])
    order = np.argsort(np.mod(ang - a0, 2.0 * np.pi))
    pts = pts[order]
    if pts.shape[0] > opt.max_points:
        # evenly spaced, more than 1 apart: distinct once rounded
        step = (pts.shape[0] - 1) / (opt.max_points - 1)   # np.linspace's, end point exact
        idx = np.rint(np.arange(opt.max_points) * step).astype(int)
        idx[-1] = pts.shape[0] - 1
        pts = pts[idx]
    if opt.point_offset_px != 0.0:
        rel = pts - centre
        pts = pts - opt.point_offset_px * rel / np.linalg.norm(rel, axis=1)[:, None]
    log.debug("limb: %d candidates -> %d lit limb points, circle r = %.2f px",
              n_cand, pts.shape[0], radius)
    return LimbPoints(
        uv=pts,
        sigma_px=np.full(pts.shape[0], opt.point_sigma_px),
        centre_px=centre,
        radius_px=radius,
        sun_dir_image=d,
        n_candidates=n_cand,
    )
