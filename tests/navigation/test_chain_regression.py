"""The chain's stages before and after the speed work of issue 18 give the same outputs.

Seeded regression test (exact frames, pinned outputs): ``data/chain_pins.json`` holds, for the
two frames of ``benchmarks/navigation.py`` (20 000 km: 600 limb points and 16 windows; 60 000
km: ~250 points), what the chain gave before its stages were vectorised (commit b35a942): the
pixel-level limb points, the RANSAC inlier sets (circle and Christian-Robinson models, seeded
generator), the Christian-Robinson fix of the inliers with its covariance, the fix of the
whole chain with and without the windows, and one EKF step (300 s prediction and update).

The limb scan, RANSAC, the fix and the filter are deterministic arithmetic on the same inputs:
rewriting their loops as array operations may only change the rounding, so the pins are tight
(points 1e-9 px, fixes and filter state 1e-9 relative, inlier sets equal). The frames are
synthetic (NumPy in double precision, no Dr.Jit render), so the pins hold on any CPU: rounding
differences between NumPy's SIMD paths are ~1e-16 relative. The chain with the
windows goes through the refinement, whose batched fit stops within 1e-4 px of its minimum: its
fix is held to 1e-6 relative, as in ``test_refine_regression.py``.

Re-pin (only after an explained, legitimate change)::

    PYTHONPATH=src python tests/navigation/test_chain_regression.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.constants import AU
from starnav.detector.schema import DetectorConfig
from starnav.navigation.christian_robinson import christian_robinson
from starnav.navigation.dynamics import PointMassDynamics
from starnav.navigation.ekf import FilterConfig, NavigationEkf
from starnav.navigation.limb import (
    limb_points_from_segments,
    segments_centroid,
    sun_direction_in_image,
)
from starnav.navigation.pipeline import ChainOptions, process_frame
from starnav.navigation.ransac import RansacConfig, ransac_limb
from starnav.navigation.refine import (
    EdgeSpread,
    PixelNoise,
    RefineConfig,
    RefineModels,
    packaged_model_error,
)
from starnav.navigation.synthetic import pointing_geometry, synthetic_frame

PINS = Path(__file__).with_name("data") / "chain_pins.json"
#: Agreement of the deterministic stages: points [px], fixes and states [relative].
POINT_TOL_PX = 1e-9
REL_TOL = 1e-9
#: The fix of the chain with windows [relative] (the refinement's convergence, see above).
REFINED_FIX_TOL = 1e-6
RANGES_KM = (20_000.0, 60_000.0)
T0 = 8.0e8


def _frame(range_km: float):
    """The frame of benchmarks/navigation.py at ``range_km``."""
    cam = Camera.preset("aa-str")
    rel = np.array([1.0, 0.3, -0.2])
    rel *= range_km * 1e3 / np.linalg.norm(rel)
    sun = AU * np.array([math.cos(1.0), math.sin(1.0), 0.05])
    g = pointing_geometry(cam, rel, sun, camera_velocity=np.array([0.0, 1000.0, 0.0]),
                          epoch_tdb=T0, moon_offset_px=(60.0, -40.0))
    frame = synthetic_frame(cam, g, supersample=4, psf_sigma_px=0.8, read_noise_dn=2.0,
                            rng=np.random.default_rng(0))
    return cam, g, frame


def _navigate_refine() -> ChainOptions:
    det = DetectorConfig()
    return ChainOptions(refine=RefineConfig(edge_model="detector-psf").to_si(),
                        refine_models=RefineModels(spread=EdgeSpread.from_detector(det),
                                                   noise=PixelNoise.from_detector(det),
                                                   model_error_table=packaged_model_error()))


def _measure_case(range_km: float, dyn: PointMassDynamics) -> dict:
    cam, g, frame = _frame(range_km)
    seg, R = frame.segments, frame.R_cam_to_inertial_measured
    sdir = sun_direction_in_image(cam, R, frame.sun_direction_inertial, segments_centroid(seg))
    lp = limb_points_from_segments(seg, sdir, options=ChainOptions().limb)
    rr = ransac_limb(lp.uv, cam, rng=np.random.default_rng(1))
    rcr = ransac_limb(lp.uv, cam, rng=np.random.default_rng(2),
                      options=RansacConfig(model="christian-robinson", threshold_px=1.0).to_si())
    fix = christian_robinson(lp.uv[rr.inliers], cam, sigma_px=0.5)
    plain = process_frame(frame, cam, options=ChainOptions(use_windows=False),
                          rng=np.random.default_rng(1))
    full = process_frame(frame, cam, options=_navigate_refine(),
                         rng=np.random.default_rng(1))
    x0 = dyn.moon_state(T0) + np.concatenate([g.camera_position, g.camera_velocity])
    ekf = NavigationEkf(dyn, dyn, T0 - 300.0, x0, np.diag([100e3**2] * 3 + [1.0] * 3),
                        options=FilterConfig(accel_psd_m2_s3=0.0).to_si())  # perfect dynamics
    ekf.predict(T0)
    x_pred, P_pred = ekf.x.copy(), ekf.P.copy()
    info = ekf.update(plain.position, plain.covariance)
    return {
        "limb_uv": lp.uv.tolist(), "limb_centre": lp.centre_px.tolist(),
        "limb_radius": lp.radius_px,
        "ransac_inliers": np.flatnonzero(rr.inliers).tolist(), "ransac_params": rr.params.tolist(),
        "ransac_cr_inliers": np.flatnonzero(rcr.inliers).tolist(),
        "fix_centre": fix.centre_camera.tolist(), "fix_cov": fix.covariance_camera.tolist(),
        "chain_position": plain.position.tolist(), "chain_cov": plain.covariance.tolist(),
        "full_position": full.position.tolist(), "full_cov": full.covariance.tolist(),
        "full_n_refined": len(full.refined),
        "ekf_x_pred": x_pred.tolist(), "ekf_P_pred": P_pred.tolist(),
        "ekf_x": ekf.x.tolist(), "ekf_P": ekf.P.tolist(), "ekf_nis": info.nis,
    }


def _measure() -> dict:
    dyn = PointMassDynamics(step_s=300.0)
    return {f"{r:.0f}km": _measure_case(r, dyn) for r in RANGES_KM}


@pytest.fixture(scope="module")
def measured() -> dict:
    return _measure()


@pytest.fixture(scope="module")
def pins() -> dict:
    return json.loads(PINS.read_text())


CASES = [f"{r:.0f}km" for r in RANGES_KM]


def _rel(got, want) -> float:
    got, want = np.asarray(got, float), np.asarray(want, float)
    assert got.shape == want.shape
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


@pytest.mark.parametrize("case", CASES)
def test_limb_points(measured, pins, case):
    got, want = measured[case], pins[case]
    uv, uv0 = np.asarray(got["limb_uv"]), np.asarray(want["limb_uv"])
    assert uv.shape == uv0.shape
    assert np.max(np.abs(uv - uv0)) <= POINT_TOL_PX
    assert np.max(np.abs(np.subtract(got["limb_centre"], want["limb_centre"]))) <= POINT_TOL_PX
    assert abs(got["limb_radius"] - want["limb_radius"]) <= POINT_TOL_PX


@pytest.mark.parametrize("case", CASES)
def test_ransac_inlier_sets(measured, pins, case):
    got, want = measured[case], pins[case]
    assert got["ransac_inliers"] == want["ransac_inliers"]
    assert got["ransac_cr_inliers"] == want["ransac_cr_inliers"]
    assert np.max(np.abs(np.subtract(got["ransac_params"], want["ransac_params"]))) <= 1e-9


@pytest.mark.parametrize("case", CASES)
def test_fixes(measured, pins, case):
    got, want = measured[case], pins[case]
    assert _rel(got["fix_centre"], want["fix_centre"]) <= REL_TOL
    assert _rel(got["fix_cov"], want["fix_cov"]) <= REL_TOL
    assert _rel(got["chain_position"], want["chain_position"]) <= REL_TOL
    assert _rel(got["chain_cov"], want["chain_cov"]) <= REL_TOL
    assert got["full_n_refined"] == want["full_n_refined"]
    assert _rel(got["full_position"], want["full_position"]) <= REFINED_FIX_TOL
    # the covariance of the refined fix follows the points' sigmas (1 % in
    # test_refine_regression) and the fix; the batched fit moves it by far less
    assert _rel(got["full_cov"], want["full_cov"]) <= 1e-4


@pytest.mark.parametrize("case", CASES)
def test_ekf_step(measured, pins, case):
    got, want = measured[case], pins[case]
    for key in ("ekf_x_pred", "ekf_P_pred", "ekf_x", "ekf_P"):
        assert _rel(got[key], want[key]) <= REL_TOL, key
    assert got["ekf_nis"] == pytest.approx(want["ekf_nis"], rel=REL_TOL)


if __name__ == "__main__":
    from starnav.atomic import atomic_write_text

    atomic_write_text(PINS, json.dumps(_measure(), indent=1) + "\n")
    print(f"wrote {PINS}")
