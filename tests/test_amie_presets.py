"""The SMART-1 AMIE camera preset and its NONE-filter spectral response.

Sources of the numbers (next to each test):
* the instrument kernel ``data/amie/calib/SMART1_AMIE_V01.TI`` (keywords ``INS-238110_*``);
* the data README (section amie/): IFOV 9.05e-5 rad, 2.65 deg field, band centre 800 nm,
  width 700 nm (450-1150 nm);
* ``data/amie/calib/amie_spectral_response_none.csv`` (column NONE x 1e-3).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.constants import PLANCK_H, SPEED_OF_LIGHT
from starnav.errors import UnknownNameError
from starnav.spectra import (
    AMIE_RESPONSE_TABLE,
    amie_quantum_efficiency,
    band_integrals,
    sensor_response,
    solar_spectrum,
)

#: Angles quoted to 3 significant digits in the README / IK [deg].
QUOTED_DEG = 0.005
#: Independent quadratures of the same piecewise-linear tables agree to this [-].
QUADRATURE_RTOL = 1e-4


# --------------------------------------------------------------------------- camera
def test_amie_camera_matches_instrument_kernel():
    cam = Camera.preset("amie")
    # INS-238110_PIXEL_SAMPLES / _LINES = 512, _PIXEL_SIZE = 14 um, _FOCAL_LENGTH = 154.7 mm,
    # _F/RATIO = 10.0
    assert (cam.width, cam.height) == (512, 512)
    assert (cam.pitch_x, cam.pitch_y) == (14e-6, 14e-6)
    assert cam.focal_length == pytest.approx(154.7e-3, rel=1e-12)
    assert cam.pupil_diameter == pytest.approx(15.47e-3, rel=1e-12)
    # INS-238110_CCD_CENTER = (256.5, 256.5), 1-based: the 0-based pixel-centre (255.5, 255.5)
    assert (cam.cx, cam.cy) == (256.5 - 1.0, 256.5 - 1.0)
    assert not cam.has_distortion  # IK: "optical distortion ... was not available"


def test_amie_ifov_and_field_match_readme():
    cam = Camera.preset("amie")
    # README amie/: IFOV 9.05e-5 rad (14 um / 154.7 mm = 9.0498e-5), field 2.65 deg
    assert cam.ifov == pytest.approx(9.05e-5, abs=0.005e-5)
    assert cam.fov_x_deg == pytest.approx(2.65, abs=QUOTED_DEG)
    assert math.degrees(cam.fov_y) == pytest.approx(2.65, abs=QUOTED_DEG)
    # INS-238110_FOV_REF_ANGLE = _FOV_CROSS_ANGLE = 1.325 deg: the half-angle to the centres of
    # the edge pixels (the FOV is defined by "the first and last pixels")
    edge = cam.unproject(np.array([[0.0, cam.cy], [cam.cx, 0.0]]))
    for ray in edge:
        assert math.degrees(math.acos(ray[2])) == pytest.approx(1.325, abs=0.001)


def test_amie_preset_is_listed_and_overridable():
    cam = Camera.preset("amie", width=256, height=256)
    assert (cam.cx, cam.cy) == (127.5, 127.5)
    with pytest.raises(UnknownNameError, match="amie"):
        Camera.preset("smart-1")


# --------------------------------------------------------------------------- response
#: the flat QE of the preset: measured on Vega (tests/reference/test_amie_vega.py re-derives it)
QE = amie_quantum_efficiency()

def _table() -> tuple[np.ndarray, np.ndarray]:
    from starnav.data import packaged_path

    t = np.loadtxt(packaged_path(AMIE_RESPONSE_TABLE), delimiter=",", skiprows=2)
    # per mille, times the flat QE measured on Vega (packaged stellar calibration)
    return t[:, 0], t[:, 1] * 1e-3 * QE


def test_amie_response_is_the_packaged_table():
    resp = sensor_response("amie")
    wl, s = _table()
    assert resp.name == "amie"
    np.testing.assert_array_equal(resp.response.wavelengths, wl)
    np.testing.assert_allclose(resp.response.values, s, rtol=1e-15)
    # a fraction (QE x T), T peaking at 0.504 near 790 nm
    assert 0.0 < resp.response.values.min()
    assert resp.response.values.max() == pytest.approx(QE * 0.504)
    # band edges = the table's support
    assert resp.band == (400.0, 1100.0)


def test_amie_response_centre_and_width_vs_readme():
    resp = sensor_response("amie")
    wl, s = resp.response.wavelengths, resp.response.values
    lo, hi = resp.band
    # README / INS-238110_FILTER_BANDWIDTH = 700 nm: the table spans exactly 700 nm (400-1100 nm;
    # the README's 450-1150 nm is the same width shifted by 50 nm)
    assert hi - lo == pytest.approx(700.0, abs=1e-9)
    # response-weighted centre: integral(lambda S) / integral(S) = 770.06 nm for this table,
    # 30 nm short of the IK's nominal INS-238110_FILTER_BANDCENTER = 800 nm (the measured
    # curve is flat-topped from 700 to 900 nm and still 0.27 at 1100 nm)
    centre = np.trapezoid(wl * s, wl) / np.trapezoid(s, wl)
    assert centre == pytest.approx(770.06, abs=0.01)
    assert abs(centre - 800.0) < 35.0
    # equivalent width integral(S) / max(S) = 493 nm
    assert np.trapezoid(s, wl) / s.max() == pytest.approx(493.0, abs=0.1)


def test_amie_band_integrals_with_astm_g173_at_1au():
    sun = solar_spectrum()
    resp = sensor_response("amie")
    bi = band_integrals(sun, resp)
    assert bi.band_nm == (400.0, 1100.0)
    # independent quadrature on a fine grid of the same piecewise-linear tables (the
    # conversion QE T lambda / hc is tabulated at the response's samples, as the renderer gets it)
    grid = np.linspace(400.0, 1100.0, 140_001)
    e = sun(grid)
    wl, s = resp.response.wavelengths, resp.response.values
    epj = np.interp(grid, wl, s * wl * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT))
    e_el = e * epj
    assert bi.irradiance == pytest.approx(np.trapezoid(e, grid), rel=QUADRATURE_RTOL)
    assert bi.electron_irradiance == pytest.approx(np.trapezoid(e_el, grid), rel=QUADRATURE_RTOL)
    # values (computed here): 907.3 W m^-2 in 400-1100 nm, QE x 1.113e21 e- s^-1 m^-2
    assert bi.irradiance == pytest.approx(907.29, rel=1e-4)
    assert bi.electron_irradiance == pytest.approx(QE * 1.1133e21, rel=1e-4)
    # bounds: min(S) and max(S) times the photon irradiance in the band
    photons = np.trapezoid(e * grid * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT), grid)
    assert s.min() * photons < bi.electron_irradiance < s.max() * photons


def test_amie_response_feeds_the_renderer_and_config():
    from starnav.config import SensorResponseConfig
    from starnav.renderer.scene import film_channels
    from starnav.spectra import sensor_response_from_config

    resp = sensor_response_from_config(SensorResponseConfig(preset="amie"))
    assert resp.name == "amie" and resp.band == (400.0, 1100.0)
    ch = film_channels(resp)
    # the L channel is the unit box over the band, the Le channel QE T lambda / hc normalised
    assert (ch.L.wavelengths[0], ch.L.wavelengths[-1]) == (400.0, 1100.0)
    assert ch.Le.values.max() == pytest.approx(1.0, rel=1e-12)
    # the AA-STR default is untouched
    assert sensor_response().band == (425.0, 1025.0)
    with pytest.raises(UnknownNameError, match="aa-str, amie"):
        sensor_response("smart-1")
