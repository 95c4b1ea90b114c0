"""The asteroid fly-by front end (issue 16, items 3-4): features tracked in windows follow the
true projections of their surface points, the front end reads nothing but the windows and
the segments, the epipolar test with the known attitude, and bad inputs.

The rendered scenario (module fixture, ~10 s): Itokawa (radar shape model, Hapke S-type) seen
from 5 km, 256 x 256 px with a 30 mm focal length (0.6 mrad pixels: the body spans ~180 x
110 px), 4 spp, phase 70 deg, 7 frames 0.05 s apart before closest approach at 0.25 km/s: the
view turns by 2.5 mrad per frame (a 5 km/s fly-by at 100 km seen at 20 Hz).
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
from pydantic import ValidationError

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

import starnav.simulate.trn as simtrn
from starnav.config import scenario_from_dict
from starnav.detector.products import Window
from starnav.detector.readout import extract_segments, min_exposure
from starnav.errors import ConfigError
from starnav.navigation.schema import TrnFrontEndConfig
from starnav.navigation.trn.features import epipolar_ransac
from starnav.navigation.trn.frontend import FlybyFrontEnd
from starnav.navigation.trn.windows import WindowAccessError, WindowReader, plan_windows
from starnav.simulate import Simulator
from starnav.simulate.trn import flyby_exposures, track_flyby

#: Accuracy goal of issue 16: rms distance of tracked positions to the true projections of
#: their surface points, over every frame after the first detection [px].
RMS_GOAL_PX = 0.3
#: Track length the accuracy is stated over [frames].
TRACK_FRAMES = 7


def _scenario():
    return scenario_from_dict({
        "camera": {"width": 256, "height": 256, "focal_length_mm": 30.0},
        "render": {"spp": 4},
        "target": {"kind": "shape_model", "model": "itokawa"},
        "trajectory": {"source": "flyby", "cadence_s": 0.05, "frames": TRACK_FRAMES,
                       "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.25,
                                 "phase_at_ca_deg": 70.0, "start_s": -0.45}},
        "pointing": {"moon_offset": "fixed", "roll": "fixed"},
        "detector": {"exposure_time_s": 3e-5}})


@pytest.fixture(scope="module")
def rendered():
    sim = Simulator(_scenario())
    renders = [sim.render(i) for i in range(len(sim))]
    steps = track_flyby(sim, renders=renders)
    return sim, renders, steps


def _errors(steps):
    """Per track: list of (age, |uv - uv_true|, sigma)."""
    out: dict[int, list[tuple[int, float, float]]] = {}
    for s in steps:
        m = s.frame.measurement
        assert [f.track_id for f in m.features] == [t.track_id for t in m.truth]
        for f, t in zip(m.features, m.truth, strict=True):
            age = len(out.get(f.track_id, []))
            out.setdefault(f.track_id, []).append(
                (age, float(np.linalg.norm(f.uv - t.uv_true)), f.sigma_px))
    return out


def test_tracks_follow_the_true_projections_of_their_surface_points(rendered):
    """Measured on this scenario: 19 tracks, all 7 frames long; rms 0.26 px over the 6
    frames after detection (growing from ~0.1 px at one frame to ~0.3 px at six: the shading
    drifts on the surface as the view turns); the truth is exact at the detection (pixel
    centres, to the float32 AOVs' 1e-4 px). Asserted: >= 10 tracks over all 7 frames,
    rms < 0.3 px, no error > 1 px, and the stated 1-sigma covers it (< 5 % of the errors
    beyond 3 sigma)."""
    _, _, steps = rendered
    tracks = _errors(steps)
    full = [k for k, v in tracks.items() if len(v) == TRACK_FRAMES]
    assert len(full) >= 10, {k: len(v) for k, v in tracks.items()}
    first = np.array([e for v in tracks.values() for a, e, _ in v if a == 0])
    assert np.max(first) < 0.01  # float32 AOVs reprojected (tests/test_small_bodies.py)
    later = np.array([(e, s) for k in full for a, e, s in tracks[k] if a >= 1])
    rms = math.sqrt(np.mean(later[:, 0] ** 2))
    assert rms < RMS_GOAL_PX, rms
    assert later[:, 0].max() < 1.0
    assert np.mean(later[:, 0] > 3 * later[:, 1]) < 0.05
    # track statistics: most born in frame 0, none ended on this easy pass (a feature that
    # rises above the detector's threshold later may be born then: one at frame 5 with the
    # renderer's electron-spectrum sampling, none before it)
    c0 = steps[0].frame.counts
    assert c0["tracked"] == 0 and c0["born"] >= len(tracks) - 2
    ended = ("lost", "left", "limb", "outlier", "aged")
    assert all(s.frame.counts[k] == 0 for s in steps for k in ended)
    assert all(s.frame.counts["tracked"] >= c0["born"] for s in steps[1:])


def test_windows_body_and_readout_law(rendered):
    """At most 16 windows inside the array, on the lit body; pixels_read = the segments scan
    (H W) + the window areas; the windows readout's N_pix is the window area and its
    minimum exposure the readout law a + b N_pix / 1000 (8 ms + 0.17 ms per 1000 px); the
    centroid and apparent radius are those of the lit pixels of the render (the segments
    threshold cuts the dimmest: radius within 3 %, centroid within 2 px)."""
    sim, renders, steps = rendered
    H, W = sim.camera.height, sim.camera.width
    for s, (_geom, img) in zip(steps, renders, strict=True):
        m = s.frame.measurement
        assert 1 <= len(m.windows) <= 16
        area = sum(h * w for _, _, h, w in m.windows)
        assert m.pixels_read == H * W + area == H * W + s.frame.window_pixels
        for r0, c0, h, w in m.windows:
            assert r0 >= 0 and c0 >= 0 and r0 + h <= H and c0 + w <= W
            assert img.mask[r0 + h // 2, c0 + w // 2]
        (win,) = [t for t in s.readout if t.mode == "windows"]
        assert win.n_pixels == area
        assert win.min_exposure == pytest.approx(8e-3 + 0.17e-3 * area / 1000.0)
        assert win.min_exposure == pytest.approx(
            min_exposure(area, sim.scenario.detector.readout.timing))
        lit = img.mask & (img.aovs["incidence"] < math.radians(88))
        v, u = np.nonzero(lit)
        assert m.apparent_radius_px == pytest.approx(math.sqrt(lit.sum() / math.pi), rel=0.03)
        assert np.hypot(m.centroid_uv[0] - u.mean(), m.centroid_uv[1] - v.mean()) < 2.0
        for f in m.features:
            r0, c0, h, w = m.windows[f.window]
            assert c0 <= f.uv[0] <= c0 + w - 1 and r0 <= f.uv[1] <= r0 + h - 1


def test_no_stage_reads_a_pixel_outside_the_windows_and_the_segments(rendered, monkeypatch):
    """Structural: the detector's full frame (DN, charge, signal) replaced by poison after
    the readout products were cut from it changes nothing in the front end's output; every
    pixel the reader handed out lies in a segments run or a window read that frame; a crop
    outside the windows is refused."""
    sim, renders, steps = rendered
    real = simtrn.expose

    def poisoned(*args, **kwargs):
        e = real(*args, **kwargs)
        return dataclasses.replace(e, dn=np.full_like(e.dn, 65535),
                                   electrons=np.full_like(e.electrons, np.nan),
                                   signal=np.full_like(e.signal, np.nan))

    monkeypatch.setattr(simtrn, "expose", poisoned)
    again = track_flyby(sim, renders=renders[:4])
    for a, b in zip(steps[:4], again, strict=True):
        ma, mb = a.frame.measurement, b.frame.measurement
        assert ma.windows == mb.windows
        assert [f.track_id for f in ma.features] == [f.track_id for f in mb.features]
        assert np.array_equal([f.uv for f in ma.features], [f.uv for f in mb.features])
        assert np.array_equal(ma.centroid_uv, mb.centroid_uv)
    monkeypatch.undo()
    fe = FlybyFrontEnd(sim.camera, TrnFrontEndConfig().to_si())
    for geom, img in renders[:3]:
        e0, e1, plan, reader = flyby_exposures(sim, img, geom, fe)
        fe.track(reader, plan)
        allowed = e0.segments.pixel_mask()
        for w in e1.windows:
            allowed[w.slices] = True
        assert reader.touched.any() and not np.any(reader.touched & ~allowed)
        r0, c0, h, w = plan.windows[0]
        with pytest.raises(WindowAccessError, match="not read"):
            reader.crop(r0, c0, h + 1, w)


def test_epipolar_ransac_with_the_known_rotation():
    """40 points of a 300 m body at 5 km seen from two poses (rotation 3 deg, baseline 150 m
    along a known direction) with 0.1 px noise, 6 of them displaced by 3-6 px: the 6 are
    exactly the outliers and the translation direction is recovered within 1 deg."""
    rng = np.random.default_rng(4)
    f_px = 1700.0
    P = rng.normal(0, 150.0, (40, 3)) + [0, 0, 5000.0]
    ang = math.radians(3.0)
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0],
                  [-math.sin(ang), 0, math.cos(ang)]])
    t = np.array([150.0, 20.0, -30.0])
    Q = P @ R.T + t
    x1 = P / P[:, 2:3]
    x2 = Q / Q[:, 2:3]
    x1[:, :2] += rng.normal(0, 0.1 / f_px, (40, 2))
    x2[:, :2] += rng.normal(0, 0.1 / f_px, (40, 2))
    bad = np.arange(6) * 6
    x2[bad, :2] += rng.choice([-1, 1], (6, 2)) * rng.uniform(3, 6, (6, 2)) / f_px
    inl, t_hat = epipolar_ransac(x1, x2, R, 1.0 / f_px, 100, np.random.default_rng(0))
    assert np.array_equal(np.flatnonzero(~inl), bad)
    cosang = abs(t_hat @ t) / np.linalg.norm(t)
    assert math.degrees(math.acos(min(cosang, 1.0))) < 1.0


def test_bad_inputs_and_a_frame_without_a_lit_body(rendered):
    """More than 16 windows is refused by the settings, the reader and the planner (naming
    the field); a frame whose segments hold no lit body gives an empty measurement (no
    centroid, no features) and ends every track."""
    with pytest.raises(ValidationError, match="n_windows"):
        TrnFrontEndConfig(n_windows=17)
    with pytest.raises(ConfigError, match=r"navigation\.trn\.front_end\.n_windows"):
        scenario_from_dict({"navigation": {"trn": {"front_end": {"n_windows": 17}}}})
    with pytest.raises(ValidationError, match="max_window_px"):
        TrnFrontEndConfig(max_window_px=20)
    with pytest.raises(ConfigError, match="max_tracks_per_window"):
        scenario_from_dict({"navigation": {"trn": {"front_end": {"max_tracks_per_window": 2}}}})
    seg = extract_segments(np.zeros((32, 32), np.uint16), (200,))
    with pytest.raises(ConfigError, match="at most 16"):
        WindowReader(seg, [Window(0, 0, np.zeros((2, 2), np.uint16))] * 17)
    sim, renders, _ = rendered
    fe = FlybyFrontEnd(sim.camera)
    geom, img = renders[0]
    e0, e1, plan, reader = flyby_exposures(sim, img, geom, fe)
    with pytest.raises(ConfigError, match="n_windows"):
        plan_windows(plan.body, [], n_windows=17, core_px=16, patch_half_px=13,
                     limb_margin_px=6, max_window_px=64)
    n = len(fe.track(reader, plan).measurement.features)
    assert n > 0
    dark = WindowReader(extract_segments(np.zeros((256, 256), np.uint16), (200,)))
    p = fe.plan(dark, index=1, epoch_tdb=0.0, R_cam_to_inertial=np.eye(3))
    assert p.status == "no-body" and p.windows == ()
    out = fe.track(dark, p)
    m = out.measurement
    assert out.status == "no-body" and out.counts["lost"] == n
    assert m.features == () and m.centroid_uv is None and m.apparent_radius_px is None
    assert m.pixels_read == 256 * 256 and fe.tracks == []
