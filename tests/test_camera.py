"""Camera model: derived optics (docs/facts.md s1), projection round trips and Jacobians
against central finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.errors import ConfigError, GeometryError, UnknownNameError

FD_STEP = 1e-6


def distorted_camera() -> Camera:
    return Camera.preset("aa-str", k1=-0.12, k2=0.03, k3=-0.004, p1=4e-4, p2=-3e-4, cx=515.2,
                         cy=508.7)


def test_aa_str_derived_optics(aa_str):
    # docs/facts.md s1: FoV 2 atan(9.216/50.7) = 20.60 deg, diagonal 28.83 deg,
    # IFOV 355 urad = 73.2 arcsec, pixel solid angle 1.2605e-7 sr, pupil 33.9 mm.
    assert aa_str.fov_x_deg == pytest.approx(20.60, abs=0.005)
    assert math.degrees(aa_str.fov_diagonal) == pytest.approx(28.83, abs=0.005)
    assert aa_str.ifov == pytest.approx(355.03e-6, rel=1e-4)
    assert math.degrees(aa_str.ifov) * 3600 == pytest.approx(73.2, abs=0.05)
    assert aa_str.pixel_solid_angle == pytest.approx(1.2605e-7, rel=1e-4)
    assert aa_str.pupil_diameter == pytest.approx(33.9e-3, rel=1e-6)
    assert aa_str.etendue == pytest.approx(math.pi * 18e-6**2 / (4 * 1.495575**2), rel=1e-12)


def test_principal_point_is_centre_of_detector(aa_str):
    # (0, 0) is the centre of the top-left pixel: the optical axis hits (W-1)/2.
    assert aa_str.project(np.array([0.0, 0.0, 1.0])) == pytest.approx([511.5, 511.5])
    # A point at the edge of the half field lands on the detector's outer edge (u = -0.5).
    half = aa_str.fov_x / 2
    uv = aa_str.project(np.array([-math.tan(half), 0.0, 1.0]))
    assert uv[0] == pytest.approx(-0.5, abs=1e-9)


def test_smaller_detector_recentres_principal_point():
    cam = Camera.preset("aa-str", width=64, height=32)
    assert (cam.cx, cam.cy) == (31.5, 15.5)


@pytest.mark.parametrize("cam", [Camera.preset("aa-str"), distorted_camera()])
def test_project_unproject_round_trip(cam):
    rng = np.random.default_rng(1)
    uv = rng.uniform(-0.5, 1023.5, size=(200, 2))
    rays = cam.unproject(uv)
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)
    back = cam.project(rays * rng.uniform(1e3, 1e8, size=(200, 1)))
    assert np.max(np.abs(back - uv)) < 1e-8


def test_project_jacobian_matches_finite_differences():
    cam = distorted_camera()
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(-0.15, 0.15, 50), rng.uniform(-0.15, 0.15, 50),
                           np.ones(50)]) * rng.uniform(5e6, 8e7, (50, 1))
    J = cam.project_jacobian(pts)
    for k in range(3):
        h = np.zeros(3)
        h[k] = FD_STEP * np.abs(pts[:, 2]).mean()
        fd = (cam.project(pts + h) - cam.project(pts - h)) / (2 * h[k])
        assert np.allclose(J[:, :, k], fd, rtol=1e-6, atol=1e-12)


def test_unproject_jacobian_matches_finite_differences():
    cam = distorted_camera()
    rng = np.random.default_rng(3)
    uv = rng.uniform(10, 1000, size=(40, 2))
    J = cam.unproject_jacobian(uv)
    for k in range(2):
        h = np.zeros(2)
        h[k] = 1e-4
        fd = (cam.unproject(uv + h) - cam.unproject(uv - h)) / 2e-4
        assert np.allclose(J[:, :, k], fd, rtol=1e-5, atol=1e-10)


def test_distortion_jacobian_matches_finite_differences():
    cam = distorted_camera()
    xy = np.random.default_rng(4).uniform(-0.18, 0.18, size=(60, 2))
    J = cam.distortion_jacobian(xy)
    for k in range(2):
        h = np.zeros(2)
        h[k] = 1e-7
        fd = (cam.distort(xy + h) - cam.distort(xy - h)) / 2e-7
        assert np.allclose(J[:, :, k], fd, rtol=1e-6, atol=1e-9)


def test_undistort_inverts_distort():
    cam = distorted_camera()
    xy = np.random.default_rng(5).uniform(-0.18, 0.18, size=(500, 2))
    assert np.max(np.abs(cam.undistort(cam.distort(xy)) - xy)) < 1e-12


def test_one_point_undistorts_as_in_a_batch():
    # regression: a single point takes the float path, a batch the array one; the same
    # Newton steps, so the same bits, and the same iteration count (a point converged early
    # in a batch keeps stepping with the others, so compare against one-point batches)
    cam = distorted_camera()
    xy = np.random.default_rng(6).uniform(-0.18, 0.18, size=(50, 2))
    for p in xy:
        one = cam.undistort(p)
        assert one.shape == (2,)
        assert np.array_equal(one, cam.undistort(np.stack([p, p]))[0])
        assert np.array_equal(cam.undistort(p[None]), one[None])


def test_unproject_with_jacobian_is_both():
    cam = distorted_camera()
    uv = np.random.default_rng(7).uniform(0, 1000, size=(20, 2))
    s, J = cam.unproject_with_jacobian(uv)
    assert np.array_equal(s, cam.unproject(uv)) and s.flags.c_contiguous
    assert np.array_equal(J, cam.unproject_jacobian(uv))


def test_relative_illumination_is_cos4(aa_str):
    # corner pixel: cos^4 of the angle to the axis
    u, v = -0.5, -0.5
    theta = math.atan(math.hypot(u - aa_str.cx, v - aa_str.cy) / aa_str.fx)
    assert aa_str.relative_illumination(u, v) == pytest.approx(math.cos(theta) ** 4, rel=1e-12)


@pytest.mark.parametrize("field,value", [("focal_length", 0.0), ("pitch_x", -1e-6),
                                         ("f_number", float("nan")), ("width", 0)])
def test_bad_camera_names_the_field(field, value):
    with pytest.raises(ConfigError, match=f"camera.{field}"):
        Camera.preset("aa-str", **{field: value})


def test_unknown_preset_lists_known():
    with pytest.raises(UnknownNameError, match="aa-str"):
        Camera.preset("no-such-camera")


def test_projecting_behind_camera_is_an_error(aa_str):
    with pytest.raises(GeometryError):
        aa_str.project(np.array([0.0, 0.0, -1.0]))


def test_pixel_solid_angles_sum_to_the_field_of_view():
    """The per-pixel solid angles of a centred pinhole sum to the exact solid angle of its
    rectangular field, 4 arcsin(a b / sqrt((a^2 + f^2)(b^2 + f^2))) with a, b the half sides of
    the detector (the solid angle of a rectangular pyramid)."""
    import math

    from starnav.camera import Camera

    cam = Camera.preset("aa-str")
    a, b, f = cam.width * cam.pitch_x / 2, cam.height * cam.pitch_y / 2, cam.focal_length
    exact = 4 * math.asin(a * b / math.sqrt((a * a + f * f) * (b * b + f * f)))
    om = cam.pixel_solid_angles()
    assert om.shape == (cam.height, cam.width)
    assert om.sum() == pytest.approx(exact, rel=1e-5)
    assert om.max() == pytest.approx(cam.pixel_solid_angle, rel=1e-6)
