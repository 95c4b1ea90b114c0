"""Acquisition of the fly-by front end: the lit body in the segments, and where to open windows.

The fly-by front end (seed paper, algorithm 3) sees the asteroid only through the AA-STR's two
products, segments and up to 16 windows of DN; this module is the gate that enforces it. Each
step in full: docs/methods.md, "starnav.navigation.trn.windows".

Technique
---------
1. Window reader (:class:`WindowReader`): the only way a frame reaches the front end; it
   records every pixel handed out, and a crop outside the windows raises
   :class:`WindowAccessError`.
2. Segments analysis (:func:`analyse_segments`): the lit body's components, its area centroid
   and apparent radius, the clearance from the limb/terminator, a Shi-Tomasi texture score.
3. Window plan (:func:`plan_windows`): one window per group of live tracks at their predicted
   positions, then birth windows on the best texture away from the edge, up to ``n_windows``.
4. Readout law: the windows' pixel count enters :func:`starnav.detector.readout.readout_timing`.

Index
-----
:class:`WindowReader`, :class:`WindowAccessError`, :func:`analyse_segments`, :class:`BodyFix`,
:func:`plan_windows`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from starnav.detector.products import MAX_WINDOWS, Segments, Window
from starnav.errors import ConfigError, StarnavError
from starnav.typing import FloatArray

WindowRect = tuple[int, int, int, int]


#: Smallest lit component kept as part of the body, as a fraction of the largest.
MIN_PART = 0.02


class WindowAccessError(StarnavError, IndexError):
    """A front-end stage asked for pixels that were not read (outside the windows and the
    segments of the frame)."""


# =========================================================================== step 1
class WindowReader:
    """The frame as the tracker reads it: a segments product and up to 16 windows.

    Parameters
    ----------
    segments : Segments or None
        Full-image compressed readout of the frame (None: none read).
    windows : sequence of Window
        Windows read this frame.

    Every pixel handed out is recorded in :attr:`touched` (a boolean map of the array, for
    the windows-only proof); the reader never holds the full DN frame.
    """

    def __init__(self, segments: Segments | None, windows: Sequence[Window] = ()) -> None:
        if len(windows) > MAX_WINDOWS:
            raise ConfigError("windows", f"{len(windows)} windows",
                              f"at most {MAX_WINDOWS} (AA-STR windows mode)")
        self._segments = segments
        self._windows = tuple(windows)
        self.shape: tuple[int, int] = tuple(segments.shape) if segments is not None else (0, 0)  # type: ignore[assignment]
        self.touched = np.zeros(self.shape, bool) if segments is not None else None
        self._seg_image: NDArray[np.float32] | None = None

    @classmethod
    def from_exposures(cls, segments_exposure: Any, windows_exposure: Any | None = None
                       ) -> WindowReader:
        """A reader of the *readout products* of two :class:`~starnav.detector.Exposure`
        (their ``segments`` and ``windows``; the full ``dn`` is never kept)."""
        wins = () if windows_exposure is None else tuple(windows_exposure.windows)
        return cls(segments_exposure.segments, wins)

    def with_windows(self, windows: Sequence[Window]) -> WindowReader:
        """The same segments with the windows of the second acquisition."""
        r = WindowReader(self._segments, windows)
        r.touched = self.touched
        r._seg_image = self._seg_image
        return r

    @property
    def segments(self) -> Segments | None:
        return self._segments

    @property
    def windows(self) -> tuple[WindowRect, ...]:
        """``(row0, col0, height, width)`` of every window read."""
        return tuple((w.row0, w.col0, w.height, w.width) for w in self._windows)

    def segments_image(self) -> NDArray[np.float32]:
        """The segments' DN as a float32 image, 0 where no run was read."""
        if self._segments is None:
            raise WindowAccessError("no segments readout in this frame")
        if self._seg_image is None:
            self._seg_image = self._segments.to_image(fill=0).astype(np.float32)
            assert self.touched is not None
            self.touched |= self._segments.pixel_mask()
        return self._seg_image

    def crop(self, row0: int, col0: int, height: int, width: int) -> NDArray[np.uint16]:
        """DN of a rectangle that lies inside one window read this frame (a copy).

        Raises
        ------
        WindowAccessError
            The rectangle is not inside any window of the frame.
        """
        for w in self._windows:
            if (w.row0 <= row0 and w.col0 <= col0 and row0 + height <= w.row0 + w.height
                    and col0 + width <= w.col0 + w.width):
                r, c = row0 - w.row0, col0 - w.col0
                if self.touched is not None:
                    self.touched[row0:row0 + height, col0:col0 + width] = True
                return np.array(w.dn[r:r + height, c:c + width], dtype=np.uint16)
        raise WindowAccessError(
            f"pixels rows {row0}..{row0 + height - 1}, columns {col0}..{col0 + width - 1} "
            f"were not read: windows read are {list(self.windows)}")

    def window_pixels(self) -> int:
        """Pixels in the windows read (the windows readout's ``N_pix``)."""
        return int(sum(w.height * w.width for w in self._windows))


# =========================================================================== step 2
@dataclass(frozen=True)
class BodyFix:
    """The lit body in one segments read.

    Attributes
    ----------
    centroid_uv : (2,) array
        Area centroid of the lit silhouette ``(u, v)`` [px].
    radius_px : float
        Equivalent radius ``sqrt(area / pi)`` [px].
    area_px : int
    clearance : (H, W) float32
        Distance of each lit pixel to the edge of the lit mask (limb or terminator) [px],
        0 off the body.
    texture : (H, W) float32
        Shi-Tomasi minimum eigenvalue of the segments image [DN^2], 0 off the body.
    dn_range : (float, float)
        1st and 99.9th percentile of the body's DN (the 8-bit scaling of the tracker).
    """

    centroid_uv: FloatArray
    radius_px: float
    area_px: int
    clearance: NDArray[np.float32] = field(repr=False)
    texture: NDArray[np.float32] = field(repr=False)
    dn_range: tuple[float, float] = (0.0, 1.0)


def analyse_segments(reader: WindowReader, *, block_px: int = 7, min_area_px: int = 50
                     ) -> BodyFix | None:
    """The lit body in the segments (module step 2); None when no component reaches
    ``min_area_px`` pixels (no lit body in the field)."""
    img = reader.segments_image()
    mask = (img > 0).astype(np.uint8)
    if int(mask.sum()) < min_area_px:
        return None
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    if int(areas.max()) < min_area_px:
        return None
    # the body: every component of at least MIN_PART of the largest (a shadowed neck or a
    # terminator can cut the lit part in pieces; isolated hot pixels stay out)
    keep = np.flatnonzero(areas >= MIN_PART * areas.max()) + 1
    body = np.isin(labels, keep).astype(np.uint8)
    area = int(body.sum())
    m = cv2.moments(body, binaryImage=True)
    centroid = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    # distance to the nearest pixel off the lit mask; the array's border counts as an edge
    padded = cv2.copyMakeBorder(body, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    clearance = cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]
    texture = cv2.cornerMinEigenVal(np.where(body > 0, img, 0).astype(np.float32), block_px)
    texture[body == 0] = 0.0
    vals = img[body > 0]
    lo, hi = (float(x) for x in np.percentile(vals, [1.0, 99.9]))
    return BodyFix(centroid_uv=centroid, radius_px=math.sqrt(area / math.pi), area_px=area,
                   clearance=clearance.astype(np.float32), texture=texture.astype(np.float32),
                   dn_range=(lo, max(hi, lo + 1.0)))


# =========================================================================== step 3
def _clamp_rect(r0: float, c0: float, r1: float, c1: float, shape: tuple[int, int],
                max_side: int) -> WindowRect | None:
    """Integer window covering rows r0..r1, columns c0..c1 (inclusive, float), at most
    ``max_side`` a side (centred cut), shifted inside the array."""
    H, W = shape
    rows = (math.floor(r0), math.ceil(r1))
    cols = (math.floor(c0), math.ceil(c1))
    out = []
    for (a, b), n in ((rows, H), (cols, W)):
        side = min(b - a + 1, max_side, n)
        mid = (a + b) / 2.0
        start = int(round(mid - (side - 1) / 2.0))
        start = min(max(start, 0), n - side)
        out.append((start, side))
    (row0, h), (col0, w) = out
    if h < 1 or w < 1:
        return None
    return (row0, col0, h, w)


def _overlaps(a: WindowRect, b: WindowRect, gap: int = 0) -> bool:
    return not (a[0] + a[2] + gap <= b[0] or b[0] + b[2] + gap <= a[0]
                or a[1] + a[3] + gap <= b[1] or b[1] + b[3] + gap <= a[1])


def plan_windows(body: BodyFix, groups: Sequence[FloatArray], *, n_windows: int, core_px: int,
                 patch_half_px: int, limb_margin_px: float, max_window_px: int,
                 min_texture_fraction: float = 0.02) -> list[WindowRect]:
    """Windows of one frame (module step 3).

    Parameters
    ----------
    body : BodyFix
        This frame's segments analysis.
    groups : sequence of (n, 2) arrays
        Predicted ``(u, v)`` [px] of the live tracks, one array per window of the previous
        frame; each gets a window covering them plus ``patch_half_px`` (the first windows of
        the list, in the order of ``groups``; empty groups are skipped).
    n_windows : int
        Windows to open (<= 16).
    core_px, patch_half_px, limb_margin_px, max_window_px
        Geometry of the windows [px] (their meanings:
        :class:`~starnav.navigation.trn.options.TrnFrontEndConfig`).
    min_texture_fraction : float
        A birth window needs a texture score of at least this fraction of the frame's best.

    Returns
    -------
    list of (row0, col0, height, width)
    """
    if not 1 <= n_windows <= MAX_WINDOWS:
        raise ConfigError("n_windows", n_windows, f"1..{MAX_WINDOWS} (AA-STR windows mode)")
    shape = body.clearance.shape
    rects: list[WindowRect] = []
    for g in groups:
        if len(g) == 0 or len(rects) >= n_windows:
            continue
        g = np.asarray(g, float)
        r = _clamp_rect(g[:, 1].min() - patch_half_px, g[:, 0].min() - patch_half_px,
                        g[:, 1].max() + patch_half_px, g[:, 0].max() + patch_half_px,
                        shape, max_window_px)
        if r is not None:
            rects.append(r)
    # birth windows on the best texture with room for the core away from limb and terminator
    side = core_px + 2 * patch_half_px
    score = np.where(body.clearance >= limb_margin_px + core_px / 2.0, body.texture, 0.0)
    floor = min_texture_fraction * float(
        cv2.boxFilter(body.texture, -1, (core_px, core_px)).max())
    blocked = np.zeros(shape, bool)
    for r in rects:
        blocked[max(r[0] - side // 2, 0):r[0] + r[2] + side // 2,
                max(r[1] - side // 2, 0):r[1] + r[3] + side // 2] = True
    score = np.where(blocked, 0.0, score)
    # a window's texture: the score smoothed over its core (a lone noise peak is no texture)
    score = cv2.boxFilter(score.astype(np.float32), -1, (core_px, core_px))
    while len(rects) < n_windows:
        k = int(np.argmax(score))
        v, u = divmod(k, shape[1])
        if score[v, u] <= floor or score[v, u] <= 0:
            break
        r = _clamp_rect(v - (side - 1) / 2.0, u - (side - 1) / 2.0, v + (side - 1) / 2.0,
                        u + (side - 1) / 2.0, shape, side)
        score[max(v - side, 0):v + side + 1, max(u - side, 0):u + side + 1] = 0.0
        if r is None or any(_overlaps(r, q) for q in rects):
            continue
        rects.append(r)
    return rects
