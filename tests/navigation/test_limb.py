"""Pixel-accuracy limb points from segments (STAR Nav algorithm 2) on analytic discs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.detector.products import Segments
from starnav.geometry import static_geometry
from starnav.navigation.limb import (
    LimbConfig,
    LimbNotFoundError,
    _column_scan,
    limb_points_from_segments,
    segments_centroid,
    sun_direction_in_image,
)
from starnav.navigation.metrics import limb_point_errors
from starnav.navigation.synthetic import draw_moon, threshold_segments

from .conftest import PEAK_DN, PSF_SIGMA_PX, THRESHOLD_DN

#: A pixel-level limb point is the centre of the lit-side end pixel: quantisation (+-0.5 px along
#: the scan, < 0.71 px along the normal) plus the outward threshold bias of a 10 % threshold
#: with a 0.8 px PSF (~ +0.5 px): every point must lie within 1.5 px of the true limb.
PIXEL_LEVEL_MAX_ERROR_PX = 1.5


def _limb(cam, g, seg, **kw):
    c0 = segments_centroid(seg)
    d = sun_direction_in_image(cam, g.R_cam_to_inertial, g.sun_direction, c0)
    return limb_points_from_segments(seg, d, options=LimbConfig(**kw).to_si()), d


def test_sun_direction_in_image_matches_projection(cam):
    g = static_geometry(cam, 6.0e7, math.radians(50), moon_offset_px=(300.0, 250.0),
                        sun_azimuth=1.1)
    mc = g.moon_centre_camera()
    s = g.sun_direction_camera()
    # the image of a short step from the Moon centre towards the Sun
    eps = 1e-3 * np.linalg.norm(mc)
    d_ref = cam.project(mc + eps * s) - cam.project(mc - eps * s)
    d_ref /= np.linalg.norm(d_ref)
    d = sun_direction_in_image(cam, g.R_cam_to_inertial, g.sun_direction,
                               g.moon_centre_pixel(cam))
    assert np.degrees(math.acos(np.clip(d @ d_ref, -1, 1))) < 0.01


def test_sun_on_the_line_of_sight_is_reported(cam):
    g = static_geometry(cam, 6.0e7, 0.0)
    with pytest.raises(LimbNotFoundError, match="along the line of sight") as err:
        sun_direction_in_image(cam, g.R_cam_to_inertial, g.sun_direction,
                               g.moon_centre_pixel(cam))
    assert err.value.reason == "sun-on-axis"


def test_pixel_level_points_lie_on_the_lit_limb(cam, disc_frame):
    g, dn, seg = disc_frame
    lp, d = _limb(cam, g, seg)
    err = limb_point_errors(lp.uv, cam, g)
    assert len(lp) > 150
    assert np.max(np.abs(err)) < PIXEL_LEVEL_MAX_ERROR_PX
    # the threshold at 10 % of the peak puts the points outside the true limb on average
    assert 0.1 < err.mean() < 0.8
    # all on the lit side: the outward normal faces the Sun in the image
    centre = g.moon_centre_pixel(cam)
    n = (lp.uv - centre) / np.linalg.norm(lp.uv - centre, axis=1)[:, None]
    assert np.all(n @ d >= 0.05)
    # the fitted circle is close to the true disc; not closer than ~2 px: the threshold bias
    # shrinks towards the cusps (dimmer limb), which pulls a half-arc circle towards the Sun
    assert np.linalg.norm(lp.centre_px - centre) < 2.5


@pytest.mark.parametrize("azimuth_deg", [0.0, 45.0, 90.0, 160.0, 200.0, 270.0, 315.0])
def test_every_sun_quadrant(cam, azimuth_deg):
    """Sun from the right, top, left, bottom and the diagonals: the lit-side end is taken from
    the right scan in every case (an error would put points on the terminator, ~R away)."""
    g = static_geometry(cam, 9.0e7, math.radians(70), sun_azimuth=math.radians(azimuth_deg),
                        moon_offset_px=(-100.0, 60.0))
    dn = draw_moon(cam, g, peak_dn=PEAK_DN, psf_sigma_px=PSF_SIGMA_PX, supersample=4)
    lp, _ = _limb(cam, g, threshold_segments(dn, (THRESHOLD_DN,)))
    err = limb_point_errors(lp.uv, cam, g)
    assert len(lp) > 40
    assert np.max(np.abs(err)) < PIXEL_LEVEL_MAX_ERROR_PX


def test_points_are_capped_at_600(cam):
    # at 20 000 km the disc is ~490 px across: more than 600 lit-limb candidates
    g = static_geometry(cam, 2.0e7, math.radians(30))
    dn = draw_moon(cam, g, peak_dn=PEAK_DN, psf_sigma_px=PSF_SIGMA_PX, supersample=2)
    lp, _ = _limb(cam, g, threshold_segments(dn, (THRESHOLD_DN,)))
    assert lp.n_candidates > 600
    assert len(lp) == 600
    lp2, _ = _limb(cam, g, threshold_segments(dn, (THRESHOLD_DN,)), max_points=100)
    assert len(lp2) == 100
    # thinning keeps the whole arc: the angular span barely changes
    def span(p):
        a = np.unwrap(np.sort(np.arctan2(p[:, 1] - lp.centre_px[1], p[:, 0] - lp.centre_px[0])))
        return a.max() - a.min()
    assert span(lp2.uv) == pytest.approx(span(lp.uv), abs=0.05)


def test_border_runs_are_not_limb_points(cam):
    # the Moon cut by the left image border: run ends at column 0 are the image's, not the Moon's
    g = static_geometry(cam, 4.0e7, math.radians(20), moon_offset_px=(-480.0, 0.0),
                        sun_azimuth=math.pi)
    dn = draw_moon(cam, g, peak_dn=PEAK_DN, psf_sigma_px=PSF_SIGMA_PX, supersample=2)
    lp, _ = _limb(cam, g, threshold_segments(dn, (THRESHOLD_DN,)))
    assert np.all(lp.uv[:, 0] >= 1)
    assert np.max(np.abs(limb_point_errors(lp.uv, cam, g))) < PIXEL_LEVEL_MAX_ERROR_PX


def _segments(rows, starts, lengths, shape=(1024, 1024)):
    n = len(rows)
    L = np.asarray(lengths, np.int32)
    return Segments(row=np.asarray(rows, np.int32), col_start=np.asarray(starts, np.int32),
                    length=L, offset=np.concatenate([[0], np.cumsum(L)[:-1]]).astype(np.int64),
                    values=np.full(int(L.sum()), 1000, np.uint16), level=np.zeros(n, np.int8),
                    thresholds=(300,), shape=shape)


def test_bad_input_messages():
    d = np.array([1.0, 0.0])
    with pytest.raises(LimbNotFoundError, match="no run above threshold") as e1:
        limb_points_from_segments(_segments([], [], []), d)
    assert e1.value.reason == "no-moon"
    with pytest.raises(LimbNotFoundError, match="no run at or above"):
        segments_centroid(_segments([], [], []))
    # a two-pixel speck: a degenerate arc
    with pytest.raises(LimbNotFoundError, match="degenerate arc") as e2:
        limb_points_from_segments(_segments([500, 501], [600, 600], [1, 1]), d)
    assert e2.value.reason == "degenerate-arc"
    # runs shorter than min_run_length_px are ignored
    with pytest.raises(LimbNotFoundError, match="length >= 3"):
        limb_points_from_segments(_segments([500, 501], [600, 600], [2, 2]), d,
                                  options=LimbConfig(min_run_length_px=3).to_si())
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=r"max_points\n.*greater than or equal to 3"):
        LimbConfig(max_points=2)


def test_multi_threshold_segments_of_the_detector_readout(cam, disc_frame):
    """The detector's readout splits a row into runs at every threshold crossing (level = the
    thresholds reached); the limb scan takes the outermost run of level >= min_level, so a
    higher level moves the points inwards by the extra threshold distance."""
    from starnav.detector.readout import extract_segments

    g, dn, _ = disc_frame
    seg = extract_segments(dn, (300, 1000, 2000))
    assert set(np.unique(seg.level)) == {0, 1, 2}
    lp0, _ = _limb(cam, g, seg)
    lp1, _ = _limb(cam, g, seg, min_level=1)
    e0 = limb_point_errors(lp0.uv, cam, g)
    e1 = limb_point_errors(lp1.uv, cam, g)
    assert np.max(np.abs(e0)) < PIXEL_LEVEL_MAX_ERROR_PX
    # same points as the single-threshold encoding at level 0
    lp_ref, _ = _limb(cam, g, threshold_segments(dn, (300,)))
    assert np.array_equal(lp0.uv, lp_ref.uv)
    assert e1.mean() < e0.mean() - 0.2


@pytest.mark.parametrize("down", [True, False])
def test_column_scan_matches_painting_every_pixel(down):
    """The sparse-table column scan (issue 18) against the plain definition: every pixel of
    every run painted into a dense image, and per column the lowest (``down``) or highest
    covered row. Random runs, overlapping ones and runs of one pixel and of the full width
    included."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        W, n = int(rng.integers(1, 260)), int(rng.integers(1, 120))
        row = rng.integers(0, 90, n)
        c0 = rng.integers(0, W, n)
        c1 = np.minimum(c0 + rng.integers(0, W, n), W - 1)
        img = np.zeros((90, W), bool)
        for r, a, b in zip(row, c0, c1, strict=True):
            img[r, a:b + 1] = True
        cols = np.flatnonzero(img.any(axis=0))
        rows = (89 - np.argmax(img[::-1], axis=0) if down else np.argmax(img, axis=0))[cols]
        u, v = _column_scan(row, c0, c1, W, down)
        np.testing.assert_array_equal(u, cols)
        np.testing.assert_array_equal(v, rows)
