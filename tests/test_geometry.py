"""Static frame geometry: requested pixel, phase angle, limb; EXR round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.errors import GeometryError
from starnav.geometry import geometry_from_dict, geometry_to_dict, static_geometry
from starnav.radiance import RadianceImage, read_exr, write_exr

PIXEL_TOL = 1e-6


@pytest.mark.parametrize("offset", [(0.0, 0.0), (300.0, -200.0), (-410.5, 380.25)])
def test_moon_centre_lands_on_requested_pixel(aa_str, offset):
    g = static_geometry(aa_str, 6e7, math.radians(40), offset, roll=0.3, sun_azimuth=1.0,
                        sub_observer_lat=0.2, sub_observer_lon=-0.7)
    uv = g.moon_centre_pixel(aa_str)
    assert np.allclose(uv, [aa_str.cx + offset[0], aa_str.cy + offset[1]], atol=PIXEL_TOL)
    assert g.phase_angle == pytest.approx(math.radians(40), abs=1e-12)
    assert g.range == pytest.approx(6e7)


def test_limb_points_are_at_the_apparent_radius(aa_str):
    g = static_geometry(aa_str, 6e7, 0.5, (350.0, 300.0))
    uv = g.limb_points(aa_str, 720)
    rays = aa_str.unproject(uv)
    centre = g.moon_centre_camera() / g.range
    ang = np.arccos(np.clip(rays @ centre, -1, 1))
    assert np.allclose(ang, g.apparent_radius, atol=1e-10)


def test_observer_inside_the_moon_is_rejected(aa_str):
    with pytest.raises(GeometryError, match="inside the Moon"):
        static_geometry(aa_str, 1.0e6, 0.3)


def test_geometry_dict_round_trip(aa_str):
    g = static_geometry(aa_str, 7e7, 1.0, (5.0, 6.0), roll=0.2)
    g2 = geometry_from_dict(geometry_to_dict(g))
    assert np.array_equal(g2.R_cam_to_inertial, g.R_cam_to_inertial)
    assert np.array_equal(g2.camera_position, g.camera_position)


def test_exr_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    img = RadianceImage(rng.random((6, 9), dtype=np.float32) * 50,
                        rng.random((6, 9), dtype=np.float32) * 1e19,
                        {"mask": (rng.random((6, 9)) > 0.5).astype(np.float32)},
                        {"geometry": {"range_m": 6e7}, "note": "x"})
    p = write_exr(img, tmp_path / "a.exr")
    back = read_exr(p)
    assert np.array_equal(back.L, img.L) and np.array_equal(back.Le, img.Le)
    assert np.array_equal(back.aovs["mask"], img.aovs["mask"])
    assert back.meta == img.meta
    assert [x.name for x in tmp_path.iterdir()] == ["a.exr"]
