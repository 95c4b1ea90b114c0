"""The chain end to end on analytic frames: process_frame, bad input, navigate, outputs, the
configuration section and the CLI command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from starnav.constants import AU
from starnav.detector.products import Segments, Window
from starnav.navigation.ekf import EkfPriors
from starnav.navigation.frames import Frame, FrameList
from starnav.navigation.pipeline import ChainOptions, navigate, process_frame
from starnav.navigation.synthetic import pointing_geometry, synthetic_frame

from ._helpers import MovingMoonTwoBody, circular_state
from .conftest import PSF_SIGMA_PX

SUN = AU * np.array([math.cos(0.6), math.sin(0.6), 0.1])
CADENCE_S = 1800.0


def _sequence(cam, n=6, dyn=None, att_sigma=0.0, seed=0):
    dyn = dyn or MovingMoonTwoBody(step=300.0)
    rng = np.random.default_rng(seed)
    x = circular_state(dyn, 6.0e7)
    frames = []
    for k in range(n):
        t = k * CADENCE_S
        if k:
            x, _ = dyn.propagate(t - CADENCE_S, x, t)
        rel = x - dyn.moon_state(t)
        g = pointing_geometry(cam, rel[:3], SUN, camera_velocity=rel[3:], epoch_tdb=t,
                              index=k, moon_offset_px=tuple(rng.uniform(-250, 250, 2)),
                              attitude_error_rad=rng.normal(0, att_sigma, 3))
        frames.append(synthetic_frame(cam, g, supersample=4, psf_sigma_px=PSF_SIGMA_PX,
                                      read_noise_dn=2.0, rng=rng))
    return dyn, frames


@pytest.fixture(scope="module")
def sequence(cam):
    return _sequence(cam)


def _rel_error(m, f):
    return np.linalg.norm(m.position - f.truth.camera_position) / f.truth.range


def test_process_frame_pixel_level_and_refined(cam, sequence):
    _, frames = sequence
    f = frames[0]
    m_pix = process_frame(f, cam, options=ChainOptions(use_windows=False))
    m_win = process_frame(f, cam)
    assert m_pix.usable and m_win.usable and m_pix.message == ""
    assert m_win.refined is not None and len(m_win.refined) >= 14
    # pixel level: the 10 % threshold moves the limb out by ~0.45 px of a 82 px radius
    assert _rel_error(m_pix, f) < 0.015
    # windows: subpixel limb, 30x better
    assert _rel_error(m_win, f) < 5e-4
    for m in (m_pix, m_win):
        assert np.all(np.linalg.eigvalsh(m.covariance) > 0)
        assert set(m.timings_s) >= {"limb", "ransac", "fix"}


def _empty_segments(shape=(1024, 1024)):
    z = np.zeros(0)
    return Segments(row=z.astype(np.int32), col_start=z.astype(np.int32),
                    length=z.astype(np.int32), offset=z.astype(np.int64),
                    values=z.astype(np.uint16), level=z.astype(np.int8), shape=shape)


def _speck():
    return Segments(row=np.array([500, 501], np.int32), col_start=np.array([600, 600], np.int32),
                    length=np.array([2, 2], np.int32), offset=np.array([0, 2], np.int64),
                    values=np.full(4, 900, np.uint16), level=np.zeros(2, np.int8),
                    shape=(1024, 1024))


def _bad(f, **kw):
    d = {k: getattr(f, k) for k in ("index", "epoch_tdb", "R_cam_to_inertial_measured",
                                     "sun_direction_inertial", "segments", "windows", "truth")}
    d.update(kw)
    return Frame(**d)


def test_bad_frames_give_reasons_not_exceptions(cam, sequence):
    _, frames = sequence
    f = frames[1]
    cases = {
        "no-segments": _bad(f, segments=None),
        "no-moon": _bad(f, segments=_empty_segments(), windows=()),
        "degenerate-arc": _bad(f, segments=_speck(), windows=()),
    }
    for status, frame in cases.items():
        m = process_frame(frame, cam)
        assert m.status == status and not m.usable
        assert len(m.message) > 20
    # a thin crescent (phase past limb.max_phase_deg): no fix, and why
    import math

    from starnav.navigation.limb import (
        LimbConfig,
        phase_angle_from_image,
        segments_centroid,
    )
    from starnav.navigation.pipeline import ChainOptions

    phase = phase_angle_from_image(cam, f.R_cam_to_inertial_measured, f.sun_direction_inertial,
                                   segments_centroid(f.segments))
    assert phase == pytest.approx(f.truth.phase_angle, abs=math.radians(1.0))
    tight = ChainOptions(limb=LimbConfig(max_phase_deg=math.degrees(phase - 0.05)).to_si())
    m = process_frame(f, cam, options=tight)
    assert m.status == "thin-crescent" and "phase angle" in m.message
    ok = ChainOptions(limb=LimbConfig(max_phase_deg=math.degrees(phase + 0.05)).to_si())
    assert process_frame(f, cam, options=ok).usable
    # windows without a limb: refinement fails, the pixel-level fix is used
    junk = tuple(Window(row0=0, col0=11 * k, dn=np.full((11, 11), 5, np.uint16))
                 for k in range(4))
    m = process_frame(_bad(f, windows=junk), cam)
    assert m.usable and m.refined is None


def test_navigate_goes_on_over_bad_frames_and_writes_outputs(cam, sequence, tmp_path):
    from starnav.navigation.report import write_outputs

    dyn, frames = sequence
    frames = list(frames)
    frames[2] = _bad(frames[2], segments=None)
    frames[3] = _bad(frames[3], segments=_speck(), windows=())
    P0 = np.diag([50e3**2] * 3 + [0.5**2] * 3)
    run = navigate(FrameList(cam, frames), dynamics=dyn, moon=dyn, P0=P0,
                   seed=1, measure_memory=True)
    assert [m.status for m in run.measurements] == ["ok", "ok", "no-segments",
                                                    "degenerate-arc", "ok", "ok"]
    assert list(run.filter.has_fix) == [True, True, False, False, True, True]
    e = run.filter.errors(run.truth)
    s3 = run.filter.sigma3()
    assert np.all(np.abs(e) <= s3)
    assert np.linalg.norm(e[-1, :3]) < np.linalg.norm(e[0, :3]) + 10e3
    assert run.peak_memory_bytes is not None and np.all(run.peak_memory_bytes > 0)
    assert np.all(np.isfinite(run.stage_times_s[:, 0]))
    paths = write_outputs(run, tmp_path, plots=True)
    for name in ("estimates", "metrics", "limb_error_pdf", "position_error",
                 "velocity_error", "consistency", "resources"):
        assert paths[name].exists() and paths[name].stat().st_size > 0, name
    metrics = json.loads(paths["metrics"].read_text())
    assert metrics["frames"] == 6 and metrics["fixes"] == 4
    assert metrics["status_counts"] == {"ok": 4, "no-segments": 1, "degenerate-arc": 1}
    assert abs(metrics["limb_error_px"]["bias"]) < 0.05
    lines = paths["estimates"].read_text().splitlines()
    assert len(lines) == 7 and lines[0].startswith("index,epoch_tdb_s,status")
    assert not list(tmp_path.glob("*.tmp*"))


def test_navigation_config_section():
    from starnav.config import scenario_from_dict
    from starnav.errors import ConfigError

    sc = scenario_from_dict({"navigation": {
        "fix": {"attitude_sigma_arcsec": 3600.0, "moon_radii_km": [1738.1, 1738.1, 1736.0]},
        "filter": {"bias_model": "additive", "bias_sigma_km": 2.0, "bias_tau_days": 0.5,
                   "initial_position_sigma_km": 10.0},
        "ransac": {"model": "christian-robinson", "threshold_px": 1.0}}})
    ch = sc.navigation.chain_options()
    assert ch.fix.attitude_sigma_rad == pytest.approx(math.radians(1.0), rel=1e-12)
    assert ch.fix.radii_m == (1738100.0, 1738100.0, 1736000.0)
    assert ch.ransac.model == "christian-robinson" and ch.limb.max_points == 600
    ek = sc.navigation.filter.to_si()
    assert ek.bias_sigma == 2000.0 and ek.bias_tau == 43200.0 and ek.bias_model == "additive"
    assert sc.navigation.ekf_priors() == EkfPriors()
    assert sc.navigation.initial_covariance()[0, 0] == pytest.approx(1e8)
    with pytest.raises(ConfigError, match="navigation.ransac.threshold"):
        scenario_from_dict({"navigation": {"ransac": {"threshold": 1.0}}})
    with pytest.raises(ConfigError, match="navigation.ransac.model"):
        scenario_from_dict({"navigation": {"ransac": {"model": "ellipse"}}})


def test_limb_common_states_take_the_terms_of_their_exposure():
    """The ``limb-common`` states carry the calibrated slowly varying fix error of the regime
    the frames are exposed in: the well-exposed fix's below the blooming threshold, the
    blooming (saturated) fix's from it on (regression test against the packaged table)."""
    from starnav.config import scenario_from_dict
    from starnav.navigation.refine import packaged_model_error

    nav = scenario_from_dict({"navigation": {"filter": {"bias_model": "limb-common"}}}).navigation
    table = packaged_model_error()
    assert table.blooming is not None
    as_tuple = lambda C: tuple(tuple(float(x) for x in r) for r in C)  # noqa: E731
    well = nav.ekf_priors(None, 1.5e-5).common_covariance
    assert well == as_tuple(table.fix_covariance) == nav.ekf_priors().common_covariance
    bloom = nav.ekf_priors(None, 7.7e-3).common_covariance
    assert bloom == as_tuple(table.blooming.fix_covariance_saturated)
    # the blooming fix's slowly varying error is larger than the well-exposed one's
    assert np.trace(np.asarray(bloom)) > 10 * np.trace(np.asarray(well))
    just_below = np.nextafter(table.blooming_min_exposure_s, 0.0)
    assert nav.ekf_priors(None, just_below).common_covariance == well
    assert nav.ekf_priors(None, table.blooming_min_exposure_s).common_covariance == bloom


def test_cli_navigate(cam, sequence, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from starnav.cli import navigate as cli_nav
    from starnav.cli.main import app  # the real command line

    runner = CliRunner()
    res = runner.invoke(app, ["navigate", str(tmp_path / "missing"), "--out", str(tmp_path)])
    assert res.exit_code == 2 and "does not exist" in res.output

    dyn, frames = sequence
    monkeypatch.setattr(cli_nav, "_open_dataset",
                        lambda path, exposure: FrameList(cam, list(frames)))
    from starnav.navigation import report

    orig = report.navigate_dataset
    monkeypatch.setattr(report, "navigate_dataset",
                        lambda *a, **kw: orig(*a, dynamics=dyn, **kw))
    out = tmp_path / "out"
    res = runner.invoke(app, ["navigate", str(tmp_path / "ds"), "--out", str(out),
                              "--no-plots"])
    assert res.exit_code == 0, res.output
    assert "frames 6, fixes 6" in res.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["fixes"] == 6 and "monte_carlo" not in m
    assert (out / "navigation_config.json").exists()


def _psf_chain() -> ChainOptions:
    """The chain with the detector-psf edge model (the one with tables to prepare)."""
    from starnav.detector.schema import DetectorConfig
    from starnav.navigation.refine import EdgeSpread, PixelNoise, RefineConfig, RefineModels

    det = DetectorConfig()
    return ChainOptions(refine=RefineConfig(edge_model="detector-psf").to_si(),
                        refine_models=RefineModels(spread=EdgeSpread.from_detector(det),
                                                   noise=PixelNoise.from_detector(det)))


def test_prepare_frame_builds_every_table_the_refinement_asks_for(cam, sequence):
    """What navigate keeps off the clock (prepare_frame) is all the table building: after
    it, processing the frame builds no edge table (a regression test of the mechanism)."""
    from starnav.navigation import refine as rf
    from starnav.navigation.pipeline import prepare_frame

    _, frames = sequence
    chain = _psf_chain()
    f = frames[4]
    prepare_frame(f, cam, options=chain, rng=np.random.default_rng(7))
    built = rf._edge_tables.cache_info().misses
    m = process_frame(f, cam, options=chain, rng=np.random.default_rng(7))
    assert m.usable and m.refined is not None and len(m.refined) >= 14
    assert rf._edge_tables.cache_info().misses == built


def test_navigate_processes_each_frame_once_on_the_clock(cam, sequence, monkeypatch):
    """Each frame goes through the chain once (plus once more, traced, with measure_memory),
    and the estimates do not depend on the heap tracing."""
    from starnav.navigation import pipeline

    dyn, frames = sequence
    frames = frames[:3]
    chain = _psf_chain()
    P0 = np.diag([50e3**2] * 3 + [0.5**2] * 3)
    calls = []
    real = pipeline.process_frame

    def counted(frame, *a, **k):
        calls.append(int(frame.index))
        return real(frame, *a, **k)

    monkeypatch.setattr(pipeline, "process_frame", counted)
    runs = {}
    for traced in (False, True):
        calls.clear()
        runs[traced] = navigate(FrameList(cam, frames), dynamics=dyn, moon=dyn, P0=P0,
                                chain=chain, seed=3, measure_memory=traced)
        assert calls == [int(f.index) for f in frames for _ in range(1 + traced)]
    assert runs[True].peak_memory_bytes is not None and runs[False].peak_memory_bytes is None
    np.testing.assert_array_equal(runs[False].filter.states, runs[True].filter.states)
    np.testing.assert_array_equal(runs[False].filter.covariances, runs[True].filter.covariances)
    assert np.all(runs[False].cpu_times_s > 0)
