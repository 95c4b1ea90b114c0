"""Scenario configuration: YAML validated by frozen pydantic models.

A scenario file has the sections ``camera``, ``detector``, ``moon``, ``sun``, ``trajectory``
(or a static ``geometry``), ``pointing``, ``render``, ``navigation``, ``output`` and ``seed``
(DESIGN.md). Every model is frozen and rejects unknown keys, so a typo is an error, not a
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
from typing import Annotated, Any, Literal

import yaml
from pydantic import Field, ValidationError, field_validator, model_validator

from starnav.atomic import atomic_write_text
from starnav.config_base import (
    StrictModel,
    apply_overrides,
    format_validation_error,
    parse_override,
)
from starnav.dem.schema import DemConfig
from starnav.errors import ConfigError, DataFileError

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]


# --------------------------------------------------------------------------- camera
class CameraConfig(StrictModel):
    """Camera optics and detector geometry. ``None`` keeps the preset's value."""

    preset: str = Field("aa-str", description="named camera (starnav.camera.CAMERA_PRESETS)")
    focal_length_mm: PositiveFloat | None = Field(None, description="effective focal length [mm]")
    pixel_pitch_um: PositiveFloat | None = Field(None, description="pixel pitch [um]")
    width: Annotated[int, Field(ge=1)] | None = Field(None, description="detector columns [px]")
    height: Annotated[int, Field(ge=1)] | None = Field(None, description="detector rows [px]")
    f_number: PositiveFloat | None = Field(None, description="f-number N = f / D [-]")
    principal_point_px: tuple[float, float] | None = Field(
        None, description="principal point (u, v) [px]; default the detector centre"
    )
    distortion: tuple[float, float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0, 0.0), description="Brown-Conrady (k1, k2, k3, p1, p2) [-]"
    )


# --------------------------------------------------------------------------- sun
class SunConfig(StrictModel):
    """Solar spectrum. ``spectrum``: ``astm-g173`` (ASTM E-490/G-173 extraterrestrial, from
    colour-science) or ``blackbody`` (``temperature_k``, scaled to ``tsi_w_m2``)."""

    spectrum: Literal["astm-g173", "blackbody"] = "astm-g173"
    tsi_w_m2: PositiveFloat | None = Field(
        None, description="rescale the spectrum to this total irradiance at 1 AU [W/m^2]"
    )
    temperature_k: PositiveFloat = Field(5772.0, description="black-body temperature [K]")


# --------------------------------------------------------------------------- sensor response
class SensorResponseConfig(StrictModel):
    """Spectral response QE(lambda) x T(lambda). Default: the AA-STR table (REFERENCE.md s1).

    Either ``preset`` or a table: ``wavelengths_nm`` band *edges* (n + 1 values) with ``qe``
    and ``transmission`` per band (n values, piecewise constant), or ``wavelengths_nm`` samples
    (n values) with ``qe``/``transmission`` per sample (piecewise linear, ``kind: samples``).
    """

    preset: str | None = "aa-str"
    kind: Literal["bands", "samples"] = "bands"
    wavelengths_nm: tuple[float, ...] | None = None
    qe: tuple[float, ...] | None = None
    transmission: tuple[float, ...] | None = None


# --------------------------------------------------------------------------- moon
class PhotometryConfig(StrictModel):
    """Photometric model of the lunar surface and its parameters.

    ``model``: ``hapke`` (Hapke 2012, the default), ``lambert``, ``lommel_seeliger`` or
    ``lunar_lambert`` (McEwen). ``preset`` picks Hapke's parameter set: ``rolo-calibrated`` (the
    phase-function and opposition parameters fitted to the ROLO model with the real albedo map,
    :mod:`starnav.lunar_calibration`) or ``sato2014`` (Sato et al. 2014 as published);
    ``params`` overrides single values (``b``, ``c``, ``bs0``, ``hs``, ``bc0``, ``hc``,
    ``theta_bar_deg``). ``spectral_shape``: ``rolo`` gives the reflectance the Moon's colour
    (ROLO's A(lambda) relative to 550 nm), ``grey`` a flat one (the analytic test cases).
    """

    model: str = "hapke"
    preset: Literal["rolo-calibrated", "sato2014"] = Field(
        "rolo-calibrated", description="Hapke parameter set (ignored by the other models)")
    params: dict[str, float] = Field(default_factory=dict)
    spectral_shape: Literal["rolo", "grey"] = Field(
        "rolo", description="reflectance colour: ROLO lunar reddening (1 at 550 nm) or flat")

    @model_validator(mode="after")
    def _known_model(self) -> PhotometryConfig:
        from starnav.photometry import get_model

        try:
            get_model(self.model).check_params(dict(self.params))
        except (KeyError, ValueError) as err:
            raise ValueError(str(err)) from None
        return self

    def resolved_params(self) -> dict[str, float]:
        """The model's parameters: the preset (Hapke) with ``params`` on top."""
        from starnav.photometry import get_model, hapke_preset

        base = hapke_preset(self.preset) if self.model == "hapke" else {}
        return get_model(self.model).check_params({**base, **self.params})


class AlbedoMapConfig(StrictModel):
    """Single-channel albedo map over selenographic longitude (columns, -180..180 deg from the
    left edge) and latitude (rows, +90 deg at the top), equirectangular. ``quantity``: the
    values are normal albedos (any model) or Hapke single-scattering albedos (Hapke only)."""

    path: Path
    scale: PositiveFloat = Field(1.0, description="multiplier applied to the decoded map [-]")
    quantity: Literal["normal_albedo", "hapke_w"] = Field(
        "normal_albedo", description="what the map's values are")


def _default_real_moon() -> DemConfig:
    """LOLA LDEM_4 terrain with the LROC WAC albedo map, both shipped with starnav."""
    return DemConfig(source="lola", albedo={"source": "lroc"})


class MoonConfig(StrictModel):
    """The Moon: shape, photometry and albedo.

    ``albedo`` is the **normal albedo** at 550 nm (:mod:`starnav.photometry`: every model derives
    its own parameter from it): a number (a uniform Moon, or the mean of a relative albedo map
    such as the default LROC one) or a map file (``shape: sphere``). ``None`` (the default) is the
    ROLO-calibrated mean normal albedo of the real Moon.
    """

    shape: Literal["sphere", "mesh", "dem"] = Field(
        "dem", description="exact sphere, icosphere mesh, or DEM mesh (starnav.dem; default: "
        "the real Moon, LOLA terrain and LROC albedo)"
    )
    radius_km: PositiveFloat = Field(1737.4, description="reference sphere radius [km]")
    mesh_subdivisions: Annotated[int, Field(ge=0, le=9)] = Field(
        7, description="icosphere subdivisions for shape=mesh (7 -> 327 680 triangles)"
    )
    photometry: PhotometryConfig = Field(default_factory=PhotometryConfig)
    albedo: NonNegativeFloat | AlbedoMapConfig | None = Field(
        None, description="normal albedo at 550 nm [-]: a number, a map, or None for the "
        "ROLO-calibrated real Moon"
    )
    albedo_scale: PositiveFloat = Field(
        1.0, description="global radiance multiplier (albedo-exposure scaling studies) [-]"
    )
    dem: DemConfig = Field(
        default_factory=_default_real_moon,
        description="DEM and albedo sources and meshing for shape=dem (starnav.dem.schema)"
    )

    @field_validator("dem", mode="before")
    @classmethod
    def _real_moon_defaults(cls, v: Any) -> Any:
        """Keys missing from a given ``dem`` section take the real-Moon defaults (as
        ``starnav init`` shows them), not the bare DemConfig's: ``source: lola``, and an albedo
        map that goes with the source (``lroc`` for ``lola``, the procedural map for
        ``procedural``, none for a user's file). An explicit ``albedo: null`` is kept."""
        if not isinstance(v, dict):
            return v
        v = dict(v)
        source = v.setdefault("source", "lola")
        default_albedo = {"lola": "lroc", "procedural": "procedural"}.get(source)
        if "albedo" not in v:
            if default_albedo is not None:
                v["albedo"] = {"source": default_albedo}
        elif isinstance(v["albedo"], dict) and "source" not in v["albedo"]:
            v["albedo"] = {"source": default_albedo or "procedural", **v["albedo"]}
        return v

    @field_validator("albedo", mode="before")
    @classmethod
    def _albedo_sign(cls, v: Any) -> Any:
        if isinstance(v, int | float) and not isinstance(v, bool):
            if v < 0:
                raise ValueError(f"the normal albedo must be >= 0, got {v}")
            if v > 1:
                raise ValueError(f"a normal albedo is at most 1 (the Moon's is ~0.12), got {v}")
        return v


# --------------------------------------------------------------------------- geometry
class StaticGeometryConfig(StrictModel):
    """One frame without a trajectory: observer range, phase angle and the Moon's place."""

    range_km: PositiveFloat = Field(60_000.0, description="camera to Moon-centre distance [km]")
    phase_angle_deg: Annotated[float, Field(ge=0, le=180)] = Field(
        30.0, description="Sun-Moon-observer angle [deg]"
    )
    sun_azimuth_deg: float = Field(
        0.0, description="direction of the subsolar point seen from the sub-observer point, "
        "measured from selenographic east towards north [deg]"
    )
    moon_offset_px: tuple[float, float] = Field(
        (0.0, 0.0), description="Moon centre offset from the principal point (du, dv) [px]"
    )
    roll_deg: float = Field(0.0, description="rotation of the camera about the Moon line [deg]")
    sub_observer_lat_deg: Annotated[float, Field(ge=-90, le=90)] = 0.0
    sub_observer_lon_deg: float = 0.0
    sun_distance_au: PositiveFloat = Field(1.0, description="Sun-Moon distance [AU]")


# --------------------------------------------------------------------------- render
class RenderConfig(StrictModel):
    """Rendering settings."""

    spp: Annotated[int, Field(ge=1)] = Field(16, description="samples per pixel")
    variants: tuple[str, ...] = Field(
        ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral"),
        description="Mitsuba variants in order of preference",
    )
    crop: bool = Field(True, description="trace only the Moon's bounding box (plus margin)")
    crop_margin_px: NonNegativeFloat = Field(4.0, description="margin around the disc [px]")
    aovs: bool = Field(True, description="write range/normal/lat/lon/angle/mask channels")
    sampler: Literal["multijitter", "stratified", "independent", "ldsampler"] = Field(
        "multijitter", description="Mitsuba sampler of the radiance pass"
    )
    wavelength_step_nm: Annotated[float, Field(gt=0, le=50)] = Field(
        1.0, description="grid step of the spectra handed to Mitsuba [nm]"
    )


class OutputConfig(StrictModel):
    directory: Path = Path("out")


from starnav.detector.schema import DetectorConfig  # noqa: E402
from starnav.navigation.schema import NavigationConfig  # noqa: E402
from starnav.scenes.schema import PointingConfig, TrajectoryConfig  # noqa: E402


class Scenario(StrictModel):
    """A complete scenario. ``geometry`` (static, one frame) is used when ``trajectory`` is
    ``None``; otherwise frames come from the trajectory."""

    camera: CameraConfig = Field(default_factory=CameraConfig)
    sensor_response: SensorResponseConfig = Field(default_factory=SensorResponseConfig)
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    moon: MoonConfig = Field(default_factory=MoonConfig)
    sun: SunConfig = Field(default_factory=SunConfig)
    geometry: StaticGeometryConfig = Field(default_factory=StaticGeometryConfig)
    trajectory: TrajectoryConfig | None = None
    pointing: PointingConfig = Field(default_factory=PointingConfig)
    render: RenderConfig = Field(default_factory=RenderConfig)
    navigation: NavigationConfig = Field(default_factory=NavigationConfig)
    output: OutputConfig = Field(default_factory=OutputConfig)
    seed: Annotated[int, Field(ge=0)] = 20250101


# --------------------------------------------------------------------------- loading
# The dotted ``--set`` overrides and the validation-error message are shared with the bench, DEM
# and sweep schemas: one implementation in starnav.config_base, re-exported here.
_format_validation_error = format_validation_error
_parse_override = parse_override


def scenario_from_dict(data: dict[str, Any],
                       overrides: list[str] | tuple[str, ...] = ()) -> Scenario:
    """Validate a scenario mapping (plus ``--set`` style overrides).

    Raises
    ------
    ConfigError
        naming the first offending field, its value and what was expected.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError("<root>", type(data).__name__, "a mapping of scenario sections")
    data = apply_overrides(data, overrides)
    try:
        return Scenario.model_validate(data)
    except ValidationError as err:
        raise _format_validation_error(err) from None


def load_scenario(path: str | os.PathLike[str] | None,
                  overrides: list[str] | tuple[str, ...] = ()) -> Scenario:
    """Read and validate a YAML scenario; ``None`` gives the built-in defaults."""
    if path is None:
        return scenario_from_dict({}, overrides)
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"scenario file {str(p)!r} does not exist")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as err:
        raise ConfigError("scenario file", str(p), f"valid YAML ({err})") from None
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


# --------------------------------------------------------------------------- builders
def build_camera(cfg: CameraConfig):  # -> starnav.camera.Camera
    """The :class:`~starnav.camera.Camera` described by ``cfg`` (SI inside)."""
    from starnav.camera import Camera

    over: dict[str, Any] = {}
    if cfg.focal_length_mm is not None:
        over["focal_length"] = cfg.focal_length_mm * 1e-3
    if cfg.pixel_pitch_um is not None:
        over["pitch_x"] = over["pitch_y"] = cfg.pixel_pitch_um * 1e-6
    if cfg.width is not None:
        over["width"] = cfg.width
    if cfg.height is not None:
        over["height"] = cfg.height
    if cfg.f_number is not None:
        over["f_number"] = cfg.f_number
    if cfg.principal_point_px is not None:
        over["cx"], over["cy"] = cfg.principal_point_px
    k1, k2, k3, p1, p2 = cfg.distortion
    over.update(k1=k1, k2=k2, k3=k3, p1=p1, p2=p2)
    return Camera.preset(cfg.preset, **over)


EXAMPLE_HEADER = """\
# starnav scenario (written by `starnav init`). Every key is optional: missing keys take the
# defaults shown here. Units are in the key names (_mm, _um, _km, _deg, _s); inside starnav
# everything is SI. Override any key from the command line: --set moon.albedo=0.2
"""
