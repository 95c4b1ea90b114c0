"""starnav.batch: what-if sweeps and Monte Carlo runs on Dask, presets, and the main job.

Public API (imports are lazy: importing :mod:`starnav.batch` loads neither Dask nor Mitsuba)::

    run_sweep(scenario, grid, out, runs=..., workers=..., scheduler=...) -> SweepResult
    run_flyby_sweep(scenario, grid, out, runs=..., workers=...) -> FlybySweepResult
    over_runs(per_run, runs), over_points(per_point, points, runner=None)  # starnav.batch.runs
    parse_grid, expand, GridAxis, GridPoint       # starnav.batch.grid
    open_runner(workers, scheduler), ClusterError # starnav.batch.cluster
    COLUMNS, read_table                           # starnav.batch.table (documented columns)
    exposure_study_scenario(), exposure_study_header(), demo_scenario()
    get_preset(name), PRESETS, PAPER_CASES        # starnav.batch.presets
    main_job(scenario, out_dir, progress=None) -> dict   # `make demo` / `starnav demo`

See docs/sweep.md.
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_EXPORTS = {
    "run_sweep": "sweep", "SweepResult": "sweep", "summarize_points": "sweep",
    "parse_grid": "grid", "expand": "grid", "GridAxis": "grid", "GridPoint": "grid",
    "UPSTREAM_SECTIONS": "grid",
    "open_runner": "cluster", "ClusterError": "cluster",
    "COLUMNS": "table", "TIMING_COLUMNS": "table", "read_table": "table",
    "exposure_study_scenario": "presets", "exposure_study_header": "presets",
    "demo_scenario": "presets", "get_preset": "presets", "PRESETS": "presets",
    "PAPER_CASES": "presets", "PAPER_EXPOSURES_S": "presets",
    "main_job": "mainjob",
    "run_flyby_sweep": "flyby_sweep", "FlybySweepResult": "flyby_sweep",
    "over_runs": "runs", "over_points": "runs", "run_ids": "runs",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
