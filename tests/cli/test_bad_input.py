"""Bad input and faults from the command line (issue 15): every case exits with code 2 and one
``error:`` line naming the file or field, the value and what was expected; no traceback; nothing
written (or nothing stale left). Run as the user a fresh clone gives, terminal-width free."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from tests.dataset.conftest import SMALL, small_dataset  # noqa: F401  (session fixture)

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

#: A directory nobody may create (read-only file system, even for root).
UNWRITABLE = "/proc/starnav-cannot-write-here"


@pytest.fixture(scope="module")
def app():
    from starnav.cli.main import app as main_app

    return main_app


def run(app, args: list[str]):
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "50"})


def assert_clean_error(r, *needles: str) -> str:
    """Exit 2, an ``error:`` line containing every needle, no traceback."""
    out = r.output
    assert r.exit_code == 2, (r.exit_code, out, repr(r.exception))
    assert "Traceback" not in out
    lines = [ln for ln in out.splitlines() if ln.startswith("error:")]
    assert lines, out
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def small_yaml(path: Path, **extra) -> Path:
    data = {k: dict(v) for k, v in SMALL.items()}
    data["trajectory"]["frames"] = 2
    for k, v in extra.items():
        data[k] = v
    path.write_text(yaml.safe_dump(data))
    return path


# --------------------------------------------------------------------------- expose inputs
@pytest.mark.parametrize("content", [b"", b"not an exr at all", b"v/1\x01" + b"\x00" * 40])
def test_expose_rejects_a_file_that_is_not_a_radiance_exr(app, tmp_path, content):
    bad = tmp_path / "frame.exr"
    bad.write_bytes(content)
    line = assert_clean_error(run(app, ["expose", bad, "--out", tmp_path / "out"]), str(bad))
    assert "OpenEXR" in line or "EXR" in line
    assert not (tmp_path / "out").exists()


def test_expose_rejects_a_truncated_exr(app, tmp_path):
    import numpy as np

    from starnav.radiance import RadianceImage, write_exr

    good = write_exr(RadianceImage(L=np.ones((16, 16), np.float32),
                                   Le=np.ones((16, 16), np.float32)), tmp_path / "good.exr")
    cut = tmp_path / "cut.exr"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    assert_clean_error(run(app, ["expose", cut, "--out", tmp_path / "out"]), str(cut))


# --------------------------------------------------------------------------- unwritable outputs
@pytest.mark.parametrize("command", ["render", "trajectory", "init", "show"])
def test_an_unwritable_output_is_one_clear_line(app, tmp_path, command):
    sc = small_yaml(tmp_path / "sc.yaml")
    target = f"{UNWRITABLE}/out" if command in ("render",) else f"{UNWRITABLE}/out.x"
    args = {"render": ["render", sc, "--out", target],
            "trajectory": ["trajectory", sc, "--out", target],
            "init": ["init", target],
            "show": ["show", sc, "--out", target]}[command]
    assert_clean_error(run(app, args), UNWRITABLE)


def test_an_output_path_that_is_a_file(app, tmp_path):
    sc = small_yaml(tmp_path / "sc.yaml")
    f = tmp_path / "afile"
    f.write_text("x")
    assert_clean_error(run(app, ["render", sc, "--out", f]), str(f))


def test_navigate_into_an_unwritable_directory(app, small_dataset):  # noqa: F811
    assert_clean_error(run(app, ["navigate", small_dataset, "--out", f"{UNWRITABLE}/nav"]),
                       UNWRITABLE)


# --------------------------------------------------------------------------- silent or false
@pytest.mark.parametrize("override, field", [
    ("geometry.range_km=1000", "range"),
    ("sensor_response.qe=[0.5,0.5]", "sensor_response"),
    ("sensor_response.qe=[-0.6,0.5,0.5]", "sensor_response"),
    ("sensor_response.qe=[2,0.5,0.5]", "sensor_response"),
    ("moon.dem.path=/nonexistent/dem.lbl", "/nonexistent/dem.lbl"),
    ("moon.albedo=5", "moon.albedo"),
])
def test_validate_checks_what_render_would(app, tmp_path, override, field):
    extra = []
    if override.startswith("sensor_response"):
        extra = ["--set", "sensor_response.preset=null", "--set",
                 "sensor_response.wavelengths_nm=[400,500,600,700]", "--set",
                 "sensor_response.transmission=[1,1,1]"]
    if override.startswith("moon.dem"):
        extra = ["--set", "moon.dem.source=file"]
    args = ["validate", "--set", override, *extra]
    if override.startswith("geometry"):
        args += ["--set", "trajectory=null"]
    assert_clean_error(run(app, args), field)


def test_navigate_refuses_keys_it_does_not_use(app, small_dataset, tmp_path):  # noqa: F811
    line = assert_clean_error(run(app, ["navigate", small_dataset, "--out", tmp_path / "n",
                                        "--set", "moon.albedo=0.5"]), "moon.albedo")
    assert "navigation." in line
    assert not (tmp_path / "n").exists()


def test_scheduler_and_workers_are_exclusive(app, tmp_path):
    sc = small_yaml(tmp_path / "sc.yaml")
    assert_clean_error(run(app, ["dataset", sc, "--out", tmp_path / "ds", "--workers", "2",
                                 "--scheduler", "tcp://127.0.0.1:1"]), "--workers")
    assert not (tmp_path / "ds").exists()
