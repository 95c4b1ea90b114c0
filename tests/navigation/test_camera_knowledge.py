"""Navigation with the camera a calibration file describes, not the simulator's: the file is
read through navigation.camera_calibration, a 1 % focal-length error between the truth's
camera and the calibrated one shows in the fix as a 1 % range scale, and the calibration's
covariance enters the fix's as consider parameters (range 1-sigma ~ range x sigma_f / f)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.camera_calibration import CameraCalibration, with_parameters, write_calibration
from starnav.errors import ConfigError
from starnav.geometry import static_geometry
from starnav.navigation.pipeline import ChainOptions, process_frame
from starnav.navigation.schema import NavigationConfig
from starnav.navigation.synthetic import synthetic_frame

RANGE = 6.0e7
SIGMA_F = 0.005  # relative 1-sigma of the calibrated focal length


@pytest.fixture(scope="module")
def truth_camera() -> Camera:
    return Camera.preset("aa-str")


@pytest.fixture(scope="module")
def frame(truth_camera):
    g = static_geometry(truth_camera, RANGE, math.radians(30.0))
    return synthetic_frame(truth_camera, g, windows=False, peak_dn=3000.0,
                           rng=np.random.default_rng(4)), g


@pytest.fixture
def calibration_file(tmp_path, truth_camera):
    f = truth_camera.focal_length
    cal = CameraCalibration(
        camera=with_parameters(truth_camera, {"focal_length_m": 1.01 * f}),
        parameters=("focal_length_m", "cx_px", "cy_px"),
        covariance=np.diag([(SIGMA_F * f) ** 2, 0.3**2, 0.3**2]),
        provenance={"method": "test: the truth's focal length + 1 %"})
    return write_calibration(tmp_path / "camera_calibration.json", cal)


def test_navigation_reads_the_calibration_file(calibration_file, truth_camera):
    nav = NavigationConfig.model_validate({"camera_calibration": str(calibration_file)})
    chain = nav.chain_options()
    assert chain.calibration is not None
    assert chain.calibration.camera.focal_length == pytest.approx(
        1.01 * truth_camera.focal_length, rel=1e-12)
    assert NavigationConfig().chain_options().calibration is None


def test_one_percent_focal_error_is_a_one_percent_range_scale(calibration_file, frame,
                                                             truth_camera):
    """Pixel-level fixes of the same frame: with the calibrated camera the range is 1.01
    times the one with the true camera (the disc's angular size scales as 1/f), to 0.05 %;
    the direction is unchanged to 1e-5 rad."""
    fr, g = frame
    chain = NavigationConfig.model_validate(
        {"camera_calibration": str(calibration_file),
         "refine": {"enabled": False}}).chain_options()
    known = process_frame(fr, truth_camera, options=ChainOptions(
        limb=chain.limb, ransac=chain.ransac, fix=chain.fix, use_windows=False),
        rng=np.random.default_rng(1))
    calib = process_frame(fr, truth_camera, options=chain, rng=np.random.default_rng(1))
    assert known.status == "ok" and calib.status == "ok"
    r0, r1 = np.linalg.norm(known.position), np.linalg.norm(calib.position)
    assert r0 == pytest.approx(RANGE, rel=1e-2)  # pixel-level points: ~0.6 % bias
    assert r1 / r0 == pytest.approx(1.01, abs=5e-4)
    cos = float(known.position @ calib.position) / (r0 * r1)
    assert math.acos(min(cos, 1.0)) < 1e-5
    # the consider term: along the line of sight the fix's variance gains (range sigma_f)^2
    u = calib.position / r1
    extra = float(u @ (calib.covariance - known.covariance) @ u)
    assert math.sqrt(extra) == pytest.approx(r1 * SIGMA_F, rel=0.1)


def test_a_calibration_of_another_detector_is_refused(tmp_path, truth_camera):
    other = Camera.preset("aa-str", width=512, height=512)
    cal = CameraCalibration(camera=other, parameters=("focal_length_m",),
                            covariance=np.array([[1e-10]]))
    p = write_calibration(tmp_path / "other.json", cal)

    class _Sc:
        from starnav.camera import CameraConfig
        camera = CameraConfig()

    nav = NavigationConfig.model_validate({"camera_calibration": str(p)})
    with pytest.raises(ConfigError, match="navigation.camera_calibration"):
        nav.calibration(_Sc())


def test_a_principal_point_error_cancels_through_the_star_attitude(frame, truth_camera):
    """A calibrated principal point (8, -5) px off: the attitude a star solve through that
    camera gives turns with it (star_alignment), so the Moon's fix keeps its direction to
    5 % of the offset's angle; used with the frame's attitude as it is, the same camera
    moves the fix by the whole offset. With a 5 px principal-point sigma the consider term
    adds almost nothing across the line of sight (the stars move as the Moon does)."""
    fr, _ = frame
    base = NavigationConfig.model_validate(
        {"camera_calibration": None, "refine": {"enabled": False}}).chain_options()
    off = with_parameters(truth_camera, {"cx_px": truth_camera.cx + 8.0,
                                         "cy_px": truth_camera.cy - 5.0})
    cal = CameraCalibration(camera=off, parameters=("cx_px", "cy_px"),
                            covariance=np.diag([25.0, 25.0]))

    def angle(a, b):
        return math.acos(min(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)), 1.0))

    known = process_frame(fr, truth_camera, options=base, rng=np.random.default_rng(1))
    calib = process_frame(fr, truth_camera, options=replace(base, calibration=cal),
                          rng=np.random.default_rng(1))
    naive = process_frame(fr, off, options=base, rng=np.random.default_rng(1))
    assert known.status == calib.status == naive.status == "ok"
    offset = math.hypot(8.0, 5.0) * truth_camera.ifov
    assert angle(known.position, naive.position) > 0.8 * offset
    assert angle(known.position, calib.position) < 0.05 * offset
    r = np.linalg.norm(calib.position)
    u = calib.position / r
    extra = calib.covariance - known.covariance
    across = np.eye(3) - np.outer(u, u)
    assert math.sqrt(np.trace(across @ extra @ across) / 2) < 0.05 * r * 5 * truth_camera.ifov


def test_bench_knowledge_is_one_emulated_bench_per_run(truth_camera):
    """navigation.camera_calibration: bench (the default): each run knows the default tracker
    as one seeded emulated bench calibrated it (the truth plus that bench's realised error,
    with its stated covariance), reproducibly per (seed, run); the runs sample several
    benches; another camera is not given the default tracker's benches."""
    from starnav.camera_calibration import _bench_pool, bench_calibration, parameter_values
    from starnav.config import Scenario

    sc = Scenario()
    assert sc.navigation.camera_calibration == "bench"
    exact = sc.navigation.model_copy(update={"camera_calibration": None})
    assert exact.calibration(sc) is None
    nav = sc.navigation
    cal = nav.calibration(sc, 3)
    assert cal is not None and cal.camera == nav.calibration(sc, 3).camera
    seeds = {nav.calibration(sc, r).provenance["bench_seed"] for r in range(12)}
    assert len(seeds) >= 4
    pool = {b["seed"]: b for b in _bench_pool()["benches"]}
    e = cal.estimate - parameter_values(truth_camera, cal.parameters)
    assert np.allclose(e, pool[cal.provenance["bench_seed"]]["error"], rtol=0, atol=1e-12)
    assert bench_calibration(Camera.preset("aa-str", width=512, height=512), 1, 0) is None
    assert nav.calibration(None) is None


def test_consider_jacobian_matches_central_differences(frame, truth_camera):
    """camera_consider_jacobian's first-order form (the fix's point Jacobian times the pixel
    shift each moved parameter makes, no new solve) against central differences of the fix
    re-solved through cameras moved by +-0.05 sigma, the attitude re-solved through each:
    every column within 2 % of the largest column's norm, and the fix's 1-sigma from the
    calibration (``sqrt(diag(J C J^T))``) within 2 %. The default bench calibration of the
    tracker (focal length, principal point, distortion)."""
    from starnav.camera_calibration import bench_calibration, star_alignment
    from starnav.navigation.christian_robinson import christian_robinson
    from starnav.navigation.pipeline import camera_consider_jacobian

    fr, _ = frame
    cal = bench_calibration(truth_camera, 7, 0)
    assert cal is not None and len(cal.parameters) == 7
    m = process_frame(fr, truth_camera, options=ChainOptions(calibration=cal))
    assert m.usable
    uv = m.points_used
    R_meas = np.asarray(fr.R_cam_to_inertial_measured, float)
    J = camera_consider_jacobian(cal, uv, m.position, R_meas, None, truth_camera,
                                 ChainOptions().fix, m.fix)
    fd = np.zeros_like(J)
    for i, name in enumerate(cal.parameters):
        h = 0.05 * cal.sigma(name)
        pos = []
        for s in (1.0, -1.0):
            d = np.zeros(len(cal.parameters))
            d[i] = s * h
            cam = cal.camera_with(d)
            R = R_meas @ star_alignment(truth_camera, cam).T
            pos.append(christian_robinson(uv, cam).position_inertial(R))
        fd[:, i] = (pos[0] - pos[1]) / (2 * h)
    scale = np.max(np.linalg.norm(fd * np.sqrt(np.diag(cal.covariance)), axis=0))
    err = np.linalg.norm((J - fd) * np.sqrt(np.diag(cal.covariance)), axis=0)
    assert np.all(err < 0.02 * scale), err / scale
    C = np.asarray(cal.covariance)
    assert np.sqrt(np.diag(J @ C @ J.T)) == pytest.approx(np.sqrt(np.diag(fd @ C @ fd.T)),
                                                         rel=0.02)
