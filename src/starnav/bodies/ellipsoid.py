"""A triaxial ellipsoid body with an IAU rotation model: the simplest small body.

Its surface is ``(x/a)^2 + (y/b)^2 + (z/c)^2 = 1`` in body-fixed axes; the rendered mesh is a
geodesic sphere mapped onto it (:func:`ellipsoid_mesh`) with the ellipsoid's exact normals
``n ~ (x/a^2, y/b^2, z/c^2)``, so shading does not depend on the facets; its silhouette is the
ellipsoid's projected conic to within the chord error of the mesh (about ``a (1 - cos(pi /
(5 * 2^k)))``-sized, sub-metre at ``k = 6`` for Itokawa's size). The navigation fix and the limb
truth use the same ellipsoid (``radii_m``), exactly: the Christian-Robinson fix is built for a
triaxial reference shape.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.bodies.base import FloatArray, TargetBody, iau_orientation, mesh_render_model
from starnav.bodies.mesh import BodyMesh, icosphere_mesh
from starnav.bodies.model import TargetModel
from starnav.bodies.schema import EllipsoidConfig


def ellipsoid_mesh(radii_m: tuple[float, float, float], subdivisions: int) -> BodyMesh:
    """Geodesic mesh of the ellipsoid ``radii_m`` [m] with its exact surface normals."""
    unit = icosphere_mesh(1.0, subdivisions)
    r = np.asarray(radii_m, float)
    v = unit.vertices * r
    n = v / r**2
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return BodyMesh(v, unit.faces, n, None)


class TriaxialBody(TargetBody):
    """A triaxial ellipsoid spinning about body z (:class:`EllipsoidConfig`)."""

    def __init__(self, config: EllipsoidConfig | None = None) -> None:
        self.config = config if config is not None else EllipsoidConfig()
        self.name = self.config.name

    @property
    def radii_m(self) -> tuple[float, float, float]:
        a, b, c = (x * 1e3 for x in self.config.radii_km)
        return (a, b, c)

    def orientation(self, epochs_tdb: ArrayLike, ephemeris: Any = None) -> FloatArray:
        c = self.config
        R = iau_orientation(epochs_tdb, math.radians(c.pole_ra_deg),
                            math.radians(c.pole_dec_deg), math.radians(c.prime_meridian_deg),
                            math.radians(c.rotation_deg_per_day))
        return np.asarray(R)

    def render_model(self) -> TargetModel:
        c = self.config
        return mesh_render_model(c.photometry, c.albedo, self.reference_radius_m,
                                 ellipsoid_mesh(self.radii_m, c.mesh_subdivisions))

    def describe(self) -> dict[str, Any]:
        c = self.config
        return {**super().describe(), "pole_ra_deg": c.pole_ra_deg,
                "pole_dec_deg": c.pole_dec_deg, "rotation_deg_per_day": c.rotation_deg_per_day,
                "photometry": c.photometry.model}
