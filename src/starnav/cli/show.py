"""``starnav show SCENARIO --out scene.png``: the Moon, the trajectory and the camera frusta.

Thin: parses, loads the scenario, calls :func:`starnav.show.render_scene` (pyvista, offscreen).
Where no offscreen OpenGL context exists, it stops with a message saying what to install.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    """Add the ``show`` command to ``app``."""

    @app.command("show")
    def show_cmd(
        scenario: Annotated[Path | None, typer.Argument(
            help="scenario YAML (default: built-in)")] = None,
        out: Annotated[Path, typer.Option("--out", help="PNG file")] = Path("scene.png"),
        frusta: Annotated[int, typer.Option("--frusta", min=1,
                                            help="camera frusta along the arc")] = 8,
        set_: Annotated[list[str] | None, typer.Option(
            "--set", help="override a scenario key: a.b=value")] = None,
        overwrite: Annotated[bool, typer.Option(
            "--overwrite", help="replace an existing PNG")] = False,
    ) -> None:
        """Draw the scenario in 3-D (offscreen) into a PNG."""
        from starnav.cli._output import check_output
        from starnav.config import load_scenario, write_resolved
        from starnav.errors import StarnavError
        from starnav.show import render_scene

        try:
            check_output(out, directory=False, overwrite=overwrite, inputs=[scenario],
                         side_files=[out.parent / f"{out.stem}.resolved.yaml"])
            sc = load_scenario(scenario, tuple(set_ or ()))
            p = render_scene(sc, out, frusta=frusta)
            write_resolved(sc, out.parent, name=f"{out.stem}.resolved.yaml")
        except StarnavError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(code=2) from None
        typer.echo(f"wrote {p}")
