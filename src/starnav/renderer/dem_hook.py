"""The renderer's use of :mod:`starnav.dem`: ``moon.shape: dem`` renders a view-adapted mesh
of a real or procedural DEM, rebuilt (or taken from the DEM cache) for each frame."""

from __future__ import annotations

from typing import TYPE_CHECKING

from starnav.camera import Camera
from starnav.geometry import FrameGeometry
from starnav.renderer.render import AlbedoMap, MoonModel
from starnav.renderer.scene import MoonMesh

if TYPE_CHECKING:
    from starnav.config import Scenario


def dem_moon_model(sc: Scenario, albedo: float | AlbedoMap) -> MoonModel:
    """A mesh :class:`MoonModel` whose mesh comes from ``sc.moon.dem`` for each view.

    The DEM (and its albedo grid, if the DEM section names one) is loaded here, so bad files are
    reported before any rendering. Per-vertex albedo from the DEM's albedo source takes
    precedence over ``moon.albedo``; ``moon.albedo_scale`` multiplies either.
    """
    from starnav.dem.load import as_dem_config, load_albedo, load_dem
    from starnav.dem.mesh import MeshOptions, view_mesh

    cfg = as_dem_config(sc.moon.dem)
    dem = load_dem(cfg)
    albedo_grid = load_albedo(cfg)
    options = MeshOptions.from_config(cfg.mesh)

    def provider(camera: Camera, geom: FrameGeometry) -> MoonMesh:
        Rb = geom.R_moon_to_inertial.T
        tm = view_mesh(dem, camera, Rb @ geom.camera_position, albedo_grid,
                       camera_to_body=Rb @ geom.R_cam_to_inertial, options=options)
        return MoonMesh.from_trimesh(tm, key=tm)

    h_min, h_max = dem.height_range
    m = sc.moon
    return MoonModel("mesh", dem.reference_radius, m.photometry.model, dict(m.photometry.params),
                     albedo, m.albedo_scale, mesh_provider=provider,
                     max_height=max(float(h_max), 0.0))
