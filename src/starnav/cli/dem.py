"""``starnav dem``: inspect a DEM and export the mesh a frame would use.

Thin commands: parse, load, call one library function, write the output.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._output import fail

dem_app = typer.Typer(add_completion=False, no_args_is_help=True,
                      help="Lunar DEMs: inspect files, export view-adapted meshes.")


def _fail(err: Exception) -> None:
    fail(err)


@dem_app.command("info")
def info(
    file: Annotated[Path, typer.Argument(help="DEM file (.LBL/.IMG, .tif, .npy) or 'procedural'")],
    fmt: Annotated[str, typer.Option("--format", help="auto|pds3|geotiff|svs-geotiff|npy")]
    = "auto",
    max_ppd: Annotated[float | None, typer.Option("--max-ppd",
                                                  help="decimate at load [px/deg]")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
) -> None:
    """Size, resolution, extent and height range of a DEM."""
    import json

    from rich.console import Console
    from rich.table import Table

    from starnav.dem.load import as_dem_config
    from starnav.dem.readers import dem_info
    from starnav.errors import StarnavError

    try:
        cfg = as_dem_config({"source": str(file), "format": fmt, "max_pixels_per_degree": max_ppd})
        info = dem_info(cfg)
    except StarnavError as err:
        _fail(err)
        return
    if as_json:
        print(json.dumps(info.as_dict()))
        return
    table = Table(title=str(file), show_header=False)
    rows = [
        ("source", info.source),
        ("size (rows x cols)", f"{info.shape[0]} x {info.shape[1]}"),
        ("resolution", f"{info.pixels_per_degree:.6g} px/deg, {info.cell_km:.4g} km/px"),
        ("extent (W E S N)", " ".join(f"{v:.6g}" for v in info.extent_deg) + " deg"),
        ("reference radius", f"{info.reference_radius_km:.4f} km"),
        ("height range", f"{info.height_min_m:.1f} .. {info.height_max_m:.1f} m"),
        ("mean height", f"{info.height_mean_m:.1f} m"),
    ]
    for k, v in rows:
        table.add_row(k, v)
    Console().print(table)


@dem_app.command("mesh")
def mesh(
    scenario: Annotated[Path | None, typer.Argument(help="scenario YAML (default: built-in)")]
    = None,
    out: Annotated[Path, typer.Option("--out", help="output mesh (.ply, .obj, .glb)")]
    = Path("mesh.ply"),
    overrides: Annotated[list[str] | None, typer.Option("--set", help="override a key: a.b=v")]
    = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="replace an existing file")]
    = False,
) -> None:
    """Write the view-adapted mesh a frame of SCENARIO would use (Moon body-fixed, metres)."""
    from starnav.cli._output import check_output
    from starnav.config import load_scenario, write_resolved
    from starnav.dem.mesh import check_mesh_path, save_mesh
    from starnav.errors import StarnavError
    from starnav.simulate import frame_mesh

    try:
        check_mesh_path(out)
        sc = load_scenario(scenario, overrides or [])
        check_output(out, directory=False, overwrite=overwrite,
                     inputs=[scenario, Path(sc.moon.dem.source)],
                     side_files=[out.parent / "scenario.resolved.yaml"])
        m = frame_mesh(sc)
        save_mesh(m, out)
        write_resolved(sc, out.parent)
    except StarnavError as err:
        _fail(err)
        return
    print(f"{out}: {len(m.vertices)} vertices, {len(m.faces)} triangles "
          f"(Moon body-fixed, metres)")


def register(app: typer.Typer) -> None:
    """Add the ``dem`` sub-command group to the main ``starnav`` app."""
    app.add_typer(dem_app, name="dem")
