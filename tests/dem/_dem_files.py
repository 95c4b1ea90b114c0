"""Writers of small DEM files for the tests (no data is downloaded)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: PDS3 SAMPLE_TYPE -> NumPy dtype character kind and byte order.
PDS_TYPES = {
    ("MSB_INTEGER", 16): ">i2",
    ("LSB_INTEGER", 16): "<i2",
    ("MSB_UNSIGNED_INTEGER", 16): ">u2",
    ("LSB_UNSIGNED_INTEGER", 16): "<u2",
    ("UNSIGNED_INTEGER", 8): "u1",
    ("PC_REAL", 32): "<f4",
    ("IEEE_REAL", 32): ">f4",
}


def write_pds3(directory: Path, name: str, dn: np.ndarray, *, sample_type: str = "LSB_INTEGER",
               bits: int = 16, scaling: float = 0.5, offset: float = 1737400.0,
               unit: str = "METER", west: float = 0.0, lines: int | None = None,
               max_lat: float | None = None, extra_bytes: int = 0, truncate: int = 0,
               radius_km: float = 1737.4) -> Path:
    """Write a LOLA-like LDEM ``.LBL`` + ``.IMG`` pair by hand (label layout of LDEM_4.LBL).

    ``dn`` is the (rows, cols) array of raw samples, written in the byte order and type
    ``sample_type``/``bits`` say. ``lines``/``max_lat`` override the label to make it lie;
    ``extra_bytes``/``truncate`` make the IMG longer/shorter than the label says.
    """
    h, w = dn.shape
    dtype = np.dtype(PDS_TYPES[(sample_type, bits)])
    raw = dn.astype(dtype).tobytes()
    if truncate:
        raw = raw[:-truncate]
    raw += b"\0" * extra_bytes
    img = directory / f"{name}.IMG"
    img.write_bytes(raw)
    res = w / 360.0
    lines = h if lines is None else lines
    max_lat = 90.0 if max_lat is None else max_lat
    scale_km = 2.0 * math.pi * radius_km / w
    centre = west + 180.0
    label = f"""PDS_VERSION_ID            = "PDS3"

/*** FILE FORMAT ***/
RECORD_TYPE               = FIXED_LENGTH
FILE_RECORDS              = {lines}
RECORD_BYTES              = {w * bits // 8}

/*** POINTERS TO START BYTE OFFSET OF OBJECTS IN IMAGE FILE ***/
^IMAGE                    = "{name}.IMG"

/*** GENERAL DATA DESCRIPTION PARAMETERS ***/
PRODUCT_ID                = "{name}"
INSTRUMENT_ID             = "LOLA"
MISSION_PHASE_NAME        = {{"COMMISSIONING","NOMINAL MISSION"}}
TARGET_NAME               = MOON

OBJECT                    = UNCOMPRESSED_FILE
 FILE_NAME                = "{name}.IMG"
 RECORD_TYPE              = FIXED_LENGTH
 FILE_RECORDS             = {lines}
 RECORD_BYTES             = {w * bits // 8}
 ^IMAGE                   = "{name}.IMG"

 OBJECT                   = IMAGE
  NAME                    = HEIGHT
  DESCRIPTION             = "Each sample represents height relative to a
    reference radius (OFFSET) and is generated using preliminary LOLA data."
  LINES                   = {lines}
  LINE_SAMPLES            = {w}
  SAMPLE_TYPE             = {sample_type}
  SAMPLE_BITS             = {bits}
  UNIT                    = {unit}
  SCALING_FACTOR          = {scaling}
  OFFSET                  = {offset}
 END_OBJECT               = IMAGE
END_OBJECT                = UNCOMPRESSED_FILE

OBJECT                    = IMAGE_MAP_PROJECTION
 MAP_PROJECTION_TYPE          = "SIMPLE CYLINDRICAL"
 MAP_RESOLUTION               = {res} <pix/deg>
 A_AXIS_RADIUS                = {radius_km} <km>
 B_AXIS_RADIUS                = {radius_km} <km>
 C_AXIS_RADIUS                = {radius_km} <km>
 FIRST_STANDARD_PARALLEL      = 'N/A'
 POSITIVE_LONGITUDE_DIRECTION = "EAST"
 CENTER_LATITUDE              = 0. <deg>
 CENTER_LONGITUDE             = {centre} <deg>
 LINE_FIRST_PIXEL             = 1
 LINE_LAST_PIXEL              = {lines}
 SAMPLE_FIRST_PIXEL           = 1
 SAMPLE_LAST_PIXEL            = {w}
 MAP_PROJECTION_ROTATION      = 0.0
 MAP_SCALE                    = {scale_km} <km/pix>
 MAXIMUM_LATITUDE             = {max_lat} <deg>
 MINIMUM_LATITUDE             = -90 <deg>
 WESTERNMOST_LONGITUDE        = {west} <deg>
 EASTERNMOST_LONGITUDE        = {west + 360.0} <deg>
 LINE_PROJECTION_OFFSET       = {90.0 * res - 0.5} <pix>
 SAMPLE_PROJECTION_OFFSET     = {(centre - west) * res - 0.5} <pix>
 COORDINATE_SYSTEM_TYPE       = "BODY-FIXED ROTATING"
 COORDINATE_SYSTEM_NAME       = "MEAN EARTH/POLAR AXIS"
END_OBJECT                = IMAGE_MAP_PROJECTION
END
"""
    lbl = directory / f"{name}.LBL"
    lbl.write_text(label)
    return lbl
