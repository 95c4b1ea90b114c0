"""Quick looks: 8-bit PNGs of a frame, its own shape, stretched and annotated for a person.

Next to each data image (16-bit DN PNG, float EXR radiance) a picture is written:

1. Levels (:func:`quicklook_levels`): black the sky (the DN median, 0 for radiance), white the
   :data:`QUICKLOOK_WHITE_PERCENTILE` of the pixels :data:`QUICKLOOK_SKY_SIGMAS` above it.
2. Stretch (:func:`asinh_stretch`): linear near the sky, logarithmic over the disc (softening
   :data:`QUICKLOOK_SOFTENING`).
3. Annotation (:func:`write_quicklook`): PNG text chunks (:data:`QUICKLOOK_KEYS`), a burnt-in
   caption and scale bar; deterministic bytes, written atomically.

References
----------
R. Lupton, J. E. Gunn and A. Szalay, AJ 118 (1999) 1406 (asinh magnitudes).

Index
-----
:func:`write_quicklook`, :func:`write_dn_quicklook`, :func:`write_radiance_quicklook`,
:class:`QuickLookInfo`, :func:`quicklook_levels`, :func:`asinh_stretch`,
:func:`quicklook_caption`, :func:`to_uint8`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from PIL import Image, ImageDraw, ImageFont

from starnav.detector.io import write_png
from starnav.errors import ConfigError
from starnav.radiance import RadianceImage


def to_uint8(v: ArrayLike) -> NDArray[np.uint8]:
    """0..1 floats to 0..255 (rounded, clipped)."""
    return np.round(np.clip(np.asarray(v, float), 0.0, 1.0) * 255.0).astype(np.uint8)


#: Softening of the quick-look asinh stretch, as a fraction of the white level [-]: values
#: well below it are shown linearly, values above it logarithmically (see :func:`asinh_stretch`).
QUICKLOOK_SOFTENING = 0.05
#: Percentile of the pixels above the black level shown as white [%].
QUICKLOOK_WHITE_PERCENTILE = 99.5
#: A pixel is "above the sky" when it exceeds the black level by this many sky sigmas [-].
QUICKLOOK_SKY_SIGMAS = 5.0
#: PNG text-chunk keys of a quick look (read them with Pillow's ``Image.open(p).text``).
QUICKLOOK_KEYS = ("Title", "Description", "starnav:stretch", "starnav:black", "starnav:white",
                  "starnav:unit")
#: Caption band drawn over the top-left of the frame and scale bar over the bottom-left [px].
QUICKLOOK_CAPTION_PX = 12
QUICKLOOK_BAR_PX = 6


@dataclass(frozen=True)
class QuickLookInfo:
    """What :func:`write_quicklook` wrote.

    Attributes
    ----------
    path : Path
        The 8-bit greyscale PNG, the frame's shape.
    black, white : float
        Values shown as 0 and 255, in ``unit``.
    unit : str
        ``"DN"`` or ``"W m^-2 sr^-1"``.
    caption : str
        The annotation (also in the PNG's ``Description`` text chunk).
    """

    path: Path
    black: float
    white: float
    unit: str
    caption: str


def asinh_stretch(values: ArrayLike, black: float, white: float,
                  softening: float = QUICKLOOK_SOFTENING) -> NDArray[np.uint8]:
    """8-bit asinh stretch: ``255 asinh(x / s) / asinh(1 / s)``, ``x = (v - black) / (white -
    black)`` clipped to 0..1, ``s`` the softening.

    A Moon frame is mostly black sky with a disc spanning three decades: asinh is linear below
    ``s`` (the sky and its noise stay dark) and logarithmic above, so terminator and limb are
    both visible and the saturated core is white (Lupton, Gunn & Szalay 1999). Evaluated once
    per distinct value of an integer frame (a look-up table) and only above ``black`` for a
    float frame: the same numbers as on every pixel.

    Parameters
    ----------
    values : array
        Frame [DN or W m^-2 sr^-1].
    black, white : float
        Values shown as 0 and 255 (``white > black``).
    softening : float
        ``s`` in (0, 1].
    """
    if not white > black:
        white = black + 1.0
    a = np.asarray(values)
    if _small_unsigned(a):
        table = _stretch(np.arange(int(a.max()) + 1 if a.size else 1, dtype=np.float64),
                         black, white, softening)
        return table[a]
    if a.dtype.kind == "f" and a.size > _STRETCH_MASKED_MIN:
        # x <= 0 is 0 (asinh(0) = 0); compared in float64 as the formula does; NaN pixels go
        # through the formula
        above = np.greater(a, np.float64(black))
        above |= np.isnan(a)
        out = np.zeros(a.shape, np.uint8)
        out[above] = _stretch(a[above].astype(np.float64), black, white, softening)
        return out
    return _stretch(np.asarray(a, np.float64), black, white, softening)


#: Above this many pixels a float frame is stretched only where it exceeds black.
_STRETCH_MASKED_MIN = 4096


def _stretch(v: NDArray[np.float64], black: float, white: float,
             softening: float) -> NDArray[np.uint8]:
    """The formula of :func:`asinh_stretch` on every element (``white > black``)."""
    x = np.clip((v - black) / (white - black), 0.0, 1.0)
    return to_uint8(np.arcsinh(x / softening) / np.arcsinh(1.0 / softening))


def _small_unsigned(a: NDArray) -> bool:
    """An unsigned integer frame of at most 16 bits (a table of its values is small)."""
    return a.dtype.kind == "u" and a.dtype.itemsize <= 2


def _order_stats_from_counts(counts: NDArray[np.int64], values: NDArray[np.float64],
                             ks: tuple[int, ...]) -> list[float]:
    """Order statistics ``ks`` (0-based) of a sample given as ``counts[i]`` copies of
    ``values[i]`` (``values`` ascending)."""
    cum = np.cumsum(counts)
    return [float(values[int(np.searchsorted(cum, k, side="right"))]) for k in ks]


def _median_of_counts(counts: NDArray[np.int64], values: NDArray[np.float64]) -> float:
    """``np.median`` of the sample ``counts`` x ``values`` (``values`` ascending): the middle
    element, or the mean of the two middle ones, computed as NumPy does (``(a + b) / 2``)."""
    n = int(counts.sum())
    if n % 2:
        return _order_stats_from_counts(counts, values, (n // 2,))[0]
    lo, hi = _order_stats_from_counts(counts, values, (n // 2 - 1, n // 2))
    return (lo + hi) / 2.0


def _sky_levels(a: NDArray, black: float | None) -> tuple[float, float]:
    """Black level and sky MAD of :func:`quicklook_levels` (the numbers of ``np.median`` on the
    whole frame), from a histogram for a 16-bit frame and from the zero count for a frame that
    is zero over more than half its pixels with black 0 (a radiance frame)."""
    if _small_unsigned(a):
        counts = np.bincount(a.ravel())
        levels = np.arange(counts.size, dtype=np.float64)
        b = _median_of_counts(counts, levels) if black is None else float(black)
        dist = np.abs(levels - b)
        order = np.argsort(dist, kind="stable")
        return b, _median_of_counts(counts[order], dist[order])
    if black is not None and float(black) == 0.0 and a.size - np.count_nonzero(a) > a.size // 2:
        return float(black), 0.0  # both middle elements of |a - 0| are 0
    f = np.asarray(a, np.float64)
    b = float(np.median(f)) if black is None else float(black)
    return b, float(np.median(np.abs(f - b)))


def quicklook_levels(values: ArrayLike, *, black: float | None = None
                     ) -> tuple[float, float]:
    """Black and white levels of a quick look.

    ``black`` (default: the frame's median, i.e. the sky, which covers most of a Moon frame;
    0 for radiance) is shown black; ``white`` is the 99.5th percentile of the pixels more than
    5 sky sigmas (sigma from the median absolute deviation, at least 1 unit of the last digit
    for DN) above ``black``. A percentile over *all* pixels would land on the sky when the
    Moon covers under 0.5 % of the frame.

    The medians of a 16-bit frame come from its histogram, and the MAD of a radiance frame
    that is black (0) over most of the field is 0 without sorting: the same numbers as
    ``np.median`` on the whole frame, ~1 ms instead of ~20 ms for 1024 x 1024 pixels.
    """
    a = np.asarray(values)
    if not (_small_unsigned(a) or a.dtype.kind == "f"):
        a = a.astype(np.float64)
    if a.size == 0 or (a.dtype.kind == "f" and not np.all(np.isfinite(a))):
        raise ConfigError("quick look", "empty frame or NaN/inf pixels", "finite pixel values")
    b, mad = _sky_levels(a, black)
    sigma = 1.4826 * mad
    # compared in float64 (a float32 frame too), as on the frame converted to float64
    above = a[np.greater(a, np.float64(b + max(QUICKLOOK_SKY_SIGMAS * sigma, 0.0)))]
    above = above.astype(np.float64)
    if above.size == 0:
        return b, b + 1.0
    w = float(np.percentile(above, QUICKLOOK_WHITE_PERCENTILE))
    return b, (w if w > b else float(above.max()))


def write_quicklook(values: ArrayLike, path: str | os.PathLike[str], caption: str, *,
                    unit: str, black: float | None = None) -> QuickLookInfo:
    """Write the 8-bit quick-look PNG of a frame, the frame's own shape.

    :func:`quicklook_levels` picks black and white, :func:`asinh_stretch` maps them to
    0..255. The annotation is in PNG text chunks (``Title``, ``Description``, the
    ``starnav:*`` keys of :data:`QUICKLOOK_KEYS`) and burnt in: a caption band top left and a
    labelled scale bar bottom left. Deterministic bytes, written atomically.

    Parameters
    ----------
    values : (H, W) array
        The frame [``unit``].
    path : path
        PNG to write (parents created).
    caption : str
        What the frame is: index, exposure with its unit, range, phase.
    unit : str
        Unit of ``values`` (``"DN"``, ``"W m^-2 sr^-1"``).
    black : float, optional
        Black level (default: the frame's median; pass 0 for radiance).
    """
    a = np.asarray(values)
    if a.ndim != 2:
        raise ConfigError("quick look", a.shape, "a 2-D frame")
    lo, hi = quicklook_levels(a, black=black)
    grey = asinh_stretch(a, lo, hi)
    stretch = (f"asinh stretch (softening {QUICKLOOK_SOFTENING:g}): black = {lo:.4g} {unit}, "
               f"white = {hi:.4g} {unit} ({QUICKLOOK_WHITE_PERCENTILE:g}th percentile of the "
               f"pixels {QUICKLOOK_SKY_SIGMAS:g} sigma above black)")
    img = Image.fromarray(grey, mode="L")
    h, w = grey.shape
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    if h >= 4 * QUICKLOOK_CAPTION_PX and w >= 64:
        text = f"{caption} | {lo:.4g}..{hi:.4g} {unit} asinh"
        box = draw.textbbox((2, 1), text, font=font)
        draw.rectangle((0, 0, min(box[2] + 2, w - 1), QUICKLOOK_CAPTION_PX - 1), fill=0)
        draw.text((2, 1), text, fill=255, font=font)
        bar_w = min(w // 3, 256)
        y0 = h - QUICKLOOK_BAR_PX - QUICKLOOK_CAPTION_PX
        draw.rectangle((0, y0, bar_w + 80, h - 1), fill=0)
        ramp = asinh_stretch(np.linspace(lo, hi, bar_w), lo, hi)
        img.paste(Image.fromarray(np.repeat(ramp[None, :], QUICKLOOK_BAR_PX, axis=0), "L"),
                  (2, h - QUICKLOOK_BAR_PX - 1))
        draw.text((2, y0 + 1), f"{lo:.4g}", fill=255, font=font)
        draw.text((bar_w + 4, h - QUICKLOOK_BAR_PX - 4), f"{hi:.4g} {unit}", fill=255,
                  font=font)
    text = [("Title", caption), ("Description", f"{caption}; {stretch}"),
            ("starnav:stretch", f"asinh softening={QUICKLOOK_SOFTENING:g}"),
            ("starnav:black", repr(lo)), ("starnav:white", repr(hi)), ("starnav:unit", unit)]
    p = Path(path)
    write_png(np.asarray(img), p, text)
    return QuickLookInfo(p, lo, hi, unit, caption)


def quicklook_caption(index: int | None, *, exposure_time: float | None = None,
                      range_m: float | None = None, phase_angle_rad: float | None = None
                      ) -> str:
    """``frame 12 | exp 0.015 ms | range 72 345 km | phase 43.2 deg`` (``?`` where unknown;
    the exposure is omitted for a rendered radiance frame)."""
    parts = [f"frame {index}" if index is not None else "frame ?"]
    if exposure_time is not None:
        parts.append(f"exp {exposure_time * 1e3:.4g} ms")
    parts.append(f"range {range_m / 1e3:,.0f} km".replace(",", " ") if range_m is not None
                 else "range ? km")
    parts.append(f"phase {math.degrees(phase_angle_rad):.1f} deg"
                 if phase_angle_rad is not None else "phase ? deg")
    return " | ".join(parts)


def write_radiance_quicklook(img: RadianceImage, path: str | os.PathLike[str],
                             index: int | None = None) -> QuickLookInfo:
    """Quick look of a rendered frame (band radiance ``L``, black = 0)."""
    g = img.meta.get("geometry", {}) if img.meta else {}
    cap = quicklook_caption(g.get("index") if index is None else index,
                            range_m=g.get("range_m"), phase_angle_rad=g.get("phase_angle_rad"))
    return write_quicklook(img.L, path, cap + " | band radiance", unit="W m^-2 sr^-1",
                           black=0.0)


def write_dn_quicklook(dn: ArrayLike, path: str | os.PathLike[str], *, index: int,
                       exposure_time: float, range_m: float | None = None,
                       phase_angle_rad: float | None = None) -> QuickLookInfo:
    """Quick look of a DN frame [DN] (black = the frame's median, the sky and the offset)."""
    cap = quicklook_caption(index, exposure_time=exposure_time, range_m=range_m,
                            phase_angle_rad=phase_angle_rad)
    return write_quicklook(dn, path, cap + " | detector DN", unit="DN")
