"""Rendered geometry: image orientation, limb of the mesh vs the exact sphere, AOVs, albedo
maps, the crop window, scalar vs llvm agreement, and bad input caught before rendering."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.bodies.mesh import icosphere_mesh
from starnav.bodies.model import AlbedoMap
from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.errors import ConfigError, DataFileError, GeometryError
from starnav.geometry import static_geometry
from starnav.renderer.render import moon_bounding_box

from .conftest import exact_solid_angles, make_renderer

R_MOON = 1.7374e6


def analytic_mask(camera: Camera, geom) -> np.ndarray:
    """Pixels whose centre ray meets the sphere (angle to the centre < apparent radius)."""
    u, v = camera.pixel_grid()
    rays = camera.unproject(np.stack([u, v], -1), undistort=False)
    c = geom.moon_centre_camera() / geom.range
    return rays @ c > math.cos(geom.apparent_radius)


def test_moon_is_where_the_camera_model_puts_it(aa_str):
    # Off-axis, the image of a sphere is an ellipse whose centre lies slightly outward of
    # the projected Moon centre (0.16 px here), so the exact check is the mask itself: the
    # pixel-centre mask equals the analytic cone test (a flipped, shifted or mis-scaled image
    # would differ by hundreds of pixels); the centroid is then near the projected centre.
    g = static_geometry(aa_str, 6.0e7, 0.0, (230.0, -140.0))
    img = make_renderer(shape="sphere").render(g, seed=1)
    diff = img.mask ^ analytic_mask(aa_str, g)
    assert diff.sum() <= 2
    ys, xs = np.nonzero(img.mask)
    uc, vc = g.moon_centre_pixel(aa_str)
    assert abs(xs.mean() - uc) < 0.5 and abs(ys.mean() - vc) < 0.5


def test_east_is_right_and_north_up(aa_str):
    # Sub-observer point (lat 0, lon 0), north up: selenographic east (+lon) is image right
    # (+u) and north (+lat) is image up (-v); the Sun at azimuth 0 lights the east limb.
    g = static_geometry(aa_str, 6.0e7, math.radians(60.0), (0.0, 0.0))
    img = make_renderer(shape="sphere").render(g, seed=2)
    uc, vc = (int(round(x)) for x in g.moon_centre_pixel(aa_str))
    lon, lat = img.aovs["lon"], img.aovs["lat"]
    assert abs(lon[vc, uc]) < 2 * aa_str.ifov * 6e7 / R_MOON
    assert lon[vc, uc + 40] > 0 > lon[vc, uc - 40]
    assert lat[vc - 40, uc] > 0 > lat[vc + 40, uc]
    assert img.L[vc, uc + 60] > img.L[vc, uc - 60]


def test_aov_geometry_is_consistent(geom60, aa_str):
    img = make_renderer(shape="sphere").render(geom60, seed=3)
    m = img.mask
    # range to the sub-observer point is d - R; normals are unit vectors
    uc, vc = (int(round(x)) for x in geom60.moon_centre_pixel(aa_str))
    assert img.aovs["range"][vc, uc] == pytest.approx(6.0e7 - R_MOON, rel=1e-5)
    n = np.stack([img.aovs[k][m] for k in ("nx", "ny", "nz")], -1)
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    # the phase angle varies little across the disc and equals the geometry's at the centre
    assert img.aovs["phase"][vc, uc] == pytest.approx(geom60.phase_angle, abs=2e-3)
    # emission at the sub-observer point is ~0, and 90 deg at the limb
    assert img.aovs["emission"][vc, uc] < 0.03
    assert img.aovs["emission"][m].max() > math.radians(80)


def test_mesh_limb_matches_exact_sphere(aa_str):
    # 327 680-triangle geodesic sphere vs Mitsuba's exact sphere: a limb displaced by
    # 0.1 px would flip ~2 pi r_px * 0.1 ~ 51 pixel centres; allow 10 % of that.
    g = static_geometry(aa_str, 6.0e7, 0.0, (-75.0, 33.0))
    sph = make_renderer(shape="sphere").render(g, seed=4)
    mesh = make_renderer(shape="mesh", mesh=icosphere_mesh(R_MOON, 7)).render(g, seed=4)
    r_px = aa_str.fx * math.tan(g.apparent_radius)
    flips = int(np.sum(sph.mask ^ mesh.mask))
    assert flips <= 0.1 * 2 * math.pi * r_px * 0.1
    om = exact_solid_angles(aa_str)
    assert np.sum(mesh.L * om) / np.sum(sph.L * om) == pytest.approx(1.0, abs=1e-3)


def test_albedo_map_on_sphere_and_mesh(aa_str):
    # A map dark in the west (0.08), bright in the east (0.24), seen from above lon 0:
    # each half renders with its own albedo (Lambert), on the exact sphere and on the mesh.
    vals = np.full((90, 180), 0.08, np.float32)
    vals[:, 90:] = 0.24
    amap = AlbedoMap(vals, "test")
    g = static_geometry(aa_str, 6.0e7, 0.0, (0.0, 0.0))
    for kw in ({"shape": "sphere"}, {"shape": "mesh", "mesh": icosphere_mesh(R_MOON, 6)}):
        img = make_renderer(albedo=amap, **kw).render(g, seed=5)
        E = img.meta["sun"]["band_irradiance_w_m2"]
        lon = img.aovs["lon"]
        inc = img.aovs["incidence"]
        ok = img.mask & (inc < math.radians(60)) & (np.abs(lon) > math.radians(5))
        ratio = img.L[ok] / (E * np.cos(inc[ok]) / math.pi)
        east = lon[ok] > 0
        assert np.mean(ratio[east]) == pytest.approx(0.24, rel=0.01), kw["shape"]
        assert np.mean(ratio[~east]) == pytest.approx(0.08, rel=0.01), kw["shape"]


def test_crop_window_gives_the_same_image(geom60):
    a = make_renderer(shape="sphere").render(geom60, seed=6)
    r = make_renderer(shape="sphere")
    r.settings = type(r.settings)(spp=16, crop=False, variants=r.settings.variants)
    b = r.render(geom60, seed=6)
    assert a.meta["render"]["crop_box_uvwh"][2] < 200
    assert b.meta["render"]["crop_box_uvwh"] == [0, 0, 1024, 1024]
    # both are unbiased estimates of the same image: equal disc sums to MC noise
    assert b.L.sum() == pytest.approx(a.L.sum(), rel=2e-3)
    assert np.array_equal(a.mask, b.mask)


def test_bounding_box_covers_the_disc(aa_str):
    for off in [(0, 0), (400, 380), (-500, 10)]:
        g = static_geometry(aa_str, 2.0e7, 0.5, off)
        box = moon_bounding_box(aa_str, g, R_MOON, 0.0)
        u0, v0, w, h = box
        m = analytic_mask(aa_str, g)
        ys, xs = np.nonzero(m)
        assert xs.min() >= u0 and xs.max() < u0 + w and ys.min() >= v0 and ys.max() < v0 + h


def test_moon_outside_the_field_renders_black(aa_str):
    g = static_geometry(aa_str, 6.0e7, 0.5, (0.0, 0.0))
    turned = type(g)(g.camera_position, g.R_cam_to_inertial @ np.array(
        [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float), g.sun_position)
    img = make_renderer(shape="sphere").render(turned, seed=1)
    assert img.meta["render"]["crop_box_uvwh"] is None
    assert not img.L.any() and not img.mask.any()


def test_scalar_and_llvm_agree():
    # Same scene in both variants: the disc-integrated irradiance agrees within Monte Carlo
    # noise (~0.1 % here) and the pixel-centre masks are identical.
    cam = Camera.preset("aa-str", focal_length=11.2e-3, width=48, height=48)
    g = static_geometry(cam, 6.0e7, math.radians(45.0), (2.0, -3.0))
    out = {}
    for variant in ("llvm_ad_spectral", "scalar_spectral"):
        r = make_renderer(cam, spp=16, variants=(variant,), shape="sphere", model="hapke",
                          albedo=0.3)
        img = r.render(g, seed=11)
        assert img.meta["render"]["variant"] == variant
        out[variant] = img
    a, b = out["llvm_ad_spectral"], out["scalar_spectral"]
    om = exact_solid_angles(cam)
    assert np.sum(b.L * om) / np.sum(a.L * om) == pytest.approx(1.0, abs=5e-3)
    assert np.array_equal(a.mask, b.mask)
    assert np.allclose(a.aovs["incidence"][a.mask], b.aovs["incidence"][b.mask], atol=1e-4)


# ----------------------------------------------------------------------------- bad input
def _never_render(*args, **kwargs):
    raise AssertionError("rendering started before the input was validated")


def test_missing_albedo_map_is_reported_before_rendering(tmp_path, monkeypatch):
    from starnav.renderer import render as render_mod
    from starnav.simulate import renderer_from_scenario

    monkeypatch.setattr(render_mod.MoonRenderer, "render", _never_render)
    sc = scenario_from_dict({"moon": {"albedo": {"path": str(tmp_path / "missing.png")}}})
    with pytest.raises(DataFileError, match="moon.albedo.path"):
        renderer_from_scenario(sc)


def test_observer_inside_the_moon_is_reported_before_rendering(monkeypatch):
    from starnav.renderer import render as render_mod
    from starnav.simulate import frame_geometries

    monkeypatch.setattr(render_mod.MoonRenderer, "render", _never_render)
    sc = scenario_from_dict({"geometry": {"range_km": 1000.0}})
    with pytest.raises(GeometryError, match="range_km"):
        frame_geometries(sc)


def test_negative_albedo_and_unknown_model_rejected():
    with pytest.raises(ConfigError, match="moon.albedo"):
        make_renderer(albedo=-0.2)
    with pytest.raises(KeyError, match="lommel_seeliger"):
        make_renderer(model="oren_nayar")


def test_albedo_map_file_round_trip(tmp_path, aa_str):
    import imageio.v3 as iio

    from starnav.bodies.model import load_albedo_map

    arr = (np.linspace(0, 1, 64 * 32).reshape(32, 64) * 65535).astype(np.uint16)
    iio.imwrite(tmp_path / "a.png", arr)
    m = load_albedo_map(tmp_path / "a.png", scale=0.5)
    assert m.values.shape == (32, 64)
    assert m.values.max() == pytest.approx(0.5)
    np.save(tmp_path / "bad.npy", -np.ones((4, 4)))
    with pytest.raises(ConfigError, match="non-negative"):
        load_albedo_map(tmp_path / "bad.npy")
