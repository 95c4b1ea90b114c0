"""Small sweeps for the batch tests (128 x 128 px, 4 spp, a few frames)."""

from __future__ import annotations

import os

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

SMALL = {
    "camera": {"width": 128, "height": 128, "focal_length_mm": 12.5},
    "render": {"spp": 4},
    "trajectory": {"frames": 5, "cadence_s": 1800.0, "duration_days": 1.0},
    "pointing": {"moon_offset_max_px": 20.0},
}


def small_scenario(frames: int = 5, overrides: tuple[str, ...] = ()):
    from starnav.config import scenario_from_dict

    data = {k: dict(v) for k, v in SMALL.items()}
    data["trajectory"]["frames"] = frames
    return scenario_from_dict(data, list(overrides))


def deterministic(rows):
    """Rows without the wall-clock columns."""
    from starnav.batch.table import TIMING_COLUMNS

    return [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]
