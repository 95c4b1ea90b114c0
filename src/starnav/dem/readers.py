"""Readers and writers of lunar DEMs and albedo maps.

Formats (:data:`DEM_READERS`; what each decodes and what is checked beyond GDAL: docs/dem.md,
"Formats"): ``pds3`` (LOLA LDEM/LDAM through GDAL's PDS driver), ``geotiff`` (any single-band
raster GDAL reads), ``svs-geotiff`` (the NASA SVS CGI Moon Kit), ``npy``. Heights are decoded
as ``raw * scale + offset`` in the file's unit, converted to metres, and the reference radius
subtracted from radii; float32 with the offset folded in float64, so LOLA's half-metre steps
are exact. Albedo decodings: :class:`starnav.dem.schema.AlbedoConfig`. Every error names the
file, the field, the value found and what was expected (:class:`DemFileError`).

Index
-----
:func:`read_dem`, :func:`detect_format`, :func:`read_albedo`, :data:`ALBEDO_DECODERS`,
:func:`dem_info`, :class:`DemInfo`, :func:`write_geotiff`, :func:`encode_svs_8bit`,
:func:`pds3_label_path`, :class:`RasterData`, :class:`DemFileError`.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path
from starnav.constants import MOON_RADIUS
from starnav.dem.grid import AlbedoGrid, DemGrid, EquirectangularGrid, area_resample_blocks
from starnav.dem.schema import AlbedoConfig, DemConfig
from starnav.errors import ConfigError, DataFileError, not_a_file_error
from starnav.registry import Registry

logger = logging.getLogger(__name__)

Extent = tuple[float, float, float, float]

#: PDS3 IMAGE keywords that declare a no-data value.
PDS3_MISSING_KEYS = ("MISSING_CONSTANT", "NULL", "CORE_NULL", "INVALID_CONSTANT")
#: Half-pixel tolerance used when cross-checking label extents [px].
EXTENT_CHECK_PX = 0.5
#: SVS Moon kit unsigned 16-bit DEMs: value = (DN - 20000) * 0.5 m (SVS 4720 page).
SVS_UINT16_SCALE = 0.5
SVS_UINT16_OFFSET = -10_000.0

_UNIT_TO_M = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0,
              "km": 1e3, "kilometer": 1e3, "kilometers": 1e3, "kilometre": 1e3,
              "kilometres": 1e3}


class DemFileError(ConfigError):
    """A DEM or albedo file is malformed or contradicts its label (field, value, expected)."""


@dataclass(frozen=True)
class RasterData:
    """Raw pixels and decoding metadata of one file (internal exchange format)."""

    raw: NDArray[Any]                 # (bands, rows, cols), masked cells already NaN if float
    mask: NDArray[np.bool_] | None    # True where the file says "no data"
    dtypes: tuple[str, ...]
    scales: tuple[float, ...]
    offsets: tuple[float, ...]
    units: tuple[str, ...]
    extent: Extent | None             # radians, None if the file has no georeferencing
    crs_radius: float | None          # sphere radius of the file's CRS [m]
    label: dict[str, Any] | None      # PDS3 label (GDAL json:PDS), if any
    full_shape: tuple[int, int]       # (rows, cols) in the file, before decimation


# ------------------------------------------------------------------------- helpers
def _unit_factor(unit: str, where: str) -> float:
    u = unit.strip().lower().strip("<>")
    if u not in _UNIT_TO_M:
        raise DemFileError(where, unit, f"a length unit ({', '.join(sorted(set(_UNIT_TO_M)))})")
    return _UNIT_TO_M[u]


def _decimated_shape(shape: tuple[int, int], extent: Extent | None, fallback: Extent,
                     max_ppd: float | None) -> tuple[int, int] | None:
    if max_ppd is None:
        return None
    ext = extent or fallback
    ppd = shape[0] / math.degrees(ext[3] - ext[2])
    if ppd <= max_ppd:
        return None
    f = max_ppd / ppd
    return (max(2, round(shape[0] * f)), max(2, round(shape[1] * f)))


def _extent_rad(ext_deg: tuple[float, float, float, float]) -> Extent:
    return tuple(math.radians(v) for v in ext_deg)  # type: ignore[return-value]


def _georef(ds: Any, path: Path) -> tuple[Extent | None, float | None]:
    """Extent [rad] and CRS sphere radius [m] from a rasterio dataset (None if absent)."""
    from rasterio.transform import Affine

    t = ds.transform
    if ds.crs is None or t == Affine.identity():
        return None, None
    if abs(t.b) > 0 or abs(t.d) > 0:
        raise DemFileError(f"{path.name}: geotransform", tuple(t)[:6],
                           "a north-up grid without rotation")
    if t.e >= 0:
        raise DemFileError(f"{path.name}: geotransform", tuple(t)[:6],
                           "rows from north to south (negative y pixel size)")
    h, w = ds.height, ds.width
    crs = ds.crs
    params = crs.to_dict()
    radius = params.get("R") or params.get("a")
    if crs.is_geographic:
        west, north = t.c, t.f
        east, south = t.c + t.a * w, t.f + t.e * h
        ext = (math.radians(west), math.radians(east), math.radians(south), math.radians(north))
    elif params.get("proj") == "eqc":
        if radius is None:
            raise DemFileError(f"{path.name}: CRS", crs.to_string(), "a spherical body radius")
        lat_ts = math.radians(params.get("lat_ts", 0.0))
        lon_0 = math.radians(params.get("lon_0", 0.0))
        lat_0 = math.radians(params.get("lat_0", 0.0))
        x0, y0 = params.get("x_0", 0.0), params.get("y_0", 0.0)
        kx = 1.0 / (radius * math.cos(lat_ts))
        ky = 1.0 / radius
        west = lon_0 + (t.c - x0) * kx
        east = lon_0 + (t.c + t.a * w - x0) * kx
        north = lat_0 + (t.f - y0) * ky
        south = lat_0 + (t.f + t.e * h - y0) * ky
        ext = (west, east, south, north)
    else:
        raise DemFileError(f"{path.name}: CRS", crs.to_string(),
                           "a geographic (lat/lon) or equirectangular (eqc) grid")
    return ext, (float(radius) if radius else None)


def _open_raster(path: Path, driver: str | None = None) -> Any:
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    if not path.is_file():
        raise not_a_file_error(path, "DEM/albedo file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            kw = {"driver": driver} if driver else {}
            return rasterio.open(path, **kw)
    except RasterioIOError as err:
        raise DemFileError(str(path), "unreadable", f"a raster GDAL can open ({err})") from None


def _read_raster(path: Path, driver: str | None, band: int | None,
                 out_shape: Callable[[tuple[int, int], Extent | None], tuple[int, int] | None],
                 label: dict[str, Any] | None = None, use_mask: bool = True) -> RasterData:
    """Read bands (all, or ``band``) with rasterio; ``use_mask=False`` ignores the file's
    no-data value (GDAL's PDS driver invents one per data type when the label has none)."""

    with _open_raster(path, driver) as ds:
        extent, radius = _georef(ds, path)
        bands = [band] if band else list(range(1, ds.count + 1))
        if band and band > ds.count:
            raise DemFileError(f"{path.name}: band", band, f"a band in 1..{ds.count}")
        shape = out_shape((ds.height, ds.width), extent)
        if shape is None:
            arr = ds.read(bands, masked=use_mask)
        else:
            # area average in float, block by block (GDAL's average rounds to the source type)
            from rasterio.windows import Window

            def rows(r0: int, r1: int, b: int) -> NDArray[Any]:
                a = ds.read(b, window=Window(0, r0, ds.width, r1 - r0), masked=use_mask)
                return np.ma.filled(a.astype(np.float32), np.nan) if use_mask else a

            arr = np.stack([area_resample_blocks(lambda r0, r1, b=b: rows(r0, r1, b),
                                                 (ds.height, ds.width), shape)
                            for b in bands])
            logger.info("%s: decimated %s -> %s at load", path.name, (ds.height, ds.width),
                        shape)
        mask = np.ma.getmaskarray(arr) if np.ma.is_masked(arr) else None
        return RasterData(
            raw=np.ma.getdata(arr), mask=mask,
            dtypes=tuple(ds.dtypes[b - 1] for b in bands),
            scales=tuple(float(ds.scales[b - 1]) for b in bands),
            offsets=tuple(float(ds.offsets[b - 1]) for b in bands),
            units=tuple((ds.units[b - 1] or "") for b in bands),
            extent=extent, crs_radius=radius, label=label,
            full_shape=(ds.height, ds.width),
        )


def _nan_masked(values: NDArray[np.float32], mask: NDArray[np.bool_] | None,
                path: Path) -> NDArray[np.float32]:
    if mask is not None and mask.any():
        logger.warning("%s: %d no-data cell(s)", path.name, int(mask.sum()))
        values = values.copy()
        values[mask] = np.nan
    return values


# ------------------------------------------------------------------------- PDS3
def _pds_label(ds: Any) -> dict[str, Any]:
    tags = ds.tags(ns="json:PDS")
    if not tags:
        return {}
    # rasterio splits GDAL's single JSON metadata item at its first ':' or '='
    ((k, v),) = tags.items()
    return json.loads(f"{k}:{v}" if v else k)


def _find_object(node: dict[str, Any], name: str) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The first ``OBJECT = name`` in a label and its parent."""
    for key, val in node.items():
        if isinstance(val, dict) and val.get("_type") == "object":
            if key == name:
                return val, node
            found = _find_object(val, name)
            if found:
                return found
    return None


def _qty(val: Any) -> float:
    """Numeric value of a label item that may carry a unit ``{"value": v, "unit": u}``."""
    if isinstance(val, dict):
        val = val.get("value")
    try:
        return float(val)
    except (TypeError, ValueError):
        return math.nan


def _find_file_ci(directory: Path, name: str) -> Path | None:
    p = directory / name
    if p.is_file():
        return p
    low = name.lower()
    for q in directory.iterdir():
        if q.name.lower() == low:
            return q
    return None


def pds3_label_path(path: Path) -> Path:
    """The file GDAL must open: the detached ``.LBL`` next to an ``.IMG`` if there is one."""
    if path.suffix.lower() == ".img":
        lbl = _find_file_ci(path.parent, path.stem + ".lbl")
        if lbl is not None:
            return lbl
    return path


def _pds3_layout(label: dict[str, Any], lbl_path: Path) -> tuple[Path, int, int, bool]:
    """Data file, byte offset of the image, its expected size in bytes, detached?"""
    found = _find_object(label, "IMAGE")
    if found is None:
        raise DemFileError(f"{lbl_path.name}: IMAGE", "missing", "an OBJECT = IMAGE")
    image, parent = found
    ptr = parent.get("^IMAGE", label.get("^IMAGE"))
    rec_bytes = _qty(parent.get("RECORD_BYTES", label.get("RECORD_BYTES")))
    fname: str | None = None
    offset = 0
    if isinstance(ptr, str):
        fname = ptr
    elif isinstance(ptr, list) and ptr:
        fname = str(ptr[0])
        if len(ptr) > 1:
            offset = _pointer_offset(ptr[1], rec_bytes, lbl_path)
    elif ptr is not None:
        offset = _pointer_offset(ptr, rec_bytes, lbl_path)
    else:
        raise DemFileError(f"{lbl_path.name}: ^IMAGE", "missing", "a pointer to the image data")
    if fname is not None:
        data = _find_file_ci(lbl_path.parent, fname)
        if data is None:
            raise DataFileError(f"{lbl_path.name}: ^IMAGE points to {fname!r}, which does not "
                                f"exist in {str(lbl_path.parent)!r}")
        detached = data.resolve() != lbl_path.resolve()
    else:
        data, detached = lbl_path, False
    need = {k: _qty(image.get(k)) for k in ("LINES", "LINE_SAMPLES", "SAMPLE_BITS")}
    for k, v in need.items():
        if not (math.isfinite(v) and v > 0 and v == int(v)):
            raise DemFileError(f"{lbl_path.name}: IMAGE.{k}", image.get(k), "a positive integer")
    bands = int(_qty(image.get("BANDS", 1)) or 1)
    prefix = int(_qty(image.get("LINE_PREFIX_BYTES", 0)) or 0)
    suffix = int(_qty(image.get("LINE_SUFFIX_BYTES", 0)) or 0)
    line_bytes = prefix + int(need["LINE_SAMPLES"]) * int(need["SAMPLE_BITS"]) // 8 + suffix
    size = bands * int(need["LINES"]) * line_bytes
    return data, offset, size, detached


def _pointer_offset(ptr: Any, rec_bytes: float, lbl_path: Path) -> int:
    if isinstance(ptr, dict) and str(ptr.get("unit", "")).upper() == "BYTES":
        return int(_qty(ptr)) - 1
    rec = _qty(ptr)
    if not (math.isfinite(rec) and rec >= 1):
        raise DemFileError(f"{lbl_path.name}: ^IMAGE", ptr, "a record number >= 1")
    if not (math.isfinite(rec_bytes) and rec_bytes > 0):
        raise DemFileError(f"{lbl_path.name}: RECORD_BYTES", rec_bytes,
                           "a positive record length (the image pointer counts records)")
    return int((rec - 1) * rec_bytes)


def _check_pds3(label: dict[str, Any], lbl_path: Path) -> None:
    """Checks GDAL does not make: file size vs label, and the label's own consistency."""
    data, offset, size, detached = _pds3_layout(label, lbl_path)
    image, _ = _find_object(label, "IMAGE")  # type: ignore[misc]
    actual = data.stat().st_size
    dims = (f"LINES {image.get('LINES')} x LINE_SAMPLES {image.get('LINE_SAMPLES')} x "
            f"SAMPLE_BITS {image.get('SAMPLE_BITS')}")
    if actual < offset + size:
        raise DemFileError(
            f"{data.name}: file size", f"{actual} bytes",
            f"{offset + size} bytes ({dims} from {lbl_path.name}, image at byte {offset}): "
            "the image file is truncated",
        )
    if detached and actual != offset + size:
        raise DemFileError(
            f"{data.name}: file size", f"{actual} bytes",
            f"{offset + size} bytes ({dims} from {lbl_path.name}): label and file size "
            "do not match",
        )
    proj = _find_object(label, "IMAGE_MAP_PROJECTION")
    if proj is None:
        return
    mp = proj[0]
    ptype = str(mp.get("MAP_PROJECTION_TYPE", "")).upper().replace("_", " ")
    if ptype and ptype not in ("SIMPLE CYLINDRICAL", "EQUIRECTANGULAR", "EQUIDISTANT"):
        raise DemFileError(f"{lbl_path.name}: IMAGE_MAP_PROJECTION.MAP_PROJECTION_TYPE",
                           mp.get("MAP_PROJECTION_TYPE"),
                           "SIMPLE CYLINDRICAL (polar products are not supported)")
    pos = str(mp.get("POSITIVE_LONGITUDE_DIRECTION", "EAST")).upper()
    if pos != "EAST":
        raise DemFileError(f"{lbl_path.name}: IMAGE_MAP_PROJECTION.POSITIVE_LONGITUDE_DIRECTION",
                           pos, "EAST")
    for key in ("MAXIMUM_LATITUDE", "MINIMUM_LATITUDE"):
        v = _qty(mp.get(key))
        if key in mp and not (math.isfinite(v) and -90.0 <= v <= 90.0):
            raise DemFileError(f"{lbl_path.name}: IMAGE_MAP_PROJECTION.{key}",
                               f"{v:g} deg", "a latitude within -90..90 deg")
    lat_max, lat_min = _qty(mp.get("MAXIMUM_LATITUDE")), _qty(mp.get("MINIMUM_LATITUDE"))
    res = _qty(mp.get("MAP_RESOLUTION"))
    lines = _qty(image.get("LINES"))
    if all(math.isfinite(v) for v in (lat_max, lat_min, res)) and res > 0:
        expect = (lat_max - lat_min) * res
        if abs(expect - lines) > EXTENT_CHECK_PX + 1e-6:
            raise DemFileError(
                f"{lbl_path.name}: IMAGE.LINES", int(lines),
                f"{expect:g} lines for MAXIMUM_LATITUDE {lat_max:g} - MINIMUM_LATITUDE "
                f"{lat_min:g} deg at MAP_RESOLUTION {res:g} px/deg: the label contradicts itself",
            )


def _read_pds3(path: Path, cfg: DemConfig) -> tuple[RasterData, dict[str, Any]]:
    lbl_path = pds3_label_path(path)
    with _open_raster(lbl_path, "PDS") as ds:
        label = _pds_label(ds)
    if not label:
        raise DemFileError(str(lbl_path), "no PDS3 label", "a PDS3 label GDAL can parse")
    _check_pds3(label, lbl_path)
    fallback = _extent_rad(cfg.extent_deg)
    image, _ = _find_object(label, "IMAGE")  # type: ignore[misc]
    missing = [_qty(image[k]) for k in PDS3_MISSING_KEYS if k in image]
    # with a declared missing constant, read at full resolution so that no hole is averaged
    # into its neighbours; GDAL's invented no-data values are ignored otherwise
    max_ppd = None if missing else cfg.max_pixels_per_degree
    rd = _read_raster(lbl_path, "PDS", 1,
                      lambda s, e: _decimated_shape(s, e, fallback, max_ppd),
                      label=label, use_mask=False)
    if missing:
        mask = np.isin(rd.raw, np.asarray(missing, dtype=rd.raw.dtype))
        rd = RasterData(**{**rd.__dict__, "mask": mask if mask.any() else None})
    if rd.extent is not None:
        _cross_check_extent(label, rd.extent, rd.full_shape, lbl_path)
    return rd, label


def _cross_check_extent(label: dict[str, Any], extent: Extent, shape: tuple[int, int],
                        lbl_path: Path) -> None:
    proj = _find_object(label, "IMAGE_MAP_PROJECTION")
    if proj is None:
        return
    mp = proj[0]
    w, e, s, n = (math.degrees(v) for v in extent)
    px_lat = (n - s) / shape[0]
    px_lon = (e - w) / shape[1]
    checks = (("MAXIMUM_LATITUDE", n, px_lat, False), ("MINIMUM_LATITUDE", s, px_lat, False),
              ("WESTERNMOST_LONGITUDE", w, px_lon, True),
              ("EASTERNMOST_LONGITUDE", e, px_lon, True))
    for key, got, px, is_lon in checks:
        v = _qty(mp.get(key))
        if not math.isfinite(v):
            continue
        diff = got - v
        if is_lon:
            diff = (diff + 180.0) % 360.0 - 180.0
        if abs(diff) > EXTENT_CHECK_PX * px + 1e-6:
            raise DemFileError(
                f"{lbl_path.name}: IMAGE_MAP_PROJECTION.{key}", f"{v:g} deg",
                f"{got:.6g} deg as implied by the projection offsets, MAP_SCALE and the image "
                "size: the label contradicts itself",
            )


# ------------------------------------------------------------------------- DEM readers
def _to_heights(raw: NDArray[Any], scale: float, offset: float, unit_m: float,
                vertical: str, radius: float, where: str) -> tuple[NDArray[np.float32], str]:
    """``(raw * scale + offset) * unit_m`` [m], minus ``radius`` for radii; float32."""
    off_m = offset * unit_m
    sc_m = scale * unit_m
    if vertical == "auto":
        if abs(off_m) > 0.5 * radius:
            vertical = "radius"
        else:
            sample = raw[:: max(1, raw.shape[0] // 64), :: max(1, raw.shape[1] // 64)]
            med = float(np.nanmedian(sample.astype(np.float64))) * sc_m + off_m
            vertical = "radius" if med > 0.5 * radius else "height"
    base = off_m - (radius if vertical == "radius" else 0.0)  # folded in float64
    out = raw.astype(np.float32, copy=False) * np.float32(sc_m)
    out += np.float32(base)
    logger.debug("%s: value = raw * %g m + %g m (%s)", where, sc_m, base, vertical)
    return out, vertical


def read_dem(path: str | os.PathLike[str], cfg: DemConfig | None = None) -> DemGrid:
    """Read a DEM file into a :class:`DemGrid` (heights [m] above the reference sphere).

    Parameters
    ----------
    path : path-like
        ``.LBL``/``.IMG`` (PDS3), ``.tif`` (GeoTIFF, SVS kit) or ``.npy``.
    cfg : DemConfig, optional
        Decoding options (``format``, ``units``, ``vertical``, ``value_scale``,
        ``value_offset``, ``extent_deg``, ``max_pixels_per_degree``); ``cfg.source`` is ignored.

    Raises
    ------
    DataFileError
        if the file does not exist.
    DemFileError
        truncated file, label/size mismatch, latitude outside -90..90 deg, unsupported
        projection, unknown unit.
    ConfigError
        NaN heights, |height| > 100 km (from :class:`DemGrid`).
    """
    p = Path(path)
    cfg = cfg or DemConfig(source=str(p))
    fmt = cfg.format if cfg.format != "auto" else detect_format(p)
    grid = DEM_READERS.get(fmt)(p, cfg)
    logger.info("read %s (%s): %r, heights %.1f..%.1f m", p.name, fmt, grid,
                *grid.height_range)
    return grid


def _dem_from_raster(rd: RasterData, p: Path, cfg: DemConfig, scale: float, offset: float,
                     unit_m: float, radius: float, fmt: str) -> DemGrid:
    raw = rd.raw[0]
    heights, _ = _to_heights(raw, scale, offset, unit_m, cfg.vertical, radius, p.name)
    heights = _nan_masked(heights, None if rd.mask is None else rd.mask[0], p)
    extent = rd.extent if rd.extent is not None else _extent_rad(cfg.extent_deg)
    if rd.extent is None:
        logger.info("%s: no georeferencing; extent_deg %s assumed", p.name, cfg.extent_deg)
    return DemGrid(heights, extent=extent, reference_radius=radius, source=f"{fmt}:{p}")


def _pds3_reader(p: Path, cfg: DemConfig) -> DemGrid:
    rd, label = _read_pds3(p, cfg)
    image, _ = _find_object(label, "IMAGE")  # type: ignore[misc]
    proj = _find_object(label, "IMAGE_MAP_PROJECTION")
    radius = cfg.reference_radius_km * 1e3
    if proj is not None:
        a = proj[0].get("A_AXIS_RADIUS")
        if a is not None:
            unit = a.get("unit", "km") if isinstance(a, dict) else "km"
            radius = _qty(a) * _unit_factor(unit, f"{p.name}: A_AXIS_RADIUS")
    # GDAL has read SCALING_FACTOR / OFFSET from the label; an explicit override wins
    scale = cfg.value_scale if cfg.value_scale is not None else rd.scales[0]
    offset = cfg.value_offset if cfg.value_offset is not None else rd.offsets[0]
    unit = str(image.get("UNIT", "METER")) if cfg.units == "auto" else cfg.units
    unit_m = _unit_factor(unit, f"{p.name}: IMAGE.UNIT")
    return _dem_from_raster(rd, p, cfg, scale, offset, unit_m, radius, "pds3")


def _geotiff_reader(p: Path, cfg: DemConfig, svs: bool = False) -> DemGrid:
    fallback = _extent_rad(cfg.extent_deg)
    rd = _read_raster(p, None, 1,
                      lambda s, e: _decimated_shape(s, e, fallback, cfg.max_pixels_per_degree))
    scale, offset = rd.scales[0], rd.offsets[0]
    unit = cfg.units if cfg.units != "auto" else (rd.units[0] or "m")
    if svs:
        if rd.dtypes[0] == "uint16":
            scale, offset, unit = SVS_UINT16_SCALE, SVS_UINT16_OFFSET, "m"
        elif rd.dtypes[0].startswith("float"):
            unit = cfg.units if cfg.units != "auto" else "km"
        else:
            raise DemFileError(f"{p.name}: data type", rd.dtypes[0],
                               "float32 (km) or uint16 (half-metres + 20000) for the SVS kit")
    if cfg.value_scale is not None:
        scale = cfg.value_scale
    if cfg.value_offset is not None:
        offset = cfg.value_offset
    radius = cfg.reference_radius_km * 1e3
    if rd.crs_radius is not None and abs(rd.crs_radius - radius) > 1e3:
        logger.warning("%s: the CRS sphere radius %.1f km differs from the reference radius "
                       "%.1f km (georeferencing kept; heights relative to the reference)",
                       p.name, rd.crs_radius / 1e3, radius / 1e3)
    unit_m = _unit_factor(unit, f"{p.name}: units")
    return _dem_from_raster(rd, p, cfg, scale, offset, unit_m, radius,
                            "svs-geotiff" if svs else "geotiff")


def _npy_reader(p: Path, cfg: DemConfig) -> DemGrid:
    if not p.is_file():
        raise not_a_file_error(p, "DEM file")
    try:
        a = np.load(p, mmap_mode="r", allow_pickle=False)
    except ValueError as err:
        raise DemFileError(str(p), "unreadable", f"a NumPy .npy array ({err})") from None
    if a.ndim != 2:
        raise DemFileError(f"{p.name}: shape", a.shape, "a 2-D array (rows = latitude)")
    unit = cfg.units if cfg.units != "auto" else "m"
    scale = cfg.value_scale if cfg.value_scale is not None else 1.0
    offset = cfg.value_offset if cfg.value_offset is not None else 0.0
    radius = cfg.reference_radius_km * 1e3
    h, _ = _to_heights(np.asarray(a), scale, offset, _unit_factor(unit, f"{p.name}: units"),
                       cfg.vertical, radius, p.name)
    g = DemGrid(h, extent=_extent_rad(cfg.extent_deg), reference_radius=radius,
                source=f"npy:{p}")
    if cfg.max_pixels_per_degree is not None:
        g = g.resampled(cfg.max_pixels_per_degree)
    return g


#: DEM readers by format name.
DEM_READERS: Registry[Callable[[Path, DemConfig], DemGrid]] = Registry("DEM format", {
    "pds3": _pds3_reader,
    "geotiff": _geotiff_reader,
    "svs-geotiff": lambda p, cfg: _geotiff_reader(p, cfg, svs=True),
    "npy": _npy_reader,
})


def detect_format(path: Path) -> str:
    """Guess a DEM file's format from its name (and, for TIFFs, its georeferencing)."""
    suf = path.suffix.lower()
    if suf in (".lbl", ".img"):
        return "pds3"
    if suf == ".npy":
        return "npy"
    if suf in (".tif", ".tiff") and re.match(r"ldem_", path.name, re.IGNORECASE):
        with _open_raster(path) as ds:
            extent, _ = _georef(ds, path)
        return "svs-geotiff" if extent is None else "geotiff"
    return "geotiff"


# ------------------------------------------------------------------------- albedo
def read_albedo(path: str | os.PathLike[str], cfg: AlbedoConfig | None = None) -> AlbedoGrid:
    """Read and decode an albedo map (see :class:`~starnav.dem.schema.AlbedoConfig`).

    Returns
    -------
    AlbedoGrid
        Values in 0..1 of ``cfg.quantity`` (a relative map scaled by ``normalize_mean`` becomes
        ``normal_albedo``).
    """
    p = Path(path)
    cfg = cfg or AlbedoConfig(source=str(p))
    fmt = cfg.format if cfg.format != "auto" else ("npy" if p.suffix.lower() == ".npy"
                                                    else "geotiff")
    fallback = _extent_rad(cfg.extent_deg)
    if fmt == "npy":
        if not p.is_file():
            raise not_a_file_error(p, "albedo file")
        a = np.load(p, allow_pickle=False)
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3:
            raise DemFileError(f"{p.name}: shape", a.shape, "(rows, cols) or (bands, rows, cols)")
        if cfg.band:
            a = a[cfg.band - 1: cfg.band]
        rd = RasterData(raw=a, mask=None, dtypes=(str(a.dtype),) * a.shape[0],
                        scales=(1.0,) * a.shape[0], offsets=(0.0,) * a.shape[0],
                        units=("",) * a.shape[0], extent=None, crs_radius=None, label=None,
                        full_shape=a.shape[1:])
    else:
        rd = _read_raster(p, None, cfg.band,
                          lambda s, e: _decimated_shape(s, e, fallback,
                                                        cfg.max_pixels_per_degree))
    n_bands = rd.raw.shape[0]
    acc = np.zeros(rd.raw.shape[1:], np.float32)
    for b in range(n_bands):
        balance = (cfg.channel_balance[b] if (n_bands == 3 and cfg.band is None) else 1.0)
        acc += _decode_albedo(rd.raw[b], rd.dtypes[b], rd.scales[b], rd.offsets[b], cfg,
                              balance, p)
    acc /= n_bands
    if rd.mask is not None:
        acc = _nan_masked(acc, rd.mask.any(axis=0), p)
    extent = rd.extent if rd.extent is not None else fallback
    quantity = cfg.resolved_quantity()
    if quantity == "relative":
        q = cfg.resolved_contrast_exponent()
        if q != 1.0:
            acc = np.power(np.clip(acc, 0.0, None), np.float32(q)).astype(np.float32)
    if cfg.normalize_mean is not None:
        tmp = AlbedoGrid(np.clip(acc, 0, 1), extent=extent, quantity=quantity)
        acc *= np.float32(cfg.normalize_mean / max(tmp.mean, 1e-12))
        if quantity == "relative":
            quantity = "normal_albedo"
    g = AlbedoGrid(acc, extent=extent, quantity=quantity, source=f"{fmt}:{p}")
    if fmt == "npy" and cfg.max_pixels_per_degree is not None:
        g = g.resampled(cfg.max_pixels_per_degree)
    logger.info("read albedo %s: %r, mean %.4f", p.name, g, g.mean)
    return g


#: ``f(x, dtype, file_scale, file_offset, cfg, balance, path)``: albedo from raw values ``x``.
AlbedoDecoder = Callable[[NDArray[np.float32], str, float, float, AlbedoConfig, float, Path],
                         NDArray[np.float32]]

#: Albedo decodings by name (``AlbedoConfig.decoding``; ``auto`` picks one by data type).
ALBEDO_DECODERS: Registry[AlbedoDecoder] = Registry("albedo decoding")


@ALBEDO_DECODERS.register("svs-8bit")
def _decode_svs_8bit(x: NDArray[np.float32], dtype: str, file_scale: float, file_offset: float,
                     cfg: AlbedoConfig, balance: float, p: Path) -> NDArray[np.float32]:
    if np.dtype(dtype) != np.uint8:
        raise DemFileError(f"{p.name}: data type", dtype, "8-bit values for svs-8bit")
    lo, hi = cfg.domain
    enc = (lo + (hi - lo) * (x / np.float32(255.0))) / np.float32(balance)
    return np.power(enc, np.float32(cfg.gamma)).astype(np.float32)


@ALBEDO_DECODERS.register("linear")
def _decode_linear(x: NDArray[np.float32], dtype: str, file_scale: float, file_offset: float,
                   cfg: AlbedoConfig, balance: float, p: Path) -> NDArray[np.float32]:
    dt = np.dtype(dtype)
    scale, offset = cfg.scale, cfg.offset
    if scale is None:
        if file_scale != 1.0 or file_offset != 0.0:
            scale, offset = file_scale, (file_offset if offset is None else offset)
        elif np.issubdtype(dt, np.unsignedinteger):
            scale = 1.0 / float(np.iinfo(dt).max)
        else:
            raise DemFileError(f"{p.name}: albedo.scale", None,
                               f"an explicit scale for {dtype} values")
    return x * np.float32(scale) + np.float32(offset or 0.0)


@ALBEDO_DECODERS.register("reflectance")
def _decode_reflectance(x: NDArray[np.float32], dtype: str, file_scale: float,
                        file_offset: float, cfg: AlbedoConfig, balance: float,
                        p: Path) -> NDArray[np.float32]:
    return x * np.float32(file_scale) + np.float32(file_offset)


def _decode_albedo(raw: NDArray[Any], dtype: str, file_scale: float, file_offset: float,
                   cfg: AlbedoConfig, balance: float, p: Path) -> NDArray[np.float32]:
    dt = np.dtype(dtype)
    dec = cfg.decoding
    if dec == "auto":
        dec = ("svs-8bit" if dt == np.uint8 else
               "linear" if np.issubdtype(dt, np.integer) else "reflectance")
    decode = ALBEDO_DECODERS.get(dec)
    return decode(raw.astype(np.float32, copy=False), dtype, file_scale, file_offset, cfg,
                  balance, p)


def encode_svs_8bit(r: NDArray[np.floating[Any]], gamma: float = 2.8,
                    domain: tuple[float, float] = (0.16, 0.40),
                    balance: float = 1.0) -> NDArray[np.uint8]:
    """Inverse of the ``svs-8bit`` decoding (for tests and for writing kit-like maps)."""
    lo, hi = domain
    enc = np.asarray(r, dtype=float) ** (1.0 / gamma) * balance
    t = np.clip((enc - lo) / (hi - lo), 0.0, 1.0)
    return np.round(t * 255.0).astype(np.uint8)


# ------------------------------------------------------------------------- writers
def write_geotiff(grid: EquirectangularGrid, path: str | os.PathLike[str]) -> Path:
    """Write a grid as a float32 GeoTIFF in the IAU 2015 Moon sphere CRS (degrees).

    Heights are written in metres above the reference sphere (band unit ``m``). The file is
    written to a temporary name and renamed (never half-written).
    """
    import rasterio
    from rasterio.crs import CRS
    from rasterio.transform import from_bounds

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    w, e, s, n = (math.degrees(v) for v in grid.extent)
    radius = getattr(grid, "reference_radius", MOON_RADIUS)
    crs = (CRS.from_user_input("IAU_2015:30100") if radius == MOON_RADIUS
           else CRS.from_proj4(f"+proj=longlat +R={radius} +no_defs"))
    with atomic_path(p, suffix=".tif") as tmp, rasterio.open(
            tmp, "w", driver="GTiff", width=grid.shape[1], height=grid.shape[0], count=1,
            dtype="float32", crs=crs,
            transform=from_bounds(w, s, e, n, grid.shape[1], grid.shape[0]),
            compress="deflate", tiled=True) as ds:
        ds.write(grid.values, 1)
        if isinstance(grid, DemGrid):
            ds.units = ("m",)
    return p


# ------------------------------------------------------------------------- info
@dataclass(frozen=True)
class DemInfo:
    """Summary of a DEM (``starnav dem info``); heights [m], angles [deg]."""

    source: str
    shape: tuple[int, int]
    pixels_per_degree: float
    cell_km: float
    extent_deg: tuple[float, float, float, float]
    reference_radius_km: float
    height_min_m: float
    height_max_m: float
    height_mean_m: float

    def as_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def dem_info(grid: DemGrid | DemConfig | str | os.PathLike[str]) -> DemInfo:
    """Size, resolution, extent and height statistics of a grid, a DEM config or a file."""
    if not isinstance(grid, DemGrid):
        from starnav.dem.load import load_dem  # lazy: cycle with starnav.dem.load

        cfg = grid if isinstance(grid, DemConfig) else DemConfig(source=str(grid))
        grid = load_dem(cfg)
    lo, hi = grid.height_range
    w = np.cos(grid.lat_centres())
    mean = float(np.average(grid.values.mean(axis=1, dtype=np.float64), weights=w))
    return DemInfo(
        source=grid.source, shape=grid.shape, pixels_per_degree=grid.pixels_per_degree,
        cell_km=grid.cell_size(grid.reference_radius) / 1e3,
        extent_deg=tuple(math.degrees(v) for v in grid.extent),  # type: ignore[arg-type]
        reference_radius_km=grid.reference_radius / 1e3,
        height_min_m=lo, height_max_m=hi, height_mean_m=mean,
    )
