"""Navigation metrics against truth: limb-point errors, estimation errors, NEES and NIS.

1. Limb-point error (the paper's figures 8, 22, 25): each measured point's signed distance to
   the true limb conic along its gradient, positive outside (:func:`limb_point_errors`).
2. Estimation error of position and velocity, and the 3-sigma bounds.
3. NEES over the 6 states and NIS of every fix (:func:`nees`, :func:`chi2_band`).
4. Monte Carlo consistency (:func:`anees_statistics`): the per-epoch ANEES against its exact
   band, and the time-averaged ANEES against a band of ``R K / tau`` effective samples, ``tau``
   the integrated autocorrelation time (the moment match of Satterthwaite 1946). The
   statistics in full: docs/navigation.md, "Consistency statistics".

References
----------
Y. Bar-Shalom, X. R. Li and T. Kirubarajan, "Estimation with applications to tracking and
navigation", Wiley (2001), sections 5.4 (NEES, NIS) and 5.4.2 (the chi-square bands).
A. D. Sokal, "Monte Carlo methods in statistical mechanics: foundations and new algorithms",
in Functional Integration, Plenum (1997), pp. 131-192, section 3 (integrated autocorrelation
time, its automatic window ``M >= c tau(M)``).
F. E. Satterthwaite, "An approximate distribution of estimates of variance components",
Biometrics Bulletin 2 (1946), 110-114.

Index
-----
:class:`NavMetrics`, :func:`limb_point_errors`, :func:`conic_signed_distance`,
:func:`undistorted_pixels`, :class:`ErrorSummary`, :func:`error_pdf`, :func:`nees`,
:func:`chi2_band`, :func:`consistency_fraction`, :func:`anees_statistics`,
:func:`autocorrelation`, :func:`integrated_autocorrelation_time`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.camera import Camera
from starnav.geometry import FrameGeometry
from starnav.navigation.christian_robinson import limb_conic_pixels, shape_transform
from starnav.typing import FloatArray


class FilterResultLike(Protocol):
    """What :class:`NavMetrics` reads of a filter run
    (:class:`starnav.navigation.pipeline.FilterResult`)."""

    epochs: FloatArray
    has_fix: NDArray[np.bool_]
    accepted: NDArray[np.bool_]
    nis: FloatArray

    def errors(self, truth: ArrayLike) -> FloatArray: ...

    def sigma3(self) -> FloatArray: ...

    def nees(self, truth: ArrayLike) -> FloatArray: ...

    def nees_position(self, truth: ArrayLike) -> FloatArray: ...

    def nees_velocity(self, truth: ArrayLike) -> FloatArray: ...


#: Newton steps when projecting a point onto the true limb conic.
CONIC_PROJECTION_STEPS = 8


def undistorted_pixels(camera: Camera, uv: ArrayLike) -> FloatArray:
    """Measured pixels ``(N, 2)`` to pinhole (distortion-free) pixels [px]."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    if not camera.has_distortion:
        return uv.copy()
    xy = camera.pixel_to_normalized(uv)
    return np.column_stack([camera.fx * xy[:, 0] + camera.cx, camera.fy * xy[:, 1] + camera.cy])


def conic_signed_distance(Q: ArrayLike, uv: ArrayLike) -> FloatArray:
    """Signed distance [px] of pinhole pixels ``(N, 2)`` to the conic ``Q`` (``> 0`` outside,
    where ``p^T Q p < 0``), by Newton steps along the gradient (module step 1)."""
    Q = np.asarray(Q, float)
    p0 = np.asarray(uv, float).reshape(-1, 2)
    p = p0.copy()
    for _ in range(CONIC_PROJECTION_STEPS):
        ph = np.column_stack([p, np.ones(p.shape[0])])
        Qp = ph @ Q.T
        f = np.sum(ph * Qp, axis=1)
        g = 2.0 * Qp[:, :2]
        p = p - (f / np.sum(g * g, axis=1))[:, None] * g
    ph0 = np.column_stack([p0, np.ones(p0.shape[0])])
    f0 = np.sum(ph0 * (ph0 @ Q.T), axis=1)
    return -np.sign(f0) * np.linalg.norm(p - p0, axis=1)


def limb_point_errors(uv: ArrayLike, camera: Camera, truth: FrameGeometry,
                      radii_m: ArrayLike | None = None) -> FloatArray:
    """Signed distance [px] of measured limb points to the true limb (positive outside).

    Parameters
    ----------
    uv : (N, 2) array
        Measured (distorted) limb points [px].
    camera : Camera
    truth : FrameGeometry
        True pose (camera position, true attitude, Moon orientation and radius).
    radii_m : (3,) array, optional
        Body semi-axes [m]; default the sphere ``truth.body_radius``.
    """
    r = (truth.body_radius,) * 3 if radii_m is None else tuple(radii_m)
    R_body_to_cam = truth.R_cam_to_inertial.T @ truth.R_body_to_inertial
    B = shape_transform(r, R_body_to_cam)
    Q = limb_conic_pixels(camera, truth.moon_centre_camera(), B)
    return conic_signed_distance(Q, undistorted_pixels(camera, uv))


@dataclass(frozen=True)
class ErrorSummary:
    """Bias, standard deviation, RMS [unit of the input] and count of a set of errors."""

    bias: float
    std: float
    rms: float
    count: int

    @classmethod
    def of(cls, e: ArrayLike) -> ErrorSummary:
        e = np.asarray(e, float).ravel()
        e = e[np.isfinite(e)]
        if e.size == 0:
            return cls(math.nan, math.nan, math.nan, 0)
        return cls(float(e.mean()), float(e.std(ddof=1)) if e.size > 1 else 0.0,
                   float(np.sqrt(np.mean(e * e))), int(e.size))

    def as_dict(self) -> dict[str, float | int]:
        return {"bias": self.bias, "std": self.std, "rms": self.rms, "count": self.count}


def error_pdf(e: ArrayLike, bins: int | ArrayLike = 60) -> tuple[FloatArray, FloatArray]:
    """Histogram density of errors: ``(bin centres, density)`` (integrates to 1)."""
    e = np.asarray(e, float).ravel()
    e = e[np.isfinite(e)]
    dens, edges = np.histogram(e, bins=bins, density=True)
    return 0.5 * (edges[1:] + edges[:-1]), dens


def nees(error: ArrayLike, P: ArrayLike) -> float | FloatArray:
    """Normalised estimation error squared ``e^T P^-1 e`` (broadcast over leading axes)."""
    e = np.asarray(error, float)
    P = np.asarray(P, float)
    sol = np.linalg.solve(P, e[..., None])[..., 0]
    out = np.sum(e * sol, axis=-1)
    return float(out) if np.ndim(out) == 0 else out


def chi2_band(dof: int, runs: int = 1, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the mean of ``runs`` chi2(``dof``) samples."""
    from scipy.stats import chi2

    a = (1.0 - probability) / 2.0
    k = dof * runs
    return float(chi2.ppf(a, k) / runs), float(chi2.ppf(1.0 - a, k) / runs)


def consistency_fraction(values: ArrayLike, dof: int, runs: int = 1,
                         probability: float = 0.95) -> float:
    """Fraction of finite ``values`` (NEES or NIS, averaged over ``runs``) inside their
    two-sided chi-square ``probability`` band."""
    lo, hi = chi2_band(dof, runs, probability)
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    return float(np.mean((v >= lo) & (v <= hi)))


#: Sokal's window constant: the autocorrelation sum stops at the first lag ``M`` with
#: ``M >= c tau(M)`` (c = 5 suits correlations that decay roughly exponentially; Sokal 1997).
AUTOCORRELATION_WINDOW_C = 5.0


def autocorrelation(values: ArrayLike) -> FloatArray:
    """Autocorrelation ``rho_k`` (``k = 0 .. K-1``) of ``R`` runs x ``K`` epochs of a
    statistic, pooled over the runs.

    Each epoch is centred on its own mean over the runs, so a trend common to the runs (a
    transient at the start of an arc) is not read as correlation; the centring scales every
    lag's covariance by the same ``1 - 1/R``, which cancels in the ratio. A single run is
    centred on its time mean instead. Non-finite entries (a NIS without a fix) are left out
    of the sums."""
    x = np.asarray(values, float)
    if x.ndim == 1:
        x = x[None, :]
    ok = np.isfinite(x)
    n = ok.sum(axis=0)
    if x.shape[0] == 1:
        mean = np.full(x.shape[1], float(x[ok].mean()) if ok.any() else 0.0)
    else:
        mean = np.where(n > 0, np.where(ok, x, 0.0).sum(axis=0) / np.maximum(n, 1), 0.0)
    d = np.where(ok, x - mean, 0.0)
    K = x.shape[1]
    c = np.empty(K)
    for k in range(K):
        pairs = (ok[:, : K - k] & ok[:, k:]).sum()
        c[k] = np.sum(d[:, : K - k] * d[:, k:]) / pairs if pairs else np.nan
    if not (np.isfinite(c[0]) and c[0] > 0):
        return np.full(K, np.nan)
    return c / c[0]


def integrated_autocorrelation_time(values: ArrayLike,
                                    window_c: float = AUTOCORRELATION_WINDOW_C
                                    ) -> tuple[float, int]:
    """Integrated autocorrelation time ``tau`` of the time mean of ``R`` runs x ``K`` epochs,
    and the window ``M`` it was summed to (Sokal 1997, s. 3).

    ``tau = 1 + 2 sum_{k=1..M} (1 - k/K) rho_k`` (:func:`autocorrelation`; the ``1 - k/K``
    weights make ``tau`` the exact variance ratio of a ``K``-sample mean when ``rho`` is
    known), with ``M`` the first lag where ``M >= window_c tau(M)`` (or ``K - 1``). ``tau`` is
    kept in ``[1, K]``: the mean of ``K`` epochs is worth between one and ``K`` independent
    epochs (a negative correlation is not trusted to do better than independence)."""
    rho = autocorrelation(values)
    K = rho.size
    if K < 2 or not np.isfinite(rho[0]):
        return 1.0, 0
    tau, M = 1.0, 0
    for k in range(1, K):
        r = rho[k] if np.isfinite(rho[k]) else 0.0
        tau += 2.0 * (1.0 - k / K) * r
        M = k
        if k >= window_c * tau:
            break
    return float(min(max(tau, 1.0), K)), M


def _verdict(m: float, band: tuple[float, float]) -> str:
    if not math.isfinite(m):
        return "no data"
    return "consistent" if band[0] <= m <= band[1] else (
        "overconfident" if m > band[1] else "pessimistic")


def anees_statistics(values: ArrayLike, dof: int, probability: float = 0.99,
                     epoch_probability: float = 0.95) -> dict[str, object]:
    """Consistency of ``R`` runs x ``K`` epochs of a chi2(``dof``) statistic (module step 4).

    Parameters
    ----------
    values : (R, K) array
        NEES (or NIS) per run and epoch; non-finite entries (no fix) are left out.
    dof : int
        Degrees of freedom of one sample (6 for the state NEES, 3 for a block or the NIS).
    probability : float
        Two-sided probability of the time-averaged band.
    epoch_probability : float
        Two-sided probability of the per-epoch band.

    Returns
    -------
    dict
        ``runs``, ``epochs``, ``dof``; ``per_epoch`` (the ANEES of each epoch, mean over its
        finite runs), ``per_epoch_band`` (``[lo, hi]`` of each epoch, from its number of
        finite runs), ``epochs_in_band`` (fraction of epochs with a value inside their band;
        a consistent filter: ``epoch_probability``), ``epochs_above`` and ``epochs_below``
        (fractions outside, above and below); ``mean`` (time-averaged ANEES, pooled over
        every finite sample), ``autocorrelation_time`` and ``window`` (``tau``, ``M`` of
        :func:`integrated_autocorrelation_time`), ``effective_samples`` (``N / tau``, ``N``
        the finite samples), ``band`` (time-averaged band with those degrees of freedom),
        ``band_independent`` (the too-narrow band of ``N`` independent samples),
        ``verdict`` (``consistent`` inside ``band``, ``overconfident`` above,
        ``pessimistic`` below).
    """
    from scipy.stats import chi2

    x = np.asarray(values, float)
    if x.ndim == 1:
        x = x[None, :]
    R, K = x.shape
    ok = np.isfinite(x)
    n_t = ok.sum(axis=0)
    has = n_t > 0
    per_epoch = np.full(K, np.nan)
    per_epoch[has] = np.where(ok, x, 0.0).sum(axis=0)[has] / n_t[has]
    a = (1.0 - epoch_probability) / 2.0
    lo_t = np.full(K, np.nan)
    hi_t = np.full(K, np.nan)
    lo_t[has] = chi2.ppf(a, dof * n_t[has]) / n_t[has]
    hi_t[has] = chi2.ppf(1.0 - a, dof * n_t[has]) / n_t[has]
    N = int(ok.sum())
    out: dict[str, object] = {"runs": R, "epochs": K, "dof": int(dof),
                              "probability": probability,
                              "epoch_probability": epoch_probability,
                              "per_epoch": per_epoch.tolist(),
                              "per_epoch_band": np.column_stack([lo_t, hi_t]).tolist()}
    if N == 0:
        out.update(mean=math.nan, verdict="no data")
        return out
    v, lo_h, hi_h = per_epoch[has], lo_t[has], hi_t[has]
    out.update(epochs_in_band=float(np.mean((v >= lo_h) & (v <= hi_h))),
               epochs_above=float(np.mean(v > hi_h)), epochs_below=float(np.mean(v < lo_h)))
    m = float(x[ok].mean())
    tau, M = integrated_autocorrelation_time(x)
    n_eff = N / tau
    b = (1.0 - probability) / 2.0
    band = (float(chi2.ppf(b, dof * n_eff) / n_eff), float(chi2.ppf(1.0 - b, dof * n_eff) / n_eff))
    naive = (float(chi2.ppf(b, dof * N) / N), float(chi2.ppf(1.0 - b, dof * N) / N))
    out.update(mean=m, autocorrelation_time=tau, window=M, effective_samples=float(n_eff),
               band=list(band), band_independent=list(naive), verdict=_verdict(m, band))
    return out


def _vec(x: ArrayLike) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(x, float))


@dataclass(frozen=True)
class NavMetrics:
    """Accuracy and consistency of one filter run against truth: the one vocabulary of
    ``metrics.json`` (``starnav navigate``), the sweep table (``starnav sweep``), the reports
    and the CLI. Norms are of EMB-centred J2000 errors; vectors are per axis.

    Attributes
    ----------
    frames, fixes, accepted : int
        Frames, frames that gave a fix, fixes the filter's gate accepted.
    final_position_error_m, final_velocity_error_m_s : float
        Norm of (estimate - truth) at the last frame [m, m/s].
    final_position_error_pct_range : float
        Final position error over the camera-Moon distance at the last frame [%].
    final_velocity_error_pct_speed : float
        Final velocity error over the EMB-centred speed at the last frame [%].
    rms_position_error_m, rms_velocity_error_m_s : float
        RMS over frames of the error norms (initial transient included).
    final_position_3sigma_m, final_velocity_3sigma_m_s : float
        Norm of the per-axis 3-sigma bounds at the last frame.
    nees_mean : float
        Mean over frames of the 6-state NEES (consistent: ~6).
    nees_position_mean, nees_velocity_mean : float
        Mean over frames of the NEES of the position alone and of the velocity alone (their
        marginal covariances; consistent: ~3 each). A 6-state NEES near 6 can hide a position
        that is overconfident behind a velocity that is mostly prior.
    nees_fraction_in_95, nis_fraction_in_95 : float
        Fraction of frames whose NEES (6 dof) / fixes whose NIS (3 dof) is inside the
        single-sample 95 % chi-square band.
    nis_mean : float
        Mean NIS of the fixes (consistent: ~3).
    final_position_error_xyz_m, final_velocity_error_xyz_m_s : tuple of 3 floats
    final_position_3sigma_xyz_m, final_velocity_3sigma_xyz_m_s : tuple of 3 floats
    fraction_within_3sigma : tuple of 6 floats
        Per state (x, y, z, vx, vy, vz), fraction of frames with ``|e| <= 3 sigma``.
    """

    frames: int
    fixes: int
    accepted: int
    final_position_error_m: float = math.nan
    final_velocity_error_m_s: float = math.nan
    final_position_error_pct_range: float = math.nan
    final_velocity_error_pct_speed: float = math.nan
    rms_position_error_m: float = math.nan
    rms_velocity_error_m_s: float = math.nan
    final_position_3sigma_m: float = math.nan
    final_velocity_3sigma_m_s: float = math.nan
    nees_mean: float = math.nan
    nees_position_mean: float = math.nan
    nees_velocity_mean: float = math.nan
    nees_fraction_in_95: float = math.nan
    nis_mean: float = math.nan
    nis_fraction_in_95: float = math.nan
    final_position_error_xyz_m: tuple[float, ...] = (math.nan,) * 3
    final_velocity_error_xyz_m_s: tuple[float, ...] = (math.nan,) * 3
    final_position_3sigma_xyz_m: tuple[float, ...] = (math.nan,) * 3
    final_velocity_3sigma_xyz_m_s: tuple[float, ...] = (math.nan,) * 3
    fraction_within_3sigma: tuple[float, ...] = (math.nan,) * 6

    #: The scalar fields (the sweep table's columns).
    SCALARS = ("fixes", "accepted", "final_position_error_m", "final_velocity_error_m_s",
               "final_position_error_pct_range", "final_velocity_error_pct_speed",
               "rms_position_error_m", "rms_velocity_error_m_s", "final_position_3sigma_m",
               "final_velocity_3sigma_m_s", "nees_mean", "nees_position_mean",
               "nees_velocity_mean", "nees_fraction_in_95", "nis_mean",
               "nis_fraction_in_95")

    @classmethod
    def of(cls, result: FilterResultLike, truth: ArrayLike | None = None,
           final_range_m: float = math.nan) -> NavMetrics:
        """Metrics of a filter run (``starnav.navigation.pipeline.FilterResult``) against the
        EMB-centred truth ``(K, 6)`` at its epochs; ``final_range_m`` the camera-Moon distance
        at the last frame [m]. Without truth only counts and NIS are filled."""
        nis = np.asarray(result.nis, float)
        nis = nis[np.isfinite(nis)]
        base = dict(frames=int(len(result.epochs)), fixes=int(np.sum(result.has_fix)),
                    accepted=int(np.sum(result.accepted)),
                    nis_mean=float(nis.mean()) if nis.size else math.nan,
                    nis_fraction_in_95=consistency_fraction(nis, 3))
        if truth is None or base["frames"] == 0:
            return cls(**base)
        truth = np.asarray(truth, float)
        e = result.errors(truth)
        s3 = result.sigma3()
        ne = np.asarray(result.nees(truth), float)
        ep, ev = np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1)
        speed = float(np.linalg.norm(truth[-1, 3:]))
        rng = float(final_range_m)
        return cls(
            **base,
            final_position_error_m=float(ep[-1]), final_velocity_error_m_s=float(ev[-1]),
            final_position_error_pct_range=100.0 * float(ep[-1]) / rng
            if math.isfinite(rng) and rng > 0 else math.nan,
            final_velocity_error_pct_speed=100.0 * float(ev[-1]) / speed
            if speed > 0 else math.nan,
            rms_position_error_m=float(np.sqrt(np.mean(ep**2))),
            rms_velocity_error_m_s=float(np.sqrt(np.mean(ev**2))),
            final_position_3sigma_m=float(np.linalg.norm(s3[-1, :3])),
            final_velocity_3sigma_m_s=float(np.linalg.norm(s3[-1, 3:])),
            nees_mean=float(np.mean(ne)), nees_fraction_in_95=consistency_fraction(ne, 6),
            nees_position_mean=float(np.mean(result.nees_position(truth))),
            nees_velocity_mean=float(np.mean(result.nees_velocity(truth))),
            final_position_error_xyz_m=_vec(e[-1, :3]),
            final_velocity_error_xyz_m_s=_vec(e[-1, 3:]),
            final_position_3sigma_xyz_m=_vec(s3[-1, :3]),
            final_velocity_3sigma_xyz_m_s=_vec(s3[-1, 3:]),
            fraction_within_3sigma=_vec(np.mean(np.abs(e) <= s3, axis=0)))

    def as_dict(self) -> dict[str, object]:
        """JSON-safe dict (NaN -> None, tuples -> lists)."""
        out: dict[str, object] = {}
        for k, v in self.__dict__.items():
            if isinstance(v, tuple):
                out[k] = [None if not math.isfinite(x) else x for x in v]
            elif isinstance(v, float):
                out[k] = v if math.isfinite(v) else None
            else:
                out[k] = v
        return out
