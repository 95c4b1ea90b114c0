"""Photon collection: radiometry, field-varying aberration PSF, distortion, stray light, ghosts.

Each step in full (accuracy of the resampling, the halo's coarse grid): docs/methods.md,
"starnav.detector.optics".

Technique
---------
1. Radiometry: ``N = t_exp A_pupil Omega_pix Le``, optionally times ``cos^4`` off axis.
2. Aberration and defocus PSF: a pillbox convolved with an elliptical Gaussian, growing with
   the field radius, computed at grid nodes and blended bilinearly on the source side (each
   source pixel's PSF sums to one).
3. Distortion: the pinhole image sampled through the inverse Brown-Conrady map, times the
   pixel-area ratio.
4. Stray light: a Harvey halo carrying the total integrated scatter; its flat part convolved on
   a coarse grid.
5. Ghosts: mapped, blurred and weighted copies of the image, on the halo's coarse grid.

References
----------
Harvey, J. E. (1976), *Light-scattering characteristics of optical surfaces*, PhD thesis, Univ.
Arizona. Brown, D. C. (1966), *Decentering distortion of lenses*, Photogramm. Eng. 32(3).
Conrady, A. E. (1919), MNRAS 79, 384.

Index
-----
:func:`photoelectrons`, :func:`relative_illumination_map`; :func:`psf_grid`, :class:`PsfGrid`,
:func:`apply_psf_grid`, :func:`aberration_kernel`, :func:`line_spread_function`;
:class:`PointSources`, :func:`point_source_image`, :func:`point_source_kernel`;
:func:`distort`, :func:`distortion_map`, :class:`DistortionMap`; :func:`stray_light`,
:func:`halo_kernels`, :func:`ghost_images`, :func:`block_sum`, :func:`block_expand`,
:func:`disc_kernel`, :func:`disc_coverage`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.camera import Camera
from starnav.detector.fftconv import convolve_add, signal_bbox
from starnav.detector.schema import AberrationPsfConfig, GhostConfig, StrayLightConfig
from starnav.errors import ConfigError
from starnav.typing import Float32Array

logger = logging.getLogger(__name__)


#: Gaussian truncation of the aberration kernels [sigma].
GAUSS_TRUNCATE_SIGMA = 4.0
#: Super-samples per axis used to integrate the halo and disc kernels over a pixel.
KERNEL_SUPERSAMPLE = 4


# =========================================================================== radiometry
@lru_cache(maxsize=8)
def relative_illumination_map(camera: Camera) -> Float32Array:
    """cos^4 natural vignetting of every pixel, ``(height, width)`` float32 [-] (cached)."""
    u, v = camera.pixel_grid()
    ri = camera.relative_illumination(u, v).astype(np.float32)
    ri.flags.writeable = False
    return ri


def photoelectrons(le: NDArray[np.floating], exposure_time: float, etendue: float,
                   relative_illumination: NDArray[np.floating] | None = None) -> Float32Array:
    """Mean photo-electrons per pixel ``N = t A Omega Le [x RI]``.

    Parameters
    ----------
    le : (H, W) array
        Electron radiance [e- s^-1 m^-2 sr^-1].
    exposure_time : float
        Integration time [s].
    etendue : float
        On-axis pixel etendue ``A_pupil * Omega_pix`` [m^2 sr].
    relative_illumination : (H, W) array, optional
        Extra factor per pixel, e.g. ``cos^4(theta)`` [-].

    Returns
    -------
    (H, W) float32
        Mean photo-electrons [e-].
    """
    out = np.multiply(le, np.float32(exposure_time * etendue), dtype=np.float32)
    if relative_illumination is not None:
        out *= relative_illumination
    return out


# =========================================================================== aberration PSF
def disc_coverage(radius: float, x: NDArray[np.float64], y: NDArray[np.float64],
                  step: float) -> NDArray[np.float64]:
    """Fraction of a sample of side ``step`` centred at ``(x, y)`` inside a disc (linear edge)."""
    r = np.hypot(x, y)
    return np.clip((radius - r) / step + 0.5, 0.0, 1.0)


def _psf_samples(defocus_radius: float, smax: float, oversample: int
                 ) -> tuple[int, int, int, float, NDArray[np.float64], NDArray[np.float64]]:
    """The sample grid of a PSF: ``(half, s, n, step, x, y)``, ``2 half + 1`` pixels a side
    (the disc and :data:`GAUSS_TRUNCATE_SIGMA` of the widest Gaussian), ``s`` samples per pixel
    and axis, ``n`` a side, sample centres ``x`` along u (columns), ``y`` along v (rows) [px]."""
    half = int(math.ceil(defocus_radius + GAUSS_TRUNCATE_SIGMA * smax + 1.0))
    s = int(oversample)
    n = (2 * half + 1) * s
    step = 1.0 / s
    t = (np.arange(n) + 0.5) * step - (half + 0.5)
    x, y = np.meshgrid(t, t)
    return half, s, n, step, x, y


@lru_cache(maxsize=512)
def aberration_kernel(defocus_radius: float, sigma_radial: float, sigma_tangential: float,
                      angle: float, oversample: int) -> Float32Array:
    """Pixel-integrated PSF: disc of ``defocus_radius`` [px] convolved with a Gaussian of
    ``sigma_radial`` along direction ``angle`` [rad, from +u towards +v] and
    ``sigma_tangential`` across it [px]. Odd square, centred, unit sum, float32."""
    from scipy.signal import fftconvolve

    smax = max(sigma_radial, sigma_tangential)
    half, s, n, step, x, y = _psf_samples(defocus_radius, smax, oversample)
    if defocus_radius > 0:
        disc = disc_coverage(defocus_radius, x, y, step)
        if disc.sum() == 0:  # radius far below a sample: a point
            disc = np.zeros_like(x)
            disc[n // 2, n // 2] = 1.0
    else:
        disc = np.zeros_like(x)
        disc[n // 2, n // 2] = 1.0
    if smax > 0:
        ca, sa = math.cos(angle), math.sin(angle)
        xr = ca * x + sa * y
        xt = -sa * x + ca * y
        sr = max(sigma_radial, 0.25 * step)
        st = max(sigma_tangential, 0.25 * step)
        gauss = np.exp(-0.5 * ((xr / sr) ** 2 + (xt / st) ** 2))
        fine = fftconvolve(disc, gauss, mode="same")
    else:
        fine = disc
    fine = np.clip(fine, 0.0, None)
    k = fine.reshape(2 * half + 1, s, 2 * half + 1, s).sum(axis=(1, 3))
    k = (k / k.sum()).astype(np.float32)
    k.flags.writeable = False
    return k


@dataclass(frozen=True)
class PsfGrid:
    """PSFs at the nodes of a regular grid over the detector.

    Attributes
    ----------
    u_nodes, v_nodes : tuple of float
        Node columns and rows [px].
    kernels : tuple of tuple of (k, k) float32
        ``kernels[j][i]`` is the PSF at ``(u_nodes[i], v_nodes[j])``.
    keys : tuple of tuple
        Cache keys of the kernels.
    """

    u_nodes: tuple[float, ...]
    v_nodes: tuple[float, ...]
    kernels: tuple[tuple[Float32Array, ...], ...]
    keys: tuple[tuple[tuple[float, ...], ...], ...]


def _grow(p0: float, p1: float, rho: float) -> float:
    return p0 + (p1 - p0) * rho * rho


def _node_parameters(camera: Camera, cfg: AberrationPsfConfig
                     ) -> tuple[tuple[float, ...], tuple[float, ...],
                                list[list[tuple[float, float, float, float]]]]:
    """Node columns, rows and, per node, ``(defocus radius, sigma radial, sigma tangential,
    radial angle)`` [px, px, px, rad] of the field law ``p0 + (p1 - p0) rho^2``."""
    nu, nv = cfg.grid_nodes
    w, h = camera.width, camera.height
    cx, cy = float(camera.cx), float(camera.cy)
    u_nodes = tuple(float(x) for x in np.linspace(0.0, w - 1.0, nu)) if nu > 1 else (cx,)
    v_nodes = tuple(float(x) for x in np.linspace(0.0, h - 1.0, nv)) if nv > 1 else (cy,)
    r_corner = max(math.hypot(u - cx, v - cy) for u in (-0.5, w - 0.5) for v in (-0.5, h - 0.5))
    rows = []
    for v in v_nodes:
        row = []
        for u in u_nodes:
            rho = min(math.hypot(u - cx, v - cy) / r_corner, 1.0)
            ang = math.atan2(v - cy, u - cx) if rho > 0 else 0.0
            row.append((round(_grow(cfg.defocus_radius_px, cfg.defocus_radius_edge_px, rho), 6),
                        round(_grow(cfg.sigma_px, cfg.sigma_radial_edge_px, rho), 6),
                        round(_grow(cfg.sigma_px, cfg.sigma_tangential_edge_px, rho), 6),
                        round(ang, 6)))
        rows.append(row)
    return u_nodes, v_nodes, rows


@lru_cache(maxsize=16)
def psf_grid(camera: Camera, cfg: AberrationPsfConfig) -> PsfGrid:
    """The PSF grid of ``camera`` described by ``cfg`` (cached per camera and config)."""
    u_nodes, v_nodes, params = _node_parameters(camera, cfg)
    rows_k, rows_key = [], []
    for prow in params:
        ks, keys = [], []
        for p in prow:
            par = (*p, cfg.oversample)
            ks.append(aberration_kernel(*par))
            keys.append(("aberration",) + par)
        rows_k.append(tuple(ks))
        rows_key.append(tuple(keys))
    return PsfGrid(u_nodes, v_nodes, tuple(rows_k), tuple(rows_key))


def _semicircle(x: NDArray[np.float64], radius: float, step: float) -> NDArray[np.float64]:
    """Projection of a uniform disc of ``radius`` on a line, ``2 sqrt(R^2 - x^2) / (pi R^2)``,
    averaged over samples of width ``step`` (exact: the primitive of the density)."""
    if radius < 0.5 * step:
        out = np.zeros_like(x)
        out[np.argmin(np.abs(x))] = 1.0 / step
        return out

    def prim(t: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.clip(t / radius, -1.0, 1.0)
        return (t * np.sqrt(1.0 - t * t) + np.arcsin(t)) / math.pi

    return (prim(x + 0.5 * step) - prim(x - 0.5 * step)) / step


def _box_convolve(f: NDArray[np.float64], width: float, step: float) -> NDArray[np.float64]:
    """``f`` convolved with a unit-area box of ``width`` (linear interpolation of the running
    integral, so any width, not only whole samples)."""
    if width < 1e-6:
        return f
    x = np.arange(f.size) * step
    F = np.concatenate([[0.0], np.cumsum(f) * step])          # integral up to sample edges
    xe = (np.arange(f.size + 1) - 0.5) * step
    hi = np.interp(x + 0.5 * width, xe, F)
    lo = np.interp(x - 0.5 * width, xe, F)
    return (hi - lo) / width


def line_spread_function(camera: Camera, cfg: AberrationPsfConfig, u: float, v: float,
                         normal: NDArray[np.float64], x: NDArray[np.float64], *,
                         pixel_boxes: int = 2, ipc: tuple[float, float] = (0.0, 0.0)
                         ) -> NDArray[np.float64]:
    """The line spread function [1/px] at pixel ``(u, v)`` across the direction ``normal``:
    :func:`apply_psf_grid`'s blur seen along one direction.

    The tent blend of the four nearest node PSFs (each a defocus disc, projecting to the
    semicircle law ``2 sqrt(R^2 - x^2) / (pi R^2)``, convolved with the elliptical Gaussian,
    projecting to variance ``sigma_r^2 cos^2 a + sigma_t^2 sin^2 a``, ``a`` the angle to the
    radial direction); ``pixel_boxes`` pixel apertures (boxes of widths ``|n_u|`` and
    ``|n_v|``; 2 by default: the renderer's pixel filter and the pixel-integrated kernels);
    and the inter-pixel capacitance ``ipc = (nearest, diagonal)`` as shifted copies.

    Parameters
    ----------
    camera : Camera
    cfg : AberrationPsfConfig
    u, v : float
        Pixel position [px].
    normal : (2,) array
        Direction across the edge (normalised here).
    x : (N,) array
        Uniformly spaced abscissae [px], symmetric about 0.

    Returns
    -------
    (N,) array
        The line spread function at ``x`` [1/px], unit area.
    """
    x = np.asarray(x, float)
    step = float(x[1] - x[0])
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    out = np.zeros_like(x)
    if cfg.enabled:
        u_nodes, v_nodes, params = _node_parameters(camera, cfg)
        uu, vv = np.array([float(u)]), np.array([float(v)])
        for j in range(len(v_nodes)):
            wv = float(_tent(vv, v_nodes, j)[0])
            if wv <= 0:
                continue
            for i in range(len(u_nodes)):
                wu = float(_tent(uu, u_nodes, i)[0])
                if wu <= 0:
                    continue
                R, sr, st, ang = params[j][i]
                c = n[0] * math.cos(ang) + n[1] * math.sin(ang)
                sn = math.sqrt(sr * sr * c * c + st * st * (1.0 - c * c))
                k = _semicircle(x, R, step)
                if sn > 0.25 * step:
                    g = np.exp(-0.5 * (x / sn) ** 2)
                    k = np.convolve(k, g / g.sum(), mode="same")
                out += wu * wv * k
    else:
        out[np.argmin(np.abs(x))] = 1.0 / step
    for _ in range(int(pixel_boxes)):
        for w in (abs(n[0]), abs(n[1])):
            out = _box_convolve(out, w, step)
    near, diag = ipc
    if near > 0 or diag > 0:
        shifted = np.zeros_like(out)
        for sgn in (-1.0, 1.0):
            for d, wgt in ((n[0], near), (n[1], near), (n[0] + n[1], diag),
                           (n[0] - n[1], diag)):
                shifted += wgt * np.interp(x - sgn * d, x, out, left=0.0, right=0.0)
        out = (1.0 - 4.0 * near - 4.0 * diag) * out + shifted
    return out / (out.sum() * step)


def _tent(coord: NDArray[np.float64], nodes: tuple[float, ...], k: int) -> NDArray[np.float64]:
    """Tent weight of node ``k`` at ``coord`` (sums to 1 over the nodes inside the span)."""
    if len(nodes) == 1:
        return np.ones_like(coord)
    d = nodes[1] - nodes[0]
    wgt = np.clip(1.0 - np.abs(coord - nodes[k]) / d, 0.0, 1.0)
    # outside the node span (only possible for half-pixel borders) the end nodes take all
    if k == 0:
        wgt[coord < nodes[0]] = 1.0
    if k == len(nodes) - 1:
        wgt[coord > nodes[-1]] = 1.0
    return wgt


def _support(nodes: tuple[float, ...], k: int, n: int) -> tuple[int, int]:
    """Half-open pixel range where node ``k``'s tent is non-zero."""
    if len(nodes) == 1:
        return 0, n
    lo = 0 if k == 0 else int(math.floor(nodes[k - 1])) + 1
    hi = n if k == len(nodes) - 1 else int(math.ceil(nodes[k + 1]))
    return lo, hi


def apply_psf_grid(image: Float32Array, grid: PsfGrid) -> tuple[Float32Array, float]:
    """Convolve ``image`` with the field-varying PSF of ``grid`` (source-side blending).

    Parameters
    ----------
    image : (H, W) float32
        Mean charge or flux per pixel (any additive unit).
    grid : PsfGrid
        Node PSFs (:func:`psf_grid`).

    Returns
    -------
    out : (H, W) float32
        Blurred image, same unit.
    lost : float
        Flux spread outside the array (same unit).
    """
    H, W = image.shape
    out = np.zeros((H, W), np.float32)
    bb = signal_bbox(image)
    if bb is None:
        return out, 0.0
    r0, r1, c0, c1 = bb
    lost = 0.0
    for j in range(len(grid.v_nodes)):
        a0, a1 = _support(grid.v_nodes, j, H)
        a0, a1 = max(a0, r0), min(a1, r1)
        if a0 >= a1:
            continue
        wv = _tent(np.arange(a0, a1, dtype=np.float64), grid.v_nodes, j).astype(np.float32)
        for i in range(len(grid.u_nodes)):
            b0, b1 = _support(grid.u_nodes, i, W)
            b0, b1 = max(b0, c0), min(b1, c1)
            if b0 >= b1:
                continue
            wu = _tent(np.arange(b0, b1, dtype=np.float64), grid.u_nodes, i).astype(np.float32)
            src = image[a0:a1, b0:b1] * wv[:, None] * wu[None, :]
            if not src.any():
                continue
            lost += convolve_add(out, src, a0, b0, grid.kernels[j][i], grid.keys[j][i])
    return out, lost


# =========================================================================== point sources
@dataclass(frozen=True)
class PointSources:
    """Unresolved sources (stars) for :func:`starnav.detector.expose`.

    Attributes
    ----------
    u, v : (n,) arrays
        Position in the *undistorted pinhole* image [px] (pixel centres at integers), where
        the renderer would have drawn them; the chain's distortion moves them afterwards.
    rate : (n,) array
        Photo-electrons per second collected through the on-axis pupil [e-/s]
        (irradiance x pupil area through the sensor response); off axis the chain multiplies by
        the pupil's foreshortening ``cos(theta)`` when ``relative_illumination`` is on.
    """

    u: NDArray[np.float64]
    v: NDArray[np.float64]
    rate: NDArray[np.float64]

    def __post_init__(self) -> None:
        arrs = [np.atleast_1d(np.asarray(getattr(self, k), float)) for k in ("u", "v", "rate")]
        if len({a.shape for a in arrs}) != 1 or arrs[0].ndim != 1:
            raise ConfigError("point_sources", [a.shape for a in arrs],
                              "1-D u, v and rate arrays of equal length")
        if not all(np.all(np.isfinite(a)) for a in arrs) or np.any(arrs[2] < 0):
            raise ConfigError("point_sources", "non-finite position or negative rate",
                              "finite positions [px] and rates >= 0 e-/s")
        for k, a in zip(("u", "v", "rate"), arrs, strict=True):
            object.__setattr__(self, k, a)

    def __len__(self) -> int:
        return int(self.u.size)


def _sampled_psf(x: NDArray[np.float64], y: NDArray[np.float64], step: float,
                 defocus_radius: float, sigma_radial: float, sigma_tangential: float,
                 angle: float) -> NDArray[np.float64] | None:
    """The point-source PSF (defocus disc convolved with the rotated aberration Gaussian)
    sampled at the sample centres ``(x, y)`` [px] of pitch ``step``, unnormalised; ``None``
    when there is no optics (no disc, no Gaussian)."""
    smax = max(sigma_radial, sigma_tangential)
    ca, sa = math.cos(angle), math.sin(angle)
    sr = max(sigma_radial, 0.25 * step)
    st = max(sigma_tangential, 0.25 * step)

    def gauss(gx: NDArray[np.float64], gy: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.exp(-0.5 * (((ca * gx + sa * gy) / sr) ** 2 + ((-sa * gx + ca * gy) / st) ** 2))

    disc = disc_coverage(defocus_radius, x, y, step) if defocus_radius > 0 else None
    if disc is not None and disc.sum() == 0:
        disc = None
    if smax <= 0 and disc is None:
        return None
    if disc is None:
        return gauss(x, y)
    if smax <= 0:
        return disc
    from scipy.signal import fftconvolve

    m = int(math.ceil(GAUSS_TRUNCATE_SIGMA * smax / step))
    g = np.arange(-m, m + 1) * step
    gx, gy = np.meshgrid(g, g)
    return fftconvolve(disc, gauss(gx, gy), mode="same")  # odd kernel: exactly centred


@lru_cache(maxsize=256)
def _point_source_integral(defocus_radius: float, sigma_radial: float, sigma_tangential: float,
                           angle: float, oversample: int) -> tuple[NDArray[np.float64], int]:
    """The centred PSF of :func:`point_source_kernel` sampled ``oversample`` times per pixel
    and axis (unit sum) and its integral image ``C[i, j] = sum(f[:i, :j])`` on the sample edges,
    ``(n + 1, n + 1)``; returns ``(C, half)`` with the samples spanning ``[-half - 0.5,
    half + 0.5]`` px. Cached per node: the per-star work is a shifted read of ``C``."""
    smax = max(sigma_radial, sigma_tangential)
    half, s, n, step, x, y = _psf_samples(defocus_radius, smax, oversample)
    fine = _sampled_psf(x, y, step, defocus_radius, sigma_radial, sigma_tangential, angle)
    if fine is None:  # no optics: a point at the centre
        fine = np.zeros((n, n))
        fine[n // 2, n // 2] = 1.0
    fine = np.clip(fine, 0.0, None)
    fine /= fine.sum()
    C = np.zeros((n + 1, n + 1))
    C[1:, 1:] = np.cumsum(np.cumsum(fine, axis=0), axis=1)
    C.flags.writeable = False
    return C, half


def _shifted_kernels(C: NDArray[np.float64], half: int, s: int, du: NDArray[np.float64],
                     dv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixel-integrated kernels ``(m, 2H + 1, 2H + 1)``, ``H = half + 1``, of the PSF whose
    integral image is ``C`` shifted by ``(du[i], dv[i])`` [px]: bilinear reads of ``C`` at the
    shifted pixel edges (indices clamped to ``[0, n]``: ``C`` is 0 before the first edge and
    constant after the last), then the 2-D difference."""
    n = C.shape[0] - 1
    q = np.arange(-(half + 1), half + 3) * s

    def edges(shift: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp],
                                                   NDArray[np.float64]]:
        k0 = (half - shift) * s
        a = np.floor(k0)
        i0 = q[None, :] + a.astype(np.intp)[:, None]
        return np.clip(i0, 0, n), np.clip(i0 + 1, 0, n), (k0 - a)[:, None, None]

    c0, c1, fu = edges(np.asarray(du, float))
    r0, r1, fv = edges(np.asarray(dv, float))
    r0, r1 = r0[:, :, None], r1[:, :, None]
    c0, c1 = c0[:, None, :], c1[:, None, :]
    E = ((1.0 - fv) * ((1.0 - fu) * C[r0, c0] + fu * C[r0, c1])
         + fv * ((1.0 - fu) * C[r1, c0] + fu * C[r1, c1]))
    return np.diff(np.diff(E, axis=1), axis=2)


def point_source_kernel(defocus_radius: float, sigma_radial: float, sigma_tangential: float,
                        angle: float, oversample: int, du: float, dv: float) -> Float32Array:
    """The PSF of :func:`aberration_kernel` for a point source at ``(du, dv)`` [px] from the
    centre of the kernel's middle pixel (``|du|, |dv| <= 0.5``), integrated over each pixel:
    odd square, unit sum (float64).

    A rendered (extended) image is already averaged over each pixel by the renderer; a point
    source is not, so its pixel values are the PSF integrated over the pixels at its sub-pixel
    position, not the pixel-integrated kernel convolved once more with a pixel. The PSF is
    sampled ``oversample`` times per pixel and axis around its centre once per node
    (:func:`_point_source_integral`, cached) and read as a piecewise-constant density: the
    integral image ``C`` of such a density is exactly bilinear inside each sample cell, so
    bilinear interpolation of ``C`` at the shifted pixel edges integrates the shifted PSF over
    each pixel exactly (no re-sampling, no FFT per star; the sum is exactly 1, and the
    density's first moment moves by exactly ``(du, dv)``)."""
    C, half = _point_source_integral(float(defocus_radius), float(sigma_radial),
                                     float(sigma_tangential), float(angle), int(oversample))
    return _shifted_kernels(C, half, int(oversample), np.array([float(du)]),
                            np.array([float(dv)]))[0]


def point_source_kernel_sampled(defocus_radius: float, sigma_radial: float,
                                sigma_tangential: float, angle: float, oversample: int,
                                du: float, dv: float) -> Float32Array:
    """Slow reference of :func:`point_source_kernel` (the part-A method, kept for tests and
    ``benchmarks/stars.py``): the PSF sampled at the shifted sample centres (``oversample``
    per pixel and axis, the disc convolved with the Gaussian by FFT for every call) and summed
    per pixel: odd square, unit sum. ~7 ms per call on the AA-STR PSF."""
    smax = max(sigma_radial, sigma_tangential)
    half = int(math.ceil(defocus_radius + GAUSS_TRUNCATE_SIGMA * smax + 1.5))
    s = int(oversample)
    n = (2 * half + 1) * s
    step = 1.0 / s
    t = (np.arange(n) + 0.5) * step - (half + 0.5)
    x, y = np.meshgrid(t - du, t - dv)
    fine = _sampled_psf(x, y, step, defocus_radius, sigma_radial, sigma_tangential, angle)
    if fine is None:  # no optics: the pixel that holds the point takes it all
        k = np.zeros((2 * half + 1, 2 * half + 1))
        k[half + int(round(dv)), half + int(round(du))] = 1.0
        return k.astype(np.float32)
    fine = np.clip(fine, 0.0, None)
    k = fine.reshape(2 * half + 1, s, 2 * half + 1, s).sum(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


def point_source_image(shape: tuple[int, int], sources: PointSources, electrons: ArrayLike,
                       camera: Camera, cfg: AberrationPsfConfig
                       ) -> tuple[Float32Array, float]:
    """Point sources of ``electrons`` [e-] each, spread by the field-varying PSF of ``cfg``
    at their sub-pixel positions (the tent blend of the four nearest node PSFs of
    :func:`psf_grid`, as :func:`apply_psf_grid` blends them for a source pixel there).

    Per node, the kernels of all stars it weighs are read at once from the node's cached
    integral image (:func:`point_source_kernel`) and everything is accumulated with one
    ``bincount``: ~0.05 ms per star (``docs/performance.md``).

    Returns the ``(H, W)`` image [e-] and the electrons that fell outside the array."""
    H, W = shape
    el = np.broadcast_to(np.asarray(electrons, float), sources.u.shape)
    keep = el > 0
    u, v, e = sources.u[keep], sources.v[keep], el[keep]
    if u.size == 0:
        return np.zeros((H, W), np.float32), 0.0
    if cfg.enabled:
        u_nodes, v_nodes, params = _node_parameters(camera, cfg)
    else:
        u_nodes, v_nodes, params = (0.0,), (0.0,), [[(0.0, 0.0, 0.0, 0.0)]]
    iu, iv = np.floor(u + 0.5), np.floor(v + 0.5)
    du, dv = u - iu, v - iv
    iu, iv = iu.astype(np.intp), iv.astype(np.intp)
    wu = [_tent(u, u_nodes, i) for i in range(len(u_nodes))]
    wv = [_tent(v, v_nodes, j) for j in range(len(v_nodes))]
    idx_parts, w_parts = [], []
    for j in range(len(v_nodes)):
        for i in range(len(u_nodes)):
            amount = e * wu[i] * wv[j]
            sel = amount > 0
            if not sel.any():
                continue
            R, sr, st, ang = params[j][i]
            C, half = _point_source_integral(R, sr, st, ang, int(cfg.oversample))
            k = _shifted_kernels(C, half, int(cfg.oversample), du[sel], dv[sel])
            off = np.arange(-(half + 1), half + 2)
            rows = iv[sel][:, None, None] + off[None, :, None]
            cols = iu[sel][:, None, None] + off[None, None, :]
            inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
            idx_parts.append((rows * W + cols)[inside])
            w_parts.append((k * amount[sel][:, None, None])[inside])
    if not idx_parts:
        return np.zeros((H, W), np.float32), float(e.sum())
    img = np.bincount(np.concatenate(idx_parts), weights=np.concatenate(w_parts),
                      minlength=H * W).reshape(H, W)
    return img.astype(np.float32), float(e.sum() - img.sum())


# =========================================================================== distortion
@dataclass(frozen=True)
class DistortionMap:
    """Bilinear gather from the pinhole image for every detector pixel (cached per camera).

    Attributes
    ----------
    index : (H, W) int64
        Flat index of the top-left neighbour in the pinhole image padded by one pixel of zeros
        on every side (shape ``(H + 2) x (W + 2)``).
    weights : (4, H, W) float32
        Bilinear weights of the neighbours (top-left, top-right, bottom-left, bottom-right),
        multiplied by the pixel-area ratio ``1 / det(d x_d / d x_u)``; 0 where the detector
        pixel looks outside the pinhole image.
    """

    index: NDArray[np.int64]
    weights: Float32Array


@lru_cache(maxsize=4)
def distortion_map(camera: Camera) -> DistortionMap:
    """Inverse Brown-Conrady map of every detector pixel of ``camera`` (cached)."""
    H, W = camera.height, camera.width
    u, v = camera.pixel_grid()
    xy_d = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], axis=-1)
    xy = camera.undistort(xy_d)
    jac = camera.distortion_jacobian(xy)
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    area = 1.0 / np.abs(det)
    su = camera.fx * xy[..., 0] + camera.cx + 1.0      # in padded-image pixels
    sv = camera.fy * xy[..., 1] + camera.cy + 1.0
    inside = (su >= 0) & (su <= W + 1) & (sv >= 0) & (sv <= H + 1)
    su = np.clip(su, 0.0, W + 1 - 1e-9)
    sv = np.clip(sv, 0.0, H + 1 - 1e-9)
    i0, j0 = np.floor(sv).astype(np.int64), np.floor(su).astype(np.int64)
    i0 = np.minimum(i0, H)
    j0 = np.minimum(j0, W)
    fv, fu = sv - i0, su - j0
    a = np.where(inside, area, 0.0)
    w = np.stack([(1 - fv) * (1 - fu), (1 - fv) * fu, fv * (1 - fu), fv * fu]) * a
    index = i0 * (W + 2) + j0
    weights = w.astype(np.float32)
    index.flags.writeable = False
    weights.flags.writeable = False
    return DistortionMap(index, weights)


def distort(image: Float32Array, camera: Camera) -> Float32Array:
    """Resample the undistorted pinhole ``image`` onto the distorted detector grid.

    Parameters
    ----------
    image : (H, W) float32
        Pinhole image (flux per pixel, any additive unit).
    camera : Camera
        Supplies the Brown-Conrady coefficients; returned unchanged if it has none.

    Returns
    -------
    (H, W) float32
        Detector image, same unit; flux conserved up to O(delta^2), delta the local scale
        change (module essay, step 3).
    """
    if not camera.has_distortion:
        return image.copy()
    H, W = image.shape
    bb = signal_bbox(image)
    out = np.zeros_like(image, dtype=np.float32)
    if bb is None:
        return out
    r0, r1, c0, c1 = bb
    # forward-map the border of the signal box (one sample per pixel) to find its image
    e_u = np.concatenate([np.arange(c0 - 1, c1 + 1), np.full(r1 - r0 + 2, c1),
                          np.arange(c0 - 1, c1 + 1), np.full(r1 - r0 + 2, c0 - 1)]).astype(float)
    e_v = np.concatenate([np.full(c1 - c0 + 2, r0 - 1), np.arange(r0 - 1, r1 + 1),
                          np.full(c1 - c0 + 2, r1), np.arange(r0 - 1, r1 + 1)]).astype(float)
    xy = np.stack([(e_u - camera.cx) / camera.fx, (e_v - camera.cy) / camera.fy], -1)
    xyd = camera.distort(xy)
    ud = camera.fx * xyd[:, 0] + camera.cx
    vd = camera.fy * xyd[:, 1] + camera.cy
    R0 = max(int(math.floor(vd.min())) - 1, 0)
    R1 = min(int(math.ceil(vd.max())) + 2, H)
    C0 = max(int(math.floor(ud.min())) - 1, 0)
    C1 = min(int(math.ceil(ud.max())) + 2, W)
    if R0 >= R1 or C0 >= C1:
        return out
    m = distortion_map(camera)
    flat = np.pad(image, 1).ravel()
    idx = m.index[R0:R1, C0:C1]
    w = m.weights[:, R0:R1, C0:C1]
    acc = flat.take(idx) * w[0]
    acc += flat.take(idx + 1) * w[1]
    acc += flat.take(idx + (W + 2)) * w[2]
    acc += flat.take(idx + (W + 3)) * w[3]
    out[R0:R1, C0:C1] = acc
    return out


# =========================================================================== coarse grid
def block_sum(image: Float32Array, b: int) -> Float32Array:
    """Sum ``b x b`` blocks (zero-padding the far edges). Shape ``ceil(H/b) x ceil(W/b)``."""
    H, W = image.shape
    h, w = -(-H // b), -(-W // b)
    if h * b != H or w * b != W:
        pad = np.zeros((h * b, w * b), np.float32)
        pad[:H, :W] = image
        image = pad
    return image.reshape(h, b, w, b).sum(axis=(1, 3), dtype=np.float32)


@lru_cache(maxsize=16)
def _expand_matrix(n_fine: int, b: int):  # -> scipy.sparse.csr_matrix
    """Sparse ``(n_fine, ceil(n_fine / b))`` operator: spread each coarse cell over its ``b``
    fine samples, then smooth with a box of ``2 floor(b/2) + 1`` samples reflected at the
    edges. Its columns sum to 1 (except the last cell's part beyond ``n_fine``)."""
    import scipy.sparse as sps

    n_coarse = -(-n_fine // b)
    fine = np.arange(n_fine)
    rep = sps.csr_matrix((np.full(n_fine, 1.0 / b), (fine, fine // b)),
                         shape=(n_fine, n_coarse))
    if b > 1:
        half = b // 2
        rows, cols = [], []
        for d in range(-half, half + 1):
            j = fine + d
            j = np.where(j < 0, -j - 1, np.where(j >= n_fine, 2 * n_fine - 1 - j, j))
            rows.append(fine)
            cols.append(j)
        box = sps.csr_matrix((np.full(n_fine * (2 * half + 1), 1.0 / (2 * half + 1)),
                              (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n_fine, n_fine))
        rep = box @ rep
    return sps.csr_matrix(rep, dtype=np.float32)


def block_expand(low: Float32Array, b: int, shape: tuple[int, int]) -> Float32Array:
    """Spread each coarse block uniformly over its ``b x b`` pixels and smooth with a unit-sum
    box of ``2 floor(b/2) + 1`` pixels with reflecting edges, cropped to ``shape``; both steps
    conserve flux (except blocks beyond ``shape``). Done as two sparse matrix products
    (single-threaded, ~0.5 ms for 1024 x 1024)."""
    ar = _expand_matrix(shape[0], b)
    ac = _expand_matrix(shape[1], b)
    tmp = ac @ np.ascontiguousarray(low[: ar.shape[1], : ac.shape[1]].T)   # (W, h)
    return np.ascontiguousarray(ar @ tmp.T, dtype=np.float32)


def _supersampled(fn, half: int, scale: float, ss: int) -> NDArray[np.float64]:
    """Mean of ``fn(r)`` over ``ss x ss`` sub-samples of each cell of a ``(2 half + 1)^2`` grid of
    cells of side ``scale`` centred on the origin."""
    off = ((np.arange(ss) + 0.5) / ss - 0.5) * scale
    c = np.arange(-half, half + 1) * scale
    x = (c[:, None] + off[None, :]).ravel()
    r = np.hypot(x[:, None], x[None, :])
    vals = fn(r).reshape(2 * half + 1, ss, 2 * half + 1, ss)
    return vals.mean(axis=(1, 3))


@lru_cache(maxsize=8)
def halo_kernels(shoulder: float, slope: float, max_radius: float, core_radius: int,
                 binning: int) -> tuple[Float32Array, Float32Array]:
    """Harvey halo split into a full-resolution core and a coarse far part.

    Returns
    -------
    core : (2 core_radius + 1)^2 float32
        ``K - K(r_c)`` inside ``r_c``, per pixel.
    far : coarse float32
        ``min(K, K(r_c))`` integrated over each coarse cell, per coarse cell.

    Both are scaled so that ``core.sum() + far.sum() == 1``.
    """
    def K(r: NDArray[np.float64]) -> NDArray[np.float64]:
        k = (1.0 + (r / shoulder) ** 2) ** (slope / 2.0)
        return np.where(r <= max_radius, k, 0.0)

    kc = float((1.0 + (core_radius / shoulder) ** 2) ** (slope / 2.0))
    core = _supersampled(lambda r: np.where(r < core_radius, K(r) - kc, 0.0), core_radius, 1.0,
                         KERNEL_SUPERSAMPLE)
    core = np.clip(core, 0.0, None)
    nb = int(math.ceil(max_radius / binning))
    far = _supersampled(lambda r: np.minimum(K(r), kc), nb, float(binning),
                        KERNEL_SUPERSAMPLE) * binning * binning
    total = core.sum() + far.sum()
    core_k, far_k = (core / total).astype(np.float32), (far / total).astype(np.float32)
    core_k.flags.writeable = False
    far_k.flags.writeable = False
    return core_k, far_k


def stray_light(image: Float32Array, cfg: StrayLightConfig) -> Float32Array:
    """Add the in-field stray-light halo (module essay, step 4).

    Parameters
    ----------
    image : (H, W) float32
        Focal-plane image (flux per pixel, any additive unit).
    cfg : StrayLightConfig
        TIS, Harvey slope and shoulder [px], support radius [px], core radius and binning.

    Returns
    -------
    (H, W) float32
        ``(1 - TIS) image + TIS * halo``, same unit; flux conserved except the halo falling
        outside the array.
    """
    tis = float(cfg.total_integrated_scatter)
    bb = signal_bbox(image)
    if tis == 0.0 or bb is None:
        return image.copy()
    core, far = halo_kernels(cfg.shoulder_px, cfg.harvey_slope, cfg.max_radius_px,
                             cfg.core_radius_px, cfg.binning)
    H, W = image.shape
    out = image * np.float32(1.0 - tis)
    r0, r1, c0, c1 = bb
    convolve_add(out, image[r0:r1, c0:c1] * np.float32(tis), r0, c0, core,
                 ("halo-core", cfg.shoulder_px, cfg.harvey_slope, cfg.max_radius_px,
                  cfg.core_radius_px, cfg.binning))
    b = cfg.binning
    low = block_sum(image, b)
    acc = np.zeros_like(low)
    lb = signal_bbox(low)
    assert lb is not None
    convolve_add(acc, low[lb[0]:lb[1], lb[2]:lb[3]] * np.float32(tis), lb[0], lb[2], far,
                 ("halo-far", cfg.shoulder_px, cfg.harvey_slope, cfg.max_radius_px,
                  cfg.core_radius_px, cfg.binning))
    out += block_expand(acc, b, (H, W))
    return out


# =========================================================================== ghosts
@lru_cache(maxsize=32)
def disc_kernel(radius: float) -> Float32Array:
    """Pixel-integrated uniform disc of ``radius`` [px], unit sum (a delta below 0.5 px)."""
    half = int(math.ceil(radius))
    if radius < 0.5:
        k = np.ones((1, 1))
    else:
        step = 1.0 / KERNEL_SUPERSAMPLE
        off = ((np.arange(KERNEL_SUPERSAMPLE) + 0.5) * step - 0.5)
        c = np.arange(-half, half + 1, dtype=float)
        x = (c[:, None] + off[None, :]).ravel()
        cov = disc_coverage(radius, x[:, None], x[None, :], step)
        k = cov.reshape(2 * half + 1, KERNEL_SUPERSAMPLE, 2 * half + 1,
                        KERNEL_SUPERSAMPLE).sum(axis=(1, 3))
    k = (k / k.sum()).astype(np.float32)
    k.flags.writeable = False
    return k


def ghost_images(image: Float32Array, ghosts: tuple[GhostConfig, ...],
                 principal_point: tuple[float, float], binning: int) -> Float32Array:
    """Add the ghosts to ``image`` (module essay, step 5).

    Parameters
    ----------
    image : (H, W) float32
        Focal-plane image (flux per pixel).
    ghosts : tuple of GhostConfig
        Weight [-], magnification [-], defocus radius [px] and offset [px] of each ghost.
    principal_point : (cx, cy)
        Centre of the ghost magnification [px].
    binning : int
        Coarse-grid factor [px].

    Returns
    -------
    (H, W) float32
        ``(1 - sum w) image + sum w_i ghost_i``, same unit.
    """
    from scipy.ndimage import map_coordinates

    if not ghosts or signal_bbox(image) is None:
        return image.copy()
    H, W = image.shape
    b = int(binning)
    low = block_sum(image, b)
    h, w = low.shape
    acc = np.zeros_like(low)
    cx, cy = principal_point
    Cx, Cy = (cx + 0.5) / b - 0.5, (cy + 0.5) / b - 0.5
    V, U = np.mgrid[0:h, 0:w].astype(np.float64)
    wsum = 0.0
    for g in ghosts:
        if g.weight == 0:
            continue
        m = float(g.magnification)
        su = Cx + (U - Cx - g.offset_px[0] / b) / m
        sv = Cy + (V - Cy - g.offset_px[1] / b) / m
        gi = map_coordinates(low, [sv, su], order=1, mode="grid-constant", cval=0.0,
                             prefilter=False).astype(np.float32) / np.float32(m * m)
        k = disc_kernel(g.defocus_radius_px / b)
        gacc = np.zeros_like(low)
        convolve_add(gacc, gi * np.float32(g.weight), 0, 0, k, ("disc", g.defocus_radius_px / b))
        acc += gacc
        wsum += g.weight
    out = image * np.float32(1.0 - wsum)
    out += block_expand(acc, b, (H, W))
    return out
