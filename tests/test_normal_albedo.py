"""One physical albedo: the normal albedo, and each photometric model's parameter derived from it.

The normal albedo is ``A_n = pi r(i=0, e=0, g=0)`` (Hapke 2012, Theory of Reflectance and
Emittance Spectroscopy, 2nd ed., section 10.D). Closed forms at i = e = g = 0:

* Lambert ``r = rho mu0 / pi``                       -> ``A_n = rho``;
* Lommel-Seeliger ``r = w/(4 pi) mu0/(mu0 + mu)``    -> ``A_n = w / 8``;
* lunar-Lambert, L(0) = 1                            -> ``A_n = A``;
* Hapke (2012, eq. 12.55 with the Hapke 1984 roughness, which at i = e = 0 gives
  ``mu0e = mue = chi``, ``S = 1``):
  ``A_n = w/8 [p(0) (1 + B_S0) + H(chi, w)^2 - 1] (1 + B_C0)``,
  ``chi = 1 / sqrt(1 + pi tan^2 theta_bar)``, H from Hapke (2002) eq. 13.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav import photometry as ph
from starnav.config import scenario_from_dict
from starnav.errors import ConfigError

SATO = ph.HAPKE_LUNAR_DEFAULTS


def hapke_normal_albedo_closed_form(w: float, b: float, c: float, bs0: float, hs: float,
                                    bc0: float, hc: float, theta_bar_deg: float) -> float:
    chi = 1.0 / math.sqrt(1.0 + math.pi * math.tan(math.radians(theta_bar_deg)) ** 2)
    gamma = math.sqrt(1.0 - w)
    r0 = (1.0 - gamma) / (1.0 + gamma)
    H = 1.0 / (1.0 - w * chi * (r0 + (1.0 - 2.0 * r0 * chi) / 2.0 * math.log((1 + chi) / chi)))
    # double HG at g = 0: back lobe (1 - b^2)/(1 - b)^3, forward (1 - b^2)/(1 + b)^3
    p0 = ((1 + c) / 2 * (1 - b * b) / (1 - b) ** 3 + (1 - c) / 2 * (1 - b * b) / (1 + b) ** 3)
    return w / 8.0 * (p0 * (1.0 + bs0) + H * H - 1.0) * (1.0 + bc0)


@pytest.mark.parametrize("w", [0.05, 0.12, 0.3, 0.6, 0.95])
def test_hapke_normal_albedo_matches_its_closed_form(w):
    assert ph.normal_albedo("hapke", w) == pytest.approx(
        hapke_normal_albedo_closed_form(w, **SATO), rel=1e-9)


def test_the_issue_numbers_sato_w_012_is_a_dark_moon():
    # issue 11: Hapke with the Sato parameters and w = 0.12 has a normal albedo of 0.08
    assert ph.normal_albedo("hapke", 0.12) == pytest.approx(0.0787, abs=5e-4)


@pytest.mark.parametrize("model,factor", [("lambert", 1.0), ("lommel_seeliger", 8.0),
                                          ("lunar_lambert", 1.0)])
def test_simple_models_parameter_is_a_fixed_multiple(model, factor):
    a = np.array([0.0, 0.07, 0.12, 0.25])
    assert np.allclose(ph.model_albedo_parameter(model, a), factor * a, rtol=0, atol=0)


@pytest.mark.parametrize("model", list(ph.PHOTOMETRIC_MODELS))
@pytest.mark.parametrize("preset", ["sato2014", "rolo-calibrated"])
def test_normal_albedo_round_trip(model, preset):
    params = ph.hapke_preset(preset) if model == "hapke" else {}
    a = np.linspace(0.0, 0.3, 31)
    p = ph.model_albedo_parameter(model, a, **params)
    assert np.allclose(ph.normal_albedo(model, p, **params), a, rtol=1e-6, atol=1e-9)
    # the same normal albedo gives every model the same head-on brightness
    assert ph.reflectance(model, 0.0, 0.0, 0.0, p[12], **params) == pytest.approx(
        a[12] / math.pi, rel=1e-6)


def test_hapke_w_above_one_is_a_clear_error():
    a_max = ph.normal_albedo("hapke", 1.0)
    with pytest.raises(ConfigError, match=r"moon\.albedo.*hapke_w > 1"):
        ph.model_albedo_parameter("hapke", [0.1, a_max * 1.01])
    with pytest.raises(ConfigError, match="moon.albedo"):
        ph.model_albedo_parameter("lambert", [-0.1])


def test_a_map_whose_quantity_does_not_fit_the_model_is_an_error():
    with pytest.raises(ConfigError, match=r"moon\.dem\.albedo.*normal_albedo map.*'lambert'"):
        ph.albedo_parameter(np.full(4, 0.2), "hapke_w", "lambert", {}, "moon.dem.albedo")
    with pytest.raises(ConfigError, match=r"hapke_w.*within \[0, 1\]"):
        ph.albedo_parameter(np.array([0.2, 1.3]), "hapke_w", "hapke", dict(SATO), "moon.albedo")
    # a Hapke w map passes through unchanged for Hapke
    w = np.array([0.1, 0.3])
    assert np.array_equal(ph.albedo_parameter(w, "hapke_w", "hapke", dict(SATO), "f"), w)
    # contrast exponents belong to relative maps only
    with pytest.raises(ConfigError, match="contrast_exponent"):
        scenario_from_dict({"moon": {"dem": {"albedo": {
            "source": "x.tif", "quantity": "hapke_w", "contrast_exponent": 0.5}}}})


def test_hapke_map_above_the_reachable_albedo_is_refused_before_rendering(tmp_path):
    from starnav.simulate import target_model_from_scenario

    path = tmp_path / "a.npy"
    np.save(path, np.full((8, 16), 0.9))
    sc = scenario_from_dict({"moon": {"shape": "sphere",
                                      "albedo": {"path": str(path), "scale": 2.0}}})
    a_max = ph.normal_albedo("hapke", 1.0, **sc.moon.photometry.resolved_params())
    assert a_max < 1.8  # no Hapke surface with these parameters is that bright
    with pytest.raises(ConfigError, match=r"moon\.albedo\.path.*hapke_w > 1"):
        target_model_from_scenario(sc)
