"""Lunar photometric models as Python ``mi.BSDF`` plugins (they run inside Dr.Jit's kernels).

Each plugin's ``eval`` returns the BSDF times the cosine of the light direction: under a
collimated irradiance ``E``, exactly the radiance factor ``r = L / E`` [sr^-1] of
:mod:`starnav.photometry` (the NumPy reference they are tested against). ``si.wi`` points to
the observer (``mu = cos e``), ``wo`` to the light (``mu0 = cos i``); the phase angle is
``acos(wi . wo)``. ``sample`` draws cosine-weighted directions (enough for the single-bounce
``direct`` integrator with emitter sampling; multiple scattering is neglected, as in every
model here).

The albedo is a Mitsuba texture (``uniform``, a one-channel ``bitmap`` over the sphere's
(u, v), or a ``mesh_attribute``) evaluated as a grey value (RGB textures, which vanish outside
360-830 nm, are never involved). Two optional factors multiply the reflectance:
``spectral_shape`` (a ``regular`` spectrum, 1 at the normal albedo's reference wavelength: the
ROLO lunar reddening by default, :mod:`starnav.lunar_calibration`) and ``scale``
(``moon.albedo_scale``: radiance is exactly linear in it, as the albedo-exposure scaling needs).

:func:`register_plugins` registers one plugin per model of
:data:`starnav.photometry.PHOTOMETRIC_MODELS`, named ``starnav_<model>``; it must run again
after every variant switch (``backend.activate`` does it).
"""

from __future__ import annotations

import functools
import math

import drjit as dr
import mitsuba as mi

from starnav.photometry import HAPKE_LUNAR_DEFAULTS, LUNAR_LAMBERT_COEFFS, PHOTOMETRIC_MODELS
from starnav.registry import Registry

INV_PI = 1.0 / math.pi
INV_FOUR_PI = 1.0 / (4.0 * math.pi)
#: tan((pi - 1e-4) / 2): the cap of tan(psi / 2) in Hapke's shadowing (psi -> pi).
_TAN_HALF_PSI_MAX = math.tan((math.pi - 1e-4) / 2.0)

#: Mitsuba plugin name for each photometric model name (derived from the model registry).
PLUGIN_NAMES: Registry[str] = Registry(PHOTOMETRIC_MODELS.kind, {
    model: f"starnav_{model}" for model in PHOTOMETRIC_MODELS})


def _define_classes() -> dict[str, type]:
    """Define the plugin classes on the *active* variant's ``mi.BSDF`` (Mitsuba's classes
    differ per variant, so this runs again after every variant switch)."""

    class _PhotometricBSDF(mi.BSDF):
        """Shared machinery: albedo texture, cosine sampling, flags, eval via ``_r``."""

        def __init__(self, props: mi.Properties) -> None:
            mi.BSDF.__init__(self, props)
            if "albedo" in props:
                alb = props["albedo"]
                if isinstance(alb, float | int):
                    alb = mi.load_dict({"type": "uniform", "value": float(alb)})
            else:
                alb = mi.load_dict({"type": "uniform", "value": 0.12})
            self.albedo = alb
            self.scale = float(props["scale"]) if "scale" in props else 1.0
            self.spectral = props["spectral_shape"] if "spectral_shape" in props else None
            self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        # Each model defines ``_r(si, wo, mu0, mu, cos_g, albedo) -> r = L / E`` on Dr.Jit floats.

        def _value(self, si, wo, active):
            mu = mi.Frame3f.cos_theta(si.wi)
            mu0 = mi.Frame3f.cos_theta(wo)
            cos_g = dr.clip(dr.dot(si.wi, wo), -1.0, 1.0)
            alb = self.albedo.eval_1(si, active)
            lit = active & (mu > 0) & (mu0 > 0)
            r = self._r(si, wo, dr.maximum(mu0, 1e-7), dr.maximum(mu, 1e-7), cos_g, alb)
            r = dr.select(lit, dr.maximum(r, 0.0), 0.0)
            if self.scale != 1.0:
                r = r * self.scale
            return r, lit

        def _spectrum(self, value, si, active):
            """``value`` (a Float) times the spectral shape at the sample's wavelengths."""
            if self.spectral is None:
                return mi.Spectrum(value)
            return mi.Spectrum(value) * self.spectral.eval(si, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = mi.BSDFSample3f()
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.wo = wo
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            val, lit = self._value(si, wo, active)
            weight = dr.select(lit & (bs.pdf > 0), val / dr.maximum(bs.pdf, 1e-12), 0.0)
            return bs, self._spectrum(weight, si, active)

        def eval(self, ctx, si, wo, active=True):
            val, _ = self._value(si, wo, active)
            return self._spectrum(val, si, active)

        def pdf(self, ctx, si, wo, active=True):
            ok = (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            callback.put("albedo", self.albedo, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"{type(self).__name__}[albedo={self.albedo}]"


    class LambertBSDF(_PhotometricBSDF):
        """``r = rho mu0 / pi``."""

        def _r(self, si, wo, mu0, mu, cos_g, alb):
            return alb * INV_PI * mu0


    class LommelSeeligerBSDF(_PhotometricBSDF):
        """``r = w / (4 pi) mu0 / (mu0 + mu)``."""

        def _r(self, si, wo, mu0, mu, cos_g, alb):
            return alb * INV_FOUR_PI * mu0 / (mu0 + mu)


    class LunarLambertBSDF(_PhotometricBSDF):
        """McEwen (1991): ``r = A/pi [2 L(g) mu0/(mu0+mu) + (1-L(g)) mu0]``, g in degrees in L."""

        def _r(self, si, wo, mu0, mu, cos_g, alb):
            gd = dr.acos(cos_g) * (180.0 / math.pi)
            c0, c1, c2, c3 = LUNAR_LAMBERT_COEFFS
            L = dr.maximum(c0 + gd * (c1 + gd * (c2 + gd * c3)), 0.0)  # clamped past its root
            return alb * INV_PI * (2.0 * L * mu0 / (mu0 + mu) + (1.0 - L) * mu0)


    class HapkeBSDF(_PhotometricBSDF):
        """Hapke (2012) with shadow-hiding and coherent-backscatter opposition and Hapke (1984)
        macroscopic roughness; parameters ``b, c, bs0, hs, bc0, hc, theta_bar_deg`` (Sato et al.
        2014 lunar defaults). See :func:`starnav.photometry.hapke` for the formulas."""

        def __init__(self, props: mi.Properties) -> None:
            super().__init__(props)
            p = {k: float(props[k]) if k in props else v for k, v in HAPKE_LUNAR_DEFAULTS.items()}
            self.b, self.c = p["b"], p["c"]
            self.bs0, self.hs = p["bs0"], p["hs"]
            self.bc0, self.hc = p["bc0"], p["hc"]
            self.theta_bar = math.radians(p["theta_bar_deg"])

        @staticmethod
        def _H(x, w):
            gamma = dr.sqrt(dr.maximum(1.0 - w, 0.0))
            r0 = (1.0 - gamma) / (1.0 + gamma)
            xs = dr.maximum(x, 1e-7)
            return 1.0 / (1.0 - w * xs * (r0 + (1.0 - 2.0 * r0 * xs) * 0.5
                                          * dr.log((1.0 + xs) / xs)))

        def _roughness(self, mu0, mu, cos_psi):
            """Effective cosines and shadowing function S (Hapke 1984)."""
            tb = math.tan(self.theta_bar)
            chi = 1.0 / math.sqrt(1.0 + math.pi * tb * tb)
            cot_tb = 1.0 / tb
            sin_i = dr.safe_sqrt(1.0 - mu0 * mu0)
            sin_e = dr.safe_sqrt(1.0 - mu * mu)
            cot_i = mu0 / dr.maximum(sin_i, 1e-7)
            cot_e = mu / dr.maximum(sin_e, 1e-7)
            c_psi = dr.clip(cos_psi, -1.0, 1.0)
            psi = dr.acos(c_psi)
            # half-angle identities instead of sin and tan of psi / 2 (two transcendental
            # functions fewer per sample): sin^2(psi/2) = (1 - cos psi) / 2 and
            # tan(psi/2) = sqrt((1 - cos psi) / (1 + cos psi)), capped as tan((pi - 1e-4)/2)
            s2 = (1.0 - c_psi) * 0.5
            tan_half_psi = dr.minimum(
                dr.safe_sqrt((1.0 - c_psi) / dr.maximum(1.0 + c_psi, 1e-30)), _TAN_HALF_PSI_MAX)
            f = dr.exp(-2.0 * tan_half_psi)

            def E1(cot_x):
                return dr.exp(-2.0 / math.pi * cot_tb * cot_x)

            def E2(cot_x):
                return dr.exp(-1.0 / math.pi * cot_tb * cot_tb * cot_x * cot_x)

            E1i, E1e, E2i, E2e = E1(cot_i), E1(cot_e), E2(cot_i), E2(cot_e)
            eta_i = chi * (mu0 + sin_i * tb * E2i / (2.0 - E1i))
            eta_e = chi * (mu + sin_e * tb * E2e / (2.0 - E1e))
            # case i <= e  (mu0 >= mu)
            d1 = 2.0 - E1e - psi * (1.0 / math.pi) * E1i
            mu0e_1 = chi * (mu0 + sin_i * tb * (cos_psi * E2e + s2 * E2i) / d1)
            mue_1 = chi * (mu + sin_e * tb * (E2e - s2 * E2i) / d1)
            S_1 = mue_1 / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * mu0 / eta_i)
            # case e < i
            d2 = 2.0 - E1i - psi * (1.0 / math.pi) * E1e
            mu0e_2 = chi * (mu0 + sin_i * tb * (E2i - s2 * E2e) / d2)
            mue_2 = chi * (mu + sin_e * tb * (cos_psi * E2i + s2 * E2e) / d2)
            S_2 = mue_2 / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * mu / eta_e)
            first = mu0 >= mu
            return (dr.select(first, mu0e_1, mu0e_2), dr.select(first, mue_1, mue_2),
                    dr.select(first, S_1, S_2))

        def _r(self, si, wo, mu0, mu, cos_g, alb):
            w = alb
            b, c = self.b, self.c
            # double Henyey-Greenstein; x^-1.5 = rsqrt(x) / x (Dr.Jit's power is exp(y log x))
            d_back = 1.0 - 2.0 * b * cos_g + b * b
            d_fwd = 1.0 + 2.0 * b * cos_g + b * b
            p = ((1.0 + c) * 0.5 * (1.0 - b * b) * dr.rsqrt(d_back) / d_back
                 + (1.0 - c) * 0.5 * (1.0 - b * b) * dr.rsqrt(d_fwd) / d_fwd)
            # tan(g/2) = sqrt((1 - cos g) / (1 + cos g))
            tan_half = dr.safe_sqrt((1.0 - cos_g) / dr.maximum(1.0 + cos_g, 1e-12))
            bsh = 1.0 + self.bs0 / (1.0 + tan_half / self.hs)
            t = dr.maximum(tan_half / self.hc, 1e-7)
            bcb = 1.0 + self.bc0 * (1.0 + (1.0 - dr.exp(-t)) / t) / (2.0 * dr.square(1.0 + t))
            if self.theta_bar > 0.0:
                wi = si.wi
                sin_i = dr.safe_sqrt(1.0 - mu0 * mu0)
                sin_e = dr.safe_sqrt(1.0 - mu * mu)
                den = sin_i * sin_e
                cos_psi = dr.select(den > 1e-9,
                                    (wi.x * wo.x + wi.y * wo.y) / dr.maximum(den, 1e-9), 1.0)
                mu0e, mue, S = self._roughness(mu0, mu, cos_psi)
            else:
                mu0e, mue, S = mu0, mu, 1.0
            multiple = self._H(mu0e, w) * self._H(mue, w) - 1.0
            return w * INV_FOUR_PI * mu0e / (mu0e + mue) * (p * bsh + multiple) * bcb * S

    return {
        "lambert": LambertBSDF,
        "lommel_seeliger": LommelSeeligerBSDF,
        "lunar_lambert": LunarLambertBSDF,
        "hapke": HapkeBSDF,
    }


@functools.cache
def _classes_of_variant(variant: str) -> dict[str, type]:
    """The plugin classes defined once per variant (``variant`` is the cache key)."""
    return _define_classes()


def plugin_classes() -> dict[str, type]:
    """The plugin classes of the active variant, keyed by photometric model name."""
    return _classes_of_variant(mi.variant())


def register_plugins() -> None:
    """Register the plugin of every photometric model with Mitsuba for the active variant."""
    classes = plugin_classes()
    for model, plugin in PLUGIN_NAMES.items():
        cls = classes[model]
        mi.register_bsdf(plugin, lambda props, cls=cls: cls(props))
