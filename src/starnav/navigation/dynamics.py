"""What the navigation filter needs from the dynamics and the ephemeris, as two small protocols.

The filter (:mod:`starnav.navigation.ekf`) only needs

* a :class:`Dynamics`: ``propagate(t0, x0, t1) -> (x1, Phi)`` for the 6-state (EMB-centred
  J2000 position [m] and velocity [m/s]) and its 6x6 state transition matrix, and
* a :class:`MoonEphemeris`: ``moon_state(t) -> (6,)``, the Moon relative to the EMB, to turn a
  Moon-relative position fix into a measurement of the EMB-centred state.

:class:`PointMassDynamics` provides both from :mod:`starnav.scenes.dynamics` (Earth, Moon and
Sun point masses from DE421 with the Sun's indirect term; RK4 with the variational equations),
the model the truth trajectory is integrated with. Any other object with these methods (a
two-body model in tests, a higher-fidelity propagator) can be used instead.

Example
-------
>>> from starnav.navigation.dynamics import PointMassDynamics
>>> dyn = PointMassDynamics(step_s=300.0)                               # doctest: +SKIP
>>> x1, Phi = dyn.propagate(t0, x0, t0 + 300.0)                         # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from starnav.scenes.dynamics import PointMassModel, propagate, rk4_stm, step_grid
from starnav.typing import FloatArray


@runtime_checkable
class Dynamics(Protocol):
    """Propagator of the 6-state with its STM."""

    def propagate(self, t0: float, x0: ArrayLike, t1: float) -> tuple[FloatArray, FloatArray]:
        """State at ``t1`` [m, m/s] and ``d x1 / d x0`` (6 x 6), from ``x0`` at ``t0`` [TDB s]."""
        ...


@runtime_checkable
class MoonEphemeris(Protocol):
    """Moon state relative to the navigation origin (the EMB), J2000 axes."""

    def moon_state(self, t: float) -> FloatArray:
        """Moon position [m] and velocity [m/s] relative to the EMB at ``t`` [TDB s], (6,)."""
        ...


class PointMassDynamics:
    """Adapter of :mod:`starnav.scenes.dynamics` to :class:`Dynamics` and :class:`MoonEphemeris`.

    Parameters
    ----------
    model : starnav.scenes.dynamics.PointMassModel, optional
        Force model; default Earth, Moon and Sun from the shared DE421 ephemeris.
    step_s : float
        RK4 step [s] (the interval is split into equal steps no longer than this).
    """

    def __init__(self, model: Any | None = None, step_s: float = 300.0) -> None:
        self.model = model if model is not None else PointMassModel()
        self.step_s = float(step_s)

    def propagate(self, t0: float, x0: ArrayLike, t1: float) -> tuple[FloatArray, FloatArray]:
        if type(self.model) is PointMassModel and float(t1) != float(t0):
            x = np.asarray(x0, float)
            if x.shape == (6,) and np.isfinite(x).all():
                # the point masses themselves: the single-trajectory kernel (a filter step)
                return rk4_stm(self.model, step_grid(t0, t1, self.step_s), x)
        x1, Phi = propagate(self.model, float(t0), np.asarray(x0, float), float(t1),
                            step=self.step_s, with_stm=True)
        assert Phi is not None
        return x1, Phi

    def moon_state(self, t: float) -> FloatArray:
        return np.asarray(self.model.ephemeris.state("moon", float(t), center="emb"), float)

    def __repr__(self) -> str:
        return f"PointMassDynamics({self.model!r}, step_s={self.step_s})"
