"""Solar spectrum, sensor spectral response and band integrals.

Everything is tabulated on wavelength grids in nm and treated as **piecewise linear** between
samples; integrals use the trapezoid rule on the same samples, which is the exact integral of that
piecewise-linear function. The renderer is handed the very same tables, so the band integrals
reported here and the per-pixel values it returns share one definition.

Quantities and units
--------------------
* Solar spectral irradiance ``E(lambda)`` [W m^-2 nm^-1] at a distance ``d`` from the Sun,
  scaled from 1 AU by ``(1 AU / d)^2``.
* Sensor response ``S(lambda) = QE(lambda) T(lambda)`` [e-/photon].
* Band irradiance ``E_band = integral E dlambda`` over the sensor band [W m^-2].
* Photo-electron irradiance ``E_e = integral E QE T lambda / (h c) dlambda`` [e- s^-1 m^-2].

Sources: ASTM G-173 extraterrestrial spectrum as colour-science ships it, packaged in
``data/sun`` (280-4000 nm; it integrates to 1347.9 W/m^2); IAU 2015 nominal TSI 1361 W/m^2;
Planck's law for the optional black body. The AA-STR QE and optics transmission are the
ABRAM AA-STR configuration (docs/facts.md section 1): 12 bands of 50 nm from 425 to 1025 nm,
piecewise constant.

Example
-------
>>> from starnav.spectra import solar_spectrum, sensor_response, band_integrals
>>> sun, resp = solar_spectrum(), sensor_response()
>>> bi = band_integrals(sun, resp)
>>> round(bi.electron_irradiance / 1e20, 2)   # e- s^-1 m^-2 at 1 AU (docs/facts.md: 7.06e20)
7.06
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from pydantic import Field

from starnav.config_base import StrictModel
from starnav.constants import AU, PLANCK_H, SPEED_OF_LIGHT, SUN_RADIUS, SUN_TEFF, TSI_IAU2015
from starnav.data import packaged_path
from starnav.errors import ConfigError, UnknownNameError
from starnav.fields import PositiveFloat
from starnav.typing import FloatArray

#: Half-width [nm] of the vertical steps used to tabulate piecewise-constant band tables.
STEP_HALF_WIDTH_NM = 1e-3


@dataclass(frozen=True)
class Spectrum:
    """A tabulated spectrum, piecewise linear between samples, zero outside.

    Parameters
    ----------
    wavelengths : (n,) array
        Strictly non-decreasing wavelengths [nm] (a repeated pair of wavelengths is not allowed;
        steps are tabulated with a tiny width, :data:`STEP_HALF_WIDTH_NM`).
    values : (n,) array
        Values in ``unit``.
    unit : str
        Free text, e.g. ``"W m^-2 nm^-1"``.
    """

    wavelengths: FloatArray
    values: FloatArray
    unit: str = ""

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelengths, dtype=float)
        val = np.asarray(self.values, dtype=float)
        if wl.ndim != 1 or wl.shape != val.shape or wl.size < 2:
            raise ConfigError("spectrum", f"{wl.shape} vs {val.shape}",
                              "1-D wavelength and value arrays of equal length >= 2")
        if np.any(np.diff(wl) <= 0):
            raise ConfigError("spectrum.wavelengths_nm", wl.tolist()[:8],
                              "strictly increasing wavelengths")
        if not np.all(np.isfinite(val)):
            raise ConfigError("spectrum.values", val.tolist()[:8], "finite values")
        object.__setattr__(self, "wavelengths", wl)
        object.__setattr__(self, "values", val)

    def __call__(self, wavelengths: FloatArray) -> FloatArray:
        """Values at ``wavelengths`` [nm] (linear interpolation, zero outside)."""
        return np.interp(wavelengths, self.wavelengths, self.values, left=0.0, right=0.0)

    def integral(self) -> float:
        """Integral over wavelength [unit x nm]."""
        return float(np.trapezoid(self.values, self.wavelengths))

    def scaled(self, factor: float) -> Spectrum:
        return Spectrum(self.wavelengths, self.values * factor, self.unit)


def product(a: Spectrum, b: Spectrum, unit: str = "") -> Spectrum:
    """Pointwise product on the union of both grids, restricted to their common support."""
    lo = max(a.wavelengths[0], b.wavelengths[0])
    hi = min(a.wavelengths[-1], b.wavelengths[-1])
    if hi <= lo:
        raise ConfigError("spectrum", (lo, hi), "overlapping wavelength ranges")
    grid = np.union1d(a.wavelengths, b.wavelengths)
    grid = grid[(grid >= lo) & (grid <= hi)]
    return Spectrum(grid, a(grid) * b(grid), unit)


# --------------------------------------------------------------------------- the Sun
#: The ASTM G-173-03 extraterrestrial spectrum, package-relative: colour-science's
#: ``SD_ASTMG173_ETR`` copied by ``tools/package_astm_g173.py`` (importing ``colour`` to read
#: it took seconds at every worker start).
ASTM_G173_FILE = "sun/astm_g173_etr.csv"


@lru_cache(maxsize=1)
def _astm_g173() -> Spectrum:
    table = np.loadtxt(packaged_path(ASTM_G173_FILE), delimiter=",", skiprows=1, ndmin=2)
    return Spectrum(table[:, 0], table[:, 1], "W m^-2 nm^-1")


def planck_spectral_radiance(wavelength_nm: FloatArray, temperature: float) -> FloatArray:
    """Black-body spectral radiance [W m^-2 sr^-1 nm^-1] (Planck's law)."""
    lam = np.asarray(wavelength_nm, float) * 1e-9
    x = PLANCK_H * SPEED_OF_LIGHT / (lam * 1.380649e-23 * temperature)
    b = 2.0 * PLANCK_H * SPEED_OF_LIGHT**2 / lam**5 / np.expm1(x)
    return b * 1e-9


SOLAR_SPECTRA = ("astm-g173", "blackbody")


def solar_spectrum(
    name: str = "astm-g173",
    distance: float = AU,
    tsi: float | None = None,
    temperature: float = SUN_TEFF,
) -> Spectrum:
    """Solar spectral irradiance at ``distance`` [m] from the Sun [W m^-2 nm^-1].

    Parameters
    ----------
    name : {"astm-g173", "blackbody"}
        ASTM G-173 extraterrestrial spectrum (colour-science), or a black body of
        ``temperature`` [K] seen under the solid angle of the Sun at 1 AU.
    distance : float
        Sun to target distance [m]; the spectrum scales as ``(1 AU / distance)^2``.
    tsi : float, optional
        Rescale so that the spectrum integrates to ``tsi`` [W m^-2] at 1 AU (e.g. 1361).
    """
    if not (math.isfinite(distance) and distance > 0):
        raise ConfigError("sun.distance", distance, "a finite distance > 0 m")
    if name == "astm-g173":
        sp = _astm_g173()
    elif name == "blackbody":
        wl = np.arange(200.0, 4000.0 + 0.5, 1.0)
        omega = math.pi * (SUN_RADIUS / AU) ** 2  # small-angle solid angle of the disc [sr]
        sp = Spectrum(wl, planck_spectral_radiance(wl, temperature) * omega, "W m^-2 nm^-1")
        if tsi is None:
            tsi = TSI_IAU2015
    else:
        raise UnknownNameError("solar spectrum", name, SOLAR_SPECTRA)
    if tsi is not None:
        if not (math.isfinite(tsi) and tsi > 0):
            raise ConfigError("sun.tsi_w_m2", tsi, "a finite irradiance > 0 W/m^2")
        sp = sp.scaled(tsi / sp.integral())
    return sp.scaled((AU / distance) ** 2)


# --------------------------------------------------------------------------- the sensor
#: AA-STR MK II spectral response (ABRAM AA-STR configuration; docs/facts.md section 1):
#: band edges [nm], quantum efficiency and optics transmission per 50 nm band.
AA_STR_BAND_EDGES_NM = tuple(float(x) for x in range(425, 1026, 50))
AA_STR_QE = (0.35, 0.43, 0.46, 0.45, 0.42, 0.37, 0.30, 0.23, 0.16, 0.09, 0.04, 0.02)
AA_STR_TRANSMISSION = (0.41, 0.687, 0.915, 0.954, 0.967, 0.977, 0.979, 0.982, 0.984, 0.987,
                       0.989, 0.992)

SENSOR_PRESETS = {"aa-str": (AA_STR_BAND_EDGES_NM, AA_STR_QE, AA_STR_TRANSMISSION)}

#: SMART-1 AMIE NONE filter: the measured spectral curve (optics and filter transmission, per
#: mille), package-relative table and the scale of its ``NONE`` column (per mille -> fraction).
AMIE_RESPONSE_TABLE = "amie/calib/amie_spectral_response_none.csv"
AMIE_RESPONSE_SCALE = 1e-3
#: AMIE quantum efficiency before the stellar calibration: the AMIE user manual's "efficiency
#: > 15 % at 640 nm", as the ABRAM AMIE validation applies it (``andrepiz/abram``
#: test/validation/amie/validation_amie.yml: QE 0.15 in every band times the measured curve as
#: transmittance). Kept for reference: starnav uses the QE measured on Vega (0.212, see
#: :func:`amie_quantum_efficiency`), which the manual's lower bound brackets.
AMIE_QUANTUM_EFFICIENCY_MANUAL = 0.15


@lru_cache(maxsize=1)
def amie_quantum_efficiency() -> float:
    """The AMIE's flat quantum efficiency [e-/photon], measured on Vega (frame 040326, 200 ms)
    against its CALSPEC spectrum through the measured NONE curve: the packaged
    ``amie/vega_calibration.json`` written by ``tools/calibrate_amie_vega.py``
    (:mod:`starnav.reference.amie.vega`)."""
    return float(json.loads(packaged_path("amie/vega_calibration.json").read_text())
                 ["quantum_efficiency"])


@lru_cache(maxsize=1)
def amie_none_response() -> Spectrum:
    """The SMART-1 AMIE NONE-filter system response ``QE x T`` [e-/photon], 400-1100 nm.

    ``T`` is the measured curve (39 samples, piecewise linear, zero outside its support), read
    lazily from the packaged table :data:`AMIE_RESPONSE_TABLE`: column ``Lambda`` [nm], column
    ``NONE`` [per mille] (source: ``andrepiz/abram`` test/validation/amie,
    ``get_amie_spectral_response.m`` scales the column by 1e-3 and uses it as the
    transmittance); ``QE`` is flat, :func:`amie_quantum_efficiency` (measured on Vega); the
    instrument kernel ``SMART1_AMIE_V01.TI`` quotes the band as centre 800 nm, width 700 nm.
    """
    path = packaged_path(AMIE_RESPONSE_TABLE)
    table = np.loadtxt(path, delimiter=",", comments="#", skiprows=2, ndmin=2)
    return Spectrum(table[:, 0], table[:, 1] * AMIE_RESPONSE_SCALE * amie_quantum_efficiency(),
                    "e-/photon")


#: Sensor responses tabulated as samples (piecewise linear), each built lazily by its loader.
SAMPLED_SENSOR_PRESETS = {"amie": amie_none_response}


def banded(edges_nm: FloatArray, values: FloatArray, unit: str = "") -> Spectrum:
    """A piecewise-constant spectrum over bands ``[edges[i], edges[i+1]]``.

    Steps are tabulated with width ``2 * STEP_HALF_WIDTH_NM`` so that the result stays a plain
    piecewise-linear table (what Mitsuba's ``irregular`` spectrum interpolates).
    """
    e = np.asarray(edges_nm, float)
    v = np.asarray(values, float)
    if e.ndim != 1 or v.ndim != 1 or e.size != v.size + 1:
        raise ConfigError("sensor_response", f"{e.size} edges, {v.size} values",
                          "n + 1 band edges for n band values")
    if np.any(np.diff(e) <= 4 * STEP_HALF_WIDTH_NM):
        raise ConfigError("sensor_response.wavelengths_nm", e.tolist(), "increasing band edges")
    h = STEP_HALF_WIDTH_NM
    wl = [e[0]]
    val = [v[0]]
    for i in range(1, e.size - 1):
        wl += [e[i] - h, e[i] + h]
        val += [v[i - 1], v[i]]
    wl.append(e[-1])
    val.append(v[-1])
    return Spectrum(np.array(wl), np.array(val), unit)


@dataclass(frozen=True)
class SensorResponse:
    """Quantum efficiency x optics transmission [e-/photon] over the sensor band."""

    response: Spectrum
    name: str = "custom"

    @property
    def band(self) -> tuple[float, float]:
        """Band limits [nm] (support of the response)."""
        nz = np.nonzero(self.response.values > 0)[0]
        wl = self.response.wavelengths
        lo = wl[max(nz[0] - 1, 0)] if nz.size else wl[0]
        hi = wl[min(nz[-1] + 1, wl.size - 1)] if nz.size else wl[-1]
        return float(lo), float(hi)

    def box(self) -> Spectrum:
        """Unit response over the band: integrates radiance into band radiance."""
        lo, hi = self.band
        return Spectrum(np.array([lo, hi]), np.array([1.0, 1.0]), "-")

    def electrons_per_joule(self) -> Spectrum:
        """``QE T lambda / (h c)`` [e- J^-1]: turns spectral power into photo-electron rate."""
        wl = self.response.wavelengths
        return Spectrum(wl, self.response.values * wl * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT),
                        "e- J^-1")


def sensor_response(
    preset: str | None = "aa-str",
    wavelengths_nm: FloatArray | None = None,
    qe: FloatArray | None = None,
    transmission: FloatArray | None = None,
    kind: str = "bands",
) -> SensorResponse:
    """The sensor's QE x T: a preset, or a table (``bands``: n + 1 edges and n values,
    piecewise constant; ``samples``: n wavelengths and n values, piecewise linear).

    Presets: ``aa-str`` (band table, :data:`SENSOR_PRESETS`) and ``amie`` (the measured SMART-1
    AMIE NONE-filter curve, sampled, :func:`amie_none_response`)."""
    if wavelengths_nm is None:
        if preset is None:
            raise ConfigError("sensor_response", None, "a preset name or a table")
        if preset in SAMPLED_SENSOR_PRESETS:
            return SensorResponse(SAMPLED_SENSOR_PRESETS[preset](), preset)
        try:
            edges, q, t = SENSOR_PRESETS[preset]
        except KeyError:
            raise UnknownNameError("sensor response preset", preset,
                                   [*SENSOR_PRESETS, *SAMPLED_SENSOR_PRESETS]) from None
        return SensorResponse(banded(edges, np.multiply(q, t), "e-/photon"), preset)
    wl = np.asarray(wavelengths_nm, float)
    q = np.ones(wl.size - (kind == "bands")) if qe is None else np.asarray(qe, float)
    t = np.ones_like(q) if transmission is None else np.asarray(transmission, float)
    if q.shape != t.shape:
        raise ConfigError("sensor_response.transmission", t.size, f"{q.size} values like qe")
    for fname, arr in (("qe", q), ("transmission", t)):
        if np.any(arr < 0) or np.any(arr > 1):
            raise ConfigError(f"sensor_response.{fname}", arr.tolist(), "values in [0, 1]")
    if kind == "bands":
        return SensorResponse(banded(wl, q * t, "e-/photon"), "table")
    if kind == "samples":
        if wl.size != q.size:
            raise ConfigError("sensor_response.qe", q.size, f"{wl.size} values (one per sample)")
        return SensorResponse(Spectrum(wl, q * t, "e-/photon"), "table")
    raise UnknownNameError("sensor response kind", kind, ["bands", "samples"])


# --------------------------------------------------------------------------- schema
class SunConfig(StrictModel):
    """Solar spectrum. ``spectrum``: ``astm-g173`` (ASTM E-490/G-173 extraterrestrial, from
    colour-science) or ``blackbody`` (``temperature_k``, scaled to ``tsi_w_m2``)."""

    spectrum: Literal["astm-g173", "blackbody"] = Field(
        "astm-g173", description="solar spectrum: astm-g173 (ASTM E-490/G-173 extraterrestrial) "
        "or blackbody (temperature_k, scaled to tsi_w_m2)")
    tsi_w_m2: PositiveFloat | None = Field(
        None, description="rescale the spectrum to this total irradiance at 1 AU [W/m^2]"
    )
    temperature_k: PositiveFloat = Field(5772.0, description="black-body temperature [K]")


class SensorResponseConfig(StrictModel):
    """Spectral response QE(lambda) x T(lambda). Default: the AA-STR table (docs/facts.md s1).

    Either ``preset`` or a table: ``wavelengths_nm`` band *edges* (n + 1 values) with ``qe``
    and ``transmission`` per band (n values, piecewise constant), or ``wavelengths_nm`` samples
    (n values) with ``qe``/``transmission`` per sample (piecewise linear, ``kind: samples``).
    """

    preset: str | None = Field(
        "aa-str", description="named QE x transmission curve, one of: "
        f"{', '.join([*SENSOR_PRESETS, *SAMPLED_SENSOR_PRESETS])} (aa-str: the AA-STR band "
        "table; amie: the measured SMART-1 AMIE curve); null: the table below")
    kind: Literal["bands", "samples"] = Field(
        "bands", description="how the table is read: bands (wavelengths_nm are n + 1 band edges, "
        "one value per band, piecewise constant) or samples (n wavelengths, one value each, "
        "piecewise linear)")
    wavelengths_nm: tuple[float, ...] | None = Field(
        None, description="band edges or sample wavelengths of the table [nm]; null: the preset")
    qe: tuple[float, ...] | None = Field(
        None, description="quantum efficiency per band or sample [e-/photon], each in [0, 1]; "
        "null: 1")
    transmission: tuple[float, ...] | None = Field(
        None, description="optics transmission per band or sample [-], each in [0, 1]; null: 1")


def sensor_response_from_config(cfg: SensorResponseConfig) -> SensorResponse:
    """:func:`sensor_response` from a :class:`~starnav.config.SensorResponseConfig`."""
    return sensor_response(cfg.preset, cfg.wavelengths_nm, cfg.qe, cfg.transmission, cfg.kind)


def solar_spectrum_from_config(cfg: SunConfig, distance: float = AU) -> Spectrum:
    """:func:`solar_spectrum` from a :class:`~starnav.config.SunConfig`."""
    return solar_spectrum(cfg.spectrum, distance=distance, tsi=cfg.tsi_w_m2,
                          temperature=cfg.temperature_k)


# --------------------------------------------------------------------------- band integrals
@dataclass(frozen=True)
class BandIntegrals:
    """Band integrals of an irradiance spectrum through a sensor response.

    Attributes
    ----------
    irradiance : float
        ``integral E dlambda`` over the sensor band [W m^-2].
    electron_irradiance : float
        ``integral E QE T lambda/(h c) dlambda`` [e- s^-1 m^-2].
    band_nm : tuple
        Band limits [nm].
    """

    irradiance: float
    electron_irradiance: float
    band_nm: tuple[float, float]

    @property
    def electrons_per_joule(self) -> float:
        """Band-averaged conversion ``E_e / E_band`` [e- J^-1] (valid for a grey target)."""
        return self.electron_irradiance / self.irradiance


def band_integrals(sun: Spectrum, response: SensorResponse) -> BandIntegrals:
    """Band irradiance [W m^-2] and photo-electron irradiance [e- s^-1 m^-2] of ``sun``."""
    box = response.box()
    e_band = product(sun, box).integral()
    e_el = product(sun, response.electrons_per_joule()).integral()
    return BandIntegrals(e_band, e_el, response.band)


def lambert_fill_time(sun: Spectrum, response: SensorResponse, etendue: float,
                      albedo: float, full_well: float) -> float:
    """Seconds for a Lambert surface of ``albedo`` lit head-on to fill ``full_well`` [e-]
    through a pixel of ``etendue`` [m^2 sr]: ``FW / (albedo E_e / pi * etendue)``."""
    e_el = band_integrals(sun, response).electron_irradiance
    return full_well / (albedo * e_el / math.pi * etendue)
