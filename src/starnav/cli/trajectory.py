"""``starnav trajectory``: build the scenario's trajectory, write it as CCSDS OEM plus a PNG plot.

Thin command: parse, load the scenario, call :func:`starnav.scenes.build_trajectory`, write the
OEM (at the scenario's frame cadence), the plot and the resolved scenario.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._output import check_output, console, fail
from starnav.errors import StarnavError


def register(app: typer.Typer) -> None:
    """Add the ``trajectory`` command to ``app``."""

    @app.command("trajectory")
    def trajectory(
        scenario: Annotated[Path | None, typer.Argument(
            help="scenario YAML (default: built-in; a missing trajectory section means the "
                 "default LUMIO-like halo)")] = None,
        out: Annotated[Path, typer.Option("--out", help="OEM file to write")] = Path(
            "trajectory.oem"),
        plot: Annotated[Path | None, typer.Option(
            "--plot", help="PNG to write (default: next to the OEM)")] = None,
        cadence_s: Annotated[float | None, typer.Option(
            "--cadence-s", help="OEM sample spacing [s] (default: trajectory.cadence_s)")] = None,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override a key: a.b=value")] = None,
        overwrite: Annotated[bool, typer.Option(
            "--overwrite", help="replace an existing OEM or PNG")] = False,
    ) -> None:
        """Build the trajectory (LUMIO-like halo in the ephemeris model, or an OEM) and write
        it as a CCSDS OEM file with a PNG plot (Moon range, phase angle, rotating-frame path)."""
        from starnav.config import load_scenario, write_resolved
        from starnav.scenes import build_trajectory, plot_trajectory, trajectory_summary
        from starnav.scenes.ephemeris import format_epoch
        from starnav.scenes.oem import write_oem
        from starnav.scenes.schema import DAY_S, MAX_ARC_SAMPLES, TrajectoryConfig
        from starnav.timeaxis import format_duration

        try:
            sc = load_scenario(scenario, set_ or [])
            cfg = sc.trajectory or TrajectoryConfig()
            png = plot if plot is not None else out.with_suffix(".png")
            resolved = (out.parent if str(out.parent) else Path(".")) / "scenario.resolved.yaml"
            inputs = [scenario, cfg.oem_path if cfg.source == "oem" else None]
            check_output(out, directory=False, overwrite=overwrite, inputs=inputs,
                         side_files=[resolved])
            check_output(png, directory=False, overwrite=overwrite, inputs=[*inputs, out],
                         option="--plot")
            cadence = cfg.cadence_s if cadence_s is None else cadence_s
            if not 0 < cadence < float("inf"):
                raise StarnavError(f"--cadence-s = {cadence!r}: expected a finite cadence > 0 s")
            span = cfg.duration_days * DAY_S
            if span / cadence > MAX_ARC_SAMPLES:
                raise StarnavError(f"--cadence-s = {cadence!r}: expected at least "
                                   f"{span / MAX_ARC_SAMPLES:.3g} s over the "
                                   f"{cfg.duration_days:g}-day arc ({span / cadence:.3g} "
                                   f"states; at most {MAX_ARC_SAMPLES:.0e})")
            with console.status("building the trajectory (halo, multiple shooting)"):
                traj = build_trajectory(cfg, spacecraft=sc.spacecraft)
            sampled = traj.resample(cadence)
            write_oem(out, sampled, comments=[f"starnav trajectory, source={cfg.source}",
                                              "states EMB-centred, ICRF axes, TDB"])
            # the plot and the summary describe what the OEM holds: its first to its last
            # epoch (the arc built may run past the last whole cadence step)
            shown = (traj.clipped(sampled.t_start, sampled.t_end)
                     if sampled.t_end > sampled.t_start else traj)
            plot_trajectory(shown, png)
            write_resolved(sc, out.parent if str(out.parent) else Path("."))
            s = trajectory_summary(shown)
        except StarnavError as err:
            fail(err)
        console.print(
            f"{format_epoch(s['t_start'], precision=0)} .. {format_epoch(s['t_end'], precision=0)}"
            f" ({format_duration(s['t_end'] - s['t_start'])}), Moon range "
            f"{s['moon_range_min'] / 1e3:.0f}-{s['moon_range_max'] / 1e3:.0f} km")
        console.print(f"wrote {out} ({len(sampled)} states every {cadence:g} s) and {png}")
