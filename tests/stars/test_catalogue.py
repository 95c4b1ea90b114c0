"""The Hipparcos catalogue: positions against SIMBAD, proper motion against astropy, the cone
query against brute force."""

from __future__ import annotations

import math

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import Distance, SkyCoord
from astropy.time import Time

from starnav.errors import ConfigError
from starnav.stars.catalogue import HIPPARCOS_EPOCH_JYEAR, MAS, hipparcos, v_minus_hp

ARCSEC = math.pi / 180 / 3600


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between unit vectors [rad], accurate at small angles."""
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b)))


def _radec(h: float, m: float, s: float, sign: int, d: float, dm: float, ds: float) -> np.ndarray:
    ra = math.radians(15 * (h + m / 60 + s / 3600))
    dec = sign * math.radians(d + dm / 60 + ds / 3600)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


#: SIMBAD (ICRS, J2000 epoch) positions and Johnson V of the belt of Orion and of Vega.
SIMBAD = {
    26311: (_radec(5, 36, 12.81335, -1, 1, 12, 6.9089), 1.69),    # Alnilam, eps Ori
    26727: (_radec(5, 40, 45.52666, -1, 1, 56, 33.2649), 1.77),   # Alnitak, zet Ori
    25930: (_radec(5, 32, 0.40009, -1, 0, 17, 56.7424), 2.23),    # Mintaka, del Ori
    91262: (_radec(18, 36, 56.33635, 1, 38, 47, 1.2802), 0.03),   # Vega, alf Lyr
}


@pytest.mark.parametrize("hip", sorted(SIMBAD))
def test_positions_at_j2000_and_v_match_simbad(hip):
    cat = hipparcos()
    ref, v = SIMBAD[hip]
    i = cat.index_of(hip)
    d = cat.directions(2000.0, [i])[0]
    assert _angle(d, ref) < 0.05 * ARCSEC, f"HIP {hip}: {_angle(d, ref) / ARCSEC:.3f} arcsec"
    # V from Hp and B - V (Bessell 2000): 0.01 mag for normal stars; Vega's Hp gives 0.075
    assert abs(cat.v[i] - v) < 0.06, f"HIP {hip}: V {cat.v[i]:.3f} vs SIMBAD {v}"


def test_belt_of_orion_is_the_three_stars_brighter_than_2_5_within_3_deg():
    cat = hipparcos()
    sel = cat.cone(SIMBAD[26311][0], math.radians(3.0), 2025.0, v_limit=2.5)
    assert sorted(sel.hip.tolist()) == [25930, 26311, 26727]
    assert np.all(np.diff(sel.v) >= 0)  # brightest first
    assert sel.hip[0] == 26311


def test_cone_equals_brute_force():
    """The k-d tree query (with its proper-motion margin) against every star propagated."""
    cat = hipparcos()
    rng = np.random.default_rng(5)
    for _ in range(4):
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        sel = cat.cone(c, math.radians(8.0), 2040.0, v_limit=6.5)
        d = cat.directions(2040.0)
        brute = np.nonzero((d @ c >= math.cos(math.radians(8.0))) & (cat.v <= 6.5))[0]
        assert sorted(sel.hip.tolist()) == sorted(cat.hip[brute].tolist())


def test_star_count_brighter_than_6_matches_the_sky():
    """About 5 000 stars are brighter than V = 6 over the whole sky (the naked-eye count;
    Hoffleit & Warren, Bright Star Catalogue, 5th ed.: 9 110 stars to V ~ 6.5)."""
    cat = hipparcos()
    assert 4500 < int(np.sum(cat.v <= 6.0)) < 5500
    assert 8000 < int(np.sum(cat.v <= 6.5)) < 9500


@pytest.mark.parametrize("hip,parallax_mas", [(87937, 548.31), (104214, 286.82),
                                              (57939, 109.99)])
def test_linear_proper_motion_against_astropy_space_motion(hip, parallax_mas):
    """Barnard's star, 61 Cyg A, Groombridge 1830 (the largest proper motions): the tangent-
    plane model against ``SkyCoord.apply_space_motion`` (zero radial velocity, as the
    catalogue has none) within 0.01 arcsec over 1991-2030."""
    cat = hipparcos()
    i = cat.index_of(hip)
    sc = SkyCoord(ra=cat.ra[i] * u.rad, dec=cat.dec[i] * u.rad,
                  pm_ra_cosdec=cat.pm_ra_cosdec[i] / MAS * u.mas / u.yr,
                  pm_dec=cat.pm_dec[i] / MAS * u.mas / u.yr,
                  distance=Distance(parallax=parallax_mas * u.mas),
                  radial_velocity=0 * u.km / u.s,
                  obstime=Time(HIPPARCOS_EPOCH_JYEAR, format="jyear", scale="tt"))
    for year in (2000.0, 2030.0):
        p = sc.apply_space_motion(new_obstime=Time(year, format="jyear", scale="tt"))
        ref = np.asarray(p.cartesian.xyz.value, float)
        ref /= np.linalg.norm(ref)
        ours = cat.directions(year, [i])[0]
        moved = _angle(ours, cat.u0[i])
        assert moved > 40 * ARCSEC  # the motion is really there
        assert _angle(ours, ref) < 0.01 * ARCSEC, (hip, year, _angle(ours, ref) / ARCSEC)


def test_v_minus_hp_follows_bessell_2000():
    # Table 2: BT-VT = 0.50 -> B-V = 0.465, V-Hp = -0.108; held at the ends
    assert v_minus_hp(0.465) == pytest.approx(-0.108, abs=1e-9)
    assert v_minus_hp(5.0) == pytest.approx(-0.106)


def test_bad_cone_is_refused():
    cat = hipparcos()
    with pytest.raises(ConfigError, match="radius"):
        cat.cone([0, 0, 1], -1.0, 2000.0)
    with pytest.raises(ConfigError, match="centre"):
        cat.cone([0, 0, 0], 0.1, 2000.0)
    with pytest.raises(ConfigError, match="hip"):
        cat.index_of(-3)
