"""The dataset format: names, canonical JSON, and the round trips of every stored product."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.dataset import format as F
from starnav.detector.readout import extract_segments, read_windows
from starnav.errors import ConfigError
from starnav.geometry import quat_xyzw_from_matrix, static_geometry


@pytest.mark.parametrize(("t", "name"), [(1.5e-5, "exposure_0.015ms"), (1.8e-4, "exposure_0.18ms"),
                                         (7.7e-3, "exposure_7.7ms"), (0.2, "exposure_200ms")])
def test_exposure_directory_names_are_the_papers_milliseconds(t, name):
    assert F.exposure_dirname(t) == name


@pytest.mark.parametrize("bad", [[], [0.0], [-1e-3], [float("nan")], [1e-3, 1.0000001e-3],
                                 ["x"]])
def test_bad_exposure_lists_are_rejected(bad):
    with pytest.raises(ConfigError):
        F.check_exposures(bad)


def test_canonical_json_sorted_exact_and_without_nan():
    obj = {"b": np.float64(0.1 + 0.2), "a": [np.int64(3), float("nan"), np.array([1.5, 2.0])],
           "c": np.bool_(True)}
    text = F.dumps(obj)
    back = json.loads(text)
    assert list(back) == ["a", "b", "c"]
    assert back["b"] == 0.1 + 0.2  # shortest round-trip repr: exact
    assert back["a"] == [3, None, [1.5, 2.0]]
    assert back["c"] is True
    assert F.dumps(back) == text  # stable


def test_segments_round_trip_through_json():
    rng = np.random.default_rng(4)
    dn = rng.integers(0, 4096, (37, 53)).astype(np.uint16)
    seg = extract_segments(dn, (1000, 3000), max_runs=200)
    back = F.segments_from_dict(json.loads(F.dumps(F.segments_to_dict(seg), compact=True)))
    for name in ("row", "col_start", "length", "offset", "values", "level"):
        a, b = getattr(seg, name), getattr(back, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert (back.thresholds, back.shape, back.truncated) == (seg.thresholds, seg.shape,
                                                             seg.truncated)
    assert np.array_equal(back.to_image(), seg.to_image())


def test_windows_round_trip_through_json():
    dn = np.arange(40 * 50, dtype=np.uint16).reshape(40, 50)
    wins = read_windows(dn, [(0, 0, 5, 7), (30, 40, 10, 10)])
    back = F.windows_from_dict(json.loads(F.dumps(F.windows_to_dict(wins, 1))))
    assert [(w.row0, w.col0) for w in back] == [(0, 0), (30, 40)]
    assert all(np.array_equal(a.dn, b.dn) for a, b in zip(wins, back, strict=True))


def test_truth_holds_the_frame_geometry_and_its_projections():
    cam = Camera.preset("aa-str", k1=-0.02)
    g = static_geometry(cam, 6.0e7, math.radians(40.0), (120.0, -80.0), roll=0.3)
    d = json.loads(F.dumps(F.truth_to_dict(g, cam, limb_points=64)))
    back = F.geometry_of_truth(d)
    assert np.allclose(back.camera_position, g.camera_position, rtol=0, atol=1e-6)
    assert np.allclose(back.R_cam_to_inertial, g.R_cam_to_inertial, rtol=0, atol=1e-15)
    q = np.array(d["attitude"]["q_cam_to_inertial_true_xyzw"])
    assert np.allclose(q, quat_xyzw_from_matrix(g.R_cam_to_inertial))
    # the Moon centre pixel is the (distorted) projection of the Moon centre: here 120, -80
    # px from the principal point before distortion
    c_pin = np.array(d["moon"]["centre_pixel_pinhole_px"])
    assert np.allclose(c_pin, [cam.cx + 120.0, cam.cy - 80.0], atol=1e-6)
    assert np.allclose(d["moon"]["centre_pixel_px"], g.moon_centre_pixel(cam, distort=True))
    limb = np.array(d["limb"]["points_px"])
    assert limb.shape == (64, 2)
    # distance of the limb points from the Moon centre ~ apparent radius in px (within the
    # ellipse's off-axis stretch and the 2 % barrel distortion)
    r = np.linalg.norm(limb - c_pin, axis=1)
    r_expected = cam.fx * math.tan(g.apparent_radius)
    assert np.all(np.abs(r / r_expected - 1) < 0.03)


def test_camera_round_trip():
    cam = Camera.preset("aa-str", width=200, height=100, k1=0.01, p2=-1e-4)
    back = F.camera_from_dict(json.loads(F.dumps(F.camera_to_dict(cam))))
    assert back == cam
