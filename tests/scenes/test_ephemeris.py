"""DE421 ephemeris: distances, speeds, mass ratio, GMs, span errors, time scales, orientation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.constants import DAY
from starnav.errors import ConfigError
from starnav.scenes.ephemeris import (
    _SCALAR_EPOCHS,
    J2000_JD,
    EphemerisRangeError,
    format_epoch,
    parse_epoch,
)

KM = 1e3


def test_earth_moon_distance_across_three_centuries(eph):
    # Meeus (1998), Astronomical Algorithms, ch. 50: between 1500 and 2500 the Moon's perigee
    # never comes below 356 375 km and its apogee never exceeds 406 720 km.
    t = np.arange(eph.t_min, eph.t_max, 0.25 * DAY)
    d = np.linalg.norm(eph.moon_geocentric(t)[0], axis=-1)
    assert d.min() > 356_000 * KM and d.max() < 407_000 * KM
    # ... and it does get close to both extremes (units and series are right)
    assert d.min() < 357_000 * KM and d.max() > 406_300 * KM


def test_moon_mean_orbital_speed(eph):
    # NASA GSFC Moon fact sheet: mean orbital velocity 1.022 km/s (0.970-1.082 km/s for the
    # mean orbit; the Sun makes the eccentricity vary between ~0.026 and ~0.077, Meeus 1998
    # ch. 50, so the instantaneous speed spans a little more).
    t = parse_epoch("2020-01-01T00:00:00 TDB") + np.arange(0, 10 * 365.25, 0.1) * DAY
    v = np.linalg.norm(eph.moon_geocentric(t)[1], axis=-1)
    assert abs(v.mean() - 1022.0) < 5.0
    assert 950.0 < v.min() < 975.0 and 1075.0 < v.max() < 1110.0


def test_velocity_is_derivative_of_position(eph):
    # near J2000, where a double resolves TDB seconds to 1e-9 s
    t = np.linspace(0, 40 * DAY, 17)
    h = 10.0
    for f in (eph.moon_geocentric, eph.emb_ssb, eph.sun_ssb):
        p = f(t)[0]
        fd = (f(t + h)[0] - f(t - h)[0]) / (2 * h)
        # truncation h^2/6 |d3x/dt3| < 2e-7 m/s, plus the rounding of |r| ~ 1.5e11 m over 2 h
        tol = 2e-7 + 4e-16 * np.max(np.abs(p)) / (2 * h)
        assert np.max(np.abs(fd - f(t)[1])) < tol  # m/s


def test_series_match_jplephem(eph):
    # independent evaluation of the same coefficients by jplephem's own (legacy) reader
    import de421
    from jplephem.ephem import Ephemeris as LegacyEphemeris

    ref = LegacyEphemeris(de421)
    for jd in (2415100.25, 2451545.0, 2461000.3, 2524000.75):
        t = (jd - J2000_JD) * DAY
        for name, fn in (("moon", eph.moon_geocentric), ("earthmoon", eph.emb_ssb),
                         ("sun", eph.sun_ssb)):
            p, v = ref.position_and_velocity(name, jd)
            ps, vs = fn(t)
            assert np.allclose(ps / KM, np.ravel(p), rtol=0, atol=1e-6)  # km
            assert np.allclose(vs * DAY / KM, np.ravel(v), rtol=0, atol=1e-9)  # km/day


def test_emb_split_follows_emrat(eph):
    # docs/facts.md s4 / DE421 constants: EMRAT = 81.3005690699153
    assert eph.emrat == pytest.approx(81.3005690699153, rel=1e-15)
    t = parse_epoch("2031-07-04T00:00:00 TDB")
    earth = eph.state("earth", t, center="emb")
    moon = eph.state("moon", t, center="emb")
    # barycentre: m_E r_E + m_M r_M = 0, so r_M = -EMRAT r_E (positions and velocities)
    assert np.allclose(moon, -eph.emrat * earth, rtol=1e-12, atol=1e-6)
    # and Earth + Moon about the EMB rebuild the geocentric Moon
    r_em = eph.moon_geocentric(t)[0]
    assert np.allclose(moon[:3] - earth[:3], r_em, rtol=0, atol=1e-6)
    assert np.linalg.norm(earth[:3]) == pytest.approx(np.linalg.norm(r_em) / (1 + eph.emrat))


def test_gm_values_from_de421_constants(eph):
    # Folkner, Williams & Boggs (2009), IPN PR 42-178, Table 8 (DE421):
    # GM_sun = 132 712 440 040.944 km^3/s^2; GM_earth = 398 600.436 233; GM_moon = 4902.800 076
    assert eph.gm_sun == pytest.approx(1.32712440040944e20, rel=1e-12)
    assert eph.gm_earth == pytest.approx(3.98600436233e14, rel=1e-11)
    assert eph.gm_moon == pytest.approx(4.902800076e12, rel=1e-9)
    assert eph.gm_earth / eph.gm_moon == pytest.approx(eph.emrat, rel=1e-14)


@pytest.mark.parametrize("epoch", ["1850-01-01T00:00:00 TDB", "2250-06-01T00:00:00 UTC",
                                   "1899-11-01T00:00:00 TDB"])
def test_outside_span_is_a_clear_error(eph, epoch):
    t = parse_epoch(epoch)
    with pytest.raises(EphemerisRangeError, match=r"outside the DE421 span 1899-12-04.*2200"):
        eph.state("moon", t)
    with pytest.raises(EphemerisRangeError, match=epoch[:4]):
        eph.positions_emb(np.array([0.0, t]))


def test_span_edges_inside(eph):
    for epoch in ("1900-01-01T00:00:00 TDB", "2199-12-31T00:00:00 TDB"):
        d = np.linalg.norm(eph.moon_geocentric(parse_epoch(epoch))[0])
        assert 356_000 * KM < d < 407_000 * KM


def test_time_scales():
    # J2000 is JD 2451545.0 TDB
    assert parse_epoch("2000-01-01T12:00:00 TDB") == 0.0
    # TDB - UTC = 32.184 s + 37 leap seconds (IERS Bulletin C, since 2017-01-01) + the
    # periodic TDB-TT term, below 1.7 ms (Fairhead & Bretagnon 1990)
    d = parse_epoch("2027-03-01T00:00:00 TDB") - parse_epoch("2027-03-01T00:00:00 UTC")
    assert abs(d - (-69.184)) < 2e-3  # the TDB clock reading is 69.184 s ahead
    tt = parse_epoch("2027-03-01T00:00:00 TT") - parse_epoch("2027-03-01T00:00:00 TDB")
    assert abs(tt) < 2e-3
    assert parse_epoch("2027-03-01T00:00:00Z") == parse_epoch("2027-03-01T00:00:00 UTC")
    t = parse_epoch("2027-03-01T12:34:56.5 UTC")
    assert format_epoch(t, "UTC") == "2027-03-01T12:34:56.500000 UTC"


@pytest.mark.parametrize("bad", ["2027-03-01T00:00:00", "2027-13-01T00:00:00 TDB", "tomorrow"])
def test_epoch_without_scale_or_invalid_is_rejected(bad):
    with pytest.raises(ConfigError, match="trajectory.epoch"):
        parse_epoch(bad, "trajectory.epoch")


def _iau2009_moon(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Moon pole and prime-meridian direction from the IAU WGCCRE 2009 model (Archinal et al.
    2011, Celest. Mech. Dyn. Astr. 109, 101-135, Table 2): it approximates the mean-Earth
    frame to ~150 m (~18")."""
    d = t / DAY
    T = d / 36525.0
    E = {1: 125.045 - 0.0529921 * d, 2: 250.089 - 0.1059842 * d, 3: 260.008 + 13.0120009 * d,
         4: 176.625 + 13.3407154 * d, 5: 357.529 + 0.9856003 * d, 6: 311.589 + 26.4057084 * d,
         7: 134.963 + 13.0649930 * d, 8: 276.617 + 0.3287146 * d, 9: 34.226 + 1.7484877 * d,
         10: 15.134 - 0.1589763 * d, 11: 119.743 + 0.0036096 * d,
         12: 239.961 + 0.1643573 * d, 13: 25.053 + 12.9590088 * d}

    def s(k):
        return math.sin(math.radians(E[k]))

    def c(k):
        return math.cos(math.radians(E[k]))

    a = (269.9949 + 0.0031 * T - 3.8787 * s(1) - 0.1204 * s(2) + 0.0700 * s(3) - 0.0172 * s(4)
         + 0.0072 * s(6) - 0.0052 * s(10) + 0.0043 * s(13))
    de = (66.5392 + 0.0130 * T + 1.5419 * c(1) + 0.0239 * c(2) - 0.0278 * c(3) + 0.0068 * c(4)
          - 0.0029 * c(6) + 0.0009 * c(7) + 0.0008 * c(10) - 0.0009 * c(13))
    W = (38.3213 + 13.17635815 * d - 1.4e-12 * d * d + 3.5610 * s(1) + 0.1208 * s(2)
         - 0.0642 * s(3) + 0.0158 * s(4) + 0.0252 * s(5) - 0.0066 * s(6) - 0.0047 * s(7)
         - 0.0046 * s(8) + 0.0028 * s(9) + 0.0052 * s(10) + 0.0040 * s(11) + 0.0019 * s(12)
         - 0.0044 * s(13))
    a, de, W = (math.radians(x) for x in (a, de, W))
    pole = np.array([math.cos(de) * math.cos(a), math.cos(de) * math.sin(a), math.sin(de)])
    node = np.array([-math.sin(a), math.cos(a), 0.0])
    x_body = math.cos(W) * node + math.sin(W) * np.cross(pole, node)
    return pole, x_body


def _angle_deg(a, b):
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


@pytest.mark.parametrize("epoch", ["1950-06-01T00:00:00 TDB", "2000-01-01T12:00:00 TDB",
                                   "2027-03-01T00:00:00 TDB", "2150-01-01T00:00:00 TDB"])
def test_moon_orientation_matches_iau_model(eph, epoch):
    t = parse_epoch(epoch)
    pole, x_body = _iau2009_moon(t)
    me = eph.moon_orientation(t, frame="ME")
    assert np.allclose(me @ me.T, np.eye(3), atol=1e-12) and np.linalg.det(me) > 0
    # ME axes agree with the IAU model to its accuracy (~18" = 0.005 deg)
    assert _angle_deg(me[:, 2], pole) < 0.006
    assert _angle_deg(me[:, 0], x_body) < 0.006
    # PA differs from ME by the constant DE421 rotation (67.92", 78.56", 0.30"): 103.9"
    pa = eph.moon_orientation(t, frame="PA")
    rot = math.degrees(math.acos((np.trace(pa.T @ me) - 1) / 2)) * 3600
    assert rot == pytest.approx(math.sqrt(67.92**2 + 78.56**2 + 0.30**2), abs=0.05)


def test_moon_angular_velocity_matches_orientation_rate(eph):
    t = parse_epoch("2027-03-05T00:00:00 TDB")
    h = 60.0
    R = eph.moon_orientation(t)
    Rd = (eph.moon_orientation(t + h) - eph.moon_orientation(t - h)) / (2 * h)
    W = Rd @ R.T  # [w]x in inertial components
    w_fd = np.array([W[2, 1], W[0, 2], W[1, 0]])
    w = eph.moon_angular_velocity(t)
    assert np.allclose(w, w_fd, rtol=0, atol=1e-12)
    # sidereal rotation period 27.32 d (synchronous with the orbit)
    assert 2 * math.pi / np.linalg.norm(w) / DAY == pytest.approx(27.32, abs=0.5)


def test_few_epoch_chebyshev_path_equals_the_array_path_to_rounding(eph):
    # a few epochs (an RK4 step's stages) take the Python-float recurrence and NumPy's
    # contraction one epoch at a time (memoised): the array form's values to rounding (NumPy's
    # sum for a row depends on how many rows it is given: its vector paths), far inside the
    # 1e-9 to which the chain and golden pins hold the filter
    t = 8.0e8 + np.array([0.0, 150.0, 300.0, 17.3 * DAY, 41.9 * DAY])
    many = np.concatenate([t, 8.0e8 + np.linspace(1.0, 50.0 * DAY, 2 * _SCALAR_EPOCHS)])
    assert t.size <= _SCALAR_EPOCHS < many.size
    for name in ("moon", "earthmoon", "sun"):
        few = eph._chebyshev(name, t)
        ref = eph._chebyshev(name, many)
        for a, b in zip(few, ref, strict=True):
            # a few units of the last place of the largest term (cancellation leaves a small
            # component a larger relative rounding)
            np.testing.assert_allclose(a, b[: t.size], rtol=0, atol=4e-16 * np.abs(b).max())


def test_an_epoch_gives_the_same_values_whichever_call_asked_first():
    # the few-epoch path memoises each epoch: alone, within a batch, repeated, mixed with new
    # epochs or after the memo was cleared, an epoch's values are the same bits (a fresh
    # instance: the shared one's memo holds other tests' epochs)
    from starnav.scenes.ephemeris import _MEMO_EPOCHS, Ephemeris

    t = 8.0e8 + np.arange(3 * _MEMO_EPOCHS) * 1800.0
    alone = Ephemeris()
    ref = {name: [alone._chebyshev(name, float(x)) for x in t] for name in ("moon", "sun")}
    picks = [[0, 1, 2], [2, 2, 0], [5, 1], [7, 8, 9, 5]]
    picks += [[i, i + 1, i + 2] for i in range(0, 3 * _MEMO_EPOCHS - 2, 2)]   # clears the memo
    e = Ephemeris()
    for name, one in ref.items():
        for idx in picks:
            fv, fd = e._chebyshev(name, t[idx])
            np.testing.assert_array_equal(fv, np.array([one[i][0] for i in idx]))
            np.testing.assert_array_equal(fd, np.array([one[i][1] for i in idx]))
        assert one[3][0].shape == (3,)
