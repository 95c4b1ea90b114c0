"""Render benchmark (issue 2): 1024 x 1024, 16 spp, Moon mesh >= 300 k triangles.

Prints seconds per frame for the first frame (scene build + JIT compilation) and the steady
state (median of the next frames, camera moving), the variant, and the same figures for the
exact sphere, at 60 000 km (Moon ~2 % of the frame) and at 9 715 km (Moon fills the field).
``real`` is the default scenario's Moon (LOLA LDEM_4 mesh built for each view, included in the
frame time, LROC albedo, calibrated Hapke, ROLO colour).
Budget (DESIGN.md): <= 0.5 s per frame steady state on llvm on the 2-core machine.

Usage: .venv/bin/python benchmarks/render.py [--frames N]
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time

from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.geometry import static_geometry
from starnav.renderer.render import MoonModel, MoonRenderer, RenderSettings
from starnav.renderer.scene import icosphere_mesh
from starnav.simulate import renderer_from_scenario
from starnav.spectra import sensor_response, solar_spectrum


def run(shape: str, range_m: float, frames: int) -> dict:
    cam = Camera.preset("aa-str")
    mesh = None
    if shape == "real":
        # the default scenario's Moon: LDEM_4 mesh rebuilt per view, LROC albedo, Hapke, colour
        r = renderer_from_scenario(scenario_from_dict({"render": {"spp": 16}}))
    else:
        mesh = icosphere_mesh(1737.4e3, 7) if shape == "mesh" else None
        moon = MoonModel(shape=shape, mesh=mesh)
        r = MoonRenderer(cam, sensor_response(), solar_spectrum(), moon,
                         RenderSettings(spp=16))
    times = []
    for k in range(frames):
        # a moving camera: the Moon's place and the phase change every frame
        g = static_geometry(cam, range_m, math.radians(20 + 3 * k), (5.0 * k, -3.0 * k),
                            roll=0.01 * k)
        t0 = time.perf_counter()
        img = r.render(g, seed=k)
        times.append(time.perf_counter() - t0)
    return {
        "shape": shape,
        "triangles": img.meta["moon"]["triangles"],
        "range_km": range_m / 1e3,
        "variant": img.meta["render"]["variant"],
        "crop": img.meta["render"]["crop_box_uvwh"],
        "first_s": times[0],
        "steady_s": statistics.median(times[1:]),
        "moon_px": int(img.mask.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=6)
    args = ap.parse_args()
    print(f"machine: {platform.node()} {platform.machine()} python {platform.python_version()}")
    print(f"{'shape':6s} {'triangles':>9s} {'range_km':>9s} {'variant':>17s} "
          f"{'first_s':>8s} {'steady_s':>8s} {'moon_px':>8s}  crop")
    for range_m in (6.0e7, 9.715e6):
        for shape in ("real", "mesh", "sphere"):
            # each configuration in a fresh renderer; the icosphere is cached across them
            res = run(shape, range_m, args.frames)
            print(f"{res['shape']:6s} {str(res['triangles']):>9s} {res['range_km']:9.0f} "
                  f"{res['variant']:>17s} {res['first_s']:8.3f} {res['steady_s']:8.3f} "
                  f"{res['moon_px']:8d}  {res['crop']}")


if __name__ == "__main__":
    main()
