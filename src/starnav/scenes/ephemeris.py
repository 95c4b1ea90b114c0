"""JPL DE421 ephemeris: Sun, Earth, Moon and Earth-Moon barycentre, lunar orientation, time.

The ``de421`` package ships DE421 as Chebyshev coefficient arrays plus its constants (nothing
is downloaded); positions and their analytic velocities are evaluated here, vectorised over
epochs. Out: SI (m, m/s, rad, rad/s); time is TDB seconds past J2000 (JD 2451545.0 TDB); axes
ICRF (the ~20 mas frame bias to EME2000 ignored). Earth and Moon about the EMB follow from
EMRAT. The Moon's body-fixed frame is DE421's principal-axis (PA) frame from its libration
angles (3-1-3); ``moon_orientation(t, frame="ME")`` applies the constant PA -> mean-Earth
rotation of the lunar maps (:func:`pa_to_me_matrix`). GM values come from the ephemeris
constants. Time scales appear only at the edges (:func:`parse_epoch`, :func:`format_epoch`).
An epoch outside the packaged span (1899-12-04 to 2199-06-22 TDB) raises
:class:`EphemerisRangeError` before any work.

References
----------
W. M. Folkner, J. G. Williams, D. H. Boggs (2009), *The Planetary and Lunar Ephemeris DE 421*,
IPN Progress Report 42-178.
J. G. Williams et al. (2008), *DE421 Lunar Orbit, Physical Librations, and Surface
Coordinates*, JPL IOM 335-JW,DB,WF-20080314-001 (PA -> ME).

Index
-----
:class:`Ephemeris`, :func:`parse_epoch`, :func:`format_epoch`, :func:`pa_to_me_matrix`,
:class:`EphemerisRangeError`, :data:`J2000_JD`, :data:`PA_TO_ME_DE421_ARCSEC`.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import re
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import ARCSEC, DAY
from starnav.errors import ConfigError, DataFileError, StarnavError
from starnav.geometry import frame_rotation_x, frame_rotation_y, frame_rotation_z
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Up to this many epochs per call the Chebyshev recurrence runs on Python floats (faster
#: than NumPy's per-call overhead on tiny arrays; the array form's result to rounding).
_SCALAR_EPOCHS = 8
#: Epochs memoised per series by the few-epoch path (cleared when full).
_MEMO_EPOCHS = 64

#: Julian date of J2000 (2000-01-01T12:00:00 TDB).
J2000_JD = 2451545.0

#: DE421 PA -> ME rotation angles [arcsec] about z, y, x (Williams et al. 2008, JPL IOM
#: 335-JW,DB,WF-20080314-001, as in NAIF's ``moon_080317.tf``).
PA_TO_ME_DE421_ARCSEC = (67.92, 78.56, 0.30)

_BODIES = ("sun", "earth", "moon", "emb")
_CENTERS = ("ssb", "emb", "earth", "moon")


class EphemerisRangeError(StarnavError, ValueError):
    """An epoch outside the span covered by the ephemeris."""


# --------------------------------------------------------------------------- rotations
_r1, _r2, _r3 = frame_rotation_x, frame_rotation_y, frame_rotation_z


def pa_to_me_matrix() -> FloatArray:
    """Constant rotation taking DE421 PA components to ME components, ``v_ME = M v_PA``."""
    az, ay, ax = (np.asarray(a * ARCSEC) for a in PA_TO_ME_DE421_ARCSEC)
    # frame rotations -67.92" about z, then -78.56" about y, then -0.30" about x
    return _r1(-ax) @ _r2(-ay) @ _r3(-az)


# --------------------------------------------------------------------------- time
_EPOCH_RE = re.compile(
    r"^\s*(?P<iso>\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2}(?:\.\d*)?)?)?)"
    r"\s*(?P<scale>Z|UTC|TT|TDB)?\s*$",
    re.IGNORECASE,
)


def parse_epoch(text: str | float, field: str = "epoch") -> float:
    """TDB seconds past J2000 from an ISO string with an explicit time scale.

    Parameters
    ----------
    text : str or float
        ``"YYYY-MM-DDTHH:MM:SS[.fff] SCALE"`` with ``SCALE`` one of ``UTC``, ``TT``, ``TDB``
        (or a trailing ``Z`` meaning UTC). A float is taken as TDB seconds past J2000 already.
    field : str
        Name of the configuration field, for the error message.

    Returns
    -------
    float
        Epoch [TDB s past J2000].

    Raises
    ------
    ConfigError
        When the string has no explicit scale or is not an ISO date.
    """
    if isinstance(text, int | float) and not isinstance(text, bool):
        if not math.isfinite(float(text)):
            raise ConfigError(field, text, "a finite number of TDB seconds past J2000")
        return float(text)
    m = _EPOCH_RE.match(str(text))
    if m is None or m.group("scale") is None:
        raise ConfigError(field, text, "an ISO date with an explicit time scale, e.g. "
                                       "'2027-03-01T00:00:00 TDB' (UTC, TT, TDB or a trailing Z)")
    from astropy.time import Time

    scale = m.group("scale").lower()
    scale = "utc" if scale == "z" else scale
    from erfa import ErfaError

    try:
        t = Time(m.group("iso").replace(" ", "T"), format="isot", scale=scale)
        tdb = t.tdb
    except (ValueError, ErfaError) as err:
        why = str(err).splitlines()[-1].removeprefix("ErfaError: ")
        raise ConfigError(field, text, f"a valid calendar date ({why})") from None
    return float(((tdb.jd1 - J2000_JD) + tdb.jd2) * DAY)


def format_epoch(t: float, scale: Literal["TDB", "UTC", "TT"] = "TDB", precision: int = 6,
                 suffix: bool = True) -> str:
    """ISO string of an epoch given in TDB seconds past J2000.

    Parameters
    ----------
    t : float
        Epoch [TDB s past J2000].
    scale : {"TDB", "UTC", "TT"}
        Time scale of the output.
    precision : int
        Decimals of the seconds.
    suffix : bool
        Append ``" " + scale``.
    """
    from astropy.time import Time

    day, frac = divmod(float(t), DAY)
    tt = Time(J2000_JD + day, frac / DAY, format="jd", scale="tdb", precision=precision)
    out = getattr(tt, scale.lower()).isot
    return f"{out} {scale}" if suffix else out


# --------------------------------------------------------------------------- ephemeris
class Ephemeris:
    """DE421 states and orientations (SI units, ICRF axes, TDB seconds past J2000).

    Parameters
    ----------
    directory : str or os.PathLike, optional
        Directory holding the ``jpl-*.npy`` and ``constants.npy`` files. Default: the installed
        ``de421`` package.

    Attributes
    ----------
    gm_sun, gm_earth, gm_moon, gm_emb : float
        Gravitational parameters from the DE421 constants [m^3/s^2].
    emrat : float
        Earth/Moon mass ratio [-].
    au : float
        Astronomical unit of DE421 [m].
    t_min, t_max : float
        Span covered [TDB s past J2000].
    """

    name = "DE421"

    def __init__(self, directory: str | os.PathLike[str] | None = None) -> None:
        if directory is None:
            try:
                import de421
            except ImportError as err:  # pragma: no cover - dependency of starnav
                raise DataFileError("the 'de421' package is not installed") from err
            directory = os.path.dirname(de421.__file__)
        self.directory = os.fspath(directory)
        path = os.path.join(self.directory, "constants.npy")
        if not os.path.isfile(path):
            raise DataFileError(f"DE421 constants file {path!r} does not exist")
        raw = np.load(path)
        c = {k.decode("ascii") if isinstance(k, bytes) else str(k): float(v) for k, v in raw}
        self.constants: dict[str, float] = c
        self.au = c["AU"] * 1e3  # km -> m
        gm_unit = self.au**3 / DAY**2  # AU^3/day^2 -> m^3/s^2
        self.emrat = c["EMRAT"]
        self.gm_sun = c["GMS"] * gm_unit
        self.gm_emb = c["GMB"] * gm_unit
        self.gm_earth = self.gm_emb * self.emrat / (1.0 + self.emrat)
        self.gm_moon = self.gm_emb / (1.0 + self.emrat)
        self._jd_alpha = c["jalpha"]
        self._jd_omega = c["jomega"]
        self.t_min = (self._jd_alpha - J2000_JD) * DAY
        self.t_max = (self._jd_omega - J2000_JD) * DAY
        self._sets: dict[str, FloatArray] = {}
        self._memo: dict[str, dict[float, FloatArray]] = {}
        self._pa_to_me = pa_to_me_matrix()

    @classmethod
    @functools.cache
    def default(cls) -> Ephemeris:
        """The shared DE421 instance from the installed ``de421`` package (loaded once)."""
        return cls()

    # ------------------------------------------------------------------ raw series
    def _load(self, name: str) -> FloatArray:
        s = self._sets.get(name)
        if s is None:
            path = os.path.join(self.directory, f"jpl-{name}.npy")
            if not os.path.isfile(path):
                raise DataFileError(f"DE421 series file {path!r} does not exist")
            s = np.load(path)
            self._sets[name] = s
        return s

    def check_span(self, t: ArrayLike) -> None:
        """Raise :class:`EphemerisRangeError` if any epoch is outside the DE421 span.

        Parameters
        ----------
        t : float or array
            Epochs [TDB s past J2000].
        """
        t = np.asarray(t, dtype=float)
        if t.size == 0:
            return
        bad = ~((t >= self.t_min) & (t <= self.t_max))
        if np.any(bad):
            tb = float(t[bad].flat[0])
            when = format_epoch(tb, precision=0) if math.isfinite(tb) and abs(tb) < 1e11 \
                else repr(tb)
            raise EphemerisRangeError(
                f"epoch {when} (t = {tb!r} s TDB past J2000) is outside the {self.name} span "
                f"{format_epoch(self.t_min, precision=0)} .. "
                f"{format_epoch(self.t_max, precision=0)}; expected an epoch inside it")

    def _chebyshev(self, name: str, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Series ``name`` and its time derivative at epochs ``t`` [TDB s]: native units
        (km or rad) and per day; shapes ``(..., n_comp)``."""
        t = np.asarray(t, dtype=float)
        sets = self._load(name)
        n_sets, n_comp, n_coef = sets.shape
        dps = (self._jd_omega - self._jd_alpha) / n_sets  # days per set
        # offset inside the set in seconds: set starts are whole seconds (exact floats), so
        # the subtraction keeps the full resolution of t
        start0 = (self._jd_alpha - J2000_JD) * DAY
        span = dps * DAY
        if t.size <= _SCALAR_EPOCHS:
            val, der = self._chebyshev_few(name, sets, t, start0, span)
        else:
            self.check_span(t)
            tf = t.ravel()
            idx = np.clip(np.floor((tf - start0) / span).astype(np.int64), 0, n_sets - 1)
            x = 2.0 * (tf - (start0 + idx * span)) / span - 1.0
            T = np.empty((n_coef, x.size))
            dT = np.empty((n_coef, x.size))
            T[0], T[1] = 1.0, x
            dT[0], dT[1] = 0.0, 1.0
            for k in range(2, n_coef):
                T[k] = 2.0 * x * T[k - 1] - T[k - 2]
                dT[k] = 2.0 * x * dT[k - 1] - dT[k - 2] + 2.0 * T[k - 1]
            coef = sets[idx]  # (n, comp, coef)
            val = np.einsum("nck,kn->nc", coef, T)
            der = np.einsum("nck,kn->nc", coef, dT)
        der = der * (2.0 / dps)
        shape = t.shape + (n_comp,)
        return val.reshape(shape), der.reshape(shape)

    def _chebyshev_few(self, name: str, sets: FloatArray, t: FloatArray, start0: float,
                       span: float) -> tuple[FloatArray, FloatArray]:
        """:meth:`_chebyshev` for a few epochs (the stages of one RK4 step, one fix's epoch):
        the set index, the scaled time and the recurrence on Python floats, the same
        operations in the same order as the array form, without its ~5 NumPy calls per
        coefficient; each epoch's values memoised (a filter step starts where the last one
        ended, and its fix asks for the Moon at that epoch again), so computed one epoch at a
        time: the same bits whichever call asked first, the array form's to rounding."""
        memo = self._memo.setdefault(name, {})
        n_sets, _, n_coef = sets.shape
        tl = t.ravel().tolist()
        got = {tj: memo.get(tj) for tj in tl}
        new = [tj for tj, v in got.items() if v is None]
        if new:
            if not all(self.t_min <= tj <= self.t_max for tj in new):
                self.check_span(np.array(new))
            if len(memo) + len(new) > _MEMO_EPOCHS:
                memo.clear()
            for tj in new:
                i = min(max(math.floor((tj - start0) / span), 0), n_sets - 1)
                xj = 2.0 * (tj - (start0 + i * span)) / span - 1.0
                tk, dk = [1.0, xj], [0.0, 1.0]
                for k in range(2, n_coef):
                    tk.append(2.0 * xj * tk[k - 1] - tk[k - 2])
                    dk.append(2.0 * xj * dk[k - 1] - dk[k - 2] + 2.0 * tk[k - 1])
                # the array form's contraction, one epoch at a time (NumPy's sum for a row
                # depends on how many rows it is given: its vector paths)
                coef = sets[i:i + 1]
                memo[tj] = got[tj] = (np.einsum("nck,kn->nc", coef, np.array([tk]).T.copy())[0],
                                      np.einsum("nck,kn->nc", coef, np.array([dk]).T.copy())[0])
        rows = [got[tj] for tj in tl]
        return (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]))

    # ------------------------------------------------------------------ states
    def moon_geocentric(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Moon relative to the Earth: position [m] and velocity [m/s], shape ``(..., 3)``."""
        p, v = self._chebyshev("moon", t)
        return p * 1e3, v * (1e3 / DAY)

    def emb_ssb(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Earth-Moon barycentre relative to the SSB: position [m], velocity [m/s]."""
        p, v = self._chebyshev("earthmoon", t)
        return p * 1e3, v * (1e3 / DAY)

    def sun_ssb(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Sun relative to the SSB: position [m], velocity [m/s]."""
        p, v = self._chebyshev("sun", t)
        return p * 1e3, v * (1e3 / DAY)

    def state(self, body: str, t: ArrayLike, center: str = "emb") -> FloatArray:
        """State of ``body`` relative to ``center`` along ICRF axes.

        Parameters
        ----------
        body : {"sun", "earth", "moon", "emb"}
        t : float or array
            Epochs [TDB s past J2000].
        center : {"ssb", "emb", "earth", "moon"}

        Returns
        -------
        (..., 6) array
            Position [m] and velocity [m/s].
        """
        if body not in _BODIES:
            raise ConfigError("body", body, f"one of {', '.join(_BODIES)}")
        if center not in _CENTERS:
            raise ConfigError("center", center, f"one of {', '.join(_CENTERS)}")
        return self._rel_emb(body, t) - self._rel_emb(center, t)

    def _rel_emb(self, name: str, t: ArrayLike) -> FloatArray:
        """State of ``name`` relative to the EMB (Earth and Moon never go through the SSB, so
        they keep full precision)."""
        t = np.asarray(t, dtype=float)
        if name == "emb":
            self.check_span(t)
            return np.zeros(t.shape + (6,))
        if name in ("earth", "moon"):
            em = np.concatenate(self.moon_geocentric(t), axis=-1)
            f = 1.0 / (1.0 + self.emrat)
            return -em * f if name == "earth" else em * (1.0 - f)
        emb = np.concatenate(self.emb_ssb(t), axis=-1)
        if name == "ssb":
            return -emb
        return np.concatenate(self.sun_ssb(t), axis=-1) - emb  # sun

    def positions_emb(self, t: ArrayLike) -> FloatArray:
        """Earth, Moon and Sun positions relative to the EMB [m], shape ``(..., 3, 3)``
        (axis -2: Earth, Moon, Sun; axis -1: x, y, z). One vectorised call for many epochs."""
        em, _ = self.moon_geocentric(t)
        emb, _ = self.emb_ssb(t)
        sun, _ = self.sun_ssb(t)
        f = 1.0 / (1.0 + self.emrat)
        return np.stack([-em * f, em * (1.0 - f), sun - emb], axis=-2)

    # ------------------------------------------------------------------ orientation
    def librations(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """DE421 lunar libration Euler angles ``(phi, theta, psi)`` [rad] and rates [rad/s]."""
        a, da = self._chebyshev("librations", t)
        return a, da / DAY

    def moon_orientation(self, t: ArrayLike, frame: Literal["PA", "ME"] = "PA") -> FloatArray:
        """Rotation Moon body-fixed -> ICRF, ``v_icrf = R @ v_body``, shape ``(..., 3, 3)``.

        Parameters
        ----------
        t : float or array
            Epochs [TDB s past J2000].
        frame : {"PA", "ME"}
            DE421 principal axes (default) or mean-Earth/polar axes (module docstring).
        """
        if frame not in ("PA", "ME"):
            raise ConfigError("moon_frame", frame, "'PA' or 'ME'")
        a, _ = self.librations(t)
        phi, theta, psi = a[..., 0], a[..., 1], a[..., 2]
        icrf_to_pa = _r3(psi) @ _r1(theta) @ _r3(phi)
        icrf_to_body = icrf_to_pa if frame == "PA" else self._pa_to_me @ icrf_to_pa
        return np.swapaxes(icrf_to_body, -1, -2)

    def moon_angular_velocity(self, t: ArrayLike) -> FloatArray:
        """Inertial angular velocity of the Moon's PA frame, ICRF components [rad/s]."""
        a, da = self.librations(t)
        phi, theta = a[..., 0], a[..., 1]
        dphi, dtheta, dpsi = da[..., 0], da[..., 1], da[..., 2]
        # 3-1-3 Euler kinematics in inertial components
        w = (dphi[..., None] * np.stack([np.zeros_like(phi), np.zeros_like(phi),
                                         np.ones_like(phi)], -1)
             + dtheta[..., None] * np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], -1)
             + dpsi[..., None] * np.stack([np.sin(theta) * np.sin(phi),
                                           -np.sin(theta) * np.cos(phi), np.cos(theta)], -1))
        return w
