"""Schema of the ``target`` section: which body the frames look at.

``target: null`` (the default) or ``{kind: moon}`` is the Moon of the ``moon`` section;
``{kind: ellipsoid, ...}`` a triaxial body with an IAU rotation model (:class:`EllipsoidConfig`);
``{kind: shape_model, model: itokawa|eros|<path>, ...}`` a small body from its shape model
(:class:`ShapeModelConfig`, :class:`starnav.bodies.small_body.ShapeModelBody`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from starnav.config_base import StrictModel
from starnav.fields import PositiveFloat
from starnav.renderer.schema import PhotometryConfig


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
