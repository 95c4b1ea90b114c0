"""Grid model: coordinates, bilinear sampling with longitude wrap, pyramid levels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.constants import MOON_RADIUS
from starnav.dem.grid import (
    AlbedoGrid,
    DemGrid,
    area_resample,
    body_to_selenographic,
    selenographic_to_body,
)
from starnav.errors import ConfigError

#: Coordinate round trips are exact to float64 rounding at the lunar radius [m].
METRE_TOL = 1e-6


def test_selenographic_body_round_trip_and_axes():
    """+x at (0, 0), +y at (0, 90E), +z at the north pole (module conventions)."""
    R = MOON_RADIUS
    np.testing.assert_allclose(selenographic_to_body(0.0, 0.0), [R, 0, 0], atol=METRE_TOL)
    np.testing.assert_allclose(selenographic_to_body(0.0, math.pi / 2), [0, R, 0],
                               atol=METRE_TOL)
    np.testing.assert_allclose(selenographic_to_body(math.pi / 2, 1.0, 100.0), [0, 0, R + 100],
                               atol=METRE_TOL)
    rng = np.random.default_rng(1)
    lat = np.arcsin(rng.uniform(-1, 1, 1000))
    lon = rng.uniform(-math.pi, math.pi, 1000)
    h = rng.uniform(-9000, 11000, 1000)
    la, lo, hh = body_to_selenographic(selenographic_to_body(lat, lon, h))
    np.testing.assert_allclose(la, lat, atol=1e-12)
    np.testing.assert_allclose(lo, lon, atol=1e-12)
    np.testing.assert_allclose(hh, h, atol=METRE_TOL)
    # longitudes come back in [-pi, pi)
    _, lo2, _ = body_to_selenographic(selenographic_to_body(0.0, np.radians([180.0, 359.0])))
    np.testing.assert_allclose(np.degrees(lo2), [-180.0, -1.0], atol=1e-9)


def _ramp_grid(west_deg: float = -180.0) -> DemGrid:
    lat = np.radians(85.0 - 10.0 * np.arange(18))
    lon = np.radians(west_deg + 5.0 + 10.0 * np.arange(36))
    v = 1000.0 * np.sin(lat)[:, None] + 500.0 * np.cos(lon)[None, :] + \
        200.0 * np.sin(2 * lon)[None, :]
    ext = (math.radians(west_deg), math.radians(west_deg + 360), -math.pi / 2, math.pi / 2)
    return DemGrid(v.astype(np.float32), extent=ext)


def test_bilinear_exact_at_centres_and_linear_between():
    g = _ramp_grid()
    lat = g.lat_centres()
    lon = g.lon_centres()
    np.testing.assert_array_equal(g.sample(lat[4], lon[7]), g.heights[4, 7])
    mid_lat = 0.5 * (lat[4] + lat[5])
    mid_lon = 0.5 * (lon[7] + lon[8])
    want = g.heights[4:6, 7:9].mean()
    assert float(g.sample(mid_lat, mid_lon)) == pytest.approx(float(want), abs=1e-3)


def test_longitude_wraps_across_the_seam_and_any_convention():
    """Between the last and the first column the interpolation wraps; longitudes given in
    [0, 360) or beyond 360 are the same points; a grid stored 0..360 gives the same samples as
    the same grid stored -180..180."""
    g = _ramp_grid(-180.0)
    seam = math.radians(180.0)  # midway between the last (175) and first (-175) centres
    want = 0.5 * (g.heights[6, -1] + g.heights[6, 0])
    lat = g.lat_centres()[6]
    for lon in (seam, -seam, seam + 2 * math.pi, seam - 4 * math.pi):
        assert float(g.sample(lat, lon)) == pytest.approx(float(want), abs=1e-3)
    g360 = DemGrid(np.roll(g.heights, -18, axis=1), extent=(0, 2 * math.pi, -math.pi / 2,
                                                            math.pi / 2))
    rng = np.random.default_rng(2)
    la = np.arcsin(rng.uniform(-1, 1, 500))
    lo = rng.uniform(-3 * math.pi, 3 * math.pi, 500)
    np.testing.assert_allclose(g360.sample(la, lo), g.sample(la, lo), atol=1e-3)


def test_poles_clamp_and_latitude_out_of_range():
    g = _ramp_grid()
    assert float(g.sample(math.pi / 2, 0.3)) == pytest.approx(float(g.sample(
        g.lat_centres()[0], 0.3)), abs=1e-3)
    with pytest.raises(ConfigError, match=r"lat = '95\.0 deg': expected a latitude within"):
        g.sample(math.radians(95.0), 0.0)
    with pytest.raises(ConfigError, match="lon"):
        g.sample(0.0, math.nan)


def test_regional_grid_fills_outside():
    ext = tuple(math.radians(v) for v in (10.0, 20.0, -5.0, 5.0))
    g = DemGrid(np.full((10, 10), 7.0, np.float32), extent=ext)
    assert not g.is_global_lon and not g.is_global_lat
    out = g.sample(np.radians([0.0, 0.0, 30.0, 0.0]), np.radians([15.0, 25.0, 15.0, 375.0]))
    np.testing.assert_array_equal(out, [7.0, 0.0, 0.0, 7.0])


def test_pyramid_levels_are_area_means():
    g = _ramp_grid()
    l1 = g.level(1)
    assert l1.shape == (9, 18)
    np.testing.assert_allclose(l1.heights, g.heights.reshape(9, 2, 18, 2).mean(axis=(1, 3)),
                               atol=1e-3)
    assert g.level(1) is l1  # kept
    assert g.level(99).shape == g.level(g.max_level).shape
    c0 = g.cell_size()
    assert g.level_for_spacing(0.5 * c0) == 0
    assert g.level_for_spacing(2.1 * c0) == 1
    # non-integer factor: the mean is preserved
    a = np.random.default_rng(0).normal(size=(30, 60)).astype(np.float32)
    b = area_resample(a, (7, 13))
    assert float(b.mean()) == pytest.approx(float(a.mean()), abs=1e-5)


def test_validation_messages():
    with pytest.raises(ConfigError, match=r"dem\.heights = 'array of shape \(5,\)'"):
        DemGrid(np.zeros(5))
    with pytest.raises(ConfigError, match=r"dem\.extent = .*west < east"):
        DemGrid(np.zeros((4, 4)), extent=(1.0, 0.5, -1.0, 1.0))
    with pytest.raises(ConfigError, match=r"albedo\.values = 'range -0\.1\.\.-0\.1'"):
        AlbedoGrid(np.full((4, 4), -0.1))
    with pytest.raises(ConfigError, match="albedo.quantity"):
        AlbedoGrid(np.zeros((4, 4)), quantity="bond")


def test_albedo_mean_is_area_weighted():
    """Bright polar rows must not dominate: a map 1 in the two polar rows (2 x 10 deg of 18)
    and 0 elsewhere has mean (1 - cos 10 deg) = 0.01519 (spherical zone area fraction)."""
    a = np.zeros((18, 36), np.float32)
    a[0] = a[-1] = 1.0
    g = AlbedoGrid(a)
    assert g.mean == pytest.approx(1.0 - math.cos(math.radians(10.0)), rel=2e-3)


def test_grids_are_read_only_and_have_content_ids():
    g = _ramp_grid()
    with pytest.raises(ValueError, match="read-only"):
        g.heights[0, 0] = 1.0
    assert g.uid == _ramp_grid().uid
    assert g.uid != DemGrid(g.heights + 1.0).uid


def test_a_turned_world_is_the_same_world_at_other_longitudes():
    """``rotated_east(a)``: the value that was at longitude ``lon`` is at ``lon + a``, exactly,
    for any angle (the grid's edges move, its cells do not), its mip levels too; a grid that
    does not cover all longitudes cannot turn. ``moon.dem.longitude_offset_deg`` turns the
    terrain and its albedo map together."""
    from starnav.dem.load import load_albedo, load_dem

    rng = np.random.default_rng(3)
    g = DemGrid(rng.normal(0, 1000, (90, 180)).astype(np.float32))
    a = math.radians(37.3)
    t = g.rotated_east(a)
    lat = rng.uniform(-1.5, 1.5, 500)
    lon = rng.uniform(-math.pi, math.pi, 500)
    assert np.allclose(t.sample(lat, lon + a), g.sample(lat, lon), atol=1e-3)
    assert np.allclose(t.level(2).sample(lat, lon + a), g.level(2).sample(lat, lon), atol=1e-3)
    assert t.uid != g.uid and g.rotated_east(0.0) is g
    part = DemGrid(np.zeros((10, 10), np.float32), extent=(0.0, 0.5, -0.5, 0.5))
    with pytest.raises(ConfigError, match="longitude_offset"):
        part.rotated_east(0.1)
    cfg = {"source": "lola", "albedo": {"source": "lroc"}}
    d0, d1 = load_dem(cfg), load_dem({**cfg, "longitude_offset_deg": 90.0})
    a0, a1 = load_albedo(cfg), load_albedo({**cfg, "longitude_offset_deg": 90.0})
    lon = rng.uniform(-math.pi, math.pi, 200)
    assert np.allclose(d1.sample(lat[:200], lon + math.pi / 2), d0.sample(lat[:200], lon),
                       atol=1e-2)
    assert np.allclose(a1.sample(lat[:200], lon + math.pi / 2), a0.sample(lat[:200], lon),
                       atol=1e-6)
