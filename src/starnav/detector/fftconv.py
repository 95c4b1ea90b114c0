"""FFT convolution of a sub-image into a frame, with cached kernel spectra.

The optics effects convolve only the part of the frame that holds signal (a Moon at 60 000 km
covers ~2 % of the AA-STR frame), so the transforms are sized on that region plus the kernel
margin. FFT shapes are rounded up to a multiple of :data:`FFT_QUANTUM` and then to a fast length,
so that successive frames with the Moon in slightly different places reuse the same kernel
spectra from the cache (guarded by a lock: a dataset makes frames in two threads).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Hashable

import numpy as np
from numpy.typing import NDArray

from starnav.cache import BoundedCache
from starnav.typing import Float32Array

logger = logging.getLogger(__name__)


#: FFT sizes are rounded up to a multiple of this before ``next_fast_len`` [samples].
FFT_QUANTUM = 32
#: Number of kernel spectra kept in the cache.
SPECTRUM_CACHE_SIZE = 256
#: Worker threads handed to scipy.fft (the budget machine has 2 cores).
FFT_WORKERS = 2

_SPECTRA: BoundedCache[tuple[Hashable, tuple[int, int]], NDArray[np.complex64]] = BoundedCache(
    SPECTRUM_CACHE_SIZE)
_SPECTRA_LOCK = threading.Lock()


def fft_shape(n_rows: int, n_cols: int) -> tuple[int, int]:
    """Fast, quantised FFT shape able to hold an ``n_rows x n_cols`` linear convolution."""
    from scipy.fft import next_fast_len

    def q(n: int) -> int:
        return next_fast_len(-(-n // FFT_QUANTUM) * FFT_QUANTUM, real=True)

    return q(n_rows), q(n_cols)


def kernel_spectrum(kernel: Float32Array, shape: tuple[int, int],
                    key: Hashable | None) -> NDArray[np.complex64]:
    """``rfft2`` of ``kernel`` zero-padded to ``shape``, from the cache when ``key`` is given."""
    import scipy.fft as sfft

    def make() -> NDArray[np.complex64]:
        return sfft.rfft2(np.asarray(kernel, dtype=np.float32), s=shape, workers=FFT_WORKERS)

    if key is None:
        return make()
    with _SPECTRA_LOCK:   # frames are made in threads (starnav.dataset.writer)
        hit = _SPECTRA.get((key, shape))
    if hit is None:
        hit = make()   # outside the lock: two threads may both make it, with equal results
        with _SPECTRA_LOCK:
            _SPECTRA.put((key, shape), hit)
    return hit


def clear_cache() -> None:
    """Forget every cached kernel spectrum."""
    with _SPECTRA_LOCK:
        _SPECTRA.clear()


def convolve_add(out: Float32Array, src: Float32Array, r0: int, c0: int,
                 kernel: Float32Array, key: Hashable | None = None) -> float:
    """Add ``src`` (placed with its top-left pixel at ``(r0, c0)`` of ``out``) convolved with
    ``kernel`` into ``out``, in place, and return the flux that fell outside ``out``.

    Parameters
    ----------
    out : (H, W) float32
        Frame accumulating the result (modified in place).
    src : (h, w) float32
    r0, c0 : int
        Position of ``src[0, 0]`` in ``out`` [px].
    kernel : (2 kh + 1, 2 kw + 1) float32
        Centred on its middle sample.
    key : hashable, optional
        Cache key of ``kernel`` (same key = same kernel).
    """
    import scipy.fft as sfft

    kh, kw = kernel.shape[0] // 2, kernel.shape[1] // 2
    if kernel.shape[0] % 2 == 0 or kernel.shape[1] % 2 == 0:
        raise ValueError(f"kernel shape {kernel.shape} must be odd")
    h, w = src.shape
    full_h, full_w = h + 2 * kh, w + 2 * kw
    shape = fft_shape(full_h, full_w)
    spec = sfft.rfft2(src.astype(np.float32, copy=False), s=shape, workers=FFT_WORKERS)
    spec *= kernel_spectrum(kernel, shape, key)
    conv = sfft.irfft2(spec, s=shape, workers=FFT_WORKERS)[:full_h, :full_w]
    # conv[i, j] lands on out[r0 - kh + i, c0 - kw + j]
    top, left = r0 - kh, c0 - kw
    H, W = out.shape
    a0, b0 = max(top, 0), max(left, 0)
    a1, b1 = min(top + full_h, H), min(left + full_w, W)
    inside = conv[a0 - top : a1 - top, b0 - left : b1 - left]
    out[a0:a1, b0:b1] += inside
    return float(conv.sum(dtype=np.float64) - inside.sum(dtype=np.float64))


def signal_bbox(image: NDArray[np.floating]) -> tuple[int, int, int, int] | None:
    """Bounding box ``(r0, r1, c0, c1)`` (half-open) of the non-zero pixels, or ``None``."""
    rows = np.flatnonzero(image.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(image[rows[0] : rows[-1] + 1].any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
