"""From a scenario to the domain objects that make its frames, each built once.

The scenario's sections are validated settings with units in their names; this module turns
them into the SI objects the physics packages work with, and is the only place that does:

* :func:`camera_from_config` -> :class:`~starnav.camera.Camera` (one per process, passed down);
* :func:`scene_from_scenario` -> :class:`~starnav.scenes.frames.Scene` (epochs, truth and
  :class:`~starnav.geometry.FrameGeometry` of each frame, static or along a trajectory);
* :func:`moon_model_from_scenario` -> :class:`~starnav.renderer.render.MoonModel` (the albedo
  converted to the photometric model's parameter, maps and DEMs read here so that a missing
  file is reported before any rendering);
* :func:`renderer_from_scenario` -> :class:`~starnav.renderer.render.MoonRenderer` (camera,
  sensor response, Sun, Moon, render settings).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import trimesh

from starnav.camera import Camera, camera_from_config
from starnav.config import Scenario
from starnav.constants import AU
from starnav.dem.detail import sub_posting_detail
from starnav.dem.grid import AlbedoGrid, DemGrid
from starnav.dem.load import as_dem_config, load_albedo, load_dem
from starnav.dem.mesh import MESH_CACHE, MeshCache, MeshOptions, view_mesh
from starnav.geometry import FrameGeometry, static_geometry_from_config
from starnav.lunar_calibration import lunar_calibration
from starnav.photometry import albedo_parameter
from starnav.radiance import RadianceImage
from starnav.renderer.dem_hook import dem_moon_model
from starnav.renderer.render import (
    AlbedoMap,
    MoonModel,
    MoonRenderer,
    RenderSettings,
    load_albedo_map,
)
from starnav.renderer.scene import check_camera_for_render, icosphere_mesh
from starnav.renderer.schema import AlbedoMapConfig
from starnav.scenes.ephemeris import Ephemeris
from starnav.scenes.frames import Scene
from starnav.scenes.trajectory import Trajectory
from starnav.spectra import sensor_response_from_config, solar_spectrum_from_config

log = logging.getLogger(__name__)


def moon_model_from_scenario(sc: Scenario) -> MoonModel:
    """The :class:`MoonModel` of a scenario: the normal albedo (number or map) converted to the
    photometric model's own parameter, the spectral shape and the parameter preset resolved.
    Albedo maps and DEMs are read here, so a missing file is reported before any rendering."""
    m = sc.moon
    radius = m.radius_km * 1e3
    model = m.photometry.model
    params = m.photometry.resolved_params()
    spectral = (lunar_calibration().spectral_shape()
                if m.photometry.spectral_shape == "rolo" else None)
    calibrated = model == "hapke" and m.photometry.preset == "rolo-calibrated"
    albedo: float | AlbedoMap
    if isinstance(m.albedo, AlbedoMapConfig):
        amap = load_albedo_map(m.albedo.path, m.albedo.scale)
        albedo = AlbedoMap(albedo_parameter(amap.values, m.albedo.quantity, model, params,
                                            "moon.albedo.path").astype(np.float32), amap.source)
    else:
        albedo = float(albedo_parameter(mean_normal_albedo(sc), "normal_albedo", model, params,
                                        "moon.albedo"))
    common = dict(model=model, params=params, albedo=albedo, albedo_scale=m.albedo_scale,
                  spectral_shape=spectral, calibrated=calibrated, radius=radius)
    if m.shape == "sphere":
        return MoonModel("sphere", **common)
    if m.shape == "mesh":
        return MoonModel("mesh", mesh=icosphere_mesh(radius, m.mesh_subdivisions), **common)
    return dem_moon_model(m.dem, common, mean_normal_albedo(sc))


def mean_normal_albedo(sc: Scenario) -> float:
    """The scenario's (mean) normal albedo: ``moon.albedo`` when a number, else the
    ROLO-calibrated mean normal albedo of the real Moon [-]."""
    if isinstance(sc.moon.albedo, int | float):
        return float(sc.moon.albedo)
    return lunar_calibration().mean_normal_albedo


def renderer_from_scenario(sc: Scenario, camera: Camera | None = None) -> MoonRenderer:
    """A :class:`MoonRenderer` configured by ``sc`` (validates camera, spectra, Moon);
    ``camera`` the scenario's camera when already built."""
    camera = camera_from_config(sc.camera) if camera is None else camera
    check_camera_for_render(camera)
    response = sensor_response_from_config(sc.sensor_response)
    sun = solar_spectrum_from_config(sc.sun, distance=AU)
    moon = moon_model_from_scenario(sc)
    r = sc.render
    settings = RenderSettings(spp=r.spp, crop=r.crop, crop_margin_px=r.crop_margin_px,
                              aovs=r.aovs, variants=tuple(r.variants), sampler=r.sampler,
                              wavelength_step_nm=r.wavelength_step_nm)
    return MoonRenderer(camera, response, sun, moon, settings)


def scene_from_scenario(sc: Scenario, ephemeris: Ephemeris | None = None, *,
                        camera: Camera | None = None, arc: Trajectory | None = None,
                        cache_dir: str | Path | None = None) -> Scene:
    """The :class:`~starnav.scenes.frames.Scene` of ``sc``: its trajectory's frames, or the one
    frame of its static ``geometry`` section (with the attitude-knowledge error either way)."""
    camera = camera_from_config(sc.camera) if camera is None else camera
    return Scene(camera, sc.pointing, trajectory=sc.trajectory, static=sc.geometry,
                 moon_radius=sc.moon.radius_km * 1e3, seed=sc.seed, ephemeris=ephemeris,
                 arc=arc, cache_dir=cache_dir)


def frame_geometries(sc: Scenario, ephemeris: Ephemeris | None = None) -> list[FrameGeometry]:
    """One :class:`FrameGeometry` per frame of ``sc`` (the renderer's geometry input)."""
    return scene_from_scenario(sc, ephemeris).geometries()


def frame_states(sc: Scenario, ephemeris: Ephemeris | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Frame epochs ``(n,)`` [TDB s past J2000] and spacecraft states ``(n, 6)`` EMB-centred
    J2000 [m, m/s]: the navigation truth. Needs a ``trajectory`` section."""
    scene = scene_from_scenario(sc, ephemeris)
    return scene.epochs.copy(), scene.states_emb.copy()


def frame_mesh(sc: Scenario, dem: DemGrid | None = None, albedo: AlbedoGrid | None = None,
               cache: MeshCache | None = MESH_CACHE) -> trimesh.Trimesh:
    """The DEM mesh a frame of ``sc``'s static ``geometry`` section would be rendered with
    (:func:`starnav.dem.mesh.view_mesh` with ``moon.dem``'s meshing and sub-posting detail).
    ``dem``/``albedo``: grids already loaded (default: read ``moon.dem``'s)."""
    cfg = as_dem_config(sc.moon.dem)
    camera = camera_from_config(sc.camera)
    geom = static_geometry_from_config(camera, sc.geometry, moon_radius=sc.moon.radius_km * 1e3)
    dem = load_dem(cfg) if dem is None else dem
    albedo = load_albedo(cfg) if albedo is None else albedo
    Rb = geom.R_moon_to_inertial.T
    return view_mesh(dem, camera, Rb @ geom.camera_position, albedo,
                     camera_to_body=Rb @ geom.R_cam_to_inertial,
                     options=MeshOptions.from_config(cfg.mesh), cache=cache,
                     detail=sub_posting_detail(dem, cfg.detail))


def describe_frame(img: RadianceImage) -> dict:
    """Short summary of a rendered frame, for the CLI."""
    g = img.meta["geometry"]
    return {
        "range_km": g["range_m"] / 1e3,
        "phase_deg": math.degrees(g["phase_angle_rad"]),
        "L_max_W_m2_sr": float(img.L.max()),
        "Le_max_e_s_m2_sr": float(img.Le.max()),
        "moon_pixels": int(img.mask.sum()),
        "variant": img.meta["render"]["variant"],
    }
