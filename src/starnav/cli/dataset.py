"""``starnav dataset SCENARIO --out DIR [--resume] [--exposures T1,T2]``: a navigation dataset;
``starnav dataset verify DIR``: check one.

Thin: parses, loads the scenario, calls :func:`starnav.dataset.generate` with a rich progress
bar (frames done, rate, ETA) and prints a summary; ``verify`` calls
:func:`starnav.dataset.verify`. ``dataset`` is a group whose default command is ``make``:
``starnav dataset SCENARIO ...`` is ``starnav dataset make SCENARIO ...``, so the one-command
form the docs, the Makefile and scripts use keeps working. The dataset format is in
docs/dataset.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from typer.core import TyperGroup

from starnav.cli._units import parse_time, parse_times


def parse_exposure_sets(items: list[str] | tuple[str, ...]
                        ) -> tuple[tuple[float, tuple[str, ...]], ...]:
    """``["7.7ms:a.b=1", "7.7e-3:c=2"]`` -> ``((0.0077, ("a.b=1", "c=2")),)`` (times as
    :func:`starnav.cli._units.parse_time` reads them)."""
    from starnav.errors import ConfigError

    by: dict[float, list[str]] = {}
    for it in items:
        t, sep, rest = it.partition(":")
        if not sep or "=" not in rest:
            raise ConfigError("--exposure-set", it, "TIME:KEY=VALUE, e.g. "
                              "7.7ms:detector.readout.segments.thresholds_dn=[2048]")
        tv = parse_time(t, "--exposure-set")
        by.setdefault(tv, []).append(rest.strip())
    return tuple((t, tuple(v)) for t, v in by.items())


def frames_progress():
    """A rich progress bar with frames done, rate and ETA."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TextColumn("ETA"),
                    TimeRemainingColumn())


class DefaultMakeGroup(TyperGroup):
    """A group whose arguments go to its ``make`` command unless they start with another of its
    commands or ask for the group's help (``starnav dataset --help``)."""

    default = "make"

    def parse_args(self, ctx, args: list[str]) -> list[str]:  # type: ignore[no-untyped-def]
        if not args or (args[0] not in self.commands and args[0] not in ctx.help_option_names):
            args = [self.default, *args]
        return super().parse_args(ctx, args)


def register(app: typer.Typer) -> None:
    """Add the ``dataset`` group (``make``, the default, and ``verify``) to ``app``."""
    group = typer.Typer(cls=DefaultMakeGroup, no_args_is_help=False, help=(
        "Navigation datasets: `starnav dataset \\[make] SCENARIO --out DIR` makes one (make is "
        "the default command), `starnav dataset verify DIR` checks one."))
    app.add_typer(group, name="dataset")

    @group.command("verify")
    def verify_cmd(
        directory: Annotated[Path, typer.Argument(help="dataset directory")],
    ) -> None:
        """Check a dataset against its manifest: every expected frame present, every file's
        size and SHA-256, no temporary left. Exit 0 with one line when it is complete and
        intact, 2 with the list of problems otherwise."""
        from starnav.cli._output import print_error
        from starnav.dataset import read_manifest, verify

        problems = verify(directory)
        if problems:
            print_error(f"dataset {str(directory)!r}: {len(problems)} problem(s)")
            for p in problems:
                typer.echo(f"  {p}", err=True)
            raise typer.Exit(code=2)
        man = read_manifest(directory)
        n = len(man["frames"])
        files = sum(len(e["files"]) for e in man["frames"])
        typer.echo(f"{directory}: complete, {n} of {man['frames_expected']} frames, {files} "
                   "files verified (size and SHA-256)")

    @group.command("make")
    def dataset_cmd(
        scenario: Annotated[Path | None, typer.Argument(
            help="scenario YAML (default: built-in)")] = None,
        out: Annotated[Path | None, typer.Option(
            "--out", help="dataset directory (default: output.directory/dataset)")] = None,
        resume: Annotated[bool, typer.Option(
            "--resume", help="continue an interrupted dataset in OUT")] = False,
        exposures: Annotated[str | None, typer.Option(
            "--exposures", help="exposure times, comma-separated, in s or with a unit "
            "(15us,7.7ms; default: detector.exposure_time_s)")] = None,
        exposure_set: Annotated[list[str] | None, typer.Option(
            "--exposure-set", help="override for one exposure, T:KEY=VALUE with a detector.* "
            "or navigation.* key, e.g. 7.7ms:detector.readout.segments.thresholds_dn=[2048]")
        ] = None,
        windows: Annotated[str, typer.Option(
            "--windows", help="windows read from a 'second' acquisition (default), the "
            "'same' one, or 'none'")] = "second",
        no_radiance: Annotated[bool, typer.Option(
            "--no-radiance", help="do not store radiance.exr")] = False,
        workers: Annotated[int, typer.Option(
            "--workers", min=0, help="0: this process; N: a local Dask cluster of N "
            "processes")] = 0,
        scheduler: Annotated[str | None, typer.Option(
            "--scheduler", help="existing Dask scheduler tcp://HOST:PORT (shared file "
            "system)")] = None,
        scheduler_file: Annotated[Path | None, typer.Option(
            "--scheduler-file", help="read the scheduler's address from the file `dask "
            "scheduler --scheduler-file` wrote")] = None,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override a scenario key: a.b=value")] = None,
    ) -> None:
        """Render, expose and read out every frame of SCENARIO into OUT (resumable)."""
        import time

        from rich.console import Console
        from rich.table import Table

        from starnav.batch.cluster import open_runner, resolve_scheduler
        from starnav.config import load_scenario
        from starnav.dataset import DatasetOptions, generate
        from starnav.errors import StarnavError

        console = Console()
        state = {"n": 0, "done": 0}
        from starnav.cli._output import check_output

        try:
            scheduler = resolve_scheduler(scheduler, scheduler_file)
            sc = load_scenario(scenario, tuple(set_ or ()))
            out = out if out is not None else sc.output.directory / "dataset"
            exps = None if exposures is None else parse_times(exposures, "--exposures")
            opts = DatasetOptions(exposures_s=exps, windows=windows, radiance=not no_radiance,
                                  exposure_overrides=parse_exposure_sets(exposure_set or ()))
            check_output(out, directory=True, overwrite=resume, flag="--resume",
                         inputs=[scenario, scheduler_file],
                         action="continue the dataset it holds")
            bar = frames_progress()
            task = bar.add_task("frames", total=None, rate="", start=False)
            first: dict[str, float] = {}

            def progress(done: int, total: int) -> None:
                now = time.perf_counter()
                if "t" not in first:  # the bar appears once the set-up has passed
                    first["t"], first["done"] = now, done
                    bar.start()
                    bar.start_task(task)
                dt = now - first["t"]
                made = done - first["done"]
                rate = f"{made / dt:.2f} frames/s" if made and dt > 0 else ""
                bar.update(task, completed=done, total=total, rate=rate)
                state["n"], state["done"] = total, done

            try:
                with open_runner(workers, scheduler) as runner:
                    summary = generate(sc, out, options=opts, resume=resume, runner=runner,
                                       progress=progress)
            finally:
                bar.stop()
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        except OSError as err:  # a full disk: the frames made stay, --resume continues
            from starnav.cli._output import fail, os_error_message

            fail(os_error_message(err, resumable=True))
        except KeyboardInterrupt:
            typer.echo(f"interrupted: {state['done']} of {state['n']} frames are in {out}; "
                       "continue with --resume", err=True)
            raise typer.Exit(code=130) from None
        table = Table(title=f"dataset {out}", show_header=False)
        table.add_row("frames", f"{summary.frames} ({summary.frames_made} made now)")
        table.add_row("runner", summary.runner)
        table.add_row("set-up", f"{summary.setup_s:.1f} s")
        table.add_row("rate", f"{summary.frames_per_s:.3g} frames/s" if summary.frames_made
                      else "nothing left to make")
        table.add_row("elapsed", f"{summary.elapsed_s:.1f} s")
        if not summary.exposures_s:
            table.add_row("fly-by", "radiance and truth per frame; segments and windows "
                          "exposed by `starnav navigate DIR`")
        for name, s in summary.per_exposure.items():
            sat = s["saturated_pixels_median"]
            wp = s["windows_planned_fraction"]
            table.add_row(name, f"saturated px (median) {sat:g}; windows planned in "
                          f"{100 * wp:.0f} % of frames; readout law "
                          f"{'ok' if s['feasible'] else 'INFEASIBLE on the AA-STR (fictitious)'}")
        console.print(table)
        console.print(f"manifest: {out / 'manifest.json'}")
