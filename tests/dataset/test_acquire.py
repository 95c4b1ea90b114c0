"""The emulated tracker acquisitions: seeds, the window plan along the limb, two acquisitions.

Analytic Moon frames (starnav.navigation.synthetic) give the electron radiance, so these tests
need no renderer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.errors import UnknownNameError
from starnav.geometry import static_geometry
from starnav.navigation.metrics import limb_point_errors
from starnav.navigation.synthetic import draw_moon
from starnav.simulate.acquire import acquire, acquisition_seed

#: Full well [e-] of the default detector.
FULL_WELL = 1.0e5


@pytest.fixture(scope="module")
def frame():
    sc = scenario_from_dict({"camera": {"width": 256, "height": 256}})
    cam = Camera.preset("aa-str", width=256, height=256)
    g = static_geometry(cam, 9.0e7, math.radians(50.0), (10.0, -6.0))
    shade = draw_moon(cam, g, peak_dn=1.0, background_dn=0.0, psf_sigma_px=0.0)
    # electron radiance that fills 60 % of the well at the peak in 15 us
    le = (shade * 0.6 * FULL_WELL / (1.5e-5 * cam.etendue)).astype(np.float32)
    return sc, cam, g, le


def test_acquisition_seeds():
    assert acquisition_seed(7, 0, 0) == 7  # run 0 segments = the dataset's own stream
    seeds = {acquisition_seed(7, r, a) for r in range(3) for a in range(2)}
    assert len(seeds) == 6
    assert acquisition_seed(7, 2, 1) == acquisition_seed(7, 2, 1)
    assert acquisition_seed(8, 2, 1) != acquisition_seed(7, 2, 1)


def test_windows_are_planned_on_the_lit_limb_and_read_in_a_second_acquisition(frame):
    sc, cam, g, le = frame
    a = acquire(le, g, cam, sc, exposure_time=1.5e-5, windows="second")
    assert a.plan_status == "ok"
    assert 8 <= len(a.windows) <= 16
    assert a.windows_exposure is not None and a.windows_exposure.seed != a.segments_exposure.seed
    # every window straddles the true limb: its centre is within a few px of the limb conic
    centres = np.array([[w.col0 + (w.width - 1) / 2, w.row0 + (w.height - 1) / 2]
                        for w in a.windows])
    d = limb_point_errors(centres, cam, g)
    assert np.all(np.abs(d) < 3.0), d
    # and contains both Moon and sky
    for w in a.windows:
        assert w.dn.max() > 1000 and w.dn.min() < 300
    # same place, independent temporal noise: the DN differ, but by noise only
    same = acquire(le, g, cam, sc, exposure_time=1.5e-5, windows="same")
    assert [(w.row0, w.col0) for w in same.windows] == [(w.row0, w.col0) for w in a.windows]
    diff = np.concatenate([(x.dn.astype(float) - y.dn.astype(float)).ravel()
                           for x, y in zip(a.windows, same.windows, strict=True)])
    assert np.any(diff != 0)
    # read noise 100 e- = 4.1 DN, shot noise adds: the rms difference of two acquisitions is
    # sqrt(2) x (4 .. 15) DN; far below the limb contrast (> 1000 DN)
    assert 3.0 < np.sqrt(np.mean(diff**2)) < 40.0


def test_none_mode_and_unknown_mode(frame):
    sc, cam, g, le = frame
    a = acquire(le, g, cam, sc, exposure_time=1.5e-5, windows="none")
    assert a.windows == () and a.windows_exposure is None and a.plan_status == "skipped"
    with pytest.raises(UnknownNameError, match="second"):
        acquire(le, g, cam, sc, windows="both")


def test_acquisitions_are_reproducible_and_runs_differ(frame):
    sc, cam, g, le = frame
    a = acquire(le, g, cam, sc, exposure_time=1.5e-5, run=1)
    b = acquire(le, g, cam, sc, exposure_time=1.5e-5, run=1)
    c = acquire(le, g, cam, sc, exposure_time=1.5e-5, run=2)
    assert np.array_equal(a.segments_exposure.dn, b.segments_exposure.dn)
    assert a.summary() == b.summary()
    assert not np.array_equal(a.segments_exposure.dn, c.segments_exposure.dn)


def test_no_moon_gives_no_windows_and_says_why(frame):
    sc, cam, g, le = frame
    a = acquire(np.zeros_like(le), g, cam, sc, exposure_time=1.5e-5)
    assert a.windows == () and a.plan_status in ("no-moon", "no-segments")
    assert a.summary()["window_plan"]["message"]
