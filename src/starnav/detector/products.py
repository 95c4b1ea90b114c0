"""Star-tracker readout products: the data contract between ``detector`` and ``navigation``.

* :class:`Segments` - the *full image compressed* mode: per-row runs of consecutive pixels whose
  DN is at or above a threshold. Run ``k`` covers row ``row[k]``, columns
  ``col_start[k] .. col_start[k] + length[k] - 1``; its DN values are
  ``values[offset[k] : offset[k] + length[k]]``; ``level[k]`` is the index of the highest
  threshold the run was extracted at (0 for the lowest). Pixel coordinates follow the camera
  convention (column = u, row = v, (0, 0) the centre of the top-left pixel).
* :class:`Window` - the *windows* mode: a rectangle of DN values, top-left pixel
  ``(row0, col0)``; up to 16 per readout on the AA-STR.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from starnav.errors import ConfigError

#: Maximum number of windows of the AA-STR windows mode (seed paper).
MAX_WINDOWS = 16


@dataclass(frozen=True)
class Segments:
    """Runs of above-threshold pixels (full image compressed mode). Arrays of equal length."""

    row: NDArray[np.int32]
    col_start: NDArray[np.int32]
    length: NDArray[np.int32]
    offset: NDArray[np.int64]
    values: NDArray[np.uint16]
    level: NDArray[np.int8]
    thresholds: tuple[int, ...] = ()
    shape: tuple[int, int] = (0, 0)
    truncated: bool = False

    def __len__(self) -> int:
        return int(self.row.size)

    @property
    def n_pixels(self) -> int:
        """Number of pixels carried by the runs."""
        return int(self.length.sum())

    def run_values(self, k: int) -> NDArray[np.uint16]:
        o = int(self.offset[k])
        return self.values[o : o + int(self.length[k])]

    def to_image(self, fill: int = 0) -> NDArray[np.uint16]:
        """Rebuild a sparse DN image (pixels outside every run set to ``fill``)."""
        img = np.full(self.shape, fill, dtype=np.uint16)
        for k in range(len(self)):
            c0 = int(self.col_start[k])
            img[int(self.row[k]), c0 : c0 + int(self.length[k])] = self.run_values(k)
        return img

    # ---------------------------------------------------------------- added by detector
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays (for ``numpy.savez``): every field, scalars as 0-d/1-d arrays."""
        return {"row": self.row, "col_start": self.col_start, "length": self.length,
                "offset": self.offset, "values": self.values, "level": self.level,
                "thresholds": np.asarray(self.thresholds, dtype=np.int64),
                "shape": np.asarray(self.shape, dtype=np.int64),
                "truncated": np.asarray(self.truncated)}

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> Segments:
        """Inverse of :meth:`to_arrays` (accepts an ``NpzFile``)."""
        return cls(row=np.asarray(d["row"], np.int32),
                   col_start=np.asarray(d["col_start"], np.int32),
                   length=np.asarray(d["length"], np.int32),
                   offset=np.asarray(d["offset"], np.int64),
                   values=np.asarray(d["values"], np.uint16),
                   level=np.asarray(d["level"], np.int8),
                   thresholds=tuple(int(t) for t in np.asarray(d["thresholds"]).ravel()),
                   shape=tuple(int(t) for t in np.asarray(d["shape"]).ravel()),  # type: ignore[arg-type]
                   truncated=bool(np.asarray(d["truncated"])))

    def pixel_mask(self) -> NDArray[np.bool_]:
        """Pixels carried by the runs, ``shape`` boolean."""
        m = np.zeros(self.shape, dtype=bool)
        for k in range(len(self)):
            c0 = int(self.col_start[k])
            m[int(self.row[k]), c0 : c0 + int(self.length[k])] = True
        return m


@dataclass(frozen=True)
class Window:
    """A rectangle of DN values read out in windows mode."""

    row0: int
    col0: int
    dn: NDArray[np.uint16] = field(repr=False)

    def __post_init__(self) -> None:
        if self.dn.ndim != 2 or self.row0 < 0 or self.col0 < 0:
            raise ConfigError("window", (self.row0, self.col0, self.dn.shape),
                              "a non-negative corner and a 2-D DN array")

    @property
    def height(self) -> int:
        return int(self.dn.shape[0])

    @property
    def width(self) -> int:
        return int(self.dn.shape[1])

    # ---------------------------------------------------------------- added by detector
    @property
    def slices(self) -> tuple[slice, slice]:
        """``(rows, cols)`` slices of the window in the full frame."""
        return (slice(self.row0, self.row0 + self.height),
                slice(self.col0, self.col0 + self.width))
