"""The attitude between star solutions: the last solution carried forward by a rate gyro.

1. Truth: between two frames the spacecraft turns by ``dR = R_0^T R_1`` (camera axes of frame
   0); the gyro measures it with an error.
2. Error model (:class:`GyroModel`, per axis): ``g = b dt + w(dt)``, ``b`` a constant rate bias
   of 1-sigma ``sigma_b`` per run, ``w`` an angle random walk ``E[w w^T] = N^2 dt I``:
   ``Q(dt) = (N^2 dt + sigma_b^2 dt^2) I`` (Farrenkopf 1978, the bias unfiltered).
3. Propagation (:func:`propagate`): ``P_1 = dR^T P_0 dR + Q(dt)`` in the camera axes of frame 1.

The defaults (``navigation.attitude``: 0.005 deg/sqrt(h), 0.01 deg/h) are of the order of a
space fibre-optic gyro, an assumption, not a data sheet.

References
----------
R. L. Farrenkopf, "Analytic steady-state accuracy solutions for two common spacecraft
attitude estimators", J. Guid. Control 1 (1978) 282-284.

Index
-----
:func:`propagate`, :class:`GyroModel`, :class:`GyroErrors`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from starnav.errors import ConfigError
from starnav.typing import FloatArray


@dataclass(frozen=True)
class GyroModel:
    """Rate-gyro error model (module step 2).

    Attributes
    ----------
    arw_rad_rt_s : float
        Angle random walk ``N`` [rad/sqrt(s)].
    bias_sigma_rad_s : float
        1-sigma of the constant rate bias ``sigma_b`` [rad/s].
    """

    arw_rad_rt_s: float = 0.005 * math.pi / 180.0 / 60.0
    bias_sigma_rad_s: float = 0.01 * math.pi / 180.0 / 3600.0

    def __post_init__(self) -> None:
        for name, v in (("gyro_arw", self.arw_rad_rt_s), ("gyro_bias", self.bias_sigma_rad_s)):
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"navigation.attitude.{name}", v, "a finite value >= 0")

    def variance(self, dt: float) -> float:
        """Per-axis variance of the integrated angle error after ``dt`` [s]: ``N^2 dt +
        sigma_b^2 dt^2`` [rad^2] (module step 2)."""
        if not dt >= 0:
            raise ConfigError("dt", dt, ">= 0 s (propagation forwards in time)")
        return self.arw_rad_rt_s**2 * dt + (self.bias_sigma_rad_s * dt) ** 2


class GyroErrors:
    """One run's gyro error realisation: a constant bias drawn once, the angle random walk
    accumulated since the last star solution (:meth:`reset`).

    Parameters
    ----------
    model : GyroModel
    rng : numpy.random.Generator
        The run's stream (bias first, then every random-walk increment in order).
    """

    def __init__(self, model: GyroModel, rng: np.random.Generator) -> None:
        self.model = model
        self.rng = rng
        self.bias = model.bias_sigma_rad_s * rng.standard_normal(3)
        self.walk = np.zeros(3)
        self.t_anchor: float | None = None
        self.t_last: float | None = None

    def reset(self, t: float) -> None:
        """A star solution at ``t`` [s]: the integration restarts from it."""
        self.walk = np.zeros(3)
        self.t_anchor = self.t_last = float(t)

    def error(self, t: float) -> FloatArray:
        """Integrated angle error ``g`` [rad] at ``t`` [s] since the anchor (module step 2)."""
        if self.t_anchor is None or self.t_last is None:
            raise ConfigError("gyro", None, "a star solution to propagate from (reset first)")
        dt = float(t) - self.t_last
        if dt < 0:
            raise ConfigError("t", t, f">= the last propagation epoch {self.t_last}")
        self.walk = self.walk + self.model.arw_rad_rt_s * math.sqrt(dt) * \
            self.rng.standard_normal(3)
        self.t_last = float(t)
        return self.bias * (float(t) - self.t_anchor) + self.walk


def propagate(R_est0: ArrayLike, P0: ArrayLike, R_true0: ArrayLike, R_true1: ArrayLike,
              dt: float, model: GyroModel, g: ArrayLike | None = None
              ) -> tuple[FloatArray, FloatArray]:
    """Carry a solution from frame 0 to frame 1 through the gyro (module step 3).

    Parameters
    ----------
    R_est0 : (3, 3) array
        Estimated camera -> inertial attitude at frame 0.
    P0 : (3, 3) array
        Its error covariance, camera axes [rad^2].
    R_true0, R_true1 : (3, 3) arrays
        True attitudes of the two frames (their relative turn is what the gyro measures).
    dt : float
        Time since the solution [s] (the gyro error's age, :meth:`GyroModel.variance`).
    model : GyroModel
    g : (3,) array, optional
        The gyro's integrated error [rad] (:meth:`GyroErrors.error`); default none (the
        covariance alone).

    Returns
    -------
    R_est1 : (3, 3) array
    P1 : (3, 3) array
        ``dR^T P0 dR + Q(dt)`` [rad^2], camera axes of frame 1.
    """
    dR = np.asarray(R_true0, float).T @ np.asarray(R_true1, float)
    ge = np.zeros(3) if g is None else np.asarray(g, float)
    R1 = np.asarray(R_est0, float) @ dR @ Rotation.from_rotvec(-ge).as_matrix()
    P1 = dR.T @ np.asarray(P0, float) @ dR + model.variance(dt) * np.eye(3)
    return R1, 0.5 * (P1 + P1.T)
