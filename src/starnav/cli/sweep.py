"""``starnav sweep SCENARIO --grid KEY=V1,V2 ... --runs N --out DIR``: what-if grids on Dask.

Thin: parses, loads the scenario (or a preset's), calls :func:`starnav.batch.run_sweep` with a
rich progress bar over the tasks, and prints the per-point medians and where the report is.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from starnav.config import Scenario


def register(app: typer.Typer) -> None:
    """Add the ``sweep`` command to ``app``."""

    @app.command("sweep")
    def sweep_cmd(
        scenario: Annotated[Path | None, typer.Argument(
            help="scenario YAML (default: the preset's, or the built-in one)")] = None,
        grid: Annotated[list[str] | None, typer.Option(
            "--grid", help="an axis KEY=V1,V2,... (repeat for a product), e.g. "
            "detector.exposure_time_s=1.5e-5,7.7e-3")] = None,
        preset: Annotated[str | None, typer.Option(
            "--preset", help="a ready study: exposure-study (grid, runs, and the scenario "
            "when none is given)")] = None,
        runs: Annotated[int | None, typer.Option(
            "--runs", min=1, help="Monte Carlo runs per point (default: navigation.runs or "
            "the preset's)")] = None,
        out: Annotated[Path, typer.Option("--out", help="output directory (new or empty)")
                       ] = Path("out/sweep"),
        workers: Annotated[int | None, typer.Option(
            "--workers", min=0, help="local Dask worker processes (0: this process; default: "
            "the CPU count)")] = None,
        scheduler: Annotated[str | None, typer.Option(
            "--scheduler", help="existing Dask scheduler, tcp://HOST:PORT")] = None,
        scheduler_file: Annotated[Path | None, typer.Option(
            "--scheduler-file", help="read the scheduler's address from the file `dask "
            "scheduler --scheduler-file` wrote")] = None,
        windows: Annotated[str | None, typer.Option(
            "--windows", help="windows acquisition: second, same or none (default: second "
            "when navigation.refine.enabled, else none)")] = None,
        overwrite: Annotated[bool, typer.Option(
            "--overwrite", help="replace a previous sweep in OUT")] = False,
        no_figures: Annotated[bool, typer.Option("--no-figures", help="skip the PNGs")] = False,
        title: Annotated[str | None, typer.Option("--title", help="report title")] = None,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override a base-scenario key: a.b=value")] = None,
    ) -> None:
        """Run a what-if grid (product of --grid axes) x --runs Monte Carlo runs; write
        results.parquet/.csv, figures/ and report.md into OUT. A fly-by scenario sweeps
        v_inf_km_s, closest_approach_km, phase_at_ca_deg (one task per point) and writes
        sweep.csv/.md/.png."""
        from starnav.batch import run_sweep
        from starnav.batch.cluster import resolve_scheduler
        from starnav.batch.presets import get_preset
        from starnav.batch.sweep import summarize_points
        from starnav.cli._output import check_output, console, print_table
        from starnav.cli.dataset import frames_progress
        from starnav.config import load_scenario, scenario_from_dict
        from starnav.errors import StarnavError
        from starnav.simulate.flyby import is_flyby_scenario

        try:
            check_output(out, directory=True, overwrite=overwrite,
                         inputs=[scenario, scheduler_file])
            scheduler = resolve_scheduler(scheduler, scheduler_file)
            p = get_preset(preset) if preset else None
            if runs is not None:  # checked by the schema's navigation.runs (its bound)
                set_ = [*(set_ or ()), f"navigation.runs={runs}"]
            if scenario is None and p is not None:
                sc = scenario_from_dict(p.scenario(), tuple(set_ or ()))
            else:
                sc = load_scenario(scenario, tuple(set_ or ()))
            axes = list(grid or ()) or (list(p.grid) if p else [])
            n_runs = runs if runs is not None else (p.runs if p else None)
            if is_flyby_scenario(sc):
                _flyby(sc, axes, out, n_runs, workers, scheduler, overwrite, no_figures)
                return
            bar = frames_progress()
            task = bar.add_task("tasks", total=None, rate="", start=False)
            started: list[bool] = []

            def progress(done: int, total: int) -> None:
                if not started:
                    started.append(True)
                    bar.start()
                    bar.start_task(task)
                bar.update(task, completed=done, total=total)

            try:
                res = run_sweep(sc, axes, out, runs=n_runs, workers=workers,
                                scheduler=scheduler, windows=windows, progress=progress,
                                figures=not no_figures, overwrite=overwrite,
                                title=title or (f"starnav sweep: {preset}" if preset else None))
            finally:
                bar.stop()
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        title = (f"sweep: {len(res.points)} point(s) x "
                 f"{len(res.rows) // max(len(res.points), 1)} run(s), {res.elapsed_s:.1f} s; "
                 "medians over runs")
        heads = ["point", "scenario", "sat px", "limb bias [px]", "limb std [px]",
                 "final pos err [km] (% range)", "final vel err [m/s]"]
        rows = []
        for s in summarize_points(res.rows):
            rows.append([str(s["point"]), s["label"],
                          f"{s.get('saturated_pixels_median', float('nan')):.0f}",
                          f"{s.get('limb_bias_px', float('nan')):+.2f}",
                          f"{s.get('limb_std_px', float('nan')):.2f}",
                          f"{s.get('final_position_error_m', float('nan')) / 1e3:.4g} "
                          f"({s.get('final_position_error_pct_range', float('nan')):.3g})",
                          f"{s.get('final_velocity_error_m_s', float('nan')):.3g}"])
        print_table(title, heads, rows, console)
        console.print(f"runner: {res.runner}")
        console.print(f"report: [bold]{res.paths['report']}[/]; table: {res.paths['parquet']}")


def _flyby(sc: Scenario, axes: list[str], out: Path, runs: int | None, workers: int | None,
           scheduler: str | None, overwrite: bool, no_figures: bool) -> None:
    """The fly-by sweep (:func:`starnav.batch.flyby_sweep.run_flyby_sweep`) with a progress
    bar over the points, then its table."""
    from starnav.batch.flyby_sweep import run_flyby_sweep
    from starnav.cli._output import console, print_table
    from starnav.cli.dataset import frames_progress

    bar = frames_progress()
    task = bar.add_task("points", total=None, rate="", start=False)
    started: list[bool] = []

    def progress(done: int, total: int) -> None:
        if not started:          # after the checks: an error is one line
            started.append(True)
            bar.start()
            bar.start_task(task)
        bar.update(task, completed=done, total=total)

    try:
        res = run_flyby_sweep(sc, axes, out, runs=runs, workers=workers, scheduler=scheduler,
                              progress=progress, figures=not no_figures, overwrite=overwrite)
    finally:
        bar.stop()
    heads = ["v_inf [km/s]", "CA [km]", "phase [deg]", "CA err med [% range]", "mean NEES",
             "band", "verdict"]
    rows = [[f"{r['v_inf_km_s']:g}", f"{r['closest_approach_km']:g}",
             f"{r['phase_at_ca_deg']:g}", f"{r['ca_error_pct_range_median']:.3f}",
             f"{r['nees_mean']:.2f}", f"[{r['nees_band_lo']:.2f}, {r['nees_band_hi']:.2f}]",
             str(r["verdict"])] for r in res.rows]
    print_table(f"fly-by sweep: {len(res.rows)} point(s), {res.elapsed_s:.1f} s", heads, rows,
                console)
    console.print(f"runner: {res.runner}")
    console.print(f"table: [bold]{res.paths['table']}[/]")
