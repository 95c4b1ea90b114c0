"""Attitude from matched star vectors: Wahba's problem by SVD, its covariance, the frame solver.

1. Wahba (:func:`wahba_svd`): ``A = U diag(1, 1, det U det V) V^T`` from the SVD of
   ``sum w_i b_i r_i^T`` (Markley 1988), the optimum of the q-method and QUEST.
2. Covariance (:func:`attitude_covariance`): ``(sum sigma_i^-2 (I - b_i b_i^T))^-1`` in camera
   axes (Shuster & Oh 1981); roll is the worst axis.
3. Centroid sigma (:func:`centroid_sigma_rad`): the centroid's 1-sigma with a systematic floor,
   over the focal length.

:func:`solve_attitude` runs a frame: centroids, identification (:mod:`starnav.stars.identify`),
the SVD and its covariance; :func:`navigation_attitude` hands it to the limb fix (docs/stars.md,
"Coupling").

References
----------
F. L. Markley, "Attitude determination using vector observations and the singular value
decomposition", J. Astronaut. Sci. 36 (1988) 245-258.
M. D. Shuster and S. D. Oh, "Three-axis attitude determination from vector observations",
J. Guid. Control 4 (1981) 70-77.

Index
-----
:func:`solve_attitude`, :class:`AttitudeSolution`, :class:`AttitudeOptions`,
:func:`navigation_attitude`, :func:`wahba_svd`, :func:`attitude_covariance`,
:func:`error_rotation`, :func:`unit_vectors`, :func:`centroid_sigma_rad`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from starnav.camera import Camera
from starnav.detector import DetectorConfig
from starnav.errors import ConfigError
from starnav.stars.catalogue import StarCatalogue, hipparcos
from starnav.stars.centroid import CentroidOptions, Centroids, Exclusion, find_stars, saturation_dn
from starnav.stars.identify import (
    Identification,
    IdentifyOptions,
    identify_lost_in_space,
    identify_tracking,
)
from starnav.typing import FloatArray

#: One arcsecond [rad].
ARCSEC = math.pi / (180.0 * 3600.0)


def wahba_svd(b: ArrayLike, r: ArrayLike, w: ArrayLike) -> FloatArray:
    """Attitude matrix ``A`` (``b ~ A r``) minimising ``sum w |b - A r|^2`` (module step 1)."""
    B = (np.asarray(w, float)[:, None, None] * np.einsum("ni,nj->nij", np.asarray(b, float),
                                                        np.asarray(r, float))).sum(0)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def attitude_covariance(b: ArrayLike, sigma_rad: ArrayLike) -> FloatArray:
    """``(sum sigma_i^-2 (I - b_i b_i^T))^-1`` [rad^2], camera axes (module step 2)."""
    bb = np.asarray(b, float)
    s = np.asarray(sigma_rad, float)
    F = ((1.0 / s**2)[:, None, None] * (np.eye(3)[None] - np.einsum("ni,nj->nij", bb, bb))).sum(0)
    return np.linalg.inv(F)


def error_rotation(R_est: ArrayLike, R_true: ArrayLike) -> FloatArray:
    """Small error rotation ``dtheta`` [rad], camera axes, with ``R_true = R_est exp([dtheta
    x])`` (``R`` camera -> inertial)."""
    return Rotation.from_matrix(np.asarray(R_est, float).T @ np.asarray(R_true, float)).as_rotvec()


@dataclass(frozen=True)
class AttitudeOptions:
    """Knobs of :func:`solve_attitude`.

    Attributes
    ----------
    floor_px : float
        Systematic centroid error added in quadrature [px] (module step 3).
    min_stars : int
        Fewer identified stars: no attitude.
    centroid, identify :
        Options of the two stages.
    """

    floor_px: float = 0.02
    min_stars: int = 4
    centroid: CentroidOptions = dataclasses.field(default_factory=CentroidOptions)
    identify: IdentifyOptions = dataclasses.field(default_factory=IdentifyOptions)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.floor_px) and self.floor_px >= 0):
            raise ConfigError("attitude.floor_px", self.floor_px, "a finite value >= 0 px")
        if self.min_stars < 3:
            raise ConfigError("attitude.min_stars", self.min_stars, "an integer >= 3")


@dataclass(frozen=True)
class AttitudeSolution:
    """The tracker's attitude of one frame, or why there is none.

    Attributes
    ----------
    status : str
        ``"ok"`` or ``"no-attitude"``.
    reason : str
        Why not (empty when ok).
    mode : str
        ``"lost-in-space"`` or ``"tracking"``.
    R_cam_to_inertial : (3, 3) array or None
    covariance_rad2 : (3, 3) array or None
        Covariance of the error rotation, camera axes (z = boresight: roll) [rad^2].
    centroids : Centroids
    identification : Identification or None
    """

    status: str
    reason: str
    mode: str
    R_cam_to_inertial: FloatArray | None
    covariance_rad2: FloatArray | None
    centroids: Centroids
    identification: Identification | None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def sigma_arcsec(self) -> FloatArray:
        """1-sigma per camera axis (x, y cross-boresight; z roll) [arcsec]."""
        if self.covariance_rad2 is None:
            return np.full(3, np.nan)
        return np.sqrt(np.diag(self.covariance_rad2)) / ARCSEC


def unit_vectors(uv: ArrayLike, camera: Camera, undistort: bool) -> FloatArray:
    """Camera-frame unit vectors of pixels ``(u, v)`` [px]."""
    xy = camera.pixel_to_normalized(np.asarray(uv, float).reshape(-1, 2), undistort=undistort)
    d = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def centroid_sigma_rad(cents: Centroids, camera: Camera, floor_px: float) -> FloatArray:
    """Per-star isotropic 1-sigma [rad] (module step 3)."""
    s = np.sqrt(0.5 * (cents.sigma_px**2).sum(axis=1) + floor_px**2)
    return s / camera.fx


def solve_attitude(dn: ArrayLike, camera: Camera, detector: DetectorConfig, *,
                   epoch_jyear: float, prior: ArrayLike | None = None,
                   prior_sigma_rad: float = 0.0, exclusions: tuple[Exclusion, ...] = (),
                   catalogue: StarCatalogue | None = None,
                   options: AttitudeOptions | None = None,
                   observer_velocity: ArrayLike | None = None) -> AttitudeSolution:
    """The attitude of one DN frame from its stars.

    Parameters
    ----------
    dn : (H, W) array
        The frame [DN] (``Exposure.dn``).
    camera : Camera
    detector : DetectorConfig
        Gain, saturation and whether the chain distorts (then centroids are undistorted).
    epoch_jyear : float
        Epoch of the star positions [Julian year].
    prior : (3, 3) array, optional
        Camera -> inertial attitude from a previous solution: tracking mode (nearest-neighbour
        matching); ``None``: lost in space.
    prior_sigma_rad : float
        1-sigma of the prior per axis [rad] (widens the tracking match radius).
    exclusions : tuple of Exclusion
        Bright body and ghosts (:func:`~starnav.stars.centroid.body_exclusions`).
    catalogue : StarCatalogue, optional
        Default Hipparcos.
    options : AttitudeOptions, optional
    observer_velocity : (3,) array, optional
        The tracker's barycentric velocity, ICRF axes [m/s]: the catalogue is corrected to
        apparent directions (:mod:`starnav.stars.aberration`). ``None``: catalogue places (an
        attitude biased by up to 20.5 arcsec when the sky is aberrated).

    Returns
    -------
    AttitudeSolution
        ``status "no-attitude"`` with the reason when too few stars are found or identified;
        never raises for frame content.
    """
    opt = options or AttitudeOptions()
    cat = catalogue if catalogue is not None else hipparcos()
    cents = find_stars(dn, gain_e_per_dn=detector.gain_e_per_dn,
                       saturation_dn=saturation_dn(detector), exclusions=exclusions,
                       options=opt.centroid)
    mode = "lost-in-space" if prior is None else "tracking"
    if len(cents) < opt.min_stars:
        return AttitudeSolution("no-attitude", f"{len(cents)} star candidates detected, "
                                f"{opt.min_stars} needed (exposure too short, or no stars)",
                                mode, None, None, cents, None)
    undistort = detector.optics.distortion.enabled and camera.has_distortion
    b = unit_vectors(cents.uv, camera, undistort)
    sig = centroid_sigma_rad(cents, camera, opt.floor_px)
    if prior is None:
        ident = identify_lost_in_space(b, sig, cat, epoch_jyear, camera.fov_diagonal,
                                       options=opt.identify,
                                       observer_velocity=observer_velocity)
    else:
        ident = identify_tracking(b, sig, cat, epoch_jyear, camera.fov_diagonal,
                                  np.asarray(prior, float), prior_sigma_rad,
                                  options=opt.identify, observer_velocity=observer_velocity)
    if not ident.ok or ident.n_matched < opt.min_stars:
        why = ident.reason or f"{ident.n_matched} identified stars, {opt.min_stars} needed"
        return AttitudeSolution("no-attitude", why, mode, None, None, cents, ident)
    m = ident.detection_index
    A = wahba_svd(b[m], ident.directions, 1.0 / sig[m] ** 2)
    P = attitude_covariance(b[m], sig[m])
    return AttitudeSolution("ok", "", mode, A.T, 0.5 * (P + P.T), cents, ident)


def navigation_attitude(solution: AttitudeSolution, frame, chain_options):
    """Hand a star attitude to the limb fix: returns ``(frame, options)`` for
    :func:`starnav.navigation.pipeline.process_frame`, with the frame's
    ``R_cam_to_inertial_measured`` replaced by the solved attitude and ``options.fix``'s
    ``attitude_sigma_rad`` by its 3x3 covariance (camera axes) [rad^2].

    ``frame`` must be a dataclass :class:`~starnav.navigation.frames.NavFrame` (such as
    :class:`~starnav.navigation.frames.Frame`); ``chain_options`` a
    :class:`~starnav.navigation.pipeline.ChainOptions`.

    Raises
    ------
    ConfigError
        The solution is not ``ok`` (the caller keeps its assumed attitude then), or ``frame``
        is not a dataclass.
    """
    if not solution.ok:
        raise ConfigError("attitude.solution", solution.status,
                          f"an ok star attitude ({solution.reason})")
    if not dataclasses.is_dataclass(frame):
        raise ConfigError("attitude.frame", type(frame).__name__, "a dataclass NavFrame")
    cov = tuple(tuple(float(x) for x in row) for row in solution.covariance_rad2)
    fix = dataclasses.replace(chain_options.fix, attitude_sigma_rad=cov)
    return (dataclasses.replace(frame, R_cam_to_inertial_measured=solution.R_cam_to_inertial),
            dataclasses.replace(chain_options, fix=fix))
