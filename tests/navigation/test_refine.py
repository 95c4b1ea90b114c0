"""Subpixel refinement from windows (STAR Nav algorithm 1) with the PSF-aware edge model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import norm

from starnav.detector.products import Window
from starnav.navigation.limb import (
    LimbNotFoundError,
    limb_points_from_segments,
    segments_centroid,
    sun_direction_in_image,
)
from starnav.navigation.metrics import limb_point_errors
from starnav.navigation.ransac import ransac_limb
from starnav.navigation.refine import (
    RefineOptions,
    cut_windows,
    edge_profile,
    f_nu,
    plan_windows,
    refine_limb,
)

from .conftest import PSF_SIGMA_PX

#: Issue 6: limb bias after refinement on a well-exposed analytic disc.
REFINED_BIAS_PX = 0.05


@pytest.mark.parametrize("nu", [-0.5, 0.0, 0.5, 1.0])
def test_f_nu_against_quadrature(nu):
    """F_nu(t) = int_0^inf y^nu phi(t - y) dy (DLMF 12.5.1 closed form vs direct quadrature)."""
    for t in (-6.0, -2.0, -0.3, 0.0, 0.7, 2.5, 8.0, 25.0, 45.0):
        # the integrand lives within 12 sigma of y = t; the singularity of y^-1/2 at 0 is
        # integrable and split off
        lo, hi = max(0.0, t - 12.0), t + 12.0
        if hi <= 0:
            ref = 0.0
        else:
            cut = min(max(lo, 1.0), hi)
            f = lambda y, t=t: y**nu * norm.pdf(t - y)  # noqa: E731
            ref = quad(f, lo, cut, limit=200)[0] + quad(f, cut, hi, limit=200)[0]
        assert f_nu(nu, np.array([t]))[0] == pytest.approx(ref, rel=2e-5, abs=1e-7), t


def test_edge_profile_of_a_pure_step_is_the_normal_cdf():
    d = np.linspace(-4, 4, 33)
    prof = edge_profile(d, 1.3, (100.0, 0.0, 0.0), background=5.0)
    assert np.allclose(prof, 5.0 + 100.0 * norm.cdf(-d / 1.3), atol=1e-9)
    # and its derivative in t is nu F_(nu - 1): checked for the sqrt term by differences
    t = np.linspace(-3, 6, 50)
    h = 2e-2  # F_1/2 is tabulated every 0.01: difference over several table steps
    fd = (f_nu(0.5, t + h) - f_nu(0.5, t - h)) / (2 * h)
    assert np.allclose(fd, 0.5 * f_nu(-0.5, t), atol=1e-4)


def _refined(cam, frame, **kw):
    g, dn, seg = frame
    c0 = segments_centroid(seg)
    d = sun_direction_in_image(cam, g.R_cam_to_inertial, g.sun_direction, c0)
    lp = limb_points_from_segments(seg, d)
    rr = ransac_limb(lp.uv, cam, rng=np.random.default_rng(0))
    opt = RefineOptions(**kw)
    req = plan_windows(lp.uv[rr.inliers], rr.params[:2], shape=dn.shape, options=opt)
    fine = refine_limb(cut_windows(dn, req), rr.params[:2], rr.params[2], options=opt)
    return lp, fine


@pytest.mark.parametrize("psf", [None, PSF_SIGMA_PX], ids=["psf-fitted", "psf-known"])
def test_refined_limb_bias_on_a_well_exposed_disc(cam, disc_frame, psf):
    g = disc_frame[0]
    lp, fine = _refined(cam, disc_frame, psf_sigma_px=psf)
    e_pix = limb_point_errors(lp.uv, cam, g)
    e = limb_point_errors(fine.uv, cam, g)
    assert len(fine) == 16
    assert abs(e.mean()) < REFINED_BIAS_PX, f"refined bias {e.mean():.4f} px"
    assert np.max(np.abs(e)) < 0.1
    # the pixel-level points of the same frame are biased (10 % threshold): the check has teeth
    assert e_pix.mean() > 4 * REFINED_BIAS_PX


def test_refined_limb_with_noise_and_offset(cam, noisy_disc_frame):
    g = noisy_disc_frame[0]
    _, fine = _refined(cam, noisy_disc_frame)
    e = limb_point_errors(fine.uv, cam, g)
    assert len(fine) >= 14
    assert abs(e.mean()) < REFINED_BIAS_PX
    # reported uncertainties describe the scatter: rms of e / sigma within a factor 2 of 1
    # (for n >= 14 correct sigmas the chi2 probability of leaving [0.5, 2] is < 1e-4)
    z = e / fine.sigma_px
    assert 0.5 < math.sqrt(np.mean(z**2)) < 2.0


def test_blurred_step_model_is_biased_on_a_sphere(cam, disc_frame):
    """Without the sqrt onset of a sphere's limb the fit is biased inwards (~ -0.08 px): the
    physical edge model matters at this level."""
    g = disc_frame[0]
    _, fine = _refined(cam, disc_frame, edge_model="blurred-step")
    assert limb_point_errors(fine.uv, cam, g).mean() < -REFINED_BIAS_PX


def test_plan_windows(cam, disc_frame):
    g, dn, seg = disc_frame
    c0 = segments_centroid(seg)
    lp = limb_points_from_segments(seg, sun_direction_in_image(cam, g.R_cam_to_inertial,
                                                               g.sun_direction, c0))
    req = plan_windows(lp.uv, lp.centre_px, shape=dn.shape)
    assert len(req) == 16
    assert all(0 <= q.row0 <= 1024 - q.height and 0 <= q.col0 <= 1024 - q.width for q in req)
    assert len({(q.row0, q.col0) for q in req}) == 16
    # spread along the arc: consecutive window centres are separated
    c = np.array([[q.col0 + q.width / 2, q.row0 + q.height / 2] for q in req])
    assert np.min(np.linalg.norm(np.diff(c, axis=0), axis=1)) > 5.0
    # a window never exceeds the detector even at its corner
    corner = plan_windows(np.array([[0.0, 0.0], [1023.0, 1023.0]]), np.array([500.0, 500.0]),
                          shape=(1024, 1024))
    assert all(0 <= q.row0 <= 1013 and 0 <= q.col0 <= 1013 for q in corner)


def test_windows_without_a_limb_are_reported():
    wins = [Window(row0=10 * k, col0=10, dn=np.full((11, 11), 20, np.uint16)) for k in range(5)]
    with pytest.raises(LimbNotFoundError, match="0 of 5 windows") as err:
        refine_limb(wins, np.array([500.0, 500.0]), 80.0)
    assert err.value.reason == "no-edge"
