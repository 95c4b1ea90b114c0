"""Figures of a navigation run, after the STAR Nav paper (PNG, matplotlib Agg).

=====================================  =====================================================
function                               paper figure
=====================================  =====================================================
:func:`plot_limb_error_pdf`            8, 22, 25: PDF of the limb-point error vs the true limb
:func:`plot_state_errors`              9, 23, 26: position / velocity error per J2000 axis
                                       with the filter's 3-sigma bounds (Monte Carlo runs in
                                       grey, the nominal run in black)
:func:`plot_consistency`               NEES and NIS with their chi-square bands
:func:`plot_resources`                 10, 24, 27: per-frame CPU time and peak memory
=====================================  =====================================================

Figures are drawn on :class:`matplotlib.figure.Figure` objects with the Agg canvas, so no global
backend is switched and nothing needs a display. Each function writes the file atomically
(temporary name, then rename) and returns its path.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from starnav.atomic import atomic_path
from starnav.navigation.metrics import ErrorSummary, chi2_band, error_pdf
from starnav.timeaxis import elapsed_axis

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _figure(nrows: int = 1, ncols: int = 1, size: tuple[float, float] = (7.0, 4.0)):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _save(fig: Figure, path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120)
    return path


def plot_limb_error_pdf(errors_px: ArrayLike, path: str | os.PathLike[str],
                        title: str = "Limb-point error vs the true limb") -> Path:
    """PDF of the signed limb-point errors [px] (positive outside), with bias and std."""
    e = np.asarray(errors_px, float).ravel()
    fig, ax = _figure()
    a = ax[0, 0]
    if e.size:
        x, d = error_pdf(e, bins=min(80, max(10, e.size // 20)))
        a.plot(x, d, drawstyle="steps-mid", color="C0")
        s = ErrorSummary.of(e)
        a.axvline(s.bias, color="C3", ls="--", label=f"bias {s.bias:.3f} px")
        a.axvline(0.0, color="k", lw=0.8)
        a.legend(title=f"std {s.std:.3f} px, n = {s.count}")
    a.set_xlabel("signed distance to the true limb [px] (> 0 outside)")
    a.set_ylabel("PDF [1/px]")
    a.set_title(title)
    return _save(fig, path)


def plot_state_errors(epochs: ArrayLike, errors: ArrayLike, sigma3: ArrayLike,
                      path: str | os.PathLike[str], kind: str = "position",
                      mc_errors: Sequence[ArrayLike] = ()) -> Path:
    """Error per J2000 axis with the +-3-sigma bounds.

    Parameters
    ----------
    epochs : (K,) array
        [TDB s]; plotted from the first, in hours below two days, else days
        (:func:`starnav.timeaxis.elapsed_axis`).
    errors, sigma3 : (K, 6) arrays
        Position [m] and velocity [m/s] errors and bounds.
    kind : {"position", "velocity"}
        Which half to plot (km or m/s).
    mc_errors : sequence of (K, 6) arrays
        Monte Carlo runs, drawn in grey.
    """
    t, t_label = elapsed_axis(epochs)
    sl, scale, unit = (slice(0, 3), 1e-3, "km") if kind == "position" else \
        (slice(3, 6), 1.0, "m/s")
    e = np.asarray(errors, float)[:, sl] * scale
    s = np.asarray(sigma3, float)[:, sl] * scale
    fig, ax = _figure(3, 1, (7.0, 6.5))
    for i, name in enumerate("xyz"):
        a = ax[i, 0]
        for m in mc_errors:
            a.plot(t, np.asarray(m, float)[:, sl][:, i] * scale, color="0.75", lw=0.6)
        a.plot(t, e[:, i], color="k", lw=1.0, label="error")
        a.plot(t, s[:, i], color="C3", lw=1.0, ls="--", label="3-sigma")
        a.plot(t, -s[:, i], color="C3", lw=1.0, ls="--")
        a.set_ylabel(f"{name} [{unit}]")
        lim = np.nanpercentile(np.abs(np.r_[e[:, i], s[len(s) // 10:, i]]), 99) * 1.3
        if np.isfinite(lim) and lim > 0:
            a.set_ylim(-lim, lim)
    ax[0, 0].legend(loc="upper right")
    ax[0, 0].set_title(f"{kind.capitalize()} error, J2000")
    ax[2, 0].set_xlabel(t_label)
    return _save(fig, path)


def plot_consistency(epochs: ArrayLike, nees_values: ArrayLike, nis_values: ArrayLike,
                     path: str | os.PathLike[str], runs: int = 1) -> Path:
    """NEES (6 dof) and NIS (3 dof), averaged over ``runs``, with their 95 % bands."""
    t, t_label = elapsed_axis(epochs)
    fig, ax = _figure(2, 1, (7.0, 5.0))
    for a, v, dof, name in ((ax[0, 0], nees_values, 6, "NEES"), (ax[1, 0], nis_values, 3, "NIS")):
        v = np.asarray(v, float)
        lo, hi = chi2_band(dof, runs)
        a.semilogy(t, v, ".", ms=3, color="k")
        a.axhline(lo, color="C3", ls="--")
        a.axhline(hi, color="C3", ls="--")
        a.axhline(dof, color="C2", lw=0.8)
        a.set_ylabel(f"{name} (mean of {runs})")
    ax[1, 0].set_xlabel(t_label)
    ax[0, 0].set_title("Filter consistency (95 % chi-square bands)")
    return _save(fig, path)


def plot_resources(cpu_s: ArrayLike, peak_bytes: ArrayLike | None,
                   path: str | os.PathLike[str], budget_ms: float = 5.0,
                   tracker_memory_kb: float = 900.0) -> Path:
    """Per-frame CPU time [ms] against the budget and peak memory [kB] against the tracker's."""
    cpu = np.asarray(cpu_s, float) * 1e3
    n = 2 if peak_bytes is not None else 1
    fig, ax = _figure(n, 1, (7.0, 2.6 * n))
    a = ax[0, 0]
    a.plot(cpu, ".", ms=3, color="C0")
    a.axhline(budget_ms, color="C3", ls="--", label=f"budget {budget_ms:g} ms")
    a.axhline(float(np.median(cpu)), color="k", lw=0.8,
              label=f"median {np.median(cpu):.2f} ms")
    a.set_ylabel("CPU time [ms]")
    a.legend(loc="upper right")
    if peak_bytes is not None:
        b = ax[1, 0]
        kb = np.asarray(peak_bytes, float) / 1024.0
        b.plot(kb, ".", ms=3, color="C1")
        b.axhline(tracker_memory_kb, color="C3", ls="--",
                  label=f"tracker {tracker_memory_kb:g} kB")
        b.set_ylabel("peak memory [kB]")
        b.legend(loc="upper right")
    ax[-1, 0].set_xlabel("frame")
    return _save(fig, path)
