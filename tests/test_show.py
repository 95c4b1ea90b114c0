"""``starnav show``: the framing geometry (pure) and one real offscreen render (pixels, no
warning on stdout/stderr)."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from starnav.config import Scenario
from starnav.show import (
    BODY_FILL,
    OVERVIEW_MARGIN,
    VIEW_MARGIN,
    body_view,
    fit_view,
    layout_scene,
    sphere_points,
)
from starnav.simulate import scene_from_scenario

#: Projection tolerance [fraction of the image]: the fit is exact up to rounding.
EPS = 1e-9


def test_fit_view_puts_every_point_inside_the_margin_and_is_tight():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(200, 3)) * [5e4, 1e4, 3e3] + [2e4, 0, 0]
    for aspect in (1.0, 2.0):
        view = fit_view(pts, [0.3, 0.2, 1.0], [0, 1, 0], aspect=aspect, margin=VIEW_MARGIN)
        uv = view.project(pts, aspect)
        ndc = np.abs(2 * uv - 1)
        assert ndc.max() <= 1 - VIEW_MARGIN + EPS          # all inside the margin
        assert ndc.max() >= 1 - VIEW_MARGIN - 1e-6          # and touching it: no wasted room


def test_the_body_fills_the_stated_fraction_of_the_close_view():
    view = body_view((0, 0, 0), 1737.4, (6e4, 1e3, -2e3), (0, 0, 1))
    uv = view.project(sphere_points((0, 0, 0), 1737.4, 4000))
    # the silhouette's extreme over a dense sphere sampling: BODY_FILL of the height, centred
    assert 2 * np.abs(uv[:, 1] - 0.5).max() == pytest.approx(BODY_FILL, rel=2e-3)
    assert uv.mean(axis=0) == pytest.approx([0.5, 0.5], abs=1e-3)


@pytest.fixture(scope="module")
def layout():
    return layout_scene(scene_from_scenario(Scenario()), aspect=1.0)


def test_the_sun_arrow_body_and_observer_are_inside_the_overview(layout):
    view = layout.overview
    for name, pts in [("sun tip", layout.sun_tip_km[None, :]),
                      ("observer", layout.observers_km),
                      ("body", sphere_points((0, 0, 0), layout.radius_km)),
                      ("frustum", np.vstack(layout.frusta_km))]:
        ndc = np.abs(2 * view.project(pts, layout.aspect) - 1)
        assert ndc.max() <= 1 - OVERVIEW_MARGIN + EPS, name
    # the default static frame: observer at 60 000 km, the arrow half of it, phase 30 deg
    assert np.linalg.norm(layout.observers_km[0]) == pytest.approx(6e4)
    assert layout.arrow_km == pytest.approx(3e4)
    cos_phase = layout.sun_dir @ layout.observers_km[0] / 6e4
    assert math.degrees(math.acos(cos_phase)) == pytest.approx(30.0)
    # the close view looks from the observer's side: the Sun arrow tip is in front of it
    tip = layout.close_arrow_km * layout.sun_dir
    ndc = np.abs(2 * layout.close.project(tip[None, :]) - 1)
    assert ndc.max() < 1 - VIEW_MARGIN


@pytest.mark.slow
def test_show_writes_a_clear_figure_without_a_word_on_stderr(tmp_path, layout):
    import matplotlib.image as mpimg

    out = tmp_path / "scene.png"
    env = {**os.environ, "COLUMNS": "50"}
    env.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
    env.pop("DISPLAY", None)  # as on a headless server: the X window would warn
    r = subprocess.run([sys.executable, "-m", "starnav.cli.main", "show", "--out", str(out)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""                                  # no VTK / X-server warning
    assert r.stdout == f"wrote {out}\n"
    img = mpimg.imread(out)[..., :3]                        # (900, 1800, 3) floats in [0, 1]
    h, w, _ = img.shape
    assert (h, w) == (900, 1800)
    black = np.all(img < 0.1, axis=2)
    assert black.mean() < 0.05                              # not "mostly black"
    background = np.all(np.abs(img - img[h - 2, w // 2 + 2]) < 0.02, axis=2)
    close = ~background[:, w // 2:]
    # the body covers pi (BODY_FILL / 2)^2 = 24 % of the square right panel (+ arrow, text)
    assert close.mean() > 0.9 * math.pi * (BODY_FILL / 2) ** 2
    assert (~background[:, : w // 2]).mean() > 0.03        # the overview has content
    # the Sun arrow (its colour) ends where the framing geometry puts its tip, in the panel
    gold = np.all(np.abs(img - np.array([0xE6, 0xA8, 0x00]) / 255) < 0.08, axis=2)
    u, v = layout.overview.project(layout.sun_tip_km[None, :], layout.aspect)[0]
    col, row = u * (w // 2), (1 - v) * h
    assert 0 < col < w // 2 and 0 < row < h
    rows, cols = np.nonzero(gold[:, : w // 2])
    assert np.hypot(rows - row, cols - col).min() < 6     # [px]: the arrow reaches its tip
