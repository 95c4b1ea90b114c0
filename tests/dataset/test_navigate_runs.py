"""``starnav navigate DATASET --runs N``: a Monte Carlo over detector noise (every frame's
radiance re-exposed), attitude knowledge and initial error, with the consistency verdict
(issue 13)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2


@pytest.fixture(scope="module")
def runs3(small_dataset):
    from starnav.batch.montecarlo import navigate_runs
    from starnav.dataset import open as open_dataset

    return navigate_runs(open_dataset(small_dataset), 3)


def test_runs_are_reproducible_independent_realisations(small_dataset, runs3):
    """The same runs twice are identical (seeded streams); the runs differ from each other;
    the time-averaged band is chi2.ppf([0.005, 0.995], 6 n) / n for n = R K / tau effective
    samples (tau in [1, K]); each epoch's band is that of a 3-run mean."""
    from starnav.batch.montecarlo import navigate_runs
    from starnav.dataset import open as open_dataset

    m = runs3["metrics"]
    again = navigate_runs(open_dataset(small_dataset), 3)["metrics"]
    assert m["nees_per_step"] == again["nees_per_step"]
    per_run = [r["nees_mean"] for r in runs3["result"].rows]
    assert len(set(per_run)) == 3
    st = m["nees"]
    K = len(m["nees_per_step"])
    n = st["effective_samples"]
    assert 1.0 <= st["autocorrelation_time"] <= K
    assert n == pytest.approx(3 * K / st["autocorrelation_time"])
    assert m["nees_band"] == pytest.approx(list(chi2.ppf([0.005, 0.995], 6 * n) / n))
    lo, hi = chi2.ppf([0.025, 0.975], 18) / 3
    inside = np.mean([lo <= v <= hi for v in m["nees_per_step"]])
    assert m["nees_steps_in_band"] == pytest.approx(inside)
    for key in ("nees_position", "nees_velocity"):
        assert m[key]["dof"] == 3 and m[key]["verdict"] in (
            "consistent", "overconfident", "pessimistic")
    assert m["verdict"] == ("consistent" if m["nees_band"][0] <= m["nees_mean"]
                            <= m["nees_band"][1] else
                            "overconfident" if m["nees_mean"] > m["nees_band"][1]
                            else "pessimistic")
    w = m["within_3sigma"]
    assert 0.0 <= w["all"] <= 1.0 and w["expected"] == pytest.approx(0.9973)


def test_cli_navigate_runs_writes_the_verdict_and_figures(small_dataset, tmp_path):
    from typer.testing import CliRunner

    from starnav.cli.main import app

    out = tmp_path / "nav"
    r = CliRunner().invoke(app, ["navigate", str(small_dataset), "--out", str(out),
                                 "--runs", "3", "--exposure", "15us"])
    assert r.exit_code == 0, r.output
    assert "over 3 runs: time-averaged NEES" in r.output
    report = (out / "report.md").read_text()
    assert report.splitlines()[2].startswith(("**Consistent**", "**Overconfident**",
                                              "**Pessimistic**"))
    m = json.loads((out / "metrics.json").read_text())
    assert m["runs"] == 3 and m["frames"] == 4
    assert m["exposure_s"] == pytest.approx(1.5e-5)
    assert len((out / "runs.csv").read_text().splitlines()) == 4
    for f in ("consistency.png", "position_error.png", "velocity_error.png"):
        assert (out / f).stat().st_size > 1000


def test_the_saturated_exposure_keeps_its_own_overrides(small_dataset):
    """The 7.7 ms exposure of a dataset is re-exposed with what it was made with (its
    overrides, its exposure time), not the dataset's base scenario."""
    from starnav.dataset import open as open_dataset

    ds = open_dataset(small_dataset, 7.7e-3)
    sc = ds.scenario()
    assert sc.detector.exposure_time_s == pytest.approx(7.7e-3)
    for item in ds.exposure_overrides:
        key, value = item.split("=", 1)
        assert key.startswith(("detector.", "navigation."))


def test_runs_need_the_radiance(tmp_path):
    """A dataset made without radiance cannot be re-exposed: a clear error naming it, before
    any work; one run is refused too (no consistency from one run)."""
    from starnav.batch.montecarlo import navigate_runs
    from starnav.dataset import DatasetOptions, generate
    from starnav.dataset import open as open_dataset
    from starnav.errors import ConfigError, DataFileError

    from .conftest import small_scenario

    out = tmp_path / "norad"
    generate(small_scenario(frames=2), out, options=DatasetOptions(radiance=False))
    ds = open_dataset(out)
    with pytest.raises(DataFileError, match="radiance"):
        navigate_runs(ds, 2)
    with pytest.raises(ConfigError, match="runs"):
        navigate_runs(ds, 1)
    assert np.isfinite(ds.exposure_time)
