"""Geometric calibration of the bench: dot pattern, centroids, calibration polynomials,
pre-warping, residuals. Each step in full: docs/methods.md, "starnav.calibration.geometric".

Technique
---------
1. Desired dots: a grid in the camera image turned into line-of-sight tangents with the camera
   model (its own distortion is not part of the bench calibration).
2. Display: Gaussian dots in radiance where the nominal bench would put them.
3. Acquisition minus a dark frame.
4. Centroiding: threshold, components, re-centred intensity-weighted centroids.
5. Matching observed to displayed dots (offset vote, mutual nearest neighbours, affine).
6. Fit: polynomials ``P`` (camera tangent -> screen) and ``Q`` (screen -> camera tangent) by
   least squares; the residual on held-out dots.
7. Closed-loop validation on a second grid drawn at ``P(t)`` (the paper's Fig. 12).
8. Pre-warping an image (:func:`prewarp`) through ``Q``.

References
----------
Seed paper, "Geometric Calibration" and Figs. 12-13 (polynomial fitted to displayed dots,
< 30 arcsec); the paper's refs. 7 and 19 for the method.

Index
-----
:func:`calibrate_geometry`, :class:`GeometricCalibrationResult`, :class:`GeometricCalibration`,
:class:`Polynomial2D`, :func:`exponents`; :class:`ScreenMapping`, :class:`NominalMapping`,
:class:`TrueMapping`; :func:`dot_grid`, :func:`fit_dot_grid`, :func:`acquire_dots`,
:class:`DotAcquisition`, :func:`auto_dot_exposure`, :func:`detect_dots`,
:func:`intensity_centroid`, :func:`match_points`; :func:`prewarp`, :func:`stimulus_counts`;
:func:`pixel_to_tangent`, :func:`tangent_to_los`, :func:`angular_residual_arcsec`;
:class:`CalibrationError`.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from scipy.spatial import cKDTree

from starnav.calibration.bench import (
    Acquisition,
    Bench,
    BenchGeometry,
    DetectorStage,
    angle_between,
)
from starnav.calibration.collimator import vignetting
from starnav.calibration.screen import gaussian_dots
from starnav.calibration.streams import bench_rng
from starnav.camera import Camera
from starnav.constants import ARCSEC
from starnav.errors import ConfigError, StarnavError
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Frame indices (temporal-noise streams) of the geometric calibration acquisitions.
FRAME_PREVIEW, FRAME_DARK, FRAME_DOTS, FRAME_VALIDATION = 99, 100, 101, 102
#: Frame index of the random-layout hold-out (its dark frame: + 1000).
FRAME_RANDOM_LAYOUT = 103
#: Smallest connected area of a dot [px] (rejects isolated hot or noisy pixels).
MIN_DOT_AREA_PX = 4
#: Smallest dot spacing, in centroid windows (2 h + 1) [-].
MIN_SPACING_WINDOWS = 2
#: Largest global misalignment searched by the matching vote [px].
MAX_SHIFT_PX = 150.0


class CalibrationError(StarnavError, RuntimeError):
    """A calibration step could not complete (too few dots seen, singular fit, ...)."""


# =========================================================================== polynomials
def exponents(order: int) -> list[tuple[int, int]]:
    """Monomial exponents ``(p, q)`` of ``x^p y^q`` with ``p + q <= order``."""
    return [(p, d - p) for d in range(order + 1) for p in range(d, -1, -1)]


@dataclass(frozen=True)
class Polynomial2D:
    """A map R^2 -> R^2, each output a polynomial of total degree ``order`` in
    ``(x - centre) / scale``.

    Attributes
    ----------
    order : int
    centre : (2,) array
    scale : float
    coef : (n_terms, 2) array
        Coefficients of :func:`exponents` ``(order)``, per output.
    """

    order: int
    centre: FloatArray
    scale: float
    coef: FloatArray

    @staticmethod
    def _design(xn: FloatArray, order: int) -> FloatArray:
        x, y = xn[:, 0], xn[:, 1]
        return np.stack([x**p * y**q for p, q in exponents(order)], axis=1)

    @classmethod
    def fit(cls, x: ArrayLike, y: ArrayLike, order: int) -> Polynomial2D:
        """Least-squares fit of ``y ~ poly(x)``.

        Raises
        ------
        CalibrationError
            Fewer points than coefficients, or a rank-deficient design.
        """
        x = np.asarray(x, float).reshape(-1, 2)
        y = np.asarray(y, float).reshape(-1, 2)
        n_terms = len(exponents(order))
        if len(x) < n_terms:
            raise CalibrationError(f"{len(x)} point(s) for a degree-{order} polynomial with "
                                   f"{n_terms} coefficients per axis; lower "
                                   "geometric.polynomial_order or use more dots")
        centre = x.mean(axis=0)
        scale = float(np.max(np.abs(x - centre))) or 1.0
        A = cls._design((x - centre) / scale, order)
        coef, _, rank, _ = np.linalg.lstsq(A, y, rcond=None)
        if rank < n_terms:
            raise CalibrationError(f"degree-{order} fit is rank deficient ({rank} < {n_terms}): "
                                   "the dots do not span the field")
        return cls(order, centre, scale, coef)

    def __call__(self, x: ArrayLike) -> FloatArray:
        x = np.asarray(x, float)
        shp = x.shape
        xn = (x.reshape(-1, 2) - self.centre) / self.scale
        return (self._design(xn, self.order) @ self.coef).reshape(shp)

    def to_dict(self) -> dict[str, Any]:
        return {"order": self.order, "centre": self.centre.tolist(), "scale": self.scale,
                "exponents": exponents(self.order), "coef": self.coef.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Polynomial2D:
        return cls(int(d["order"]), np.asarray(d["centre"], float), float(d["scale"]),
                   np.asarray(d["coef"], float))


# =========================================================================== mappings
class ScreenMapping(Protocol):
    """What a stimulus generator needs: screen pixel <-> camera line-of-sight tangent."""

    def screen_for_tangent(self, t: FloatArray) -> FloatArray:
        """Camera tangents ``(..., 2)`` -> screen pixels ``(..., 2)`` (column, row)."""
        ...

    def tangent_for_screen(self, ji: FloatArray) -> FloatArray:
        """Screen pixels ``(..., 2)`` -> camera tangents ``(..., 2)``."""
        ...


@dataclass(frozen=True)
class NominalMapping:
    """The bench as designed (uncalibrated): a screen point at ``f t`` is seen along ``t``."""

    geometry: BenchGeometry

    def screen_for_tangent(self, t: FloatArray) -> FloatArray:
        return self.geometry.nominal_tangent_to_screen(t)

    def tangent_for_screen(self, ji: FloatArray) -> FloatArray:
        return self.geometry.screen_to_nominal_tangent(ji)


@dataclass(frozen=True)
class TrueMapping:
    """The emulated bench's exact mapping (an oracle for tests that isolate radiometry)."""

    geometry: BenchGeometry

    def screen_for_tangent(self, t: FloatArray) -> FloatArray:
        t = np.asarray(t, float)
        uv = self.geometry.camera.project(np.concatenate([t, np.ones(t.shape[:-1] + (1,))], -1))
        return self.geometry.pixel_to_screen(uv)

    def tangent_for_screen(self, ji: FloatArray) -> FloatArray:
        v = self.geometry.screen_to_los(ji)
        return v[..., :2] / v[..., 2:3]


@dataclass(frozen=True)
class GeometricCalibration:
    """The fitted bench model: calibration polynomials between screen and camera tangents.

    Attributes
    ----------
    to_screen : Polynomial2D
        ``P``: camera tangent -> nominal screen tangent ``(a, b) / f_coll``.
    to_camera : Polynomial2D
        ``Q``: nominal screen tangent -> camera tangent.
    geometry : BenchGeometry
        Nominal geometry (screen size, pitch, collimator focal length) for unit conversions.
    stats : dict
        Fit statistics (see :class:`GeometricCalibrationResult`).
    """

    to_screen: Polynomial2D
    to_camera: Polynomial2D
    geometry: BenchGeometry
    stats: dict[str, Any] = field(default_factory=dict)

    def screen_for_tangent(self, t: FloatArray) -> FloatArray:
        return self.geometry.nominal_tangent_to_screen(self.to_screen(t))

    def tangent_for_screen(self, ji: FloatArray) -> FloatArray:
        return self.to_camera(self.geometry.screen_to_nominal_tangent(ji))

    def to_dict(self) -> dict[str, Any]:
        g = self.geometry
        return {"kind": "starnav.calibration.geometric", "version": 1,
                "screen_shape_rows_cols": list(g.shape), "screen_pitch_m": g.pitch,
                "collimator_focal_length_m": g.focal_length,
                "to_screen": self.to_screen.to_dict(), "to_camera": self.to_camera.to_dict(),
                "stats": self.stats}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, d: dict[str, Any], camera: Camera) -> GeometricCalibration:
        """Rebuild from :meth:`to_dict` (the camera is needed for pixel conversions).

        Raises
        ------
        ConfigError
            Not a starnav geometric calibration.
        """
        if d.get("kind") != "starnav.calibration.geometric":
            raise ConfigError("geometric calibration file kind", d.get("kind"),
                              "'starnav.calibration.geometric' (written by hil geometric)")
        rows, cols = d["screen_shape_rows_cols"]
        g = BenchGeometry(camera, float(d["collimator_focal_length_m"]),
                          float(d["screen_pitch_m"]), (int(rows), int(cols)))
        return cls(Polynomial2D.from_dict(d["to_screen"]),
                   Polynomial2D.from_dict(d["to_camera"]), g, dict(d.get("stats", {})))


# =========================================================================== dots
def dot_grid(camera: Camera, n: tuple[int, int], margin_px: float,
             offset_half_step: bool = False) -> FloatArray:
    """Desired dot positions ``(N, 2)`` (u, v) on the detector [px]: ``n = (nx, ny)`` evenly
    spaced between ``margin_px`` from each edge; ``offset_half_step`` shifts the grid by half a
    step (and drops the outermost column/row) to fall between the calibration dots."""
    nx, ny = n
    u0, u1 = margin_px, camera.width - 1 - margin_px
    v0, v1 = margin_px, camera.height - 1 - margin_px
    if offset_half_step:
        su = (u1 - u0) / max(nx, 1)
        sv = (v1 - v0) / max(ny, 1)
        us = u0 + su * (np.arange(nx) + 0.5)
        vs = v0 + sv * (np.arange(ny) + 0.5)
    else:
        us = np.linspace(u0, u1, nx)
        vs = np.linspace(v0, v1, ny)
    U, V = np.meshgrid(us, vs)
    return np.stack([U.ravel(), V.ravel()], -1)


def fit_dot_grid(camera: Camera, n: tuple[int, int], margin_px: float, half_window: int,
                 offset: bool = False) -> tuple[int, int]:
    """``n`` reduced so that dots stay :data:`MIN_SPACING_WINDOWS` centroid windows apart on
    this detector (a small detector gets fewer dots, with a log message)."""
    min_sp = MIN_SPACING_WINDOWS * (2 * half_window + 1)
    out = []
    for k, size in zip(n, (camera.width, camera.height), strict=True):
        span = size - 1 - 2 * margin_px
        kmax = int(span // min_sp) + (0 if offset else 1)
        out.append(max(1 if offset else 2, min(k, kmax)))
    if tuple(out) != tuple(n):
        log.info("dot grid %s reduced to %s to keep dots %d px apart on a %d x %d detector",
                 tuple(n), tuple(out), min_sp, camera.width, camera.height)
    return out[0], out[1]


def pixel_to_tangent(camera: Camera, uv: ArrayLike) -> FloatArray:
    """Detector pixels (distorted image) -> undistorted line-of-sight tangents ``(..., 2)``."""
    return camera.pixel_to_normalized(np.asarray(uv, float), undistort=True)


def tangent_to_los(t: ArrayLike) -> FloatArray:
    """Tangents ``(..., 2)`` -> unit vectors ``(..., 3)``."""
    t = np.asarray(t, float)
    v = np.concatenate([t, np.ones(t.shape[:-1] + (1,))], -1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angular_residual_arcsec(t_a: ArrayLike, t_b: ArrayLike) -> FloatArray:
    """Angle between the lines of sight of two tangent arrays [arcsec]."""
    return angle_between(tangent_to_los(t_a), tangent_to_los(t_b)) / ARCSEC


def detect_dots(image: ArrayLike, threshold: float, half_window: int,
                min_area: int = MIN_DOT_AREA_PX) -> tuple[FloatArray, FloatArray]:
    """Centroids of the bright blobs of a background-subtracted image.

    Parameters
    ----------
    image : (H, W) array
        Background-subtracted signal [DN or e-].
    threshold : float
        Detection threshold [same unit].
    half_window : int
        Centroid window half size [px]; windows that leave the image are rejected.
    min_area : int
        Smallest connected area above threshold [px].

    Returns
    -------
    centroids : (N, 2) array
        ``(u, v)`` [px].
    flux : (N,) array
        Sum of the window [same unit as ``image``].
    """
    img = np.asarray(image, float)
    H, W = img.shape
    lab, n = ndimage.label(img > threshold)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0)
    idx = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(img), lab, idx)
    peaks = ndimage.maximum_position(img, lab, idx)
    h = int(half_window)
    offs = np.arange(-h, h + 1, dtype=float)
    cents, fluxes = [], []
    for a, (r, c) in zip(area, peaks, strict=True):
        if a < min_area:
            continue
        cu, cv = float(c), float(r)
        ok = True
        s = 0.0
        for _ in range(3):
            r0, c0 = int(round(cv)) - h, int(round(cu)) - h
            if r0 < 0 or c0 < 0 or r0 + 2 * h + 1 > H or c0 + 2 * h + 1 > W:
                ok = False
                break
            win = img[r0:r0 + 2 * h + 1, c0:c0 + 2 * h + 1]
            s = float(win.sum())
            if s <= 0:
                ok = False
                break
            cu = c0 + h + float((win.sum(axis=0) * offs).sum()) / s
            cv = r0 + h + float((win.sum(axis=1) * offs).sum()) / s
        if ok:
            cents.append((cu, cv))
            fluxes.append(s)
    return np.asarray(cents, float).reshape(-1, 2), np.asarray(fluxes, float)


def match_points(observed: ArrayLike, predicted: ArrayLike, spacing: float,
                 max_shift: float = MAX_SHIFT_PX) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Pair observed with predicted points of a grid of pitch ``spacing`` [px].

    Returns index arrays ``(i_obs, i_pred)`` of the matched pairs.
    """
    obs = np.asarray(observed, float).reshape(-1, 2)
    pred = np.asarray(predicted, float).reshape(-1, 2)
    if len(obs) == 0 or len(pred) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # 1. global shift by a vote over every pairwise offset. The offsets of a periodic grid pile
    # up at every lattice vector; the right one has the most pairs (a wrong one loses a row or
    # a column at the grid's edge), but only if each peak is counted whole: a rotation or a
    # distortion spreads a peak over a good part of a spacing, so the vote sums boxes half a
    # spacing wide, not a few bins (which picks a lattice neighbour at random)
    d = (obs[:, None, :] - pred[None, :, :]).reshape(-1, 2)
    d = d[np.all(np.abs(d) <= max_shift, axis=1)]
    shift = np.zeros(2)
    if len(d):
        b = max(2.0, spacing / 16.0)
        nb = int(math.ceil(2 * max_shift / b))
        hist, xe, ye = np.histogram2d(d[:, 0], d[:, 1], bins=nb,
                                      range=[[-max_shift, max_shift]] * 2)
        box = 2 * max(1, int(round(spacing / (4.0 * b)))) + 1
        votes = np.rint(ndimage.correlate(hist, np.ones((box, box)), mode="constant"))
        # a tie is not rare: an offset that pushes a row (column) of dots off the detector
        # leaves the grid one row short, and the lattice vector one spacing the other way pairs
        # as many dots. Positions alone cannot tell the two apart; the nominal bench's
        # prediction can: of the candidates with the most votes, the offset nearest zero
        # (right whenever the true offset is under half a spacing)
        cx = (xe[:-1] + xe[1:]) / 2
        cy = (ye[:-1] + ye[1:]) / 2
        best = votes == votes.max()
        dist = np.where(best, np.hypot(cx[:, None], cy[None, :]), np.inf)
        ix, iy = np.unravel_index(int(np.argmin(dist)), dist.shape)
        centre = np.array([cx[ix], cy[iy]])
        near = np.all(np.abs(d - centre) < spacing / 4.0, axis=1)
        shift = np.median(d[near], axis=0) if np.any(near) else centre

    def mutual(p: FloatArray, gate: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        t_pred = cKDTree(p)
        t_obs = cKDTree(obs)
        dist, j = t_pred.query(obs, distance_upper_bound=gate)
        _, back = t_obs.query(p, distance_upper_bound=gate)
        i = np.arange(len(obs))
        ok = np.isfinite(dist)
        ok[ok] &= back[j[ok]] == i[ok]
        return i[ok], j[ok].astype(np.int64)

    io, ip = mutual(pred + shift, spacing / 3.0)
    if len(io) >= 3:
        A = np.concatenate([pred[ip], np.ones((len(ip), 1))], 1)
        M, *_ = np.linalg.lstsq(A, obs[io], rcond=None)
        io, ip = mutual(np.concatenate([pred, np.ones((len(pred), 1))], 1) @ M, spacing / 4.0)
    return io, ip


# =========================================================================== pre-warping
def prewarp(le_camera: ArrayLike, mapping: ScreenMapping, bench: Bench,
            scale: float = 1.0) -> FloatArray:
    """Screen electron radiance ``(rows, cols)`` that reproduces a pinhole image at the camera.

    Every screen pixel near the image's lit region takes ``scale`` x the value of the pinhole
    image ``le_camera`` [e- s^-1 m^-2 sr^-1] at the pixel where ``mapping`` says it is seen
    (bilinear; zero outside). With a collimator aperture set, the design vignetting is divided
    out.
    """
    le = np.asarray(le_camera, float)
    cam = bench.camera
    if le.shape != (cam.height, cam.width):
        raise ConfigError("image Le", f"shape {le.shape}",
                          f"the camera's ({cam.height}, {cam.width})")
    Hs, Ws = bench.screen_shape
    out = np.zeros((Hs, Ws))
    rows, cols = np.nonzero(le > 0)
    if rows.size == 0:
        return out
    # where the lit box (plus 2 px) lands on the screen
    u0, u1 = cols.min() - 2.5, cols.max() + 2.5
    v0, v1 = rows.min() - 2.5, rows.max() + 2.5
    n = 33
    border = np.concatenate([
        np.stack([np.linspace(u0, u1, n), np.full(n, v0)], -1),
        np.stack([np.linspace(u0, u1, n), np.full(n, v1)], -1),
        np.stack([np.full(n, u0), np.linspace(v0, v1, n)], -1),
        np.stack([np.full(n, u1), np.linspace(v0, v1, n)], -1)])
    t = np.stack([(border[:, 0] - cam.cx) / cam.fx, (border[:, 1] - cam.cy) / cam.fy], -1)
    ji = mapping.screen_for_tangent(t)
    j0 = max(int(math.floor(ji[:, 0].min())) - 3, 0)
    j1 = min(int(math.ceil(ji[:, 0].max())) + 4, Ws)
    i0 = max(int(math.floor(ji[:, 1].min())) - 3, 0)
    i1 = min(int(math.ceil(ji[:, 1].max())) + 4, Hs)
    if j1 <= j0 or i1 <= i0:
        return out
    J, I = np.meshgrid(np.arange(j0, j1, dtype=float), np.arange(i0, i1, dtype=float))
    tt = mapping.tangent_for_screen(np.stack([J, I], -1))
    u = cam.fx * tt[..., 0] + cam.cx
    v = cam.fy * tt[..., 1] + cam.cy
    vals = ndimage.map_coordinates(le, [v.ravel(), u.ravel()], order=1, mode="constant",
                                   cval=0.0).reshape(u.shape)
    if bench.config.collimator.clear_aperture_mm is not None:
        vig = vignetting(bench.config.collimator, cam.pupil_diameter,
                         np.hypot(tt[..., 0], tt[..., 1]))
        vals = np.where(vig > 1e-3, vals / np.maximum(vig, 1e-3), 0.0)
    out[i0:i1, j0:j1] = np.maximum(vals, 0.0) * scale
    return out


def stimulus_counts(le_camera: ArrayLike, mapping: ScreenMapping, bench: Bench,
                    scale: float = 1.0, method: str | None = None,
                    rng: np.random.Generator | None = None) -> NDArray[np.uint16]:
    """Screen counts that display ``scale`` x the pinhole image ``le_camera`` at the camera
    (pre-warp + radiometric inverse; ``method`` default ``radiometric.quantization``).

    Raises
    ------
    ConfigError
        The stimulus exceeds the screen's full white (raise k), or no emittance data.
    """
    target = prewarp(le_camera, mapping, bench, scale)
    m = method or bench.config.radiometric.quantization
    if m == "dither" and rng is None:
        rng = bench_rng(bench.config, "stimulus")
    return bench.radiometry.counts_for(target, m, rng)


# =========================================================================== calibration
@dataclass
class DotAcquisition:
    """Dots shown and seen in one acquisition.

    Attributes
    ----------
    desired_px : (N, 2) array
        Where each dot should appear on the detector [px] (distorted image).
    screen_px : (N, 2) array
        Where each dot was drawn (column, row) [screen px].
    observed_px : (N, 2) array
        Matched centroid, NaN when not found [px].
    acquisition : Acquisition
    dark_dn : (H, W) array or None
    """

    desired_px: FloatArray
    screen_px: FloatArray
    observed_px: FloatArray
    acquisition: Acquisition
    dark_dn: FloatArray | None

    @property
    def found(self) -> NDArray[np.bool_]:
        return np.all(np.isfinite(self.observed_px), axis=1)


def auto_dot_exposure(bench: Bench, counts: NDArray[np.uint16], detector: DetectorStage,
                      fraction: float, frame_index: int = 99) -> float:
    """Exposure [s] at which the brightest dot of ``counts`` peaks at ``fraction`` x the full
    well: a first guess from the collimator-only preview (peak = full well), then one preview
    acquisition with ``detector`` (its peak measured on a 3 x 3 median-filtered frame, so hot
    pixels do not count) rescales it."""
    le = bench.radiance_at_camera(counts)
    peak = float(le.max())
    if peak <= 0:
        raise CalibrationError("the dot pattern does not reach the detector (nothing to "
                               "expose): check the misalignments and the collimator")
    t0 = detector.full_well_e / (peak * bench.camera.etendue)
    fr = detector.expose(le, t0, frame_index)
    sig = ndimage.median_filter(fr.dn, 3) - np.median(fr.dn)
    peak_e = float(sig.max()) * detector.gain_e_per_dn
    if peak_e <= 0:
        return fraction * t0
    return t0 * fraction * detector.full_well_e / min(peak_e, detector.full_well_e)


def acquire_dots(bench: Bench, desired_px: FloatArray, screen_px: FloatArray,
                 detector: DetectorStage, exposure_time: float, frame_index: int,
                 predicted_px: FloatArray, spacing: float,
                 dark_dn: FloatArray | None = None,
                 dark_frame_index: int | None = None) -> DotAcquisition:
    """Display Gaussian dots at ``screen_px``, acquire, centroid and match them to
    ``predicted_px`` (where they are expected on the detector)."""
    g = bench.config.geometric
    rad = bench.radiometry
    counts = gaussian_dots(bench.screen_shape, screen_px, g.dot_sigma_screen_px, rad.le_max, rad)
    acq = bench.acquire(counts, exposure_time, detector, frame_index)
    if g.subtract_dark_frame and dark_dn is None:
        black = np.zeros(bench.screen_shape, np.uint16)
        dark_dn = bench.acquire(black, exposure_time, detector,
                                dark_frame_index if dark_frame_index is not None
                                else frame_index + 1000).dn
    if dark_dn is not None:
        sig = acq.dn - dark_dn
    else:
        sig = acq.dn - np.median(acq.dn)
    noise = 1.4826 * float(np.median(np.abs(sig - np.median(sig))))
    noise = max(noise, 1e-12 * max(float(np.abs(sig).max()), 1.0))
    thr = float(np.median(sig)) + g.detection_threshold_sigma * noise
    cents, _ = detect_dots(sig, thr, g.centroid_half_window_px)
    io, ip = match_points(cents, predicted_px, spacing)
    obs = np.full_like(np.asarray(desired_px, float), np.nan)
    obs[ip] = cents[io]
    log.info("dots: %d shown, %d detected, %d matched (threshold %.3g, noise %.3g)",
             len(desired_px), len(cents), len(io), thr, noise)
    return DotAcquisition(np.asarray(desired_px, float), np.asarray(screen_px, float), obs,
                          acq, dark_dn)


@dataclass
class GeometricCalibrationResult:
    """Everything the geometric calibration measured.

    Attributes
    ----------
    calibration : GeometricCalibration
        Final polynomials (all dots).
    holdout_residual_arcsec : (n,) array
        Angular error of the first fit on the dots kept out of it [arcsec].
    fit_residual_arcsec : (m,) array
        Angular error of the final fit on its own dots [arcsec].
    uncalibrated_residual_arcsec : (N,) array
        Desired vs obtained line of sight with the nominal (uncalibrated) display [arcsec].
    closed_loop_residual_arcsec : (K,) array
        Desired vs obtained line of sight of the validation dots drawn through the calibration
        [arcsec].
    calibration_dots, validation_dots : DotAcquisition
    exposure_time : float
        [s]
    """

    calibration: GeometricCalibration
    holdout_residual_arcsec: FloatArray
    fit_residual_arcsec: FloatArray
    uncalibrated_residual_arcsec: FloatArray
    closed_loop_residual_arcsec: FloatArray
    calibration_dots: DotAcquisition
    validation_dots: DotAcquisition | None
    exposure_time: float

    @staticmethod
    def _rms(x: FloatArray) -> float:
        return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")

    @property
    def holdout_rms_arcsec(self) -> float:
        return self._rms(self.holdout_residual_arcsec)

    @property
    def closed_loop_rms_arcsec(self) -> float:
        return self._rms(self.closed_loop_residual_arcsec)

    @property
    def uncalibrated_rms_arcsec(self) -> float:
        return self._rms(self.uncalibrated_residual_arcsec)

    def summary(self) -> dict[str, Any]:
        def stats(x: FloatArray) -> dict[str, float]:
            if len(x) == 0:
                return {"n": 0}
            return {"n": int(len(x)), "rms_arcsec": self._rms(x),
                    "median_arcsec": float(np.median(x)),
                    "p95_arcsec": float(np.percentile(x, 95)), "max_arcsec": float(np.max(x))}

        return {
            "polynomial_order": self.calibration.to_screen.order,
            "exposure_s": self.exposure_time,
            "dots_shown": int(len(self.calibration_dots.desired_px)),
            "dots_matched": int(self.calibration_dots.found.sum()),
            "uncalibrated": stats(self.uncalibrated_residual_arcsec),
            "fit": stats(self.fit_residual_arcsec),
            "holdout": stats(self.holdout_residual_arcsec),
            "closed_loop": stats(self.closed_loop_residual_arcsec),
            "validation_dots_matched": (int(self.validation_dots.found.sum())
                                        if self.validation_dots is not None else 0),
        }


def calibrate_geometry(bench: Bench, detector: DetectorStage | None = None,
                       rng: np.random.Generator | None = None,
                       validate: bool = True) -> GeometricCalibrationResult:
    """Run the dot-pattern geometric calibration on the emulated bench (module essay, steps
    1-7).

    Parameters
    ----------
    bench : Bench
    detector : DetectorStage, optional
        Default: the scenario's detector chain (:meth:`Bench.chain_detector`).
    rng : numpy.random.Generator, optional
        Hold-out split; default the bench's ``"geometric"`` stream.
    validate : bool
        Also run the closed-loop validation acquisition (step 7).

    Raises
    ------
    CalibrationError
        Too few dots matched for the polynomial order.
    """
    cfg = bench.config.geometric
    det = detector if detector is not None else bench.chain_detector()
    rng = rng if rng is not None else bench_rng(bench.config, "geometric")
    cam = bench.camera
    nominal = NominalMapping(bench.geometry.nominal())
    Hs, Ws = bench.screen_shape
    pad = 4.0 * cfg.dot_sigma_screen_px

    def on_screen(ji: FloatArray) -> NDArray[np.bool_]:
        return ((ji[:, 0] >= pad) & (ji[:, 0] <= Ws - 1 - pad)
                & (ji[:, 1] >= pad) & (ji[:, 1] <= Hs - 1 - pad))

    # 1-2: desired dots, drawn where the nominal bench would put them
    grid = fit_dot_grid(cam, cfg.dot_grid, cfg.dot_margin_px, cfg.centroid_half_window_px)
    valid_grid = fit_dot_grid(cam, cfg.validation_grid, cfg.dot_margin_px,
                              cfg.centroid_half_window_px, offset=True)
    desired = dot_grid(cam, grid, cfg.dot_margin_px)
    t_des = pixel_to_tangent(cam, desired)
    screen = nominal.screen_for_tangent(t_des)
    keep = on_screen(screen)
    desired, t_des, screen = desired[keep], t_des[keep], screen[keep]
    spacing = float(min((cam.width - 2 * cfg.dot_margin_px) / max(grid[0] - 1, 1),
                        (cam.height - 2 * cfg.dot_margin_px) / max(grid[1] - 1, 1)))
    rad = bench.radiometry
    probe = gaussian_dots(bench.screen_shape, screen, cfg.dot_sigma_screen_px, rad.le_max, rad)
    t_exp = (cfg.exposure_ms * 1e-3 if cfg.exposure_ms is not None
             else auto_dot_exposure(bench, probe, det, cfg.dot_peak_fraction, FRAME_PREVIEW))
    # 3-5
    dots = acquire_dots(bench, desired, screen, det, t_exp, FRAME_DOTS, desired, spacing,
                        dark_frame_index=FRAME_DARK)
    found = dots.found
    n_terms = len(exponents(cfg.polynomial_order))
    if found.sum() < n_terms + 3:
        raise CalibrationError(f"only {int(found.sum())} of {len(desired)} dots were seen and "
                               f"matched; a degree-{cfg.polynomial_order} fit needs > "
                               f"{n_terms + 3} (lower geometric.polynomial_order, or "
                               "geometric.dot_margin_px on a small detector)")
    t_obs = pixel_to_tangent(cam, dots.observed_px[found])
    s_nom = bench.geometry.screen_to_nominal_tangent(dots.screen_px[found])
    uncal = angular_residual_arcsec(t_des[found], t_obs)
    # 6: hold-out fit, then the final fit on every dot
    n = len(t_obs)
    n_hold = int(round(cfg.holdout_fraction * n))
    n_hold = min(n_hold, n - (n_terms + 3))
    perm = rng.permutation(n)
    hold, train = perm[:n_hold], perm[n_hold:]
    q_train = Polynomial2D.fit(s_nom[train], t_obs[train], cfg.polynomial_order)
    holdout = (angular_residual_arcsec(q_train(s_nom[hold]), t_obs[hold]) if n_hold > 0
               else np.zeros(0))
    P = Polynomial2D.fit(t_obs, s_nom, cfg.polynomial_order)
    Q = Polynomial2D.fit(s_nom, t_obs, cfg.polynomial_order)
    fit_res = angular_residual_arcsec(Q(s_nom), t_obs)
    calib = GeometricCalibration(P, Q, bench.geometry.nominal())
    # 7: closed loop on dots between the calibration dots
    val = None
    closed = np.zeros(0)
    if validate:
        vdes = dot_grid(cam, valid_grid, cfg.dot_margin_px, offset_half_step=True)
        vt = pixel_to_tangent(cam, vdes)
        vscreen = calib.screen_for_tangent(vt)
        ok = on_screen(vscreen)
        vdes, vt, vscreen = vdes[ok], vt[ok], vscreen[ok]
        vspacing = float(min((cam.width - 2 * cfg.dot_margin_px) / valid_grid[0],
                             (cam.height - 2 * cfg.dot_margin_px) / valid_grid[1]))
        val = acquire_dots(bench, vdes, vscreen, det, t_exp, FRAME_VALIDATION, vdes, vspacing,
                           dark_dn=dots.dark_dn)
        vf = val.found
        closed = angular_residual_arcsec(vt[vf], pixel_to_tangent(cam, val.observed_px[vf]))
    res = GeometricCalibrationResult(calib, holdout, fit_res, uncal, closed, dots, val, t_exp)
    calib.stats.update(res.summary())
    log.info("geometric calibration: uncalibrated %.1f\", hold-out %.2f\", closed loop %.2f\" "
             "RMS", res.uncalibrated_rms_arcsec, res.holdout_rms_arcsec,
             res.closed_loop_rms_arcsec)
    return res


def random_layout_holdout(bench: Bench, calibration: ScreenMapping, n_points: int = 60,
                          rng: np.random.Generator | None = None,
                          detector: DetectorStage | None = None,
                          exposure_time: float | None = None,
                          dark_dn: FloatArray | None = None) -> dict[str, Any]:
    """Geometric hold-out on a layout no calibration grid has: ``n_points`` point sources at
    random positions (seeded, a star-field-like pattern, at least 4 centroid windows apart),
    displayed through ``calibration`` and centroided; their angular error [arcsec].
    ``exposure_time`` [s] and ``dark_dn`` default to a new preview and dark frame.

    Raises
    ------
    CalibrationError
        Fewer than half the points found.
    """
    cam = bench.camera
    cfg = bench.config.geometric
    rng = rng if rng is not None else bench_rng(bench.config, "random_layout")
    det = detector if detector is not None else bench.chain_detector()
    sep = 4.0 * cfg.centroid_half_window_px
    lo = np.array([cfg.dot_margin_px, cfg.dot_margin_px])
    hi = np.array([cam.width - 1 - cfg.dot_margin_px, cam.height - 1 - cfg.dot_margin_px])
    pts: list[FloatArray] = []
    for _ in range(100 * n_points):
        if len(pts) == n_points:
            break
        p = lo + rng.random(2) * (hi - lo)
        if all(np.hypot(*(p - q)) >= sep for q in pts):
            pts.append(p)
    des = np.array(pts)
    t = pixel_to_tangent(cam, des)
    scr = calibration.screen_for_tangent(t)
    H, W = bench.screen_shape
    ok = ((scr[:, 0] >= 0) & (scr[:, 0] <= W - 1) & (scr[:, 1] >= 0) & (scr[:, 1] <= H - 1))
    des, t, scr = des[ok], t[ok], scr[ok]
    if exposure_time is None:
        counts = gaussian_dots(bench.screen_shape, scr, cfg.dot_sigma_screen_px,
                               bench.radiometry.le_max, bench.radiometry)
        exposure_time = auto_dot_exposure(bench, counts, det, cfg.dot_peak_fraction)
    acq = acquire_dots(bench, des, scr, det, exposure_time, FRAME_RANDOM_LAYOUT, des, sep,
                       dark_dn=dark_dn)
    f = acq.found
    if f.sum() < max(3, len(des) // 2):
        raise CalibrationError(f"random-layout hold-out: {int(f.sum())} of {len(des)} points "
                               "found (expected at least half)")
    r = angular_residual_arcsec(t[f], pixel_to_tangent(cam, acq.observed_px[f]))
    return {"points_shown": int(len(des)), "points_found": int(f.sum()),
            "rms_arcsec": float(np.sqrt(np.mean(r**2))),
            "p95_arcsec": float(np.percentile(r, 95)), "max_arcsec": float(r.max())}


# =========================================================================== extended object
def intensity_centroid(image: ArrayLike, mask: ArrayLike) -> FloatArray:
    """Intensity-weighted centroid ``(u, v)`` of ``image`` over ``mask`` [px] (weights not
    clipped)."""
    img = np.where(np.asarray(mask, bool), np.asarray(image, float), 0.0)
    s = img.sum()
    if s <= 0:
        return np.array([np.nan, np.nan])
    v, u = np.indices(img.shape)
    return np.array([(img * u).sum() / s, (img * v).sum() / s])


__all__ = ["CalibrationError", "DotAcquisition", "GeometricCalibration",
           "GeometricCalibrationResult", "NominalMapping", "Polynomial2D", "ScreenMapping",
           "TrueMapping", "acquire_dots", "angular_residual_arcsec", "calibrate_geometry",
           "detect_dots", "dot_grid", "exponents", "intensity_centroid", "match_points",
           "pixel_to_tangent", "prewarp", "random_layout_holdout", "stimulus_counts"]
