"""Christian-Robinson position fix from limb points of a triaxial ellipsoid, with covariance.

Given the lines of sight to points on the limb of a known ellipsoid (the Moon: a sphere by
default) and the camera attitude, the non-iterative method of Christian & Robinson (2016)
returns the body centre in the camera frame, from one linear least-squares solve.

Technique
---------
1. **Lines of sight.** Each limb pixel ``(u_i, v_i)`` is undistorted and unprojected to a unit
   vector ``x_i`` in the camera frame (:meth:`~starnav.camera.Camera.unproject`).
2. **Scaled space.** With the body's semi-axes ``(a, b, c)`` and ``T`` the rotation body ->
   camera, ``B = diag(1/a, 1/b, 1/c) T^T`` maps the ellipsoid onto the unit sphere
   (``A = B^T B`` is its shape matrix in the camera frame). In that space the limb rays
   ``s_i = B x_i / |B x_i|`` graze a unit sphere centred at ``c' = B r_C``, so all of them make
   the same angle with ``c'``: ``s_i^T n = 1`` with ``n = c' / sqrt(c'^T c' - 1)``.
3. **Solve.** Stack the ``s_i^T`` as rows of ``H`` and solve ``H n = 1`` by least squares.
4. **Centre.** ``r_C = (n^T n - 1)^(-1/2) B^{-1} n``: the body centre relative to the camera,
   camera frame [m]. The camera position relative to the body, inertial, is
   ``r = -R_cam_to_inertial r_C``.
5. **Covariance.** The fix is linearised exactly in every pixel:
   ``G_i = d r_C / d(u_i, v_i) = J_c M^{-1} (e_i I - s_i n^T) J_s,i`` with ``M = H^T H``,
   ``e_i = 1 - s_i^T n`` (the least-squares residual), ``J_c = d r_C / d n`` and
   ``J_s,i = d s_i / d(u_i, v_i)``; then ``P_C = sum_i G_i Sigma_i G_i^T`` for independent point
   errors of covariance ``Sigma_i = sigma_i^2 I``. Attitude knowledge error ``sigma_att`` [rad]
   adds ``[r x] sigma_att^2 [r x]^T`` in the inertial frame.
6. **Residual in pixels.** For scoring (RANSAC) each point's residual is the angle, in scaled
   space, between its ray and the predicted limb cone, ``acos(s_i^T n / |n|) - acos(1/|n|)``,
   divided by the pixel's angular size ``1/f_x``: an ellipse-aware distance in pixels that
   does not depend on the circle approximation.

Reference
---------
J. A. Christian and S. B. Robinson, "Noniterative horizon-based optical navigation by Cholesky
factorization", J. Guid. Control Dyn. 39 (2016) 2757-2765, doi:10.2514/1.G000708.
J. A. Christian, "A tutorial on horizon-based optical navigation and attitude determination
with space imaging systems", IEEE Access 9 (2021) 19819-19853,
doi:10.1109/ACCESS.2021.3051914.

Index
-----
:func:`christian_robinson`, :class:`LimbFix`, :class:`ChristianRobinsonOptions`,
:class:`FixError`, :func:`christian_robinson_centres`, :func:`christian_robinson_jacobian`,
:func:`christian_robinson_jacobian_from`, :func:`attitude_covariance`, :func:`shape_transform`,
:func:`scaled_rays`, :func:`centre_from_n`, :func:`cone_residual_px`, :func:`limb_cone_matrix`,
:func:`limb_conic_pixels`, :func:`ellipsoid_limb_points`.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from starnav.camera import Camera
from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError, StarnavError
from starnav.linalg import lstsq_vectors, solve_vectors
from starnav.typing import FloatArray

log = logging.getLogger(__name__)


class FixError(StarnavError, ValueError):
    """The limb points do not give a position (too few, collinear, or inconsistent)."""


@dataclass(frozen=True)
class ChristianRobinsonOptions:
    """Knobs of :func:`christian_robinson` (their meanings:
    :class:`~starnav.navigation.schema.FixConfig`).

    Attributes
    ----------
    radii_m : (a, b, c)
        Semi-axes of the body along its body-fixed axes [m]; default the Moon sphere.
    min_points : int
        Minimum number of limb points.
    attitude_sigma_rad : float, (3,) tuple or (3, 3) nested tuple
        Attitude knowledge: a 1-sigma [rad] for every axis, one per camera axis ``(x, y, z)``
        (z the boresight: roll), or a full 3x3 covariance of the error rotation in camera
        axes [rad^2] (a star tracker's solution, :mod:`starnav.stars.attitude`); added to the
        inertial covariance.
    """

    radii_m: tuple[float, float, float] = (MOON_RADIUS, MOON_RADIUS, MOON_RADIUS)
    min_points: int = 3
    attitude_sigma_rad: float | tuple[float, float, float] = 0.0
    radius_sigma_fraction: float = 0.0

    def __post_init__(self) -> None:
        if len(self.radii_m) != 3 or not all(math.isfinite(r) and r > 0 for r in self.radii_m):
            raise ConfigError("fix.radii_m", self.radii_m, "three finite semi-axes > 0 m")
        if self.min_points < 3:
            raise ConfigError("fix.min_points", self.min_points, "an integer >= 3")
        attitude_covariance(self.attitude_sigma_rad)


def attitude_covariance(attitude_sigma_rad: float | ArrayLike) -> FloatArray:
    """The 3x3 attitude covariance [rad^2], camera axes, of ``attitude_sigma_rad``: one 1-sigma
    [rad] (isotropic), three (per camera axis), or already a 3x3 symmetric positive
    semi-definite covariance [rad^2]."""
    a = np.asarray(attitude_sigma_rad, float)
    if a.shape == (3, 3):
        if not (np.all(np.isfinite(a)) and np.allclose(a, a.T, rtol=1e-9, atol=1e-30)
                and np.linalg.eigvalsh(0.5 * (a + a.T))[0] >= -1e-12 * max(np.abs(a).max(),
                                                                          1e-300)):
            raise ConfigError("fix.attitude_sigma_rad", a.tolist(),
                              "a symmetric positive semi-definite 3x3 covariance [rad^2]")
        return 0.5 * (a + a.T)
    a = np.atleast_1d(a)
    if a.ndim != 1 or a.size not in (1, 3) or not (np.all(a >= 0) and np.all(np.isfinite(a))):
        raise ConfigError("fix.attitude_sigma_rad", attitude_sigma_rad,
                          "one value or three (camera x, y, z) >= 0 rad, or a 3x3 "
                          "covariance [rad^2]")
    return np.diag(np.broadcast_to(a, (3,)) ** 2)


@functools.lru_cache(maxsize=16)
def _attitude_covariance_of(attitude_sigma_rad: float | tuple) -> tuple[FloatArray, bool]:
    S = attitude_covariance(attitude_sigma_rad)
    S.flags.writeable = False
    return S, bool(np.any(S != 0))


def _attitude_covariance_nonzero(attitude_sigma_rad: float | ArrayLike
                                 ) -> tuple[FloatArray, bool]:
    """:func:`attitude_covariance` (read-only) and whether it is nonzero, made once per
    value for a float or a tuple (every frame's fix asks for the configured one)."""
    try:
        return _attitude_covariance_of(attitude_sigma_rad)  # type: ignore[arg-type]
    except TypeError:   # unhashable (an array): made anew
        S = attitude_covariance(attitude_sigma_rad)
        return S, bool(np.any(S != 0))


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def shape_transform(radii_m: ArrayLike, R_body_to_cam: ArrayLike | None = None) -> FloatArray:
    """The matrix ``B = diag(1/a, 1/b, 1/c) R_body_to_cam^T`` mapping the body to the unit sphere.

    Parameters
    ----------
    radii_m : (3,) array
        Semi-axes [m].
    R_body_to_cam : (3, 3) array, optional
        Rotation body-fixed -> camera; identity by default (irrelevant for a sphere).

    Returns
    -------
    (3, 3) array
        ``B`` [1/m]; ``B^T B`` is the ellipsoid's shape matrix in the camera frame.
    """
    r = np.asarray(radii_m, float)
    T = np.eye(3) if R_body_to_cam is None else np.asarray(R_body_to_cam, float)
    return np.diag(1.0 / r) @ T.T


@dataclass(frozen=True)
class LimbFix:
    """A Christian-Robinson fix.

    Attributes
    ----------
    centre_camera : (3,) array
        Body centre relative to the camera, camera frame [m].
    covariance_camera : (3, 3) array
        Its first-order covariance [m^2].
    n : (3,) array
        The least-squares solution of ``H n = 1`` in scaled space [-].
    residual_px : (N,) array
        Per-point residual to the fitted limb cone [px] (module step 6).
    n_points : int
        Number of limb points used.
    point_jacobian : (N, 3, 2) array or None
        ``d centre_camera / d(u_i, v_i)`` [m/px] when the covariance was computed
        (:meth:`with_sigma` reuses it).
    """

    centre_camera: FloatArray
    covariance_camera: FloatArray
    n: FloatArray
    residual_px: FloatArray
    n_points: int
    point_jacobian: FloatArray | None = field(default=None, repr=False, compare=False)

    def with_sigma(self, sigma_px: float | ArrayLike) -> LimbFix:
        """The same fix with the covariance of other point sigmas [px] (the Jacobian is the
        same: no new solve)."""
        if self.point_jacobian is None:
            raise FixError("LimbFix.with_sigma: the fix was solved without its covariance")
        return replace(self, covariance_camera=_point_covariance(self.point_jacobian, sigma_px))

    @property
    def range_m(self) -> float:
        """Distance camera - body centre [m]."""
        return float(np.linalg.norm(self.centre_camera))

    def position_inertial(self, R_cam_to_inertial: ArrayLike) -> FloatArray:
        """Camera position relative to the body centre, inertial axes [m]."""
        return -np.asarray(R_cam_to_inertial, float) @ self.centre_camera

    def covariance_inertial(self, R_cam_to_inertial: ArrayLike,
                            attitude_sigma_rad: float | ArrayLike = 0.0,
                            radius_sigma_fraction: float = 0.0) -> FloatArray:
        """Covariance of :meth:`position_inertial` [m^2], attitude knowledge error included.

        Parameters
        ----------
        R_cam_to_inertial : (3, 3) array
            Attitude used for the fix.
        attitude_sigma_rad : float, (3,) array or (3, 3) array
            1-sigma attitude knowledge error [rad] (small-angle): isotropic, or per camera axis
            ``(x, y, z)``, or the full covariance ``S`` [rad^2] of the error rotation in camera
            axes (:func:`attitude_covariance`). An error rotation ``dtheta`` (camera axes)
            moves the camera-frame centre ``c`` by ``-dtheta x c``, so
            ``P += R [c x] S [c x]^T R^T`` (``S = diag(sigma^2)`` for sigmas).
        radius_sigma_fraction : float
            1-sigma relative error of the body's apparent limb radius shared by every point
            (terrain, :mod:`starnav.dem.limb`): the fix scales with the radius, so
            ``P += f^2 R c c^T R^T``.
        """
        R = np.asarray(R_cam_to_inertial, float)
        P = R @ self.covariance_camera @ R.T
        S, nonzero = _attitude_covariance_nonzero(attitude_sigma_rad)
        if nonzero:
            X = _skew(np.asarray(self.centre_camera, float))
            P = P + R @ X @ S @ X.T @ R.T
        if radius_sigma_fraction > 0:
            c = R @ np.asarray(self.centre_camera, float)
            P = P + radius_sigma_fraction**2 * np.outer(c, c)
        return 0.5 * (P + P.T)


def scaled_rays(uv: ArrayLike, camera: Camera, B: FloatArray,
                with_jacobian: bool = False) -> tuple[FloatArray, FloatArray | None]:
    """Scaled-space unit rays ``s_i = B x_i / |B x_i|`` and optionally ``d s_i / d(u_i, v_i)``.

    Returns ``(s (N, 3), J (N, 3, 2) or None)``; ``J`` in [1/px].
    """
    uv = np.asarray(uv, float)
    if with_jacobian:
        x, Jx = camera.unproject_with_jacobian(uv)
    else:
        x, Jx = camera.unproject(uv), None
    y = x @ B.T
    ny = np.linalg.norm(y, axis=1)
    s = y / ny[:, None]
    if Jx is None:
        return s, None
    BJ = np.matmul(B, Jx)  # (N, 3, 2)
    # (I - s s^T) / |y| applied to B Jx without forming the (N, 3, 3) projector
    sBJ = np.matmul(s[:, None, :], BJ)                 # (N, 1, 2)
    return s, (BJ - s[:, :, None] * sBJ) / ny[:, None, None]


def cone_residual_px(s: FloatArray, n: FloatArray, pixel_angle_rad: float) -> FloatArray:
    """Angle between rays ``s (N, 3)`` and the limb cone ``s^T n = 1``, in pixels.

    ``n`` may be ``(3,)`` (result ``(N,)``) or ``(K, 3)`` for ``K`` hypotheses (result
    ``(N, K)``). Positive outside the limb. ``pixel_angle_rad`` is the angle per pixel (1/fx).
    """
    n = np.asarray(n, float)
    nn = np.linalg.norm(n, axis=-1)
    with np.errstate(invalid="ignore"):
        half = np.arccos(np.clip(1.0 / nn, -1.0, 1.0))
        ang = np.arccos(np.clip((s @ n.T) / nn, -1.0, 1.0))
    return (ang - half) / pixel_angle_rad


def centre_from_n(n: FloatArray, B: FloatArray) -> FloatArray:
    """``r_C = (n^T n - 1)^(-1/2) B^{-1} n`` [m] (module step 4)."""
    nn = float(n @ n)
    if not nn > 1.0:
        raise FixError(f"Christian-Robinson: n^T n = {nn:.6g} <= 1, the limb points do not "
                       "bound a body (noise-dominated or outliers)")
    return solve_vectors(B, n) / math.sqrt(nn - 1.0)


def christian_robinson(
    uv: ArrayLike,
    camera: Camera,
    *,
    sigma_px: float | ArrayLike = 0.5,
    R_body_to_cam: ArrayLike | None = None,
    options: ChristianRobinsonOptions | None = None,
    with_covariance: bool = True,
) -> LimbFix:
    """Christian-Robinson fix from limb points (module steps 1-5).

    Parameters
    ----------
    uv : (N, 2) array
        Limb points, measured (distorted) pixels [px].
    camera : Camera
        Camera model (distortion is removed before unprojection).
    sigma_px : float or (N,) array
        1-sigma isotropic error of each point [px], for the covariance.
    R_body_to_cam : (3, 3) array, optional
        Body-fixed -> camera rotation (needed for a triaxial body only).
    options : ChristianRobinsonOptions, optional
        Body shape and limits.
    with_covariance : bool
        Skip the covariance (RANSAC hypotheses) when False (returns zeros).

    Returns
    -------
    LimbFix

    Raises
    ------
    FixError
        Fewer than ``min_points`` points, collinear rays, or ``n^T n <= 1``.
    """
    opt = options or ChristianRobinsonOptions()
    uv = np.asarray(uv, float).reshape(-1, 2)
    N = uv.shape[0]
    if N < opt.min_points:
        raise FixError(f"Christian-Robinson: {N} limb points, need >= {opt.min_points}")
    B = shape_transform(opt.radii_m, R_body_to_cam)
    s, Js = scaled_rays(uv, camera, B, with_jacobian=with_covariance)
    n, rank = lstsq_vectors(s, np.ones(N))
    if rank < 3:
        raise FixError(f"Christian-Robinson: the {N} limb rays are degenerate (rank {rank}); "
                       "need >= 3 points spread along the limb")
    c = centre_from_n(n, B)
    res = cone_residual_px(s, n, 1.0 / camera.fx)
    cov, G = np.zeros((3, 3)), None
    if with_covariance:
        G = christian_robinson_jacobian_from(s, Js, n, B)
        cov = _point_covariance(G, sigma_px)
    return LimbFix(centre_camera=c, covariance_camera=cov, n=n, residual_px=res, n_points=N,
                   point_jacobian=G)


def _point_covariance(G: FloatArray, sigma_px: float | ArrayLike) -> FloatArray:
    """``sum_i sigma_i^2 G_i G_i^T`` of the per-point Jacobians ``G (N, 3, 2)`` [m^2]."""
    sig = np.broadcast_to(np.asarray(sigma_px, float), (G.shape[0],))
    X = (G * sig[:, None, None]).transpose(1, 0, 2).reshape(3, -1)
    cov = X @ X.T
    return 0.5 * (cov + cov.T)


def christian_robinson_centres(uv_sets: ArrayLike, camera: Camera, *,
                               R_body_to_cam: ArrayLike | None = None,
                               options: ChristianRobinsonOptions | None = None) -> FloatArray:
    """Body centres ``(K, 3)`` [m, camera frame] of ``K`` sets of ``N`` limb points
    ``(K, N, 2)`` [px], without covariance: the same arithmetic as :func:`christian_robinson`
    on each set, the rays of all sets unprojected at once (the pipeline's sensitivity to
    errors all points share moves every point and solves again)."""
    opt = options or ChristianRobinsonOptions()
    uv = np.asarray(uv_sets, float)
    K, N = uv.shape[:2]
    if N < opt.min_points:
        raise FixError(f"Christian-Robinson: {N} limb points, need >= {opt.min_points}")
    B = shape_transform(opt.radii_m, R_body_to_cam)
    s = scaled_rays(uv.reshape(-1, 2), camera, B)[0].reshape(K, N, 3)
    ns, ranks = lstsq_vectors(s, np.ones((K, N)))   # each set on its own, in one call
    out = np.empty((K, 3))
    for k in range(K):
        if ranks[k] < 3:
            raise FixError(f"Christian-Robinson: the {N} limb rays are degenerate (rank "
                           f"{ranks[k]}); need >= 3 points spread along the limb")
        out[k] = centre_from_n(ns[k], B)
    return out


def christian_robinson_jacobian_from(s: FloatArray, Js: FloatArray, n: FloatArray,
                                     B: FloatArray) -> FloatArray:
    """Exact ``d r_C / d(u_i, v_i)``, ``(N, 3, 2)`` [m/px] (module step 5)."""
    M = s.T @ s
    Minv = np.linalg.inv(M)
    e = 1.0 - s @ n
    nn = float(n @ n)
    Binv = np.linalg.inv(B)
    Jc = Binv @ (np.eye(3) / math.sqrt(nn - 1.0) - np.outer(n, n) / (nn - 1.0) ** 1.5)
    # dn/ds_i = Minv (e_i I - s_i n^T), applied to Js without forming the (N, 3, 3) D_i
    DJ = e[:, None, None] * Js - s[:, :, None] * np.matmul(n, Js)[:, None, :]
    return np.matmul(Jc @ Minv, DJ)


def christian_robinson_jacobian(uv: ArrayLike, camera: Camera, *,
                                R_body_to_cam: ArrayLike | None = None,
                                options: ChristianRobinsonOptions | None = None) -> FloatArray:
    """Jacobian of the fix ``r_C`` with respect to every limb pixel, ``(N, 3, 2)`` [m/px]."""
    opt = options or ChristianRobinsonOptions()
    uv = np.asarray(uv, float).reshape(-1, 2)
    B = shape_transform(opt.radii_m, R_body_to_cam)
    s, Js = scaled_rays(uv, camera, B, with_jacobian=True)
    n, *_ = np.linalg.lstsq(s, np.ones(uv.shape[0]), rcond=None)
    return christian_robinson_jacobian_from(s, Js, n, B)


# ------------------------------------------------------------------- the true limb
def limb_cone_matrix(centre_camera: ArrayLike, B: FloatArray) -> FloatArray:
    """Matrix ``C`` of the limb cone ``x^T C x = 0`` in the camera frame (``> 0`` on the body).

    ``C = B^T (c' c'^T - (c'^T c' - 1) I) B`` with ``c' = B r_C`` (scaled space).
    """
    cp = B @ np.asarray(centre_camera, float)
    return B.T @ (np.outer(cp, cp) - (cp @ cp - 1.0) * np.eye(3)) @ B


def limb_conic_pixels(camera: Camera, centre_camera: ArrayLike, B: FloatArray) -> FloatArray:
    """The limb's image conic ``[u v 1] Q [u v 1]^T = 0`` for the pinhole [px] (``> 0`` inside).

    Normalised so that ``|Q|_F = 1``.
    """
    Kinv = np.linalg.inv(camera.K)
    Q = Kinv.T @ limb_cone_matrix(centre_camera, B) @ Kinv
    return Q / np.linalg.norm(Q)


def ellipsoid_limb_points(camera: Camera, centre_camera: ArrayLike, B: FloatArray,
                          n: int = 360, distort: bool = True) -> FloatArray:
    """Exact limb points ``(n, 2)`` [px] of the ellipsoid ``|B (X - r_C)| = 1`` (camera frame).

    In scaled space the limb is the circle of tangency of the cone from the origin to the unit
    sphere at ``c' = B r_C``; it is mapped back with ``B^{-1}`` and projected.
    """
    cp = B @ np.asarray(centre_camera, float)
    d = float(np.linalg.norm(cp))
    if d <= 1.0:
        raise FixError("the camera is inside the body")
    ch = cp / d
    a = np.cross(ch, [0.0, 0.0, 1.0] if abs(ch[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(ch, a)
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    along = (d * d - 1.0) / d
    rad = math.sqrt(d * d - 1.0) / d
    ys = along * ch + rad * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    X = np.linalg.solve(B, ys.T).T
    X = X[X[:, 2] > 0]
    return camera.project(X, distort=distort)
