"""Reading a star camera's frame from a file: grey levels, saturation and the epoch if told.

Formats
-------
* **TIFF, PNG** (Pillow): 16-bit and 8-bit grey; colour is averaged to grey (equal weights: a
  star camera's frame is monochrome, a colour one is only a picture). Saturation at the type's
  top code. Epoch: the TIFF ``DateTime`` tag or EXIF ``DateTimeOriginal`` when present (taken
  as UTC).
* **FITS** (astropy): the first HDU with a 2-D image; ``DATE-OBS`` (with ``TIMESYS``, default
  UTC) gives the epoch; integer data saturate at their type's top code.
* **starnav DN frames** (``dn.png``, ``stars_dn.png`` of a dataset): 16-bit PNG; the epoch is
  the frame's ``truth.json`` ``epoch_tdb_s`` two directories up.

Anything else is refused with one line naming the file and what was expected.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from starnav.errors import DataFileError
from starnav.stars.catalogue import jyear_from_tdb

#: File suffixes read as FITS.
FITS_SUFFIXES = (".fits", ".fit", ".fts", ".fits.gz")


@dataclass(frozen=True)
class StarImage:
    """A frame read from a file.

    Attributes
    ----------
    data : (H, W) array
        Grey levels as stored (integers stay integers).
    saturation_dn : float
        Grey level at which a pixel is saturated (``inf``: unknown, float data).
    epoch_jyear : float or None
        Epoch of the exposure [Julian year] when the file tells it; ``epoch_source`` says where.
    limiting_v : float or None
        Faintest V magnitude a point source can reach on this frame when the camera's
        radiometry and the exposure are known (``limiting_v_source`` says how); None otherwise.
    """

    path: Path
    data: NDArray
    saturation_dn: float
    epoch_jyear: float | None
    epoch_source: str
    limiting_v: float | None = None
    limiting_v_source: str = ""


def _jyear_from_iso(text: str, scale: str = "utc") -> float:
    from astropy.time import Time

    return float(Time(text, scale=scale.lower()).jyear)


def _read_fits(path: Path) -> StarImage:
    from astropy.io import fits

    try:
        with fits.open(path, memmap=False) as hdul:
            for hdu in hdul:
                if hdu.data is not None and np.ndim(hdu.data) == 2:
                    data = np.asarray(hdu.data)
                    hdr = hdu.header
                    break
            else:
                raise DataFileError(f"{path}: FITS file without a 2-D image HDU; expected a "
                                    "grey star frame")
    except (OSError, ValueError, TypeError) as exc:
        raise DataFileError(f"{path}: not a readable FITS file ({exc})") from exc
    epoch, src = None, "not in the file"
    if "DATE-OBS" in hdr:
        try:
            epoch = _jyear_from_iso(str(hdr["DATE-OBS"]), str(hdr.get("TIMESYS", "UTC")))
            src = "FITS DATE-OBS"
        except ValueError:
            src = f"FITS DATE-OBS {hdr['DATE-OBS']!r} unreadable"
    sat = (float(np.iinfo(data.dtype).max) if np.issubdtype(data.dtype, np.integer)
           else math.inf)
    return StarImage(path, data, sat, epoch, src)


def _pil_epoch(im) -> tuple[float | None, str]:
    text = None
    try:
        tags = getattr(im, "tag_v2", None)
        if tags is not None and 306 in tags:
            text = str(tags[306])
        else:
            exif = im.getexif()
            text = exif.get_ifd(0x8769).get(36867) or exif.get(306)
    except (AttributeError, KeyError, ValueError):
        text = None
    if not text:
        return None, "not in the file"
    iso = str(text).strip().replace(":", "-", 2).replace(" ", "T", 1)
    try:
        return _jyear_from_iso(iso), "image DateTime tag (taken as UTC)"
    except ValueError:
        return None, f"image date {text!r} unreadable"


def _truth_epoch(path: Path) -> tuple[float | None, str]:
    truth = path.parent.parent / "truth.json"
    if path.name not in ("dn.png", "stars_dn.png") or not truth.is_file():
        return None, ""
    try:
        epoch_tdb = json.loads(truth.read_text())["epoch_tdb_s"]
        return jyear_from_tdb(float(epoch_tdb)), "dataset truth.json"
    except (OSError, ValueError, KeyError, TypeError):
        return None, ""


def read_star_image(path: str | Path) -> StarImage:
    """Read a frame (module formats).

    Raises
    ------
    DataFileError
        Missing file, not an image, not a 2-D grey frame.
    """
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"{p}: no such file; expected a star image (TIFF, PNG, FITS)")
    if p.name.lower().endswith(FITS_SUFFIXES):
        return _read_fits(p)
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(p) as im:
            im.load()
            mode = im.mode
            epoch, src = _pil_epoch(im)
            if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
                data = np.asarray(im, dtype=np.uint16)
                sat = 65535.0
            elif mode == "L":
                data = np.asarray(im, dtype=np.uint8)
                sat = 255.0
            elif mode in ("I", "F"):
                data = np.asarray(im)
                sat = math.inf if mode == "F" else float(data.max())
            elif mode in ("RGB", "RGBA", "LA", "P", "1"):
                grey = im.convert("RGB")
                data = np.asarray(grey, dtype=np.float64).mean(axis=2)
                sat = 255.0
            else:
                raise DataFileError(f"{p}: image mode {mode!r}; expected a grey or colour "
                                    "8/16-bit image")
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        if isinstance(exc, DataFileError):
            raise
        raise DataFileError(f"{p}: not an image Pillow can read ({type(exc).__name__}); "
                            "expected a TIFF, PNG or FITS star frame") from exc
    if data.ndim != 2 or min(data.shape) < 32:
        raise DataFileError(f"{p}: {data.shape} pixels; expected a 2-D frame of at least "
                            "32 px per side")
    if epoch is None:
        e2, s2 = _truth_epoch(p)
        if e2 is not None:
            epoch, src = e2, s2
    return StarImage(p, data, sat, epoch, src)
