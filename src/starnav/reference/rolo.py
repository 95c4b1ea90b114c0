"""The ROLO lunar disc-reflectance model (Kieffer & Stone 2005, model 311g): the real Moon's
brightness, as a reference for everything starnav renders.

ROLO fits the Moon's disc-equivalent reflectance ``A_k`` in 32 bands (350-2384 nm) as one
empirical function of the phase angle, the Sun's selenographic longitude ``Phi`` and the
observer's libration (Eq. 10, Table 4); the irradiance at an observer follows by Eq. 8, with
the per-band Apollo factor (``apollo=True``) of the published irradiances. The API is SI
(radians, metres; wavelengths in nm, linear in ``A`` between band centres); ``Phi > 0`` for
the waxing Moon. The fit covers ``1.55 < g < 97 deg`` seen from Earth: outside it the result is
flagged ``extrapolated`` and a warning is logged. The formula, the sign of ``Phi`` and the
validity in full: docs/methods.md, "starnav.reference.rolo".

References
----------
Kieffer, H. H. & Stone, T. C. (2005), The spectral irradiance of the Moon, AJ 129, 2887-2901,
doi:10.1086/430185 (Eqs. 8 and 10, Table 4: model 311g).

Index
-----
:func:`rolo_reflectance`, :func:`rolo_spectrum`, :func:`rolo_irradiance`,
:class:`RoloIrradiance`, :func:`rolo_geometry`, :class:`RoloGeometry`,
:func:`rolo_irradiance_for_frame`, :func:`rolo_extrapolation`, :func:`rolo_coefficients`,
:class:`RoloCoefficients`.
"""

from __future__ import annotations

import io
import logging
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib.resources import files
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import AU, MOON_RADIUS
from starnav.errors import ConfigError, DataFileError
from starnav.spectra import SensorResponse, Spectrum, band_integrals, product, solar_spectrum
from starnav.typing import FloatArray

if TYPE_CHECKING:
    from starnav.geometry import FrameGeometry

logger = logging.getLogger(__name__)

#: Band centres of ROLO model 311g [nm] (Kieffer & Stone 2005, Table 4); checked against the
#: packaged coefficient file when it is loaded.
ROLO_WAVELENGTHS_NM: FloatArray = np.array([
    350.0, 355.1, 405.0, 412.3, 414.4, 441.6, 465.8, 475.0, 486.9, 544.0, 549.1, 553.8,
    665.1, 693.1, 703.6, 745.3, 763.7, 774.8, 865.3, 872.6, 882.0, 928.4, 939.3, 942.1,
    1059.5, 1243.2, 1538.7, 1633.6, 1981.5, 2126.3, 2250.9, 2383.6,
])
ROLO_WAVELENGTHS_NM.flags.writeable = False

#: Libration coefficients c1..c4 (Table 4): c1, c2 per degree of observer latitude/longitude,
#: c3, c4 per (radian of Phi x degree).
ROLO_C = (0.00034115, -0.0013425, 0.00095906, 0.00066229)
#: Opposition and oscillation constants p1..p4 [deg] (Table 4).
ROLO_P_DEG = (4.06054, 12.8802, -30.5858, 16.7498)
#: Solid angle of the Moon at the reference distance [sr] (Kieffer & Stone 2005, Eq. 8).
ROLO_MOON_SOLID_ANGLE = 6.4177e-5
#: Reference Earth-Moon distance of the irradiance formula [m].
ROLO_REFERENCE_DISTANCE = 384_400e3
#: Phase range of the fit [rad]: 1.55-97 deg.
ROLO_PHASE_RANGE = (math.radians(1.55), math.radians(97.0))
#: Largest angle [rad] between the sub-observer point and the mean sub-Earth point (0, 0) that
#: still counts as a near-side view.
ROLO_NEAR_SIDE_LIMIT = math.pi / 2

_PACKAGE_DIR = ("data", "rolo")
_COEFF_FILE = "rolo_coefficients.csv"
_APOLLO_FILE = "rolo_apollo_correction.csv"
_COEFF_HEADER = ("wavelength_nm", "a0", "a1", "a2", "a3", "b1", "b2", "b3", "d1", "d2", "d3")
_APOLLO_HEADER = ("wavelength_nm", "apollo_factor")


# --------------------------------------------------------------------------- coefficients
@dataclass(frozen=True)
class RoloCoefficients:
    """The per-band coefficients of model 311g (Kieffer & Stone 2005, Table 4).

    Attributes
    ----------
    wavelengths_nm : (32,) array
        Band centres [nm].
    a : (32, 4) array
        ``a_0k..a_3k``, the phase polynomial (g in radians).
    b : (32, 3) array
        ``b_1k..b_3k``, the odd polynomial in Phi (radians).
    d : (32, 3) array
        ``d_1k..d_3k``, the opposition and oscillation terms (dimensionless).
    apollo : (32,) array
        Apollo adjustment factor of each band (published ROLO = A_k x factor).
    """

    wavelengths_nm: FloatArray
    a: FloatArray
    b: FloatArray
    d: FloatArray
    apollo: FloatArray


def _read_table(name: str, header: tuple[str, ...]) -> FloatArray:
    res = files("starnav").joinpath(*_PACKAGE_DIR, name)
    where = "starnav/" + "/".join((*_PACKAGE_DIR, name))
    try:
        text = res.read_text(encoding="utf-8")
    except (FileNotFoundError, OSError) as exc:
        raise DataFileError(f"packaged data file {where!r} is missing from the installed "
                            "starnav (reinstall starnav; see data/rolo/PROVENANCE.md)") from exc
    first, _, body = text.partition("\n")
    got = tuple(h.strip() for h in first.split(","))
    if got != header:
        raise DataFileError(f"{where}: header {got!r}, expected {header!r}")
    table = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2)
    if table.shape != (ROLO_WAVELENGTHS_NM.size, len(header)) or not np.all(np.isfinite(table)):
        raise DataFileError(f"{where}: table of shape {table.shape}, expected "
                            f"{ROLO_WAVELENGTHS_NM.size} finite rows of {len(header)} values")
    if not np.array_equal(table[:, 0], ROLO_WAVELENGTHS_NM):
        raise DataFileError(f"{where}: band centres {table[:, 0].tolist()} differ from "
                            "ROLO_WAVELENGTHS_NM (Kieffer & Stone 2005, Table 4)")
    return table


@lru_cache(maxsize=1)
def rolo_coefficients() -> RoloCoefficients:
    """The packaged model-311g coefficients, read once (``starnav/data/rolo``).

    Raises
    ------
    DataFileError
        A file is missing, or its header, size or band centres are not the expected ones.
    """
    t = _read_table(_COEFF_FILE, _COEFF_HEADER)
    ap = _read_table(_APOLLO_FILE, _APOLLO_HEADER)
    arrays = (t[:, 0], t[:, 1:5], t[:, 5:8], t[:, 8:11], ap[:, 1])
    for arr in arrays:
        arr.flags.writeable = False
    return RoloCoefficients(*(np.ascontiguousarray(a) for a in arrays))


# --------------------------------------------------------------------------- validation
def _wrap(angle: FloatArray) -> FloatArray:
    """Angles wrapped to ``[-pi, pi)``."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _angles(name: str, value: ArrayLike, lo: float, hi: float, expected: str) -> FloatArray:
    x = np.asarray(value, dtype=float)
    bad = ~np.isfinite(x) | (x < lo) | (x > hi)
    if np.any(bad):
        shown = float(x) if x.ndim == 0 else x[bad].tolist()[:8]
        raise ConfigError(name, shown, expected)
    return x


def _distance(name: str, value: float, minimum: float, expected: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(name, value, expected) from None
    if not (math.isfinite(v) and v > minimum):
        raise ConfigError(name, value, expected)
    return v


def _geometry_arrays(phase: ArrayLike, sun_lon: ArrayLike, obs_lat: ArrayLike,
                     obs_lon: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    g = _angles("phase", phase, 0.0, math.pi, "a phase angle in [0, pi] rad")
    s = _angles("sun_lon", sun_lon, -np.inf, np.inf, "a finite longitude [rad]")
    t = _angles("obs_lat", obs_lat, -math.pi / 2, math.pi / 2,
                "a latitude in [-pi/2, pi/2] rad")
    p = _angles("obs_lon", obs_lon, -np.inf, np.inf, "a finite longitude [rad]")
    g, s, t, p = np.broadcast_arrays(g, _wrap(s), t, _wrap(p))
    return g, s, t, p


def rolo_extrapolation(phase: ArrayLike, obs_lat: ArrayLike = 0.0,
                       obs_lon: ArrayLike = 0.0) -> str | None:
    """Why ROLO is extrapolated at this geometry, or ``None`` inside its fit range.

    Parameters
    ----------
    phase : float or array
        Phase angle(s) [rad].
    obs_lat, obs_lon : float or array
        Selenographic latitude and east longitude of the observer [rad].

    Returns
    -------
    str or None
        A sentence naming the first violated limit (phase outside 1.55-97 deg, or sub-observer
        point more than 90 deg from (0, 0), i.e. off the near side) for any element.
    """
    g, _, t, p = _geometry_arrays(phase, 0.0, obs_lat, obs_lon)
    lo, hi = ROLO_PHASE_RANGE
    out = (g < lo) | (g > hi)
    if np.any(out):
        deg = np.degrees(g[out])
        return (f"phase {deg.ravel()[0]:.2f} deg is outside the ROLO fit range "
                f"{math.degrees(lo):.2f}-{math.degrees(hi):.0f} deg")
    separation = np.arccos(np.clip(np.cos(t) * np.cos(p), -1.0, 1.0))  # from (0, 0)
    off = separation >= ROLO_NEAR_SIDE_LIMIT
    if np.any(off):
        i = np.flatnonzero(off.ravel())[0]
        return (f"sub-observer point ({math.degrees(t.ravel()[i]):.1f}, "
                f"{math.degrees(p.ravel()[i]):.1f}) deg is off the near side (more than "
                f"{math.degrees(ROLO_NEAR_SIDE_LIMIT):.0f} deg from (0, 0)); ROLO was fitted "
                "to Earth-based views only")
    return None


def _warn(reason: str | None) -> None:
    if reason is not None:
        logger.warning("ROLO model extrapolated: %s", reason)


# --------------------------------------------------------------------------- reflectance
def _ln_reflectance(c: RoloCoefficients, g: FloatArray, sun_lon: FloatArray,
                    obs_lat: FloatArray, obs_lon: FloatArray) -> FloatArray:
    """``ln A_k`` of Eq. 10 for every band: shape ``g.shape + (32,)``; inputs in radians."""
    g = g[..., None]
    Phi = sun_lon[..., None]
    theta = np.degrees(obs_lat)[..., None]
    phi = np.degrees(obs_lon)[..., None]
    g_deg = np.degrees(g)
    a, b, d = c.a, c.b, c.d
    c1, c2, c3, c4 = ROLO_C
    p1, p2, p3, p4 = ROLO_P_DEG
    phase_poly = a[:, 0] + g * (a[:, 1] + g * (a[:, 2] + g * a[:, 3]))
    Phi2 = Phi * Phi
    sun_poly = Phi * (b[:, 0] + Phi2 * (b[:, 1] + Phi2 * b[:, 2]))
    libration = c1 * theta + c2 * phi + c3 * Phi * theta + c4 * Phi * phi
    opposition = (d[:, 0] * np.exp(-g_deg / p1) + d[:, 1] * np.exp(-g_deg / p2)
                  + d[:, 2] * np.cos((g_deg - p3) / p4))
    return phase_poly + sun_poly + libration + opposition


def _check_wavelengths(wavelength_nm: ArrayLike) -> FloatArray:
    wl = np.asarray(wavelength_nm, dtype=float)
    lo, hi = ROLO_WAVELENGTHS_NM[0], ROLO_WAVELENGTHS_NM[-1]
    bad = ~np.isfinite(wl) | (wl < lo) | (wl > hi)
    if np.any(bad):
        shown = float(wl) if wl.ndim == 0 else wl[bad].tolist()[:8]
        raise ConfigError("wavelength_nm", shown,
                          f"wavelengths within the ROLO table {lo:g}-{hi:g} nm")
    return wl


def _interp_bands(values: FloatArray, wl: FloatArray) -> FloatArray:
    """Linear interpolation along the last (band) axis at ``wl`` [nm]: ``shape[:-1] + wl.shape``."""
    W = ROLO_WAVELENGTHS_NM
    i = np.clip(np.searchsorted(W, wl, side="right") - 1, 0, W.size - 2)
    t = (wl - W[i]) / (W[i + 1] - W[i])
    return values[..., i] * (1.0 - t) + values[..., i + 1] * t


def rolo_reflectance(
    phase: ArrayLike,
    sun_lon: ArrayLike,
    obs_lat: ArrayLike = 0.0,
    obs_lon: ArrayLike = 0.0,
    wavelength_nm: ArrayLike | None = None,
    apollo: bool = False,
) -> FloatArray:
    """ROLO disc-equivalent reflectance ``A`` [-] (Kieffer & Stone 2005, Eq. 10).

    Parameters
    ----------
    phase : float or array
        Phase angle ``g`` (Sun-Moon-observer angle) [rad], in ``[0, pi]``.
    sun_lon : float or array
        Selenographic east longitude of the subsolar point, ``Phi`` [rad]; positive for the
        waxing Moon seen from Earth. Wrapped to ``[-pi, pi)``.
    obs_lat, obs_lon : float or array
        Selenographic latitude and east longitude of the sub-observer point [rad]; (0, 0) is
        the mean sub-Earth point.
    wavelength_nm : float or array, optional
        Wavelengths [nm] in 350-2383.6 nm, ``A`` linear between band centres; ``None``: the 32
        bands of :data:`ROLO_WAVELENGTHS_NM`.
    apollo : bool
        Multiply by the per-band Apollo factor (the published ROLO scale) before interpolating.

    Returns
    -------
    ndarray
        Shape ``broadcast(phase, sun_lon, obs_lat, obs_lon).shape`` followed by ``(32,)`` or by
        the shape of ``wavelength_nm`` (a 0-d result is a NumPy scalar). Outside the fit range
        (:func:`rolo_extrapolation`) it is computed anyway and a warning is logged.

    Raises
    ------
    ConfigError
        A phase outside ``[0, pi]``, a latitude outside ``[-pi/2, pi/2]``, a non-finite angle,
        or a wavelength outside the table.
    """
    g, s, t, p = _geometry_arrays(phase, sun_lon, obs_lat, obs_lon)
    wl = None if wavelength_nm is None else _check_wavelengths(wavelength_nm)
    _warn(rolo_extrapolation(g, t, p))
    c = rolo_coefficients()
    A = np.exp(_ln_reflectance(c, g, s, t, p))
    if apollo:
        A = A * c.apollo
    if wl is not None:
        A = _interp_bands(A, wl)
    return A[()]


def rolo_spectrum(
    phase: float,
    sun_lon: float,
    obs_lat: float = 0.0,
    obs_lon: float = 0.0,
    apollo: bool = False,
) -> Spectrum:
    """ROLO disc-equivalent reflectance ``A(lambda)`` [-] as a :class:`~starnav.spectra.Spectrum`.

    Sampled at the 32 band centres (350-2383.6 nm) and, like every starnav spectrum, piecewise
    linear between them and zero outside. Arguments as :func:`rolo_reflectance` (scalars).
    """
    for name, v in (("phase", phase), ("sun_lon", sun_lon), ("obs_lat", obs_lat),
                    ("obs_lon", obs_lon)):
        if np.ndim(v) != 0:
            raise ConfigError(name, np.shape(v), "a scalar angle [rad] (one geometry)")
    A = rolo_reflectance(phase, sun_lon, obs_lat, obs_lon, apollo=apollo)
    return Spectrum(np.array(ROLO_WAVELENGTHS_NM), np.asarray(A, float), "-")


# --------------------------------------------------------------------------- irradiance
@dataclass(frozen=True)
class RoloIrradiance:
    """The Moon's irradiance at an observer by the ROLO model, and the inputs that gave it.

    Attributes
    ----------
    irradiance : float
        ``integral I(lambda) dlambda`` over ``band_nm`` [W m^-2].
    electron_irradiance : float or None
        ``integral I QE T lambda / (h c) dlambda`` [e- s^-1 m^-2] (``None`` without response).
    band_nm : tuple of float
        Integration band [nm].
    spectrum : Spectrum
        Spectral irradiance ``I(lambda)`` at the observer [W m^-2 nm^-1] over the ROLO table.
    phase, sun_lon, obs_lat, obs_lon : float
        Geometry [rad] (longitudes wrapped to ``[-pi, pi)``).
    sun_distance, observer_distance : float
        Sun-Moon and observer-Moon centre distances [m].
    apollo, extrapolated : bool
        Whether the Apollo factors were applied; the geometry is outside the fit range.
    reason : str or None
        :func:`rolo_extrapolation`'s sentence.
    """

    irradiance: float
    electron_irradiance: float | None
    band_nm: tuple[float, float]
    spectrum: Spectrum
    phase: float
    sun_lon: float
    obs_lat: float
    obs_lon: float
    sun_distance: float
    observer_distance: float
    apollo: bool = False
    extrapolated: bool = False
    reason: str | None = None


def rolo_irradiance(
    phase: float,
    sun_lon: float,
    obs_lat: float,
    obs_lon: float,
    sun_distance_m: float,
    observer_distance_m: float,
    sun_1au: Spectrum | None = None,
    response: SensorResponse | None = None,
    *,
    band_nm: tuple[float, float] | None = None,
    apollo: bool = False,
) -> RoloIrradiance:
    """Irradiance of the Moon at an observer, band-integrated (Kieffer & Stone 2005, Eq. 8).

    ``I(lambda) = A(lambda) Omega_M E(lambda) / pi (1 AU / D_sun)^2 (384 400 km / D_obs)^2``,
    with ``Omega_M = 6.4177e-5 sr``; the band integrals are those of
    :func:`starnav.spectra.band_integrals`.

    Parameters
    ----------
    phase, sun_lon, obs_lat, obs_lon : float
        Geometry [rad], as :func:`rolo_reflectance`.
    sun_distance_m, observer_distance_m : float
        Sun and observer to Moon-centre distances [m] (the observer's above the Moon radius).
    sun_1au : Spectrum, optional
        Solar spectral irradiance **at 1 AU** [W m^-2 nm^-1]; default the ASTM G-173
        extraterrestrial spectrum (:func:`starnav.spectra.solar_spectrum`).
    response : SensorResponse, optional
        Sensor ``QE x T`` [e-/photon]: sets the band (within the ROLO table) and gives the
        electron irradiance.
    band_nm : (float, float), optional
        Integration band [nm] without ``response``; default the whole table.
    apollo : bool
        Apply the Apollo factors (the published ROLO scale).

    Returns
    -------
    RoloIrradiance

    Raises
    ------
    ConfigError
        Bad geometry (see :func:`rolo_reflectance`), a distance that is not finite and positive
        (the observer's must exceed the Moon radius), or a band outside the ROLO table or the
        solar spectrum.
    """
    d_sun = _distance("sun_distance_m", sun_distance_m, 0.0, "a finite distance > 0 m")
    d_obs = _distance("observer_distance_m", observer_distance_m, MOON_RADIUS,
                      f"a finite distance > the Moon radius {MOON_RADIUS:g} m")
    if response is not None and band_nm is not None:
        raise ConfigError("band_nm", band_nm, "None when a sensor response is given "
                          "(the response sets the band)")
    A = rolo_spectrum(phase, sun_lon, obs_lat, obs_lon, apollo=apollo)
    sun = solar_spectrum() if sun_1au is None else sun_1au
    scale = (ROLO_MOON_SOLID_ANGLE / math.pi * (AU / d_sun) ** 2
             * (ROLO_REFERENCE_DISTANCE / d_obs) ** 2)
    spec = product(sun, A, "W m^-2 nm^-1").scaled(scale)
    support = (float(spec.wavelengths[0]), float(spec.wavelengths[-1]))

    if response is not None:
        band = response.band
        field = "response.band"
    else:
        band = support if band_nm is None else (float(band_nm[0]), float(band_nm[1]))
        field = "band_nm"
    if not (support[0] <= band[0] < band[1] <= support[1]):
        raise ConfigError(field, band, f"an increasing band within {support[0]:g}-"
                          f"{support[1]:g} nm (the ROLO table and the solar spectrum)")
    if response is not None:
        bi = band_integrals(spec, response)
        e_band, e_el = bi.irradiance, bi.electron_irradiance
    else:
        box = Spectrum(np.array(band), np.ones(2), "-")
        e_band, e_el = product(spec, box).integral(), None

    g, s, t, p = (float(x) for x in _geometry_arrays(phase, sun_lon, obs_lat, obs_lon))
    reason = rolo_extrapolation(g, t, p)
    return RoloIrradiance(
        irradiance=float(e_band), electron_irradiance=None if e_el is None else float(e_el),
        band_nm=(float(band[0]), float(band[1])), spectrum=spec, phase=g, sun_lon=s,
        obs_lat=t, obs_lon=p, sun_distance=d_sun, observer_distance=d_obs, apollo=apollo,
        extrapolated=reason is not None, reason=reason,
    )


# --------------------------------------------------------------------------- frame geometry
@dataclass(frozen=True)
class RoloGeometry:
    """ROLO's geometry of one frame (SI).

    Attributes
    ----------
    phase : float
        Sun-Moon-observer angle [rad].
    sun_lon, sun_lat : float
        Selenographic east longitude (``Phi``) and latitude of the subsolar point [rad]
        (ROLO uses only the longitude).
    obs_lon, obs_lat : float
        Selenographic east longitude and latitude of the sub-observer point [rad].
    sun_distance, observer_distance : float
        Sun to Moon-centre and observer to Moon-centre distances [m].
    """

    phase: float
    sun_lon: float
    sun_lat: float
    obs_lat: float
    obs_lon: float
    sun_distance: float
    observer_distance: float


def _lat_lon(v: FloatArray) -> tuple[float, float]:
    r = float(np.linalg.norm(v))
    lat = math.asin(max(-1.0, min(1.0, float(v[2]) / r)))
    lon = float(_wrap(np.float64(math.atan2(float(v[1]), float(v[0])))))
    return lat, lon


def rolo_geometry(geom: FrameGeometry) -> RoloGeometry:
    """Phase, subsolar and sub-observer points and distances of a frame.

    The Sun and camera positions of :class:`~starnav.geometry.FrameGeometry` are Moon-centred
    inertial; they are rotated into the Moon body-fixed (selenographic) frame with
    ``R_body_to_inertial.T`` (+x at (0, 0), +y at 90 deg E, +z north).

    Parameters
    ----------
    geom : FrameGeometry
        The frame.
    """
    R = np.asarray(geom.R_body_to_inertial, float)
    sun_body = R.T @ np.asarray(geom.sun_position, float)
    obs_body = R.T @ np.asarray(geom.camera_position, float)
    sun_lat, sun_lon = _lat_lon(sun_body)
    obs_lat, obs_lon = _lat_lon(obs_body)
    return RoloGeometry(phase=geom.phase_angle, sun_lon=sun_lon, sun_lat=sun_lat,
                        obs_lat=obs_lat, obs_lon=obs_lon, sun_distance=geom.sun_distance,
                        observer_distance=geom.range)


def rolo_irradiance_for_frame(
    geom: FrameGeometry,
    sun_1au: Spectrum | None = None,
    response: SensorResponse | None = None,
    *,
    band_nm: tuple[float, float] | None = None,
    apollo: bool = False,
) -> RoloIrradiance:
    """:func:`rolo_irradiance` at the geometry of a frame (:func:`rolo_geometry`).

    Parameters as :func:`rolo_irradiance`; the distances are the frame's Sun-Moon distance and
    camera range [m].
    """
    rg = rolo_geometry(geom)
    return rolo_irradiance(rg.phase, rg.sun_lon, rg.obs_lat, rg.obs_lon, rg.sun_distance,
                           rg.observer_distance, sun_1au, response, band_nm=band_nm,
                           apollo=apollo)
