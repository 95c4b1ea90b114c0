"""From a scenario to the domain objects that make its frames, each built once.

The scenario's sections are validated settings with units in their names; this module turns
them into the SI objects the physics packages work with, and is the only place that does:

* :func:`camera_from_config` -> :class:`~starnav.camera.Camera` (one per process, passed down);
* :func:`scene_from_scenario` -> :class:`~starnav.scenes.frames.Scene` (epochs, truth and
  :class:`~starnav.geometry.FrameGeometry` of each frame, static or along a trajectory);
* :func:`target_model_from_scenario` -> :class:`~starnav.bodies.model.TargetModel` (the albedo
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

from starnav.bodies import Moon, ShapeModelBody, TargetBody, TargetModel, TriaxialBody
from starnav.camera import Camera, camera_from_config
from starnav.config import Scenario
from starnav.constants import AU
from starnav.dem.detail import sub_posting_detail
from starnav.dem.grid import AlbedoGrid, DemGrid
from starnav.dem.load import as_dem_config, load_albedo, load_dem
from starnav.dem.mesh import MESH_CACHE, MeshCache, MeshOptions, view_mesh
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry, static_geometry_from_config
from starnav.navigation.pipeline import ChainOptions
from starnav.radiance import RadianceImage
from starnav.renderer.render import MoonRenderer, RenderSettings
from starnav.renderer.scene import check_camera_for_render
from starnav.scenes.ephemeris import Ephemeris
from starnav.scenes.frames import Scene
from starnav.scenes.trajectory import Trajectory, default_cache_dir
from starnav.spectra import sensor_response_from_config, solar_spectrum_from_config

log = logging.getLogger(__name__)


def body_from_scenario(sc: Scenario) -> TargetBody:
    """The target body of ``sc``: the Moon of its ``moon`` section (``target`` null or
    ``kind: moon``; body-fixed axes ``trajectory.moon_frame``), or the ``target`` section's
    small body (:mod:`starnav.bodies`)."""
    t = sc.target
    flyby = sc.trajectory is not None and sc.trajectory.source == "flyby"
    if t is None or t.kind == "moon":
        if flyby:
            raise ConfigError("trajectory.source", "flyby", "a small-body target "
                              "(target.kind: shape_model or ellipsoid) for a fly-by")
        frame = sc.trajectory.moon_frame if sc.trajectory is not None else "PA"
        return Moon(sc.moon, frame=frame)
    if sc.trajectory is not None and not flyby:
        raise ConfigError("target.kind", t.kind,
                          "a static geometry section (trajectory: null) or a fly-by "
                          "(trajectory.source: flyby): halo and OEM arcs are Moon-centred")
    if t.kind == "shape_model":
        return ShapeModelBody(t)
    return TriaxialBody(t)


def target_model_from_scenario(sc: Scenario) -> TargetModel:
    """The renderer's model of the scenario's target body (:meth:`TargetBody.render_model`):
    the normal albedo converted to the photometric model's own parameter, maps and DEMs read
    here, so that a missing file is reported before any rendering."""
    return body_from_scenario(sc).render_model()


def renderer_from_scenario(sc: Scenario, camera: Camera | None = None) -> MoonRenderer:
    """A :class:`MoonRenderer` configured by ``sc`` (validates camera, spectra, Moon);
    ``camera`` the scenario's camera when already built."""
    camera = camera_from_config(sc.camera) if camera is None else camera
    check_camera_for_render(camera, sc.render.spp)
    response = sensor_response_from_config(sc.sensor_response)
    sun = solar_spectrum_from_config(sc.sun, distance=AU)
    moon = body_from_scenario(sc).render_model()
    r = sc.render
    settings = RenderSettings(spp=r.spp, crop=r.crop, crop_margin_px=r.crop_margin_px,
                              aovs=r.aovs, variants=tuple(r.variants), sampler=r.sampler,
                              wavelength_step_nm=r.wavelength_step_nm,
                              adaptive=r.adaptive, interior_spp=r.interior_spp,
                              spectral_sampling=r.spectral_sampling,
                              earth_shadow=r.earth_shadow,
                              sun_limb_darkening=r.sun_limb_darkening)
    return MoonRenderer(camera, response, sun, moon, settings)


def scene_from_scenario(sc: Scenario, ephemeris: Ephemeris | None = None, *,
                        camera: Camera | None = None, arc: Trajectory | None = None,
                        cache_dir: str | Path | None = None) -> Scene:
    """The :class:`~starnav.scenes.frames.Scene` of ``sc``: its trajectory's frames, or the one
    frame of its static ``geometry`` section (with the attitude-knowledge error either way).

    A halo arc is kept on disk in ``cache_dir`` (default
    :func:`starnav.scenes.trajectory.default_cache_dir`): the client of a dataset or sweep
    writes it and each worker process reads it instead of shooting it again (~2 s each).
    """
    camera = camera_from_config(sc.camera) if camera is None else camera
    cache_dir = default_cache_dir() if cache_dir is None else cache_dir
    body = body_from_scenario(sc)
    eph = ephemeris or Ephemeris.default()
    return Scene(camera, sc.pointing, trajectory=sc.trajectory, static=sc.geometry,
                 body_radius=body.reference_radius_m, seed=sc.seed, ephemeris=eph,
                 arc=arc, cache_dir=cache_dir,
                 orientation=lambda t: body.orientation(t, eph),
                 gm=body.gm, spacecraft=sc.spacecraft)


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
    geom = static_geometry_from_config(camera, sc.geometry, body_radius=Moon(sc.moon).radii_m[0])
    dem = load_dem(cfg) if dem is None else dem
    albedo = load_albedo(cfg) if albedo is None else albedo
    Rb = geom.R_body_to_inertial.T
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


def chain_options(sc: Scenario) -> ChainOptions:
    """The navigation chain's SI options for ``sc``: its ``navigation`` section with the target
    body's reference ellipsoid (unless ``navigation.fix.moon_radii_km`` sets one) and what the
    frames were made with (noise, terrain, attitude knowledge)."""
    body = body_from_scenario(sc)
    return sc.navigation.chain_options(scenario=sc, radii_m=body.radii_m)
