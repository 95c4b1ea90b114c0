"""Reproducible random streams: one scenario seed, split by purpose and frame.

``SeedSequence(seed, spawn_key=(stage, frame, ...))`` is exactly the child that
``SeedSequence(seed).spawn`` would give at those indices, so every stream depends only on the
scenario seed and its keys, never on how many workers there are or in which order frames are
made. Stage keys are fixed integers, listed here once.

The procedural Moon is the one world that is not drawn from the scenario seed: its terrain,
albedo and sub-posting detail come from their own seeds (``moon.dem.procedural.seed``,
``moon.dem.detail.seed``), so that one world can be flown through by many scenarios. Its
streams are children of *that* seed under the world keys below (``WORLD_*``, which are not
stages and may share numbers with them: the root seed differs), followed by the stream's own
indices (a crater octave, a noise octave). They were fixed when the procedural Moon was first
written; renumbering them would change every procedural world.
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
STAGE_FLYBY_SYNTHETIC = 8   # synthetic fly-by measurements and initial errors (trn.synthetic)
STAGE_CAMERA_CALIBRATION = 9  # a run's bench calibration of the camera (camera_calibration)

#: Stream keys under a procedural world's own seed (never renumber: worlds depend on them).
WORLD_CRATERS = 1
WORLD_BASINS = 2
WORLD_FRACTAL = 3
WORLD_DETAIL = 4


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


def seed_u64(seed: int, *keys: int) -> int:
    """A 64-bit integer seed for the stream ``keys`` (e.g. a hashed noise lattice)."""
    return int(seed_sequence(seed, *keys).generate_state(1, np.uint64)[0])
