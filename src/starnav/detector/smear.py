"""Smear: APS rolling shutter under spacecraft rotation, and CCD frame-transfer smear.

Technique
---------
1. **Image motion.** A spacecraft turning at ``omega = (w_x, w_y)`` [rad/s] about the camera
   x and y axes moves a direction near the boresight by ``d(x, y)/dt = (-w_y, w_x)`` in
   normalised coordinates (from ``ds/dt = -omega x s`` with ``s ~ (x, y, 1)``), i.e. by
   ``a = (-f_x w_y, f_y w_x)`` [px/s]. Rotation about the boresight is not modelled (it would
   make the blur vary over the field).
2. **Rolling shutter.** Row ``r`` integrates over ``[r t_row, r t_row + t_exp]``. A pixel
   collects ``I0(x - a t)`` averaged over that window, which is the image blurred by a line of
   length ``|a| t_exp`` (motion blur) and then shifted by ``a r t_row`` (skew):
   ``out(u, r) = B(u - a_u r t_row, r - a_v r t_row)``. The line kernel is rendered with
   sub-pixel (bilinear) sampling of the segment, unit sum; the per-row shift is a bilinear
   resampling. Both conserve charge except at the array edges.
3. **Frame-transfer smear (CCD option).** While the frame is shifted to the storage area each
   charge packet spends ``t_shift`` under every row of its column and collects its light:
   ``smear(c) = (t_shift / t_exp) * sum_r N(r, c)``, added to every pixel of column ``c``.

References: Liang, C.-K. et al. (2008), *Analysis and compensation of rolling shutter effect*,
IEEE TIP 17(8); Janesick, J. R. (2001), *Scientific Charge-Coupled Devices*, SPIE (smear).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from starnav.detector.fftconv import convolve_add, signal_bbox
from starnav.typing import Float32Array

#: Motion blur shorter than this is ignored [px].
MIN_BLUR_PX = 0.05
#: Sub-samples per pixel of blur length used to draw the line kernel.
LINE_SAMPLES_PER_PX = 8


def image_velocity(rate_xy: tuple[float, float], fx: float, fy: float) -> tuple[float, float]:
    """Image velocity ``(a_u, a_v)`` [px/s] for a rate ``(w_x, w_y)`` [rad/s] (essay step 1)."""
    wx, wy = rate_xy
    return -fx * wy, fy * wx


def line_kernel(du: float, dv: float) -> Float32Array:
    """Unit-sum kernel of a uniform motion from ``(0, 0)`` to ``(du, dv)`` [px], odd, centred."""
    length = math.hypot(du, dv)
    n = max(int(math.ceil(length * LINE_SAMPLES_PER_PX)), 1)
    t = (np.arange(n) + 0.5) / n
    pu, pv = t * du, t * dv
    half = int(math.ceil(max(abs(du), abs(dv)))) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1))
    iu, iv = np.floor(pu).astype(int), np.floor(pv).astype(int)
    fu, fv = pu - iu, pv - iv
    for a, b, w in ((0, 0, (1 - fv) * (1 - fu)), (0, 1, (1 - fv) * fu),
                    (1, 0, fv * (1 - fu)), (1, 1, fv * fu)):
        np.add.at(k, (iv + a + half, iu + b + half), w)
    return (k / k.sum()).astype(np.float32)


def rolling_shutter(image: Float32Array, velocity_px_s: tuple[float, float],
                    exposure_time: float, row_time: float) -> Float32Array:
    """Motion blur and rolling-shutter skew (essay step 2).

    Parameters
    ----------
    image : (H, W) float32
        Mean charge an inertially fixed camera would collect [e-].
    velocity_px_s : (a_u, a_v)
        Image velocity [px/s] (:func:`image_velocity`).
    exposure_time : float
        Integration time of each row [s].
    row_time : float
        Delay between the starts of successive rows [s].

    Returns
    -------
    (H, W) float32
        Smeared image [e-].
    """
    au, av = velocity_px_s
    H, W = image.shape
    bb = signal_bbox(image)
    if bb is None or (au == 0.0 and av == 0.0):
        return image.copy()
    du, dv = au * exposure_time, av * exposure_time
    blurred = image
    if math.hypot(du, dv) >= MIN_BLUR_PX:
        blurred = np.zeros_like(image)
        r0, r1, c0, c1 = bb
        convolve_add(blurred, image[r0:r1, c0:c1], r0, c0, line_kernel(du, dv))
    su, sv = au * row_time, av * row_time  # shift per row [px/row]
    if max(abs(su), abs(sv)) * H < 1e-3:
        return blurred.astype(np.float32, copy=False)
    bb = signal_bbox(blurred)
    if bb is None:
        return blurred
    r0, r1, c0, c1 = bb
    m_v = abs(sv) * H + 2
    R0, R1 = max(int(r0 - m_v), 0), min(int(math.ceil(r1 + m_v)), H)
    out = np.zeros_like(image)
    out[R0:R1] = _skew_rows(blurred, np.arange(R0, R1), su, sv)
    return out


def _skew_rows(img: Float32Array, rows: NDArray[np.int64], su: float,
               sv: float) -> Float32Array:
    """``out[k, c] = img(c - su r_k, r_k - sv r_k)`` (bilinear, zero outside) for ``rows``.

    The shift depends on the output row only, so the 2-D bilinear resampling separates into a
    blend of two source rows and a per-row shift along the row.
    """
    H, W = img.shape
    pad = np.zeros((H + 2, W + 2), np.float32)
    pad[1:-1, 1:-1] = img
    src_r = rows - sv * rows + 1.0                    # padded row coordinate
    src_r = np.clip(src_r, 0.0, H + 1.0 - 1e-9)
    i0 = np.floor(src_r).astype(np.int64)
    g = (src_r - i0).astype(np.float32)[:, None]
    x = pad[i0] * (1.0 - g) + pad[np.minimum(i0 + 1, H + 1)] * g   # (n, W + 2)
    out = np.zeros((rows.size, W), np.float32)
    for k, r in enumerate(rows):
        off = -su * r                                  # out[c] = x(c + off), padded +1
        j = math.floor(off)
        f = np.float32(off - j)
        a0, a1 = max(0, -j - 1), min(W, W - j)         # keep source cols j+1+c .. in 0..W+1
        if a0 >= a1:
            continue
        src = x[k, a0 + j + 1 : a1 + j + 1]
        nxt = x[k, a0 + j + 2 : a1 + j + 2]
        if nxt.size < src.size:                        # last column has no right neighbour
            nxt = np.append(nxt, np.float32(0.0))
        out[k, a0:a1] = src * (1 - f) + nxt * f
    return out


def transfer_smear(image: Float32Array, exposure_time: float,
                   row_transfer_time: float) -> Float32Array:
    """Add frame-transfer smear (essay step 3).

    Parameters
    ----------
    image : (H, W) float32
        Mean photo-charge of the exposure [e-].
    exposure_time : float
        Integration time [s].
    row_transfer_time : float
        Time a packet spends under each row during the transfer [s].
    """
    col = image.sum(axis=0, dtype=np.float64) * (row_transfer_time / exposure_time)
    return image + col.astype(np.float32)[None, :]
