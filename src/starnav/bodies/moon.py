"""The Moon as a target body: a sphere, an icosphere or the DEM mesh of the real (LOLA, LROC)
or procedural Moon, with the DE421 librations (``PA`` or ``ME`` axes) for its orientation.

The albedo the user gives is a normal albedo (a number, a map, or the ROLO-calibrated mean of
the real Moon); :meth:`Moon.render_model` converts it to the photometric model's own parameter
(:func:`starnav.photometry.albedo_parameter`) and reads every map and DEM before a frame is
rendered; for ``shape: dem``, :func:`dem_moon_model` gives the renderer a view-adapted mesh of
the real or procedural DEM for each frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.bodies.base import FloatArray, TargetBody
from starnav.bodies.mesh import BodyMesh, icosphere_mesh
from starnav.bodies.model import AlbedoMap, TargetModel, load_albedo_map
from starnav.bodies.schema import AlbedoMapConfig, MoonConfig
from starnav.cache import BoundedCache
from starnav.camera import Camera
from starnav.dem.detail import sub_posting_detail
from starnav.dem.load import as_dem_config, load_albedo, load_dem
from starnav.dem.mesh import MeshOptions, view_mesh
from starnav.dem.schema import DemConfig
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.lunar_calibration import lunar_calibration
from starnav.photometry import albedo_parameter
from starnav.scenes.ephemeris import Ephemeris


def mean_normal_albedo(moon: MoonConfig) -> float:
    """The (mean) normal albedo of a ``moon`` section: ``albedo`` when a number, else the
    ROLO-calibrated mean normal albedo of the real Moon [-]."""
    if isinstance(moon.albedo, int | float):
        return float(moon.albedo)
    return lunar_calibration().mean_normal_albedo


class Moon(TargetBody):
    """The Moon of a ``moon`` section.

    Parameters
    ----------
    config : MoonConfig
    frame : {"PA", "ME"}
        Body-fixed axes of the DE421 librations (``trajectory.moon_frame``).
    """

    name = "moon"

    def __init__(self, config: MoonConfig | None = None, frame: str = "PA") -> None:
        self.config = config if config is not None else MoonConfig()
        if frame not in ("PA", "ME"):
            raise ConfigError("trajectory.moon_frame", frame, "'PA' or 'ME'")
        self.frame = frame

    @property
    def radii_m(self) -> tuple[float, float, float]:
        r = self.config.to_si().radius
        return (r, r, r)

    def orientation(self, epochs_tdb: ArrayLike, ephemeris: Any = None) -> FloatArray:
        if ephemeris is None:
            ephemeris = Ephemeris.default()
        return np.asarray(ephemeris.moon_orientation(epochs_tdb, frame=self.frame))

    def render_model(self) -> TargetModel:
        m = self.config
        radius = self.radii_m[0]
        model = m.photometry.model
        params = m.photometry.resolved_params()
        spectral = (lunar_calibration().spectral_shape()
                    if m.photometry.spectral_shape == "rolo" else None)
        calibrated = model == "hapke" and m.photometry.preset == "rolo-calibrated"
        albedo: float | AlbedoMap
        if isinstance(m.albedo, AlbedoMapConfig):
            amap = load_albedo_map(m.albedo.path, m.albedo.scale)
            albedo = AlbedoMap(albedo_parameter(amap.values, m.albedo.quantity, model, params,
                                                "moon.albedo.path").astype(np.float32),
                               amap.source)
        else:
            albedo = float(albedo_parameter(mean_normal_albedo(m), "normal_albedo", model,
                                            params, "moon.albedo"))
        common = dict(model=model, params=params, albedo=albedo, albedo_scale=m.albedo_scale,
                      spectral_shape=spectral, calibrated=calibrated, radius=radius)
        if m.shape == "sphere":
            return TargetModel("sphere", **common)
        if m.shape == "mesh":
            return TargetModel("mesh", mesh=icosphere_mesh(radius, m.mesh_subdivisions),
                             **common)
        return dem_moon_model(m.dem, common, mean_normal_albedo(m))

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "shape": self.config.shape, "frame": self.frame,
                "photometry": self.config.photometry.model}


def dem_moon_model(dem_config: DemConfig | dict[str, Any], common: dict[str, Any],
                   mean_normal_albedo: float) -> TargetModel:
    """A mesh :class:`TargetModel` whose mesh comes from ``dem_config`` (``moon.dem``) for each
    view.

    The DEM and its albedo grid are loaded here, so bad files are reported before any
    rendering. The grid's values become the model's albedo parameter per vertex: a relative map
    is first scaled to ``mean_normal_albedo`` (the scenario's ``moon.albedo``, else the
    ROLO-calibrated one: :func:`starnav.simulate.mean_normal_albedo`), a normal-albedo
    map is converted, a ``hapke_w`` map is used as it is
    (Hapke only). Without an albedo grid the constant ``common['albedo']`` applies.
    ``moon.albedo_scale`` multiplies the reflectance, whatever the source.

    A view's mesh comes from the DEM cache when the view falls in the cell of an earlier
    frame's (``moon.dem.mesh.cache_quantum_px``: the sub-camera direction to that many pixels,
    the range to 1/8 octave; the attitude only when the Moon overfills the field); that frame
    then gets the earlier frame's :class:`BodyMesh`, and the renderer its loaded scene.
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

    # the renderer's meshes by view mesh (id of the cached trimesh, which each BodyMesh keeps
    # alive as its key): a frame whose view mesh comes from the DEM cache gets the very
    # BodyMesh of the earlier frame, so the renderer keeps its loaded scene
    meshes: BoundedCache[int, BodyMesh] = BoundedCache(2)

    def provider(camera: Camera, geom: FrameGeometry) -> BodyMesh:
        Rb = geom.R_body_to_inertial.T
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
        mesh = BodyMesh.from_trimesh(tm, albedo=alb, key=tm)
        meshes.put(id(tm), mesh)
        return mesh

    h_min, h_max = dem.height_range
    extra = 0.0 if detail is None else float(detail.max_detail_m)
    return TargetModel("mesh", mesh_provider=provider, max_height=max(float(h_max), 0.0) + extra,
                     **{**common, "radius": dem.reference_radius})
