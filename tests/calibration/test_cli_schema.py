"""Bench files and the ``starnav hil`` commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import typer
import yaml
from pydantic import ValidationError
from typer.testing import CliRunner

from starnav.calibration.schema import BenchConfig, load_bench
from starnav.errors import ConfigError, DataFileError
from starnav.radiance import RadianceImage, write_exr

from .conftest import MISALIGNMENT, lambert_disc_le, small_camera

SMALL = ["--set", "scenario.camera.width=256", "--set", "scenario.camera.height=256",
         "--set", "geometric.polynomial_order=3", "--set", "geometric.dot_margin_px=12"]


@pytest.fixture(scope="module")
def app() -> typer.Typer:
    from starnav.cli.main import app as main_app  # the real command line

    return main_app


def test_defaults_are_the_papers_bench():
    b = BenchConfig()
    assert b.screen.height_mm == 65.0
    assert b.collimator.focal_length_mm == 180.0
    assert b.collimator.spot_field_deg == (0.0, 3.67, 7.32, 9.61)
    assert b.collimator.spot_rms_radius_px == (0.49, 0.72, 1.49, 2.13)
    assert b.check.stated_camera_fov_deg == 10.0
    assert "representative" in b.screen.emittance.source
    with pytest.raises(ValidationError, match="frozen"):
        b.screen.height_mm = 70.0


def test_bench_file_with_a_relative_scenario_and_overrides(tmp_path):
    (tmp_path / "sc.yaml").write_text(yaml.safe_dump({"camera": {"width": 256, "height": 256}}))
    (tmp_path / "bench.yaml").write_text(yaml.safe_dump(
        {"scenario": "sc.yaml", "misalignment": MISALIGNMENT}))
    b = load_bench(tmp_path / "bench.yaml", ["collimator.focal_length_mm=170"])
    assert b.scenario.camera.width == 256
    assert b.collimator.focal_length_mm == 170.0
    assert b.misalignment.screen_roll_deg == 0.4


def test_unknown_keys_and_missing_files_are_named(tmp_path):
    (tmp_path / "b.yaml").write_text("collimator:\n  focal_lenght_mm: 170\n")
    with pytest.raises(ConfigError) as err:
        load_bench(tmp_path / "b.yaml")
    assert "collimator.focal_lenght_mm" in str(err.value)
    with pytest.raises(DataFileError):
        load_bench(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="screen.height_mm"):
        load_bench(None, ["screen.height_mm=-3"])


def test_hil_check_writes_both_verdicts(app, tmp_path):
    r = CliRunner().invoke(app, ["hil", "check", "default", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "check.json").read_text())
    assert [c["satisfied"] for c in s["conditions"]] == [True, False, True]
    assert s["fills_field"] is False
    assert s["paper"]["fov_implied_by_that_bound_deg"] == pytest.approx(20.46, abs=0.01)
    assert (tmp_path / "coverage.png").stat().st_size > 1000
    assert (tmp_path / "bench.resolved.yaml").exists()


def one_line(text: str) -> str:
    """``text`` with every run of whitespace (line breaks included) made one space: CLI output
    compared this way does not depend on the terminal width."""
    return " ".join(text.split())


def test_hil_check_bad_input_exits_2_with_the_field(app, tmp_path):
    r = CliRunner().invoke(app, ["hil", "check", str(tmp_path / "missing.yaml")])
    assert r.exit_code == 2 and "does not exist" in one_line(r.output)
    r = CliRunner().invoke(app, ["hil", "check", "default", "--set", "screen.bit_depth=40"])
    assert r.exit_code == 2 and "screen.bit_depth" in one_line(r.output)


@pytest.mark.parametrize("command", [["hil", "check"], ["validate"], ["dem", "info"]])
def test_error_message_is_one_line_on_a_narrow_terminal(app, tmp_path, command):
    # `make test` on a fresh clone: rich wrapped the error at 80 columns and split
    # "does not exist" when the temporary path was long. Errors are never wrapped.
    missing = tmp_path / ("a_long_directory_name_" * 5) / "missing.yaml"
    r = CliRunner().invoke(app, [*command, str(missing)], env={"COLUMNS": "40"})
    assert r.exit_code == 2
    line = next(ln for ln in r.output.splitlines() if ln.startswith("error:"))
    assert str(missing) in line and line.rstrip().endswith("does not exist"), r.output


def test_hil_geometric_then_stimulate(app, tmp_path):
    runner = CliRunner()
    geo = tmp_path / "geo"
    r = runner.invoke(app, ["hil", "geometric", "default", "--out", str(geo), "--no-moon",
                            *SMALL, "--set", f"misalignment.screen_roll_deg={0.3}"])
    assert r.exit_code == 0, r.output
    s = json.loads((geo / "geometric.json").read_text())
    assert s["geometric"]["holdout"]["rms_arcsec"] < 5.0
    # a layout no calibration grid has (random point sources), through the calibration
    rl = s["random_layout_holdout"]
    assert rl["points_found"] >= 0.9 * rl["points_shown"] and rl["rms_arcsec"] < 5.0
    # the star-field stimulus, predicted through the calibrated camera
    sf = s["star_field_holdout"]
    assert sf["stars"] >= 4 and sf["passes"], sf
    for f in ("residuals_pdf_cdf.png", "dot_displacements.png", "geometric_calibration.json"):
        assert (geo / f).exists()
    # the camera as the bench estimated it, in the file navigation reads
    from starnav.camera_calibration import read_calibration

    cam_cal = read_calibration(geo / "camera_calibration.json")
    assert cam_cal.camera.width == 256 and cam_cal.sigma("focal_length_m") > 0
    assert s["camera"]["parameters"] == list(cam_cal.parameters)
    # ... with the screen's radiometric calibration against the reference instrument
    from starnav.calibration.radiometric_lab import RadiometricCalibration

    rad = RadiometricCalibration.from_dict(cam_cal.radiometric)
    assert rad.counts[-1] == 255 and np.all(np.diff(rad.le) > 0)
    v = s["radiometric_lab"]["validation"]
    assert v["points"] > 0 and v["consistent"] and "tracker linearity" in v["budget_rms"]
    # a dataset as `starnav render` writes it: RadianceImage EXRs
    cam = small_camera(256)
    ds = tmp_path / "ds"
    for i, c in enumerate([(120.0, 130.0), (140.5, 110.2)]):
        le = lambert_disc_le(cam, c, 40.0, 2.7e19).astype(np.float32)
        write_exr(RadianceImage(le / 8.6e17, le, {}, {}), ds / f"frame_{i:06d}.exr")
    out = tmp_path / "stim"
    r = runner.invoke(app, ["hil", "stimulate", "default", str(ds), "--out", str(out),
                            "--calibration", str(geo / "geometric_calibration.json"), *SMALL,
                            "--set", "misalignment.screen_roll_deg=0.3"])
    assert r.exit_code == 0, r.output
    s = json.loads((out / "stimulate.json").read_text())
    assert len(s["frames"]) == 2 and s["plan"]["k"] == pytest.approx(13333.33, rel=1e-6)
    # the default bench has a truth: counts from the lab's calibration, shown on the truth
    # screen, each frame with its budget and verdict
    assert s["stimulus_path"].startswith("truth bench")
    assert s["radiometric_calibration"]["counts"][-1] == 255
    for f in s["frames"]:
        assert f["truth_bench"] and f["consistent"] and f["centroid_offset_px"] < 0.5
        assert abs(f["disc_ratio"] - 1) <= f["z_crit"] * f["sigma"]["disc_ratio"]
        assert f["budget"]["disc_ratio"]["reference absolute"] > 0
    import imageio.v3 as iio

    scr = iio.imread(out / "screen" / "frame_000000.png")
    assert scr.shape == (2160, 3840) and scr.dtype == np.uint8 and 0 < scr.max() <= 16
    assert iio.imread(out / "predicted" / "frame_000001_dn.png").dtype == np.uint16
    # wrong camera size and empty directory: clear errors
    r = runner.invoke(app, ["hil", "stimulate", "default", str(ds), "--out", str(out),
                            "--overwrite"])
    assert r.exit_code == 2 and "256 x 256" in one_line(r.output)
    empty = tmp_path / "empty"
    empty.mkdir()
    r = runner.invoke(app, ["hil", "stimulate", "default", str(empty), "--out", str(out),
                            "--overwrite"])
    assert r.exit_code == 2 and "EXR" in one_line(r.output)


@pytest.mark.slow
def test_hil_radiometric_cli(app, tmp_path):
    r = CliRunner().invoke(app, ["hil", "radiometric", "default", "--out", str(tmp_path),
                                 *SMALL, "--set", "scenario.geometry.range_km=200000"])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "radiometric.json").read_text())
    assert abs(s["validation"]["disc_ratio"] - 1) < 0.02
    ks = s["albedo_exposure_ks"]
    # the default bench has a truth: the equivalence runs on it and its ratios are within
    # their budget (the KS test may reject a scaled case there: docs/calibration.md, section 5)
    assert ks["truth_bench"] and ks["ratios_consistent"] and ks["control_ratio_detected"]
    assert ks["control_detected"]
    assert s["end_to_end"]["plan"]["k"] == pytest.approx(13333.33, rel=1e-6)
    assert s["end_to_end"]["truth_bench"] and s["end_to_end"]["metrics"]["consistent"]
    for f in ("count_flux_mapping.png", "radiometric_validation.png",
              "albedo_exposure_histograms.png", "end_to_end.png", "count_flux_mapping.json"):
        assert (tmp_path / f).exists()
