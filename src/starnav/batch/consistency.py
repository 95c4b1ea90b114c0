"""Filter consistency over a Monte Carlo of noise realisations: is the filter's covariance true?

A consistent filter's normalised estimation error squared ``NEES = e^T P^-1 e`` over its 6
position-velocity states is chi-square with 6 degrees of freedom; averaged over ``N``
independent runs it lies in ``chi2.ppf([a/2, 1 - a/2], 6 N) / N`` with probability ``1 - a``
(Bar-Shalom, Li & Kirubarajan 2001, s. 5.4.2). The runs must differ in what the filter does not
know: here each run re-exposes every rendered frame with its own detector noise (shot, read,
the acquisition's seed; the fixed pattern stays the sensor's), re-runs the whole chain
(segments, windows, refinement, fix) and starts the filter from its own initial error drawn
from ``P0``: the same machinery as ``starnav sweep --runs`` (:mod:`starnav.batch.tasks`),
in process.

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
from dataclasses import dataclass
from typing import Any

import numpy as np

from starnav.batch.tasks import FrameResult, RenderedFrame, expose_task, filter_task, render_task


@dataclass
class NoiseMonteCarlo:
    """Rendered frames and, per frame, the ``runs`` acquisitions and chain results."""

    config: dict[str, Any]
    runs: int
    rendered: list[RenderedFrame]
    frames: list[list[FrameResult]]


def noise_monte_carlo(config: dict[str, Any], runs: int) -> NoiseMonteCarlo:
    """Render every frame of the (resolved) scenario dict ``config`` once, and expose and
    process it ``runs`` times with independent detector noise."""
    from starnav.config import scenario_from_dict
    from starnav.errors import ConfigError

    if int(runs) < 2:
        raise ConfigError("runs", runs, "an integer >= 2 (a consistency test needs runs)")
    from starnav.scenes.frames import Scene

    k = len(Scene(scenario_from_dict(config)))
    rendered = [render_task(config, i) for i in range(k)]
    frames = [expose_task(config, r, int(runs), "second", 1.0) for r in rendered]
    return NoiseMonteCarlo(config, int(runs), rendered, frames)


def filter_consistency(mc: NoiseMonteCarlo, config: dict[str, Any] | None = None,
                       probability: float = 0.99) -> dict[str, Any]:
    """The filter of every run (navigation settings of ``config``, default ``mc.config``):
    run-averaged NEES per step, its time mean, the two-sided ``probability`` band of a
    run average and the verdict (the time mean inside the band)."""
    from scipy.stats import chi2

    cfg = copy.deepcopy(config if config is not None else mc.config)
    res = filter_task(cfg, 0, mc.frames, mc.runs)
    nees = np.array([row["nees_mean"] for row in res.rows], float)
    lo, hi = (chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], 6 * mc.runs)
              / mc.runs)
    mean = float(np.nanmean(nees))
    pos = np.array([row["final_position_error_pct_range"] for row in res.rows], float)
    return {"runs": mc.runs, "nees_mean": mean, "nees_per_run": nees.tolist(),
            "band": (float(lo), float(hi)), "probability": probability,
            "consistent": bool(lo <= mean <= hi),
            "verdict": ("consistent" if lo <= mean <= hi
                        else "overconfident" if mean > hi else "pessimistic"),
            "final_position_error_pct_range_median": float(np.nanmedian(pos)),
            "errors": res.errors, "sigma3": res.sigma3}
