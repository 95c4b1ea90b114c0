"""Features of the fly-by front end: corners in the windows, Lucas-Kanade between frames,
and the epipolar test with the tracker's own attitude.

Each step and what limits the accuracy: docs/methods.md, "starnav.navigation.trn.features".

Technique
---------
1. DN to 8 bit for OpenCV's LK (:func:`to_8bit`), one map per track's pair of patches.
2. Detection (:func:`detect_corners`): Shi-Tomasi in a window's allowed region, at pixel
   centres (the truth is read from the renderer's per-pixel AOVs).
3. Tracking (:func:`track_patch`): pyramidal LK from the prediction, then backwards; the
   forward-backward distance below ``fb_max_px``.
4. Epipolar test with the known attitude (:func:`epipolar_ransac`): each track constrains the
   translation, ``n . t = 0``; RANSAC over pairs.

Index
-----
:func:`to_8bit`, :func:`detect_corners`, :func:`track_patch`, :func:`epipolar_ransac`,
:data:`LK_CRITERIA`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from starnav.typing import FloatArray

#: LK termination: 30 iterations or 0.003 px.
LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.003)


def to_8bit(dn: NDArray[np.integer], dn_range: tuple[float, float]) -> NDArray[np.uint8]:
    """Map DN to 8 bit with ``(lo, hi) -> (0, 255)`` (module step 1)."""
    lo, hi = dn_range
    q = (dn.astype(np.float32) - np.float32(lo)) * np.float32(255.0 / (hi - lo))
    return np.clip(np.rint(q), 0, 255).astype(np.uint8)


def detect_corners(dn: NDArray[np.integer], allowed: NDArray[np.bool_], *, max_corners: int,
                   quality: float, min_distance_px: float, block_px: int) -> FloatArray:
    """Shi-Tomasi corners ``(n, 2)`` ``(u, v)`` in the crop's pixel coordinates (step 2)."""
    if max_corners < 1 or not allowed.any():
        return np.zeros((0, 2))
    c = cv2.goodFeaturesToTrack(dn.astype(np.float32), maxCorners=int(max_corners),
                                qualityLevel=float(quality), minDistance=float(min_distance_px),
                                mask=allowed.astype(np.uint8), blockSize=int(block_px))
    if c is None:
        return np.zeros((0, 2))
    return c.reshape(-1, 2).astype(float)


def track_patch(prev8: NDArray[np.uint8], next8: NDArray[np.uint8], p_prev: FloatArray,
                p_init: FloatArray, *, template_half_px: int, fb_max_px: float
                ) -> tuple[FloatArray | None, float, float]:
    """Track one point from ``prev8`` to ``next8`` (patch coordinates, step 3).

    Returns
    -------
    p_next : (2,) array or None
        Tracked position in ``next8`` coordinates; None when LK failed or the
        forward-backward distance exceeds ``fb_max_px``.
    fb_px : float
        Forward-backward distance [px] (inf on failure).
    min_eig : float
        LK's minimum eigenvalue of the template's spatial gradient matrix (normalised by the
        template's pixel count, intensities in 8 bit).
    """
    win = (2 * template_half_px + 1, 2 * template_half_px + 1)
    p0 = np.asarray(p_prev, np.float32).reshape(1, 1, 2)
    p1 = np.asarray(p_init, np.float32).reshape(1, 1, 2).copy()
    flags = cv2.OPTFLOW_USE_INITIAL_FLOW | cv2.OPTFLOW_LK_GET_MIN_EIGENVALS
    p1, st, eig = cv2.calcOpticalFlowPyrLK(prev8, next8, p0, p1, winSize=win, maxLevel=0,
                                           criteria=LK_CRITERIA, flags=flags)
    if st is None or not st[0, 0]:
        return None, math.inf, 0.0
    back = p0.copy()
    pb, st_b, _ = cv2.calcOpticalFlowPyrLK(next8, prev8, p1, back, winSize=win, maxLevel=0,
                                           criteria=LK_CRITERIA, flags=flags)
    if st_b is None or not st_b[0, 0]:
        return None, math.inf, float(eig[0, 0])
    fb = float(np.linalg.norm(pb.reshape(2) - p0.reshape(2)))
    if fb > fb_max_px:
        return None, fb, float(eig[0, 0])
    return p1.reshape(2).astype(float), fb, float(eig[0, 0])


def epipolar_ransac(x_prev: FloatArray, x_cur: FloatArray, R: FloatArray, threshold: float,
                    iterations: int, rng: np.random.Generator) -> tuple[NDArray[np.bool_],
                                                                        FloatArray]:
    """Tracks consistent with one camera translation, the rotation known (step 4).

    Parameters
    ----------
    x_prev, x_cur : (n, 3) arrays
        Lines of sight (any length) of the tracks in the previous and current camera frames.
    R : (3, 3) array
        Rotation previous camera -> current camera.
    threshold : float
        Largest distance to the epipolar line, in normalised image units (px / focal in px).
    iterations : int
        Pairs drawn.
    rng : numpy Generator

    Returns
    -------
    inliers : (n,) bool
    t : (3,) array
        Unit translation direction of the best pair (zeros when fewer than 3 tracks: then
        every track is kept, nothing can be tested).
    """
    n = len(x_prev)
    if n < 3:
        return np.ones(n, bool), np.zeros(3)
    a = x_prev @ R.T
    a = a / a[:, 2:3]
    b = x_cur / x_cur[:, 2:3]
    normals = np.cross(a, b)

    i = rng.integers(0, n, int(iterations))
    j = (i + rng.integers(1, n, int(iterations))) % n  # a different track
    t = np.cross(normals[i], normals[j])
    norm = np.linalg.norm(t, axis=1)
    t = t[norm > 1e-15] / norm[norm > 1e-15, None]
    best_count = -1
    best, best_t = np.ones(n, bool), np.zeros(3)
    if len(t):
        lines = np.cross(t[:, None, :], a[None, :, :])  # epipolar lines (draw, track, 3)
        r = np.abs(np.sum(lines * b[None], axis=2)) / np.maximum(
            np.hypot(lines[..., 0], lines[..., 1]), 1e-300)
        inl = r < threshold
        count = inl.sum(axis=1)
        cost = np.minimum(r, threshold).sum(axis=1)
        k = int(np.lexsort((cost, -count))[0])  # most inliers, then the smallest cost
        best, best_t, best_count = inl[k], t[k], int(count[k])
    if best_count < 0:  # every pair degenerate: a pure rotation, nothing to reject
        return np.ones(n, bool), np.zeros(3)
    return best, best_t
