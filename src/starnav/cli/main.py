"""The ``starnav`` command line: thin commands over the library.

Each command parses its arguments, loads and validates the scenario (with ``--set a.b=value``
overrides), calls one library function and writes its outputs plus the resolved scenario next to
them. Errors from the library are shown as one clear line and exit with status 2.
"""

from __future__ import annotations

import json
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
import yaml
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from starnav import __version__
from starnav.cli._output import console, fail, os_error_message
from starnav.errors import StarnavError
from starnav.registry import Registry

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="starnav: a star tracker as a navigation camera, from photons to "
                  "navigation.")
#: Errors: stderr, never wrapped nor cropped (``soft_wrap``), whatever the terminal width, so a
#: message and the paths in it stay on one line (rich wraps at 80 columns when not on a terminal).

ScenarioArg = Annotated[Path | None, typer.Argument(help="scenario YAML (default: built-in)")]
SetOpt = Annotated[list[str] | None, typer.Option("--set", help="override a key: a.b=value")]


def _fail(err: Exception) -> None:
    fail(err)


def _load(scenario: Path | None, overrides: list[str] | None):
    from starnav.config import load_scenario

    try:
        return load_scenario(scenario, overrides or [])
    except StarnavError as err:
        _fail(err)


def progress_bar() -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                    TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(),
                    TimeRemainingColumn(), console=console)


@app.callback()
def _main(verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")


@app.command()
def info() -> None:
    """Versions, Mitsuba variants available, the variant chosen and the LLVM used."""
    from starnav.renderer import backend

    v = backend.versions()
    table = Table(title=f"starnav {__version__}", show_header=False)
    table.add_row("python", sys.version.split()[0])
    table.add_row("mitsuba", str(v["mitsuba"]))
    table.add_row("drjit", str(v["drjit"]))
    table.add_row("variants compiled", ", ".join(v["variants"]))
    cands = backend.llvm_candidates()
    table.add_row("libLLVM found", ", ".join(f"{c.path} ({c.major})" for c in cands) or "none")
    try:
        chosen = backend.activate()
        table.add_row("variant chosen", chosen.variant)
        table.add_row("LLVM used", chosen.llvm_path or "not used")
        if chosen.llvm_target:
            t = chosen.llvm_target
            table.add_row("LLVM target", f"{t['cpu']}, {t['vector_width']} lanes, "
                          f"{' '.join(t['simd'])}")
        for v, why in chosen.reasons.items():
            table.add_row(f"skipped {v}", why)
    except StarnavError as err:
        table.add_row("variant chosen", f"none: {err}")
    console.print(table)


def _default_preset() -> tuple[str, dict[str, Any]]:
    from starnav.config import EXAMPLE_HEADER, Scenario, scenario_to_dict

    return EXAMPLE_HEADER, scenario_to_dict(Scenario())


def _exposure_study_preset() -> tuple[str, dict[str, Any]]:
    from starnav.batch.presets import exposure_study_header, exposure_study_scenario

    return exposure_study_header(), exposure_study_scenario()


def _demo_preset() -> tuple[str, dict[str, Any]]:
    from starnav.batch.presets import demo_scenario
    from starnav.config import EXAMPLE_HEADER, scenario_from_dict, scenario_to_dict

    header = EXAMPLE_HEADER + "# preset: the `make demo` scenario (a LUMIO arc)\n"
    return header, scenario_to_dict(scenario_from_dict(demo_scenario()))


def _flyby_preset() -> tuple[str, dict[str, Any]]:
    from starnav.batch.presets import flyby_header, flyby_scenario
    from starnav.config import EXAMPLE_HEADER

    return EXAMPLE_HEADER + flyby_header(), flyby_scenario()


#: Scenario presets of ``starnav init``: name -> () -> (commented header, scenario mapping).
INIT_PRESETS: Registry[Callable[[], tuple[str, dict[str, Any]]]] = Registry("preset", {
    "default": _default_preset, "exposure-study": _exposure_study_preset, "demo": _demo_preset,
    "flyby": _flyby_preset})


@app.command()
def init(
    out: Annotated[Path, typer.Argument(help="scenario file to write")] = Path("scenario.yaml"),
    preset: Annotated[str, typer.Option(help=f"scenario preset: {', '.join(INIT_PRESETS)}")]
    = "default",
    overwrite: Annotated[bool, typer.Option("--overwrite", "--force",
                                            help="replace an existing file")] = False,
) -> None:
    """Write a commented example scenario (every key at its value for the preset, with its
    description, unit and allowed values from the schema above it)."""
    from starnav.atomic import atomic_write_text
    from starnav.cli._output import check_output
    from starnav.config import Scenario
    from starnav.config_base import commented_yaml

    check_output(out, directory=False, overwrite=overwrite, option="OUT")
    try:
        make = INIT_PRESETS.get(preset)
    except StarnavError as err:  # UnknownNameError: lists the known presets
        _fail(err)
    header, data = make()
    atomic_write_text(out, header + "\n" + commented_yaml(Scenario, data))
    console.print(f"wrote {out}")


@app.command()
def validate(scenario: ScenarioArg = None, set_: SetOpt = None) -> None:
    """Validate a scenario as far as rendering it would (camera, spectra, target body and its
    files, every frame's geometry, navigation options) and print it fully resolved, with the
    derived quantities."""
    from starnav.config import scenario_to_dict
    from starnav.simulate.check import check_scenario

    sc = _load(scenario, set_)
    try:
        derived = check_scenario(sc)
    except StarnavError as err:
        _fail(err)
    console.print(yaml.safe_dump(scenario_to_dict(sc), sort_keys=False))
    console.print("[green]valid[/]  derived: " + json.dumps(_significant(derived)))


def _significant(value: Any, digits: int = 6) -> Any:
    """``value`` with floats to ``digits`` significant digits (never rounded away to 0)."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}")
    if isinstance(value, dict):
        return {k: _significant(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_significant(v, digits) for v in value]
    return value


@app.command()
def render(
    scenario: ScenarioArg = None,
    out: Annotated[Path | None, typer.Option(
        "--out", help="output directory (default: output.directory/render)")] = None,
    set_: SetOpt = None,
    preview: Annotated[bool, typer.Option(
        "--preview", help="also write an 8-bit PNG per frame next to its EXR: L from 0 to the "
        "99.9th percentile of the lit pixels, labelled (starnav.preview)")] = False,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an earlier render in OUT (its frame_* files and "
        "scenario.resolved.yaml are removed first); without it such a directory is refused")
    ] = False,
) -> None:
    """Render the scenario's frames to OpenEXR (channels L, Le and the AOVs)."""
    from starnav.cli._output import check_output
    from starnav.config import write_resolved
    from starnav.simulate import frame_geometries, render_to_directory
    from starnav.simulate.outdir import previous_render

    sc = _load(scenario, set_)
    out = out if out is not None else sc.output.directory / "render"
    # an earlier render in OUT: refused (or replaced) by render_to_directory, which names it
    check_output(out, directory=True, overwrite=overwrite, inputs=[scenario],
                 ours=lambda d: bool(previous_render(d)))
    try:
        n = len(frame_geometries(sc))
        with progress_bar() as bar:
            task = bar.add_task("render", total=n)
            paths = render_to_directory(sc, out, lambda k, t: bar.update(task, completed=k),
                                        overwrite=overwrite)
        if preview:
            from starnav.preview import write_previews

            write_previews(paths)
        write_resolved(sc, out)
    except StarnavError as err:
        _fail(err)
    console.print(f"wrote {len(paths)} frame(s) to {out}" + (" (EXR + preview PNG)" if preview
                                                             else ""))


#: What ``starnav demo`` writes into its output directory (a re-run continues it).
DEMO_ENTRIES = frozenset({"dataset", "navigation", "figures", "report.md",
                          "scenario.resolved.yaml"})


def _is_demo_output(out: Path) -> bool:
    """Whether ``out`` holds an earlier ``starnav demo`` and nothing else."""
    return (out / "dataset" / "manifest.json").is_file() and \
        {p.name for p in out.iterdir()} <= DEMO_ENTRIES


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="output directory")] = Path("out/demo"),
    set_: SetOpt = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="write into a non-empty OUT that holds something else (its files "
        "of the same names are replaced); an earlier demo in OUT is continued without it")
    ] = False,
) -> None:
    """The main job on built-in defaults: a short LUMIO-arc dataset at the paper's well-exposed
    and saturated exposures, navigation on it, and the report with its figures."""
    from starnav.batch import main_job
    from starnav.cli._output import check_output

    check_output(out, directory=True, overwrite=overwrite, ours=_is_demo_output)
    try:
        with progress_bar() as bar:
            task = bar.add_task("demo", total=None)
            summary = main_job(None, out, overrides=set_ or (),
                               progress=lambda d, n: bar.update(task, completed=d, total=n))
    except StarnavError as err:
        _fail(err)
    from starnav.cli._output import format_quantity, print_table

    print_table("starnav demo", None, [[k, format_quantity(k, v)] for k, v in summary.items()])
    console.print(f"report: [bold]{summary['report']}[/]")


def _register_parts() -> None:
    """Add the commands owned by the other subpackages."""
    import importlib

    for name in ("trajectory", "dem", "expose", "dataset", "navigate", "sweep", "hil", "show",
                 "real", "stars"):
        importlib.import_module(f"starnav.cli.{name}").register(app)


_register_parts()


def _guarded(callback: Callable[..., Any]) -> Callable[..., Any]:
    """``callback`` with the CLI's error contract: a :class:`StarnavError` or a failed read or
    write (``OSError``: unwritable or full output, a path through a file) is one ``error:`` line
    and exit status 2, never a traceback."""
    import functools

    @functools.wraps(callback)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return callback(*args, **kwargs)
        except StarnavError as err:
            fail(err)
        except OSError as err:
            fail(os_error_message(err))

    return run


def unwrapped_help(doc: str) -> str:
    """A docstring as help text: its lines joined into paragraphs (a blank line between
    paragraphs is kept), so that the help is wrapped to the terminal, not cut where the source
    line ended."""
    import inspect

    paragraphs = inspect.cleandoc(doc).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs if p.strip())


def _guard_all(t: typer.Typer) -> None:
    for cmd in t.registered_commands:
        if cmd.callback is not None:
            if cmd.help is None and cmd.callback.__doc__:
                cmd.help = unwrapped_help(cmd.callback.__doc__)
            cmd.callback = _guarded(cmd.callback)
    for group in t.registered_groups:
        if group.typer_instance is not None:
            _guard_all(group.typer_instance)


_guard_all(app)


if __name__ == "__main__":  # pragma: no cover
    app()
