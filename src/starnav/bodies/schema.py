"""Schema of the ``target`` and ``moon`` sections: which body the frames look at, and the Moon.

``moon`` says what the Moon is (shape, photometric model and its parameters, albedo as a number
or a map, the DEM for ``shape: dem``; :class:`MoonConfig`); :class:`PhotometryConfig` is the
photometric model of every body's surface.
``target: null`` (the default) or ``{kind: moon}`` is the Moon of the ``moon`` section;
``{kind: ellipsoid, ...}`` a triaxial body with an IAU rotation model (:class:`EllipsoidConfig`);
``{kind: shape_model, model: itokawa|eros|<path>, ...}`` a small body from its shape model
(:class:`ShapeModelConfig`, :class:`starnav.bodies.small_body.ShapeModelBody`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator

from starnav.config_base import StrictModel
from starnav.dem.schema import DemConfig
from starnav.fields import NonNegativeFloat, PositiveFloat
from starnav.photometry import PHOTOMETRIC_MODELS, get_model, hapke_preset


class PhotometryConfig(StrictModel):
    """Photometric model of a body's surface and its parameters.

    ``model``: ``hapke`` (Hapke 2012, the default), ``lambert``, ``lommel_seeliger`` or
    ``lunar_lambert`` (McEwen). ``preset`` picks Hapke's parameter set: ``rolo-calibrated`` (the
    phase-function and opposition parameters fitted to the ROLO model with the real albedo map,
    :mod:`starnav.lunar_calibration`) or ``sato2014`` (Sato et al. 2014 as published);
    ``params`` overrides single values (``b``, ``c``, ``bs0``, ``hs``, ``bc0``, ``hc``,
    ``theta_bar_deg``). ``spectral_shape``: ``rolo`` gives the reflectance the Moon's colour
    (ROLO's A(lambda) relative to 550 nm), ``grey`` a flat one (the analytic test cases).
    ``clark2002`` is the S-type asteroid set of the small bodies
    (:data:`starnav.photometry.HAPKE_S_TYPE_CLARK2002`).
    """

    model: str = Field(
        "hapke", description=f"photometric model of the surface, one of: "
        f"{', '.join(PHOTOMETRIC_MODELS)} (hapke: Hapke 2012; lunar_lambert: McEwen)")
    preset: Literal["rolo-calibrated", "sato2014", "clark2002"] = Field(
        "rolo-calibrated", description="Hapke parameter set (ignored by the other models)")
    params: dict[str, float] = Field(
        default_factory=dict, description="single parameter overrides of the model, name: value "
        "(Hapke: b, c, bs0, hs, bc0, hc, theta_bar_deg); empty: the preset's")
    spectral_shape: Literal["rolo", "grey"] = Field(
        "rolo", description="reflectance colour: ROLO lunar reddening (1 at 550 nm) or flat")

    @model_validator(mode="after")
    def _known_model(self) -> PhotometryConfig:
        try:
            get_model(self.model).check_params(dict(self.params))
        except (KeyError, ValueError) as err:
            raise ValueError(str(err)) from None
        return self

    def resolved_params(self) -> dict[str, float]:
        """The model's parameters: the preset (Hapke) with ``params`` on top."""
        base = hapke_preset(self.preset) if self.model == "hapke" else {}
        return get_model(self.model).check_params({**base, **self.params})


class AlbedoMapConfig(StrictModel):
    """Single-channel albedo map over selenographic longitude (columns, -180..180 deg from the
    left edge) and latitude (rows, +90 deg at the top), equirectangular. ``quantity``: the
    values are normal albedos (any model) or Hapke single-scattering albedos (Hapke only)."""

    path: Path = Field(
        description="equirectangular single-channel albedo map file (longitude -180..180 deg from "
        "the left edge, +90 deg latitude at the top)")
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
    photometry: PhotometryConfig = Field(
        default_factory=PhotometryConfig, description="photometric model of the surface and its "
        "parameters")
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


class EllipsoidConfig(StrictModel):
    """A triaxial ellipsoid body spinning about its shortest axis (body-fixed z).

    The defaults are Itokawa's best-fit ellipsoid (Fujiwara et al. 2006, Science 312, 1330:
    535 x 294 x 209 m), its IAU pole and period (Archinal et al. 2018, table 5: alpha0 = 90.53,
    delta0 = -66.30 deg, W = 0.0 + 712.143 deg/day, i.e. 12.132 h, retrograde) and a
    Lommel-Seeliger surface (the small-body photometry of the fly-by issue replaces it with
    published S-type Hapke parameters).
    """

    kind: Literal["ellipsoid"] = Field(
        "ellipsoid", description="body type: a triaxial ellipsoid")
    name: str = Field("itokawa-ellipsoid", description="label in manifests and reports")
    radii_km: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = Field(
        (0.2675, 0.147, 0.1045), description="semi-axes along body x, y, z [km]")
    pole_ra_deg: float = Field(90.53, description="pole right ascension, J2000 [deg]")
    pole_dec_deg: Annotated[float, Field(ge=-90, le=90)] = Field(
        -66.30, description="pole declination, J2000 [deg]")
    prime_meridian_deg: float = Field(0.0, description="W0, prime meridian at J2000 [deg]")
    rotation_deg_per_day: float = Field(
        712.143, description="W_dot [deg/day] (IAU: W = W0 + W_dot d)")
    photometry: PhotometryConfig = Field(
        default_factory=lambda: PhotometryConfig(model="lommel_seeliger",
                                                 spectral_shape="grey"),
        description="photometric model (hapke, lommel_seeliger, lambert, lunar_lambert)")
    albedo: Annotated[float, Field(gt=0, le=1)] = Field(
        0.12, description="normal albedo at 550 nm [-]; Lommel-Seeliger reaches at most "
        "0.125 (w = 8 A_n <= 1): brighter S-types (~0.25) need Hapke with an opposition surge")
    mesh_subdivisions: Annotated[int, Field(ge=0, le=8)] = Field(
        6, description="icosphere subdivisions of the rendered mesh (6 -> 81 920 triangles)")


class ShapeModelConfig(StrictModel):
    """A small body from a shape model: a packaged one (``itokawa``, ``eros``) or a ``.tab`` /
    ``.obj`` file (km, body-fixed axes, origin at the centre of mass).

    Every ``None`` takes the packaged model's published value
    (:data:`starnav.bodies.small_body.SMALL_BODY_FACTS`: IAU rotation model, GM, albedo); a
    model read from a file has no published values, so its spin (the four IAU angles and
    rates) must be given, and its GM defaults to 0 (straight-line fly-by).
    """

    kind: Literal["shape_model"] = Field(
        "shape_model", description="a small body from its shape model (PDS .tab or OBJ), "
        "rotating with its spin state")
    model: str = Field("itokawa", description="packaged model name (itokawa, eros) or a path "
                       "to a .tab (PDS vertex/facet) or .obj file in km")
    name: str | None = Field(None, description="label in manifests; None: the model's name")
    pole_ra_deg: float | None = Field(None, description="pole right ascension, J2000 [deg]")
    pole_dec_deg: Annotated[float, Field(ge=-90, le=90)] | None = Field(
        None, description="pole declination, J2000 [deg]")
    prime_meridian_deg: float | None = Field(None, description="W0 at J2000 [deg]")
    rotation_deg_per_day: float | None = Field(
        None, description="W_dot [deg/day] (IAU: W = W0 + W_dot d)")
    gm_m3_s2: Annotated[float, Field(ge=0)] | None = Field(
        None, description="gravitational parameter [m^3/s^2] (the hyperbolic fly-by)")
    radii_km: tuple[PositiveFloat, PositiveFloat, PositiveFloat] | None = Field(
        None, description="reference ellipsoid semi-axes along body x, y, z [km]; None: the "
        "ellipsoid with the mesh's moments of inertia (ShapeModel.equivalent_ellipsoid_radii)")
    photometry: PhotometryConfig = Field(
        default_factory=lambda: PhotometryConfig(model="hapke", preset="clark2002",
                                                 spectral_shape="grey"),
        description="photometric model: Hapke with the S-type (Eros, Clark et al. 2002) "
        "parameters by default; lommel_seeliger, lambert also work")
    albedo: Annotated[float, Field(gt=0, le=1)] | None = Field(
        None, description="normal albedo at 550 nm [-]; None: the model's published "
        "geometric albedo")


class MoonTargetConfig(StrictModel):
    """The Moon described by the scenario's ``moon`` section."""

    kind: Literal["moon"] = Field(
        "moon", description="body type: the Moon of the moon section")


#: The ``target`` section: one of the bodies above, told apart by ``kind``.
TargetConfig = Annotated[MoonTargetConfig | EllipsoidConfig | ShapeModelConfig,
                         Field(discriminator="kind")]
