"""From a scenario to rendered frames: builds the camera, spectra, Moon model and renderer,
validates everything before any rendering starts, and writes one EXR per frame."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from starnav.config import AlbedoMapConfig, Scenario, build_camera
from starnav.constants import AU
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry, static_geometry_from_config
from starnav.lunar_calibration import lunar_calibration
from starnav.photometry import albedo_parameter
from starnav.radiance import RadianceImage, write_exr
from starnav.renderer.render import (
    AlbedoMap,
    MoonModel,
    MoonRenderer,
    RenderSettings,
    load_albedo_map,
)
from starnav.renderer.scene import check_camera_for_render, icosphere_mesh
from starnav.seeding import STAGE_RENDER, seed_u32
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
    from starnav.renderer.dem_hook import dem_moon_model  # loads starnav.dem only when needed

    return dem_moon_model(sc, common, mean_normal_albedo(sc))


def mean_normal_albedo(sc: Scenario) -> float:
    """The scenario's (mean) normal albedo: ``moon.albedo`` when a number, else the
    ROLO-calibrated mean normal albedo of the real Moon [-]."""
    if isinstance(sc.moon.albedo, int | float):
        return float(sc.moon.albedo)
    return lunar_calibration().mean_normal_albedo


def renderer_from_scenario(sc: Scenario) -> MoonRenderer:
    """A :class:`MoonRenderer` configured by ``sc`` (validates camera, spectra, Moon)."""
    camera = build_camera(sc.camera)
    check_camera_for_render(camera)
    response = sensor_response_from_config(sc.sensor_response)
    sun = solar_spectrum_from_config(sc.sun, distance=AU)
    moon = moon_model_from_scenario(sc)
    r = sc.render
    settings = RenderSettings(spp=r.spp, crop=r.crop, crop_margin_px=r.crop_margin_px,
                              aovs=r.aovs, variants=tuple(r.variants), sampler=r.sampler,
                              wavelength_step_nm=r.wavelength_step_nm)
    return MoonRenderer(camera, response, sun, moon, settings)


def frame_geometries(sc: Scenario) -> list[FrameGeometry]:
    """The frames of a scenario: its trajectory's, or the single static ``geometry`` frame."""
    camera = build_camera(sc.camera)
    radius = sc.moon.radius_km * 1e3
    if sc.trajectory is None:
        return [static_geometry_from_config(camera, sc.geometry, radius)]
    from starnav.scenes import frame_geometries as scene_frames

    return list(scene_frames(sc))


def render_scenario(sc: Scenario, frames: list[FrameGeometry] | None = None
                    ) -> Iterator[RadianceImage]:
    """Render every frame of ``sc`` (validated up front); yields RadianceImages in order."""
    renderer = renderer_from_scenario(sc)
    geoms = frame_geometries(sc) if frames is None else frames
    for g in geoms:
        yield renderer.render(g, seed=seed_u32(sc.seed, STAGE_RENDER, g.index))


def render_to_directory(sc: Scenario, out: str | Path,
                        progress: Callable[[int, int], None] | None = None) -> list[Path]:
    """Render the scenario's frames to ``out/frame_NNNNNN.exr`` (atomic writes)."""
    out = Path(out)
    geoms = frame_geometries(sc)
    if not geoms:
        raise ConfigError("trajectory", None, "at least one frame")
    paths = []
    for k, img in enumerate(render_scenario(sc, geoms)):
        idx = geoms[k].index
        paths.append(write_exr(img, out / f"frame_{idx:06d}.exr"))
        if progress is not None:
            progress(k + 1, len(geoms))
        log.info("frame %d: L max %.4g W m^-2 sr^-1", idx, float(img.L.max()))
    return paths


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
