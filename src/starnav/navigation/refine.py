"""Subpixel limb refinement from readout windows, with a PSF-aware edge model (algorithm 1).

The pixel-accuracy limb (:mod:`starnav.navigation.limb`) is good to about a pixel. The STAR Nav
subpixel algorithm then reads up to 16 *windows* of DN values along that limb and refines the
limb position inside each of them. Here each window is fitted with a physical model of a blurred
limb, so the result is unbiased for any PSF width the model is told or can fit.

Technique
---------
1. **Plan.** :func:`plan_windows` places ``n_windows`` (<= 16) square windows of ``size_px``
   evenly along the lit arc of the pixel-level limb (points ordered by angle), each centred on a
   limb point and clipped to the detector.
2. **Local geometry.** A coarse circle ``(c, R)`` (RANSAC) gives, for every pixel centre ``p``
   of a window, its radius ``rho = |p - c|`` and its arc coordinate ``t = R (phi - phi_w)``
   about the window's reference angle ``phi_w``. The edge inside the window is
   ``rho_e(t) = R + delta + tau t`` (an offset and a tilt), so a pixel's signed distance outside
   the edge is ``d = rho - rho_e(t)``; the curvature comes from the circle, and the ellipse's
   different curvature changes ``rho_e`` by < 0.01 px over a window.
3. **Edge model.** Across the limb of a sphere the scene radiance, as a function of the
   distance ``x`` inside the limb, is ``f(x) = H(x) [A + G1 x + Gh sqrt(x)]`` to first order in
   the emission angle (``cos e = sqrt(2x/R)``; exact for a Lambert sphere to ``O((x/R)^1.5)``;
   ``H`` the step). It is blurred by a Gaussian PSF of ``sigma`` (the pixel's box adds 1/12 px^2
   to the variance), which gives the closed-form basis ``sigma^nu F_nu(x/sigma)`` with
   ``F_nu(t) = int_0^inf y^nu phi(t - y) dy`` (``F_0 = Phi``, ``F_1 = t Phi + phi``;
   ``F_1/2`` from the parabolic cylinder function ``D_-3/2``, tabulated once). The model of a
   pixel is ``I = Bg + A F_0 + G1 sigma F_1 + Gh sigma^(1/2) F_1/2``.

   **3b. The detector's own blur** (``detector-psf``, the default when the frames' detector is
   known, :class:`EdgeSpread`). A star tracker is defocused on purpose: its PSF is a disc
   convolved with an elliptical Gaussian that grows across the field
   (:mod:`starnav.detector.optics`), whose tails are not a Gaussian's. The window's edge is
   then blurred by the detector's line spread function across the limb normal at that field
   position (:func:`starnav.detector.optics.line_spread_function`: the tent blend of the node
   PSFs, the pixel apertures, the inter-pixel capacitance), tabulated once per field cell and
   direction, and the model is a blurred step and ramp, ``I = Bg + A b0(d') + G1 b1(d')``
   (plus the step's tangential gradient), ``b0 = int_{s>d} lsf``, ``b1 = int_{s>d} (s - d)
   lsf``, at ``d' = d + var_t / (2 R)``: a disc's blurred edge is a straight edge's moved
   inwards by the blur's variance along the edge over twice the radius (to first order;
   -0.03 px on a 20 px disc blurred by 1 px without it).
   With the blur known the edge's position is no longer traded against its width, and a
   **saturated** window (its inside clipped at the full well) keeps its edge: its
   unsaturated tail is the known blur of an unknown step, fitted with ``A`` alone (the inside
   profile ``G1`` is not seen). Measured on rendered frames at 0.18 ms: bias +0.01 px against
   -1.9 +- 2.9 px with a fitted Gaussian. Windows whose step exceeds ``max_overexposure`` times
   the headroom to saturation are dropped (there blooming shapes the edge: the 7.7 ms case).
4. **Fit.** Gauss-Newton with Levenberg damping on ``(delta, tau, sigma, Bg, A, G1, Gh)`` with
   the analytic Jacobian (``dF_nu/dt = nu F_(nu-1)``); ``sigma`` is held at
   ``sqrt(psf_sigma_px^2 + 1/12)`` when the PSF is known, and absent with the detector's
   blur. Saturated pixels are left out. With the pixels' noise known (:class:`PixelNoise`:
   read, shot, PRNU, quantisation from the detector settings) the fit is repeated with weights
   ``1 / var(I)`` at the first fit's prediction.

   **All windows at once.** The 16 fits are one batched fit (:class:`_BatchFit`): the
   windows' pixels are ``(K, M)`` arrays, their bases ``(K, p, M)`` (pixels contiguous), the
   amplitudes of every window come from one batched normal-equation solve, the LM steps
   from one batched ``(k, n, n)`` solve; each window keeps its own damping and convergence,
   and only the windows still iterating are evaluated (an iteration's arrays shrink as
   windows converge; a retry after a rejected step evaluates only the windows retrying).
   The ``detector-psf`` tables of the 16 windows are laid end to end on their common grid
   (cached per set of tables) and read with one gather for the three of them instead of
   16 x 3 ``np.interp``. A window has converged when an accepted step moves its edge by
   < 1e-4 px anywhere in it, or a rejected step by < 2e-4 px (the cost rose along it, so it
   brackets the minimum within half its length: without this, a window at its minimum
   spent up to seven damped retries shrinking a 1.5e-4 px step below 1e-4 px). The first,
   unweighted pass of a noise-weighted fit only sets the weights and stops at 1e-2 px
   (the weights change by < 1e-3; the points by < 2e-5 px on the pinned frames; not for
   saturated windows, whose rougher cost let such weights move a 7.7 ms fix by 4e-5).
   Against the
   per-window fit this replaced (a Python loop, ``lstsq`` per evaluation, eight damped
   retries at every minimum): the same points to 1.7e-4 px and sigmas to 4e-6 on the
   pinned frames (``tests/navigation/test_refine_regression.py``), ~11 evaluations and 9
   Jacobians per frame (two passes) instead of ~27 evaluations of all 16 windows
   (``docs/performance.md``). Tried and left out: Newton terms for the offset and tilt
   (residual times the blur's second derivative; Gauss-Newton gains about one digit per
   iteration on these frames, the model's blur being not the scene's): quadratic
   convergence in the first pass, but no faster per frame (the extra basis rows cost what
   the saved iterations gain) and, on saturated windows, stationary points 2e-3 px from
   Gauss-Newton's.
5. **Point and uncertainty.** Each window gives one refined limb point
   ``c + (R + delta) (cos phi_w, sin phi_w)``. Its sigma is the fit's ``sqrt((J^T W J)^-1)``
   (inflated by the reduced chi-square where above 1; ``s^2 (J^T J)^-1`` without a noise
   model) combined with the model errors: the edge model's own error and a saturated
   window's extra (per bin of phase angle), and the terrain's limb-height spread over the
   window's arc (:mod:`starnav.dem.limb`, times a scale), calibrated by Monte Carlo on
   rendered calibration arcs (:class:`ModelErrorCalibration`,
   ``tools/calibrate_refine_model_error.py``). What all points of a frame share (the disc's
   apparent radius, a pull of the limb towards the Sun) goes into
   ``LimbPoints.common_covariance_px2`` for the fix, not into the points' sigma. Windows
   whose fit does not converge, puts the edge outside the window, or finds no contrast are
   dropped.

Tuning
------
=====================  =================  ===================================================
option                 default            effect
=====================  =================  ===================================================
``n_windows``          16                 windows planned along the lit limb (AA-STR: <= 16)
``size_px``            11                 side of each square window [px]
``edge_model``         ``blurred-limb``   ``detector-psf`` (the detector's blur; needs
                                          ``spread``), ``blurred-limb`` (Gaussian: step +
                                          ramp + sqrt onset) or ``blurred-step``
``spread``             None               :class:`EdgeSpread` of the frames' detector
``noise``              None               :class:`PixelNoise`: weighted fit
``max_overexposure``   20                 saturated windows brighter than this many times
                                          the headroom are dropped
``model_error_table``  None               :class:`ModelErrorCalibration` (per phase)
``psf_sigma_px``       None               Gaussian PSF sigma [px]; None: fitted per window
``sigma0_px``          1.0                starting sigma when fitted [px]
``saturation_dn``      4095               pixels at or above are ignored [DN]
``max_iterations``     30                 Gauss-Newton iterations per window
``min_sigma_px``       0.02               floor of the reported uncertainty [px] (model
                                          error on analytic discs: ~0.015 px rms)
``min_contrast_dn``    10                 minimum step amplitude A [DN]
=====================  =================  ===================================================

Example
-------
>>> from starnav.navigation.refine import plan_windows, refine_limb
>>> plan = plan_windows(limb.uv, limb.centre_px, shape=(1024, 1024))   # doctest: +SKIP
>>> fine = refine_limb(windows, limb.centre_px, limb.radius_px)         # doctest: +SKIP

Reference
---------
Seed paper (STAR Nav), the subpixel-accuracy limb algorithm (its reference 5). The blurred-edge
fit follows the PSF-aware edge models of J. A. Christian, "Accurate planetary limb localization
for image-based spacecraft navigation", J. Spacecr. Rockets 54 (2017) 708-730,
doi:10.2514/1.A33692. Parabolic cylinder integral: Abramowitz & Stegun 19.5.3 / DLMF 12.5.1.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import gamma, ndtr, pbdv

from starnav.data import packaged_path
from starnav.dem.limb import LimbTopography
from starnav.detector.optics import line_spread_function
from starnav.detector.products import MAX_WINDOWS, Window
from starnav.errors import ConfigError
from starnav.navigation.limb import LimbNotFoundError, LimbPoints
from starnav.registry import Registry

FloatArray = NDArray[np.float64]
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


@dataclass(frozen=True)
class RefineOptions:
    """Knobs of :func:`plan_windows` and :func:`refine_limb` (module table)."""

    n_windows: int = MAX_WINDOWS
    size_px: int = 11
    edge_model: str = "blurred-limb"
    psf_sigma_px: float | None = None
    sigma0_px: float = 1.0
    saturation_dn: float = 4095.0
    max_iterations: int = 30
    min_sigma_px: float = 0.02
    min_contrast_dn: float = 10.0
    noise: PixelNoise | None = None
    model_error_px: float | None = None
    limb_topography: LimbTopography | None = None
    spread: EdgeSpread | None = None
    saturated_model_error_px: float | None = None
    max_overexposure: float = 20.0
    terrain_scale: float | None = None
    model_error_table: ModelErrorCalibration | None = None

    def model_errors(self, phase_rad: float | None) -> tuple[float, float, float]:
        """``(edge model error [px], saturated extra [px], terrain scale)`` at a phase angle
        [rad]: each given value, else the calibration's at that phase (its largest without a
        phase), else 0, 0, 1."""
        tab = (self.model_error_table.at(phase_rad) if self.model_error_table is not None
               else (0.0, 0.0, 1.0))
        return (tab[0] if self.model_error_px is None else self.model_error_px,
                tab[1] if self.saturated_model_error_px is None
                else self.saturated_model_error_px,
                tab[2] if self.terrain_scale is None else self.terrain_scale)

    def common_covariance(self, radius_px: float) -> FloatArray:
        """Covariance [px^2] of the errors every point of a frame shares, at a disc radius
        ``radius_px``: ``(a, b, c)`` of :class:`ModelErrorCalibration` (the disc's apparent
        radius, a shift of the limb towards the Sun in the image and one across it). From
        the calibration when there is one (terrain and edge model together, scaling with
        the disc), else the DEM's half-circle limb height times the terrain scale (radius
        only); zero without terrain."""
        out = np.zeros((3, 3))
        topo = self.limb_topography
        t = self.model_error_table
        if topo is None:
            return out
        if t is not None and self.terrain_scale is None:
            return np.asarray(t.common_covariance, float) * radius_px**2
        k = 1.0 if self.terrain_scale is None else self.terrain_scale
        out[0, 0] = (k * topo.common_fraction * radius_px) ** 2
        return out

    def fix_covariance(self, radius_px: float, saturated: bool) -> FloatArray | None:
        """Covariance [px^2] of a fix's slowly varying error in the three limb modes
        (:attr:`ModelErrorCalibration.fix_covariance`, or its smooth-Moon value without
        terrain) at a disc radius ``radius_px``; None without a calibration."""
        t = self.model_error_table
        if t is None or self.terrain_scale is not None:
            return None
        if self.limb_topography is None:
            C = t.fix_covariance_smooth
        else:
            C = t.fix_covariance_saturated if saturated else t.fix_covariance
        return np.asarray(C, float) * radius_px**2

    def __post_init__(self) -> None:
        if not 1 <= self.n_windows <= MAX_WINDOWS:
            raise ConfigError("refine.n_windows", self.n_windows, f"1..{MAX_WINDOWS} windows")
        if self.size_px < 5:
            raise ConfigError("refine.size_px", self.size_px, "a window side >= 5 px")
        EDGE_MODELS.check(self.edge_model)
        if self.psf_sigma_px is not None and not (self.psf_sigma_px >= 0
                                                  and math.isfinite(self.psf_sigma_px)):
            raise ConfigError("refine.psf_sigma_px", self.psf_sigma_px, "None or >= 0 px")
        if not self.sigma0_px > 0:
            raise ConfigError("refine.sigma0_px", self.sigma0_px, "> 0 px")
        for name in ("model_error_px", "saturated_model_error_px", "terrain_scale"):
            v = getattr(self, name)
            if v is not None and not (v >= 0 and math.isfinite(v)):
                raise ConfigError(f"refine.{name}", v, "None or a finite value >= 0")
        if not self.max_overexposure > 1:
            raise ConfigError("refine.max_overexposure", self.max_overexposure, "> 1")
        if self.edge_model == "detector-psf" and self.spread is None:
            raise ConfigError("refine.edge_model", self.edge_model,
                              "an EdgeSpread (the detector's blur) with the detector-psf model")


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
        """``(b0, b1, lsf)`` at outward distances ``d`` [px] (asymptotes past the table:
        ``b0 = 1``, ``b1 = mean - d`` inside; 0 outside)."""
        x = self.x
        b0 = np.interp(d, x, self.b0, left=1.0, right=0.0)
        b1 = np.interp(d, x, self.b1, left=np.nan, right=0.0)
        inside = d < x[0]
        if np.any(inside):
            b1[inside] = self.mean - d[inside]
        lsf = np.interp(d, x, self.lsf, left=0.0, right=0.0)
        return b0, b1, lsf


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
    def from_detector(cls, detector: object) -> EdgeSpread:
        """From a :class:`~starnav.detector.schema.DetectorConfig`."""
        d = detector
        ipc = d.signal.ipc  # type: ignore[attr-defined]
        return cls(aberration=d.optics.aberration,  # type: ignore[attr-defined]
                   ipc=(float(ipc.nearest_fraction), float(ipc.diagonal_fraction))
                   if ipc.enabled else (0.0, 0.0))

    def tables(self, camera: object, u: float, v: float, normal: ArrayLike) -> EdgeTables:
        n = np.asarray(normal, float)
        ang = round(math.degrees(math.atan2(n[1], n[0])))
        cu = round(float(u) / self.cell_px) * self.cell_px
        cv = round(float(v) / self.cell_px) * self.cell_px
        return _edge_tables(self, camera, cu, cv, int(ang))


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
    """

    phase_edges_deg: tuple[float, ...]
    edge_model_error_px: tuple[float, ...]
    saturated_model_error_px: tuple[float, ...]
    terrain_scale: float = 1.0
    common_covariance: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance_saturated: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3
    fix_covariance_smooth: tuple[tuple[float, float, float], ...] = ((0.0,) * 3,) * 3

    def __post_init__(self) -> None:
        n = len(self.phase_edges_deg) - 1
        if n < 1 or any(len(t) != n for t in (self.edge_model_error_px,
                                              self.saturated_model_error_px)):
            raise ConfigError("model error calibration", n, "one value per phase bin")

    def at(self, phase_rad: float | None) -> tuple[float, float, float]:
        """``(edge model error, saturated extra, terrain scale)`` in the bin of ``phase_rad``
        (None: the largest)."""
        if phase_rad is None or not math.isfinite(phase_rad):
            return (max(self.edge_model_error_px), max(self.saturated_model_error_px),
                    self.terrain_scale)
        k = int(np.searchsorted(self.phase_edges_deg, math.degrees(phase_rad), "right")) - 1
        k = min(max(k, 0), len(self.edge_model_error_px) - 1)
        return self.edge_model_error_px[k], self.saturated_model_error_px[k], self.terrain_scale

    @classmethod
    def from_dict(cls, doc: dict) -> ModelErrorCalibration:
        def mat(key: str) -> tuple[tuple[float, float, float], ...]:
            return tuple(tuple(float(x) for x in row)  # type: ignore[misc]
                         for row in doc.get(key, [[0.0] * 3] * 3))

        return cls(tuple(doc["phase_edges_deg"]), tuple(doc["edge_model_error_px"]),
                   tuple(doc["saturated_model_error_px"]), float(doc["terrain_scale"]),
                   mat("common_covariance"), mat("fix_covariance"),
                   mat("fix_covariance_saturated"), mat("fix_covariance_smooth"))


@functools.lru_cache(maxsize=1)
def packaged_model_error() -> ModelErrorCalibration:
    """The packaged calibration (:data:`MODEL_ERROR_FILE`, written by
    ``tools/calibrate_refine_model_error.py`` on arcs that never score it)."""
    return ModelErrorCalibration.from_dict(json.loads(packaged_path(MODEL_ERROR_FILE)
                                                      .read_text()))


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
                 options: RefineOptions | None = None) -> list[WindowRequest]:
    """Window requests evenly spread along a limb arc (module step 1).

    Parameters
    ----------
    uv : (N, 2) array
        Pixel-level limb points, ordered along the arc [px].
    centre_px : (2,) array
        Centre of the limb circle [px], used to order the points.
    shape : (rows, cols)
        Detector size [px].
    options : RefineOptions, optional
        ``n_windows`` and ``size_px``.

    Returns
    -------
    list of WindowRequest
        At most ``n_windows`` windows, inside the detector.
    """
    opt = options or RefineOptions()
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
    s = min(opt.size_px, H, W)
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
    of window ``k`` at ``x[i]`` are at ``[:, k n + i]`` of ``tab`` (and their forward
    differences in ``diff``); ``shift[k]`` its curvature correction."""

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
            # forward differences (the last sample of each table is never a left neighbour)
            # values and forward differences in one array: one gather per evaluation
            hit = (tuple(tables), np.concatenate([tab, np.diff(tab, axis=1, append=0.0)]),
                   np.array([t.mean for t in tables])[:, None])
            with self._lock:
                while len(self._cache) >= self._CACHE_SIZE:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[key] = hit
        self.tabdiff, self.mean = hit[1:]
        # a curved edge blurred looks like a straight one moved inwards by the blur's
        # variance along the edge over twice the radius of curvature (to first order)
        shift = np.array([t.tangent_variance for t in tables]) / (2.0 * radius_px)
        self.shift = shift[:, None]
        self.base = (np.arange(len(tables)) * self.n)[:, None]

    def bases(self, k: NDArray[np.intp] | slice, d: FloatArray, t_arc: FloatArray, ramp: bool
              ) -> tuple[FloatArray, FloatArray, None]:
        """Basis ``(k, p, M)`` of the windows ``k`` at distances ``d`` and its derivative
        with respect to ``d``: rows background, step, [ramp,] and the tangential gradient of
        the step (``dB0/dd = -lsf``, ``dB1/dd = -b0``); linear interpolation, as
        ``np.interp``."""
        dd = d + self.shift[k]
        u = (dd - self.x0) / self.h
        j = u.clip(0, self.n - 2).astype(np.intp)    # floor, u >= 0 once clipped
        f = u - j
        j += self.base[k]
        g = self.tabdiff.take(j, axis=1)
        g[3:] *= f
        g[:3] += g[3:]
        b0, b1, lsf = g[0], g[1], g[2]
        if dd.min() < self.x0:    # asymptotes past the table (inside)
            inside = dd < self.x0
            b0[inside] = 1.0
            b1[inside] = np.broadcast_to(self.mean[k], dd.shape)[inside] - dd[inside]
            lsf[inside] = 0.0
        if dd.max() > self.x1:    # outside
            outside = dd > self.x1
            b0[outside] = b1[outside] = lsf[outside] = 0.0
        p = 4 if ramp else 3
        K, M = d.shape
        Bm, dB = np.empty((K, p, M)), np.empty((K, p, M))
        Bm[:, 0], dB[:, 0] = 1.0, 0.0
        Bm[:, 1] = b0
        np.negative(lsf, out=dB[:, 1])
        if ramp:
            Bm[:, 2] = b1
            np.negative(b0, out=dB[:, 2])
        np.multiply(t_arc, b0, out=Bm[:, p - 1])
        np.multiply(t_arc, dB[:, 1], out=dB[:, p - 1])
        return Bm, dB, None


def _solve(A: FloatArray, b: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Batched ``A x = b`` (``(K, n, n)``, ``(K, n)``); rows whose matrix is singular get NaN
    and ``False`` in the returned mask."""
    try:
        return np.linalg.solve(A, b[..., None])[..., 0], np.ones(len(A), bool)
    except np.linalg.LinAlgError:
        out, ok = np.full(b.shape, np.nan), np.ones(len(A), bool)
        for i in range(len(A)):
            try:
                out[i] = np.linalg.solve(A[i], b[i])
            except np.linalg.LinAlgError:
                ok[i] = False
        return out, ok


_ALL = slice(None)


class _BatchFit:
    """Variable-projection Levenberg-Marquardt of ``K`` windows at once (module step 4).

    Each window keeps its own parameters, damping and convergence, and the windows still
    iterating are evaluated together on ``(k, p, M)`` arrays (the basis functions along the
    middle axis, the pixels contiguous): an iteration costs a few dozen array operations
    whatever ``K``, instead of ``K`` small fits of as many operations each, and a window
    that has converged (or whose step was accepted while another retries) drops out of the
    arrays. ``mask`` marks the pixels that count (saturated pixels and the padding of
    smaller windows have weight 0)."""

    def __init__(self, y: FloatArray, mask: NDArray[np.bool_], rho: FloatArray,
                 t_arc: FloatArray, radius_px: float, basis, sigma0: float,
                 fit_sigma: bool, opt: RefineOptions) -> None:
        self.y, self.mask, self.rho, self.t_arc = y, mask, rho, t_arc
        self.R, self.basis, self.fit_sigma, self.opt = radius_px, basis, fit_sigma, opt
        K = y.shape[0]
        self._weigh(mask.astype(float))   # sqrt of the weights: 1 until the noise model
        self.delta, self.tau = np.zeros(K), np.zeros(K)
        self.sigma = np.full(K, float(sigma0))

    def _weigh(self, sw: FloatArray) -> None:
        self.sw, self.yw = sw, self.y * sw

    def evaluate(self, k: NDArray[np.intp] | slice, delta: FloatArray, tau: FloatArray,
                 sigma: FloatArray) -> dict:
        """Model of the windows ``k`` at ``(delta, tau, sigma)`` (one value per window of
        ``k``): the amplitudes solved for (weighted linear least squares), the weighted
        residuals and cost."""
        t_arc, sw, yw = self.t_arc[k], self.sw[k], self.yw[k]
        # d = rho - (R + delta + tau t_arc): each pixel's signed distance outside the edge
        d = self.rho[k] - (self.R + delta[:, None] + tau[:, None] * t_arc)
        Bm, dBd, dBs = self.basis(k, d, t_arc, sigma)
        Bw = Bm * sw[:, None, :]
        lin, ok = _solve(Bw @ Bw.transpose(0, 2, 1), (Bw @ yw[..., None])[..., 0])
        for i in np.flatnonzero(~ok):   # rank-deficient: the minimum-norm solution
            lin[i] = np.linalg.lstsq(Bw[i].T, yw[i], rcond=None)[0]
        r = yw - (lin[:, None, :] @ Bw)[:, 0, :]
        return {"lin": lin, "r": r, "cost": np.einsum("km,km->k", r, r), "Bm": Bm,
                "dBd": dBd, "dBs": dBs}

    def jacobian(self, st: dict, k: NDArray[np.intp] | slice) -> FloatArray:
        """Weighted Jacobian ``(k, n, M)`` of the windows ``k`` (``st`` their state) with
        respect to ``(delta, tau[, sigma])`` and the amplitudes (``dd/ddelta = -1``,
        ``dd/dtau = -t_arc``)."""
        lin, Bm = st["lin"][:, None, :], st["Bm"]
        q = 3 if self.fit_sigma else 2   # rows of the nonlinear parameters
        J = np.empty((Bm.shape[0], q + Bm.shape[1], Bm.shape[2]))
        np.matmul(lin, st["dBd"], out=J[:, 0:1])
        np.negative(J[:, 0], out=J[:, 0])
        np.multiply(J[:, 0], self.t_arc[k], out=J[:, 1])
        if self.fit_sigma:
            np.matmul(lin, st["dBs"], out=J[:, 2:3])
        J[:, q:] = Bm
        J *= self.sw[k][:, None, :]
        return J

    def run(self, tolerance_px: float = _CONVERGED_STEP) -> dict:
        """One Levenberg-Marquardt pass from the current parameters, a window converged
        once an accepted step moves its edge by < ``tolerance_px`` (or a rejected one by
        less than twice that); returns the state."""
        K = self.y.shape[0]
        st = self.evaluate(_ALL, self.delta, self.tau, self.sigma)
        keys = [key for key, v in st.items() if v is not None]
        lam = np.full(K, _LM_LAMBDA0)
        it = np.zeros(K, int)
        converged = np.zeros(K, bool)
        active = np.full(K, self.opt.max_iterations > 0)
        while active.any():
            a = np.flatnonzero(active)   # the windows still iterating
            it[a] += 1
            # (all windows: views instead of copies, the usual case but for the last ones)
            ka = _ALL if a.size == K else a
            sa = st if a.size == K else {key: st[key][a] for key in keys}
            J = self.jacobian(sa, ka)
            JTJ = J @ J.transpose(0, 2, 1)
            g = (J @ sa["r"][..., None])[..., 0]
            diag = np.diagonal(JTJ, axis1=1, axis2=2).copy()
            diag[diag <= 0] = 1.0
            damp = diag[:, :, None] * np.eye(diag.shape[1])
            trying = np.ones(a.size, bool)   # of a: no step accepted or stalled yet
            for _ in range(_LM_RETRIES):
                ti = np.flatnonzero(trying)
                w = a[ti]
                step, ok = _solve(JTJ[ti] + lam[w][:, None, None] * damp[ti], g[ti])
                lam[w[~ok]] *= _LM_GROWTH
                go, step = ti[ok], step[ok]   # of a: the windows that step
                wg = a[go]
                if wg.size:
                    mx = np.maximum(np.abs(step[:, 0]), np.abs(step[:, 1]) * 5.0)
                    step /= np.maximum(mx, 1.0)[:, None]   # at most 1 px of edge motion
                    nd, nt = self.delta[wg] + step[:, 0], self.tau[wg] + step[:, 1]
                    ns = (np.clip(self.sigma[wg] + step[:, 2], 0.2, 10.0) if self.fit_sigma
                          else self.sigma[wg])
                    trial = self.evaluate(_ALL if wg.size == K else wg, nd, nt, ns)
                    acc = trial["cost"] <= st["cost"][wg]
                    wa = wg[acc]
                    converged[wa] = mx[acc] < tolerance_px
                    if wa.size == K:   # every window stepped and improved: take the trial
                        self.delta, self.tau, self.sigma = nd, nt, ns
                        st = trial
                    else:
                        self.delta[wa], self.tau[wa], self.sigma[wa] = nd[acc], nt[acc], ns[acc]
                        for key in keys:
                            st[key][wa] = trial[key][acc]
                    lam[wa] = np.maximum(lam[wa] / _LM_GROWTH, _LM_LAMBDA_MIN)
                    # a rejected step (the cost rose along it) brackets the minimum within
                    # half its length: one under twice the tolerance has converged
                    stall = ~acc & (mx < 2.0 * tolerance_px)
                    converged[wg[stall]] = True
                    lam[wg[~acc & ~stall]] *= _LM_GROWTH
                    trying[go[acc | stall]] = False
                if not trying.any():
                    break
            converged[a[trying]] = True   # no descent direction left: at a minimum
            active = ~converged & (it < self.opt.max_iterations)
        st.update(it=it, converged=converged)
        return st

    def weight(self, noise: PixelNoise, st: dict) -> None:
        """Weights ``1 / var(I)`` at the fit's prediction (the noise model)."""
        pred = (st["lin"][:, None, :] @ st["Bm"])[:, 0, :]
        self._weigh(np.where(self.mask, 1.0 / np.sqrt(noise.variance_dn2(pred)), 0.0))

    def results(self, st: dict) -> list[EdgeFit]:
        """Per window: the fit and the 1-sigma of ``delta`` from ``(J^T W J)^-1`` (module
        step 5)."""
        J = self.jacobian(st, _ALL)
        dof = np.maximum(self.mask.sum(axis=1) - J.shape[1], 1)
        s2 = st["cost"] / dof
        # known noise: the covariance is (J^T W J)^-1, inflated by the reduced chi-square where
        # the model fits worse than the noise (a-posteriori factor >= 1); unknown noise:
        # s^2 (J^T J)^-1
        factor = np.maximum(s2, 1.0) if self.opt.noise is not None else s2
        JTJ = J @ J.transpose(0, 2, 1)
        e0 = np.zeros(JTJ.shape[:2])
        e0[:, 0] = 1.0
        c00, ok = _solve(JTJ, e0)
        sd = np.where(ok, np.sqrt(np.maximum(factor * c00[:, 0], 0.0)), math.inf)
        return [EdgeFit(delta=float(self.delta[i]), tau=float(self.tau[i]),
                        sigma=float(self.sigma[i]),
                        amplitudes=np.asarray(st["lin"][i, 1:], float),
                        background=float(st["lin"][i, 0]), sigma_delta=float(sd[i]),
                        rms=math.sqrt(s2[i]), iterations=int(st["it"][i]),
                        converged=bool(st["converged"][i])) for i in range(len(sd))]


def _fit_windows(y: FloatArray, mask: NDArray[np.bool_], rho: FloatArray, t_arc: FloatArray,
                 radius_px: float, opt: RefineOptions,
                 tables: Sequence[EdgeTables] | None = None,
                 saturated: bool = False) -> list[EdgeFit]:
    """Fit the window model to ``K`` windows of ``M`` pixels at once (module steps 3-4):
    ``y``, ``mask``, ``rho``, ``t_arc`` are ``(K, M)``; with ``tables`` (one per window) the
    ``detector-psf`` model (a step only when ``saturated``), else the Gaussian one."""
    if tables is not None:
        stack = _StackedTables(tables, radius_px)

        def basis(k, d, t_arc, sigma):
            return stack.bases(k, d, t_arc, ramp=not saturated)

        fit = _BatchFit(y, mask, rho, t_arc, radius_px, basis, math.nan, False, opt)
    else:
        nus = EDGE_MODELS["blurred-limb" if opt.edge_model == "detector-psf"
                          else opt.edge_model]
        fit_sigma = opt.psf_sigma_px is None
        sigma = (opt.sigma0_px if fit_sigma
                 else math.sqrt(opt.psf_sigma_px**2 + PIXEL_BOX_VARIANCE))

        def basis(k, d, t_arc, sigma):
            return _gauss_bases(d, t_arc, sigma, nus, fit_sigma)

        fit = _BatchFit(y, mask, rho, t_arc, radius_px, basis, sigma, fit_sigma, opt)
    if opt.noise is not None:
        # (a saturated window's cost is rough at the 1e-3 px level: there the first pass
        # converges as fully as the second, or its weights move the edge by ~1e-3 px)
        st = fit.run(_CONVERGED_STEP if saturated else _WEIGHTS_STEP)
        # weighted pass: weights from the noise model at the unweighted fit's prediction
        fit.weight(opt.noise, st)
    st = fit.run()
    return fit.results(st)


def fit_edge_window(
    dn: ArrayLike,
    rho: ArrayLike,
    t_arc: ArrayLike,
    radius_px: float,
    *,
    options: RefineOptions | None = None,
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
    options : RefineOptions, optional
    tables : EdgeTables, optional
        The detector's blurred step and ramp at this window (``detector-psf`` model); without
        them the Gaussian model of ``options.edge_model``.
    saturated : bool
        The window held saturated pixels (removed from ``dn``): the inside of the limb is not
        seen, so only a blurred step is fitted (``detector-psf`` model).

    Returns
    -------
    EdgeFit
        ``amplitudes[0]`` is the step ``A`` [DN]; with tables ``sigma`` is NaN (not fitted).
    """
    y = np.asarray(dn, float)[None, :]
    return _fit_windows(y, np.ones(y.shape, bool), np.asarray(rho, float)[None, :],
                        np.asarray(t_arc, float)[None, :], float(radius_px),
                        options or RefineOptions(),
                        None if tables is None else [tables], saturated)[0]


def _window_pixels(windows: Sequence[Window], c: FloatArray
                   ) -> tuple[FloatArray, NDArray[np.bool_], FloatArray, FloatArray, FloatArray]:
    """The windows' pixels as ``(K, M)`` arrays: DN, a mask of real pixels (windows smaller
    than the largest are padded), and each pixel centre's offset ``(u, v)`` from ``c``
    [px]; and the windows' centres ``(K, 2)`` [px]."""
    K = len(windows)
    hw = np.array([w.dn.shape for w in windows]).reshape(K, 2)
    rc0 = np.array([(w.row0, w.col0) for w in windows], float).reshape(K, 2)
    centres = rc0[:, ::-1] + (hw[:, ::-1] - 1) / 2.0
    if (hw == hw[0]).all():
        h, w = (int(x) for x in hw[0])
        dn = np.stack([w_.dn for w_ in windows]).reshape(K, h * w).astype(float)
        rows = np.repeat(np.arange(h, dtype=float), w)
        cols = np.tile(np.arange(w, dtype=float), h)
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
    options: RefineOptions | None = None,
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
    options : RefineOptions, optional
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
    opt = options or RefineOptions()
    c = np.asarray(centre_px, float)
    R = float(radius_px)
    half = opt.size_px / 2.0 + 1.0
    tabulated = opt.edge_model == "detector-psf"
    if tabulated and camera is None:
        raise ConfigError("camera", None, "a Camera for the detector-psf edge model")
    if len(windows) < 3:
        raise LimbNotFoundError(f"subpixel refinement: {len(windows)} windows (need >= 3)",
                                "no-edge")
    # model error of a point: the terrain's limb-height spread averaged over the window's arc,
    # at this disc size (its half-circle mean is shared by all points: ``common``), and the
    # edge model's own error
    edge_err, sat_err, t_scale = opt.model_errors(phase_rad)
    topo = opt.limb_topography
    frac = topo.sigma_fraction_over(opt.size_px / max(R, 1.0)) if topo is not None else 0.0
    model_px = math.hypot(edge_err, t_scale * frac * R)
    common = opt.common_covariance(R)

    # local geometry of every pixel of every window (module step 2), all windows at once
    dn, real, rel_u, rel_v, centres = _window_pixels(windows, c)
    rho = np.hypot(rel_u, rel_v)
    phi = np.arctan2(rel_v, rel_u)
    # reference angle: where the window centre's ray crosses the coarse limb
    phi_w = np.arctan2(centres[:, 1] - c[1], centres[:, 0] - c[0])
    normal = np.column_stack([np.cos(phi_w), np.sin(phi_w)])
    t_arc = R * np.angle(np.exp(1j * (phi - phi_w[:, None])))
    ok = real & (dn < opt.saturation_dn)
    n_ok = ok.sum(axis=1)
    saturated = n_ok < real.sum(axis=1)
    # a Gaussian of fitted width cannot be told from the edge's position when the inside is
    # clipped (measured: -1.9 +- 2.9 px at 0.18 ms): only the detector's own blur makes a
    # saturated edge usable
    usable = (n_ok >= 12) & (tabulated | ~saturated)
    for i in np.flatnonzero(~usable):
        log.debug("window at (%d, %d): %d unsaturated pixels%s, skipped", windows[i].row0,
                  windows[i].col0, int(n_ok[i]),
                  " (saturated, no detector PSF)" if saturated[i] else "")
    # fit the well-exposed windows together and the saturated ones together (their model
    # has no ramp): module steps 3-4
    fits: dict[int, EdgeFit] = {}
    for group in (usable & ~saturated, usable & saturated):
        k = np.flatnonzero(group)
        if not k.size:
            continue
        tables = None
        if tabulated:
            edge = c + R * normal[k]
            tables = [opt.spread.tables(camera, u, v, n)  # type: ignore[union-attr]
                      for (u, v), n in zip(edge, normal[k], strict=True)]
        got = _fit_windows(dn[k], ok[k], rho[k], t_arc[k], R, opt, tables,
                           saturated=bool(saturated[k[0]]))
        fits.update(zip(k.tolist(), got, strict=True))

    pts, sig, fit_sig, sat_flags, overexposure = [], [], [], [], []
    for i in sorted(fits):
        fit = fits[i]
        blur = 1.0 if tabulated else fit.sigma
        outward = rho[i] - R - fit.delta
        a_step = fit.amplitudes[0]
        valid = (fit.converged and abs(fit.delta) < half and math.isfinite(fit.sigma_delta)
                 and a_step >= opt.min_contrast_dn
                 and bool(np.any(outward[ok[i]] > blur))
                 and bool(np.any((outward < -blur) & real[i])))
        if saturated[i]:
            # far past the full well the edge is blooming and halo, not the optics' blur
            overexposure.append(a_step / max(opt.saturation_dn - fit.background, 1.0))
            valid = valid and overexposure[-1] <= opt.max_overexposure
        if not valid:
            log.debug("window at (%d, %d): no valid edge (delta %.2f px, A %.1f DN, conv %s)",
                      windows[i].row0, windows[i].col0, fit.delta, a_step, fit.converged)
            continue
        pts.append(c + (R + fit.delta) * normal[i])
        extra = sat_err if saturated[i] else 0.0
        sig.append(max(math.hypot(fit.sigma_delta, model_px, extra), opt.min_sigma_px))
        fit_sig.append(fit.sigma_delta)
        sat_flags.append(bool(saturated[i]))
    if overexposure and float(np.median(overexposure)) > opt.max_overexposure:
        # the frame is in the blooming regime (the paper's 7.7 ms): its saturated windows'
        # edges, even where one fits, are not the optics' blur of the limb
        keep = [not f for f in sat_flags]
        log.debug("saturated windows overexposed %.0fx (median): dropped",
                  float(np.median(overexposure)))
        pts, sig, fit_sig, sat_flags = ([x for x, k in zip(v, keep, strict=True) if k]
                                        for v in (pts, sig, fit_sig, sat_flags))
    if len(pts) < 3:
        raise LimbNotFoundError(f"subpixel refinement: {len(pts)} of {len(windows)} windows "
                                "hold a valid limb edge (need >= 3)", "no-edge")
    d = np.zeros(2) if sun_dir_image is None else np.asarray(sun_dir_image, float)
    return LimbPoints(uv=np.array(pts), sigma_px=np.array(sig), centre_px=c, radius_px=R,
                      sun_dir_image=d, n_candidates=len(windows), source="windows",
                      common_covariance_px2=common,
                      fix_covariance_px2=opt.fix_covariance(R, any(sat_flags)),
                      fit_sigma_px=np.array(fit_sig),
                      saturated=np.array(sat_flags, bool))
