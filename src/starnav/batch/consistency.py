"""Filter consistency over a Monte Carlo of noise realisations: is the filter's covariance true?

A consistent filter's normalised estimation error squared ``NEES = e^T P^-1 e`` over its 6
position-velocity states is chi-square with 6 degrees of freedom; averaged over ``N``
independent runs it lies in ``chi2.ppf([a/2, 1 - a/2], 6 N) / N`` with probability ``1 - a``
at each epoch (Bar-Shalom, Li & Kirubarajan 2001, s. 5.4.2); its mean over the epochs as
well lies in a band whose degrees of freedom follow from the NEES series' autocorrelation
(:func:`starnav.navigation.metrics.anees_statistics`). The runs must differ in what the
filter does not know: here each run re-exposes every rendered frame with its own detector
noise (shot, read, the acquisition's seed; the fixed pattern stays the sensor's), re-runs the
whole chain (segments, windows, refinement, fix) and starts the filter from its own initial
error drawn from ``P0``: the same machinery as ``starnav sweep --runs``
(:mod:`starnav.batch.tasks`), in process.

:func:`noise_monte_carlo` renders once and exposes ``runs`` times; :func:`filter_consistency`
runs the filter of every run for one navigation setting (so that filter settings can be
compared on the same acquisitions, e.g. by ``tools/tune_bias_states.py``) and returns the
run-averaged NEES per step, its time mean and the band.

Example
-------
>>> from starnav.batch.consistency import noise_monte_carlo, filter_consistency
>>> mc = noise_monte_carlo(config, runs=20)                     # doctest: +SKIP
>>> filter_consistency(mc, config)["verdict"]                   # doctest: +SKIP
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from starnav.batch.runs import over_runs, run_ids
from starnav.batch.tasks import (
    FrameResult,
    PointResult,
    RenderedFrame,
    expose_task,
    filter_task,
    render_task,
)
from starnav.config import scenario_from_dict, scenario_to_dict
from starnav.errors import ConfigError
from starnav.navigation.metrics import anees_statistics
from starnav.seeding import STAGE_TERRAIN, generator
from starnav.simulate import scene_from_scenario


@dataclass
class NoiseMonteCarlo:
    """Rendered frames and, per frame, the ``runs`` acquisitions and chain results."""

    config: dict[str, Any]
    runs: int
    rendered: list[RenderedFrame]
    frames: list[list[FrameResult]]


def terrain_offsets_deg(seed: int, runs: int) -> list[float]:
    """The terrain realisation of each run: run 0 the Moon as it is, run ``r`` the terrain
    turned by a uniform random angle about the pole (``moon.dem.longitude_offset_deg``, from
    the stream ``(STAGE_TERRAIN, r)`` of ``seed``) [deg]."""
    return [0.0] + over_runs(
        lambda r: float(generator(int(seed), STAGE_TERRAIN, r).uniform(0.0, 360.0)),
        run_ids(int(runs) - 1, 1, minimum=0))


def terrain_renders(config: dict[str, Any], runs: int,
                    rendered: list[RenderedFrame] | None = None) -> list[list[RenderedFrame]]:
    """The arc rendered once per run, each run on its own terrain (:func:`terrain_offsets_deg`;
    run 0, the Moon as it is, may be given as ``rendered``)."""
    sc = scenario_from_dict(config)
    if sc.moon.shape != "dem":
        raise ConfigError("moon.shape", sc.moon.shape, "'dem' for terrain realisations")
    offsets = terrain_offsets_deg(sc.seed, runs)
    return [render_arc(config) if rendered is None else rendered] + over_runs(
        lambda r: render_arc(scenario_to_dict(scenario_from_dict(
            config, [f"moon.dem.longitude_offset_deg={offsets[r]!r}"]))),
        run_ids(int(runs) - 1, 1, minimum=0))


def noise_monte_carlo(config: dict[str, Any], runs: int,
                      rendered: list[RenderedFrame] | None = None, *,
                      terrain: bool = False,
                      per_run: list[list[RenderedFrame]] | None = None) -> NoiseMonteCarlo:
    """Render every frame of the (resolved) scenario dict ``config`` once (or take
    ``rendered``), and expose and process it ``runs`` times with independent detector
    noise, attitude knowledge error and initial error.

    With ``terrain`` every run also has its own terrain (:func:`terrain_offsets_deg`: the
    DEM and its albedo turned about the pole, the geometry unchanged) and is rendered again:
    the only way a Monte Carlo samples the limb's terrain error, which is otherwise the same
    in every run of an arc (a fixed, unknown bias of that arc: one draw, whatever the number
    of runs). ``rendered`` then holds run 0's frames (the Moon as it is); ``per_run``, from
    :func:`terrain_renders`, reuses the terrains' renders (e.g. for another exposure)."""
    if int(runs) < 2:
        raise ConfigError("runs", runs, "an integer >= 2 (a consistency test needs runs)")
    if per_run is not None:
        terrain = True
        rendered = per_run[0]
    rendered = render_arc(config) if rendered is None else rendered
    if not terrain:
        frames = [expose_task(config, r, int(runs), "second", 1.0) for r in rendered]
        return NoiseMonteCarlo(config, int(runs), rendered, frames)
    if per_run is None:
        per_run = terrain_renders(config, runs, rendered)
    if len(per_run) != int(runs):
        raise ConfigError("per_run", len(per_run), f"{runs} rendered arcs, one per run")
    arcs = per_run
    frames = [over_runs(lambda r, k=k: expose_task(config, arcs[r][k], 1, "second", 1.0,
                                                   first_run=r)[0], int(runs))
              for k in range(len(rendered))]
    return NoiseMonteCarlo(config, int(runs), rendered, frames)


#: Expected fraction of a Gaussian error inside its 3-sigma bound.
THREE_SIGMA_FRACTION = 0.9973

#: The two exposures the refinement's model error is calibrated and checked at, with the
#: segment threshold each is read with: well exposed (the paper's 0.015 ms) and saturated
#: near the limb (0.18 ms, before the blooming regime). Shared by
#: tools/calibrate_refine_model_error.py, benchmarks/consistency.py and the CI tests.
WELL_EXPOSED = (1.5e-5, ("detector.readout.segments.thresholds_dn=[200]",))
SATURATED = (1.8e-4, ("detector.readout.segments.thresholds_dn=[2048]",))


def consistency_metrics(res: PointResult, probability: float = 0.99) -> dict[str, Any]:
    """Whether a filter's covariance is true, over ``R`` Monte Carlo runs (``res`` from
    :func:`~starnav.batch.tasks.filter_task`), by
    :func:`~starnav.navigation.metrics.anees_statistics`:

    * ``nees``, ``nees_position``, ``nees_velocity``, ``nis``: the statistics of the 6-state
      NEES, of its position and velocity 3-dof blocks and of the NIS (3 dof, steps with a
      fix): per-epoch ANEES against the 95 % band of an ``R``-run mean and the fraction of
      epochs inside it; time-averaged ANEES against the two-sided ``probability`` band of its
      effective number of samples (the NEES series' measured autocorrelation);
    * the 6-state numbers also flat, as before: ``nees_mean``, ``nees_band`` (the corrected
      band), ``verdict`` (``consistent``, ``overconfident`` above, ``pessimistic`` below),
      ``nees_steps_in_band``, ``nees_per_step``; ``nis_mean``, ``nis_band``, ``nis_fixes``,
      ``nis_per_step``;
    * ``within_3sigma``: fraction of all (run, step, component) errors inside the filter's
      3-sigma bounds, per component and overall (a consistent Gaussian filter: 99.73 %);
    * final position error in % of range (median and 90th percentile over runs).
    """
    R = len(res.rows)
    out: dict[str, Any] = {"runs": R, "probability": probability}
    if res.nees is None or res.errors is None or res.sigma3 is None:
        out["verdict"] = "no truth"
        return out
    st = anees_statistics(res.nees, 6, probability)
    out.update({"nees_mean": st["mean"], "nees_band": st["band"],
                "consistent": st["verdict"] == "consistent", "verdict": st["verdict"],
                "nees_steps_in_band": st["epochs_in_band"], "nees_per_step": st["per_epoch"],
                "nees": _compact(st)})
    for name, values in (("nees_position", res.nees_position),
                         ("nees_velocity", res.nees_velocity)):
        if values is not None:
            out[name] = _compact(anees_statistics(values, 3, probability))
    if res.nis is not None and np.any(np.isfinite(res.nis)):
        nis = anees_statistics(res.nis, 3, probability)
        out.update({"nis_mean": nis["mean"], "nis_band": nis["band"],
                    "nis_fixes": int(np.isfinite(res.nis).sum()),
                    "nis_per_step": nis["per_epoch"], "nis": _compact(nis)})
    inside = np.abs(res.errors) <= res.sigma3
    out["within_3sigma"] = {"position": float(inside[..., :3].mean()),
                            "velocity": float(inside[..., 3:].mean()),
                            "all": float(inside.mean()), "expected": THREE_SIGMA_FRACTION}
    pos = np.array([r.get("final_position_error_pct_range", math.nan) for r in res.rows])
    out["final_position_error_pct_range"] = {
        "median": float(np.nanmedian(pos)), "p90": float(np.nanpercentile(pos, 90))}
    return out


def _compact(st: dict[str, Any]) -> dict[str, Any]:
    """:func:`~starnav.navigation.metrics.anees_statistics` without its per-epoch lists
    (``nees_per_step`` and ``nis_per_step`` carry them)."""
    return {k: v for k, v in st.items() if k not in ("per_epoch", "per_epoch_band")}


def filter_consistency(mc: NoiseMonteCarlo, config: dict[str, Any] | None = None,
                       probability: float = 0.99) -> dict[str, Any]:
    """The filter of every run (navigation settings of ``config``, default ``mc.config``):
    :func:`consistency_metrics`, plus the per-run NEES and the errors and bounds."""
    cfg = copy.deepcopy(config if config is not None else mc.config)
    res = filter_task(cfg, 0, mc.frames, mc.runs)
    out = consistency_metrics(res, probability)
    out.update({"nees_per_run": [float(r["nees_mean"]) for r in res.rows],
                "band": tuple(out["nees_band"]),
                "final_position_error_pct_range_median":
                    out["final_position_error_pct_range"]["median"],
                "errors": res.errors, "sigma3": res.sigma3, "result": res})
    return out


# ----------------------------------------------------------------------------- limb points
_COLUMNS = ("error", "sigma", "fit_sigma", "common_var", "sun_angle", "saturated",
            "overexposure", "radius", "phase", "frame", "run")


def limb_point_table(frames: list[list[FrameResult]]) -> dict[str, np.ndarray]:
    """Every refined limb point of every run, as columns: ``error`` (signed distance to the
    true limb, > 0 outside), ``sigma`` (its own, as the fix uses it), ``fit_sigma`` (pixels'
    noise alone), ``common_var`` (the variance it shares with its frame) [px^2], ``sun_angle``
    (of the point's normal from the Sun in the image) [rad],
    ``saturated``, ``overexposure`` (fitted step over the headroom to saturation, 0 well
    exposed), ``radius`` [px], ``phase`` [rad], ``frame``, ``run`` (pixel-level points,
    without windows, are left out)."""
    cols: dict[str, list[Any]] = {k: [] for k in _COLUMNS}
    for per_frame in frames:
        for fr in per_frame:
            p = fr.points
            if p is None or not p.refined or p.sigma_px.size != fr.limb_errors_px.size:
                continue
            n = p.sigma_px.size
            cols["error"].append(fr.limb_errors_px.astype(float))
            cols["sigma"].append(p.sigma_px.astype(float))
            cols["fit_sigma"].append(p.fit_sigma_px.astype(float))
            cols["common_var"].append(p.common_var_px2.astype(float))
            cols["sun_angle"].append(np.zeros(n) if p.sun_angle_rad is None
                                     else p.sun_angle_rad.astype(float))
            cols["saturated"].append(p.saturated)
            cols["overexposure"].append(np.zeros(n) if p.overexposure is None
                                        else p.overexposure.astype(float))
            cols["radius"].append(np.full(n, p.radius_px))
            cols["phase"].append(np.full(n, p.phase_rad))
            cols["frame"].append(np.full(n, fr.index))
            cols["run"].append(np.full(n, fr.run))
    return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in cols.items()}


def fix_mode_table(frames: list[list[FrameResult]]) -> dict[str, np.ndarray]:
    """Per fix made from refined points: ``error`` ``(F, 3)``, ``noise`` and ``white``
    ``(F, 3, 3)`` in the three shared modes [units of the disc radius]
    (:class:`~starnav.batch.tasks.LimbPointRecord`), ``radius`` [px], ``saturated`` (any
    window saturated), ``phase`` [rad], ``frame``, ``run``."""
    rows = [fr for per in frames for fr in per if fr.points is not None
            and fr.points.mode_error is not None]
    nan3 = np.full((3, 3), np.nan)
    return {"error": np.array([r.points.mode_error for r in rows]).reshape(-1, 3),
            "noise": np.array([r.points.mode_noise for r in rows]).reshape(-1, 3, 3),
            "white": np.array([nan3 if r.points.mode_white is None else r.points.mode_white
                               for r in rows]).reshape(-1, 3, 3),
            "radius": np.array([r.points.radius_px for r in rows]),
            "saturated": np.array([bool(np.any(r.points.saturated)) for r in rows]),
            "phase": np.array([r.points.phase_rad for r in rows]),
            "frame": np.array([r.index for r in rows]), "run": np.array([r.run for r in rows])}


def total_sigma(table: dict[str, np.ndarray]) -> np.ndarray:
    """A point's whole 1-sigma [px]: its own and its share of the frame's common errors
    along its normal, ``sqrt(sigma^2 + x^T C x)``, ``x = (1, cos phi, sin phi)``."""
    return np.sqrt(table["sigma"] ** 2 + table["common_var"])


def refinement_consistency(table: dict[str, np.ndarray]) -> dict[str, Any]:
    """rms of ``error / sigma_total`` of refined points (:func:`total_sigma`): 1 for a
    consistent refinement; also for saturated and unsaturated windows apart, the bias and the
    spread [px]."""
    e, s = table["error"], total_sigma(table)
    out: dict[str, Any] = {"points": int(e.size)}
    for name, sel in (("all", np.ones(e.size, bool)), ("saturated", table["saturated"]),
                      ("unsaturated", ~table["saturated"].astype(bool))):
        sel = np.asarray(sel, bool)
        z = e[sel] / s[sel]
        out[name] = {"points": int(sel.sum()),
                     "rms_z": float(np.sqrt(np.mean(z * z))) if z.size else None,
                     "bias_px": float(e[sel].mean()) if z.size else None,
                     "std_px": float(e[sel].std()) if z.size else None}
    return out


#: Phase-angle bins of the model-error calibration [deg]: the edge model holds to a quarter
#: Moon; on a crescent the terminator comes into the windows.
PHASE_EDGES_DEG: tuple[float, ...] = (0.0, 90.0, 120.0, 180.0)
#: Fewest frames a phase bin needs to be calibrated on its own (else it takes its
#: neighbour's value).
MIN_FRAMES_PER_BIN = 3
#: Fewest points of a frame for its shared errors to be estimated.
MIN_POINTS_PER_FRAME = 8


def _frame_keys(t: dict[str, np.ndarray], sel: np.ndarray) -> list[tuple[int, int]]:
    return sorted(set(zip(t["frame"][sel].astype(int).tolist(),
                          t["run"][sel].astype(int).tolist(), strict=True)))


def _filled(v: list[float], error: str = "no phase bin is calibrated") -> list[float]:
    """Each NaN bin of ``v`` takes its nearest calibrated neighbour's value (a bin with too
    few frames); ValueError ``error`` when no bin is calibrated."""
    ok = [i for i, x in enumerate(v) if math.isfinite(x)]
    if not ok:
        raise ValueError(error)
    return [v[i] if math.isfinite(v[i]) else v[min(ok, key=lambda j: abs(j - i))]
            for i in range(len(v))]


def three_mode_fit(err: np.ndarray, phi: np.ndarray, own: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The weighted least-squares fit of one frame's point errors [px] to the shared modes
    ``a + b cos(phi) + c sin(phi)`` (weights ``1 / own``, the points' own variances):
    ``(coefficients, their covariance, residuals)``, None when the normal matrix is singular
    (points on too short a stretch of limb)."""
    X = np.column_stack([np.ones(err.size), np.cos(phi), np.sin(phi)])
    W = 1.0 / own
    try:
        C = np.linalg.inv(X.T @ (X * W[:, None]))
    except np.linalg.LinAlgError:
        return None
    beta = C @ (X.T @ (W * err))
    return beta, C, err - X @ beta


def calibrate_model_error(smooth: dict[str, np.ndarray], terrain: dict[str, np.ndarray],
                          fixes: dict[str, np.ndarray] | None, topography: Any, window_px: int,
                          phase_edges_deg: tuple[float, ...] = PHASE_EDGES_DEG,
                          smooth_fixes: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """The model-error terms of the ``detector-psf`` refinement by the method of moments
    (``tools/calibrate_refine_model_error.py``;
    :class:`~starnav.navigation.refine.ModelErrorCalibration`, whose error model this
    follows: a point's own error ``e`` plus the frame's shared ``a + b cos(phi) +
    c sin(phi)``):

    1. **edge model error** ``s_e`` per bin of phase: on a smooth (terrain-free) Moon,
       unsaturated windows, ``s_e^2 = mean(err^2 - s_fit^2)``: what the step-and-ramp model
       misses of a real limb profile (the photometry's limb darkening, the terminator near a
       crescent's limb) and of the render;
    2. **saturated extra** ``s_s`` per bin: the same on saturated windows, beyond ``s_e``
       (blooming, inter-pixel capacitance of clipped neighbours, non-linearity);
    3. on the real Moon (unsaturated windows), per frame, the weighted least-squares fit of
       ``err = a + b cos(phi) + c sin(phi)`` (weights from the points' own variance):
       **terrain scale** ``k`` from the residuals, ``k^2 = mean(r^2 n/(n-3) - s_fit^2 - s_e^2)
       / mean(t_l^2)`` (``t_l`` the DEM's limb-height spread over a window's arc, in pixels
       at the frame's disc radius; floored at 1: the silhouette is always there), and the
       **shared terms** as fractions of the disc radius ``R``: ``f_a^2 = mean((a^2 -
       var_a) / R^2)`` and likewise ``f_b``, ``f_c`` (``var`` the part of each coefficient's
       spread that the points' own errors explain; floored at 0).

    A phase bin with fewer than :data:`MIN_FRAMES_PER_BIN` frames takes its nearest
    calibrated neighbour's values.
    """
    edges = np.asarray(phase_edges_deg, float)
    nb = edges.size - 1

    def bins(t: dict[str, np.ndarray]) -> np.ndarray:
        return np.clip(np.searchsorted(edges, np.degrees(t["phase"]), "right") - 1, 0, nb - 1)

    bs = bins(smooth)
    se, ss, mom = [math.nan] * nb, [math.nan] * nb, []
    for b in range(nb):
        u = (bs == b) & ~smooth["saturated"].astype(bool)
        s = (bs == b) & smooth["saturated"].astype(bool)
        row: dict[str, Any] = {"phase_deg": [float(edges[b]), float(edges[b + 1])],
                               "smooth_frames": len(_frame_keys(smooth, u)),
                               "saturated_frames": len(_frame_keys(smooth, s))}
        if row["smooth_frames"] >= MIN_FRAMES_PER_BIN:
            se2 = max(float(np.mean(smooth["error"][u] ** 2 - smooth["fit_sigma"][u] ** 2)), 0)
            se[b] = math.sqrt(se2)
            if row["saturated_frames"] >= MIN_FRAMES_PER_BIN:
                ss[b] = math.sqrt(max(float(np.mean(smooth["error"][s] ** 2
                                                    - smooth["fit_sigma"][s] ** 2)) - se2, 0))
        mom.append(row)

    se, ss = (_filled(v, "no phase bin has enough calibration frames") for v in (se, ss))
    # the real Moon, frame by frame
    bt = bins(terrain)
    un = ~terrain["saturated"].astype(bool)
    res_num, res_den, coef = [], [], []
    for f, r in _frame_keys(terrain, un):
        sel = un & (terrain["frame"] == f) & (terrain["run"] == r)
        n = int(sel.sum())
        if n < MIN_POINTS_PER_FRAME:
            continue
        R = float(terrain["radius"][sel][0])
        phi = terrain["sun_angle"][sel]
        err = terrain["error"][sel]
        tl = topography.sigma_fraction_over(window_px / R) * R
        own = terrain["fit_sigma"][sel] ** 2 + se[int(bt[sel][0])] ** 2 + tl**2
        fit = three_mode_fit(err, phi, own)
        if fit is None:
            continue
        beta, C, resid = fit
        res_num.append(float(np.mean(resid**2)) * n / (n - 3)
                       - float(np.mean(terrain["fit_sigma"][sel] ** 2
                                       + se[int(bt[sel][0])] ** 2)))
        res_den.append(tl**2)
        # the coefficients' spread the own errors explain, at the calibrated k: iterated below
        coef.append((beta, C, own, tl, R))
    k2 = max(float(np.mean(res_num)) / float(np.mean(res_den)), 1.0)
    # the shared errors, where they act: the fixes' errors in the three modes, less what the
    # points' own errors and the attitude explain, per unit disc radius squared
    def psd_mean(mats: list[np.ndarray]) -> np.ndarray:
        S = np.mean(mats, axis=0) if mats else np.zeros((3, 3))
        w, v = np.linalg.eigh(0.5 * (S + S.T))
        return (v * np.maximum(w, 0.0)) @ v.T

    common = fix_c = fix_cs = np.zeros((3, 3))
    n_fix = n_sat = 0
    if fixes is not None:
        sat = fixes["saturated"].astype(bool)
        n_fix, n_sat = int((~sat).sum()), int(sat.sum())
        if n_fix == 0:
            raise ValueError("no unsaturated fix to calibrate the shared errors on")
        E = [np.outer(e, e) for e in fixes["error"]]
        common = psd_mean([E[i] - fixes["noise"][i] for i in np.flatnonzero(~sat)])
        fix_c = scaled_to_nees(psd_mean([E[i] - fixes["white"][i] for i in np.flatnonzero(~sat)]),
                             fixes, ~sat)
        fix_cs = scaled_to_nees(psd_mean([E[i] - fixes["white"][i] for i in np.flatnonzero(sat)]),
                              fixes, sat) if n_sat else fix_c

    def summary(S: np.ndarray) -> dict[str, Any]:
        sd = np.sqrt(np.diag(S))
        sd_safe = np.where(sd > 0, sd, 1.0)
        return {"sigma_km_equivalent": (sd * 1737.4).tolist(),
                "correlation": (S / np.outer(sd_safe, sd_safe)).tolist()}

    fix_sm = np.zeros((3, 3))
    if smooth_fixes is not None and smooth_fixes["error"].size:
        ok = ~smooth_fixes["saturated"].astype(bool)
        E = [np.outer(e, e) for e in smooth_fixes["error"]]
        fix_sm = scaled_to_nees(psd_mean([E[i] - smooth_fixes["white"][i]
                                        for i in np.flatnonzero(ok)]), smooth_fixes, ok)
    return {"phase_edges_deg": [float(x) for x in edges],
            "edge_model_error_px": se, "saturated_model_error_px": ss,
            "terrain_scale": math.sqrt(k2), "common_covariance": common.tolist(),
            "fix_covariance": fix_c.tolist(), "fix_covariance_saturated": fix_cs.tolist(),
            "fix_covariance_smooth": fix_sm.tolist(),
            "moments": {"bins": mom, "terrain_frames": len(res_num),
                        "fixes": n_fix, "saturated_fixes": n_sat,
                        "common": summary(common), "fix": summary(fix_c),
                        "fix_saturated": summary(fix_cs), "fix_smooth": summary(fix_sm)}}


def shared_covariance_mle(fixes: dict[str, np.ndarray], sel: np.ndarray) -> np.ndarray:
    """The covariance ``C`` of the fixes' slowly varying error in the three limb modes
    (units of the disc radius squared) by maximum likelihood: ``e_i ~ N(0, W_i + C)``, ``W_i``
    the fix's white part (``fixes["white"]``), over the fixes where ``sel``; ``C = L L^T``
    with ``L`` lower triangular. The method of moments (``mean(e e^T - W)``) leans on the
    few fixes from a short stretch of limb, whose white part is large along one mode, and
    can turn indefinite; the likelihood weighs each fix by its own covariance."""
    from scipy.optimize import minimize

    idx = np.flatnonzero(sel)
    if idx.size < 6:
        raise ValueError(f"{idx.size} fixes: at least 6 are needed for the shared covariance")
    e = np.asarray(fixes["error"], float)[idx]
    W = np.asarray(fixes["white"], float)[idx]
    tril = np.tril_indices(3)

    def unpack(x: np.ndarray) -> np.ndarray:
        L = np.zeros((3, 3))
        L[tril] = x
        L[np.diag_indices(3)] = np.exp(np.diag(L))
        return L @ L.T

    def nll(x: np.ndarray) -> float:
        S = W + unpack(x)[None]
        sign, logdet = np.linalg.slogdet(S)
        if np.any(sign <= 0):
            return 1e300
        return float(np.sum(logdet) + np.einsum("ni,ni->", e, np.linalg.solve(
            S, e[..., None])[..., 0]))

    x0 = np.zeros(6)
    x0[[0, 2, 5]] = np.log(np.maximum(np.sqrt(np.mean(e * e, axis=0)), 1e-6))
    res = minimize(nll, x0, method="Nelder-Mead",
                   options={"maxiter": 20000, "xatol": 1e-8, "fatol": 1e-10})
    res = minimize(nll, res.x, method="BFGS")
    return unpack(res.x)


def scaled_to_nees(C: np.ndarray, fixes: dict[str, np.ndarray], sel: np.ndarray) -> np.ndarray:
    """``s C`` with ``s`` such that the fixes' mean NEES (3 dof) with ``white + s C`` is 3 on
    the calibration fixes: the moments give the shape of ``C``, this its size where it is
    used (a mean of ratios, not a ratio of means: the fixes' own noise varies tenfold with
    the disc's size)."""
    idx = np.flatnonzero(sel)

    def mean_nees(scale: float) -> float:
        return float(np.mean([fixes["error"][i] @ np.linalg.solve(
            fixes["white"][i] + scale * C, fixes["error"][i]) for i in idx]))

    if not np.any(C) or mean_nees(0.0) <= 3.0:
        return C
    lo, hi = 0.0, 1.0
    while mean_nees(hi) > 3.0 and hi < 1e6:
        lo, hi = hi, hi * 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mean_nees(mid) > 3.0 else (lo, mid)
    return hi * C


def fix_phase_scales(fixes: dict[str, np.ndarray], C: np.ndarray, saturated: bool,
                     phase_edges_deg: tuple[float, ...] = PHASE_EDGES_DEG) -> list[float]:
    """Per bin of phase, the factor ``s`` on the slowly varying fix covariance ``C`` (its
    shape pooled over all phases) that makes the bin's calibration fixes' mean NEES (3 dof)
    with ``white + s C`` equal 3 (:func:`scaled_to_nees`): the shared limb errors grow towards
    the crescent, where shadows eat the lit limb. A bin with fewer than
    :data:`MIN_FRAMES_PER_BIN` fixes takes its nearest calibrated neighbour's factor."""
    edges = np.asarray(phase_edges_deg, float)
    nb = edges.size - 1
    b = np.clip(np.searchsorted(edges, np.degrees(fixes["phase"]), "right") - 1, 0, nb - 1)
    sat = fixes["saturated"].astype(bool) == saturated
    C = np.asarray(C, float)
    out = [math.nan] * nb
    for k in range(nb):
        sel = sat & (b == k) & np.isfinite(fixes["phase"])
        if int(sel.sum()) >= MIN_FRAMES_PER_BIN and np.any(C):
            out[k] = float(scaled_to_nees(C, fixes, sel)[np.unravel_index(
                np.argmax(np.abs(C)), C.shape)] / C.flat[np.argmax(np.abs(C))])
    if not any(math.isfinite(x) for x in out):
        return [1.0] * nb
    return _filled(out)


def saturated_extra_by_phase(points: dict[str, np.ndarray], calibration: Any, topography: Any,
                             window_px: int, phase_edges_deg: tuple[float, ...]) -> list[float]:
    """Per bin of phase, a saturated window's extra error [px] beyond the pixels' noise, the
    edge model's error and the terrain (``calibration``'s, a
    :class:`~starnav.navigation.refine.ModelErrorCalibration`), from the residuals of each
    frame's weighted fit of the three shared modes (as :func:`calibrate_model_error`'s
    terrain scale): ``s^2 = mean(r^2 n/(n-3) - s_fit^2 - s_e^2 - (k t_l)^2)``, floored at 0.
    Frames with fewer than 5 saturated points are left out; a bin with fewer than
    :data:`MIN_FRAMES_PER_BIN` frames takes its nearest calibrated neighbour's value."""
    edges = np.asarray(phase_edges_deg, float)
    nb = edges.size - 1
    b_of = np.clip(np.searchsorted(edges, np.degrees(points["phase"]), "right") - 1, 0, nb - 1)
    sat = points["saturated"].astype(bool)
    per_bin: list[list[float]] = [[] for _ in range(nb)]
    for f, r in _frame_keys(points, sat):
        sel = sat & (points["frame"] == f) & (points["run"] == r)
        n = int(sel.sum())
        if n < 5:
            continue
        R = float(points["radius"][sel][0])
        phase = float(points["phase"][sel][0])
        se, _, k = calibration.at(phase)
        tl = 0.0 if topography is None else topography.sigma_fraction_over(window_px / R) * R
        own = points["fit_sigma"][sel] ** 2 + se**2 + (k * tl) ** 2
        fit = three_mode_fit(points["error"][sel], points["sun_angle"][sel], own)
        if fit is None:
            continue
        resid = fit[2]
        per_bin[int(b_of[sel][0])].append(float(np.mean(resid**2)) * n / (n - 3)
                                          - float(np.mean(own)))
    out = [math.sqrt(max(float(np.mean(v)), 0.0)) if len(v) >= MIN_FRAMES_PER_BIN
           else math.nan for v in per_bin]
    return _filled(out, "no phase bin has enough saturated calibration frames")


def modelled_sigma(table: dict[str, np.ndarray], calibration: Any, topography: Any,
                   window_px: int) -> np.ndarray:
    """Each point's whole 1-sigma [px] under a model-error ``calibration``
    (:class:`~starnav.navigation.refine.ModelErrorCalibration`), from its recorded
    components, as :func:`total_sigma` would have it, to score a calibration on other arcs;
    ``topography`` None for a smooth Moon (no terrain terms)."""
    out = np.empty(table["error"].size)
    for i, (fit, sat, r, ph, phi) in enumerate(zip(
            table["fit_sigma"], table["saturated"], table["radius"], table["phase"],
            table["sun_angle"], strict=True)):
        se, ss, k = calibration.at(float(ph))
        v = fit**2 + se**2 + (ss**2 if sat else 0.0)
        if topography is not None:
            tl = topography.sigma_fraction_over(window_px / r) * r
            x = np.array([1.0, math.cos(phi), math.sin(phi)])
            v += (k * tl) ** 2 + r**2 * float(x @ np.asarray(calibration.common_covariance) @ x)
        out[i] = math.sqrt(v)
    return out


def render_arc(config: dict[str, Any]) -> list[RenderedFrame]:
    """Every frame of the resolved scenario dict ``config``, rendered (in this process)."""
    n = len(scene_from_scenario(scenario_from_dict(config)))
    return [render_task(config, i) for i in range(n)]


def limb_point_records(config: dict[str, Any], runs: int = 1,
                       exposures: tuple[tuple[float, tuple[str, ...]], ...] = (),
                       rendered: list[RenderedFrame] | None = None
                       ) -> dict[float, dict[str, Any]]:
    """Render every frame of the resolved scenario dict ``config`` once (or take
    ``rendered``) and, for each ``(exposure_time, overrides)`` (default: the scenario's exposure
    alone), expose and process it ``runs`` times. Per exposure: ``points``
    (:func:`limb_point_table`), ``fixes`` (:func:`fix_mode_table`) and ``fix_nees``, the NEES
    (3 dof) of every fix against the true Moon-relative position.

    The chain knows the camera exactly here (``navigation.camera_calibration`` null): these
    are the image's errors against the points' and fixes' own error model; the camera's
    calibration error is one constant per arc, which the filter carries as consider states."""
    config = scenario_to_dict(scenario_from_dict(config, ["navigation.camera_calibration=null"]))
    sc = scenario_from_dict(config)
    rendered = render_arc(config) if rendered is None else rendered
    cases = exposures or ((float(sc.detector.exposure_time_s), ()),)
    out: dict[float, dict[str, Any]] = {}
    for t, overrides in cases:
        cfg = scenario_to_dict(scenario_from_dict(
            config, [f"detector.exposure_time_s={t!r}", *overrides]))
        frames = [expose_task(cfg, r, int(runs), "second", 1.0) for r in rendered]
        nees = []
        for r, per_frame in zip(rendered, frames, strict=True):
            truth = np.asarray(r.geometry.camera_position, float)
            for fr in per_frame:
                if fr.position is not None and fr.covariance is not None:
                    d = np.asarray(fr.position) - truth
                    nees.append(float(d @ np.linalg.solve(fr.covariance, d)))
        out[float(t)] = {"points": limb_point_table(frames), "fixes": fix_mode_table(frames),
                         "fix_nees": np.array(nees)}
    return out
