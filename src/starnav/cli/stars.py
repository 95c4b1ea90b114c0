"""``starnav stars``: star images from any camera (plate solving).

Thin commands: parse, call one library function, print one line per image.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from starnav.cli._output import console, fail, print_error

stars_app = typer.Typer(add_completion=False, no_args_is_help=True,
                        help="Star images: attitude and camera from a frame's stars.")


@stars_app.command("solve")
def solve(
    images: Annotated[list[Path], typer.Argument(
        help="image files: 16/8-bit TIFF or PNG, FITS, starnav DN frames (dn.png), raw "
        "SMART-1 AMIE .IMG")],
    out: Annotated[Path, typer.Option("--out", help="output directory")] = Path("out/stars"),
    camera: Annotated[str | None, typer.Option(
        "--camera", help="camera preset the --set camera.* keys override (default aa-str); "
        "the detector size is the image's")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="camera.KEY=VALUE, e.g. camera.focal_length_mm=35 "
        "camera.pixel_pitch_um=6.9")] = None,
    epoch: Annotated[str | None, typer.Option(
        "--epoch", help="epoch of the exposures: Julian year (2019.58) or ISO date-time (UTC); "
        "default the file's date, else J2000.0")] = None,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="write into a non-empty OUT, replacing an earlier solve's "
        "results.json, report.md and overlay_*.png (nothing else is touched)")] = False,
) -> None:
    """Lost-in-space attitude, focal length and distortion of each image from its stars;
    results.json, report.md and an overlay PNG per image. Exit 2 if an image is bad input
    (unreadable, no or too few stars, wrong size), 1 if one could not be identified."""
    from starnav.errors import StarnavError
    from starnav.stars.solve_images import camera_config, parse_epoch, solve_images

    try:
        cfg = camera_config(camera, set_ or [])
        ep = parse_epoch(epoch)
        summary = solve_images(list(images), out, camera=cfg, epoch_jyear=ep,
                               overwrite=overwrite, reader=_read)
    except StarnavError as err:
        fail(err)
        return
    bad, unsolved = 0, 0
    for r in summary["results"]:
        name = Path(r["image"]).name
        if r["status"] == "error":
            print_error(r["reason"])
            bad += 1
        elif r["status"] != "ok":
            console.print(f"{name}: not solved ({r['status']}): {r['reason']}", soft_wrap=True)
            unsolved += 1
        else:
            s = r["sigma_arcsec"]
            console.print(
                f"{name}: RA {r['ra_deg']:.5f} Dec {r['dec_deg']:+.5f} roll {r['roll_deg']:.4f} "
                f"deg (1-sigma {s['x']:.1f}/{s['y']:.1f}/{s['roll']:.1f} arcsec), f "
                f"{r['focal_length_mm']:.3f} mm, FOV {r['fov_x_deg']:.4f} deg, "
                f"{r['n_matched']} stars, rms {r['rms_arcsec']:.1f} arcsec", soft_wrap=True)
    console.print(f"results: {summary['results_path']}  report: {summary['report']}",
                  soft_wrap=True)
    if bad:
        raise typer.Exit(code=2)
    if unsolved:
        raise typer.Exit(code=1)


def _read(path: Path):
    """Any star image; a raw SMART-1 AMIE ``.IMG`` through its PDS reader."""
    from starnav.stars.images import read_star_image

    if path.suffix.lower() == ".img":
        from starnav.reference.amie.stars import amie_star_image

        return amie_star_image(path)
    return read_star_image(path)


def register(app: typer.Typer) -> None:
    app.add_typer(stars_app, name="stars")
