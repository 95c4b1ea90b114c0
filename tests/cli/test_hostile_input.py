"""Plausible but bad input, each line one case: the command exits with status 2 and one
``error:`` line naming the file or field (no traceback), before any work, with nothing written.
Scenario values are checked by the schema, so ``validate`` refuses what ``render`` refuses (each
scenario case runs through both)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tests.dataset.conftest import write_small_yaml

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

FLYBY = ["--set", "trajectory.source=flyby", "--set", "trajectory.frames=2"]
OEM = ["--set", "trajectory.source=oem", "--set", "trajectory.frames=4", "--set",
       "trajectory.cadence_s=3600", "--set", "trajectory.duration_days=0.15"]

#: Scenario cases: ``--set`` items (or a file name of ``_files``) -> what the error names.
SCENARIO_CASES = {
    "non-UTF-8 scenario": (["FILE:latin.yaml"], "UTF-8"),
    "scenario of 2 MB": (["FILE:big.yaml"], "at most 1048576 bytes"),
    "scenario is a directory": (["FILE:adir"], "is a directory"),
    "scenario is a device": (["FILE:/dev/null"], "not a regular file"),
    "unclosed YAML list": (["--set", "camera.width=[1,2"], "--set"),
    "YAML date that is none": (["--set", "trajectory.epoch=9999-99-99T00:00:00"], "--set"),
    "calendar date that is none": (["--set", "trajectory.epoch=9999-99-99T00:00:00 TDB"],
                                   "trajectory.epoch"),
    "focal length 1e300 mm": (["--set", "camera.focal_length_mm=1e300"],
                              "camera.focal_length_mm"),
    "infinite Sun azimuth": (["--set", "geometry.sun_azimuth_deg=.inf"],
                             "geometry.sun_azimuth_deg"),
    "NaN roll": (["--set", "geometry.roll_deg=.nan"], "geometry.roll_deg"),
    "exposure 1e30 s": (["--set", "detector.exposure_time_s=1e30"], "detector.exposure_time_s"),
    "RK4 step 1 ns": (["--set", "trajectory.step_s=1e-9"], "step_s"),
    "cadence 1 us": (["--set", "trajectory.cadence_s=1e-6"], "cadence_s"),
    "1e12 samples per pixel": (["--set", "render.spp=1000000000000"], "render.spp"),
    "principal point 1e9 px": (["--set", "camera.principal_point_px=[1e9,3]"],
                               "camera.principal_point_px"),
    "NaN principal point": (["--set", "camera.principal_point_px=[.nan,3]"],
                            "camera.principal_point_px"),
    "NaN distortion": (["--set", "camera.distortion=[.nan,0,0,0,0]"], "camera.distortion"),
    "distortion k1 1e10": (["--set", "camera.distortion=[1e10,0,0,0,0]"], "camera.distortion"),
    "a boolean width": (["--set", "camera.width=true"], "camera.width"),
    "Sun 1e-9 AU away": (["--set", "trajectory=null", "--set", "geometry.sun_distance_au=1e-9"],
                         "geometry.sun_distance_au"),
    "range 1e30 km": (["--set", "trajectory=null", "--set", "geometry.range_km=1e30"],
                      "geometry.range_km"),
    "-500 degC": (["--set", "detector.charge.dark_current.temperature_c=-500"],
                  "temperature_c"),
    "fly-by at the speed of light": (FLYBY + ["--set", "trajectory.flyby.v_inf_km_s=3e5"],
                                     "v_inf_km_s"),
    "star epoch -1e9 years": (["--set", "stars.epoch_jyear=-1e9"], "stars.epoch_jyear"),
    "a 20000-value list (not echoed whole)": (
        ["--set", "camera.distortion=[" + ",".join(["0.5"] * 20000) + "]"],
        "camera.distortion"),
}

#: Other commands: arguments -> what the error names.
COMMAND_CASES = {
    "non-UTF-8 bench": (["hil", "check", "FILE:latin.yaml"], "UTF-8"),
    "non-UTF-8 calibration": (["hil", "radiometric", "default", "--calibration",
                               "FILE:latin.yaml", "--out", "OUT"], "latin.yaml"),
    "collimator focal length 1e-12 mm": (["hil", "check", "default", "--set",
                                          "collimator.focal_length_mm=1e-12"],
                                         "collimator.focal_length_mm"),
    "OEM cadence 1 us": (["trajectory", "SC", "--out", "OUT/t.oem", "--cadence-s", "1e-6"],
                         "--cadence-s"),
    "exposure 1e30 s": (["expose", "FILE:in.exr", "--out", "OUT", "--exposure", "1e30"],
                        "detector.exposure_time_s"),
    "100000 workers": (["dataset", "SC", "--out", "OUT", "--workers", "100000"], "--workers"),
    "200 sweep workers": (["sweep", "SC", "--out", "OUT", "--grid", "seed=1,2", "--workers",
                           "200"], "--workers"),
    "1e8 Monte Carlo runs": (["navigate", "SC", "--out", "OUT", "--runs", "100000000"],
                             "navigation.runs"),
    "1e8 sweep runs": (["sweep", "SC", "--out", "OUT", "--grid", "seed=1,2", "--runs",
                        "100000000"], "navigation.runs"),
    "port 99999": (["dataset", "SC", "--out", "OUT", "--scheduler", "tcp://127.0.0.1:99999"],
                   "port"),
    "a mesh type nobody writes": (["dem", "mesh", "SC", "--out", "OUT/mesh.xyz"], "--out"),
    "a geometry axis on a trajectory": (["sweep", "SC", "--out", "OUT", "--grid",
                                         "geometry.range_km=1,2", "--workers", "0"],
                                        "geometry.range_km"),
    "a radiance image that is a device": (["expose", "FILE:/dev/null", "--out", "OUT"],
                                          "not a regular file"),
    "an OEM with a state that jumped": (["validate", "SC", *OEM, "--set",
                                         "trajectory.oem_path=FILE:jump.oem"],
                                        "2025-01-01T02:00:00"),
    "an OEM that is a directory": (["trajectory", "SC", "--out", "OUT/t.oem", "--set",
                                    "trajectory.source=oem", "--set",
                                    "trajectory.oem_path=FILE:adir"], "is a directory"),
}


def straight_oem(jump: bool) -> str:
    """A Moon-centred OEM: 60 000 km from the Moon, 1 km/s along y, a state an hour; with
    ``jump`` the third state is on the Moon's far side (still outside it)."""
    lines = ["CCSDS_OEM_VERS = 2.0", "CREATION_DATE = 2025-01-01T00:00:00",
             "ORIGINATOR = starnav tests", "", "META_START", "OBJECT_NAME = SC",
             "OBJECT_ID = 1", "CENTER_NAME = MOON", "REF_FRAME = ICRF", "TIME_SYSTEM = TDB",
             "START_TIME = 2025-01-01T00:00:00", "STOP_TIME = 2025-01-01T04:00:00",
             "META_STOP"]
    for k in range(5):
        x, y = (-60000.0, 0.0) if jump and k == 2 else (60000.0, 3600.0 * k)
        lines.append(f"2025-01-01T{k:02d}:00:00 {x} {y} 0.0 0.0 1.0 0.0")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def app():
    from starnav.cli.main import app as main_app

    return main_app


def _files(tmp: Path) -> dict[str, str]:
    import numpy as np

    from starnav.radiance import RadianceImage, write_exr

    (tmp / "latin.yaml").write_bytes(b"seed: 3\n# caf\xe9\n")
    (tmp / "big.yaml").write_text("seed: 3\n" + "# padding\n" * 220_000)
    (tmp / "adir").mkdir()
    (tmp / "jump.oem").write_text(straight_oem(jump=True))
    (tmp / "straight.oem").write_text(straight_oem(jump=False))
    write_exr(RadianceImage(L=np.ones((16, 16), np.float32), Le=np.ones((16, 16), np.float32)),
              tmp / "in.exr")
    return {"SC": str(write_small_yaml(tmp / "sc.yaml", frames=2)), "OUT": str(tmp / "out")}


def _args(args: list[str], tmp: Path, names: dict[str, str]) -> list[str]:
    out = []
    for a in args:
        if "FILE:" in a:
            pre, _, f = a.partition("FILE:")
            a = pre + (f if f.startswith("/") else str(tmp / f))
        head, _, rest = a.partition("/")
        out.append(names[head] + (f"/{rest}" if rest else "") if head in names else a)
    return out


def _check(r, named: str) -> None:
    assert r.exit_code == 2, (r.exit_code, r.output, repr(r.exception))
    assert "Traceback" not in r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and named in lines[0], r.output
    assert len(lines[0]) < 600  # one readable line, not the input echoed back


@pytest.mark.parametrize("command", ["validate", "render"])
@pytest.mark.parametrize("case", list(SCENARIO_CASES))
def test_bad_scenario_values_are_refused_alike_by_validate_and_render(app, tmp_path, case,
                                                                      command):
    names = _files(tmp_path)
    items, named = SCENARIO_CASES[case]
    if items[0].startswith("FILE:"):
        args = [command, *_args(items, tmp_path, names)]
    else:
        args = [command, names["SC"], *items]
    if command == "render":
        args += ["--out", names["OUT"]]
    before = sorted(p.name for p in tmp_path.iterdir())
    _check(CliRunner().invoke(app, args, env={"COLUMNS": "50"}), named)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


@pytest.mark.parametrize("case", list(COMMAND_CASES))
def test_bad_command_input_is_one_line_before_any_work(app, tmp_path, case):
    names = _files(tmp_path)
    args, named = COMMAND_CASES[case]
    before = sorted(p.name for p in tmp_path.iterdir())
    _check(CliRunner().invoke(app, _args(args, tmp_path, names), env={"COLUMNS": "50"}), named)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_a_fly_by_with_no_tracked_feature_prints_its_summary():
    """``feature_error_rms_px`` is None when no feature was tracked (the metrics' JSON form of
    NaN): the summary says so instead of failing after the outputs are written."""
    import typer
    from typer.testing import CliRunner as _Runner

    from starnav.cli.navigate import _echo_flyby

    cmd = typer.Typer()

    @cmd.command()
    def show() -> None:
        _echo_flyby({"ca_position_error_m": 12.5, "ca_position_error_pct_range": 0.5,
                     "ca_range_m": 2500.0, "feature_error_rms_px": None,
                     "monte_carlo": {"runs": 2, "nees_mean": None, "nees_band": [0.5, 1.7],
                                     "verdict": "inconclusive"}}, Path("out"))

    r = _Runner().invoke(cmd, [])
    assert r.exit_code == 0, r.output
    assert "no feature tracked" in r.output and "mean NEES -" in r.output


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 truncated"])
def test_an_empty_or_truncated_trajectory_cache_is_rebuilt_not_fatal(tmp_path, content):
    from starnav.errors import DataFileError
    from starnav.scenes.trajectory import _load_npz, load_cached_arc

    p = tmp_path / "halo-x.npz"
    p.write_bytes(content)
    assert _load_npz(p) is None  # the builder then makes the arc again and replaces the file
    with pytest.raises(DataFileError, match="unreadable"):
        load_cached_arc(p)


def test_render_on_a_full_disk_is_one_line_and_leaves_no_directory(app, tmp_path,
                                                                   monkeypatch):
    """OpenEXR reports a write that finds the disk full as a RuntimeError: one line naming the
    frame and the hint, and the output directory the render created is gone again."""
    import OpenEXR

    class FullDisk:
        def __init__(self, *args, **kwargs) -> None:
            """Takes OpenEXR.File's arguments; the write below is what fails."""

        def __enter__(self) -> FullDisk:
            return self

        def __exit__(self, *exc) -> None:
            return None

        def write(self, path: str) -> None:
            raise RuntimeError(f"Cannot write image file \"{path}\". No space left on device")

    names = _files(tmp_path)
    monkeypatch.setattr(OpenEXR, "File", FullDisk)
    r = CliRunner().invoke(app, ["render", names["SC"], "--out", names["OUT"], "--set",
                                 "trajectory.frames=1"], env={"COLUMNS": "50"})
    _check(r, "frame_000000.exr")
    assert "disk is full" in r.output
    assert not Path(names["OUT"]).exists()


def test_a_continuous_oem_passes_the_jump_check(app, tmp_path):
    """The control of the jump case: the same OEM without the jump validates."""
    names = _files(tmp_path)
    r = CliRunner().invoke(app, ["validate", names["SC"], *OEM, "--set",
                                 f"trajectory.oem_path={tmp_path / 'straight.oem'}"])
    assert r.exit_code == 0, r.output
