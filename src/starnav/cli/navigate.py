"""``starnav navigate DATASET --out DIR [--runs N]``: the navigation chain over a dataset.

Thin: parses, opens the dataset with :func:`starnav.dataset.open`, takes the dataset's
resolved scenario at the selected exposure (or ``--config``), applies ``--set`` overrides and
calls the library:

* one run: :func:`starnav.navigation.report.navigate_dataset` on the dataset's own
  acquisitions (``estimates.csv``, ``metrics.json``, the PNG figures,
  ``navigation_config.json``);
* ``--runs N`` (N >= 2): :func:`starnav.batch.montecarlo.navigate_runs`, a Monte Carlo over
  detector noise (each frame's radiance re-exposed), attitude knowledge error and initial
  error, with the consistency verdict (``report.md``, ``metrics.json``, ``runs.csv``,
  ``consistency.png``, error figures);
* a fly-by dataset (manifest ``target_kind: flyby``): the fly-by closed loop on its stored
  radiance, :func:`starnav.dataset.flyby.navigate_flyby_dataset` (the same runs as
  ``navigate SCENARIO.yaml``); a fly-by scenario YAML: the closed loop rendering it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._units import parse_time


def _open_dataset(path: Path, exposure_time: float | None = None):
    from starnav.errors import DataFileError

    if not path.exists():
        raise DataFileError(f"dataset {str(path)!r} does not exist")
    try:
        from starnav.dataset import open as open_dataset
    except (ImportError, AttributeError):
        raise DataFileError(
            "starnav.dataset.open() is not available in this version; the navigation chain "
            "needs a reader returning a NavDataset (see starnav.navigation.frames)") from None
    return open_dataset(path, exposure_time)


#: What ``navigate --set`` may change: the frames are already made.
NAVIGATE_KEYS = ("navigation.", "seed")


def check_navigate_overrides(items: list[str] | tuple[str, ...]) -> None:
    """``navigate`` re-runs the navigation on frames already rendered and exposed: an override
    of anything else (``moon.albedo``, ``detector.*``) would be silently ignored, so it is an
    error naming the key."""
    from starnav.errors import ConfigError

    for item in items:
        key = item.split("=", 1)[0].strip()
        if not (key == "seed" or key.startswith("navigation.")):
            raise ConfigError("--set", item, "a navigation.* or seed override: navigate re-runs "
                              "the navigation on the dataset's frames, which are already made "
                              f"(make a new dataset to change {key.split('.')[0]}.*)")


def _navigate_flyby(path: Path, out: Path, runs: int | None, set_: list[str] | None,
                    seed: int | None, no_plots: bool, sweep: list[str] | None = None) -> None:
    """``navigate SCENARIO.yaml`` for a fly-by: the frames of a fly-by depend on each other
    (the front end places this frame's windows from the last frame's tracks), so the closed
    loop renders the scenario once and runs the front end and the estimator per run.
    ``--sweep``: the closed loop over a grid of v_inf, CA distance and phase instead."""
    from starnav.batch.flyby import navigate_flyby
    from starnav.batch.flyby_sweep import flyby_rendered_sweep, parse_sweep_axes, write_flyby_sweep
    from starnav.config import load_scenario
    from starnav.simulate import Simulator
    from starnav.simulate.flyby import check_flyby_scenario

    overrides = tuple(set_ or ()) + ((f"seed={seed}",) if seed is not None else ())
    axes = parse_sweep_axes(sweep or ())
    sc = load_scenario(path, overrides)
    check_flyby_scenario(sc)
    n = sc.navigation.runs if runs is None else runs
    if sweep:
        rows = flyby_rendered_sweep(sc, axes, n)
        paths = write_flyby_sweep(rows, out, plots=not no_plots)
        for r in rows:
            typer.echo(f"v_inf {r['v_inf_km_s']:g} km/s, CA {r['closest_approach_km']:g} km, "
                       f"phase {r['phase_at_ca_deg']:g} deg: CA error median "
                       f"{r['ca_error_pct_range_median']:.3g} % of range, mean NEES "
                       f"{r['nees_mean']:.2f} ({r['verdict']})")
        typer.echo(f"table: {paths['table']}")
        return
    _echo_flyby(navigate_flyby(Simulator(sc), out, n, plots=not no_plots), out)


def _echo_flyby(m: dict, out: Path) -> None:
    """The fly-by closed loop's summary lines."""
    def num(v: object, fmt: str, scale: float = 1.0) -> str:
        """``v`` formatted, ``-`` when absent (None: e.g. no feature tracked) or not finite."""
        return format(float(v) * scale, fmt) if isinstance(v, int | float) and \
            float(v) == float(v) and abs(float(v)) != float("inf") else "-"

    rms = m.get("feature_error_rms_px")
    typer.echo(f"position error at CA {num(m.get('ca_position_error_m'), '.1f')} m "
               f"({num(m.get('ca_position_error_pct_range'), '.3g')} % of "
               f"{num(m.get('ca_range_m'), '.2f', 1e-3)} km), "
               + (f"feature error rms {num(rms, '.2f')} px" if num(rms, ".2f") != "-"
                  else "no feature tracked"))
    if "monte_carlo" in m:
        mc = m["monte_carlo"]
        band = mc.get("nees_band") or (None, None)
        typer.echo(f"{mc['runs']} runs: mean NEES {num(mc.get('nees_mean'), '.2f')}, band "
                   f"[{num(band[0], '.2f')}, {num(band[1], '.2f')}]: {mc['verdict']}")
    typer.echo(f"outputs in {out}")


def _navigate_flyby_dataset(path: Path, out: Path, runs: int | None, set_: list[str] | None,
                            seed: int | None, no_plots: bool, exposure: str | None,
                            config: Path | None) -> None:
    """``navigate DATASET`` for a fly-by dataset: the closed loop on its stored radiance
    (:func:`starnav.dataset.flyby.navigate_flyby_dataset`); the limb chain's options that
    select an exposure or another scenario are refused."""
    from starnav.batch.flyby import navigate_flyby_dataset
    from starnav.errors import ConfigError

    if exposure is not None:
        raise ConfigError("--exposure", exposure, "none for a fly-by dataset: it stores no "
                          "exposure, the closed loop exposes each run's segments and windows "
                          "(detector.exposure_time_s)")
    if config is not None:
        raise ConfigError("--config", str(config), "none for a fly-by dataset: its own "
                          "scenario is used (change navigation.* with --set)")
    overrides = tuple(set_ or ()) + ((f"seed={seed}",) if seed is not None else ())
    _echo_flyby(navigate_flyby_dataset(path, out, runs, overrides=overrides,
                                       plots=not no_plots), out)


def register(app: typer.Typer) -> None:
    """Add the ``navigate`` command to ``app``."""

    @app.command("navigate")
    def navigate_cmd(
        dataset: Annotated[Path, typer.Argument(help="dataset directory (starnav dataset)")],
        out: Annotated[Path, typer.Option("--out", help="output directory")],
        runs: Annotated[int | None, typer.Option(
            "--runs", min=1, help="Monte Carlo runs over detector noise, attitude knowledge "
            "and initial errors, with the consistency verdict (default: 1)")] = None,
        config: Annotated[Path | None, typer.Option(
            "--config", help="scenario YAML (navigation section)")] = None,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override, e.g. navigation.ransac.model=christian-robinson")] = None,
        exposure: Annotated[str | None, typer.Option(
            "--exposure", help="which exposure of the dataset, in s or with a unit (15us, "
            "7.7ms; default: its first)")] = None,
        seed: Annotated[int | None, typer.Option(
            "--seed", help="seed of the runs (default: the scenario's)")] = None,
        no_plots: Annotated[bool, typer.Option("--no-plots", help="skip the PNG figures")] = False,
        sweep: Annotated[list[str] | None, typer.Option(
            "--sweep", help="fly-by scenario only: AXIS=V1,V2 (repeat), AXIS v_inf_km_s, "
            "closest_approach_km or phase_at_ca_deg; the closed loop at every point of the "
            "grid, --runs runs each; sweep.csv, sweep.md, sweep.png")] = None,
        overwrite: Annotated[bool, typer.Option(
            "--overwrite", help="write into a non-empty OUT (its files of the same names are "
            "replaced)")] = False,
    ) -> None:
        """Run limb -> RANSAC -> Christian-Robinson -> EKF over DATASET; write CSV, JSON, PNG.
        DATASET may also be a fly-by scenario YAML: the fly-by closed loop (render once, then
        per run the front end and the estimator), metrics.json, figures, report.md."""
        from starnav.cli._output import check_output
        from starnav.config import load_scenario
        from starnav.errors import StarnavError
        from starnav.navigation.report import budget_warning, navigate_dataset

        check_output(out, directory=True, overwrite=overwrite, inputs=[dataset, config])
        if runs is not None:  # checked by the schema's navigation.runs (its bound)
            set_ = [*(set_ or ()), f"navigation.runs={runs}"]
        if dataset.is_file() and dataset.suffix.lower() in (".yaml", ".yml"):
            _navigate_flyby(dataset, out, runs, set_, seed, no_plots, sweep)
            return
        try:
            if sweep:
                from starnav.errors import ConfigError

                raise ConfigError("--sweep", " ".join(sweep), "a fly-by scenario YAML as "
                                  "the argument (a dataset's frames are already made)")
            from starnav.dataset.flyby import is_flyby_dataset

            if dataset.is_dir() and is_flyby_dataset(dataset):
                _navigate_flyby_dataset(dataset, out, runs, set_, seed, no_plots, exposure,
                                        config)
                return
            check_navigate_overrides(set_ or ())
            ds = _open_dataset(dataset, None if exposure is None
                               else parse_time(exposure, "--exposure"))
            overrides = tuple(set_ or ()) + ((f"seed={seed}",) if seed is not None else ())
            if config is None and callable(getattr(ds, "scenario", None)):
                # the dataset's own resolved scenario at this exposure, with the overrides
                scenario = ds.scenario(overrides)
            else:
                scenario = load_scenario(config, overrides)
            n_runs = scenario.navigation.runs if runs is None else runs
            if n_runs >= 2:
                from starnav.batch.montecarlo import navigate_runs, verdict_line, write

                nav = navigate_runs(ds, n_runs, scenario=scenario)
                write(out, nav, plots=not no_plots)
                typer.echo(verdict_line(nav["metrics"]).replace("**", ""))
                typer.echo(f"outputs in {out}")
                return
            if scenario.navigation.attitude.source == "stars":
                from starnav.dataset.attitude import navigate_with_star_attitude

                summary = navigate_with_star_attitude(ds, out, scenario, plots=not no_plots)
                typer.echo("attitude from the stars: " + ", ".join(
                    f"{k} {v}" for k, v in summary["attitude"].items()) + " frames")
            else:
                summary = navigate_dataset(ds, out, config=scenario.navigation,
                                           seed=int(scenario.seed), plots=not no_plots,
                                           scenario=scenario)
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        typer.echo(f"frames {summary['frames']}, fixes {summary['fixes']}, "
                   f"accepted {summary['accepted']}")
        le = summary["limb_error_px"]
        typer.echo(f"limb error: bias {le['bias']:.3f} px, std {le['std']:.3f} px")
        if summary.get("final_position_error_m") is not None:
            typer.echo(f"final position error {summary['final_position_error_m'] / 1e3:.3f} km "
                       f"({summary['final_position_error_pct_range']:.3g} % of range), velocity "
                       f"error {summary['final_velocity_error_m_s']:.4f} m/s; mean NEES "
                       f"{summary['nees_mean']:.3g} (6 states)")
        typer.echo(f"chain CPU median {summary['timing_ms']['chain_cpu_median']:.2f} ms "
                   f"(budget {summary['timing_ms']['budget']:g} ms); outputs in {out}")
        warning = budget_warning(summary)
        if warning:
            typer.echo(warning)
        if "report" in summary.get("paths", {}):
            typer.echo(f"report: {summary['paths']['report']}")
