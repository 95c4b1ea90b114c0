"""Render-free geometric tools for the mesh tests: limb profiles and ray casting.

These are the slow, independent references the view-adapted mesh is checked against:

* :func:`sphere_limb_radius`: the exact limb of a sphere along image azimuths from the projected
  centre, by bisection on the analytic "ray hits the sphere" predicate (the angle between the
  pixel ray and the centre direction equals ``asin(R / d)`` on the limb).
* :func:`mesh_outline_radius`: the outline of a mesh's projection along the same azimuths: a
  pinhole ray hits a triangle in front of the camera iff its pixel lies in the triangle's
  projection, so the outline is the farthest crossing of a projected edge.
* :func:`mesh_hits`: which pixels' rays hit the mesh (2-D point-in-projected-triangle with a
  KD-tree of triangle centroids).
* :func:`heightfield_hits`: which rays hit the DEM's terrain, by marching along each ray and
  testing ``|x| <= R + h(lat, lon)`` (bilinear DEM), independent of any mesh.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from starnav.dem.grid import body_to_selenographic


def _project(camera, geom, pts_body):
    pc = (geom.R_cam_to_inertial.T @ (pts_body @ geom.R_body_to_inertial.T
                                      - geom.camera_position).T).T
    return camera.project(pc, distort=False)


def pixel_rays_body(camera, geom, uv):
    """Unit ray directions in the body frame for pixels ``uv`` (pinhole)."""
    rc = camera.unproject(uv, undistort=False)
    return rc @ geom.R_cam_to_inertial.T @ geom.R_body_to_inertial


def sphere_limb_radius(camera, geom, az, radius):
    """Exact limb distance [px] from the projected centre along azimuths ``az`` [rad]."""
    c_uv = geom.moon_centre_pixel(camera)
    C = geom.R_body_to_inertial.T @ geom.camera_position
    d = np.linalg.norm(C)
    cos_lim = math.sqrt(d * d - radius * radius) / d
    lo = np.zeros_like(az)
    hi = np.full_like(az, 2.0 * camera.fx * radius / d + 50.0)
    dirs = np.stack([np.cos(az), np.sin(az)], -1)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        rays = pixel_rays_body(camera, geom, c_uv + mid[:, None] * dirs)
        inside = rays @ (-C / d) >= cos_lim
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return 0.5 * (lo + hi)


def mesh_outline_radius(mesh, camera, geom, az, r_min):
    """Outline distance [px] of the mesh projection along azimuths ``az``; only edges reaching
    beyond ``r_min`` px from the projected centre are considered."""
    c_uv = geom.moon_centre_pixel(camera)
    uv = _project(camera, geom, np.asarray(mesh.vertices))
    e = np.asarray(mesh.edges_unique)
    p, q = uv[e[:, 0]] - c_uv, uv[e[:, 1]] - c_uv
    keep = np.maximum(np.linalg.norm(p, axis=1), np.linalg.norm(q, axis=1)) >= r_min
    p, q = p[keep], q[keep]
    out = np.full(az.shape, np.nan)
    for i, a in enumerate(az):
        dvec = np.array([math.cos(a), math.sin(a)])
        w = q - p
        det = dvec[0] * (-w[:, 1]) - dvec[1] * (-w[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (p[:, 0] * (-w[:, 1]) - p[:, 1] * (-w[:, 0])) / det
            s = (dvec[0] * p[:, 1] - dvec[1] * p[:, 0]) / det
        ok = (np.abs(det) > 1e-15) & (s >= -1e-12) & (s <= 1 + 1e-12) & (t > 0)
        out[i] = t[ok].max() if ok.any() else np.nan
    return out


def mesh_hits(mesh, camera, geom, uv):
    """Boolean per pixel ``uv`` (n, 2): does the pixel's ray hit the mesh?"""
    V = _project(camera, geom, np.asarray(mesh.vertices))
    F = np.asarray(mesh.faces)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cen = (A + B + C) / 3.0
    rad = np.max(np.stack([np.linalg.norm(X - cen, axis=1) for X in (A, B, C)]), axis=0)
    tree = cKDTree(cen)
    cand = tree.query_ball_point(uv, r=float(rad.max()) + 1e-9)
    hit = np.zeros(len(uv), bool)
    for i, ids in enumerate(cand):
        if not ids:
            continue
        ids = np.asarray(ids)
        a, b, c = A[ids], B[ids], C[ids]
        p = uv[i]
        d1 = (p[0] - b[:, 0]) * (a[:, 1] - b[:, 1]) - (a[:, 0] - b[:, 0]) * (p[1] - b[:, 1])
        d2 = (p[0] - c[:, 0]) * (b[:, 1] - c[:, 1]) - (b[:, 0] - c[:, 0]) * (p[1] - c[:, 1])
        d3 = (p[0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (p[1] - a[:, 1])
        neg = (d1 < 0) | (d2 < 0) | (d3 < 0)
        pos = (d1 > 0) | (d2 > 0) | (d3 > 0)
        hit[i] = bool(np.any(~(neg & pos)))
    return hit


def heightfield_hits(dem, camera, geom, uv, step_m=200.0, height_offset=0.0):
    """Boolean per pixel: does the ray hit the terrain ``R + h + height_offset``? (ray march)"""
    R = dem.reference_radius
    h_lo, h_hi = dem.height_range
    r_top = R + h_hi + max(height_offset, 0.0)
    C = geom.R_body_to_inertial.T @ geom.camera_position
    rays = pixel_rays_body(camera, geom, uv)
    b = rays @ C
    cc = C @ C - r_top * r_top
    disc = b * b - cc
    hit = np.zeros(len(uv), bool)
    for i in np.flatnonzero(disc >= 0):
        t0 = -b[i] - math.sqrt(disc[i])
        t1 = -b[i] + math.sqrt(disc[i])
        t = np.arange(t0, t1 + step_m, step_m)
        x = C[None, :] + t[:, None] * rays[i][None, :]
        lat, lon, hgt = body_to_selenographic(x, R)
        below = hgt <= dem.sample(lat, lon) + height_offset
        hit[i] = bool(below.any())
    return hit
