"""The truth's forces beyond the filter's point masses (starnav.scenes.forces), each against a
closed form: planetary tides 2 GM r / d^3 along the line to the planet, cannonball SRP
P C_r A / m at 1 AU (zero in the Earth's umbra), J2 on the equator and the pole, and their
effect on a propagated state, 1/2 a t^2."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.constants import DAY
from starnav.scenes.dynamics import PointMassModel, propagate
from starnav.scenes.ephemeris import Ephemeris, parse_epoch
from starnav.scenes.forces import (
    EARTH_J2,
    EARTH_J2_RADIUS,
    SOLAR_PRESSURE_1AU,
    SUN_RADIUS,
    SrpParameters,
    TruthForceModel,
    j2_acceleration,
    shadow_fraction,
)

EPH = Ephemeris.default()
T0 = parse_epoch("2027-03-01T00:00:00 TDB")
#: A halo spacecraft's distance from the Earth-Moon barycentre [m] (L2: ~1.15 lunar distances).
R_HALO = 4.5e8
SRP = SrpParameters(area=0.6, mass=22.0, reflectivity=1.3)


def _planet_emb(model: TruthForceModel, t: float, i: int) -> np.ndarray:
    return model.body_positions(t)[3 + i]


@pytest.mark.parametrize(("planet", "what"), [("venus", "closest"), ("jupiter", "any"),
                                              ("mars", "closest"), ("saturn", "any")])
def test_planet_tide_is_2_gm_r_over_d3(planet, what):
    """On the line from the barycentre to the planet, at R_HALO, the planet's pull less its
    pull on the Earth-Moon barycentre is the tide 2 GM r / d^3 (to O(r/d) ~ 1 %); Venus at its
    closest in 2027-2029 gives ~4e-9 m/s^2 (the old docs' 'below 1e-12' was wrong)."""
    m = TruthForceModel(EPH, planets=[planet])
    t = T0
    if what == "closest":
        ts = T0 + np.arange(0.0, 900.0) * DAY
        d = np.linalg.norm(m.body_positions(ts)[:, 3], axis=1)
        t = float(ts[int(np.argmin(d))])
    rp = _planet_emb(m, t, 0)
    d = float(np.linalg.norm(rp))
    r = R_HALO * rp / d
    got = np.linalg.norm(m.force_breakdown(t, r)[f"planet:{planet}"])
    want = 2.0 * m.gm_planets[0] * R_HALO / d**3
    assert got == pytest.approx(want, rel=0.03), (got, want)
    if planet == "venus":
        assert 2e-9 < got < 6e-9
    if planet == "jupiter":
        assert 2e-10 < got < 8e-10


def test_srp_is_p_cr_a_over_m_in_sunlight():
    """Full Sun: |a| = P C_r A / m (AU / d)^2 along the Sun-spacecraft line, ~1.6e-7 m/s^2
    for the default 12U CubeSat (22 kg, 0.6 m^2, C_r 1.3) at ~1 AU."""
    m = TruthForceModel(EPH, srp=SRP)
    b = EPH.positions_emb(T0)
    r = b[1] + np.cross(b[2], [0.0, 0.0, 1.0]) / np.linalg.norm(b[2]) * 6e7  # off the shadow
    a = m.force_breakdown(T0, r)["srp"]
    d = r - b[2]
    want = SOLAR_PRESSURE_1AU * 1.3 * 0.6 / 22.0 * (EPH.au / np.linalg.norm(d)) ** 2
    assert np.linalg.norm(a) == pytest.approx(want, rel=1e-9)
    assert float(a @ d) / (np.linalg.norm(a) * np.linalg.norm(d)) == pytest.approx(1.0)
    assert SRP.acceleration_1au == pytest.approx(4.54e-6 * 1.3 * 0.6 / 22.0, rel=2e-3)
    assert 1e-7 < np.linalg.norm(a) < 3e-7


def test_srp_is_zero_in_the_earths_umbra_and_partial_in_its_penumbra():
    """Behind the Earth at 3 Earth radii (its umbra is ~1.4e6 km long): no SRP; across the
    shadow's edge the lit fraction goes from 0 to 1 through the penumbra, whose width at
    distance L behind the Earth is ~2 L R_sun / d_sun."""
    m = TruthForceModel(EPH, srp=SRP)
    b = EPH.positions_emb(T0)
    u = (b[0] - b[2]) / np.linalg.norm(b[0] - b[2])
    r = b[0] + 3.0 * EARTH_J2_RADIUS * u
    assert np.all(m.force_breakdown(T0, r)["srp"] == 0.0)
    side = np.cross(u, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    L = 1.0e8
    half = 2.0 * L * SUN_RADIUS / np.linalg.norm(b[0] - b[2])
    # the umbra's edge at L: R_E - L tan(a - b0), penumbra's: R_E + L tan(a + b0), ~ R_E -/+ half/2
    offsets = np.linspace(-3.0 * half, 3.0 * half, 61) + EARTH_J2_RADIUS
    nu = shadow_fraction(b[0] + L * u + offsets[:, None] * side, b[2], b[0], EARTH_J2_RADIUS)
    assert nu[0] == 0.0 and nu[-1] == 1.0
    assert np.all(np.diff(nu) >= -1e-12)
    partial = offsets[(nu > 0) & (nu < 1)]
    assert partial.max() - partial.min() == pytest.approx(half, rel=0.1)


def test_shadow_fraction_closed_forms():
    """Sun of apparent radius a, occulter b: centred and b < a gives the annular 1 - b^2/a^2;
    discs just touching (c = a + b) give 1; half-overlapping equal discs give the lens area."""
    sun = np.array([1.5e11, 0.0, 0.0])
    a = math.asin(SUN_RADIUS / 1.5e11)
    # an occulter on the line, of apparent radius a / 2: annular
    dist = 1.0e9
    Rb = dist * math.sin(a / 2)
    assert shadow_fraction(np.zeros(3), sun, [dist, 0, 0], Rb) == pytest.approx(0.75, rel=1e-6)
    # equal discs, centres a apart: lit 1 - (2/3 - sqrt(3)/(2 pi)) (lens of two unit circles)
    Rb = dist * math.sin(a)
    off = [dist * math.cos(a), dist * math.sin(a), 0.0]
    lens = 2.0 / 3.0 - math.sqrt(3.0) / (2.0 * math.pi)
    assert shadow_fraction(np.zeros(3), sun, off, Rb) == pytest.approx(1.0 - lens, rel=1e-3)
    far = [dist * math.cos(2.01 * a), dist * math.sin(2.01 * a), 0.0]
    assert shadow_fraction(np.zeros(3), sun, far, Rb) == 1.0
    # an occulter behind the observer casts nothing
    assert shadow_fraction(np.zeros(3), sun, [-dist, 0, 0], 1e7) == 1.0


def test_j2_on_the_equator_and_the_pole():
    """J2 pulls inward by 3/2 J2 GM R^2 / rho^4 on the equator and outward by 3 J2 GM R^2 /
    rho^4 on the pole (Montenbruck & Gill 2000, eq. 3.x from the degree-2 zonal potential)."""
    gm, rho = EPH.gm_earth, 4.0e8
    k = EARTH_J2 * gm * EARTH_J2_RADIUS**2 / rho**4
    p = np.array([0.0, 0.0, 1.0])
    eq = j2_acceleration([rho, 0.0, 0.0], p, gm, EARTH_J2, EARTH_J2_RADIUS)
    pole = j2_acceleration([0.0, 0.0, rho], p, gm, EARTH_J2, EARTH_J2_RADIUS)
    assert eq == pytest.approx([-1.5 * k, 0.0, 0.0], rel=1e-12, abs=1e-30)
    assert pole == pytest.approx([0.0, 0.0, 3.0 * k], rel=1e-12, abs=1e-30)
    m = TruthForceModel(EPH, j2=True)
    b = m.body_positions(T0)
    f = m.force_breakdown(T0, b[1] * 1.15)
    assert 1e-10 < np.linalg.norm(f["j2_earth"]) < 3e-9     # ~1e-9 at a lunar distance
    assert 1e-11 < np.linalg.norm(f["j2_moon"]) < 3e-9      # ~7e-10 at 50 000 km


def test_nothing_on_is_the_filters_model_and_srp_drifts_half_a_t_squared():
    """With no extra force the truth model is the filter's point masses bit for bit; with SRP
    alone a state propagated one day departs from the filter's by ~1/2 a t^2 (a nearly
    constant in direction over a day; within 20 %)."""
    pm = PointMassModel(EPH)
    x0 = np.concatenate([EPH.positions_emb(T0)[1] * 1.15, [0.0, 1000.0, 0.0]])
    same = TruthForceModel(EPH)
    assert not same.extra
    assert np.array_equal(propagate(same, T0, x0, T0 + 3600.0)[0],
                          propagate(pm, T0, x0, T0 + 3600.0)[0])
    srp = TruthForceModel(EPH, srp=SRP)
    t = 0.5 * DAY
    d = propagate(srp, T0, x0, T0 + t)[0][:3] - propagate(pm, T0, x0, T0 + t)[0][:3]
    a = np.linalg.norm(srp.force_breakdown(T0, x0[:3])["srp"])
    assert np.linalg.norm(d) == pytest.approx(0.5 * a * t * t, rel=0.2)


def test_filter_process_noise_default_is_the_unmodelled_acceleration_estimate():
    """navigation.filter.accel_psd_m2_s3's default is a_rms^2 tau of what the truth adds with
    every force on (default spacecraft, 14 days near L2 from the default epoch), within 30 %
    (the halo's exact path moves the tides and J2 by less than that; SRP dominates)."""
    from starnav.navigation.schema import FilterConfig
    from starnav.scenes.forces import UNMODELLED_CORRELATION_TIME, unmodelled_acceleration_psd

    m = TruthForceModel(EPH, planets=["venus", "mars", "jupiter", "saturn"], srp=SRP, j2=True)
    ts = T0 + np.arange(0.0, 14.0, 0.5) * DAY
    r = EPH.positions_emb(ts)[:, 1] * 1.15
    rms, q = unmodelled_acceleration_psd(m, ts, r)
    assert q == pytest.approx(rms**2 * UNMODELLED_CORRELATION_TIME)
    assert FilterConfig().accel_psd_m2_s3 == pytest.approx(q, rel=0.3), (rms, q)
    assert FilterConfig().dynamics == "earth-moon-sun"
