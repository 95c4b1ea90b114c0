"""Warm Dask workers: a worker process pays its one-off costs when it starts, not in its first
task.

A fresh worker process spends seconds before its first frame: importing starnav's chain
(NumPy, SciPy, pydantic, the navigation and detector modules), loading Mitsuba and Dr.Jit and
choosing the variant, and reading the solar spectrum (packaged since issue 18: reading it
through ``colour`` took ~4 s on the 2-core development machine). :func:`warm` does these once
per process;
the scenario-specific set-up (scene, renderer, kernels) stays in the per-process caches the
tasks use (:func:`starnav.simulate.simulator_for`, :func:`starnav.dataset.writer.frame_maker`).

Use it as a Dask *preload*: a module with ``dask_setup(worker)`` that the worker runs before it
registers with the scheduler, so no task is sent to a worker that is still cold, and a worker
that a nanny restarts after a crash is warm again before it takes work:

.. code-block:: bash

    dask worker --scheduler-file sched.json --nthreads 1 --preload starnav.batch.warm

:func:`starnav.batch.cluster.open_runner` gives it to the workers of the local clusters it
starts (``cluster.WORKER_PRELOAD``). The time moves from the first tasks to the cluster start
(measured in ``benchmarks/sweep.py``, docs/performance.md); a worker that lives across several
sweeps pays it once.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import starnav.batch.tasks  # noqa: F401  (the sweep tasks and everything they import)
import starnav.dataset.writer  # noqa: F401  (the dataset task)
from starnav.renderer import backend
from starnav.spectra import SunConfig, solar_spectrum_from_config

log = logging.getLogger(__name__)


def warm() -> dict[str, Any]:
    """Load Mitsuba with the default variant preference and the default solar spectrum in this
    process; what was chosen and how long it took [s]."""
    t0 = time.perf_counter()
    info = backend.activate(backend.DEFAULT_VARIANTS)
    solar_spectrum_from_config(SunConfig())
    dt = time.perf_counter() - t0
    log.info("worker warmed in %.1f s (variant %s)", dt, info.variant)
    return {"variant": info.variant, "seconds": dt}


def dask_setup(worker: Any = None) -> None:
    """Dask's preload hook (``dask worker --preload starnav.batch.warm``): :func:`warm`."""
    warm()
