"""The procedural Moon: determinism, crater shapes and numbers, maria.

Crater shapes are measured on the terrain grid itself, after stamping an isolated crater; to
resolve a 10 km crater by ~100 cells without a 50 000-column global grid, the stamping is done
on a small sphere (radius tens of km): the stamper only uses great-circle distances, so the
profile it writes is the same as on the Moon.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.dem.procedural import (
    CraterMorphology,
    crater_catalogue,
    power_law_slope_mle,
    procedural_moon,
    stamp_craters,
)
from starnav.dem.schema import ProceduralDemConfig

#: Pike (1977) fresh lunar craters (km): simple d = 0.196 D^1.010 (we use d/D = 0.196),
#: complex d = 1.044 D^0.301; rim height simple 0.036 D^1.014, complex 0.236 D^0.399.
PIKE_SIMPLE_DEPTH_RATIO = 0.196
PIKE_COMPLEX = (1.044, 0.301)
#: Depth measured on the grid: rim crest between cells costs ~2 cells / D (<= 2 % here).
DEPTH_RTOL = 0.03


def _isolated_crater(diameter_m: float, morph: CraterMorphology, cells_across: float = 100.0):
    """Stamp one crater at (0, 0) on a zero grid of a sphere sized so that the crater spans
    ``cells_across`` cells; return heights and distances r / R of the cells."""
    n_lat = 360
    cell = diameter_m / cells_across
    radius = cell * n_lat / math.pi
    h = np.zeros((n_lat, 2 * n_lat), np.float32)
    stamp_craters(h, np.array([0.0]), np.array([0.0]), np.array([diameter_m]), morph, radius)
    lat = math.pi / 2 - (np.arange(n_lat) + 0.5) * math.pi / n_lat
    lon = -math.pi + (np.arange(2 * n_lat) + 0.5) * math.pi / n_lat
    cosd = np.cos(lat)[:, None] * np.cos(lon)[None, :]
    r_over_R = np.arccos(np.clip(cosd, -1, 1)) * radius / (0.5 * diameter_m)
    return h, r_over_R


@pytest.mark.parametrize("ratio", [PIKE_SIMPLE_DEPTH_RATIO, 0.15])
def test_simple_crater_depth_diameter(ratio):
    """Rim-crest-to-floor depth / D of a 10 km simple crater equals the configured ratio."""
    morph = CraterMorphology(simple_depth_ratio=ratio)
    D = 10_000.0
    h, rr = _isolated_crater(D, morph)
    inner = rr <= 1.05
    depth = float(h[inner].max() - h[inner].min())
    assert depth / D == pytest.approx(ratio, rel=DEPTH_RTOL)
    # rim raised above the surroundings by Pike's 0.036 D^1.014 km
    rim = float(h[inner].max())
    assert rim == pytest.approx(1e3 * 0.036 * (D / 1e3) ** 1.014, rel=DEPTH_RTOL)


@pytest.mark.parametrize("D_km", [30.0, 80.0])
def test_complex_crater_depth_and_transition(D_km):
    """Complex craters (above the 15 km transition) follow d = 1.044 D^0.301 km: far shallower
    than simple ones (d/D = 0.068 at 30 km, 0.039 at 80 km)."""
    morph = CraterMorphology()
    D = D_km * 1e3
    h, rr = _isolated_crater(D, morph)
    inner = rr <= 1.05
    depth = float(h[inner].max() - h[inner].min())
    want = 1e3 * PIKE_COMPLEX[0] * D_km ** PIKE_COMPLEX[1]
    assert depth == pytest.approx(want, rel=DEPTH_RTOL)
    assert depth / D < 0.5 * PIKE_SIMPLE_DEPTH_RATIO
    # flat floor: a ring of the floor between the central peak and the wall is level
    floor = h[(rr > 0.3) & (rr < 0.4)]
    assert float(floor.max() - floor.min()) < 0.02 * depth


def test_transition_diameter_is_configurable():
    m = CraterMorphology(transition_diameter=20_000.0)
    assert m.depth(18_000.0) == pytest.approx(0.196 * 18_000.0)
    assert CraterMorphology().depth(18_000.0) == pytest.approx(1044.0 * 18**0.301)


@pytest.mark.parametrize("exponent", [3.0, 2.5])
def test_ejecta_thickness_falls_off_as_configured_power(exponent):
    """log h vs log(r/R) between 1.2 R and 2.4 R has slope -exponent (McGetchin et al. 1973)."""
    morph = CraterMorphology(ejecta_exponent=exponent)
    h, rr = _isolated_crater(10_000.0, morph, cells_across=60.0)
    sel = (rr > 1.2) & (rr < 2.4)
    slope = np.polyfit(np.log(rr[sel]), np.log(h[sel].astype(float)), 1)[0]
    assert slope == pytest.approx(-exponent, abs=0.05)


@pytest.mark.parametrize(("slope", "d_min_km"), [(2.0, 10.0), (2.6, 5.0)])
def test_size_frequency_slope_and_density(slope, d_min_km):
    """Cumulative SFD of the catalogue: MLE slope within 5 sigma (sigma = b / sqrt(n), Aban et
    al. 2006) of the configured one, and N(>= d_min) within 5 sigma of the Poisson mean
    N1 * area * (d_min^-b - d_max^-b)."""
    cfg = ProceduralDemConfig(sfd_slope=slope, seed=11)
    cat = crater_catalogue(cfg, d_min_km * 1e3)
    n = len(cat)
    area = 4 * math.pi * 1737.4**2
    mean = cfg.crater_density_1km_km2 * area * (d_min_km**-slope - 300.0**-slope)
    assert abs(n - mean) < 5 * math.sqrt(mean)
    b = power_law_slope_mle(cat.diameter, d_min_km * 1e3, 300e3)
    assert b == pytest.approx(slope, abs=5 * slope / math.sqrt(n))
    assert cat.diameter.min() >= d_min_km * 1e3
    # positions uniform on the sphere: mean sin(lat) ~ 0, mean sin^2 = 1/3
    s = np.sin(cat.lat)
    assert abs(s.mean()) < 5 / math.sqrt(3 * n)
    assert (s**2).mean() == pytest.approx(1 / 3, abs=5 * math.sqrt(4 / 45 / n))
    # post-mare fraction = N1_mare / N1_highland (binomial, 5 sigma)
    p = cfg.mare_crater_density_1km_km2 / cfg.crater_density_1km_km2
    assert abs(cat.post_mare.mean() - p) < 5 * math.sqrt(p * (1 - p) / n)


def test_mle_detects_a_wrong_slope():
    """Negative control: diameters drawn with b = 2.4 are not accepted as b = 2.0."""
    from starnav.dem.procedural import sample_power_law

    d = sample_power_law(np.random.default_rng(0), 5000, 10e3, 300e3, 2.4)
    b = power_law_slope_mle(d, 10e3, 300e3)
    assert abs(b - 2.0) > 5 * 2.0 / math.sqrt(5000)
    assert b == pytest.approx(2.4, abs=5 * 2.4 / math.sqrt(5000))


def test_same_seed_same_world_other_seed_other_world():
    """Seeded regression: exact equality is intended (same seed, same bits)."""
    from starnav.dem import procedural

    cfg = ProceduralDemConfig(pixels_per_degree=1.0, seed=5)
    a = procedural_moon(cfg)
    procedural._CACHE.clear()
    b = procedural_moon(cfg)
    assert a is not b
    np.testing.assert_array_equal(a.dem.heights, b.dem.heights)
    np.testing.assert_array_equal(a.albedo.values, b.albedo.values)
    c = procedural_moon(ProceduralDemConfig(pixels_per_degree=1.0, seed=6))
    assert np.abs(c.dem.heights - a.dem.heights).max() > 1000.0


def test_large_craters_do_not_depend_on_resolution():
    """A finer grid adds small craters; the craters both resolutions have are the same."""
    cfg = ProceduralDemConfig(seed=3)
    coarse = crater_catalogue(cfg, 20e3)
    fine = crater_catalogue(cfg, 8e3)
    big = fine.diameter >= 20e3
    assert big.sum() == len(coarse) > 100
    np.testing.assert_array_equal(np.sort(fine.diameter[big]), np.sort(coarse.diameter))


def test_maria_cover_the_configured_fraction_and_are_dark_and_low():
    cfg = ProceduralDemConfig(pixels_per_degree=2.0, seed=2)
    moon = procedural_moon(cfg)
    w = np.cos(moon.dem.lat_centres())[:, None] * np.ones(moon.dem.shape[1])
    mare = moon.mare > 0.5
    frac = float((w * mare).sum() / w.sum())
    assert frac == pytest.approx(cfg.mare_fraction, abs=0.02)
    alb = moon.albedo.values
    a_mare = float(np.average(alb[moon.mare > 0.95], weights=w[moon.mare > 0.95]))
    a_high = float(np.average(alb[moon.mare < 0.05], weights=w[moon.mare < 0.05]))
    assert a_mare == pytest.approx(cfg.mare_albedo, rel=0.15)
    assert a_high == pytest.approx(cfg.highland_albedo, rel=0.15)
    h = moon.dem.heights
    assert float(h[moon.mare > 0.95].mean()) < float(h[moon.mare < 0.05].mean()) - 500.0
    # near-side bias: more mare within 60 deg of (0, 0) than on the far side
    lon = moon.dem.lon_centres()
    near = (np.abs(lon) < np.radians(60))[None, :] & np.ones_like(mare)
    assert mare[near].mean() > 2 * mare[~near].mean()


def test_relief_is_lunar_like():
    """Heights within the Moon's -9..+11 km (LOLA) order of magnitude, not flat."""
    moon = procedural_moon(ProceduralDemConfig(pixels_per_degree=2.0, seed=2))
    lo, hi = moon.dem.height_range
    assert -15_000 < lo < -2_000 and 2_000 < hi < 15_000
    assert 500 < float(moon.dem.heights.std()) < 4000
