"""Signal chain to DN and the AA-STR readout modes: segments, windows, full frame, and timing.

1. Non-linearity (:func:`nonlinearity`): ``S / (1 + beta S / F)``, the full well reading
   ``(1 - d) F``.
2. Read noise (:func:`read_noise`) from the frame's temporal stream.
3. ADC (:func:`adc`): ``clip(round(S / g + offset), 0, 2^bits - 1)``.
4. Segments (:func:`extract_segments`): per-row runs of pixels in one threshold band; the
   thresholded frame is rebuilt exactly; ``truncated`` when the buffer fills.
5. Windows (:func:`read_windows`): up to 16 rectangles of DN.
6. Readout law (seed paper eq. 1, :func:`readout_timing`): ``t_min = a + b N_pix / unit``;
   a shorter exposure is infeasible for that readout.

Index
-----
:func:`nonlinearity`, :func:`read_noise`, :func:`adc`, :func:`extract_segments`,
:func:`thresholded`, :func:`read_windows`, :func:`check_windows`, :func:`readout_timing`,
:class:`ReadoutTiming`, :func:`min_exposure`, :func:`check_timing`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from starnav.detector.products import MAX_WINDOWS, Segments, Window
from starnav.detector.schema import ReadoutTimingConfig, WindowSpec
from starnav.errors import ConfigError
from starnav.typing import Float32Array

logger = logging.getLogger(__name__)


# =========================================================================== signal to DN
def nonlinearity(signal: Float32Array, full_well: float, deficit: float) -> Float32Array:
    """Compress ``signal`` [e-] so the full well reads ``(1 - deficit)`` of itself (step 1)."""
    if deficit == 0.0:
        return signal.copy()
    beta = deficit / (1.0 - deficit)
    d = np.maximum(signal, 0.0)   # the denominator 1 + beta/F max(S, 0), built in place
    d *= np.float32(beta / full_well)
    d += 1.0
    return np.divide(signal, d, out=d).astype(np.float32, copy=False)


def read_noise(signal: Float32Array, sigma: float, rng: np.random.Generator) -> Float32Array:
    """Add Gaussian read noise of ``sigma`` [e- rms] (step 2)."""
    if sigma == 0.0:
        return signal.copy()
    z = rng.standard_normal(signal.shape, dtype=np.float32)
    z *= np.float32(sigma)
    z += signal
    return z


def adc(signal: Float32Array, gain: float, offset: float, bits: int) -> NDArray[np.uint16]:
    """Convert ``signal`` [e-] to DN: ``clip(round(S / gain + offset), 0, 2^bits - 1)`` (step 3).

    Parameters
    ----------
    signal : (H, W) float32
        Signal [e-].
    gain : float
        Conversion gain [e-/DN].
    offset : float
        Pedestal [DN].
    bits : int
        ADC resolution [bit], <= 16.
    """
    x = signal * np.float32(1.0 / gain)
    x += np.float32(offset)
    np.rint(x, out=x)
    np.clip(x, 0.0, float(2**bits - 1), out=x)
    return x.astype(np.uint16)


# =========================================================================== segments
def extract_segments(dn: NDArray[np.integer], thresholds: Sequence[int],
                     max_runs: int | None = None, max_pixels: int | None = None) -> Segments:
    """Full-image compressed readout (step 4).

    Parameters
    ----------
    dn : (H, W) integer array
        DN frame.
    thresholds : sequence of int
        Strictly increasing DN thresholds.
    max_runs, max_pixels : int, optional
        Readout limits; ``None`` means unlimited.

    Returns
    -------
    Segments
        Runs in raster order; ``truncated`` when a limit cut the list.
    """
    th = tuple(int(t) for t in thresholds)
    if not th or any(b <= a for a, b in zip(th, th[1:], strict=False)):
        raise ConfigError("thresholds_dn", th, "a non-empty, strictly increasing tuple")
    H, W = dn.shape
    # level = number of thresholds reached - 1; each row padded with a -1 sentinel so that
    # runs never cross rows
    lv = np.full((H, W + 1), -1, np.int16)
    body = lv[:, :W]
    for t in th:
        body += dn >= t
    flat = lv.ravel()
    change = np.empty(flat.size, bool)
    change[0] = True
    change[1:] = flat[1:] != flat[:-1]
    starts = np.flatnonzero(change)
    ends = np.append(starts[1:], flat.size)
    keep = flat[starts] >= 0
    starts, ends = starts[keep], ends[keep]
    row = (starts // (W + 1)).astype(np.int32)
    col = (starts % (W + 1)).astype(np.int32)
    length = (ends - starts).astype(np.int32)
    lev = flat[starts].astype(np.int8)
    truncated = False
    n = row.size
    if max_runs is not None and n > max_runs:
        n, truncated = int(max_runs), True
    if max_pixels is not None:
        cum = np.cumsum(length[:n], dtype=np.int64)
        n_fit = int(np.searchsorted(cum, max_pixels, side="right"))
        if n_fit < n:
            n, truncated = n_fit, True
    row, col, length, lev = row[:n], col[:n], length[:n], lev[:n]
    offset = np.zeros(n, np.int64)
    if n:
        offset[1:] = np.cumsum(length[:-1], dtype=np.int64)
    # values: the DN of every pixel of every kept run, in run order
    if n:
        kept_pixels = int(length.sum())
        run_id = np.repeat(np.arange(n), length)
        within = np.arange(kept_pixels) - np.repeat(offset, length)
        flat_idx = row[run_id].astype(np.int64) * W + col[run_id] + within
        values = dn.ravel()[flat_idx].astype(np.uint16)
    else:
        values = np.zeros(0, np.uint16)
    if truncated:
        logger.info("segments readout truncated at %d runs / %d pixels", n, int(length.sum()))
    return Segments(row=row, col_start=col, length=length, offset=offset, values=values,
                    level=lev, thresholds=th, shape=(H, W), truncated=truncated)


def thresholded(dn: NDArray[np.integer], threshold: int, fill: int = 0) -> NDArray[np.uint16]:
    """The frame with every pixel below ``threshold`` set to ``fill`` (what segments carry)."""
    return np.where(dn >= threshold, dn, fill).astype(np.uint16)


# =========================================================================== windows
def _as_spec(w: WindowSpec | Sequence[int] | dict) -> WindowSpec:
    if isinstance(w, WindowSpec):
        return w
    if isinstance(w, dict):
        return WindowSpec(**w)
    r0, c0, h, wd = (int(x) for x in w)
    return WindowSpec(row0=r0, col0=c0, height=h, width=wd)


def check_windows(windows: Iterable[WindowSpec | Sequence[int] | dict],
                  shape: tuple[int, int]) -> tuple[WindowSpec, ...]:
    """Validate windows against the AA-STR limit and the array ``shape``.

    Raises
    ------
    ConfigError
        More than :data:`MAX_WINDOWS` windows, or a window not inside the array.
    """
    specs = tuple(windows)
    if len(specs) > MAX_WINDOWS:
        raise ConfigError("readout.windows", f"{len(specs)} windows",
                          f"at most {MAX_WINDOWS} windows (AA-STR windows mode)")
    out = []
    H, W = shape
    for k, w in enumerate(specs):
        try:
            s = _as_spec(w)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"readout.windows[{k}]", w,
                              f"(row0, col0, height, width) with row0, col0 >= 0 and sizes "
                              f">= 1 ({err})") from None
        if s.row0 + s.height > H or s.col0 + s.width > W:
            raise ConfigError(f"readout.windows[{k}]",
                              (s.row0, s.col0, s.height, s.width),
                              f"a window inside the {H} x {W} array (rows 0..{H - 1}, "
                              f"columns 0..{W - 1})")
        out.append(s)
    return tuple(out)


def read_windows(dn: NDArray[np.integer], windows: Iterable[WindowSpec | Sequence[int] | dict]
                 ) -> tuple[Window, ...]:
    """Windows mode (step 5): a copy of the DN inside each (validated) window."""
    specs = check_windows(windows, dn.shape)
    return tuple(Window(s.row0, s.col0,
                        np.array(dn[s.row0 : s.row0 + s.height, s.col0 : s.col0 + s.width],
                                 dtype=np.uint16))
                 for s in specs)


# =========================================================================== timing
@dataclass(frozen=True)
class ReadoutTiming:
    """Whether an exposure is compatible with a readout (step 6).

    Attributes
    ----------
    mode : str
        ``segments``, ``windows`` or ``full_frame``.
    n_pixels : int
        Pixels the gate array reads.
    min_exposure : float
        Shortest exposure the readout law allows [s].
    exposure : float
        Requested exposure [s].
    feasible : bool
        ``exposure >= min_exposure``.
    """

    mode: str
    n_pixels: int
    min_exposure: float
    exposure: float
    feasible: bool

    def to_dict(self) -> dict[str, object]:
        return {"mode": self.mode, "n_pixels": self.n_pixels,
                "min_exposure_s": self.min_exposure, "exposure_s": self.exposure,
                "feasible": self.feasible}


def min_exposure(n_pixels: int, timing: ReadoutTimingConfig, full_frame: bool = False) -> float:
    """Shortest exposure [s] for a readout of ``n_pixels`` (seed paper eq. 1, step 6)."""
    si = timing.to_si()
    t = si.a + si.b * n_pixels / si.n_pix_unit
    return max(t, si.full_frame_min) if full_frame else t


def readout_timing(mode: str, shape: tuple[int, int], exposure: float,
                   timing: ReadoutTimingConfig,
                   windows: Sequence[WindowSpec] = ()) -> ReadoutTiming:
    """Timing check of one readout ``mode`` for an exposure [s] on an array of ``shape``."""
    if mode in ("segments", "full_frame"):
        n = int(shape[0] * shape[1])
        t = min_exposure(n, timing, full_frame=True)
    elif mode == "windows":
        n = int(sum(w.height * w.width for w in windows))
        t = min_exposure(n, timing)
    else:
        raise ConfigError("readout.modes", mode, "one of segments, windows, full_frame")
    return ReadoutTiming(mode, n, t, float(exposure), bool(exposure >= t * (1 - 1e-12)))


def check_timing(timings: Sequence[ReadoutTiming], policy: str) -> None:
    """Apply the timing ``policy`` (``enforce`` raises, ``warn`` logs, ``ignore``)."""
    for t in timings:
        if t.feasible or policy == "ignore":
            continue
        msg = (f"a {t.mode} readout of {t.n_pixels} px needs an exposure >= "
               f"{t.min_exposure * 1e3:.4g} ms (readout law t = a + b N_pix)")
        if policy == "enforce":
            raise ConfigError("exposure_time_s", t.exposure, msg)
        logger.warning("exposure %.4g ms is infeasible on the AA-STR: %s", t.exposure * 1e3, msg)
