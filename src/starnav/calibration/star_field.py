"""Geometric hold-out of the camera calibration on the star-field stimulus.

Each catalogue star's direction is placed on the screen through the collimator *as designed*;
the tracker sees it through the bench *as built*. The camera calibration
(:mod:`~starnav.calibration.intrinsics`) never saw this pattern.

Technique
---------
1. Stimulus: Hipparcos stars (``V <= v_limit``) about a boresight, inverted through the design
   collimator to screen pixels; blends (closer than four centroid windows to a brighter star)
   dropped; drawn as the calibration's dots (the test is geometric).
2. Acquisition on the truth bench; centroids matched to the datasheet camera's prediction.
3. Prediction: the *calibrated* camera projecting the design directions, the mount attitude
   re-solved from the stars (generalised least squares, 3 nuisance parameters).
4. Covariance: ``J_theta C J_theta^T`` (``C`` the calibration's, noise + consider) plus the
   centroid noise.
5. Residual test: ``chi^2 = r^T Sigma^-1 r``, ``2N - 3`` dof, one-sided at a stated
   false-alarm rate (``residual_test``).
6. Verdict (``passes``): the camera correction the stars ask for (GLS in the calibrated
   parameters and the attitude) against the stated covariance plus its own noise, ``chi^2``
   with as many dof as parameters: it concentrates one wrong parameter that step 5 spreads
   over ``2N - 3`` dof.

References
----------
B. D. Tapley, B. E. Schutz and G. H. Born, *Statistical Orbit Determination*, Elsevier (2004),
ch. 4.3 (weighted least squares, residual chi-square).

Index
-----
:func:`star_field_screen_px`, :func:`acquire_star_field`, :func:`star_field_holdout`,
:func:`run_star_field_holdout`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from starnav.calibration.bench import Bench, BenchGeometry, DetectorStage
from starnav.calibration.geometric import (
    CalibrationError,
    DotAcquisition,
    acquire_dots,
    auto_dot_exposure,
)
from starnav.calibration.intrinsics import IntrinsicsResult, _directions
from starnav.calibration.screen import gaussian_dots
from starnav.camera import Camera
from starnav.camera_calibration import CameraCalibration, with_parameters
from starnav.config import build_camera
from starnav.errors import ConfigError
from starnav.stars.catalogue import HIPPARCOS_EPOCH_JYEAR, hipparcos
from starnav.typing import FloatArray

#: Acquisition frame index of the star-field stimulus (distinct from the dot frames).
FRAME_STAR_FIELD = 104
#: Default boresight (RA, Dec) [deg]: Orion, a field with many bright stars.
DEFAULT_BORESIGHT_DEG = (84.0, -1.0)


def _camera_basis(ra_deg: float, dec_deg: float) -> FloatArray:
    """Rows: the camera's x, y, z axes in ICRS (z the boresight, y towards the north)."""
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    z = np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])
    north = np.array([0.0, 0.0, 1.0]) if abs(dec_deg) < 89.0 else np.array([1.0, 0.0, 0.0])
    x = np.cross(north, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _screen_for_beam_tangent(geometry: BenchGeometry, t: FloatArray) -> FloatArray:
    """Screen pixels whose beam through ``geometry`` has tangent ``t`` (fixed point)."""
    s = geometry.nominal_tangent_to_screen(t)
    for _ in range(30):
        bt, _ = geometry.beam_tangent(s)
        step = geometry.nominal_tangent_to_screen(t - bt) - np.array(geometry.centre)
        s = s + step
        if float(np.abs(step).max(initial=0.0)) < 1e-9:
            break
    return s


def star_field_screen_px(bench: Bench, boresight_deg: tuple[float, float] = DEFAULT_BORESIGHT_DEG,
                         v_limit: float = 7.0, max_stars: int = 80
                         ) -> tuple[FloatArray, FloatArray]:
    """The star-field stimulus (module step 1): screen pixels ``(N, 2)`` (column, row) and the
    stars' V magnitudes, brightest first.

    Raises
    ------
    ConfigError
        ``max_stars`` < 4 or fewer than 4 separated stars in the field.
    """
    if max_stars < 4:
        raise ConfigError("max_stars", max_stars, "at least 4 stars")
    cfg = bench.config.geometric
    design = bench.geometry.design()
    cam = build_camera(bench.config.scenario.camera)
    basis = _camera_basis(*boresight_deg)
    sel = hipparcos().cone(basis[2], 0.5 * cam.fov_diagonal, HIPPARCOS_EPOCH_JYEAR, v_limit)
    d = sel.directions @ basis.T
    t = d[:, :2] / d[:, 2:3]
    scr = _screen_for_beam_tangent(design, t)
    uv = cam.project(_directions(design, scr))
    m = cfg.dot_margin_px
    H, W = bench.screen_shape
    ok = ((uv[:, 0] >= m) & (uv[:, 0] <= cam.width - 1 - m) & (uv[:, 1] >= m)
          & (uv[:, 1] <= cam.height - 1 - m) & (scr[:, 0] >= 0) & (scr[:, 0] <= W - 1)
          & (scr[:, 1] >= 0) & (scr[:, 1] <= H - 1))
    sep = 4.0 * cfg.centroid_half_window_px
    keep: list[int] = []
    for i in np.flatnonzero(ok):
        if all(np.hypot(*(uv[i] - uv[j])) >= sep for j in keep):
            keep.append(int(i))
        if len(keep) == max_stars:
            break
    if len(keep) < 4:
        raise ConfigError("boresight_deg", list(boresight_deg),
                          f"a field with at least 4 separated stars of V <= {v_limit}")
    return scr[keep], sel.v[keep]


def acquire_star_field(bench: Bench, screen_px: FloatArray,
                       detector: DetectorStage | None = None,
                       exposure_time: float | None = None,
                       dark_dn: FloatArray | None = None) -> DotAcquisition:
    """Show the stars at ``screen_px`` on the bench and centroid them (module step 2).

    Raises
    ------
    CalibrationError
        Fewer than half the stars found.
    """
    cfg = bench.config.geometric
    det = detector if detector is not None else bench.chain_detector()
    design = bench.geometry.design()
    pred = build_camera(bench.config.scenario.camera).project(_directions(design, screen_px))
    if exposure_time is None:
        counts = gaussian_dots(bench.screen_shape, screen_px, cfg.dot_sigma_screen_px,
                               bench.radiometry.le_max, bench.radiometry)
        exposure_time = auto_dot_exposure(bench, counts, det, cfg.dot_peak_fraction)
    acq = acquire_dots(bench, pred, screen_px, det, exposure_time, FRAME_STAR_FIELD, pred,
                       4.0 * cfg.centroid_half_window_px, dark_dn=dark_dn)
    if acq.found.sum() < max(4, len(pred) // 2):
        raise CalibrationError(f"star-field hold-out: {int(acq.found.sum())} of {len(pred)} "
                               "stars found (expected at least half)")
    return acq


def star_field_holdout(calibration: CameraCalibration, mount_rotation_rad: FloatArray,
                       design: BenchGeometry, screen_px: FloatArray, observed_px: FloatArray,
                       centroid_sigma_px: float, false_alarm: float = 1e-3) -> dict[str, Any]:
    """Residuals of the stars seen against the calibrated camera's prediction, and their
    chi-square against the calibration's covariance (module steps 3-5).

    Parameters
    ----------
    calibration : CameraCalibration
        The camera under test, with its covariance.
    mount_rotation_rad : (3,) array
        The calibration's mount rotation (start of the attitude solution).
    design : BenchGeometry
        The bench as designed (the collimator the prediction assumes).
    screen_px, observed_px : (N, 2) arrays
        Where each star was drawn and seen (found stars only).
    centroid_sigma_px : float
        Centroid noise of one star [px].
    false_alarm : float
        Probability that a right calibration fails the test.
    """
    s = np.asarray(screen_px, float).reshape(-1, 2)
    uv = np.asarray(observed_px, float).reshape(-1, 2)
    if s.shape != uv.shape or len(s) < 4 or not np.all(np.isfinite(uv)):
        raise ConfigError("observed_px", uv.shape, f"finite centroids, one per star ({s.shape}),"
                          " at least 4")
    if not (math.isfinite(centroid_sigma_px) and centroid_sigma_px > 0):
        raise ConfigError("centroid_sigma_px", centroid_sigma_px, "a finite value > 0")
    if not 0 < false_alarm < 1:
        raise ConfigError("false_alarm", false_alarm, "a probability in (0, 1)")
    d = _directions(design, s)
    names = calibration.parameters
    x_cal = np.array(calibration.estimate, float)

    def predict(theta: FloatArray, omega: FloatArray) -> FloatArray:
        cam: Camera = with_parameters(calibration.camera, dict(zip(names, theta, strict=True)))
        return cam.project(d @ Rotation.from_rotvec(omega).as_matrix().T).ravel()

    omega = np.asarray(mount_rotation_rad, float).copy()
    sig = np.sqrt(np.clip(np.diag(calibration.covariance), 0, None))
    J_t = np.stack([(predict(x_cal + e * h, omega) - predict(x_cal - e * h, omega)) / (2 * h)
                    for e, h in zip(np.eye(len(names)), np.maximum(sig, 1e-12), strict=True)],
                   -1)
    Sigma = J_t @ calibration.covariance @ J_t.T + centroid_sigma_px ** 2 * np.eye(2 * len(s))
    Si = np.linalg.inv(Sigma)
    for _ in range(5):                                    # Gauss-Newton on the attitude
        y = uv.ravel() - predict(x_cal, omega)
        h = 1e-6
        A = np.stack([(predict(x_cal, omega + e * h) - predict(x_cal, omega - e * h)) / (2 * h)
                      for e in np.eye(3)], -1)
        step = np.linalg.solve(A.T @ Si @ A, A.T @ Si @ y)
        omega = omega + step
        if float(np.abs(step).max()) < 1e-12:
            break
    r = uv.ravel() - predict(x_cal, omega)
    chi = float(r @ Si @ r)
    dof = 2 * len(s) - 3
    thr = float(chi2.ppf(1 - false_alarm, dof))
    chi_noise = float(r @ r) / centroid_sigma_px ** 2
    # the camera correction the stars ask for (attitude free, centroid-noise weights), against
    # the stated covariance plus its own noise: a test in the parameters' 7 dimensions
    B = np.concatenate([J_t * sig, A], -1)
    N_inv = np.linalg.inv(B.T @ B) * centroid_sigma_px ** 2
    dz = (N_inv @ B.T @ r / centroid_sigma_px ** 2)[:len(names)]
    dth = dz * sig
    k = len(names)
    P = calibration.covariance + (np.diag(sig) @ N_inv[:k, :k] @ np.diag(sig))
    chi_p = float(dth @ np.linalg.solve(P, dth))
    rn = np.hypot(*r.reshape(-1, 2).T)
    thr_p = float(chi2.ppf(1 - false_alarm, k))
    return {"stars": int(len(s)), "false_alarm": false_alarm, "passes": chi_p <= thr_p,
            "parameter_test": {"chi2": chi_p, "dof": k, "threshold": thr_p,
                               "correction": dict(zip(names, map(float, dth), strict=True)),
                               "correction_over_sigma": dict(zip(
                                   names, map(float, dth / sig), strict=True))},
            "residual_test": {"chi2": chi, "dof": dof, "threshold": thr,
                              "passes": chi <= thr,
                              "chi2_centroid_noise_only": chi_noise},
            "residual_rms_px": float(np.sqrt(np.mean(rn ** 2))),
            "residual_max_px": float(rn.max()), "centroid_sigma_px": centroid_sigma_px,
            "attitude_change_arcsec": float(np.linalg.norm(
                omega - np.asarray(mount_rotation_rad, float)) * 180 / math.pi * 3600)}


def run_star_field_holdout(bench: Bench, intrinsics: IntrinsicsResult,
                           detector: DetectorStage | None = None,
                           exposure_time: float | None = None,
                           dark_dn: FloatArray | None = None,
                           false_alarm: float = 1e-3) -> dict[str, Any]:
    """The whole hold-out (steps 1-5) of ``intrinsics`` on ``bench``, with the stimulus's
    boresight and magnitude limit."""
    scr, v = star_field_screen_px(bench)
    acq = acquire_star_field(bench, scr, detector, exposure_time, dark_dn)
    f = acq.found
    out = star_field_holdout(intrinsics.calibration, intrinsics.mount_rotation_rad,
                             bench.geometry.design(), scr[f], acq.observed_px[f],
                             intrinsics.centroid_sigma_px, false_alarm)
    return {"boresight_ra_dec_deg": list(DEFAULT_BORESIGHT_DEG), "stars_shown": int(len(scr)),
            "v_range_mag": [float(v.min()), float(v.max())], **out}


__all__ = ["DEFAULT_BORESIGHT_DEG", "FRAME_STAR_FIELD", "acquire_star_field",
           "run_star_field_holdout", "star_field_holdout", "star_field_screen_px"]
