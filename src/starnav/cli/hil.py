"""``starnav hil``: emulate the hardware-in-the-loop bench (screen + collimator).

Thin commands: parse, load the bench file, call one function of
:mod:`starnav.calibration.workflows`, write its figures (PNG), its JSON summary and the
resolved bench next to them. ``BENCH`` is a bench YAML file, or ``default`` for the paper's
TinyV3RSE bench.

``hil stimulate`` takes a directory of RadianceImage EXRs as written by ``starnav render``
(one factor k for the whole directory).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from starnav.cli._output import fail

hil_app = typer.Typer(add_completion=False, no_args_is_help=True,
                      help="Hardware-in-the-loop bench emulation: collimator check, geometric "
                           "and radiometric calibration, screen stimuli.")

BenchArg = Annotated[str, typer.Argument(help="bench YAML file, or 'default' (TinyV3RSE)")]
SetOpt = Annotated[list[str] | None, typer.Option("--set", help="override a key: a.b=value")]
OverwriteOpt = Annotated[bool, typer.Option(
    "--overwrite", help="write into a non-empty OUT (its files of the same names are replaced)")]
CalOpt = Annotated[Path | None, typer.Option(
    "--calibration", help="geometric_calibration.json from `hil geometric` (default: run the "
    "emulated dot calibration first)")]


def _fail(err: Exception) -> None:
    fail(err)


def _check_out(out: Path | None, overwrite: bool, *inputs: Any) -> None:
    """The CLI's overwrite rule for OUT (:func:`starnav.cli._output.check_output`)."""
    from starnav.cli._output import check_output

    if out is not None:
        check_output(out, directory=True, overwrite=overwrite, inputs=[Path(i) if isinstance(
            i, str) else i for i in inputs])


def _load(bench: str, overrides: list[str] | None):
    from starnav.calibration.schema import load_bench

    return load_bench(None if bench == "default" else bench, overrides or [])


def _write_report(report: Any, cfg: Any, out: Path, name: str) -> None:
    import yaml

    from starnav.atomic import atomic_path, atomic_write_text
    from starnav.calibration.schema import bench_to_dict

    out.mkdir(parents=True, exist_ok=True)
    for fig_name, fig in report.figures.items():
        with atomic_path(out / f"{fig_name}.png") as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    for fname, text in report.texts.items():
        atomic_write_text(out / fname, text)
    atomic_write_text(out / f"{name}.json", json.dumps(report.summary, indent=1, default=float))
    atomic_write_text(out / "bench.resolved.yaml",
                      yaml.safe_dump(bench_to_dict(cfg), sort_keys=False))


def _table(title: str, rows: list[tuple[str, Any]]) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    t = Table(title=title, show_header=False)
    for k, v in rows:
        t.add_row(escape(k), escape(f"{v:.6g}" if isinstance(v, float) else str(v)))
    Console().print(t)


@hil_app.command("check")
def check(
    bench: BenchArg,
    out: Annotated[Path | None, typer.Option("--out", help="write check.json and the "
                                             "coverage figure here")] = None,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Optical-stimulator condition (paper eq. 2) with the stated and the derived FoV, and how
    much of the detector the screen covers."""
    from starnav.calibration.workflows import run_check
    from starnav.errors import StarnavError

    try:
        _check_out(out, overwrite, bench)
        cfg = _load(bench, set_)
        rep = run_check(cfg)
        if out is not None:
            _write_report(rep, cfg, out, "check")
    except StarnavError as err:
        _fail(err)
        return
    s = rep.summary
    rows = [(c["fov_source"], c["sentence"]) for c in s["conditions"]]
    rows += [("stimulated fraction", s["stimulated_fraction"]),
             ("screen pixel on the detector (px)", s["screen_pixel_camera_px"]),
             ("verdict", s["verdict"])]
    _table("hil check", rows)


@hil_app.command("geometric")
def geometric(
    bench: BenchArg,
    out: Annotated[Path, typer.Option("--out", help="output directory")]
    = Path("out/hil/geometric"),
    no_moon: Annotated[bool, typer.Option("--no-moon", help="skip the displayed-Moon check "
                                          "(no rendering)")] = False,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Dot-pattern geometric calibration: residual PDF/CDF, pre-warped Moon placement, the
    calibration polynomials (geometric_calibration.json), and camera_calibration.json: the
    camera's intrinsics and the screen's radiometric calibration against the reference
    instrument, with their covariance (hold-out validation in geometric.json)."""
    from starnav.calibration.workflows import run_geometric
    from starnav.errors import StarnavError

    try:
        _check_out(out, overwrite, bench)
        cfg = _load(bench, set_)
        rep = run_geometric(cfg, moon=not no_moon)
        _write_report(rep, cfg, out, "geometric")
    except StarnavError as err:
        _fail(err)
        return
    g = rep.summary["geometric"]
    rows = [("dots matched", f"{g['dots_matched']} / {g['dots_shown']}"),
            ("uncalibrated RMS (arcsec)", g["uncalibrated"]["rms_arcsec"]),
            ("hold-out RMS (arcsec)", g["holdout"].get("rms_arcsec", float("nan"))),
            ("closed-loop RMS (arcsec)", g["closed_loop"].get("rms_arcsec", float("nan"))),
            ("random-layout hold-out RMS (arcsec)",
             rep.summary["random_layout_holdout"]["rms_arcsec"])]
    lab = rep.summary["radiometric_lab"]
    v, pl = lab["validation"], lab["plausibility"]
    rows += [("radiometric hold-outs: rms error", v["rms_error"]),
             ("  stated 1-sigma (rms)", v["sigma_rms"]),
             ("  max |error| / sigma (limit)", f"{v['max_abs_z']:.3g} ({v['z_crit']:.3g})"),
             ("  meets the paper's use", f"{v['meets_paper_use']} (tolerance "
              f"{v['tolerance']:g} at {v['coverage_k']:g} sigma)"),
             ("screen too dim by (calibrated)", pl["screen_too_dim"]["calibrated"]),
             ("k = 13 333 peak count (calibrated)", pl["k_peak_count"]["calibrated"])]
    if "moon_placement" in rep.summary:
        m = rep.summary["moon_placement"]
        rows += [("Moon offset, calibrated (px)", m["calibrated_offset_px"]),
                 ("Moon offset, uncalibrated (px)", m["uncalibrated_offset_px"])]
    _table("hil geometric", rows)
    typer.echo(f"outputs in {out}")


@hil_app.command("radiometric")
def radiometric(
    bench: BenchArg,
    out: Annotated[Path, typer.Option("--out", help="output directory")]
    = Path("out/hil/radiometric"),
    calibration: CalOpt = None,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Radiometric calibration: count <-> Moon flux, validated stimulus, albedo-exposure scaling
    (KS test) and the end-to-end 0.015 ms case."""
    from starnav.calibration.workflows import run_radiometric
    from starnav.errors import StarnavError

    try:
        _check_out(out, overwrite, bench, calibration)
        cfg = _load(bench, set_)
        rep = run_radiometric(cfg, calibration)
        _write_report(rep, cfg, out, "radiometric")
    except StarnavError as err:
        _fail(err)
        return
    s = rep.summary
    ks = s["albedo_exposure_ks"]
    e2e = s["end_to_end"]
    _table("hil radiometric", [
        ("screen too dim by", s["screen_too_dim_factor"]),
        ("k (albedo / k, exposure x k)", s["plan"]["k"]),
        ("stimulus peak count", s["plan"]["peak_count"]),
        ("validation disc ratio", s["validation"]["disc_ratio"]),
        ("KS bench", "truth (calibrated counts)" if ks["truth_bench"] else "nominal model"),
        ("KS scaled p-values", ", ".join(f"{c['p_value']:.3g}" for c in ks["cases"][1:])),
        ("KS control p-value", f"{ks['control']['p_value']:.3g}"),
        ("KS scaled disc ratio - 1 (1-sigma)",
         ", ".join(f"{c['ratio_error']:+.4f} ({c['ratio_sigma']:.4f})" for c in ks["cases"][1:])),
        ("KS control disc ratio - 1", f"{ks['control']['ratio_error']:+.4f}"),
        ("KS scaled ratios within budget", ks["ratios_consistent"]),
        ("end-to-end bench", "truth (calibrated counts)" if e2e["truth_bench"]
         else "nominal model"),
        ("end-to-end disc ratio", e2e["metrics"]["disc_ratio"]),
        ("end-to-end KS p-value", e2e["ks_p_value"]),
        *([("end-to-end disc ratio 1-sigma", e2e["metrics"]["sigma"]["disc_ratio"]),
           ("end-to-end consistent with its budget", e2e["metrics"]["consistent"])]
          if e2e["truth_bench"] else []),
    ])
    typer.echo(f"outputs in {out}")


@hil_app.command("stimulate")
def stimulate(
    bench: BenchArg,
    dataset: Annotated[Path, typer.Argument(help="directory of RadianceImage EXRs written by "
                                            "`starnav render`")],
    out: Annotated[Path, typer.Option("--out", help="output directory")] = Path("out/hil/stimuli"),
    calibration: CalOpt = None,
    set_: SetOpt = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Screen images (counts, PNG) for every rendered frame, with the predicted bench
    acquisition and the in-orbit exposure (16-bit DN PNG)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from starnav.calibration.workflows import png_frame_sink, run_stimulate
    from starnav.errors import StarnavError

    try:
        _check_out(out, overwrite, bench, dataset, calibration)
        cfg = _load(bench, set_)
        sink = png_frame_sink(out, cfg.screen.bit_depth)

        with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                      TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn()) as bar:
            task = bar.add_task("stimulate", total=None)
            rep = run_stimulate(cfg, dataset, sink, calibration,
                                lambda k, n: bar.update(task, completed=k, total=n))
        _write_report(rep, cfg, out, "stimulate")
    except StarnavError as err:
        _fail(err)
        return
    s = rep.summary
    rows = [("frames", len(s["frames"])), ("k", s["plan"]["k"]),
            ("bench exposure (s)", s["plan"]["bench_exposure_s"]),
            ("peak count", s["plan"]["peak_count"]), ("stimulus path", s["stimulus_path"])]
    if "radiometric_calibration" in s:
        fr = s["frames"]
        rows += [("frames consistent with the budget",
                  f"{sum(f['consistent'] for f in fr)} / {len(fr)}"),
                 ("frames within the paper's use (2 sigma <= tolerance)",
                  f"{sum(f['meets_paper_use'] for f in fr)} / {len(fr)}")]
    _table("hil stimulate", rows)
    typer.echo(f"outputs in {out}")


def register(app: typer.Typer) -> None:
    """Add the ``hil`` sub-command group to the main ``starnav`` app."""
    app.add_typer(hil_app, name="hil")
