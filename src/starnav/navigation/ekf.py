"""Extended Kalman filter of the spacecraft state from limb position fixes (EMB, J2000).

The STAR Nav filter estimates the spacecraft's position and velocity about the Earth-Moon
barycentre in J2000 from the Christian-Robinson fixes, with Gauss-Markov states that absorb a
slowly varying bias of the image processing. Each step and the bias models in full:
docs/methods.md, "starnav.navigation.ekf".

Technique
---------
1. State ``(r, v, b)``, ``b`` the states of the ``bias_model`` (:data:`BIAS_MODELS`: none,
   additive, range-scale, range-scale+additive, limb-common).
2. Prediction: state and STM from :class:`~starnav.navigation.dynamics.Dynamics`; each bias a
   first-order Gauss-Markov process, exactly discretised; white-acceleration process noise.
3. Measurement: a fix (camera relative to the Moon, inertial [m]) with its covariance; analytic
   Jacobian.
4. Gate on the NIS (chi-square, 3 dof); after ``max_consecutive_rejections`` the next fix is
   forced in.
5. Update in Joseph form.
6. A frame without a usable limb only propagates.
7. Considered parameters (the camera's calibration: focal length, principal point,
   distortion): Schmidt states, constant over the arc, with the calibration's covariance and
   never updated. Their error is one constant for every fix of an arc, which a per-fix
   covariance would treat as new at each frame; estimating them is not possible either, since
   a limb fix cannot tell a focal-length error from a range error.

The knobs are the scenario section :class:`FilterConfig`; the covariances the builder
resolves from calibrations, :class:`EkfPriors`.

References
----------
Seed paper (STAR Nav), step 5 of the pixel-accuracy algorithm and its reference 3 (LUMIO
navigation). R. G. Brown and P. Y. C. Hwang, "Introduction to random signals and applied Kalman
filtering", 4th ed., Wiley (2012): 4.2 (Gauss-Markov discretisation), 4.7 (Joseph form).
B. D. Tapley, B. E. Schutz and G. H. Born, "Statistical orbit determination", Elsevier (2004),
4.7 (EKF with the STM), ch. 6 (consider covariance analysis). S. F. Schmidt, "Application of
state-space methods to navigation problems", Advances in Control Systems 3 (1966) 293-340 (the
Schmidt-Kalman consider filter).

Index
-----
:class:`NavigationEkf`, :class:`FilterConfig`, :class:`EkfPriors`, :func:`bias_covariance`,
:class:`UpdateInfo`, :func:`measurement_model`, :func:`gauss_markov_discrete`,
:func:`white_acceleration_q`, :data:`BIAS_MODELS`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field
from scipy.special import chdtri

from starnav.config_base import SIView, StrictModel
from starnav.errors import ConfigError
from starnav.fields import NonNegativeFloat, PositiveFloat
from starnav.linalg import solve, solve_vectors
from starnav.navigation.dynamics import Dynamics, MoonEphemeris
from starnav.registry import Registry
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Number of bias states of each bias model.
BIAS_MODELS: Registry[int] = Registry("bias model", {
    "none": 0, "additive": 3, "range-scale": 1, "range-scale+additive": 4, "limb-common": 3})


class FilterConfig(StrictModel):
    """Scenario section ``navigation.filter``: the EKF (:class:`NavigationEkf` reads its SI
    view, ``to_si()``; the initial sigmas and the RK4 step are read by its callers)."""

    bias_model: Literal["none", "additive", "range-scale", "range-scale+additive",
                        "limb-common"] = Field(
        "none", description="Gauss-Markov bias states: additive (3-axis shift), range-scale, "
        "both, or limb-common (the errors all refined limb points of a frame share, with "
        "their calibrated covariance; only bias_tau_days is used)")
    bias_sigma_km: NonNegativeFloat = Field(0.0, description="additive bias 1-sigma [km]")
    range_scale_sigma: NonNegativeFloat = Field(0.0, description="range-scale bias 1-sigma [-]")
    bias_tau_days: PositiveFloat = Field(1.0, description="bias correlation time [days]")
    dynamics: Literal["earth-moon-sun"] = Field(
        "earth-moon-sun", description="the filter's force model: Earth, Moon and Sun point "
        "masses from DE421 (starnav.scenes.dynamics), whatever trajectory.forces adds to the "
        "truth")
    accel_psd_m2_s3: NonNegativeFloat = Field(
        2.4e-9, description="white acceleration noise density [m^2/s^3]: what the filter's "
        "model leaves out (planets, SRP of a 12U CubeSat, J2 at the halo: rms 1.7e-7 m/s^2, "
        "starnav.scenes.forces.unmodelled_acceleration_psd; 0: perfect dynamics knowledge)")
    gate_probability: Annotated[float, Field(gt=0, lt=1)] | None = Field(
        0.9999, description="chi-square gate on the NIS; null disables")
    max_consecutive_rejections: Annotated[int, Field(ge=1)] = Field(
        5, description="after this many fixes in a row rejected by the gate, the next one is "
        "accepted regardless (recovery from a diverged filter)")
    initial_position_sigma_km: PositiveFloat = Field(100.0, description="initial 1-sigma [km]")
    initial_velocity_sigma_m_s: PositiveFloat = Field(1.0, description="initial 1-sigma [m/s]")
    rk4_step_s: PositiveFloat = Field(
        1800.0, description="longest RK4 step of the filter dynamics [s] (an interval is split "
        "into equal steps no longer than this; 1800 s near L2: under a millimetre per day from "
        "the converged integration, one step per frame at the demo's cadence)")


#: The defaults' SI view.
_DEFAULT = FilterConfig().to_si()
#: What ``filter.common_covariance`` must be.
_COMMON_EXPECTED = ("a positive semi-definite 3 x 3 covariance with a positive diagonal for "
                    "bias_model='limb-common'")


def _is_covariance(C: FloatArray, tol: float, positive_diagonal: bool = False) -> bool:
    """``C`` is a finite square matrix with a non-negative (``positive_diagonal``: positive)
    diagonal whose symmetric part has no eigenvalue below ``-tol``."""
    if C.ndim != 2 or C.shape[0] != C.shape[1] or not np.all(np.isfinite(C)):
        return False
    d = np.diag(C)
    return bool((np.all(d > 0) if positive_diagonal else np.all(d >= 0))
                and np.min(np.linalg.eigvalsh(0.5 * (C + C.T))) >= -tol)


@dataclass(frozen=True)
class EkfPriors:
    """What the builder resolves for :class:`NavigationEkf` from calibrations (the knobs are
    :class:`FilterConfig`'s): ``common_covariance``, the ``limb-common`` bias states' steady
    state (3 x 3, per unit of disc radius; that model needs it), and ``consider_covariance``,
    the considered camera parameters' (n x n, module step 7; None: no consider states)."""

    common_covariance: tuple[tuple[float, float, float], ...] | None = None
    consider_covariance: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        if self.consider_covariance is not None:
            C = np.asarray(self.consider_covariance, float)
            if (C.ndim != 2 or C.size == 0
                    or not _is_covariance(C, 1e-9 * float(np.max(np.diag(C))))):
                raise ConfigError("filter.consider_covariance", np.shape(C),
                                  "a square positive semi-definite covariance of the considered "
                                  "camera parameters")
        if self.common_covariance is not None:
            C = np.asarray(self.common_covariance, float)
            if C.shape != (3, 3) or not _is_covariance(C, 1e-12 * float(np.max(C)), True):
                raise ConfigError("filter.common_covariance", self.common_covariance,
                                  _COMMON_EXPECTED)

    @property
    def n_consider(self) -> int:
        """Number of considered parameters (Schmidt states, module step 7)."""
        return 0 if self.consider_covariance is None else len(self.consider_covariance)


def bias_covariance(options: SIView, priors: EkfPriors) -> FloatArray:
    """Steady-state covariance of the bias states of ``options.bias_model`` (``options`` a
    :class:`FilterConfig`'s SI view; scale [-] first, then metres)."""
    model = options.bias_model
    if model == "limb-common":
        if priors.common_covariance is None:
            raise ConfigError("filter.common_covariance", None, _COMMON_EXPECTED)
        return np.asarray(priors.common_covariance, float)
    sb = {"none": np.zeros(0),
          "additive": np.full(3, options.bias_sigma),
          "range-scale": np.array([options.range_scale_sigma]),
          "range-scale+additive": np.array([options.range_scale_sigma]
                                           + [options.bias_sigma] * 3)}[model]
    if np.any(sb <= 0):
        scale = sb[0] <= 0 and model.startswith("range-scale")
        raise ConfigError("filter.range_scale_sigma" if scale else "filter.bias_sigma_km",
                          options.range_scale_sigma if scale else options.bias_sigma / 1e3,
                          f"a bias 1-sigma > 0 for bias_model={model!r}")
    return np.diag(sb * sb)


def gauss_markov_discrete(dt: float, sigma: float, tau: float) -> tuple[float, float]:
    """Exact discretisation of a first-order Gauss-Markov process over ``dt`` [s].

    Returns ``(phi, q)``: ``b_k+1 = phi b_k + w`` with ``phi = exp(-|dt|/tau)`` and
    ``Var(w) = q = sigma^2 (1 - exp(-2 |dt|/tau))`` (``sigma`` steady-state 1-sigma,
    ``tau`` [s] correlation time).
    """
    phi = math.exp(-abs(dt) / tau)
    return phi, sigma * sigma * -math.expm1(-2.0 * abs(dt) / tau)


def white_acceleration_q(dt: float, psd: float) -> FloatArray:
    """Discrete process noise (6 x 6) of white acceleration of density ``psd`` [m^2/s^3]."""
    dt = abs(dt)
    Q = np.zeros((6, 6))
    i = _AXES
    Q[i, i] = psd * (dt**3 / 3.0)
    Q[i, i + 3] = Q[i + 3, i] = psd * (dt**2 / 2.0)
    Q[i + 3, i + 3] = psd * dt
    return Q


_AXES = np.arange(3)


def measurement_model(x: ArrayLike, moon_position: ArrayLike, bias_model: str,
                      common_jacobian: ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
    """Predicted fix ``h(x)`` [m] and its Jacobian ``H = dh/dx`` (3 x n) (module step 3).

    Parameters
    ----------
    x : (6 + n_bias,) array
        State: EMB-centred position [m], velocity [m/s], bias states.
    moon_position : (3,) array
        Moon relative to the EMB [m].
    bias_model : str
        One of :data:`BIAS_MODELS`.
    common_jacobian : (3, 3) array, optional
        ``G`` of the ``limb-common`` model [m per unit of disc radius]; None: the fix carries
        no shared limb error (its bias states are not seen).
    """
    x = np.asarray(x, float)
    m = x[:3] - np.asarray(moon_position, float)
    n = x.size
    H = np.zeros((3, n))
    if bias_model == "none":
        H[:, :3] = np.eye(3)
        return m, H
    if bias_model == "additive":
        H[:, :3] = np.eye(3)
        H[:, 6:9] = np.eye(3)
        return m + x[6:9], H
    if bias_model == "range-scale":
        k = x[6]
        H[:, :3] = (1.0 + k) * np.eye(3)
        H[:, 6] = m
        return (1.0 + k) * m, H
    if bias_model == "range-scale+additive":
        k = x[6]
        H[:, :3] = (1.0 + k) * np.eye(3)
        H[:, 6] = m
        H[:, 7:10] = np.eye(3)
        return (1.0 + k) * m + x[7:10], H
    if bias_model == "limb-common":
        H[:, :3] = np.eye(3)
        if common_jacobian is None:
            return m, H
        G = np.asarray(common_jacobian, float)
        H[:, 6:9] = G
        return m + G @ x[6:9], H
    BIAS_MODELS.check(bias_model)  # an unknown name: UnknownNameError listing the known ones
    raise AssertionError(f"bias model {bias_model!r} has no measurement model")


@dataclass(frozen=True)
class UpdateInfo:
    """Outcome of one measurement update.

    Attributes
    ----------
    accepted : bool
    nis : float
        ``nu^T S^-1 nu`` [-].
    innovation : (3,) array
        ``z - h(x)`` [m].
    S : (3, 3) array
        Innovation covariance [m^2].
    forced : bool
        Accepted past the gate after too many rejections.
    """

    accepted: bool
    nis: float
    innovation: FloatArray
    S: FloatArray
    forced: bool = False


class NavigationEkf:
    """The EKF of the module docstring.

    Parameters
    ----------
    dynamics : Dynamics
        Propagator of the 6-state with its STM.
    moon : MoonEphemeris
        Moon state relative to the EMB.
    t0 : float
        Epoch of the initial state [TDB s past J2000].
    x0 : (6,) array
        Initial EMB-centred J2000 position [m] and velocity [m/s].
    P0 : (6, 6) array
        Its covariance [m^2, m^2/s, m^2/s^2].
    options : SIView, optional
        The SI view of a :class:`FilterConfig` (bias model, noise, gate); default its
        defaults.
    priors : EkfPriors, optional
        The resolved covariances (limb-common bias states, considered parameters).
    bias0 : (n_bias,) array, optional
        Initial bias estimate (default zero; its covariance is the steady state).
    """

    def __init__(self, dynamics: Dynamics, moon: MoonEphemeris, t0: float, x0: ArrayLike,
                 P0: ArrayLike, *, options: SIView | None = None,
                 priors: EkfPriors | None = None, bias0: ArrayLike | None = None) -> None:
        self.options = opt = options if options is not None else _DEFAULT
        self.priors = priors = priors if priors is not None else EkfPriors()
        x0 = np.asarray(x0, float)
        P0 = np.asarray(P0, float)
        if x0.shape != (6,) or not np.all(np.isfinite(x0)):
            raise ConfigError("filter.x0", x0, "a finite 6-state (m, m/s)")
        if P0.shape != (6, 6) or not np.all(np.isfinite(P0)):
            raise ConfigError("filter.P0", P0.shape, "a finite 6 x 6 covariance")
        try:
            np.linalg.cholesky(0.5 * (P0 + P0.T))
        except np.linalg.LinAlgError:
            raise ConfigError("filter.P0", "not positive definite",
                              "a positive-definite 6 x 6 covariance") from None
        # the knobs the steps read, once (an SI view's attribute is a dictionary look-up)
        self.bias_model: str = BIAS_MODELS.check(opt.bias_model)
        self.n_bias = nb = BIAS_MODELS[self.bias_model]
        self.n_consider = nc = priors.n_consider
        self._bias_cov = bias_covariance(opt, priors)
        self._accel_psd = float(opt.accel_psd)
        self._bias_tau = float(opt.bias_tau)
        self._max_rejections = int(opt.max_consecutive_rejections)
        self.dynamics = dynamics
        self.moon = moon
        self.t = float(t0)
        self.x = np.zeros(6 + nb + nc)
        self.x[:6] = x0
        if nb:
            self.x[6:6 + nb] = 0.0 if bias0 is None else np.asarray(bias0, float)
        self.P = np.zeros((6 + nb + nc, 6 + nb + nc))
        self.P[:6, :6] = 0.5 * (P0 + P0.T)
        if nb:
            self.P[6:6 + nb, 6:6 + nb] = self._bias_cov
        if nc:
            C = np.asarray(priors.consider_covariance, float)
            self.P[6 + nb:, 6 + nb:] = 0.5 * (C + C.T)
        self.rejections_in_a_row = 0
        self._gate = math.inf
        if opt.gate_probability is not None:
            # chi-square quantile of 3 dof (scipy.stats.chi2.ppf; the special function itself
            # costs 1/100 of the distribution object's call, and scipy.stats is a heavy import)
            self._gate = float(chdtri(3, 1.0 - opt.gate_probability))

    @property
    def n(self) -> int:
        """State dimension."""
        return int(self.x.size)

    def predict(self, t: float) -> None:
        """Propagate state and covariance to ``t`` [TDB s] (module step 2)."""
        t = float(t)
        dt = t - self.t
        if dt == 0.0:
            return
        x6, Phi = self.dynamics.propagate(self.t, self.x[:6], t)
        n, nb = self.n, self.n_bias
        F = np.zeros((n, n))
        F[:6, :6] = Phi
        # the considered parameters are constants (no process noise)
        F[6 + nb:, 6 + nb:] = np.eye(self.n_consider)
        Q = np.zeros((n, n))
        if self._accel_psd > 0:
            Q[:6, :6] = white_acceleration_q(dt, self._accel_psd)
        if nb:
            # every bias a first-order Gauss-Markov process of the same time constant:
            # Q = (1 - phi^2) times the steady-state covariance (exact)
            phi_b, q1 = gauss_markov_discrete(dt, 1.0, self._bias_tau)
            F[6:6 + nb, 6:6 + nb] = phi_b * np.eye(nb)
            Q[6:6 + nb, 6:6 + nb] = q1 * self._bias_cov
            self.x[6:6 + nb] *= phi_b
        self.x[:6] = x6
        P = F @ self.P @ F.T + Q
        self.P = 0.5 * (P + P.T)
        self.t = t

    def predicted_measurement(self, common_jacobian: ArrayLike | None = None
                              ) -> tuple[FloatArray, FloatArray]:
        """``h(x)`` [m] and ``H`` at the current epoch."""
        moon = self.moon.moon_state(self.t)
        return measurement_model(self.x, moon[:3], self.bias_model, common_jacobian)

    def update(self, z: ArrayLike, R: ArrayLike,
               common_jacobian: ArrayLike | None = None,
               consider_jacobian: ArrayLike | None = None) -> UpdateInfo:
        """Process a fix at the current epoch (module steps 3-5).

        Parameters
        ----------
        z : (3,) array
            Camera position relative to the Moon centre, inertial [m].
        R : (3, 3) array
            Its covariance [m^2] (with ``limb-common``: without the shared limb errors).
        common_jacobian : (3, 3) array, optional
            ``G`` of the ``limb-common`` model [m per unit of disc radius].
        consider_jacobian : (3, n_consider) array, optional
            ``J = d z / d theta`` of the considered parameters [m per unit] (module step 7);
            None: the fix does not depend on them (``R`` then carries their share).
        """
        z = np.asarray(z, float)
        R = np.asarray(R, float)
        h, H = self.predicted_measurement(common_jacobian)
        nc = self.n_consider
        if consider_jacobian is not None:
            J = np.asarray(consider_jacobian, float)
            if J.shape != (3, nc):
                raise ConfigError("consider_jacobian", J.shape,
                                  f"(3, {nc}): one column per considered parameter")
            H[:, self.n - nc:] = J
        nu = z - h
        S = H @ self.P @ H.T + R
        S = 0.5 * (S + S.T)
        nis = float(nu @ solve_vectors(S, nu))
        forced = False
        gate = self._gate
        if gate < math.inf:
            if nis > gate:
                if self.rejections_in_a_row < self._max_rejections:
                    self.rejections_in_a_row += 1
                    log.info("EKF: fix at t = %.1f s rejected (NIS %.1f > gate %.1f)", self.t,
                             nis, gate)
                    return UpdateInfo(False, nis, nu, S)
                forced = True
                log.warning("EKF: %d fixes rejected in a row; accepting the fix at t = %.1f s "
                            "(NIS %.1f)", self.rejections_in_a_row, self.t, nis)
        self.rejections_in_a_row = 0
        K = solve(S, H @ self.P).T
        if nc:
            # Schmidt: the considered parameters are never estimated (Joseph form below is
            # exact for this suboptimal gain)
            K[self.n - nc:] = 0.0
        self.x = self.x + K @ nu
        IKH = np.eye(self.n) - K @ H
        P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (P + P.T)
        return UpdateInfo(True, nis, nu, S, forced)
