"""The fly-by on the AA-STR without the true map: the frame budget against the tracker's readout
law, the estimator's coarse shape model (not the truth), its landmarks against the truth, and
the consistency of a short dispersed pass under the per-epoch statistic.

Synthetic passes (``navigation.trn.synthetic``: the truth is the full Itokawa radar mesh, the
filter navigates on the 500-face coarse model scaled by a per-run draw of 2 % 1-sigma): CA 5 km
at 0.5 km/s, Sun phase 60 deg at CA, from 50 km out to 50 km out (-100 s .. +100 s), a frame
every 4 s (the readout law allows 0.25 s: the long pass at that cadence is the slow test, a
strict xfail: overconfident). The silhouette's model error of these runs
(``scoring.SYNTHETIC_FILTER``) is the coarse map's as calibrated on the two calibration fly-bys
(tools/calibrate_flyby_coarse_map.py: the shape law over phase and apparent size, bias states
correlated over 65 deg of aspect); this pass is the development fly-by, one of them (in
sample; docs/navigation.md, "Asteroid fly-by on the AA-STR"). The out-of-sample score is the
record of ``tools/score_flyby.py``. On a large body (Eros, the development fly-bys of
``scoring.DEVELOPMENT_FLYBYS``): the map-error terms follow the navigated model's own
departure, and the centroid bias stays an image offset when the Sun's image direction turns.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest
from scipy.stats import chi2

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from starnav.batch.flyby import estimator_body, flyby_closed_loop
from starnav.batch.flyby_synthetic import flyby_monte_carlo
from starnav.batch.presets import flyby_scenario
from starnav.bodies.mesh import icosphere_mesh
from starnav.bodies.schema import ShapeModelConfig
from starnav.bodies.small_body import ShapeModelBody
from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.data import packaged_path
from starnav.detector.products import MAX_WINDOWS
from starnav.errors import ConfigError
from starnav.navigation.metrics import anees_statistics
from starnav.navigation.schema import TrnFilterConfig, TrnShapeModelConfig
from starnav.navigation.trn.body_model import coarse_of, estimator_model
from starnav.navigation.trn.body_view import BodyInCamera, lit_silhouette
from starnav.navigation.trn.filter import (
    ShapePrior,
    aspect_change,
    crescent_term,
    map_error_factor,
    run_filter,
    silhouette_scale,
)
from starnav.navigation.trn.scoring import (
    CALIBRATION_FLYBYS,
    CRESCENT_CALIBRATION_FLYBYS,
    DEVELOPMENT_FLYBYS,
    SCORING_FLYBYS,
    SCORING_SEED,
    SPENT_FLYBYS,
    SPENT_SEEDS,
    SYNTHETIC,
    SYNTHETIC_FILTER,
    TARGETS,
    read_record,
)
from starnav.navigation.trn.synthetic import boresight_attitude, flyby_truth, run_measurements
from starnav.scenes.flyby import flyby_from_config
from starnav.scenes.schema import FlybyConfig
from starnav.simulate import Simulator
from starnav.simulate.build import body_from_scenario
from starnav.simulate.flyby import flyby_exposures
from starnav.simulate.trn import flyby_frame_budget, track_flyby

#: The AA-STR's readout law as the seed paper gives it (eq. 1: 8 ms + 0.17 ms per unit of
#: N_pix, a unit of 1000 px; a full-array scan at least 200 ms) [s]; written out here, not
#: read from the code under test.
LAW_A, LAW_B, LAW_UNIT, LAW_FULL = 8e-3, 0.17e-3, 1000.0, 0.2
SEED = 11
RUNS = 4
SYN = SYNTHETIC


def preset(**trajectory):
    d = flyby_scenario()
    d["trajectory"]["flyby"].update(trajectory)
    return scenario_from_dict(d)


# ----------------------------------------------------------------------------- frame budget
@pytest.fixture(scope="module")
def near_ca():
    """Three frames of the preset about CA (the body largest: most pixels, most windows)."""
    sim = Simulator(preset(start_s=-0.25, end_s=0.25))
    renders = [sim.render(i) for i in range(len(sim))]
    return sim, renders


def test_frame_budget_fits_the_readout_law_at_the_preset_cadence(near_ca):
    """Per frame at CA: at most 16 windows; the pixels read are the windows' areas; the two
    acquisitions (exposure + the paper's readout law on the segments scan and on the windows
    actually read) fit in the preset's 0.25 s cadence, and so does the budget's worst case (16
    windows of the largest size), which bounds every frame."""
    sim, renders = near_ca
    sc = sim.scenario
    budget = flyby_frame_budget(sc)
    assert budget.n_windows <= MAX_WINDOWS == 16
    cam = sim.camera
    assert (cam.width, cam.height) == (1024, 1024)
    assert math.degrees(cam.fov_x) == pytest.approx(20.6, abs=0.05)   # the AA-STR's 20.6 deg
    t_exp = sc.detector.exposure_time_s
    t_seg = max(LAW_A + LAW_B * cam.width * cam.height / LAW_UNIT, LAW_FULL)
    steps = track_flyby(sim, renders=renders)
    for s in steps:
        m = s.frame.measurement
        assert 0 < len(m.windows) <= MAX_WINDOWS
        n_win = sum(h * w for _, _, h, w in m.windows)
        seg, win = s.readout
        assert (seg.mode, seg.n_pixels) == ("segments", cam.width * cam.height)
        assert (win.mode, win.n_pixels) == ("windows", n_win)
        t_win = LAW_A + LAW_B * n_win / LAW_UNIT
        assert win.min_exposure == pytest.approx(t_win) and seg.min_exposure == pytest.approx(
            t_seg)
        frame_time = 2 * t_exp + t_seg + t_win
        assert frame_time <= budget.frame_time <= sc.trajectory.cadence_s
    assert budget.fits


def test_the_preset_exposure_is_well_exposed(near_ca):
    """The lit asteroid well exposed (the paper: well-exposed images only): at CA its
    brightest 0.1 % of pixels between a quarter of the 12-bit range and below saturation."""
    sim, renders = near_ca
    fe = sim.scenario.navigation.trn.front_end.to_si()
    from starnav.navigation.trn.frontend import FlybyFrontEnd

    geom, img = renders[1]
    e0, _, _, _ = flyby_exposures(sim, img, geom, FlybyFrontEnd(sim.camera, fe))
    dn = np.asarray(e0.dn, float)
    full = 2 ** sim.scenario.detector.adc.bits - 1
    body = dn[dn > 0.05 * full]
    assert body.size > 10_000
    top = float(np.percentile(body, 99.9))
    assert 0.25 * full < top < full, top
    assert np.count_nonzero(dn >= full) == 0


# ----------------------------------------------------------------------------- the map
def test_the_map_the_filter_uses_is_not_the_truth():
    """The estimator's body is the coarse model (fewer faces, other vertices), its scale drawn
    per run (different runs, different scales; volume ratio (1 + e)^3), and the filter gets the
    scale sigma and a landmark height sigma of the model's; fails if the two meshes or their
    scales are identical."""
    sc = preset()
    assert sc.navigation.trn.shape_model.map == "coarse"
    truth = body_from_scenario(sc)
    m0, m1 = (estimator_body(sc, r, truth) for r in (0, 1))
    for m in (m0, m1):
        assert m.body.shape.n_faces < truth.shape.n_faces
        assert m.body.shape.n_vertices != truth.shape.n_vertices
        assert m.scale_error != 0.0
        assert m.body.shape.volume / truth.shape.volume == pytest.approx(
            (1 + m.scale_error) ** 3, rel=1e-9)
        assert m.prior.scale_sigma == 0.02
        assert m.prior.height_sigma > m.info["height_rms_m"] > 0
    assert m0.scale_error != m1.scale_error
    assert m0.body.gm == truth.gm and m0.body.spin == truth.spin


def test_a_coarse_model_finer_than_the_truth_is_one_error_before_rendering(monkeypatch):
    """``shape_model.faces`` at or above the truth's faces: a ConfigError naming the key, the
    value and the bound, raised before any frame is rendered."""
    d = flyby_scenario()
    d["trajectory"]["flyby"].update(start_s=-0.25, end_s=0.25)
    sim = Simulator(scenario_from_dict(d, ["navigation.trn.shape_model.faces=20000"]))

    def no_render(*_a, **_k):
        raise AssertionError("rendered before the check")

    monkeypatch.setattr(sim, "render", no_render)
    with pytest.raises(ConfigError, match=r"shape_model\.faces.*20000.*12192"):
        flyby_closed_loop(sim, 1)


# ----------------------------------------------------------------------------- synthetic
@pytest.fixture(scope="module")
def itokawa():
    return ShapeModelBody()


def synthetic_pass(body, epochs, runs, *, v=0.5, ca=5.0, phase=60.0):
    """The development fly-by of ``scoring.CALIBRATION_FLYBYS`` at ``epochs``."""
    cam = Camera.preset("aa-str")
    fl = flyby_from_config(FlybyConfig(v_inf_km_s=v, closest_approach_km=ca,
                                       phase_at_ca_deg=phase), epoch_ca=0.0, gm=body.gm)
    truth = flyby_truth(fl, body, cam, epochs, SYN, seed=1)
    c = TrnFilterConfig(**SYNTHETIC_FILTER)
    return truth, flyby_monte_carlo(truth, cam, body, runs, c.initial_covariance(), seed=SEED,
                                    synthetic=SYN, options=c.to_si(),
                                    shape_model=TrnShapeModelConfig(map="coarse"))


@pytest.fixture(scope="module")
def short_pass(itokawa):
    return synthetic_pass(itokawa, np.arange(-100.0, 100.01, 4.0), RUNS)


def test_coarse_map_landmarks_converge_to_the_truth_within_their_covariance(short_pass):
    """Every landmark's last estimate against the true surface point of its track: NEES mean
    over the landmarks inside the two-sided 99 % band of one independent landmark per run (the
    landmarks of a run share its scale error, so they are not independent of each other), and
    the median error smaller at the last estimate than at birth."""
    truth, mc = short_pass
    nees, first, last = [], [], []
    for r, run in enumerate(mc.runs):
        points = {f.track_id: f.point_body
                  for m in run_measurements(truth, SEED, r, SYN) for f in m.truth}
        for tid, (x, P) in run.info["landmark_last"].items():
            d = x - points[tid]
            nees.append(float(d @ np.linalg.solve(P, d)))
            last.append(float(np.linalg.norm(d)))
            first.append(float(np.linalg.norm(run.info["landmark_first"][tid][0] - points[tid])))
    assert len(nees) > 50
    lo, hi = (chi2.ppf(p, 3 * RUNS) / RUNS for p in (0.005, 0.995))
    assert lo <= np.mean(nees) <= hi, np.mean(nees)
    assert np.median(last) < np.median(first)


def test_the_scale_is_carried_not_estimated(short_pass):
    """The model's scale error is a consider state: its sigma stays the prior's 2 %, its value
    the model's; the truth of every run (``-e / (1 + e)``) lies within 3 sigma of it."""
    _, mc = short_pass
    for run in mc.runs:
        info = run.info
        assert info["shape_model"]["map"] == "coarse"
        assert np.all(info["shape_scale"] == 0.0)
        assert np.allclose(info["shape_scale_sigma"], 0.02)
        assert abs(info["shape_model"]["scale_truth"]) < 3 * 0.02


def test_short_dispersed_pass_consistent_under_the_per_epoch_statistic(short_pass):
    """Runs that differ in their measurements, initial error and model scale: the time-averaged
    ANEES inside its band (effective samples from the autocorrelation time, 1 % false alarm)
    and no epoch above its per-epoch 95 % band in more than 10 % of the epochs (a consistent
    filter: 2.5 % expected above). Measured: mean 6.30 in [3.11, 10.01] (6.7 effective
    samples; the released crescent term included), every epoch inside its band (with the
    former constant 1 px / 3 % sigmas and 19 s: mean 5.04, 80 % inside, 20 % below)."""
    _, mc = short_pass
    st = anees_statistics(mc.nees, 6)
    assert st["verdict"] == "consistent", (st["mean"], st["band"])
    assert st["epochs_above"] <= 0.10, st["epochs_above"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "measured: time-averaged ANEES 15.1 above the band's upper 9.20 (the former map-error "
    "defaults: 15.6 above [3.46, 9.36], thirds 7.8 / 15.8 / 23.1; 61 % of the epochs above "
    "their band), CA error 0.02 - 2.5 % of range. Not the aspect "
    "correlation (65 or 180 deg: the same); with the exact map the landmarks' births, 16 "
    "times as many, make it 15.3 (4.1 without landmarks, 3.9 with births held until the "
    "position is within 10 m); with the coarse map and no landmarks 11.0: docs/navigation.md"))
def test_long_pass_at_the_readout_cadence(itokawa):
    """Approach to departure at the preset's cadence (0.25 s, 801 frames, 50 km -> 5 km ->
    50 km), 4 runs: CA position error below 2 % of range in every run and the time-averaged
    ANEES not above its band."""
    _, mc = synthetic_pass(itokawa, np.arange(-100.0, 100.01, 0.25), RUNS)
    st = anees_statistics(mc.nees, 6)
    assert st["mean"] <= st["band"][1], st["mean"]
    assert max(m.ca_position_error_pct_range for m in mc.metrics) < 2.0


# ----------------------------------------------------------------------------- the record
def test_scoring_record_is_of_the_current_defaults_and_outside_the_envelope():
    """The packaged score (tools/score_flyby.py) was made with today's settings (a changed
    default makes it stale: re-score), its scoring fly-bys lie outside the calibration
    envelope (v_inf, CA distance and phase each outside the calibration's range, or another
    body), 20 dispersed runs each, and each recorded verdict follows from its numbers."""
    rec = read_record()
    def as_json(d):
        return json.loads(json.dumps(d))

    assert rec["defaults"]["synthetic_filter"] == as_json(SYNTHETIC_FILTER)
    assert rec["defaults"]["shape_model"] == as_json(
        TrnShapeModelConfig(map="coarse").model_dump())
    assert rec["defaults"]["filter"] == as_json(TrnFilterConfig(**SYNTHETIC_FILTER).model_dump())
    assert {c.name for c in SCORING_FLYBYS} == set(rec["scoring"])
    assert rec["seed"] == SCORING_SEED and SCORING_SEED not in SPENT_SEEDS
    assert {c.name for c in CALIBRATION_FLYBYS} == set(rec["calibration"])
    cal = CALIBRATION_FLYBYS
    for c in SCORING_FLYBYS:
        outside = [not min(getattr(k, f) for k in cal) <= getattr(c, f)
                   <= max(getattr(k, f) for k in cal)
                   for f in ("v_inf", "closest_approach", "phase_at_ca")]
        assert all(outside) or c.body not in {k.body for k in cal}, c
        s = rec["scoring"][c.name]
        assert s["runs"] >= 20 and s["case"]["name"] == c.name
        lo, hi = TARGETS["epochs_in_band"]
        assert s["targets_met"]["epochs_in_band"] == (lo <= s["epochs_in_band"] <= hi)
        assert s["targets_met"]["ca_position_pct_p95"] == (
            s["ca_position_pct_p95"] <= TARGETS["ca_position_pct_p95"])
    assert any(c.body == "eros" for c in SCORING_FLYBYS)


def geometry(c):
    return (c.body, c.v_inf, c.closest_approach, c.phase_at_ca, c.start_ca_ranges, c.cadence)


def test_the_scoring_set_is_new_and_the_spent_ones_are_recorded():
    """The scoring fly-bys share neither a name nor a geometry with the calibration, the
    development or the spent scoring fly-bys (a fly-by whose score was seen never scores
    again), and each spent fly-by's old score stays in the record with the defaults it was
    scored with."""
    rec = read_record()
    seen = CALIBRATION_FLYBYS + SPENT_FLYBYS + DEVELOPMENT_FLYBYS
    used = {geometry(c) for c in seen}
    names = {c.name for c in seen}
    for c in SCORING_FLYBYS:
        assert geometry(c) not in used and c.name not in names, c
        assert all(not (c.body == k.body and (c.v_inf, c.closest_approach, c.phase_at_ca)
                        == (k.v_inf, k.closest_approach, k.phase_at_ca))
                   for k in seen), c
    assert set(rec["spent"]) == {c.name for c in SPENT_FLYBYS}
    for c in SPENT_FLYBYS:
        old = rec["spent"][c.name]
        assert old["case"]["name"] == c.name and old["runs"] >= 20
        assert old["defaults"]["synthetic_filter"] != rec["defaults"]["synthetic_filter"]


# ----------------------------------------------------------------------------- the map's error
def test_the_scoring_silhouette_settings_are_the_coarse_map_calibration():
    """The synthetic score's silhouette settings are the calibration's values
    (tools/calibrate_flyby_coarse_map.py on the calibration fly-bys only, rounded to 2
    significant figures); a regression check of the record against the settings."""
    cal = json.loads(packaged_path("navigation/flyby_coarse_map_error.json").read_text())
    assert cal["calibration_flybys"] == [c.name for c in CALIBRATION_FLYBYS]
    assert set(cal["calibration_flybys"]).isdisjoint(c.name for c in SCORING_FLYBYS)
    for key, value in cal["filter"].items():
        if isinstance(value, str):
            assert SYNTHETIC_FILTER[key] == value
        else:
            assert SYNTHETIC_FILTER[key] == pytest.approx(value, rel=0.02, abs=0.005), key


def test_aspect_change_against_rotations():
    """The aspect change of a view turned by 30 deg with the Sun held is 30 deg; of a body
    spun by 10 deg (view and Sun both turn by 10 deg in the body frame) hypot(10, 10) deg;
    zero for the same view."""
    def rz(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    u, s = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.6, 0.8])
    assert aspect_change(u, s, u, s) == 0.0
    assert aspect_change(u, s, rz(math.radians(30)) @ u, s) == pytest.approx(math.radians(30))
    R, s1 = rz(math.radians(10)), np.array([0.0, 1.0, 0.0])
    assert aspect_change(u, s1, R @ u, R @ s1) == pytest.approx(
        math.hypot(math.radians(10), math.radians(10)))


def test_shape_law_scales_the_centroid_with_size_and_both_with_phase():
    """``silhouette_scaling: shape``: at the reference geometry the factors are one; the
    centroid's doubles with the apparent radius, the radius fraction's does not; both follow
    ``hypot(q, sin(phase / 2))`` (closed form at phase 0 and 180 deg)."""
    o = TrnFilterConfig(silhouette_scaling="shape", silhouette_shape_error_floor=0.1,
                        silhouette_reference_radius_px=50.0,
                        silhouette_reference_phase_deg=60.0).to_si()
    assert silhouette_scale(50.0, math.radians(60.0), o) == pytest.approx(np.ones(3))
    f = silhouette_scale(100.0, math.radians(60.0), o)
    assert f == pytest.approx([2.0, 2.0, 1.0])
    m0 = math.hypot(0.1, 0.5)
    assert silhouette_scale(50.0, 0.0, o)[2] == pytest.approx(0.1 / m0)
    assert silhouette_scale(50.0, math.pi, o)[2] == pytest.approx(math.hypot(0.1, 1.0) / m0)


def test_the_crescent_term_is_the_spheres_dark_to_lit_lever():
    """The crescent term against a sphere's lit silhouette in closed form (an 81 920-facet
    geodesic sphere of 10 px apparent radius on the AA-STR's boresight, so far that the view
    is all but orthographic: 0.2 deg of perspective; ``lit_silhouette``):
    at phase ``alpha`` the lit area is ``f = (1 + cos alpha) / 2`` of the disc, its centroid
    ``4 rho (1 - cos alpha) / (3 pi)`` from the disc's centre towards the Sun, and
    ``crescent_term`` is the dark part's area over the lit part's, the lever by which a
    displacement of the dark part's centroid moves the lit one (their moments about the
    centre cancel)."""
    cam = Camera.preset("aa-str")
    R = 1000.0
    sphere = icosphere_mesh(R, 6)
    D = R / math.sin(10.0 * cam.pitch_x / cam.focal_length)
    placed = BodyInCamera.place(sphere.vertices, sphere.faces, np.eye(3), [0.0, 0.0, D])
    full = lit_silhouette(placed, [0.0, 0.0, -1.0], cam)         # phase 0: the whole disc
    rho = full.radius_px
    assert rho == pytest.approx(10.0, rel=0.01)
    for deg in (30.0, 90.0, 120.0, 140.0, 160.0):
        a = math.radians(deg)
        lit = lit_silhouette(placed, [math.sin(a), 0.0, -math.cos(a)], cam)
        f = lit.area_px2 / full.area_px2
        assert f == pytest.approx(0.5 * (1.0 + math.cos(a)), abs=0.003), deg
        d = lit.centroid_uv - full.centroid_uv
        assert d[0] == pytest.approx(4.0 * rho * (1.0 - math.cos(a)) / (3.0 * math.pi),
                                     abs=0.003 * rho), deg
        assert abs(d[1]) < 0.002 * rho
        dark_moment = -lit.area_px2 * d[0]                          # the disc's is zero
        dark_centroid = dark_moment / (full.area_px2 - lit.area_px2)
        assert -d[0] / dark_centroid == pytest.approx(crescent_term(a), rel=0.03), deg
    assert crescent_term(math.radians(90.0)) == pytest.approx(1.0)
    assert crescent_term(math.radians(120.0)) == pytest.approx(3.0)
    assert crescent_term(0.0) == 0.0 and crescent_term(math.pi) == math.inf


def test_the_crescent_term_multiplies_only_the_across_sun_centroid():
    """``silhouette_crescent_gain`` kappa: the across-Sun centroid's factor is the shape
    law's times ``hypot(1, kappa tan^2(alpha / 2))`` over its value at the reference phase
    (1 there); the along-Sun centroid's and the radius's are the law's alone; kappa 0 is the
    law without the term."""
    base = {"silhouette_scaling": "shape", "silhouette_shape_error_floor": 0.1,
            "silhouette_reference_radius_px": 50.0, "silhouette_reference_phase_deg": 60.0}
    o0 = TrnFilterConfig(**base).to_si()
    o = TrnFilterConfig(**base, silhouette_crescent_gain=0.5).to_si()
    assert silhouette_scale(50.0, math.radians(60.0), o) == pytest.approx(np.ones(3))
    g_ref = math.hypot(1.0, 0.5 / 3.0)                             # tan^2(30 deg) = 1/3
    for deg in (10.0, 90.0, 120.0, 150.0):
        a = math.radians(deg)
        f0, f = silhouette_scale(80.0, a, o0), silhouette_scale(80.0, a, o)
        assert f[[0, 2]] == pytest.approx(f0[[0, 2]])
        assert f0[1] == pytest.approx(f0[0])
        assert f[1] / f0[1] == pytest.approx(
            math.hypot(1.0, 0.5 * math.tan(a / 2.0) ** 2) / g_ref), deg
    with pytest.raises(ValueError, match="silhouette_crescent_gain"):
        TrnFilterConfig(silhouette_crescent_gain=-0.1)


def test_the_crescent_calibration_never_reads_a_scoring_flyby():
    """The crescent term is calibrated on the calibration and development fly-bys of more
    than one body (``scoring.CRESCENT_CALIBRATION_FLYBYS``, the packaged record's input),
    none of which is a scoring or spent fly-by by name or geometry; the released gain is
    either off (not yet scored) or the calibrated one."""
    cal = json.loads(packaged_path("navigation/flyby_coarse_map_error.json").read_text())
    cres = cal["crescent"]
    assert cres["calibration_flybys"] == [c.name for c in CRESCENT_CALIBRATION_FLYBYS]
    assert len({c.body for c in CRESCENT_CALIBRATION_FLYBYS}) >= 2
    assert set(CRESCENT_CALIBRATION_FLYBYS) <= set(CALIBRATION_FLYBYS + DEVELOPMENT_FLYBYS)
    scored = SCORING_FLYBYS + SPENT_FLYBYS
    for c in CRESCENT_CALIBRATION_FLYBYS:
        assert c.name not in {k.name for k in scored}, c
        assert geometry(c) not in {geometry(k) for k in scored}, c
    gain = SYNTHETIC_FILTER.get("silhouette_crescent_gain", 0.0)
    assert gain == 0.0 or gain == pytest.approx(
        cres["filter"]["silhouette_crescent_gain"], rel=0.02, abs=0.005)


def test_the_map_error_keys_reach_the_filter_and_bad_values_are_refused():
    """``silhouette_bias_angle_deg`` / ``silhouette_scaling: shape`` /
    ``silhouette_shape_error_floor`` of a scenario reach the estimator's SI view (the angle in
    radians); out of range is a ConfigError naming the key."""
    sc = scenario_from_dict({"navigation": {"trn": {"filter": {
        "silhouette_bias_angle_deg": 30.0, "silhouette_scaling": "shape",
        "silhouette_shape_error_floor": 0.1}}}})
    opt = sc.navigation.trn.filter.to_si()
    assert opt.silhouette_bias_angle == pytest.approx(math.radians(30.0))
    assert (opt.silhouette_scaling, opt.silhouette_shape_error_floor) == ("shape", 0.1)
    for key, bad in (("silhouette_bias_angle_deg", 200.0), ("silhouette_shape_error_floor", 0.0),
                     ("silhouette_scaling", "aspect")):
        with pytest.raises(ConfigError, match=key):
            scenario_from_dict({"navigation": {"trn": {"filter": {key: bad}}}})
    with pytest.raises(ValueError, match="silhouette_bias_angle"):
        TrnFilterConfig(silhouette_bias_angle_deg=-0.1)


# ----------------------------------------------------------------------------- a large body's map
@pytest.fixture(scope="module")
def eros_and_itokawa_models():
    """The coarse estimator models of Eros and Itokawa (no scale error)."""
    sm = TrnShapeModelConfig(map="coarse")
    return {name: (body, estimator_model(body, sm, 0.0))
            for name in ("eros", "itokawa")
            for body in [ShapeModelBody(ShapeModelConfig(model=name))]}


def test_the_map_error_terms_scale_with_the_bodys_own_map(eros_and_itokawa_models):
    """Regression test of the Eros overconfidence: the coarse map's error model follows the
    navigated model's own departure from the truth, not metres or radius fractions fitted on
    Itokawa. The landmark height sigma is ``height_sigma_ratio`` times the model's rms height
    error, the silhouette sigmas' factor is its relative height error over the calibration
    body's (1 on Itokawa, about 1.8 on Eros: its 500-face model departs relatively more), and
    that factor reaches the filter's silhouette bias sigmas (frame 0, no silhouette update)."""
    opt = TrnFilterConfig(**SYNTHETIC_FILTER).to_si()
    f = {}
    for name, (body, m) in eros_and_itokawa_models.items():
        rms = m.info["height_rms_m"]
        assert m.prior.height_sigma == pytest.approx(
            TrnShapeModelConfig().height_sigma_ratio * rms)
        assert m.prior.height_fraction == pytest.approx(
            rms / coarse_of(body, 500, 10).mean_radius)
        f[name] = map_error_factor(m.prior, opt)
    assert f["itokawa"] == pytest.approx(1.0, abs=0.01)
    assert 1.5 < f["eros"] < 2.2
    assert map_error_factor(ShapePrior(), opt) == 1.0       # exact map: nothing stated

    body, m = eros_and_itokawa_models["eros"]
    truth = eros_pass(body, np.array([-8.0, -4.0]))
    meas = run_measurements(truth, SEED, 0, SYN)
    cfg = TrnFilterConfig(**{**SYNTHETIC_FILTER, "use_centroid": False, "use_radius": False})
    P0 = cfg.initial_covariance()
    runs = [run_filter(meas[:1], Camera.preset("aa-str"), m.body, truth.states[0], P0,
                       cfg.to_si(), sun_direction=truth.sun_direction, prior=p)
            for p in (m.prior, ShapePrior(scale_sigma=m.prior.scale_sigma,
                                          height_sigma=m.prior.height_sigma))]
    assert runs[0].info["bias_sigma"][0] == pytest.approx(
        f["eros"] * runs[1].info["bias_sigma"][0])


def eros_pass(body, epochs):
    """The first development fly-by of Eros (``scoring.DEVELOPMENT_FLYBYS``) at ``epochs``."""
    c = DEVELOPMENT_FLYBYS[0]
    fl = flyby_from_config(FlybyConfig(v_inf_km_s=c.v_inf / 1e3,
                                       closest_approach_km=c.closest_approach / 1e3,
                                       phase_at_ca_deg=math.degrees(c.phase_at_ca)),
                           epoch_ca=0.0, gm=body.gm)
    return flyby_truth(fl, body, Camera.preset("aa-str"), epochs, SYN, seed=1)


def test_the_eros_maps_silhouette_error_is_the_scaled_law_not_itokawas(eros_and_itokawa_models):
    """Regression test of the cause on an Eros development fly-by (not a calibration or
    scoring one), below phase 120 deg where the shape law's form holds: the coarse model's lit
    silhouette against the full model's, at the true pose every 16 s. Its error over the
    calibrated law (``shape_error_term`` times the calibration's sigmas) has an rms above 1.2
    in the across-Sun centroid and the radius with Itokawa's factor (1: the former model) and
    between 0.4 and 1.2 in all three once scaled by ``map_error_factor``."""
    body, m = eros_and_itokawa_models["eros"]
    coarse = coarse_of(body, 500, 10).shape
    opt = TrnFilterConfig(**SYNTHETIC_FILTER).to_si()
    cam = Camera.preset("aa-str")
    c = DEVELOPMENT_FLYBYS[1]
    fl = flyby_from_config(FlybyConfig(v_inf_km_s=c.v_inf / 1e3,
                                       closest_approach_km=c.closest_approach / 1e3,
                                       phase_at_ca_deg=math.degrees(c.phase_at_ca)),
                           epoch_ca=0.0, gm=body.gm)
    half = c.start_ca_ranges * c.closest_approach / c.v_inf
    t = np.arange(-half, half, 16.0)
    X, s = fl.states(t), np.asarray(fl.sun_direction, float)
    Rb = np.asarray(body.orientation(t), float).reshape(-1, 3, 3)
    share = np.array([opt.centroid_sun_share, 1.0 - opt.centroid_sun_share])
    sig0 = np.r_[opt.centroid_model_sigma_px * np.sqrt(2.0 * share), opt.radius_model_fraction]
    z = []
    for k in range(t.size):
        r = X[k, :3]
        phase = math.acos(float(r @ s) / float(np.linalg.norm(r)))
        if phase >= math.radians(120.0):
            continue
        Rc = boresight_attitude(r, fl.z_hat)
        R_bc, cen, sc = Rc.T @ Rb[k], Rc.T @ (-r), Rc.T @ s
        true = lit_silhouette(BodyInCamera.place(body.shape.vertices, body.shape.faces, R_bc,
                                                 cen), sc, cam)
        model = lit_silhouette(BodyInCamera.place(coarse.vertices, coarse.faces, R_bc, cen), sc,
                               cam)
        e = cam.project_jacobian(cen) @ sc
        e /= np.linalg.norm(e)
        d = np.column_stack([e, [-e[1], e[0]]]).T @ (model.centroid_uv - true.centroid_uv)
        sig = sig0 * silhouette_scale(true.radius_px, phase, opt)
        z.append(np.r_[d, model.radius_px / true.radius_px - 1.0] / sig)
    z = np.array(z)
    assert z.shape[0] >= 40
    rms = np.sqrt(np.mean(z**2, axis=0))
    f = map_error_factor(m.prior, opt)
    assert np.all(rms[1:] > 1.2), rms
    assert np.all((0.4 < rms / f) & (rms / f < 1.2)), rms / f


def test_the_centroid_bias_stays_an_image_offset_when_the_suns_image_direction_turns(
        eros_and_itokawa_models):
    """Regression test (the other cause found on the Eros development fly-bys): the centroid's
    bias states are along and across the Sun's image direction, which turns fast near phase 0;
    the offset they carry is one of the image and must be carried over, not turned with the
    axes. Two frames 1 s apart, the second's Sun turned by 180 deg about the line of sight
    (same phase, the Sun's image direction reversed), no centroid and an uninformative radius
    in it, the bias's decay switched off: the bias in the new axes is minus the old one (the
    same image offset; before the fix it kept its value: the image offset reversed)."""
    body, m = eros_and_itokawa_models["eros"]
    truth = eros_pass(body, np.array([-8.0, -7.0]))
    m0, m1 = run_measurements(truth, SEED, 0, SYN)
    u = -truth.states[1, :3] / np.linalg.norm(truth.states[1, :3])
    s = np.asarray(truth.sun_direction, float)
    m1 = dataclasses.replace(m1, features=(), centroid_uv=None, apparent_radius_sigma_px=1e6,
                             sun_direction=2.0 * float(s @ u) * u - s)
    cfg = TrnFilterConfig(**{**SYNTHETIC_FILTER, "silhouette_bias_angle_deg": 0.0,
                             "silhouette_bias_time_s": 1e12, "max_landmarks": 0})
    run = run_filter([m0, m1], Camera.preset("aa-str"), m.body, truth.states[0],
                     cfg.initial_covariance(), cfg.to_si(), sun_direction=s, prior=m.prior)
    b0, b1 = run.info["bias"][:, :2]
    assert np.linalg.norm(b0) > 0.01
    # the same image offset, within the few % the bias's geometry factor (apparent radius,
    # phase) changes in 1 s near CA
    assert np.linalg.norm(b1 + b0) < 0.1 * np.linalg.norm(b0), (b0, b1)
