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
:func:`plot_limb_overlay`              (none) one frame: segments DN, windows, limb points
                                       (RANSAC inliers / outliers), fitted and true limb
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
from starnav.camera import Camera
from starnav.geometry import FrameGeometry
from starnav.navigation.christian_robinson import ellipsoid_limb_points, shape_transform
from starnav.navigation.frames import NavFrame
from starnav.navigation.metrics import ErrorSummary, chi2_band, error_pdf
from starnav.navigation.pipeline import FrameMeasurement
from starnav.quicklook import asinh_stretch, quicklook_levels
from starnav.timeaxis import elapsed_axis
from starnav.typing import FloatArray

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


# ============================================================================ limb overlay
def fitted_limb_polyline(camera: Camera, centre_camera: ArrayLike, radii_m: ArrayLike,
                         R_body_to_cam: ArrayLike | None = None, n: int = 720) -> FloatArray:
    """The limb of the body at ``centre_camera`` [m, camera frame] as seen through the lens:
    ``(m, 2)`` distorted pixels [px], a closed polyline (the first point repeated last).

    The exact limb of the ellipsoid (:func:`~starnav.navigation.christian_robinson.
    ellipsoid_limb_points`); for a fix, ``centre_camera`` is the fix's, for the truth, the true
    centre in the true camera frame. Its undistorted points lie on
    :func:`~starnav.navigation.christian_robinson.limb_conic_pixels` (tested to 0.1 px).
    """
    B = shape_transform(radii_m, R_body_to_cam)
    pts = ellipsoid_limb_points(camera, np.asarray(centre_camera, float), B, n=n, distort=True)
    return np.vstack([pts, pts[:1]]) if len(pts) else pts


def true_limb_polyline(camera: Camera, truth: FrameGeometry, radii_m: ArrayLike,
                       n: int = 720) -> FloatArray:
    """The true limb of a frame, distorted pixels [px] (:func:`fitted_limb_polyline` at the
    true centre, in the true camera frame)."""
    R_b2c = truth.R_cam_to_inertial.T @ truth.R_body_to_inertial
    return fitted_limb_polyline(camera, truth.moon_centre_camera(), radii_m, R_b2c, n)


def plot_limb_overlay(frame: NavFrame, measurement: FrameMeasurement, camera: Camera,
                      path: str | os.PathLike[str], *, radii_m: ArrayLike,
                      margin_px: float = 20.0) -> Path:
    """One frame as the chain saw it, with what the chain made of it.

    Drawn: the segments readout as a DN image (what the tracker sends; pixels outside every
    run are 0), asinh-stretched (:func:`starnav.quicklook.asinh_stretch`); the windows
    (rectangles); the pixel-level limb points, RANSAC inliers and outliers apart; the refined
    (subpixel) points; the fitted limb (the Christian-Robinson fix's limb,
    :func:`fitted_limb_polyline`) and the true limb (:func:`true_limb_polyline`). Axes in
    pixels (``u`` column, ``v`` row, pixel centres at integers), cropped to the Moon plus
    ``margin_px``.
    """
    from matplotlib.patches import Rectangle

    seg = frame.segments
    img = seg.to_image() if seg is not None else np.zeros((camera.height, camera.width),
                                                          np.uint16)
    lo, hi = quicklook_levels(img, black=0.0)
    fig, ax = _figure(1, 1, (7.0, 6.6))
    a = ax[0, 0]
    a.imshow(asinh_stretch(img, lo, hi), cmap="gray", vmin=0, vmax=255,
             interpolation="nearest", origin="upper")
    shown: list[FloatArray] = []
    for k, w in enumerate(frame.windows):
        a.add_patch(Rectangle((w.col0 - 0.5, w.row0 - 0.5), w.width, w.height, fill=False,
                              ec="C1", lw=0.9, label="windows" if k == 0 else None))
        shown.append(np.array([[w.col0, w.row0], [w.col0 + w.width, w.row0 + w.height]]))
    m = measurement
    if m.limb is not None and len(m.limb.uv):
        uv = m.limb.uv
        inl = m.inliers if m.inliers is not None else np.ones(len(uv), bool)
        a.plot(uv[inl, 0], uv[inl, 1], ".", ms=3, color="C2", label="limb points: inliers")
        if np.any(~inl):
            a.plot(uv[~inl, 0], uv[~inl, 1], "x", ms=4, color="C3",
                   label="limb points: RANSAC outliers")
        shown.append(uv)
    if m.refined is not None and len(m.refined.uv):
        a.plot(m.refined.uv[:, 0], m.refined.uv[:, 1], "+", ms=4, color="C9",
               label="refined points (windows)")
    if m.fix is not None:
        R_ci = np.asarray(frame.R_cam_to_inertial_measured, float)
        R_mi = getattr(frame, "R_body_to_inertial", None)
        R_b2c = None if R_mi is None else R_ci.T @ np.asarray(R_mi, float)
        fit = fitted_limb_polyline(camera, m.fix.centre_camera, radii_m, R_b2c)
        a.plot(fit[:, 0], fit[:, 1], "-", lw=1.0, color="C0", label="fitted limb (fix)")
    if frame.truth is not None:
        tru = true_limb_polyline(camera, frame.truth, radii_m)
        a.plot(tru[:, 0], tru[:, 1], "--", lw=1.0, color="m", label="true limb")
        shown.append(tru)
    if shown:
        allp = np.vstack(shown)
        u0, v0 = allp.min(axis=0) - margin_px
        u1, v1 = allp.max(axis=0) + margin_px
        a.set_xlim(max(u0, -0.5), min(u1, camera.width - 0.5))
        a.set_ylim(min(v1, camera.height - 0.5), max(v0, -0.5))
    a.set_xlabel("u (column) [px]")
    a.set_ylabel("v (row) [px]")
    a.set_title(f"frame {frame.index}: {m.status}"
                + (f" ({m.message})" if m.message else "")
                + f"\nsegments DN, asinh stretch 0..{hi:.0f} DN", fontsize=9)
    a.legend(fontsize=7, loc="upper right", framealpha=0.8)
    return _save(fig, path)
