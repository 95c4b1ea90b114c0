"""The renderer's use of :mod:`starnav.dem`: ``moon.shape: dem`` renders a view-adapted mesh
of a real or procedural DEM, taken from the DEM cache when the frame's view falls in the cell
of an earlier frame's (``moon.dem.mesh.cache_quantum_px``: the sub-camera direction to that many
pixels, the range to 1/8 octave; the attitude only when the Moon overfills the field) and
built otherwise. A frame that gets the earlier frame's mesh gets the renderer's loaded Mitsuba
scene with it: only the sensor and the Sun move (:mod:`starnav.renderer.render`, step 1)."""

from __future__ import annotations

from typing import Any

import numpy as np

from starnav.cache import BoundedCache
from starnav.camera import Camera
from starnav.dem.detail import sub_posting_detail
from starnav.dem.load import as_dem_config, load_albedo, load_dem
from starnav.dem.mesh import MeshOptions, view_mesh
from starnav.dem.schema import DemConfig
from starnav.geometry import FrameGeometry
from starnav.photometry import albedo_parameter
from starnav.renderer.render import MoonModel
from starnav.renderer.scene import MoonMesh


def dem_moon_model(dem_config: DemConfig | dict[str, Any], common: dict[str, Any],
                   mean_normal_albedo: float) -> MoonModel:
    """A mesh :class:`MoonModel` whose mesh comes from ``dem_config`` (``moon.dem``) for each
    view.

    The DEM and its albedo grid are loaded here, so bad files are reported before any
    rendering. The grid's values become the model's albedo parameter per vertex: a relative map
    is first scaled to ``mean_normal_albedo`` (the scenario's ``moon.albedo``, else the
    ROLO-calibrated one: :func:`starnav.simulate.mean_normal_albedo`), a normal-albedo
    map is converted, a ``hapke_w`` map is used as it is
    (Hapke only). Without an albedo grid the constant ``common['albedo']`` applies.
    ``moon.albedo_scale`` multiplies the reflectance, whatever the source.
    """
    cfg = as_dem_config(dem_config)
    dem = load_dem(cfg)
    albedo_grid = load_albedo(cfg)
    options = MeshOptions.from_config(cfg.mesh)
    detail = sub_posting_detail(dem, cfg.detail) if cfg.detail.enabled else None
    model, params = common["model"], common["params"]
    quantity = None if albedo_grid is None else albedo_grid.quantity
    factor = 1.0
    if quantity == "relative":
        factor = mean_normal_albedo / max(albedo_grid.mean, 1e-12)
        quantity = "normal_albedo"
    if albedo_grid is not None:
        # fail now, not at the first frame: the brightest value must be reachable
        albedo_parameter(np.array([albedo_grid.values.max() * factor]), quantity, model,
                         params, "moon.dem.albedo")

    # the renderer's meshes by view mesh (id of the cached trimesh, which each MoonMesh keeps
    # alive as its key): a frame whose view mesh comes from the DEM cache gets the very
    # MoonMesh of the earlier frame, so the renderer keeps its loaded scene
    meshes: BoundedCache[int, MoonMesh] = BoundedCache(2)

    def provider(camera: Camera, geom: FrameGeometry) -> MoonMesh:
        Rb = geom.R_moon_to_inertial.T
        tm = view_mesh(dem, camera, Rb @ geom.camera_position, albedo_grid,
                       camera_to_body=Rb @ geom.R_cam_to_inertial, options=options,
                       detail=detail)
        mesh = meshes.get(id(tm))
        if mesh is not None and mesh.key is tm:
            return mesh
        alb = None
        if albedo_grid is not None:
            raw = np.asarray(tm.vertex_attributes["albedo"], float) * factor
            alb = albedo_parameter(raw, quantity, model, params, "moon.dem.albedo")
        mesh = MoonMesh.from_trimesh(tm, albedo=alb, key=tm)
        meshes.put(id(tm), mesh)
        return mesh

    h_min, h_max = dem.height_range
    extra = 0.0 if detail is None else float(detail.max_detail_m)
    return MoonModel("mesh", mesh_provider=provider, max_height=max(float(h_max), 0.0) + extra,
                     **{**common, "radius": dem.reference_radius})
