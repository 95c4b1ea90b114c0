"""The navigation side's PSF and terrain knowledge are its own: an estimate from star images and a
coarser DEM, never the simulator's settings (truth richer than the model)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from starnav.batch.presets import demo_scenario
from starnav.camera import camera_from_config
from starnav.config import scenario_from_dict
from starnav.navigation.psf import (
    PSF_PARAMETERS,
    PsfEstimate,
    estimate_psf,
    estimated_psf,
    psf_fingerprint,
    star_calibration_frames,
)

#: Joint false-alarm rate of the estimate-vs-truth chi-square tests.
ALPHA = 1e-3


@pytest.fixture(scope="module")
def demo():
    sc = scenario_from_dict(demo_scenario(), [])
    return sc, camera_from_config(sc.camera)


def _mahalanobis(est: PsfEstimate, truth) -> float:
    d = np.array([getattr(est.aberration, k) - getattr(truth, k) for k in PSF_PARAMETERS])
    return float(d @ np.linalg.solve(np.array(est.covariance), d))


def test_estimate_of_another_psf_finds_it_within_its_covariance(demo):
    """A detector whose PSF is 25 % wider than the design (and not the fit's start): the fit to
    its star frames lands on it within the estimate's own covariance (5 dof, 0.1 %)."""
    sc, cam = demo
    ab = sc.detector.optics.aberration
    wide = sc.detector.model_copy(update={"optics": sc.detector.optics.model_copy(update={
        "aberration": ab.model_copy(update={k: 1.25 * getattr(ab, k) for k in PSF_PARAMETERS})})})
    est = estimate_psf(star_calibration_frames(wide, cam, n_frames=1, n_stars=60, seed=31),
                       cam, wide)
    assert est.n_stars >= 40
    assert _mahalanobis(est, wide.optics.aberration) < chi2.ppf(1 - ALPHA, 5)
    # and it is not the design's PSF
    assert _mahalanobis(est, ab) > chi2.ppf(1 - ALPHA, 5)


def test_packaged_estimate_is_the_default_trackers_and_holds_its_own_error(demo):
    """The packaged estimate (tools/estimate_psf.py) is made for the default detector and
    camera; it is close to the setting but not equal to it (its own error), within 0.1 px."""
    sc, cam = demo
    est = estimated_psf(sc.detector, cam)
    assert est.fingerprint == psf_fingerprint(sc.detector, cam)
    d = [getattr(est.aberration, k) - getattr(sc.detector.optics.aberration, k)
         for k in PSF_PARAMETERS]
    assert 0 < max(map(abs, d)) < 0.1
    assert PsfEstimate.from_dict(est.to_dict()) == est


def test_chain_options_navigate_with_the_estimate_and_a_coarser_terrain(demo):
    """By default the edge model's PSF is the estimate and the limb-height statistics come from
    a 1 px/deg DEM; the analysis options restore the simulator's own."""
    sc, _ = demo
    opt = sc.navigation.chain_options(scenario=sc)
    assert opt.refine_models.spread.aberration != sc.detector.optics.aberration
    assert opt.refine_models.spread.aberration == estimated_psf(
        sc.detector, camera_from_config(sc.camera)).aberration
    perfect = scenario_from_dict(demo_scenario(), ["navigation.refine.psf_knowledge=detector",
                                                   "navigation.refine.terrain_model_ppd=null"])
    popt = perfect.navigation.chain_options(scenario=perfect)
    assert popt.refine_models.spread.aberration == sc.detector.optics.aberration
    # the coarse grid smooths the relief: a smaller limb-height spread than the rendered DEM's
    coarse, fine = opt.refine_models.limb_topography, popt.refine_models.limb_topography
    assert 0.85 < coarse.std_m / fine.std_m < 0.99
