"""The wavelengths of each sample are drawn by the electron spectrum of the lit surface
(``render.spectral_sampling: electrons``, issue 18).

Every starnav surface is *separable*: its reflectance is a grey factor of position and angles
times one spectral shape (:mod:`starnav.renderer.bsdfs`). The radiance is then
``colour(lambda) r(x)`` with ``colour`` = solar irradiance x shape, the electron radiance is
``r(x) int colour QE T lambda / hc`` and the band radiance is ``kappa`` times it, with one
constant ``kappa`` for the whole frame. The film draws the wavelengths by
``colour QE T lambda / hc`` (both film channels carry it, ``L``'s scale carries ``kappa``), so
no sample carries the solar spectrum's lines or the Moon's reddening: the Monte Carlo only
integrates over the pixel footprint. That the renders keep their mean is checked against the
renders from before issue 18 (``test_speed_agreement.py``, every radiometric case, the ROLO
colour among them); here: ``kappa`` against the band integrals computed independently, the
constant ratio in the rendered frames, and the noise it removes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from starnav.errors import ConfigError
from starnav.geometry import static_geometry
from starnav.lunar_calibration import lunar_calibration
from starnav.renderer.render import MoonRenderer, RenderSettings
from starnav.renderer.scene import film_channels
from starnav.spectra import band_integrals, product, sensor_response, solar_spectrum

from .test_speed_agreement import RANGE_M, _camera, _cases


def test_kappa_is_the_ratio_of_the_band_integrals():
    """For a grey surface, ``kappa`` is the band irradiance over the electron irradiance of
    :func:`starnav.spectra.band_integrals` (the numbers the frame metadata reports); with the
    ROLO colour it is that of the coloured Sun."""
    resp, sun = sensor_response(), solar_spectrum()
    for colour in (sun, product(sun, lunar_calibration().spectral_shape())):
        ch = film_channels(resp, colour)
        bi = band_integrals(colour, resp)
        assert ch.scale_L / ch.scale_Le == pytest.approx(bi.irradiance / bi.electron_irradiance,
                                                         rel=1e-9)
        # one response for both channels, peak-normalised for the film's sampling
        assert ch.L is ch.Le and ch.Le.values.max() == pytest.approx(1.0, rel=1e-12)
    # the reference sampling: the band box and the normalised electron response
    ref = film_channels(resp)
    assert ref.scale_L == 1.0 and ref.L.values.min() == ref.L.values.max() == 1.0


def _renders(case: str, mode: str, spp: int, seeds) -> list:
    cam = _camera()
    r = MoonRenderer(cam, sensor_response(), solar_spectrum(), _cases()[case],
                     RenderSettings(spp=spp, spectral_sampling=mode, adaptive=False,
                                    variants=("llvm_ad_spectral", "scalar_spectral")))
    g = static_geometry(cam, RANGE_M, math.radians(60.0), (1.5, -1.0))
    return [r.render(g, seed=s) for s in seeds]


def test_band_radiance_is_kappa_times_electron_radiance_in_every_pixel():
    """Calibrated Hapke, an albedo map and the ROLO colour: in every lit pixel of every render
    ``L / Le`` is the frame's ``kappa`` to float32 rounding (measured: within 1e-7); with the
    response sampling each pixel's ratio scatters by the spectral noise (measured 1.6 %)."""
    cal = lunar_calibration()
    colour = product(solar_spectrum(), cal.spectral_shape())
    bi = band_integrals(colour, sensor_response())
    kappa = bi.irradiance / bi.electron_irradiance
    imgs = _renders("hapke_map_colour", "electrons", 4, range(3))
    assert imgs[0].meta["render"]["spectral_sampling"] == "electrons"
    for im in imgs:
        lit = im.Le > 0
        assert lit.sum() > 500
        ratio = im.L[lit].astype(np.float64) / im.Le[lit]
        assert np.all(np.abs(ratio / kappa - 1.0) < 1e-5), np.abs(ratio / kappa - 1.0).max()
    ref = _renders("hapke_map_colour", "response", 4, range(1))[0]
    lit = ref.Le > 0
    spread = np.std(ref.L[lit].astype(np.float64) / ref.Le[lit]) / kappa
    assert spread > 3e-3, spread


def test_the_electron_sampling_removes_the_spectral_noise():
    """Per-pixel noise of ``Le`` over 8 seeds at 4 spp in the lit interior of the coloured,
    mapped Hapke Moon (0.5 deg pixels): the electron sampling leaves the footprint's noise only
    (measured median 0.28 % against 1.54 % with the response sampling). Both are unbiased
    (``test_speed_agreement.py``); the bound (a quarter) leaves room for the seeds."""
    rel = {}
    for mode in ("electrons", "response"):
        stack = np.stack([im.Le for im in _renders("hapke_map_colour", mode, 4, range(8))])
        m, s = stack.mean(0), stack.std(0, ddof=1)
        lit = m > 0.2 * m.max()
        rel[mode] = float(np.median(s[lit] / m[lit]))
    assert rel["electrons"] < 0.25 * rel["response"], rel


def test_an_unknown_spectral_sampling_is_named():
    with pytest.raises(ConfigError, match="render.spectral_sampling"):
        RenderSettings(spectral_sampling="sun")
    s = RenderSettings()
    assert s.spectral_sampling == "electrons"
    assert dataclasses.replace(s, spectral_sampling="response").spectral_sampling == "response"
