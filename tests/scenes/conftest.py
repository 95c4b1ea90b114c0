"""Fixtures of the scenes tests: DE421, the force model, the default LUMIO-like arc."""

from __future__ import annotations

import pytest

from starnav.scenes.dynamics import PointMassModel
from starnav.scenes.ephemeris import Ephemeris, parse_epoch

#: Default epoch of the arc used by the tests (the TrajectoryConfig default).
ARC_EPOCH = "2027-03-01T00:00:00 TDB"
#: Arc length required by issue 4 [s].
ARC_DURATION = 28 * 86_400.0
#: One kilometre [m].
KM = 1_000.0


@pytest.fixture(scope="session")
def eph() -> Ephemeris:
    return Ephemeris.default()


@pytest.fixture(scope="session")
def model(eph) -> PointMassModel:
    return PointMassModel(eph)


@pytest.fixture(scope="session")
def arc(model):
    """The 28-day ephemeris-model halo arc (built once, ~1 s; no disk cache)."""
    from starnav.scenes.trajectory import ephemeris_halo_arc

    return ephemeris_halo_arc(model, parse_epoch(ARC_EPOCH), ARC_DURATION, cache_dir=False)
