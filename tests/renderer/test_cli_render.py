"""`starnav render` and `starnav info` from the command line (Typer's runner)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from starnav.cli.main import app
from starnav.radiance import read_exr


def test_render_writes_exr_with_channels_and_resolved_config(tmp_path):
    out = tmp_path / "r"
    res = CliRunner().invoke(app, [
        "render", "--out", str(out), "--set", "camera.width=96", "--set", "camera.height=96",
        "--set", "camera.focal_length_mm=10", "--set", "render.spp=4"])
    assert res.exit_code == 0, res.output
    img = read_exr(out / "frame_000000.exr")
    assert img.L.shape == (96, 96)
    assert set(img.aovs) >= {"range", "lat", "lon", "incidence", "emission", "phase", "mask"}
    assert img.meta["geometry"]["range_m"] == 6.0e7
    assert np.isfinite(img.L).all() and img.L.max() > 0
    assert (out / "scenario.resolved.yaml").exists()


def test_render_bad_input_exits_with_message(tmp_path):
    res = CliRunner().invoke(app, ["render", "--out", str(tmp_path),
                                   "--set", "geometry.range_km=100"])
    assert res.exit_code == 2
    assert "inside the Moon" in res.output
    assert not list(tmp_path.glob("*.exr"))


def test_info_reports_variant():
    res = CliRunner().invoke(app, ["info"])
    assert res.exit_code == 0, res.output
    assert "variant chosen" in res.output
