"""The navigation report's overlay figures: the file exists and is linked, and the geometry
drawn (fitted and true limb polylines) is the limb conic to 0.1 px."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from starnav.constants import MOON_RADIUS
from starnav.dataset import open as open_dataset
from starnav.navigation.christian_robinson import limb_conic_pixels, shape_transform
from starnav.navigation.metrics import conic_signed_distance, undistorted_pixels
from starnav.navigation.plots import fitted_limb_polyline, true_limb_polyline
from starnav.navigation.report import budget_warning, navigate_dataset

#: The drawn limb must lie on the conic to this [px].
POLYLINE_TOL_PX = 0.1


@pytest.mark.slow
def test_overlay_figures_exist_and_the_report_links_them(small_dataset, tmp_path):
    ds = open_dataset(small_dataset, exposure=1.5e-5)
    s = navigate_dataset(ds, tmp_path / "nav", measure_memory=False, plots=True)
    over = sorted(k for k in s["paths"] if k.startswith("overlay_"))
    # first, middle and last of the 4 frames with a limb: 0, 2, 3
    assert over == ["overlay_000000", "overlay_000002", "overlay_000003"]
    report = (tmp_path / "nav" / "report.md").read_text()
    linked = re.findall(r"\]\((overlay_\d{6}\.png)\)", report)
    assert linked == [f"{k}.png" for k in over]
    for name in linked:
        assert (tmp_path / "nav" / name).stat().st_size > 10_000
    assert "true limb" in report and "RANSAC" in report


def test_drawn_limbs_lie_on_the_conic(small_dataset):
    ds = open_dataset(small_dataset, exposure=1.5e-5)
    cam = ds.camera
    r = (MOON_RADIUS,) * 3
    for frame in ds:
        g = frame.truth
        R_b2c = g.R_cam_to_inertial.T @ g.R_body_to_inertial
        Q = limb_conic_pixels(cam, g.moon_centre_camera(), shape_transform(r, R_b2c))
        tru = true_limb_polyline(cam, g, r)
        d = conic_signed_distance(Q, undistorted_pixels(cam, tru))
        assert np.max(np.abs(d)) < POLYLINE_TOL_PX
        # closed, and around the true Moon centre pixel at the apparent radius
        assert np.array_equal(tru[0], tru[-1])
        c = np.asarray(g.moon_centre_pixel(cam, distort=True))
        rad = np.hypot(*(tru - c).T)
        r_px = cam.fx * np.tan(g.apparent_radius)
        assert np.allclose(rad, r_px, rtol=0.02)
        # a fit 1 % farther away: its limb lies on its own conic, inside the true one
        centre = 1.01 * g.moon_centre_camera()
        fit = fitted_limb_polyline(cam, centre, r, R_b2c)
        Qf = limb_conic_pixels(cam, centre, shape_transform(r, R_b2c))
        assert np.max(np.abs(conic_signed_distance(Qf, undistorted_pixels(cam, fit)))) \
            < POLYLINE_TOL_PX
        assert np.all(conic_signed_distance(Q, undistorted_pixels(cam, fit)) < 0)


def test_budget_warning_when_the_median_exceeds_the_budget():
    s = {"timing_ms": {"chain_cpu_median": 7.25, "budget": 5.0}}
    assert budget_warning(s) == ("warning: the chain's median CPU time 7.25 ms exceeds the "
                                 "tracker's 5 ms budget (Python on the machine that ran "
                                 "it; see resources.png)")
    assert budget_warning({"timing_ms": {"chain_cpu_median": 4.9, "budget": 5.0}}) is None


def test_navigate_prints_the_budget_warning(small_dataset, tmp_path, monkeypatch):
    from starnav.cli.main import app
    from starnav.navigation import report

    monkeypatch.setattr(report, "BUDGET_MS", 1e-6)   # any real chain exceeds 1 ns
    res = CliRunner().invoke(app, ["navigate", str(small_dataset), "--out",
                                   str(tmp_path / "nav"), "--no-plots"],
                             env={"COLUMNS": "50"})
    assert res.exit_code == 0, res.output
    lines = [x for x in res.output.splitlines() if x.startswith("warning:")]
    assert len(lines) == 1 and "exceeds the tracker's 1e-06 ms budget" in lines[0]
