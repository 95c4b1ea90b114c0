"""Star centroids on a DN frame: detection, rejection of what is not a star, centroid and its noise.

Each step in full: docs/methods.md, "starnav.stars.centroid".

Technique
---------
1. Background: block medians and ``1.4826 MAD`` noise, zoomed back (:func:`background`).
2. Detection: a matched Gaussian filter, a threshold, 8-connected components.
3. Rejection: saturated, hot pixels, extended objects, exclusion discs of a bright body
   (:func:`body_exclusions`).
4. Centroid: iteratively weighted centre of mass (:func:`iwc`, :func:`iwc_many`), unbiased for
   a symmetric PSF.
5. Noise: the fixed point linearised, with shot and background variance.

The knobs are :class:`CentroidOptions`.

References
----------
B. M. Quine et al., "Determining star-image location: a new sub-pixel interpolation technique
to process image centroids", Comput. Phys. Commun. 177 (2007) 700-706 (IWC).
C. C. Liebe, "Accuracy performance of star trackers - a tutorial", IEEE Trans. Aerosp.
Electron. Syst. 38 (2002) 587.

Index
-----
:func:`find_stars`, :class:`Centroids`, :class:`CentroidOptions`, :class:`Exclusion`,
:func:`body_exclusions`, :func:`background`, :func:`iwc`, :func:`iwc_many`,
:func:`saturation_dn`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from starnav.errors import ConfigError
from starnav.typing import FloatArray

#: 1.4826 MAD is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class CentroidOptions:
    """Knobs of :func:`find_stars` (lengths in pixels).

    Attributes
    ----------
    block_px : int
        Background block: smaller follows the Moon's halo closer.
    smooth_sigma_px, threshold_sigma : float
        Detection matched filter; threshold in units of the smoothed noise.
    spike_ratio : float
        Hot-pixel test: the eight neighbours must hold at least this fraction of the peak.
    max_area_px, max_sigma_px : int, float
        Larger blobs, or a larger second-moment sigma: an extended body.
    weight_sigma_px, max_iterations : float, int
        IWC weight width (about the PSF's rms width); iterations at most.
    detect_bin : int
        2: background, detection and rejection on the 2 x 2 binned frame, the centroid and its
        noise at full resolution.
    axis_ratio : float
        With ``detect_bin`` 2, the hot-pixel test also asks for this fraction of the peak
        above the local level in the two neighbours along each axis (a PSF of sigma >= 0.4 px
        puts >= 0.25 there).
    """

    block_px: int = 32
    smooth_sigma_px: float = 1.0
    threshold_sigma: float = 5.0
    spike_ratio: float = 0.5
    max_area_px: int = 150
    max_sigma_px: float = 3.0
    weight_sigma_px: float = 1.5
    max_iterations: int = 20
    detect_bin: int = 1
    axis_ratio: float = 0.1

    def __post_init__(self) -> None:
        for name in ("smooth_sigma_px", "threshold_sigma", "spike_ratio", "max_sigma_px",
                     "weight_sigma_px"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"centroid.{name}", v, "a finite value > 0")
        if self.detect_bin not in (1, 2):
            raise ConfigError("centroid.detect_bin", self.detect_bin, "1 or 2")
        if self.block_px < 8 or self.max_area_px < 1 or self.max_iterations < 1:
            raise ConfigError("centroid", (self.block_px, self.max_area_px,
                                           self.max_iterations),
                              "block_px >= 8, max_area_px >= 1, max_iterations >= 1")


@dataclass(frozen=True)
class Exclusion:
    """A disc of the image where no star is accepted (a bright body or its ghost) [px]."""

    u: float
    v: float
    radius: float


@dataclass(frozen=True)
class Centroids:
    """Accepted star candidates, brightest first, and the rejected ones counted by reason.

    Attributes
    ----------
    uv : (n, 2) array
        Centroids ``(u, v)`` [px] (pixel centres at integers).
    sigma_px : (n, 2) array
        Predicted 1-sigma of ``u`` and ``v`` (module step 5) [px].
    flux_e : (n,) array
        Background-subtracted electrons in the ``4 s`` box [e-].
    peak_dn : (n,) array
        Brightest pixel [DN].
    rejected : dict
        ``{"saturated": n, "hot_pixel": n, "extended": n, "excluded": n, "edge": n,
        "diverged": n}``.
    background_sigma_e : float
        Median background noise of the frame [e-].
    """

    uv: FloatArray
    sigma_px: FloatArray
    flux_e: FloatArray
    peak_dn: FloatArray
    rejected: dict[str, int] = field(default_factory=dict)
    background_sigma_e: float = 0.0

    def __len__(self) -> int:
        return int(self.flux_e.size)

    def subset(self, keep: ArrayLike) -> Centroids:
        k = np.asarray(keep)
        return Centroids(self.uv[k], self.sigma_px[k], self.flux_e[k], self.peak_dn[k],
                         dict(self.rejected), self.background_sigma_e)


def background(dn: NDArray, block_px: int) -> tuple[FloatArray, FloatArray]:
    """Background level and noise maps [DN] of ``dn`` (module step 1)."""
    H, W = dn.shape
    nb_v, nb_u = max(1, H // block_px), max(1, W // block_px)
    bv, bu = H // nb_v, W // nb_u
    ft = np.float32 if np.asarray(dn).dtype == np.float32 else float  # single stays single
    core = np.asarray(dn[:nb_v * bv, :nb_u * bu], ft).reshape(nb_v, bv, nb_u, bu)
    blocks = core.transpose(0, 2, 1, 3).reshape(nb_v, nb_u, bv * bu)
    med = np.median(blocks, axis=2)
    mad = MAD_TO_SIGMA * np.median(np.abs(blocks - med[..., None]), axis=2)
    mad = np.maximum(mad, 0.5)  # quantisation floor: a 1 DN step has rms 0.29 DN

    def weights(n_px: int, size: int, n_b: int) -> tuple[NDArray[np.intp], NDArray[np.intp],
                                                         FloatArray]:
        x = np.clip((np.arange(n_px) + 0.5) / size - 0.5, 0, n_b - 1)
        i0 = np.floor(x).astype(np.intp)
        return i0, np.minimum(i0 + 1, n_b - 1), x - i0

    def zoom(m: FloatArray) -> FloatArray:
        if m.size == 1:
            return np.full((H, W), float(m.flat[0]))
        # block centres -> pixels, bilinear, held at the ends: separable (rows, then
        # columns), the same weights as ndimage.map_coordinates(order=1) at ~1/20 the cost
        v0, v1, fv = weights(H, bv, nb_v)
        u0, u1, fu = weights(W, bu, nb_u)
        rows = m[v0] * (1.0 - fv)[:, None] + m[v1] * fv[:, None]
        return rows[:, u0] * (1.0 - fu) + rows[:, u1] * fu

    return zoom(med), zoom(mad)


def body_exclusions(centre_px: ArrayLike, radius_px: float, camera_centre_px: ArrayLike,
                    ghosts: tuple = (), margin_px: float = 20.0,
                    margin_fraction: float = 0.15) -> tuple[Exclusion, ...]:
    """Exclusion discs of a bright body of apparent ``radius_px`` at ``centre_px`` and of its
    ghosts (each :class:`~starnav.detector.schema.GhostConfig`: image ``c + m (x - c) + o``
    about the principal point ``c``, radius ``|m| R + defocus``) [px]; every radius grows by
    ``margin_fraction`` and ``margin_px`` (the halo, the blooming columns' ends)."""
    x = np.asarray(centre_px, float)
    c = np.asarray(camera_centre_px, float)
    grow = 1.0 + margin_fraction
    out = [Exclusion(float(x[0]), float(x[1]), grow * radius_px + margin_px)]
    for g in ghosts:
        p = c + g.magnification * (x - c) + np.asarray(g.offset_px, float)
        r = abs(g.magnification) * radius_px + g.defocus_radius_px
        out.append(Exclusion(float(p[0]), float(p[1]), grow * r + margin_px))
    return tuple(out)


def _patch(img_e: FloatArray, u: float, v: float, s: float, h: int):
    """The (2h+1)^2 patch of ``img_e`` about the pixel nearest ``(u, v)``, its pixel
    coordinates' offsets from ``(u, v)`` and the Gaussian weights of width ``s``; None where
    the patch leaves the frame."""
    H, W = img_e.shape
    iu, iv = int(round(u)), int(round(v))
    r0, r1, c0, c1 = iv - h, iv + h + 1, iu - h, iu + h + 1
    if r0 < 0 or c0 < 0 or r1 > H or c1 > W:
        return None
    yy, xx = np.mgrid[r0:r1, c0:c1]
    dx, dy = xx - u, yy - v
    return img_e[r0:r1, c0:c1], dx, dy, np.exp(-0.5 * (dx * dx + dy * dy) / (s * s))


def iwc(img_e: FloatArray, u0: float, v0: float, s: float, var_b: float,
        max_iterations: int = 20) -> tuple[float, float, float, float, float, bool]:
    """Iteratively weighted centroid of the background-subtracted ``img_e`` [e-] from
    ``(u0, v0)`` [px] (module steps 4-5). Returns ``(u, v, sigma_u, sigma_v, flux, ok)``."""
    h = int(math.ceil(4.0 * s))
    u, v = float(u0), float(v0)
    for _ in range(max_iterations):
        patch = _patch(img_e, u, v, s, h)
        if patch is None:
            return u, v, math.inf, math.inf, 0.0, False
        I, dx, dy, w = patch
        wi = w * I
        sw = float(wi.sum())
        if sw <= 0:
            return u, v, math.inf, math.inf, 0.0, False
        du, dv = float((wi * dx).sum() / sw), float((wi * dy).sum() / sw)
        u, v = u + du, v + dv
        if math.hypot(du, dv) < 1e-4:
            break
    if abs(u - u0) > h or abs(v - v0) > h:
        return u, v, math.inf, math.inf, 0.0, False
    patch = _patch(img_e, u, v, s, h)
    if patch is None:
        return u, v, math.inf, math.inf, 0.0, False
    I, dx, dy, w = patch
    var = np.maximum(I, 0.0) + var_b
    Du = float((w * I * (1.0 - dx * dx / (s * s))).sum())
    Dv = float((w * I * (1.0 - dy * dy / (s * s))).sum())
    if Du <= 0 or Dv <= 0:
        return u, v, math.inf, math.inf, 0.0, False
    su = math.sqrt(float((w * w * dx * dx * var).sum())) / Du
    sv = math.sqrt(float((w * w * dy * dy * var).sum())) / Dv
    return u, v, su, sv, float(I.sum()), True


def iwc_many(img_e: FloatArray, u0: ArrayLike, v0: ArrayLike, s: float, var_b: ArrayLike,
             max_iterations: int = 20) -> tuple[FloatArray, ...]:
    """:func:`iwc` of many starting points at once (the same iteration, fixed point and
    noise, vectorised over the stars: one NumPy pass per iteration instead of one per star).
    Returns arrays ``(u, v, sigma_u, sigma_v, flux, ok)``; a failed star has ``ok`` False,
    flux 0 and infinite sigmas."""
    u0 = np.asarray(u0, float)
    v0 = np.asarray(v0, float)
    var_b = np.broadcast_to(np.asarray(var_b, float), u0.shape)
    n = u0.size
    h = int(math.ceil(4.0 * s))
    H, W = img_e.shape
    off = np.arange(-h, h + 1)
    u, v = u0.copy(), v0.copy()
    ok = np.ones(n, bool)
    active = np.ones(n, bool)

    def patch(idx: NDArray[np.intp]):
        iu, iv = np.rint(u[idx]).astype(np.intp), np.rint(v[idx]).astype(np.intp)
        inside = (iv - h >= 0) & (iu - h >= 0) & (iv + h + 1 <= H) & (iu + h + 1 <= W)
        ok[idx[~inside]] = False
        idx, iu, iv = idx[inside], iu[inside], iv[inside]
        rows, cols = iv[:, None] + off, iu[:, None] + off
        I = img_e[rows[:, :, None], cols[:, None, :]]
        dx1 = cols - u[idx][:, None]
        dy1 = rows - v[idx][:, None]
        # the Gaussian weight is separable: two 1-D factors instead of a 2-D exponential
        w = np.exp(-0.5 * (dy1 * dy1) / (s * s))[:, :, None] \
            * np.exp(-0.5 * (dx1 * dx1) / (s * s))[:, None, :]
        return idx, I, dx1[:, None, :], dy1[:, :, None], w

    for _ in range(max_iterations):
        idx = np.nonzero(active & ok)[0]
        if idx.size == 0:
            break
        idx, I, dx, dy, w = patch(idx)
        wi = w * I
        sw = wi.sum(axis=(1, 2))
        good = sw > 0
        ok[idx[~good]] = False
        idx, wi, dx, dy, sw = idx[good], wi[good], dx[good], dy[good], sw[good]
        du = (wi * dx).sum(axis=(1, 2)) / sw
        dv = (wi * dy).sum(axis=(1, 2)) / sw
        u[idx] += du
        v[idx] += dv
        active[idx[np.hypot(du, dv) < 1e-4]] = False
    ok &= (np.abs(u - u0) <= h) & (np.abs(v - v0) <= h)
    su = np.full(n, math.inf)
    sv = np.full(n, math.inf)
    flux = np.zeros(n)
    idx = np.nonzero(ok)[0]
    if idx.size:
        idx, I, dx, dy, w = patch(idx)
        var = np.maximum(I, 0.0) + var_b[idx][:, None, None]
        Du = (w * I * (1.0 - dx * dx / (s * s))).sum(axis=(1, 2))
        Dv = (w * I * (1.0 - dy * dy / (s * s))).sum(axis=(1, 2))
        good = (Du > 0) & (Dv > 0)
        ok[idx[~good]] = False
        g = idx[good]
        su[g] = np.sqrt((w * w * dx * dx * var).sum(axis=(1, 2)))[good] / Du[good]
        sv[g] = np.sqrt((w * w * dy * dy * var).sum(axis=(1, 2)))[good] / Dv[good]
        flux[g] = I.sum(axis=(1, 2))[good]
    return u, v, su, sv, flux, ok


def find_stars(dn: ArrayLike, *, gain_e_per_dn: float, saturation_dn: float,
               exclusions: tuple[Exclusion, ...] = (),
               options: CentroidOptions | None = None) -> Centroids:
    """Star centroids of a DN frame (module steps 1-5).

    Parameters
    ----------
    dn : (H, W) array
        The frame [DN].
    gain_e_per_dn : float
        Conversion gain [e-/DN].
    saturation_dn : float
        A blob with a pixel at or above this is saturated [DN] (the ADC's top code, or the
        offset plus the full well, whichever is lower).
    exclusions : tuple of Exclusion
        Discs where no star is accepted (:func:`body_exclusions`).
    options : CentroidOptions, optional

    Returns
    -------
    Centroids
        Brightest first. Never raises for frame content (a frame with no star gives an empty
        list).
    """
    opt = options or CentroidOptions()
    a = np.asarray(dn)
    if a.ndim != 2 or min(a.shape) < opt.block_px:
        raise ConfigError("centroid.dn", getattr(a, "shape", None),
                          f"a 2-D frame of at least {opt.block_px} px per side")
    if not (math.isfinite(gain_e_per_dn) and gain_e_per_dn > 0):
        raise ConfigError("centroid.gain_e_per_dn", gain_e_per_dn, "a finite gain > 0 e-/DN")
    if opt.detect_bin == 2:
        return _find_stars_binned(a, gain_e_per_dn, saturation_dn, exclusions, opt)
    frame = a.astype(float)
    bkg, noise = background(frame, opt.block_px)
    sub = frame - bkg
    smooth = ndimage.gaussian_filter(sub, opt.smooth_sigma_px, mode="nearest", truncate=3.0)
    smooth_noise = noise / (2.0 * math.sqrt(math.pi) * opt.smooth_sigma_px)
    mask = smooth > opt.threshold_sigma * smooth_noise
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    rej = {"saturated": 0, "hot_pixel": 0, "extended": 0, "excluded": 0, "edge": 0,
           "diverged": 0}
    sigma_b_e = float(np.median(noise)) * gain_e_per_dn
    if n == 0:
        return Centroids(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), rej,
                         sigma_b_e)
    img_e = sub * gain_e_per_dn
    H, W = frame.shape
    rows = []
    for lab, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        m = labels[sl] == lab
        area = int(m.sum())
        if area > opt.max_area_px:
            rej["extended"] += 1
            continue
        if float(frame[sl][m].max()) >= saturation_dn:
            rej["saturated"] += 1
            continue
        yy, xx = np.nonzero(m)
        yy, xx = yy + sl[0].start, xx + sl[1].start
        wts = np.maximum(sub[yy, xx], 0.0)
        k = int(np.argmax(sub[yy, xx]))
        pv, pu = int(yy[k]), int(xx[k])
        sw = float(wts.sum())
        if sw > 0 and area >= 3:
            # second moments: np.cov's weighted, unbiased form written out (without its
            # per-call overhead), the larger eigenvalue of the 2 x 2 in closed form
            du = xx - float((wts * xx).sum()) / sw
            dv = yy - float((wts * yy).sum()) / sw
            wp = wts + 1e-12
            s0 = float(wp.sum())
            du = du - float((wp * du).sum()) / s0
            dv = dv - float((wp * dv).sum()) / s0
            fact = s0 - float((wp * wp).sum()) / s0
            cuu, cvv = float((wp * du * du).sum()) / fact, float((wp * dv * dv).sum()) / fact
            cuv = float((wp * du * dv).sum()) / fact
            big = 0.5 * (cuu + cvv) + math.sqrt(0.25 * (cuu - cvv) ** 2 + cuv * cuv)
            if math.sqrt(max(big, 0.0)) > opt.max_sigma_px:
                rej["extended"] += 1
                continue
        if any(math.hypot(pu - x.u, pv - x.v) <= x.radius for x in exclusions):
            rej["excluded"] += 1
            continue
        if pv < 1 or pu < 1 or pv >= H - 1 or pu >= W - 1:
            rej["edge"] += 1
            continue
        peak = float(sub[pv, pu])
        neigh = float(sub[pv - 1:pv + 2, pu - 1:pu + 2].sum()) - peak
        if neigh < opt.spike_ratio * peak:
            rej["hot_pixel"] += 1
            continue
        rows.append((pu, pv, float(noise[pv, pu] * gain_e_per_dn) ** 2, float(frame[pv, pu])))
    if not rows:
        return Centroids(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), rej,
                         sigma_b_e)
    pu_, pv_, var_b, peak_dn = (np.array(c) for c in zip(*rows, strict=True))
    u, v, su, sv, flux, ok = iwc_many(img_e, pu_, pv_, opt.weight_sigma_px, var_b,
                                      opt.max_iterations)
    rej["edge"] += int(np.count_nonzero(~ok))  # as iwc's failures (flux 0, infinite sigma)
    t = np.stack([u, v, su, sv, flux, peak_dn], axis=1)[ok]
    if t.shape[0] == 0:
        return Centroids(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), rej,
                         sigma_b_e)
    order = np.argsort(-t[:, 4], kind="stable")
    t = t[order]
    return Centroids(t[:, 0:2].copy(), t[:, 2:4].copy(), t[:, 4].copy(), t[:, 5].copy(), rej,
                     sigma_b_e)


def _find_stars_binned(a: NDArray, gain: float, sat: float, exclusions: tuple[Exclusion, ...],
                       opt: CentroidOptions) -> Centroids:
    """:func:`find_stars` with steps 1-3 on the 2 x 2 binned frame (``detect_bin`` 2): the
    background, the smoothing (half the width, in binned pixels), the threshold and the
    labelling on a quarter of the pixels, the per-candidate tests vectorised over the labels
    (:func:`scipy.ndimage` label statistics); each candidate's peak pixel and the rejection
    tests at full resolution (saturation on every full-resolution pixel of the blob through the
    2 x 2 maxima), the centroid (step 4) and its noise (step 5) on the full-resolution frame."""
    H, W = a.shape
    H2, W2 = H // 2, W // 2
    full = np.asarray(a[:2 * H2, :2 * W2], np.float32)
    quads = (full[0::2, 0::2], full[0::2, 1::2], full[1::2, 0::2], full[1::2, 1::2])
    binned = 0.25 * (quads[0] + quads[1] + quads[2] + quads[3])
    bkg_b, noise_b = background(binned, max(opt.block_px // 2, 4))
    sub_b = (binned - bkg_b).astype(np.float32)
    s_b = 0.5 * opt.smooth_sigma_px
    smooth = ndimage.gaussian_filter(sub_b, s_b, mode="nearest", truncate=3.0)
    x = np.arange(-math.ceil(3.0 * s_b), math.ceil(3.0 * s_b) + 1)
    k = np.exp(-0.5 * (x / s_b) ** 2)
    k /= k.sum()
    # noise of the mean of 4 pixels is half a pixel's; the smoothed noise exactly (sum k^2)
    mask = smooth > opt.threshold_sigma * noise_b * float((k * k).sum())
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    rej = {"saturated": 0, "hot_pixel": 0, "extended": 0, "excluded": 0, "edge": 0,
           "diverged": 0}
    sigma_b_e = 2.0 * float(np.median(noise_b)) * gain  # one full-resolution pixel's
    empty = Centroids(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), rej,
                      sigma_b_e)
    if n == 0:
        return empty
    lab = labels.ravel()
    on = lab > 0
    lab_on = lab[on]
    area = np.bincount(lab_on, minlength=n + 1)[1:] * 4  # full-resolution pixels
    cmax = np.maximum(np.maximum(quads[0], quads[1]), np.maximum(quads[2], quads[3]))
    cmax = cmax.ravel()[on]
    top = np.full(n + 1, -np.inf)
    np.maximum.at(top, lab_on, cmax)
    w = np.maximum(sub_b.ravel()[on], 0.0).astype(float)
    yy, xx = np.divmod(np.nonzero(on)[0], W2)
    yy, xx = yy.astype(float), xx.astype(float)
    sw = np.bincount(lab_on, w, n + 1)[1:]
    sw_safe = np.maximum(sw, 1e-30)
    mu = np.bincount(lab_on, w * xx, n + 1)[1:] / sw_safe
    mv = np.bincount(lab_on, w * yy, n + 1)[1:] / sw_safe
    cuu = np.bincount(lab_on, w * xx * xx, n + 1)[1:] / sw_safe - mu * mu
    cvv = np.bincount(lab_on, w * yy * yy, n + 1)[1:] / sw_safe - mv * mv
    cuv = np.bincount(lab_on, w * xx * yy, n + 1)[1:] / sw_safe - mu * mv
    big = 0.5 * (cuu + cvv) + np.sqrt(0.25 * (cuu - cvv) ** 2 + cuv * cuv)
    # second moments of 2 px cells: times 4 for pixels, less the cell's own 1/12 -> 4/12
    sig_full = np.sqrt(np.maximum(4.0 * big, 0.0))
    extended = (area > opt.max_area_px) | ((area >= 12) & (sig_full > opt.max_sigma_px))
    saturated = ~extended & (top[1:] >= sat)
    # the peak: the binned cell of largest background-subtracted signal, then its brightest pixel
    on_idx = np.nonzero(on)[0]
    order = np.argsort(sub_b.ravel()[on_idx], kind="stable")
    peak_flat = np.empty(n + 1, np.intp)
    peak_flat[lab_on[order]] = on_idx[order]  # the last, largest, of each label wins
    pvb, pub = np.divmod(peak_flat[1:], W2)
    quad = np.stack([qd[pvb, pub] for qd in quads], axis=1)
    q = np.argmax(quad, axis=1)
    pv, pu = 2 * pvb + q // 2, 2 * pub + q % 2
    excluded = np.zeros(n, bool)
    for e in exclusions:
        excluded |= np.hypot(pu - e.u, pv - e.v) <= e.radius
    excluded &= ~extended & ~saturated
    edge = ~extended & ~saturated & ~excluded & ((pv < 1) | (pu < 1) | (pv >= H - 1)
                                                 | (pu >= W - 1))
    # full-resolution background: the binned map, each value over its 2 x 2 pixels
    img = np.asarray(a, np.float32)  # a copy when ``a`` is integer
    if img is a:
        img = img.copy()
    bkg32 = bkg_b.astype(np.float32)
    for dv in (0, 1):
        for du in (0, 1):
            img[dv:2 * H2:2, du:2 * W2:2] -= bkg32
    if H > 2 * H2:
        img[-1, :2 * W2:2] -= bkg32[-1]
        img[-1, 1:2 * W2:2] -= bkg32[-1]
    if W > 2 * W2:
        img[:, -1] -= np.repeat(bkg32[:, -1], 2)[:H] if H == 2 * H2 else \
            np.append(np.repeat(bkg32[:, -1], 2), bkg32[-1, -1])
    good = ~(extended | saturated | excluded | edge)
    gv, gu = np.clip(pv, 2, H - 3), np.clip(pu, 2, W - 3)
    off = np.arange(-2, 3)
    box = img[gv[:, None, None] + off[:, None], gu[:, None, None] + off[None, :]]
    # the local level: the median of the 5 x 5 box's border (the block background's bias
    # under a hot pixel, a ramp); then the star tests on the 3 x 3 core above it
    ring = np.concatenate([box[:, 0, :], box[:, -1, :], box[:, 1:-1, 0], box[:, 1:-1, -1]],
                          axis=1)
    core = box[:, 1:4, 1:4] - np.median(ring, axis=1)[:, None, None]
    peak = core[:, 1, 1]
    # a star spreads light into the neighbours along both axes; a hot pixel, a cosmic ray
    # or a hot pair along a column does not
    lr = core[:, 1, 0] + core[:, 1, 2]
    ud = core[:, 0, 1] + core[:, 2, 1]
    hot = good & ((core.sum(axis=(1, 2)) - peak < opt.spike_ratio * peak)
                  | (np.minimum(lr, ud) < opt.axis_ratio * peak))
    rej["extended"] += int(extended.sum())
    rej["saturated"] += int(saturated.sum())
    rej["excluded"] += int(excluded.sum())
    rej["edge"] += int(edge.sum())
    rej["hot_pixel"] += int(hot.sum())
    keep = np.nonzero(good & ~hot)[0]
    if keep.size == 0:
        return empty
    pu_, pv_ = pu[keep], pv[keep]
    noise = 2.0 * noise_b[np.minimum(pv_ // 2, H2 - 1), np.minimum(pu_ // 2, W2 - 1)]
    var_b = (noise * gain) ** 2
    peak_dn = np.asarray(a)[pv_, pu_].astype(float)
    u, v, su, sv, flux, ok = iwc_many(img * gain if gain != 1.0 else img, pu_, pv_,
                                      opt.weight_sigma_px, var_b, opt.max_iterations)
    rej["edge"] += int(np.count_nonzero(~ok))
    t = np.stack([u, v, su, sv, flux, peak_dn], axis=1)[ok]
    if t.shape[0] == 0:
        return empty
    t = t[np.argsort(-t[:, 4], kind="stable")]
    return Centroids(t[:, 0:2].copy(), t[:, 2:4].copy(), t[:, 4].copy(), t[:, 5].copy(), rej,
                     sigma_b_e)


def saturation_dn(detector) -> float:  # detector: starnav.detector.DetectorConfig
    """The DN at which a pixel is saturated: the ADC top code, or offset + full well / gain."""
    top = 2 ** detector.adc.bits - 1
    full = detector.adc.offset_dn + detector.saturation.full_well_e / detector.gain_e_per_dn
    return float(min(top, full)) - 1.0
