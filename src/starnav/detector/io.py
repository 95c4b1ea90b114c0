"""Files of an exposed frame: DN PNG (16 bit), segments and windows (NPZ), summary (JSON).

All files are written to a temporary name and renamed (never half-written) and are readable
without starnav: ``imageio.v3.imread`` for the PNG, ``numpy.load`` for the NPZ, ``json`` for
the summary.

========================= ================================================================
file                      content
========================= ================================================================
``<prefix>dn.png``        full DN frame, uint16 PNG (values 0 .. 2^bits - 1)
``<prefix>segments.npz``  :meth:`Segments.to_arrays` (row, col_start, length, offset,
                          values, level, thresholds, shape, truncated)
``<prefix>windows.npz``   ``corners`` (n, 2) int (row0, col0) and ``dn_<k>`` per window
``<prefix>readout.json``  :meth:`Exposure.summary`: exposure, gain, seeds, charge ledger,
                          readout timing and feasibility, segment / window counts
========================= ================================================================
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image

from starnav.atomic import atomic_path
from starnav.detector.products import Segments, Window
from starnav.errors import DataFileError

#: zlib level of the DN PNGs (and of the quick looks, :mod:`starnav.quicklook`): a DN frame is
#: mostly read and shot noise, which zlib hardly compresses at any level: 1 writes it 5x faster
#: than Pillow's default 6 (0.11 vs 0.6 s for a 1024 x 1024 frame) for 7 % more bytes
#: (issue 18, docs/performance.md). The pixels are the same at every level.
PNG_COMPRESS_LEVEL = 1

if TYPE_CHECKING:
    from starnav.detector.chain import Exposure


def _atomic(path: Path, write: Any, suffix: str) -> Path:
    """Call ``write(tmp)`` on a temporary name and rename it to ``path``."""
    with atomic_path(path, suffix=suffix) as tmp:
        write(str(tmp))
    return path


def write_dn_png(dn: NDArray[np.uint16], path: str | os.PathLike[str]) -> Path:
    """Write a DN frame as a 16-bit grey PNG (zlib level :data:`PNG_COMPRESS_LEVEL`),
    atomically."""
    img = Image.fromarray(np.ascontiguousarray(dn, dtype=np.uint16))
    return _atomic(Path(path), lambda tmp: img.save(tmp, format="PNG",
                                                    compress_level=PNG_COMPRESS_LEVEL), ".png")


def read_dn_png(path: str | os.PathLike[str]) -> NDArray[np.uint16]:
    """Read a DN frame written by :func:`write_dn_png`."""
    import imageio.v3 as iio

    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"DN image {str(p)!r} does not exist")
    return np.asarray(iio.imread(p), dtype=np.uint16)


def write_segments(seg: Segments, path: str | os.PathLike[str]) -> Path:
    """Write segments as NPZ, atomically."""
    return _atomic(Path(path), lambda tmp: np.savez_compressed(tmp, **seg.to_arrays()), ".npz")


def read_segments(path: str | os.PathLike[str]) -> Segments:
    """Read segments written by :func:`write_segments`."""
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"segments file {str(p)!r} does not exist")
    with np.load(p) as d:
        return Segments.from_arrays(dict(d))


def write_windows(windows: tuple[Window, ...], path: str | os.PathLike[str]) -> Path:
    """Write windows as NPZ (``corners`` and ``dn_<k>``), atomically."""
    arrays: dict[str, NDArray[Any]] = {
        "corners": np.array([[w.row0, w.col0] for w in windows], dtype=np.int64).reshape(-1, 2)}
    for k, w in enumerate(windows):
        arrays[f"dn_{k}"] = w.dn
    return _atomic(Path(path), lambda tmp: np.savez_compressed(tmp, **arrays), ".npz")


def read_windows(path: str | os.PathLike[str]) -> tuple[Window, ...]:
    """Read windows written by :func:`write_windows`."""
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"windows file {str(p)!r} does not exist")
    with np.load(p) as d:
        corners = d["corners"]
        return tuple(Window(int(r), int(c), np.asarray(d[f"dn_{k}"], np.uint16))
                     for k, (r, c) in enumerate(corners))


def write_exposure(frame: Exposure, directory: str | os.PathLike[str],
                   prefix: str = "") -> dict[str, Path]:
    """Write the DN PNG, the readout products and the summary of ``frame`` into ``directory``.

    Returns
    -------
    dict
        Written paths by kind (``dn``, ``segments``, ``windows``, ``summary``).
    """
    d = Path(directory)
    out = {"dn": write_dn_png(frame.dn, d / f"{prefix}dn.png")}
    if frame.segments is not None:
        out["segments"] = write_segments(frame.segments, d / f"{prefix}segments.npz")
    if frame.windows:
        out["windows"] = write_windows(frame.windows, d / f"{prefix}windows.npz")
    text = json.dumps(frame.summary(), indent=2, sort_keys=True)
    out["summary"] = _atomic(d / f"{prefix}readout.json",
                             lambda tmp: Path(tmp).write_text(text), ".json")
    return out
