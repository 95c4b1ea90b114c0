"""Files of an exposure (PNG 16 bit, NPZ, JSON) and the ``starnav expose`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from starnav.config import build_camera, load_scenario, scenario_from_dict
from starnav.detector import expose
from starnav.detector.io import read_dn_png, read_segments, read_windows, write_exposure
from starnav.radiance import RadianceImage, write_exr

from .conftest import lambert_disc


def test_write_exposure_round_trips(tmp_path, cam64):
    le = lambert_disc(64, (30.0, 30.0), 14.0, 3e18)
    f = expose(le, cam64, seed=4, windows=[(3, 4, 10, 12), (40, 40, 20, 24)], exposure_time=1e-3)
    paths = write_exposure(f, tmp_path)
    assert np.array_equal(read_dn_png(paths["dn"]), f.dn)
    seg = read_segments(paths["segments"])
    assert f.segments is not None
    for name in ("row", "col_start", "length", "offset", "values", "level"):
        assert np.array_equal(getattr(seg, name), getattr(f.segments, name))
    assert seg.thresholds == f.segments.thresholds and seg.shape == (64, 64)
    wins = read_windows(paths["windows"])
    assert [(w.row0, w.col0) for w in wins] == [(3, 4), (40, 40)]
    assert all(np.array_equal(a.dn, b.dn) for a, b in zip(wins, f.windows, strict=True))
    summary = json.loads(paths["summary"].read_text())
    assert summary["seed"] == 4 and summary["timing"][0]["mode"] == "segments"
    assert not list(tmp_path.glob(".*"))        # no temporary file left behind


def test_cli_expose_writes_the_library_result(tmp_path):
    sc_data = {"camera": {"width": 48, "height": 40}, "seed": 17,
               "detector": {"readout": {"windows": [
                   {"row0": 2, "col0": 3, "height": 5, "width": 6}]}}}
    sc_file = tmp_path / "s.yaml"
    sc_file.write_text(yaml.safe_dump(sc_data))
    le = np.zeros((40, 48), np.float32)
    le[10:30, 12:40] = 2e18
    exr = write_exr(RadianceImage(L=le * 1e-18, Le=le), tmp_path / "r.exr")
    from starnav.cli.main import app  # the real command line

    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["expose", str(exr), "--scenario", str(sc_file), "--out",
                                   str(out), "--exposure-s", "2e-3", "--frame-index", "3"])
    assert res.exit_code == 0, res.output
    assert "INFEASIBLE" in res.output
    sc = scenario_from_dict(sc_data, ["detector.exposure_time_s=2e-3"])
    ref = expose(le, build_camera(sc.camera), sc.detector, seed=17, frame_index=3)
    assert np.array_equal(read_dn_png(out / "dn.png"), ref.dn)
    assert np.array_equal(read_windows(out / "windows.npz")[0].dn, ref.windows[0].dn)
    from PIL import Image

    with Image.open(out / "dn_quicklook.png") as im:  # the picture next to the data
        ql = np.asarray(im)
    assert ql.dtype == np.uint8 and ql.shape[:2] == (40, 48)
    lit = ql[14:26, 16:36].astype(float).mean()  # inside the lit block, off the caption bands
    dark = ql[14:26, 2:8].astype(float).mean()
    assert lit > 150 and dark < 40, (lit, dark)
    resolved = yaml.safe_load((out / "scenario.resolved.yaml").read_text())
    assert resolved["detector"]["exposure_time_s"] == 2e-3
    assert load_scenario(out / "scenario.resolved.yaml") == sc     # the resolved file reloads
    bad = CliRunner().invoke(app, ["expose", str(exr), "--scenario", str(sc_file), "--out",
                                   str(out), "--exposure-s", "-1"])
    assert bad.exit_code == 2
    assert "--exposure = '-1': expected a time > 0" in " ".join(bad.output.split())


def test_png_encoder_round_trips_through_pillow_and_imageio():
    """:func:`starnav.detector.io.png_bytes` (filter none, zlib Huffman-only or run-length)
    decodes to the array in Pillow and imageio (libpng's rules: CRCs, chunk order, big-endian
    16-bit samples), 8 and 16 bit, odd sizes, the extreme values, a noisy and a mostly black
    image; text chunks in order, Latin-1 or not."""
    import io

    import imageio.v3 as iio
    from PIL import Image

    from starnav.detector.io import png_bytes

    rng = np.random.default_rng(8)
    arrays = [rng.integers(0, 65536, (37, 53)).astype(np.uint16),
              rng.integers(0, 256, (1, 1)).astype(np.uint8),
              np.array([[0, 65535, 1, 256]], np.uint16),
              rng.integers(0, 256, (64, 3)).astype(np.uint8),
              np.where(rng.random((40, 30)) < 0.02, 200, 0).astype(np.uint8)]  # runs: Z_RLE
    text = [("Title", "frame 3"), ("starnav:unit", "W m^-2 sr^-1"), ("note", "µ 5 ✓")]
    for a in arrays:
        data = png_bytes(a, text)
        assert data == png_bytes(a, text)  # deterministic
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            assert im.size == (a.shape[1], a.shape[0])
            assert np.array_equal(np.asarray(im).astype(a.dtype), a)
            assert list(im.text.items()) == text
        back = iio.imread(data, extension=".png")
        assert back.dtype == a.dtype and np.array_equal(back, a)


def test_png_encoder_refuses_what_it_cannot_store():
    from starnav.detector.io import png_bytes
    from starnav.errors import ConfigError

    for bad in (np.zeros((4, 4), np.float32), np.zeros((2, 2, 3), np.uint8),
                np.zeros((0, 4), np.uint8)):
        with pytest.raises(ConfigError, match="2-D uint8 or uint16"):
            png_bytes(bad)
