"""``starnav navigate DATASET --out DIR [--runs N]``: the navigation chain over a dataset.

Thin: parses, opens the dataset with :func:`starnav.dataset.open` (issue 8), takes the
``navigation`` section of the dataset's resolved scenario (or of ``--config``), applies
``--set`` overrides, calls
:func:`starnav.navigation.report.navigate_dataset` and prints the headline numbers. Outputs:
``estimates.csv``, ``metrics.json``, the PNG figures and ``navigation_config.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _open_dataset(path: Path, exposure_s: float | None = None):
    from starnav.errors import DataFileError

    if not path.exists():
        raise DataFileError(f"dataset {str(path)!r} does not exist")
    try:
        from starnav.dataset import open as open_dataset  # issue 8
    except (ImportError, AttributeError):
        raise DataFileError(
            "starnav.dataset.open() is not available in this version; the navigation chain "
            "needs a reader returning a NavDataset (see starnav.navigation.frames)") from None
    return open_dataset(path, exposure_s)


def register(app: typer.Typer) -> None:
    """Add the ``navigate`` command to ``app``."""

    @app.command("navigate")
    def navigate_cmd(
        dataset: Annotated[Path, typer.Argument(help="dataset directory (starnav dataset)")],
        out: Annotated[Path, typer.Option("--out", help="output directory")],
        runs: Annotated[int | None, typer.Option(
            "--runs", min=1, help="Monte Carlo runs over initial errors (default: config)")] = None,
        config: Annotated[Path | None, typer.Option(
            "--config", help="scenario YAML (navigation section)")] = None,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override, e.g. navigation.ransac.model=christian-robinson")] = None,
        exposure_ms: Annotated[float | None, typer.Option(
            "--exposure-ms", help="which exposure of the dataset (default: its first)")] = None,
        seed: Annotated[int, typer.Option("--seed", help="seed of initial errors, RANSAC")] = 0,
        no_plots: Annotated[bool, typer.Option("--no-plots", help="skip the PNG figures")] = False,
    ) -> None:
        """Run limb -> RANSAC -> Christian-Robinson -> EKF over DATASET; write CSV, JSON, PNG."""
        from starnav.config import load_scenario, scenario_from_dict
        from starnav.errors import StarnavError
        from starnav.navigation.report import navigate_dataset

        try:
            ds = _open_dataset(dataset, None if exposure_ms is None else exposure_ms * 1e-3)
            overrides = tuple(set_ or ())
            if config is None and isinstance(getattr(ds, "config", None), dict):
                # the dataset's own resolved scenario, with the command-line overrides
                scenario = scenario_from_dict(ds.config, overrides)
            else:
                scenario = load_scenario(config, overrides)
            summary = navigate_dataset(ds, out, config=scenario.navigation, runs=runs,
                                       seed=seed, plots=not no_plots)
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        fin = summary.get("final", {})
        typer.echo(f"frames {summary['frames']}, fixes {summary['fixes']}, "
                   f"accepted {summary['accepted']}")
        le = summary["limb_error_px"]
        typer.echo(f"limb error: bias {le['bias']:.3f} px, std {le['std']:.3f} px")
        if fin:
            typer.echo(f"final position error {fin['position_error_norm_m'] / 1e3:.3f} km, "
                       f"velocity error {fin['velocity_error_norm_m_s']:.4f} m/s")
        typer.echo(f"chain CPU median {summary['timing_ms']['chain_cpu_median']:.2f} ms; "
                   f"outputs in {out}")
