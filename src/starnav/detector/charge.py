"""Charge generation: PRNU, dark current (DSNU, hot pixels, temperature) and shot noise.

1. PRNU: a frozen per-pixel gain ``1 + sigma_prnu z`` from the sensor's fixed-pattern stream
   (:func:`prnu_map`).
2. Dark current ``D_ref 2^((T - T_ref) / T_2)`` with DSNU and hot pixels
   (:func:`dark_rate_at`, :func:`dark_pattern`, :func:`hot_pixel_mask`), added to the mean
   before shot noise (:func:`add_dark_current`).
3. Shot noise (:func:`shot_noise`): Poisson, or ``N(mu, mu)`` above ``gaussian_above_e``
   (skewness ``mu^-1/2``: 3 % at 1000 e-).

Index
-----
:func:`prnu_map`, :func:`dark_rate_at`, :func:`dark_pattern`, :func:`hot_pixel_mask`,
:func:`add_dark_current`, :func:`shot_noise`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from starnav.detector.seeding import fixed_pattern_rng
from starnav.typing import Float32Array


@lru_cache(maxsize=8)
def prnu_map(sensor_seed: int, shape: tuple[int, int], sigma: float) -> Float32Array:
    """Frozen PRNU gain map ``1 + sigma z`` of sensor ``sensor_seed`` [-] (cached, read-only)."""
    rng = fixed_pattern_rng(sensor_seed, "prnu")
    g = rng.standard_normal(shape, dtype=np.float32)
    g *= np.float32(sigma)
    g += np.float32(1.0)
    np.clip(g, 0.0, None, out=g)
    g.flags.writeable = False
    return g


def dark_rate_at(rate_ref: float, temperature: float, reference: float,
                 doubling: float) -> float:
    """Mean dark current at ``temperature``: ``rate_ref 2^((T - T_ref) / T_2)`` [e-/s]
    (temperatures and the doubling step in K; only differences enter)."""
    return float(rate_ref) * 2.0 ** ((temperature - reference) / doubling)


@lru_cache(maxsize=8)
def dark_pattern(sensor_seed: int, shape: tuple[int, int], dsnu: float, hot_fraction: float,
                 hot_factor: float) -> Float32Array:
    """Frozen relative dark-current map (mean rate = 1) of sensor ``sensor_seed`` [-].

    ``1 + dsnu z`` clipped at 0, with a fixed random ``hot_fraction`` of pixels set to
    ``hot_factor``. Multiply by the mean rate [e-/s] and the exposure [s] to get electrons.
    """
    rng = fixed_pattern_rng(sensor_seed, "dark_current")
    d = rng.standard_normal(shape, dtype=np.float32)
    d *= np.float32(dsnu)
    d += np.float32(1.0)
    np.clip(d, 0.0, None, out=d)
    n_hot = int(round(hot_fraction * d.size))
    if n_hot:
        hot = fixed_pattern_rng(sensor_seed, "hot_pixels").choice(d.size, n_hot, replace=False)
        d.ravel()[hot] = np.float32(hot_factor)
    d.flags.writeable = False
    return d


def hot_pixel_mask(sensor_seed: int, shape: tuple[int, int],
                   hot_fraction: float) -> NDArray[np.bool_]:
    """Boolean map of the hot pixels of sensor ``sensor_seed`` (the draw of
    :func:`dark_pattern`)."""
    m = np.zeros(shape, bool)
    n_hot = int(round(hot_fraction * m.size))
    if n_hot:
        m.ravel()[fixed_pattern_rng(sensor_seed, "hot_pixels").choice(m.size, n_hot,
                                                                       replace=False)] = True
    return m


def add_dark_current(charge: Float32Array, pattern: Float32Array, rate: float,
                     exposure_time: float) -> Float32Array:
    """Mean charge plus dark charge ``pattern * rate * t`` [e-] (new array)."""
    return charge + pattern * np.float32(rate * exposure_time)


def shot_noise(mean: Float32Array, rng: np.random.Generator,
               gaussian_above: float | None = 1000.0) -> Float32Array:
    """Draw the collected charge for mean charge ``mean`` [e-] (module essay, step 3).

    Parameters
    ----------
    mean : (H, W) float32
        Mean charge [e-], >= 0.
    rng : numpy.random.Generator
        Temporal stream of this frame.
    gaussian_above : float or None
        Mean [e-] above which ``N(mu, mu)`` replaces ``Poisson(mu)``; ``None``: never.

    Returns
    -------
    (H, W) float32
        Charge [e-] (integers below ``gaussian_above``; clipped at 0 above).
    """
    # a PSF applied by FFT leaves round-off of either sign (~1e-2 e-) where there is no light:
    # a negative mean charge is zero charge
    lam = np.maximum(mean, 0.0, dtype=np.float64)   # (cast, then clipped: one pass)
    gauss = None
    if gaussian_above is not None:
        gauss = lam >= gaussian_above
        if gauss.any():
            lam[gauss] = 0.0
        else:
            gauss = None
    out = rng.poisson(lam).astype(np.float32)
    if gauss is not None:
        mu = mean[gauss]
        z = rng.standard_normal(mu.size, dtype=np.float32)
        out[gauss] = np.maximum(mu + np.sqrt(mu) * z, 0.0)
    return out
