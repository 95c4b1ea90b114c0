"""The fly-by sweep on rendered frames (issue 16): the closed loop at every point of a grid
over v_inf, CA distance and phase, the table and the figure, and ``starnav navigate
SCENARIO.yaml --sweep``.

Tiny grid for the default suite: 1 x 1 x 2 (phase 40 and 70 deg), Itokawa at 128 x 128 px,
15 mm (~45 px across at 5 km), 3 frames 0.2 s apart about CA, 2 runs per point (~1 s a point).
"""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.batch.flyby import flyby_closed_loop
from starnav.batch.flyby_sweep import flyby_rendered_sweep, parse_sweep_axes, write_flyby_sweep
from starnav.errors import ConfigError
from starnav.navigation.metrics import chi2_band
from starnav.simulate import Simulator
from tests.flyby_scenarios import tiny_flyby

PHASES = [40.0, 70.0]




@pytest.fixture(scope="module")
def rows():
    return flyby_rendered_sweep(tiny_flyby(), {"phase_at_ca_deg": PHASES}, runs=2)


def test_one_row_per_point_with_its_own_closed_loop(rows):
    """Axes not given keep the base's value; each row is the closed loop of its point's
    scenario (the same seeded runs as a direct call); NEES band of 2 runs' effective samples."""
    assert [(r["v_inf_km_s"], r["closest_approach_km"], r["phase_at_ca_deg"]) for r in rows] \
        == [(0.5, 5.0, p) for p in PHASES]
    direct = flyby_closed_loop(Simulator(tiny_flyby(PHASES[1])), 2)
    pct = [r.metrics.ca_position_error_pct_range for r in direct.runs]
    assert rows[1]["ca_error_pct_range_median"] == pytest.approx(np.median(pct), rel=1e-12)
    assert rows[1]["ca_error_pct_range_max"] == pytest.approx(max(pct), rel=1e-12)
    assert rows[1]["nees_mean"] == pytest.approx(direct.summary["nees_mean"], rel=1e-12)
    assert rows[1]["verdict"] == direct.summary["verdict"]
    lo, hi = chi2_band(6, 2, 0.99)
    for r in rows:
        assert r["ca_range_m"] == pytest.approx(5e3, rel=1e-9)
        # the band of R K / tau effective samples: inside that of a 2-run mean
        assert lo <= r["nees_band_lo"] <= r["nees_band_hi"] <= hi
        assert r["median_mean_tracks_per_frame"] > 0
    # a different phase is a different lit silhouette: different errors
    assert rows[0]["ca_error_pct_range_median"] != rows[1]["ca_error_pct_range_median"]


def test_table_and_figure(rows, tmp_path):
    paths = write_flyby_sweep(rows, tmp_path)
    with open(paths["csv"], newline="") as f:
        got = list(csv.DictReader(f))
    assert [float(g["phase_at_ca_deg"]) for g in got] == PHASES
    assert float(got[0]["nees_mean"]) == pytest.approx(rows[0]["nees_mean"], rel=1e-12)
    md = paths["table"].read_text()
    assert "| v_inf [km/s] | CA [km] | phase [deg] | CA error median [% range]" in md
    assert f"| 0.5 | 5 | 70 | {rows[1]['ca_error_pct_range_median']:.3f} |" in md
    assert "![sweep](sweep.png)" in md
    assert paths["figure"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_axes_are_refused_before_rendering():
    with pytest.raises(ConfigError, match="--sweep"):
        parse_sweep_axes(["inclination_deg=1,2"])
    with pytest.raises(ConfigError, match="numbers"):
        parse_sweep_axes(["v_inf_km_s=fast"])
    assert parse_sweep_axes(["trajectory.flyby.v_inf_km_s=0.4, 0.6"]) == {
        "v_inf_km_s": [0.4, 0.6]}
    with pytest.raises(ConfigError, match="sweep point.*phase_at_ca_deg"):
        flyby_rendered_sweep(tiny_flyby(), {"phase_at_ca_deg": [40.0, 200.0]}, runs=1)


def test_cli_navigate_sweep(tmp_path):
    """``starnav navigate SCENARIO.yaml --sweep ...`` writes the table; a bad axis or a
    dataset with --sweep is one error line, exit 2."""
    import yaml
    from typer.testing import CliRunner

    from starnav.cli.main import app
    from starnav.config import scenario_to_dict

    env = {"COLUMNS": "50"}
    sc = tmp_path / "fb.yaml"
    sc.write_text(yaml.safe_dump(scenario_to_dict(tiny_flyby())))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["navigate", str(sc), "--out", str(out), "--runs", "1",
                                   "--sweep", "v_inf_km_s=0.6", "--no-plots"], env=env)
    assert res.exit_code == 0, res.output
    got = list(csv.DictReader(open(out / "sweep.csv", newline="")))
    assert len(got) == 1 and float(got[0]["v_inf_km_s"]) == 0.6
    assert not (out / "sweep.png").exists()
    bad = CliRunner().invoke(app, ["navigate", str(sc), "--out", str(out), "--overwrite",
                                   "--sweep", "spin=1"], env=env)
    assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1
    notyaml = tmp_path / "frames"
    notyaml.mkdir()
    ds = CliRunner().invoke(app, ["navigate", str(notyaml), "--out", str(out), "--overwrite",
                                  "--sweep", "v_inf_km_s=1"], env=env)
    assert ds.exit_code == 2 and "--sweep" in ds.output


def test_cli_sweep_of_a_flyby_runs_the_points_on_the_batch_runner(rows, tmp_path):
    """``starnav sweep FLYBY.yaml --grid phase_at_ca_deg=40,70 --runs 2 --workers 0`` runs
    one batch task per point (:func:`starnav.batch.flyby_sweep.flyby_sweep_row`, the function
    the in-process sweep maps): its sweep.csv equals the in-process rows, with the tracker's
    per-frame stage costs; sweep.md, sweep.png, sweep.json and the resolved scenario are
    written; a second run into the same directory needs --overwrite; a bad axis is one error
    line, exit 2, nothing written."""
    import json

    import yaml
    from typer.testing import CliRunner

    from starnav.cli.main import app
    from starnav.config import scenario_to_dict

    env = {"COLUMNS": "50"}
    sc = tmp_path / "fb.yaml"
    sc.write_text(yaml.safe_dump(scenario_to_dict(tiny_flyby())))
    out = tmp_path / "sw"
    args = ["sweep", str(sc), "--grid", "phase_at_ca_deg=40,70", "--runs", "2",
            "--workers", "0", "--out", str(out)]
    res = CliRunner().invoke(app, args, env=env)
    assert res.exit_code == 0, res.output
    got = list(csv.DictReader(open(out / "sweep.csv", newline="")))
    assert [float(g["phase_at_ca_deg"]) for g in got] == PHASES
    for g, r in zip(got, rows, strict=True):
        assert float(g["nees_mean"]) == pytest.approx(r["nees_mean"], rel=1e-12)
        assert float(g["ca_error_pct_range_median"]) == pytest.approx(
            r["ca_error_pct_range_median"], rel=1e-12)
        for stage in ("detector", "front_end", "filter"):
            assert float(g[f"{stage}_s_per_frame"]) > 0
    info = json.loads((out / "sweep.json").read_text())
    assert info["kind"] == "flyby" and info["runs"] == 2 and info["points"] == 2
    assert info["grid"] == [{"key": "trajectory.flyby.phase_at_ca_deg", "values": PHASES}]
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| 0.5 | 5 | 70 |" in (out / "sweep.md").read_text()
    assert (out / "scenario.resolved.yaml").is_file()
    again = CliRunner().invoke(app, args, env=env)
    assert again.exit_code == 2 and "--overwrite" in again.output
    bad = CliRunner().invoke(app, ["sweep", str(sc), "--grid", "spin_deg=1,2", "--workers",
                                   "0", "--out", str(tmp_path / "sw2")], env=env)
    assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1
    assert "--grid" in bad.output and "v_inf_km_s" in bad.output and not (tmp_path / "sw2").exists()
