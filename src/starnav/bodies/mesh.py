"""The triangle mesh of a body in body-fixed coordinates, as the renderer draws it.

Index
-----
:class:`BodyMesh`, :func:`icosphere_mesh`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class BodyMesh:
    """A triangle mesh of a body in **body-fixed** coordinates [m].

    Attributes
    ----------
    vertices : (n, 3) float
        Vertex positions [m].
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    normals : (n, 3) float
        Unit vertex normals.
    albedo : (n,) float or None
        Per-vertex albedo (model's meaning), or ``None`` to use the scenario's albedo.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    normals: NDArray[np.float64]
    albedo: NDArray[np.float64] | None = None
    key: object = None

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    @cached_property
    def bounding_radius(self) -> float:
        """Largest vertex distance from the body centre [m]."""
        v = self.vertices
        return float(np.sqrt(np.max(np.einsum("ij,ij->i", v, v)))) if len(v) else 0.0

    @classmethod
    def from_trimesh(cls, tm, albedo: NDArray[np.float64] | None = None,
                     key: object = None) -> BodyMesh:
        """From a ``trimesh.Trimesh`` in body-fixed metres (its vertex normals are used;
        ``vertex_attributes['albedo']`` is used when ``albedo`` is not given). ``key``
        identifies the mesh for the renderer's scene cache (the same key: the same mesh)."""
        if albedo is None:
            albedo = tm.vertex_attributes.get("albedo") if hasattr(tm, "vertex_attributes") \
                else None
        return cls(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64),
                   np.asarray(tm.vertex_normals, float),
                   None if albedo is None else np.asarray(albedo, float), key)


@lru_cache(maxsize=4)
def _icosphere(subdivisions: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    import trimesh

    tm = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64)


def icosphere_mesh(radius: float, subdivisions: int) -> BodyMesh:
    """A geodesic sphere of ``20 * 4**subdivisions`` triangles with vertices on the sphere of
    ``radius`` [m] and exact radial normals."""
    v, f = _icosphere(int(subdivisions))
    return BodyMesh(v * radius, f, v.copy(), None)
