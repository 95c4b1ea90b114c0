"""Files of an exposed frame: DN PNG (16 bit), segments and windows (NPZ), summary (JSON).

Written atomically, readable without starnav (``imageio.v3.imread``, ``numpy.load``, ``json``):

========================= ================================================================
file                      content
========================= ================================================================
``<prefix>dn.png``        full DN frame, uint16 PNG (values 0 .. 2^bits - 1)
``<prefix>segments.npz``  :meth:`Segments.to_arrays`
``<prefix>windows.npz``   ``corners`` (n, 2) int (row0, col0) and ``dn_<k>`` per window
``<prefix>readout.json``  :meth:`Exposure.summary`
========================= ================================================================

PNG encoding (:func:`png_bytes`): greyscale 8 or 16 bit, filter 0, one zlib stream at
:data:`PNG_COMPRESS_LEVEL` with a strategy chosen for the content (Huffman only for noisy
frames, run-length for mostly flat ones), optional ``tEXt`` chunks, no time stamp:
deterministic bytes for one zlib build (ISO/IEC 15948).

Index
-----
:func:`write_exposure`, :func:`png_bytes`, :func:`write_png`, :func:`write_dn_png`,
:func:`read_dn_png`, :func:`write_segments`, :func:`read_segments`, :func:`write_windows`,
:func:`read_windows`.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path, atomic_write_bytes
from starnav.detector.products import Segments, Window
from starnav.errors import ConfigError, not_a_file_error

#: zlib level of the PNGs written here and by :mod:`starnav.quicklook`. With the run-length
#: strategy (:data:`PNG_ZLIB_STRATEGY`) zlib's levels 1-9 give the same stream; 0 would store
#: the frame uncompressed. The pixels are the same at every level.
PNG_COMPRESS_LEVEL = 1
#: zlib strategies of the PNGs (module essay, "PNG encoding"): run-length matches for an image
#: whose neighbouring samples are mostly equal (a black sky), Huffman coding alone otherwise
#: (a noisy frame: no match is worth looking for).
PNG_ZLIB_STRATEGY_RUNS = zlib.Z_RLE
PNG_ZLIB_STRATEGY_NOISE = zlib.Z_HUFFMAN_ONLY

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

if TYPE_CHECKING:
    from starnav.detector.chain import Exposure


def _atomic(path: Path, write: Any, suffix: str) -> Path:
    """Call ``write(tmp)`` on a temporary name and rename it to ``path``."""
    with atomic_path(path, suffix=suffix) as tmp:
        write(str(tmp))
    return path


def _chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type and data."""
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)) & 0xFFFFFFFF))


def _text_chunk(key: str, value: str) -> bytes:
    """``tEXt`` (Latin-1 key and value) or, for other characters, an uncompressed ``iTXt``."""
    k = key.encode("latin-1")
    if not 1 <= len(k) <= 79:
        raise ConfigError("PNG text key", key, "1 to 79 Latin-1 characters")
    try:
        return _chunk(b"tEXt", k + b"\0" + value.encode("latin-1"))
    except UnicodeEncodeError:
        return _chunk(b"iTXt", k + b"\0\0\0\0\0" + value.encode("utf-8"))


def png_bytes(image: NDArray[Any], text: Iterable[tuple[str, str]] = ()) -> bytes:
    """Encode a greyscale image as PNG (module essay, "PNG encoding").

    Parameters
    ----------
    image : (H, W) uint8 or uint16 array
        Pixel values (8 or 16 bit grey).
    text : iterable of (key, value)
        Text chunks, in order (``tEXt``; ``iTXt`` for characters outside Latin-1).

    Returns
    -------
    bytes
        The PNG file: signature, ``IHDR``, the text chunks, one ``IDAT``, ``IEND``.
    """
    a = np.asarray(image)
    if a.ndim != 2 or a.dtype not in (np.uint8, np.uint16) or 0 in a.shape:
        raise ConfigError("PNG image", f"{a.dtype} {a.shape}",
                          "a non-empty 2-D uint8 or uint16 array")
    h, w = a.shape
    depth = 8 * a.dtype.itemsize
    rows = np.empty((h, 1 + w * a.dtype.itemsize), np.uint8)
    rows[:, 0] = 0  # filter type 0 (none) on every row
    rows[:, 1:].view(">u2" if depth == 16 else np.uint8)[...] = a  # PNG: big-endian samples
    flat = a.ravel()
    runs = flat.size > 1 and np.count_nonzero(flat[1:] != flat[:-1]) < flat.size // 2
    z = zlib.compressobj(PNG_COMPRESS_LEVEL, zlib.DEFLATED, zlib.MAX_WBITS, 9,
                         PNG_ZLIB_STRATEGY_RUNS if runs else PNG_ZLIB_STRATEGY_NOISE)
    idat = z.compress(rows.data) + z.flush()
    head = struct.pack(">IIBBBBB", w, h, depth, 0, 0, 0, 0)  # grey, deflate, no interlace
    return b"".join([_PNG_SIGNATURE, _chunk(b"IHDR", head),
                     *(_text_chunk(k, v) for k, v in text),
                     _chunk(b"IDAT", idat), _chunk(b"IEND", b"")])


def write_png(image: NDArray[Any], path: str | os.PathLike[str],
              text: Iterable[tuple[str, str]] = ()) -> Path:
    """Write :func:`png_bytes` of ``image`` (with ``text`` chunks) to ``path`` atomically."""
    return atomic_write_bytes(path, png_bytes(image, text))


def write_dn_png(dn: NDArray[np.uint16], path: str | os.PathLike[str]) -> Path:
    """Write a DN frame as a 16-bit grey PNG (:func:`png_bytes`), atomically."""
    return write_png(np.ascontiguousarray(dn, dtype=np.uint16), path)


def read_dn_png(path: str | os.PathLike[str]) -> NDArray[np.uint16]:
    """Read a DN frame written by :func:`write_dn_png`."""
    import imageio.v3 as iio

    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, "DN image")
    return np.asarray(iio.imread(p), dtype=np.uint16)


def write_segments(seg: Segments, path: str | os.PathLike[str]) -> Path:
    """Write segments as NPZ, atomically."""
    return _atomic(Path(path), lambda tmp: np.savez_compressed(tmp, **seg.to_arrays()), ".npz")


def read_segments(path: str | os.PathLike[str]) -> Segments:
    """Read segments written by :func:`write_segments`."""
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, "segments file")
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
        raise not_a_file_error(p, "windows file")
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
