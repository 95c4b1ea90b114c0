#!/usr/bin/env python
"""Convert the LROC WAC colour mosaic (NASA SVS CGI Moon Kit) once into starnav's packaged grey
albedo map ``src/starnav/data/albedo/lroc_wac_grey_2048.tif``.

Input: ``lroc_color_poles_4k.jpg``, 4096 x 2048 8-bit sRGB, equirectangular (plate carree),
pixel-is-area, **longitude 0 at the image centre**: the left edge is 180 W, east is to the right,
the top edge is 90 N (Tycho, 43.3 S 11.4 W, lies left of the centre, below the equator).

Steps
-----
1. Decode sRGB to linear RGB with colour-science (``colour.cctf_decoding(x, function="sRGB")``,
   the IEC 61966-2-1 piecewise curve), in row blocks.
2. One grey channel: the CIE 1931 relative luminance ``Y`` of linear sRGB, i.e. the Rec. 709
   weights ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (the second row of colour-science's sRGB
   RGB-to-XYZ matrix). Why luminance and not, say, the red channel or the channel mean: the
   mosaic is a *visual* product whose colours were balanced for the eye, so its meaningful
   brightness is the photometric one, ``Y``; the Moon's spectral shape (it is redder than the
   Sun) is applied elsewhere, from the ROLO model (:mod:`starnav.lunar_calibration`), not
   guessed from the JPEG's colour balance.
3. Area-average resample (exact cell-overlap weights, :func:`starnav.dem.grid.area_resample_blocks`)
   to 2048 x 1024 (0.176 deg/px, ~5.3 km at the equator: finer than LDEM_4's 7.6 km).
4. Quantise ``round(Y * 65535)`` to uint16 and write a GeoTIFF (DEFLATE, horizontal predictor 2,
   tiled 256 x 256) with band scale ``1/65535`` and offset 0, so GDAL readers decode it to linear
   0..1 (starnav: ``AlbedoConfig(decoding="linear")``). Georeferencing: geographic degrees on a
   1737.4 km sphere (``+proj=longlat +R=1737400 +no_defs``), west edge -180 deg, north edge
   +90 deg, 360/2048 deg per pixel; checked to round-trip after writing. Written to a temporary
   name and renamed (:mod:`starnav.atomic`).

The values are RELATIVE linear brightness, not calibrated reflectance: the kit says the mosaic
is optimised for aesthetics, its tone curve is not documented. The absolute scale (and a
contrast exponent) are calibrated against the ROLO lunar model elsewhere
(``tools/calibrate_moon_rolo.py``). Provenance: ``src/starnav/data/albedo/PROVENANCE.md``.

Usage::

    .venv/bin/python tools/convert_lroc_albedo.py     # the source kept in tools/sources/albedo
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path
from starnav.dem.grid import area_resample_blocks

ROOT = Path(__file__).resolve().parents[1]
#: The source mosaic, kept in the repository with its licence (tools/sources/albedo/).
DEFAULT_SRC = ROOT / "tools" / "sources" / "albedo" / "lroc_color_poles_4k.jpg"
DEFAULT_OUT = ROOT / "src" / "starnav" / "data" / "albedo" / "lroc_wac_grey_2048.tif"
#: Output grid (columns, rows).
OUT_SHAPE = (1024, 2048)
#: uint16 full scale: the band scale is 1 / DN_MAX.
DN_MAX = 65535
#: Lunar geographic CRS: degrees on the 1737.4 km reference sphere (LOLA's).
CRS_PROJ4 = "+proj=longlat +R=1737400 +no_defs"
#: Source image layout (data/README.md): 4096 x 2048, left edge 180 W, top edge 90 N.
SRC_SHAPE = (2048, 4096)
#: Rows decoded at a time (memory: ~rows x 4096 x 3 float64).
BLOCK_ROWS = 128


def luminance_weights() -> NDArray[np.float64]:
    """Rec. 709 / sRGB relative-luminance weights (R, G, B) from colour-science [-]."""
    import colour

    w = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ[1], dtype=np.float64)
    assert np.allclose(w, (0.2126, 0.7152, 0.0722), atol=1e-4), w
    return w


def srgb8_to_linear_y(rgb: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Linear relative luminance ``Y`` (0..1) of 8-bit sRGB pixels ``(..., 3)`` (steps 1-2)."""
    import colour

    lin = colour.cctf_decoding(rgb.astype(np.float64) / 255.0, function="sRGB")
    return np.asarray(lin, dtype=np.float64) @ luminance_weights()


def convert(src: Path, out: Path) -> dict[str, object]:
    """Run steps 1-4; returns what was written (shape, statistics, tags)."""
    import rasterio
    from PIL import Image
    from rasterio.crs import CRS
    from rasterio.transform import from_origin

    with Image.open(src) as im:
        if im.mode != "RGB":
            raise SystemExit(f"{src}: mode {im.mode!r}, expected 'RGB'")
        rgb = np.asarray(im)
    if rgb.shape[:2] != SRC_SHAPE:
        raise SystemExit(f"{src}: shape {rgb.shape[:2]}, expected {SRC_SHAPE} (rows, cols)")

    def rows(r0: int, r1: int) -> NDArray[np.float64]:
        return srgb8_to_linear_y(rgb[r0:r1])

    y = area_resample_blocks(rows, SRC_SHAPE, OUT_SHAPE,
                             block_cells=BLOCK_ROWS * SRC_SHAPE[1]).astype(np.float64)
    dn = np.round(np.clip(y, 0.0, 1.0) * DN_MAX).astype(np.uint16)
    n_rows, n_cols = OUT_SHAPE
    transform = from_origin(-180.0, 90.0, 360.0 / n_cols, 180.0 / n_rows)
    crs = CRS.from_proj4(CRS_PROJ4)
    sha = hashlib.sha256(src.read_bytes()).hexdigest()
    tags = {
        "STARNAV_PRODUCT": "LROC WAC mosaic, one relative linear grey channel",
        "STARNAV_VALUES": "RELATIVE linear brightness 0..1 (CIE Y of linear sRGB), NOT "
                          "calibrated reflectance: the absolute scale is calibrated against the "
                          "ROLO lunar model elsewhere (starnav.lunar_calibration)",
        "STARNAV_SOURCE": "NASA SVS CGI Moon Kit (svs.gsfc.nasa.gov/4720), LROC WAC colour "
                          "mosaic lroc_color_poles_4k.jpg, NASA/GSFC/Arizona State University; "
                          "credit: NASA's Scientific Visualization Studio; file taken from "
                          f"github SEscobedo/artastra @ 79e7881c; sha256 {sha}",
        "STARNAV_CONVERSION": "tools/convert_lroc_albedo.py: sRGB decoded to linear "
                              "(colour.cctf_decoding, function='sRGB'), Y = 0.2126 R + 0.7152 G "
                              "+ 0.0722 B (Rec. 709), area-average 4096x2048 -> 2048x1024, "
                              "DN = round(Y * 65535), band scale 1/65535, offset 0",
        "STARNAV_GRID": "equirectangular, pixel-is-area, west edge -180 deg (longitude 0 at "
                        "the centre, east to the right), north edge +90 deg, 360/2048 deg/px",
    }
    with atomic_path(out, suffix=".tif") as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=n_cols, height=n_rows, count=1,
                           dtype="uint16", crs=crs, transform=transform, compress="deflate",
                           predictor=2, zlevel=9, tiled=True, blockxsize=256,
                           blockysize=256) as ds:
            ds.write(dn, 1)
            ds.scales = (1.0 / DN_MAX,)
            ds.offsets = (0.0,)
            ds.update_tags(**tags)
            ds.set_band_description(1, "relative linear grey (CIE Y), decodes to 0..1")
        _check_round_trip(tmp, dn, crs, transform)
    v = dn.astype(np.float64) / DN_MAX
    return {"path": str(out), "shape": dn.shape, "dtype": str(dn.dtype), "min": float(v.min()),
            "mean": float(v.mean()), "max": float(v.max()), "bytes": out.stat().st_size,
            "source_sha256": sha}


def _check_round_trip(path: Path, dn: NDArray[np.uint16], crs: Any, transform: Any) -> None:
    """Read the written file back: pixels, scale/offset, CRS and geotransform unchanged."""
    import rasterio

    with rasterio.open(path) as ds:
        back = ds.read(1)
        ok = (np.array_equal(back, dn) and ds.scales[0] == 1.0 / DN_MAX and ds.offsets[0] == 0.0
              and ds.crs is not None and ds.crs.is_geographic
              and ds.crs.to_dict() == crs.to_dict()  # GeoTIFF stores lat/lon axis order: not ==
              and ds.transform.almost_equals(transform) and ds.nodata is None)
        got = (ds.crs.to_proj4() if ds.crs else None, tuple(ds.transform)[:6], ds.scales,
               ds.offsets, ds.nodata)
    if not ok:
        raise SystemExit(f"{path}: the GeoTIFF does not round-trip: {got}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC, help="lroc_color_poles_4k.jpg")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="GeoTIFF to write")
    a = ap.parse_args(argv)
    if not a.src.is_file():
        print(f"error: {a.src} does not exist", file=sys.stderr)
        return 2
    r = convert(a.src, a.out)
    print(f"wrote {r['path']}: {r['shape'][1]} x {r['shape'][0]} px {r['dtype']}, "
          f"{r['bytes'] / 1e6:.2f} MB; decoded (linear, 0..1): min {r['min']:.4f}, "
          f"mean {r['mean']:.4f}, max {r['max']:.4f} (unweighted)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
