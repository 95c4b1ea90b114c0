"""Albedo-exposure scaling: choosing k, and showing that scaled acquisitions are equivalent.

Only the product of albedo and exposure matters to a pixel's charge, so the bench displays the
Moon rendered with ``rho / k`` and acquires it with ``k t`` (no screen reaches the Moon's flux,
and the AA-STR cannot read a full frame under 200 ms). Each step in full: docs/methods.md,
"starnav.calibration.scaling".

Technique
---------
1. :func:`plan_scaling`: ``k`` large enough for the screen and for the readout law.
2. :func:`albedo_exposure_experiment` (the paper's Fig. 18): two-sample Kolmogorov-Smirnov
   tests of scaled acquisitions against the first, each rejecting a true equivalence with
   probability <= ``ks_alpha``; a control sample off by ``control_product_factor``.
3. :func:`end_to_end` (the paper's Fig. 19): a frame exposed in orbit against its scaled bench
   acquisition.

References
----------
Seed paper, "Scaling between exposure time and albedo" (Figs. 18-19).

Index
-----
:func:`plan_scaling`, :class:`ScalingPlan`, :func:`bench_min_exposure`,
:func:`albedo_exposure_experiment`, :class:`KsExperiment`, :class:`KsCase`, :func:`ks_test`,
:func:`end_to_end`, :class:`EndToEnd`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from starnav.calibration.bench import Bench, DetectorStage
from starnav.calibration.geometric import ScreenMapping, stimulus_counts
from starnav.calibration.radiometric import StimulusComparison, compare_stimulus
from starnav.calibration.screen import ScreenRadiometry
from starnav.calibration.streams import bench_rng
from starnav.detector import min_exposure
from starnav.errors import ConfigError
from starnav.radiance import RadianceImage
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Frame indices of the scaling experiments.
FRAME_KS = 300
FRAME_E2E = 400


# =========================================================================== k
@dataclass(frozen=True)
class ScalingPlan:
    """Albedo-exposure factor and what it implies on the bench.

    Attributes
    ----------
    k : float
        Albedo divisor = exposure multiplier [-].
    albedo_factor : float
        ``1 / k``: multiply the render's albedo by it (``moon.albedo_scale``) [-].
    render_exposure_s, bench_exposure_s : float
        [s]
    k_screen : float
        Smallest k for which the stimulus fits the screen [-].
    k_readout : float
        Smallest k for which the bench exposure allows the readout [-] (1 when not required).
    peak_le_stimulus : float
        Stimulus peak at the camera [e- s^-1 m^-2 sr^-1].
    peak_count_continuous : float
        Its (non-integer) screen count [-].
    peak_count : int
        Nearest screen level [-].
    peak_step_fraction : float
        Radiance step between the levels around the peak, relative [-].
    notes : list of str
    """

    k: float
    albedo_factor: float
    render_exposure_s: float
    bench_exposure_s: float
    k_screen: float
    k_readout: float
    peak_le_stimulus: float
    peak_count_continuous: float
    peak_count: int
    peak_step_fraction: float
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def plan_scaling(moon_peak_le: float, render_exposure_s: float, radiometry: ScreenRadiometry,
                 *, bench_min_exposure_s: float | None = None,
                 bench_exposure_s: float | None = None, headroom: float = 0.9) -> ScalingPlan:
    """Choose the albedo-exposure factor k (module essay, step 2).

    Parameters
    ----------
    moon_peak_le : float
        Brightest rendered pixel at the true albedo [e- s^-1 m^-2 sr^-1].
    render_exposure_s : float
        In-orbit exposure to reproduce [s].
    radiometry : ScreenRadiometry
    bench_min_exposure_s : float, optional
        Shortest bench exposure the readout allows [s] (:func:`bench_min_exposure`).
    bench_exposure_s : float, optional
        Impose the bench exposure (then ``k = bench / render``) [s].
    headroom : float
        Stimulus peak at most this fraction of full white [-].

    Raises
    ------
    ConfigError
        Non-positive inputs, or an imposed bench exposure whose k does not fit the screen
        (names the smallest admissible exposure).
    """
    for name, v in (("moon_peak_le", moon_peak_le), ("render_exposure_s", render_exposure_s)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(name, v, "a finite value > 0")
    k_screen = max(1.0, moon_peak_le / (headroom * radiometry.le_max))
    k_readout = 1.0 if bench_min_exposure_s is None else bench_min_exposure_s / render_exposure_s
    notes = []
    if bench_exposure_s is not None:
        k = bench_exposure_s / render_exposure_s
        if k < k_screen * (1 - 1e-9):
            raise ConfigError("scaling.bench_exposure_ms", bench_exposure_s * 1e3,
                              f">= {k_screen * render_exposure_s * 1e3:.4g} ms: with k = "
                              f"{k:.4g} the stimulus needs {moon_peak_le / k:.4g} e- s^-1 m^-2 "
                              f"sr^-1, above the screen's {headroom:g} x full white")
        if k < k_readout:
            notes.append(f"bench exposure {bench_exposure_s * 1e3:.4g} ms is shorter than the "
                         f"readout needs ({bench_min_exposure_s * 1e3:.4g} ms)")
    else:
        k = max(k_screen, k_readout)
    peak = moon_peak_le / k
    n_cont = float(radiometry.continuous_count(peak))
    lo = int(math.floor(n_cont))
    hi = min(lo + 1, radiometry.max_count)
    lut = radiometry.le_lut
    step = float((lut[hi] - lut[lo]) / peak) if peak > 0 else float("nan")
    n_near = int(radiometry.counts_for(np.array([peak]), "nearest", clip=True)[0])
    if n_near < 32:
        od = math.log10(max(headroom * radiometry.le_max / peak, 1.0)) if peak > 0 else 0.0
        notes.append(f"the stimulus peaks at count {n_near} of {radiometry.max_count}: "
                     f"radiance steps of {100 * step:.0f} % there; dithering hides them, or an "
                     f"ND filter of OD {od:.1f} in the beam lets the screen show the peak near "
                     "full white at the same exposure")
    if k_screen > 1.0:
        notes.append(f"the screen is {moon_peak_le / radiometry.le_max:.3g}x too dim for the "
                     "rendered Moon at its true albedo")
    return ScalingPlan(float(k), 1.0 / k, float(render_exposure_s), float(k * render_exposure_s),
                       float(k_screen), float(k_readout), float(peak), n_cont, n_near, step,
                       notes)


def bench_min_exposure(bench: Bench, readout: str | None = None,
                       window_pixels: int | None = None) -> float:
    """Shortest bench exposure [s] the star tracker's readout allows (paper eq. 1, via
    :func:`starnav.detector.min_exposure`): ``full_frame`` (>= 200 ms) or ``windows`` of
    ``window_pixels`` pixels (default: the whole detector)."""
    mode = readout or bench.config.scaling.readout
    timing = bench.config.scenario.detector.readout.timing
    cam = bench.camera
    if mode == "full_frame":
        return min_exposure(cam.width * cam.height, timing, full_frame=True)
    if mode == "windows":
        n = window_pixels if window_pixels is not None else cam.width * cam.height
        return min_exposure(int(n), timing)
    raise ConfigError("scaling.readout", mode, "full_frame or windows")


# =========================================================================== KS experiment
def ks_test(a: ArrayLike, b: ArrayLike) -> tuple[float, float]:
    """Two-sample Kolmogorov-Smirnov statistic and p-value (asymptotic)."""
    r = stats.ks_2samp(np.asarray(a, float).ravel(), np.asarray(b, float).ravel(),
                       method="asymp")
    return float(r.statistic), float(r.pvalue)


@dataclass
class KsCase:
    """One acquisition of the equivalence experiment.

    Attributes
    ----------
    label : str
    k : float
        Albedo divisor [-].
    exposure_s : float
        Bench exposure [s].
    product_ratio : float
        ``(albedo x exposure) / (reference albedo x exposure)`` [-].
    peak_count : int
    statistic, p_value : float
        KS against the reference case (0 and 1 for the reference itself).
    equivalent : bool
        ``p_value > alpha``.
    dn : (n,) array
        Dark-subtracted DN of the disc region.
    """

    label: str
    k: float
    exposure_s: float
    product_ratio: float
    peak_count: int
    statistic: float
    p_value: float
    equivalent: bool
    dn: FloatArray

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("dn")
        d["n_pixels"] = int(self.dn.size)
        d["mean_dn"] = float(self.dn.mean())
        return d


@dataclass
class KsExperiment:
    """Scaled acquisitions and the control sample (the paper's Fig. 18)."""

    cases: list[KsCase]
    control: KsCase
    alpha: float
    k_screen: float

    @property
    def scaled_equivalent(self) -> bool:
        """No scaled case told apart from the reference."""
        return all(c.equivalent for c in self.cases)

    @property
    def control_detected(self) -> bool:
        return not self.control.equivalent

    def to_dict(self) -> dict[str, Any]:
        return {"alpha": self.alpha, "k_screen": self.k_screen,
                "scaled_equivalent": self.scaled_equivalent,
                "control_detected": self.control_detected,
                "false_alarm_rate_per_test": f"<= {self.alpha} (conservative, see module essay)",
                "cases": [c.to_dict() for c in self.cases],
                "control": self.control.to_dict()}


def albedo_exposure_experiment(bench: Bench, le: ArrayLike | RadianceImage,
                               render_exposure_s: float, mapping: ScreenMapping,
                               detector: DetectorStage | None = None,
                               rng: np.random.Generator | None = None) -> KsExperiment:
    """Acquire the rendered Moon scaled by several k (and a control) and KS-test them
    (module essay, step 3; knobs from ``bench.config.scaling``).

    Parameters
    ----------
    le : (H, W) array or RadianceImage
        Rendered pinhole electron radiance at the true albedo [e- s^-1 m^-2 sr^-1].
    render_exposure_s : float
        The in-orbit exposure whose charge every case reproduces [s].
    mapping : ScreenMapping
    detector : DetectorStage, optional
    rng : numpy.random.Generator, optional
        Dithering stream; default the bench's ``"scaling"`` stream.
    """
    from scipy import ndimage

    sc = bench.config.scaling
    det = detector if detector is not None else bench.chain_detector()
    rng = rng if rng is not None else bench_rng(bench.config, "scaling")
    img = np.asarray(le.Le if isinstance(le, RadianceImage) else le, float)
    rad = bench.radiometry
    k_screen = max(1.0, float(img.max()) / (bench.config.radiometric.headroom_fraction
                                            * rad.le_max))
    mask = img > 0
    region = ndimage.binary_dilation(mask, iterations=bench.config.radiometric.disc_margin_px)
    specs = [(f"k = {m * k_screen:.4g}", m * k_screen, 1.0) for m in sc.ks_k_multiples]
    k_ctrl = max(sc.ks_k_multiples) * k_screen
    specs.append((f"control: k = {k_ctrl:.4g}, exposure x {sc.control_product_factor:g}",
                  k_ctrl, sc.control_product_factor))
    dark_cache: dict[float, FloatArray] = {}
    cases = []
    for idx, (label, k, pf) in enumerate(specs):
        t = k * render_exposure_s * pf
        counts = stimulus_counts(img, mapping, bench, 1.0 / k,
                                 bench.config.radiometric.quantization, rng)
        acq = bench.acquire(counts, t, det, FRAME_KS + 2 * idx)
        if t not in dark_cache:
            dark_cache[t] = bench.acquire(np.zeros_like(counts), t, det,
                                          FRAME_KS + 2 * idx + 1).dn
        dn = (acq.dn - dark_cache[t])[region]
        cases.append((label, k, t, pf, int(counts.max()), dn))
    ref = cases[0][5]
    out = []
    for label, k, t, pf, pk, dn in cases:
        d, p = (0.0, 1.0) if dn is ref else ks_test(ref, dn)
        out.append(KsCase(label, k, t, pf, pk, d, p, p > sc.ks_alpha, dn))
    exp = KsExperiment(out[:-1], out[-1], sc.ks_alpha, k_screen)
    log.info("albedo-exposure KS: scaled p = %s, control p = %.3g",
             ", ".join(f"{c.p_value:.3g}" for c in exp.cases), exp.control.p_value)
    return exp


# =========================================================================== end to end
@dataclass
class EndToEnd:
    """The paper's 0.015 ms render vs k = 13 333 acquisition (Fig. 19)."""

    plan: ScalingPlan
    comparison: StimulusComparison
    ks_statistic: float
    ks_p_value: float
    alpha: float

    def to_dict(self) -> dict[str, Any]:
        return {"plan": self.plan.to_dict(), "metrics": self.comparison.metrics(),
                "ks_statistic": self.ks_statistic, "ks_p_value": self.ks_p_value,
                "ks_equivalent": self.ks_p_value > self.alpha, "alpha": self.alpha}


def end_to_end(bench: Bench, le: ArrayLike | RadianceImage, mapping: ScreenMapping,
               detector: DetectorStage | None = None, *,
               le_scaled: ArrayLike | RadianceImage | None = None,
               render_exposure_s: float | None = None, bench_exposure_s: float | None = None,
               rng: np.random.Generator | None = None) -> EndToEnd:
    """Render-in-orbit vs scaled bench acquisition, end to end (module essay, step 4).

    Parameters
    ----------
    le : (H, W) array or RadianceImage
        Rendered at the true albedo [e- s^-1 m^-2 sr^-1].
    mapping : ScreenMapping
        The geometric calibration.
    le_scaled : array or RadianceImage, optional
        The same frame rendered with ``albedo / k`` (``moon.albedo_scale = plan.albedo_factor``);
        default ``le / k``.
    render_exposure_s, bench_exposure_s : float, optional
        [s]; defaults ``scaling.render_exposure_ms`` and the plan's exposure (``scaling``
        section: fixed, or the shortest the readout allows).
    """
    sc = bench.config.scaling
    img = np.asarray(le.Le if isinstance(le, RadianceImage) else le, float)
    t_r = render_exposure_s if render_exposure_s is not None else sc.render_exposure_ms * 1e-3
    t_b = bench_exposure_s
    if t_b is None and sc.bench_exposure_ms is not None:
        t_b = sc.bench_exposure_ms * 1e-3
    plan = plan_scaling(float(img.max()), t_r, bench.radiometry,
                        bench_min_exposure_s=bench_min_exposure(bench), bench_exposure_s=t_b,
                        headroom=bench.config.radiometric.headroom_fraction)
    rng = rng if rng is not None else bench_rng(bench.config, "end_to_end")
    comp = compare_stimulus(bench, img, t_r, mapping, detector,
                            bench_exposure_s=plan.bench_exposure_s, le_displayed=le_scaled,
                            rng=rng, frame_base=FRAME_E2E)
    gain = comp.gain
    d, p = ks_test(comp.orbit_signal_e[comp.region] / gain, comp.bench_signal_e[comp.region] / gain)
    return EndToEnd(plan, comp, d, p, sc.ks_alpha)


__all__ = ["EndToEnd", "KsCase", "KsExperiment", "ScalingPlan", "albedo_exposure_experiment",
           "bench_min_exposure", "end_to_end", "ks_test", "plan_scaling"]
