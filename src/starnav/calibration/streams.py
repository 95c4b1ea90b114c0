"""Random streams of the bench emulation.

Every stochastic step takes a ``numpy.random.Generator``; the defaults come from here:
``SeedSequence(bench.seed, spawn_key=(STAGE_HIL, purpose))``, so a bench run is reproducible and
independent of the order in which its steps are run (``STAGE_HIL`` is registered in
:mod:`starnav.seeding` with the other stages).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from starnav.registry import Registry
from starnav.seeding import STAGE_HIL, generator

if TYPE_CHECKING:  # pragma: no cover
    from starnav.calibration.schema import BenchConfig

#: Purpose keys (never renumber: results depend on them).
STREAMS: Registry[int] = Registry("bench random stream", {
    "geometric": 1, "stimulus": 2, "radiometric": 3, "scaling": 4, "end_to_end": 5,
    "placement": 6, "truth": 7, "reference": 8, "radiometric_lab": 9,
    "random_layout": 10})


def bench_rng(cfg: BenchConfig, purpose: str) -> np.random.Generator:
    """The generator of ``purpose`` for a :class:`~starnav.calibration.schema.BenchConfig`."""
    return generator(int(cfg.seed), STAGE_HIL, STREAMS.get(purpose))
