"""The stimulating screen: digital counts <-> radiance seen by the camera, and what it displays.

1. Each channel at count ``n`` emits ``L_c(lambda) [b + (1 - b) (n / n_max)^gamma_c]``
   (:class:`~starnav.calibration.schema.ScreenEmittanceConfig`).
2. Radiance is conserved through the collimator (times its transmission and the ND filter),
   so the camera sees the electron radiance ``Le`` of the renderer's channel: the paper's
   "effective radiant flux density".
3. A look-up table of ``Le`` per count turns counts into radiance and back (grey stimuli).
4. Radiance to counts: ``nearest``, or ``dither`` (the expected radiance exact, removing the
   quantisation bias of the paper's Fig. 16).

References
----------
Seed paper, "Radiometric Calibration", steps 1-2 and Figs. 14-16.

Index
-----
:class:`ScreenRadiometry`, :func:`quantize_to_counts`, :func:`gaussian_dots`,
:data:`QUANTIZATION_METHODS`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.calibration.schema import CollimatorConfig, ScreenConfig
from starnav.errors import ConfigError
from starnav.spectra import SensorResponse, Spectrum, product
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

QUANTIZATION_METHODS = ("nearest", "dither")



def quantize_to_counts(x: FloatArray, table: FloatArray, method: str,
                       rng: np.random.Generator | None) -> NDArray[np.uint16]:
    """Counts whose table values bracket ``x``: the nearest of the two, or a random choice
    between them with expectation ``x`` (``dither``, needs ``rng``). ``table`` is
    non-decreasing over counts ``0 .. len(table) - 1``; ``x`` within its range."""
    n_max = len(table) - 1
    hi = np.clip(np.searchsorted(table, x, side="left"), 0, n_max)
    lo = np.clip(hi - 1, 0, n_max)
    span = table[hi] - table[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(span > 0, (x - table[lo]) / span, 0.0)
    pick_hi = t >= 0.5 if method == "nearest" else rng.random(np.shape(x)) < t
    return np.where(pick_hi, hi, lo).astype(np.uint16)

@dataclass(frozen=True)
class ScreenRadiometry:
    """Radiance at the camera produced by each screen count (through the collimator).

    Attributes
    ----------
    max_count : int
        Largest count ``2^bits - 1``.
    le_lut : (max_count + 1,) array
        Electron radiance at the camera of a grey pixel (R = G = B = n) [e- s^-1 m^-2 sr^-1].
    l_lut : (max_count + 1,) array
        Band radiance at the camera of a grey pixel [W m^-2 sr^-1].
    channel_le : (3, max_count + 1) array
        Electron radiance of each channel alone [e- s^-1 m^-2 sr^-1].
    channel_l : (3, max_count + 1) array
        Band radiance of each channel alone [W m^-2 sr^-1].
    throughput : float
        Collimator transmission x ND filter transmission [-].
    """

    max_count: int
    le_lut: FloatArray
    l_lut: FloatArray
    channel_le: FloatArray
    channel_l: FloatArray
    throughput: float

    # ................................................................ construction
    @classmethod
    def from_config(cls, screen: ScreenConfig, collimator: CollimatorConfig,
                    response: SensorResponse) -> ScreenRadiometry:
        """Convolve the screen's emittance with the camera response (paper, step 2).

        Raises
        ------
        ConfigError
            ``screen.emittance`` is missing (not measured) or emits nothing inside the camera
            band.
        """
        em = screen.emittance
        if em is None:
            raise ConfigError("screen.emittance", None,
                              "per-channel spectral radiance tables (wavelengths_nm, "
                              "red/green/blue_w_m2_sr_nm at full count, gamma): measure the "
                              "screen (paper, radiometric step 1) or use the representative one")
        wl = np.asarray(em.wavelengths_nm, float)
        tables = em.channels()
        s_e = response.electrons_per_joule()
        box = response.box()
        throughput = collimator.transmission * 10.0 ** (-collimator.nd_optical_density)
        k_e = np.zeros(3)
        k_l = np.zeros(3)
        lo, hi = response.band
        for c in range(3):
            sp = Spectrum(wl, tables[c], "W m^-2 sr^-1 nm^-1")
            if wl[-1] <= lo or wl[0] >= hi:
                continue
            k_e[c] = product(sp, s_e).integral() * throughput
            k_l[c] = product(sp, box).integral() * throughput
        if not np.any(k_e > 0):
            raise ConfigError("screen.emittance", f"{wl[0]:g}-{wl[-1]:g} nm",
                              f"emission inside the camera band {lo:g}-{hi:g} nm (the screen "
                              "does not excite the detector)")
        n_max = screen.max_count
        frac = np.arange(n_max + 1, dtype=float) / n_max
        b = em.black_level_fraction
        g = np.stack([b + (1.0 - b) * frac ** gam for gam in em.gamma])  # (3, n)
        ch_le = g * k_e[:, None]
        ch_l = g * k_l[:, None]
        return cls(n_max, ch_le.sum(0), ch_l.sum(0), ch_le, ch_l, float(throughput))

    # ................................................................ properties
    @property
    def le_max(self) -> float:
        """Electron radiance at full white [e- s^-1 m^-2 sr^-1]."""
        return float(self.le_lut[-1])

    @property
    def le_min(self) -> float:
        """Electron radiance at count 0 (black level) [e- s^-1 m^-2 sr^-1]."""
        return float(self.le_lut[0])

    @property
    def electrons_per_joule(self) -> float:
        """Band-averaged e- per J of the white screen through the camera response [e- J^-1]."""
        return float(self.le_lut[-1] / self.l_lut[-1])

    # ................................................................ counts -> radiance
    def check_counts(self, counts: ArrayLike, field: str = "screen counts") -> NDArray[np.int64]:
        """Validate counts: integers in ``[0, max_count]``.

        Raises
        ------
        ConfigError
            A count is negative, above ``max_count`` or not an integer.
        """
        c = np.asarray(counts)
        if c.size == 0:
            return c.astype(np.int64)
        if not np.issubdtype(c.dtype, np.integer):
            if not np.all(np.isfinite(c)) or np.any(c != np.round(c)):
                raise ConfigError(field, f"non-integer values (dtype {c.dtype})",
                                  f"integer counts in [0, {self.max_count}]")
        cmax, cmin = c.max(), c.min()
        if cmax > self.max_count or cmin < 0:
            bad = cmax if cmax > self.max_count else cmin
            idx = np.unravel_index(int(np.argmax(c == bad)), c.shape)
            raise ConfigError(field, f"{int(bad)} at index {tuple(int(i) for i in idx)}",
                              f"counts in [0, {self.max_count}] (screen.bit_depth = "
                              f"{int(math.log2(self.max_count + 1))})")
        return c.astype(np.int64)

    def electron_radiance(self, counts: ArrayLike) -> FloatArray:
        """Electron radiance at the camera for grey counts (R = G = B), any shape
        [e- s^-1 m^-2 sr^-1]; see :meth:`electron_radiance_rgb` for RGB counts."""
        c = self.check_counts(counts)
        return self.le_lut[c]

    def electron_radiance_rgb(self, counts: ArrayLike) -> FloatArray:
        """Electron radiance at the camera for RGB counts ``(..., 3)`` [e- s^-1 m^-2 sr^-1]."""
        c = self.check_counts(counts)
        if c.ndim < 1 or c.shape[-1] != 3:
            raise ConfigError("screen counts", f"shape {c.shape}", "(..., 3) RGB counts")
        return (self.channel_le[0][c[..., 0]] + self.channel_le[1][c[..., 1]]
                + self.channel_le[2][c[..., 2]])

    # ................................................................ radiance -> counts
    def continuous_count(self, le: ArrayLike) -> FloatArray:
        """The (non-integer) grey count whose radiance is ``le``, interpolated between levels."""
        x = np.asarray(le, float)
        return np.interp(x, self.le_lut, np.arange(self.max_count + 1, dtype=float))

    def counts_for(self, le: ArrayLike, method: str = "nearest",
                   rng: np.random.Generator | None = None, clip: bool = False,
                   field: str = "stimulus electron radiance") -> NDArray[np.uint16]:
        """Grey counts that display the electron radiance ``le`` at the camera.

        Parameters
        ----------
        le : array
            Wanted electron radiance at the camera [e- s^-1 m^-2 sr^-1].
        method : {"nearest", "dither"}
            Nearest level in radiance, or random choice between the two neighbouring levels
            with expectation ``le`` (needs ``rng``).
        rng : numpy.random.Generator, optional
            Random stream of the dithering.
        clip : bool
            Clip radiance above full white (and below the black level) instead of raising.

        Raises
        ------
        ConfigError
            ``le`` above the screen's full-white radiance (``clip`` False), negative or NaN;
            unknown ``method``; ``dither`` without ``rng``.
        """
        if method not in QUANTIZATION_METHODS:
            raise ConfigError("radiometric.quantization", method,
                              f"one of {', '.join(QUANTIZATION_METHODS)}")
        x = np.asarray(le, float)
        if x.size and not np.all(np.isfinite(x)):
            raise ConfigError(field, "non-finite values", "finite radiance >= 0")
        if x.size and x.min() < 0:
            raise ConfigError(field, float(x.min()), "radiance >= 0 [e- s^-1 m^-2 sr^-1]")
        top = self.le_max
        if x.size and x.max() > top * (1 + 1e-9):
            if not clip:
                raise ConfigError(
                    field, f"{x.max():.4g} e- s^-1 m^-2 sr^-1",
                    f"<= the screen's full white {top:.4g} (count {self.max_count}); "
                    f"raise the albedo-exposure factor k by >= {x.max() / top:.4g}x")
            log.warning("stimulus clipped at full white: %d pixel(s) above %.4g",
                        int(np.count_nonzero(x > top)), top)
        x = np.clip(x, self.le_min, top)
        if method != "nearest" and rng is None:
            raise ConfigError("rng", None, "a numpy Generator for dithering")
        return quantize_to_counts(x, self.le_lut, method, rng)


# --------------------------------------------------------------------------- patterns
def gaussian_dots(shape: tuple[int, int], centres: ArrayLike, sigma: float,
                  peak_le: float, radiometry: ScreenRadiometry) -> NDArray[np.uint16]:
    """A screen image of anti-aliased Gaussian dots at sub-pixel positions.

    Each dot is a Gaussian of ``sigma`` [screen px] *in radiance* (the inverse gamma is applied
    per pixel through :meth:`ScreenRadiometry.counts_for`, nearest level), peaking at
    ``peak_le`` [e- s^-1 m^-2 sr^-1], so its radiance centroid is the wanted sub-pixel position
    up to the count quantisation.

    Parameters
    ----------
    shape : (rows, cols)
        Screen size [px].
    centres : (N, 2) array
        Dot centres as (column, row) [screen px]; dots off the screen are clipped at the edge.
    sigma : float
        Gaussian radius [screen px].
    """
    H, W = shape
    c = np.asarray(centres, float).reshape(-1, 2)
    le = np.zeros((H, W))
    r = int(math.ceil(4.0 * sigma))
    offs = np.arange(-r, r + 1)
    for x0, y0 in c:
        j0, i0 = int(round(x0)), int(round(y0))
        jj = j0 + offs
        ii = i0 + offs
        jj = jj[(jj >= 0) & (jj < W)]
        ii = ii[(ii >= 0) & (ii < H)]
        if jj.size == 0 or ii.size == 0:
            continue
        gx = np.exp(-0.5 * ((jj - x0) / sigma) ** 2)
        gy = np.exp(-0.5 * ((ii - y0) / sigma) ** 2)
        patch = peak_le * gy[:, None] * gx[None, :]
        sl = le[ii[0]:ii[-1] + 1, jj[0]:jj[-1] + 1]
        np.maximum(sl, patch, out=sl)
    return radiometry.counts_for(le, "nearest", clip=True)
