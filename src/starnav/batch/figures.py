"""Sweep figures (PNG, matplotlib Agg, no display needed), after the STAR Nav paper.

=================================  ================================================================
function                           figure
=================================  ================================================================
:func:`plot_limb_error_pdfs`       PDF of the limb-point error vs the true limb, one curve per grid
                                   point (paper figures 8, 22, 25)
:func:`plot_error_vs_time`         position and velocity error per J2000 axis with the filter's
                                   3-sigma bounds, every run of one point (figures 9, 23, 26)
:func:`plot_error_vs_exposure`     limb bias and final navigation errors against the exposure time,
                                   one series per combination of the other grid values
=================================  ================================================================

Figures are drawn on :class:`matplotlib.figure.Figure` with the Agg canvas (no global backend
switch) and written atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.atomic import atomic_path
from starnav.timeaxis import elapsed_axis


def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def _save(fig: Any, path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    with atomic_path(p, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, metadata={"Software": None})
    return p


def plot_limb_error_pdfs(series: Sequence[tuple[str, ArrayLike, float, float]],
                         path: str | os.PathLike[str]) -> Path:
    """One histogram density per ``(label, errors_px, bias_px, std_px)`` on common bins [px].

    The curve is every limb point of every run pooled; the legend gives ``bias_px`` and
    ``std_px`` as the report's table does (the median over runs of each run's bias and std),
    and says so, so the figure and the table show the same numbers."""
    fig, ax = _figure(1, 1, (7.5, 4.2 + 0.18 * len(series)))
    a = ax[0, 0]
    data = [(lab, np.asarray(e, float)[np.isfinite(np.asarray(e, float))]) for lab, e, *_ in
            series]
    stats = [(float(b), float(sd)) for _, _, b, sd in series]
    allv = np.concatenate([e for _, e in data if e.size]) if any(e.size for _, e in data) \
        else np.empty(0)
    if allv.size:
        for k, (lab, e) in enumerate(data):
            if not e.size:
                continue
            lo, hi = np.percentile(e, [0.5, 99.5])
            pad = 0.05 * max(hi - lo, 0.5)
            nb = int(min(60, max(8, e.size // 25)))
            d, edges = np.histogram(e, bins=nb, range=(lo - pad, hi + pad), density=True)
            c = 0.5 * (edges[1:] + edges[:-1])
            a.plot(c, d, drawstyle="steps-mid", color=f"C{k % 10}",
                   label=f"{lab}: bias {stats[k][0]:+.2f} px, std {stats[k][1]:.2f} px "
                   "(median over runs)")
        a.axvline(0.0, color="k", lw=0.8)
        if np.max(np.abs(allv)) > 20.0:
            a.set_xscale("symlog", linthresh=2.0)
        a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    else:
        a.text(0.5, 0.5, "no limb points", ha="center", transform=a.transAxes)
    a.set_xlabel("signed distance to the true limb [px] (> 0 outside)")
    a.set_ylabel("PDF [1/px]")
    a.set_title("Limb-point error per scenario (curves: all frames and runs pooled; "
                "legend: median over runs, as in the table)", fontsize=9)
    return _save(fig, path)


def plot_error_vs_time(epochs: ArrayLike, errors: ArrayLike, sigma3: ArrayLike,
                       path: str | os.PathLike[str], title: str) -> Path:
    """Errors per J2000 axis of every run (run 0 black, others grey) with run 0's +-3 sigma.

    Parameters
    ----------
    epochs : (K,) array
        [TDB s]; plotted from the first frame (:func:`starnav.timeaxis.elapsed_axis`).
    errors, sigma3 : (R, K, 6) arrays
        Position [m] and velocity [m/s] errors and 3-sigma bounds.
    """
    t, t_label = elapsed_axis(epochs)
    E = np.asarray(errors, float)
    S = np.asarray(sigma3, float)
    fig, ax = _figure(3, 2, (10.0, 7.0))
    for col, (sl, scale, unit, what) in enumerate(((slice(0, 3), 1e-3, "km", "position"),
                                                   (slice(3, 6), 1.0, "m/s", "velocity"))):
        for i, name in enumerate("xyz"):
            a = ax[i, col]
            j = sl.start + i
            for r in range(1, E.shape[0]):
                a.plot(t, E[r, :, j] * scale, color="0.7", lw=0.6)
            a.plot(t, E[0, :, j] * scale, color="k", lw=1.0, label="error (run 0)")
            a.plot(t, S[0, :, j] * scale, color="C3", ls="--", lw=1.0, label="3-sigma")
            a.plot(t, -S[0, :, j] * scale, color="C3", ls="--", lw=1.0)
            a.set_ylabel(f"{what} {name} [{unit}]")
            tail = np.r_[np.abs(E[:, len(t) // 5:, j]).ravel(), S[0, len(t) // 5:, j]] * scale
            lim = np.nanpercentile(tail, 99) * 1.4 if tail.size else math.nan
            if np.isfinite(lim) and lim > 0:
                a.set_ylim(-lim, lim)
        ax[2, col].set_xlabel(t_label)
    ax[0, 0].legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Navigation error, J2000, EMB-centred: {title}")
    return _save(fig, path)


def plot_error_vs_exposure(rows: Sequence[dict[str, Any]], series_keys: Sequence[str],
                           path: str | os.PathLike[str]) -> Path:
    """Median over runs (markers) and min-max (bars) of the limb bias and final errors against
    the exposure time, one series per combination of the values of ``series_keys`` (the grid
    keys that do not vary with the exposure)."""
    others = [k for k in series_keys if k != "detector.exposure_time_s"]
    series: dict[str, dict[float, list[dict[str, Any]]]] = {}
    for r in rows:
        lab = ", ".join(f"{k.split('.')[-1]}={r.get(k)!r}" for k in others) or "all"
        series.setdefault(lab, {}).setdefault(float(r["exposure_time_s"]), []).append(r)
    panels = (("limb_bias_px", "limb bias [px]", False),
              ("final_position_error_pct_range", "final position error [% of range]", True),
              ("final_velocity_error_pct_speed", "final velocity error [% of speed]", True))
    fig, ax = _figure(1, 3, (13.0, 4.0))
    for j, (col, ylabel, logy) in enumerate(panels):
        a = ax[0, j]
        vals = np.array([float(r[col]) if r.get(col) is not None else np.nan for r in rows])
        if not np.any(np.isfinite(vals)):
            a.text(0.5, 0.5, "no values (no filter: static scenario?)", ha="center",
                   va="center", transform=a.transAxes)
            a.set_ylabel(ylabel)
            continue
        logy = logy and bool(np.any(vals[np.isfinite(vals)] > 0))
        for k, (lab, byexp) in enumerate(series.items()):
            xs = sorted(byexp)
            med, lo, hi = [], [], []
            for x in xs:
                v = np.array([float(r[col]) for r in byexp[x]], float)
                v = v[np.isfinite(v)]
                med.append(np.median(v) if v.size else np.nan)
                lo.append(v.min() if v.size else np.nan)
                hi.append(v.max() if v.size else np.nan)
            xm = np.array(xs) * 1e3
            med_a = np.array(med)
            a.errorbar(xm, med_a, yerr=[med_a - np.array(lo), np.array(hi) - med_a],
                       marker="o", ms=4, capsize=3, color=f"C{k % 10}", label=lab)
        a.set_xscale("log")
        if logy:
            a.set_yscale("log")
        a.set_xlabel("exposure time [ms]")
        a.set_ylabel(ylabel)
        a.grid(True, which="both", lw=0.3)
    ax[0, 0].axhline(0.0, color="k", lw=0.8)
    ax[0, 1].axhline(1.0, color="C3", ls=":", lw=0.8)
    ax[0, 1].axhline(0.5, color="C2", ls=":", lw=0.8)
    if len(series) > 1:
        ax[0, 0].legend(fontsize=7)
    fig.suptitle("Error vs exposure (median over runs, bars: min-max); dotted: the paper's "
                 "1 % and 0.5 %")
    return _save(fig, path)


def plot_attitude_vs_exposure(rows: Sequence[dict[str, Any]],
                              path: str | os.PathLike[str]) -> Path:
    """The attitude side of the exposure trade-off: stars detected and identified in the
    navigation frames (left) and the cross-boresight and roll 1-sigma of the frames that
    solve (right, log), median over runs against the exposure time (rows with the
    :data:`starnav.batch.table.STAR_COLUMNS`)."""
    by: dict[float, list[dict[str, Any]]] = {}
    for r in rows:
        if "stars_detected_median" in r:
            by.setdefault(float(r["exposure_time_s"]), []).append(r)
    xs = sorted(by)

    def med(col: str) -> NDArray[np.float64]:
        out = []
        for x in xs:
            v = np.array([float(r[col]) for r in by[x]], float)
            v = v[np.isfinite(v)]
            out.append(np.median(v) if v.size else np.nan)
        return np.array(out)

    fig, ax = _figure(1, 2, (10.0, 4.0))
    xm = np.array(xs) * 1e3
    a = ax[0, 0]
    a.plot(xm, med("stars_detected_median"), "o-", label="detected")
    a.plot(xm, med("stars_identified_median"), "s--", label="identified (lost in space)")
    a.axhline(4, color="C3", ls=":", lw=0.8, label="4 needed")
    a.set_xscale("log")
    a.set_xlabel("exposure time [ms]")
    a.set_ylabel("stars per navigation frame")
    a.legend(fontsize=7)
    a.grid(True, which="both", lw=0.3)
    a = ax[0, 1]
    cross, roll = med("frame_attitude_sigma_cross_arcsec"), med("frame_attitude_sigma_roll_arcsec")
    a.plot(xm, cross, "o-", label="cross-boresight")
    a.plot(xm, roll, "s-", label="roll")
    for x, c in zip(xm, cross, strict=True):
        if not np.isfinite(c):
            a.text(x, 0.05, "no attitude", transform=a.get_xaxis_transform(), rotation=90,
                   fontsize=7, ha="center", va="bottom").set_in_layout(False)
    a.set_xscale("log")
    a.set_xlim(ax[0, 0].get_xlim())
    if np.any(np.isfinite(cross)):
        a.set_yscale("log")
    a.set_xlabel("exposure time [ms]")
    a.set_ylabel("attitude 1-sigma from the frame's stars [arcsec]")
    a.legend(fontsize=7)
    a.grid(True, which="both", lw=0.3)
    fig.suptitle("The attitude side: the navigation frame's own stars (median over runs)")
    return _save(fig, path)
