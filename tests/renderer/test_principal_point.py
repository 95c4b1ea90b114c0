"""An off-centre principal point: the rendered Moon sits where the camera model puts it.

The reference is computed without the renderer: every (sub-)pixel is unprojected with
:meth:`starnav.camera.Camera.unproject` and its ray is intersected with the sphere analytically
(the discriminant of ``|t r - c|^2 = R^2``). A sign or scale error in the principal-point
offsets handed to Mitsuba moves the disc by a multiple of the offset (the defect this guards
against moved it by twice the offset, mirrored: 30-70 px here).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.geometry import static_geometry

from .conftest import make_renderer

#: Tolerance on the position of the Moon's centroid in the image [px].
CENTROID_TOL_PX = 0.05
#: Range [m] giving a disc of ~80 px diameter with the AA-STR focal length.
RANGE = 1.2e8
#: Sub-pixels per pixel side of the supersampled reference radiance.
SUPERSAMPLE = 8


def ray_sphere(rays: np.ndarray, centre: np.ndarray, radius: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Analytic first hit of unit rays ``(..., 3)`` from the origin with a sphere.

    Returns the hit mask and the unit outward normals at the hits (zero elsewhere).
    """
    b = rays @ centre                                 # t of the closest approach [m]
    disc = radius**2 - (centre @ centre - b * b)      # R^2 - (miss distance)^2 [m^2]
    hit = (disc >= 0.0) & (b > 0.0)
    t = b - np.sqrt(np.where(hit, disc, 0.0))
    n = (t[..., None] * rays - centre) / radius
    return hit, np.where(hit[..., None], n, 0.0)


def centroid(weight: np.ndarray) -> np.ndarray:
    """Weighted centroid ``(u, v)`` [px] of an image (pixel-centre coordinates)."""
    v, u = np.mgrid[0:weight.shape[0], 0:weight.shape[1]]
    w = weight.astype(float)
    return np.array([np.sum(u * w), np.sum(v * w)]) / np.sum(w)


def reference_radiance(camera: Camera, geom, n: int = SUPERSAMPLE) -> np.ndarray:
    """Box-filtered Lambert radiance ``max(cos i, 0)`` (up to a constant) of every pixel,
    averaged over ``n x n`` sub-pixel rays of the camera model."""
    c = geom.moon_centre_camera()
    s = geom.sun_direction_camera()
    off = (np.arange(n) + 0.5) / n - 0.5
    u, v = camera.pixel_grid()
    out = np.zeros_like(u)
    for dv in off:
        for du in off:
            rays = camera.unproject(np.stack([u + du, v + dv], -1), undistort=False)
            hit, nrm = ray_sphere(rays, c, geom.body_radius)
            out += np.where(hit, np.maximum(nrm @ s, 0.0), 0.0)
    return out / n**2


@pytest.mark.parametrize("pp_offset,moon_offset", [
    ((12.0, -7.0), (30.0, -20.0)),
    ((-30.0, 20.0), (25.0, -35.0)),
])
def test_off_centre_principal_point_puts_the_moon_where_the_camera_model_does(
        pp_offset, moon_offset):
    base = Camera.preset("aa-str", width=256, height=256)
    cam = Camera.preset("aa-str", width=256, height=256,
                        cx=base.cx + pp_offset[0], cy=base.cy + pp_offset[1])
    g = static_geometry(cam, RANGE, math.radians(20.0), moon_offset)
    img = make_renderer(cam, spp=16, shape="sphere", model="lambert").render(g, seed=7)

    # pixel-centre rays of the camera model against the sphere: the AOV mask's definition
    rays = cam.unproject(np.stack(cam.pixel_grid(), -1), undistort=False)
    exact_mask, _ = ray_sphere(rays, g.moon_centre_camera(), g.body_radius)
    assert 4000 < exact_mask.sum() < 6500 and not exact_mask[[0, -1]].any()
    assert int(np.sum(img.mask ^ exact_mask)) <= 2
    np.testing.assert_allclose(centroid(img.mask), centroid(exact_mask), atol=CENTROID_TOL_PX)

    # the radiance pass (jittered samples over each pixel) against the supersampled reference
    ref = reference_radiance(cam, g)
    np.testing.assert_allclose(centroid(img.L), centroid(ref), atol=CENTROID_TOL_PX)
