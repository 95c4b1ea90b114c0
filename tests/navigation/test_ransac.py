"""RANSAC outlier rejection: the paper's circle model and the conic-aware Christian-Robinson
model (docs/facts.md s4: a sphere's limb is an ellipse off-axis, up to ~1.7 px from a circle)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from starnav.geometry import static_geometry
from starnav.navigation.limb import fit_circle_kasa
from starnav.navigation.ransac import RansacConfig, RansacError, ransac_limb


def _limb_with_outliers(cam, offset, n=300, frac=0.3, seed=1, noise=0.2):
    g = static_geometry(cam, 3.0e7, math.radians(30), moon_offset_px=offset)
    rng = np.random.default_rng(seed)
    pts = g.limb_points(cam, n=2 * n)[:n] + rng.normal(0, noise, (n, 2))
    k = int(frac * n)
    bad = rng.choice(n, k, replace=False)
    # outliers: stars, hot pixels and terminator points 3-40 px inside or outside the limb
    c = g.moon_centre_pixel(cam)
    rel = pts[bad] - c
    pts[bad] += rel / np.linalg.norm(rel, axis=1)[:, None] * rng.uniform(3, 40, (k, 1)) * \
        rng.choice([-1, 1], (k, 1))
    is_out = np.zeros(n, bool)
    is_out[bad] = True
    return g, pts, is_out


@pytest.mark.parametrize("model,thr", [("circle", 2.0), ("christian-robinson", 1.0)])
def test_outliers_are_rejected(cam, model, thr):
    g, pts, is_out = _limb_with_outliers(cam, (100.0, -50.0))
    res = ransac_limb(pts, cam, rng=np.random.default_rng(0),
                      options=RansacConfig(model=model, threshold_px=thr).to_si())
    assert not np.any(res.inliers & is_out), "an outlier survived"
    assert np.mean(res.inliers[~is_out]) > 0.99
    assert res.iterations < 200  # adaptive stop at 70 % inliers


def test_conic_model_keeps_the_off_axis_limb_where_the_circle_cannot(cam):
    """Near the field corner the limb of a 30 000 km Moon is an ellipse ~1 px from its best
    circle: a 0.5 px circle threshold loses true limb points, the Christian-Robinson model
    scores the exact conic and keeps them all."""
    g = static_geometry(cam, 3.0e7, math.radians(30), moon_offset_px=(380.0, 380.0))
    pts = g.limb_points(cam, n=400)
    c, r = fit_circle_kasa(pts)
    misfit = np.max(np.abs(np.linalg.norm(pts - c, axis=1) - r))
    assert misfit > 0.5
    circ = ransac_limb(pts, cam, rng=np.random.default_rng(0),
                       options=RansacConfig(model="circle", threshold_px=0.5,
                                             min_inlier_fraction=0.05).to_si())
    cr = ransac_limb(pts, cam, rng=np.random.default_rng(0),
                     options=RansacConfig(model="christian-robinson", threshold_px=0.05).to_si())
    assert circ.n_inliers < 0.9 * len(pts)
    assert cr.n_inliers == len(pts)
    assert np.max(np.abs(cr.residual_px)) < 1e-6


def test_bad_input_messages(cam):
    rng = np.random.default_rng(0)
    with pytest.raises(RansacError, match="2 limb points, need >= 3"):
        ransac_limb(np.zeros((2, 2)), cam, rng=rng)
    # scattered points: no consensus
    pts = rng.uniform(0, 1000, (50, 2))
    with pytest.raises(RansacError, match="consistent with one limb"):
        ransac_limb(pts, cam, rng=rng, options=RansacConfig(threshold_px=0.5,
                                                            min_inlier_fraction=0.5).to_si())
    with pytest.raises(ValidationError, match="model\n.*'circle' or 'christian-robinson'"):
        RansacConfig(model="ellipse")
