"""The sweep's Markdown report: set-up, results per point, figures, comparison with the paper.

The comparison section appears for every point whose exposure time is one of the paper's four
(:data:`starnav.batch.presets.PAPER_CASES`, within 1 %); it prints the paper's statement, the
measured medians over runs, and whether they agree by the stated criteria. Nothing is smoothed:
where the toolkit disagrees with the paper, the report says so.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from starnav.atomic import atomic_write_text
from starnav.batch.presets import PAPER_CITATION, PAPER_MIL_SATURATED, paper_case
from starnav.batch.tasks import TIMED_STAGES
from starnav.config import Scenario, build_camera

if TYPE_CHECKING:
    from starnav.batch.grid import GridAxis, GridPoint


def _g(x: Any, fmt: str = ".3g", scale: float = 1.0) -> str:
    try:
        v = float(x) * scale
    except (TypeError, ValueError):
        return "-"
    return "-" if not math.isfinite(v) else format(v, fmt)


def describe_moon(sc: Scenario) -> str:
    """One line on the scenario's Moon: shape and sources, photometry, albedo, colour."""
    m = sc.moon
    if m.shape == "dem":
        alb = m.dem.albedo.source if m.dem.albedo is not None else "uniform"
        shape = f"DEM {m.dem.source} with albedo map {alb}"
    else:
        shape = m.shape
    phot = m.photometry.model + (f" ({m.photometry.preset})" if m.photometry.model == "hapke"
                                 else "")
    if m.albedo is None:
        albedo = "mean normal albedo: ROLO-calibrated"
    elif isinstance(m.albedo, int | float):
        albedo = f"normal albedo {m.albedo:g}"
    else:
        albedo = f"albedo map {m.albedo.path}"
    return f"{shape}, {phot}, {albedo}, colour {m.photometry.spectral_shape}"


def describe_scenario(sc: Scenario) -> list[str]:
    """Bullet lines describing a scenario's set-up."""
    cam = build_camera(sc.camera)
    m = sc.moon
    lines = [f"- camera: {sc.camera.preset}, {cam.width} x {cam.height} px, f = "
             f"{cam.focal_length * 1e3:.4g} mm, IFOV {cam.ifov * 1e6:.1f} urad",
             f"- Moon: {describe_moon(sc)}; albedo_scale {m.albedo_scale:g}; render "
             f"{sc.render.spp} spp"]
    t = sc.trajectory
    if t is None:
        g = sc.geometry
        lines.append(f"- geometry: static, range {g.range_km:g} km, phase "
                     f"{g.phase_angle_deg:g} deg (no filter: one frame)")
    else:
        lines.append(f"- arc: {t.source}, epoch {t.epoch or 'default'}, {t.duration_days:g} d, "
                     f"an image every {t.cadence_s:g} s"
                     + (f", at most {t.frames} frames" if t.frames else ""))
    n = sc.navigation
    algo = ("windows + subpixel refinement" if n.refine.enabled
            else "pixel-level limb (segments only)")
    bloom = (sc.detector.saturation.blooming.mode if sc.detector.saturation.blooming.enabled
             else "off")
    lines.append(f"- navigation: {algo}, RANSAC {n.ransac.model}, EKF bias model "
                 f"{n.filter.bias_model}, initial "
                 f"1-sigma {n.filter.initial_position_sigma_km:g} km / "
                 f"{n.filter.initial_velocity_sigma_m_s:g} m/s")
    lines.append(f"- detector: order {sc.detector.order}, full well "
                 f"{sc.detector.saturation.full_well_e:g} e-, blooming "
                 f"{bloom}, read noise {sc.detector.signal.read_noise.sigma_e:g} e-; "
                 f"seed {sc.seed}")
    return lines


def paper_comparison(summary: Sequence[dict[str, Any]]) -> list[str]:
    """Markdown lines comparing per-point medians with the paper (empty if no case applies)."""
    rows = []
    criteria = []
    for s in summary:
        c = paper_case(float(s["exposure_time_s"]))
        if c is None:
            continue
        b, sd = float(s.get("limb_bias_px", math.nan)), float(s.get("limb_std_px", math.nan))
        limb_ok = c.limb_ok(b, sd) if math.isfinite(b) else c.exposure_time >= 0.2
        nav_ok = c.navigation_ok(s)
        meas_limb = f"bias {_g(b, '+.2f')} px, std {_g(sd, '.2f')} px"
        meas_nav = (f"{_g(s.get('fixes'), '.0f')}/{_g(s.get('frames'), '.0f')} fixes; final "
                    f"{_g(s.get('final_position_error_m'), '.4g', 1e-3)} km "
                    f"({_g(s.get('final_position_error_pct_range'), '.3g')} %), "
                    f"{_g(s.get('final_velocity_error_m_s'), '.3g')} m/s "
                    f"({_g(s.get('final_velocity_error_pct_speed'), '.3g')} %)")
        verdict = (f"limb {'agrees' if limb_ok else '**differs**'}, navigation "
                   f"{'agrees' if nav_ok else '**differs**'}")
        rows.append(f"| {c.name} | {s['label']} | {c.paper_limb} | {meas_limb} | "
                    f"{c.paper_navigation} | {meas_nav} | {verdict} |")
        if c.criteria not in criteria:
            criteria.append(f"{c.name}: {c.criteria}")
    if not rows:
        return []
    out = ["## Comparison with the paper", "", f"Source: {PAPER_CITATION}.", "",
           "Medians over the Monte Carlo runs of each point. The paper's numbers come from its "
           "HIL bench (7.7 ms, 0.015 ms), from statements (200 ms, 0.18 ms), and are read from "
           "figures; \"agrees\" uses the criteria listed below.", "",
           "| paper case | point | paper: limb | measured limb | paper: navigation | "
           "measured navigation | verdict |", "|---|---|---|---|---|---|---|"]
    out += rows
    out += ["", "Criteria:", ""] + [f"- {c}" for c in dict.fromkeys(criteria)]
    out += ["", f"Context: the paper's {PAPER_MIL_SATURATED}.", "",
            "Caveats: the paper's limb errors are measured on real HIL acquisitions of a "
            "defocused, aberrated optics with the TinyV3RSE collimator; here every detector "
            "effect (PSF, stray light, blooming, crosstalk) is modelled with the assumptions "
            "listed in docs/detector.md, and the Moon is the scenario's (by default the real "
            "Moon: LOLA LDEM_4 terrain, LROC albedo, Hapke photometry calibrated to ROLO "
            "within 2 %). The saturated cases depend most on those assumptions.", ""]
    return out


def consistency_section(summary: Sequence[dict[str, Any]], runs: int,
                        consistency: dict[int, dict[str, Any]]) -> list[str]:
    """Markdown lines: per point, the filter's consistency over the Monte Carlo runs (each run
    its own detector noise, attitude knowledge error and initial error) as
    :func:`~starnav.batch.consistency.consistency_metrics` judges it (``consistency``, by
    point): the time-averaged NEES (6 states) against its band corrected for the NEES
    series' autocorrelation, the position and velocity NEES, the fraction of epochs whose
    run-averaged NEES is inside its 95 % band; the verdict, and the exposures at which the
    filter is not consistent."""
    if runs < 2:
        return ["## Consistency", "",
                "One run per point: no consistency verdict (give `--runs` >= 2).", ""]
    L = ["## Consistency (are the 3-sigma bounds true?)", "",
         f"Over the {runs} runs: the NEES (6 states) averaged over runs and epochs against its "
         "two-sided 99 % band, whose degrees of freedom are those of the runs times the "
         "epochs divided by the NEES series' integrated autocorrelation time (consistent: "
         "inside; above: the filter is overconfident); position and velocity NEES (3 dof "
         "each); the fraction of epochs whose run-averaged NEES is inside the 95 % band of "
         f"a {runs}-run mean (consistent: 95 %). The runs sample detector noise, attitude "
         "knowledge error and initial error; the terrain in view along the arc is the same in "
         "every run, so the verdict is conditional on it (docs/navigation.md, \"Consistency "
         "needs the terrain sampled\").", "",
         "| point | scenario | exposure [ms] | NEES | band | position NEES | velocity NEES | "
         "epochs in 95 % band | verdict |", "|---|---|---|---|---|---|---|---|---|"]
    bad = []
    for s in summary:
        m = consistency.get(int(s["point"]), {})
        head = (f"| {s['point']} | {s['label']} | {_g(s['exposure_time_s'], '.4g', 1e3)} | ")
        if "nees_mean" not in m:
            L.append(head + "- | - | - | - | - | no filter |")
            continue
        if m["verdict"] != "consistent":
            bad.append((float(s["exposure_time_s"]), m["verdict"]))
        lo, hi = m["nees_band"]
        L.append(head + f"{m['nees_mean']:.2f} | {lo:.2f}-{hi:.2f} | "
                 f"{_g(m.get('nees_position', {}).get('mean'), '.2f')} | "
                 f"{_g(m.get('nees_velocity', {}).get('mean'), '.2f')} | "
                 f"{_g(m['nees_steps_in_band'], '.0f', 100)} % | {m['verdict']} |")
    if bad:
        L += ["", "**Not consistent at " + ", ".join(
            f"{t * 1e3:.4g} ms ({v})" for t, v in sorted(bad)) + "**."]
    else:
        L += ["", "**The filter is consistent at every point.**"]
    return L + [""]


def attitude_section(rows: Sequence[dict[str, Any]], summary: Sequence[dict[str, Any]]
                     ) -> list[str]:
    """The attitude side of each point (points that draw the stars): what the navigation
    frame's own stars give at its exposure (lost in space) and the attitude the fixes used
    (empty without stars)."""
    if not any("attitude_source" in r for r in rows):
        return []
    src = {int(r["point"]): r.get("attitude_source", "-") for r in rows}
    L = ["## Attitude (median over runs)", "",
         "The navigation frame's own stars, solved lost in space (centroids with the Moon and "
         "its ghosts excluded, triangle identification, QUEST), and the attitude each fix "
         "used (`navigation.attitude.source`; assumed: the pointing knowledge error and "
         "sigma).", "",
         "| point | exposure [ms] | stars detected | stars identified | solved | frame 1-sigma "
         "cross / roll [arcsec] | frame error cross / roll [arcsec RMS] | fix attitude | its "
         "error cross / roll [arcsec RMS] | its 1-sigma cross / roll [arcsec] |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        if "stars_detected_median" not in s:
            continue
        solved = s.get("frame_attitude_solved_fraction", math.nan)
        L.append(
            f"| {s['point']} | {_g(s['exposure_time_s'], '.4g', 1e3)} | "
            f"{_g(s.get('stars_detected_median'), '.0f')} | "
            f"{_g(s.get('stars_identified_median'), '.0f')} | "
            f"{'yes' if solved == 1 else 'no' if solved == 0 else _g(100 * solved, '.0f') + ' %'}"
            f" | {_g(s.get('frame_attitude_sigma_cross_arcsec'), '.2f')} / "
            f"{_g(s.get('frame_attitude_sigma_roll_arcsec'), '.2f')} | "
            f"{_g(s.get('frame_attitude_error_cross_rms_arcsec'), '.2f')} / "
            f"{_g(s.get('frame_attitude_error_roll_rms_arcsec'), '.2f')} | "
            f"{src.get(int(s['point']), '-')} | "
            f"{_g(s.get('attitude_error_cross_rms_arcsec'), '.2f')} / "
            f"{_g(s.get('attitude_error_roll_rms_arcsec'), '.2f')} | "
            f"{_g(s.get('attitude_sigma_cross_arcsec'), '.2f')} / "
            f"{_g(s.get('attitude_sigma_roll_arcsec'), '.2f')} |")
    return L + [""]


def write_report(path: str | os.PathLike[str], *, base: Scenario, axes: Sequence[GridAxis],
                 points: Sequence[GridPoint], rows: Sequence[dict[str, Any]], runs: int,
                 n_frames: dict[str, int], groups: dict[str, list[GridPoint]], runner: str,
                 elapsed: float, counts: dict[str, int], figures: dict[str, str],
                 title: str | None = None,
                 consistency: dict[int, dict[str, Any]] | None = None) -> Path:
    """Write ``report.md`` (module docstring); ``consistency``: per point,
    :func:`~starnav.batch.consistency.consistency_metrics` of its runs."""
    from starnav.batch.sweep import summarize_points  # lazy: cycle with starnav.batch.sweep

    summary = summarize_points(rows)
    L: list[str] = [f"# {title or 'starnav sweep'}", ""]
    L += ["## Set-up", ""] + describe_scenario(base)
    L += ["- grid: " + "; ".join(f"`{a.key}` = {', '.join(repr(v) for v in a.values)}"
                                  for a in axes),
          f"- {len(points)} point(s) x {runs} Monte Carlo run(s); "
          f"{sum(n_frames.values()) // max(len(n_frames), 1)} frames per point; "
          f"{len(groups)} render group(s): {counts['render']} renders shared by "
          f"{counts['expose']} expose tasks",
          f"- runner: {runner}; wall time {elapsed:.1f} s", ""]
    L += ["## Results (median over runs)", "",
          "| point | scenario | exposure [ms] | saturated px | limb bias [px] | limb std [px] | "
          "fixes | final position error [km] (% range) | final velocity error [m/s] (% speed) |"
          " 3-sigma [km] | readout law |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        L.append(
            f"| {s['point']} | {s['label']} | {_g(s['exposure_time_s'], '.4g', 1e3)} | "
            f"{_g(s.get('saturated_pixels_median'), '.0f')} | "
            f"{_g(s.get('limb_bias_px'), '+.2f')} | {_g(s.get('limb_std_px'), '.2f')} | "
            f"{_g(s.get('fixes'), '.0f')}/{_g(s.get('frames'), '.0f')} | "
            f"{_g(s.get('final_position_error_m'), '.4g', 1e-3)} "
            f"({_g(s.get('final_position_error_pct_range'), '.3g')}) | "
            f"{_g(s.get('final_velocity_error_m_s'), '.3g')} "
            f"({_g(s.get('final_velocity_error_pct_speed'), '.3g')}) | "
            f"{_g(s.get('final_position_3sigma_m'), '.3g', 1e-3)} | "
            f"{'ok' if s['readout_feasible'] else 'infeasible (fictitious)'} |")
    L += ["", "Every run's row is in `results.parquet` / `results.csv` (columns and units: "
          "docs/sweep.md and `sweep.json`).", ""]
    L += attitude_section(rows, summary)
    L += consistency_section(summary, runs, consistency or {})
    L += paper_comparison(summary)
    if figures:
        L += ["## Figures", ""]
        if "limb_error_pdf" in figures:
            L += ["Limb-point error against the true limb, per scenario:", "",
                  f"![limb-point error PDFs]({figures['limb_error_pdf']})", ""]
        if "error_vs_exposure" in figures:
            L += ["Limb bias and final navigation errors against the exposure time:", "",
                  f"![error vs exposure]({figures['error_vs_exposure']})", ""]
        if "attitude_vs_exposure" in figures:
            L += ["The attitude side: stars identified in the navigation frames and the "
                  "attitude 1-sigma they give, against the exposure time:", "",
                  f"![attitude vs exposure]({figures['attitude_vs_exposure']})", ""]
        for p in points:
            k = f"error_vs_time_{p.index:03d}"
            if k in figures:
                L += [f"Navigation error vs time, point {p.index} ({p.label}):", "",
                      f"![error vs time, point {p.index}]({figures[k]})", ""]
    L += ["## Time per stage (median per frame, all points and runs)", "",
          "| stage | median [ms] |", "|---|---|"]
    for st in TIMED_STAGES:
        vals = [float(r[f"time_{st}_s"]) for r in rows
                if r.get(f"time_{st}_s") is not None and math.isfinite(float(r[f"time_{st}_s"]))]
        med = sorted(vals)[len(vals) // 2] if vals else math.nan
        L.append(f"| {st} | {_g(med, '.3g', 1e3)} |")
    L += ["", "Times are wall clock on the workers (not reproducible; every other column is).",
          ""]
    p = Path(path)
    atomic_write_text(p, "\n".join(L))
    return p
