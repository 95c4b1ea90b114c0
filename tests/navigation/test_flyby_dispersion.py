"""The fly-by Monte Carlo with the orientation dispersed (``navigation.trn.dispersion:
orientation``, ``starnav.batch.flyby``, module step 2e): what a run draws, that each run
is its own fly-by judged against its own truth, the fly-by frame of the error figures, and
the refusals. The consistency verdicts on rendered fly-bys are in
``test_flyby_closed_loop.py``."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from scipy.stats import kstest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.batch.flyby import flyby_closed_loop, navigate_flyby
from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.errors import ConfigError
from starnav.navigation.trn.metrics import errors_in_flyby_frame, summarise_runs
from starnav.scenes.flyby import flyby_from_config
from starnav.simulate import Simulator
from starnav.simulate.build import body_from_scenario
from starnav.simulate.flyby import dispersed_flyby, render_flyby
from tests.flyby_scenarios import tiny_flyby

#: Draws of the uniformity test and its per-component false-alarm rate (three components:
#: 3e-3 in all).
DRAWS, ALPHA = 400, 1e-3


def dispersed(sc, **extra):
    d = scenario_to_dict(sc)
    d["navigation"]["trn"]["dispersion"] = "orientation"
    for k, v in extra.items():
        d[k] = v
    return scenario_from_dict(d)


def test_a_run_keeps_the_flyby_and_draws_its_orientation_uniformly():
    """Run r's fly-by has the base's CA distance, speed and phase at CA (checked on the
    relative states), a reproducible draw, and over 400 runs the body's pole seen in the
    fly-by frame is uniform on the sphere (each component uniform on [-1, 1], Archimedes;
    Kolmogorov-Smirnov at 1e-3 per component): the fly-by frame is Haar-distributed relative
    to the body, whose IAU orientation is untouched."""
    base = dispersed(tiny_flyby(60.0))
    pole = body_from_scenario(base).orientation(np.array([0.0]))[0][:, 2]
    comps = []
    for r in range(DRAWS):
        sc, draw = dispersed_flyby(base, r)
        fb_cfg = sc.trajectory.flyby
        assert sc.navigation.trn.dispersion == "none"    # a concrete fly-by
        assert (fb_cfg.v_inf_km_s, fb_cfg.closest_approach_km, fb_cfg.phase_at_ca_deg,
                fb_cfg.sun_azimuth_deg) == (0.5, 5.0, 60.0, 180.0)
        assert draw == {k: getattr(fb_cfg, k) for k in draw}
        fb = flyby_from_config(fb_cfg, epoch_ca=0.0)
        if r < 20:
            x = fb.states(np.array([0.0]))[0]
            assert np.linalg.norm(x[:3]) == pytest.approx(5e3, rel=1e-12)
            assert np.linalg.norm(x[3:]) == pytest.approx(500.0, rel=1e-12)
            assert math.degrees(fb.phase_angles(np.array([0.0]))[0]) == pytest.approx(60.0)
        A = np.array([fb.x_hat, fb.y_hat, fb.z_hat])
        assert A @ A.T == pytest.approx(np.eye(3), abs=1e-12)
        comps.append(A @ pole)
    again, draw_again = dispersed_flyby(base, 7)
    assert draw_again == dispersed_flyby(base, 7)[1]
    assert draw_again != dispersed_flyby(dispersed(tiny_flyby(60.0), seed=4), 7)[1]
    comps = np.array(comps)
    for i in range(3):
        assert kstest(comps[:, i], "uniform", args=(-1.0, 2.0)).pvalue > ALPHA, i


@pytest.fixture(scope="module")
def tiny_loop():
    """Two dispersed runs of the tiny fly-by (3 frames at 128 px: ~2 s)."""
    return flyby_closed_loop(Simulator(dispersed(tiny_flyby(60.0))), 2)


def test_each_run_is_its_own_flyby_against_its_own_truth(tiny_loop):
    """Every run renders its own fly-by: different truths (J2000), each run's metrics and
    NEES against its own, the summary says so, and a run is the same whatever the number of
    runs (run 1 alone equals run 1 of two)."""
    loop = tiny_loop
    assert loop.dispersion == "orientation" and loop.summary["dispersion"] == "orientation"
    assert len(loop.run_truths) == 2 and len(loop.draws) == 2
    assert not np.allclose(loop.run_truths[0][:, :3], loop.run_truths[1][:, :3])
    for k, r in enumerate(loop.runs):
        # the same CA range in every run: the fly-by is the base's
        assert r.metrics.ca_range_m == pytest.approx(5e3, rel=1e-9)
        ne = r.filter.nees(loop.truth_of(k))
        assert r.metrics.nees_mean == pytest.approx(float(ne.mean()), rel=1e-12)
    per_run = [r.filter.nees(loop.truth_of(k)).mean() for k, r in enumerate(loop.runs)]
    assert loop.summary["nees_mean"] == pytest.approx(float(np.mean(per_run)), rel=1e-12)
    alone = flyby_closed_loop(Simulator(dispersed(tiny_flyby(60.0))), 1, first_run=1)
    assert np.array_equal(alone.runs[0].filter.states, loop.runs[1].filter.states)
    assert alone.draws[0] == loop.draws[1]
    assert loop.first is not None and len(loop.first[1]) == 3


def test_frames_given_with_a_dispersed_scenario_are_refused():
    """A dispersed run renders its own fly-by: frames rendered once (a dataset's) cannot be
    dispersed, one ConfigError naming the key, before any work."""
    sim = Simulator(tiny_flyby(60.0))
    renders, _ = render_flyby(sim)
    with pytest.raises(ConfigError, match="navigation.trn.dispersion"):
        flyby_closed_loop(Simulator(dispersed(tiny_flyby(60.0))), 2, renders=renders)
    with pytest.raises(ConfigError, match="navigation.trn.dispersion"):
        navigate_flyby(Simulator(dispersed(tiny_flyby(60.0))), "unused", 2, renders=renders)
    with pytest.raises(ConfigError, match="truth"):
        loop = flyby_closed_loop(sim, 2, renders=renders)
        summarise_runs([r.filter for r in loop.runs], [r.metrics for r in loop.runs],
                       [loop.truth] * 3, loop.epochs, loop.epoch_ca)


def test_errors_in_the_flyby_frame_are_the_j2000_errors_turned():
    """Turned into a frame (rows of a rotation), the errors keep their norm per block and
    their NEES, and each 3-sigma is that of the turned covariance's diagonal: for the frame's
    own axes, the projection of the J2000 covariance on them."""
    rng = np.random.default_rng(3)
    A = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    e = rng.standard_normal((4, 6))
    L = rng.standard_normal((4, 6, 6))
    P = L @ np.transpose(L, (0, 2, 1)) + np.eye(6)
    ef, s3 = errors_in_flyby_frame(e, P, A)
    assert np.linalg.norm(ef[:, :3], axis=1) == pytest.approx(np.linalg.norm(e[:, :3], axis=1))
    T = np.kron(np.eye(2), A)
    for k in range(4):
        Pf = T @ P[k] @ T.T
        assert ef[k] @ np.linalg.solve(Pf, ef[k]) == pytest.approx(e[k] @ np.linalg.solve(
            P[k], e[k]))
        assert s3[k, 0] == pytest.approx(3.0 * math.sqrt(A[0] @ P[k, :3, :3] @ A[0]))
        assert s3[k, 4] == pytest.approx(3.0 * math.sqrt(A[1] @ P[k, 3:, 3:] @ A[1]))


@pytest.mark.slow
def test_cli_navigate_a_dispersed_flyby(tmp_path):
    """``starnav navigate FLYBY.yaml --runs 2 --set navigation.trn.dispersion=orientation``:
    metrics.json records the dispersion and each run's draw, the report says what the band
    sampled, the error figures are in the fly-by frame; the same option on a fly-by dataset is
    one error line naming the key."""
    from typer.testing import CliRunner

    from starnav.cli.main import app

    env = {"COLUMNS": "50"}
    cli = CliRunner()
    sc = tmp_path / "fb.yaml"
    sc.write_text(json.dumps(scenario_to_dict(tiny_flyby(60.0))))
    out = tmp_path / "out"
    res = cli.invoke(app, ["navigate", str(sc), "--out", str(out), "--runs", "2", "--set",
                           "navigation.trn.dispersion=orientation"], env=env)
    assert res.exit_code == 0, res.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["monte_carlo"]["dispersion"] == "orientation"
    assert m["dispersion"]["kind"] == "orientation" and len(m["dispersion"]["draws_deg"]) == 2
    assert "Each run drew the fly-by's orientation" in (out / "report.md").read_text()
    assert (out / "position.png").stat().st_size > 0
    ds = tmp_path / "ds"
    assert cli.invoke(app, ["dataset", str(sc), "--out", str(ds)], env=env).exit_code == 0
    bad = cli.invoke(app, ["navigate", str(ds), "--out", str(tmp_path / "o2"), "--runs", "2",
                           "--set", "navigation.trn.dispersion=orientation"], env=env)
    assert bad.exit_code == 2, bad.output
    assert "navigation.trn.dispersion" in bad.output
    assert len(bad.output.strip().splitlines()) == 1
