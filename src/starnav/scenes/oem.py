"""CCSDS Orbit Ephemeris Message (OEM), KVN text: read and write.

Format (CCSDS 502.0-B-3, *Orbit Data Messages*, ch. 5): a header (``CCSDS_OEM_VERS``,
``CREATION_DATE``, ``ORIGINATOR``), then one or more segments, each a metadata block between
``META_START`` and ``META_STOP`` (``OBJECT_NAME``, ``OBJECT_ID``, ``CENTER_NAME``,
``REF_FRAME``, ``TIME_SYSTEM``, ``START_TIME``, ``STOP_TIME``, optional ``USEABLE_*``,
``INTERPOLATION``, ``INTERPOLATION_DEGREE``) followed by data lines
``EPOCH X Y Z X_DOT Y_DOT Z_DOT [X_DDOT Y_DDOT Z_DDOT]`` in km and km/s, and optional
covariance blocks (``COVARIANCE_START`` .. ``COVARIANCE_STOP``, skipped on reading).
``COMMENT`` lines may appear in the header and at the start of blocks.

What starnav writes: one segment, ``CENTER_NAME = EARTH-MOON BARYCENTER`` (or ``MOON``/``EARTH``
on request), ``REF_FRAME = ICRF``, ``TIME_SYSTEM = TDB``, epochs with microseconds, positions
with 6 decimals of km (mm), velocities with 9 decimals of km/s (um/s). Reading back gives the
written values to that printed precision (epochs exactly, to the microsecond).

What it reads: centres ``EARTH-MOON BARYCENTER`` (spellings with a space, ``BARYCENTRE``,
``EMB``), ``MOON``, ``EARTH``, ``SUN``, ``SOLAR SYSTEM BARYCENTER`` (converted to the EMB with
DE421); frames ``ICRF``, ``EME2000``, ``J2000`` (the ~20 mas frame bias is ignored); time systems
``TDB``, ``TT``, ``TAI``, ``UTC``; epochs ``YYYY-MM-DDThh:mm:ss[.f]`` or
``YYYY-DDDThh:mm:ss[.f]``. Anything else is an :class:`OEMFormatError` naming the line.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from starnav.atomic import atomic_write_bytes
from starnav.constants import DAY, MOON_RADIUS
from starnav.errors import GeometryError, StarnavError, not_a_file_error
from starnav.scenes.ephemeris import J2000_JD, Ephemeris
from starnav.scenes.trajectory import Trajectory
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Decimals written for positions [km], velocities [km/s] and epoch seconds.
POSITION_DECIMALS = 6
VELOCITY_DECIMALS = 9
EPOCH_DECIMALS = 6

_J2000_TDB = _dt.datetime(2000, 1, 1, 12, 0, 0)

_CENTER_ALIASES = {
    "EARTH-MOON BARYCENTER": "emb", "EARTH MOON BARYCENTER": "emb",
    "EARTH-MOON BARYCENTRE": "emb", "EARTH MOON BARYCENTRE": "emb", "EMB": "emb",
    "EARTH BARYCENTER": "emb",
    "MOON": "moon", "EARTH": "earth", "SUN": "sun",
    "SOLAR SYSTEM BARYCENTER": "ssb", "SSB": "ssb",
}
_CENTER_NAMES = {"emb": "EARTH-MOON BARYCENTER", "moon": "MOON", "earth": "EARTH"}
_FRAMES = ("ICRF", "EME2000", "J2000")
_TIME_SYSTEMS = ("TDB", "TT", "TAI", "UTC")
_REQUIRED_META = ("OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM",
                  "START_TIME", "STOP_TIME")
_EPOCH_RE = re.compile(
    r"^(\d{4})-(?:(\d{2})-(\d{2})|(\d{3}))T(\d{2}):(\d{2}):(\d{2})(?:\.(\d+))?Z?$")


class OEMFormatError(StarnavError, ValueError):
    """A malformed OEM file: the message names the file, the line and what was expected."""


# --------------------------------------------------------------------------- epochs
def tdb_to_iso(t: float, decimals: int = EPOCH_DECIMALS) -> str:
    """ISO calendar string (no scale suffix) of ``t`` [TDB s past J2000] in TDB, rounded to
    ``decimals`` (<= 6). Exact integer arithmetic: TDB has no leap seconds."""
    us = int(round(float(t) * 1e6))
    d = _J2000_TDB + _dt.timedelta(microseconds=us)
    base = d.strftime("%Y-%m-%dT%H:%M:%S")
    if decimals <= 0:
        return base
    frac = f"{d.microsecond:06d}"[:decimals]
    return f"{base}.{frac}"


def _parse_calendar(text: str) -> tuple[_dt.datetime, int] | None:
    """(datetime to whole seconds, extra picoseconds) or None; leap second 60 allowed."""
    m = _EPOCH_RE.match(text)
    if m is None:
        return None
    year, mon, day, doy, hh, mm, ss, frac = m.groups()
    try:
        if doy is not None:
            base = _dt.datetime(int(year), 1, 1) + _dt.timedelta(days=int(doy) - 1)
        else:
            base = _dt.datetime(int(year), int(mon), int(day))
        hh_i, mm_i, ss_i = int(hh), int(mm), int(ss)
        if hh_i > 23 or mm_i > 59 or ss_i > 60:
            return None
        d = base + _dt.timedelta(hours=hh_i, minutes=mm_i, seconds=ss_i)
    except ValueError:
        return None
    ps = int((frac or "0")[:12].ljust(12, "0"))
    return d, ps


def _epochs_to_tdb(texts: list[str], system: str, where: list[str]) -> FloatArray:
    parsed = []
    for txt, loc in zip(texts, where, strict=True):
        p = _parse_calendar(txt)
        if p is None:
            raise OEMFormatError(f"{loc}: epoch {txt!r}: expected YYYY-MM-DDThh:mm:ss[.f] or "
                                 "YYYY-DDDThh:mm:ss[.f]")
        parsed.append(p)
    if system == "TDB":
        out = np.empty(len(parsed))
        for i, (d, ps) in enumerate(parsed):
            delta = d - _J2000_TDB
            out[i] = (delta.days * 86400 + delta.seconds) + ps * 1e-12
        return out
    from astropy.time import Time

    iso = [d.strftime("%Y-%m-%dT%H:%M:%S") for d, _ in parsed]
    frac = np.array([ps * 1e-12 for _, ps in parsed])
    t = Time(iso, format="isot", scale=system.lower())
    tdb = t.tdb
    return ((tdb.jd1 - J2000_JD) + tdb.jd2) * DAY + frac


# --------------------------------------------------------------------------- writing
def format_oem(traj: Trajectory, center: str = "EARTH-MOON BARYCENTER",
               originator: str = "STARNAV", comments: Iterable[str] = (),
               ephemeris: Ephemeris | None = None,
               creation_date: str | None = None) -> str:
    """OEM KVN text of a trajectory (module docstring for the layout).

    Parameters
    ----------
    traj : Trajectory
        EMB-centred J2000 states [m, m/s] at TDB epochs.
    center : str
        ``EARTH-MOON BARYCENTER`` (default), ``MOON`` or ``EARTH``; non-EMB centres are
        converted with the ephemeris.
    originator : str
    comments : iterable of str
        Written as ``COMMENT`` lines in the header.
    ephemeris : Ephemeris, optional
        For a non-EMB centre; default DE421.
    creation_date : str, optional
        UTC ISO string; default now.
    """
    key = _CENTER_ALIASES.get(center.strip().upper())
    if key not in _CENTER_NAMES:
        raise OEMFormatError(f"center {center!r}: expected one of "
                             f"{', '.join(_CENTER_NAMES.values())}")
    states = traj.states.copy()
    if key != "emb":
        eph = ephemeris or Ephemeris.default()
        states -= eph.state(key, traj.times, center="emb")
    if creation_date is None:
        creation_date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S")
    name = traj.object_name.strip() or "UNKNOWN"
    lines = ["CCSDS_OEM_VERS = 2.0"]
    lines += [f"COMMENT {c}" for c in comments]
    lines += [f"CREATION_DATE = {creation_date}", f"ORIGINATOR = {originator}", "",
              "META_START",
              f"OBJECT_NAME = {name}",
              f"OBJECT_ID = {name}",
              f"CENTER_NAME = {_CENTER_NAMES[key]}",
              "REF_FRAME = ICRF",
              "TIME_SYSTEM = TDB",
              f"START_TIME = {tdb_to_iso(traj.t_start)}",
              f"STOP_TIME = {tdb_to_iso(traj.t_end)}",
              "INTERPOLATION = HERMITE",
              "INTERPOLATION_DEGREE = 3",
              "META_STOP", ""]
    pf, vf = f"{{:.{POSITION_DECIMALS}f}}", f"{{:.{VELOCITY_DECIMALS}f}}"
    for t, x in zip(traj.times, states, strict=True):
        p, v = x[:3] / 1e3, x[3:] / 1e3
        lines.append(" ".join([tdb_to_iso(t)] + [pf.format(c) for c in p]
                              + [vf.format(c) for c in v]))
    return "\n".join(lines) + "\n"


def write_oem(path: str | os.PathLike[str], traj: Trajectory, **kwargs: object) -> Path:
    """Write :func:`format_oem` text to ``path`` (temporary file + rename). Returns the path."""
    text = format_oem(traj, **kwargs)  # type: ignore[arg-type]
    return atomic_write_bytes(path, text.encode("ascii", errors="replace"))


# --------------------------------------------------------------------------- reading
def parse_oem(text: str, source: str = "<string>",
              ephemeris: Ephemeris | None = None) -> Trajectory:
    """Parse OEM KVN text into an EMB-centred J2000 :class:`Trajectory` (SI, TDB).

    Raises
    ------
    OEMFormatError
        Naming ``source``, the line number and what was expected.
    """
    lines = text.splitlines()
    n = len(lines)
    i = 0

    def where(k: int) -> str:
        return f"{source}, line {k + 1}"

    def next_content(k: int) -> int:
        while k < n and (not lines[k].strip() or lines[k].strip().startswith("COMMENT")):
            k += 1
        return k

    def key_values(k: int, stop: str, context: str, at_end: str) -> tuple[dict[str, str], int]:
        """The ``KEY = value`` lines from line ``k`` up to the line ``stop``: the mapping and
        the index of the ``stop`` line."""
        out: dict[str, str] = {}
        while True:
            k = next_content(k)
            if k >= n:
                raise OEMFormatError(at_end)
            s = lines[k].strip()
            if s == stop:
                return out, k
            kv = _key_value(s)
            if kv is None:
                raise OEMFormatError(f"{where(k)}: {s!r}: expected 'KEY = value' {context}")
            out[kv[0]] = kv[1]
            k += 1

    i = next_content(0)
    if i >= n or not re.match(r"^CCSDS_OEM_VERS\s*=\s*[12]\.\d+\s*$", lines[i].strip()):
        raise OEMFormatError(f"{where(min(i, max(n - 1, 0)))}: expected the header line "
                             "'CCSDS_OEM_VERS = 2.0' (or 1.0) first")
    header, i = key_values(i + 1, "META_START", "in the header or META_START",
                           f"{source}: no META_START block: expected at least one segment")
    for k in ("CREATION_DATE", "ORIGINATOR"):
        if k not in header:
            raise OEMFormatError(f"{source}: header: missing {k}")

    all_t: list[FloatArray] = []
    all_x: list[FloatArray] = []
    object_name = None
    while i < n:
        i = next_content(i)
        if i >= n:
            break
        if lines[i].strip() != "META_START":
            raise OEMFormatError(f"{where(i)}: {lines[i].strip()!r}: expected META_START")
        meta_line = i
        meta, i = key_values(i + 1, "META_STOP", "in metadata",
                             f"{where(meta_line)}: META_START without META_STOP")
        i += 1
        for k in _REQUIRED_META:
            if k not in meta:
                raise OEMFormatError(f"{where(meta_line)}: metadata: missing {k}")
        center = _CENTER_ALIASES.get(meta["CENTER_NAME"].upper())
        if center is None:
            raise OEMFormatError(f"{where(meta_line)}: CENTER_NAME = {meta['CENTER_NAME']!r}: "
                                 f"expected one of {', '.join(sorted(_CENTER_ALIASES))}")
        frame = meta["REF_FRAME"].upper()
        if frame not in _FRAMES:
            raise OEMFormatError(f"{where(meta_line)}: REF_FRAME = {meta['REF_FRAME']!r}: "
                                 f"expected one of {', '.join(_FRAMES)}")
        system = meta["TIME_SYSTEM"].upper()
        if system not in _TIME_SYSTEMS:
            raise OEMFormatError(f"{where(meta_line)}: TIME_SYSTEM = {meta['TIME_SYSTEM']!r}: "
                                 f"expected one of {', '.join(_TIME_SYSTEMS)}")
        object_name = object_name or meta["OBJECT_NAME"]
        # data lines
        ep_txt: list[str] = []
        ep_loc: list[str] = []
        vals: list[list[float]] = []
        while i < n:
            s = lines[i].strip()
            if not s or s.startswith("COMMENT"):
                i += 1
                continue
            if s == "META_START":
                break
            if s == "COVARIANCE_START":
                start = i
                while i < n and lines[i].strip() != "COVARIANCE_STOP":
                    i += 1
                if i >= n:
                    raise OEMFormatError(f"{where(start)}: COVARIANCE_START without "
                                         "COVARIANCE_STOP")
                i += 1
                continue
            parts = s.split()
            if len(parts) not in (7, 10):
                raise OEMFormatError(f"{where(i)}: {s!r}: expected an epoch and 6 (or 9) "
                                     "numbers: X Y Z [km] X_DOT Y_DOT Z_DOT [km/s]")
            try:
                nums = [float(p) for p in parts[1:7]]
                if len(parts) == 10:
                    [float(p) for p in parts[7:]]
            except ValueError:
                raise OEMFormatError(f"{where(i)}: {s!r}: expected numbers after the "
                                     "epoch") from None
            if not all(np.isfinite(nums)):
                raise OEMFormatError(f"{where(i)}: {s!r}: expected finite numbers")
            ep_txt.append(parts[0])
            ep_loc.append(where(i))
            vals.append(nums)
            i += 1
        if not vals:
            raise OEMFormatError(f"{where(meta_line)}: segment without data lines")
        t = _epochs_to_tdb(ep_txt, system, ep_loc)
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise OEMFormatError(f"{ep_loc[bad[0] + 1]}: epoch {ep_txt[bad[0] + 1]!r}: "
                                 "expected epochs strictly increasing within a segment")
        x = np.array(vals) * 1e3  # km, km/s -> m, m/s
        if center != "emb":
            eph = ephemeris or Ephemeris.default()
            x = x + eph.state(center, t, center="emb")
        all_t.append(t)
        all_x.append(x)
    times = np.concatenate(all_t)
    states = np.concatenate(all_x)
    # segments may share their boundary epoch: keep the first occurrence
    order = np.argsort(times, kind="stable")
    times, states = times[order], states[order]
    keep = np.concatenate([[True], np.diff(times) > 0])
    if np.sum(keep) < 2:
        raise OEMFormatError(f"{source}: fewer than 2 distinct epochs: expected a trajectory")
    return Trajectory(times[keep], states[keep], object_name or "UNKNOWN",
                      {"source": f"oem:{source}", "header": header})


def _key_value(s: str) -> tuple[str, str] | None:
    if "=" not in s:
        return None
    k, v = s.split("=", 1)
    k, v = k.strip().upper(), v.strip()
    if not re.match(r"^[A-Z_][A-Z0-9_]*$", k) or not v:
        return None
    return k, v


def read_oem(path: str | os.PathLike[str], ephemeris: Ephemeris | None = None) -> Trajectory:
    """Read an OEM KVN file into an EMB-centred J2000 :class:`Trajectory` [m, m/s, TDB s].

    Raises
    ------
    DataFileError
        Missing or unreadable file.
    OEMFormatError
        Malformed content (line number and expectation in the message).
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, "OEM file")
    try:
        text = p.read_text(encoding="ascii", errors="strict")
    except (OSError, UnicodeDecodeError) as err:
        raise OEMFormatError(f"{p}: not a readable ASCII OEM file ({err})") from None
    return parse_oem(text, source=str(p), ephemeris=ephemeris)


#: Continuity of an ephemeris: between consecutive states, the position change may differ from
#: the mean of their velocities times the step by this fraction of the change (plus
#: :data:`JUMP_FLOOR_M`). The trapezoid rule errs by ~2 % of the step on a circular orbit
#: sampled every 30 deg; a state that jumped (a typo, a wrong centre) errs by ~100 %.
JUMP_TOLERANCE = 0.2
JUMP_FLOOR_M = 1000.0


def check_continuous(traj: Trajectory, source: str) -> None:
    """Refuse a trajectory whose positions do not follow its velocities (a state that jumped).

    Raises
    ------
    GeometryError
        Naming ``source``, the first such state's epoch (TDB), how far it is from where its
        neighbour's position and the two velocities put it, and the tolerance.
    """
    t = np.asarray(traj.times, float)
    x = np.asarray(traj.states, float)
    if t.size < 2:
        return
    dt = np.diff(t)[:, None]
    dr = np.diff(x[:, :3], axis=0)
    pred = 0.5 * (x[:-1, 3:] + x[1:, 3:]) * dt
    miss = np.linalg.norm(dr - pred, axis=1)
    tol = JUMP_TOLERANCE * np.maximum(np.linalg.norm(dr, axis=1),
                                      np.linalg.norm(pred, axis=1)) + JUMP_FLOOR_M
    bad = np.flatnonzero(miss > tol)
    if bad.size:
        k = int(bad[0])
        raise GeometryError(
            f"{source}: the state at {tdb_to_iso(float(t[k + 1]), 3)} TDB (state {k + 2} of "
            f"{len(t)} in the span used) is {miss[k] / 1e3:.4g} km from where the state before "
            f"it and their velocities put it: expected a continuous trajectory (within "
            f"{tol[k] / 1e3:.4g} km, {JUMP_TOLERANCE:.0%} of the step)")


def check_outside_moon(traj: Trajectory, source: str, ephemeris: Ephemeris | None = None,
                       radius: float = MOON_RADIUS) -> None:
    """Refuse a trajectory with a state inside the Moon (``|r - r_moon| < radius`` [m]).

    Raises
    ------
    GeometryError
        Naming ``source``, the first such state's epoch (TDB), its distance from the Moon's
        centre and the radius it must stay outside.
    """
    eph = ephemeris or Ephemeris.default()
    rng = traj.moon_range(eph)
    bad = np.flatnonzero(rng < radius)
    if bad.size:
        k = int(bad[0])
        raise GeometryError(
            f"{source}: the state at {tdb_to_iso(float(traj.times[k]), 3)} TDB (state {k + 1} "
            f"of {len(traj)} in the span used) is {rng[k] / 1e3:.0f} km from the Moon's centre, "
            f"inside the Moon: expected every position at least the Moon's radius "
            f"({radius / 1e3:.1f} km) from its centre")
