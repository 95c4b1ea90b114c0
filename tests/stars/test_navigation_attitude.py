"""Issue 17, part C: navigation with the tracker's own attitude (``navigation.attitude``): the
gyro model's covariance, the schedule of star acquisitions and the fall-backs, the comparison
with the assumed attitude on the demo's arc."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from starnav.batch.attitude_study import (
    attitude_comparison,
    attitude_monte_carlo,
    comparison_markdown,
    monte_carlo_markdown,
    reduced_demo,
)
from starnav.config import scenario_from_dict
from starnav.errors import ConfigError, StarnavError
from starnav.geometry import FrameGeometry, look_rotation
from starnav.navigation.schema import AttitudeSourceConfig
from starnav.simulate.attitude import StarAttitudeTracker
from starnav.simulate.frames import Simulator
from starnav.stars.attitude import ARCSEC, error_rotation
from starnav.stars.gyro import GyroErrors, GyroModel, propagate

DEG = math.pi / 180.0
HOUR = 3600.0


# ------------------------------------------------------------------ gyro model
def test_settings_convert_to_si_and_the_gyro_variance_is_the_closed_form():
    """``gyro_arw_deg_rt_h`` and ``gyro_bias_deg_h`` through the SI view: 0.005 deg/sqrt(h) =
    0.005 (pi/180) / 60 rad/sqrt(s); 0.01 deg/h = 0.01 (pi/180) / 3600 rad/s. After 30 min:
    N^2 dt + sigma_b^2 dt^2 = (0.005^2 x 0.5 + (0.01 x 0.5)^2) deg^2 = 3.75e-5 deg^2
    (6.12e-3 deg = 22.0 arcsec)."""
    si = AttitudeSourceConfig().to_si()
    assert si.gyro_arw == pytest.approx(0.005 * DEG / 60.0, rel=1e-12)
    assert si.gyro_bias == pytest.approx(0.01 * DEG / 3600.0, rel=1e-12)
    assert si.star_exposure == 0.2
    g = GyroModel(si.gyro_arw, si.gyro_bias)
    assert g.variance(1800.0) == pytest.approx(3.75e-5 * DEG**2, rel=1e-12)
    assert math.sqrt(g.variance(1800.0)) / ARCSEC == pytest.approx(22.05, abs=0.01)
    assert g.variance(0.0) == 0.0


def test_propagated_error_scatter_grows_as_the_gyro_model_says():
    """4000 gyro realisations (bias drawn per run, ARW accumulated over two steps): the sample
    variance per axis after 0.5 h and 1 h equals N^2 dt + sigma_b^2 dt^2 within 6 % (12 000
    samples: the estimate's rms is 1.3 %, a 4.6-sigma band); the ARW part alone (bias 0) is
    linear in dt and the bias part alone quadratic."""
    for arw, bias in ((0.005, 0.01), (0.01, 0.0), (0.0, 0.02)):
        m = GyroModel(arw * DEG / 60.0, bias * DEG / HOUR)
        rng = np.random.default_rng(7)
        e1, e2 = [], []
        for _ in range(4000):
            ge = GyroErrors(m, rng)
            ge.reset(100.0)
            e1.append(ge.error(100.0 + 1800.0))
            e2.append(ge.error(100.0 + 3600.0))
        for e, dt in ((e1, 1800.0), (e2, 3600.0)):
            v = np.mean(np.square(e))
            assert v == pytest.approx(m.variance(dt), rel=0.06), (arw, bias, dt)


def test_propagate_rotates_the_covariance_and_adds_the_gyro_error_to_first_order():
    """A 90 deg slew about x between the frames: P1 = dR^T P0 dR + Q(dt) (the y and z
    variances swap); a solution error dtheta_0 and a gyro error g give the propagated error
    dR^T dtheta_0 + g within second-order terms (1e-9 rad at 1e-5 rad)."""
    m = GyroModel(0.005 * DEG / 60.0, 0.01 * DEG / HOUR)
    P0 = np.diag([1e-12, 4e-12, 9e-11])
    R_true0 = look_rotation(np.array([0.0, 0, 1]), np.array([0.2, 0.3, 0.9]))
    dR = Rotation.from_rotvec([math.pi / 2, 0, 0]).as_matrix()
    R_true1 = R_true0 @ dR
    d0 = np.array([3e-6, -2e-6, 1e-5])
    R_est0 = R_true0 @ Rotation.from_rotvec(-d0).as_matrix()   # R_true = R_est exp([d0 x])
    assert np.allclose(error_rotation(R_est0, R_true0), d0, atol=1e-12)
    g = np.array([1e-5, 2e-6, -4e-6])
    R1, P1 = propagate(R_est0, P0, R_true0, R_true1, 1800.0, m, g)
    assert np.allclose(P1, np.diag([1e-12, 9e-11, 4e-12]) + m.variance(1800.0) * np.eye(3),
                       rtol=1e-9, atol=1e-20)
    assert np.allclose(error_rotation(R1, R_true1), dR.T @ d0 + g, atol=1e-9)


# ------------------------------------------------------------------ the schedule
def _sim(**attitude) -> Simulator:
    return Simulator(scenario_from_dict({
        "stars": {"enabled": True},
        "navigation": {"attitude": {"source": "stars", "navigation_frames": False,
                                    **attitude}}}))


def _sky_frames(n: int, cadence_s: float = 1800.0) -> list[FrameGeometry]:
    """Frames pointing at an open sky field (the Moon behind the camera), slewing 0.3 deg
    about the camera x axis per frame."""
    R0 = look_rotation(np.array([0.0, 0, 1]),
                       np.array([math.cos(0.4) * math.cos(1.2), math.cos(0.4) * math.sin(1.2),
                                 math.sin(0.4)]))
    out = []
    for k in range(n):
        R = R0 @ Rotation.from_rotvec([0.3 * DEG * k, 0, 0]).as_matrix()
        out.append(FrameGeometry(camera_position=3.8e8 * R[:, 2], R_cam_to_inertial=R,
                                 sun_position=np.array([1.5e11, 0.0, 0.0]),
                                 epoch_tdb=8e8 + cadence_s * k, index=k))
    return out


def test_schedule_alternates_star_frames_and_gyro_propagation():
    """``schedule_every: 2`` on 4 frames (no navigation-frame stars, star field only): star
    acquisitions at frames 0 and 2 solved (lost in space, then tracking from the propagated
    prior), frames 1 and 3 propagated 1800 s with covariance dR^T P dR + Q(1800 s) of the
    last solution, exactly; every attitude error inside 4 predicted sigmas per axis; the
    star frames' cross-boresight error < 3 arcsec."""
    sim = _sim(schedule_every=2)
    tr = StarAttitudeTracker(sim)
    geoms = _sky_frames(4)
    zeros = np.zeros((sim.camera.height, sim.camera.width), np.float32)
    recs = [tr.step(zeros, g, None) for g in geoms]
    assert [r.star_frame for r in recs] == [True, False, True, False]
    assert [r.source for r in recs] == ["star-frame", "propagated", "star-frame", "propagated"]
    assert [r.mode for r in recs] == ["lost-in-space", "", "tracking", ""]
    assert [r.since_solution_s for r in recs] == [0.0, 1800.0, 0.0, 1800.0]
    for a, b, ga, gb in ((recs[0], recs[1], geoms[0], geoms[1]),
                         (recs[2], recs[3], geoms[2], geoms[3])):
        dR = ga.R_cam_to_inertial.T @ gb.R_cam_to_inertial
        expect = dR.T @ a.covariance_rad2 @ dR + tr.gyro.variance(1800.0) * np.eye(3)
        assert np.allclose(b.covariance_rad2, expect, rtol=1e-9, atol=0)
    for r in recs:
        assert np.all(np.abs(r.error_rad) < 4 * np.sqrt(np.diag(r.covariance_rad2))), r.summary()
        assert not r.reasons
    assert np.all(np.abs(recs[0].error_rad[:2]) / ARCSEC < 3.0)
    assert np.all(np.abs(recs[2].error_rad[:2]) / ARCSEC < 3.0)


def test_a_failed_star_solve_falls_back_and_says_why():
    """Star acquisitions at 0.015 ms: no star is detectable, so there is no solution to
    propagate: the frames keep the assumed attitude (the scenario's knowledge error and
    sigma), and each record says why ("0 star candidates detected")."""
    sim = _sim(star_exposure_s=1.5e-5, schedule_every=1)
    tr = StarAttitudeTracker(sim)
    zeros = np.zeros((sim.camera.height, sim.camera.width), np.float32)
    for g in _sky_frames(2):
        r = tr.step(zeros, g, None)
        assert r.source == "assumed" and r.star_frame
        assert len(r.reasons) == 1 and "star frame 0.015 ms: 0 star candidates detected" \
            in r.reasons[0]
        sig = np.array(sim.scenario.pointing.knowledge_sigma) / ARCSEC
        assert np.allclose(r.sigma_arcsec, sig)


def test_bad_attitude_settings_give_clear_errors():
    """Unknown source, schedule 0, a negative gyro, stars off with source stars, an
    assumed-source tracker: each a StarnavError naming the field, before any frame."""
    for bad, field in (({"source": "star"}, "source"), ({"schedule_every": 0}, "schedule_every"),
                       ({"gyro_arw_deg_rt_h": -1}, "gyro_arw_deg_rt_h"),
                       ({"star_exposure_s": 0}, "star_exposure_s")):
        with pytest.raises(StarnavError, match=field):
            scenario_from_dict({"navigation": {"attitude": bad}})
    off = Simulator(scenario_from_dict({"navigation": {"attitude": {"source": "stars"}}}))
    with pytest.raises(ConfigError, match="stars.enabled"):
        StarAttitudeTracker(off)
    with pytest.raises(ConfigError, match="navigation.attitude.source"):
        StarAttitudeTracker(Simulator(scenario_from_dict({"stars": {"enabled": True}})))
    with pytest.raises(ConfigError, match="size_px"):
        reduced_demo(frames=3, size_px=64)
    with pytest.raises(ConfigError, match="exposures_s"):
        attitude_comparison(reduced_demo(frames=2), exposures_s=(-1.0,))
    with pytest.raises(ConfigError, match="trajectory"):
        attitude_comparison({})


# ------------------------------------------------------------------ the comparison
def _check_report(res, exposures):
    md = comparison_markdown(res)
    for t in exposures:
        for case in ("assumed", "stars"):
            assert f"| {t * 1e3:.4g} ms | {case} |" in md
    return md


def test_comparison_on_a_short_demo_arc_lists_both_cases_and_the_interplay():
    """The demo's arc, 3 frames at 1024 px, 0.015 ms, star acquisitions at 200 ms every 2nd
    frame: the report lists both cases; frames 0 and 2 solved from the 200 ms star
    acquisition with the Moon in the field (> 30 stars, cross-boresight error < 3 arcsec,
    no Moon-blob star matched: the solution is right), frame 1 says "0 star candidates" for
    its 0.015 ms frame and is propagated; the solved attitude's NEES (9 dof) is inside its
    two-sided 99 % band; the assumed case keeps the 5/5/40 arcsec sigma."""
    res = attitude_comparison(reduced_demo(frames=3, size_px=1024, spp=4),
                              exposures_s=(1.5e-5,), attitude={"schedule_every": 2})
    md = _check_report(res, (1.5e-5,))
    assert "0 star candidates detected" in md
    rows = res["records"]["1.5e-05"]
    assert [r["source"] for r in rows] == ["star-frame", "propagated", "star-frame"]
    for r in (rows[0], rows[2]):
        assert r["stars_matched"] > 30 and r["error_cross_arcsec"] < 3.0
    assert rows[1]["since_solution_s"] == 1800.0
    nees = [r["nees"] for r in rows]
    lo, hi = chi2.ppf([0.005, 0.995], 9) / 3
    assert lo < np.mean(nees) < hi, nees
    assumed, stars = res["cases"]
    assert assumed["case"] == "assumed" and stars["case"] == "stars"
    assert assumed["attitude"]["sigma_roll_mean_arcsec"] == pytest.approx(40.0)
    assert stars["attitude"]["sources"] == {"star-frame": 2, "navigation-frame": 0,
                                            "propagated": 1, "assumed": 0}
    assert stars["navigation"]["fixes"] == 3


@pytest.fixture(scope="module")
def demo_comparison():
    """13 frames (6 h) of the demo arc at 1024 px, 8 spp, both demo exposures, star
    acquisitions at 200 ms every 2nd frame (~2.5 min)."""
    res = attitude_comparison(reduced_demo(frames=13, size_px=1024, spp=8),
                              attitude={"schedule_every": 2})
    print(comparison_markdown(res))
    return res, {(c["exposure_s"], c["case"]): c for c in res["cases"]}


@pytest.mark.slow
def test_navigation_with_solved_attitude_at_the_demo_exposures(demo_comparison):
    """Both cases navigate every frame at both exposures; the solved attitude's roll error is
    smaller than the assumed one's (star frames: ~2.5 arcsec roll sigma against 40); at
    7.7 ms (the navigation frames' own bright stars solve the frames between star
    acquisitions) the cross-boresight error too, while at 0.015 ms the frames between are
    propagated 30 min by the gyro (22 arcsec); the attitude covariance is not overconfident
    (mean attitude NEES below the band's top: it is conservative, docs/stars.md), and the
    7.7 ms filter with the solved attitude is inside its NEES band (seeded run)."""
    res, by = demo_comparison
    _check_report(res, (1.5e-5, 7.7e-3))
    for c in res["cases"]:
        assert c["navigation"]["fixes"] == 13
    for t in (1.5e-5, 7.7e-3):
        a, s = by[(t, "assumed")]["attitude"], by[(t, "stars")]["attitude"]
        assert s["error_roll_rms_arcsec"] < a["error_roll_rms_arcsec"]
        assert s["nees_mean"] < s["nees_band"][1]
    s7, a7 = by[(7.7e-3, "stars")], by[(7.7e-3, "assumed")]
    assert s7["attitude"]["error_cross_rms_arcsec"] < a7["attitude"]["error_cross_rms_arcsec"]
    assert s7["attitude"]["sources"]["navigation-frame"] >= 1
    assert s7["navigation"]["nees_in_band"]
    s0 = by[(1.5e-5, "stars")]["attitude"]["sources"]
    assert s0["navigation-frame"] == 0 and s0["propagated"] == 6


def _check_monte_carlo(res: dict, runs: int) -> None:
    """Every run on its own terrain (run 0 the Moon as it is), and per exposure and case the
    filter's mean NEES (6 states, runs x frames) not above the two-sided 99 % band of a
    ``runs``-run mean of chi2(6) (overconfidence is the failure that matters: a filter whose
    sigma under-states its error; false alarm <= 0.5 % for a consistent one), the position
    and velocity blocks likewise (3 dof), and the solved attitude's NEES not above its
    band."""
    off = res["terrain_offsets_deg"]
    assert off[0] == 0.0 and len(set(off)) == runs
    print(monte_carlo_markdown(res))
    for c in res["cases"]:
        assert c["nees_mean"] <= c["nees_band"][1], (c["exposure_s"], c["case"], c["nees_mean"])
        assert c["nees_position_mean"] <= c["nees_band_3dof"][1], c["nees_position_mean"]
        assert c["nees_velocity_mean"] <= c["nees_band_3dof"][1], c["nees_velocity_mean"]
        assert len(set(np.round(c["nees_per_run"], 9))) == runs   # the runs differ
        if c["case"] == "stars":
            assert c["attitude"]["nees_mean"] <= c["attitude"]["nees_band"][1]
            assert c["attitude"]["sources"]["star-frame"] >= runs


@pytest.fixture(scope="module")
def short_monte_carlo():
    """4 runs, each on its own terrain, 5 frames (2 h) of the demo's arc at 1024 px, 4 spp,
    both demo exposures, star acquisitions at 200 ms every 2nd frame (~25 s)."""
    return attitude_monte_carlo(reduced_demo(frames=5, size_px=1024, spp=4), 4,
                                attitude={"schedule_every": 2})


@pytest.mark.slow
def test_attitude_monte_carlo_is_not_overconfident_on_a_short_arc(short_monte_carlo):
    """The Monte Carlo verdict's fast version (the slow test below is the verdict): the
    assumed and the solved attitude at both exposures not overconfident (measured 7.10,
    10.65, 7.35, 7.30 against the 4-run band's top 11.39; velocity block of the solved
    attitude at 0.015 ms 6.99 against 7.07: the closest)."""
    _check_monte_carlo(short_monte_carlo, 4)


@pytest.fixture(scope="module")
def demo_monte_carlo():
    """20 Monte Carlo runs, each on its own terrain (the lit-terrain limb error drawn afresh
    per run, as the band assumes: docs/navigation.md, "Consistency needs the terrain
    sampled"), 13 frames at 1024 px, 8 spp, both demo exposures (~5 min)."""
    return attitude_monte_carlo(reduced_demo(frames=13, size_px=1024, spp=8), 20,
                                attitude={"schedule_every": 2})


@pytest.mark.slow
def test_navigation_with_solved_attitude_is_consistent_over_terrains(demo_monte_carlo):
    """Issue 17's consistency verdict on the demo's arc: the assumed and the solved attitude
    at both exposures inside the two-sided 99 % band of a 20-run mean of chi2(6), [4.19,
    8.18] (measured 7.13, 6.60 at 0.015 ms; 4.79, 4.79 at 7.7 ms; docs/stars.md)."""
    _check_monte_carlo(demo_monte_carlo, 20)
    for c in demo_monte_carlo["cases"]:
        assert c["verdict"] == "consistent", (c["exposure_s"], c["case"], c["nees_mean"])
