"""Navigation with the tracker's own attitude next to the assumed one, at the demo's exposures.

Technique
---------
1. **Scenario.** The demo's (:func:`starnav.batch.presets.demo_scenario`, or
   :func:`reduced_demo`: fewer frames, a smaller image, fewer samples) with the stars drawn
   (``stars.enabled``, in both cases: the two cases see the same frames) and each exposure's
   overrides (:data:`~starnav.batch.presets.DEMO_EXPOSURE_OVERRIDES`).
2. **Frames.** Every frame is rendered once; at each exposure it is exposed (segments +
   windows, :meth:`~starnav.simulate.frames.Simulator.observe`) and the star attitude tracker
   (:class:`~starnav.simulate.attitude.StarAttitudeTracker`) takes its star acquisition on the
   schedule, tries the navigation frame's own stars, or propagates by the gyro.
3. **Navigation, twice per exposure** (same frames, same seeds): (a) *assumed*: the frame's
   attitude knowledge error (``pointing.knowledge_*``) and the fix's assumed sigma; (b)
   *stars*: the solved or propagated attitude and its 3x3 covariance in each fix.
4. **Metrics** per case: fixes, final position error (% of range), mean NEES of the 6 states
   with its two-sided 95 % band ``chi2(6K)/K`` (K steps treated as independent: a single run's
   indication, not a Monte Carlo verdict), the attitude errors (RMS cross-boresight and roll
   [arcsec]) with the predicted 1-sigma and the attitude NEES (3 dof) against ``chi2(3K)/K``;
   for (b) the attitude sources per frame and why the better ones failed.

:func:`comparison_markdown` writes the table (``benchmarks/stars.py --navigation`` prints it
for the reduced demo; docs/stars.md holds the measured numbers).

Example
-------
>>> res = attitude_comparison(reduced_demo(frames=4, size_px=512))      # doctest: +SKIP
>>> print(comparison_markdown(res))                                     # doctest: +SKIP
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2

from starnav.batch.presets import DEMO_EXPOSURE_OVERRIDES, DEMO_EXPOSURES_S, demo_scenario
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import apply_overrides
from starnav.errors import ConfigError
from starnav.navigation.dynamics import PointMassDynamics
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
    return {"frames": k, "fixes": int(m.fixes), "accepted": int(m.accepted),
            "final_position_error_m": float(m.final_position_error_m),
            "final_position_error_pct_range": float(m.final_position_error_pct_range),
            "nees_mean": float(m.nees_mean), "nees_band": [lo, hi],
            "nees_in_band": bool(lo <= m.nees_mean <= hi)}


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
    exposures_s : sequence of float
        Navigation exposures [s] (default the demo's: 0.015 ms and 7.7 ms).
    exposure_overrides : sequence of (exposure, overrides)
        Per-exposure ``a.b=value`` overrides (default the demo's).
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
    for k in range(K):
        geom, img = sim.render(k)
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
                      ekf=nav.ekf_options(), seed=int(sc.seed), run=run)
        ra = navigate(frames_a[j], chain=chains[j], **common)
        rs = navigate(frames_s[j], chains=chains_s[j], **common)
        t_exp = float(sc.detector.exposure_time_s)
        P_a = np.repeat(assumed_covariance(chains[j])[None], K, axis=0)
        cases.append({"exposure_s": t_exp, "case": "assumed", "navigation": _nav_stats(ra),
                      "attitude": _attitude_stats(np.array(assumed_err[j]), P_a)})
        recs = records[j]
        st = _attitude_stats(np.array([r.error_rad for r in recs]),
                             np.array([r.covariance_rad2 for r in recs]))
        st["sources"] = {s: sum(r.source == s for r in recs) for s in SOURCES}
        cases.append({"exposure_s": t_exp, "case": "stars", "navigation": _nav_stats(rs),
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
