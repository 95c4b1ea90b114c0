"""DEM meshes through the renderer (issue 3): a zero-height DEM renders the exact sphere's limb,
and a scenario with ``moon.shape: dem`` renders terrain from the procedural Moon."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.bodies.mesh import BodyMesh
from starnav.config import scenario_from_dict
from starnav.dem.grid import DemGrid
from starnav.dem.mesh import view_mesh
from starnav.geometry import static_geometry

from .conftest import exact_solid_angles, make_renderer

R_MOON = 1.7374e6


def zero_dem_provider(camera, geom):
    Rb = geom.R_body_to_inertial.T
    tm = view_mesh(DemGrid.zeros(1.0), camera, Rb @ geom.camera_position,
                   camera_to_body=Rb @ geom.R_cam_to_inertial)
    return BodyMesh.from_trimesh(tm, key=tm)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (310.0, -260.0)])
def test_zero_height_dem_renders_the_sphere_limb(aa_str, offset):
    # A limb displaced by 0.1 px flips ~2 pi r_px * 0.1 pixel centres (~51 here); the view
    # mesh's silhouette error is the chord sagitta (~0.001 px), so allow 10 % of that budget.
    g = static_geometry(aa_str, 6.0e7, 0.0, offset)
    sph = make_renderer(shape="sphere").render(g, seed=1)
    dem = make_renderer(shape="mesh", mesh_provider=zero_dem_provider).render(g, seed=1)
    r_px = aa_str.fx * math.tan(g.apparent_radius)
    assert int(np.sum(sph.mask ^ dem.mask)) <= 0.1 * 2 * math.pi * r_px * 0.1
    om = exact_solid_angles(aa_str)
    assert np.sum(dem.L * om) / np.sum(sph.L * om) == pytest.approx(1.0, abs=2e-3)


@pytest.mark.slow
def test_scenario_with_procedural_dem_renders_terrain():
    sc = scenario_from_dict({
        "camera": {"width": 160, "height": 160},
        "geometry": {"range_km": 12000.0, "phase_angle_deg": 75.0},
        "moon": {"shape": "dem", "dem": {"source": "procedural",
                                         "procedural": {"pixels_per_degree": 2.0},
                                         "albedo": {"source": "procedural"}}},
        "render": {"spp": 4},
    })
    from starnav.simulate import render_scenario

    img = next(render_scenario(sc))
    assert img.meta["moon"]["shape"] == "mesh" and img.meta["moon"]["triangles"] > 1000
    m = img.mask
    # terrain: surface normals depart from the radial direction at the same lat/lon (a sphere
    # would give 0; the static frame's body axes are the inertial ones)
    lat, lon = img.aovs["lat"][m], img.aovs["lon"][m]
    radial = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    n = np.stack([img.aovs[k][m] for k in ("nx", "ny", "nz")], -1)
    tilt = np.degrees(np.arccos(np.clip(np.sum(n * radial, -1), -1, 1)))
    assert np.median(tilt) > 0.5
    # albedo: maria and highlands (procedural albedo map), seen as L / cos(i) spread
    lit = m & (img.aovs["incidence"] < math.radians(70))
    ratio = img.L[lit] / np.cos(img.aovs["incidence"][lit])
    assert np.std(ratio) > 0.1 * np.mean(ratio)
    assert np.isfinite(img.L).all()
