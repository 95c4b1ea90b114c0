"""Check a scenario as far as rendering it would, without rendering: ``starnav validate``.

Builds, in the order a frame needs them, every object :class:`~starnav.simulate.Simulator`
would: the camera (and its fitness for the renderer), the sensor response and the Sun's
spectrum (table lengths, values in [0, 1]), the target body and the renderer's model of it (the
DEM and albedo files read, the albedo reachable by the photometric model), every frame's
geometry (an observer inside the body is an error here, not at frame 12), and the navigation
chain's options. Any problem is the :class:`~starnav.errors.StarnavError` the first frame of
``render`` or ``dataset`` would raise. Returns the derived quantities a user wants to see, with
their units and enough digits.
"""

from __future__ import annotations

import math
from typing import Any

from starnav.camera import camera_from_config
from starnav.config import Scenario
from starnav.constants import AU
from starnav.renderer.scene import check_camera_for_render
from starnav.simulate.build import body_from_scenario, chain_options, scene_from_scenario
from starnav.spectra import band_integrals, sensor_response_from_config, solar_spectrum_from_config


def check_scenario(sc: Scenario) -> dict[str, Any]:
    """Everything ``render`` would check before its first frame (module docstring); returns the
    derived quantities (SI, names carry the units)."""
    camera = camera_from_config(sc.camera)
    check_camera_for_render(camera, sc.render.spp)
    response = sensor_response_from_config(sc.sensor_response)
    sun = solar_spectrum_from_config(sc.sun, distance=AU)
    band = band_integrals(sun, response)
    body = body_from_scenario(sc)
    body.render_model()
    geoms = scene_from_scenario(sc, camera=camera).geometries()
    chain_options(sc)
    ranges = [g.range for g in geoms]
    phases = [math.degrees(g.phase_angle) for g in geoms]
    d = camera.describe()
    return {
        "frames": len(geoms),
        "target": body.describe(),
        "range_km": [min(ranges) / 1e3, max(ranges) / 1e3],
        "phase_angle_deg": [min(phases), max(phases)],
        "apparent_radius_px": [min(g.apparent_radius for g in geoms) / camera.ifov,
                               max(g.apparent_radius for g in geoms) / camera.ifov],
        "band_irradiance_1au_w_m2": band.irradiance,
        "band_electron_irradiance_1au_e_s_m2": band.electron_irradiance,
        "band_nm": list(band.band_nm),
        "camera": d,
    }
