"""Features of the fly-by front end: corners in the windows, Lucas-Kanade between frames,
and the epipolar test with the tracker's own attitude.

Technique
---------
1. **DN to 8 bit.** OpenCV's pyramidal Lucas-Kanade takes 8-bit images. A patch is mapped
   ``q = clip(round(255 (DN - lo) / (hi - lo)), 0, 255)`` with ``(lo, hi)`` the 1st and
   99.9th percentile of the lit body's DN in *this* frame's segments, the same map for the
   previous and the current patch of a track (brightness constancy holds between them). With a
   body spread over ~2000 DN the step is ~8 DN (a quantisation noise of 2.3 DN rms), below the
   shot noise of a well-exposed pixel (tens of DN). Detection works on the DN as float32.
2. **Detection** (:func:`detect_corners`): Shi-Tomasi (``cv2.goodFeaturesToTrack``) in a
   window's allowed region (clear of the window border by the tracking patch, of the limb and
   terminator by ``limb_margin_px``, of existing tracks by ``min_distance_px``). Corners are
   kept at pixel centres: the truth of a track is the surface point the pixel-centre ray of
   its first position hits, read exactly from the renderer's per-pixel AOVs.
3. **Tracking** (:func:`track_patch`): a square patch of half side ``template_half +
   search_margin + 1`` around the track in the previous frame's window and one around its
   predicted position in this frame's window (both wholly inside the windows read, else the
   track ends: "left the window"); pyramidal LK (``cv2.calcOpticalFlowPyrLK``, 2 levels,
   ``2 template_half + 1`` window, started at the prediction), then the same backwards: the
   forward-backward distance must stay below ``fb_max_px``.
4. **Epipolar test with the known attitude** (:func:`epipolar_ransac`). Between two frames the
   body turns by the camera's rotation ``R = R_k^T R_{k-1}`` (from the tracker's own
   attitude; the asteroid's spin, < 1e-5 rad per frame, is neglected) and the camera moves by
   an unknown ``t``: ``x_k . (t x R x_{k-1}) = 0`` for every surface point. Each track gives
   one linear constraint ``n . t = 0`` with ``n = R x_{k-1} x x_k``, two tracks fix
   ``t = n_i x n_j``; RANSAC over pairs keeps the tracks within ``epipolar_px`` of their
   epipolar line. OpenCV has no known-rotation solver (``findEssentialMat`` would re-estimate
   the rotation the tracker measures better); a near-pure rotation (``t ~ 0``) passes every
   track, which is right: nothing can then be told apart.

What limits the accuracy
------------------------
The asteroid's texture at these resolutions is shading of facets and shadows, smooth at the
scale of the template: the LK error grows as ``sigma_DN / sqrt(sum |grad I|^2)``; the
template's perspective change between frames (the view turns by ``v dt / d``) biases it;
frame-to-frame tracking makes the error a random walk along the track (the truth is the
point seen at the first detection). The per-feature 1-sigma is therefore
``sqrt(sigma_detect^2 + age sigma_step^2)``, constants measured on rendered fly-bys
(``tests/navigation/test_trn_frontend.py``).
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
