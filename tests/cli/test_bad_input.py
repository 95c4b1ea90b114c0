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


# --------------------------------------------------------------------------- OEM inside the Moon
#: A Moon-centred OEM whose second state is 1063 km from the Moon's centre (radius 1737.4 km).
INSIDE_OEM = """CCSDS_OEM_VERS = 2.0
CREATION_DATE = 2025-01-01T00:00:00
ORIGINATOR = starnav tests

META_START
OBJECT_NAME = SC
OBJECT_ID = 1
CENTER_NAME = MOON
REF_FRAME = ICRF
TIME_SYSTEM = TDB
START_TIME = 2025-01-01T00:00:00
STOP_TIME = 2025-01-01T02:00:00
META_STOP
2025-01-01T00:00:00 60000.0 0.0 0.0 0.0 0.1 0.0
2025-01-01T01:00:00 1000.0 860.0 0.0 0.0 0.1 0.0
2025-01-01T02:00:00 60000.0 720.0 0.0 0.0 0.1 0.0
"""


@pytest.mark.parametrize("command", ["trajectory", "render", "dataset", "validate"])
def test_an_oem_inside_the_moon_is_refused_before_anything_is_written(app, tmp_path, command):
    oem = tmp_path / "inside.oem"
    oem.write_text(INSIDE_OEM)
    sc = small_yaml(tmp_path / "sc.yaml", trajectory={
        "source": "oem", "oem_path": str(oem), "frames": 3, "cadence_s": 3600.0,
        "duration_days": 1.0})
    out = tmp_path / "out"
    args = {"trajectory": ["trajectory", sc, "--out", out / "t.oem"],
            "render": ["render", sc, "--out", out],
            "dataset": ["dataset", sc, "--out", out],
            "validate": ["validate", sc]}[command]
    line = assert_clean_error(run(app, args), str(oem), "2025-01-01T01:00:00", "inside the Moon")
    assert "1319" in line  # |(1000, 860, 0)| km, the distance from the Moon's centre
    assert "1737.4" in line  # what was expected: outside the Moon's radius
    assert not out.exists()


# --------------------------------------------------------------------------- stale outputs
def _stale_render(out: Path, frames: int = 8) -> dict[str, bytes]:
    """What a previous 8-frame render left in ``out`` (names as `starnav render` writes)."""
    out.mkdir(parents=True)
    for i in range(frames):
        (out / f"frame_{i:06d}.exr").write_bytes(b"old frame %d" % i)
        (out / f"frame_{i:06d}.png").write_bytes(b"old preview %d" % i)
        (out / f"frame_{i:06d}_quicklook.png").write_bytes(b"old quick look %d" % i)
    (out / "scenario.resolved.yaml").write_text("trajectory: {frames: 8}\n")
    (out / "notes.txt").write_text("the user's own file")
    return {p.name: p.read_bytes() for p in out.iterdir()}


def test_render_refuses_a_directory_holding_frames_of_another_run(app, tmp_path):
    sc = small_yaml(tmp_path / "sc.yaml")
    out = tmp_path / "r"
    before = _stale_render(out)
    line = assert_clean_error(run(app, ["render", sc, "--out", out]), str(out), "--overwrite")
    assert "8 frame" in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing touched


def test_render_overwrite_leaves_only_the_new_run(app, tmp_path):
    sc = small_yaml(tmp_path / "sc.yaml", trajectory={**SMALL["trajectory"], "frames": 1})
    out = tmp_path / "r"
    _stale_render(out)
    r = run(app, ["render", sc, "--out", out, "--overwrite"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frame_000000.exr", "frame_000000_quicklook.png", "notes.txt",
                     "scenario.resolved.yaml"]
    assert (out / "frame_000000.exr").read_bytes() != b"old frame 0"
    assert yaml.safe_load((out / "scenario.resolved.yaml").read_text())["trajectory"][
        "frames"] == 1
    assert (out / "notes.txt").read_text() == "the user's own file"  # not ours: left alone


# --------------------------------------------------------------------------- output.directory
@pytest.mark.parametrize("command", ["render", "dataset"])
def test_output_directory_is_the_default_output(app, tmp_path, command):
    sc = small_yaml(tmp_path / "sc.yaml", trajectory={**SMALL["trajectory"], "frames": 1})
    base = tmp_path / "runs"
    extra = ["--no-radiance"] if command == "dataset" else []
    r = run(app, [command, sc, "--set", f"output.directory={base}", *extra])
    assert r.exit_code == 0, r.output
    made = base / command
    assert (made / "scenario.resolved.yaml").is_file()
    if command == "render":
        assert (made / "frame_000000.exr").is_file()
    else:
        assert (made / "manifest.json").is_file() and (made / "frames" / "000000").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs", "sc.yaml"]


# --------------------------------------------------------------------------- a full disk
def test_a_full_disk_during_a_dataset_is_one_line_and_resume_is_byte_identical(
        app, tmp_path, monkeypatch, small_dataset):  # noqa: F811
    import errno

    import starnav.atomic as atomic
    from tests.dataset.conftest import tree_bytes, write_small_yaml

    sc = write_small_yaml(tmp_path / "sc.yaml", frames=4)
    out = tmp_path / "ds"
    real = atomic._sync_file
    calls = {"n": 0}

    def full_after_20(fd: int) -> None:  # the 21st file to land finds the disk full
        calls["n"] += 1
        if calls["n"] > 20:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as fsync reports it
        real(fd)

    monkeypatch.setattr(atomic, "_sync_file", full_after_20)
    args = ["dataset", sc, "--out", out, "--exposures", "1.5e-5,7.7e-3"]
    line = assert_clean_error(run(app, args), str(out / "frames"), "disk is full", "--resume")
    assert "\n" not in line
    frames = out / "frames"
    assert [p.name for p in frames.iterdir() if p.name.startswith(".")] == []  # no partial frame
    done = sorted(p.name for p in frames.iterdir())
    assert 0 < len(done) < 4  # some frames landed before the disk filled up
    assert [p for p in out.rglob(".*") if p.name != ".lock"] == []  # no temporary file at all
    monkeypatch.setattr(atomic, "_sync_file", real)
    r = run(app, [*args, "--resume"])
    assert r.exit_code == 0, r.output
    a, b = tree_bytes(small_dataset), tree_bytes(out)
    assert sorted(a) == sorted(b)
    assert [k for k in a if a[k] != b[k]] == []  # every frame file and the manifest


@pytest.mark.parametrize("command", ["render", "navigate", "expose"])
def test_a_full_disk_is_one_line_and_leaves_no_partial_file(app, tmp_path, monkeypatch,
                                                             command, small_dataset):  # noqa: F811
    """The first file to land finds the disk full (as fsync reports it on a real disk)."""
    import errno

    import numpy as np

    import starnav.atomic as atomic
    from starnav.radiance import RadianceImage, write_exr

    sc = small_yaml(tmp_path / "sc.yaml", trajectory={**SMALL["trajectory"], "frames": 1})
    exr = write_exr(RadianceImage(L=np.ones((16, 16), np.float32),
                                  Le=np.full((16, 16), 1e15, np.float32)), tmp_path / "in.exr")
    out = tmp_path / "out"
    args = {"render": ["render", sc, "--out", out],
            "navigate": ["navigate", small_dataset, "--out", out],
            "expose": ["expose", exr, "--out", out, "--set", "camera.width=16",
                       "--set", "camera.height=16"]}[command]

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic, "_sync_file", full)
    line = assert_clean_error(run(app, args), str(out), "disk is full")
    assert "\n" not in line
    left = [p for p in out.rglob("*") if p.is_file()] if out.exists() else []
    assert [p.name for p in left if p.name.startswith(".")] == []  # no temporary
    assert left == []  # the first file failed: nothing landed


def test_expose_into_an_unwritable_directory(app, tmp_path):
    import numpy as np

    from starnav.radiance import RadianceImage, write_exr

    exr = write_exr(RadianceImage(L=np.ones((16, 16), np.float32),
                                  Le=np.ones((16, 16), np.float32)), tmp_path / "in.exr")
    assert_clean_error(run(app, ["expose", exr, "--out", f"{UNWRITABLE}/x", "--set",
                                "camera.width=16", "--set", "camera.height=16"]), UNWRITABLE)


def test_render_refuses_an_albedo_the_model_cannot_reach(app, tmp_path):
    sc = small_yaml(tmp_path / "sc.yaml")
    out = tmp_path / "r"
    assert_clean_error(run(app, ["render", sc, "--out", out, "--set", "moon.albedo=5"]),
                       "moon.albedo")
    assert not out.exists()
