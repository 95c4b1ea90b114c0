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
    assert "inside the Moon" in " ".join(res.output.split())
    assert not list(tmp_path.glob("*.exr"))


def test_info_reports_variant():
    res = CliRunner().invoke(app, ["info"])
    assert res.exit_code == 0, res.output
    assert "variant chosen" in " ".join(res.output.split())


#: A sphere with a grey Lambert surface: the preview test needs no packaged DEM or calibration.
SIMPLE_MOON = ["--set", "moon.shape=sphere", "--set", "moon.photometry.model=lambert",
               "--set", "moon.photometry.spectral_shape=grey", "--set", "moon.albedo=0.12"]


def test_render_preview_writes_an_8bit_png_with_the_moon_where_the_mask_is(tmp_path):
    from PIL import Image
    from scipy.ndimage import binary_dilation, center_of_mass

    from starnav.preview import CAPTION_PX, MIN_WIDTH_PX

    out = tmp_path / "r"
    res = CliRunner().invoke(app, [
        "render", "--out", str(out), "--preview", "--set", "camera.width=96",
        "--set", "camera.height=96", "--set", "camera.focal_length_mm=10",
        "--set", "render.spp=4", "--set", "geometry.moon_offset_px=[12,-8]", *SIMPLE_MOON])
    assert res.exit_code == 0, res.output
    png = out / "frame_000000.png"
    with Image.open(png) as im:
        assert im.mode == "L"  # single channel, 8 bits (a 16-bit PNG opens as "I;16")
        a = np.asarray(im)
    assert a.dtype == np.uint8
    img = read_exr(out / "frame_000000.exr")
    h, w = img.L.shape
    c0 = (max(w, MIN_WIDTH_PX) - w) // 2
    frame = a[CAPTION_PX:CAPTION_PX + h, c0:c0 + w]
    mask = img.mask
    assert mask.sum() > 100
    # bright pixels lie on the Moon (limb pixels partly covered: one pixel of slack)...
    bright = frame > 64
    assert not (bright & ~binary_dilation(mask, iterations=1)).any()
    assert (frame[~binary_dilation(mask, iterations=1)] == 0).all()
    # ... and cover its lit part (phase 30 deg: ~7 % of the disc is in shadow)
    assert bright[mask].mean() > 0.7
    # same place (the lit part's centroid leans ~1.3 px sunward; a flipped frame is 24 px off)
    assert np.hypot(*np.subtract(center_of_mass(bright), center_of_mass(mask))) < 3.0
    # the caption strip carries text (the labels), the EXR stays as it was
    assert a[:CAPTION_PX].max() > 128
    assert img.L.dtype == np.float32
