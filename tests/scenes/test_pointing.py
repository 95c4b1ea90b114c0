"""Moon pointing: requested pixel to 1e-6 px, disc inside, roll, knowledge error, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from starnav.camera import Camera
from starnav.constants import ARCSEC
from starnav.errors import GeometryError
from starnav.geometry import FrameGeometry
from starnav.scenes.pointing import (
    disc_inside,
    disc_radius_px,
    frame_generators,
    moon_pointing,
    rotation_from_vector,
    sample_pointing,
)

#: Tolerance of the Moon-centre projection (issue 4) [px].
CENTRE_TOL_PX = 1e-6
SUN = np.array([1.496e11, 0.0, 0.0])


def _positions():
    rng = np.random.default_rng(7)
    out = []
    for r in (2.0e7, 4.5e7, 6.0e7, 9.0e7):
        d = rng.normal(size=3)
        out.append(r * d / np.linalg.norm(d))
    out.append(np.array([0.0, 0.0, 6.0e7]))  # above the pole: line of sight along -z
    return out


@pytest.mark.parametrize("distorted", [False, True])
def test_moon_centre_projects_to_requested_pixel(aa_str, distorted):
    cam = aa_str if not distorted else Camera.preset("aa-str", k1=-0.05, k2=0.01, p1=1e-4)
    for pos in _positions():
        for pixel in ([511.5, 511.5], [100.25, 900.75], [800.0, 50.0]):
            for roll in (0.0, 1.0, -2.5):
                R = moon_pointing(cam, pos, pixel, roll)
                g = FrameGeometry(camera_position=pos, R_cam_to_inertial=R, sun_position=SUN)
                uv = g.moon_centre_pixel(cam, distort=distorted)
                assert np.abs(uv - pixel).max() < CENTRE_TOL_PX


def test_roll_zero_puts_north_up_and_roll_turns_it(aa_str):
    pos = np.array([6.0e7, 0.0, 0.0])
    R0 = moon_pointing(aa_str, pos, [aa_str.cx, aa_str.cy], 0.0)
    north_cam = R0.T @ np.array([0.0, 0.0, 1.0])
    assert north_cam[1] < -0.99  # camera +y is down: north towards the top of the image
    R90 = moon_pointing(aa_str, pos, [aa_str.cx, aa_str.cy], math.pi / 2)
    n90 = R90.T @ np.array([0.0, 0.0, 1.0])
    assert abs(n90[1]) < 1e-9 and abs(abs(n90[0]) - 1) < 1e-9


def test_random_placement_keeps_disc_inside(aa_str):
    margin = 8.0
    for i, pos in enumerate(_positions()):
        for k in range(20):
            rng, krng = frame_generators(1234, 100 * i + k)
            p = sample_pointing(aa_str, pos, rng, krng, margin=margin, sun_position=SUN)
            g = FrameGeometry(camera_position=pos, R_cam_to_inertial=p.R_true,
                              sun_position=SUN)
            pts = g.limb_points(aa_str, n=720)
            assert pts[:, 0].min() >= margin - 0.5 and pts[:, 1].min() >= margin - 0.5
            assert pts[:, 0].max() <= aa_str.width - 0.5 - margin
            assert pts[:, 1].max() <= aa_str.height - 0.5 - margin
            assert np.abs(g.moon_centre_pixel(aa_str) - p.moon_pixel).max() < CENTRE_TOL_PX
            assert np.hypot(*(p.moon_pixel - [aa_str.cx, aa_str.cy])) <= 512.0


def test_random_placement_covers_the_allowed_box(aa_str):
    # uniform over the allowed box: at 60 000 km the disc radius is ~82 px, so centres reach
    # within ~90 px of the edges; means near the centre (3 sigma of a uniform mean, N = 400)
    pos = np.array([0.0, 6.0e7, 0.0])
    px = []
    for k in range(400):
        rng, krng = frame_generators(99, k)
        px.append(sample_pointing(aa_str, pos, rng, krng, max_offset=1e4,
                                  sun_position=SUN).moon_pixel)
    px = np.array(px)
    r = disc_radius_px(aa_str, 6.0e7)
    assert 2 * r == pytest.approx(163.0, abs=1.0)  # docs/facts.md s3: 163 px across at 60 000 km
    half = (aa_str.width - 2 * (r + 8)) / 2
    assert np.all(np.abs(px - [aa_str.cx, aa_str.cy]) <= half + 1e-9)
    assert np.abs(px.mean(0) - [aa_str.cx, aa_str.cy]).max() < 3 * half / math.sqrt(3 * 400)
    assert (px.max(0) - px.min(0)).min() > 1.8 * half


def test_fixed_offset_that_does_not_fit_is_an_error(aa_str):
    rng, krng = frame_generators(1, 0)
    with pytest.raises(GeometryError, match="moon_offset_px"):
        sample_pointing(aa_str, [6.0e7, 0, 0], rng, krng, moon_offset="fixed",
                        moon_offset_px=(480.0, 0.0))
    with pytest.raises(GeometryError, match="does not fit"):
        sample_pointing(aa_str, [5.0e6, 0, 0], rng, krng)  # 5000 km: disc > detector


def test_knowledge_error_statistics_and_separation(aa_str):
    sigma = np.array([5.0, 5.0, 40.0]) * ARCSEC
    pos = np.array([6.0e7, 1.0e7, -2.0e7])
    errs, angles = [], []
    for k in range(2000):
        rng, krng = frame_generators(7, k)
        p = sample_pointing(aa_str, pos, rng, krng, knowledge_sigma=sigma, sun_position=SUN)
        errs.append(p.knowledge_error)
        dR = p.R_true.T @ p.R_measured
        angles.append(np.linalg.norm(Rotation.from_matrix(dR).as_rotvec()))
        assert np.allclose(dR, rotation_from_vector(p.knowledge_error), atol=1e-15)
    errs = np.array(errs)
    # sample standard deviations within 4.5 sigma of their sampling spread (sigma / sqrt(2N)):
    # false-alarm rate < 1e-5 per axis
    sd = errs.std(0, ddof=1)
    assert np.all(np.abs(sd / sigma - 1) < 4.5 / math.sqrt(2 * 2000))
    assert np.allclose(angles, np.linalg.norm(errs, axis=1), rtol=1e-6, atol=1e-12)
    # the true attitude does not depend on the knowledge error
    rng, krng = frame_generators(7, 3)
    a = sample_pointing(aa_str, pos, rng, krng, knowledge_sigma=sigma, sun_position=SUN)
    rng, krng = frame_generators(7, 3)
    b = sample_pointing(aa_str, pos, rng, krng, knowledge_sigma=10 * sigma, sun_position=SUN)
    assert np.array_equal(a.R_true, b.R_true)
    assert not np.array_equal(a.R_measured, b.R_measured)


def test_generators_are_per_frame_and_reproducible():
    a1, k1 = frame_generators(5, 3)
    a2, k2 = frame_generators(5, 3)
    assert a1.random() == a2.random() and k1.random() == k2.random()
    b, kb = frame_generators(5, 4)
    c, kc = frame_generators(6, 3)
    x = frame_generators(5, 3)[0].random()
    assert x != b.random() and x != c.random()
    # same as the frame's child of SeedSequence(seed).spawn(...)
    root = np.random.SeedSequence(5).spawn(4)[3]
    assert root.spawn_key == (3,)


def test_disc_inside_detects_an_edge(aa_str):
    pos = np.array([6.0e7, 0.0, 0.0])
    R = moon_pointing(aa_str, pos, [30.0, 511.5])  # centre 30 px from the left edge
    g = FrameGeometry(camera_position=pos, R_cam_to_inertial=R, sun_position=SUN)
    assert not disc_inside(g, aa_str, 0.0)
    R = moon_pointing(aa_str, pos, [200.0, 511.5])
    g = FrameGeometry(camera_position=pos, R_cam_to_inertial=R, sun_position=SUN)
    assert disc_inside(g, aa_str, 8.0)
