"""Scenario -> per-frame FrameGeometry and EMB truth; schema validation; the CLI command."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from starnav.config import scenario_from_dict
from starnav.constants import AU, MOON_RADIUS
from starnav.errors import ConfigError
from starnav.geometry import static_geometry_from_config
from starnav.scenes import frames as scene_frames
from starnav.scenes import trajectory as traj_mod
from starnav.scenes.ephemeris import parse_epoch
from starnav.scenes.oem import write_oem
from starnav.simulate import frame_geometries, frame_states, scene_from_scenario

from .conftest import ARC_EPOCH, KM

SCENE_SC = {"trajectory": {"frames": 6, "cadence_s": 600.0, "frame_offset_s": 300.0},
            "seed": 11}


@pytest.fixture(scope="module")
def scene(arc):
    return scene_from_scenario(scenario_from_dict(SCENE_SC), arc=arc)


def test_frame_epochs_and_truth(scene, arc, eph):
    t0 = parse_epoch(ARC_EPOCH)
    assert np.allclose(scene.epochs, t0 + 300.0 + 600.0 * np.arange(6))
    assert np.array_equal(scene.states_emb, arc.sample(scene.epochs))
    for i, g in enumerate(scene.geometries()):
        moon = eph.state("moon", g.epoch_tdb, center="emb")
        sun = eph.state("sun", g.epoch_tdb, center="emb")
        assert g.index == i
        assert np.allclose(g.camera_position, scene.states_emb[i, :3] - moon[:3], atol=1e-6)
        assert np.allclose(g.camera_velocity, scene.states_emb[i, 3:] - moon[3:], atol=1e-9)
        assert np.allclose(g.sun_position, sun[:3] - moon[:3], atol=1e-3)
        assert abs(g.sun_distance / AU - 1) < 0.035  # Earth orbit eccentricity 0.0167 + Moon
        assert 35_000 * KM < g.range < 90_000 * KM
        assert np.allclose(g.R_body_to_inertial, eph.moon_orientation(g.epoch_tdb), atol=0)
        assert g.body_radius == MOON_RADIUS
        # measured attitude: true one off by a few tens of arcsec at most (5", 5", 40" 1-sigma)
        dR = g.R_cam_to_inertial.T @ g.R_cam_to_inertial_measured
        ang = math.acos(min(1.0, (np.trace(dR) - 1) / 2))
        assert 0 < ang < math.radians(250 / 3600)


def test_frames_do_not_depend_on_order(scene, arc):
    g4 = scene.geometry(4)
    other = scene_from_scenario(scenario_from_dict(SCENE_SC), arc=arc)
    h4 = other.geometry(4)  # built first in this scene
    assert np.array_equal(g4.R_cam_to_inertial, h4.R_cam_to_inertial)
    assert np.array_equal(g4.R_cam_to_inertial_measured, h4.R_cam_to_inertial_measured)
    assert not np.array_equal(scene.geometry(3).R_cam_to_inertial, g4.R_cam_to_inertial)


def test_frame_geometry_truth_products(scene):
    cam = scene.camera
    for g in scene.geometries():
        uv = g.moon_centre_pixel(cam)
        limb = g.limb_points(cam, n=360)
        assert limb.shape == (360, 2)
        assert limb.min() >= 8 - 0.5 and limb.max() <= 1024 - 0.5 - 8
        r_px = np.linalg.norm(limb - uv, axis=1)
        # apparent radius asin(R/d) in pixels on axis, the limb ellipse slightly larger off axis
        r_axis = cam.fx * math.tan(g.apparent_radius)
        assert 0.99 * r_axis < r_px.mean() < 1.05 * r_axis
        assert 0 <= g.phase_angle <= math.pi


def test_scenario_functions(arc, monkeypatch):
    from starnav.scenes import frames as frames_mod

    monkeypatch.setattr(frames_mod, "build_trajectory",
                        lambda cfg, eph=None, cache=None, spacecraft=None: arc)
    sc = scenario_from_dict({"trajectory": {"frames": 3}})
    epochs, states = frame_states(sc)
    assert epochs.shape == (3,) and states.shape == (3, 6)
    geoms = frame_geometries(sc)
    assert [g.index for g in geoms] == [0, 1, 2]
    assert np.allclose([g.epoch_tdb for g in geoms], epochs)


def test_static_scenario_gives_one_frame():
    sc = scenario_from_dict({"geometry": {"range_km": 50_000.0, "phase_angle_deg": 45.0}})
    scene = scene_from_scenario(sc)
    assert len(scene) == 1
    g = scene.geometry(0)
    ref = static_geometry_from_config(scene.camera, sc.geometry, scene.body_radius)
    assert np.array_equal(g.camera_position, ref.camera_position)
    assert np.array_equal(g.R_cam_to_inertial, ref.R_cam_to_inertial)
    assert g.R_cam_to_inertial_measured is not None
    with pytest.raises(ConfigError, match="trajectory"):
        _ = scene.states_emb


def test_oem_source(arc, tmp_path, scene):
    path = write_oem(tmp_path / "arc.oem", arc.resample(300.0))
    sc = scenario_from_dict({"trajectory": {"source": "oem", "oem_path": str(path),
                                            "frames": 6, "cadence_s": 600.0,
                                            "frame_offset_s": 300.0}, "seed": 11})
    other = scene_from_scenario(sc)
    assert np.allclose(other.epochs, scene.epochs, atol=1e-6)
    assert np.abs(other.states_emb[:, :3] - scene.states_emb[:, :3]).max() < 1e-2  # printed mm
    g, h = other.geometry(2), scene.geometry(2)
    assert np.allclose(g.R_cam_to_inertial, h.R_cam_to_inertial, atol=1e-9)


@pytest.mark.parametrize(
    ("section", "field"),
    [
        ({"epoch": "2027-03-01T00:00:00"}, "trajectory.epoch"),
        ({"epochh": "2027-03-01T00:00:00 TDB"}, "trajectory.epochh"),
        ({"source": "oem"}, "trajectory"),
        ({"cadence_s": 0}, "trajectory.cadence_s"),
        ({"halo_z0_km": 100.0}, "trajectory.halo_z0_km"),
        ({"halo_phase_deg": 360.0}, "trajectory.halo_phase_deg"),
        ({"range_min_km": 90_000.0}, "trajectory"),
    ],
)
def test_trajectory_config_is_validated(section, field):
    with pytest.raises(ConfigError) as info:
        scenario_from_dict({"trajectory": section})
    assert info.value.field == field


def test_yaml_utc_timestamp_keeps_its_scale():
    data = yaml.safe_load("trajectory:\n  epoch: 2027-03-01T00:00:00Z\n")
    sc = scenario_from_dict(data)
    assert sc.trajectory.epoch == "2027-03-01T00:00:00.000000 UTC"
    assert parse_epoch(sc.trajectory.epoch) == parse_epoch("2027-03-01T00:00:00 UTC")
    with pytest.raises(ConfigError, match="trajectory.epoch"):  # a date has no time scale
        scenario_from_dict(yaml.safe_load("trajectory:\n  epoch: 2027-03-01\n"))


def test_pointing_config_is_validated():
    with pytest.raises(ConfigError, match="pointing.roll"):
        scenario_from_dict({"pointing": {"roll": "spin"}})
    with pytest.raises(ConfigError, match="pointing.knowledge_cross_arcsec"):
        scenario_from_dict({"pointing": {"knowledge_cross_arcsec": -1}})
    sc = scenario_from_dict({"pointing": {"moon_offset": "fixed", "moon_offset_px": [40, -30]}})
    assert sc.pointing.moon_offset_px == (40.0, -30.0)


def test_fixed_pointing_in_a_scene(arc):
    sc = scenario_from_dict({"trajectory": {"frames": 2},
                             "pointing": {"moon_offset": "fixed", "moon_offset_px": [40, -30],
                                          "roll": "fixed", "roll_deg": 0.0}})
    scene = scene_from_scenario(sc, arc=arc)
    g = scene.geometry(1)
    uv = g.moon_centre_pixel(scene.camera)
    assert np.abs(uv - [scene.camera.cx + 40, scene.camera.cy - 30]).max() < 1e-6


def test_cli_trajectory_writes_oem_plot_and_config(tmp_path):
    from starnav.cli.main import app  # the real command line
    from starnav.scenes.oem import read_oem

    scen = tmp_path / "s.yaml"
    scen.write_text(yaml.safe_dump({"trajectory": {"duration_days": 2.0}}))
    out = tmp_path / "o" / "t.oem"
    res = CliRunner().invoke(app, ["trajectory", str(scen), "--out", str(out),
                                   "--cadence-s", "3600"])
    assert res.exit_code == 0, res.output
    traj = read_oem(out)
    assert len(traj) == 49 and np.allclose(np.diff(traj.times), 3600.0)
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert (out.parent / "scenario.resolved.yaml").is_file()
    bad = CliRunner().invoke(app, ["trajectory", str(scen), "--out", str(out), "--overwrite",
                                   "--set", "trajectory.epoch=2250-01-01T00:00:00 TDB"])
    assert bad.exit_code == 2 and "outside the DE421 span" in bad.output



def test_scene_from_scenario_keeps_the_halo_arc_on_disk(tmp_path, monkeypatch):
    """The halo arc is written to the cache directory by the first process that shoots it and
    read back, unchanged, by the next one (a dataset's or sweep's workers: issue 18)."""
    monkeypatch.setenv("STARNAV_CACHE_DIR", str(tmp_path))
    sc = scenario_from_dict({"trajectory": {"frames": 3, "cadence_s": 1800.0,
                                            "duration_days": 0.5}})
    scene_frames._ARC_MEMO.clear()   # as in a fresh process
    first = scene_from_scenario(sc)
    assert len(list((tmp_path / "trajectories").glob("halo-*.npz"))) == 1
    scene_frames._ARC_MEMO.clear()   # the next process reads the file and shoots nothing
    monkeypatch.setattr(traj_mod, "multiple_shooting",
                        lambda *a, **k: pytest.fail("the arc was shot again"))
    second = scene_from_scenario(sc)
    np.testing.assert_array_equal(second.trajectory.times, first.trajectory.times)
    np.testing.assert_array_equal(second.trajectory.states, first.trajectory.states)
