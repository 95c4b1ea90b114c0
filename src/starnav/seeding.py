"""Reproducible random streams: one scenario seed, split by purpose and frame.

``SeedSequence(seed, spawn_key=(stage, frame, ...))`` is exactly the child that
``SeedSequence(seed).spawn`` would give at those indices, so every stream depends only on the
scenario seed and its keys, never on how many workers there are or in which order frames are
made (DESIGN.md, "Randomness"). Stage keys are fixed integers, listed here once.
"""

from __future__ import annotations

import numpy as np

#: Stage keys of the random streams (never renumber: datasets depend on them).
STAGE_RENDER = 1
STAGE_POINTING = 2
STAGE_DETECTOR_FIXED = 3
STAGE_DETECTOR_TEMPORAL = 4
STAGE_NAVIGATION = 5
STAGE_HIL = 6
STAGE_TERRAIN = 7


def seed_sequence(seed: int, *keys: int) -> np.random.SeedSequence:
    """The child of ``SeedSequence(seed)`` at spawn path ``keys``."""
    if seed < 0:
        raise ValueError(f"seed = {seed!r}: expected a non-negative integer")
    return np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in keys))


def generator(seed: int, *keys: int) -> np.random.Generator:
    """A PCG64 generator for the stream ``keys`` of ``seed``."""
    return np.random.Generator(np.random.PCG64(seed_sequence(seed, *keys)))


def seed_u32(seed: int, *keys: int) -> int:
    """A 32-bit integer seed for the stream ``keys`` (e.g. Mitsuba's sampler seed)."""
    return int(seed_sequence(seed, *keys).generate_state(1, np.uint32)[0])
