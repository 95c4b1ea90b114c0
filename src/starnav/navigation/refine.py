"""Subpixel limb refinement from readout windows, with a PSF-aware edge model (algorithm 1).

The pixel-accuracy limb (:mod:`starnav.navigation.limb`) is good to about a pixel; up to 16
*windows* of DN values along it are then read and each is fitted with a physical model of a
blurred limb, so that the edge is unbiased for the PSF the model is told or fits. Each step in
full: docs/methods.md, "starnav.navigation.refine".

Technique
---------
1. **Plan** ``n_windows`` square windows evenly along the lit arc (:func:`plan_windows`).
2. **Local geometry**: a coarse circle gives each pixel its signed distance outside an edge
   with an offset ``delta`` and a tilt ``tau``.
3. **Edge model**: a sphere's limb profile ``H(x) [A + G1 x + Gh sqrt(x)]`` blurred by a
   Gaussian (closed-form basis ``sigma^nu F_nu``); 3b with the detector's own blur, its line
   spread function across the limb (:class:`EdgeSpread`), which also keeps saturated windows.
4. **Fit**: Levenberg-Marquardt on the nonlinear parameters with the amplitudes solved
   linearly, all windows batched; weighted by the pixels' noise (:class:`PixelNoise`).
5. **Point and uncertainty**: one limb point per window, its sigma from the fit combined with
   the calibrated model errors (:class:`ModelErrorCalibration`); what all points share goes to
   ``LimbPoints.common_covariance_px2``.

The knobs are the scenario section :class:`RefineConfig`; what the builder resolves from
the scenario (noise, blur, terrain, calibration), :class:`RefineModels`.

References
----------
Seed paper (STAR Nav), the subpixel-accuracy limb algorithm (its reference 5).
J. A. Christian, "Accurate planetary limb localization for image-based spacecraft navigation",
J. Spacecr. Rockets 54 (2017) 708-730, doi:10.2514/1.A33692 (PSF-aware edge models).
Abramowitz & Stegun 19.5.3 / DLMF 12.5.1 (parabolic cylinder integral).

Index
-----
:func:`plan_windows`, :class:`WindowRequest`, :func:`cut_windows`; :func:`refine_limb`,
:func:`fit_edge_window`, :class:`EdgeFit`, :func:`edge_profile`, :func:`f_nu`;
:class:`RefineConfig`, :class:`RefineModels`, :class:`PixelNoise`, :class:`EdgeSpread`,
:class:`EdgeTables`, :class:`ModelErrorCalibration`, :func:`packaged_model_error`, :func:`warm_up`,
:func:`prepare_edge_tables`.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import json
import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field
from scipy.special import gamma, ndtr, pbdv

from starnav.config_base import SIView, StrictModel
from starnav.data import packaged_path
from starnav.dem.limb import LimbTopography
from starnav.detector.optics import line_spread_function
from starnav.detector.products import MAX_WINDOWS, Window
from starnav.errors import ConfigError
from starnav.fields import NonNegativeFloat, PositiveFloat
from starnav.linalg import solve, solve_vectors
from starnav.navigation.limb import LimbNotFoundError, LimbPoints
from starnav.registry import Registry
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Variance of a unit pixel's box response projected on any direction [px^2].
PIXEL_BOX_VARIANCE = 1.0 / 12.0
_TABLE_T = (-10.0, 30.0, 0.01)


@dataclass(frozen=True)
class WindowRequest:
    """Where to open one readout window: top-left pixel and size [px]."""

    row0: int
    col0: int
    height: int
    width: int


@dataclass(frozen=True)
class PixelNoise:
    """Per-pixel noise of a window's DN values, from the detector settings (module step 4).

    ``var(I) = [read^2 + g s + (prnu g s)^2] / g^2 + 1/12`` [DN^2] for a pixel of ``I`` DN,
    ``s = max(I - offset, 0)`` DN above the offset and ``g`` the gain [e-/DN]: read noise, shot
    noise of the collected charge, photo-response non-uniformity (a fixed pattern, random from
    pixel to pixel as the limb moves over the detector) and quantisation.
    """

    gain_e_per_dn: float
    read_noise_e: float = 0.0
    prnu_fraction: float = 0.0
    offset_dn: float = 0.0

    def __post_init__(self) -> None:
        for name, v, ok in (("gain_e_per_dn", self.gain_e_per_dn, self.gain_e_per_dn > 0),
                            ("read_noise_e", self.read_noise_e, self.read_noise_e >= 0),
                            ("prnu_fraction", self.prnu_fraction, 0 <= self.prnu_fraction < 1),
                            ("offset_dn", self.offset_dn, math.isfinite(self.offset_dn))):
            if not (ok and math.isfinite(v)):
                raise ConfigError(f"refine.noise.{name}", v, "a finite value in range")

    def variance_dn2(self, dn: ArrayLike) -> FloatArray:
        """Variance [DN^2] of pixels whose expected value is ``dn`` [DN]."""
        g = self.gain_e_per_dn
        e = np.maximum(np.asarray(dn, float) - self.offset_dn, 0.0) * g
        return (self.read_noise_e**2 + e + (self.prnu_fraction * e) ** 2) / g**2 + 1.0 / 12.0

    @classmethod
    def from_detector(cls, detector: object) -> PixelNoise:
        """From a :class:`~starnav.detector.schema.DetectorConfig` (PRNU and read noise count
        only where enabled)."""
        d = detector
        prnu = d.charge.prnu  # type: ignore[attr-defined]
        rn = d.signal.read_noise  # type: ignore[attr-defined]
        return cls(gain_e_per_dn=float(d.gain_e_per_dn),  # type: ignore[attr-defined]
                   read_noise_e=float(rn.sigma_e) if getattr(rn, "enabled", True) else 0.0,
                   prnu_fraction=float(prnu.sigma_fraction) if prnu.enabled else 0.0,
                   offset_dn=float(d.adc.offset_dn))  # type: ignore[attr-defined]


class RefineConfig(StrictModel):
    """Scenario section ``navigation.refine``: subpixel refinement from windows
    (:func:`plan_windows` and :func:`refine_limb` read its SI view, ``to_si()``; the builder
    resolves :class:`RefineModels` from it and the scenario)."""

    enabled: bool = Field(True, description="refine with the frame's windows when present")
    n_windows: Annotated[int, Field(ge=1, le=MAX_WINDOWS)] = Field(
        MAX_WINDOWS, description="windows planned")
    window_size_px: Annotated[int, Field(ge=5)] = Field(11, description="window side [px]")
    edge_model: Literal["auto", "detector-psf", "blurred-limb", "blurred-step"] = Field(
        "auto", description="edge model of the window fit: detector-psf (the dataset "
        "detector's own blur: defocus disc * Gaussian, pixel apertures, IPC; needs the "
        "scenario), blurred-limb / blurred-step (Gaussian of fitted width); auto: detector-psf "
        "when the scenario is known and its aberration PSF is on, else blurred-limb")
    psf_sigma_px: NonNegativeFloat | None = Field(
        None, description="Gaussian PSF sigma [px]; null: fitted per window")
    psf_knowledge: Literal["estimated", "detector"] = Field(
        "estimated", description="the PSF of the detector-psf edge model: estimated (fitted "
        "to star images exposed through the detector, starnav.navigation.psf) or detector "
        "(the simulator's own setting: perfect knowledge, an analysis option)")
    saturation_dn: PositiveFloat = Field(4095.0, description="pixels at or above are ignored [DN]")
    min_sigma_px: PositiveFloat = Field(0.02, description="floor of a refined point's sigma [px]")
    noise_model: bool = Field(
        True, description="weight each window fit with the scenario detector's per-pixel noise "
        "(read, shot, PRNU, quantisation) and take its covariance from it")
    terrain_model_error: bool = Field(
        True, description="add the DEM's limb-height spread (starnav.dem.limb) to each refined "
        "point's sigma when the Moon has terrain")
    terrain_model_ppd: PositiveFloat | None = Field(
        1.0, description="resolution of the DEM the navigation's limb-height statistics come "
        "from [px/deg] (area-averaged from the scenario's DEM): a terrain model coarser than "
        "the one that renders; null: the rendered DEM itself (perfect knowledge)")
    outlier_px: PositiveFloat = Field(0.5, description="refined points farther from the first "
                                                       "fix are dropped [px]")
    model_error_px: NonNegativeFloat | None = Field(
        None, description="the edge model's own error [px], added to every refined point's "
        "sigma; null: the packaged calibration with the detector-psf model "
        "(starnav/data/navigation/refine_model_error.json), 0 otherwise")
    saturated_model_error_px: NonNegativeFloat | None = Field(
        None, description="extra model error of a window whose inside is saturated [px] "
        "(detector-psf model); null: the packaged calibration")
    terrain_error_scale: NonNegativeFloat | None = Field(
        None, description="factor on the DEM's limb-height spread (terrain_model_error): what "
        "the lit limb shows beyond the silhouette; null: the packaged calibration with the "
        "detector-psf model, 1 otherwise")
    max_overexposure: Annotated[float, Field(gt=1, allow_inf_nan=False)] = Field(
        20.0, description="saturated windows whose fitted step exceeds this many times the "
        "headroom to saturation are dropped (blooming, not the optics, shapes that edge); "
        "not at the exposures of the packaged calibration's blooming terms, which carry them")


#: The defaults' SI view.
_DEFAULT = RefineConfig().to_si()
#: Starting Gaussian blur of a fitted-width edge model [px].
SIGMA0_PX = 1.0
#: Most Levenberg-Marquardt iterations of a window fit.
MAX_ITERATIONS = 30


@dataclass(frozen=True)
class RefineModels:
    """What the builder resolves for :func:`refine_limb` from the scenario (the knobs are
    :class:`RefineConfig`'s): the detector's per-pixel ``noise`` (None: unweighted fits) and
    blur ``spread`` (with it, ``edge_model: auto`` is ``detector-psf``), the DEM's
    ``limb_topography``, the packaged ``model_error_table`` of the ``detector-psf`` model, and
    ``min_contrast_dn``, the smallest fitted edge step of the detector's DN scale [DN] (10 of
    the tracker's 12 bits; 5 of a 10-bit camera, :mod:`starnav.reference.amie.validate`)."""

    noise: PixelNoise | None = None
    spread: EdgeSpread | None = None
    limb_topography: LimbTopography | None = None
    model_error_table: ModelErrorCalibration | None = None
    min_contrast_dn: float = 10.0

    def __post_init__(self) -> None:
        if not (self.min_contrast_dn > 0 and math.isfinite(self.min_contrast_dn)):
            raise ConfigError("refine.min_contrast_dn", self.min_contrast_dn,
                              "a finite step > 0 DN")

    def edge_model(self, options: SIView) -> str:
        """The edge model the fit uses: ``options.edge_model``, ``auto`` resolved
        (``detector-psf`` with a :attr:`spread`, else ``blurred-limb``)."""
        name = options.edge_model
        if name == "auto":
            return "blurred-limb" if self.spread is None else "detector-psf"
        if name == "detector-psf" and self.spread is None:
            raise ConfigError("refine.edge_model", name,
                              "an EdgeSpread (the detector's blur) with the detector-psf model")
        return EDGE_MODELS.check(name)

    def model_errors(self, options: SIView, phase_rad: float | None
                     ) -> tuple[float, float, float]:
        """``(edge model error [px], saturated extra [px], terrain scale)`` at a phase angle
        [rad]: each value ``options`` gives, else the calibration's at that phase (its largest
        without a phase), else 0, 0, 1."""
        tab = (self.model_error_table.at(phase_rad) if self.model_error_table is not None
               else (0.0, 0.0, 1.0))
        e, s, k = (options.model_error_px, options.saturated_model_error_px,
                   options.terrain_error_scale)
        return (tab[0] if e is None else e, tab[1] if s is None else s,
                tab[2] if k is None else k)

    def common_covariance(self, options: SIView, radius_px: float) -> FloatArray:
        """Covariance [px^2] of the errors every point of a frame shares, at a disc radius
        ``radius_px``: ``(a, b, c)`` of :class:`ModelErrorCalibration` (the disc's apparent
        radius, a shift of the limb towards the Sun in the image and one across it). From
        the calibration when there is one and ``options.terrain_error_scale`` is null
        (terrain and edge model together, scaling with the disc), else the DEM's half-circle
        limb height times the terrain scale (radius only); zero without terrain."""
        out = np.zeros((3, 3))
        topo = self.limb_topography
        t = self.model_error_table
        scale = options.terrain_error_scale
        if topo is None:
            return out
        if t is not None and scale is None:
            return np.asarray(t.common_covariance, float) * radius_px**2
        k = 1.0 if scale is None else scale
        out[0, 0] = (k * topo.common_fraction * radius_px) ** 2
        return out

    def fix_covariance(self, options: SIView, radius_px: float, saturated: bool,
                       phase_rad: float | None = None) -> FloatArray | None:
        """Covariance [px^2] of a fix's slowly varying error in the three limb modes
        (:attr:`ModelErrorCalibration.fix_covariance` times its factor at ``phase_rad``,
        or its smooth-Moon value without terrain) at a disc radius ``radius_px``; None
        without a calibration or with ``options.terrain_error_scale`` set."""
        t = self.model_error_table
        if t is None or options.terrain_error_scale is not None:
            return None
        if self.limb_topography is None:
            return np.asarray(t.fix_covariance_smooth, float) * radius_px**2
        C = t.fix_covariance_saturated if saturated else t.fix_covariance
        return np.asarray(C, float) * (radius_px**2 * self.fix_scale(options, phase_rad,
                                                                     saturated))

    def fix_scale(self, options: SIView, phase_rad: float | None, saturated: bool) -> float:
        """The calibration's factor on the slowly varying fix covariance at ``phase_rad``
        (:meth:`ModelErrorCalibration.fix_scale`; 1 without one, without terrain, or with
        ``options.terrain_error_scale`` set)."""
        t = self.model_error_table
        if t is None or options.terrain_error_scale is not None or self.limb_topography is None:
            return 1.0
        return t.fix_scale(phase_rad, saturated)


# ------------------------------------------------------------------------ F_nu functions
def warm_up() -> None:
    """Build the refinement's static tables (edge profile integrals, ~96 kB) now, once per
    process, so that per-frame memory and time measurements exclude them."""
    _half_tables()


@functools.lru_cache(maxsize=1)
def _half_tables() -> tuple[FloatArray, FloatArray, FloatArray]:
    """Tables of ``F_1/2`` and ``F_-1/2`` on a grid of ``t`` (built once: 4001 points, 96 kB;
    linear interpolation error < 1e-5)."""
    t0, t1, h = _TABLE_T
    t = np.arange(t0, t1 + h / 2, h)
    e = np.exp(-t * t / 4.0) / math.sqrt(2.0 * math.pi)
    fh = gamma(1.5) * e * pbdv(-1.5, -t)[0]
    fmh = gamma(0.5) * e * pbdv(-0.5, -t)[0]
    return t, fh, fmh


def f_nu(nu: float, t: FloatArray) -> FloatArray:
    """``F_nu(t) = int_0^inf y^nu phi(t - y) dy`` for ``nu`` in {-1/2, 0, 1/2, 1} [-].

    ``phi`` is the standard normal density. Closed forms for 0 and 1; a table of the parabolic
    cylinder form ``Gamma(nu + 1) e^(-t^2/4) D_(-nu-1)(-t) / sqrt(2 pi)`` for +-1/2, with the
    asymptote ``t^nu (1 + nu (nu - 1) / (2 t^2))`` past the table.
    """
    t = np.asarray(t, float)
    if nu == 0:
        return ndtr(t)
    if nu == 1:
        return t * ndtr(t) + np.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi)
    tt, fh, fmh = _half_tables()
    tab = fh if nu == 0.5 else fmh if nu == -0.5 else None
    if tab is None:
        raise ConfigError("nu", nu, "one of -0.5, 0, 0.5, 1")
    out = np.interp(t, tt, tab, left=0.0)
    big = t > tt[-1]
    if np.any(big):
        tb = t[big]
        out[big] = tb**nu * (1.0 + nu * (nu - 1.0) / (2.0 * tb * tb))
    return out


#: Registry of edge models: name -> exponents ``nu`` of the inward-distance terms (Gaussian
#: blur of fitted or given width); ``detector-psf`` blurs a step and a ramp (``nu`` 0 and 1) by
#: the detector's own line spread function (:class:`EdgeSpread`).
EDGE_MODELS: Registry[tuple[float, ...]] = Registry("edge model", {
    "blurred-limb": (0.0, 1.0, 0.5),
    "blurred-step": (0.0, 1.0),
    "detector-psf": (0.0, 1.0),
})

#: Sampling of the tabulated edge bases [px]: spacing and half-width.
_EDGE_TABLE_STEP = 0.02
_EDGE_TABLE_HALF = 12.0


@dataclass(frozen=True)
class EdgeTables:
    """The blurred step and ramp of one window's edge, tabulated against the outward distance
    ``x`` [px]: ``lsf`` the line spread function [1/px], ``b0(d) = int_{s>d} lsf`` (a unit
    step inside the limb, blurred) and ``b1(d) = int_{s>d} (s - d) lsf(s) ds`` (a unit ramp
    growing inwards, blurred); ``dB0/dd = -lsf``, ``dB1/dd = -b0``."""

    x: FloatArray
    lsf: FloatArray
    b0: FloatArray
    b1: FloatArray
    mean: float
    tangent_variance: float = 0.0

    @classmethod
    def from_lsf(cls, x: FloatArray, lsf: FloatArray,
                 tangent_variance: float = 0.0) -> EdgeTables:
        """Tables of a line spread function sampled at ``x`` [px, 1/px]; ``tangent_variance``
        [px^2] is the blur's variance along the edge (the curvature correction of
        :func:`fit_edge_window`)."""
        h = float(x[1] - x[0])
        w = lsf * h
        b0 = np.cumsum(w[::-1])[::-1] - 0.5 * w        # mass beyond each sample (midpoint)
        m1 = np.cumsum((x * w)[::-1])[::-1] - 0.5 * x * w
        mean = float(np.sum(x * w))
        return cls(x, lsf, b0, m1 - x * b0, mean, float(tangent_variance))

    def evaluate(self, d: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(b0, b1, lsf)`` at outward distances ``d`` [px]: ``lsf`` interpolated linearly,
        ``b0`` and ``b1`` its integrals (:func:`_table_values`); asymptotes past the table:
        ``b0 = 1``, ``b1 = mean - d`` inside; 0 outside."""
        x, d = self.x, np.asarray(d, float)
        h = float(x[1] - x[0])
        u = (d - x[0]) / h
        j = u.clip(0, x.size - 2).astype(np.intp)   # floor where u >= 0
        tab = np.array([self.b0, self.b1, self.lsf])
        b0, b1, lsf = _table_values(np.concatenate([tab, np.diff(tab, axis=1, append=0.0)]),
                                    j, u - j, h)
        inside, outside = u < 0.0, u > x.size - 1
        b0[inside], b1[inside], lsf[inside] = 1.0, self.mean - d[inside], 0.0
        b0[outside] = b1[outside] = lsf[outside] = 0.0
        return b0, b1, lsf


def _table_values(tabdiff: FloatArray, j: NDArray[np.intp], f: FloatArray,
                  h: float) -> FloatArray:
    """``(b0, b1, lsf)``, ``(3,) + j.shape``, from tables of the samples ``(b0, b1, lsf)``
    and their forward differences (rows 0-2 and 3-5 of ``tabdiff``), at the fractions ``f``
    of the steps ``h`` [px] after the samples ``j``.

    ``lsf`` is interpolated linearly and ``b0``, ``b1`` are its exact integrals, quadratic
    within a step: the samples of :meth:`EdgeTables.from_lsf` obey ``b0_j - b0_(j+1) = h
    (lsf_j + lsf_(j+1)) / 2`` (the trapezoid rule), so ``b0 = b0_j + f Db0 + (h/2) f (1 -
    f) Dlsf`` has the derivative ``-lsf`` of the linear ``lsf`` everywhere, and likewise
    ``b1`` has ``-b0`` (to ``h^2 lsf' / 4``). The window model is then smooth in the edge's
    position, and the Jacobian (``-lsf``, ``-b0``) its exact derivative: with ``b0`` and
    ``b1`` linear between samples a step 4 000 DN above the noise made the cost of a
    saturated window rough at the 1e-3 px level (a kink where any pixel crosses a sample,
    every ~2e-4 px) and its minimum 2e-3 px from the Gauss-Newton stationary point."""
    g = tabdiff.take(j, axis=-1)
    g[3:] *= f
    g[:3] += g[3:]
    g[0:2] += (1.0 - f) * (0.5 * h) * g[5:2:-2]   # f (1 - f) h/2 (Dlsf, Db0)
    return g[:3]


@dataclass(frozen=True)
class EdgeSpread:
    """The tracker's blur across the limb, from its detector settings (module step 3b).

    ``line_spread(camera, u, v, normal, x)`` returns the detector's line spread function at
    pixel ``(u, v)`` across ``normal`` (:func:`starnav.detector.optics.line_spread_function`:
    the field-varying defocus disc * Gaussian, the pixel apertures, inter-pixel capacitance);
    :meth:`tables` tabulates the blurred step and ramp from it, cached per field cell of
    ``cell_px`` and per degree of edge direction.
    """

    aberration: object
    ipc: tuple[float, float] = (0.0, 0.0)
    pixel_boxes: int = 2
    cell_px: float = 4.0

    @classmethod
    def from_detector(cls, detector: object, aberration: object | None = None) -> EdgeSpread:
        """From a :class:`~starnav.detector.schema.DetectorConfig`; ``aberration`` replaces
        its PSF section (e.g. an estimate, :func:`starnav.navigation.psf.estimated_psf`)."""
        d = detector
        ipc = d.signal.ipc  # type: ignore[attr-defined]
        ab = d.optics.aberration if aberration is None else aberration  # type: ignore[attr-defined]
        return cls(aberration=ab,
                   ipc=(float(ipc.nearest_fraction), float(ipc.diagonal_fraction))
                   if ipc.enabled else (0.0, 0.0))

    def tables(self, camera: object, u: float, v: float, normal: ArrayLike) -> EdgeTables:
        """The tables of the edge at pixel ``(u, v)`` across ``normal`` [px, -]."""
        return self.tables_along(camera, np.array([[u, v]], float),
                                 np.asarray(normal, float).reshape(1, 2))[0]

    def tables_along(self, camera: object, uv: ArrayLike, normals: ArrayLike
                     ) -> tuple[EdgeTables, ...]:
        """The tables of ``K`` edges at pixels ``uv`` ``(K, 2)`` across ``normals``
        ``(K, 2)`` [px, -]: the field cell (``cell_px``) and whole degree of direction of
        each (rounded half to even), one cached set per frame's cells."""
        uv, n = np.asarray(uv, float), np.asarray(normals, float)
        cell = np.rint(uv / self.cell_px) * self.cell_px
        ang = np.rint(np.degrees(np.arctan2(n[:, 1], n[:, 0]))).astype(int)
        return _edge_table_set(self, camera, tuple(zip(cell[:, 0].tolist(), cell[:, 1].tolist(),
                                                       ang.tolist(), strict=True)))


#: Packaged calibration of the saturated-window model error (tools/calibrate_refine_model_error.py).
MODEL_ERROR_FILE = "navigation/refine_model_error.json"


@dataclass(frozen=True)
class ModelErrorCalibration:
    """Model-error terms of the ``detector-psf`` refinement, calibrated by Monte Carlo on
    rendered calibration arcs (:data:`MODEL_ERROR_FILE`).

    A refined point's error is taken as ``a + b cos(phi) + c sin(phi) + e``, ``phi`` the angle
    of its limb normal from the Sun's direction in the image: ``e`` is its own (independent
    from point to point: the pixels' noise, the edge model's error, the terrain over the
    window's arc), ``a``, ``b`` and ``c`` are shared by the whole frame (the disc's apparent
    radius, and a shift of the limb towards and across the Sun: the lit limb stands out
    towards the Sun and is eaten by shadows towards the terminator); ``a`` and ``b`` are
    strongly anti-correlated (measured -0.86), so they are kept as one covariance.

    Attributes
    ----------
    phase_edges_deg : tuple of float
        Bin edges of the phase angle [deg], ``len(bins) + 1`` of them.
    edge_model_error_px, saturated_model_error_px : tuple of float
        The edge model's own error and a saturated window's extra, per bin [px].
    terrain_scale : float
        Factor on the DEM's limb-height spread over a window's arc (``e``) [-].
    common_covariance : 3 x 3 tuple of float
        Covariance of ``(a, b, c)`` in units of the disc radius squared [-] (the terrain's
        effect on the limb, like the limb heights, scales with the disc).
    fix_covariance, fix_covariance_saturated : 3 x 3 tuple of float
        Covariance, in the same three modes and units, of *everything* in a fix's error but
        its pixels' noise and the attitude (the points' own model errors included: from one
        frame to the next, an hour apart, the limb in view and so all of these errors
        change slowly), for fixes from well-exposed windows and from windows with saturated
        pixels: what the fix's covariance and the filter's ``limb-common`` states carry.
    fix_covariance_smooth : 3 x 3 tuple of float
        The same for a Moon without terrain (the edge model's error alone; a sphere scenario).
    fix_scale_by_phase, fix_scale_saturated_by_phase : tuple of float or None
        Per bin of phase, the factor on ``fix_covariance`` (``fix_covariance_saturated``):
        its shape is pooled over all phases, its size follows the phase (the shadows near
        the terminator eat more of the lit limb towards the crescent); None: 1 in every bin.
    blooming : ModelErrorCalibration or None
        The terms of a limb far past the full well (the paper's 7.7 ms), calibrated at that
        exposure: the saturated windows' extra, covariance and its factors per bin of phase
        (their own bins), the rest as here. There the fitted step no longer measures the
        over-exposure (the step and the edge's place trade off along the clipped profile),
        so no window is dropped for it (:attr:`keep_overexposed`); the edge sits pixels
        outside the limb, and the fix's covariance carries that. None: not calibrated.
    blooming_min_exposure_s : float
        The exposure from which :meth:`for_exposure` gives :attr:`blooming` [s]: the
        geometric mean of the saturated and the blooming calibration exposures.
    keep_overexposed : bool
        This table's saturated windows are kept whatever their fitted over-exposure.
    """

    phase_edges_deg: tuple[float, ...]
    edge_model_error_px: tuple[float, ...]
    saturated_model_error_px: tuple[float, ...]
    terrain_scale: float = 1.0
    common_covariance: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance_saturated: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance_smooth: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_scale_by_phase: tuple[float, ...] | None = None
    fix_scale_saturated_by_phase: tuple[float, ...] | None = None
    blooming: ModelErrorCalibration | None = None
    blooming_min_exposure_s: float = math.inf
    keep_overexposed: bool = False

    def __post_init__(self) -> None:
        n = len(self.phase_edges_deg) - 1
        if n < 1 or any(len(t) != n for t in (self.edge_model_error_px,
                                              self.saturated_model_error_px)):
            raise ConfigError("model error calibration", n, "one value per phase bin")
        for name in ("fix_scale_by_phase", "fix_scale_saturated_by_phase"):
            v = getattr(self, name)
            if v is not None and (len(v) != n or not all(math.isfinite(x) and x > 0
                                                          for x in v)):
                raise ConfigError(f"model error calibration: {name}", v,
                                  f"{n} factors > 0, one per phase bin")

    def for_exposure(self, exposure_s: float | None) -> ModelErrorCalibration:
        """The terms for frames exposed ``exposure_s`` [s]: :attr:`blooming` from
        :attr:`blooming_min_exposure_s` on, else these (None: these)."""
        if (self.blooming is not None and exposure_s is not None
                and exposure_s >= self.blooming_min_exposure_s):
            return self.blooming
        return self

    def _bin(self, phase_rad: float) -> int:
        k = bisect.bisect_right(self.phase_edges_deg, math.degrees(phase_rad)) - 1
        return min(max(k, 0), len(self.edge_model_error_px) - 1)

    def fix_scale(self, phase_rad: float | None, saturated: bool) -> float:
        """The factor on the slowly varying fix covariance at a phase angle [rad] (None:
        the largest)."""
        v = self.fix_scale_saturated_by_phase if saturated else self.fix_scale_by_phase
        if v is None:
            return 1.0
        if phase_rad is None or not math.isfinite(phase_rad):
            return max(v)
        return float(v[self._bin(phase_rad)])

    def at(self, phase_rad: float | None) -> tuple[float, float, float]:
        """``(edge model error, saturated extra, terrain scale)`` in the bin of ``phase_rad``
        (None: the largest)."""
        if phase_rad is None or not math.isfinite(phase_rad):
            return (max(self.edge_model_error_px), max(self.saturated_model_error_px),
                    self.terrain_scale)
        k = self._bin(phase_rad)
        return self.edge_model_error_px[k], self.saturated_model_error_px[k], self.terrain_scale

    @classmethod
    def from_dict(cls, doc: dict) -> ModelErrorCalibration:
        def mat(key: str) -> tuple[tuple[float, float, float], ...]:
            return tuple(tuple(float(x) for x in row)  # type: ignore[misc]
                         for row in doc.get(key, [[0.0] * 3] * 3))

        def scales(key: str) -> tuple[float, ...] | None:
            v = doc.get(key)
            return None if v is None else tuple(float(x) for x in v)

        base = cls(tuple(doc["phase_edges_deg"]), tuple(doc["edge_model_error_px"]),
                   tuple(doc["saturated_model_error_px"]), float(doc["terrain_scale"]),
                   mat("common_covariance"), mat("fix_covariance"),
                   mat("fix_covariance_saturated"), mat("fix_covariance_smooth"),
                   scales("fix_scale_by_phase"), scales("fix_scale_saturated_by_phase"),
                   keep_overexposed=bool(doc.get("keep_overexposed", False)))
        b = doc.get("blooming")
        if b is None:
            return base
        edges = [float(x) for x in b["phase_edges_deg"]]
        mids = [math.radians(0.5 * (lo + hi)) for lo, hi in zip(edges[:-1], edges[1:],
                                                                  strict=False)]
        # the well-exposed terms on the blooming bins (their edges refine these)
        table = {k: v for k, v in doc.items() if k != "blooming"}
        table.update({
            "phase_edges_deg": edges,
            "edge_model_error_px": [base.at(m)[0] for m in mids],
            "fix_scale_by_phase": (None if base.fix_scale_by_phase is None
                                   else [base.fix_scale(m, False) for m in mids]),
            "saturated_model_error_px": b["saturated_model_error_px"],
            "fix_covariance_saturated": b["fix_covariance_saturated"],
            "fix_scale_saturated_by_phase": b.get("fix_scale_saturated_by_phase"),
            "keep_overexposed": True})
        return dataclasses.replace(base, blooming=cls.from_dict(table),
                                   blooming_min_exposure_s=float(b["min_exposure_s"]))


@functools.lru_cache(maxsize=1)
def packaged_model_error() -> ModelErrorCalibration:
    """The packaged calibration (:data:`MODEL_ERROR_FILE`, written by
    ``tools/calibrate_refine_model_error.py`` on arcs that never score it)."""
    return ModelErrorCalibration.from_dict(json.loads(packaged_path(MODEL_ERROR_FILE)
                                                      .read_text()))


@functools.lru_cache(maxsize=64)
def _edge_table_set(spread: EdgeSpread, camera: object,
                    cells: tuple[tuple[float, float, int], ...]) -> tuple[EdgeTables, ...]:
    return tuple(_edge_tables(spread, camera, u, v, a) for u, v, a in cells)


@functools.lru_cache(maxsize=4096)
def _edge_tables(spread: EdgeSpread, camera: object, u: float, v: float,
                 angle_deg: int) -> EdgeTables:
    h = _EDGE_TABLE_STEP
    k = int(round(_EDGE_TABLE_HALF / h))
    x = np.arange(-k, k + 1) * h
    a = math.radians(angle_deg)
    lsf = line_spread_function(camera, spread.aberration, u, v,  # type: ignore[arg-type]
                               np.array([math.cos(a), math.sin(a)]), x,
                               pixel_boxes=spread.pixel_boxes, ipc=spread.ipc)
    along = line_spread_function(camera, spread.aberration, u, v,  # type: ignore[arg-type]
                                 np.array([-math.sin(a), math.cos(a)]), x,
                                 pixel_boxes=spread.pixel_boxes, ipc=spread.ipc)
    return EdgeTables.from_lsf(x, lsf, float(np.sum(x * x * along) * h))


def edge_profile(d: ArrayLike, sigma: float, amplitudes: Sequence[float], background: float = 0.0,
                 model: str = "blurred-limb") -> FloatArray:
    """The blurred limb profile at signed outward distances ``d`` [px] (module step 3).

    ``amplitudes`` are ``(A, G1[, Gh])`` [DN, DN/px, DN/px^0.5]; ``sigma`` the total Gaussian
    blur [px].
    """
    nus = EDGE_MODELS[model]
    t = -np.asarray(d, float) / sigma
    out = np.full(t.shape, float(background))
    for nu, a in zip(nus, amplitudes, strict=True):
        out += a * sigma**nu * f_nu(nu, t)
    return out


# ------------------------------------------------------------------------ planning
def plan_windows(uv: ArrayLike, centre_px: ArrayLike, *, shape: tuple[int, int],
                 options: SIView | None = None) -> list[WindowRequest]:
    """Window requests evenly spread along a limb arc (module step 1).

    Parameters
    ----------
    uv : (N, 2) array
        Pixel-level limb points, ordered along the arc [px].
    centre_px : (2,) array
        Centre of the limb circle [px], used to order the points.
    shape : (rows, cols)
        Detector size [px].
    options : SIView, optional
        The SI view of a :class:`RefineConfig` (``n_windows``, ``window_size_px``); default
        its defaults.

    Returns
    -------
    list of WindowRequest
        At most ``n_windows`` windows, inside the detector.
    """
    opt = options if options is not None else _DEFAULT
    p = np.asarray(uv, float).reshape(-1, 2)
    if p.shape[0] == 0:
        return []
    c = np.asarray(centre_px, float)
    ang = np.unwrap(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))
    p = p[np.argsort(ang)]
    k = min(opt.n_windows, p.shape[0])
    # centres of k equal parts of the arc, in point order
    idx = np.round((np.arange(k) + 0.5) * p.shape[0] / k - 0.5).astype(int)
    H, W = shape
    s = min(opt.window_size_px, H, W)
    out = []
    for u, v in p[idx]:
        r0 = int(np.clip(round(v) - s // 2, 0, H - s))
        c0 = int(np.clip(round(u) - s // 2, 0, W - s))
        out.append(WindowRequest(r0, c0, s, s))
    return out


def cut_windows(image: ArrayLike, requests: Sequence[WindowRequest]) -> list[Window]:
    """Read windows out of a full DN image (tests and emulation of the windows mode)."""
    img = np.asarray(image)
    return [Window(row0=q.row0, col0=q.col0,
                   dn=np.ascontiguousarray(img[q.row0:q.row0 + q.height,
                                               q.col0:q.col0 + q.width]).astype(np.uint16))
            for q in requests]


# ------------------------------------------------------------------------ fit
@dataclass(frozen=True)
class EdgeFit:
    """Result of one window fit: offset ``delta``, tilt ``tau``, blur ``sigma`` [px] and
    amplitudes; ``sigma_delta`` the 1-sigma of ``delta`` [px]."""

    delta: float
    tau: float
    sigma: float
    amplitudes: FloatArray
    background: float
    sigma_delta: float
    rms: float
    iterations: int
    converged: bool


_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
#: Levenberg damping: start, floor, growth on a rejected step, retries per iteration.
_LM_LAMBDA0, _LM_LAMBDA_MIN, _LM_GROWTH, _LM_RETRIES = 1e-3, 1e-9, 10.0, 8
#: A window has converged when a step moves its edge by less than this [px] (anywhere in the
#: window: offset and tilt times 5 px); a rejected step (the cost rose) brackets the minimum
#: along it within half its length, so one shorter than twice this is converged too.
_CONVERGED_STEP = 1e-4
#: The same for the unweighted first pass when a second, weighted one follows [px]: it only
#: sets the weights (the noise at its prediction), which a 1e-2 px edge changes by < 1e-3.
_WEIGHTS_STEP = 1e-2
#: Secant rescaling of the Gauss-Newton step: measured on accepted steps shorter than this
#: [px] (where the cost is near its quadratic model), clipped to this range [-].
_SECANT_NEAR = 0.2
_SECANT_RANGE = (0.5, 2.0)


def _gauss_bases(d: FloatArray, t_arc: FloatArray, sigma: FloatArray, nus: tuple[float, ...],
                 fit_sigma: bool) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Linear basis ``(K, p, M)`` of the Gaussian window model of ``K`` windows of ``M``
    pixels and its derivatives with respect to the signed distance ``d`` and to ``sigma``
    (``(K,)``, one per window); rows: background, one per ``nu``, and the tangential
    gradient ``t_arc F_0`` of the step amplitude."""
    s = sigma[:, None]
    t = -d / s
    phi = np.exp(-0.5 * t * t) * _INV_SQRT_2PI
    f0 = ndtr(t)
    cols, dcols = [np.ones_like(d)], [np.zeros_like(d)]   # d basis / d t
    for nu in nus:
        scale = s**nu
        if nu == 0:
            f, df = f0, phi
        elif nu == 1:
            f, df = t * f0 + phi, f0
        else:
            f, df = f_nu(nu, t), nu * f_nu(nu - 1, t)
        cols.append(scale * f)
        dcols.append(scale * df)
    cols.append(t_arc * cols[1])   # nus[0] == 0: the step, scale 1
    dcols.append(t_arc * phi)
    Bm, dBt = np.stack(cols, axis=1), np.stack(dcols, axis=1)
    dBs = None
    if fit_sigma:
        # B_nu = sigma^nu F_nu(-d / sigma): dB/dsigma = nu B / sigma - dB/dt * t / sigma
        dBs = -dBt * (t / s)[:, None, :]
        for j, nu in enumerate(nus, start=1):
            dBs[:, j] += nu * Bm[:, j] / s
    # dt/dd = -1/sigma
    return Bm, -dBt / s[..., None], dBs


class _StackedTables:
    """The :class:`EdgeTables` of ``K`` windows on their common grid, laid end to end for one
    gather per evaluation (``np.interp`` takes one table at a time): ``b0``, ``b1``, ``lsf``
    of window ``k`` at ``x[i]`` are at ``[:, k n + i]`` of ``tabdiff`` (its rows 3-5 their
    forward differences); ``shift[k]`` the window's curvature correction [px]."""

    #: The stacks of the last few window sets (the tables themselves are cached per field
    #: cell and direction, so consecutive frames mostly ask for the same ones): key the
    #: tables' ids, value the tables (held, so that the ids stay theirs) and the arrays.
    _cache: dict[tuple[int, ...], tuple] = {}
    _CACHE_SIZE = 8
    _lock = threading.Lock()   # Dask runs frames in threads

    def __init__(self, tables: Sequence[EdgeTables], radius_px: float) -> None:
        x = tables[0].x
        self.x0, self.x1, self.h, self.n = float(x[0]), float(x[-1]), float(x[1] - x[0]), x.size
        key = tuple(id(t) for t in tables)
        with self._lock:
            hit = self._cache.get(key)
        if hit is None or any(a is not b for a, b in zip(hit[0], tables, strict=True)):
            if any(t.x is not x and not np.array_equal(t.x, x) for t in tables[1:]):
                raise ConfigError("edge tables", "grids", "one common sampling grid")
            tab = np.array([np.concatenate([getattr(t, name) for t in tables])
                            for name in ("b0", "b1", "lsf")])
            # values and forward differences in one array: one gather per evaluation (the
            # last sample of each table is never a left neighbour)
            hit = (tuple(tables), np.concatenate([tab, np.diff(tab, axis=1, append=0.0)]),
                   np.array([t.mean for t in tables])[:, None],
                   # a curved edge blurred looks like a straight one moved inwards by the
                   # blur's variance along the edge over twice the radius (first order)
                   np.array([t.tangent_variance for t in tables])[:, None])
            with self._lock:
                while len(self._cache) >= self._CACHE_SIZE:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[key] = hit
        self.tabdiff, self.mean = hit[1:3]
        self.shift = hit[3] / (2.0 * radius_px)
        self.base = (np.arange(len(tables)) * self.n)[:, None]

    def values(self, k: NDArray[np.intp] | slice, u: FloatArray) -> FloatArray:
        """``(b0, b1, lsf)``, ``(3, k, M)``, of the windows ``k`` at table coordinates ``u``
        (``(x - x0) / h`` of the outward distance ``x``), as :meth:`EdgeTables.evaluate`
        (:func:`_table_values`), with the asymptotes past the table (inside ``b0 = 1``,
        ``b1 = mean - x``, ``lsf = 0``; outside all 0)."""
        lo, hi = u.min(), u.max()
        inner = lo >= 0.0 and hi <= self.n - 1
        j = (u if inner else u.clip(0, self.n - 2)).astype(np.intp)   # floor, as u >= 0
        f = u - j
        j += self.base[k]
        v = _table_values(self.tabdiff, j, f, self.h)
        if not inner:
            inside, outside = u < 0.0, u > self.n - 1
            b0, b1, lsf = v
            b0[inside] = 1.0
            x = self.x0 + self.h * u
            b1[inside] = np.broadcast_to(self.mean[k], u.shape)[inside] - x[inside]
            lsf[inside] = 0.0
            b0[outside] = b1[outside] = lsf[outside] = 0.0
        return v


def _solve(A: FloatArray, b: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Batched ``A x = b`` (``(K, n, n)``, ``(K, n)`` or ``(K, n, m)``); windows whose matrix
    is singular get the minimum-norm least-squares solution and ``False`` in the mask."""
    try:
        x = solve_vectors(A, b) if b.ndim == A.ndim - 1 else solve(A, b)
        return x, np.ones(len(A), bool)
    except np.linalg.LinAlgError:
        out, ok = np.empty(b.shape), np.ones(len(A), bool)
        for i in range(len(A)):
            try:
                out[i] = np.linalg.solve(A[i], b[i])
            except np.linalg.LinAlgError:
                out[i] = np.linalg.lstsq(A[i], b[i], rcond=None)[0]
                ok[i] = False
        return out, ok


_ALL = slice(None)

#: Weights of the offset and tilt steps in the edge motion they cause anywhere in a window
#: (tilt times 5 px) [-].
_EDGE_MOTION = np.array([1.0, 5.0])


class _TableModel:
    """The ``detector-psf`` model of ``K`` windows (module steps 3b-4), evaluated through one
    Gram matrix per window.

    The weighted basis rows (background, step, [ramp,] the step's tangential gradient), the
    weighted data and the step's derivative rows ``lsf w {1, t, t^2}`` are the rows of one
    ``(k, p + 4, M)`` array ``Y``, and ``G = Y Y^T`` holds all a Gauss-Newton step needs:
    the amplitudes are ``A^-1 b`` (``A``, ``b`` the basis block of ``G`` and its data
    column), and projecting the basis out of the other rows, ``Gp = G_DD - G_DB A^-1
    G_BD``, gives the cost ``Gp_yy`` and the normal equations of ``(delta, tau)`` reduced by
    the amplitudes (the Schur complement of the full ``(2 + p)`` ones, whose inverse's
    ``delta`` entry is the full one's): the edge's Jacobian rows are ``[[A, Gt, 0], [0, A,
    Gt]] lsf w {1, t, t^2}`` (``A`` the step, ``Gt`` its tangential gradient; the ramp's
    term is a basis row and projects out), so ``S = L Gp L^T`` and ``g = L Gp_.y``."""

    q = 2

    def __init__(self, y: FloatArray, mask: NDArray[np.bool_], rho: FloatArray,
                 t_arc: FloatArray, radius_px: float, stack: _StackedTables,
                 ramp: bool) -> None:
        self.y, self.mask, self.t_arc, self.stack = y, mask, t_arc, stack
        self.p = 4 if ramp else 3
        # table coordinate of each pixel at delta = tau = 0, and its rate along the arc
        self.u0 = (rho - radius_px + stack.shift - stack.x0) / stack.h
        self.th = t_arc / stack.h
        self.sigma0 = math.nan
        self.weigh(mask.astype(float))

    def weigh(self, sw: FloatArray) -> None:
        """Set the square roots ``(K, M)`` of the pixels' weights."""
        W = np.empty((sw.shape[0], 3, sw.shape[1]))
        W[:, 0] = sw
        np.multiply(sw, self.t_arc, out=W[:, 1])
        np.multiply(W[:, 1], self.t_arc, out=W[:, 2])
        self.W = W
        self.C = np.stack([sw, self.y * sw], axis=1)   # rows 0 and p of Y

    def _values(self, k: NDArray[np.intp] | slice, X: FloatArray) -> FloatArray:
        u = self.u0[k] - X[:, 0:1] / self.stack.h
        u -= X[:, 1:2] * self.th[k]
        return self.stack.values(k, u)

    def _state(self, k: NDArray[np.intp] | slice, v: FloatArray) -> FloatArray:
        W = self.W[k]
        n, p = W.shape[0], self.p
        Y = np.empty((n, p + 4, W.shape[2]))
        Y[:, 0:p + 1:p] = self.C[k]                                 # background, data
        np.multiply(v[0][:, None], W[:, 0:2], out=Y[:, 1:p:p - 2])  # step, its gradient
        if p == 4:
            np.multiply(v[1], W[:, 0], out=Y[:, 2])                 # ramp
        np.multiply(v[2][:, None], W, out=Y[:, p + 1:])             # lsf w {1, t, t^2}
        G = Y @ Y.transpose(0, 2, 1)
        P, _ = _solve(G[:, :p, :p], G[:, :p, p:])
        Gp = G[:, p:, p:] - G[:, p:, :p] @ P
        Z = np.empty((n, p + 7))
        Z[:, :p] = lin = P[:, :, 0]
        Z[:, p] = Gp[:, 0, 0]
        L = np.zeros((n, 6))   # [[A, Gt, 0], [0, A, Gt]], row-major
        L[:, 0::4] = lin[:, 1:2]
        L[:, 1::4] = lin[:, p - 1:p]
        L = L.reshape(n, 2, 3)
        LG = L @ Gp[:, 1:]
        np.matmul(LG[:, :, 1:], L.transpose(0, 2, 1), out=Z[:, p + 1:p + 5].reshape(n, 2, 2))
        Z[:, p + 5:] = LG[:, :, 0]
        return Z

    def evaluate(self, k: NDArray[np.intp] | slice, X: FloatArray) -> FloatArray:
        """The state (:func:`_levenberg_marquardt`) of the windows ``k`` at the parameters
        ``X`` (one row ``(delta, tau, sigma)`` per window)."""
        return self._state(k, self._values(k, X))

    def reweigh(self, noise: PixelNoise, lin: FloatArray, X: FloatArray) -> FloatArray:
        """Weights ``1 / var(I)`` at the model's prediction (amplitudes ``lin``, parameters
        ``X``), and the state of every window with them."""
        v = self._values(_ALL, X)
        p = self.p
        pred = lin[:, 0:1] + (lin[:, 1:2] + lin[:, p - 1:p] * self.t_arc) * v[0]
        if p == 4:
            pred += lin[:, 2:3] * v[1]
        self.weigh(np.where(self.mask, 1.0 / np.sqrt(noise.variance_dn2(pred)), 0.0))
        return self._state(_ALL, v)


class _GaussModel:
    """The Gaussian window model of ``K`` windows (module steps 3-4): the basis functions
    ``sigma^nu F_nu`` of the signed distance; the Jacobian of ``(delta, tau[, sigma])`` is
    formed and reduced by the amplitudes' normal equations (Schur complement)."""

    def __init__(self, y: FloatArray, mask: NDArray[np.bool_], rho: FloatArray,
                 t_arc: FloatArray, radius_px: float, nus: tuple[float, ...], sigma0: float,
                 fit_sigma: bool) -> None:
        self.y, self.mask, self.rho, self.t_arc, self.R = y, mask, rho, t_arc, radius_px
        self.nus, self.fit_sigma, self.sigma0 = nus, fit_sigma, sigma0
        self.p, self.q = len(nus) + 2, 3 if fit_sigma else 2
        self.weigh(mask.astype(float))

    def weigh(self, sw: FloatArray) -> None:
        self.sw, self.yw = sw, self.y * sw

    def _bases(self, k: NDArray[np.intp] | slice, X: FloatArray
               ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        t_arc = self.t_arc[k]
        # d = rho - (R + delta + tau t_arc): each pixel's signed distance outside the edge
        d = self.rho[k] - (self.R + X[:, 0:1] + X[:, 1:2] * t_arc)
        return _gauss_bases(d, t_arc, X[:, 2], self.nus, self.fit_sigma)

    def _state(self, k: NDArray[np.intp] | slice, Bm: FloatArray, dBd: FloatArray,
               dBs: FloatArray | None) -> FloatArray:
        sw, yw, t_arc = self.sw[k], self.yw[k], self.t_arc[k]
        n, p, q = Bm.shape[0], self.p, self.q
        Bw = Bm * sw[:, None, :]
        A = Bw @ Bw.transpose(0, 2, 1)
        lin, _ = _solve(A, (Bw @ yw[..., None])[..., 0])
        r = yw - (lin[:, None, :] @ Bw)[:, 0, :]
        # Jacobian of the nonlinear parameters (dd/ddelta = -1, dd/dtau = -t_arc)
        J = np.empty((n, q, Bm.shape[2]))
        np.matmul(lin[:, None, :], dBd, out=J[:, 0:1])
        np.negative(J[:, 0], out=J[:, 0])
        np.multiply(J[:, 0], t_arc, out=J[:, 1])
        if dBs is not None:
            np.matmul(lin[:, None, :], dBs, out=J[:, 2:3])
        J *= sw[:, None, :]
        C = Bw @ J.transpose(0, 2, 1)
        X, _ = _solve(A, C)
        Z = np.empty((n, p + 1 + q * q + q))
        Z[:, :p] = lin
        Z[:, p] = np.einsum("km,km->k", r, r)
        Z[:, p + 1:p + 1 + q * q] = (J @ J.transpose(0, 2, 1)
                                     - C.transpose(0, 2, 1) @ X).reshape(n, q * q)
        Z[:, p + 1 + q * q:] = (J @ r[..., None])[..., 0]
        return Z

    def evaluate(self, k: NDArray[np.intp] | slice, X: FloatArray) -> FloatArray:
        return self._state(k, *self._bases(k, X))

    def reweigh(self, noise: PixelNoise, lin: FloatArray, X: FloatArray) -> FloatArray:
        bases = self._bases(_ALL, X)
        pred = (lin[:, None, :] @ bases[0])[:, 0, :]
        self.weigh(np.where(self.mask, 1.0 / np.sqrt(noise.variance_dn2(pred)), 0.0))
        return self._state(_ALL, *bases)


def _levenberg_marquardt(model: _TableModel | _GaussModel, X: FloatArray, Z: FloatArray,
                         tolerance_px: float, max_iterations: int
                         ) -> tuple[NDArray[np.int_], NDArray[np.bool_]]:
    """Levenberg-Marquardt on the reduced normal equations of every window at once (module
    step 4).

    ``X`` holds each window's ``(delta, tau, sigma)`` and ``Z`` its state there, one row per
    window: the amplitudes (``p``), the cost, the reduced normal matrix (``q x q``) and
    gradient (``q``) of the nonlinear parameters; both are updated in place (``Z`` to the
    last point evaluated). Returns each window's iterations and whether it converged.

    The windows still iterating step together; only those taking a trial step are
    evaluated. A window has converged when its next step would move its edge by less than
    ``tolerance_px`` anywhere in it (the step is then taken without evaluating it), or when
    a rejected step (the cost rose) puts the minimum along it that close: the parabola
    through the cost, its slope and the trial's cost has its minimum at ``alpha* < 1/2`` of
    the step. Each accepted step shorter than ``_SECANT_NEAR`` measures the cost's curvature
    along it (the change of the gradient) against Gauss-Newton's, and the next step is
    divided by their ratio: the curvature Gauss-Newton leaves out (the residuals times the
    blur's second derivative, large where the model's blur is not the scene's) made it
    converge linearly, ~5x per step, and ~2x on saturated windows."""
    p, q = model.p, model.q
    s0, g0 = p + 1, p + 1 + q * q
    K = X.shape[0]
    lam = np.full(K, _LM_LAMBDA0)
    scale = np.ones(K)
    it = np.zeros(K, int)
    rejected = np.zeros(K, int)
    converged = np.zeros(K, bool)
    active = np.full(K, max_iterations > 0)
    while True:
        a = active.nonzero()[0]   # the windows still iterating
        if not a.size:
            break
        every = a.size == K   # all windows: whole arrays, no gathers (the common case)
        Za = Z.copy() if every else Z[a]
        dg = Za[:, s0:g0:q + 1]   # a view of the diagonal: damped in place
        dg += (lam if every else lam[a])[:, None] * np.where(dg > 0, dg, 1.0)
        step, ok = _solve(Za[:, s0:g0].reshape(-1, q, q), Za[:, g0:])
        step /= (scale if every else scale[a])[:, None]
        mx = np.abs(step[:, :2] * _EDGE_MOTION).max(axis=1)
        ok &= mx < np.inf
        step /= np.maximum(mx, 1.0)[:, None]   # at most 1 px of edge motion
        last = ok & (mx < tolerance_px)
        if last.any():   # at the minimum to within the tolerance: step unevaluated
            w = a[last]
            X[w, :q] += step[last]
            converged[w] = True
            it[w] += 1
        if not ok.all():   # no step: damp more
            w = a[~ok]
            lam[w] *= _LM_GROWTH
            rejected[w] += 1
            tired = w[rejected[w] >= _LM_RETRIES]
            converged[tired] = True
            it[tired] += 1
        go = ok & ~last
        if go.any():
            every = every and bool(go.all())
            wg, sg, mg = (a, step, mx) if every else (a[go], step[go], mx[go])
            Xt = X.copy() if every else X[wg]
            Xt[:, :q] += sg
            if q == 3:
                np.clip(Xt[:, 2], 0.2, 10.0, out=Xt[:, 2])
            T = model.evaluate(_ALL if every else wg, Xt)
            acc = T[:, p] <= (Z[:, p] if every else Z[wg, p])
            all_acc = bool(acc.all())
            every = every and all_acc
            wa, D, Ta = (wg, sg, T) if all_acc else (wg[acc], sg[acc], T[acc])
            if wa.size:
                # the cost's curvature along the step against Gauss-Newton's
                Zo = Z if every else Z[wa]
                den = (D[:, None, :] @ Zo[:, s0:g0].reshape(-1, q, q) @ D[..., None])[:, 0, 0]
                num = ((Zo[:, g0:] - Ta[:, g0:]) * D).sum(axis=1)
                ratio = np.divide(num, den, out=np.ones_like(num),
                                  where=(den > 0) & ((mg if every else mg[acc]) < _SECANT_NEAR))
                if every:   # every window stepped and was accepted: in place
                    np.minimum(np.maximum(ratio, _SECANT_RANGE[0]), _SECANT_RANGE[1], out=scale)
                    X[:] = Xt
                    Z[:] = Ta
                    np.maximum(lam / _LM_GROWTH, _LM_LAMBDA_MIN, out=lam)
                    it += 1
                    rejected[:] = 0
                else:
                    scale[wa] = np.minimum(np.maximum(ratio, _SECANT_RANGE[0]),
                                           _SECANT_RANGE[1])
                    X[wa] = Xt[acc]
                    Z[wa] = Ta
                    lam[wa] = np.maximum(lam[wa] / _LM_GROWTH, _LM_LAMBDA_MIN)
                    it[wa] += 1
                    rejected[wa] = 0
            if wa.size < wg.size:
                rj = ~acc
                wr = wg[rj]
                # the cost along the step, c0 + slope alpha + curv alpha^2 through the trial
                slope = -(Z[wr, g0:] * sg[rj]).sum(axis=1)
                curv = T[rj, p] - Z[wr, p] - slope
                at_min = (slope < 0) & (-slope * np.minimum(mg[rj], 1.0)
                                        < 2.0 * curv * tolerance_px)
                converged[wr[at_min]] = True
                it[wr[at_min]] += 1
                wr = wr[~at_min]
                scale[wr] = 1.0
                lam[wr] *= _LM_GROWTH
                rejected[wr] += 1
                # _LM_RETRIES rejections in a row: no descent direction left, at a minimum
                tired = wr[rejected[wr] >= _LM_RETRIES]
                converged[tired] = True
                it[tired] += 1
        active = ~converged & (it < max_iterations)
    return it, converged


def _fit_windows(y: FloatArray, mask: NDArray[np.bool_], rho: FloatArray, t_arc: FloatArray,
                 radius_px: float, edge_model: str, psf_sigma_px: float | None,
                 noise: PixelNoise | None, tables: Sequence[EdgeTables] | None = None,
                 saturated: bool = False) -> _WindowFits:
    """Fit the window model to ``K`` windows of ``M`` pixels at once (module steps 3-4):
    ``y``, ``mask``, ``rho``, ``t_arc`` are ``(K, M)``; with ``tables`` (one per window) the
    ``detector-psf`` model (a step only when ``saturated``), else the Gaussian one of
    ``edge_model`` (of width ``psf_sigma_px``, or fitted when None); weighted by ``noise``."""
    model: _TableModel | _GaussModel
    if tables is not None:
        model = _TableModel(y, mask, rho, t_arc, radius_px,
                            _StackedTables(tables, radius_px), ramp=not saturated)
    else:
        fit_sigma = psf_sigma_px is None
        model = _GaussModel(y, mask, rho, t_arc, radius_px,
                            EDGE_MODELS["blurred-limb" if edge_model == "detector-psf"
                                        else edge_model],
                            SIGMA0_PX if fit_sigma
                            else math.sqrt(psf_sigma_px**2 + PIXEL_BOX_VARIANCE),
                            fit_sigma)
    K, p, q = y.shape[0], model.p, model.q
    X = np.zeros((K, 3))
    X[:, 2] = model.sigma0
    Z = model.evaluate(_ALL, X)
    if noise is not None:
        # (a saturated window's cost is rough at the 1e-3 px level: there the first pass
        # converges as fully as the second, or its weights move the edge by ~1e-3 px)
        _levenberg_marquardt(model, X, Z, _CONVERGED_STEP if saturated else _WEIGHTS_STEP,
                             MAX_ITERATIONS)
        # weighted pass: weights from the noise model at the unweighted fit's prediction
        Z = model.reweigh(noise, Z[:, :p], X)
    it, converged = _levenberg_marquardt(model, X, Z, _CONVERGED_STEP, MAX_ITERATIONS)
    lin, cost, S = Z[:, :p], Z[:, p], Z[:, p + 1:p + 1 + q * q].reshape(K, q, q)
    # 1-sigma of delta (module step 5): the delta entry of (J^T W J)^-1 of all parameters,
    # the reduced S^-1's, at the last point evaluated; known noise: inflated by the reduced
    # chi-square where the model fits worse than the noise (a-posteriori factor >= 1);
    # unknown noise: s^2 (J^T J)^-1
    dof = np.maximum(mask.sum(axis=1) - q - p, 1)
    s2 = cost / dof
    factor = np.maximum(s2, 1.0) if noise is not None else s2
    e0 = np.zeros((K, q))
    e0[:, 0] = 1.0
    c00, ok = _solve(S, e0)
    sd = np.where(ok, np.sqrt(np.maximum(factor * c00[:, 0], 0.0)), math.inf)
    return _WindowFits(X[:, 0], X[:, 1], X[:, 2], lin, sd, np.sqrt(s2), it, converged)


class _WindowFits(NamedTuple):
    """The fits of ``K`` windows (:class:`EdgeFit`'s fields, one array each; ``lin`` the
    background and amplitudes ``(K, p)``)."""

    delta: FloatArray
    tau: FloatArray
    sigma: FloatArray
    lin: FloatArray
    sigma_delta: FloatArray
    rms: FloatArray
    iterations: NDArray[np.int_]
    converged: NDArray[np.bool_]

    def edge_fit(self, i: int) -> EdgeFit:
        return EdgeFit(delta=float(self.delta[i]), tau=float(self.tau[i]),
                       sigma=float(self.sigma[i]), amplitudes=np.array(self.lin[i, 1:]),
                       background=float(self.lin[i, 0]),
                       sigma_delta=float(self.sigma_delta[i]), rms=float(self.rms[i]),
                       iterations=int(self.iterations[i]), converged=bool(self.converged[i]))


def fit_edge_window(
    dn: ArrayLike,
    rho: ArrayLike,
    t_arc: ArrayLike,
    radius_px: float,
    *,
    options: SIView | None = None,
    noise: PixelNoise | None = None,
    tables: EdgeTables | None = None,
    saturated: bool = False,
) -> EdgeFit:
    """Fit the blurred limb model to the pixels of one window (module steps 3-4).

    Parameters
    ----------
    dn : (M,) array
        Pixel values [DN] (saturated ones already removed).
    rho : (M,) array
        Distance of each pixel centre from the coarse centre [px].
    t_arc : (M,) array
        Arc coordinate of each pixel about the window's reference angle [px].
    radius_px : float
        Coarse limb radius [px].
    options : SIView, optional
        The SI view of a :class:`RefineConfig` (``edge_model``, ``psf_sigma_px``); default
        its defaults.
    noise : PixelNoise, optional
        The pixels' noise: a weighted fit with its covariance; None: unweighted.
    tables : EdgeTables, optional
        The detector's blurred step and ramp at this window (``detector-psf`` model); without
        them the Gaussian model of ``options.edge_model`` (``auto`` and ``detector-psf``:
        ``blurred-limb``).
    saturated : bool
        The window held saturated pixels (removed from ``dn``): the inside of the limb is not
        seen, so only a blurred step is fitted (``detector-psf`` model).

    Returns
    -------
    EdgeFit
        ``amplitudes[0]`` is the step ``A`` [DN]; with tables ``sigma`` is NaN (not fitted).
    """
    opt = options if options is not None else _DEFAULT
    y = np.asarray(dn, float)[None, :]
    edge = "blurred-limb" if opt.edge_model == "auto" else opt.edge_model
    return _fit_windows(y, np.ones(y.shape, bool), np.asarray(rho, float)[None, :],
                        np.asarray(t_arc, float)[None, :], float(radius_px), edge,
                        opt.psf_sigma_px, noise, None if tables is None else [tables],
                        saturated).edge_fit(0)


@functools.lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int) -> tuple[FloatArray, FloatArray]:
    """Row and column of each pixel of an ``h x w`` window, row-major [px]."""
    rows, cols = np.divmod(np.arange(h * w, dtype=float), w)
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def _window_corners(windows: Sequence[Window]
                    ) -> tuple[NDArray[np.int_], FloatArray, FloatArray]:
    """Each window's ``(height, width)``, top-left ``(row, col)`` and centre ``(u, v)`` [px],
    ``(K, 2)`` each."""
    K = len(windows)
    hw = np.array([w.dn.shape for w in windows]).reshape(K, 2)
    rc0 = np.array([(w.row0, w.col0) for w in windows], float).reshape(K, 2)
    return hw, rc0, rc0[:, ::-1] + (hw[:, ::-1] - 1) * 0.5


def _window_normals(centres: FloatArray, c: FloatArray) -> FloatArray:
    """Unit direction from the coarse centre ``c`` to each window's centre ``(K, 2)``: where
    the window centre's ray crosses the coarse limb is the window's reference point."""
    normal = centres - c
    normal /= np.hypot(normal[:, 0], normal[:, 1])[:, None]
    return normal


def prepare_edge_tables(windows: Sequence[Window], centre_px: ArrayLike, radius_px: float, *,
                        options: SIView | None = None, models: RefineModels | None = None,
                        camera: object | None = None) -> None:
    """Build (and cache) the ``detector-psf`` edge tables :func:`refine_limb` will ask for
    with these windows and this coarse circle: those of every window's field cell and edge
    direction (:meth:`EdgeSpread.tables_along`). A tracker carries its tables before the
    frame comes; nothing to do for the Gaussian edge models."""
    opt = options if options is not None else _DEFAULT
    models = models if models is not None else RefineModels()
    if models.edge_model(opt) != "detector-psf" or not windows or camera is None:
        return
    c, R = np.asarray(centre_px, float), float(radius_px)
    dn, real, _, _, centres = _window_pixels(windows, c)
    normal = _window_normals(centres, c)
    _, _, saturated, usable = _window_groups(dn, real, opt.saturation_dn, True)
    for k in _fit_groups(usable, saturated):
        # the tables and their stack, as refine_limb asks for them
        _StackedTables(models.spread.tables_along(  # type: ignore[union-attr]
            camera, c + R * normal[k], normal[k]), R)


def _window_groups(dn: FloatArray, real: NDArray[np.bool_], saturation_dn: float,
                   tabulated: bool) -> tuple[NDArray[np.bool_], NDArray[np.int_],
                                             NDArray[np.bool_], NDArray[np.bool_]]:
    """Per pixel: unsaturated (``ok``); per window: its count, saturated, usable
    (``tabulated``: the ``detector-psf`` model, which keeps saturated windows)."""
    ok = real & (dn < saturation_dn)
    n_ok = ok.sum(axis=1)
    saturated = n_ok < real.sum(axis=1)
    # a Gaussian of fitted width cannot be told from the edge's position when the inside is
    # clipped (measured: -1.9 +- 2.9 px at 0.18 ms): only the detector's own blur makes a
    # saturated edge usable
    usable = (n_ok >= 12) & (tabulated | ~saturated)
    return ok, n_ok, saturated, usable


def _fit_groups(usable: NDArray[np.bool_], saturated: NDArray[np.bool_]
                ) -> list[NDArray[np.intp]]:
    """The windows fitted together: the well-exposed ones, then the saturated ones (their
    model has no ramp)."""
    groups = (np.flatnonzero(usable & ~saturated), np.flatnonzero(usable & saturated))
    return [k for k in groups if k.size]


def _window_pixels(windows: Sequence[Window], c: FloatArray
                   ) -> tuple[FloatArray, NDArray[np.bool_], FloatArray, FloatArray, FloatArray]:
    """The windows' pixels as ``(K, M)`` arrays: DN, a mask of real pixels (windows smaller
    than the largest are padded), and each pixel centre's offset ``(u, v)`` from ``c``
    [px]; and the windows' centres ``(K, 2)`` [px]."""
    K = len(windows)
    shapes = [w.dn.shape for w in windows]
    hw, rc0, centres = _window_corners(windows)
    if shapes.count(shapes[0]) == K:
        h, w = shapes[0]
        dn = np.array([w_.dn for w_ in windows], float).reshape(K, h * w)
        rows, cols = _pixel_grid(h, w)
        rel_u = rc0[:, 1:2] + cols - c[0]
        rel_v = rc0[:, 0:1] + rows - c[1]
        return dn, np.ones(dn.shape, bool), rel_u, rel_v, centres
    M = int((hw[:, 0] * hw[:, 1]).max())
    dn, mask = np.zeros((K, M)), np.zeros((K, M), bool)
    rel_u, rel_v = np.zeros((K, M)), np.zeros((K, M))
    for i, win in enumerate(windows):
        v, u = np.mgrid[win.row0:win.row0 + win.dn.shape[0],
                        win.col0:win.col0 + win.dn.shape[1]].astype(float)
        n = u.size
        dn[i, :n], mask[i, :n] = win.dn.astype(float).ravel(), True
        rel_u[i, :n], rel_v[i, :n] = u.ravel() - c[0], v.ravel() - c[1]
    return dn, mask, rel_u, rel_v, centres


def refine_limb(
    windows: Sequence[Window],
    centre_px: ArrayLike,
    radius_px: float,
    *,
    sun_dir_image: ArrayLike | None = None,
    options: SIView | None = None,
    models: RefineModels | None = None,
    camera: object | None = None,
    phase_rad: float | None = None,
) -> LimbPoints:
    """Subpixel limb points, one per window (module steps 2-5).

    Parameters
    ----------
    windows : sequence of Window
        DN windows along the limb (at most 16 on the AA-STR).
    centre_px, radius_px : (2,) array, float
        Coarse limb circle [px] (from RANSAC on the pixel-level points).
    sun_dir_image : (2,) array, optional
        Carried into the result.
    options : SIView, optional
        The SI view of a :class:`RefineConfig`; default its defaults.
    models : RefineModels, optional
        What the builder resolved (noise, blur, terrain, calibration); default none.
    camera : Camera, optional
        Needed by the ``detector-psf`` model (the field position of each window).
    phase_rad : float, optional
        Phase angle of the frame [rad]: selects the calibrated model errors.

    Returns
    -------
    LimbPoints
        ``source="windows"``; ``sigma_px`` from each fit.

    Raises
    ------
    LimbNotFoundError
        When fewer than 3 windows give a valid edge.
    """
    opt = options if options is not None else _DEFAULT
    models = models if models is not None else RefineModels()
    # the knobs, read once
    edge_model = models.edge_model(opt)
    size_px, saturation_dn = opt.window_size_px, opt.saturation_dn
    psf_sigma_px, noise = opt.psf_sigma_px, models.noise
    c = np.asarray(centre_px, float)
    R = float(radius_px)
    half = size_px / 2.0 + 1.0
    tabulated = edge_model == "detector-psf"
    if tabulated and camera is None:
        raise ConfigError("camera", None, "a Camera for the detector-psf edge model")
    if len(windows) < 3:
        raise LimbNotFoundError(f"subpixel refinement: {len(windows)} windows (need >= 3)",
                                "no-edge")
    # model error of a point: the terrain's limb-height spread averaged over the window's arc,
    # at this disc size (its half-circle mean is shared by all points: ``common``), and the
    # edge model's own error
    edge_err, sat_err, t_scale = models.model_errors(opt, phase_rad)
    topo = models.limb_topography
    frac = topo.sigma_fraction_over(size_px / max(R, 1.0)) if topo is not None else 0.0
    model_px = math.hypot(edge_err, t_scale * frac * R)
    common = models.common_covariance(opt, R)

    # local geometry of every pixel of every window (module step 2), all windows at once
    dn, real, rel_u, rel_v, centres = _window_pixels(windows, c)
    rho = np.hypot(rel_u, rel_v)
    # reference direction: where the window centre's ray crosses the coarse limb; a pixel's
    # arc coordinate is R times its angle from it
    normal = _window_normals(centres, c)
    nu, nv = normal[:, 0:1], normal[:, 1:2]
    t_arc = R * np.arctan2(nu * rel_v - nv * rel_u, nu * rel_u + nv * rel_v)
    ok, n_ok, saturated, usable = _window_groups(dn, real, saturation_dn, tabulated)
    debug = log.isEnabledFor(logging.DEBUG)
    if debug:
        for i in np.flatnonzero(~usable):
            log.debug("window at (%d, %d): %d unsaturated pixels%s, skipped", windows[i].row0,
                      windows[i].col0, int(n_ok[i]),
                      " (saturated, no detector PSF)" if saturated[i] else "")
    # fit the well-exposed windows together and the saturated ones together (their model
    # has no ramp): module steps 3-4
    K = len(windows)
    delta, step_dn, background = np.zeros(K), np.zeros(K), np.zeros(K)
    blur, sd, converged = np.ones(K), np.full(K, math.inf), np.zeros(K, bool)
    for k in _fit_groups(usable, saturated):
        tables = None
        if tabulated:
            tables = models.spread.tables_along(  # type: ignore[union-attr]
                camera, c + R * normal[k], normal[k])
        f = _fit_windows(dn[k], ok[k], rho[k], t_arc[k], R, edge_model, psf_sigma_px, noise,
                         tables, saturated=bool(saturated[k[0]]))
        delta[k], step_dn[k], background[k] = f.delta, f.lin[:, 1], f.lin[:, 0]
        sd[k], converged[k] = f.sigma_delta, f.converged
        if not tabulated:
            blur[k] = f.sigma

    # a valid edge: converged inside the window, with contrast, and pixels beyond the blur
    # on both sides of it
    outward = rho - R - delta[:, None]
    valid = (usable & converged & (np.abs(delta) < half) & np.isfinite(sd)
             & (step_dn >= models.min_contrast_dn)
             & (ok & (outward > blur[:, None])).any(axis=1)
             & (real & (outward < -blur[:, None])).any(axis=1))
    # far past the full well the edge is blooming and halo, not the optics' blur
    fitted_saturated = usable & saturated
    table = models.model_error_table
    max_overexposure = (math.inf if table is not None and table.keep_overexposed
                        else opt.max_overexposure)
    overexposure = step_dn / np.maximum(saturation_dn - background, 1.0)
    valid &= ~fitted_saturated | (overexposure <= max_overexposure)
    if debug:
        for i in np.flatnonzero(usable & ~valid):
            log.debug("window at (%d, %d): no valid edge (delta %.2f px, A %.1f DN, conv %s)",
                      windows[i].row0, windows[i].col0, delta[i], step_dn[i], converged[i])
    if (fitted_saturated.any()
            and float(np.median(overexposure[fitted_saturated])) > max_overexposure):
        # the frame is in the blooming regime (the paper's 7.7 ms): its saturated windows'
        # edges, even where one fits, are not the optics' blur of the limb
        log.debug("saturated windows overexposed %.0fx (median): dropped",
                  float(np.median(overexposure[fitted_saturated])))
        valid &= ~saturated
    i = np.flatnonzero(valid)
    if i.size < 3:
        raise LimbNotFoundError(f"subpixel refinement: {i.size} of {len(windows)} windows "
                                "hold a valid limb edge (need >= 3)", "no-edge")
    pts = c + (R + delta[i])[:, None] * normal[i]
    sat_flags = saturated[i]
    sig = np.maximum(np.sqrt(sd[i] ** 2 + model_px**2 + np.where(sat_flags, sat_err, 0.0) ** 2),
                     opt.min_sigma_px)
    d = np.zeros(2) if sun_dir_image is None else np.asarray(sun_dir_image, float)
    return LimbPoints(uv=pts, sigma_px=sig, centre_px=c, radius_px=R,
                      sun_dir_image=d, n_candidates=len(windows), source="windows",
                      common_covariance_px2=common,
                      fix_covariance_px2=models.fix_covariance(opt, R, bool(sat_flags.any()),
                                                               phase_rad),
                      fit_sigma_px=sd[i], saturated=sat_flags,
                      overexposure=np.where(sat_flags, overexposure[i], 0.0))
