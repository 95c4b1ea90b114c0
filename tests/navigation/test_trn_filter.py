"""The fly-by estimator (issue 16 items 5-6): Jacobians by central differences, ray casting
against closed forms, a noise-free run that stays on truth, the Monte Carlo consistency and the
accuracy at closest approach on synthetic measurements of an Itokawa fly-by, bad inputs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from pydantic import ValidationError

from starnav.batch.flyby_synthetic import flyby_monte_carlo, flyby_sweep
from starnav.bodies.small_body import ShapeModelBody
from starnav.camera import Camera
from starnav.errors import ConfigError, StarnavError
from starnav.navigation.metrics import chi2_band
from starnav.navigation.schema import NavigationConfig, TrnConfig, TrnFilterConfig
from starnav.navigation.trn.body_view import BodyInCamera, lit_silhouette, raycast, visible
from starnav.navigation.trn.filter import (
    centroid_model,
    features_model,
    landmark_births,
    propagate,
    radius_model,
    rotation_vector_matrix,
    run_filter,
    silhouette_offset,
    silhouette_scale,
)
from starnav.navigation.trn.measurements import FeatureObservation, FlybyMeasurement
from starnav.navigation.trn.metrics import (
    FlybyMetrics,
    plot_flyby_errors,
    plot_flyby_nees,
    plot_tracks,
    track_lengths,
    write_report,
)
from starnav.navigation.trn.synthetic import (
    SyntheticOptions,
    flyby_truth,
    run_measurements,
)
from starnav.scenes.flyby import flyby_from_config
from starnav.scenes.schema import FlybyConfig

ARCSEC = math.pi / 180 / 3600
#: Central-difference steps: position [m], rotation [rad], pixel [px].
H_POS, H_ROT, H_PX = 1e-2, 1e-7, 1e-4
#: The Monte Carlo: Itokawa passed at 10 km and 1 km/s, Sun phase 45 deg at CA, a frame every
#: 4 s from 40 s before to 40 s after CA (range 41 km -> 10 km -> 41 km).
RUNS = 20
EPOCHS = np.arange(-40.0, 40.01, 4.0)
#: The accuracy required at CA: 1 % of the range (100 m at 10 km): the limb navigation's
#: requirement (docs/navigation.md) carried over; the centroid alone gives ~0.4 px x 355 urad
#: x 10 km = 1.4 m across the line of sight and the apparent radius (56 px +- 0.3 px) 0.5 %
#: along it, so 1 % is met with margin once the features tie the motion together.
CA_FRACTION = 0.01
#: The filter's settings for synthetic measurements, whose features are independent draws and
#: whose silhouette is the lit-facet model itself: a small model error (0.3 px, 1 %,
#: unscaled), no divergence reset (the scenario's values are the rendered frames'
#: calibration).
SMALL = {"feature_correlation": 0.0, "silhouette_scaling": "constant",
         "centroid_model_sigma_px": 0.3, "radius_model_fraction": 0.01, "reset_after": 0}


def _opt(**keys):
    """The SI filter settings of SMALL with ``keys`` (scenario keys) changed."""
    return TrnFilterConfig(**{**SMALL, **keys}).to_si()
ZERO3 = np.zeros(3)


def fd(f, x, h):
    x = np.asarray(x, float)
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = h
        cols.append((np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.fixture(scope="module")
def body():
    return ShapeModelBody()


@pytest.fixture(scope="module")
def camera():
    return Camera.preset("aa-str", k1=-0.05, p1=1e-4)


@pytest.fixture(scope="module")
def flyby(body):
    cfg = FlybyConfig(v_inf_km_s=1.0, closest_approach_km=10.0, phase_at_ca_deg=45.0)
    return flyby_from_config(cfg, epoch_ca=0.0, gm=body.gm)


@pytest.fixture(scope="module")
def truth(flyby, body, camera):
    return flyby_truth(flyby, body, camera, EPOCHS, SyntheticOptions(max_features=20), seed=1)


# ----------------------------------------------------------------------------- Jacobians
def _pose(truth, k):
    return truth.states[k, :3], truth.R_cam_to_inertial[k], truth.R_body_to_inertial[k]


def test_feature_jacobians_match_central_differences(truth, camera):
    r, R_m, R_bi = _pose(truth, 10)
    L = truth.candidates[truth.trackable[10]][:5]
    dth = np.array([2e-5, -1e-5, 3e-5])
    _, Hr, Hl, Ht, front = features_model(camera, r, L, R_m, R_bi, np.zeros(3))
    assert front.all()
    for i in range(L.shape[0]):
        def at(r_=r, l_=L[i], t_=ZERO3):
            return features_model(camera, r_, l_[None], R_m, R_bi, t_)[0][0]
        np.testing.assert_allclose(Hr[i], fd(lambda v: at(r_=v), r, H_POS), rtol=1e-5,
                                   atol=1e-9)
        np.testing.assert_allclose(Hl[i], fd(lambda v: at(l_=v), L[i], H_POS), rtol=1e-5,
                                   atol=1e-9)
        np.testing.assert_allclose(Ht[i], fd(lambda v: at(t_=v), np.zeros(3), H_ROT),
                                   rtol=1e-4, atol=1e-3)
    # the attitude convention: R_true = R_m exp([dth]x) sees the point where R_m sees it moved
    p = features_model(camera, r, L[:1], R_m, R_bi, dth)[0][0]
    R_true = R_m @ rotation_vector_matrix(dth)
    q = camera.project(R_true.T @ (R_bi @ L[0] - r))
    np.testing.assert_allclose(p, q, atol=1e-9)


def test_centroid_radius_and_prediction_jacobians(truth, camera, body):
    r, R_m, _ = _pose(truth, 10)
    D = np.array([30.0, -20.0, 10.0])
    _, Hr, Ht = centroid_model(camera, r, D, R_m)
    np.testing.assert_allclose(Hr, fd(lambda v: centroid_model(camera, v, D, R_m)[0], r, H_POS),
                               rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(
        Ht, fd(lambda v: centroid_model(camera, r, D, R_m, v)[0], np.zeros(3), H_ROT),
        rtol=1e-4, atol=1e-3)
    _, Hrad = radius_model(r, 5e5)
    np.testing.assert_allclose(Hrad, fd(lambda v: [radius_model(v, 5e5)[0]], r, H_POS),
                               rtol=1e-6)
    x = np.r_[r, truth.states[10, 3:]]
    _, Phi, Q = propagate(x, 25.0, 5e3, 1e-8)   # a strong GM, so the gradient term counts
    np.testing.assert_allclose(Phi, fd(lambda v: propagate(v, 25.0, 5e3, 0.0)[0], x, 1e-2),
                               rtol=1e-6, atol=1e-9)
    # white-acceleration noise: Q_rr = q dt^3 / 3 (Bar-Shalom et al. 2001, eq. 6.2.2-12)
    assert propagate(x, 25.0, 0.0, 1e-8)[2][0, 0] == pytest.approx(1e-8 * 25.0**3 / 3)


def test_landmark_birth_jacobians_match_central_differences(truth, camera, body):
    r, R_m, R_bi = _pose(truth, 10)
    uv = truth.uv[10][truth.trackable[10]][:3]
    b0 = landmark_births(camera, r, R_m, R_bi, uv, shape=body.shape)
    for i, b in enumerate(b0):
        assert b is not None
        # the ray from the true pose lands on the true surface point
        np.testing.assert_allclose(b.point_body,
                                   truth.candidates[truth.trackable[10]][i], atol=1e-6)

        def pt(r_=r, t_=ZERO3, uv_=uv[i]):
            R = R_m @ rotation_vector_matrix(t_)
            return landmark_births(camera, r_, R, R_bi, uv_, shape=body.shape)[0].point_body
        np.testing.assert_allclose(b.J_r, fd(lambda v: pt(r_=v), r, 1e-3), rtol=1e-4,
                                   atol=1e-6)
        np.testing.assert_allclose(b.J_theta, fd(lambda v: pt(t_=v), np.zeros(3), 1e-8),
                                   rtol=1e-3, atol=1e-2)
        np.testing.assert_allclose(b.J_uv, fd(lambda v: pt(uv_=v), uv[i], H_PX), rtol=1e-4,
                                   atol=1e-6)


def test_raycast_on_a_sphere_against_its_closed_form():
    """Icosphere of radius 100 m 1 km ahead: the boresight hits the vertex at 900 m exactly;
    every hit lies on the facets, between the sphere and the facets' inner sphere (sagitta
    R (1 - cos(e/2)) < 0.4 m for the 0.16 rad edges of 642 vertices) and no nearer than the
    sphere's own hit d cos(a) - sqrt(R^2 - d^2 sin^2 a); a ray past the limb misses; the far
    side is not visible."""
    m = trimesh.creation.icosphere(subdivisions=3, radius=100.0)
    b = BodyInCamera.place(m.vertices, m.faces, np.eye(3), [0.0, 0.0, 1000.0])
    a = np.radians([0.0, 3.0, 5.5, 6.0])
    dirs = np.column_stack([np.sin(a), np.zeros(4), np.cos(a)])
    t, face = raycast(b, dirs)
    want = 1000 * np.cos(a[:3]) - np.sqrt(100.0**2 - (1000 * np.sin(a[:3])) ** 2)
    assert t[0] == pytest.approx(900.0, abs=1e-9)
    hit_radius = np.linalg.norm(dirs[:3] * t[:3, None] - [0.0, 0.0, 1000.0], axis=1)
    assert np.all((hit_radius <= 100.0 + 1e-9) & (hit_radius >= 99.6)), hit_radius
    assert np.all(t[:3] >= want - 1e-9)
    assert face[3] == -1 and math.isinf(t[3])
    assert visible(b, [[0.0, 0.0, 900.0 + 0.1]], tolerance=0.5).all()
    assert not visible(b, [[0.0, 0.0, 1100.0]], tolerance=0.5).any()
    # a ray inside a facet's bounding box but off the facet: no hit (not an error; met
    # between a limb facet's box corner and its hypotenuse)
    tri = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]])
    one = BodyInCamera.place(tri, np.array([[0, 2, 1]]), np.eye(3), [0.0, 0.0, 100.0])
    t1, f1 = raycast(one, [[0.09, 0.09, 1.0]])       # (9, 9) at 100 m: beyond x + y = 10
    assert f1[0] == -1 and math.isinf(t1[0])
    t2, f2 = raycast(one, [[0.01, 0.01, 1.0], [0.09, 0.09, 1.0]])
    assert f2.tolist() == [0, -1] and t2[0] == pytest.approx(math.sqrt(2e-4 + 1) * 100.0)


# ----------------------------------------------------------------------------- runs
def _noise_free(truth):
    return replace(SyntheticOptions(max_features=20), pixel_sigma_px=1e-4,
                   attitude_sigma=(0.0, 0.0, 0.0), centroid_sigma_px=1e-4,
                   radius_sigma_px=1e-4)


def test_noise_free_run_converges_to_truth(truth, camera, body):
    """Noise-free measurements, the start 800 m and 3 m/s off: the filter's only errors are
    initial error, shrunk by the information gathered: at CA the position is within 20 m of
    truth (0.2 % of range: 40 times less than at the start) and the velocity within 2 m/s,
    inside the 3-sigma bounds."""
    meas = run_measurements(truth, 0, 0, _noise_free(truth))
    P0 = TrnFilterConfig().initial_covariance()
    x0 = truth.states[0] + np.array([600.0, -500.0, 200.0, 3.0, -2.0, 1.0])
    opt = _opt(centroid_model_sigma_px=0.02, radius_model_fraction=1e-3)
    run = run_filter(meas, camera, body, x0, P0, opt, sun_direction=truth.sun_direction)
    e = run.errors(truth.states)
    k = int(np.argmin(np.abs(EPOCHS)))
    assert np.linalg.norm(e[k, :3]) < 20.0, e[k]
    assert np.linalg.norm(e[k, 3:]) < 2.0, e[k]
    assert np.all(np.abs(e[k]) <= run.sigma3()[k])
    assert run.features_used.sum() > 100 and run.features_rejected.sum() == 0


@pytest.fixture(scope="module")
def mc(truth, camera, body):
    # the synthetic features' errors are independent draws: no shared part, and the
    # synthetic silhouette is the lit-facet model itself: no model error beyond the
    # small model error (SMALL: 0.3 px, 1 %, unscaled); the scenario's values are the
    # rendered frames' calibration (tools/calibrate_flyby_model_error.py)
    c = TrnFilterConfig(feature_correlation=0.0, silhouette_scaling="constant",
                        centroid_model_sigma_px=SMALL["centroid_model_sigma_px"],
                        radius_model_fraction=SMALL["radius_model_fraction"])
    return flyby_monte_carlo(truth, camera, body, RUNS, c.initial_covariance(), seed=11,
                             synthetic=SyntheticOptions(max_features=20), options=c.to_si())


def test_monte_carlo_mean_nees_inside_its_chi2_band(mc):
    """NEES of the 6 states, averaged over 20 runs and over the frames, inside its two-sided
    99 % band of R K / tau effective samples (metrics.anees_statistics): narrower than the
    band of a 20-run mean, chi2.ppf([0.005, 0.995], 120) / 20 = [4.19, 8.18], wider than that
    of 20 x K independent samples; a consistent filter fails with probability ~1 %. The NEES
    at CA alone against the exact band of a 20-run mean."""
    s = mc.summary
    lo, hi = chi2_band(6, RUNS, 0.99)
    li, hi_i = s["nees_band_independent"]
    assert lo <= s["nees_band"][0] <= li and hi_i <= s["nees_band"][1] <= hi
    assert s["nees_band"][0] <= s["nees_mean"] <= s["nees_band"][1], (s["nees_mean"],
                                                                      s["nees_band"])
    assert s["nees_ca_band"] == pytest.approx([lo, hi])
    assert lo <= s["nees_ca"] <= hi, s["nees_ca"]
    assert s["verdict"] == "consistent"


def test_position_error_at_closest_approach_below_one_percent_of_range(mc):
    """Every run: |r_hat - r| at CA < 1 % of the 10 km range (CA_FRACTION, argued above)."""
    pct = [m.ca_position_error_pct_range for m in mc.metrics]
    assert max(pct) < 100 * CA_FRACTION, pct
    assert all(m.ca_range_m == pytest.approx(10_000.0) for m in mc.metrics)


def test_gate_rejects_tracker_jumps(truth, camera, body):
    """5 % of observations moved by 15 px (50 sigma): the chi-square gate (0.9999) rejects
    them and the CA error stays below 1 % of range."""
    syn = replace(SyntheticOptions(max_features=20), outlier_fraction=0.05)
    meas = run_measurements(truth, 5, 0, syn)
    jumps = sum(np.linalg.norm(f.uv - t.uv_true) > 5 for m in meas
                for f, t in zip(m.features, m.truth, strict=True))
    c = TrnFilterConfig(feature_correlation=0.0)   # independent synthetic features
    run = run_filter(meas, camera, body, truth.states[0], c.initial_covariance(), c.to_si(),
                     sun_direction=truth.sun_direction)
    assert jumps > 10
    # a jump of a track not yet a landmark is spent on its birth, so rejections <= jumps
    assert 0.5 * jumps <= run.features_rejected.sum() <= jumps
    m = FlybyMetrics.of(run, meas, truth.states, truth.epoch_ca)
    assert m.ca_position_error_pct_range < 100 * CA_FRACTION


# ----------------------------------------------------------------------------- metrics
def test_metrics_tracks_figures_and_report(mc, truth, tmp_path):
    meas = run_measurements(truth, 11, 0, SyntheticOptions(max_features=20))
    run = mc.runs[0]
    m = FlybyMetrics.of(run, meas, truth.states, truth.epoch_ca)
    assert m == mc.metrics[0]
    L = track_lengths(meas)
    assert L.sum() == sum(len(x.features) for x in meas) and m.tracks == L.size
    # the synthetic pixel noise is 0.3 px per axis: |error| has rms 0.3 sqrt(2)
    assert m.feature_error_rms_px == pytest.approx(0.3 * math.sqrt(2), rel=0.1)
    d = m.as_dict()
    assert all(isinstance(v, (int, float)) or v is None for v in d.values())
    t = truth.epochs - truth.epoch_ca
    figs = [plot_flyby_errors(t, run.errors(truth.states), run.sigma3(), tmp_path / "p.png"),
            plot_flyby_nees(t, mc.nees.mean(axis=0), tmp_path / "n.png", runs=RUNS),
            plot_tracks(t, meas, run, tmp_path / "t.png")]
    assert all(f.stat().st_size > 1000 for f in figs)
    rep = write_report(tmp_path / "report.md", m, mc.summary, [str(f) for f in figs])
    text = rep.read_text()
    assert f"{m.ca_position_error_m:.1f} m" in text and "consistent" in text


def test_sweep_over_closest_approach_scales_the_ca_uncertainty(body, camera):
    """Two CA distances, 2 runs each, the same frames: the 3-sigma position bound at CA grows
    with the CA distance (bearing and radius errors scale with range)."""
    P0 = TrnFilterConfig().initial_covariance()
    rows = flyby_sweep(body, camera, v_inf_km_s=[1.0], closest_approach_km=[10.0, 20.0],
                       phase_deg=[45.0], span_s=20.0, cadence_s=5.0, runs=2,
                       initial_covariance=P0, synthetic=SyntheticOptions(max_features=15),
                       options=_opt())
    assert [r["closest_approach_km"] for r in rows] == [10.0, 20.0]
    assert rows[1]["median_ca_position_3sigma_m"] > rows[0]["median_ca_position_3sigma_m"]
    assert rows[0]["median_ca_range_m"] == pytest.approx(10_000.0)
    with pytest.raises(ConfigError, match="phase_deg"):
        flyby_sweep(body, camera, v_inf_km_s=[1.0], closest_approach_km=[10.0], phase_deg=[],
                    span_s=20.0, cadence_s=5.0, runs=2, initial_covariance=P0)


# ----------------------------------------------------------------------------- bad inputs
def _meas(epoch, **kw):
    base = dict(frame_index=0, epoch_tdb=epoch, R_cam_to_inertial=np.eye(3),
                attitude_sigma=np.full(3, 5 * ARCSEC))
    base.update(kw)
    return FlybyMeasurement(**base)


@pytest.mark.parametrize("meas, x0, P0, field", [
    ([], np.zeros(6), np.eye(6), "measurements"),
    ([_meas(1.0), _meas(1.0)], np.ones(6), np.eye(6), r"measurements\[1\].epoch_tdb"),
    ([_meas(0.0)], np.ones(5), np.eye(6), "initial_state"),
    ([_meas(0.0)], np.ones(6), np.eye(5), "initial_covariance"),
    ([_meas(0.0)], np.ones(6), -np.eye(6), "initial_covariance"),
    ([_meas(0.0, R_cam_to_inertial=np.ones((3, 3)))], np.ones(6), np.eye(6),
     r"measurements\[0\].R_cam_to_inertial"),
    ([_meas(0.0, attitude_sigma=np.ones(2))], np.ones(6), np.eye(6),
     r"measurements\[0\].attitude_sigma"),
    ([_meas(0.0, features=(FeatureObservation(1, np.ones(3), 0.3),))], np.ones(6), np.eye(6),
     r"measurements\[0\].features\[0\].uv"),
    ([_meas(0.0, centroid_uv=np.ones(3))], np.ones(6), np.eye(6),
     r"measurements\[0\].centroid_uv"),
])
def test_bad_inputs_name_the_field(body, camera, meas, x0, P0, field):
    with pytest.raises(StarnavError, match=field):
        run_filter(meas, camera, body, x0, P0)


def test_config_is_read_in_si():
    c = NavigationConfig.model_validate(
        {"trn": {"filter": {"max_incidence_deg": 60, "initial_position_sigma_km": 2}}})
    assert isinstance(c.trn, TrnConfig)
    o = c.trn.filter.to_si()
    assert o.max_incidence == pytest.approx(math.radians(60))
    assert c.trn.filter.initial_covariance()[0, 0] == pytest.approx(2000.0**2)
    with pytest.raises(ValueError, match="max_incidence_deg"):
        NavigationConfig.model_validate({"trn": {"filter": {"max_incidence_deg": 95}}})


# ----------------------------------------------------------------------------- shared bias
#: Runs of the shared-bias Monte Carlo (each run draws its own silhouette bias).
BIAS_RUNS = 10


def _biased_runs(truth, camera, body, options, seed=5, offset=None, mean=(0.0, 0.0, 0.0)):
    """BIAS_RUNS synthetic runs whose silhouette carries a model error shared by every frame
    of the run, as the rendered frames' (tools/calibrate_flyby_model_error.py): along the
    Sun's image direction N(0, sa), across it N(0, sx), the radius scale N(0, sr), with the
    filter's default sigmas (the calibrated ones), plus ``mean`` (along, across [px], radius
    fraction). Returns the NEES (runs, frames)."""
    o = _opt()
    sa = o.centroid_model_sigma_px * math.sqrt(2 * o.centroid_sun_share)
    sx = o.centroid_model_sigma_px * math.sqrt(2 * (1 - o.centroid_sun_share))
    P0 = TrnFilterConfig().initial_covariance()
    g = np.random.default_rng(seed)
    out = []
    for r in range(BIAS_RUNS):
        ba, bx, br = g.standard_normal(3) * [sa, sx, o.radius_model_fraction] + mean
        meas = []
        for k, m in enumerate(run_measurements(truth, seed, r, SyntheticOptions(max_features=20))):
            R = truth.R_cam_to_inertial[k]
            e = camera.project_jacobian(R.T @ -truth.states[k, :3]) @ (R.T @ truth.sun_direction)
            e /= np.linalg.norm(e)
            c = m.centroid_uv + ba * e + bx * np.array([-e[1], e[0]])
            rad = m.apparent_radius_px + br * truth.radius_px[k]
            if offset is not None:   # the deterministic part of the error, at the truth
                r_k = truth.states[k, :3]
                off = silhouette_offset(r_k, truth.sun_direction,
                                        truth.radius_px[k] * np.linalg.norm(r_k), offset)
                c, rad = c + off.centroid_px * e, rad + off.radius_px
            meas.append(replace(m, centroid_uv=c, apparent_radius_px=rad))
        x0 = truth.states[0] + np.linalg.cholesky(P0) @ g.standard_normal(6)
        res = run_filter(meas, camera, body, x0, P0, options, sun_direction=truth.sun_direction)
        out.append(res.nees(truth.states))
    return np.array(out)


def test_silhouette_bias_states_keep_a_shared_model_error_consistent(truth, camera, body):
    """The rendered fly-by's diagnosis in closed form: the silhouette's model error is the same
    in every frame of a run (a bias), not white. With the first-order Gauss-Markov bias states
    (correlation time 85 s, longer than this 80 s pass) the mean NEES of BIAS_RUNS runs is
    inside the two-sided 99 % band of a BIAS_RUNS-run mean of chi2(6); the same sigmas added
    to each frame as white noise (``silhouette_bias_time = 0``, the old model) make the filter
    overconfident: above the band."""
    lo, hi = chi2_band(6, BIAS_RUNS, 0.99)
    gm = _biased_runs(truth, camera, body, _opt())
    white = _biased_runs(truth, camera, body, _opt(silhouette_bias_time_s=0.0))
    assert lo <= gm.mean() <= hi, gm.mean()
    assert white.mean() > hi, white.mean()


def test_silhouette_offset_closed_forms_and_gradients(truth):
    """The deterministic offset (filter step 4c) against its closed forms: the centroid
    ``c rho sin(alpha)``, the radius ``w / (1 + cos alpha) - rho tan(alpha / 2) delta / 2``
    (at phase 0 only the limb blur's ``w / 2`` px; the same without a Sun), and its gradients
    with respect to ``r`` by central differences."""
    opt = _opt(silhouette_centroid_offset_fraction=0.032, silhouette_limb_blur_px=3.95,
               silhouette_terminator_shift_deg=8.23)
    r = truth.states[10, :3]
    sun = truth.sun_direction
    k = 56.0 * float(np.linalg.norm(r))            # 56 px at this range
    a = math.acos(float(r @ sun) / np.linalg.norm(r))
    off = silhouette_offset(r, sun, k, opt)
    assert off.centroid_px == pytest.approx(0.032 * 56.0 * math.sin(a), rel=1e-12)
    assert off.radius_px == pytest.approx(3.95 / (1 + math.cos(a)) - 56.0 * math.tan(a / 2)
                                          * math.radians(8.23) / 2, rel=1e-12)
    np.testing.assert_allclose(
        off.centroid_grad, fd(lambda v: silhouette_offset(v, sun, k, opt).centroid_px, r, H_POS),
        rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(
        off.radius_grad, fd(lambda v: silhouette_offset(v, sun, k, opt).radius_px, r, H_POS),
        rtol=1e-5, atol=1e-12)
    zero = silhouette_offset(r, r / np.linalg.norm(r), k, opt)
    bare = silhouette_offset(r, None, k, opt)
    for o in (zero, bare):
        assert (o.centroid_px, o.radius_px) == pytest.approx((0.0, 3.95 / 2))
    with pytest.raises(ValidationError, match="silhouette_centroid_offset_fraction"):
        _opt(silhouette_centroid_offset_fraction=0.7)


@pytest.mark.slow
def test_silhouette_offset_in_the_prediction_removes_the_deterministic_error(truth, camera,
                                                                           body):
    """Synthetic runs whose silhouette carries the step-4c offset law (centroid ``0.033 rho
    sin(alpha)`` along the Sun, radius limb blur 3.95 px and terminator shift 8.23 deg: the
    rendered calibration's) on top of the shared random bias of the bias test: with
    ``silhouette_offset`` the filter predicts it and its mean NEES over BIAS_RUNS runs is
    inside the two-sided 99 % band of chi2(6), [3.55, 9.20] (measured 7.69); without, the same
    bias sigmas leave the offset (up to 1.3 px, and +0.6 to +1.9 px of radius at 56 to 14 px)
    unexplained and the NEES is above the band (measured 13.4)."""
    lo, hi = chi2_band(6, BIAS_RUNS, 0.99)
    law = _opt(silhouette_offset=True)
    on = _biased_runs(truth, camera, body, law, offset=law)
    off = _biased_runs(truth, camera, body, _opt(), offset=law)
    assert lo <= on.mean() <= hi, on.mean()
    assert off.mean() > hi, off.mean()


#: The silhouette model error's mean measured on the rendered calibration (along the Sun,
#: across it [px], radius fraction; tools/calibrate_flyby_model_error.py, 40 draws): 3.5 and
#: 2 of the algorithm's default sigmas (0.42 px along, 1 %).
SYSTEMATIC = (1.47, 0.035, 0.0198)


@pytest.mark.slow
def test_bias_mean_in_the_prediction_removes_a_systematic_error(truth, camera, body):
    """Synthetic runs whose shared silhouette bias has a non-zero mean (SYSTEMATIC, filter
    step 4d): with ``bias_mean`` set to it the mean NEES over BIAS_RUNS runs is inside the
    two-sided 99 % band of chi2(6), [3.55, 9.20]; with a zero-mean prior and the same sigmas
    the offset is an error the filter does not know it makes: above the band."""
    lo, hi = chi2_band(6, BIAS_RUNS, 0.99)
    known = _biased_runs(truth, camera, body, _opt(silhouette_bias_mean=SYSTEMATIC),
                         mean=SYSTEMATIC)
    unknown = _biased_runs(truth, camera, body, _opt(), mean=SYSTEMATIC)
    assert lo <= known.mean() <= hi, known.mean()
    assert unknown.mean() > hi, unknown.mean()


def test_divergence_reset_recovers_a_locked_out_run(truth, camera, body):
    """Filter step 5a. The first two frames' silhouettes are wrong (centroid 20 px off,
    radius 5 % large: a glitch) and claim their usual 0.3 px: the honest 1 km prior accepts
    them and the estimate lands ~400 m off with a covariance that excludes the truth. Without
    the rule the gate then rejects every later centroid (lock-out) and the position at CA is
    off by more than 2 % of range; with ``reset_after = 3`` the filter re-opens once, in frame
    4 (after frames 2, 3 and 4 rejected), uses every later centroid and ends at CA below 1 %
    of range, inside its 3-sigma."""
    meas = run_measurements(truth, 3, 0, SyntheticOptions(max_features=20))
    for j in (0, 1):
        m = meas[j]
        meas[j] = replace(m, centroid_uv=m.centroid_uv + np.array([20.0, 0.0]),
                          apparent_radius_px=1.05 * m.apparent_radius_px)
    P0 = TrnFilterConfig().initial_covariance()
    k = int(np.argmin(np.abs(EPOCHS)))
    rng = np.linalg.norm(truth.states[k, :3])
    stuck = run_filter(meas, camera, body, truth.states[0], P0, _opt(),
                       sun_direction=truth.sun_direction)
    reset = run_filter(meas, camera, body, truth.states[0], P0,
                       _opt(reset_after=3), sun_direction=truth.sun_direction)
    assert stuck.info["resets"] == [] and stuck.centroid_used[2:].sum() <= 3
    assert np.linalg.norm(stuck.errors(truth.states)[k, :3]) > 2 * CA_FRACTION * rng
    assert reset.info["resets"] == [4], reset.info["resets"]
    assert reset.centroid_used[4:].all()
    e = reset.errors(truth.states)[k]
    assert np.linalg.norm(e[:3]) < CA_FRACTION * rng, e
    assert np.all(np.abs(e) <= reset.sigma3()[k])
    with pytest.raises(ValidationError, match="reset_after"):
        _opt(reset_after=-1)
    with pytest.raises(ValidationError, match="silhouette_bias_mean"):
        _opt(silhouette_bias_mean=(0.0, 0.0, 0.7))


@pytest.mark.slow
def test_no_reset_on_consistent_runs(truth, camera, body):
    """The divergence rule's false alarm: 20 consistent synthetic runs (the Monte Carlo of
    ``test_monte_carlo_mean_nees_inside_its_chi2_band``'s settings) with ``reset_after = 3``
    never reset."""
    c = TrnFilterConfig(feature_correlation=0.0, silhouette_scaling="constant",
                        centroid_model_sigma_px=SMALL["centroid_model_sigma_px"],
                        radius_model_fraction=SMALL["radius_model_fraction"], reset_after=3)
    mc = flyby_monte_carlo(truth, camera, body, RUNS, c.initial_covariance(), seed=11,
                           synthetic=SyntheticOptions(max_features=20), options=c.to_si())
    assert mc.summary["resets"] == 0


# ----------------------------------------------------------------------------- scaling law
def _sphere_lit(alpha: float, camera: Camera) -> tuple[float, float, float]:
    """Lit-facet centroid offset towards the Sun [px], equivalent radius [px] and the whole
    disc's radius [px] of an icosphere (radius 100 m, 40 km ahead: nearly orthographic) with
    the Sun at phase ``alpha`` in the image's +u direction."""
    m = trimesh.creation.icosphere(subdivisions=6, radius=100.0)
    b = BodyInCamera.place(m.vertices, m.faces, np.eye(3), [0.0, 0.0, 4.0e4])
    sun = [math.sin(alpha), 0.0, -math.cos(alpha)]     # from the body, camera at -z
    lit = lit_silhouette(b, sun, camera)
    disc = lit_silhouette(b, [0.0, 0.0, -1.0], camera)
    return (float(lit.centroid_uv[0] - disc.centroid_uv[0]), lit.radius_px, disc.radius_px)


def test_silhouette_scale_is_the_sphere_terminator_shift_law():
    """The lit sphere against its closed form (half disc plus half ellipse of semi-axis
    ``rho cos alpha``): centroid offset ``4 rho (1 - cos alpha) / (3 pi)`` towards the Sun and
    equivalent radius ``rho sqrt((1 + cos alpha) / 2)``, within 0.5 % of rho (the facets of a
    40 962-vertex icosphere); and ``silhouette_scale``'s factors are the ratios of the
    derivatives of these with respect to a shift of the terminator (central differences of
    3 deg, wider than the facets) between phase 70 (or 30) deg and the reference 50 deg,
    within 3 %: the centroid law the filter scales its bias sigmas with (the radius factor
    with the limb-blur term off: ``limb_blur_px = 0``). "constant" gives ones."""
    camera = Camera.preset("aa-str")
    h = math.radians(3.0)
    deriv = {}
    for deg in (30.0, 50.0, 70.0):
        a = math.radians(deg)
        c, r, rho = _sphere_lit(a, camera)
        assert c == pytest.approx(4 * rho * (1 - math.cos(a)) / (3 * math.pi), abs=5e-3 * rho)
        assert r == pytest.approx(rho * math.sqrt((1 + math.cos(a)) / 2), abs=5e-3 * rho)
        cp, rp, _ = _sphere_lit(a + h, camera)
        cm, rm, _ = _sphere_lit(a - h, camera)
        deriv[deg] = ((cp - cm) / (2 * h), (math.log(rp) - math.log(rm)) / (2 * h), rho)
    law = {"silhouette_reference_radius_px": deriv[50.0][2],
           "silhouette_reference_phase_deg": 50.0, "silhouette_limb_blur_px": 0.0,
           "silhouette_scaling": "geometry"}
    opt = _opt(**law)
    for deg in (30.0, 70.0):
        s = silhouette_scale(deriv[deg][2], math.radians(deg), opt)
        assert s[0] == pytest.approx(s[1])
        assert s[0] == pytest.approx(deriv[deg][0] / deriv[50.0][0], rel=0.03)
        assert s[2] == pytest.approx(deriv[deg][1] / deriv[50.0][1], rel=0.03)
    # twice the apparent radius, twice the centroid factor; the radius factor is a fraction
    s2 = silhouette_scale(2 * deriv[50.0][2], math.radians(50.0), opt)
    assert s2 == pytest.approx([2.0, 2.0, 1.0])
    # the limb-blur term alone: dA = pi rho w over A = pi rho^2 (1 + cos a) / 2, halved
    limb = _opt(**{**law, "silhouette_limb_blur_px": 2.0,
                   "silhouette_terminator_shift_deg": 0.0})
    s3 = silhouette_scale(30.0, math.radians(70.0), limb)
    assert s3[2] == pytest.approx(deriv[50.0][2] * (1 + math.cos(math.radians(50.0)))
                                  / (30.0 * (1 + math.cos(math.radians(70.0)))))
    flat = _opt(**{**law, "silhouette_scaling": "constant"})
    assert silhouette_scale(10.0, 1.2, flat) == pytest.approx([1.0, 1.0, 1.0])
    with pytest.raises(ValidationError, match="silhouette_scaling\n.*'geometry'"):
        _opt(silhouette_scaling="phase")
