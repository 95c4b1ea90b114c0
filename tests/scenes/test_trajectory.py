"""The LUMIO-like arc in the ephemeris point-mass model, frames, sampling, cache."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from starnav.constants import DAY
from starnav.errors import ConfigError
from starnav.scenes import trajectory as trajmod
from starnav.scenes.cr3bp import MU_EARTH_MOON, l2_halo
from starnav.scenes.dynamics import propagate
from starnav.scenes.ephemeris import EphemerisRangeError, parse_epoch
from starnav.scenes.trajectory import (
    ShootingOptions,
    Trajectory,
    emb_to_rotating,
    ephemeris_halo_arc,
    rotating_to_emb,
)

from .conftest import ARC_DURATION, ARC_EPOCH, KM


def test_arc_spans_28_days_on_300_s_nodes(arc):
    assert arc.t_start == parse_epoch(ARC_EPOCH)
    assert arc.duration >= ARC_DURATION
    assert np.allclose(np.diff(arc.times), 300.0, rtol=0, atol=1e-6)
    assert arc.meta["shooting_max_position_defect_m"] < 1e-3
    assert arc.meta["shooting_max_velocity_defect_m_s"] < 1e-9


def test_arc_moon_range_in_band(arc, eph):
    # issue 4: 35 000-90 000 km from the Moon along the whole arc
    r = arc.moon_range(eph)
    assert r.min() > 35_000 * KM and r.max() < 90_000 * KM
    # and it is the LUMIO-like orbit, not something else inside the band (docs/facts.md s4:
    # 48 000-77 000 km in the CR3BP; the Sun stretches it by a few thousand km)
    assert 42_000 * KM < r.min() < 50_000 * KM and 74_000 * KM < r.max() < 84_000 * KM


def test_arc_speed_is_lumio_like(arc):
    # seed paper: LUMIO's speed oscillates between 0.93 and 1.35 km/s (EMB J2000)
    v = np.linalg.norm(arc.states[:, 3:], axis=1)
    assert 0.90e3 < v.min() < 1.0e3 and 1.30e3 < v.max() < 1.45e3


def test_arc_matches_dop853_reintegration(arc, model):
    # issue 4: re-integrating the initial state with an independent integrator (DOP853, tight
    # tolerances) matches the stored arc within 1 km over 28 days
    sol = solve_ivp(model.derivative, (arc.t_start, arc.t_end), arc.states[0],
                    method="DOP853", rtol=1e-13, atol=1e-7, t_eval=arc.times[::12])
    assert sol.success
    err = np.linalg.norm(sol.y[:3].T - arc.states[::12, :3], axis=1)
    assert err.max() < 1 * KM


def test_arc_is_ballistic_between_nodes(arc, model):
    # every node follows from the previous one in the same force model (no manoeuvre), to the
    # shooting tolerance at patch epochs
    idx = np.arange(0, len(arc) - 1, 97)
    for i in idx:
        x1, _ = propagate(model, arc.times[i], arc.states[i], arc.times[i + 1], step=300.0)
        assert np.linalg.norm(x1[:3] - arc.states[i + 1, :3]) < 1e-3
        assert np.linalg.norm(x1[3:] - arc.states[i + 1, 3:]) < 1e-8


def test_hermite_sampling_between_nodes(arc, model):
    # cubic Hermite between 300 s nodes vs an exact propagation to mid-interval: < 1 mm
    for i in (10, 2000, 5000):
        tm = arc.times[i] + 150.0
        x_ref, _ = propagate(model, arc.times[i], arc.states[i], tm, step=150.0)
        x_int = arc.sample([tm])[0]
        assert np.linalg.norm(x_int[:3] - x_ref[:3]) < 1e-3
        assert np.linalg.norm(x_int[3:] - x_ref[3:]) < 1e-6
    assert np.array_equal(arc.sample(arc.times[:5]), arc.states[:5])
    with pytest.raises(ConfigError, match="span"):
        arc.sample([arc.t_end + 10.0])


def test_rotating_frame_round_trip_and_moon(eph):
    t = parse_epoch(ARC_EPOCH) + np.linspace(0, 20, 5) * DAY
    halo = l2_halo()
    rho = halo.states(np.linspace(0, 2, 5))
    x = rotating_to_emb(eph, t, rho)
    assert np.allclose(emb_to_rotating(eph, t, x), rho, rtol=0, atol=1e-10)
    # the Moon sits at (1 - f, 0, 0) at rest in the pulsating rotating frame
    moon = eph.state("moon", t, center="emb")
    m = emb_to_rotating(eph, t, moon)
    f = 1 / (1 + eph.emrat)
    assert np.allclose(m[:, :3], [1 - f, 0, 0], atol=1e-12)
    assert np.abs(m[:, 3:]).max() < 1e-6
    assert f == pytest.approx(MU_EARTH_MOON, rel=1e-6)


def test_cache_round_trip(model, tmp_path, monkeypatch):
    t0 = parse_epoch("2027-01-10T00:00:00 TDB")
    a = ephemeris_halo_arc(model, t0, 3 * DAY, cache_dir=tmp_path)
    files = list((tmp_path / "trajectories").glob("halo-*.npz"))
    assert len(files) == 1

    def boom(*args, **kwargs):
        raise AssertionError("the cached arc must be used")

    monkeypatch.setattr(trajmod, "multiple_shooting", boom)
    b = ephemeris_halo_arc(model, t0, 3 * DAY, cache_dir=tmp_path)
    assert np.array_equal(a.times, b.times) and np.array_equal(a.states, b.states)
    assert b.meta["cache_key"] == a.meta["cache_key"]
    with pytest.raises(AssertionError, match="cached"):  # other inputs, other key
        ephemeris_halo_arc(model, t0, 3 * DAY, phase=0.25, cache_dir=tmp_path)


def test_errors_come_before_work(model, monkeypatch):
    def boom(*args, **kwargs):
        raise AssertionError("no shooting for bad inputs")

    monkeypatch.setattr(trajmod, "multiple_shooting", boom)
    with pytest.raises(EphemerisRangeError, match="2250"):
        ephemeris_halo_arc(model, parse_epoch("2250-01-01T00:00:00 TDB"), DAY,
                           cache_dir=False)
    with pytest.raises(ConfigError, match="duration"):
        ephemeris_halo_arc(model, parse_epoch(ARC_EPOCH), -1.0, cache_dir=False)
    with pytest.raises(ConfigError, match="phase"):
        ephemeris_halo_arc(model, parse_epoch(ARC_EPOCH), DAY, phase=1.5, cache_dir=False)
    with pytest.raises(ConfigError, match="segment"):
        ShootingOptions(segment=10.0, step=300.0)


def test_trajectory_validation():
    with pytest.raises(ConfigError):
        Trajectory(np.array([0.0, 0.0]), np.zeros((2, 6)))
    with pytest.raises(ConfigError):
        Trajectory(np.array([0.0, 1.0]), np.zeros((3, 6)))


@pytest.mark.slow
def test_long_arc_stays_in_band(model, eph):
    # 90 days (six revolutions) from another epoch and phase: still converged and in band
    arc = ephemeris_halo_arc(model, parse_epoch("2030-05-01T00:00:00 UTC"), 90 * DAY,
                             phase=0.25, cache_dir=False)
    r = arc.moon_range(eph)
    assert r.min() > 35_000 * KM and r.max() < 90_000 * KM
    assert arc.meta["shooting_max_position_defect_m"] < 1e-3
