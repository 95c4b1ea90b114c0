"""Lunar photometric models in NumPy: the reference the renderer's Mitsuba plugins are tested
against, and the closed forms used by calibration and analysis.

Each model gives the radiance factor per unit irradiance ``r(i, e, g) = L / E`` [sr^-1] at
incidence ``i``, emission ``e`` and phase ``g`` (radians; the BRDF is ``r / cos i``): Lambert,
Lommel-Seeliger, lunar-Lambert (McEwen 1991) and Hapke (2012) with opposition surges and
roughness (:data:`PHOTOMETRIC_MODELS`). Users give one physical albedo, the normal albedo
``A_n = pi r(0, 0, 0)``, from which each model derives its own parameter
(:func:`model_albedo_parameter`), so every model has the same head-on brightness.
:func:`validity_warning` reports phases outside a model's fit. The formulas and the albedo
table: docs/renderer.md and docs/methods.md, "starnav.photometry".

References
----------
* McEwen, A. S. (1991), Photometric functions for photoclinometry and other applications,
  Icarus 92, 298-311; the lunar-Lambert L(g) polynomial as used in USGS ISIS.
* Hapke, B. (1984), Bidirectional reflectance spectroscopy 3: Correction for macroscopic
  roughness, Icarus 59, 41-59.
* Hapke, B. (2002), Bidirectional reflectance spectroscopy 5: The coherent backscatter
  opposition effect and anisotropic scattering, Icarus 157, 523-534 (H-function approximation).
* Hapke, B. (2012), Theory of Reflectance and Emittance Spectroscopy, 2nd ed., CUP.
* Sato, H. et al. (2014), Resolved Hapke parameter maps of the Moon, JGR Planets 119,
  doi:10.1002/2013JE004580 (lunar defaults).

Index
-----
:func:`reflectance`, :func:`get_model`, :class:`PhotometricModel`; :func:`lambert`,
:func:`lommel_seeliger`, :func:`lunar_lambert`, :func:`lunar_lambert_L`, :func:`hapke` (with
:func:`hapke_h`, :func:`double_henyey_greenstein`, :func:`shadow_hiding`,
:func:`coherent_backscatter`, :func:`hapke_roughness`), :func:`hapke_preset`;
:func:`normal_albedo`, :func:`model_albedo_parameter`, :func:`albedo_parameter`,
:func:`validity_warning`; :func:`lambert_sphere_phase_integral`,
:func:`lambert_sphere_irradiance`, :func:`sphere_irradiance_quadrature`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from starnav.errors import ConfigError
from starnav.lunar_calibration import lunar_calibration
from starnav.registry import Registry
from starnav.typing import FloatArray

#: Default Hapke parameters for the Moon (Sato et al. 2014, as used by ABRAM).
HAPKE_LUNAR_DEFAULTS: dict[str, float] = {
    "b": 0.25,
    "c": 0.30,
    "bs0": 2.2,
    "hs": 0.07,
    "bc0": 0.0,
    "hc": 1.0,
    "theta_bar_deg": 23.66,
}

#: Hapke parameters of an S-type asteroid: 433 Eros from NEAR NIS disc-resolved photometry at
#: 946 nm (Clark, B. E. et al. 2002, Icarus 155, 189-204: single-term Henyey-Greenstein
#: asymmetry g = -0.25, shadow-hiding B0 = 1.4, h = 0.022, mean slope 28 deg; their w = 0.33 is
#: not used, the body's normal albedo sets w). The single backscattering lobe is the
#: double-HG with b = |g|, c = 1; no coherent-backscatter term (B_C0 = 0). Kitazato et al.
#: (2008, Icarus 194, 137) find Itokawa's roughness 26 +- 1 deg, "similar to Eros", and a
#: weaker opposition surge: these are the S-type defaults of the small bodies, not an Itokawa
#: fit. The values were taken from the literature as quoted, not re-read from the paper here.
HAPKE_S_TYPE_CLARK2002: dict[str, float] = {
    "b": 0.25,
    "c": 1.0,
    "bs0": 1.4,
    "hs": 0.022,
    "bc0": 0.0,
    "hc": 1.0,
    "theta_bar_deg": 28.0,
}

#: The Hapke parameter sets by name (:func:`hapke_preset`), each a function giving a fresh dict.
HAPKE_PRESETS: Registry[Callable[[], dict[str, float]]] = Registry("Hapke parameter preset", {
    "rolo-calibrated": lambda: dict(lunar_calibration().hapke),
    "sato2014": lambda: dict(HAPKE_LUNAR_DEFAULTS),
    "clark2002": lambda: dict(HAPKE_S_TYPE_CLARK2002),
})


def hapke_preset(name: str) -> dict[str, float]:
    """Hapke parameters of a named set: ``sato2014`` (:data:`HAPKE_LUNAR_DEFAULTS`, as published),
    ``rolo-calibrated`` (fitted to the ROLO lunar model, :mod:`starnav.lunar_calibration`) or
    ``clark2002`` (S-type asteroid Eros, :data:`HAPKE_S_TYPE_CLARK2002`)."""
    return HAPKE_PRESETS.get(name)()


#: Lunar-Lambert L(g) polynomial coefficients, g in degrees (McEwen 1991; USGS ISIS).
LUNAR_LAMBERT_COEFFS = (1.0, -0.019, 2.42e-4, -1.46e-6)


@dataclass(frozen=True)
class PhotometricModel:
    """A named model: its reference function and its default parameters."""

    name: str
    function: Callable[..., FloatArray]
    defaults: dict[str, float] = field(default_factory=dict)

    def check_params(self, params: dict[str, float]) -> dict[str, float]:
        """Defaults merged with ``params``; unknown or out-of-range names raise ConfigError."""
        unknown = sorted(set(params) - set(self.defaults))
        if unknown:
            raise ConfigError(f"moon.photometry.params.{unknown[0]}", params[unknown[0]],
                              f"one of {sorted(self.defaults) or 'no parameters'} for "
                              f"model {self.name!r}")
        out = {**self.defaults, **{k: float(v) for k, v in params.items()}}
        if self.name == "hapke":
            _check_range("b", out["b"], 0.0, 1.0, closed_hi=False)
            _check_range("c", out["c"], -1.0, 1.0)
            _check_range("bs0", out["bs0"], 0.0, math.inf)
            _check_range("bc0", out["bc0"], 0.0, math.inf)
            _check_range("hs", out["hs"], 0.0, math.inf, closed_lo=False)
            _check_range("hc", out["hc"], 0.0, math.inf, closed_lo=False)
            _check_range("theta_bar_deg", out["theta_bar_deg"], 0.0, 60.0)
        return out


def _check_range(name: str, v: float, lo: float, hi: float, closed_lo: bool = True,
                 closed_hi: bool = True) -> None:
    ok_lo = v >= lo if closed_lo else v > lo
    ok_hi = v <= hi if closed_hi else v < hi
    if not (ok_lo and ok_hi and math.isfinite(v)):
        a = "[" if closed_lo else "("
        b = "]" if closed_hi else ")"
        raise ConfigError(f"moon.photometry.params.{name}", v, f"a value in {a}{lo}, {hi}{b}")


def _cosines(i: ArrayLike, e: ArrayLike) -> tuple[FloatArray, FloatArray]:
    return np.cos(np.asarray(i, float)), np.cos(np.asarray(e, float))


def lambert(i: ArrayLike, e: ArrayLike, g: ArrayLike, albedo: ArrayLike) -> FloatArray:
    """Lambert: ``r = rho mu0 / pi`` [sr^-1]."""
    mu0, mu = _cosines(i, e)
    lit = (mu0 > 0) & (mu > 0)
    return np.where(lit, np.asarray(albedo, float) * mu0 / math.pi, 0.0)


def lommel_seeliger(i: ArrayLike, e: ArrayLike, g: ArrayLike, albedo: ArrayLike) -> FloatArray:
    """Lommel-Seeliger: ``r = w / (4 pi) mu0 / (mu0 + mu)`` [sr^-1]."""
    mu0, mu = _cosines(i, e)
    lit = (mu0 > 0) & (mu > 0)
    den = np.where(lit, mu0 + mu, 1.0)
    return np.where(lit, np.asarray(albedo, float) / (4 * math.pi) * mu0 / den, 0.0)


#: Phase angle [rad] where McEwen's L(g) polynomial reaches zero (103.9 deg); beyond it L is
#: clamped at 0 (pure Lambert). Root of the cubic, computed once.
LUNAR_LAMBERT_L_ZERO = math.radians(float(min(
    r.real for r in np.roots(LUNAR_LAMBERT_COEFFS[::-1]) if abs(r.imag) < 1e-9 and r.real > 0)))


def lunar_lambert_L(g: ArrayLike) -> FloatArray:
    """McEwen's limb-darkening weight L(g), ``g`` in radians (polynomial in degrees), clamped
    at 0 beyond :data:`LUNAR_LAMBERT_L_ZERO` (the polynomial's fitted range ends near 100 deg;
    past its root it would make the reflectance negative near the terminator)."""
    gd = np.degrees(np.asarray(g, float))
    c0, c1, c2, c3 = LUNAR_LAMBERT_COEFFS
    return np.maximum(c0 + gd * (c1 + gd * (c2 + gd * c3)), 0.0)


def lunar_lambert(i: ArrayLike, e: ArrayLike, g: ArrayLike, albedo: ArrayLike) -> FloatArray:
    """Lunar-Lambert (McEwen 1991): ``r = A/pi [2 L mu0/(mu0+mu) + (1-L) mu0]`` [sr^-1], with
    ``L(g)`` clamped at 0 past its root (then ``r`` is Lambert's, never negative)."""
    mu0, mu = _cosines(i, e)
    lit = (mu0 > 0) & (mu > 0)
    L = lunar_lambert_L(g)
    den = np.where(lit, mu0 + mu, 1.0)
    r = np.asarray(albedo, float) / math.pi * (2 * L * mu0 / den + (1 - L) * mu0)
    return np.where(lit, np.maximum(r, 0.0), 0.0)


# ------------------------------------------------------------------------------ Hapke
def hapke_h(x: ArrayLike, w: ArrayLike) -> FloatArray:
    """Chandrasekhar H-function, Hapke (2002) approximation, eq. 13."""
    x = np.asarray(x, float)
    w = np.asarray(w, float)
    gamma = np.sqrt(np.clip(1.0 - w, 0.0, 1.0))
    r0 = (1.0 - gamma) / (1.0 + gamma)
    xs = np.maximum(x, 1e-12)
    return 1.0 / (1.0 - w * xs * (r0 + (1.0 - 2.0 * r0 * xs) / 2.0 * np.log((1.0 + xs) / xs)))


def double_henyey_greenstein(g: ArrayLike, b: float, c: float) -> FloatArray:
    """Two-lobe Henyey-Greenstein phase function in Hapke's (2012) convention, normalised to
    4 pi over the sphere; ``c > 0`` is backscattering (g is the phase angle)."""
    cg = np.cos(np.asarray(g, float))
    back = (1 - b * b) / (1 - 2 * b * cg + b * b) ** 1.5
    fwd = (1 - b * b) / (1 + 2 * b * cg + b * b) ** 1.5
    return (1 + c) / 2 * back + (1 - c) / 2 * fwd


def shadow_hiding(g: ArrayLike, bs0: float, hs: float) -> FloatArray:
    """Shadow-hiding opposition factor ``1 + B_S0 / (1 + tan(g/2)/h_S)``."""
    return 1.0 + bs0 / (1.0 + np.tan(np.asarray(g, float) / 2.0) / hs)


def coherent_backscatter(g: ArrayLike, bc0: float, hc: float) -> FloatArray:
    """Coherent-backscatter opposition factor ``1 + B_C0 B_C(g)`` (Hapke 2002, eq. 31)."""
    t = np.tan(np.asarray(g, float) / 2.0) / hc
    ts = np.maximum(t, 1e-12)
    bc = (1.0 + -np.expm1(-ts) / ts) / (2.0 * (1.0 + ts) ** 2)
    return 1.0 + bc0 * bc


def hapke_roughness(i: ArrayLike, e: ArrayLike, psi: ArrayLike, theta_bar: float
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Hapke (1984) macroscopic roughness: effective cosines ``mu0e``, ``mue`` and the
    shadowing function ``S``, for ``0 <= i, e < pi/2`` and azimuth ``0 <= psi <= pi``
    between the planes of incidence and emission. ``theta_bar`` [rad] is the mean slope.
    """
    i = np.asarray(i, float)
    e = np.asarray(e, float)
    psi = np.abs(np.asarray(psi, float))
    mu0, mu = np.cos(i), np.cos(e)
    if theta_bar <= 0.0:
        return mu0, mu, np.ones(np.broadcast(i, e, psi).shape)
    tb = math.tan(theta_bar)
    chi = 1.0 / math.sqrt(1.0 + math.pi * tb * tb)
    cot_tb = 1.0 / tb
    tiny = 1e-9

    def E1(x: FloatArray) -> FloatArray:
        return np.exp(-2.0 / math.pi * cot_tb / np.tan(np.maximum(x, tiny)))

    def E2(x: FloatArray) -> FloatArray:
        return np.exp(-1.0 / math.pi * cot_tb**2 / np.tan(np.maximum(x, tiny)) ** 2)

    def eta(x: FloatArray) -> FloatArray:
        return chi * (np.cos(x) + np.sin(x) * tb * E2(x) / (2.0 - E1(x)))

    s2 = np.sin(psi / 2.0) ** 2
    f = np.exp(-2.0 * np.tan(np.minimum(psi, math.pi - 1e-9) / 2.0))
    eta_i, eta_e = eta(i), eta(e)
    # case i <= e
    d1 = 2.0 - E1(e) - psi / math.pi * E1(i)
    mu0e_1 = chi * (mu0 + np.sin(i) * tb * (np.cos(psi) * E2(e) + s2 * E2(i)) / d1)
    mue_1 = chi * (mu + np.sin(e) * tb * (E2(e) - s2 * E2(i)) / d1)
    S_1 = mue_1 / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * mu0 / eta_i)
    # case e < i
    d2 = 2.0 - E1(i) - psi / math.pi * E1(e)
    mu0e_2 = chi * (mu0 + np.sin(i) * tb * (E2(i) - s2 * E2(e)) / d2)
    mue_2 = chi * (mu + np.sin(e) * tb * (np.cos(psi) * E2(i) + s2 * E2(e)) / d2)
    S_2 = mue_2 / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * mu / eta_e)
    first = i <= e
    return (np.where(first, mu0e_1, mu0e_2), np.where(first, mue_1, mue_2),
            np.where(first, S_1, S_2))


def hapke(i: ArrayLike, e: ArrayLike, g: ArrayLike, albedo: ArrayLike, psi: ArrayLike | None
          = None, b: float = 0.25, c: float = 0.30, bs0: float = 2.2, hs: float = 0.07,
          bc0: float = 0.0, hc: float = 1.0, theta_bar_deg: float = 23.66) -> FloatArray:
    """Hapke (2012) bidirectional reflectance ``r(i, e, g)`` [sr^-1] with porosity K = 1::

        r = w/(4 pi) mu0e/(mu0e + mue) [p(g) B_SH(g) + H(mu0e) H(mue) - 1] B_CB(g) S(i, e, psi)

    ``albedo`` is the single-scattering albedo ``w``. ``psi`` (azimuth between the planes of
    incidence and emission) is derived from ``i, e, g`` when not given.
    """
    i = np.asarray(i, float)
    e = np.asarray(e, float)
    g = np.asarray(g, float)
    w = np.asarray(albedo, float)
    mu0, mu = np.cos(i), np.cos(e)
    lit = (mu0 > 0) & (mu > 0)
    if psi is None:
        si_se = np.sin(i) * np.sin(e)
        cpsi = np.where(si_se > 1e-12, (np.cos(g) - mu0 * mu) / np.where(si_se > 1e-12, si_se,
                                                                            1.0), 1.0)
        psi = np.arccos(np.clip(cpsi, -1.0, 1.0))
    ic = np.where(lit, i, 0.0)
    ec = np.where(lit, e, 0.0)
    mu0e, mue, S = hapke_roughness(ic, ec, psi, math.radians(theta_bar_deg))
    p = double_henyey_greenstein(g, b, c)
    multiple = hapke_h(mu0e, w) * hapke_h(mue, w) - 1.0
    r = (w / (4 * math.pi) * mu0e / (mu0e + mue) * (p * shadow_hiding(g, bs0, hs) + multiple)
         * coherent_backscatter(g, bc0, hc) * S)
    return np.where(lit, r, 0.0)


# ------------------------------------------------------------------------------ normal albedo
#: Grid of Hapke ``w`` used to invert the normal albedo (monotone; interpolation error < 1e-7).
_HAPKE_W_GRID = np.linspace(0.0, 1.0, 4097)


@lru_cache(maxsize=16)
def _hapke_normal_albedo_table(params: tuple[tuple[str, float], ...]) -> FloatArray:
    """Hapke's normal albedo on :data:`_HAPKE_W_GRID` for one parameter set (cached: the
    renderer converts every view-adapted mesh's albedo with it)."""
    table = normal_albedo("hapke", _HAPKE_W_GRID, **dict(params))
    table.flags.writeable = False
    return table


def normal_albedo(name: str, parameter: ArrayLike, **params: float) -> FloatArray:
    """Normal albedo ``A_n = pi r(0, 0, 0)`` [-] of model ``name`` with albedo parameter
    ``parameter`` (rho, w, A or Hapke w; see the module docstring)."""
    model = get_model(name)
    p = model.check_params(params)
    x = np.asarray(parameter, float)
    zero = np.zeros_like(x)
    return math.pi * model.function(zero, zero, zero, x, **p)


def model_albedo_parameter(name: str, normal: ArrayLike, field: str = "moon.albedo",
                           **params: float) -> FloatArray:
    """The albedo parameter of model ``name`` that gives the normal albedo ``normal`` [-].

    Lambert's rho and lunar-Lambert's A equal ``A_n``; Lommel-Seeliger's ``w = 8 A_n``; Hapke's
    ``w`` inverts :func:`normal_albedo` (monotone in ``w``) on a fine grid.

    Raises
    ------
    ConfigError
        naming ``field`` if ``normal`` is negative or not finite, or if a Hapke surface with
        these parameters cannot be that bright (``w`` would exceed 1).
    """
    a = np.asarray(normal, float)
    if a.size and (not np.all(np.isfinite(a)) or float(np.min(a)) < 0.0):
        raise ConfigError(field, float(np.min(a)) if a.size else a,
                          "finite normal albedos >= 0")
    model = get_model(name)
    p = model.check_params(params)
    if name in ("lambert", "lunar_lambert"):
        return a.copy()
    if name == "lommel_seeliger":
        return 8.0 * a
    if name == "hapke":
        table = _hapke_normal_albedo_table(tuple(sorted(p.items())))
        a_max = float(table[-1])
        if a.size and float(np.max(a)) > a_max * (1 + 1e-9):
            raise ConfigError(field, float(np.max(a)),
                              f"a normal albedo <= {a_max:.4g}: with these Hapke parameters it "
                              "needs a single-scattering albedo hapke_w > 1")
        return np.interp(a, table, _HAPKE_W_GRID)
    # a registered model without an explicit rule: invert numerically like Hapke
    table = normal_albedo(name, _HAPKE_W_GRID, **p)
    return np.interp(a, table, _HAPKE_W_GRID)  # pragma: no cover


def albedo_parameter(values: ArrayLike, quantity: str, model: str, params: dict[str, float],
                     field: str) -> FloatArray:
    """The photometric model's albedo parameter from albedo values of ``quantity``
    (``normal_albedo`` or ``hapke_w``; :func:`starnav.photometry.model_albedo_parameter`).

    Raises
    ------
    ConfigError
        a ``hapke_w`` map for another model than Hapke (naming ``field``), or a normal albedo
        that the model cannot reach (Hapke ``w`` > 1).
    """
    v = np.asarray(values, float)
    if quantity == "hapke_w":
        if model != "hapke":
            raise ConfigError(field, "quantity hapke_w",
                              f"a normal_albedo map for photometric model {model!r} (a Hapke "
                              "single-scattering albedo means nothing to it)")
        if v.size and (float(v.min()) < 0.0 or float(v.max()) > 1.0):
            raise ConfigError(field, f"hapke_w {float(v.min()):.4g}..{float(v.max()):.4g}",
                              "Hapke single-scattering albedos within [0, 1]")
        return v
    if quantity != "normal_albedo":
        raise ConfigError(field, f"quantity {quantity}", "normal_albedo or hapke_w")
    return model_albedo_parameter(model, v, field=field, **params)


def validity_warning(name: str, phase: float, calibrated: bool = False) -> str | None:
    """Why model ``name`` is outside its validity at ``phase`` [rad], or ``None``.

    ``calibrated`` says the parameters are the ROLO fit (valid over 1.55-97 deg).
    """
    deg = math.degrees(phase)
    if name == "lunar_lambert" and phase > LUNAR_LAMBERT_L_ZERO:
        return (f"lunar-Lambert at phase {deg:.1f} deg: past the root of McEwen's L(g) "
                f"({math.degrees(LUNAR_LAMBERT_L_ZERO):.1f} deg) L is clamped at 0 (Lambert)")
    if name == "hapke" and calibrated and not (ROLO_PHASE_RANGE[0] <= phase
                                                 <= ROLO_PHASE_RANGE[1]):
        return (f"Hapke with the ROLO-calibrated parameters at phase {deg:.1f} deg: the fit "
                f"covers {math.degrees(ROLO_PHASE_RANGE[0]):.2f}-"
                f"{math.degrees(ROLO_PHASE_RANGE[1]):.0f} deg; beyond it the brightness is the "
                "physical model's extrapolation, not a measured one")
    return None


#: Phase range [rad] of the ROLO model's fit (Kieffer & Stone 2005): 1.55-97 deg.
ROLO_PHASE_RANGE = (math.radians(1.55), math.radians(97.0))


#: Registry of photometric models by name (the renderer's Mitsuba plugins follow it:
#: :data:`starnav.renderer.bsdfs.PLUGIN_NAMES`).
PHOTOMETRIC_MODELS: Registry[PhotometricModel] = Registry("photometric model", {
    m.name: m for m in (
        PhotometricModel("lambert", lambert),
        PhotometricModel("lommel_seeliger", lommel_seeliger),
        PhotometricModel("lunar_lambert", lunar_lambert),
        PhotometricModel("hapke", hapke, dict(HAPKE_LUNAR_DEFAULTS)),
    )})


def get_model(name: str) -> PhotometricModel:
    """The registered model ``name``; an unknown name lists the known ones."""
    return PHOTOMETRIC_MODELS.get(name)


def reflectance(name: str, i: ArrayLike, e: ArrayLike, g: ArrayLike, albedo: ArrayLike,
                **params: float) -> FloatArray:
    """``r(i, e, g) = L / E`` [sr^-1] of the model ``name`` (see module docstring)."""
    model = get_model(name)
    p = model.check_params(params)
    return model.function(i, e, g, albedo, **p)


def lambert_sphere_phase_integral(phase: ArrayLike) -> FloatArray:
    """Disc-integrated Lambert sphere phase law ``[sin a + (pi - a) cos a] / pi`` (=1 at 0)."""
    a = np.asarray(phase, float)
    return (np.sin(a) + (math.pi - a) * np.cos(a)) / math.pi


def lambert_sphere_irradiance(sun_irradiance: float, albedo: float, radius: float,
                              distance: float, phase: ArrayLike) -> FloatArray:
    """Irradiance at the observer from a Lambert sphere [W m^-2] (docs/facts.md section 2)::

        E_cam = E_sun (2 rho / 3) [sin a + (pi - a) cos a] / pi (R / d)^2
    """
    return (sun_irradiance * 2.0 * albedo / 3.0 * lambert_sphere_phase_integral(phase)
            * (radius / distance) ** 2)


def sphere_irradiance_quadrature(name: str, sun_irradiance: float, albedo: float,
                                 radius: float, distance: float, phase: float,
                                 n_theta: int = 400, n_phi: int = 800, **params: float) -> float:
    """Irradiance at an observer at finite ``distance`` [m] from a sphere of ``radius`` [m]
    whose surface follows the model ``name``, by Gauss-Legendre quadrature [W m^-2]::

        E_cam = integral over the lit and visible surface of
                r(i, e, g) E_sun cos(e) / rho^2 dA

    with ``rho`` the distance from the surface element to the observer and ``g`` the local
    phase angle. This is exact for any range (the closed form
    :func:`lambert_sphere_irradiance` is its limit for ``distance -> infinity``); it shares
    no code with the renderer.
    """
    model = get_model(name)
    p = model.check_params(params)
    # observer on +x at `distance`; Sun in the x-y plane at `phase` from +x
    obs = np.array([distance, 0.0, 0.0])
    sun = np.array([math.cos(phase), math.sin(phase), 0.0])
    # integrate over the cap facing the observer: polar angle t from +x in [0, acos(R/d)]
    t_max = math.acos(radius / distance)
    xt, wt = np.polynomial.legendre.leggauss(n_theta)
    xp, wp = np.polynomial.legendre.leggauss(n_phi)
    t = 0.5 * t_max * (xt + 1.0)
    wt = 0.5 * t_max * wt
    ph = math.pi * (xp + 1.0)
    wp = math.pi * wp
    T, P = np.meshgrid(t, ph, indexing="ij")
    n = np.stack([np.cos(T), np.sin(T) * np.cos(P), np.sin(T) * np.sin(P)], axis=-1)
    pts = radius * n
    to_obs = obs - pts
    rho = np.linalg.norm(to_obs, axis=-1)
    v = to_obs / rho[..., None]
    mu = np.sum(n * v, axis=-1)
    mu0 = n @ sun
    g = np.arccos(np.clip(v @ sun, -1.0, 1.0))
    i = np.arccos(np.clip(mu0, -1.0, 1.0))
    e = np.arccos(np.clip(mu, -1.0, 1.0))
    r = model.function(i, e, g, albedo, **p)
    integrand = r * sun_irradiance * np.clip(mu, 0.0, None) / rho**2
    dA = radius**2 * np.sin(T)
    return float(np.sum(integrand * dA * wt[:, None] * wp[None, :]))
