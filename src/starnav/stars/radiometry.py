"""Star radiometry: spectral irradiance at the aperture from V and B - V, and electrons.

Technique
---------
1. **Temperature from colour.** ``T = 4600 K (1 / (0.92 (B-V) + 1.7) + 1 / (0.92 (B-V) +
   0.62))`` (Ballesteros 2012, EPL 97:34008, eq. 14: black bodies matched to the colours of
   main-sequence stars; ~10 100 K at B - V = 0, 5 800 K at 0.65, 3 900 K at 1.5).
2. **Shape.** A black body of that temperature, tabulated every 1 nm over
   :data:`STAR_GRID_NM` and piecewise linear between samples (the :mod:`starnav.spectra`
   convention).
3. **Scale: a Vega-based zero point in V.** The spectrum is scaled so that its photon-weighted
   mean flux density in the Johnson V passband, ``<F> = int F S_V lambda dlambda /
   int S_V lambda dlambda``, equals ``F0 10^(-0.4 V)`` with ``F0 = 3.61e-11 W m^-2 nm^-1``,
   the flux density of a V = 0 star (REFERENCE.md s6; Bessell 1979, PASP 91:589; Bessell,
   Castelli & Plez 1998, A&A 333:231, Table A2, give 3.631e-11 at 545 nm). The V passband is
   ``GROUND_JOHNSON_V`` of ``pyphot`` (Bessell's tabulation, 475-740 nm).
4. **Electrons.** The irradiance spectrum goes through the SAME sensor response as the Moon:
   ``rate = A_pupil int F QE T lambda / (h c) dlambda`` [e-/s] is
   :func:`starnav.spectra.band_integrals`' ``electron_irradiance`` times the pupil area
   (:func:`electron_rate`); :func:`electron_rates` does the same integral for many stars at
   once on the same union grid (equal to 1e-12, tested).

What a black body leaves out: absorption lines and the Balmer jump (an A0V star has ~10 %
less flux below 400 nm than its black body; the AA-STR band starts at 425 nm), molecular bands
of M stars. ``docs/stars.md`` compares the result with Vega's CALSPEC spectrum.

Example
-------
>>> from starnav.spectra import sensor_response
>>> from starnav.stars.radiometry import electron_rate
>>> round(electron_rate(0.0, 0.0, sensor_response("aa-str"), 1.0) / 1e9, 2)  # doctest: +SKIP
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from starnav.constants import PLANCK_H, SPEED_OF_LIGHT
from starnav.errors import ConfigError
from starnav.spectra import SensorResponse, Spectrum, band_integrals, planck_spectral_radiance
from starnav.typing import FloatArray

#: Flux density of a V = 0 star [W m^-2 nm^-1] (module step 3).
V_ZERO_POINT_W_M2_NM = 3.61e-11
#: Wavelength grid of the stellar spectra [nm] (covers every sensor preset: 400-1150 nm).
STAR_GRID_NM = np.arange(300.0, 1300.0 + 0.5, 1.0)
#: ``pyphot`` name of the Johnson V passband.
V_PASSBAND = "GROUND_JOHNSON_V"


def colour_temperature(b_v: ArrayLike) -> FloatArray:
    """Black-body temperature [K] of a star of colour ``B - V`` [mag] (Ballesteros 2012)."""
    x = np.asarray(b_v, float)
    if np.any(~np.isfinite(x)) or np.any(x <= -0.5):
        raise ConfigError("stars.b_v", x[np.isfinite(x) == 0].tolist()[:4] or x.min(),
                          "finite B - V > -0.5 mag")
    return 4600.0 * (1.0 / (0.92 * x + 1.7) + 1.0 / (0.92 * x + 0.62))


@lru_cache(maxsize=1)
def v_passband() -> Spectrum:
    """The Johnson V passband (``pyphot`` ``GROUND_JOHNSON_V``), relative response vs nm."""
    import pyphot

    f = pyphot.get_library()[V_PASSBAND]
    wl = np.asarray(f.wavelength.to("nm").value, float)
    return Spectrum(wl, np.asarray(f.transmit, float), "-")


def _v_weights() -> tuple[FloatArray, FloatArray]:
    """The V passband's photon weights ``S_V lambda`` on :data:`STAR_GRID_NM` and their sum
    (trapezoid on the grid)."""
    w = v_passband()(STAR_GRID_NM) * STAR_GRID_NM
    return w, float(np.trapezoid(w, STAR_GRID_NM))


def star_spectra(v: ArrayLike, b_v: ArrayLike) -> FloatArray:
    """Spectral irradiance at the aperture [W m^-2 nm^-1] of stars of magnitude ``V`` and
    colour ``B - V`` [mag] on :data:`STAR_GRID_NM`, shape ``(n, len(grid))`` (steps 1-3)."""
    vv = np.atleast_1d(np.asarray(v, float))
    if np.any(~np.isfinite(vv)):
        raise ConfigError("stars.v", vv.tolist()[:4], "finite V magnitudes")
    temp = np.atleast_1d(colour_temperature(b_v))
    shape = np.broadcast_shapes(vv.shape, temp.shape)
    vv, temp = np.broadcast_to(vv, shape).ravel(), np.broadcast_to(temp, shape).ravel()
    bb = np.stack([planck_spectral_radiance(STAR_GRID_NM, t) for t in temp])
    w, wsum = _v_weights()
    mean = np.trapezoid(bb * w, STAR_GRID_NM, axis=-1) / wsum
    scale = V_ZERO_POINT_W_M2_NM * 10.0 ** (-0.4 * vv) / mean
    return bb * scale[:, None]


def star_spectrum(v: float, b_v: float) -> Spectrum:
    """One star's spectral irradiance at the aperture as a :class:`~starnav.spectra.Spectrum`
    [W m^-2 nm^-1]."""
    return Spectrum(STAR_GRID_NM, star_spectra(v, b_v)[0], "W m^-2 nm^-1")


def electron_rate(v: float, b_v: float, response: SensorResponse, pupil_area: float) -> float:
    """Photo-electrons per second [e-/s] of one star through ``response`` and a pupil of
    ``pupil_area`` [m^2]: :func:`starnav.spectra.band_integrals` (step 4)."""
    _check_area(pupil_area)
    return band_integrals(star_spectrum(v, b_v), response).electron_irradiance * pupil_area


def _check_area(pupil_area: float) -> None:
    if not (math.isfinite(pupil_area) and pupil_area > 0):
        raise ConfigError("camera.pupil_area", pupil_area, "a finite pupil area > 0 m^2")


def electron_rates(v: ArrayLike, b_v: ArrayLike, response: SensorResponse,
                   pupil_area: float) -> FloatArray:
    """:func:`electron_rate` for many stars at once [e-/s]: the same trapezoid on the same
    union grid as :func:`starnav.spectra.product`."""
    _check_area(pupil_area)
    f = star_spectra(v, b_v)
    e = response.electrons_per_joule()
    lo = max(STAR_GRID_NM[0], e.wavelengths[0])
    hi = min(STAR_GRID_NM[-1], e.wavelengths[-1])
    grid = np.union1d(STAR_GRID_NM, e.wavelengths)
    grid = grid[(grid >= lo) & (grid <= hi)]
    fg = np.stack([np.interp(grid, STAR_GRID_NM, row, left=0.0, right=0.0) for row in f])
    return np.trapezoid(fg * e(grid), grid, axis=-1) * pupil_area


def photon_flux_density(wavelength_nm: float, f_lambda: float) -> float:
    """Photons s^-1 m^-2 nm^-1 of a flux density ``f_lambda`` [W m^-2 nm^-1] at
    ``wavelength_nm`` (REFERENCE.md: V = 0 at 550 nm is ~1.0e8)."""
    return f_lambda * wavelength_nm * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT)
