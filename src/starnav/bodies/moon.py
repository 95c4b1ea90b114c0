"""The Moon as a target body: a sphere, an icosphere or the DEM mesh of the real (LOLA, LROC)
or procedural Moon, with the DE421 librations (``PA`` or ``ME`` axes) for its orientation.

The albedo the user gives is a normal albedo (a number, a map, or the ROLO-calibrated mean of
the real Moon); :meth:`Moon.render_model` converts it to the photometric model's own parameter
(:func:`starnav.photometry.albedo_parameter`) and reads every map and DEM before a frame is
rendered.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.bodies.base import FloatArray, TargetBody
from starnav.errors import ConfigError
from starnav.lunar_calibration import lunar_calibration
from starnav.photometry import albedo_parameter
from starnav.renderer.dem_hook import dem_moon_model
from starnav.renderer.render import AlbedoMap, MoonModel, load_albedo_map
from starnav.renderer.scene import icosphere_mesh
from starnav.renderer.schema import AlbedoMapConfig, MoonConfig
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

    def render_model(self) -> MoonModel:
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
            return MoonModel("sphere", **common)
        if m.shape == "mesh":
            return MoonModel("mesh", mesh=icosphere_mesh(radius, m.mesh_subdivisions),
                             **common)
        return dem_moon_model(m.dem, common, mean_normal_albedo(m))

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "shape": self.config.shape, "frame": self.frame,
                "photometry": self.config.photometry.model}
