"""The main job (``make demo`` / ``starnav demo``): a LUMIO-arc dataset, navigation, a report.

1. Dataset (:func:`starnav.dataset.generate`) of the demo scenario
   (:func:`starnav.batch.presets.demo_scenario`), exposed at the paper's 0.015 and 7.7 ms with
   its per-exposure settings (:data:`~starnav.batch.presets.DEMO_EXPOSURE_OVERRIDES`); an
   existing dataset of the same scenario is resumed.
2. Navigation per exposure (:func:`starnav.navigation.report.navigate_dataset`), then the
   filter's consistency over :data:`DEMO_RUNS` Monte Carlo runs
   (:func:`starnav.batch.montecarlo.navigate_runs`).
3. Report ``report.md``: set-up, results, the comparison with the paper, the figures (among
   them :data:`FRAME_FIGURE`, one frame rendered next to its DN frames).

Its time budget and measured duration: docs/performance.md.

Index
-----
:func:`main_job`, :data:`DEMO_RUNS`, :data:`FRAME_FIGURE`.
"""

from __future__ import annotations

import logging
import math
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from starnav.atomic import atomic_write_text
from starnav.batch.cluster import open_runner
from starnav.batch.cluster import quiet_logger as _quiet
from starnav.batch.montecarlo import navigate_runs, verdict_line, write
from starnav.batch.presets import (
    DEMO_EXPOSURE_OVERRIDES,
    DEMO_EXPOSURES_S,
    PAPER_CITATION,
    demo_scenario,
    paper_case,
)
from starnav.batch.report import _g, describe_scenario
from starnav.batch.scores import scored_line
from starnav.config import Scenario, scenario_from_dict, write_resolved
from starnav.dataset import DatasetOptions, generate
from starnav.dataset import format as F
from starnav.dataset import open as open_dataset
from starnav.dataset.format import exposure_dirname
from starnav.errors import ConfigError, DataFileError
from starnav.navigation.report import navigate_dataset
from starnav.preview import frame_caption, plot_radiance_and_dn
from starnav.simulate import scene_from_scenario

log = logging.getLogger(__name__)

#: Monte Carlo runs of the consistency check, per exposure.
DEMO_RUNS = 8

#: The report's radiance-next-to-DN figure, relative to the output directory.
FRAME_FIGURE = "figures/frame_radiance_dn.png"


def _num(x: Any) -> float:
    """``x`` as a float, NaN for None (a metric without truth)."""
    return math.nan if x is None else float(x)


def _dataset(sc: Scenario, out: Path, opts: Any, workers: int,
             progress: Callable[[int], None] | None) -> Any:
    with open_runner(workers) as runner:
        try:
            return generate(sc, out, options=opts, resume=True, runner=runner,
                            progress=(lambda d, n: progress(d)) if progress else None)
        except ConfigError as err:
            if err.field != "--resume" or not (out / F.MANIFEST).is_file():
                raise
            log.warning("%s holds a dataset of another scenario; making it again", out)
            shutil.rmtree(out)
            return generate(sc, out, options=opts, runner=runner,
                            progress=(lambda d, n: progress(d)) if progress else None)


def main_job(scenario: Scenario | None = None, out_dir: str | Path = "out/demo",
             progress: Callable[[int, int], None] | None = None, *,
             exposures_s: Sequence[float] = DEMO_EXPOSURES_S,
             exposure_overrides: Sequence[tuple[float, Sequence[str]]] = DEMO_EXPOSURE_OVERRIDES,
             workers: int = 0, overrides: Sequence[str] = (),
             runs: int = DEMO_RUNS) -> dict[str, Any]:
    """Make the demo dataset, navigate it at each exposure, write the report (module steps).

    Parameters
    ----------
    scenario : Scenario, optional
        Default :func:`starnav.batch.presets.demo_scenario`. Needs a ``trajectory``.
    overrides : sequence of str
        ``--set`` items applied to the default demo scenario (ignored with ``scenario``).
    out_dir : path
        Output directory: ``dataset/``, ``navigation/exposure_<ms>ms/``, ``report.md``.
    progress : callable, optional
        ``progress(done, total)``: the dataset's frames, one step per exposure, the report.
    exposures_s : sequence of float
        Exposure times [s]; default the paper's 0.015 ms and 7.7 ms.
    exposure_overrides : sequence of (exposure_time, overrides)
        ``detector.*`` / ``navigation.*`` overrides per exposure; default
        :data:`~starnav.batch.presets.DEMO_EXPOSURE_OVERRIDES`.
    workers : int
        0: this process; N: a local Dask cluster for the dataset.
    runs : int
        Monte Carlo runs of the consistency check per exposure (0 or 1: none).

    Returns
    -------
    dict
        Flat summary: ``report``, ``dataset``, ``frames``, ``dataset_frames_per_s``,
        ``elapsed_s``, and per exposure the limb bias [px], the final position error [km] and
        its fraction of the range [%].
    """
    t0 = time.perf_counter()
    sc = scenario if scenario is not None else scenario_from_dict(demo_scenario(),
                                                                  list(overrides))
    if sc.trajectory is None:
        raise ConfigError("trajectory", None, "a trajectory section (the main job navigates "
                          "along an arc)")
    out = Path(out_dir)
    n = len(scene_from_scenario(sc))
    mc_steps = len(exposures_s) if runs >= 2 else 0
    total = n + len(exposures_s) + mc_steps + 1
    report_progress = (lambda d: progress(d, total)) if progress else None
    opts = DatasetOptions(exposures_s=tuple(exposures_s), exposure_overrides=tuple(
        (float(t), tuple(o)) for t, o in exposure_overrides)).resolved(sc)
    ds_summary = _dataset(sc, out / "dataset", opts, workers, report_progress)
    nav: dict[float, dict[str, Any]] = {}
    t_nav = time.perf_counter()
    for j, t in enumerate(ds_summary.exposures_s):
        data = open_dataset(out / "dataset", exposure=t)
        with _quiet("starnav.navigation.ekf"):
            nav[t] = navigate_dataset(data, out / "navigation" / exposure_dirname(t),
                                      config=opts.scenario_for(sc, t).navigation,
                                      seed=sc.seed, measure_memory=False, plots=True)
        if progress:
            progress(n + j + 1, total)
    consistency: dict[float, dict[str, Any]] = {}
    if runs >= 2:
        for j, t in enumerate(ds_summary.exposures_s):
            data = open_dataset(out / "dataset", exposure=t)
            with _quiet("starnav.navigation.ekf"):
                mc = navigate_runs(data, int(runs), scenario=data.scenario())
            write(out / "navigation" / exposure_dirname(t) / "montecarlo", mc)
            consistency[t] = mc["metrics"]
            if progress:
                progress(n + len(exposures_s) + j + 1, total)
    nav_s = time.perf_counter() - t_nav
    write_resolved(sc, out)
    frame_fig = _frame_figure(out, sc, opts, ds_summary.exposures_s)
    report = _write_report(out, sc, ds_summary, nav, nav_s, time.perf_counter() - t0, opts,
                           frame_fig, consistency)
    if progress:
        progress(total, total)
    summary: dict[str, Any] = {
        "report": str(report),
        "dataset": str(out / "dataset"),
        "frames": ds_summary.frames,
        "dataset_frames_per_s": ds_summary.frames_per_s,
        "elapsed_s": time.perf_counter() - t0,
    }
    for t, s in nav.items():
        key = f"{t * 1e3:.6g} ms"
        summary[f"{key}: limb bias [px]"] = s["limb_error_px"]["bias"]
        summary[f"{key}: final position error [km]"] = _num(s.get("final_position_error_m")) / 1e3
        summary[f"{key}: final position error [% range]"] = _num(
            s.get("final_position_error_pct_range"))
        if t in consistency:
            summary[f"{key}: filter ({runs} runs)"] = consistency[t]["verdict"]
            summary[f"{key}: mean NEES ({runs} runs)"] = consistency[t]["nees_mean"]
    return summary


def _frame_figure(out: Path, sc: Scenario, opts: Any, exposures_s: Sequence[float]
                  ) -> tuple[str, str] | None:
    """Draw the middle frame's rendered radiance next to its DN frames, one per exposure
    (:func:`starnav.preview.plot_radiance_and_dn`); returns the PNG's path relative to ``out``
    and its caption, or None if the dataset holds no frame or no radiance."""
    data = open_dataset(out / "dataset", exposure=exposures_s[0])
    if len(data) == 0:
        return None
    k = len(data) // 2
    frame = data[k]
    try:
        img = frame.radiance()
    except DataFileError as err:
        log.warning("no radiance/DN figure in the report: %s", err)
        return None
    dn = [(f"{t * 1e3:g} ms", data.select(t)[k].dn(),
           2 ** opts.scenario_for(sc, t).detector.adc.bits - 1) for t in exposures_s]
    epoch = frame.entry.get("epoch_tdb_iso")
    title = frame_caption(img.meta, frame.index) + (f" | {epoch}" if epoch else "")
    plot_radiance_and_dn(img, dn, out / FRAME_FIGURE, title=title)
    return FRAME_FIGURE, title


def _write_report(out: Path, sc: Scenario, ds: Any, nav: dict[float, dict[str, Any]],
                  nav_s: float, elapsed: float, opts: Any,
                  frame_fig: tuple[str, str] | None = None,
                  consistency: dict[float, dict[str, Any]] | None = None) -> Path:
    L = ["# starnav main job: can the AA-STR star tracker navigate at the Moon?", "",
         "A LUMIO-like arc rendered in physical units, exposed and read out like the AA-STR "
         "(segments, then windows along the limb), navigated with the limb-based chain "
         "(RANSAC, Christian-Robinson, EKF).", "", "## Set-up", ""]
    L += describe_scenario(sc)
    L += [f"- dataset: `{ds.path}` ({ds.frames} frames, exposures "
          + ", ".join(f"{t * 1e3:g} ms" for t in ds.exposures_s)
          + f"; {ds.frames_made} made in this run at {_g(ds.frames_per_s)} frames/s)",
          f"- wall time: {elapsed:.1f} s (navigation {nav_s:.1f} s)"]
    for t, items in opts.exposure_overrides:
        L.append(f"- {t * 1e3:g} ms: " + ", ".join(f"`{i}`" for i in items))
    L += ["",
          "## Results", "",
          "| exposure [ms] | saturated px (median) | fixes | limb bias [px] | limb std [px] | "
          "final position error [km] (% range) | final velocity error [m/s] | "
          "3-sigma position [km] | chain CPU median [ms] |",
          "|---|---|---|---|---|---|---|---|---|"]
    for t, s in nav.items():
        pe = ds.per_exposure.get(exposure_dirname(t), {})
        L.append(f"| {t * 1e3:g} | {_g(pe.get('saturated_pixels_median'), '.0f')} | "
                 f"{s['fixes']}/{s['frames']} | {_g(s['limb_error_px']['bias'], '+.3f')} | "
                 f"{_g(s['limb_error_px']['std'], '.3f')} | "
                 f"{_g(s.get('final_position_error_m'), '.4g', 1e-3)} "
                 f"({_g(s.get('final_position_error_pct_range'), '.3g')}) | "
                 f"{_g(s.get('final_velocity_error_m_s'), '.3g')} | "
                 f"{_g(s.get('final_position_3sigma_m'), '.3g', 1e-3)} | "
                 f"{_g(s['timing_ms']['chain_cpu_median'], '.3g')} |")
    if consistency:
        runs = next(iter(consistency.values()))["runs"]
        L += ["", f"## Can the 3-sigma bounds be trusted? ({runs} Monte Carlo runs)", "",
              "Each run re-exposes every frame's rendered radiance with its own detector noise, "
              "draws a fresh attitude knowledge error and initial error, and runs the whole "
              "chain and the filter (`starnav navigate DATASET --runs N`; "
              "`navigation/exposure_*/montecarlo/`).", ""]
        for t, m in consistency.items():
            L.append(f"- **{t * 1e3:g} ms**: " + verdict_line(m))
        L += ["", "Every run sees the dataset's one terrain, so these verdicts are conditional on "
              "this arc's terrain. " + scored_line()]
    L += ["", "## Against the paper", "", f"Source: {PAPER_CITATION}.", ""]
    for t, s in nav.items():
        c = paper_case(t)
        if c is None:
            continue
        L.append(f"- **{c.name}**: the paper reports {c.paper_limb} and {c.paper_navigation}; "
                 f"measured here: limb bias {_g(s['limb_error_px']['bias'], '+.2f')} px "
                 f"(std {_g(s['limb_error_px']['std'], '.2f')} px; windows and subpixel "
                 f"refinement on, saturated pixels left out of the fit), final position error "
                 f"{_g(s.get('final_position_error_pct_range'), '.3g')} % of range.")
    L += ["", "The paper's HIL numbers are for its pixel-accuracy algorithm (segments only); the "
          "demo also refines the limb in the windows, which the paper ran only in PIL. "
          "`starnav sweep --preset exposure-study` runs the paper's four exposures with the "
          "pixel-level algorithm and Monte Carlo runs.", "", "## Figures", ""]
    if frame_fig:
        L += ["### One frame: rendered radiance and detector DN", "",
              f"{frame_fig[1]}: the middle frame of the arc as rendered (band radiance, "
              "linear from 0 to the 99.9th percentile of the lit pixels, sRGB-encoded for "
              "display) next to the detector's DN frame of the same epoch at each exposure "
              "(linear from 0 to the ADC full scale, same encoding: saturated pixels are "
              "white).", "",
              f"![rendered radiance and detector DN frames]({frame_fig[0]})", ""]
    for t in nav:
        d = f"navigation/{exposure_dirname(t)}"
        over = sorted(k for k in nav[t].get("paths", {}) if k.startswith("overlay_"))
        L += [f"### {t * 1e3:g} ms", ""]
        if over:
            L += ["Frames as the chain saw them (segments DN; windows, limb points with RANSAC "
                  "inliers and outliers, the fix's limb and the true limb; "
                  f"`{d}/report.md`):", ""]
            L += [f"![{k.replace('_', ' ')}: limb overlay]({d}/{k}.png)" for k in over] + [""]
        L += [f"![limb-point error]({d}/limb_error_pdf.png)", "",
              f"![position error]({d}/position_error.png)", "",
              f"![velocity error]({d}/velocity_error.png)", ""]
        if consistency and t in consistency:
            L += [f"![NEES and NIS over the runs]({d}/montecarlo/consistency.png)", ""]
    L += ["Per-frame estimates: `navigation/exposure_*/estimates.csv`; metrics: "
          "`metrics.json`; the dataset's format: docs/dataset.md.", ""]
    p = out / "report.md"
    atomic_write_text(p, "\n".join(L))
    return p
