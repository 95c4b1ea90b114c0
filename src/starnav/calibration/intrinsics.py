"""The camera's focal length, principal point and distortion estimated on the bench, with
their covariance: the calibration product navigation reads.

Each matched dot of :mod:`starnav.calibration.geometric` pairs a screen pixel (a known
direction through the nominal collimator) with the detector pixel it was seen at; fitting the
camera model to those pairs estimates the camera (docs/calibration.md, "The camera's focal
length, principal point and distortion").

Technique
---------
1. Model ``uv = camera(theta).project(R(omega) d(s))``: ``theta`` the parameters
   :data:`ESTIMATED`, ``omega`` the unknown mount rotation (a nuisance, not written).
2. Prior on the mount's tilts (they mimic a principal-point shift); the roll is free.
3. Fit: Levenberg-Marquardt on the pixel residuals, alternating with the centroid noise.
4. Covariance ``(J^T W J)^-1``.
5. Consider parameters (:data:`CONSIDER`: collimator focal length and distortion, screen
   shift, tilt and defocus): the estimate's response to each (and each pair) at 1 sigma is
   fitted as a quadratic whose second moment over Gaussian departures is added.

References
----------
B. D. Tapley, B. E. Schutz and G. H. Born, *Statistical Orbit Determination*, Elsevier (2004),
ch. 6.3 (consider covariance). A. M. Mathai and S. B. Provost, *Quadratic Forms in Random
Variables*, Dekker (1992), ch. 3.

Index
-----
:func:`estimate_camera`, :func:`calibrate_camera`, :class:`IntrinsicsResult`,
:func:`draw_as_built`, :data:`ESTIMATED`, :data:`CONSIDER`, :data:`CAMERA_SPREAD`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from starnav.calibration.bench import Bench, BenchGeometry
from starnav.calibration.geometric import DotAcquisition, calibrate_geometry
from starnav.camera import Camera
from starnav.camera_calibration import (
    CameraCalibration,
    parameter_values,
    with_parameters,
)
from starnav.config import build_camera
from starnav.errors import ConfigError
from starnav.typing import FloatArray

#: Camera parameters the bench estimates, in the order of the covariance.
ESTIMATED = ("focal_length_m", "cx_px", "cy_px", "k1", "k2", "p1", "p2")
#: Parameter scales used to condition the fit and the finite differences.
_SCALE = {"focal_length_m": 1e-4, "cx_px": 1.0, "cy_px": 1.0, "k1": 1e-3, "k2": 1e-3,
          "p1": 1e-4, "p2": 1e-4}
_ROT_SCALE = 1e-4  # [rad]


@dataclass(frozen=True)
class IntrinsicsResult:
    """The bench's estimate of the camera.

    Attributes
    ----------
    calibration : CameraCalibration
        Estimate and full covariance (noise + consider), ready for
        :func:`~starnav.camera_calibration.write_calibration`.
    covariance_noise, covariance_consider : (p, p) arrays
        The two parts of the covariance (same order as ``calibration.parameters``).
    mount_rotation_rad : (3,) array
        Estimated mounting rotation vector (nuisance).
    residual_px : (N, 2) array
        Post-fit residuals of the dots.
    centroid_sigma_px : float
        Centroid noise estimated from the residuals.
    """

    calibration: CameraCalibration
    covariance_noise: FloatArray
    covariance_consider: FloatArray
    mount_rotation_rad: FloatArray
    residual_px: FloatArray
    centroid_sigma_px: float

    def summary(self) -> dict[str, Any]:
        cal = self.calibration
        return {
            "parameters": list(cal.parameters),
            "estimate": [float(x) for x in cal.estimate],
            "sigma": [cal.sigma(p) for p in cal.parameters],
            "sigma_noise_only": [float(math.sqrt(self.covariance_noise[i, i]))
                                 for i in range(len(cal.parameters))],
            "mount_rotation_arcsec": [float(x) * 180 / math.pi * 3600
                                      for x in self.mount_rotation_rad],
            "dots": int(len(self.residual_px)),
            "residual_rms_px": float(np.sqrt(np.mean(np.square(self.residual_px)))),
            "centroid_sigma_px": self.centroid_sigma_px,
        }


def _directions(geometry: BenchGeometry, screen_px: FloatArray) -> FloatArray:
    t, _ = geometry.beam_tangent(screen_px)
    v = np.concatenate([t, np.ones(t.shape[:-1] + (1,))], -1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


#: What the bench does not know about itself (consider parameters, step 5): name -> unit.
CONSIDER = {
    "collimator_focal_length": "relative",
    "collimator_k1": "-",
    "screen_shift_x": "m", "screen_shift_y": "m",
    "screen_tilt_x": "rad", "screen_tilt_y": "rad",
    "screen_defocus": "m",
}


def _perturbed(geometry: BenchGeometry, name: str, delta: float) -> BenchGeometry:
    """``geometry`` with one :data:`CONSIDER` parameter moved by ``delta``."""
    g = geometry
    if name == "collimator_focal_length":
        return replace(g, focal_length=g.focal_length * (1.0 + delta))
    if name == "collimator_k1":
        return replace(g, k1=g.k1 + delta)
    if name in ("screen_shift_x", "screen_shift_y"):
        return replace(g, shift=np.asarray(g.shift, float)
                       + delta * np.eye(2)[int(name.endswith("_y"))])
    if name in ("screen_tilt_x", "screen_tilt_y"):
        axis = np.eye(3)[1 if name.endswith("_y") else 0]
        return replace(g, R_screen=Rotation.from_rotvec(delta * axis).as_matrix() @ g.R_screen)
    if name == "screen_defocus":
        return replace(g, defocus=g.defocus + delta)
    raise ConfigError("consider parameter", name, f"one of {list(CONSIDER)}")


def estimate_camera(nominal: Camera, geometry: BenchGeometry, screen_px: FloatArray,
                    observed_px: FloatArray, *, mount_tilt_sigma_rad: float,
                    consider: dict[str, float],
                    provenance: dict[str, Any] | None = None) -> IntrinsicsResult:
    """Estimate the camera from matched dots (module essay, steps 1-5).

    Parameters
    ----------
    nominal : Camera
        The camera as designed (datasheet): the start of the fit and everything not
        estimated (size, pitch, f-number, ``k3``).
    geometry : BenchGeometry
        The bench *as designed* (:meth:`BenchGeometry.nominal`): the fit knows no more.
    screen_px, observed_px : (N, 2) arrays
        Where each dot was drawn [screen px] and where its centroid was seen [detector px].
    mount_tilt_sigma_rad : float
        Mechanical tolerance of the camera's tilts on the bench (prior, step 2) [rad].
    consider : dict
        1-sigma knowledge of the bench's own parameters, :data:`CONSIDER` name -> sigma in
        its unit (step 5); a parameter left out is taken as exact.
    provenance : dict, optional
        Added to the calibration file's provenance.

    Raises
    ------
    ConfigError
        Too few dots for the parameters, or a tolerance that is not a finite value > 0.
    """
    s = np.asarray(screen_px, float).reshape(-1, 2)
    uv = np.asarray(observed_px, float).reshape(-1, 2)
    if s.shape != uv.shape:
        raise ConfigError("observed_px", uv.shape, f"one pixel per drawn dot ({s.shape})")
    for name, val in (("mount_tilt_sigma_rad", mount_tilt_sigma_rad), *consider.items()):
        if not (math.isfinite(val) and val > 0):
            raise ConfigError(name, val, "a finite tolerance > 0")
        if name != "mount_tilt_sigma_rad" and name not in CONSIDER:
            raise ConfigError("consider parameter", name, f"one of {list(CONSIDER)}")
    n_par = len(ESTIMATED) + 3
    if 2 * len(s) < n_par + 10:
        raise ConfigError("dots", len(s), f"at least {(n_par + 10 + 1) // 2} matched dots to "
                          f"estimate {len(ESTIMATED)} camera parameters and the mount")
    scale = np.array([_SCALE[p] for p in ESTIMATED] + [_ROT_SCALE] * 3)
    x0 = np.concatenate([parameter_values(nominal, ESTIMATED), np.zeros(3)])
    d_nom = _directions(geometry, s)

    def model(x: FloatArray, d: FloatArray) -> FloatArray:
        cam = with_parameters(nominal, dict(zip(ESTIMATED, x[:len(ESTIMATED)], strict=True)))
        R = Rotation.from_rotvec(x[len(ESTIMATED):]).as_matrix()
        return cam.project(d @ R.T)

    def residual(z: FloatArray, d: FloatArray, sigma_px: float) -> FloatArray:
        x = x0 + z * scale
        r = ((model(x, d) - uv) / sigma_px).ravel()
        prior = x[len(ESTIMATED):len(ESTIMATED) + 2] / mount_tilt_sigma_rad
        return np.concatenate([r, prior])

    # the prior is weighed against the centroid noise, which the residuals measure: alternate
    # the two until the noise estimate settles
    z, sigma_px = np.zeros(n_par), 1.0
    for _ in range(4):
        fit = least_squares(residual, z, args=(d_nom, sigma_px), method="lm", x_scale=1.0,
                            xtol=1e-12, ftol=1e-12)
        z = fit.x
        res_px = model(x0 + z * scale, d_nom) - uv
        new = max(float(np.sqrt(np.sum(res_px ** 2) / max(2 * len(s) - n_par, 1))), 1e-6)
        done = abs(new / sigma_px - 1) < 0.01
        sigma_px = new
        if done:
            break

    def jac(fun: Any, z: FloatArray, h: float = 1e-3) -> FloatArray:
        cols = []
        for k in range(len(z)):
            e = np.zeros_like(z)
            e[k] = h
            cols.append((fun(z + e) - fun(z - e)) / (2 * h))
        return np.stack(cols, -1)

    J = jac(lambda q: residual(q, d_nom, sigma_px), z)          # whitened, scaled
    info = J.T @ J
    cov_z = np.linalg.inv(info)
    # consider parameters (step 5): the estimate's response to the bench's departures, through
    # the full bench model at 1 sigma, as a quadratic in the standardised departures u (a
    # tilted screen's response is not linear at its tolerance, and two tilts interact):
    # dz(u) = L u + u^T Q u / 2, from dz at +-u_i and at u_i + u_j
    r0 = residual(z, d_nom, sigma_px)
    names = list(consider)

    def response(u: dict[str, float]) -> FloatArray:
        g = geometry
        for name, ui in u.items():
            g = _perturbed(g, name, ui * consider[name])
        return -cov_z @ J.T @ (residual(z, _directions(g, s), sigma_px) - r0)

    m = len(names)
    L = np.zeros((n_par, m))
    Q = np.zeros((m, m, n_par))
    for i, a in enumerate(names):
        plus, minus = response({a: 1.0}), response({a: -1.0})
        L[:, i] = (plus - minus) / 2.0
        Q[i, i] = plus + minus
    for i, a in enumerate(names):
        for j in range(i + 1, m):
            both = response({a: 1.0, names[j]: 1.0})
            Q[i, j] = Q[j, i] = both - L[:, i] - L[:, j] - (Q[i, i] + Q[j, j]) / 2.0
    # second moment over Gaussian departures u ~ N(0, I): L L^T + mean mean^T + the variance
    # of the quadratic part, Var(u^T A u / 2, u^T B u / 2) = tr(A B) / 2
    mean = 0.5 * np.einsum("iik->k", Q)
    q = Q.reshape(m * m, n_par)
    cov_c_z = L @ L.T + np.outer(mean, mean) + 0.5 * q.T @ q
    D = np.diag(scale)
    k = len(ESTIMATED)
    cov_noise = (D @ (0.5 * (cov_z + cov_z.T)) @ D)[:k, :k]
    cov_consider = (D @ cov_c_z @ D)[:k, :k]
    x = x0 + z * scale
    cam = with_parameters(nominal, dict(zip(ESTIMATED, x[:k], strict=True)))
    prov = {"method": "bench dot pattern, camera model fitted through the nominal collimator",
            "dots": int(len(s)), "centroid_sigma_px": sigma_px,
            "mount_tilt_sigma_rad": mount_tilt_sigma_rad,
            "consider_sigma": dict(consider),
            **(provenance or {})}
    cov = cov_noise + cov_consider
    cal = CameraCalibration(cam, ESTIMATED, 0.5 * (cov + cov.T), prov)
    res = np.asarray(model(x, d_nom) - uv)
    return IntrinsicsResult(cal, cov_noise, cov_consider, x[k:], res, sigma_px)


def calibrate_camera(bench: Bench, dots: DotAcquisition | None = None) -> IntrinsicsResult:
    """The camera calibration of an emulated bench: its dot acquisition
    (:func:`~starnav.calibration.geometric.calibrate_geometry`, or ``dots`` already acquired),
    fitted through the bench *as designed* from the scenario's datasheet camera, with the
    tolerances of ``bench.config.geometric``."""
    if dots is None:
        dots = calibrate_geometry(bench, validate=False).calibration_dots
    g = bench.config.geometric
    f = dots.found
    return estimate_camera(
        build_camera(bench.config.scenario.camera), bench.geometry.design(),
        dots.screen_px[f], dots.observed_px[f],
        mount_tilt_sigma_rad=math.radians(g.mount_tilt_sigma_deg),
        consider={"collimator_focal_length": g.collimator_focal_length_sigma,
                  "collimator_k1": g.collimator_k1_sigma,
                  "screen_shift_x": g.screen_shift_sigma_mm * 1e-3,
                  "screen_shift_y": g.screen_shift_sigma_mm * 1e-3,
                  "screen_tilt_x": math.radians(g.screen_tilt_sigma_deg),
                  "screen_tilt_y": math.radians(g.screen_tilt_sigma_deg),
                  "screen_defocus": g.screen_defocus_sigma_mm * 1e-3},
        provenance={"bench_seed": bench.config.seed})


#: 1-sigma of the flight camera's departures from its datasheet that the bench must find
#: (an assumption of the order of a star tracker's build tolerances).
CAMERA_SPREAD = {"camera_focal_length_error": 0.005, "camera_principal_point_offset_px": 5.0,
                 "camera_k1_error": 0.005}


def draw_as_built(rng: np.random.Generator, geometric: Any) -> dict[str, Any]:
    """A truth bench's ``misalignment`` section: screen, mount, collimator and camera
    departures drawn from the tolerances of ``geometric`` (a bench config's ``geometric``
    section) and :data:`CAMERA_SPREAD`."""
    g, r = geometric, rng
    return {"screen_shift_mm": list(r.normal(0, g.screen_shift_sigma_mm, 2)),
            "screen_tilt_deg": list(r.normal(0, g.screen_tilt_sigma_deg, 2)),
            "screen_roll_deg": float(r.normal(0, 0.3)),
            "screen_defocus_mm": float(r.normal(0, g.screen_defocus_sigma_mm)),
            "camera_tilt_deg": list(r.normal(0, g.mount_tilt_sigma_deg, 2)),
            "camera_roll_deg": float(r.normal(0, 0.3)),
            "collimator_focal_length_error": float(r.normal(
                0, g.collimator_focal_length_sigma)),
            "collimator_k1_error": float(r.normal(0, g.collimator_k1_sigma)),
            "camera_focal_length_error": float(r.normal(
                0, CAMERA_SPREAD["camera_focal_length_error"])),
            "camera_principal_point_offset_px": list(r.normal(
                0, CAMERA_SPREAD["camera_principal_point_offset_px"], 2)),
            "camera_k1_error": float(r.normal(0, CAMERA_SPREAD["camera_k1_error"]))}


__all__ = ["CAMERA_SPREAD", "CONSIDER", "ESTIMATED", "IntrinsicsResult", "calibrate_camera",
           "draw_as_built", "estimate_camera"]
