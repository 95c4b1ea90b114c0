"""Albedo-exposure scaling: choosing k, and showing that scaled acquisitions are equivalent.

Only the product of albedo and exposure matters to a pixel's charge, so the bench displays the
Moon rendered with ``rho / k`` and acquires it with ``k t``. Each step in full:
docs/methods.md, "starnav.calibration.scaling".

Technique
---------
1. :func:`plan_scaling`: ``k`` large enough for the screen and for the readout law.
2. :func:`albedo_exposure_experiment` (the paper's Fig. 18): two-sample Kolmogorov-Smirnov
   tests of scaled acquisitions against the first (false rejection <= ``ks_alpha``), a
   control sample off by ``control_product_factor``, and each case's disc DN ratio with its
   budget. On the truth bench the cases' counts come from the calibrated LUT and sit where
   its errors differ; the ratio's budget: the LUT's covariance along the difference of the
   cases' sensitivities, their interpolation errors, the non-linearity on the two pedestals,
   the pixels' scatter (field, monitor, aperture and spot cancel).
3. :func:`end_to_end` (the paper's Fig. 19): a frame in orbit against its scaled bench
   acquisition (on the truth bench:
   :func:`~starnav.calibration.moon_stimulus.compare_moon_stimulus`).

References
----------
Seed paper, "Scaling between exposure time and albedo" (Figs. 18-19); JCGM 100:2008 (GUM).

Index
-----
:func:`plan_scaling`, :class:`ScalingPlan`, :func:`bench_min_exposure`,
:func:`albedo_exposure_experiment`, :class:`KsExperiment`, :class:`KsCase`, :data:`RATIO_TERMS`,
:func:`ks_test`, :func:`end_to_end`, :class:`EndToEnd`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:  # radiometric_lab imports this module
    from starnav.calibration.moon_stimulus import MoonStimulusComparison
    from starnav.calibration.radiometric_lab import RadiometricCalibration
    from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen

log = logging.getLogger(__name__)

#: Frame indices of the scaling experiments.
FRAME_KS = 300
FRAME_E2E = 400
#: Budget terms of a case's disc-DN ratio to the first case, in the order they are reported.
RATIO_TERMS = ("reference absolute", "reference repeatability", "reference spectral",
               "LUT interpolation", "tracker linearity", "tracker pixels")
#: Normal-consistency factor of the median absolute deviation [-].
_MAD_SIGMA = 1.4826


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
    k_screen, k_readout : float
        Smallest k for which the stimulus fits the screen, and for which the bench exposure
        allows the readout (1 when not required) [-].
    peak_le_stimulus : float
        Stimulus peak at the camera [e- s^-1 m^-2 sr^-1].
    peak_count_continuous, peak_count : float, int
        Its screen count, and the nearest level [-].
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
    k, exposure_s : float
        Albedo divisor [-]; bench exposure [s].
    product_ratio : float
        ``(albedo x exposure) / (reference albedo x exposure)`` [-].
    peak_count : int
    statistic, p_value : float
        KS against the reference case (0 and 1 for the reference itself).
    equivalent : bool
        ``p_value > alpha``.
    dn : (n,) array
        Dark-subtracted DN of the disc region.
    disc_ratio : float
        Summed ``dn`` over the reference case's (1 for an equivalent acquisition) [-].
    ratio_budget : dict
        ``{term: relative 1-sigma}`` of ``disc_ratio`` (:data:`RATIO_TERMS`; zeros for the
        reference itself).
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
    disc_ratio: float = 1.0
    ratio_budget: dict[str, float] = field(default_factory=dict)

    @property
    def ratio_error(self) -> float:
        """``disc_ratio - 1``: the departure from the equivalence [-]."""
        return self.disc_ratio - 1.0

    @property
    def ratio_sigma(self) -> float:
        """Combined relative 1-sigma of ``disc_ratio`` (terms in quadrature) [-]."""
        return math.sqrt(sum(v * v for v in self.ratio_budget.values()))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("dn")
        d["n_pixels"] = int(self.dn.size)
        d["mean_dn"] = float(self.dn.mean())
        d["ratio_error"] = self.ratio_error
        d["ratio_sigma"] = self.ratio_sigma
        return d


@dataclass
class KsExperiment:
    """Scaled acquisitions and the control sample (the paper's Fig. 18)."""

    cases: list[KsCase]
    control: KsCase
    alpha: float
    k_screen: float
    truth_bench: bool = False

    @property
    def scaled_equivalent(self) -> bool:
        """No scaled case told apart from the reference."""
        return all(c.equivalent for c in self.cases)

    @property
    def control_detected(self) -> bool:
        return not self.control.equivalent

    @property
    def z_crit(self) -> float:
        """Bonferroni bound on a ratio's ``|z|`` over the scaled cases (not the reference) at the
        family false-alarm rate."""
        from starnav.calibration.radiometric_lab import (
            FAMILY_ALPHA,  # lazy: cycle with starnav.calibration.radiometric_lab
        )

        return float(stats.norm.isf(FAMILY_ALPHA / (2 * max(len(self.cases) - 1, 1))))

    def ratio_within_budget(self, case: KsCase) -> bool:
        """``|disc_ratio - 1| <= z_crit x ratio_sigma``."""
        return abs(case.ratio_error) <= self.z_crit * case.ratio_sigma

    @property
    def ratios_consistent(self) -> bool:
        """Every scaled case's disc ratio within its budget."""
        return all(self.ratio_within_budget(c) for c in self.cases[1:])

    def to_dict(self) -> dict[str, Any]:
        from starnav.calibration.radiometric_lab import (
            FAMILY_ALPHA,  # lazy: cycle with starnav.calibration.radiometric_lab
        )

        return {"alpha": self.alpha, "k_screen": self.k_screen,
                "scaled_equivalent": self.scaled_equivalent,
                "control_detected": self.control_detected,
                "false_alarm_rate_per_test": f"<= {self.alpha} (conservative, see module essay)",
                "cases": [c.to_dict() for c in self.cases],
                "control": self.control.to_dict(),
                "truth_bench": self.truth_bench, "ratio_z_crit": self.z_crit,
                "ratio_family_false_alarm": FAMILY_ALPHA,
                "ratios_consistent": self.ratios_consistent,
                "control_ratio_detected": not self.ratio_within_budget(self.control)}


def albedo_exposure_experiment(bench: Bench, le: ArrayLike | RadianceImage,
                               render_exposure_s: float, mapping: ScreenMapping,
                               detector: DetectorStage | None = None,
                               rng: np.random.Generator | None = None, *,
                               calibration: RadiometricCalibration | None = None,
                               truth: TruthScreen | None = None,
                               instrument: ReferenceInstrument | None = None) -> KsExperiment:
    """Acquire the rendered Moon scaled by several k (and a control) and KS-test them
    (module essay, step 2; knobs from ``bench.config.scaling``).

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
    calibration, truth, instrument : optional, all three or none
        The lab's radiometric calibration, the truth screen and the reference instrument: the
        cases are chosen with the calibration and shown on the truth screen (module essay);
        without them, the nominal bench model.

    Raises
    ------
    ConfigError
        Only some of ``calibration``, ``truth``, ``instrument`` given; an empty image.
    """
    from scipy import ndimage

    from starnav.calibration.moon_stimulus import (
        calibrated_counts,  # lazy: cycle with starnav.calibration.radiometric_lab
        calibrated_k,
        monitor,
    )

    given = [x is not None for x in (calibration, truth, instrument)]
    if any(given) and not all(given):
        raise ConfigError("truth bench", "calibration, truth, instrument given: "
                          + ", ".join(str(g) for g in given), "all three or none")
    sc = bench.config.scaling
    det = detector if detector is not None else bench.chain_detector()
    rng = rng if rng is not None else bench_rng(bench.config, "scaling")
    img = np.asarray(le.Le if isinstance(le, RadianceImage) else le, float)
    if not np.any(img > 0):
        raise ConfigError("radiance image Le", "all zero", "a frame with the Moon in the field")
    rad = bench.radiometry
    on_truth = calibration is not None and truth is not None and instrument is not None
    if on_truth:
        t_acq, scale, _ = monitor(bench, calibration, instrument)
        k_screen = calibrated_k(bench, calibration, img, scale)
    else:
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
        if on_truth:
            counts, n_cam = calibrated_counts(bench, calibration, img / k, mapping, scale, None,
                                              rng)
            le_b = truth.radiance_at_camera(counts, t_acq)
            acq_dn = det.expose(le_b, t, FRAME_KS + 2 * idx).dn
            if t not in dark_cache:
                dark_cache[t] = det.expose(truth.camera_image(0, t_acq), t,
                                           FRAME_KS + 2 * idx + 1).dn
        else:
            counts = stimulus_counts(img, mapping, bench, 1.0 / k,
                                     bench.config.radiometric.quantization, rng)
            n_cam = None
            acq_dn = bench.acquire(counts, t, det, FRAME_KS + 2 * idx).dn
            if t not in dark_cache:
                dark_cache[t] = bench.acquire(np.zeros_like(counts), t, det,
                                              FRAME_KS + 2 * idx + 1).dn
        full = acq_dn - dark_cache[t]
        cases.append((label, k, t, pf, int(counts.max()), full, n_cam))
    ref_full, ref_n = cases[0][5], cases[0][6]
    ref = ref_full[region]
    budget_of = _ratio_budget(bench, det, img, ref_full, ref_n, cases[0][2], calibration,
                              scale if on_truth else 1.0)
    out = []
    for label, k, t, pf, pk, full, n_cam in cases:
        dn = full[region]
        first = full is ref_full
        d, p = (0.0, 1.0) if first else ks_test(ref, dn)
        ratio = float(dn.sum()) / float(ref.sum())
        budget = {name: 0.0 for name in RATIO_TERMS} if first else budget_of(full, n_cam, t)
        out.append(KsCase(label, k, t, pf, pk, d, p, p > sc.ks_alpha, dn, ratio, budget))
    exp = KsExperiment(out[:-1], out[-1], sc.ks_alpha, k_screen, on_truth)
    log.info("albedo-exposure KS (%s bench): scaled p = %s, control p = %.3g; disc ratios %s",
             "truth" if on_truth else "nominal",
             ", ".join(f"{c.p_value:.3g}" for c in exp.cases), exp.control.p_value,
             ", ".join(f"{c.disc_ratio:.4f}" for c in out))
    return exp


def _ratio_budget(bench: Bench, det: DetectorStage, img: FloatArray, ref_full: FloatArray,
                  ref_n: FloatArray | None, ref_t: float,
                  cal: RadiometricCalibration | None, scale: float):
    """``budget(full_dn, n_cam, t)``: the relative 1-sigma terms (:data:`RATIO_TERMS`) of a
    case's disc ratio to the reference case (module essay, step 2)."""
    from scipy import ndimage

    from starnav.calibration.moon_stimulus import (
        lut_sensitivity,  # lazy: cycle with starnav.calibration.radiometric_lab
        lut_terms,
    )
    from starnav.calibration.radiometric_lab import (
        nonlinearity_beta,  # lazy: cycle with starnav.calibration.radiometric_lab
    )

    lit = img > 0
    w = img[lit] / float(img[lit].sum())
    inner = ndimage.binary_erosion(lit, iterations=3)
    s_ref = np.clip(ref_full[lit], 0.0, None)
    beta = nonlinearity_beta(det)
    cam = bench.camera
    v, u = np.nonzero(lit)
    ri = cam.relative_illumination(u.astype(float), v.astype(float))
    if cal is not None:
        f_lit = cal.field_factor(np.stack([u, v], -1).astype(float))
        black = float(cal.lut(0)) * scale * f_lit
        J_ref, i_ref = lut_sensitivity(cal, ref_n[lit], w)
    else:
        black = np.full(u.shape, float(bench.radiometry.le_lut[0]))
        J_ref, i_ref = None, 0.0

    def pedestal_term(t: float) -> float:
        return float(w @ (2.0 * beta * black * ri * cam.etendue * t / det.full_well_e))

    def budget(full: FloatArray, n_cam: FloatArray | None, t: float) -> dict[str, float]:
        if cal is not None and J_ref is not None and n_cam is not None:
            J, i_case = lut_sensitivity(cal, n_cam[lit], w)
            terms = lut_terms(cal, J - J_ref)
            terms["LUT interpolation"] = math.hypot(i_case, i_ref)
        else:
            # the nominal bench displays with the table that chose the counts
            terms = {name: 0.0 for name in RATIO_TERMS[:4]}
        terms["tracker linearity"] = abs(pedestal_term(t) - pedestal_term(ref_t))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = full[inner] / ref_full[inner]
        r = r[np.isfinite(r)]
        sig_px = (_MAD_SIGMA * float(np.median(np.abs(r - np.median(r)))) if r.size > 1
                  else 0.0)
        terms["tracker pixels"] = sig_px * math.sqrt(float((s_ref**2).sum())) / max(
            float(s_ref.sum()), 1e-300)
        return {name: float(terms[name]) for name in RATIO_TERMS}

    return budget


# =========================================================================== end to end
@dataclass
class EndToEnd:
    """The paper's 0.015 ms render vs k = 13 333 acquisition (Fig. 19)."""

    plan: ScalingPlan
    comparison: StimulusComparison
    ks_statistic: float
    ks_p_value: float
    alpha: float
    truth: MoonStimulusComparison | None = None

    def to_dict(self) -> dict[str, Any]:
        metrics = (self.truth.metrics() if self.truth is not None
                   else self.comparison.metrics() | {"truth_bench": False})
        return {"plan": self.plan.to_dict(), "metrics": metrics,
                "ks_statistic": self.ks_statistic, "ks_p_value": self.ks_p_value,
                "ks_equivalent": self.ks_p_value > self.alpha, "alpha": self.alpha,
                "truth_bench": self.truth is not None}


def end_to_end(bench: Bench, le: ArrayLike | RadianceImage, mapping: ScreenMapping,
               detector: DetectorStage | None = None, *,
               le_scaled: ArrayLike | RadianceImage | None = None,
               render_exposure_s: float | None = None, bench_exposure_s: float | None = None,
               rng: np.random.Generator | None = None,
               calibration: RadiometricCalibration | None = None,
               truth: TruthScreen | None = None,
               instrument: ReferenceInstrument | None = None) -> EndToEnd:
    """Render-in-orbit vs scaled bench acquisition, end to end (module essay, step 3).

    Parameters
    ----------
    le : (H, W) array or RadianceImage
        Rendered at the true albedo [e- s^-1 m^-2 sr^-1].
    mapping : ScreenMapping
        The geometric calibration.
    le_scaled : array or RadianceImage, optional
        The same frame rendered with ``albedo / k``; default ``le / k``.
    render_exposure_s, bench_exposure_s : float, optional
        [s]; defaults ``scaling.render_exposure_ms`` and the plan's exposure.
    calibration, truth, instrument : optional, all three or none
        The truth bench (:func:`~starnav.calibration.moon_stimulus.compare_moon_stimulus`);
        without them, the nominal bench model.

    Raises
    ------
    ConfigError
        Only some of ``calibration``, ``truth``, ``instrument`` given; see also
        :func:`plan_scaling`.
    """
    given = [x is not None for x in (calibration, truth, instrument)]
    if any(given) and not all(given):
        raise ConfigError("truth bench", "calibration, truth, instrument given: "
                          + ", ".join(str(g) for g in given), "all three or none")
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
    mc = None
    if calibration is not None and truth is not None and instrument is not None:
        from starnav.calibration.moon_stimulus import (
            compare_moon_stimulus,  # lazy: cycle with starnav.calibration.radiometric_lab
        )

        mc = compare_moon_stimulus(bench, img, t_r, mapping, calibration, truth, instrument,
                                   detector, bench_exposure_s=plan.bench_exposure_s,
                                   le_displayed=le_scaled, rng=rng, frame_base=FRAME_E2E)
        comp = mc.comparison
    else:
        comp = compare_stimulus(bench, img, t_r, mapping, detector,
                                bench_exposure_s=plan.bench_exposure_s, le_displayed=le_scaled,
                                rng=rng, frame_base=FRAME_E2E)
    gain = comp.gain
    d, p = ks_test(comp.orbit_signal_e[comp.region] / gain, comp.bench_signal_e[comp.region] / gain)
    return EndToEnd(plan, comp, d, p, sc.ks_alpha, mc)


__all__ = ["RATIO_TERMS", "EndToEnd", "KsCase", "KsExperiment", "ScalingPlan",
           "albedo_exposure_experiment",
           "bench_min_exposure", "end_to_end", "ks_test", "plan_scaling"]
