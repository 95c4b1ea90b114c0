"""Star radiometry: spectral irradiance at the aperture from V and B - V, and electrons.

1. Temperature from colour (:func:`colour_temperature`, Ballesteros 2012, eq. 14).
2. Shape: a black body of that temperature on :data:`STAR_GRID_NM`, piecewise linear.
3. Scale: the photon-weighted mean flux density in Johnson V (:func:`v_passband`) equals
   :data:`V_ZERO_POINT_W_M2_NM` ``10^(-0.4 V)``.
4. Electrons through the same sensor response as the Moon (:func:`electron_rate`,
   :func:`electron_rates`).

A black body leaves out absorption lines, the Balmer jump and the bands of M stars; the result
against Vega's CALSPEC spectrum: docs/stars.md.

References
----------
B. Ballesteros (2012), "New insights into black bodies", EPL 97, 34008.
M. S. Bessell (1979), PASP 91, 589; M. S. Bessell, F. Castelli and B. Plez (1998), A&A 333,
231, Table A2 (the V zero point).

Index
-----
:func:`star_spectrum`, :func:`star_spectra`, :func:`electron_rate`, :func:`electron_rates`,
:func:`colour_temperature`, :func:`v_passband`.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

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
