"""The Moon stimulus on the truth bench: counts chosen with the lab's radiometric calibration,
shown on the real screen, and the tracker's DN compared with the in-orbit DN within a budget.

Unlike :func:`~starnav.calibration.radiometric.compare_stimulus` (one datasheet table chooses
and displays the counts, so it cannot fail), the counts come from the lab's
:class:`~starnav.calibration.radiometric_lab.RadiometricCalibration` and the
:class:`~starnav.calibration.radiometric_truth.TruthScreen` shows them.

Technique
---------
1. **Monitor.** At ``radiometric_lab.validation_delay_min`` the reference re-reads full white
   on axis; the calibration is rescaled by ``s = reading / monitor``.
2. **Counts** (:func:`calibrated_counts`): ``Le / k`` divided by the field factor and ``s``,
   pre-warped, inverted through ``LUT(n) - LUT(0)`` (dithered); every acquisition is
   dark-subtracted with a black screen.
3. **Display** (:meth:`TruthScreen.radiance_at_camera`) at the acquisition time.
4. **Comparison.** In orbit at ``t``, on the bench at ``k t`` through the same detector: the
   disc electrons ratio and the inner-disc median ratio.
5. **Budget** (relative 1-sigma per term of :data:`MOON_TERMS`, per metric): the LUT's
   covariance through the Jacobian of ``LUT(n) - LUT(0)`` weighted as the metric; the hold-out
   interpolation, field and aperture terms; the monitor's repeatability; the tracker's
   non-linearity on the black pedestal (``2 beta P / FWC``); the collimator spot's spill; the
   tracker pixels' scatter. **Consistent** when both errors are within the Bonferroni bound at
   :data:`~starnav.calibration.radiometric_lab.FAMILY_ALPHA`; **meets the paper's use** when
   consistent and ``coverage_k`` sigma is within ``tolerance``.

References
----------
Seed paper, "Radiometric Calibration" (Figs. 15-16); JCGM 100:2008 (GUM), first-order
propagation.

Index
-----
:func:`compare_moon_stimulus`, :class:`MoonStimulusComparison`, :func:`calibrated_counts`,
:func:`calibrated_k`, :func:`monitor`, :func:`lut_sensitivity`, :func:`lut_terms`,
:data:`MOON_TERMS`, :data:`METRICS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from starnav.calibration.bench import (
    Acquisition,
    Bench,
    DetectorStage,
    field_varying_blur,
)
from starnav.calibration.geometric import ScreenMapping, prewarp
from starnav.calibration.radiometric import StimulusComparison, checked_render, disc_regions
from starnav.calibration.radiometric_lab import (
    FAMILY_ALPHA,
    RadiometricCalibration,
    aperture_sigma,
    nonlinearity_beta,
)
from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen
from starnav.calibration.screen import QUANTIZATION_METHODS, quantize_to_counts
from starnav.calibration.streams import bench_rng
from starnav.errors import ConfigError
from starnav.radiance import RadianceImage
from starnav.typing import FloatArray

#: Budget terms of the Moon-stimulus comparison, in the order they are reported.
MOON_TERMS = ("reference absolute", "reference repeatability", "reference spectral",
              "reference aperture", "LUT interpolation", "field factor", "field interpolation",
              "monitor / drift", "tracker linearity", "collimator spot", "tracker pixels")
#: The compared quantities (keys of :meth:`StimulusComparison.metrics`).
METRICS = ("disc_ratio", "inner_median_ratio")
#: Normal-consistency factor of the median absolute deviation [-].
_MAD_SIGMA = 1.4826
#: Standard error of a median over that of a mean, Gaussian samples [-].
_MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)


def calibrated_counts(bench: Bench, cal: RadiometricCalibration, le_camera: ArrayLike,
                      mapping: ScreenMapping, scale: float = 1.0, method: str | None = None,
                      rng: np.random.Generator | None = None
                      ) -> tuple[NDArray[np.uint16], FloatArray]:
    """Screen counts that show the pinhole image ``le_camera`` above the black screen, chosen
    with the lab's calibration (module essay, step 2).

    Parameters
    ----------
    le_camera : (H, W) array
        Wanted electron radiance above the black screen at the camera [e- s^-1 m^-2 sr^-1].
    scale : float
        Monitor rescaling of the calibration at the acquisition time [-].
    method : {"nearest", "dither"}, optional
        Default ``radiometric.quantization``.

    Returns
    -------
    counts : (rows, cols) uint16
        The screen image.
    n_camera : (H, W) array
        The continuous count each camera pixel asks for (0 outside the image) [-].

    Raises
    ------
    ConfigError
        The stimulus exceeds the calibrated full white (raise k), bad ``method``, negative
        radiance.
    """
    le = np.asarray(le_camera, float)
    if le.size and (not np.all(np.isfinite(le)) or le.min() < 0):
        raise ConfigError("stimulus electron radiance", "negative or non-finite values",
                          "radiance >= 0 [e- s^-1 m^-2 sr^-1]")
    m = method or bench.config.radiometric.quantization
    if m not in QUANTIZATION_METHODS:
        raise ConfigError("radiometric.quantization", m,
                          f"one of {', '.join(QUANTIZATION_METHODS)}")
    lit = le > 0
    want = np.zeros_like(le)
    v, u = np.nonzero(lit)
    if u.size:
        f = cal.field_factor(np.stack([u, v], -1).astype(float))
        want[v, u] = le[v, u] / (np.clip(f, 1e-6, None) * scale)
    n_max = bench.config.screen.max_count
    grid = np.arange(n_max + 1, dtype=float)
    table = np.maximum.accumulate(np.clip(cal.lut(grid) - cal.lut(0), 0.0, None))
    target = prewarp(want, mapping, bench, 1.0)
    top = float(table[-1])
    if target.size and float(target.max()) > top * (1 + 1e-9):
        raise ConfigError("stimulus electron radiance", f"{target.max():.4g} e- s^-1 m^-2 sr^-1",
                          f"<= the calibrated full white above black {top:.4g} (count {n_max}); "
                          f"raise the albedo-exposure factor k by >= {target.max() / top:.4g}x")
    counts = np.zeros(target.shape, np.uint16)
    # screen pixels outside the bench's window never reach the detector
    j0, i0, j1, i1 = bench.screen_window
    ii, jj = np.nonzero(target[i0:i1, j0:j1] > 0)
    on = (ii + i0, jj + j0)
    if m != "nearest":
        rng = rng if rng is not None else bench_rng(bench.config, "stimulus")
    counts[on] = quantize_to_counts(target[on], table, m, rng)
    n_cam = np.interp(want, table, grid) * lit
    return counts, n_cam


@dataclass
class MoonStimulusComparison:
    """A rendered image in orbit and its stimulus on the truth bench, with the budget.

    Attributes
    ----------
    comparison : StimulusComparison
        Frames, masks and the metrics of the nominal path.
    budget : dict
        ``{metric: {term: relative 1-sigma}}`` for each of :data:`METRICS`.
    acquisition_time_s : float
        After power-on [s].
    monitor_scale : float
        The calibration's rescaling by the monitor at that time [-].
    tolerance, coverage_k : float
        The paper's use and the coverage factor (``radiometric_lab``).
    """

    comparison: StimulusComparison
    budget: dict[str, dict[str, float]]
    acquisition_time_s: float
    monitor_scale: float
    tolerance: float
    coverage_k: float

    def errors(self) -> dict[str, float]:
        """``ratio - 1`` of each metric [-]."""
        m = self.comparison.metrics()
        return {k: float(m[k]) - 1.0 for k in METRICS}

    def sigmas(self) -> dict[str, float]:
        """Combined relative 1-sigma of each metric (terms in quadrature) [-]."""
        return {k: math.sqrt(sum(v * v for v in self.budget[k].values())) for k in METRICS}

    @property
    def z_crit(self) -> float:
        """Bonferroni bound on ``|z|`` over :data:`METRICS` at the family false-alarm rate."""
        return float(stats.norm.isf(FAMILY_ALPHA / (2 * len(METRICS))))

    @property
    def consistent(self) -> bool:
        e, s = self.errors(), self.sigmas()
        return all(abs(e[k]) <= self.z_crit * s[k] for k in METRICS)

    @property
    def meets_use(self) -> bool:
        s = self.sigmas()
        return self.consistent and all(self.coverage_k * s[k] <= self.tolerance
                                       for k in METRICS)

    def metrics(self) -> dict[str, Any]:
        """The comparison's metrics plus the error, sigma, budget and verdicts (JSON-safe)."""
        e, s = self.errors(), self.sigmas()
        return self.comparison.metrics() | {
            "truth_bench": True, "acquisition_time_s": self.acquisition_time_s,
            "monitor_scale": self.monitor_scale,
            "error": e, "sigma": s, "z": {k: e[k] / s[k] if s[k] > 0 else float("inf")
                                          for k in METRICS},
            "budget": {k: dict(v) for k, v in self.budget.items()},
            "z_crit": self.z_crit, "family_false_alarm": FAMILY_ALPHA,
            "consistent": self.consistent, "tolerance": self.tolerance,
            "coverage_k": self.coverage_k, "meets_paper_use": self.meets_use}


#: The LUT's covariance terms and their names in the budgets.
_LUT_TERM_NAMES = {"absolute": "reference absolute", "repeatability": "reference repeatability",
                   "spectral": "reference spectral"}


def lut_sensitivity(cal: RadiometricCalibration, n_cam: ArrayLike, weights: ArrayLike
                    ) -> tuple[FloatArray, float]:
    """Relative sensitivity of a weighted mean of ``LUT(n) - LUT(0)`` over the stimulus counts
    ``n_cam`` to the calibrated LUT values, and the weighted interpolation error.

    Returns
    -------
    J : (n,) array
        ``d ln(mean) / d le`` over the calibrated counts [(e- s^-1 m^-2 sr^-1)^-1].
    interpolation : float
        Weighted relative interpolation error (:meth:`RadiometricCalibration.interpolation_sigma`)
        [-].
    """
    w = np.asarray(weights, float)
    n_max = int(cal.counts[-1])
    bins = np.clip(np.rint(np.asarray(n_cam, float)), 1, n_max).astype(int)
    sel = w > 0
    W = np.bincount(bins[sel], weights=w[sel], minlength=n_max + 1)
    W = W / max(W.sum(), 1e-300)
    ms = np.nonzero(W)[0].astype(float)
    base = np.clip(cal.lut(ms) - cal.lut(0), 1e-300, None)
    J = (W[ms.astype(int)] / base) @ cal.lut_jacobian(ms)
    interp = sum(W[int(mm)] * cal.interpolation_sigma(mm) for mm in ms)
    return J, float(interp)


def lut_terms(cal: RadiometricCalibration, J: FloatArray) -> dict[str, float]:
    """Relative 1-sigma of each of the LUT's covariance terms along the sensitivity ``J``
    (:func:`lut_sensitivity`, or a difference of two) [-]."""
    return {_LUT_TERM_NAMES[k]: math.sqrt(max(float(J @ c @ J), 0.0))
            for k, c in cal.covariance.items() if k in _LUT_TERM_NAMES}


def _lut_terms(cal: RadiometricCalibration, n_cam: FloatArray, weights: FloatArray
               ) -> dict[str, float]:
    """LUT covariance terms and interpolation of a weighted mean over the stimulus counts."""
    J, interp = lut_sensitivity(cal, n_cam, weights)
    out = lut_terms(cal, J)
    out["LUT interpolation"] = interp
    return out


def monitor(bench: Bench, cal: RadiometricCalibration, instrument: ReferenceInstrument
            ) -> tuple[float, float, float]:
    """The stimulus's acquisition time, the calibration's rescaling by the monitor then, and
    the relative 1-sigma of that rescaling (module essay, step 1).

    Returns
    -------
    time_s, scale, sigma : float
        After power-on [s]; ``reading / monitor`` [-]; [-].
    """
    lab = bench.config.radiometric_lab
    cam = bench.camera
    t_acq = cal.session_end_s + lab.validation_delay_min * 60.0
    if cal.options.get("monitor", True):
        thru = cal.options.get("through_collimator", True)
        rs = [instrument.read(bench.config.screen.max_count, np.array([cam.cx, cam.cy]), t_acq,
                              thru) for _ in range(lab.readings_per_point)]
        return (float(t_acq), float(np.mean([r.le for r in rs])) / cal.monitor_le,
                math.sqrt(2.0) * cal.monitor_sigma)
    return float(t_acq), 1.0, abs(cal.drift_per_s) * (t_acq - cal.session_end_s)


def calibrated_k(bench: Bench, cal: RadiometricCalibration, le: FloatArray,
                 scale: float = 1.0) -> float:
    """Smallest albedo divisor whose stimulus peaks at ``radiometric.headroom_fraction`` of the
    calibrated full white (above black) at its field point [-]."""
    lit = le > 0
    v, u = np.nonzero(lit)
    f = cal.field_factor(np.stack([u, v], -1).astype(float))
    n_max = bench.config.screen.max_count
    white = float(cal.lut(n_max) - cal.lut(0)) * scale
    return max(1.0, float(np.max(le[lit] / f)) / (bench.config.radiometric.headroom_fraction
                                                  * white))


def compare_moon_stimulus(bench: Bench, le: ArrayLike | RadianceImage, render_exposure_s: float,
                          mapping: ScreenMapping, cal: RadiometricCalibration,
                          truth: TruthScreen, instrument: ReferenceInstrument,
                          detector: DetectorStage | None = None, *,
                          bench_exposure_s: float | None = None,
                          le_displayed: ArrayLike | RadianceImage | None = None,
                          rng: np.random.Generator | None = None,
                          frame_base: int = 200) -> MoonStimulusComparison:
    """Expose a rendered image in orbit and its stimulus on the truth bench, chosen with the
    lab's calibration, and the budget of the comparison (module essay).

    Parameters
    ----------
    le : (H, W) array or RadianceImage
        Rendered pinhole electron radiance at the true albedo [e- s^-1 m^-2 sr^-1].
    render_exposure_s : float
        In-orbit exposure [s].
    mapping : ScreenMapping
        Geometric calibration.
    cal : RadiometricCalibration
        The lab's calibration of this bench (:func:`calibrate_radiometry`).
    truth, instrument : TruthScreen, ReferenceInstrument
        The bench as it is and the reference that re-reads the monitor.
    detector, bench_exposure_s, le_displayed, rng, frame_base
        As :func:`~starnav.calibration.radiometric.compare_stimulus` (``bench_exposure_s``
        taken on the calibrated screen).

    Raises
    ------
    ConfigError
        Empty image, non-positive exposure, or a stimulus brighter than the calibrated screen.
    """
    det = detector if detector is not None else bench.chain_detector()
    img = checked_render(le, render_exposure_s)
    cfg = bench.config
    lab = cfg.radiometric_lab
    cam = bench.camera
    # 1. time and monitor
    t_acq, scale, drift_sigma = monitor(bench, cal, instrument)
    lit = img > 0
    v, u = np.nonzero(lit)
    uv = np.stack([u, v], -1).astype(float)
    f_lit = cal.field_factor(uv)
    if bench_exposure_s is None:
        bench_exposure_s = calibrated_k(bench, cal, img, scale) * render_exposure_s
    k = float(bench_exposure_s) / render_exposure_s
    disp = (img / k if le_displayed is None else
            np.asarray(le_displayed.Le if isinstance(le_displayed, RadianceImage)
                       else le_displayed, float))
    # 2. counts from the calibration; 3. shown on the truth screen
    counts, n_cam = calibrated_counts(bench, cal, disp, mapping, scale, None, rng)
    orbit = det.expose(img, render_exposure_s, frame_base)
    orbit_dark = det.expose(np.zeros_like(img), render_exposure_s, frame_base + 1)
    le_b = truth.radiance_at_camera(counts, t_acq)
    fr = det.expose(le_b, bench_exposure_s, frame_base + 2)
    dark = det.expose(truth.camera_image(0, t_acq), bench_exposure_s, frame_base + 3)
    acq = Acquisition(le_b, fr.dn, fr.electrons, float(bench_exposure_s), frame_base + 2)
    region, inner = disc_regions(img, cfg.radiometric.disc_margin_px)
    comp = StimulusComparison(img, counts, k, float(render_exposure_s), float(bench_exposure_s),
                              orbit.dn, orbit_dark.dn, orbit.electrons, acq, dark.dn,
                              det.gain_e_per_dn, det.full_well_e, region, inner)
    # 5. the budget
    ri = cam.relative_illumination(u.astype(float), v.astype(float))
    f_lin = cal.field_factor(uv, 1)
    f_sig = cal.field_factor_sigma(uv)
    beta = nonlinearity_beta(det)
    pedestal = float(cal.lut(0)) * scale * f_lit * bench_exposure_s * cam.etendue * ri
    # the collimator spot's spill out of the disc region, by the bench's design
    spill = 0.0
    if cfg.acquisition.include_spot_psf:
        blurred = field_varying_blur(img, bench.sigma_map, cfg.acquisition.psf_levels)
        spill = abs(float(blurred[region].sum()) / float(img[lit].sum()) - 1.0)
    so, sb = comp.orbit_signal_e, comp.bench_signal_e
    with np.errstate(divide="ignore", invalid="ignore"):
        r = sb[inner] / so[inner]
    r = r[np.isfinite(r)]
    sig_px = (_MAD_SIGMA * float(np.median(np.abs(r - np.median(r)))) if r.size > 1 else 0.0)
    s_lit = np.clip(so[lit], 0.0, None)
    weights = {"disc_ratio": img[lit], "inner_median_ratio": inner[lit].astype(float)}
    pixels = {"disc_ratio": sig_px * math.sqrt(float((s_lit**2).sum())) / max(
        float(s_lit.sum()), 1e-300),
              "inner_median_ratio": _MEDIAN_EFFICIENCY * sig_px / math.sqrt(max(r.size, 1))}
    a_sig = aperture_sigma(bench, instrument)
    budget: dict[str, dict[str, float]] = {}
    for key, w in weights.items():
        wn = w / max(float(w.sum()), 1e-300)
        terms = _lut_terms(cal, n_cam[lit], wn)
        terms["reference aperture"] = a_sig
        terms["field factor"] = float(wn @ (f_sig / np.clip(f_lit, 1e-6, None)))
        terms["field interpolation"] = (float(wn @ (np.abs(f_lit - f_lin) / f_lit))
                                        if cal.options.get("model_field", True) else 0.0)
        terms["monitor / drift"] = drift_sigma
        terms["tracker linearity"] = float(wn @ (2.0 * beta * pedestal / det.full_well_e))
        terms["collimator spot"] = spill if key == "disc_ratio" else 0.0
        terms["tracker pixels"] = pixels[key]
        budget[key] = {t: terms[t] for t in MOON_TERMS}
    return MoonStimulusComparison(comp, budget, float(t_acq), float(scale), lab.tolerance,
                                  lab.coverage_k)


__all__ = ["METRICS", "MOON_TERMS", "MoonStimulusComparison", "calibrated_counts",
           "calibrated_k", "compare_moon_stimulus", "lut_sensitivity", "lut_terms", "monitor"]
