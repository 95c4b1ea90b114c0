"""Readers: LOLA PDS3, GeoTIFF (plain and SVS kit), .npy, albedo decodings, and bad input.

Every file is written here (no data is downloaded): the PDS3 pair by hand in the LDEM_4 label
layout (conftest.write_pds3), the GeoTIFFs with rasterio.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import rasterio
from _dem_files import PDS_TYPES, write_pds3
from pydantic import ValidationError
from rasterio.crs import CRS
from rasterio.transform import from_bounds

from starnav.constants import MOON_RADIUS
from starnav.dem.grid import DemGrid
from starnav.dem.readers import (
    DemFileError,
    dem_info,
    detect_format,
    encode_svs_8bit,
    read_albedo,
    read_dem,
    write_geotiff,
)
from starnav.dem.schema import AlbedoConfig, DemConfig
from starnav.errors import ConfigError, DataFileError

#: float32 heights of a few km carry ~0.5 mm of rounding.
HEIGHT_TOL_M = 2e-3


def _centres(grid: DemGrid) -> tuple[np.ndarray, np.ndarray]:
    lat, lon = np.meshgrid(grid.lat_centres(), grid.lon_centres(), indexing="ij")
    return lat, lon


# ------------------------------------------------------------------------- PDS3
@pytest.mark.parametrize(("sample_type", "bits"), sorted(PDS_TYPES))
def test_pds3_honours_sample_type_scaling_and_offset(tmp_path, relief_dn, sample_type, bits):
    """Heights = DN * SCALING_FACTOR + OFFSET - A_AXIS_RADIUS with a non-default offset and
    scale, for every sample type (byte order, signedness, integer/real): a reader that ignored
    any of them would be off by metres to kilometres."""
    dn = relief_dn.astype(np.int64)
    if "UNSIGNED" in sample_type:
        dn = dn - dn.min() if bits == 16 else np.clip((dn - dn.min()) // 64, 0, 255)
    scaling, offset = 0.25, 1_737_000.0  # LOLA uses 0.5 and 1 737 400 m
    lbl = write_pds3(tmp_path, "LDEM_T", dn, sample_type=sample_type, bits=bits,
                     scaling=scaling, offset=offset)
    g = read_dem(lbl)
    expected = dn * scaling + offset - 1_737_400.0
    np.testing.assert_allclose(g.heights, expected, atol=HEIGHT_TOL_M, rtol=0)
    assert g.reference_radius == pytest.approx(1_737_400.0)
    # LOLA global products run 0..360 deg east from the left edge
    assert g.extent == pytest.approx((0.0, 2 * math.pi, -math.pi / 2, math.pi / 2), abs=1e-9)


def test_pds3_heights_offset_zero_and_kilometres(tmp_path, relief_dn):
    """OFFSET = 0 means the values are heights, not radii; UNIT = KILOMETER converts."""
    lbl = write_pds3(tmp_path, "H", relief_dn, scaling=0.0005, offset=0.0, unit="KILOMETER")
    g = read_dem(lbl)
    np.testing.assert_allclose(g.heights, relief_dn * 0.5, atol=HEIGHT_TOL_M, rtol=0)


def test_pds3_reference_radius_from_label(tmp_path, relief_dn):
    """A_AXIS_RADIUS sets the reference sphere the radii are reduced to."""
    lbl = write_pds3(tmp_path, "R", relief_dn, offset=1_738_000.0, radius_km=1738.0)
    g = read_dem(lbl)
    assert g.reference_radius == pytest.approx(1_738_000.0)
    np.testing.assert_allclose(g.heights, relief_dn * 0.5, atol=HEIGHT_TOL_M, rtol=0)


def test_pds3_open_by_img_name_and_info(tmp_path, relief_dn):
    write_pds3(tmp_path, "LDEM_X", relief_dn)
    g = read_dem(tmp_path / "LDEM_X.IMG")
    assert g.shape == (36, 72)
    info = dem_info(g)
    assert info.pixels_per_degree == pytest.approx(0.2)
    assert info.height_min_m == pytest.approx(relief_dn.min() * 0.5, abs=HEIGHT_TOL_M)
    assert info.height_max_m == pytest.approx(relief_dn.max() * 0.5, abs=HEIGHT_TOL_M)
    assert info.cell_km == pytest.approx(math.pi * 1737.4 / 36)


def test_pds3_decimation_is_an_area_average(tmp_path, relief_dn):
    lbl = write_pds3(tmp_path, "D", relief_dn)
    g = read_dem(lbl, DemConfig(source=str(lbl), max_pixels_per_degree=0.1))
    assert g.shape == (18, 36)
    full = relief_dn * 0.5
    np.testing.assert_allclose(g.heights, full.reshape(18, 2, 36, 2).mean(axis=(1, 3)),
                               atol=HEIGHT_TOL_M)


# ------------------------------------------------------------------------- GeoTIFF / npy
def _write_tif(path, values, *, crs=None, bounds=None, units=None, scale=None, offset=None):
    h, w = values.shape
    kw = {}
    if crs is not None:
        kw.update(crs=crs, transform=from_bounds(*bounds, w, h))
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1,
                       dtype=values.dtype, **kw) as ds:
        ds.write(values, 1)
        if units:
            ds.units = (units,)
        if scale is not None:
            ds.scales = (scale,)
            ds.offsets = (offset,)


def test_geotiff_readers_give_the_same_heights_as_pds3(tmp_path, relief_dn):
    """The same grid as PDS3 (0..360), SVS-kit float-km TIFF (-180..180, no georeferencing),
    geographic GeoTIFF in metres, equirectangular GeoTIFF with scale/offset, and .npy give
    identical bilinear heights everywhere (longitudes of the others are shifted by 180 deg)."""
    h_m = relief_dn * 0.5
    ref = read_dem(write_pds3(tmp_path, "LDEM_4", relief_dn))
    rolled = np.roll(h_m, 36, axis=1)  # 0..360 -> -180..180
    _write_tif(tmp_path / "ldem_4.tif", (rolled / 1e3).astype(np.float32))
    geo = CRS.from_user_input("IAU_2015:30100")
    _write_tif(tmp_path / "geo.tif", rolled.astype(np.float32), crs=geo,
               bounds=(-180, -90, 180, 90), units="m")
    eqc = CRS.from_proj4(f"+proj=eqc +lon_0=180 +R={MOON_RADIUS} +units=m +no_defs")
    half = math.pi * MOON_RADIUS
    _write_tif(tmp_path / "eqc.tif", relief_dn, crs=eqc,
               bounds=(-half, -half / 2, half, half / 2), units="m", scale=0.5, offset=0.0)
    np.save(tmp_path / "dem.npy", rolled.astype(np.float32))
    assert detect_format(tmp_path / "ldem_4.tif") == "svs-geotiff"
    assert detect_format(tmp_path / "geo.tif") == "geotiff"
    rng = np.random.default_rng(3)
    lat = np.arcsin(rng.uniform(-1, 1, 2000))
    lon = rng.uniform(-math.pi, math.pi, 2000)
    want = ref.sample(lat, lon)
    for name in ("ldem_4.tif", "geo.tif", "eqc.tif", "dem.npy"):
        g = read_dem(tmp_path / name)
        np.testing.assert_allclose(g.sample(lat, lon), want, atol=HEIGHT_TOL_M, rtol=0,
                                   err_msg=name)
    assert want.std() > 500.0  # the relief is not trivially flat


def test_svs_uint16_half_metres_plus_20000(tmp_path, relief_dn):
    """SVS kit 16-bit TIFF: DN = source half-metres + 20 000."""
    dn = (relief_dn.astype(np.int64) + 20_000).astype(np.uint16)
    _write_tif(tmp_path / "ldem_4_uint.tif", dn)
    g = read_dem(tmp_path / "ldem_4_uint.tif")
    np.testing.assert_allclose(g.heights, relief_dn * 0.5, atol=HEIGHT_TOL_M, rtol=0)


def test_write_geotiff_round_trip(tmp_path, relief_dn):
    ref = read_dem(write_pds3(tmp_path, "A", relief_dn))
    out = write_geotiff(ref, tmp_path / "out" / "a.tif")
    g = read_dem(out)
    np.testing.assert_array_equal(g.heights, ref.heights)
    assert g.extent == pytest.approx(ref.extent, abs=1e-9)


# ------------------------------------------------------------------------- bad input
def test_truncated_img_is_an_error(tmp_path, relief_dn):
    lbl = write_pds3(tmp_path, "T", relief_dn, truncate=10)
    with pytest.raises(DemFileError, match=r"T\.IMG: file size = '5174 bytes'.*5184 bytes.*"
                                           r"truncated"):
        read_dem(lbl)


def test_label_size_mismatch_is_an_error(tmp_path, relief_dn):
    lbl = write_pds3(tmp_path, "M", relief_dn, extra_bytes=144)
    with pytest.raises(DemFileError, match="label and file size do not match"):
        read_dem(lbl)
    # LINES says 37 rows: 144 bytes more than the file holds
    lbl = write_pds3(tmp_path, "L", relief_dn, lines=37)
    with pytest.raises(DemFileError, match="LINES 37.*truncated"):
        read_dem(lbl)


def test_label_lines_contradicting_latitude_extent(tmp_path, relief_dn):
    """36 lines at 0.2 px/deg cover 180 deg; a label claiming 90..-80 deg contradicts itself."""
    lbl = write_pds3(tmp_path, "C", relief_dn, max_lat=80.0)
    with pytest.raises(DemFileError, match=r"IMAGE\.LINES = 36: expected 34 lines"):
        read_dem(lbl)


def test_latitude_out_of_range(tmp_path, relief_dn):
    lbl = write_pds3(tmp_path, "O", relief_dn, max_lat=95.0)
    with pytest.raises(DemFileError, match=r"MAXIMUM_LATITUDE = '95 deg': expected a "
                                           r"latitude within -90\.\.90 deg"):
        read_dem(lbl)
    with pytest.raises(ConfigError, match=r"dem\.extent\.north = '95 deg'"):
        DemGrid(np.zeros((4, 8)), extent=(-math.pi, math.pi, -math.pi / 2, math.radians(95)))
    with pytest.raises(ValidationError, match=r"latitude edges .* out of range"):
        DemConfig(extent_deg=(-180, 180, -90, 91))


def test_nan_heights_are_an_error(tmp_path):
    a = np.zeros((10, 20), np.float32)
    a[3, 7] = np.nan
    np.save(tmp_path / "nan.npy", a)
    with pytest.raises(ConfigError, match=r"dem\.heights = '1 NaN/inf cell\(s\), first at row "
                                          r"3, column 7 \(lat 27\.0000 deg, lon -45\.0000 deg\)"):
        read_dem(tmp_path / "nan.npy")
    # GeoTIFF no-data cells are NaN too
    b = np.zeros((10, 20), np.float32)
    b[0, 0] = -9999.0
    with rasterio.open(tmp_path / "nd.tif", "w", driver="GTiff", width=20, height=10, count=1,
                       dtype="float32", nodata=-9999.0) as ds:
        ds.write(b, 1)
    with pytest.raises(ConfigError, match="NaN/inf cell"):
        read_dem(tmp_path / "nd.tif")


def test_radii_read_as_heights_are_an_error(tmp_path):
    np.save(tmp_path / "radii.npy", np.full((10, 20), MOON_RADIUS, np.float32))
    with pytest.raises(ConfigError, match=r"are these radii"):
        read_dem(tmp_path / "radii.npy", DemConfig(source="x", vertical="height"))
    g = read_dem(tmp_path / "radii.npy")  # auto: recognised as radii
    assert np.all(g.heights == 0.0)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(DataFileError, match="does not exist"):
        read_dem(tmp_path / "nope.tif")
    (tmp_path / "junk.tif").write_bytes(b"not a tiff")
    with pytest.raises(DemFileError, match="a raster GDAL can open"):
        read_dem(tmp_path / "junk.tif")


# ------------------------------------------------------------------------- albedo
def test_albedo_svs_8bit_decoding(tmp_path):
    """SVS kit: gamma 2.8 then (0.16, 0.40) -> 0..255, so DN 0 -> 0.16^2.8 = 0.005918 and
    DN 255 -> 0.40^2.8 = 0.07689 (computed by hand)."""
    dn = np.zeros((10, 20), np.uint8)
    dn[:, 10:] = 255
    _write_tif(tmp_path / "c.tif", dn)
    g = read_albedo(tmp_path / "c.tif", AlbedoConfig(source="c"))
    assert g.values[0, 0] == pytest.approx(0.16**2.8, rel=1e-5)
    assert g.values[0, 15] == pytest.approx(0.40**2.8, rel=1e-5)
    # round trip through the encoder over the whole domain, within one DN
    r = np.linspace(0.16**2.8, 0.40**2.8, 200).reshape(10, 20)
    _write_tif(tmp_path / "r.tif", encode_svs_8bit(r))
    back = read_albedo(tmp_path / "r.tif").values
    step = (0.40**2.8 - 0.16**2.8) * 2.8 / 255  # worst-case d r / d DN bound
    assert np.max(np.abs(back - r)) < step


def test_albedo_rgb_colour_balance_and_band(tmp_path):
    rgb = np.full((3, 4, 8), 200, np.uint8)
    with rasterio.open(tmp_path / "rgb.tif", "w", driver="GTiff", width=8, height=4, count=3,
                       dtype="uint8") as ds:
        ds.write(rgb)
    enc = 0.16 + 0.24 * 200 / 255
    want = np.mean([(enc / b) ** 2.8 for b in (0.935, 1.005, 1.04)])
    g = read_albedo(tmp_path / "rgb.tif")
    assert g.values[0, 0] == pytest.approx(want, rel=1e-5)
    g1 = read_albedo(tmp_path / "rgb.tif", AlbedoConfig(band=1))
    assert g1.values[0, 0] == pytest.approx(enc**2.8, rel=1e-5)


def test_albedo_16bit_float_hapke_and_normalisation(tmp_path):
    a16 = np.full((4, 8), 13107, np.uint16)  # 13107 / 65535 = 0.2
    _write_tif(tmp_path / "a16.tif", a16)
    assert read_albedo(tmp_path / "a16.tif").values[0, 0] == pytest.approx(0.2, rel=1e-6)
    w = np.linspace(0.1, 0.5, 32, dtype=np.float32).reshape(4, 8)
    _write_tif(tmp_path / "w.tif", w)
    g = read_albedo(tmp_path / "w.tif", AlbedoConfig(quantity="hapke_w"))
    assert g.quantity == "hapke_w"
    np.testing.assert_allclose(g.values, w)
    n = read_albedo(tmp_path / "w.tif", AlbedoConfig(normalize_mean=0.12))
    assert n.mean == pytest.approx(0.12, rel=1e-5)
    _write_tif(tmp_path / "bad.tif", w * 4)
    with pytest.raises(ConfigError, match=r"albedo\.values = 'range 0\.4\.\.2'"):
        read_albedo(tmp_path / "bad.tif")
