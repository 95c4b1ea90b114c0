"""Navigation with the tracker's own attitude next to the assumed one, at the demo's exposures.

1. Scenario: the demo's (or :func:`reduced_demo`) with the stars drawn, per-exposure overrides.
2. Frames rendered once; at each exposure exposed and the star attitude tracker
   (:class:`~starnav.simulate.attitude.StarAttitudeTracker`) run on its schedule.
3. Navigation twice per exposure on the same frames and seeds: (a) *assumed* attitude error
   and sigma; (b) *stars*: the solved or propagated attitude and its covariance.
4. Metrics per case: fixes, final position error, mean NEES with its 95 % band (a single run's
   indication, not a Monte Carlo verdict), attitude errors and NEES, the attitude sources.

:func:`comparison_markdown` writes the table (numbers: docs/stars.md).

Index
-----
:func:`attitude_comparison`, :func:`comparison_markdown`, :func:`attitude_monte_carlo`,
:func:`monte_carlo_markdown`, :func:`reduced_demo`, :func:`exposure_scenario`.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2

from starnav.batch.consistency import terrain_offsets_deg
from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES, DEMO_EXPOSURES_S, demo_scenario
from starnav.batch.runs import over_runs
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import apply_overrides
from starnav.errors import ConfigError
from starnav.navigation.dynamics import PointMassDynamics
from starnav.navigation.metrics import chi2_band, nees
from starnav.navigation.pipeline import navigate
from starnav.simulate.attitude import (
    SOURCES,
    StarAttitudeTracker,
    assumed_covariance,
    with_attitude,
)
from starnav.simulate.build import chain_options
from starnav.simulate.frames import Simulator
from starnav.stars.attitude import ARCSEC, error_rotation

log = logging.getLogger(__name__)

#: Two-sided probability of the NEES bands.
BAND_PROBABILITY = 0.95
#: The demo's image side and the Moon's largest offset from the centre [px].
DEMO_SIZE_PX, DEMO_OFFSET_PX = 1024, 300.0


def reduced_demo(frames: int = 4, size_px: int = 512, spp: int = 4) -> dict[str, Any]:
    """The demo scenario on ``frames`` frames of its arc (same cadence), a ``size_px`` square
    image with the AA-STR's focal length and pixels (a smaller field: fewer stars; at 512 px
    ~10 deg, ~20 stars to V 6.5) and the Moon's offset scaled with it, rendered at ``spp``."""
    if not (isinstance(frames, int) and frames >= 2):
        raise ConfigError("frames", frames, "an integer >= 2")
    if not (isinstance(size_px, int) and 128 <= size_px <= DEMO_SIZE_PX):
        raise ConfigError("size_px", size_px, f"an integer in [128, {DEMO_SIZE_PX}]")
    d = demo_scenario()
    cad = float(d["trajectory"]["cadence_s"])
    d["trajectory"]["duration_days"] = (frames - 1) * cad / 86400.0
    d["camera"]["width"] = d["camera"]["height"] = size_px
    d["pointing"]["moon_offset_max_px"] = DEMO_OFFSET_PX * size_px / DEMO_SIZE_PX
    d["render"]["spp"] = int(spp)
    return d


def _band(dof: int, k: int) -> tuple[float, float]:
    a = (1.0 - BAND_PROBABILITY) / 2.0
    lo, hi = chi2.ppf([a, 1.0 - a], dof * k) / k
    return float(lo), float(hi)


def _attitude_stats(errors: np.ndarray, covs: np.ndarray) -> dict[str, Any]:
    e = errors / ARCSEC
    s = np.sqrt(np.einsum("kii->ki", covs)) / ARCSEC
    n = np.array([float(x @ np.linalg.solve(P, x)) for x, P in zip(errors, covs, strict=True)])
    lo, hi = _band(3, len(n))
    return {"error_cross_rms_arcsec": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))),
            "error_roll_rms_arcsec": float(np.sqrt(np.mean(e[:, 2] ** 2))),
            "sigma_cross_mean_arcsec": float(np.mean(np.hypot(s[:, 0], s[:, 1]))),
            "sigma_roll_mean_arcsec": float(np.mean(s[:, 2])),
            "nees_mean": float(np.mean(n)), "nees_band": [lo, hi]}


def _nav_stats(run: Any) -> dict[str, Any]:
    m = run.metrics()
    k = int(m.frames)
    lo, hi = _band(6, k)
    out = {"frames": k, "fixes": int(m.fixes), "accepted": int(m.accepted),
           "final_position_error_m": float(m.final_position_error_m),
           "final_position_error_pct_range": float(m.final_position_error_pct_range),
           "nees_mean": float(m.nees_mean), "nees_band": [lo, hi],
           "nees_in_band": bool(lo <= m.nees_mean <= hi)}
    if run.truth is not None:
        # per step: the whole NEES (6 states) and its position and velocity blocks (3 each)
        e = run.filter.errors(run.truth)
        P = run.filter.covariances[:, :6, :6]
        out["nees_per_step"] = np.asarray(nees(e, P), float).tolist()
        out["nees_position_per_step"] = np.asarray(nees(e[:, :3], P[:, :3, :3]),
                                                   float).tolist()
        out["nees_velocity_per_step"] = np.asarray(nees(e[:, 3:], P[:, 3:, 3:]),
                                                   float).tolist()
    return out


def _fix_stats(run: Any, geoms: Sequence[Any]) -> dict[str, Any]:
    """Per frame, the limb fix's own NEES (3 dof) against the true Moon-relative position:
    with its whole covariance and with its ``white`` part alone (pixel noise and attitude:
    the ``limb-common`` filter's measurement noise); the error along the line of sight
    (range) and across it [m] (NaN without a fix)."""
    out: dict[str, list[float]] = {"fix_nees_per_step": [], "fix_nees_white_per_step": [],
                                   "fix_error_range_m": [], "fix_error_cross_m": []}
    for m, g in zip(run.measurements, geoms, strict=True):
        if m.position is None or m.covariance is None:
            for v in out.values():
                v.append(math.nan)
            continue
        e = np.asarray(m.position, float) - np.asarray(g.camera_position, float)
        out["fix_nees_per_step"].append(float(e @ np.linalg.solve(m.covariance, e)))
        W = m.white_covariance
        out["fix_nees_white_per_step"].append(
            math.nan if W is None else float(e @ np.linalg.solve(W, e)))
        los = -np.asarray(g.camera_position, float)
        los /= np.linalg.norm(los)
        out["fix_error_range_m"].append(float(-e @ los))
        out["fix_error_cross_m"].append(float(np.linalg.norm(e - (e @ los) * los)))
    return out


def exposure_scenario(base: dict[str, Any], exposure_time: float,
                      exposure_overrides: Sequence[tuple[float, Sequence[str]]],
                      attitude: dict[str, Any]) -> Scenario:
    """``base`` at ``exposure_time`` [s] with that exposure's overrides, the stars on and
    ``navigation.attitude`` = ``{source: stars, **attitude}`` (validated)."""
    d = apply_overrides(base, [f"detector.exposure_time_s={exposure_time!r}"])
    for t, ov in exposure_overrides:
        if math.isclose(float(t), exposure_time, rel_tol=1e-6):
            d = apply_overrides(d, ov)
    d.setdefault("stars", {})["enabled"] = True
    d["navigation"]["attitude"] = {**d["navigation"].get("attitude", {}), **attitude,
                                   "source": "stars"}
    return scenario_from_dict(d)


def attitude_comparison(
    scenario: Scenario | dict[str, Any],
    *,
    exposures_s: Sequence[float] = DEMO_EXPOSURES_S,
    exposure_overrides: Sequence[tuple[float, Sequence[str]]] = DEMO_EXPOSURE_OVERRIDES,
    attitude: dict[str, Any] | None = None,
    run: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Navigate the scenario's frames at each exposure with the assumed and with the solved
    attitude (module steps 1-4).

    Parameters
    ----------
    scenario : Scenario or dict
        Needs a ``trajectory`` (an arc to filter over).
    exposures_s, exposure_overrides : sequences
        Navigation exposures [s] and their ``a.b=value`` overrides (default the demo's).
    attitude : dict, optional
        ``navigation.attitude`` keys for the solved case (``star_exposure_s``,
        ``schedule_every``, ``navigation_frames``, ``gyro_*``); ``source`` is set to stars.
    run : int
        Monte Carlo run (its noise, knowledge error, gyro and initial error streams).
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    dict
        ``cases``: one dict per (exposure, case) with ``navigation`` and ``attitude`` metrics;
        ``records``: the solved case's per-frame attitude rows per exposure; ``settings``;
        ``wall_time_s``.
    """
    base = scenario_to_dict(scenario) if isinstance(scenario, Scenario) else \
        scenario_to_dict(scenario_from_dict(scenario))
    if base.get("trajectory") is None:
        raise ConfigError("trajectory", None, "an arc (the comparison filters over frames)")
    if not exposures_s:
        raise ConfigError("exposures_s", list(exposures_s), "at least one exposure [s]")
    for t in exposures_s:
        if not (isinstance(t, int | float) and math.isfinite(t) and t > 0):
            raise ConfigError("exposures_s", t, "exposure times > 0 s")
    att = dict(attitude or {})
    scs = [exposure_scenario(base, float(t), exposure_overrides, att) for t in exposures_s]
    t_start = time.perf_counter()
    sim = Simulator(scs[0])
    trackers = [StarAttitudeTracker(sim, run, sc) for sc in scs]  # validates before rendering
    chains = [chain_options(sc) for sc in scs]
    K = len(sim)
    frames_a: list[list[Any]] = [[] for _ in scs]
    frames_s: list[list[Any]] = [[] for _ in scs]
    chains_s: list[list[Any]] = [[] for _ in scs]
    assumed_err: list[list[np.ndarray]] = [[] for _ in scs]
    records: list[list[Any]] = [[] for _ in scs]
    geoms = []
    for k in range(K):
        geom, img = sim.render(k)
        geoms.append(geom)
        for j, (sc, tr, ch) in enumerate(zip(scs, trackers, chains, strict=True)):
            obs = sim.observe(img, geom, run=run, exposure_time=float(sc.detector.exposure_time_s),
                              scenario=sc)
            rec = tr.step(img, geom, obs.acquisition, ch)
            f_s, c_s = with_attitude(obs.frame, ch, rec)
            frames_a[j].append(obs.frame)
            assumed_err[j].append(error_rotation(obs.frame.R_cam_to_inertial_measured,
                                                 geom.R_cam_to_inertial))
            frames_s[j].append(f_s)
            chains_s[j].append(c_s)
            records[j].append(rec)
        if progress is not None:
            progress(k + 1, K)
    cases, rec_rows = [], {}
    for j, sc in enumerate(scs):
        nav = sc.navigation
        dyn = PointMassDynamics(step_s=nav.filter.to_si().rk4_step)
        common = dict(camera=sim.camera, dynamics=dyn, moon=dyn, P0=nav.initial_covariance(),
                      ekf=nav.filter.to_si(), ekf_priors=nav.ekf_priors(
                          chains[j].calibration, float(sc.detector.exposure_time_s)),
                      seed=int(sc.seed),
                      run=run)
        ra = navigate(frames_a[j], chain=chains[j], **common)
        rs = navigate(frames_s[j], chains=chains_s[j], **common)
        t_exp = float(sc.detector.exposure_time_s)
        P_a = np.repeat(assumed_covariance(chains[j])[None], K, axis=0)
        cases.append({"exposure_s": t_exp, "case": "assumed",
                      "navigation": {**_nav_stats(ra), **_fix_stats(ra, geoms)},
                      "attitude": _attitude_stats(np.array(assumed_err[j]), P_a)})
        recs = records[j]
        st = _attitude_stats(np.array([r.error_rad for r in recs]),
                             np.array([r.covariance_rad2 for r in recs]))
        st["sources"] = {s: sum(r.source == s for r in recs) for s in SOURCES}
        cases.append({"exposure_s": t_exp, "case": "stars",
                      "navigation": {**_nav_stats(rs), **_fix_stats(rs, geoms)},
                      "attitude": st})
        rec_rows[f"{t_exp:.6g}"] = [r.summary() for r in recs]
    a = scs[0].navigation.attitude
    return {"cases": cases, "records": rec_rows, "frames": K,
            "settings": {"star_exposure_s": a.star_exposure_s,
                         "schedule_every": a.schedule_every,
                         "navigation_frames": a.navigation_frames,
                         "gyro_arw_deg_rt_h": a.gyro_arw_deg_rt_h,  # unit: quoted back
                         "gyro_bias_deg_h": a.gyro_bias_deg_h,  # unit: quoted back
                         "image_px": [sim.camera.width, sim.camera.height]},
            "wall_time_s": time.perf_counter() - t_start}


def _f(x: float, spec: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def comparison_markdown(result: dict[str, Any]) -> str:
    """The comparison as a Markdown table, with the solved case's sources and the reasons the
    star solves failed (first of each kind)."""
    s = result["settings"]
    L = [f"Attitude: assumed vs solved from the stars ({result['frames']} frames, "
         f"{s['image_px'][0]} x {s['image_px'][1]} px; star acquisitions at "
         f"{s['star_exposure_s'] * 1e3:.4g} ms every {s['schedule_every']} frame(s); gyro ARW "
         f"{s['gyro_arw_deg_rt_h']:g} deg/sqrt(h), bias {s['gyro_bias_deg_h']:g} deg/h)", "",
         "| exposure | attitude | fixes | final error [% range] | NEES mean [95 % band] | "
         "att. error cross / roll [arcsec RMS] | predicted 1-sigma cross / roll [arcsec] | "
         "att. NEES [band] | sources |",
         "|---|---|---|---|---|---|---|---|---|"]
    for c in result["cases"]:
        n, a = c["navigation"], c["attitude"]
        src = ", ".join(f"{k} {v}" for k, v in a.get("sources", {}).items() if v) or "-"
        L.append(f"| {c['exposure_s'] * 1e3:.4g} ms | {c['case']} | {n['fixes']}/{n['frames']} "
                 f"| {_f(n['final_position_error_pct_range'], '.3g')} | "
                 f"{_f(n['nees_mean'], '.2f')} [{n['nees_band'][0]:.2f}-{n['nees_band'][1]:.2f}]"
                 f" | {_f(a['error_cross_rms_arcsec'], '.2f')} / "
                 f"{_f(a['error_roll_rms_arcsec'], '.2f')} | "
                 f"{_f(a['sigma_cross_mean_arcsec'], '.2f')} / "
                 f"{_f(a['sigma_roll_mean_arcsec'], '.2f')} | {_f(a['nees_mean'], '.2f')} "
                 f"[{a['nees_band'][0]:.2f}-{a['nees_band'][1]:.2f}] | {src} |")
    L.append("")
    for key, rows in result["records"].items():
        seen: dict[str, str] = {}
        for r in rows:
            for why in r["reasons"]:
                seen.setdefault(why.split(":")[0], f"frame {r['frame']}: {why}")
        for why in seen.values():
            L.append(f"- {float(key) * 1e3:.4g} ms: {why}")
    return "\n".join(L) + "\n"


# ----------------------------------------------------------------------------- Monte Carlo
#: Two-sided probability of the Monte Carlo NEES bands.
MC_BAND_PROBABILITY = 0.99


def _nanmean(x: Any, axis: int | None = None) -> Any:
    """``np.nanmean``, NaN without a warning where every value is NaN (a case without white
    fix covariances: the saturated frames' range-scale model)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(np.asarray(x, float), axis=axis)


def _verdict(x: float, band: Sequence[float]) -> str:
    if not math.isfinite(x):
        return "no truth"
    return "consistent" if band[0] <= x <= band[1] else (
        "overconfident" if x > band[1] else "pessimistic")


def attitude_monte_carlo(
    scenario: Scenario | dict[str, Any],
    runs: int,
    *,
    exposures_s: Sequence[float] = DEMO_EXPOSURES_S,
    exposure_overrides: Sequence[tuple[float, Sequence[str]]] = DEMO_EXPOSURE_OVERRIDES,
    attitude: dict[str, Any] | None = None,
    terrain: bool = True,
    probability: float = MC_BAND_PROBABILITY,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """The comparison (:func:`attitude_comparison`) over ``runs`` Monte Carlo runs, each on
    its own terrain: is the filter consistent with the assumed and with the solved attitude?

    Run ``r`` is ``attitude_comparison(scenario, run=r)`` with the Moon's DEM and albedo
    turned about the pole by :func:`starnav.batch.consistency.terrain_offsets_deg`'s angle
    ``r`` (run 0: the Moon as it is), so that the runs also sample the lit-terrain limb
    error; without it the verdict is conditional on the arc's one terrain (docs/navigation.md,
    "Consistency needs the terrain sampled").

    Verdict per exposure and case: the mean over runs of each run's mean NEES (6 states)
    against the two-sided ``probability`` band of an ``R``-run mean of chi2(6)
    (:func:`~starnav.navigation.metrics.chi2_band`); a run's time mean of correlated steps has
    at most the variance of one chi2(6) sample, so the band is conservative. The position,
    velocity and attitude NEES (3 dof each) are judged the same way.

    Parameters
    ----------
    scenario : Scenario or dict
        Needs a ``trajectory`` and, with ``terrain``, ``moon.shape: dem``.
    runs : int
        Monte Carlo runs (>= 2).
    exposures_s, exposure_overrides, attitude :
        As :func:`attitude_comparison`.
    terrain : bool
        Each run on its own terrain (default). ``False``: noise runs on the arc's terrain.
    probability : float
        Two-sided probability of the bands.
    progress : callable, optional
        ``progress(done, total)`` after each run.

    Returns
    -------
    dict
        ``cases``: per (exposure, case) the run-averaged NEES (whole, position, velocity) with
        bands and verdicts, per step and per run, the final position error per run, the
        attitude's NEES and errors and sources; ``terrain_offsets_deg``, ``frames``, ``runs``,
        ``settings``, ``run_wall_times_s``, ``wall_time_s``.
    """
    if not (isinstance(runs, int) and runs >= 2):
        raise ConfigError("runs", runs, "an integer >= 2 (a Monte Carlo verdict needs runs)")
    if not (0.0 < probability < 1.0):
        raise ConfigError("probability", probability, "a probability in (0, 1)")
    sc = scenario if isinstance(scenario, Scenario) else scenario_from_dict(scenario)
    if terrain and sc.moon.shape != "dem":
        raise ConfigError("moon.shape", sc.moon.shape, "'dem' for terrain realisations")
    base = scenario_to_dict(sc)
    offsets = terrain_offsets_deg(int(sc.seed), runs) if terrain else [0.0] * runs
    t_start = time.perf_counter()

    def one_run(r: int) -> dict[str, Any]:
        d = (base if offsets[r] == 0.0 else
             apply_overrides(base, [f"moon.dem.longitude_offset_deg={offsets[r]!r}"]))
        res = attitude_comparison(d, exposures_s=exposures_s,
                                  exposure_overrides=exposure_overrides, attitude=attitude,
                                  run=r)
        log.info("attitude Monte Carlo: run %d/%d (terrain %+.1f deg) in %.1f s", r + 1, runs,
                 offsets[r], float(res["wall_time_s"]))
        return res

    results = over_runs(one_run, runs, progress=progress)
    walls = [float(res["wall_time_s"]) for res in results]
    band6 = chi2_band(6, runs, probability)
    band3 = chi2_band(3, runs, probability)
    cases = []
    for i, c0 in enumerate(results[0]["cases"]):
        per = [res["cases"][i] for res in results]
        nav = [c["navigation"] for c in per]
        att = [c["attitude"] for c in per]
        step = {k: np.array([n[k] for n in nav], float)
                for k in ("nees_per_step", "nees_position_per_step", "nees_velocity_per_step")}
        run_mean = {k: v.mean(axis=1) for k, v in step.items()}
        m6, mp, mv = (float(run_mean[k].mean()) for k in step)
        fix = {k: np.array([n[k] for n in nav], float)
               for k in ("fix_nees_per_step", "fix_nees_white_per_step", "fix_error_range_m",
                         "fix_error_cross_m")}
        fe = np.array([n["final_position_error_m"] for n in nav], float)
        fp = np.array([n["final_position_error_pct_range"] for n in nav], float)
        an = np.array([a["nees_mean"] for a in att], float)
        sources: dict[str, int] = {}
        for a in att:
            for k, v in a.get("sources", {}).items():
                sources[k] = sources.get(k, 0) + int(v)
        cases.append({
            "exposure_s": c0["exposure_s"], "case": c0["case"],
            "fixes": int(sum(n["fixes"] for n in nav)),
            "nees_mean": m6, "nees_band": list(band6), "verdict": _verdict(m6, band6),
            "nees_position_mean": mp, "nees_velocity_mean": mv, "nees_band_3dof": list(band3),
            "verdict_position": _verdict(mp, band3), "verdict_velocity": _verdict(mv, band3),
            "nees_per_run": run_mean["nees_per_step"].tolist(),
            "nees_per_step": step["nees_per_step"].mean(axis=0).tolist(),
            "nees_position_per_step": step["nees_position_per_step"].mean(axis=0).tolist(),
            "nees_velocity_per_step": step["nees_velocity_per_step"].mean(axis=0).tolist(),
            "fix_nees_mean": float(_nanmean(fix["fix_nees_per_step"])),
            "fix_nees_white_mean": float(_nanmean(fix["fix_nees_white_per_step"])),
            "fix_nees_per_step": _nanmean(fix["fix_nees_per_step"], axis=0).tolist(),
            "fix_nees_white_per_step": _nanmean(fix["fix_nees_white_per_step"],
                                                  axis=0).tolist(),
            "fix_error_range_rms_m": float(np.sqrt(_nanmean(fix["fix_error_range_m"] ** 2))),
            "fix_error_cross_rms_m": float(np.sqrt(_nanmean(fix["fix_error_cross_m"] ** 2))),
            "final_position_error_m": {"median": float(np.median(fe)), "max": float(fe.max()),
                                       "per_run": fe.tolist()},
            "final_position_error_pct_range": {"median": float(np.median(fp)),
                                               "max": float(fp.max())},
            "attitude": {"nees_mean": float(an.mean()), "nees_band": list(band3),
                         "verdict": _verdict(float(an.mean()), band3),
                         "error_cross_rms_arcsec": float(np.sqrt(np.mean(
                             [a["error_cross_rms_arcsec"] ** 2 for a in att]))),
                         "error_roll_rms_arcsec": float(np.sqrt(np.mean(
                             [a["error_roll_rms_arcsec"] ** 2 for a in att]))),
                         "sigma_cross_mean_arcsec": float(np.mean(
                             [a["sigma_cross_mean_arcsec"] for a in att])),
                         "sigma_roll_mean_arcsec": float(np.mean(
                             [a["sigma_roll_mean_arcsec"] for a in att])),
                         "sources": sources}})
    return {"cases": cases, "runs": runs, "frames": results[0]["frames"],
            "probability": probability, "terrain": bool(terrain),
            "terrain_offsets_deg": offsets, "settings": results[0]["settings"],
            "run_wall_times_s": walls, "wall_time_s": time.perf_counter() - t_start}


def monte_carlo_markdown(result: dict[str, Any]) -> str:
    """The Monte Carlo verdict (:func:`attitude_monte_carlo`) as a Markdown table."""
    s = result["settings"]
    p = 100 * result["probability"]
    L = [f"Attitude Monte Carlo: {result['runs']} runs"
         f"{' each on its own terrain' if result['terrain'] else ' (one terrain)'}, "
         f"{result['frames']} frames, {s['image_px'][0]} x {s['image_px'][1]} px; star "
         f"acquisitions at {s['star_exposure_s'] * 1e3:.4g} ms every {s['schedule_every']} "
         f"frame(s); bands: two-sided {p:g} % of an {result['runs']}-run mean", "",
         "| exposure | attitude | NEES (6) [band] | verdict | position / velocity NEES (3) "
         "[band] | final error median / max [% range] | att. error cross / roll [arcsec RMS] "
         "| att. NEES (3) | sources |",
         "|---|---|---|---|---|---|---|---|---|"]
    for c in result["cases"]:
        b, b3, a = c["nees_band"], c["nees_band_3dof"], c["attitude"]
        fp = c["final_position_error_pct_range"]
        src = ", ".join(f"{k} {v}" for k, v in a["sources"].items() if v) or "-"
        L.append(f"| {c['exposure_s'] * 1e3:.4g} ms | {c['case']} | {c['nees_mean']:.2f} "
                 f"[{b[0]:.2f}-{b[1]:.2f}] | {c['verdict']} | {c['nees_position_mean']:.2f} / "
                 f"{c['nees_velocity_mean']:.2f} [{b3[0]:.2f}-{b3[1]:.2f}] | "
                 f"{_f(fp['median'], '.3g')} / {_f(fp['max'], '.3g')} | "
                 f"{_f(a['error_cross_rms_arcsec'], '.2f')} / "
                 f"{_f(a['error_roll_rms_arcsec'], '.2f')} | {_f(a['nees_mean'], '.2f')} | "
                 f"{src} |")
    return "\n".join(L) + "\n"
