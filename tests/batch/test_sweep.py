"""Sweeps end to end: outputs, shared renders, determinism across workers, a dying worker,
the exposure-study preset on a reduced camera, and bad input."""

from __future__ import annotations

import json
import os
import signal
import socket
import time

import pytest

from starnav.batch import run_sweep
from starnav.batch.cluster import ClusterError
from starnav.batch.presets import PAPER_EXPOSURES_S, get_preset
from starnav.batch.table import COLUMNS, read_table
from starnav.errors import ConfigError, DataFileError

from .conftest import deterministic, small_scenario

GRID = ["detector.exposure_time_s=1.5e-5,7.7e-3", "moon.albedo_scale=1,0.5"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The in-process sweep every other run is compared with."""
    out = tmp_path_factory.mktemp("sweep") / "ref"
    return run_sweep(small_scenario(), GRID, out, runs=2, workers=0)


def test_outputs_and_shared_renders(reference):
    res = reference
    assert len(res.points) == 4 and len(res.rows) == 8
    assert [(r["point"], r["run"]) for r in res.rows] == [(p, r) for p in range(4)
                                                          for r in range(2)]
    # exposure and a Lambert albedo scale act after the renderer: one render per frame
    assert res.render_tasks == 5 and res.expose_tasks == 20 and res.filter_tasks == 4
    names = {c.name for c in COLUMNS}
    assert names <= set(res.columns) and {"detector.exposure_time_s",
                                           "moon.albedo_scale"} <= set(res.columns)
    rows = read_table(res.paths["parquet"])
    assert deterministic(rows) == deterministic(res.rows)
    for k in ("csv", "report", "sweep", "limb_error_pdf", "error_vs_exposure",
              "error_vs_time_000"):
        assert res.paths[k].is_file(), k
    info = json.loads(res.paths["sweep"].read_text())
    assert info["tasks"] == {"render": 5, "expose": 20, "filter": 4}
    report = res.paths["report"].read_text()
    assert all(p.label in report for p in res.points)
    assert "Comparison with the paper" in report and "7.7 ms (HIL, fictitious)" in report
    assert not any(p.name.startswith(".") for p in res.out.parent.iterdir())  # no staging left
    # physics sanity: 7.7 ms saturates, 0.015 ms does not; the saturated limb lies outside
    by = {(r["exposure_time_s"], r["albedo_scale"], r["run"]): r for r in res.rows}
    assert by[(1.5e-5, 1.0, 0)]["saturated_pixels_median"] == 0
    assert by[(7.7e-3, 1.0, 0)]["saturated_pixels_median"] > 100
    assert abs(by[(1.5e-5, 1.0, 0)]["limb_bias_px"]) < 0.5
    assert by[(7.7e-3, 1.0, 0)]["limb_bias_px"] > 1.0


def test_albedo_scale_is_the_same_as_exposure(reference, tmp_path):
    """Albedo-exposure equivalence (the paper's HIL scaling): albedo x 0.5 at 2 t collects
    what albedo x 1 collects at t (dark current aside), so the limb is the same."""
    res = run_sweep(small_scenario(frames=3), ["detector.exposure_time_s+moon.albedo_scale="
                                               "[1e-5,1],[2e-5,0.5]"], tmp_path / "eq", runs=1,
                    workers=0, figures=False)
    a, b = res.rows
    assert res.render_tasks == 3
    assert abs(a["limb_bias_px"] - b["limb_bias_px"]) < 0.05
    assert a["limb_points"] == pytest.approx(b["limb_points"], rel=0.05)


def test_two_workers_give_the_same_table(reference, tmp_path):
    res = run_sweep(small_scenario(), GRID, tmp_path / "two", runs=2, workers=2, figures=False)
    assert res.runner.startswith("local cluster, 2")
    assert deterministic(res.rows) == deterministic(reference.rows)


@pytest.mark.slow
def test_a_worker_that_dies_mid_sweep(reference, tmp_path):
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        pids = client.run(os.getpid)
        killed: list[int] = []

        def progress(done: int, total: int) -> None:
            if done >= 3 and not killed and done < total - 5:
                pid = sorted(pids.values())[0]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

        res = run_sweep(small_scenario(), GRID, tmp_path / "dies", runs=2,
                        scheduler=cluster.scheduler_address, progress=progress, figures=False)
        assert killed, "no worker was killed"
        assert set(client.run(os.getpid).values()) != set(pids.values())  # a new one
    assert deterministic(res.rows) == deterministic(reference.rows)


@pytest.mark.slow
def test_exposure_study_preset_on_a_reduced_camera(tmp_path):
    p = get_preset("exposure-study")
    res = run_sweep(p.scenario(), p.grid, tmp_path / "study", runs=1, workers=0,
                    overrides=["camera.width=256", "camera.height=256",
                               "camera.focal_length_mm=25", "trajectory.frames=3",
                               "render.spp=4"])
    rows = {r["exposure_time_s"]: r for r in res.rows}
    assert sorted(rows) == sorted(PAPER_EXPOSURES_S)
    # the paper's ordering: 200 ms unusable, 7.7 ms biased by saturation, the short
    # exposures at pixel level
    assert rows[0.2]["limb_bias_px"] > 10 * max(abs(rows[1.5e-5]["limb_bias_px"]), 0.1)
    assert rows[7.7e-3]["limb_bias_px"] > rows[1.8e-4]["limb_bias_px"]
    assert abs(rows[1.5e-5]["limb_bias_px"]) < 1.0
    report = res.paths["report"].read_text()
    for case in ("200 ms (unmodified tracker)", "7.7 ms (HIL, fictitious)",
                 "0.18 ms (firmware limit)", "0.015 ms (HIL, well exposed)"):
        assert case in report


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(("kw", "err", "match"), [
    ({"grid": ["detector.exposure_time=1e-3"]}, ConfigError, "did you mean"),
    ({"grid": []}, ConfigError, "at least one --grid"),
    ({"grid": ["detector.exposure_time_s="]}, ConfigError, "empty"),
    ({"grid": ["detector.exposure_time_s=1e-3,abc"]}, ConfigError, "point 1"),
    ({"runs": 0}, ConfigError, "runs"),
    ({"scheduler": "localhost"}, ConfigError, "tcp://"),
    ({"windows": "both"}, Exception, "second"),
])
def test_bad_input_fails_fast_and_writes_nothing(tmp_path, kw, err, match):
    out = tmp_path / "out"
    args = {"grid": ["detector.exposure_time_s=1e-3"], "runs": 1, "workers": 0} | kw
    t0 = time.monotonic()
    with pytest.raises(err, match=match):
        run_sweep(small_scenario(frames=2), args.pop("grid"), out, **args)
    assert time.monotonic() - t0 < 10.0
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_unwritable_or_occupied_output(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(DataFileError, match="not a directory"):
        run_sweep(small_scenario(frames=2), ["seed=1"], f / "out", workers=0)
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "mine.txt").write_text("keep")
    with pytest.raises(DataFileError, match="not empty"):
        run_sweep(small_scenario(frames=2), ["seed=1"], busy, workers=0)
    with pytest.raises(DataFileError, match="no previous sweep"):
        run_sweep(small_scenario(frames=2), ["seed=1"], busy, workers=0, overwrite=True)
    assert [p.name for p in busy.iterdir()] == ["mine.txt"]


def test_a_scheduler_that_does_not_answer(tmp_path):
    out = tmp_path / "out"
    t0 = time.monotonic()
    with pytest.raises(ClusterError, match="does not answer"):
        run_sweep(small_scenario(frames=2), ["seed=1"], out,
                  scheduler=f"tcp://127.0.0.1:{_free_port()}", connect_timeout_s=2.0)
    assert time.monotonic() - t0 < 15.0
    assert not out.exists()


def test_sweep_cli(tmp_path):
    from typer.testing import CliRunner

    from starnav.cli.main import app  # the real command line, with every part wired in

    r = CliRunner().invoke(app, ["sweep", "--grid", "detector.exposure_tim=1", "--out",
                                 str(tmp_path / "x"), "--workers", "0"])
    assert r.exit_code == 2 and "did you mean detector.exposure_time_s" in r.output
    r = CliRunner().invoke(app, ["sweep", "--preset", "nope", "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "exposure-study" in r.output
    assert not (tmp_path / "x").exists()
