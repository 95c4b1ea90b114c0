"""The one driver of runs and points (``starnav.batch.runs``): a run is a function of its
number (any subset of runs gives the same runs), points come back in point order whatever order
a runner finishes them in, and a bad run count is one clear error."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.batch.montecarlo import filter_runs
from starnav.batch.runs import over_points, over_runs, run_ids
from starnav.errors import ConfigError
from starnav.navigation.pipeline import FrameMeasurement, initial_error_normal, run_filter
from starnav.seeding import STAGE_NAVIGATION, generator
from tests.navigation._helpers import MovingMoonTwoBody, circular_state, fix_covariance


def _draw(r: int) -> float:
    return float(generator(3, STAGE_NAVIGATION, r).standard_normal())


def test_a_run_is_a_function_of_its_number():
    seen = []
    full = over_runs(_draw, 5, progress=lambda d, n: seen.append((d, n)))
    assert full == [_draw(r) for r in range(5)] and len(set(full)) == 5
    assert seen == [(k, 5) for k in range(1, 6)]
    assert over_runs(_draw, 2, first_run=3) == full[3:5]
    assert over_runs(_draw, run_ids(2, 3)) == full[3:5]


class _ReverseRunner:
    """A runner that finishes its tasks last first (as a cluster may)."""

    def submit(self, fn, *args, key):
        return (key, fn, args)

    def as_completed(self, handles):
        for h in reversed(list(handles)):
            yield h, h[1](*h[2])


def test_points_come_back_in_point_order():
    points = [(v, p) for v in (1.0, 2.0) for p in (10, 20, 30)]
    here = over_points(lambda v, p: v * p, points)
    seen = []
    remote = over_points(pow, points, runner=_ReverseRunner(),
                         progress=lambda d, n: seen.append(d))
    assert here == [10.0, 20.0, 30.0, 20.0, 40.0, 60.0]
    assert remote == [v**p for v, p in points]
    assert seen == list(range(7))


@pytest.mark.parametrize("runs", [0, -1, 2.5, True, "3", None])
def test_a_bad_run_count_is_one_error_naming_it(runs):
    with pytest.raises(ConfigError, match=r"runs = .*expected an integer >= 1"):
        run_ids(runs)


def test_a_consistency_run_count_needs_two_and_a_first_run_its_sign():
    with pytest.raises(ConfigError, match="runs = 1: expected an integer >= 2"):
        run_ids(1, minimum=2)
    with pytest.raises(ConfigError, match="first_run"):
        run_ids(2, -1)
    assert run_ids(0, 1, minimum=0) == range(1, 1)


def test_filter_runs_draw_each_run_its_own_initial_error():
    """Regression of the seeding contract (the filter's own model on its own simulated fixes):
    run ``r`` of the filter's Monte Carlo starts from ``truth[0] + L z(seed, r)``, runs 1 on,
    the stream of the sweeps' run ``r``."""
    dyn = MovingMoonTwoBody(step=300.0)
    rng = np.random.default_rng(4)
    x, t, truth, meas = circular_state(dyn, 6.0e7), 0.0, [], []
    for k in range(6):
        x, _ = dyn.propagate(t, x, t + 1800.0)
        t += 1800.0
        rel = x[:3] - dyn.moon_state(t)[:3]
        R = fix_covariance(rel, 30e3, 3e3)
        meas.append(FrameMeasurement(k, t, "ok", position=rel
                                     + np.linalg.cholesky(R) @ rng.standard_normal(3),
                                     covariance=R))
        truth.append(x)
    P0 = np.diag([100e3**2] * 3 + [1.0**2] * 3)
    runs = filter_runs(meas, truth, dynamics=dyn, moon=dyn, P0=P0, runs=2, seed=5)
    x0 = truth[0] + np.linalg.cholesky(P0) @ initial_error_normal(5, 2)
    alone = run_filter(meas, dynamics=dyn, moon=dyn, t0=meas[0].epoch_tdb, x0=x0, P0=P0)
    assert len(runs) == 2 and np.array_equal(runs[1].states, alone.states)
    assert not np.array_equal(runs[0].states, runs[1].states)
    with pytest.raises(ConfigError, match="runs"):
        filter_runs(meas, truth, dynamics=dyn, moon=dyn, P0=P0, runs=0)
