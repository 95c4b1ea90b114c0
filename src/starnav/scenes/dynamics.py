"""Point-mass dynamics about the Earth-Moon barycentre, RK4 propagation and the STM.

The force model of the navigation filter and, unless ``trajectory.forces`` adds planets, solar
radiation pressure or J2 (:mod:`starnav.scenes.forces`), of the truth trajectory: Earth, Moon
and Sun point masses in EMB-centred J2000 axes (SI, TDB seconds past J2000) with the
barycentre's indirect term (``emb_indirect``: ``barycentric``, exact, or ``sun-at-emb``).
Propagation is fixed-step RK4 with the ephemeris evaluated at every stage in one call, and the
STM integrated with the same stages. The equations and the Jacobian: docs/methods.md,
"starnav.scenes.dynamics".

References
----------
O. Montenbruck, E. Gill (2000), *Satellite Orbits*, Springer, ss. 3.2 (point masses and
indirect terms) and 7.2 (variational equations).

Index
-----
:class:`PointMassModel`, :func:`propagate`, :func:`propagate_many`, :func:`rk4_grid`,
:func:`rk4_stm`, :func:`step_grid`, :data:`DEFAULT_STEP`.
"""

from __future__ import annotations

import logging
import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from starnav.errors import ConfigError
from starnav.scenes.ephemeris import Ephemeris
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Default RK4 step [s] (docs/facts.md s4: mm-accurate over a halo period).
DEFAULT_STEP = 300.0

_INDIRECT = ("barycentric", "sun-at-emb")


class PointMassModel:
    """Earth, Moon and Sun point masses about the Earth-Moon barycentre (module docstring).

    Parameters
    ----------
    ephemeris : Ephemeris, optional
        Source of the body positions and default GMs; default the shared DE421 instance.
    gm_earth, gm_moon, gm_sun : float, optional
        Gravitational parameters [m^3/s^2]; default the ephemeris values.
    emb_indirect : {"barycentric", "sun-at-emb"}
        Inertial acceleration of the EMB subtracted from every body's pull: exact mass-weighted
        Sun pull on Earth and Moon, or the docs/facts.md s4 approximation ``GM_S r_S/|r_S|^3``.

    Notes
    -----
    Positions ``r`` are EMB-centred along ICRF axes [m]; epochs ``t`` are TDB s past J2000.
    """

    def __init__(self, ephemeris: Ephemeris | None = None, *, gm_earth: float | None = None,
                 gm_moon: float | None = None, gm_sun: float | None = None,
                 emb_indirect: Literal["barycentric", "sun-at-emb"] = "barycentric") -> None:
        self.ephemeris = ephemeris if ephemeris is not None else Ephemeris.default()
        e = self.ephemeris
        self.gm_earth = float(e.gm_earth if gm_earth is None else gm_earth)
        self.gm_moon = float(e.gm_moon if gm_moon is None else gm_moon)
        self.gm_sun = float(e.gm_sun if gm_sun is None else gm_sun)
        for name in ("gm_earth", "gm_moon", "gm_sun"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(name, v, "a finite gravitational parameter > 0 m^3/s^2")
        if emb_indirect not in _INDIRECT:
            raise ConfigError("emb_indirect", emb_indirect, f"one of {', '.join(_INDIRECT)}")
        self.emb_indirect = emb_indirect
        #: Moon's share of the Earth-Moon mass, ``1 / (1 + EMRAT)`` [-].
        self.moon_fraction = 1.0 / (1.0 + e.emrat)
        self._gm = np.array([self.gm_earth, self.gm_moon, self.gm_sun])

    def __repr__(self) -> str:
        return (f"PointMassModel({self.ephemeris.name}, gm_earth={self.gm_earth:.6e}, "
                f"gm_moon={self.gm_moon:.6e}, gm_sun={self.gm_sun:.6e}, "
                f"emb_indirect={self.emb_indirect!r})")

    @property
    def gm(self) -> FloatArray:
        """``(GM_E, GM_M, GM_S)`` [m^3/s^2]."""
        return self._gm.copy()

    def key(self) -> dict[str, object]:
        """Everything that defines the force model (for cache keys and metadata)."""
        return {"ephemeris": self.ephemeris.name, "gm_earth": self.gm_earth,
                "gm_moon": self.gm_moon, "gm_sun": self.gm_sun,
                "emb_indirect": self.emb_indirect, "emrat": self.ephemeris.emrat}

    # ------------------------------------------------------------------ environment
    def body_positions(self, t: ArrayLike) -> FloatArray:
        """EMB-centred Earth, Moon, Sun positions [m], shape ``(..., 3, 3)`` (body, xyz)."""
        return self.ephemeris.positions_emb(t)

    def frame_acceleration_from(self, bodies: FloatArray) -> FloatArray:
        """Inertial acceleration of the EMB [m/s^2] ``(..., 3)`` from body positions."""
        rE, rM, rS = bodies[..., 0, :], bodies[..., 1, :], bodies[..., 2, :]
        if self.emb_indirect == "sun-at-emb":
            return self.gm_sun * rS / _norm3(rS)
        f = self.moon_fraction
        dE, dM = rE - rS, rM - rS
        return -self.gm_sun * ((1.0 - f) * dE / _norm3(dE) + f * dM / _norm3(dM))

    def frame_acceleration(self, t: ArrayLike) -> FloatArray:
        """Inertial acceleration of the EMB at epochs ``t`` [m/s^2], shape ``(..., 3)``."""
        return self.frame_acceleration_from(self.body_positions(t))

    def environment(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Body positions ``(..., 3, 3)`` [m] and EMB acceleration ``(..., 3)`` [m/s^2]."""
        b = self.body_positions(t)
        return b, self.frame_acceleration_from(b)

    # ------------------------------------------------------------------ kernels
    def _accel(self, r: FloatArray, bodies: FloatArray, a_frame: FloatArray) -> FloatArray:
        d = r[..., None, :] - bodies  # (..., 3 bodies, 3)
        n2 = np.einsum("...bk,...bk->...b", d, d)
        w = self._gm / (n2 * np.sqrt(n2))
        return -np.einsum("...b,...bk->...k", w, d) - a_frame

    def _accel_jac(self, r: FloatArray, bodies: FloatArray,
                   a_frame: FloatArray) -> tuple[FloatArray, FloatArray]:
        d = r[..., None, :] - bodies
        n2 = np.einsum("...bk,...bk->...b", d, d)
        w = self._gm / (n2 * np.sqrt(n2))
        a = -np.einsum("...b,...bk->...k", w, d) - a_frame
        J = 3.0 * np.einsum("...b,...bi,...bj->...ij", w / n2, d, d)
        J = J - w.sum(-1)[..., None, None] * np.eye(3)
        return a, J

    # ------------------------------------------------------------------ public API
    def acceleration(self, t: float, r: ArrayLike) -> FloatArray:
        """Acceleration of a spacecraft at EMB-centred ``r`` [m] at epoch ``t`` [TDB s].

        Returns
        -------
        (3,) array
            ``r''`` in the EMB-centred non-rotating frame [m/s^2].
        """
        b, af = self.environment(float(t))
        return self._accel(np.asarray(r, dtype=float), b, af)

    def jacobian(self, t: float, r: ArrayLike) -> FloatArray:
        """Analytic ``d r'' / d r`` [1/s^2], shape ``(3, 3)``, at ``r`` [m] and ``t`` [TDB s]."""
        b, af = self.environment(float(t))
        return self._accel_jac(np.asarray(r, dtype=float), b, af)[1]

    def derivative(self, t: float, x: ArrayLike) -> FloatArray:
        """Time derivative of the state ``x = (r [m], v [m/s])``: ``(v, r'')``, shape ``(6,)``.

        Suitable as the right-hand side of :func:`scipy.integrate.solve_ivp`.
        """
        x = np.asarray(x, dtype=float)
        return np.concatenate([x[3:6], self.acceleration(t, x[:3])])

    def derivative_with_stm(self, t: float, y: ArrayLike) -> FloatArray:
        """Right-hand side for the state plus the row-major 6x6 STM (42 values)."""
        y = np.asarray(y, dtype=float)
        b, af = self.environment(float(t))
        a, J = self._accel_jac(y[:3], b, af)
        P = y[6:].reshape(6, 6)
        dP = np.concatenate([P[3:], J @ P[:3]])
        return np.concatenate([y[3:6], a, dP.ravel()])


def _norm3(v: FloatArray) -> FloatArray:
    n2 = np.einsum("...k,...k->...", v, v)[..., None]
    return n2 * np.sqrt(n2)


# --------------------------------------------------------------------------- RK4 core
def rk4_grid(model: PointMassModel, tgrid: ArrayLike, x0: ArrayLike, with_stm: bool = False,
             keep: ArrayLike | None = None) -> tuple[FloatArray, FloatArray | None]:
    """RK4 over given grids of epochs, for one or many trajectories at once.

    Parameters
    ----------
    model : PointMassModel
    tgrid : (n + 1,) or (m, n + 1) array
        Epochs [TDB s] of the nodes of each trajectory (any monotonic spacing; a step is taken
        between consecutive nodes). With a 2-D grid, ``m`` trajectories advance together.
    x0 : (6,) or (m, 6) array
        States at ``tgrid[..., 0]`` [m, m/s].
    with_stm : bool
        Also integrate the 6x6 state transition matrix from ``tgrid[..., 0]``.
    keep : int array, optional
        Node indices at which to return the state (default: the last node only).

    Returns
    -------
    X : (..., k, 6) array
        States at the kept nodes (``k = len(keep)``; the node axis is dropped when ``keep`` is
        None).
    Phi : (..., k, 6, 6) array or None
        STMs from the first node to the kept nodes.
    """
    tg = np.asarray(tgrid, dtype=float)
    single = tg.ndim == 1
    tg = np.atleast_2d(tg)
    X = np.array(x0, dtype=float).reshape(-1, 6)
    m, n1 = tg.shape
    if X.shape[0] != m:
        raise ConfigError("x0", X.shape, f"{m} states of 6 values, one per grid")
    nsteps = n1 - 1
    keep_idx = np.array([nsteps]) if keep is None else np.asarray(keep, dtype=int)
    h = np.diff(tg, axis=1)  # (m, n)
    stage_t = np.empty((m, 2 * nsteps + 1))
    stage_t[:, 0::2] = tg
    stage_t[:, 1::2] = tg[:, :-1] + 0.5 * h
    B, AF = model.environment(stage_t)  # (m, 2n+1, 3, 3), (m, 2n+1, 3)

    out_x = np.empty((m, keep_idx.size, 6))
    out_p = np.empty((m, keep_idx.size, 6, 6)) if with_stm else None
    want = {int(k): j for j, k in enumerate(keep_idx)}

    r, v = X[:, :3].copy(), X[:, 3:].copy()
    if with_stm:
        Pr = np.zeros((m, 3, 6))
        Pv = np.zeros((m, 3, 6))
        Pr[:, :, :3] = np.eye(3)
        Pv[:, :, 3:] = np.eye(3)

    def store(k: int) -> None:
        j = want.get(k)
        if j is None:
            return
        out_x[:, j, :3], out_x[:, j, 3:] = r, v
        if with_stm:
            out_p[:, j, :3], out_p[:, j, 3:] = Pr, Pv

    store(0)
    acc = model._accel
    jac = model._accel_jac
    for i in range(nsteps):
        hh = h[:, i, None]
        b0, bh, b1 = B[:, 2 * i], B[:, 2 * i + 1], B[:, 2 * i + 2]
        f0, fh, f1 = AF[:, 2 * i], AF[:, 2 * i + 1], AF[:, 2 * i + 2]
        if not with_stm:
            k1r, k1v = v, acc(r, b0, f0)
            k2r = v + 0.5 * hh * k1v
            k2v = acc(r + 0.5 * hh * k1r, bh, fh)
            k3r = v + 0.5 * hh * k2v
            k3v = acc(r + 0.5 * hh * k2r, bh, fh)
            k4r = v + hh * k3v
            k4v = acc(r + hh * k3r, b1, f1)
            r = r + hh / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r)
            v = v + hh / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        else:
            h3 = hh[..., None]
            k1v, J1 = jac(r, b0, f0)
            k1r, k1Pr, k1Pv = v, Pv, J1 @ Pr
            k2v, J2 = jac(r + 0.5 * hh * k1r, bh, fh)
            k2r = v + 0.5 * hh * k1v
            k2Pr = Pv + 0.5 * h3 * k1Pv
            k2Pv = J2 @ (Pr + 0.5 * h3 * k1Pr)
            k3v, J3 = jac(r + 0.5 * hh * k2r, bh, fh)
            k3r = v + 0.5 * hh * k2v
            k3Pr = Pv + 0.5 * h3 * k2Pv
            k3Pv = J3 @ (Pr + 0.5 * h3 * k2Pr)
            k4v, J4 = jac(r + hh * k3r, b1, f1)
            k4r = v + hh * k3v
            k4Pr = Pv + h3 * k3Pv
            k4Pv = J4 @ (Pr + h3 * k3Pr)
            r = r + hh / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r)
            v = v + hh / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
            Pr = Pr + h3 / 6.0 * (k1Pr + 2.0 * k2Pr + 2.0 * k3Pr + k4Pr)
            Pv = Pv + h3 / 6.0 * (k1Pv + 2.0 * k2Pv + 2.0 * k3Pv + k4Pv)
        store(i + 1)

    if keep is None:
        out_x = out_x[:, 0]
        out_p = out_p[:, 0] if out_p is not None else None
    if single:
        out_x = out_x[0]
        out_p = out_p[0] if out_p is not None else None
    return out_x, out_p


def rk4_stm(model: PointMassModel, tgrid: ArrayLike, x0: ArrayLike
            ) -> tuple[FloatArray, FloatArray]:
    """:func:`rk4_grid` with the STM for one trajectory of the point-mass model itself: the
    same stages and operations on plain ``(3,)`` and ``(3, 6)`` arrays (a filter's step:
    its per-call cost is NumPy's, so batch axes and ``einsum`` parsing are left out).

    Parameters
    ----------
    model : PointMassModel
        Exactly this class (a subclass's forces are not these).
    tgrid : (n + 1,) array
        Epochs [TDB s] of the nodes.
    x0 : (6,) array
        State at ``tgrid[0]`` [m, m/s].

    Returns
    -------
    x1 : (6,) array
        State at ``tgrid[-1]`` [m, m/s].
    Phi : (6, 6) array
        STM from the first node to the last.
    """
    if type(model) is not PointMassModel:
        raise ConfigError("model", type(model).__name__, "a PointMassModel (not a subclass)")
    tg = np.asarray(tgrid, dtype=float)
    nsteps = tg.size - 1
    stage_t = np.empty(2 * nsteps + 1)
    stage_t[0::2] = tg
    h = np.diff(tg)
    stage_t[1::2] = tg[:-1] + 0.5 * h
    B, AF = model.environment(stage_t)   # (2n+1, 3, 3), (2n+1, 3)
    gm = model._gm
    eye3 = np.eye(3)

    def jac(r: FloatArray, b: FloatArray, af: FloatArray) -> tuple[FloatArray, FloatArray]:
        d = r - b                          # (3 bodies, 3)
        n2 = (d * d).sum(axis=1)
        w = gm / (n2 * np.sqrt(n2))
        a = -(w @ d) - af
        J = (3.0 * (w / n2)[:, None] * d).T @ d
        J -= w.sum() * eye3
        return a, J

    x0 = np.asarray(x0, dtype=float)
    r, v = x0[:3].copy(), x0[3:].copy()
    Pr = np.zeros((3, 6))
    Pv = np.zeros((3, 6))
    Pr[:, :3] = eye3
    Pv[:, 3:] = eye3
    for i, hh in enumerate(h.tolist()):
        b0, bh, b1 = B[2 * i], B[2 * i + 1], B[2 * i + 2]
        f0, fh, f1 = AF[2 * i], AF[2 * i + 1], AF[2 * i + 2]
        h2 = 0.5 * hh
        k1v, J1 = jac(r, b0, f0)
        k1Pv = J1 @ Pr
        k2v, J2 = jac(r + h2 * v, bh, fh)
        k2r = v + h2 * k1v
        k2Pr = Pv + h2 * k1Pv
        k2Pv = J2 @ (Pr + h2 * Pv)
        k3v, J3 = jac(r + h2 * k2r, bh, fh)
        k3r = v + h2 * k2v
        k3Pr = Pv + h2 * k2Pv
        k3Pv = J3 @ (Pr + h2 * k2Pr)
        k4v, J4 = jac(r + hh * k3r, b1, f1)
        k4r = v + hh * k3v
        k4Pr = Pv + hh * k3Pv
        k4Pv = J4 @ (Pr + hh * k3Pr)
        h6 = hh / 6.0
        r = r + h6 * (v + 2.0 * k2r + 2.0 * k3r + k4r)
        v = v + h6 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        Pr = Pr + h6 * (Pv + 2.0 * k2Pr + 2.0 * k3Pr + k4Pr)
        Pv = Pv + h6 * (k1Pv + 2.0 * k2Pv + 2.0 * k3Pv + k4Pv)
    return np.concatenate([r, v]), np.concatenate([Pr, Pv])


def step_grid(t0: float, t1: float, step: float = DEFAULT_STEP) -> FloatArray:
    """Epochs from ``t0`` to ``t1`` [s] in ``ceil(|t1 - t0| / step)`` equal steps (both ends
    included; ``step`` is used exactly when it divides the interval)."""
    if not (math.isfinite(step) and step > 0):
        raise ConfigError("step", step, "a finite RK4 step > 0 s")
    span = float(t1) - float(t0)
    n = max(1, math.ceil(abs(span) / step - 1e-9))
    g = float(t0) + span * (np.arange(n + 1) / n)
    g[-1] = float(t1)
    return g


def propagate(model: PointMassModel, t0: float, x0: ArrayLike, t1: float,
              step: float = DEFAULT_STEP,
              with_stm: bool = False) -> tuple[FloatArray, FloatArray | None]:
    """Propagate a state from ``t0`` to ``t1`` with fixed-step RK4.

    Parameters
    ----------
    model : PointMassModel
    t0, t1 : float
        Start and end epochs [TDB s past J2000]; ``t1 < t0`` propagates backwards.
    x0 : (6,) array
        EMB-centred J2000 state at ``t0``: position [m], velocity [m/s].
    step : float
        Nominal RK4 step [s]; the interval is split into equal steps no longer than this.
    with_stm : bool
        Also return the 6x6 state transition matrix ``d x1 / d x0``.

    Returns
    -------
    x1 : (6,) array
        State at ``t1`` [m, m/s].
    Phi : (6, 6) array or None
        STM (None unless ``with_stm``).
    """
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (6,) or not np.all(np.isfinite(x0)):
        raise ConfigError("x0", x0, "a finite 6-state (m, m/s)")
    if float(t1) == float(t0):
        return x0.copy(), (np.eye(6) if with_stm else None)
    return rk4_grid(model, step_grid(t0, t1, step), x0, with_stm=with_stm)


def propagate_many(model: PointMassModel, t0: float, x0: ArrayLike, times: ArrayLike,
                   step: float = DEFAULT_STEP,
                   with_stm: bool = False) -> tuple[FloatArray, FloatArray | None]:
    """Propagate a state from ``t0`` and sample it at ``times``.

    Each interval between consecutive sample epochs is split into equal RK4 steps no longer
    than ``step``, so the samples fall on integration nodes (no interpolation).

    Parameters
    ----------
    model : PointMassModel
    t0 : float
        Epoch of ``x0`` [TDB s past J2000].
    x0 : (6,) array
        State at ``t0`` [m, m/s].
    times : (k,) array
        Sample epochs [TDB s], monotonic and all on the same side of ``t0`` (``t0`` itself may
        be included).
    step : float
        Nominal RK4 step [s].
    with_stm : bool
        Also return the STMs from ``t0`` to each sample.

    Returns
    -------
    X : (k, 6) array
        States at ``times`` [m, m/s].
    Phi : (k, 6, 6) array or None
    """
    x0 = np.asarray(x0, dtype=float)
    ts = np.asarray(times, dtype=float).ravel()
    if ts.size == 0:
        return np.empty((0, 6)), (np.empty((0, 6, 6)) if with_stm else None)
    d = np.diff(np.concatenate([[float(t0)], ts]))
    if not (np.all(d >= 0) or np.all(d <= 0)):
        raise ConfigError("times", "not monotonic from t0",
                          "sample epochs sorted away from t0 (all after it or all before it)")
    nodes = [np.array([float(t0)])]
    keep = []
    count = 0
    prev = float(t0)
    for t in ts:
        if t != prev:
            g = step_grid(prev, t, step)[1:]
            nodes.append(g)
            count += g.size
        keep.append(count)
        prev = t
    grid = np.concatenate(nodes)
    if grid.size == 1:  # every sample at t0
        X = np.repeat(x0[None], ts.size, 0)
        return X, (np.repeat(np.eye(6)[None], ts.size, 0) if with_stm else None)
    return rk4_grid(model, grid, x0, with_stm=with_stm, keep=np.array(keep))
