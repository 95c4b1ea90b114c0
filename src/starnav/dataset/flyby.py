"""``starnav navigate DATASET`` of a fly-by: the closed loop on a dataset's stored radiance.

A fly-by's acquisitions cannot be fixed in a dataset: the front end places a frame's windows
from the previous frame's tracks (and from the run's own noise and estimate), so the windows
a run reads exist only inside that run. A fly-by dataset (``starnav dataset FLYBY.yaml``)
therefore keeps what does not depend on the run: every frame's full-frame spectral radiance
with its per-pixel truth (``radiance.exr``: the body-fixed surface point, normal and
coordinates AOVs), the frame's truth (``truth.json``: geometry, the true trajectory) and the
exposures of the dataset's own acquisitions (for inspection). Navigating it re-exposes the
segments and windows from the stored radiance at navigate time, run by run
(:func:`starnav.simulate.flyby.navigate_flyby` with the dataset's renders), exactly as the
scenario's closed loop does after rendering: the same radiance gives the same runs.

Steps: (1) open the dataset (complete, with radiance) and its resolved scenario, check it is
a fly-by; (2) rebuild the frames' geometry from that scenario and check it against the
dataset's frame count and indices; (3) the closed loop and its outputs.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from starnav.dataset.reader import Dataset, read_manifest
from starnav.dataset.reader import open as open_dataset
from starnav.errors import DataFileError, StarnavError
from starnav.simulate.flyby import Renders, check_flyby_scenario, navigate_flyby
from starnav.simulate.frames import Simulator


def is_flyby_dataset(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a dataset made from a fly-by scenario (False for anything
    else, errors included: the limb path reports those)."""
    try:
        cfg = read_manifest(path).get("config", {})
    except (StarnavError, OSError, ValueError):
        return False
    return (cfg.get("trajectory") or {}).get("source") == "flyby"


def flyby_renders(ds: Dataset, sim: Simulator) -> Renders:
    """Every frame of the dataset as ``(geometry, radiance)``, the geometry rebuilt from the
    dataset's scenario (``sim``); a dataset that does not hold every frame of it, in order,
    or was made without radiance, is a DataFileError naming it."""
    if len(ds) != len(sim):
        raise DataFileError(f"dataset {str(ds.path)!r}: {len(ds)} frames, its scenario has "
                            f"{len(sim)} (a fly-by is navigated over every frame)")
    out = []
    for i in range(len(sim)):
        frame = ds[i]
        if frame.index != i:
            raise DataFileError(f"dataset {str(ds.path)!r}: frame {i} is index {frame.index}")
        out.append((sim.geometry(i), frame.radiance()))
    return out


def navigate_flyby_dataset(path: str | os.PathLike[str], out: str | os.PathLike[str],
                           runs: int | None = None, overrides: tuple[str, ...] = (), *,
                           plots: bool = True) -> dict[str, Any]:
    """The fly-by closed loop over the dataset at ``path`` (module essay): ``runs`` runs
    (default ``navigation.runs``), outputs as :func:`~starnav.simulate.flyby.navigate_flyby`
    into ``out``. ``overrides`` (``KEY=VALUE``) apply to the dataset's scenario (navigation
    settings, the seed of the runs). Returns the metrics dict."""
    ds = open_dataset(Path(path))
    sc = ds.scenario(overrides)
    check_flyby_scenario(sc)
    sim = Simulator(sc)
    renders = flyby_renders(ds, sim)
    n = sc.navigation.runs if runs is None else runs
    return navigate_flyby(sim, out, n, plots=plots, renders=renders)
