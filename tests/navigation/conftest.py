"""Fixtures of the navigation tests: analytic Moon frames (drawn once per session)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav.camera import Camera
from starnav.geometry import static_geometry
from starnav.navigation.synthetic import draw_moon, threshold_segments

#: Gaussian PSF of the analytic frames [px] (about the AA-STR's defocus, docs/facts.md s4).
PSF_SIGMA_PX = 0.8
#: Peak DN and segment threshold of a well-exposed analytic frame (12-bit ADC).
PEAK_DN = 3000.0
THRESHOLD_DN = 300


@pytest.fixture(scope="session")
def cam() -> Camera:
    return Camera.preset("aa-str")


@pytest.fixture(scope="session")
def disc_frame(cam):
    """A well-exposed Lambert Moon at 60 000 km, phase 40 deg, off-axis (geometry, dn, segments)."""
    g = static_geometry(cam, 6.0e7, math.radians(40.0), moon_offset_px=(250.0, -150.0),
                        sun_azimuth=0.7)
    dn = draw_moon(cam, g, peak_dn=PEAK_DN, psf_sigma_px=PSF_SIGMA_PX, supersample=8)
    return g, dn, threshold_segments(dn, (THRESHOLD_DN,))


@pytest.fixture(scope="session")
def noisy_disc_frame(cam):
    """The same Moon with 3 DN read noise and a 20 DN offset, phase 60 deg, other side."""
    g = static_geometry(cam, 7.0e7, math.radians(60.0), moon_offset_px=(-180.0, 220.0),
                        sun_azimuth=2.5)
    dn = draw_moon(cam, g, peak_dn=PEAK_DN, psf_sigma_px=PSF_SIGMA_PX, supersample=8,
                   background_dn=20.0, read_noise_dn=3.0, rng=np.random.default_rng(7))
    return g, dn, threshold_segments(dn, (THRESHOLD_DN,))
