"""The fly-by report's frame overlays (issue 16): what is drawn is the front end's own
geometry (its windows, its measured pixels, the truth it carries, its centroid), on the very
segments image it read, and the estimator's predicted lit centroid is the shape model's.

A 5-frame cut of the scoring fly-by (Itokawa, 256 x 256 px, CA 5 km at 0.5 km/s, phase 60 deg,
frames 0.2 s apart about CA), rendered once (~2 s), one run.
"""

from __future__ import annotations

import dataclasses
import os
from types import SimpleNamespace

import numpy as np
import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from starnav.batch.flyby import flyby_closed_loop, plot_overlays
from starnav.config import scenario_from_dict
from starnav.navigation.trn.metrics import draw_frame_overlay, predicted_silhouette
from starnav.navigation.trn.options import BLOCK_PX, MIN_BODY_AREA_PX
from starnav.navigation.trn.windows import analyse_segments
from starnav.simulate import Simulator
from starnav.simulate.build import body_from_scenario
from starnav.simulate.flyby import render_flyby, segments_image

FRAMES = 5


@pytest.fixture(scope="module")
def setup():
    sc = scenario_from_dict({
        "camera": {"width": 256, "height": 256, "focal_length_mm": 30.0},
        "render": {"spp": 4},
        "target": {"kind": "shape_model", "model": "itokawa"},
        "trajectory": {"source": "flyby", "cadence_s": 0.2, "frames": FRAMES,
                       "flyby": {"closest_approach_km": 5.0, "v_inf_km_s": 0.5,
                                 "phase_at_ca_deg": 60.0, "start_s": -0.4}},
        "pointing": {"moon_offset": "fixed", "roll": "fixed"},
        "detector": {"exposure_time_s": 3e-5}, "seed": 7})
    sim = Simulator(sc)
    renders, _ = render_flyby(sim)
    return sim, renders, flyby_closed_loop(sim, 1, renders=renders, first_run=1)


def test_segments_image_is_the_one_the_front_end_read(setup):
    """Re-exposed with the run's noise stream, the segments give the front end's own lit
    centroid and radius, to the last bit (run 1: not the frame's default stream)."""
    sim, renders, loop = setup
    for k in (0, FRAMES - 1):
        img = segments_image(sim, renders[k], run=1)
        reader = SimpleNamespace(segments_image=lambda img=img: img)
        fix = analyse_segments(reader, block_px=BLOCK_PX, min_area_px=MIN_BODY_AREA_PX)
        m = loop.runs[0].measurements[k]
        assert np.array_equal(fix.centroid_uv, m.centroid_uv)
        assert fix.radius_px == m.apparent_radius_px
    assert not np.array_equal(segments_image(sim, renders[0], run=0),
                              segments_image(sim, renders[0], run=1))


def test_overlay_draws_the_measurement_geometry(setup):
    """Rectangles = the measurement's windows (over their pixels: edges half a pixel out),
    labelled W0...; the measured points = the features' uv, the circles = their true
    projections, the crosses = the measured and predicted centroids; axes span the array."""
    sim, renders, loop = setup
    run = loop.runs[0]
    k = FRAMES // 2
    m = run.measurements[k]
    assert m.windows and m.features and m.truth
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    pred = np.array([120.25, 131.5])
    draw_frame_overlay(ax, segments_image(sim, renders[k], run=1), m, pred)
    rects = [p for p in ax.patches if isinstance(p, Rectangle)]
    got = [(p.get_y() + 0.5, p.get_x() + 0.5, p.get_height(), p.get_width()) for p in rects]
    assert got == [tuple(float(x) for x in w) for w in m.windows]
    assert [t.get_text() for t in ax.texts] == [f"W{i}" for i in range(len(m.windows))]
    coll = {c.get_label(): c for c in ax.collections}
    pts = {k: np.asarray(c.get_offsets(), float) for k, c in coll.items()}
    assert np.array_equal(pts["tracked (measured)"], [f.uv for f in m.features])
    truth = [t.uv_true for t in m.truth if np.all(np.isfinite(t.uv_true))]
    assert np.array_equal(pts["true projection"], truth)
    assert np.array_equal(pts["lit centroid, measured"], [m.centroid_uv])
    assert np.array_equal(pts["lit centroid, predicted"], [pred])
    # one colour per track: the measured '+' and its true 'o' share it
    fc = coll["tracked (measured)"].get_facecolors()
    ec = coll["true projection"].get_edgecolors()
    ids = [f.track_id for f in m.features]
    tids = [t.track_id for t in m.truth if np.all(np.isfinite(t.uv_true))]
    for i, tid in enumerate(tids):
        assert np.allclose(ec[i], fc[ids.index(tid)])
    assert ax.get_xlim() == (-0.5, 255.5) and ax.get_ylim() == (255.5, -0.5)
    assert ax.get_legend() is not None and "[px]" in ax.get_xlabel()


def test_predicted_centroid_from_the_true_state_matches_the_measured_one(setup):
    """The lit silhouette of the shape model from the TRUE position and attitude is the
    segments' lit body to its calibrated model error (centroid bias ~1.3 px along the Sun,
    0.9 px rms; radius 1.6 %, data/navigation/flyby_model_error.json): within 4 px and 5 %."""
    sim, renders, loop = setup
    body = body_from_scenario(sim.scenario)
    X = sim.scene.relative_states
    for k, m in enumerate(loop.runs[0].measurements):
        geom = renders[k][0]
        mt = dataclasses.replace(m, R_cam_to_inertial=geom.R_cam_to_inertial)
        sil = predicted_silhouette(sim.camera, body, X[k, :3], mt)
        assert np.linalg.norm(sil.centroid_uv - m.centroid_uv) < 4.0
        assert sil.radius_px == pytest.approx(m.apparent_radius_px, rel=0.05)


def test_plot_overlays_one_file_per_chosen_frame(setup, tmp_path):
    """First, closest approach (the middle frame) and last: three PNG files."""
    sim, renders, loop = setup
    paths = plot_overlays(sim, renders, loop, tmp_path)
    assert [p.name for p in paths] == ["overlay_first.png", "overlay_ca.png",
                                       "overlay_last.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in paths)
