"""Random streams of the detector chain, keyed so that results never depend on processing order.

Each child stream is built by its *spawn key*, ``SeedSequence(entropy, spawn_key=(k1, ...))``,
the child a chain of ``spawn`` calls would give (NumPy's documented construction), in any
order:

=============== ============================================ =================================
stream          key                                          changes with
=============== ============================================ =================================
fixed pattern   ``(sensor_seed, (STAGE_DETECTOR_FIXED, effect))`` the sensor seed only
temporal        ``(seed, (STAGE_DETECTOR_TEMPORAL, frame, effect))`` the seed and frame index
=============== ============================================ =================================

``effect`` is a stable integer per effect name (:data:`EFFECT_STREAMS`), never ``hash()``;
the stage keys come from :mod:`starnav.seeding`.
"""

from __future__ import annotations

import numpy as np

from starnav.errors import ConfigError
from starnav.registry import Registry
from starnav.seeding import STAGE_DETECTOR_FIXED, STAGE_DETECTOR_TEMPORAL, generator

#: Stable stream number of every stochastic effect. Append only: never renumber.
EFFECT_STREAMS: Registry[int] = Registry("random stream", {
    "prnu": 1,
    "dark_current": 2,
    "hot_pixels": 3,
    "shot_noise": 10,
    "read_noise": 11,
})



def _check_seed(name: str, seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(name, seed, "a non-negative integer")
    return int(seed)


def fixed_pattern_rng(sensor_seed: int, effect: str) -> np.random.Generator:
    """Generator of the fixed-pattern map ``effect`` of sensor ``sensor_seed``.

    Parameters
    ----------
    sensor_seed : int
        Seed identifying one physical sensor (>= 0).
    effect : str
        Name in :data:`EFFECT_STREAMS` (``prnu``, ``dark_current``, ``hot_pixels``).
    """
    seed = _check_seed("sensor_seed", sensor_seed)
    return generator(seed, STAGE_DETECTOR_FIXED, EFFECT_STREAMS.get(effect))


def temporal_rng(seed: int, frame_index: int, effect: str) -> np.random.Generator:
    """Generator of the temporal noise ``effect`` of frame ``frame_index`` of dataset ``seed``."""
    s = _check_seed("seed", seed)
    f = _check_seed("frame_index", frame_index)
    return generator(s, STAGE_DETECTOR_TEMPORAL, f, EFFECT_STREAMS.get(effect))
