"""A shape model seen by the camera: rays cast onto its facets, and its lit silhouette.

Two geometric services of the fly-by estimator (:mod:`~starnav.navigation.trn.filter`) and of
its synthetic measurements (:mod:`~starnav.navigation.trn.synthetic`), both on the facets of a
:class:`~starnav.bodies.shape.ShapeModel` placed in the camera frame:

1. **First hit of a ray** (:func:`raycast`). Rays leave the camera centre. A ray can only hit a
   facet whose image (its vertices divided by depth, the normalised image plane) contains the
   ray's own normalised point, so each ray is tested (Moller & Trumbore 1997) only against the
   facets facing the camera whose normalised bounding box holds that point: a few tens out of
   the 12 192 of Itokawa. The first hit of a ray on a closed mesh from outside is always on a
   facet facing the ray, which is why the others are skipped. A surface point is *visible*
   when the first hit of the ray towards it lies at its own distance.
2. **Lit silhouette** (:func:`lit_silhouette`). The facets that face both the camera and the
   Sun, projected with the camera model (distortion included); their summed image area ``A``
   and area-weighted centroid. ``sqrt(A / pi)`` is the equivalent radius of the lit region
   and the centroid its centre: what a segments read of a well-exposed body measures, phase
   bias included (the lit part of a body at phase ``alpha`` is offset towards the Sun).
   Approximations, documented where the filter uses them: cast shadows are ignored (a facet
   facing the Sun counts as lit) and facets hidden behind nearer ones are counted (a concave
   body such as Itokawa's neck: a few per cent of the area at most).

Reference
---------
T. Moller and B. Trumbore, "Fast, minimum storage ray-triangle intersection", Journal of
Graphics Tools 2 (1997) 21-28.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.camera import Camera
from starnav.errors import GeometryError
from starnav.typing import FloatArray

IntArray = NDArray[np.int64]

#: Barycentric slack of a hit on a facet edge [-] (a ray through a shared edge hits both).
EDGE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class BodyInCamera:
    """The facets of a shape model in the camera frame.

    Attributes
    ----------
    vertices : (V, 3) array
        Vertex positions in the camera frame [m] (camera at the origin, +z the boresight).
    faces : (F, 3) int array
    normals : (F, 3) array
        Unit outward facet normals in the camera frame.
    """

    vertices: FloatArray
    faces: IntArray
    normals: FloatArray

    @classmethod
    def place(cls, vertices_body: ArrayLike, faces: ArrayLike, R_body_to_cam: ArrayLike,
              body_centre_cam: ArrayLike) -> BodyInCamera:
        """Put body-fixed vertices [m] in the camera frame: ``R v + c``."""
        R = np.asarray(R_body_to_cam, float)
        V = np.asarray(vertices_body, float) @ R.T + np.asarray(body_centre_cam, float)
        F = np.asarray(faces, np.int64)
        n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return cls(V, F, n)

    @cached_property
    def facing(self) -> NDArray[np.bool_]:
        """Facets whose outward normal points towards the camera."""
        c = self.vertices[self.faces].mean(axis=1)
        return np.einsum("ij,ij->i", self.normals, -c) > 0.0

    @cached_property
    def _front(self) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
        """The facets facing the camera: indices, vertices and normalised-image bounds."""
        front = np.flatnonzero(self.facing)
        tri = self.vertices[self.faces[front]]                 # (F', 3, 3)
        if np.any(tri[..., 2] <= 0):
            raise GeometryError("raycast: the body reaches behind the camera plane")
        xy = tri[..., :2] / tri[..., 2:3]                      # normalised image of facets
        return front, tri, xy.min(axis=1), xy.max(axis=1)


def raycast(body: BodyInCamera, directions: ArrayLike) -> tuple[FloatArray, IntArray]:
    """First hit of rays from the camera centre on the body (module step 1).

    Parameters
    ----------
    body : BodyInCamera
    directions : (N, 3) array
        Ray directions in the camera frame (any length, ``z > 0``).

    Returns
    -------
    t : (N,) array
        Distance along the *unit* ray to the first hit [m] (``inf``: no hit).
    face : (N,) int array
        Index of the facet hit (-1: none).
    """
    d = np.asarray(directions, float).reshape(-1, 3)
    if np.any(d[:, 2] <= 0):
        raise GeometryError("raycast: ray directions must point forwards (z > 0)")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    front, tri, lo, hi = body._front
    q = d[:, :2] / d[:, 2:3]
    inside = ((q[:, None, 0] >= lo[None, :, 0]) & (q[:, None, 0] <= hi[None, :, 0])
              & (q[:, None, 1] >= lo[None, :, 1]) & (q[:, None, 1] <= hi[None, :, 1]))
    ray, cand = np.nonzero(inside)
    t_out = np.full(d.shape[0], np.inf)
    f_out = np.full(d.shape[0], -1, np.int64)
    if ray.size == 0:
        return t_out, f_out
    v0, v1, v2 = tri[cand, 0], tri[cand, 1], tri[cand, 2]
    dd = d[ray]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(dd, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = -v0
    u = np.einsum("ij,ij->i", s, p) * inv
    qv = np.cross(s, e1)
    w = np.einsum("ij,ij->i", dd, qv) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = (ok & (u >= -EDGE_TOLERANCE) & (w >= -EDGE_TOLERANCE)
           & (u + w <= 1.0 + EDGE_TOLERANCE) & (t > 0))
    ray, cand, t = ray[hit], cand[hit], t[hit]
    if ray.size == 0:                    # inside facets' boxes, but missing every facet
        return t_out, f_out
    order = np.lexsort((t, ray))
    ray, cand, t = ray[order], cand[order], t[order]
    first = np.r_[True, ray[1:] != ray[:-1]]
    t_out[ray[first]] = t[first]
    f_out[ray[first]] = front[cand[first]]
    return t_out, f_out


def visible(body: BodyInCamera, points_cam: ArrayLike, tolerance: float = 1e-3
            ) -> NDArray[np.bool_]:
    """Whether surface points (camera frame [m]) are the first hit of the ray towards them
    (``tolerance`` [m] on the distance)."""
    p = np.asarray(points_cam, float).reshape(-1, 3)
    out = np.zeros(p.shape[0], bool)
    ahead = p[:, 2] > 0
    if not np.any(ahead):
        return out
    rng = np.linalg.norm(p[ahead], axis=1)
    t, _ = raycast(body, p[ahead])
    out[ahead] = t >= rng - tolerance
    return out


@dataclass(frozen=True)
class LitSilhouette:
    """The lit part of the body in the image (module step 2).

    Attributes
    ----------
    centroid_uv : (2,) array
        Area-weighted centre of the lit facets' images [px] (distorted detector coordinates).
    radius_px : float
        Equivalent radius ``sqrt(area / pi)`` [px].
    area_px2 : float
        Summed image area of the lit facets facing the camera [px^2].
    facets : int
        Facets counted.
    """

    centroid_uv: FloatArray
    radius_px: float
    area_px2: float
    facets: int


def lit_silhouette(body: BodyInCamera, sun_cam: ArrayLike, camera: Camera) -> LitSilhouette:
    """Centroid and equivalent radius of the lit facets facing the camera (module step 2).

    ``sun_cam`` is the direction to the Sun in the camera frame (any length; the Sun is far:
    one direction for every facet). Raises :class:`~starnav.errors.GeometryError` when no lit
    facet faces the camera (a new body: nothing to measure).
    """
    s = np.asarray(sun_cam, float)
    s = s / np.linalg.norm(s)
    sel = body.facing & (body.normals @ s > 0.0)
    if not np.any(sel):
        raise GeometryError("lit_silhouette: no lit facet faces the camera (phase ~ 180 deg)")
    tri = body.vertices[body.faces[sel]]
    uv = camera.project(tri)                                    # (F, 3, 2)
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                        - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    total = float(area.sum())
    centroid = (area[:, None] * (a + b + c) / 3.0).sum(axis=0) / total
    return LitSilhouette(centroid, float(np.sqrt(total / np.pi)), total, int(sel.sum()))
