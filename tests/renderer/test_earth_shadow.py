"""The Earth's shadow on the rendered Moon, against a closed-form occultation of the solar disc.

Own geometry, written here: the Moon at the origin, the Sun at 1 AU along -x, the Earth on the
Sun-Moon line's side at 384 400 km, moved across it (a passage through the penumbra and the
umbra); a Lambert sphere seen at 30 deg phase from 110 000 km. The test's closed form: the
fraction of the solar disc seen from a surface point is 1 - (lens area of the solar and
terrestrial discs) / (pi a^2), with the lens written below from the circle-circle intersection
(not the module's code), and the Moon's disc-integrated brightness is its integral over the
visible disc weighted by Lambert's cos(incidence) (the radiance of a Lambert surface, any
albedo), by a fine quadrature on the disc. Tolerances: the render's Monte Carlo noise on the
disc sum (4 spp on ~6 000 pixels: < 0.2 %) and the limb pixels' partial coverage.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.constants import AU, MOON_RADIUS, SUN_RADIUS
from starnav.eclipse import (
    EARTH_SHADOW_RADIUS,
    disc_fraction_visible,
    disc_mean_sunlit_fraction,
    sunlit_fraction,
)
from starnav.geometry import FrameGeometry
from tests.renderer.conftest import make_renderer

EARTH_DISTANCE = 384_400e3
CAMERA_DISTANCE = 1.1e8
PHASE = math.radians(30.0)
#: Disc-integrated brightness: rendered / closed form, within this (noise, limb pixels).
BRIGHTNESS_RTOL = 0.01


def _geometry(earth_offset_m: float | None) -> FrameGeometry:
    sun = np.array([-AU, 0.0, 0.0])
    cam = CAMERA_DISTANCE * np.array([-math.cos(PHASE), 0.0, math.sin(PHASE)])
    z = -cam / np.linalg.norm(cam)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    earth = None if earth_offset_m is None else np.array([-EARTH_DISTANCE, earth_offset_m, 0.0])
    return FrameGeometry(camera_position=cam, R_cam_to_inertial=np.stack([x, y, z], axis=1),
                         sun_position=sun, earth_position=earth)


def _lens(a: float, b: float, d: float) -> float:
    """Area common to two circles of radii a, b at centre distance d (circle-circle
    intersection: two circular segments)."""
    if d >= a + b:
        return 0.0
    if d <= abs(a - b):
        return math.pi * min(a, b) ** 2
    x = (d * d + a * a - b * b) / (2 * d)        # chord's distance from the first centre

    def segment(r: float, dist: float) -> float:
        return r * r * math.acos(dist / r) - dist * math.sqrt(max(r * r - dist * dist, 0.0))

    return segment(a, x) + segment(b, d - x)


def _fraction(p: np.ndarray, sun: np.ndarray, earth: np.ndarray) -> float:
    s, e = sun - p, earth - p
    a = math.asin(SUN_RADIUS / np.linalg.norm(s))
    b = math.asin(EARTH_SHADOW_RADIUS / np.linalg.norm(e))
    d = math.acos(np.clip(s @ e / (np.linalg.norm(s) * np.linalg.norm(e)), -1.0, 1.0))
    return 1.0 - _lens(a, b, d) / (math.pi * a * a)


def _closed_form_brightness(g: FrameGeometry, n: int = 120) -> float:
    """Integral over the visible disc of f(P) cos(incidence) (Lambert), relative to f = 1."""
    v = g.camera_position / np.linalg.norm(g.camera_position)
    e1 = np.cross(v, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(v, e1)
    num = den = 0.0
    grid = (np.arange(n) + 0.5) / n * 2 - 1
    for x in grid:
        for y in grid:
            if x * x + y * y >= 1.0:
                continue
            p = MOON_RADIUS * (x * e1 + y * e2 + math.sqrt(1 - x * x - y * y) * v)
            n_hat = p / MOON_RADIUS
            s_hat = (g.sun_position - p) / np.linalg.norm(g.sun_position - p)
            mu0 = float(n_hat @ s_hat)
            if mu0 <= 0:
                continue
            den += mu0
            num += mu0 * _fraction(p, g.sun_position, g.earth_position)
    return num / den


def test_lens_formula_against_the_module():
    """The module's overlap against the test's own (two segments), over every regime."""
    a, b = 0.00465, 0.0172
    for d in (0.0, 0.005, 0.0126, 0.013, 0.017, 0.02, 0.0218, 0.03):
        want = 1.0 - _lens(a, b, d) / (math.pi * a * a)
        assert disc_fraction_visible(a, b, d) == pytest.approx(want, abs=1e-12), d


def test_limb_darkened_sun_limits():
    """u = 0 by rings equals the lens; a limb-darkened Sun is hidden less at the first contact
    (its dim edge goes first) and all of it in the umbra."""
    a, b = 0.00465, 0.0172
    d = np.array([0.0, 0.01, 0.014, 0.018, 0.02, 0.0215, 0.03])
    lens = disc_fraction_visible(a, b, d)
    rings = disc_fraction_visible(a, b, d, limb_darkening=1e-12)
    np.testing.assert_allclose(rings, lens, atol=5e-4)
    dark = disc_fraction_visible(a, b, d, limb_darkening=0.6)
    assert dark[0] == 0.0 and dark[-1] == 1.0
    edge = (d > b) & (d < a + b)           # less than half the Sun hidden
    assert np.all(dark[edge] > lens[edge])


@pytest.fixture(scope="module")
def renderer():
    cam = Camera.preset("aa-str", width=128, height=128)
    return make_renderer(cam, spp=4, model="lambert", albedo=0.12)


#: Earth offsets across the Sun-Moon line [m] (at the Moon the umbra is ~4 700 km in radius, the
#: penumbra ~8 300 km, the Moon 1 737 km): outside, penumbra, partial umbra, umbra.
OFFSETS = {"outside": 40e6, "penumbra": 7.5e6, "partial umbra": 4.5e6, "umbra": 0.0}


@pytest.mark.parametrize("where", list(OFFSETS))
def test_disc_brightness_through_the_shadow_matches_the_closed_form(renderer, where):
    g = _geometry(OFFSETS[where])
    ref = renderer.render(_geometry(None), seed=3)
    img = renderer.render(g, seed=3)
    want = _closed_form_brightness(g)
    got = float(img.L.sum(dtype=np.float64) / ref.L.sum(dtype=np.float64))
    if where == "umbra":
        assert want == pytest.approx(0.0, abs=1e-12) and got == 0.0
    elif where == "outside":
        assert want == 1.0 and got == 1.0
    else:
        assert 0.02 < want < 0.98, want                   # a real partial eclipse
        assert got == pytest.approx(want, rel=BRIGHTNESS_RTOL, abs=2e-3), (got, want)
    mean = disc_mean_sunlit_fraction(g.camera_position, MOON_RADIUS, g.sun_position,
                                     g.earth_position)
    assert ("eclipse" in img.meta) == (where != "outside")
    if where != "outside":
        assert img.meta["eclipse"]["disc_mean_sunlit_fraction"] == pytest.approx(mean)


def test_outside_the_shadow_the_render_is_bit_identical(renderer):
    """A frame outside the penumbra (and one without an Earth) renders bit for bit as before
    the model: the code path is not entered."""
    a = renderer.render(_geometry(None), seed=5)
    b = renderer.render(_geometry(OFFSETS["outside"]), seed=5)
    np.testing.assert_array_equal(a.L, b.L)
    np.testing.assert_array_equal(a.Le, b.Le)
    assert "eclipse" not in b.meta


def test_the_model_off_leaves_an_eclipsed_frame_lit():
    cam = Camera.preset("aa-str", width=128, height=128)
    on = make_renderer(cam, spp=1, model="lambert")
    from dataclasses import replace

    off = make_renderer(cam, spp=1, model="lambert")
    off.settings = replace(off.settings, earth_shadow=False)
    g = _geometry(OFFSETS["umbra"])
    assert on.render(g, seed=1).L.max() == 0.0
    np.testing.assert_array_equal(off.render(g, seed=1).L, on.render(_geometry(None), seed=1).L)


def test_sunlit_fraction_at_the_2004_may_4_eclipse():
    """DE421 at the total lunar eclipse of 2004 May 4 (NASA's canon: penumbral 17:51, partial
    18:48, total 19:52-21:08, partial ends 22:12 UT): the Moon's centre as seen from the Earth
    is lit before 17:51, dark at greatest eclipse (20:30), partly lit at 22:00, fully at
    23:30."""
    from starnav.reference.amie.geometry import amie_epoch_tdb
    from starnav.scenes.ephemeris import Ephemeris

    eph = Ephemeris.default()

    def f(utc: str) -> float:
        t = amie_epoch_tdb(utc)
        sun = eph.state("sun", t, center="moon")[:3]
        earth = eph.state("earth", t, center="moon")[:3]
        return float(sunlit_fraction(np.zeros(3), sun, earth))

    assert f("2004-05-04T17:30:00") == 1.0
    assert f("2004-05-04T20:30:00") == 0.0
    assert 0.0 < f("2004-05-04T22:00:00") < 1.0
    assert f("2004-05-04T23:30:00") == 1.0


def test_dataset_truth_carries_the_eclipse_fraction():
    """truth.json's ``eclipse.disc_mean_sunlit_fraction``: 0 in the umbra, 1 outside, the
    visible disc's mean in the penumbra; null for a frame without an Earth."""
    from starnav.dataset.format import truth_to_dict

    cam = Camera.preset("aa-str", width=128, height=128)
    got = {k: truth_to_dict(_geometry(v), cam, limb_points=8)["eclipse"]
           for k, v in OFFSETS.items()}
    assert got["umbra"]["disc_mean_sunlit_fraction"] == 0.0
    assert got["outside"]["disc_mean_sunlit_fraction"] == 1.0
    assert 0.5 < got["penumbra"]["disc_mean_sunlit_fraction"] < 0.95
    assert truth_to_dict(_geometry(None), cam, limb_points=8)["eclipse"] is None
    assert "earth_position_m" in truth_to_dict(_geometry(0.0), cam, limb_points=8)["geometry"]
