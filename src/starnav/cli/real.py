"""``starnav real``: starnav held against real images (SMART-1 AMIE frames of the Moon).

Thin commands: parse, call one library function, print where the outputs are.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._output import check_output, console, fail

real_app = typer.Typer(add_completion=False, no_args_is_help=True,
                       help="Real images: compare starnav with real frames of the Moon.")


@real_app.command("amie")
def amie(
    frames: Annotated[list[Path] | None, typer.Argument(
        help="raw AMIE .IMG files (PDS3, attached label); default: the packaged Moon frames")]
    = None,
    out: Annotated[Path, typer.Option("--out", help="output directory")] = Path("out/amie"),
    spp: Annotated[int, typer.Option("--spp", min=1, help="render samples per pixel")] = 16,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="write into a non-empty OUT (its files of the same names are "
        "replaced)")] = False,
) -> None:
    """Rebuild each frame's view from its label, render and expose it with the AMIE camera on the
    real Moon, compare (signal, pixels, limb), navigate on the real frame; write report.md,
    results.json and figures/."""
    from starnav.errors import StarnavError
    from starnav.reference.amie.validate import AmieOptions, run_amie_validation

    try:
        check_output(out, directory=True, overwrite=overwrite, inputs=list(frames or ()))
        summary = run_amie_validation(frames or None, out, AmieOptions(spp=spp))
    except StarnavError as err:
        fail(err)
        return
    for r in summary["frames"]:
        if r.comparison != "compared":
            console.print(f"{r.name}: {r.comparison}: {r.comparison_reason}", soft_wrap=True)
            continue
        nav = (f"range error {r.nav_range_error_pct:+.2f} % with the nominal focal length, "
               f"{r.nav_range_error_calibrated_pct:+.2f} +- {r.nav_range_sigma_calibrated_pct:.2f} "
               f"% with the calibrated one" if r.navigation == "fix"
               else f"no fix ({r.navigation_reason})")
        console.print(f"{r.name}: signal sim/real {r.signal_ratio:.3f}, limb rms "
                      f"{r.limb_diff_rms_px:.2f} px, {nav}", soft_wrap=True)
    console.print(f"report: {summary['report']}", soft_wrap=True)


def register(app: typer.Typer) -> None:
    app.add_typer(real_app, name="real")
