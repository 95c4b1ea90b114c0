"""Warm Dask workers: a worker process pays its one-off costs when it starts, not in its first
task.

:func:`warm` imports starnav's chain, loads Mitsuba and chooses the variant, reads the solar
spectrum and the packaged data every default sweep needs (:func:`warm_data`: the LOLA limb
topography, the Hipparcos catalogue and its pair table), once per process; scenario-specific
set-up stays in the per-process caches of the tasks (:func:`starnav.simulate.simulator_for`,
:func:`starnav.dataset.writer.frame_maker`).

Use it as a Dask *preload* (``dask_setup(worker)`` runs before the worker registers, so no
task reaches a cold worker, and a restarted worker is warm again before it takes work)::

    dask worker --scheduler-file sched.json --nthreads 1 --preload starnav.batch.warm

:func:`starnav.batch.cluster.open_runner` gives it to the local clusters it starts
(``cluster.WORKER_PRELOAD``); the cost it moves: docs/performance.md.

Index
-----
:func:`warm`, :func:`warm_data`, :func:`dask_setup`.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import starnav.batch.tasks  # noqa: F401  (the sweep tasks and everything they import)
import starnav.dataset.writer  # noqa: F401  (the dataset task)
from starnav.config import build_camera, scenario_from_dict
from starnav.dem.limb import limb_topography_for
from starnav.renderer import backend
from starnav.scenes.ephemeris import parse_epoch
from starnav.scenes.schema import DEFAULT_EPOCH
from starnav.spectra import SunConfig, solar_spectrum_from_config
from starnav.stars.catalogue import hipparcos, jyear_from_tdb
from starnav.stars.identify import IdentifyOptions, star_index

log = logging.getLogger(__name__)


def warm() -> dict[str, Any]:
    """Load Mitsuba with the default variant preference and the default solar spectrum in this
    process, and the packaged data every sweep of the default Moon and tracker reads (see
    :func:`warm_data`); what was chosen and how long it took [s]."""
    t0 = time.perf_counter()
    info = backend.activate(backend.DEFAULT_VARIANTS)
    solar_spectrum_from_config(SunConfig())
    data = warm_data()
    dt = time.perf_counter() - t0
    log.info("worker warmed in %.1f s (variant %s; data %s)", dt, info.variant, data)
    return {"variant": info.variant, "seconds": dt, "data_s": data}


def warm_data() -> dict[str, float]:
    """Read into this process's caches what the first task of every worker would otherwise
    read, paid again by each worker of a sweep (``benchmarks/sweep.py``): the limb topography
    of the default DEM (the packaged LOLA LDEM_4, for the navigation chain's limb-height
    prior, :func:`starnav.dem.limb.limb_topography_for`), the
    Hipparcos catalogue and its lost-in-space pair table for the default camera in the year
    of a trajectory's default first epoch (:func:`starnav.stars.identify.star_index`; the
    demo's and the exposure study's frames). Scenarios with
    another DEM, camera or year fill their own cache entries in their first task, as before.
    Seconds per item; an item that fails is logged and left to the task (which reports it)."""
    sc = scenario_from_dict({})
    out: dict[str, float] = {}

    def timed(name: str, fn: Any) -> None:
        t = time.perf_counter()
        try:
            fn()
        except Exception as err:  # noqa: BLE001 - warming is best effort; the task reports
            log.warning("warming %s failed: %s", name, err)
        out[name] = round(time.perf_counter() - t, 3)

    timed("limb_topography", lambda: limb_topography_for(sc.moon.dem))
    timed("hipparcos", hipparcos)
    # the year of a trajectory's default first epoch: the demo's and the exposure study's
    # frames (the stars are drawn at each frame's epoch, the pair table per year)
    year = jyear_from_tdb(parse_epoch(DEFAULT_EPOCH))
    timed("star_index", lambda: star_index(hipparcos(), IdentifyOptions().index_v_limit,
                                           build_camera(sc.camera).fov_diagonal, year))
    return out


def dask_setup(worker: Any = None) -> None:
    """Dask's preload hook (``dask worker --preload starnav.batch.warm``): :func:`warm`."""
    warm()
