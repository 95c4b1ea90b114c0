"""``MoonRenderer.surface``: the triangles and vertex albedo a frame is rendered on, as handed to
another engine (``benchmarks/render.py --cycles-python``). Checked against the render itself
with the test's own ray caster and the Lambert closed form, not against the renderer's code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.bodies.mesh import icosphere_mesh
from starnav.bodies.model import AlbedoMap
from starnav.camera import Camera
from starnav.config import build_camera, scenario_from_dict
from starnav.geometry import static_geometry
from starnav.simulate import frame_geometries, renderer_from_scenario

from .conftest import make_renderer

R_MOON = 1.7374e6


def _albedo_map() -> AlbedoMap:
    """Smooth, strongly varying albedo: 0.06-0.18 over longitude and latitude."""
    lat = np.linspace(90, -90, 90)[:, None]
    lon = np.linspace(-180, 180, 180)[None, :]
    a = 0.12 + 0.04 * np.cos(np.radians(3 * lon)) + 0.02 * np.sin(np.radians(2 * lat))
    return AlbedoMap(a.astype(np.float32), "test")


def _cast(origin, dirs, v, f):
    """Nearest hit of rays ``origin + t dirs`` on triangles (Moller-Trumbore): distance, face
    and barycentric (u, v) per ray; distance inf where a ray misses."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    t_best = np.full(len(dirs), np.inf)
    face = np.full(len(dirs), -1)
    bu, bv = np.zeros(len(dirs)), np.zeros(len(dirs))
    for i0 in range(0, len(dirs), 64):
        d = dirs[i0:i0 + 64, None, :]
        p = np.cross(d, e2[None])
        det = np.einsum("rfk,fk->rf", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = origin - a
            u = np.einsum("rfk,fk->rf", p, s) * inv
            q = np.cross(s, e1)
            w = np.einsum("rk,fk->rf", dirs[i0:i0 + 64], q) * inv
            t = np.einsum("fk,fk->f", e2, q)[None] * inv
        ok = (np.abs(det) > 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
        t = np.where(ok, t, np.inf)
        k = np.argmin(t, axis=1)
        rows = np.arange(len(k))
        t_best[i0:i0 + 64] = t[rows, k]
        face[i0:i0 + 64] = k
        bu[i0:i0 + 64], bv[i0:i0 + 64] = u[rows, k], w[rows, k]
    return t_best, face, bu, bv


def _pixel_rays(cam: Camera, g, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre rays ``uv`` (n, 2) of frame ``g`` in the Moon's body frame: the camera
    centre and the unit directions (n, 3)."""
    Rb = g.R_body_to_inertial.T
    dirs = cam.unproject(uv, undistort=False) @ (Rb @ g.R_cam_to_inertial).T
    return Rb @ g.camera_position, dirs


@pytest.fixture(scope="module")
def exported():
    cam = Camera(width=96, height=96, focal_length=0.0507, pitch_x=4.4e-5, pitch_y=4.4e-5,
                 f_number=2.0)
    g = static_geometry(cam, 6.0e7, math.radians(35.0), (6.0, -4.0))
    mesh = icosphere_mesh(R_MOON, 4)
    r = make_renderer(cam, spp=16, shape="mesh", mesh=mesh, albedo=_albedo_map(),
                      albedo_scale=1.3)
    img = r.render(g, seed=3)
    surf = r.surface(g)
    assert surf is not None
    u, v = cam.pixel_grid()
    cast = _cast(*_pixel_rays(cam, g, np.stack([u.ravel(), v.ravel()], -1)),
                 surf[0].vertices, surf[0].faces)
    return cam, g, img, surf, cast


def test_sphere_has_no_triangle_surface(aa_str):
    g = static_geometry(aa_str, 6.0e7, 0.5)
    assert make_renderer(shape="sphere").surface(g) is None


def test_exported_triangles_are_the_rendered_surface(exported):
    _, _, img, _, (t, _, _, _) = exported
    hit = np.isfinite(t)
    mask = img.mask.ravel()
    assert hit.sum() > 2000  # the disc is ~ 2 800 pixels
    # the render's mask and range come from its pixel-centre rays: the same rays as here
    assert np.array_equal(hit, mask)
    rng = img.aovs["range"].ravel()[hit]
    np.testing.assert_allclose(rng, t[hit], rtol=2e-6)  # float32 km coordinates in Mitsuba


def test_exported_albedo_renders_the_lambert_closed_form(exported):
    """Each lit interior pixel's band radiance equals the exported albedo, interpolated at the
    pixel centre's hit as the renderer interpolates it, times ``E cos i / pi`` with the
    interpolated vertex normal. The pixel is an area average and the centre a point, and the
    default render draws 2 samples in the flat interior: a pixel where cos i changes by a few
    per cent across it differs from its centre's value by as much (up to ~4 % near the
    terminator here, at random). So the per-pixel check is on the median (0.2 % measured;
    limit 0.5 %, where a misregistration of the map by one of its 2-degree cells gives
    ~3 %), and the disc sum, where that noise averages out (~0.02 %), must agree to 0.1 %."""
    cam, g, img, (mesh, albedo), (t, face, bu, bv) = exported
    # interior pixels: hit, and all eight neighbours hit too
    m = np.isfinite(t).reshape(cam.height, cam.width)
    inner = m.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            inner &= np.roll(np.roll(m, dy, 0), dx, 1)
    f = mesh.faces[face]
    w = np.stack([1 - bu - bv, bu, bv], -1)
    a = np.einsum("rk,rk->r", w, albedo[f])
    n = np.einsum("rk,rkj->rj", w, mesh.normals[f])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cos_i = n @ (g.R_body_to_inertial.T @ g.sun_direction)
    sel = inner.ravel() & (cos_i > 0.2)
    assert sel.sum() > 1000
    ref = a[sel] * img.meta["sun"]["band_irradiance_w_m2"] * cos_i[sel] / math.pi
    L = img.L.ravel()[sel]
    assert np.median(np.abs(L / ref - 1)) < 5e-3
    assert np.sum(L) / np.sum(ref) == pytest.approx(1.0, abs=1e-3)
    # the scale is in the export: without it the ratio would be 1.3
    assert albedo.min() > 1.3 * 0.06 * 0.99 and albedo.max() < 1.3 * 0.18 * 1.01


def test_real_moon_view_mesh_export_is_the_rendered_surface():
    """The default Moon (LOLA terrain, LROC albedo, Hapke): the exported view mesh of a frame is
    the surface its pixel-centre rays hit. Each pixel's candidate triangles are found from the
    vertices' projections (a triangle can hold a pixel centre only inside its projected box),
    then cast against with the test's own ray caster."""
    sc = scenario_from_dict({
        "camera": {"width": 96, "height": 96, "pixel_pitch_um": 44.0},
        "render": {"spp": 4},
        "geometry": {"range_km": 60_000.0, "phase_angle_deg": 40.0,
                     "moon_offset_px": [20.0, -10.0]}})
    cam = build_camera(sc.camera)
    r = renderer_from_scenario(sc)
    g = frame_geometries(sc)[0]
    img = r.render(g, seed=5)
    mesh, albedo = r.surface(g)
    assert mesh.n_triangles > 5000 and albedo.shape == (len(mesh.vertices),)
    assert np.all(np.isfinite(albedo)) and 0.02 < np.median(albedo) < 0.5

    R_cb = g.R_body_to_inertial.T @ g.R_cam_to_inertial  # camera -> body
    cam_b = g.R_body_to_inertial.T @ g.camera_position  # camera centre, body frame
    p_cam = (mesh.vertices - cam_b) @ R_cb  # vertices in the camera frame
    assert np.all(p_cam[:, 2] > 0)
    uv = cam.project(p_cam, distort=False)[mesh.faces]  # (faces, 3, 2)
    lo, hi = np.ceil(uv.min(axis=1)).astype(int), np.floor(uv.max(axis=1)).astype(int)
    span = hi - lo + 1
    assert span.max() <= 4  # the view mesh's triangles are about a pixel across
    cand: dict[tuple[int, int], list[int]] = {}
    for du in range(4):
        for dv in range(4):
            k = np.flatnonzero((du < span[:, 0]) & (dv < span[:, 1]))
            for f, uu, vv in zip(k, lo[k, 0] + du, lo[k, 1] + dv, strict=True):
                if 0 <= uu < cam.width and 0 <= vv < cam.height:
                    cand.setdefault((int(uu), int(vv)), []).append(int(f))
    t = np.full((cam.height, cam.width), np.inf)
    for (uu, vv), faces in cand.items():
        o, d = _pixel_rays(cam, g, np.array([[uu, vv]], float))
        t[vv, uu] = _cast(o, d, mesh.vertices, mesh.faces[faces])[0][0]
    hit = np.isfinite(t)
    assert 1500 < hit.sum() < cam.width * cam.height  # the disc, with its limb in the frame
    # float32 in Mitsuba against float64 here: a grazing ray at the limb may fall either way
    assert int(np.sum(hit ^ img.mask)) <= 3
    both = hit & img.mask
    np.testing.assert_allclose(img.aovs["range"][both], t[both], rtol=5e-7)  # 30 m; seen 9 m
