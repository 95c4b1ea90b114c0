"""The calibration file contract between the bench and navigation (regression: the file's own
round trip and its refusals)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.camera_calibration import (
    CameraCalibration,
    read_calibration,
    with_parameters,
    write_calibration,
)
from starnav.errors import ConfigError, DataFileError


def _cal() -> CameraCalibration:
    cam = with_parameters(Camera.preset("aa-str"), {"focal_length_m": 50.9e-3, "cx_px": 512.3,
                                                    "k1": -2e-3})
    names = ("focal_length_m", "cx_px", "cy_px", "k1")
    sig = np.array([20e-6, 0.3, 0.3, 1e-4])
    corr = np.eye(4)
    corr[0, 3] = corr[3, 0] = 0.4
    return CameraCalibration(cam, names, corr * np.outer(sig, sig), {"method": "test"})


def test_round_trip(tmp_path):
    cal = _cal()
    p = write_calibration(tmp_path / "cal.json", cal)
    back = read_calibration(p)
    assert back.camera == cal.camera
    assert back.parameters == cal.parameters
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    assert back.sigma("focal_length_m") == pytest.approx(20e-6)
    assert back.sigma("p2") == 0.0


def test_samples_follow_the_covariance():
    cal = _cal()
    rng = np.random.default_rng(1)
    f = np.array([cal.sample(rng).focal_length for _ in range(4000)])
    assert abs(f.mean() - 50.9e-3) < 4 * 20e-6 / np.sqrt(4000)
    assert f.std() == pytest.approx(20e-6, rel=0.06)


@pytest.mark.parametrize("edit, field", [
    (lambda d: d.update(version=7), "version"),
    (lambda d: d.update(format="x"), "format"),
    (lambda d: d.pop("covariance"), "covariance"),
    (lambda d: d.update(estimate=[1.0]), "estimate"),
    (lambda d: d.update(parameters=["focal_length_m", "cx_px", "cy_px", "zoom"]), "parameters"),
    (lambda d: d["covariance"][0].__setitem__(0, -1.0), "covariance"),
    (lambda d: d["camera"].pop("pitch_x_m"), "pitch_x_m"),
])
def test_malformed_files_name_the_entry(tmp_path, edit, field):
    d = _cal().to_dict()
    edit(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(ConfigError, match=field):
        read_calibration(p)


def test_missing_and_unreadable(tmp_path):
    with pytest.raises(DataFileError):
        read_calibration(tmp_path / "none.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="bin.json"):
        read_calibration(tmp_path / "bin.json")
