"""Star electrons: a V = 0 A0V star through the AA-STR band against a hand-computed integral."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.errors import ConfigError
from starnav.spectra import AA_STR_BAND_EDGES_NM, AA_STR_QE, AA_STR_TRANSMISSION, sensor_response
from starnav.stars.radiometry import (
    colour_temperature,
    electron_rate,
    electron_rates,
    star_spectrum,
    v_passband,
)

H, C, K = 6.62607015e-34, 2.99792458e8, 1.380649e-23
#: V = 0 flux density [W m^-2 nm^-1] (REFERENCE.md s6; Bessell 1979, PASP 91:589).
F0 = 3.61e-11


def test_v0_a0v_star_through_aa_str_equals_the_hand_integral():
    """Independent computation: Planck at the A0V temperature (Ballesteros 2012 at B - V = 0:
    4600 (1/1.7 + 1/0.62) = 10 125 K), scaled so that its photon-weighted mean over the
    Johnson V passband is F0, then photons through the AA-STR's 12 bands (QE x T, piecewise
    constant) and the preset's pupil (diameter f / N)."""
    cam = Camera.preset("aa-str")
    T = 4600.0 * (1 / 1.7 + 1 / 0.62)
    lam = np.linspace(300.0, 1300.0, 200_001)  # nm, 5 pm steps
    planck = 2 * H * C**2 / (lam * 1e-9) ** 5 / np.expm1(H * C / (lam * 1e-9 * K * T))
    vp = v_passband()
    sv = np.interp(lam, vp.wavelengths, vp.values, left=0, right=0) * lam
    f = planck * F0 / (np.trapezoid(planck * sv, lam) / np.trapezoid(sv, lam))
    edges = np.asarray(AA_STR_BAND_EDGES_NM)
    qt = np.asarray(AA_STR_QE) * np.asarray(AA_STR_TRANSMISSION)
    band = np.clip(np.searchsorted(edges, lam, side="right") - 1, 0, len(qt) - 1)
    resp = np.where((lam >= edges[0]) & (lam <= edges[-1]), qt[band], 0.0)
    photons = f * lam * 1e-9 / (H * C)
    expected = np.trapezoid(photons * resp, lam) * cam.pupil_area
    got = electron_rate(0.0, 0.0, sensor_response("aa-str"), cam.pupil_area)
    assert got == pytest.approx(expected, rel=2e-3), (got, expected)
    # REFERENCE.md s6 estimate: ~1e7 e-/s through the AA-STR aperture and band
    assert 0.7e7 < got < 1.4e7


def test_zero_point_at_550_nm_and_magnitude_scale():
    s0 = star_spectrum(0.0, 0.0)
    assert s0(np.array([550.0]))[0] == pytest.approx(F0, rel=0.01)
    r = sensor_response("aa-str")
    assert electron_rate(5.0, 0.0, r, 1.0) / electron_rate(0.0, 0.0, r, 1.0) == \
        pytest.approx(10 ** (-2.0), rel=1e-12)


def test_colour_temperature_ballesteros_2012():
    # the Sun, B - V = 0.65: 5 778 K (Ballesteros 2012, EPL 97:34008, who quotes it)
    assert colour_temperature(0.65) == pytest.approx(5778.4, abs=0.5)
    assert colour_temperature(0.0) == pytest.approx(10125.2, abs=0.5)
    with pytest.raises(ConfigError, match="b_v"):
        colour_temperature(np.nan)


def test_red_star_gives_more_electrons_in_the_red_band_at_equal_v():
    """At equal V a red star puts more photons into the AA-STR's 425-1025 nm band than a
    blue one (its flux rises towards the band's red half)."""
    r = sensor_response("aa-str")
    assert electron_rate(0.0, 1.5, r, 1.0) > 1.3 * electron_rate(0.0, 0.0, r, 1.0)


def test_vectorised_rates_equal_band_integrals():
    r = sensor_response("amie")
    v = np.array([-1.0, 2.0, 6.5])
    bv = np.array([-0.2, 0.6, 1.7])
    many = electron_rates(v, bv, r, 0.02)
    one = [electron_rate(a, b, r, 0.02) for a, b in zip(v, bv, strict=True)]
    np.testing.assert_allclose(many, one, rtol=1e-12)
