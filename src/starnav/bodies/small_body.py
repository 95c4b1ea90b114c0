"""A small body from its shape model: mesh, IAU spin state, S-type photometry, per-pixel truth.

:class:`ShapeModelBody` is the :class:`~starnav.bodies.base.TargetBody` of
``target: {kind: shape_model, model: itokawa|eros|<path>}``:

* shape: the model's facets (:mod:`starnav.bodies.shape`, metres, body-fixed), rendered as
  they are;
* orientation: the IAU model (:func:`~starnav.bodies.base.iau_orientation`), spin about z;
* reference ellipsoid: the uniform ellipsoid of the mesh's moments of inertia, or
  ``radii_km``; ``bounding_radius_m`` bounds every vertex;
* photometry: Hapke with Eros's S-type parameters
  (:data:`starnav.photometry.HAPKE_S_TYPE_CLARK2002`) at the body's normal albedo, or any
  registered model;
* truth: :meth:`render_model` asks the renderer for each pixel's body-fixed surface point
  (AOVs ``x_body``, ``y_body``, ``z_body`` [m]).

References
----------
B. A. Archinal et al., "Report of the IAU Working Group on Cartographic Coordinates and
Rotational Elements: 2015", Celest. Mech. Dyn. Astron. 130 (2018) 22, table 5. The other
sources of :data:`SMALL_BODY_FACTS` stand beside it.

Index
-----
:class:`ShapeModelBody`, :data:`SMALL_BODY_FACTS`, :class:`SmallBodyFacts`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.bodies.base import FloatArray, TargetBody, iau_orientation, mesh_render_model
from starnav.bodies.mesh import BodyMesh
from starnav.bodies.model import TargetModel
from starnav.bodies.schema import ShapeModelConfig
from starnav.bodies.shape import (
    PACKAGED_SHAPE_MODELS,
    ShapeModel,
    read_shape_model,
    shape_model_path,
)
from starnav.errors import ConfigError
from starnav.registry import Registry


@dataclass(frozen=True)
class SmallBodyFacts:
    """Published values of a packaged small body (sources beside :data:`SMALL_BODY_FACTS`).

    The geometric albedo stands in for the normal albedo (they are equal for a Lommel-Seeliger
    sphere; a Hapke surface's limb darkening makes the geometric albedo a few per cent lower).
    """

    pole_ra_deg: float
    pole_dec_deg: float
    prime_meridian_deg: float
    rotation_deg_per_day: float
    gm_m3_s2: float
    normal_albedo: float

    @property
    def rotation_period_s(self) -> float:
        """Sidereal rotation period [s]."""
        return 360.0 / abs(self.rotation_deg_per_day) * 86400.0


#: Published spin, GM and albedo of the packaged models, by the shape model's name.
#: Itokawa: IAU rotation from Archinal et al. 2018 table 5 (the Hayabusa pole of Demura et al.
#: 2006, ecliptic (128.5, -89.66) deg; period 12.132 h); mass 3.51e10 kg +-3 % (Fujiwara et
#: al. 2006); geometric albedo V 0.27 (Tatsumi et al. 2018, Icarus 311, 175).
#: Eros: IAU rotation from Archinal et al. 2018 table 5 (period 5.270 h); GM from Miller et al.
#: 2002, Icarus 155, 3; geometric albedo 0.25 (Veverka et al. 2000, Science 289, 2088).
SMALL_BODY_FACTS: Registry[SmallBodyFacts] = Registry("small body", {
    "itokawa": SmallBodyFacts(90.53, -66.30, 0.0, 712.143, 6.6743e-11 * 3.51e10, 0.27),
    "eros": SmallBodyFacts(11.35, 17.22, 326.07, 1639.38864745, 4.4631e5, 0.25),
})

_SPIN_FIELDS = ("pole_ra_deg", "pole_dec_deg", "prime_meridian_deg", "rotation_deg_per_day")


class ShapeModelBody(TargetBody):
    """A small body from a shape model (module docstring).

    Parameters
    ----------
    config : ShapeModelConfig, optional
        Default: the packaged Itokawa radar model with its published values.
    shape : ShapeModel, optional
        An already-read model (default: read ``config.model``'s file here, so that a bad file
        is reported when the body is built, before any frame).
    """

    def __init__(self, config: ShapeModelConfig | None = None,
                 shape: ShapeModel | None = None) -> None:
        self.config = config if config is not None else ShapeModelConfig()
        c = self.config
        packaged = c.model in PACKAGED_SHAPE_MODELS
        facts = SMALL_BODY_FACTS.get(c.model) if packaged else None
        if facts is None:
            missing = [f for f in _SPIN_FIELDS if getattr(c, f) is None]
            if missing:
                raise ConfigError(f"target.{missing[0]}", None,
                                  f"the spin of shape model {c.model!r} ({', '.join(missing)}"
                                  "): a model read from a file has no published values")
        self.facts = facts
        self.spin = tuple(float(getattr(c, f)) if getattr(c, f) is not None
                          else float(getattr(facts, f)) for f in _SPIN_FIELDS)
        self.gm = (float(c.gm_m3_s2) if c.gm_m3_s2 is not None
                   else (facts.gm_m3_s2 if facts is not None else 0.0))
        self.normal_albedo = (float(c.albedo) if c.albedo is not None
                              else (facts.normal_albedo if facts is not None else 0.25))
        self.shape = shape if shape is not None else read_shape_model(shape_model_path(c.model))
        self.name = c.name or (c.model if packaged else self.shape.source)

    @cached_property
    def _radii(self) -> tuple[float, float, float]:
        if self.config.radii_km is not None:
            a, b, c = (x * 1e3 for x in self.config.radii_km)
            return (a, b, c)
        return self.shape.equivalent_ellipsoid_radii()

    @property
    def radii_m(self) -> tuple[float, float, float]:
        return self._radii

    @property
    def bounding_radius_m(self) -> float:
        """Radius of the sphere about the body origin holding every vertex [m]."""
        return self.shape.bounding_radius

    @property
    def reference_radius_m(self) -> float:
        """The bounding radius [m]: the frame geometry's sphere must hold the whole body (an
        observer inside it is refused; the pointing keeps it in the field)."""
        return self.bounding_radius_m

    @property
    def rotation_period_s(self) -> float:
        """Sidereal rotation period [s]."""
        return 360.0 / abs(self.spin[3]) * 86400.0

    def orientation(self, epochs_tdb: ArrayLike, ephemeris: Any = None) -> FloatArray:
        ra, dec, w0, wd = (math.radians(x) for x in self.spin)
        return np.asarray(iau_orientation(epochs_tdb, ra, dec, w0, wd))

    def render_mesh(self) -> BodyMesh:
        """The facets with their area-weighted vertex normals, body-fixed metres."""
        return BodyMesh(self.shape.vertices, self.shape.faces, self.shape.vertex_normals, None)

    def render_model(self) -> TargetModel:
        return mesh_render_model(self.config.photometry, self.normal_albedo,
                                 self.bounding_radius_m, self.render_mesh(), body_fixed_aovs=True)

    def describe(self) -> dict[str, Any]:
        c = self.config
        return {**super().describe(), "model": c.model, "source": self.shape.source,
                "vertices": self.shape.n_vertices, "faces": self.shape.n_faces,
                "bounding_radius_m": self.bounding_radius_m,
                "pole_ra_deg": self.spin[0], "pole_dec_deg": self.spin[1],
                "prime_meridian_deg": self.spin[2], "rotation_deg_per_day": self.spin[3],
                "gm_m3_s2": self.gm, "normal_albedo": self.normal_albedo,
                "photometry": c.photometry.model}
