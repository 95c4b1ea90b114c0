"""Reference attitudes of the real star images from cedar-solve, an independent solver.

Run it with the Python of a throwaway venv that holds cedar-solve (never a starnav
dependency; this script imports nothing of starnav)::

    python3 -m venv /tmp/venv-cedar && /tmp/venv-cedar/bin/pip install cedar-solve
    /tmp/venv-cedar/bin/python tools/cedar_reference.py tests/data/stars/*.tiff \
        --out tests/data/stars/reference_cedar.json

cedar-solve (the maintained fork of ESA's tetra3) ships its own pattern database for 10-30 deg
fields (Hipparcos stars to V ~8, proper motions to its epoch). Each image is solved lost in
space with its own star extraction, the field of view searched around the nominal lens
(2 atan(W p / 2 f)) and the radial distortion solved for. Written per image: RA, Dec of the
image centre and roll [deg] in cedar's conventions (roll: celestial north relative to the
image's up, positive counter-clockwise), the horizontal field of view [deg], cedar's
distortion coefficient, the rms residual [arcsec], the matched stars (Hipparcos numbers and
their pixel centroids, (u, v) with the top-left pixel's centre at (0, 0)) and the solve time.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np
from PIL import Image


def solve(t3, path: Path, fov_deg: float) -> dict:
    img = Image.open(path)
    t0 = time.perf_counter()
    sol = t3.solve_from_image(img, fov_estimate=fov_deg, fov_max_error=0.1 * fov_deg,
                              distortion=(-0.2, 0.1), return_matches=True)
    dt = time.perf_counter() - t0
    if sol.get("RA") is None:
        return {"image": path.name, "solved": False, "time_s": dt}
    cen = np.asarray(sol["matched_centroids"], float)  # (y, x), pixel centre at +0.5
    return {
        "image": path.name, "solved": True,
        "ra_deg": float(sol["RA"]), "dec_deg": float(sol["Dec"]),
        "roll_deg": float(sol["Roll"]), "fov_x_deg": float(sol["FOV"]),
        "distortion": float(sol["distortion"]), "rmse_arcsec": float(sol["RMSE"]),
        "matches": int(sol["Matches"]), "false_positive_probability": float(sol["Prob"]),
        "matched_hip": [int(x) for x in sol["matched_catID"]],
        "matched_uv_px": [[round(float(x) - 0.5, 3), round(float(y) - 0.5, 3)]
                          for y, x in cen],
        "time_s": round(dt, 4),
        "t_extract_ms": float(sol["T_extract"]), "t_solve_ms": float(sol["T_solve"]),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("images", nargs="+", type=Path)
    ap.add_argument("--focal-length-mm", type=float, default=35.0)
    ap.add_argument("--pixel-um", type=float, default=6.9)
    ap.add_argument("--out", type=Path, default=None, help="JSON file (default: stdout)")
    a = ap.parse_args(argv)
    import tetra3

    t3 = tetra3.Tetra3("default_database")
    rows = []
    for p in a.images:
        w = Image.open(p).size[0]
        fov = math.degrees(2 * math.atan(0.5 * w * a.pixel_um * 1e-3 / a.focal_length_mm))
        rows.append(solve(t3, p, fov))
    props = {k: (v.tolist() if hasattr(v, "tolist") else v)
             for k, v in t3.database_properties.items()}
    doc = {
        "made_by": "tools/cedar_reference.py with cedar-solve " + metadata.version("cedar-solve")
                   + " (pip, PyPI) and its default_database",
        "command": "python tools/cedar_reference.py " + " ".join(str(p) for p in a.images),
        "nominal_camera": {"focal_length_mm": a.focal_length_mm, "pixel_um": a.pixel_um},
        "database": {k: props[k] for k in ("star_catalog", "star_max_magnitude",
                                            "epoch_proper_motion", "min_fov", "max_fov")},
        "images": rows,
    }
    text = json.dumps(doc, indent=1, default=lambda x: None if x != x else x)
    if a.out:
        a.out.write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
