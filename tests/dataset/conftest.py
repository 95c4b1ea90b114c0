"""Small, fast scenarios for the dataset tests (128 x 128 px, 4 spp, a few frames).

The camera keeps the AA-STR pitch and f-number with a short focal length (12.5 mm) so that the
Moon at ~80 000 km covers ~40 px: every stage runs, each frame in a fraction of a second.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

SMALL = {
    "camera": {"width": 128, "height": 128, "focal_length_mm": 12.5},
    "render": {"spp": 4},
    "trajectory": {"frames": 4, "cadence_s": 1800.0, "duration_days": 1.0},
    "pointing": {"moon_offset_max_px": 20.0},
}

#: The ``starnav`` command of this environment.
STARNAV = str(Path(sys.executable).with_name("starnav"))


def small_scenario(frames: int = 4, **extra):
    from starnav.config import scenario_from_dict

    data = {k: dict(v) for k, v in SMALL.items()}
    data["trajectory"]["frames"] = frames
    for k, v in extra.items():
        data.setdefault(k, {}).update(v)
    return scenario_from_dict(data)


def write_small_yaml(path: Path, frames: int = 4) -> Path:
    import yaml

    data = {k: dict(v) for k, v in SMALL.items()}
    data["trajectory"]["frames"] = frames
    path.write_text(yaml.safe_dump(data))
    return path


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes)."""
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory):
    """A 4-frame dataset at 0.015 ms and 7.7 ms, made once per session."""
    from starnav.dataset import DatasetOptions, generate

    out = tmp_path_factory.mktemp("ds") / "small"
    generate(small_scenario(), out, options=DatasetOptions(exposures_s=(1.5e-5, 7.7e-3)))
    yield out
    shutil.rmtree(out, ignore_errors=True)
