"""starnav.dataset: navigation datasets on disk (EXR, PNG, JSON), crash-safe and resumable.

Public API (imports are lazy: importing :mod:`starnav.dataset` loads nothing heavy)::

    open(path, exposure=None) -> Dataset          # reader; a navigation NavDataset
    verify(path) -> list of problems              # re-hash every file against the manifest
    generate(scenario, out, options=..., resume=..., runner=..., progress=...)
    DatasetOptions, DatasetSummary, Dataset, DatasetFrame
    acquire(radiance, geom, camera, scenario, exposure_time=..., run=..., windows=...)
    Acquisition, acquisition_seed                 # the emulated tracker acquisitions
    TaskRunner, InProcessRunner                   # how frames are made (Dask: starnav.batch)
    read_flyby(path), navigate_flyby_dataset(path, out, runs)   # a fly-by dataset

The format is documented in ``docs/dataset.md`` and :mod:`starnav.dataset.format`.
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_EXPORTS = {
    "open": "reader", "verify": "reader", "read_manifest": "reader", "Dataset": "reader",
    "DatasetFrame": "reader",
    "generate": "writer", "DatasetOptions": "writer", "DatasetSummary": "writer",
    "DatasetLockedError": "writer", "make_frame": "writer", "FrameMaker": "writer",
    "acquire": "acquire", "Acquisition": "acquire", "acquisition_seed": "acquire",
    "WINDOWS_MODES": "acquire",
    "TaskRunner": "runner", "InProcessRunner": "runner",
    "SCHEMA_VERSION": "format",
    "read_flyby": "flyby", "navigate_flyby_dataset": "flyby", "is_flyby_dataset": "flyby",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
