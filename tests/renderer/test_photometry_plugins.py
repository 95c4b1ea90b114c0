"""Photometric plugins (Dr.Jit) against the NumPy reference and the published closed forms.

The plugins are evaluated through Mitsuba's own BSDF interface (``bsdf.eval``) at random
geometries; the NumPy module :mod:`starnav.photometry` is an independent implementation of the
published formulas (McEwen 1991; Hapke 1984, 2002, 2012).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from starnav import photometry as ph

#: float32 evaluation inside Dr.Jit vs float64 NumPy.
PLUGIN_RTOL = 2e-4


def random_geometry(n: int, seed: int, max_angle: float = 1.45):
    rng = np.random.default_rng(seed)
    i = rng.uniform(0.0, max_angle, n)
    e = rng.uniform(0.0, max_angle, n)
    psi = rng.uniform(0.0, math.pi, n)
    cg = np.cos(i) * np.cos(e) + np.sin(i) * np.sin(e) * np.cos(psi)
    g = np.arccos(np.clip(cg, -1, 1))
    return i, e, psi, g


def eval_plugin(model: str, albedo: float, i, e, psi, params=None):
    """Evaluate the registered plugin for local directions built from (i, e, psi)."""
    import drjit as dr
    import mitsuba as mi

    from starnav.renderer import backend

    backend.activate(("llvm_ad_spectral", "scalar_spectral"))
    from starnav.renderer.bsdfs import PLUGIN_NAMES  # needs a variant set

    d = {"type": PLUGIN_NAMES[model], "albedo": {"type": "uniform", "value": albedo}}
    d.update(params or {})
    bsdf = mi.load_dict(d)
    wi = np.stack([np.sin(e), np.zeros_like(e), np.cos(e)], 1)  # to the observer
    wo = np.stack([np.sin(i) * np.cos(psi), np.sin(i) * np.sin(psi), np.cos(i)], 1)  # to Sun
    out = []
    ctx = mi.BSDFContext()
    if mi.variant().startswith("scalar"):
        for a, b in zip(wi, wo, strict=True):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*a)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.wavelengths = mi.Spectrum(550.0)
            out.append(float(np.asarray(bsdf.eval(ctx, si, mi.Vector3f(*b)))[0]))
        return np.array(out)
    si = dr.zeros(mi.SurfaceInteraction3f, len(i))
    si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wavelengths = dr.full(mi.Spectrum, 550.0, len(i))
    val = bsdf.eval(ctx, si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2]))
    return np.asarray(val)[0] if np.asarray(val).ndim == 2 else np.asarray(val)


@pytest.mark.parametrize("model", ["lambert", "lommel_seeliger", "lunar_lambert"])
def test_simple_models_match_closed_forms(model):
    i, e, psi, g = random_geometry(400, 1)
    albedo = 0.17
    mu0, mu = np.cos(i), np.cos(e)
    closed = {
        "lambert": albedo * mu0 / math.pi,
        "lommel_seeliger": albedo / (4 * math.pi) * mu0 / (mu0 + mu),
    }
    if model == "lunar_lambert":
        gd = np.degrees(g)
        Lg = 1 - 0.019 * gd + 2.42e-4 * gd**2 - 1.46e-6 * gd**3  # McEwen 1991 / USGS ISIS
        Lg = np.maximum(Lg, 0.0)  # clamped past its root (103.9 deg): Lambert there
        closed[model] = albedo / math.pi * (2 * Lg * mu0 / (mu0 + mu) + (1 - Lg) * mu0)
    ref = ph.reflectance(model, i, e, g, albedo)
    assert np.allclose(ref, closed[model], rtol=1e-12)
    got = eval_plugin(model, albedo, i, e, psi)
    assert np.allclose(got, ref, rtol=PLUGIN_RTOL, atol=1e-7)


def test_lunar_lambert_limits():
    # L(0) = 1: Lommel-Seeliger shape with r = 2 A/pi mu0/(mu0+mu); L = 0 would be Lambert.
    i, e = np.array([0.3, 1.0]), np.array([0.5, 0.2])
    assert np.allclose(ph.lunar_lambert(i, e, 0.0, 0.2),
                       2 * 0.2 / math.pi * np.cos(i) / (np.cos(i) + np.cos(e)))


def test_lunar_lambert_past_its_root_is_lambert_not_negative():
    """McEwen's L(g) cubic has its root at 103.9 deg; the 28-day LUMIO arc reaches 164 deg.
    Past the root L is clamped at 0: the reflectance is Lambert's (never negative, never
    silently clipped by the renderer)."""
    assert math.degrees(ph.LUNAR_LAMBERT_L_ZERO) == pytest.approx(103.95, abs=0.01)
    g = np.radians([110.0, 140.0, 164.0])
    i, e = np.radians([60.0, 80.0, 85.0]), np.radians([50.0, 60.0, 79.0])
    assert np.allclose(ph.lunar_lambert(i, e, g, 0.2), 0.2 * np.cos(i) / math.pi, rtol=1e-12)
    # azimuth pi between the planes: phase = i + e = 110, 140, 164 deg, as above
    got = eval_plugin("lunar_lambert", 0.2, i, e, np.full(3, math.pi))
    assert np.allclose(got, 0.2 * np.cos(i) / math.pi, rtol=PLUGIN_RTOL, atol=1e-7)
    assert ph.validity_warning("lunar_lambert", math.radians(120.0)) is not None
    assert ph.validity_warning("lunar_lambert", math.radians(90.0)) is None


def test_hapke_plugin_matches_numpy():
    i, e, psi, g = random_geometry(500, 2, max_angle=1.4)
    w = 0.32
    got = eval_plugin("hapke", w, i, e, psi)
    ref = ph.hapke(i, e, g, w, psi=psi)
    assert np.allclose(got, ref, rtol=PLUGIN_RTOL, atol=1e-7)


def test_hapke_plugin_with_coherent_backscatter_matches_numpy():
    i, e, psi, g = random_geometry(300, 3, max_angle=1.3)
    params = {"bc0": 0.8, "hc": 0.05, "theta_bar_deg": 12.0}
    got = eval_plugin("hapke", 0.5, i, e, psi, params)
    ref = ph.hapke(i, e, g, 0.5, psi=psi, **params)
    assert np.allclose(got, ref, rtol=PLUGIN_RTOL, atol=1e-7)


@pytest.mark.parametrize("theta_bar", [0.0, 23.66, 40.0])
def test_hapke_reciprocity(theta_bar):
    # Helmholtz reciprocity of the BRDF r / mu0: swapping incidence and emission.
    i, e, psi, g = random_geometry(300, 4)
    f1 = ph.hapke(i, e, g, 0.3, psi=psi, theta_bar_deg=theta_bar) / np.cos(i)
    f2 = ph.hapke(e, i, g, 0.3, psi=psi, theta_bar_deg=theta_bar) / np.cos(e)
    assert np.allclose(f1, f2, rtol=1e-12)
    p1 = eval_plugin("hapke", 0.3, i, e, psi, {"theta_bar_deg": theta_bar}) / np.cos(i)
    p2 = eval_plugin("hapke", 0.3, e, i, psi, {"theta_bar_deg": theta_bar}) / np.cos(e)
    assert np.allclose(p1, p2, rtol=5 * PLUGIN_RTOL)


def test_hapke_reduces_to_isotropic_no_opposition_form():
    # b = c = B0 = 0 and no roughness: r = w/(4 pi) mu0/(mu0+mu) H(mu0) H(mu) (isotropic
    # scatterers; Hapke 2012 eq. 10.4 with p = 1), H from Hapke (2002) eq. 13.
    i, e, psi, g = random_geometry(200, 5)
    w = 0.6
    mu0, mu = np.cos(i), np.cos(e)
    gamma = math.sqrt(1 - w)
    r0 = (1 - gamma) / (1 + gamma)

    def H(x):
        return 1 / (1 - w * x * (r0 + (1 - 2 * r0 * x) / 2 * np.log((1 + x) / x)))

    expected = w / (4 * math.pi) * mu0 / (mu0 + mu) * H(mu0) * H(mu)
    params = dict(b=0.0, c=0.0, bs0=0.0, bc0=0.0, theta_bar_deg=0.0)
    assert np.allclose(ph.hapke(i, e, g, w, psi=psi, **params), expected, rtol=1e-12)
    assert np.allclose(eval_plugin("hapke", w, i, e, psi, params), expected, rtol=PLUGIN_RTOL)


@pytest.mark.parametrize("w", [0.3, 0.9, 0.99])
def test_hapke_h_approximation_against_integral_equation(w):
    # Chandrasekhar's H-function solves H(x) = 1 + (w/2) x H(x) int_0^1 H(t)/(x+t) dt.
    # Solve it by fixed-point iteration on a Gauss-Legendre grid (an independent method);
    # Hapke (2002) states his approximation is within 1 %.
    x, wts = np.polynomial.legendre.leggauss(200)
    mu, wt = 0.5 * (x + 1), 0.5 * wts
    H = np.ones_like(mu)
    for _ in range(20000):
        Hn = 1 / (1 - w / 2 * mu * np.sum(wt * H[None, :] / (mu[:, None] + mu[None, :]), 1))
        if np.max(np.abs(Hn - H)) < 1e-13:
            break
        H = Hn
    sel = mu > 0.02
    assert np.allclose(ph.hapke_h(mu[sel], w), H[sel], rtol=0.01)


def test_opposition_terms_at_zero_phase():
    # B_S(0) = 1 and B_C(0) = 1, so the factors are 1 + B0 at g = 0.
    assert ph.shadow_hiding(0.0, 2.2, 0.07) == pytest.approx(3.2)
    assert ph.coherent_backscatter(0.0, 0.5, 0.1) == pytest.approx(1.5, rel=1e-6)


def test_double_hg_is_normalised():
    # (1/4pi) integral p dOmega = 1 for the Hapke-convention two-lobe HG.
    x, wts = np.polynomial.legendre.leggauss(400)
    g = np.arccos(x)
    val = 0.5 * np.sum(ph.double_henyey_greenstein(g, 0.25, 0.3) * wts)
    assert val == pytest.approx(1.0, rel=1e-10)
