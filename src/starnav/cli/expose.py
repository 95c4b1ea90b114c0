"""``starnav expose``: radiance image -> DN frame and star-tracker readout products.

Parses, loads the scenario, calls :func:`starnav.detector.expose` once and writes the DN PNG,
the readout products and the resolved scenario. No numerical work here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._units import parse_time


def register(app: typer.Typer) -> None:
    """Add the ``expose`` command to ``app``."""

    @app.command("expose")
    def expose_cmd(
        radiance: Annotated[Path, typer.Argument(help="RadianceImage OpenEXR (channel Le)")],
        out: Annotated[Path, typer.Option("--out", help="output directory")],
        scenario: Annotated[Path | None, typer.Option(
            "--scenario", help="scenario YAML (camera, detector, seed); default built-ins")] = None,
        exposure: Annotated[str | None, typer.Option(
            "--exposure", "--exposure-s",
            help="exposure time, in s or with a unit (2e-3, 2ms; overrides "
            "detector.exposure_time_s)")] = None,
        frame_index: Annotated[int, typer.Option(
            "--frame-index", help="frame number (selects the temporal noise)")] = 0,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override a scenario key, e.g. detector.saturation.full_well_e=8e4")
        ] = None,
        overwrite: Annotated[bool, typer.Option(
            "--overwrite", help="write into a non-empty OUT (its files of the same names are "
            "replaced)")] = False,
    ) -> None:
        """Expose the AA-STR detector to RADIANCE and write dn.png (data: 12-bit DN in a 16-bit
        PNG), dn_quicklook.png (the picture: 8-bit, stretched, annotated), segments.npz,
        windows.npz, readout.json and scenario.resolved.yaml into OUT."""
        from starnav.cli._output import check_output
        from starnav.config import build_camera, load_scenario, write_resolved
        from starnav.detector import expose, write_exposure
        from starnav.errors import StarnavError
        from starnav.quicklook import write_dn_quicklook
        from starnav.radiance import read_exr

        overrides = list(set_ or [])
        try:
            if exposure is not None:
                t = parse_time(exposure, "--exposure")
                overrides.append(f"detector.exposure_time_s={t!r}")
            sc = load_scenario(scenario, overrides)
            check_output(out, directory=True, overwrite=overwrite, inputs=[radiance, scenario])
            camera = build_camera(sc.camera)
            img = read_exr(radiance)
            frame = expose(img, camera, sc.detector, seed=sc.seed, frame_index=frame_index)
            paths = write_exposure(frame, out)
            ql = Path(out) / "dn_quicklook.png"
            write_dn_quicklook(frame.dn, ql, index=frame_index, exposure_time=frame.exposure_time)
            paths["dn quick look"] = ql
            write_resolved(sc, out)
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        s = frame.summary()
        typer.echo(f"exposure {frame.exposure_time * 1e3:.6g} ms, gain {frame.gain:.4g} e-/DN, "
                   f"DN max {s['dn_max']}, saturated pixels {s['saturated_pixels']}")
        for t in frame.timing:
            flag = "ok" if t.feasible else "INFEASIBLE on the AA-STR"
            typer.echo(f"  {t.mode}: {t.n_pixels} px, needs >= {t.min_exposure * 1e3:.4g} ms: "
                       f"{flag}")
        if frame.segments is not None:
            typer.echo(f"  segments: {len(frame.segments)} runs, {frame.segments.n_pixels} px"
                       + (" (truncated)" if frame.segments.truncated else ""))
        for kind, p in paths.items():
            typer.echo(f"  wrote {kind}: {p}")
