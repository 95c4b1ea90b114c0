"""The real data shipped in ``starnav/data``: LOLA LDEM_4 and the LROC WAC grey albedo map.

Read with starnav's own readers (:func:`starnav.dem.load_dem`, :func:`starnav.dem.readers.
read_albedo`), from the installed package only (no /work/shared, no network). The checks are on
the Moon itself: published LOLA extremes, the South Pole-Aitken basin, the far-side highlands,
and map features whose places every lunar atlas gives (so a flipped or shifted map fails).
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from starnav.data import LDEM_4_LABEL, LROC_ALBEDO, packaged_path
from starnav.dem import DemConfig, load_dem
from starnav.dem.grid import AlbedoGrid, EquirectangularGrid
from starnav.dem.readers import read_albedo
from starnav.dem.schema import AlbedoConfig
from starnav.errors import DataFileError

# Smith, D. E. et al. (2010), Initial observations from the Lunar Orbiter Laser Altimeter,
# GRL 37, L18204: heights relative to 1737.4 km range from -9.133 km (in Antoniadi crater,
# 70.3646 S, 187.7673 E) to +10.786 km (5.4125 N, 201.3665 E, near Engel'gardt).
LOLA_LOWEST_M, LOLA_LOWEST_LAT_LON = -9133.0, (-70.3646, 187.7673)
LOLA_HIGHEST_M, LOLA_HIGHEST_LAT_LON = 10786.0, (5.4125, 201.3665)
#: At 4 px/deg (7.58 km cells, each the mean of many LOLA shots) a pit or a summit a few km
#: across is averaged with its surroundings: the grid's extremes may be up to 1 km less extreme
#: than the published ones (LDEM_4 V3.0: -8.879 / +10.504 km), never more extreme by more than
#: the later data's adjustment (50 m).
SMOOTHING_MARGIN_M = 1000.0
OVERSHOOT_M = 50.0
#: The extremes must lie in the published places within this [deg of arc] (2 cells).
EXTREME_PLACE_TOL_DEG = 0.5
#: Cell registration: 1/1000 of a 0.25 deg cell (7.6 m). GDAL builds the grid from the label's
#: rounded MAP_SCALE (7580.84 m/px), which puts the edges ~6e-5 deg (2 m) off the label's exact
#: 90 N / 0 E; the pixel-is-point mistake (half a cell, 0.125 deg) fails by a factor of 500.
REGISTRATION_TOL_DEG = 0.25e-3

#: SHA-256 recorded in data/lola/PROVENANCE.md: the files are copies, unchanged.
LDEM_4_SHA256 = {
    "LDEM_4.IMG": "972d66d7f330abca62abc21aae270661516c00dd1a881ec102b94df9563656b5",
    "LDEM_4.LBL": "b5a197b4d417e3b5e0e84f8fe15f9a1d2203b8eb5d7213236c0ffbc86e940cc6",
}

# Albedo-map features (IAU names, centres from the Lunar Gazetteer), and the contrasts the
# tests require. Each threshold sits between the true map's value and the value of the same
# check on the east/west-mirrored map, with a margin on both sides (values measured on the
# packaged map: Crisium 0.33 vs mirror 0.67; Tycho 1.40 vs mirror 0.90).
CRISIUM = (17.0, 59.0)              # Mare Crisium, an isolated mare ringed by highlands
CRISIUM_MAX_CONTRAST = 0.5          # centre (3 deg disc) / ring 9-12 deg from the centre
TYCHO = (-43.3, -11.4)              # Tycho: young, bright floor and central peak
TYCHO_MIN_CONTRAST = 1.25           # centre (1 deg disc) / ring 2-4 deg (the ejecta blanket)
IMBRIUM = (33.0, -16.0)             # Mare Imbrium
IMBRIUM_MAX_OF_MEAN = 0.5           # 4 deg disc / global area-weighted mean


@pytest.fixture(scope="module")
def ldem4():
    return load_dem(DemConfig(source=str(packaged_path(LDEM_4_LABEL))))


@pytest.fixture(scope="module")
def lroc() -> AlbedoGrid:
    p = packaged_path(LROC_ALBEDO)
    return read_albedo(p, AlbedoConfig(source=str(p), decoding="linear"))


def _cap_mean(grid: EquirectangularGrid, lat_deg: float, lon_deg: float, r0_deg: float,
              r1_deg: float) -> float:
    """Area-weighted mean of ``grid`` over the spherical ring ``r0..r1`` [deg of arc] around
    (lat, lon) [deg]: a polar grid of 0.1 deg x 5 deg cells weighted by sin(r)."""
    r = np.radians(np.arange(r0_deg + 0.05, r1_deg, 0.1))[:, None]
    az = np.radians(np.arange(2.5, 360.0, 5.0))[None, :]
    la0, lo0 = math.radians(lat_deg), math.radians(lon_deg)
    lat = np.arcsin(np.sin(la0) * np.cos(r) + np.cos(la0) * np.sin(r) * np.cos(az))
    lon = lo0 + np.arctan2(np.sin(az) * np.sin(r) * np.cos(la0),
                           np.cos(r) - np.sin(la0) * np.sin(lat))
    w = np.broadcast_to(np.sin(r), lat.shape)
    return float(np.average(grid.sample(lat, lon), weights=w))


def _box_mean(grid: EquirectangularGrid, lat: tuple[float, float],
              lon: tuple[float, float]) -> float:
    """Area-weighted mean over a lat/lon box [deg], sampled every 0.25 deg."""
    la = np.radians(np.arange(lat[0], lat[1] + 1e-9, 0.25))
    lo = np.radians(np.arange(lon[0], lon[1] + 1e-9, 0.25))
    LA, LO = np.meshgrid(la, lo, indexing="ij")
    return float(np.average(grid.sample(LA, LO), weights=np.cos(LA)))


def _arc_deg(a: tuple[float, float], b: tuple[float, float]) -> float:
    la1, lo1, la2, lo2 = map(math.radians, (*a, *b))
    c = (math.sin(la1) * math.sin(la2)
         + math.cos(la1) * math.cos(la2) * math.cos(lo1 - lo2))
    return math.degrees(math.acos(min(1.0, c)))


def _mirrored(g: AlbedoGrid) -> AlbedoGrid:
    """The map flipped east/west about the central meridian (a sign error in longitude)."""
    return AlbedoGrid(g.values[:, ::-1], extent=g.extent, quantity=g.quantity, source="mirror")


def crisium_contrast(g: AlbedoGrid) -> float:
    return _cap_mean(g, *CRISIUM, 0.0, 3.0) / _cap_mean(g, *CRISIUM, 9.0, 12.0)


def tycho_contrast(g: AlbedoGrid) -> float:
    return _cap_mean(g, *TYCHO, 0.0, 1.0) / _cap_mean(g, *TYCHO, 2.0, 4.0)


# ----------------------------------------------------------------------------- packaging
def test_packaged_path_finds_the_files_and_names_a_missing_one():
    for rel in (LDEM_4_LABEL, LROC_ALBEDO, "lola/LDEM_4.IMG", "lola/PROVENANCE.md",
                "albedo/PROVENANCE.md"):
        assert packaged_path(rel).is_file(), rel
    with pytest.raises(DataFileError, match="starnav/data/lola/LDEM_64.LBL"):
        packaged_path("lola/LDEM_64.LBL")
    with pytest.raises(DataFileError, match="inside starnav/data"):
        packaged_path("../errors.py")


def test_ldem4_files_are_the_unchanged_pds_product():
    for name, sha in LDEM_4_SHA256.items():
        data = packaged_path(f"lola/{name}").read_bytes()
        assert hashlib.sha256(data).hexdigest() == sha, name
        assert sha in packaged_path("lola/PROVENANCE.md").read_text()


# ----------------------------------------------------------------------------- LOLA
def test_ldem4_loads_as_heights_in_metres(ldem4):
    assert ldem4.shape == (720, 1440)
    assert ldem4.pixels_per_degree == pytest.approx(4.0)
    assert ldem4.is_global_lon and ldem4.is_global_lat
    # pixel registration of the label: line 0 at 89.875 N, sample 0 at 0.125 E
    assert math.degrees(ldem4.lat_centres()[0]) == pytest.approx(89.875,
                                                                 abs=REGISTRATION_TOL_DEG)
    lon0 = math.degrees(ldem4.lon_centres()[0]) % 360.0
    assert lon0 == pytest.approx(0.125, abs=REGISTRATION_TOL_DEG)
    lo, hi = ldem4.height_range
    assert LOLA_LOWEST_M - OVERSHOOT_M <= lo <= LOLA_LOWEST_M + SMOOTHING_MARGIN_M
    assert LOLA_HIGHEST_M - SMOOTHING_MARGIN_M <= hi <= LOLA_HIGHEST_M + OVERSHOOT_M
    # half-metre DN: every height is a multiple of 0.5 m (no radius left in, no rescaling)
    h = ldem4.heights
    assert np.array_equal(h * 2.0, np.round(h * 2.0))
    # ... and the extremes are where LOLA found them (a longitude or latitude flip fails)
    lat = np.degrees(ldem4.lat_centres())
    lon = np.degrees(ldem4.lon_centres())
    for idx, place in ((np.argmin(h), LOLA_LOWEST_LAT_LON), (np.argmax(h), LOLA_HIGHEST_LAT_LON)):
        i, j = np.unravel_index(idx, h.shape)
        assert _arc_deg((lat[i], lon[j]), place) < EXTREME_PLACE_TOL_DEG


def test_ldem4_south_pole_aitken_is_low_and_far_side_highlands_high(ldem4):
    # SPA basin (centre ~53 S, 169 W; ~2 500 km across, floor ~-5 km): a 14 x 14 deg box
    spa = _box_mean(ldem4, (-60.0, -46.0), (-176.0, -162.0))
    # far-side highlands around the highest point (Korolev-Engel'gardt, ~5 N, 159 W)
    highlands = _box_mean(ldem4, (-10.0, 10.0), (-170.0, -150.0))
    assert spa < -3000.0
    assert highlands > 3000.0
    # the near-side maria are low too, but far above SPA's floor: the basin is the deepest
    assert _box_mean(ldem4, (25.0, 40.0), (-25.0, -5.0)) > spa + 1000.0  # Mare Imbrium


# ----------------------------------------------------------------------------- LROC albedo
def test_lroc_map_decodes_to_relative_linear_0_1(lroc):
    assert lroc.shape == (1024, 2048)
    assert [round(math.degrees(v), 9) for v in lroc.extent] == [-180.0, 180.0, -90.0, 90.0]
    v = lroc.values
    assert v.dtype == np.float32
    assert 0.0 < float(v.min()) and float(v.max()) <= 1.0
    # the band scale 1/65535 is applied (raw DN would be up to 65535): the brightest cells are
    # saturated white in the source (1.0), the mean is a mid grey
    assert float(v.max()) == pytest.approx(1.0, abs=1e-6)
    assert 0.15 < lroc.mean < 0.5
    import rasterio

    with rasterio.open(packaged_path(LROC_ALBEDO)) as ds:
        assert ds.dtypes[0] == "uint16" and ds.compression.value == "DEFLATE"
        assert ds.crs.is_geographic and ds.crs.to_dict().get("R") == 1737400
        assert "RELATIVE linear brightness" in ds.tags()["STARNAV_VALUES"]


def test_lroc_map_orientation_on_known_features(lroc):
    assert crisium_contrast(lroc) < CRISIUM_MAX_CONTRAST
    assert tycho_contrast(lroc) > TYCHO_MIN_CONTRAST
    assert _cap_mean(lroc, *IMBRIUM, 0.0, 4.0) < IMBRIUM_MAX_OF_MEAN * lroc.mean


def test_lroc_orientation_checks_fail_on_a_mirrored_map(lroc):
    mirror = _mirrored(lroc)
    # Crisium's place in the mirror is 59 W, inside Oceanus Procellarum: dark, but so is the ring
    assert crisium_contrast(mirror) > CRISIUM_MAX_CONTRAST
    assert tycho_contrast(mirror) < TYCHO_MIN_CONTRAST
