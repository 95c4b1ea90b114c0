"""Figures of the bench emulation (matplotlib ``Figure`` objects, no global pyplot state).

Each function returns a :class:`matplotlib.figure.Figure`; the CLI saves them as PNG. They mirror
the seed paper's HIL figures: residual PDF/CDF (Fig. 12), Moon before/after geometric calibration
(Fig. 13), count <-> Moon flux (Fig. 14), expected vs acquired image (Figs. 15-16), histograms
of scaled acquisitions (Fig. 18) and the end-to-end case (Fig. 19).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from starnav.calibration.bench import Bench, BenchCheck
    from starnav.calibration.geometric import GeometricCalibrationResult
    from starnav.calibration.radiometric import CountFluxMapping, MoonFlux, StimulusComparison
    from starnav.calibration.scaling import EndToEnd, KsExperiment, ScalingPlan


def _figure(w: float, h: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout="constrained")


def residual_pdf_cdf(res: GeometricCalibrationResult) -> Figure:
    """PDF and CDF of the angular residuals (seed paper Fig. 12) [arcsec]."""
    fig = _figure(10, 4)
    ax_pdf, ax_cdf = fig.subplots(1, 2)
    sets = [("hold-out dots (not in the fit)", res.holdout_residual_arcsec, "C0"),
            ("closed loop (pre-warped dots)", res.closed_loop_residual_arcsec, "C1"),
            ("uncalibrated", res.uncalibrated_residual_arcsec, "C3")]
    allv = np.concatenate([s[1] for s in sets if len(s[1])]) if any(len(s[1]) for s in sets) \
        else np.array([1.0])
    lo = max(float(allv[allv > 0].min()) if np.any(allv > 0) else 0.01, 0.01)
    bins = np.logspace(math.log10(lo), math.log10(float(allv.max()) * 1.05 + 1e-9), 40)
    for label, v, col in sets:
        if len(v) == 0:
            continue
        rms = float(np.sqrt(np.mean(v**2)))
        ax_pdf.hist(v, bins=bins, density=True, histtype="step", color=col,
                    label=f"{label}: RMS {rms:.2f}\"")
        x = np.sort(v)
        ax_cdf.step(x, np.arange(1, len(x) + 1) / len(x), where="post", color=col, label=label)
    for ax in (ax_pdf, ax_cdf):
        ax.set_xscale("log")
        ax.set_xlabel("angle between desired and obtained line of sight [arcsec]")
        ax.axvline(5.0, color="k", ls=":", lw=1)
        ax.axvline(30.0, color="grey", ls="--", lw=1)
    ax_pdf.set_ylabel("PDF [1/arcsec]")
    ax_cdf.set_ylabel("CDF")
    ax_pdf.legend(fontsize=7)
    ax_pdf.set_title("geometric calibration residuals (5\" goal, 30\" paper)")
    ax_cdf.set_title("cumulative")
    return fig


def dot_displacements(res: GeometricCalibrationResult) -> Figure:
    """Uncalibrated displacement of the dots on the detector (observed - desired) [px], raw and
    with the best affine map removed (what is left: distortion, keystone)."""
    d = res.calibration_dots
    ok = d.found
    des, obs = d.desired_px[ok], d.observed_px[ok]
    A = np.concatenate([des, np.ones((len(des), 1))], 1)
    M, *_ = np.linalg.lstsq(A, obs, rcond=None)
    H, W = d.acquisition.dn.shape
    fig = _figure(11, 5)
    axes = fig.subplots(1, 2)
    spacing = float(np.min(np.diff(np.unique(np.round(des[:, 0]))))) if len(des) > 1 else 50.0
    for ax, dv, title in ((axes[0], obs - des, "observed - desired"),
                          (axes[1], obs - A @ M, "observed - best affine map")):
        mag = np.hypot(dv[:, 0], dv[:, 1])
        gain = 0.7 * spacing / max(float(mag.max()), 1e-9)
        q = ax.quiver(des[:, 0], des[:, 1], dv[:, 0], dv[:, 1], mag, angles="xy",
                      scale_units="xy", scale=1.0 / gain, cmap="viridis")
        fig.colorbar(q, ax=ax, label=f"displacement [px] (arrows x{gain:.3g})", shrink=0.8)
        ax.set_xlim(0, W)
        ax.set_ylim(H, 0)
        ax.set_aspect("equal")
        ax.set_title(f"uncalibrated bench: {title}")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    return fig


def _crop_box(mask: NDArray[np.bool_], pad: int = 12) -> tuple[slice, slice]:
    r, c = np.nonzero(mask)
    if r.size == 0:
        return slice(None), slice(None)
    return (slice(max(r.min() - pad, 0), r.max() + pad + 1),
            slice(max(c.min() - pad, 0), c.max() + pad + 1))


def moon_placement(calibrated: StimulusComparison,
                   uncalibrated: StimulusComparison | None = None) -> Figure:
    """Acquired Moon before/after the geometric calibration, with the circle where it should
    appear (seed paper Fig. 13)."""
    panels = [("after calibration", calibrated)]
    if uncalibrated is not None:
        panels.insert(0, ("before calibration", uncalibrated))
    fig = _figure(5 * len(panels), 5)
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    ref = calibrated
    mask = ref.le_orbit > 0
    rr, cc = np.nonzero(mask)
    cy, cx = rr.mean(), cc.mean()
    rad = math.sqrt(mask.sum() / math.pi)
    big = ref.region
    for comp in panels:
        big = big | (comp[1].bench_signal_e > 0.2 * comp[1].bench_signal_e.max())
    sl = _crop_box(big, 20)
    for ax, (title, comp) in zip(axes, panels, strict=True):
        img = comp.bench_signal_e[sl]
        ax.imshow(img, cmap="gray", origin="upper",
                  extent=(sl[1].start - 0.5, sl[1].start + img.shape[1] - 0.5,
                          sl[0].start + img.shape[0] - 0.5, sl[0].start - 0.5))
        t = np.linspace(0, 2 * math.pi, 361)
        ax.plot(cx + rad * np.cos(t), cy + rad * np.sin(t), color="C0", lw=1)
        m = comp.metrics()
        ax.set_title(f"{title}: centroid off by {m['centroid_offset_px']:.2f} px")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    return fig


def count_flux(mapping: CountFluxMapping, moon: MoonFlux | None = None,
               plan: ScalingPlan | None = None) -> Figure:
    """Screen count vs equivalent Moon radiant flux density per pixel (seed paper Fig. 14)."""
    fig = _figure(7, 4.5)
    ax = fig.subplots()
    ax.semilogy(mapping.counts[1:], mapping.moon_equivalent_flux_px[1:], color="C0",
                label="Moon flux per pixel giving the same electrons")
    ax.set_xlabel("screen count (grey)")
    ax.set_ylabel("Moon radiant flux density per pixel [W m$^{-2}$]")
    if moon is not None:
        omega = mapping.moon_equivalent_flux_px[-1] / mapping.moon_equivalent_l[-1]
        peak = moon.peak_le / mapping.moon_electrons_per_joule * omega
        ax.axhline(peak, color="C3", ls="--", label="rendered Moon peak (true albedo)")
        if plan is not None:
            ax.axhline(peak / plan.k, color="C2", ls=":",
                       label=f"peak / k (k = {plan.k:.4g}) -> count {plan.peak_count}")
    ax.legend(fontsize=8)
    ax.set_title("radiometric calibration: count <-> Moon flux")
    return fig


def stimulus_comparison(comp: StimulusComparison, title: str = "") -> Figure:
    """Expected (in-orbit) vs acquired (bench) image, their ratio and a profile (seed paper
    Figs. 15-16, 19)."""
    fig = _figure(14, 4)
    a1, a2, a3, a4 = fig.subplots(1, 4)
    sl = _crop_box(comp.region, 4)
    so, sb = comp.orbit_signal_e[sl], comp.bench_signal_e[sl]
    vmax = float(max(so.max(), sb.max()))
    a1.imshow(so, cmap="gray", vmin=0, vmax=vmax)
    a1.set_title(f"in orbit, {comp.render_exposure_s * 1e3:.4g} ms [e-]")
    im = a2.imshow(sb, cmap="gray", vmin=0, vmax=vmax)
    a2.set_title(f"bench, {comp.bench_exposure_s * 1e3:.4g} ms (k = {comp.k:.4g})")
    fig.colorbar(im, ax=a2, shrink=0.8)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(comp.inner[sl], sb / so, np.nan)
    im3 = a3.imshow(ratio, cmap="coolwarm", vmin=0.9, vmax=1.1)
    fig.colorbar(im3, ax=a3, shrink=0.8)
    a3.set_title("bench / orbit (inner disc)")
    row = int(np.argmax(so.sum(axis=1)))
    a4.plot(so[row], label="in orbit")
    a4.plot(sb[row], label="bench", ls="--")
    a4.set_xlabel("column in crop [px]")
    a4.set_ylabel("signal [e-]")
    m = comp.metrics()
    a4.set_title(f"disc ratio {m['disc_ratio']:.4f}, peak count {m['peak_count']}")
    a4.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    return fig


def ks_histograms(exp: KsExperiment) -> Figure:
    """DN histograms of the scaled acquisitions and of the control (seed paper Fig. 18)."""
    fig = _figure(7, 4.5)
    ax = fig.subplots()
    allv = np.concatenate([c.dn for c in exp.cases] + [exp.control.dn])
    bins = np.linspace(float(np.percentile(allv, 0.5)), float(allv.max()), 60)
    for c in exp.cases:
        ax.hist(c.dn, bins=bins, histtype="step", label=f"{c.label}: p = {c.p_value:.3g}")
    ax.hist(exp.control.dn, bins=bins, histtype="step", color="k", ls="--",
            label=f"{exp.control.label}: p = {exp.control.p_value:.2g}")
    ax.set_yscale("log")
    ax.set_xlabel("dark-subtracted DN (disc)")
    ax.set_ylabel("pixels")
    ax.set_title(f"albedo / k with exposure x k (KS alpha = {exp.alpha:g})")
    ax.legend(fontsize=7)
    return fig


def end_to_end_figure(e2e: EndToEnd) -> Figure:
    """The 0.015 ms render vs the k-scaled acquisition (seed paper Fig. 19)."""
    return stimulus_comparison(
        e2e.comparison, f"end to end: k = {e2e.plan.k:.6g}, KS p = {e2e.ks_p_value:.3g}")


def coverage(bench: Bench, check: BenchCheck) -> Figure:
    """The screen and where the detector's field lands on it [mm]; unstimulated pixels."""
    fig = _figure(11, 4.5)
    a1, a2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1]})
    sc = bench.config.screen
    w, h = sc.width_mm, sc.height_mm
    a1.add_patch(_rect(-w / 2, -h / 2, w, h))
    cam = bench.camera
    W, H = cam.width, cam.height
    n = 64
    s = np.linspace(-0.5, W - 0.5, n)
    t = np.linspace(-0.5, H - 0.5, n)
    outline = np.concatenate([np.stack([s, np.full(n, -0.5)], -1),
                              np.stack([np.full(n, W - 0.5), t], -1),
                              np.stack([s[::-1], np.full(n, H - 0.5)], -1),
                              np.stack([np.full(n, -0.5), t[::-1]], -1)])
    ji = bench.geometry.pixel_to_screen(outline)
    cj, ci = bench.geometry.centre
    p = sc.pitch_mm
    a1.plot((ji[:, 0] - cj) * p, (ji[:, 1] - ci) * p, color="C3", label="detector field")
    a1.set_xlim(-w / 2 - 5, w / 2 + 5)
    a1.set_ylim(h / 2 + 5, -h / 2 - 5)
    a1.set_aspect("equal")
    a1.set_xlabel("screen x [mm]")
    a1.set_ylabel("screen y [mm]")
    a1.legend(fontsize=8)
    a1.set_title("field of the camera on the screen")
    a2.imshow(bench.stimulated_mask, cmap="gray", vmin=0, vmax=1)
    a2.set_title(f"stimulated pixels: {100 * check.stimulated_fraction:.2f} %")
    return fig


def _rect(x: float, y: float, w: float, h: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, fill=False, color="k", label="screen")
