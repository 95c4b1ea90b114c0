"""Scenario configuration: YAML validated by frozen pydantic models.

A scenario file has the sections ``camera``, ``detector``, ``moon``, ``sun``, ``trajectory``
(or a static ``geometry``), ``pointing``, ``render``, ``navigation``, ``output`` and ``seed``.
Every model is frozen and rejects unknown keys, so a typo is an error, not a
silently ignored setting. Unit suffixes (``_mm``, ``_um``, ``_km``, ``_deg``) appear only here,
at the edge; :func:`build_camera` and friends convert to SI.

Each subpackage owns the schema of its own section (``starnav.detector.schema`` and so on); this
module assembles them into :class:`Scenario`.

Example
-------
>>> from starnav.config import Scenario
>>> sc = Scenario()                      # built-in defaults: AA-STR at 60 000 km, phase 30 deg
>>> sc.camera.preset
'aa-str'
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import Field

from starnav.atomic import atomic_write_text
from starnav.bodies.schema import AlbedoMapConfig, MoonConfig, PhotometryConfig, TargetConfig
from starnav.camera import CameraConfig, camera_from_config
from starnav.config_base import StrictModel, apply_overrides, model_from_mapping, read_yaml_file
from starnav.detector.schema import DetectorConfig
from starnav.geometry import StaticGeometryConfig
from starnav.navigation.schema import NavigationConfig
from starnav.renderer.schema import RenderConfig
from starnav.scenes.schema import PointingConfig, SpacecraftConfig, TrajectoryConfig
from starnav.spectra import SensorResponseConfig, SunConfig
from starnav.stars.schema import StarsConfig

#: The camera of a ``camera`` section (:func:`starnav.camera.camera_from_config`).
build_camera = camera_from_config


class OutputConfig(StrictModel):
    """Where commands write when no ``--out`` is given."""

    directory: Path = Field(
        Path("out"), description="default output directory (relative to the working "
        "directory): `starnav render` writes into directory/render, `starnav dataset` into "
        "directory/dataset, unless --out is given")


class Scenario(StrictModel):
    """A complete scenario. ``geometry`` (static, one frame) is used when ``trajectory`` is
    ``None``; otherwise frames come from the trajectory."""

    camera: CameraConfig = Field(
        default_factory=CameraConfig, description="camera optics and detector geometry (pinhole + "
        "distortion)")
    sensor_response: SensorResponseConfig = Field(
        default_factory=SensorResponseConfig, description="spectral response of the sensor: QE x "
        "optics transmission")
    detector: DetectorConfig = Field(
        default_factory=DetectorConfig, description="the detector chain from photons to DN and "
        "its readout modes")
    moon: MoonConfig = Field(
        default_factory=MoonConfig, description="the Moon: shape, photometry, albedo, terrain")
    sun: SunConfig = Field(
        default_factory=SunConfig, description="the solar spectrum")
    geometry: StaticGeometryConfig = Field(
        default_factory=StaticGeometryConfig, description="the one static frame, used when "
        "trajectory is null")
    trajectory: TrajectoryConfig | None = Field(
        None, description="the observer's arc and the frame epochs along it; null: the one static "
        "frame of the geometry section")
    spacecraft: SpacecraftConfig = Field(
        default_factory=SpacecraftConfig, description="the spacecraft as the truth dynamics "
        "see it: mass, area and reflectivity for the solar radiation pressure "
        "(trajectory.forces.srp)")
    pointing: PointingConfig = Field(
        default_factory=PointingConfig, description="the camera's Moon-pointing attitude and its "
        "on-board knowledge error")
    render: RenderConfig = Field(
        default_factory=RenderConfig, description="Mitsuba rendering settings")
    target: TargetConfig | None = Field(
        None, description="the body the frames look at: null or {kind: moon} for the Moon of "
        "the moon section, {kind: ellipsoid, ...} for a triaxial small body (starnav.bodies)")
    stars: StarsConfig = Field(
        default_factory=StarsConfig, description="stars in the frames (Hipparcos, physical "
        "units, the detector's PSF; off by default: a black sky)")
    navigation: NavigationConfig = Field(
        default_factory=NavigationConfig, description="the navigation chain: limb points, "
        "refinement, RANSAC, fix, filter")
    output: OutputConfig = Field(
        default_factory=OutputConfig, description="output settings")
    seed: Annotated[int, Field(ge=0)] = Field(
        20250101, description="master seed of every random stream (noise, pointing, knowledge "
        "errors; starnav.seeding)")


# --------------------------------------------------------------------------- loading
# One loader for every configuration file (scenario, bench): starnav.config_base.


def scenario_from_dict(data: dict[str, Any],
                       overrides: list[str] | tuple[str, ...] = ()) -> Scenario:
    """Validate a scenario mapping (plus ``--set`` style overrides).

    Raises
    ------
    ConfigError
        naming the first offending field, its value and what was expected.
    """
    return model_from_mapping(Scenario, data, overrides, root="<root>",
                              expected="a mapping of scenario sections")


def load_scenario(path: str | os.PathLike[str] | None,
                  overrides: list[str] | tuple[str, ...] = ()) -> Scenario:
    """Read and validate a YAML scenario; ``None`` gives the built-in defaults."""
    if path is None:
        return scenario_from_dict({}, overrides)
    data = read_yaml_file(Path(path), "scenario file")
    sc = scenario_from_dict(data or {}, overrides)
    return sc


def scenario_to_dict(sc: Scenario) -> dict[str, Any]:
    """JSON/YAML-safe dict of the fully resolved scenario."""
    return sc.model_dump(mode="json")


def write_resolved(sc: Scenario, directory: str | os.PathLike[str],
                   name: str = "scenario.resolved.yaml") -> Path:
    """Write the resolved scenario next to a command's outputs."""
    text = yaml.safe_dump(scenario_to_dict(sc), sort_keys=False)
    return atomic_write_text(Path(directory) / name, text)


EXAMPLE_HEADER = """\
# starnav scenario (written by `starnav init`). Every key is optional: missing keys take the
# defaults shown here. Units are in the key names (_mm, _um, _km, _deg, _s); inside starnav
# everything is SI. Override any key from the command line: --set moon.albedo=0.2
"""


__all__ = ["AlbedoMapConfig", "CameraConfig", "DetectorConfig", "MoonConfig", "NavigationConfig",
           "OutputConfig", "PhotometryConfig", "PointingConfig", "RenderConfig", "Scenario",
           "SensorResponseConfig", "SpacecraftConfig", "StaticGeometryConfig", "SunConfig",
           "TrajectoryConfig",
           "apply_overrides", "build_camera", "camera_from_config", "load_scenario",
           "scenario_from_dict", "scenario_to_dict", "write_resolved"]
