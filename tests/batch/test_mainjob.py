"""The main job (``make demo``) on a reduced scenario, and the 3-D look (``starnav show``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from .conftest import small_scenario


def test_main_job_makes_dataset_navigation_and_report(tmp_path):
    from starnav.batch import main_job
    from starnav.dataset import verify

    calls: list[tuple[int, int]] = []
    s = main_job(small_scenario(frames=4), tmp_path / "demo",
                 progress=lambda d, n: calls.append((d, n)), runs=2)
    report = tmp_path / "demo" / "report.md"
    assert s["report"] == str(report) and report.is_file()
    text = report.read_text()
    assert "0.015 ms (HIL, well exposed)" in text and "7.7 ms (HIL, fictitious)" in text
    assert "detector.readout.segments.thresholds_dn=[2048]" in text
    for e in ("exposure_0.015ms", "exposure_7.7ms"):
        for f in ("metrics.json", "estimates.csv", "limb_error_pdf.png", "position_error.png"):
            assert (tmp_path / "demo" / "navigation" / e / f).is_file()
    assert verify(tmp_path / "demo" / "dataset") == []
    assert s["frames"] == 4 and calls[-1] == (9, 9) and calls[0][0] == 0
    # the consistency over Monte Carlo runs, next to the accuracy
    assert "Can the 3-sigma bounds be trusted? (2 Monte Carlo runs)" in text
    assert "over 2 runs: time-averaged NEES" in text
    # ... conditional on the dataset's one terrain; the scored record beside it
    from starnav.batch.scores import recorded_scores

    assert "conditional on this arc's terrain" in text
    for t in (1.5e-5, 7.7e-3):
        rows = [r for r in recorded_scores()["scores"] if r["exposure_s"] == t]
        k = round(sum(r["epochs_in_band"] * r["epochs"] for r in rows))
        assert f"{t * 1e3:g} ms {k}/{sum(r['epochs'] for r in rows)}" in text
    for e in ("exposure_0.015ms", "exposure_7.7ms"):
        assert (tmp_path / "demo" / "navigation" / e / "montecarlo" / "metrics.json").is_file()
    assert s["0.015 ms: filter (2 runs)"] in ("consistent", "overconfident", "pessimistic")
    # one figure: the middle frame (index 2) rendered, next to its DN frames at both exposures
    _assert_report_shows_radiance_next_to_dn(tmp_path / "demo", text, index=2)
    assert math.isfinite(s["0.015 ms: limb bias [px]"])
    # the saturated limb lies farther out than the well-exposed one
    assert s["7.7 ms: limb bias [px]"] > s["0.015 ms: limb bias [px]"] + 0.5
    # a second run resumes the finished dataset instead of remaking it
    s2 = main_job(small_scenario(frames=4), tmp_path / "demo", runs=0)
    assert s2["frames"] == 4 and s2["0.015 ms: limb bias [px]"] == s["0.015 ms: limb bias [px]"]


def _assert_report_shows_radiance_next_to_dn(out, text, index):
    import json

    import imageio.v3 as iio

    from starnav.batch.mainjob import FRAME_FIGURE

    assert f"![rendered radiance and detector DN frames]({FRAME_FIGURE})" in text
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    entry = next(f for f in manifest["frames"] if f["index"] == index)
    # the caption names the frame and its epoch: radiance and DN are of the same epoch
    assert f"frame {index} | range" in text and entry["epoch_tdb_iso"] in text
    fig = iio.imread(out / FRAME_FIGURE)
    assert fig.dtype == np.uint8 and fig.shape[1] > 2.5 * fig.shape[0]  # 3 panels in a row


def test_main_job_needs_a_trajectory(tmp_path):
    from starnav.batch import main_job
    from starnav.config import scenario_from_dict
    from starnav.errors import ConfigError

    with pytest.raises(ConfigError, match="trajectory"):
        main_job(scenario_from_dict({}), tmp_path / "x")


@pytest.mark.slow
def test_show_draws_the_scene(tmp_path):
    import imageio.v3 as iio

    from starnav.show import render_scene

    p = render_scene(small_scenario(frames=6), tmp_path / "scene.png", frusta=3,
                     window_size=(400, 300))
    img = iio.imread(p)
    assert img.shape[:2] == (300, 400)
    # not a blank frame: orange frusta and the blue trajectory are drawn on black
    assert np.count_nonzero(img[..., :3].max(axis=2) > 60) > 500


def test_show_says_clearly_when_it_cannot_run_headless(tmp_path, monkeypatch):
    import sys

    from starnav import show

    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'vtkXOpenGLRenderWindow: bad X server connection' >&2\n"
                    "exit 1\n")
    fake.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(fake))
    with pytest.raises(show.ShowUnavailableError) as e:
        show.render_scene(small_scenario(frames=2), tmp_path / "s.png")
    msg = str(e.value)
    assert "xvfb-run" in msg and "bad X server connection" in msg and "OSMesa" in msg
    assert not (tmp_path / "s.png").exists()


def test_main_job_overrides_apply_to_the_demo_scenario(tmp_path, monkeypatch):
    from starnav.batch import mainjob

    seen = {}

    def fake_dataset(sc, out, opts, workers, progress):
        seen["sc"] = sc
        raise RuntimeError("stop")

    monkeypatch.setattr(mainjob, "_dataset", fake_dataset)
    with pytest.raises(RuntimeError, match="stop"):
        mainjob.main_job(None, tmp_path / "x", overrides=["trajectory.frames=2", "seed=9"])
    sc = seen["sc"]
    assert sc.trajectory.frames == 2 and sc.seed == 9 and sc.camera.preset == "aa-str"
