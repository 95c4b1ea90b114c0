#!/usr/bin/env python
"""Calibrate the coarse shape model's silhouette error on the CALIBRATION fly-bys only; writes
``src/starnav/data/navigation/flyby_coarse_map_error.json``, whose rounded values are the
silhouette settings of the synthetic scoring (``starnav.navigation.trn.scoring.
SYNTHETIC_FILTER``; ``tests/navigation/test_flyby_aastr.py`` checks they agree).

What is measured: along each calibration fly-by (``scoring.CALIBRATION_FLYBYS``, sampled every
``--step`` s, the true states and the boresight attitude of the synthetic front end), the lit
silhouette of the coarse model (500 faces, the truth's volume, no scale error: the scale is
the filter's consider state) against the full shape model's, both by
``navigation.trn.body_view.lit_silhouette``: the centroid difference along and across the
Sun's image direction [px] and the radius's relative difference [-]. Then

1. **The phase law** (``navigation.trn.filter.shape_error_term``): centroid error ~ ``k rho
   hypot(q, sin(alpha / 2))`` per axis, radius fraction ~ ``k_r hypot(q, sin(alpha /
   2))``; ``q`` shared, chosen on a grid by the Gaussian likelihood of all three series, the
   ``k`` their maximum-likelihood scale at that ``q``. The filter's sigmas are the law at its
   reference geometry (``silhouette_reference_radius_px``, ``_phase_deg``).
   The errors of a fly-by are divided by its body's map error factor
   (``navigation.trn.filter.map_error_factor``: the coarse model's rms height error over its
   mean radius, over the first calibration body's, which is recorded as the filter's
   ``silhouette_reference_height_fraction``), so that the sigmas are those of the reference
   body's map and scale to another body's model through that factor.
2. **The correlation angle**: each series divided by its law, resampled on a uniform grid of
   the accumulated aspect change (``filter.aspect_change``), its autocorrelation's integral
   scale, pooled over the two fly-bys and about zero (the integral up to the first zero
   crossing, lags up to 3/4 of the pass: the scale at which an average over the pass has the
   variance of a first-order Gauss-Markov process of that correlation angle); the largest
   over the three series (the longer, the less the filter averages).

3. **The crescent term** (``navigation.trn.filter.crescent_term``): with ``q`` and the
   ``k`` of item 1 held, the across-Sun centroid sigma times ``hypot(1, kappa (1 - f) / f)``
   (``f = (1 + cos alpha) / 2``, the lit fraction; relative to its value at the reference
   phase, as the filter applies it); ``kappa`` by maximum likelihood on a grid over the
   crescent fly-bys (``scoring.CRESCENT_CALIBRATION_FLYBYS``: the calibration fly-bys and
   the development fly-bys of Itokawa and Eros), each sampled at ``--crescent-samples``
   epochs over its pass (equal weight per fly-by) and brought to the reference map like
   item 1. Recorded under ``crescent``, with the rms of each fly-by's error over the law
   with and without the term per phase bin; the filter's value is ``crescent.filter``
   (released once scored: ``scoring.SYNTHETIC_FILTER``).

No scoring fly-by is read. Usage::

    PYTHONPATH=src python tools/calibrate_flyby_coarse_map.py [--step 0.25]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from starnav.bodies.schema import ShapeModelConfig
from starnav.bodies.small_body import ShapeModelBody
from starnav.camera import Camera
from starnav.navigation.schema import TrnFilterConfig, TrnShapeModelConfig
from starnav.navigation.trn.body_model import coarse_of
from starnav.navigation.trn.body_view import BodyInCamera, lit_silhouette
from starnav.navigation.trn.filter import aspect_change, crescent_term
from starnav.navigation.trn.scoring import CALIBRATION_FLYBYS, CRESCENT_CALIBRATION_FLYBYS
from starnav.navigation.trn.synthetic import boresight_attitude
from starnav.scenes.flyby import flyby_from_config
from starnav.scenes.schema import FlybyConfig

OUT = (Path(__file__).resolve().parents[1]
       / "src/starnav/data/navigation/flyby_coarse_map_error.json")
#: Grid of the law's floor q.
Q_GRID = np.round(np.arange(0.02, 1.001, 0.01), 2)
#: Grid step of the accumulated aspect [rad].
ASPECT_STEP = math.radians(0.25)
#: Grid of the crescent term's gain kappa.
KAPPA_GRID = np.round(np.r_[0.0, np.arange(0.01, 2.001, 0.01)], 2)
#: Phase bins of the crescent term's record [deg].
PHASE_BINS = (0.0, 60.0, 120.0, 135.0, 150.0, 180.0)


def series(case, step: float) -> dict[str, np.ndarray]:
    """The coarse model's silhouette error along ``case`` (module item 0)."""
    body = ShapeModelBody(ShapeModelConfig(model=case.body))
    sm = TrnShapeModelConfig(map="coarse")
    cm = coarse_of(body, sm.faces, sm.smoothing_iterations)
    coarse = cm.shape
    cam = Camera.preset("aa-str")
    fl = flyby_from_config(FlybyConfig(v_inf_km_s=case.v_inf / 1e3,
                                       closest_approach_km=case.closest_approach / 1e3,
                                       phase_at_ca_deg=math.degrees(case.phase_at_ca)),
                           epoch_ca=0.0, gm=body.gm)
    half = case.start_ca_ranges * case.closest_approach / case.v_inf
    t = np.arange(-half, half + 1e-9, step)
    X = fl.states(t)
    Rb = np.asarray(body.orientation(t), float).reshape(-1, 3, 3)
    s = np.asarray(fl.sun_direction, float)
    out = {k: np.zeros(t.size) for k in ("rho", "phase", "aspect", "along", "across",
                                         "radius")}
    out["height_fraction"] = np.array(cm.height_rms / cm.mean_radius)
    prev = None
    for k in range(t.size):
        r = X[k, :3]
        Rc = boresight_attitude(r, fl.z_hat)
        R_bc, c, sc = Rc.T @ Rb[k], Rc.T @ (-r), Rc.T @ s
        true = lit_silhouette(BodyInCamera.place(body.shape.vertices, body.shape.faces, R_bc, c),
                              sc, cam)
        model = lit_silhouette(BodyInCamera.place(coarse.vertices, coarse.faces, R_bc, c), sc,
                               cam)
        e = cam.project_jacobian(c) @ sc
        e /= np.linalg.norm(e)
        d = np.column_stack([e, [-e[1], e[0]]]).T @ (model.centroid_uv - true.centroid_uv)
        view = (Rb[k].T @ (r / np.linalg.norm(r)), Rb[k].T @ s)
        out["aspect"][k] = (out["aspect"][k - 1] + aspect_change(*prev, *view)) if prev else 0.0
        prev = view
        out["rho"][k] = true.radius_px
        out["phase"][k] = math.acos(min(max(float(r @ s) / np.linalg.norm(r), -1.0), 1.0))
        out["along"][k], out["across"][k] = d
        out["radius"][k] = model.radius_px / true.radius_px - 1.0
    return out


def crescent_factor(phase: np.ndarray, kappa: float, phase_ref: float) -> np.ndarray:
    """The across-Sun factor of item 3, relative to the reference phase, as the filter's
    ``silhouette_scale`` applies it."""
    t = np.array([crescent_term(float(a)) for a in np.atleast_1d(phase)])
    return np.hypot(1.0, kappa * t) / math.hypot(1.0, kappa * crescent_term(phase_ref))


def fit_crescent(data: dict[str, dict[str, np.ndarray]], q: float, k_across: float,
                 phase_ref: float) -> tuple[float, dict[str, dict[str, list[float]]]]:
    """``kappa`` of item 3 by maximum likelihood (each fly-by's mean log-likelihood, summed:
    equal weight per fly-by), and per fly-by the rms over the law of the across-Sun error
    per :data:`PHASE_BINS` bin without and with the term."""
    z = {n: s["across"] / (k_across * s["rho"] * law(s["phase"], q)) for n, s in data.items()}
    best = None
    for kappa in KAPPA_GRID:
        nll = 0.0
        for n, s in data.items():
            g = crescent_factor(s["phase"], float(kappa), phase_ref)
            nll += float(np.mean(2.0 * np.log(g) + (z[n] / g) ** 2))
        if best is None or nll < best[0]:
            best = (nll, float(kappa))
    kappa = best[1]
    bins: dict[str, dict[str, list[float]]] = {}
    for n, s in data.items():
        g = crescent_factor(s["phase"], kappa, phase_ref)
        deg = np.degrees(s["phase"])
        rows = {}
        for lo, hi in zip(PHASE_BINS[:-1], PHASE_BINS[1:], strict=True):
            m = (deg >= lo) & (deg < hi)
            if m.sum() >= 3:
                rows[f"{lo:.0f}-{hi:.0f}"] = [int(m.sum()),
                                              float(np.sqrt(np.mean(z[n][m] ** 2))),
                                              float(np.sqrt(np.mean((z[n][m] / g[m]) ** 2)))]
        bins[n] = rows
    return kappa, bins


def law(phase: np.ndarray, q: float) -> np.ndarray:
    return np.hypot(q, np.sin(0.5 * phase))


def normalised(s: dict[str, np.ndarray], q: float) -> dict[str, np.ndarray]:
    m = law(s["phase"], q)
    return {"along": s["along"] / (s["rho"] * m), "across": s["across"] / (s["rho"] * m),
            "radius": s["radius"] / m}


def integral_scale(passes: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """The autocorrelation's integral up to its first zero crossing [rad] (module item 2) of
    series ``(aspect, y)`` pooled over passes. About zero, not about each pass's mean: the
    filter's bias states have mean zero, and what a pass's error keeps over its whole length
    is the most correlated part of it."""
    grids = []
    for aspect, y in passes:
        g = np.arange(0.0, aspect[-1], ASPECT_STEP)
        grids.append(np.interp(g, aspect, y))
    n = max(v.size for v in grids)
    num, den = np.zeros(n), np.zeros(n)
    for v in grids:
        for lag in range(v.size):
            num[lag] += float(np.dot(v[:v.size - lag], v[lag:]))
            den[lag] += v.size - lag
    rho = num / np.maximum(den, 1) / (num[0] / den[0])
    acc = 0.5 * ASPECT_STEP
    for lag in range(1, n):
        if den[lag] < 0.25 * den[0] or rho[lag] <= 0:
            break
        acc += float(rho[lag]) * ASPECT_STEP
    return acc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=0.25, help="sampling of the passes [s]")
    ap.add_argument("--crescent-samples", type=int, default=600,
                    help="epochs per fly-by of the crescent term's fit (item 3)")
    args = ap.parse_args()
    if args.step <= 0 or args.crescent_samples < 10:
        ap.error(f"--step must be > 0 s (got {args.step}) and --crescent-samples >= 10 "
                 f"(got {args.crescent_samples})")
    data = {c.name: series(c, args.step) for c in CALIBRATION_FLYBYS}
    ref_fraction = float(data[CALIBRATION_FLYBYS[0].name]["height_fraction"])
    for s in data.values():                 # item 1: to the reference body's map error
        f = float(s["height_fraction"]) / ref_fraction
        for comp in ("along", "across", "radius"):
            s[comp] = s[comp] / f
    best = None
    for q in Q_GRID:
        nll, ks = 0.0, {}
        for comp in ("along", "across", "radius"):
            z = np.concatenate([normalised(s, q)[comp] for s in data.values()])
            m = np.concatenate([law(s["phase"], q) for s in data.values()])
            rho = np.concatenate([s["rho"] for s in data.values()]) if comp != "radius" else 1.0
            k2 = float(np.mean(z**2))
            ks[comp] = math.sqrt(k2)
            nll += float(np.sum(np.log(k2 * (m * rho) ** 2))) + z.size
        if best is None or nll < best[0]:
            best = (nll, float(q), ks)
    _, q, ks = best
    scales = {comp: integral_scale([(s["aspect"], normalised(s, q)[comp])
                                    for s in data.values()])
              for comp in ("along", "across", "radius")}
    angle = max(scales.values())
    ref = TrnFilterConfig().to_si()
    m0 = float(law(np.array(ref.silhouette_reference_phase), q))
    sa = ks["along"] * ref.silhouette_reference_radius_px * m0
    sx = ks["across"] * ref.silhouette_reference_radius_px * m0
    cres = {}                               # item 3, each brought to the reference map
    for c in CRESCENT_CALIBRATION_FLYBYS:
        half = c.start_ca_ranges * c.closest_approach / c.v_inf
        s = series(c, 2.0 * half / (args.crescent_samples - 1))
        f = float(s["height_fraction"]) / ref_fraction
        s["across"] = s["across"] / f
        s["map_factor"] = np.array(f)
        cres[c.name] = s
    kappa, bins = fit_crescent(cres, q, ks["across"], ref.silhouette_reference_phase)
    record = {
        "what": "the coarse shape model's lit-silhouette error against the full model on the "
                "calibration fly-bys (tools/calibrate_flyby_coarse_map.py)",
        "calibration_flybys": [c.name for c in CALIBRATION_FLYBYS], "step_s": args.step,
        "law": "centroid [px] = k rho hypot(q, sin(phase / 2)); radius fraction = k_r "
               "hypot(q, sin(phase / 2))",
        "q": q, "k_along": ks["along"], "k_across": ks["across"], "k_radius": ks["radius"],
        "integral_scale_deg": {c: math.degrees(v) for c, v in scales.items()},
        "reference_radius_px": ref.silhouette_reference_radius_px,
        "reference_phase_deg": math.degrees(ref.silhouette_reference_phase),
        "filter": {"silhouette_scaling": "shape", "silhouette_shape_error_floor": q,
                   "centroid_model_sigma_px": math.sqrt(0.5 * (sa**2 + sx**2)),
                   "centroid_sun_share": sa**2 / (sa**2 + sx**2),
                   "radius_model_fraction": ks["radius"] * m0,
                   "silhouette_bias_angle_deg": math.degrees(angle),
                   "silhouette_reference_height_fraction": ref_fraction},
        "per_flyby": {n: {"frames": int(s["rho"].size),
                          "height_fraction": float(s["height_fraction"]),
                          "phase_deg": [math.degrees(float(s["phase"].min())),
                                        math.degrees(float(s["phase"].max()))],
                          "rho_px": [float(s["rho"].min()), float(s["rho"].max())],
                          "aspect_deg": math.degrees(float(s["aspect"][-1])),
                          "rms": {c: float(np.sqrt(np.mean(y**2)))
                                  for c, y in normalised(s, q).items()},
                          "mean": {c: float(np.mean(y)) for c, y in normalised(s, q).items()}}
                      for n, s in data.items()},
        "crescent": {
            "calibration_flybys": [c.name for c in CRESCENT_CALIBRATION_FLYBYS],
            "bodies": sorted({c.body for c in CRESCENT_CALIBRATION_FLYBYS}),
            "samples_per_flyby": args.crescent_samples,
            "law": "across-Sun centroid sigma times hypot(1, kappa (1 - f) / f) / hypot(1, "
                   "kappa (1 - f_ref) / f_ref), f = (1 + cos phase) / 2; q and k_across held",
            "filter": {"silhouette_crescent_gain": kappa},
            "map_factor": {n: float(s["map_factor"]) for n, s in cres.items()},
            "across_rms_over_law": {
                "columns": ["frames", "without the term", "with the term"], **bins},
        },
    }
    OUT.write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps({k: record[k] for k in ("q", "k_along", "k_across", "k_radius",
                                             "integral_scale_deg", "filter", "crescent")},
                     indent=1))


if __name__ == "__main__":
    main()
