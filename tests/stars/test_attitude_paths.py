"""Issue 17, coupling: ``navigation.attitude.source: stars`` through the user-facing paths (a
dataset navigated from the command line, the sweep, the Monte Carlo tasks) gives the numbers
of the in-memory run, through the one code path
(:meth:`starnav.simulate.attitude.StarAttitudeTracker.advance`); the exposure study's attitude
side from the real centroid / identification chain on rendered frames.

The scenario: the demo's arc, 3 frames (1 h) at 1024 px and 2 spp, the 7.7 ms exposure with
its overrides, star acquisitions at 200 ms every 2nd frame (frames 0 and 2), the navigation
frame's own stars at frame 1."""

from __future__ import annotations

import csv
import json
import math

import pytest
from typer.testing import CliRunner

from starnav.batch.attitude_study import attitude_comparison, exposure_scenario, reduced_demo
from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES, get_preset
from starnav.batch.sweep import run_sweep
from starnav.batch.tasks import expose_task
from starnav.cli.main import app
from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.dataset import DatasetOptions, generate
from starnav.dataset import open as open_dataset
from starnav.errors import ConfigError
from starnav.simulate.attitude import uses_star_attitude

T_NAV = 7.7e-3
#: The assumed attitude knowledge of the demo (pointing.knowledge_sigma): roll 1-sigma [arcsec].
ASSUMED_ROLL_SIGMA_ARCSEC = 40.0
REL = 1e-9


@pytest.fixture(scope="module")
def stars_scenario():
    base = reduced_demo(frames=3, size_px=1024, spp=2)
    return exposure_scenario(base, T_NAV, DEMO_EXPOSURE_OVERRIDES, {"schedule_every": 2})


@pytest.fixture(scope="module")
def in_memory(stars_scenario):
    """The attitude study's run 0 (assumed and stars) on the scenario's frames."""
    return attitude_comparison(scenario_to_dict(stars_scenario), exposures_s=(T_NAV,),
                               exposure_overrides=(), attitude={"schedule_every": 2})


def _case(res, name):
    return next(c for c in res["cases"] if c["case"] == name)


@pytest.mark.slow
def test_navigate_dataset_with_star_attitude_equals_the_in_memory_run(
        stars_scenario, in_memory, tmp_path_factory):
    """A dataset made with ``source: stars`` records the star acquisitions of frames 0 and 2
    (``stars_dn.png``, none at frame 1); ``starnav navigate DATASET`` solves them and the
    frame's own DN through the tracker and gives the in-memory run's fixes, final error and
    NEES (same numbers to 1e-9), and each frame's attitude source, error and sigma
    (``attitude.json``); the solved attitude changed the result (it differs from the
    assumed case). ``--runs 2``: run 0 of the Monte Carlo is the same run."""
    root = tmp_path_factory.mktemp("ds")
    generate(stars_scenario, root / "ds", options=DatasetOptions(exposures_s=(T_NAV,)))
    ds = open_dataset(root / "ds")
    assert [f.star_dn() is not None for f in ds] == [True, False, True]
    r = CliRunner().invoke(app, ["navigate", str(root / "ds"), "--out", str(root / "nav"),
                                 "--no-plots"], env={"COLUMNS": "50"})
    assert r.exit_code == 0, r.output
    assert "attitude from the stars: star-frame 2, navigation-frame 1 frames" in r.output
    m = json.loads((root / "nav" / "metrics.json").read_text())
    ref = _case(in_memory, "stars")["navigation"]
    assert m["fixes"] == ref["fixes"] == 3
    assert m["final_position_error_m"] == pytest.approx(ref["final_position_error_m"], rel=REL)
    assert m["nees_mean"] == pytest.approx(ref["nees_mean"], rel=REL)
    assumed = _case(in_memory, "assumed")["navigation"]
    assert not math.isclose(ref["final_position_error_m"], assumed["final_position_error_m"],
                            rel_tol=1e-6)
    rows = json.loads((root / "nav" / "attitude.json").read_text())
    mem = in_memory["records"][f"{T_NAV:.6g}"]
    assert [x["source"] for x in rows] == [x["source"] for x in mem] == \
        ["star-frame", "navigation-frame", "star-frame"]
    for a, b in zip(rows, mem, strict=True):
        assert a["error_roll_arcsec"] == pytest.approx(b["error_roll_arcsec"], rel=REL)
        assert a["sigma_arcsec_xyz"] == pytest.approx(b["sigma_arcsec_xyz"], rel=REL)
    # --runs: the Monte Carlo re-exposes the star acquisitions per run; run 0 is the dataset's
    r = CliRunner().invoke(app, ["navigate", str(root / "ds"), "--out", str(root / "mc"),
                                 "--runs", "2", "--no-plots"], env={"COLUMNS": "50"})
    assert r.exit_code == 0, r.output
    with open(root / "mc" / "runs.csv", newline="") as fh:
        runs = list(csv.DictReader(fh))
    assert [x["attitude_source"] for x in runs] == ["stars", "stars"]
    assert float(runs[0]["final_position_error_m"]) == pytest.approx(
        ref["final_position_error_m"], rel=REL)
    assert float(runs[1]["final_position_error_m"]) != pytest.approx(
        ref["final_position_error_m"], rel=1e-6)


def test_sweep_with_star_attitude_beats_the_assumed_roll_at_77ms(stars_scenario, in_memory,
                                                                 tmp_path):
    """A sweep over ``navigation.attitude.source`` at 7.7 ms: the assumed point keeps the
    demo's 40 arcsec roll sigma and solves nothing; the stars point solves every frame (two
    200 ms star acquisitions, the 7.7 ms frame's own stars) with a roll 1-sigma and RMS roll
    error below half the assumed sigma; each point's navigation equals the in-memory run's
    case (one code path)."""
    res = run_sweep(stars_scenario, ["navigation.attitude.source=assumed,stars"],
                    tmp_path / "sw", runs=1, workers=0, figures=False)
    rows = {r["attitude_source"]: r for r in res.rows}
    a, s = rows["assumed"], rows["stars"]
    assert a["attitude_sigma_roll_arcsec"] == pytest.approx(ASSUMED_ROLL_SIGMA_ARCSEC)
    assert a["attitude_solved_fraction"] == 0.0
    assert s["attitude_solved_fraction"] == 1.0
    assert s["attitude_sigma_roll_arcsec"] < ASSUMED_ROLL_SIGMA_ARCSEC / 2
    assert s["attitude_error_roll_rms_arcsec"] < ASSUMED_ROLL_SIGMA_ARCSEC / 2
    assert s["attitude_error_cross_rms_arcsec"] < a["attitude_sigma_cross_arcsec"]
    for row, case in ((a, "assumed"), (s, "stars")):
        ref = _case(in_memory, case)
        assert row["final_position_error_m"] == pytest.approx(
            ref["navigation"]["final_position_error_m"], rel=REL)
        assert row["attitude_error_roll_rms_arcsec"] == pytest.approx(
            ref["attitude"]["error_roll_rms_arcsec"], rel=REL)
    assert "| stars |" in res.paths["report"].read_text()


@pytest.mark.slow
def test_exposure_study_reports_the_attitude_side(tmp_path):
    """The exposure study's grid at 0.015 ms and 200 ms (2 frames, 1024 px, 2 spp): at
    0.015 ms fewer than the 4 candidates a solve needs (noise peaks at most), none
    identified, no attitude; at 200 ms every frame solves
    lost in space from its own stars (Moon blob and ghosts excluded) with a roll 1-sigma
    < 20 arcsec and errors within 4 sigma; the report's attitude table and figure say so."""
    p = get_preset("exposure-study")
    assert p.scenario()["stars"]["enabled"] is True
    base = reduced_demo(frames=2, size_px=1024, spp=2)
    base["stars"] = {"enabled": True}
    res = run_sweep(base, ["detector.exposure_time_s+detector.readout.segments.thresholds_dn="
                           "[1.5e-5,[200]],[0.2,[2048]]"], tmp_path / "study", runs=1,
                    workers=0, figures=True)
    rows = {r["exposure_time_s"]: r for r in res.rows}
    short, long_ = rows[1.5e-5], rows[0.2]
    assert short["stars_detected_median"] < 4 and short["stars_identified_median"] == 0
    assert short["frame_attitude_solved_fraction"] == 0.0
    assert math.isnan(short["frame_attitude_sigma_roll_arcsec"])
    assert long_["frame_attitude_solved_fraction"] == 1.0
    assert long_["stars_identified_median"] >= 20
    assert long_["frame_attitude_sigma_roll_arcsec"] < 20.0
    assert long_["frame_attitude_error_roll_rms_arcsec"] < \
        4 * long_["frame_attitude_sigma_roll_arcsec"]
    assert long_["frame_attitude_error_cross_rms_arcsec"] < \
        4 * long_["frame_attitude_sigma_cross_arcsec"]
    report = res.paths["report"].read_text()
    assert "## Attitude (median over runs)" in report
    line = {float(x.split("|")[2]): x for x in report.splitlines()
            if x.startswith("| ") and x.count("|") == 11 and x.split("|")[2].strip()
            .replace(".", "").isdigit()}
    assert "| 0 | no |" in line[0.015] and "| yes |" in line[200.0]
    assert (tmp_path / "study" / "figures" / "attitude_vs_exposure.png").stat().st_size > 0
    assert "attitude_vs_exposure.png" in report


def test_star_attitude_is_refused_clearly_where_it_cannot_work(stars_scenario, tmp_path):
    """``source: stars`` without the stars drawn: the sweep and the dataset say so before any
    work; a per-frame expose task refuses a stars scenario (its frames depend on the ones
    before); a dataset made with ``source: assumed`` cannot be navigated with ``stars``:
    the star frames lack their acquisition, named."""
    d = scenario_to_dict(stars_scenario)
    d["stars"]["enabled"] = False
    off = scenario_from_dict(d)
    with pytest.raises(ConfigError, match="stars.enabled"):
        run_sweep(off, ["seed=1"], tmp_path / "sw", runs=1, workers=0)
    assert not (tmp_path / "sw").exists()
    with pytest.raises(ConfigError, match="stars.enabled"):
        generate(off, tmp_path / "ds0", options=DatasetOptions(exposures_s=(T_NAV,)))
    assert not (tmp_path / "ds0").exists()
    with pytest.raises(ConfigError, match="expose_sequence_task"):
        expose_task(scenario_to_dict(stars_scenario), None, 1, "none", 1.0)
    assert uses_star_attitude(stars_scenario)
    d = scenario_to_dict(stars_scenario)
    d["navigation"]["attitude"]["source"] = "assumed"
    generate(scenario_from_dict(d), tmp_path / "ds", options=DatasetOptions(exposures_s=(T_NAV,)))
    r = CliRunner().invoke(app, ["navigate", str(tmp_path / "ds"), "--out", str(tmp_path / "n"),
                                 "--set", "navigation.attitude.source=stars", "--no-plots"],
                           env={"COLUMNS": "50"})
    assert r.exit_code == 2
    assert "star frames [0, 2] have no stars_dn.png" in r.output
