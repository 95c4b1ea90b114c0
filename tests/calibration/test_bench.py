"""Bench geometry and emulated acquisition: inverse maps, radiance conservation, flux and
centroid conservation of the splatting and of the field-varying spot, Table 2 spot size,
vignetting, defocus."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from starnav.calibration.bench import (
    Bench,
    BenchGeometry,
    IdealDetector,
    field_varying_blur,
    splat,
)
from starnav.calibration.collimator import disc_overlap_fraction
from starnav.calibration.schema import bench_from_dict
from starnav.errors import ConfigError

from .conftest import MISALIGNMENT, small_camera


def test_inverse_map_inverts_the_forward_map(misaligned_bench):
    rng = np.random.default_rng(3)
    uv = rng.uniform(-0.5, 1023.5, size=(500, 2))
    g = misaligned_bench.geometry
    ji = g.pixel_to_screen(uv)
    assert np.max(np.abs(g.screen_to_pixel(ji) - uv)) < 1e-6


def test_nominal_bench_maps_screen_offsets_by_f_cam_over_f_coll(paper_bench):
    g = paper_bench.geometry.nominal()
    cj, ci = g.centre
    cam = g.camera
    ji = np.array([[cj + 700.0, ci - 300.0]])
    uv = g.screen_to_pixel(ji)[0]
    # pinhole: u = cx + fx (a / f_coll), a = 700 p
    assert uv[0] == pytest.approx(cam.cx + cam.fx * 700 * g.pitch / g.focal_length, abs=1e-9)
    assert uv[1] == pytest.approx(cam.cy - cam.fy * 300 * g.pitch / g.focal_length, abs=1e-9)


def test_splat_conserves_flux_and_the_centroid_of_extended_sources():
    rng = np.random.default_rng(5)
    n = 2000
    uv = rng.uniform(5, 45, size=(n, 2))
    w = rng.uniform(0.1, 1.0, n)
    val = rng.uniform(0, 1, n)
    img = splat(val, uv, w, (50, 50))
    flux = val * w * w
    assert img.sum() == pytest.approx(flux.sum(), rel=1e-12)
    # a screen-like grid of 0.47 px elements with a Gaussian of sigma 0.7 px on it: its
    # centroid is kept (area sampling of a source wider than a pixel)
    j, i = np.meshgrid(np.arange(-12, 13), np.arange(-12, 13))
    pos = np.stack([20.37 + 0.47 * j.ravel(), 24.81 + 0.47 * i.ravel()], -1)
    g = np.exp(-0.5 * ((pos[:, 0] - 20.37) ** 2 + (pos[:, 1] - 24.81) ** 2) / 0.7**2)
    img = splat(g, pos, np.full(len(g), 0.47), (50, 50))
    v, u = np.indices(img.shape)
    assert (img * u).sum() / img.sum() == pytest.approx(20.37, abs=0.01)
    assert (img * v).sum() / img.sum() == pytest.approx(24.81, abs=0.01)


def test_splat_box_overlap_closed_cases():
    one = splat([1.0], [[3.0, 2.0]], [1.0], (5, 5))
    assert one[2, 3] == 1.0 and one.sum() == 1.0
    half = splat([1.0], [[3.5, 2.0]], [0.5], (5, 5))  # footprint [3.25, 3.75] x [1.75, 2.25]
    assert half[2, 3] == pytest.approx(0.125) and half[2, 4] == pytest.approx(0.125)
    big = splat([1.0], [[3.0, 2.0]], [2.0], (7, 7), jac=np.eye(2)[None] * 2.0)
    assert big.sum() == pytest.approx(4.0)
    with pytest.raises(ConfigError):
        splat([1.0], [[3.0, 2.0]], [2.0], (7, 7))


def test_field_varying_blur_conserves_flux_and_point_centroids():
    img = np.zeros((80, 80))
    img[20, 30] = 1.0
    img[55, 60] = 2.0
    sig = np.fromfunction(lambda r, c: 0.4 + 0.03 * c, img.shape)
    out = field_varying_blur(img, sig, 6)
    assert out.sum() == pytest.approx(3.0, rel=1e-9)
    for (r, c) in ((20, 30), (55, 60)):
        sl = (slice(r - 15, r + 16), slice(c - 15, c + 16))
        sub = out[sl]
        v, u = np.indices(sub.shape)
        assert (sub * u).sum() / sub.sum() == pytest.approx(15.0, abs=1e-9)
        assert (sub * v).sum() / sub.sum() == pytest.approx(15.0, abs=1e-9)
    # constant sigma: the plain Gaussian filter
    flat = np.full(img.shape, 1.3)
    np.testing.assert_allclose(field_varying_blur(img, flat, 6),
                               ndimage.gaussian_filter(img, 1.3, mode="constant"), atol=1e-12)


@pytest.mark.slow
def test_uniform_screen_gives_its_radiance_at_the_camera(paper_bench):
    # radiance is conserved through the collimator: a uniform screen is a uniform scene.
    # Without the spot the footprints tile to O(roll^2) (0.6 deg in total: 1.1e-4); the
    # input-side blending of the field-varying spot leaves ripples < 1e-3 where the blend
    # weights change slope.
    counts = np.full(paper_bench.screen_shape, 128, np.uint16)
    ref = paper_bench.radiometry.le_lut[128]
    le = paper_bench.radiance_at_camera(counts)
    assert np.max(np.abs(le[30:-30, 30:-30] / ref - 1.0)) < 1e-3
    sharp = Bench(bench_from_dict({"acquisition": {"include_spot_psf": False},
                                   "misalignment": MISALIGNMENT}))
    le0 = sharp.radiance_at_camera(counts)
    assert np.max(np.abs(le0[30:-30, 30:-30] / ref - 1.0)) < 3e-4
    assert le[-1, 512] < 0.5 * ref   # the unstimulated rows (eq. 2 with the derived FoV)


def test_single_screen_pixel_flux_and_table_2_spot_at_9p61_deg():
    bench = Bench(bench_from_dict({"collimator": {"distortion_k1": 0.0}}))
    g = bench.geometry
    cam = bench.camera
    cj, ci = g.centre
    # the screen pixel seen at 9.61 deg along +x
    d = round(math.tan(math.radians(9.61)) * g.focal_length / g.pitch)
    counts = np.zeros(bench.screen_shape, np.uint16)
    counts[int(ci + 0.5), int(cj + 0.5) + d] = 255
    le = bench.radiance_at_camera(counts)
    # flux: Le x footprint area (p / f_coll)^2 fx^2 / cos^3-ish local magnification
    ji = np.array([[int(cj + 0.5) + d, int(ci + 0.5)]], float)
    J = (g.screen_to_pixel(ji + [0.5, 0]) - g.screen_to_pixel(ji - [0.5, 0]))[0, 0] * \
        (g.screen_to_pixel(ji + [0, 0.5]) - g.screen_to_pixel(ji - [0, 0.5]))[0, 1]
    assert le.sum() == pytest.approx(bench.radiometry.le_max * J, rel=1e-3)
    # RMS radius^2 = r_spot^2 + 2 (w^2 / 12) (the footprint box, per axis)
    v, u = np.indices(le.shape)
    cu, cv = (le * u).sum() / le.sum(), (le * v).sum() / le.sum()
    r2 = (le * ((u - cu) ** 2 + (v - cv) ** 2)).sum() / le.sum()
    theta = math.atan(d * g.pitch / g.focal_length)
    r_spot = float(bench.spot.rms_radius_at(theta)) / cam.ifov
    assert r_spot == pytest.approx(2.13, abs=0.1)  # Table 2 at 9.61 deg
    assert math.sqrt(r2) == pytest.approx(math.sqrt(r_spot**2 + 2 * J / 12), rel=0.03)


def test_vignetting_of_a_small_aperture_darkens_the_corners():
    bench = Bench(bench_from_dict({"collimator": {"clear_aperture_mm": 40.0,
                                                  "pupil_distance_mm": 60.0,
                                                  "focal_length_mm": 170.0,
                                                  "distortion_k1": 0.0},
                                   "acquisition": {"include_spot_psf": False}}))
    counts = np.full(bench.screen_shape, 255, np.uint16)
    le = bench.radiance_at_camera(counts)
    cam = bench.camera
    ref = bench.radiometry.le_max
    assert le[512, 512] / ref == pytest.approx(1.0, abs=1e-3)
    t = math.hypot(1000 - cam.cx, 1000 - cam.cy) / cam.fx
    expect = float(disc_overlap_fraction(20e-3, cam.pupil_diameter / 2, 60e-3 * t))
    assert expect < 0.9
    assert le[1000, 1000] / ref == pytest.approx(expect, rel=5e-3)


def test_screen_defocus_adds_its_blur_in_quadrature():
    base = Bench(bench_from_dict({}), camera=small_camera(64))
    foc = Bench(bench_from_dict({"misalignment": {"screen_defocus_mm": 0.5}}),
                camera=small_camera(64))
    cam = base.camera
    add = cam.pupil_diameter * 0.5e-3 / 0.18**2 / 4 / cam.ifov   # D z / (4 f^2) [px]
    assert foc.sigma_map[32, 32] == pytest.approx(math.hypot(base.sigma_map[32, 32], add),
                                                  rel=1e-3)


def test_misalignments_move_the_image_as_their_geometry_says():
    # a pure in-plane screen shift s moves the image by fx s / f_coll
    cam = small_camera(128)
    shift = Bench(bench_from_dict({"misalignment": {"screen_shift_mm": [0.5, 0.0]},
                                   "collimator": {"distortion_k1": 0.0}}), camera=cam)
    ref = BenchGeometry(cam, 0.18, 65e-3 / 2160, (2160, 3840))
    ji = np.array([[1919.5, 1079.5]])
    du = shift.geometry.screen_to_pixel(ji)[0, 0] - ref.screen_to_pixel(ji)[0, 0]
    assert du == pytest.approx(cam.fx * 0.5e-3 / 0.18, rel=1e-9)
    # a camera roll turns the image about the collimator axis
    rolled = Bench(bench_from_dict({"misalignment": {"camera_roll_deg": 1.0},
                                    "collimator": {"distortion_k1": 0.0}}), camera=cam)
    p = rolled.geometry.screen_to_pixel(np.array([[1919.5 + 100, 1079.5]]))[0]
    ang = math.degrees(math.atan2(p[1] - cam.cy, p[0] - cam.cx))
    assert abs(ang) == pytest.approx(1.0, abs=1e-3)


def test_acquire_refuses_a_bad_exposure_and_bad_counts(paper_bench):
    counts = np.zeros(paper_bench.screen_shape, np.uint16)
    det = IdealDetector(paper_bench.camera)
    with pytest.raises(ConfigError, match="exposure"):
        paper_bench.acquire(counts, 0.0, det)
    with pytest.raises(ConfigError, match="shape"):
        paper_bench.acquire(np.zeros((10, 10), np.uint16), 1e-3, det)
    counts[5, 5] = 999
    with pytest.raises(ConfigError, match=r"\[0, 255\]"):
        paper_bench.acquire(counts, 1e-3, det)


def test_misalignment_schema_rejects_large_tilts():
    with pytest.raises(ConfigError, match="misalignment.screen_tilt_deg"):
        bench_from_dict({"misalignment": MISALIGNMENT | {"screen_tilt_deg": [20.0, 0.0]}})


def test_the_image_carries_the_camera_distortion_once():
    """The bench draws the radiance on the camera's pinhole grid and the detector stage applies
    the camera's distortion, once: a dot near each corner of a camera with k1 = -0.05 is
    centroided where the full as-built geometry (through the camera's distortion) puts it,
    through the chain (noise, PSF: 0.1 px) and the ideal detector (0.03 px). Distorted twice
    (the bench and the chain each) the corner dots would land ~1.2 px off."""
    from starnav.calibration.geometric import detect_dots
    from starnav.calibration.screen import gaussian_dots
    from starnav.camera import Camera

    cam = Camera.preset("aa-str", k1=-0.05)
    bench = Bench(bench_from_dict({"misalignment": MISALIGNMENT}), camera=cam)
    uv = np.array([[100.3, 110.6], [920.7, 105.2], [108.1, 915.4], [912.5, 921.9],
                   [511.6, 500.3]])
    screen = bench.geometry.pixel_to_screen(uv)
    truth = bench.geometry.screen_to_pixel(screen)
    xy = np.stack([(truth[:, 0] - cam.cx) / cam.fx, (truth[:, 1] - cam.cy) / cam.fy], -1)
    twice = cam.distort(xy) * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    assert np.min(np.hypot(*(twice - truth)[:4].T)) > 1.0   # what the test would see
    counts = gaussian_dots(bench.screen_shape, screen, 1.5, bench.radiometry.le_max,
                           bench.radiometry)
    peak = float(bench.radiance_at_camera(counts).max())
    for det, tol in ((bench.chain_detector(), 0.1), (IdealDetector(cam), 0.03)):
        t = 1.5 * det.full_well_e / (peak * cam.etendue)   # ~half the well after the PSF
        dn = bench.acquire(counts, t, det, 1).dn
        sig = dn - np.median(dn)
        c, _ = detect_dots(sig, 0.05 * sig.max(), 7)
        d = np.hypot(*(c[:, None, :] - truth[None, :, :]).transpose(2, 0, 1))
        assert len(c) == len(uv)
        assert np.all(d.min(axis=0) < tol), d.min(axis=0)
