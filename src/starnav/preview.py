"""Preview pictures of rendered frames: 8-bit PNGs a person can look at, labelled with units.

1. Stretch (:func:`radiance_stretch`): linear from 0 to the 99.9th percentile of the lit pixels.
2. Display encoding (:func:`srgb_encode`): the sRGB curve (IEC 61966-2-1), so the screen's
   luminance is proportional to radiance.
3. Layout (:func:`write_radiance_preview`): caption, the frame pixel for pixel, a scale bar in
   W m^-2 sr^-1; 8-bit greyscale PNG written atomically.

:func:`write_previews` puts one next to each EXR (``starnav render --preview``);
:func:`plot_radiance_and_dn` draws the radiance next to the DN frames of the same epoch.

Index
-----
:func:`write_radiance_preview`, :class:`PreviewInfo`, :func:`write_previews`,
:func:`plot_radiance_and_dn`, :func:`radiance_stretch`, :func:`srgb_encode`,
:func:`frame_caption`.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.atomic import atomic_path
from starnav.errors import ConfigError
from starnav.quicklook import to_uint8
from starnav.radiance import RadianceImage, read_exr

log = logging.getLogger(__name__)

#: Percentile of the lit pixels' radiance mapped to white [%] (module step 1).
STRETCH_PERCENTILE = 99.9
#: Report figure: crop around the Moon, margin as a fraction of its size [-], at least [px].
CROP_MARGIN = 0.5
CROP_MIN_PX = 64
#: Caption strip above the frame and scale bar below it [px].
CAPTION_PX = 48
SCALE_BAR_PX = 40
#: The PNG is at least this wide so that the caption fits [px].
MIN_WIDTH_PX = 480
_DPI = 100.0
#: Room right of the scale bar for its unit [px].
_UNIT_PX = 120
_UNIT_TEX = r"W m$^{-2}$ sr$^{-1}$"
_FONT_PT = 8.5
_BG = 0.0


@dataclass(frozen=True)
class PreviewInfo:
    """What :func:`write_radiance_preview` wrote.

    Attributes
    ----------
    path : Path
        The PNG (8-bit greyscale).
    l_top : float
        Radiance shown as white [W m^-2 sr^-1] (0 if no pixel is lit).
    origin : (int, int)
        PNG pixel (row, column) of the frame's pixel (0, 0); the frame is not resampled.
    shape : (int, int)
        PNG size (rows, columns) [px].
    caption : str
    """

    path: Path
    l_top: float
    origin: tuple[int, int]
    shape: tuple[int, int]
    caption: str


def srgb_encode(x: ArrayLike) -> NDArray[np.float64]:
    """sRGB transfer curve (IEC 61966-2-1) of linear values ``x`` in 0..1 (clipped) [-]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def radiance_stretch(L: ArrayLike, percentile: float = STRETCH_PERCENTILE
                     ) -> tuple[NDArray[np.uint8], float]:
    """8-bit display values of a radiance frame (module steps 1-2).

    Parameters
    ----------
    L : (H, W) array
        Band radiance [W m^-2 sr^-1].
    percentile : float
        Percentile of the lit pixels (``L > 0``) shown as white [%], in (0, 100].

    Returns
    -------
    grey : (H, W) uint8
        ``round(255 * srgb_encode(L / l_top))``; all 0 when nothing is lit.
    l_top : float
        The radiance shown as white [W m^-2 sr^-1] (0 when nothing is lit).

    Raises
    ------
    ConfigError
        ``percentile`` outside (0, 100], or non-finite radiance.
    """
    if not 0.0 < percentile <= 100.0:
        raise ConfigError("percentile", percentile, "a percentile in (0, 100]")
    a = np.asarray(L, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ConfigError("L", "NaN/inf pixels", "finite radiance [W m^-2 sr^-1]")
    lit = a[a > 0.0]
    if lit.size == 0:
        return np.zeros(a.shape, np.uint8), 0.0
    top = float(np.percentile(lit, percentile))
    if not top > 0.0:
        top = float(lit.max())
    return to_uint8(srgb_encode(a / top)), top


def frame_caption(meta: Mapping[str, Any], index: int | None = None) -> str:
    """``frame 12 | range 72 345 km | phase 43.2 deg`` from a RadianceImage's ``meta``."""
    g = meta.get("geometry", {}) if meta else {}
    idx = index if index is not None else g.get("index")
    parts = [f"frame {idx}" if idx is not None else "frame ?"]
    rng = g.get("range_m")
    parts.append(f"range {rng / 1e3:,.0f} km".replace(",", " ") if rng is not None
                 else "range ? km")
    ph = g.get("phase_angle_rad")
    parts.append(f"phase {math.degrees(ph):.1f} deg" if ph is not None else "phase ? deg")
    return " | ".join(parts)


def _figure(width_px: int, height_px: int) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / _DPI, height_px / _DPI), dpi=_DPI, facecolor=(_BG,) * 3)
    FigureCanvasAgg(fig)
    return fig


def _grey_png(fig: Any, path: Path) -> None:
    """Render ``fig`` with Agg and write it as an 8-bit greyscale PNG, atomically."""
    import imageio.v3 as iio

    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    grey = rgba[..., :3].astype(np.uint16).sum(axis=2) // 3  # the picture is grey already
    with atomic_path(path, suffix=".png") as tmp:
        iio.imwrite(tmp, grey.astype(np.uint8), extension=".png")


def _ticks(top: float) -> list[float]:
    """Round radiance values for the scale bar, 0..top [W m^-2 sr^-1]."""
    if not top > 0:
        return [0.0]
    step = 10 ** math.floor(math.log10(top / 4))
    for m in (1, 2, 2.5, 5, 10):
        if top / (m * step) <= 5:
            step *= m
            break
    return [k * step for k in range(int(top / step + 1e-9) + 1)]


def write_radiance_preview(img: RadianceImage, path: str | os.PathLike[str], *,
                           percentile: float = STRETCH_PERCENTILE,
                           index: int | None = None) -> PreviewInfo:
    """Write the 8-bit preview PNG of a rendered frame (module steps 1-3).

    Parameters
    ----------
    img : RadianceImage
        The rendered frame (``L`` [W m^-2 sr^-1]; ``meta["geometry"]`` for the caption).
    path : path
        PNG to write (atomically; parent directories are created).
    percentile : float
        Percentile of the lit pixels shown as white [%].
    index : int, optional
        Frame index for the caption (default ``meta["geometry"]["index"]``).
    """
    grey, top = radiance_stretch(img.L, percentile)
    h, w = grey.shape
    W = max(w, MIN_WIDTH_PX)
    H = CAPTION_PX + h + SCALE_BAR_PX
    fig = _figure(W, H)
    # frame pixel for pixel: figimage places an unresampled image at pixel offsets (x from the
    # left, y from the bottom); an RGB uint8 array bypasses the colormap's 256-entry table
    col0 = (W - w) // 2
    fig.figimage(np.repeat(grey[:, :, None], 3, axis=2), xo=col0, yo=SCALE_BAR_PX,
                 origin="upper", resize=False)
    caption = frame_caption(img.meta, index)
    scale = (f"white = {top:.4g} {_UNIT_TEX} = {percentile:g}th percentile of lit pixels "
             "(linear in L, sRGB-encoded)" if top > 0 else "no lit pixel (L = 0 everywhere)")
    fig.text(6 / W, 1 - 6 / H, caption, color="white", fontsize=_FONT_PT + 1, va="top",
             ha="left")
    fig.text(6 / W, 1 - 27 / H, scale, color="white", fontsize=_FONT_PT - 1, va="top",
             ha="left")
    # scale bar: the same encoding as the frame, linear in radiance along the bar
    x0, bar_w, bar_top = 12, W - 12 - _UNIT_PX, SCALE_BAR_PX - 6
    bar = to_uint8(srgb_encode(np.linspace(0.0, 1.0, bar_w)))[None, :].repeat(10, axis=0)
    fig.figimage(np.repeat(bar[:, :, None], 3, axis=2), xo=x0, yo=bar_top - 10,
                 origin="upper", resize=False)
    for t in _ticks(top):
        x = (x0 + (t / top if top > 0 else 0.0) * (bar_w - 1)) / W
        fig.text(x, (bar_top - 12) / H, f"{t:g}", color="white", fontsize=_FONT_PT - 1.5,
                 va="top", ha="center")
    fig.text((x0 + bar_w + 8) / W, (bar_top - 5) / H, f"L [{_UNIT_TEX}]", color="white",
             fontsize=_FONT_PT - 1, va="center", ha="left")
    p = Path(path)
    _grey_png(fig, p)
    log.info("wrote preview %s (white = %.4g W m^-2 sr^-1)", p, top)
    return PreviewInfo(p, top, (CAPTION_PX, col0), (H, W), caption)


def plot_radiance_and_dn(img: RadianceImage, dn_frames: Sequence[tuple[str, ArrayLike, int]],
                         path: str | os.PathLike[str], *, title: str | None = None,
                         percentile: float = STRETCH_PERCENTILE,
                         crop_margin: float | None = CROP_MARGIN) -> Path:
    """One figure: the rendered radiance next to the detector's DN frames of the same epoch.

    Parameters
    ----------
    img : RadianceImage
        The rendered frame; shown with :func:`radiance_stretch`.
    dn_frames : sequence of (label, dn, full_scale)
        DN frames ``(H, W)`` with a label and the ADC full scale [DN]; each shown linear from
        0 to full scale through the same sRGB encoding (saturation white, exposures compare).
    path : path
        PNG to write (atomically).
    title : str, optional
        Figure title (default: :func:`frame_caption`).
    percentile : float
        Stretch of the radiance panel [%].
    crop_margin : float or None
        Show the square around the Moon (pixels with ``L > 0``) widened by this fraction on
        each side, the same crop in every panel; None: the whole frame.
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import FuncNorm

    grey, top = radiance_stretch(img.L, percentile)
    rows, cols = _moon_crop(np.asarray(img.L), crop_margin)
    where = ("" if (rows, cols) == (slice(0, grey.shape[0]), slice(0, grey.shape[1])) else
             f", crop rows {rows.start}-{rows.stop - 1}, columns {cols.start}-{cols.stop - 1}")
    n = 1 + len(dn_frames)
    fig = _figure(int(3.6 * _DPI * n), int(4.3 * _DPI))
    fig.set_facecolor("white")
    fig.set_layout_engine("constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]

    def panel(ax: Any, shown: NDArray[np.uint8], vmax: float, label: str, unit: str) -> None:
        ax.imshow(shown, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        top_ = vmax if vmax > 0 else 1.0
        norm = FuncNorm((lambda v: srgb_encode(np.asarray(v) / top_),
                         lambda s: top_ * _srgb_decode(s)), vmin=0.0, vmax=top_)
        cb = fig.colorbar(ScalarMappable(norm=norm, cmap="gray"), ax=ax, location="bottom",
                          shrink=0.9, pad=0.02)
        cb.set_ticks(_ticks(top_))
        cb.set_label(unit, fontsize=8)
        cb.ax.tick_params(labelsize=7)

    panel(axes[0], grey[rows, cols], top, f"rendered radiance\nwhite = {top:.3g} {_UNIT_TEX} "
          f"({percentile:g}th pct of lit px)", f"band radiance L [{_UNIT_TEX}]")
    for ax, (label, dn, full) in zip(axes[1:], dn_frames, strict=True):
        d = np.asarray(dn, dtype=np.float64)
        sat = int(np.count_nonzero(d >= full))
        panel(ax, to_uint8(srgb_encode(d[rows, cols] / float(full))), float(full),
              f"detector {label}\nmax {int(d.max())} DN, {sat} px at full scale", "[DN]")
    fig.suptitle((title or frame_caption(img.meta)) + where, fontsize=10)
    p = Path(path)
    with atomic_path(p, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=_DPI, metadata={"Software": None})
    return p


def _moon_crop(L: NDArray[Any], margin: float | None) -> tuple[slice, slice]:
    """Rows and columns of the square around the lit pixels, widened by ``margin`` of its size
    on each side and clipped to the frame (the whole frame if nothing is lit or no margin)."""
    h, w = L.shape
    full = (slice(0, h), slice(0, w))
    lit = np.argwhere(L > 0)
    if margin is None or lit.size == 0:
        return full
    (r0, c0), (r1, c1) = lit.min(axis=0), lit.max(axis=0)
    size = max(math.ceil(max(r1 - r0 + 1, c1 - c0 + 1) * (1.0 + 2.0 * margin)), CROP_MIN_PX)
    r_start = round(0.5 * (r0 + r1 + 1 - size))
    c_start = round(0.5 * (c0 + c1 + 1 - size))
    return (slice(max(0, r_start), min(h, r_start + size)),
            slice(max(0, c_start), min(w, c_start + size)))


def _srgb_decode(s: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`srgb_encode` [-]."""
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
    return np.where(s <= 0.04045, s / 12.92, np.power((s + 0.055) / 1.055, 2.4))


def write_previews(exr_paths: Sequence[str | os.PathLike[str]], *,
                   percentile: float = STRETCH_PERCENTILE) -> list[PreviewInfo]:
    """A preview PNG next to each EXR frame (``frame_000012.exr`` -> ``frame_000012.png``),
    each stretched on its own (:func:`write_radiance_preview`).

    Parameters
    ----------
    exr_paths : sequence of path
        Frames written by :func:`starnav.radiance.write_exr`.
    percentile : float
        Percentile of the lit pixels shown as white [%].
    """
    return [write_radiance_preview(read_exr(p), Path(p).with_suffix(".png"),
                                   percentile=percentile) for p in exr_paths]

