"""Navigation whose uncertainty can be trusted (issue 13): the per-pixel noise model of the
refinement, the terrain's limb-height model, the anisotropic attitude knowledge of the fix, and
the refined points' error/sigma on rendered, exposed frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.batch.consistency import SATURATED, WELL_EXPOSED
from starnav.constants import MOON_RADIUS
from starnav.dem.grid import DemGrid
from starnav.dem.limb import limb_heights, limb_topography
from starnav.navigation.christian_robinson import LimbFix
from starnav.navigation.refine import PixelNoise, fit_edge_window

ARCSEC = math.pi / 180.0 / 3600.0


# ----------------------------------------------------------------------------- pixel noise
def test_pixel_noise_variance_closed_form():
    """var = (read^2 + g s + (prnu g s)^2) / g^2 + 1/12 DN^2, s the DN above the offset."""
    n = PixelNoise(gain_e_per_dn=24.0, read_noise_e=100.0, prnu_fraction=0.02, offset_dn=100.0)
    s = 1500.0
    e = s * 24.0
    want = (100.0**2 + e + (0.02 * e) ** 2) / 24.0**2 + 1.0 / 12.0
    assert n.variance_dn2(100.0 + s) == pytest.approx(want, rel=1e-12)
    # below the offset: read noise and quantisation only
    assert n.variance_dn2(50.0) == pytest.approx((100.0 / 24.0) ** 2 + 1.0 / 12.0)


def test_pixel_noise_from_the_detector_settings():
    from starnav.detector.schema import DetectorConfig

    d = DetectorConfig()
    n = PixelNoise.from_detector(d)
    assert n.gain_e_per_dn == pytest.approx(d.gain_e_per_dn)
    assert n.read_noise_e == d.signal.read_noise.sigma_e
    assert n.prnu_fraction == d.charge.prnu.sigma_fraction
    off = DetectorConfig.model_validate({"charge": {"prnu": {"enabled": False}}})
    assert PixelNoise.from_detector(off).prnu_fraction == 0.0


def test_weighted_edge_fit_sigma_matches_its_scatter():
    """Windows drawn with PRNU-dominated noise (the sigma of the fit must follow the noise, not
    a pooled residual): over 400 windows rms(error / sigma) is 1 within 0.1 (its sampling
    spread is 1/sqrt(2 N) = 0.035: a consistent estimator fails with probability < 1e-3), while
    the unweighted fit with a pooled residual variance is overconfident."""
    from starnav.navigation.refine import edge_profile

    rng = np.random.default_rng(7)
    noise = PixelNoise(gain_e_per_dn=24.4, read_noise_e=100.0, prnu_fraction=0.02,
                       offset_dn=100.0)
    yy, xx = np.mgrid[-5:6, -5:6].astype(float)
    R = 80.0
    z_w, z_u = [], []
    for _ in range(400):
        delta = rng.uniform(-0.5, 0.5)
        rho = np.hypot(xx + R, yy).ravel()
        t = (R * np.arctan2(yy, xx + R)).ravel()
        clean = 100.0 + edge_profile(rho - (R + delta), math.sqrt(1.2**2 + 1 / 12),
                                     (1500.0, 60.0, 300.0))
        dn = np.round(clean + rng.standard_normal(clean.size)
                      * np.sqrt(noise.variance_dn2(clean) - 1 / 12))
        for out, px_noise in ((z_w, noise), (z_u, None)):
            f = fit_edge_window(dn, rho, t, R, noise=px_noise)
            out.append((f.delta - delta) / f.sigma_delta)
    rms_w = float(np.sqrt(np.mean(np.square(z_w))))
    rms_u = float(np.sqrt(np.mean(np.square(z_u))))
    assert abs(rms_w - 1.0) < 0.1, rms_w
    assert rms_u > rms_w + 0.1, (rms_u, rms_w)


# ----------------------------------------------------------------------------- terrain
def test_limb_of_a_flat_dem_is_the_sphere_plus_its_height():
    """A constant height h0 everywhere: the limb height is h0 at every view and position angle
    (to the theta sampling: R step^2 / 8 ~ 4 m)."""
    g = DemGrid(np.full((180, 360), 1234.0, np.float32))
    h = limb_heights(g, np.random.default_rng(0).standard_normal((5, 3)), 36)
    assert np.allclose(h, 1234.0, atol=10.0)


def test_limb_of_a_single_ridge_matches_the_tangent_geometry():
    """A ridge of height H along the meridian lon = 0 (one column of cells), viewed from
    (lat 0, lon 90 deg): the limb through the ridge (the image direction towards lon 0, i.e.
    the equator's direction) sits H higher; 90 deg away (towards the pole) it does not."""
    v = np.zeros((721, 1440), np.float32)
    v[:, 719:721] = 3000.0                 # lon ~ 0 (cells centred at -0.125 and +0.125 deg)
    g = DemGrid(v)
    h = limb_heights(g, np.array([[0.0, 1.0, 0.0]]), 4)
    # position angle 0 and 180 deg lie along +-e1; e1 = v x z for this view -> (1, 0, 0)
    # and (-1, 0, 0): lon 0 (the ridge) and lon 180 (flat); 90/270 deg: the poles (flat)
    assert sorted(np.round(h[0] / 1000.0, 1).tolist()) == [0.0, 0.0, 0.0, 3.0]


def test_lola_limb_topography_numbers():
    """LOLA LDEM_4 (packaged): the limb stands ~0.5 km above the 1737.4 km sphere on average,
    spreads ~2.4 km point by point, and its half-circle mean (what a whole lit limb shares)
    spreads ~1.2 km; averaging over a wider arc can only reduce the spread."""
    from starnav.dem.limb import limb_topography_for

    t = limb_topography_for({"source": "lola"})
    assert 0.2e3 < t.mean_m < 1.0e3
    assert 2.0e3 < t.std_m < 2.8e3
    assert 0.8e3 < t.common_std_m < 1.6e3
    assert all(a >= b - 1.0 for a, b in zip(t.std_arc_m[:-1], t.std_arc_m[1:], strict=True))
    assert t.sigma_fraction_over(math.radians(8)) * MOON_RADIUS < t.std_m


def test_limb_topography_is_reproducible():
    g = DemGrid(np.random.default_rng(1).normal(0, 500, (90, 180)).astype(np.float32))
    a, b = limb_topography(g, n_views=8, seed=3), limb_topography(g, n_views=8, seed=3)
    assert a == b


# ----------------------------------------------------------------------------- fix covariance
def test_anisotropic_attitude_covariance_against_monte_carlo():
    """P_att = R [c x] diag(s^2) [c x]^T R^T, checked by rotating the camera by random small
    errors (5, 5, 40 arcsec about camera x, y, z) and measuring the scatter of R_meas (-c):
    within 5 % on every diagonal term (4 000 draws: the sampling spread is ~2.2 %)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(11)
    c = np.array([3.0e6, -2.0e6, 6.0e7])          # off-axis Moon centre, camera frame [m]
    R = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    sig = np.array([5.0, 5.0, 40.0]) * ARCSEC
    fix = LimbFix(centre_camera=c, covariance_camera=np.zeros((3, 3)), n=c / np.linalg.norm(c),
                  residual_px=np.zeros(3), n_points=3)
    P = fix.covariance_inertial(R, sig)
    pos = []
    for d in rng.standard_normal((4000, 3)) * sig:
        Rm = R @ Rotation.from_rotvec(d).as_matrix()      # the attitude the fix is made with
        pos.append(fix.position_inertial(Rm))
    S = np.cov(np.array(pos).T)
    assert np.allclose(np.diag(S), np.diag(P), rtol=0.05)
    # an isotropic 5 arcsec misses exactly the extra roll: (40^2 - 5^2) arcsec^2 |z x c|^2
    extra = np.trace(P) - np.trace(fix.covariance_inertial(R, 5.0 * ARCSEC))
    assert extra == pytest.approx((40.0**2 - 5.0**2) * ARCSEC**2 * (c[0] ** 2 + c[1] ** 2),
                                  rel=1e-9)


def test_radius_error_moves_the_fix_along_the_line_of_sight():
    c = np.array([0.0, 0.0, 6.0e7])
    fix = LimbFix(centre_camera=c, covariance_camera=np.zeros((3, 3)), n=c / 6e7,
                  residual_px=np.zeros(3), n_points=3)
    P = fix.covariance_inertial(np.eye(3), 0.0, radius_sigma_fraction=7e-4)
    assert P[2, 2] == pytest.approx((6.0e7 * 7e-4) ** 2)
    assert abs(P[0, 0]) < 1e-6 and abs(P[1, 1]) < 1e-6


# ----------------------------------------------------------------------------- rendered frames
#: The test arcs, never used by the calibration (tools/calibrate_refine_model_error.py: other
#: epochs and seeds): the demo's halo arc (phase 0, 2027-03-01, seed 20250101) and two more,
#: each 10 frames 1.5 days apart, so that the frames show many stretches of limb (the terrain
#: error of a frame depends on the stretch in view: frame by frame it scatters by a factor 2)
#: at Sun phases from 20 to 120 deg.
TEST_ARCS = ([], ["trajectory.halo_phase_deg=180", "trajectory.epoch=2027-06-15T00:00:00 TDB",
                  "seed=777"],
             ["trajectory.halo_phase_deg=90", "trajectory.epoch=2027-07-20T00:00:00 TDB",
              "seed=778"])
ARC = ["trajectory.duration_days=13.5", "trajectory.cadence_s=129600", "render.spp=8"]


@pytest.fixture(scope="module")
def limb_records():
    """The test arcs rendered once (real Moon, AA-STR, 8 spp, 30 frames), exposed at 0.015 ms
    and at 0.18 ms, every frame through the chain the scenario implies (~60 s)."""
    from starnav.batch.consistency import limb_point_records
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict

    recs = [limb_point_records(scenario_to_dict(scenario_from_dict(demo_scenario(),
                                                                   arc + ARC)),
                               1, (WELL_EXPOSED, SATURATED)) for arc in TEST_ARCS]
    out = {}
    for t in (WELL_EXPOSED[0], SATURATED[0]):
        pts = [r[t]["points"] for r in recs]
        out[t] = {"points": {k: np.concatenate([p[k] for p in pts]) for k in pts[0]},
                  "fix_nees": np.concatenate([r[t]["fix_nees"] for r in recs])}
    return out


@pytest.mark.parametrize("exposure", [WELL_EXPOSED[0], SATURATED[0]], ids=["0.015ms", "0.18ms"])
def test_refined_points_error_over_sigma_is_one_on_rendered_frames(limb_records, exposure):
    """Issue 13: rms(error / sigma) of the refined limb points within 1 +- 0.1 on rendered,
    exposed frames at 0.015 ms and at 0.18 ms (saturated inside the limb), sigma being a
    point's whole 1-sigma (its own and the part its frame shares). ~380 points (frames past
    the 145 deg crescent limit give none); the model errors were calibrated on other arcs.
    Before the detector-PSF edge model the 0.18 ms windows were biased by -1.9 +- 2.9 px (a
    fitted Gaussian cannot place a clipped edge)."""
    from starnav.batch.consistency import refinement_consistency

    tab = limb_records[exposure]["points"]
    res = refinement_consistency(tab)
    assert res["points"] >= 350, res
    assert abs(res["all"]["rms_z"] - 1.0) < 0.1, res
    if exposure == SATURATED[0]:
        assert res["saturated"]["points"] >= 200, res
        assert abs(res["saturated"]["bias_px"]) < 0.1, res     # the edge, not the clipping
    # subpixel, as the paper's algorithm 1 promises: well below the pixel-level 0.4 px
    assert res["all"]["std_px"] < 0.2, res


@pytest.mark.parametrize("exposure", [WELL_EXPOSED[0], SATURATED[0]], ids=["0.015ms", "0.18ms"])
def test_fix_covariance_is_consistent_on_rendered_frames(limb_records, exposure):
    """The fixes' own NEES (3 dof) against the true Moon-relative position, averaged over the
    frames, inside the two-sided 99 % chi-square band of that mean (a consistent covariance
    fails with probability 1 %)."""
    from scipy.stats import chi2

    nees = limb_records[exposure]["fix_nees"]
    n = nees.size
    assert n >= 24
    lo, hi = chi2.ppf([0.005, 0.995], 3 * n) / n
    assert lo < np.mean(nees) < hi, (np.mean(nees), lo, hi)


def test_noise_monte_carlo_runs_are_independent_noise_realisations():
    """starnav.batch.consistency: every run re-exposes the same rendered frames with its own
    detector noise and re-runs the chain. The run-to-run scatter of each frame's fix is the
    detector noise alone (terrain and attitude error are common to all runs, and the camera
    is known exactly here: with the bench default each run would know it as another bench),
    so its NEES against the reported covariance (which also holds terrain and attitude) is
    below 3 on average, and not zero; the band is the chi-square of the effective number of samples
    of the run and time average."""
    from scipy.stats import chi2

    from starnav.batch.consistency import filter_consistency, noise_monte_carlo
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict

    sc = scenario_from_dict(demo_scenario(), ["trajectory.duration_days=0.125",
                                              "trajectory.cadence_s=3600", "render.spp=4",
                                              "navigation.camera_calibration=null"])
    mc = noise_monte_carlo(scenario_to_dict(sc), runs=6)
    assert len(mc.frames) == 4 and all(len(f) == 6 for f in mc.frames)
    scatter = []
    for runs in mc.frames:
        pos = np.array([r.position for r in runs if r.position is not None])
        cov = np.mean([r.covariance for r in runs if r.covariance is not None], axis=0)
        d = pos - pos.mean(axis=0)
        scatter.append(np.mean([x @ np.linalg.solve(cov, x) for x in d]))
    assert 0.0 < np.mean(scatter) < 3.0, scatter
    res = filter_consistency(mc)
    n = res["nees"]["effective_samples"]  # 6 runs x 4 frames / the NEES autocorrelation time
    assert 6 <= n <= 24
    lo, hi = chi2.ppf([0.005, 0.995], 6 * n) / n
    assert res["band"] == pytest.approx((lo, hi))
    assert len(res["nees_per_run"]) == 6
    assert res["consistent"] == (lo <= res["nees_mean"] <= hi)


def test_monte_carlo_runs_redraw_the_attitude_knowledge_error():
    """Run r >= 1 of a frame draws a fresh knowledge error from its own stream: over 3 000 runs
    the error's per-axis spread is the configured (5, 5, 40) arcsec within 5 %, runs differ,
    and the same run is reproducible; run 0 is refused (it is the frame's own draw)."""
    from starnav.errors import ConfigError
    from starnav.scenes.pointing import knowledge_for_run

    sig = np.array([5.0, 5.0, 40.0]) * ARCSEC
    R0 = np.eye(3)
    errs = []
    for r in range(1, 3001):
        Rm = knowledge_for_run(R0, sig, 7, 3, r)
        # small-angle rotation vector of R0^T Rm: the off-diagonal (skew) part
        errs.append([Rm[2, 1], Rm[0, 2], Rm[1, 0]])
    errs = np.array(errs)
    assert np.allclose(errs.std(axis=0), sig, rtol=0.05)
    assert np.array_equal(knowledge_for_run(R0, sig, 7, 3, 5), knowledge_for_run(R0, sig, 7, 3, 5))
    with pytest.raises(ConfigError, match="run"):
        knowledge_for_run(R0, sig, 7, 3, 0)


#: The demo's arc, short: 4 frames two hours apart (Sun phase ~82 deg), never used to tune
#: the bias states (tools/tune_bias_states.py: other epochs, halo phases and seeds); its truth
#: feels what the filter does not model (planets, SRP with eclipses, J2: starnav.scenes.forces).
SHORT_ARC = ["trajectory.duration_days=0.25", "trajectory.cadence_s=7200", "render.spp=8",
             "trajectory.forces.planets=[venus,mars,jupiter,saturn]",
             "trajectory.forces.srp=true", "trajectory.forces.j2=true"]
RUNS = 20
#: The per-epoch statistic on the short arc's 4 epochs: at least 3 inside their 95 % band (a
#: consistent filter has 2 or fewer with probability 1 - 0.95^4 - 4 0.95^3 0.05 = 1.4 %, for
#: independent epochs; correlated ones make it looser).
PER_EPOCH_MIN = 0.75


@pytest.fixture(scope="module")
def demo_arc():
    """The short demo arc with the truth's extra forces on, rendered once per Monte Carlo
    run, each run on its own terrain (the DEM and its albedo turned about the pole, the
    geometry unchanged: 80 renders, ~60 s); its resolved scenario."""
    from starnav.batch.consistency import terrain_renders
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict

    cfg = scenario_to_dict(scenario_from_dict(demo_scenario(), SHORT_ARC))
    return cfg, terrain_renders(cfg, RUNS)


def _consistency(cfg, per_run, overrides: list[str]):
    from starnav.batch.consistency import filter_consistency, noise_monte_carlo
    from starnav.config import scenario_from_dict, scenario_to_dict

    c = scenario_to_dict(scenario_from_dict(cfg, overrides))
    return filter_consistency(noise_monte_carlo(c, RUNS, per_run=per_run))


@pytest.mark.slow
def test_filter_is_consistent_on_a_smooth_moon_over_noise_runs():
    """Issue 13 (CI): 8 rendered, exposed frames at 0.015 ms of a smooth (terrain-free) Moon;
    20 Monte Carlo runs over detector noise, attitude knowledge error and initial error, each
    through the whole chain and the filter (no bias states): the run-averaged NEES lies in the
    two-sided 99 % chi-square band of a 20-run mean (a consistent filter fails with probability
    ~1 %; the steps of a run are correlated, so the test is looser than its nominal rate)."""
    from starnav.batch.consistency import filter_consistency, noise_monte_carlo
    from starnav.batch.presets import demo_scenario
    from starnav.config import scenario_from_dict, scenario_to_dict

    cfg = scenario_to_dict(scenario_from_dict(demo_scenario(), [
        "trajectory.duration_days=0.3", "trajectory.cadence_s=3600", "render.spp=8",
        "moon.shape=sphere", "navigation.filter.bias_model=none"]))
    res = filter_consistency(noise_monte_carlo(cfg, RUNS))
    assert res["consistent"], (res["nees_mean"], res["band"])


def test_filter_with_tuned_bias_states_is_consistent_on_the_real_moon(demo_arc):
    """Issue 13 (CI): the real Moon (LOLA + LROC, the demo arc, 0.015 ms; a truth with
    planets, SRP and J2 the filter does not model), 20 runs over the terrain in view, detector
    noise, attitude knowledge and initial error, the bias states tuned on *other* arcs
    (tools/tune_bias_states.py -> the demo preset): NEES (time-averaged, effective-sample band)
    and NIS inside their two-sided 99 % bands, no epoch above its per-epoch band and at least
    3 of the 4 inside it (PER_EPOCH_MIN); the paper's
    HIL accuracy (final position error < 0.5 % of range, seed paper, HIL 0.015 ms); the
    3-sigma bounds hold the errors at their rate (99.73 % for a consistent filter; >= 97 %
    asked of 480 time-correlated samples)."""
    res = _consistency(*demo_arc, [])
    assert res["consistent"], (res["nees_mean"], res["band"])
    assert res["nees"]["epochs_above"] == 0.0, res["nees_per_step"]
    assert res["nees"]["epochs_in_band"] >= PER_EPOCH_MIN, res["nees_per_step"]
    assert res["nees_position"]["verdict"] == "consistent", res["nees_position"]
    assert res["nis_band"][0] <= res["nis_mean"] <= res["nis_band"][1], res["nis_mean"]
    assert res["final_position_error_pct_range"]["median"] < 0.5
    assert res["final_position_error_pct_range"]["p90"] < 0.5
    assert res["within_3sigma"]["all"] >= 0.97, res["within_3sigma"]


def test_filter_with_tuned_bias_states_is_consistent_at_7_7_ms(demo_arc):
    """Issue 13 (CI): the paper's saturated 7.7 ms case on the same rendered frames (the demo's
    2048 DN segment threshold and its bias states, tuned on other arcs): consistent over 20
    runs (time-averaged, and at least 3 of the 4 epochs inside their 95 % band), and the
    paper's HIL result for it, final errors < 1 % (seed paper, 7.7 ms)."""
    from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES

    over = dict(DEMO_EXPOSURE_OVERRIDES)[7.7e-3]
    res = _consistency(*demo_arc, ["detector.exposure_time_s=0.0077", *over])
    assert res["consistent"], (res["nees_mean"], res["band"])
    assert res["nees"]["epochs_above"] == 0.0, res["nees_per_step"]
    assert res["nees"]["epochs_in_band"] >= PER_EPOCH_MIN, res["nees_per_step"]
    assert res["final_position_error_pct_range"]["p90"] < 1.0
    assert res["within_3sigma"]["all"] >= 0.97, res["within_3sigma"]


def test_sweep_report_states_consistency_per_point():
    """The sweep report's consistency section: per point, the verdict of
    consistency_metrics (time-averaged NEES against its autocorrelation-corrected band) with
    that band, the position and velocity NEES and the epochs inside the per-epoch band; a
    consistent point (NEES chi2(6)), an overconfident (x 4) and a pessimistic one (x 0.2)."""
    from starnav.batch.consistency import consistency_metrics
    from starnav.batch.report import consistency_section
    from starnav.batch.tasks import PointResult

    rng = np.random.default_rng(2)
    R, K = 4, 12
    cons = {}
    for i, scale in enumerate((1.0, 4.0, 0.2)):
        e = rng.standard_normal((R, K, 6))
        res = PointResult(
            point=i, rows=[{"final_position_error_pct_range": 0.1}] * R,
            epochs=np.arange(K, dtype=float), errors=e * math.sqrt(scale),
            sigma3=np.full((R, K, 6), 3.0), limb_errors_px=np.empty(0, np.float32),
            nees=scale * np.sum(e * e, axis=2),
            nees_position=scale * np.sum(e[..., :3] ** 2, axis=2),
            nees_velocity=scale * np.sum(e[..., 3:] ** 2, axis=2))
        cons[i] = consistency_metrics(res)
    assert [c["verdict"] for c in cons.values()] == ["consistent", "overconfident",
                                                     "pessimistic"]
    summ = [{"point": i, "label": f"p{i}", "exposure_time_s": t}
            for i, t in enumerate((1.5e-5, 7.7e-3, 1.8e-4))]
    text = "\n".join(consistency_section(summ, R, cons))
    lo, hi = cons[1]["nees_band"]
    assert (f"| 1 | p1 | 7.7 | {cons[1]['nees_mean']:.2f} | {lo:.2f}-{hi:.2f} | "
            f"{cons[1]['nees_position']['mean']:.2f} | ") in text
    assert "| 0 | p0 | 0.015 |" in text and "consistent |" in text
    assert "Not consistent at 0.18 ms (pessimistic), 7.7 ms (overconfident)" in text
    assert "no consistency verdict" in "\n".join(consistency_section(summ, 1, {}))


def test_model_error_calibration_recovers_known_terms():
    """The method of moments of tools/calibrate_refine_model_error.py on synthetic records
    drawn with known terms: edge model error per phase bin, saturated extra, terrain scale and
    the fix-level covariance come back within their sampling error (thousands of points,
    500 fixes: ~5 % on the standard deviations)."""
    from starnav.batch.consistency import calibrate_model_error

    class Topo:                     # the DEM's limb-height spread as fractions of the radius
        common_fraction = 6e-4

        @staticmethod
        def sigma_fraction_over(arc):
            return 9e-4

    rng = np.random.default_rng(5)
    se_true, ss_true, k_true = (0.03, 0.08, 0.10), (0.05, 0.09, 0.15), 1.3
    C_true = np.array([[4e-6, -3e-6, 0.0], [-3e-6, 6e-6, 0.0], [0.0, 0.0, 1e-6]])

    def table(n_frames, terrain, saturated):
        cols = {k: [] for k in ("error", "fit_sigma", "saturated", "radius", "phase",
                                "sun_angle", "frame", "run")}
        for f in range(n_frames):
            ph = rng.uniform(0.2, 2.4)
            b = int(np.searchsorted([0, math.radians(90), math.radians(120)], ph, "right")) - 1
            R = rng.uniform(50, 110)
            phi = rng.uniform(-1.4, 1.4, 16)
            fit = rng.uniform(0.005, 0.02, 16)
            own = fit**2 + se_true[b] ** 2 + (ss_true[b] ** 2 if saturated else 0.0)
            if terrain:
                own = own + (k_true * 9e-4 * R) ** 2
            e = rng.standard_normal(16) * np.sqrt(own)
            if terrain:
                a, bb, c = np.linalg.cholesky(C_true * R**2) @ rng.standard_normal(3)
                e = e + a + bb * np.cos(phi) + c * np.sin(phi)
            for k, v in (("error", e), ("fit_sigma", fit), ("saturated", np.full(16, saturated)),
                         ("radius", np.full(16, R)), ("phase", np.full(16, ph)),
                         ("sun_angle", phi), ("frame", np.full(16, f)), ("run", np.zeros(16))):
                cols[k].append(v)
        return {k: np.concatenate(v) for k, v in cols.items()}

    smooth = {k: np.concatenate([a, b]) for (k, a), b in zip(
        table(300, False, False).items(), table(300, False, True).values(), strict=True)}
    smooth["frame"] = np.arange(smooth["frame"].size) // 16
    terrain = table(400, True, False)
    W = [np.diag(rng.uniform(0.5, 2.0, 3)) * 1e-6 for _ in range(500)]
    fixes = {"error": np.array([np.linalg.cholesky(C_true + w) @ rng.standard_normal(3)
                                for w in W]),
             "white": np.array(W), "noise": np.array(W), "radius": np.full(500, 70.0),
             "saturated": np.zeros(500, bool), "frame": np.arange(500), "run": np.zeros(500)}
    res = calibrate_model_error(smooth, terrain, fixes, Topo(), 11)
    assert np.allclose(res["edge_model_error_px"], se_true, rtol=0.1)
    assert np.allclose(res["saturated_model_error_px"], ss_true, rtol=0.15)
    assert res["terrain_scale"] == pytest.approx(k_true, rel=0.1)
    C = np.array(res["fix_covariance"])
    assert np.allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(C_true)), rtol=0.1)
    assert C[0, 1] / math.sqrt(C[0, 0] * C[1, 1]) == pytest.approx(-0.61, abs=0.1)


def test_blooming_terms_recover_known_values():
    """The blooming calibration's two estimators on synthetic records with known terms:
    ``shared_covariance_mle`` recovers a shared covariance whose fixes' white parts span
    a factor 10^4 along one mode (a short stretch of limb), where the method of moments
    scatters by several times the term (and can turn indefinite);
    ``saturated_extra_by_phase`` recovers a saturated window's extra per bin through each
    frame's shared offset and Sun-ward shift (~5 % sampling error)."""
    from starnav.batch.consistency import saturated_extra_by_phase, shared_covariance_mle
    from starnav.navigation.refine import ModelErrorCalibration

    rng = np.random.default_rng(11)
    C_true = np.array([[1.5e-3, -2e-4, 0.0], [-2e-4, 5e-4, 0.0], [0.0, 0.0, 1.5e-4]])
    n = 400
    W = np.array([np.diag([1e-6, 1e-6, 1e-6 * (1e4 if i % 5 == 0 else 1.0)])
                  for i in range(n)])
    e = np.array([np.linalg.cholesky(C_true + w) @ rng.standard_normal(3) for w in W])
    fixes = {"error": e, "white": W}
    C = shared_covariance_mle(fixes, np.ones(n, bool))
    assert np.allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(C_true)), rtol=0.12)
    moments = np.mean([np.outer(x, x) - w for x, w in zip(e, W, strict=True)], axis=0)
    # why the likelihood is used: the moments' sampling error on that mode is ~5x its size
    assert abs(moments[2, 2] - C_true[2, 2]) > 2 * abs(C[2, 2] - C_true[2, 2])
    with pytest.raises(ValueError, match="at least 6"):
        shared_covariance_mle(fixes, np.arange(n) < 3)

    cal = ModelErrorCalibration((0.0, 180.0), (0.05,), (0.0,))
    extra_true = {0: 2.0, 1: 0.8, 2: 0.15}
    cols = {k: [] for k in ("error", "fit_sigma", "saturated", "radius", "phase", "sun_angle",
                            "frame", "run")}
    for f in range(360):
        b = f % 3
        ph = math.radians((30.0, 75.0, 140.0)[b])
        phi = rng.uniform(-1.4, 1.4, 12)
        fit = rng.uniform(0.05, 0.2, 12)
        err = (rng.standard_normal(12) * np.sqrt(fit**2 + 0.05**2 + extra_true[b] ** 2)
               + rng.normal(0, 3.0) + rng.normal(0, 1.0) * np.cos(phi))
        for k, v in (("error", err), ("fit_sigma", fit), ("saturated", np.ones(12, bool)),
                     ("radius", np.full(12, 80.0)), ("phase", np.full(12, ph)),
                     ("sun_angle", phi), ("frame", np.full(12, f)), ("run", np.zeros(12))):
            cols[k].append(v)
    points = {k: np.concatenate(v) for k, v in cols.items()}
    got = saturated_extra_by_phase(points, cal, None, 11, (0.0, 60.0, 90.0, 180.0))
    assert np.allclose(got, [extra_true[b] for b in range(3)], rtol=0.1), got


def test_fix_phase_scales_recover_known_factors():
    """starnav.batch.consistency.fix_phase_scales on synthetic fixes whose slowly varying
    error has covariance ``s_b C`` in bin ``b`` of phase (s = 0.5, 1, 3): each factor is
    recovered within 20 % (the bin's mean NEES of 300 fixes scatters by ~7 %); a bin
    without enough fixes takes its neighbour's; saturated fixes are kept apart."""
    from starnav.batch.consistency import fix_phase_scales

    rng = np.random.default_rng(5)
    C = np.array([[4.0, -3.0, 0.5], [-3.0, 6.0, -1.0], [0.5, -1.0, 1.0]])
    truth = {0: 0.5, 1: 1.0, 2: 3.0}
    centres = {0: 45.0, 1: 105.0, 2: 140.0}
    err, white, phase, sat = [], [], [], []
    for b, s in truth.items():
        for _ in range(300):
            W = np.diag(rng.uniform(0.5, 2.0, 3))
            err.append(rng.multivariate_normal(np.zeros(3), W + s * C))
            white.append(W)
            phase.append(math.radians(centres[b]))
            sat.append(False)
    # two saturated fixes far off: ignored by the well-exposed factors
    for _ in range(2):
        err.append(np.full(3, 100.0))
        white.append(np.eye(3))
        phase.append(math.radians(140.0))
        sat.append(True)
    fixes = {"error": np.array(err), "white": np.array(white), "phase": np.array(phase),
             "saturated": np.array(sat)}
    got = fix_phase_scales(fixes, C, saturated=False)
    for b, s in truth.items():
        assert got[b] == pytest.approx(s, rel=0.2), got
    # only bin 0 calibrated: the others take its factor
    only0 = {k: v[:300] for k, v in fixes.items()}
    assert fix_phase_scales(only0, C, saturated=False) == pytest.approx([got[0]] * 3)
