"""Solar spectrum, sensor response and band integrals against published numbers."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from colour.plotting.datasets.astm_g_173 import SD_ASTMG173_ETR

from starnav.constants import AU, TSI_IAU2015
from starnav.errors import ConfigError, UnknownNameError
from starnav.spectra import (
    AA_STR_QE,
    AA_STR_TRANSMISSION,
    band_integrals,
    banded,
    lambert_fill_time,
    sensor_response,
    solar_spectrum,
)


def test_astm_g173_total():
    # docs/facts.md s2: the ASTM G-173 extraterrestrial spectrum integrates to 1347.9 W/m^2
    # over 280-4000 nm.
    assert solar_spectrum().integral() == pytest.approx(1347.9, abs=0.1)


def test_tsi_scaling_and_inverse_square():
    sp = solar_spectrum(tsi=TSI_IAU2015)
    assert sp.integral() == pytest.approx(1361.0, rel=1e-12)
    far = solar_spectrum(tsi=TSI_IAU2015, distance=1.5 * AU)
    assert far.integral() == pytest.approx(1361.0 / 2.25, rel=1e-12)


def test_blackbody_defaults_to_tsi():
    bb = solar_spectrum("blackbody")
    assert bb.integral() == pytest.approx(TSI_IAU2015, rel=1e-12)
    # Wien: peak of the spectral irradiance per nm at b/T = 2.8978e-3/5772 m = 502 nm
    assert bb.wavelengths[np.argmax(bb.values)] == pytest.approx(502.0, abs=1.5)


def test_planck_integrates_to_stefan_boltzmann():
    # integral of B_lambda over all wavelengths = sigma T^4 / pi; seen under the Sun's solid
    # angle at 1 AU this is the TSI: sigma 5772^4 (R_sun/AU)^2 = 1361 W/m^2 (IAU 2015 B3).
    from starnav.constants import SUN_RADIUS
    from starnav.spectra import planck_spectral_radiance

    wl = np.geomspace(50.0, 2e5, 200_000)
    radiance = np.trapezoid(planck_spectral_radiance(wl, 5772.0), wl)
    sigma = 5.670374419e-8
    assert radiance == pytest.approx(sigma * 5772.0**4 / math.pi, rel=1e-5)
    assert radiance * math.pi * (SUN_RADIUS / AU) ** 2 == pytest.approx(1361.0, rel=1e-3)


def test_aa_str_band_integrals_match_reference():
    # docs/facts.md s2: ASTM G-173 with the AA-STR QE x T gives 7.06e20 e- s^-1 m^-2 at 1 AU,
    # 3.07e9 e-/s per pixel for a rho = 0.12 Lambert surface lit head-on, and the 100 ke-
    # well fills in ~33 us.
    bi = band_integrals(solar_spectrum(), sensor_response())
    assert bi.electron_irradiance == pytest.approx(7.06e20, rel=2e-3)
    assert bi.band_nm == (425.0, 1025.0)
    etendue = math.pi * 18e-6**2 / (4 * 1.495575**2)
    per_pixel = 0.12 * bi.electron_irradiance / math.pi * etendue
    assert per_pixel == pytest.approx(3.07e9, rel=2e-3)
    t_fill = lambert_fill_time(solar_spectrum(), sensor_response(), etendue, 0.12, 1e5)
    assert t_fill == pytest.approx(33e-6, rel=0.02)


def test_banded_response_integral_is_exact():
    r = sensor_response()
    expected = 50.0 * float(np.dot(AA_STR_QE, AA_STR_TRANSMISSION))
    assert r.response.integral() == pytest.approx(expected, rel=1e-9)


def test_band_irradiance_is_integral_over_band():
    sun = solar_spectrum()
    wl = sun.wavelengths
    sel = (wl >= 425) & (wl <= 1025)
    direct = np.trapezoid(sun.values[sel], wl[sel])
    assert band_integrals(sun, sensor_response()).irradiance == pytest.approx(direct, rel=1e-9)


def test_custom_table_and_errors():
    r = sensor_response(None, [400, 500, 600], qe=[0.5, 0.25], transmission=[1, 1])
    assert r.response.integral() == pytest.approx(100 * 0.5 + 100 * 0.25, rel=1e-9)
    with pytest.raises(ConfigError, match="sensor_response.qe"):
        sensor_response(None, [400, 500, 600], qe=[1.5, 0.2])
    with pytest.raises(ConfigError):
        banded([400, 500], [0.1, 0.2])
    with pytest.raises(UnknownNameError, match="aa-str"):
        sensor_response("nope")
    with pytest.raises(UnknownNameError, match="astm-g173"):
        solar_spectrum("nope")


def test_packaged_astm_g173_is_colours_table():
    # the packaged CSV (tools/package_astm_g173.py) is colour-science's SD_ASTMG173_ETR bit for
    # bit: the default Sun, hence every render, is the same as when it was read from colour
    sp = solar_spectrum()
    np.testing.assert_array_equal(sp.wavelengths, np.asarray(SD_ASTMG173_ETR.wavelengths, float))
    np.testing.assert_array_equal(sp.values, np.asarray(SD_ASTMG173_ETR.values, float))


def test_solar_spectrum_does_not_import_colour():
    # the point of packaging the table: a worker's first render does not pay colour's import
    code = ("import sys; from starnav.spectra import solar_spectrum; solar_spectrum(); "
            "print('colour' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert out.stdout.strip() == "False"
