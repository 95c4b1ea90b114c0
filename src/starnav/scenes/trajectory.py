r"""The LUMIO-like truth trajectory: a CR3BP L2 halo carried into the ephemeris model.

Each step in full: docs/methods.md, "starnav.scenes.trajectory".

Technique
---------
1. CR3BP southern L2 halo by differential correction (:mod:`starnav.scenes.cr3bp`).
2. Patch points: the halo mapped to EMB-centred J2000 with DE421's instantaneous Earth-Moon
   geometry (pulsating rotating frame, :func:`rotating_to_emb`).
3. Multiple shooting in the point-mass ephemeris model (:mod:`starnav.scenes.dynamics`):
   minimum-norm Newton updates on the continuity defects (:func:`multiple_shooting`).
4. The arc: each segment propagated from its converged patch state; it must stay within
   ``[range_min, range_max]`` of the Moon.
5. Cache: the arc stored as ``.npz`` in the user cache, keyed by a hash of every input.

The knobs are :class:`ShootingOptions`.

References
----------
K. C. Howell, H. J. Pernicka (1988), *Numerical determination of Lissajous trajectories in the
restricted three-body problem*, Celestial Mechanics 41, 107-124.
T. A. Pavlak (2013), *Trajectory design and orbit maintenance strategies in multi-body
dynamical regimes*, PhD thesis, Purdue University, ch. 3.

Index
-----
:func:`ephemeris_halo_arc`, :class:`Trajectory`, :func:`halo_patch_guess`,
:func:`multiple_shooting`, :class:`ShootingResult`, :class:`ShootingOptions`,
:func:`rotating_frame`, :func:`rotating_to_emb`, :func:`emb_to_rotating`, :func:`load_cached_arc`,
:func:`default_cache_dir`.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import os
import time
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.atomic import atomic_write_bytes
from starnav.constants import DAY
from starnav.errors import ConfigError, DataFileError
from starnav.scenes.cr3bp import LU, REFERENCE_HALO, TU, ConvergenceError, HaloOrbit, l2_halo
from starnav.scenes.dynamics import PointMassModel, rk4_grid
from starnav.scenes.ephemeris import Ephemeris
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Bump when the algorithm changes so that cached arcs are recomputed.
ALGORITHM_VERSION = 1
#: Velocity unit of the CR3BP scaling [m/s].
VU = LU / TU


# --------------------------------------------------------------------------- trajectory
@dataclass(frozen=True)
class Trajectory:
    """States of a spacecraft on a grid of epochs.

    Parameters
    ----------
    times : (n,) array
        Epochs [TDB s past J2000], strictly increasing.
    states : (n, 6) array
        EMB-centred ICRF/J2000 position [m] and velocity [m/s].
    object_name : str
        Name written to OEM files.
    meta : dict
        Provenance (source, force model, shooting statistics).
    """

    times: FloatArray
    states: FloatArray
    object_name: str = "LUMIO-LIKE"
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=float).ravel()
        x = np.asarray(self.states, dtype=float)
        if x.shape != (t.size, 6):
            raise ConfigError("trajectory.states", x.shape, f"shape ({t.size}, 6)")
        if t.size < 2 or np.any(np.diff(t) <= 0):
            raise ConfigError("trajectory.times", f"{t.size} epochs",
                              "at least 2 strictly increasing epochs")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
            raise ConfigError("trajectory", "non-finite values", "finite epochs and states")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "states", x)

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def t_start(self) -> float:
        """First epoch [TDB s]."""
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        """Last epoch [TDB s]."""
        return float(self.times[-1])

    @property
    def duration(self) -> float:
        """Covered span [s]."""
        return self.t_end - self.t_start

    def sample(self, times: ArrayLike) -> FloatArray:
        """States ``(k, 6)`` at ``times`` [TDB s] by cubic Hermite interpolation of the nodes
        (exact at the nodes).

        Raises
        ------
        ConfigError
            For epochs outside ``[t_start, t_end]``.
        """
        ts = np.asarray(times, dtype=float)
        flat = ts.ravel()
        eps = 1e-6
        if flat.size and (flat.min() < self.t_start - eps or flat.max() > self.t_end + eps):
            raise ConfigError("epoch", f"{flat.min():.3f}..{flat.max():.3f} s TDB",
                              f"epochs within the trajectory span {self.t_start:.3f}.."
                              f"{self.t_end:.3f} s TDB")
        flat = np.clip(flat, self.t_start, self.t_end)
        i = np.clip(np.searchsorted(self.times, flat, side="right") - 1, 0, self.times.size - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        h = (t1 - t0)[:, None]
        s = ((flat - t0) / (t1 - t0))[:, None]
        p0, v0 = self.states[i, :3], self.states[i, 3:]
        p1, v1 = self.states[i + 1, :3], self.states[i + 1, 3:]
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        pos = h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1
        d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
        vel = (d00 * p0 + d01 * p1) / h + d10 * v0 + d11 * v1
        out = np.concatenate([pos, vel], axis=1)
        exact = (flat == t0)
        out[exact] = self.states[i[exact]]
        exact1 = (flat == t1)
        out[exact1] = self.states[i[exact1] + 1]
        return out.reshape(ts.shape + (6,))

    def epochs_at_cadence(self, cadence: float, start: float | None = None,
                          count: int | None = None) -> FloatArray:
        """Epochs ``start + k cadence`` [TDB s] inside the span (``count`` of them at most)."""
        if not (math.isfinite(cadence) and cadence > 0):
            raise ConfigError("cadence_s", cadence, "a finite cadence > 0 s")
        t0 = self.t_start if start is None else float(start)
        n = int(math.floor((self.t_end - t0) / cadence + 1e-9)) + 1
        if n < 1:
            raise ConfigError("start", t0, f"an epoch within the span ending {self.t_end}")
        if count is not None:
            n = min(n, int(count))
        return t0 + cadence * np.arange(n)

    def resample(self, cadence: float = 300.0) -> Trajectory:
        """The same trajectory on a regular grid of ``cadence`` [s] from ``t_start``."""
        ts = self.epochs_at_cadence(cadence)
        return Trajectory(ts, self.sample(ts), self.object_name, dict(self.meta))

    def clipped(self, t0: float, t1: float) -> Trajectory:
        """The same trajectory on ``[t0, t1]`` [TDB s]: its nodes inside, plus the two ends
        sampled exactly (what an OEM resampled over that span covers, at full resolution)."""
        if not (self.t_start - 1e-6 <= t0 < t1 <= self.t_end + 1e-6):
            raise ConfigError("span", f"{t0!r}..{t1!r} s TDB",
                              f"a span inside {self.t_start!r}..{self.t_end!r} s TDB")
        inside = self.times[(self.times > t0) & (self.times < t1)]
        ts = np.concatenate([[t0], inside, [t1]])
        return Trajectory(ts, self.sample(ts), self.object_name, dict(self.meta))

    def moon_range(self, ephemeris: Ephemeris | None = None) -> FloatArray:
        """Distance to the Moon centre at the nodes [m]."""
        eph = ephemeris or Ephemeris.default()
        moon = eph.state("moon", self.times, center="emb")
        return np.linalg.norm(self.states[:, :3] - moon[:, :3], axis=1)


# --------------------------------------------------------------------------- frames
def rotating_frame(ephemeris: Ephemeris, t: ArrayLike,
                   dt: float = 60.0) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                              FloatArray]:
    """Instantaneous Earth-Moon rotating frame at epochs ``t`` [TDB s].

    Returns
    -------
    C : (..., 3, 3)
        Columns ``x_hat`` (Earth->Moon), ``y_hat``, ``z_hat`` (orbit normal), ICRF components.
    C_dot : (..., 3, 3)
        Time derivative of ``C`` [1/s] (central difference over ``dt``).
    l, l_dot : (...,)
        Earth-Moon distance [m] and its rate [m/s].
    theta_dot : (...,)
        Rotation rate ``|r x v| / l^2`` [rad/s].
    """
    t = np.asarray(t, dtype=float)

    def frame(tt: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        r, v = ephemeris.moon_geocentric(tt)
        h = np.cross(r, v)
        x = r / np.linalg.norm(r, axis=-1, keepdims=True)
        z = h / np.linalg.norm(h, axis=-1, keepdims=True)
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=-1), r, v

    C, r, v = frame(t)
    Cp, _, _ = frame(t + dt)
    Cm, _, _ = frame(t - dt)
    C_dot = (Cp - Cm) / (2.0 * dt)
    ln = np.linalg.norm(r, axis=-1)
    l_dot = np.einsum("...k,...k->...", r, v) / ln
    theta_dot = np.linalg.norm(np.cross(r, v), axis=-1) / ln**2
    return C, C_dot, ln, l_dot, theta_dot


def rotating_to_emb(ephemeris: Ephemeris, t: ArrayLike, rho: ArrayLike) -> FloatArray:
    """Map non-dimensional CR3BP states ``(..., 6)`` at epochs ``t`` [TDB s] to EMB-centred
    J2000 states [m, m/s] with the pulsating rotating frame (module docstring, step 2)."""
    rho = np.asarray(rho, dtype=float)
    C, Cd, ln, ld, th = rotating_frame(ephemeris, t)
    p, dp = rho[..., :3], rho[..., 3:]
    Cp = np.einsum("...ij,...j->...i", C, p)
    pos = ln[..., None] * Cp
    vel = (ld[..., None] * Cp + ln[..., None] * np.einsum("...ij,...j->...i", Cd, p)
           + (ln * th)[..., None] * np.einsum("...ij,...j->...i", C, dp))
    return np.concatenate([pos, vel], axis=-1)


def emb_to_rotating(ephemeris: Ephemeris, t: ArrayLike, x: ArrayLike) -> FloatArray:
    """Inverse of :func:`rotating_to_emb`: EMB-centred J2000 states [m, m/s] to pulsating
    rotating non-dimensional states ``(..., 6)`` (positions in units of the instantaneous
    Earth-Moon distance)."""
    x = np.asarray(x, dtype=float)
    C, Cd, ln, ld, th = rotating_frame(ephemeris, t)
    CT = np.swapaxes(C, -1, -2)
    p = np.einsum("...ij,...j->...i", CT, x[..., :3]) / ln[..., None]
    Cp = np.einsum("...ij,...j->...i", C, p)
    rest = x[..., 3:] - ld[..., None] * Cp - ln[..., None] * np.einsum("...ij,...j->...i", Cd, p)
    dp = np.einsum("...ij,...j->...i", CT, rest) / (ln * th)[..., None]
    return np.concatenate([p, dp], axis=-1)


# --------------------------------------------------------------------------- shooting
@dataclass(frozen=True)
class ShootingOptions:
    """Knobs of the multiple-shooting transfer (module docstring table). SI units.

    Attributes
    ----------
    segment : float
        Patch-point spacing [s].
    pad : float
        Free margin before and after the requested arc [s].
    step : float
        RK4 step [s] of the shooting and of the final arc.
    tol_position : float
        Continuity tolerance on positions [m].
    tol_velocity : float
        Continuity tolerance on velocities [m/s].
    max_iter : int
        Newton iterations.
    range_min, range_max : float
        Allowed distance to the Moon along the arc [m].
    """

    segment: float = 0.5 * DAY
    pad: float = 2.0 * DAY
    step: float = 300.0
    tol_position: float = 1e-3
    tol_velocity: float = 1e-9
    max_iter: int = 40
    range_min: float = 35_000e3
    range_max: float = 90_000e3

    def __post_init__(self) -> None:
        for name in ("segment", "step", "tol_position", "tol_velocity", "range_max"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"shooting.{name}", v, "a finite value > 0")
        if not (math.isfinite(self.pad) and self.pad >= 0):
            raise ConfigError("shooting.pad", self.pad, "a finite margin >= 0 s")
        if self.segment < self.step:
            raise ConfigError("shooting.segment", self.segment, f">= the step {self.step} s")
        if not (0 <= self.range_min < self.range_max):
            raise ConfigError("shooting.range_min", self.range_min, "0 <= range_min < range_max")
        if self.max_iter < 1:
            raise ConfigError("shooting.max_iter", self.max_iter, "at least 1 iteration")


@dataclass(frozen=True)
class ShootingResult:
    """Converged patch points.

    Attributes
    ----------
    times : (N + 1,) array
        Patch epochs [TDB s].
    states : (N + 1, 6) array
        Patch states, EMB-centred J2000 [m, m/s].
    iterations : int
    max_position_defect, max_velocity_defect : float
        Final continuity defects [m], [m/s].
    initial_position_defect : float
        Largest position defect of the CR3BP guess [m].
    """

    times: FloatArray
    states: FloatArray
    iterations: int
    max_position_defect: float
    max_velocity_defect: float
    initial_position_defect: float


def _defects(model: PointMassModel, times: FloatArray, X: FloatArray, step: float,
             with_stm: bool) -> tuple[FloatArray, FloatArray | None]:
    seg = times[1] - times[0]
    n_sub = max(1, math.ceil(seg / step - 1e-9))
    grids = times[:-1, None] + seg * (np.arange(n_sub + 1) / n_sub)[None, :]
    grids[:, -1] = times[1:]
    Xf, P = rk4_grid(model, grids, X[:-1], with_stm=with_stm)
    return Xf - X[1:], P


def multiple_shooting(model: PointMassModel, times: ArrayLike, guess: ArrayLike,
                      options: ShootingOptions = ShootingOptions(),
                      progress: Callable[[int, float], None] | None = None) -> ShootingResult:
    """Make a sequence of patch states continuous in ``model`` (module docstring, step 3).

    Parameters
    ----------
    model : PointMassModel
    times : (N + 1,) array
        Equally spaced patch epochs [TDB s].
    guess : (N + 1, 6) array
        Initial patch states [m, m/s].
    options : ShootingOptions
    progress : callable, optional
        ``progress(iteration, max_position_defect_m)`` after each iteration.

    Raises
    ------
    ConvergenceError
        When the defects are not below the tolerances after ``max_iter`` iterations.
    """
    ts = np.asarray(times, dtype=float)
    X = np.array(guess, dtype=float)
    n = ts.size - 1
    if n < 1 or X.shape != (n + 1, 6):
        raise ConfigError("guess", X.shape, f"({ts.size}, 6) patch states")
    if not np.allclose(np.diff(ts), ts[1] - ts[0], rtol=0, atol=1e-6):
        raise ConfigError("times", "unequal spacing", "equally spaced patch epochs")
    scale = np.array([LU] * 3 + [VU] * 3)

    def norms(F: FloatArray) -> tuple[float, float]:
        return float(np.abs(F[:, :3]).max()), float(np.abs(F[:, 3:]).max())

    F, P = _defects(model, ts, X, options.step, True)
    dp0, dv0 = norms(F)
    dp, dv = dp0, dv0
    log.info("multiple shooting: %d segments, initial defects %.3e m, %.3e m/s", n, dp, dv)
    for it in range(1, options.max_iter + 1):
        if dp < options.tol_position and dv < options.tol_velocity:
            return ShootingResult(ts, X, it - 1, dp, dv, dp0)
        # scaled Jacobian: dF_k/dx_k = Phi_k, dF_k/dx_k+1 = -I
        J = np.zeros((6 * n, 6 * (n + 1)))
        for k in range(n):
            J[6 * k:6 * k + 6, 6 * k:6 * k + 6] = P[k] * scale[None, :] / scale[:, None]
            J[6 * k:6 * k + 6, 6 * k + 6:6 * k + 12] = -np.eye(6)
        Fs = (F / scale).ravel()
        dX = -J.T @ np.linalg.solve(J @ J.T, Fs)
        dX = dX.reshape(n + 1, 6) * scale
        lam = 1.0
        cost = float(np.sum(Fs**2))
        while True:
            Xn = X + lam * dX
            Fn, Pn = _defects(model, ts, Xn, options.step, True)
            cost_n = float(np.sum((Fn / scale) ** 2))
            if cost_n < cost or lam < 1.0 / 64:
                break
            lam *= 0.5
        X, F, P = Xn, Fn, Pn
        dp, dv = norms(F)
        log.info("multiple shooting iteration %d: step %.3g, defects %.3e m, %.3e m/s",
                 it, lam, dp, dv)
        if progress is not None:
            progress(it, dp)
    if dp < options.tol_position and dv < options.tol_velocity:
        return ShootingResult(ts, X, options.max_iter, dp, dv, dp0)
    raise ConvergenceError(
        f"multiple shooting did not converge in {options.max_iter} iterations: defects "
        f"{dp:.3e} m / {dv:.3e} m/s (tolerances {options.tol_position:g} m / "
        f"{options.tol_velocity:g} m/s); try a shorter shooting segment or another epoch")


# --------------------------------------------------------------------------- the arc
def default_cache_dir() -> Path:
    """``STARNAV_CACHE_DIR``, else ``$XDG_CACHE_HOME/starnav``, else ``~/.cache/starnav``."""
    env = os.environ.get("STARNAV_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "starnav"


def _cache_key(payload: dict[str, Any]) -> str:
    text = json.dumps(payload, sort_keys=True, default=float)
    return hashlib.sha256(text.encode()).hexdigest()[:20]




def _save_npz(path: Path, traj: Trajectory) -> None:
    buf = io.BytesIO()
    np.savez(buf, times=traj.times, states=traj.states,
             meta=np.array(json.dumps(traj.meta, default=str)),
             object_name=np.array(traj.object_name))
    atomic_write_bytes(path, buf.getvalue())


def _load_npz(path: Path) -> Trajectory | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            return Trajectory(z["times"], z["states"], str(z["object_name"]),
                              json.loads(str(z["meta"])))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
        # an empty or truncated file (a full disk, a killed write): rebuilt and replaced
        log.warning("ignoring unreadable trajectory cache %s (%s)", path, err)
        return None


def _segment_nodes(model: PointMassModel, result: ShootingResult,
                   step: float) -> tuple[FloatArray, FloatArray]:
    """Every RK4 node of the converged segments, each propagated from its own patch state
    (module docstring, step 4): epochs ``(k,)`` and states ``(k, 6)``."""
    ts = result.times
    seg = ts[1] - ts[0]
    n_sub = max(1, math.ceil(seg / step - 1e-9))
    grids = ts[:-1, None] + seg * (np.arange(n_sub + 1) / n_sub)[None, :]
    grids[:, -1] = ts[1:]
    Xs, _ = rk4_grid(model, grids, result.states[:-1], keep=np.arange(n_sub + 1))
    times = np.concatenate([grids[:, :-1].ravel(), ts[-1:]])
    states = np.concatenate([Xs[:, :-1].reshape(-1, 6), result.states[-1:]])
    return times, states


def halo_patch_guess(ephemeris: Ephemeris, orbit: HaloOrbit, t0: float, times: ArrayLike,
                     phase: float = 0.0) -> FloatArray:
    """EMB-centred J2000 patch states [m, m/s] at ``times`` [TDB s] from the CR3BP ``orbit``
    at phase ``phase`` [fraction of a period, 0..1) at ``t0`` (module docstring, step 2)."""
    ts = np.asarray(times, dtype=float)
    tau = phase * orbit.period + (ts - t0) / TU
    rho = orbit.states(tau)
    return rotating_to_emb(ephemeris, ts, rho)


def ephemeris_halo_arc(
    model: PointMassModel,
    t0: float,
    duration: float,
    *,
    z0: float | None = None,
    phase: float = 0.0,
    options: ShootingOptions = ShootingOptions(),
    cache_dir: str | os.PathLike[str] | None | bool = None,
    object_name: str = "LUMIO-LIKE",
    progress: Callable[[int, float], None] | None = None,
) -> Trajectory:
    """Ballistic L2 quasi-halo arc in the ephemeris point-mass model (module docstring).

    Parameters
    ----------
    model : PointMassModel
        Force model (also the navigation filter's).
    t0 : float
        First epoch of the arc [TDB s past J2000].
    duration : float
        Arc length [s] (> 0).
    z0 : float, optional
        Out-of-plane amplitude of the CR3BP halo at its x-z crossing [LU]; default docs/facts.md
        (-0.065 LU, southern).
    phase : float
        Position on the halo at ``t0`` [fraction of the period, 0 = x-z crossing at ``z0``].
    options : ShootingOptions
    cache_dir : path, None or False
        Where to cache the arc: None = :func:`default_cache_dir`, False = no caching.
    object_name : str
    progress : callable, optional
        Forwarded to :func:`multiple_shooting`.

    Returns
    -------
    Trajectory
        States at every RK4 node (``options.step``) from ``t0`` to ``t0 + duration``.

    Raises
    ------
    ConfigError, EphemerisRangeError
        Bad inputs, checked before any work.
    ConvergenceError
        Shooting failure, or an arc leaving the Moon-range band.
    """
    z0 = REFERENCE_HALO[1] if z0 is None else float(z0)
    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError("trajectory.duration_days", duration / DAY, "a duration > 0 days")
    if not (math.isfinite(phase) and 0.0 <= phase < 1.0):
        raise ConfigError("trajectory.halo_phase_deg", phase * 360.0, "0 <= phase < 360 deg")
    eph = model.ephemeris
    t_first, t_last = t0 - options.pad, t0 + duration + options.pad
    eph.check_span([t0, t0 + duration])
    eph.check_span([t_first - 60.0, t_last + 60.0])  # shooting margins

    payload = {"version": ALGORITHM_VERSION, "t0": float(t0), "duration": float(duration),
               "z0": z0, "phase": float(phase), "options": asdict(options),
               "model": model.key(), "object": object_name}
    key = _cache_key(payload)
    cache_path: Path | None = None
    if cache_dir is not False:
        base = default_cache_dir() if cache_dir in (None, True) else Path(cache_dir)
        cache_path = base / "trajectories" / f"halo-{key}.npz"
        if cache_path.is_file():
            traj = _load_npz(cache_path)
            if traj is not None:
                log.info("trajectory arc read from cache %s", cache_path)
                return traj

    tic = time.perf_counter()
    orbit = l2_halo(z0)
    n_seg = max(1, math.ceil((t_last - t_first) / options.segment - 1e-9))
    times = t_first + options.segment * np.arange(n_seg + 1)
    # t0 must be a patch epoch: shift the grid so that it is
    k0 = int(round((t0 - t_first) / options.segment))
    times = times + (t0 - times[k0])
    guess = halo_patch_guess(eph, orbit, t0, times, phase)
    result = multiple_shooting(model, times, guess, options, progress=progress)

    grid, X = _segment_nodes(model, result, options.step)
    n_steps = math.ceil(duration / options.step - 1e-9)
    i0 = int(np.argmin(np.abs(grid - t0)))
    grid, X = grid[i0:i0 + n_steps + 1], X[i0:i0 + n_steps + 1]
    traj = Trajectory(grid, X, object_name)
    rng = traj.moon_range(eph)
    elapsed = time.perf_counter() - tic
    meta = {
        "source": "starnav.scenes.trajectory.ephemeris_halo_arc",
        "cache_key": key,
        "inputs": payload,
        "halo_period_s": orbit.period * TU,
        "halo_state0": orbit.state0.tolist(),
        "shooting_iterations": result.iterations,
        "shooting_max_position_defect_m": result.max_position_defect,
        "shooting_max_velocity_defect_m_s": result.max_velocity_defect,
        "guess_max_position_defect_m": result.initial_position_defect,
        "moon_range_min_m": float(rng.min()),
        "moon_range_max_m": float(rng.max()),
        "elapsed_s": elapsed,
    }
    traj = Trajectory(grid, X, object_name, meta)
    log.info("ephemeris halo arc: %d shooting iterations, defects %.2e m, Moon range "
             "%.0f-%.0f km, %.1f s", result.iterations, result.max_position_defect,
             rng.min() / 1e3, rng.max() / 1e3, elapsed)
    if rng.min() < options.range_min or rng.max() > options.range_max:
        raise ConvergenceError(
            f"the converged arc leaves the Moon-range band: {rng.min() / 1e3:.0f}-"
            f"{rng.max() / 1e3:.0f} km, allowed {options.range_min / 1e3:.0f}-"
            f"{options.range_max / 1e3:.0f} km; try another epoch, phase or amplitude")
    if cache_path is not None:
        try:
            _save_npz(cache_path, traj)
        except OSError as err:
            log.warning("could not write the trajectory cache %s (%s)", cache_path, err)
    return traj


def load_cached_arc(path: str | os.PathLike[str]) -> Trajectory:
    """Read an arc written by the cache (``.npz``)."""
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"trajectory cache file {str(p)!r} does not exist")
    traj = _load_npz(p)
    if traj is None:
        raise DataFileError(f"trajectory cache file {str(p)!r} is unreadable")
    return traj
