"""One navigation run (issue 14): a dataset navigated by ``starnav navigate`` and the same
scenario run in memory by ``starnav sweep`` make the same frames (one ``simulate.Simulator``),
draw the same RANSAC and initial-error streams (``starnav.seeding``) and filter them the same
way: the sweep's run 0 equals the dataset's navigation, number for number."""

from __future__ import annotations

import json

import pytest

from .conftest import small_scenario


def test_navigate_on_a_dataset_equals_the_sweeps_run_0(small_dataset, tmp_path):
    from starnav.batch import run_sweep
    from starnav.dataset import open as open_dataset
    from starnav.navigation.report import navigate_dataset

    ds = open_dataset(small_dataset).select(1.5e-5)
    nav = navigate_dataset(ds, tmp_path / "nav", config=ds.scenario().navigation,
                           plots=False, measure_memory=False)
    res = run_sweep(small_scenario(), ["detector.exposure_time_s=1.5e-5"], tmp_path / "sweep",
                    runs=1, workers=0, figures=False)
    row = res.rows[0]
    assert nav["fixes"] == row["fixes"] == 4
    for key in ("final_position_error_m", "final_velocity_error_m_s", "rms_position_error_m",
                "final_position_3sigma_m", "nees_mean", "final_position_error_pct_range"):
        assert nav[key] == pytest.approx(row[key], rel=1e-9, abs=1e-9), key
    on_disk = json.loads((tmp_path / "nav" / "metrics.json").read_text())
    assert on_disk["final_position_error_m"] == pytest.approx(row["final_position_error_m"],
                                                               rel=1e-9)
