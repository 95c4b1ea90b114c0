"""View-adapted meshes, checked geometrically (no renderer): limb vs the exact sphere, ray-cast
coverage of everything visible, attributes, edge sizes, frustum culling and the cache.

References are independent of the mesher (tests/dem/_dem_geometry_tools.py): the exact sphere
limb by bisection on the analytic predicate, and terrain hits by ray marching the DEM.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _dem_geometry_tools import (
    heightfield_hits,
    mesh_hits,
    mesh_outline_radius,
    pixel_rays_body,
    sphere_limb_radius,
)

from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.dem.grid import DemGrid, body_to_selenographic
from starnav.dem.mesh import MeshCache, MeshOptions, pixel_angle, view_mesh
from starnav.dem.procedural import procedural_moon
from starnav.dem.schema import ProceduralDemConfig
from starnav.errors import GeometryError
from starnav.geometry import static_geometry
from starnav.simulate import frame_mesh

#: Issue 3: a zero-height DEM must give the sphere's limb within 0.1 px.
LIMB_TOL_PX = 0.1
AA_STR = Camera.preset("aa-str")
#: A 256 x 256 camera with the AA-STR field and 4x its pixel angle: same geometry, 16x fewer
#: triangles, so that the ray-casting tests stay fast.
COARSE = Camera(width=256, height=256, focal_length=50.7e-3, pitch_x=72e-6, pitch_y=72e-6,
                f_number=1.5, name="coarse")
AZ = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)


def _limb_error(mesh, camera, geom, radius):
    rt = sphere_limb_radius(camera, geom, AZ, radius)
    rm = mesh_outline_radius(mesh, camera, geom, AZ, rt.min() - 5.0)
    assert np.all(np.isfinite(rm)), "some azimuths do not reach the mesh outline"
    return np.abs(rm - rt)


@pytest.mark.parametrize(("range_km", "offset", "sub_lat", "sub_lon"), [
    (60_000.0, (0.0, 0.0), 0.0, 0.0),
    (60_000.0, (300.0, -200.0), 0.0, 0.0),        # off-axis: the limb is an ellipse
    (80_000.0, (-150.0, 100.0), 40.0, 100.0),     # sub-camera point away from (0, 0)
    (25_000.0, (0.0, 0.0), -60.0, -170.0),
])
def test_zero_height_dem_limb_matches_the_sphere(range_km, offset, sub_lat, sub_lon):
    g = DemGrid.zeros(1.0)
    geom = static_geometry(AA_STR, range_km * 1e3, math.radians(30.0), moon_offset_px=offset,
                           sub_observer_lat=math.radians(sub_lat),
                           sub_observer_lon=math.radians(sub_lon))
    m = view_mesh(g, AA_STR, geom.camera_position, camera_to_body=geom.R_cam_to_inertial,
                  cache=None)
    err = _limb_error(m, AA_STR, geom, g.reference_radius)
    assert err.max() < LIMB_TOL_PX


@pytest.mark.slow
def test_zero_height_dem_limb_matches_the_sphere_at_10000_km():
    g = DemGrid.zeros(1.0)
    geom = static_geometry(AA_STR, 10_000e3, math.radians(30.0))
    m = view_mesh(g, AA_STR, geom.camera_position, camera_to_body=geom.R_cam_to_inertial,
                  cache=None)
    assert _limb_error(m, AA_STR, geom, g.reference_radius).max() < LIMB_TOL_PX


def test_limb_check_detects_a_coarse_mesh():
    """Negative control: 30 px edges put chords ~1 px inside the limb; the check sees it."""
    g = DemGrid.zeros(1.0)
    geom = static_geometry(AA_STR, 60_000e3, math.radians(30.0))
    m = view_mesh(g, AA_STR, geom.camera_position, options=MeshOptions(edge_px=30.0),
                  cache=None)
    assert _limb_error(m, AA_STR, geom, g.reference_radius).max() > 5 * LIMB_TOL_PX


def _mountain_dem(lat0: float, lon0: float, height: float, sigma: float) -> DemGrid:
    """Zero heights with one Gaussian mountain at (lat0, lon0) [rad], sigma [m]."""
    n = 720  # 0.25 deg
    lat = math.pi / 2 - (np.arange(n) + 0.5) * math.pi / n
    lon = -math.pi + (np.arange(2 * n) + 0.5) * math.pi / n
    cosd = (np.sin(lat)[:, None] * math.sin(lat0)
            + np.cos(lat)[:, None] * math.cos(lat0) * np.cos(lon[None, :] - lon0))
    dist = np.arccos(np.clip(cosd, -1, 1)) * 1_737_400.0
    return DemGrid((height * np.exp(-0.5 * (dist / sigma) ** 2)).astype(np.float32))


def _coverage(dem, mesh, camera, geom, uv, tol_m):
    must = heightfield_hits(dem, camera, geom, uv, height_offset=-tol_m)
    may = heightfield_hits(dem, camera, geom, uv, height_offset=+tol_m)
    got = mesh_hits(mesh, camera, geom, uv)
    return must, may, got


def test_cap_contains_terrain_seen_past_the_horizon():
    """A 40 km mountain 3 deg past the sphere's horizon shows above the limb (~5 px). Ray
    casting from the camera: every pixel whose ray surely hits the terrain (terrain lowered by
    0.3 px footprint) hits the mesh, and no pixel hits the mesh that misses the terrain raised
    by as much. Without the terrain margin the mountain is cut away: the check fails."""
    d = 5_000e3
    R = 1_737_400.0
    theta_h = math.acos(R / d)
    lon0 = theta_h + math.radians(3.0)
    dem = _mountain_dem(0.0, lon0, 40_000.0, 60_000.0)
    geom = static_geometry(COARSE, d, math.radians(30.0), moon_offset_px=(0.0, 0.0))
    top = np.array([math.cos(lon0), math.sin(lon0), 0.0]) * (R + 40_000.0)
    uv_top = COARSE.project(geom.R_cam_to_inertial.T @ (top - geom.camera_position),
                            distort=False)
    du, dv = np.meshgrid(np.arange(-20, 21), np.arange(-20, 21))
    uv = np.stack([du.ravel(), dv.ravel()], -1) + np.round(uv_top)
    foot = pixel_angle(COARSE) * math.sqrt(d * d - R * R)
    tol = 0.3 * foot
    # pixels that see the mountain where the sphere alone would show sky
    rays = pixel_rays_body(COARSE, geom, uv)
    c_dir = -geom.camera_position / d
    past_limb = rays @ c_dir < math.sqrt(d * d - R * R) / d
    mesh = view_mesh(dem, COARSE, geom.camera_position, cache=None)
    must, may, got = _coverage(dem, mesh, COARSE, geom, uv, tol)
    assert np.count_nonzero(must & past_limb) >= 20  # the test exercises the margin
    assert np.all(got[must]), f"{np.count_nonzero(must & ~got)} visible pixels missed"
    assert np.all(may[got])
    # negative control: the cap cut at the sphere's horizon misses the mountain
    cut = view_mesh(dem, COARSE, geom.camera_position, cache=None,
                    options=MeshOptions(terrain_margin=False))
    assert np.count_nonzero(must & ~mesh_hits(cut, COARSE, geom, uv)) >= 20


def test_no_holes_at_the_limb_of_cratered_terrain():
    """Procedural terrain (+-8 km relief) at 10 000 km: in a band of +-4 px around the limb,
    rays that surely hit the terrain (lowered by a quarter of a pixel footprint, 3.3 km, for
    the mesh's level-of-detail smoothing) hit the mesh, and rays that hit the mesh hit the
    terrain raised by as much (the mountain test below covers the terrain margin)."""
    moon = procedural_moon(ProceduralDemConfig(pixels_per_degree=2.0, seed=4))
    dem = moon.dem
    d = 10_000e3
    geom = static_geometry(COARSE, d, math.radians(30.0), sub_observer_lat=0.3,
                           sub_observer_lon=2.0)
    mesh = view_mesh(dem, COARSE, geom.camera_position, camera_to_body=geom.R_cam_to_inertial,
                     cache=None)
    R = dem.reference_radius
    az = np.linspace(0, 2 * math.pi, 240, endpoint=False)
    r0 = sphere_limb_radius(COARSE, geom, az, R)
    c = geom.moon_centre_pixel(COARSE)
    dr = np.arange(-4.0, 4.5, 1.0)
    uv = (c[None, None, :] + (r0[:, None, None] + dr[None, :, None])
          * np.stack([np.cos(az), np.sin(az)], -1)[:, None, :]).reshape(-1, 2)
    tol = 0.25 * pixel_angle(COARSE) * math.sqrt(d * d - R * R)
    must, may, got = _coverage(dem, mesh, COARSE, geom, uv, tol)
    assert must.sum() > 0.3 * len(uv) and (~may).sum() > 0.3 * len(uv)
    assert np.all(got[must]), f"{np.count_nonzero(must & ~got)} visible pixels missed"
    assert np.all(may[got])
    # sensitivity: 1 % of the faces removed at random leaves visible holes in this band
    import trimesh

    keep = np.random.default_rng(0).random(len(mesh.faces)) > 0.01
    holed = trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)
    assert np.count_nonzero(must & ~mesh_hits(holed, COARSE, geom, uv)) >= 1


def test_frustum_culling_keeps_every_pixel_in_the_field():
    """Moon half out of the field: fewer vertices than the whole cap, and every in-field
    pixel inside the disc hits the mesh (grid of pixels, including the field edges)."""
    g = DemGrid.zeros(1.0)
    geom = static_geometry(COARSE, 10_000e3, math.radians(30.0), moon_offset_px=(150.0, 40.0))
    full = view_mesh(g, COARSE, geom.camera_position, cache=None)
    part = view_mesh(g, COARSE, geom.camera_position, camera_to_body=geom.R_cam_to_inertial,
                     cache=None)
    assert len(part.vertices) < 0.8 * len(full.vertices)
    u, v = np.meshgrid(np.linspace(-0.5, 255.5, 60), np.linspace(-0.5, 255.5, 60))
    uv = np.stack([u.ravel(), v.ravel()], -1)
    rays = pixel_rays_body(COARSE, geom, uv)
    d = np.linalg.norm(geom.camera_position)
    R = g.reference_radius
    inside = rays @ (-geom.camera_position / d) > math.sqrt(d * d - R * R) / d + 1e-5
    assert inside.sum() > 500
    assert np.all(mesh_hits(part, COARSE, geom, uv[inside]))


def test_attributes_normals_and_frame():
    moon = procedural_moon(ProceduralDemConfig(pixels_per_degree=1.0, seed=8))
    dem, alb = moon.dem, moon.albedo
    geom = static_geometry(AA_STR, 60_000e3, 0.5, sub_observer_lat=math.radians(20),
                           sub_observer_lon=math.radians(-40))
    m = view_mesh(dem, AA_STR, geom.camera_position, alb, cache=None)
    v = np.asarray(m.vertices)
    lat, lon, h = body_to_selenographic(v, dem.reference_radius)
    va = m.vertex_attributes
    np.testing.assert_allclose(va["lat"], lat, atol=5e-7)
    np.testing.assert_allclose(va["lon"], lon, atol=5e-7)
    np.testing.assert_allclose(va["height"], h, atol=0.01)
    assert va["albedo"].dtype == np.float32
    direct = alb.sample(lat, lon)
    assert np.corrcoef(va["albedo"], direct)[0, 1] > 0.95
    n = np.asarray(m.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert np.mean(np.sum(n * radial, axis=1) > 0.5) > 0.99
    fn = np.asarray(m.face_normals)
    assert np.mean(np.sum(fn * np.asarray(m.triangles_center), axis=1) > 0) > 0.99
    # body-fixed: the cap is centred on the sub-camera direction
    o = geom.camera_position / np.linalg.norm(geom.camera_position)
    ang = np.arccos(np.clip(radial @ o, -1, 1))
    assert ang.min() < 1e-9
    assert ang.max() <= m.metadata["starnav"]["theta_cap"] + 1e-9


def test_edges_are_about_one_pixel():
    """Projected edges: <= 1 px (+5 %) tangentially at the limb and everywhere in the inner
    disc, not much finer (median >= 0.5 px), and ~2 triangles per px^2 of disc."""
    g = DemGrid.zeros(1.0)
    geom = static_geometry(AA_STR, 60_000e3, math.radians(30.0))
    m = view_mesh(g, AA_STR, geom.camera_position, cache=None)
    pc = (geom.R_cam_to_inertial.T @ (np.asarray(m.vertices) - geom.camera_position).T).T
    uv = AA_STR.project(pc, distort=False) - geom.moon_centre_pixel(AA_STR)
    e = np.asarray(m.edges_unique)
    p, q = uv[e[:, 0]], uv[e[:, 1]]
    r_p, r_q = np.linalg.norm(p, axis=1), np.linalg.norm(q, axis=1)
    r_limb = AA_STR.fx * math.tan(geom.apparent_radius)
    seg = q - p
    mid = 0.5 * (p + q)
    radial_dir = mid / np.maximum(np.linalg.norm(mid, axis=1, keepdims=True), 1e-12)
    tang = np.abs(seg[:, 0] * radial_dir[:, 1] - seg[:, 1] * radial_dir[:, 0])
    near_limb = np.minimum(r_p, r_q) > r_limb - 2.0
    assert tang[near_limb].max() < 1.05
    inner = np.maximum(r_p, r_q) < 0.7 * r_limb
    length = np.linalg.norm(seg, axis=1)
    assert length[inner].max() < 1.05 * math.sqrt(2)  # quad diagonals
    assert np.median(length[inner]) > 0.5
    disc = math.pi * r_limb**2
    assert 1.0 * disc < len(m.faces) < 4.0 * disc


def test_cache_reuses_meshes_and_quantum_stays_conservative():
    g = DemGrid.zeros(1.0)
    cache = MeshCache(4)
    geom = static_geometry(AA_STR, 60_000e3, math.radians(30.0))
    c = geom.camera_position
    a = view_mesh(g, AA_STR, c, cache=cache)
    assert view_mesh(g, AA_STR, c, cache=cache) is a
    assert view_mesh(g, AA_STR, c * 1.001, cache=cache) is not a
    # a quantum of 2 px: a camera moved by ~0.1 px of nadir footprint reuses the mesh
    opts = MeshOptions(cache_quantum_px=2.0)
    q1 = view_mesh(g, AA_STR, c, options=opts, cache=cache)
    foot = pixel_angle(AA_STR) * (60_000e3 - g.reference_radius)
    moved = c + np.array([0.0, 0.1 * foot, 0.0])
    q2 = view_mesh(g, AA_STR, moved, options=opts, cache=cache)
    assert q2 is q1
    # ... and the shared mesh still gives the moved camera's limb within tolerance
    rot = _rotation_between(c, moved)
    geom2 = type(geom)(camera_position=moved, R_cam_to_inertial=rot @ geom.R_cam_to_inertial,
                       sun_position=geom.sun_position)
    assert _limb_error(q2, AA_STR, geom2, g.reference_radius).max() < LIMB_TOL_PX
    assert cache.hits >= 2


def _rotation_between(a, b):
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    s, c = np.linalg.norm(v), float(a @ b)
    if s < 1e-15:
        return np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = math.atan2(s, c)
    return np.eye(3) + math.sin(ang) * k + (1 - math.cos(ang)) * k @ k


def test_bad_camera_positions():
    dem = DemGrid(np.full((10, 20), 5000.0, np.float32))
    with pytest.raises(GeometryError, match="not above the highest terrain"):
        view_mesh(dem, AA_STR, np.array([1_740_000.0, 0, 0]), cache=None)
    with pytest.raises(GeometryError, match="finite 3-vector"):
        view_mesh(dem, AA_STR, np.array([np.nan, 0, 0]), cache=None)


def test_vertex_budget_coarsens_edges():
    g = DemGrid.zeros(1.0)
    geom = static_geometry(AA_STR, 60_000e3, math.radians(30.0))
    m = view_mesh(g, AA_STR, geom.camera_position, cache=None,
                  options=MeshOptions(max_vertices=5000))
    assert len(m.vertices) <= 5000
    assert m.metadata["starnav"]["edge_px"] > 1.0


def test_frame_mesh_of_a_scenario():
    sc = scenario_from_dict({
        # quantum 0: the mesh of this exact view (the default shares one per 8 px cell)
        "moon": {"shape": "dem", "dem": {"procedural": {"pixels_per_degree": 1.0},
                                         "albedo": {"source": "procedural"},
                                         "mesh": {"cache_quantum_px": 0.0}}},
        "geometry": {"range_km": 60_000.0, "sub_observer_lat_deg": 10.0,
                     "sub_observer_lon_deg": 30.0},
    })
    m = frame_mesh(sc, cache=None)
    assert "albedo" in m.vertex_attributes
    o = np.asarray(m.metadata["starnav"]["sub_camera_direction"])
    want = np.array([math.cos(math.radians(10)) * math.cos(math.radians(30)),
                     math.cos(math.radians(10)) * math.sin(math.radians(30)),
                     math.sin(math.radians(10))])
    np.testing.assert_allclose(o, want, atol=1e-12)
