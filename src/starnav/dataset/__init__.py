"""starnav.dataset: navigation datasets on disk (EXR, PNG, JSON), crash-safe and resumable.

Public API (imports are lazy: importing :mod:`starnav.dataset` loads nothing heavy)::

    open(path, exposure=None) -> Dataset          # reader; a navigation NavDataset
    verify(path) -> list of problems              # re-hash every file against the manifest
    generate(scenario, out, options=..., resume=..., runner=..., progress=...)
    DatasetOptions, DatasetSummary, Dataset, DatasetFrame
    acquire(radiance, geom, camera, scenario, exposure_s=..., run=..., windows=...)
    Acquisition, acquisition_seed                 # the emulated tracker acquisitions
    TaskRunner, InProcessRunner                   # how frames are made (Dask: starnav.batch)

The format is documented in ``docs/dataset.md`` and :mod:`starnav.dataset.format`.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "open": "reader", "verify": "reader", "read_manifest": "reader", "Dataset": "reader",
    "DatasetFrame": "reader",
    "generate": "writer", "DatasetOptions": "writer", "DatasetSummary": "writer",
    "DatasetLockedError": "writer", "make_frame": "writer", "FrameMaker": "writer",
    "acquire": "acquire", "Acquisition": "acquire", "acquisition_seed": "acquire",
    "WINDOWS_MODES": "acquire",
    "TaskRunner": "runner", "InProcessRunner": "runner",
    "SCHEMA_VERSION": "format",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'starnav.dataset' has no attribute {name!r}")
    return getattr(importlib.import_module(f"starnav.dataset.{mod}"), name)


def __dir__() -> list[str]:
    return __all__
