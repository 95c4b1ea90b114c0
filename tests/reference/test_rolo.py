"""The ROLO lunar model (Kieffer & Stone 2005, model 311g) against published and hand-made numbers.

Sources of the numbers (next to each test):
* data README = the project's reference-data README, section rolo/, copied into
  src/starnav/data/rolo/PROVENANCE.md ("Sanity values" and "Reference numbers");
* docs/facts.md section 6 (band irradiances over 425-1025 nm, the Moon's redness), copied into
  the same file ("Reference numbers");
* Kieffer & Stone 2005, AJ 129:2887, Table 4 (coefficients, Apollo factors), Eq. 8.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from starnav.constants import AU, PLANCK_H, SPEED_OF_LIGHT
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry, static_geometry
from starnav.reference import (
    ROLO_WAVELENGTHS_NM,
    rolo_coefficients,
    rolo_extrapolation,
    rolo_geometry,
    rolo_irradiance,
    rolo_irradiance_for_frame,
    rolo_reflectance,
    rolo_spectrum,
)
from starnav.spectra import sensor_response, solar_spectrum

DEG = math.pi / 180.0
#: Angles computed from vectors: agree to float precision [rad].
ANGLE_TOL = 1e-12
#: Relative tolerance of quantities that are exact by construction (scalings, factors).
EXACT_RTOL = 1e-12
#: Reference distance of ROLO's irradiance formula [m] (Kieffer & Stone 2005, Eq. 8).
D_REF = 384_400e3
ROLO_LOGGER = "starnav.reference.rolo"


@pytest.fixture(scope="module")
def sun():
    return solar_spectrum("astm-g173")  # ASTM G-173 extraterrestrial, 1 AU


@pytest.fixture(scope="module")
def box():
    """QE x T = 1 over 425-1025 nm: the band integral is the plain integral over the band."""
    return sensor_response(wavelengths_nm=[425.0, 1025.0])


def _half_unit(value: float) -> float:
    """Half a unit in the last digit of a number quoted with 3 significant digits."""
    return 0.5 * 10.0 ** (math.floor(math.log10(abs(value))) - 2)


# --------------------------------------------------------------------------- the table
def test_coefficients_are_table_4():
    # Kieffer & Stone 2005 Table 4, first and last rows (350.0 and 2383.6 nm).
    c = rolo_coefficients()
    assert c.a.shape == (32, 4) and c.b.shape == (32, 3) and c.d.shape == (32, 3)
    np.testing.assert_array_equal(c.wavelengths_nm, ROLO_WAVELENGTHS_NM)
    np.testing.assert_array_equal(c.a[0], [-2.67511, -1.78539, 0.50612, -0.25578])
    np.testing.assert_array_equal(c.d[-1], [0.36134, -0.28408, 0.01010])
    assert c.apollo[9] == 1.0148 and ROLO_WAVELENGTHS_NM[9] == 544.0
    assert rolo_coefficients() is c  # loaded once


# --------------------------------------------------------------------------- reflectance
@pytest.mark.parametrize(("wavelength", "phase_deg", "expected"), [
    # data README, rolo/ sanity values (Phi = theta = phi = 0), 4 digits
    (544.0, 2.0, 0.1270),
    (544.0, 30.0, 0.0524),
    (745.3, 2.0, 0.1606),
    (745.3, 30.0, 0.0705),
])
def test_readme_sanity_values(wavelength, phase_deg, expected):
    a = rolo_reflectance(phase_deg * DEG, 0.0, 0.0, 0.0, wavelength_nm=wavelength)
    assert float(a) == pytest.approx(expected, abs=0.5e-4)


def test_the_moon_is_red():
    # docs/facts.md s6: ROLO's A at 2 deg rises from 0.107 (405 nm) to 0.161 (745 nm).
    a405, a745 = rolo_reflectance(2.0 * DEG, 0.0, wavelength_nm=[405.0, 745.3])
    assert a405 == pytest.approx(0.107, abs=0.5e-3)
    assert a745 == pytest.approx(0.161, abs=0.5e-3)


def test_waxing_moon_is_brighter():
    # The waxing Moon (Phi > 0, module docstring) lights the eastern near side; the waning Moon
    # the mare-rich western one (Oceanus Procellarum): the waxing Moon is brighter at the same
    # phase. Checks the sign convention of Phi against that known asymmetry.
    g = 60.0 * DEG
    ratio = rolo_reflectance(g, +g) / rolo_reflectance(g, -g)
    assert np.all(ratio > 1.0)


def test_vectorised_over_phase_and_shapes():
    phases = np.array([5.0, 20.0, 45.0, 80.0]) * DEG
    table = rolo_reflectance(phases, phases)
    assert table.shape == (4, 32)
    for i, g in enumerate(phases):
        np.testing.assert_allclose(table[i], rolo_reflectance(g, g), rtol=EXACT_RTOL)
    assert rolo_reflectance(phases, 0.0, wavelength_nm=[500.0, 600.0, 700.0]).shape == (4, 3)
    assert np.ndim(rolo_reflectance(0.3, 0.3, wavelength_nm=550.0)) == 0


def test_wavelength_interpolation_is_linear_between_band_centres():
    g, phi = 25.0 * DEG, 25.0 * DEG
    bands = rolo_reflectance(g, phi)
    np.testing.assert_allclose(rolo_reflectance(g, phi, wavelength_nm=ROLO_WAVELENGTHS_NM),
                               bands, rtol=EXACT_RTOL)
    # halfway between 544.0 and 549.1 nm (bands 9 and 10): the mean of the two
    mid = rolo_reflectance(g, phi, wavelength_nm=(544.0 + 549.1) / 2)
    assert mid == pytest.approx(0.5 * (bands[9] + bands[10]), rel=EXACT_RTOL)
    sp = rolo_spectrum(g, phi)
    np.testing.assert_allclose(sp.values, bands, rtol=EXACT_RTOL)
    assert sp(546.55) == pytest.approx(mid, rel=1e-9)


def test_apollo_factor_applied():
    # Kieffer & Stone 2005 Table 4 (rolo_apollo_correction.csv): 405.0 nm 0.9325, 544.0 nm
    # 1.0148, 2250.9 nm 0.8945. Published ROLO values = A_k x factor.
    g = 40.0 * DEG
    ratio = rolo_reflectance(g, g, apollo=True) / rolo_reflectance(g, g)
    for wl, factor in ((405.0, 0.9325), (544.0, 1.0148), (2250.9, 0.8945)):
        k = int(np.flatnonzero(ROLO_WAVELENGTHS_NM == wl)[0])
        assert ratio[k] == pytest.approx(factor, rel=EXACT_RTOL)
    r1 = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, band_nm=(543.0, 545.0), apollo=True)
    r0 = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, band_nm=(543.0, 545.0))
    assert r1.apollo and not r0.apollo
    assert r1.irradiance / r0.irradiance == pytest.approx(1.0148, abs=2e-3)


# --------------------------------------------------------------------------- irradiance
@pytest.mark.parametrize(("phase_deg", "expected_w_m2"), [
    # docs/facts.md s6: ROLO band-integrated over 425-1025 nm, ASTM G-173 at 1 AU, 384 400 km,
    # Sun selenographic longitude = phase, observer at 0/0. Quoted to 3 digits.
    (7.0, 1.90e-3),
    (30.0, 1.08e-3),
    (60.0, 5.38e-4),
    (90.0, 2.24e-4),
])
def test_reference_band_irradiance(phase_deg, expected_w_m2, sun, box):
    g = phase_deg * DEG
    r = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun, box)
    assert r.band_nm == (425.0, 1025.0)
    assert r.irradiance == pytest.approx(expected_w_m2, abs=_half_unit(expected_w_m2))
    assert not r.extrapolated and r.reason is None


def test_band_integrals_against_a_fine_quadrature(sun, box):
    # Slow reference: Eq. 8 on a 0.05 nm grid, A from rolo_reflectance, E from the raw table;
    # electrons with QE = 1: integral I lambda / (h c).
    g = 30.0 * DEG
    r = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun, box)
    lam = np.arange(425.0, 1025.0 + 0.025, 0.05)
    spec = (rolo_reflectance(g, g, wavelength_nm=lam) * 6.4177e-5 / math.pi * sun(lam))
    assert r.irradiance == pytest.approx(np.trapezoid(spec, lam), rel=1e-4)
    electrons = np.trapezoid(spec * lam * 1e-9 / (PLANCK_H * SPEED_OF_LIGHT), lam)
    assert r.electron_irradiance == pytest.approx(electrons, rel=1e-4)


def test_no_response_gives_band_irradiance_only(sun, box):
    g = 30.0 * DEG
    with_box = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun, box)
    plain = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun, band_nm=(425.0, 1025.0))
    assert plain.electron_irradiance is None
    assert plain.irradiance == pytest.approx(with_box.irradiance, rel=1e-9)
    whole = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun)
    assert whole.band_nm == (350.0, 2383.6)
    assert whole.irradiance == pytest.approx(whole.spectrum.integral(), rel=EXACT_RTOL)


def test_inverse_square_in_both_distances(sun, box):
    # Eq. 8: I scales as (1 AU / D_sun)^2 (384 400 km / D_obs)^2.
    g = 45.0 * DEG
    base = rolo_irradiance(g, g, 0.0, 0.0, AU, D_REF, sun, box)
    far_sun = rolo_irradiance(g, g, 0.0, 0.0, 2.0 * AU, D_REF, sun, box)
    far_obs = rolo_irradiance(g, g, 0.0, 0.0, AU, 3.0 * D_REF, sun, box)
    both = rolo_irradiance(g, g, 0.0, 0.0, 0.98 * AU, 0.25 * D_REF, sun, box)
    assert far_sun.irradiance == pytest.approx(base.irradiance / 4.0, rel=EXACT_RTOL)
    assert far_obs.irradiance == pytest.approx(base.irradiance / 9.0, rel=EXACT_RTOL)
    assert both.irradiance == pytest.approx(base.irradiance * 16.0 / 0.98**2, rel=EXACT_RTOL)
    assert far_obs.electron_irradiance == pytest.approx(base.electron_irradiance / 9.0,
                                                        rel=EXACT_RTOL)
    assert (base.sun_distance, base.observer_distance) == (AU, D_REF)


# --------------------------------------------------------------------------- validity
@pytest.mark.parametrize(("phase_deg", "obs_lon_deg", "what"), [
    (1.0, 0.0, "phase"),      # below 1.55 deg
    (120.0, 0.0, "phase"),    # above 97 deg
    (30.0, 100.0, "near side"),
])
def test_extrapolation_flagged_and_logged(phase_deg, obs_lon_deg, what, caplog):
    g = phase_deg * DEG
    with caplog.at_level(logging.WARNING, logger=ROLO_LOGGER):
        r = rolo_irradiance(g, g, 0.0, obs_lon_deg * DEG, AU, D_REF, band_nm=(500.0, 600.0))
    assert r.extrapolated and what in r.reason
    assert any(what in rec.getMessage() for rec in caplog.records)


def test_inside_the_fit_range_is_silent(caplog):
    with caplog.at_level(logging.WARNING, logger=ROLO_LOGGER):
        r = rolo_irradiance(50.0 * DEG, -50.0 * DEG, 5.0 * DEG, -7.0 * DEG, AU, D_REF,
                            band_nm=(500.0, 600.0))
    assert not r.extrapolated and not caplog.records
    assert rolo_extrapolation(np.array([1.6, 96.9]) * DEG) is None
    assert rolo_extrapolation(np.array([1.6, 97.1]) * DEG) is not None


# --------------------------------------------------------------------------- geometry
def _frame(camera_body, sun_body, R):
    return FrameGeometry(camera_position=R @ camera_body, R_cam_to_inertial=np.eye(3),
                         sun_position=R @ sun_body, R_body_to_inertial=R)


def _unit(lat, lon):
    return np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon),
                     math.sin(lat)])


def test_geometry_observer_on_x_sun_in_the_equator():
    # Observer on the body +x axis (sub-observer point 0/0), Sun in the x-y plane at +30 deg:
    # phase 30 deg, subsolar longitude +30 deg (east: the waxing Moon).
    d_obs, d_sun = 400_000e3, 1.01 * AU
    s = math.radians(30.0)
    geom = FrameGeometry(camera_position=[d_obs, 0.0, 0.0], R_cam_to_inertial=np.eye(3),
                         sun_position=[d_sun * math.cos(s), d_sun * math.sin(s), 0.0])
    rg = rolo_geometry(geom)
    assert rg.phase == pytest.approx(s, abs=ANGLE_TOL)
    assert rg.sun_lon == pytest.approx(s, abs=ANGLE_TOL)
    assert rg.sun_lat == pytest.approx(0.0, abs=ANGLE_TOL)
    assert (rg.obs_lat, rg.obs_lon) == pytest.approx((0.0, 0.0), abs=ANGLE_TOL)
    assert rg.observer_distance == pytest.approx(d_obs, rel=EXACT_RTOL)
    assert rg.sun_distance == pytest.approx(d_sun, rel=EXACT_RTOL)


def test_geometry_with_a_rotated_moon():
    # Moon body frame turned by +40 deg about z: v_inertial = Rz(40) v_body. An inertial
    # observer on +x sees the body longitude -40 deg; an inertial Sun at +30 deg sits over
    # body longitude -10 deg. Phase unchanged (30 deg).
    b = math.radians(40.0)
    Rz = np.array([[math.cos(b), -math.sin(b), 0.0], [math.sin(b), math.cos(b), 0.0],
                   [0.0, 0.0, 1.0]])
    s = math.radians(30.0)
    geom = FrameGeometry(camera_position=[D_REF, 0.0, 0.0], R_cam_to_inertial=np.eye(3),
                         sun_position=[AU * math.cos(s), AU * math.sin(s), 0.0],
                         R_body_to_inertial=Rz)
    rg = rolo_geometry(geom)
    assert rg.obs_lon == pytest.approx(math.radians(-40.0), abs=ANGLE_TOL)
    assert rg.sun_lon == pytest.approx(math.radians(-10.0), abs=ANGLE_TOL)
    assert rg.phase == pytest.approx(s, abs=ANGLE_TOL)


def test_geometry_round_trip_with_latitudes():
    # Sub-observer (6 N, 7 W) and subsolar (1.5 S, 50 E) points put into a Moon turned by an
    # arbitrary rotation; phase from the spherical law of cosines.
    R = Rotation.from_euler("zyx", [123.0, -35.0, 71.0], degrees=True).as_matrix()
    o_lat, o_lon, s_lat, s_lon = (math.radians(x) for x in (6.0, -7.0, -1.5, 50.0))
    geom = _frame(D_REF * _unit(o_lat, o_lon), AU * _unit(s_lat, s_lon), R)
    rg = rolo_geometry(geom)
    cos_g = (math.sin(o_lat) * math.sin(s_lat)
             + math.cos(o_lat) * math.cos(s_lat) * math.cos(s_lon - o_lon))
    assert rg.phase == pytest.approx(math.acos(cos_g), abs=1e-9)
    assert (rg.obs_lat, rg.obs_lon) == pytest.approx((o_lat, o_lon), abs=1e-9)
    assert (rg.sun_lat, rg.sun_lon) == pytest.approx((s_lat, s_lon), abs=1e-9)


@pytest.mark.parametrize(("azimuth", "sign"), [(0.0, +1.0), (math.pi, -1.0)])
def test_static_geometry_sun_east_is_the_waxing_moon(aa_str, box, sun, azimuth, sign):
    # static_geometry puts the subsolar point at `phase` from the sub-observer point (0, 0)
    # towards azimuth 0 = local east: Phi = +phase; azimuth 180 deg: west, Phi = -phase.
    # At 30 deg, 1 AU, 384 400 km the waxing Moon gives docs/facts.md's 1.08e-3 W m^-2.
    g = 30.0 * DEG
    geom = static_geometry(aa_str, D_REF, g, sun_azimuth=azimuth, sun_distance=AU)
    rg = rolo_geometry(geom)
    assert rg.sun_lon == pytest.approx(sign * g, abs=ANGLE_TOL)
    r = rolo_irradiance_for_frame(geom, sun, box)
    direct = rolo_irradiance(g, sign * g, 0.0, 0.0, AU, D_REF, sun, box)
    assert r.irradiance == pytest.approx(direct.irradiance, rel=1e-9)
    if sign > 0:
        assert r.irradiance == pytest.approx(1.08e-3, abs=_half_unit(1.08e-3))


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(("wl", "offending"), [
    (300.0, 300.0), (2400.0, 2400.0), ([500.0, 349.0], [349.0]),
])
def test_wavelength_outside_the_table(wl, offending):
    with pytest.raises(ConfigError, match="expected wavelengths within the ROLO table "
                       "350-2383.6 nm") as exc:
        rolo_reflectance(0.5, 0.5, wavelength_nm=wl)
    assert exc.value.field == "wavelength_nm"
    assert exc.value.value == offending
    assert str(offending) in str(exc.value)


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"sun_distance_m": -1.0}, "sun_distance_m"),
    ({"sun_distance_m": float("nan")}, "sun_distance_m"),
    ({"observer_distance_m": -384_400e3}, "observer_distance_m"),
    ({"observer_distance_m": 1_000e3}, "observer_distance_m"),  # inside the Moon
])
def test_bad_distances(kwargs, field):
    args = {"sun_distance_m": AU, "observer_distance_m": D_REF} | kwargs
    with pytest.raises(ConfigError, match="expected a finite distance") as exc:
        rolo_irradiance(0.5, 0.5, 0.0, 0.0, band_nm=(500.0, 600.0), **args)
    assert exc.value.field == field
    assert str(kwargs[field]) in str(exc.value)


def test_bad_angles_and_bands(sun):
    with pytest.raises(ConfigError, match=r"phase = -0.1: expected a phase angle in \[0, pi\]"):
        rolo_reflectance(-0.1, 0.0)
    with pytest.raises(ConfigError, match="obs_lat"):
        rolo_reflectance(0.5, 0.0, obs_lat=2.0)
    wide = sensor_response(wavelengths_nm=[300.0, 1100.0])
    with pytest.raises(ConfigError, match="response.band") as exc:
        rolo_irradiance(0.5, 0.5, 0.0, 0.0, AU, D_REF, sun, wide)
    assert "350-2383.6 nm" in str(exc.value)
    with pytest.raises(ConfigError, match="band_nm"):
        rolo_irradiance(0.5, 0.5, 0.0, 0.0, AU, D_REF, sun, wide, band_nm=(500.0, 600.0))
