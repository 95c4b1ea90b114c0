"""Benchmark: view-adapted Moon mesh for a 1024 x 1024 AA-STR frame at several ranges.

Budget (issue 3): <= 1 s and <= 1 GB for the mesh of a frame at 60 000 km.

For each range the camera looks at the Moon centre (static geometry, phase 30 deg), the mesh is
built with frustum culling, and we print: build time (cold = first build with this DEM, which
also builds the DEM's mip levels it needs; warm = median of repeats with the cache disabled),
vertices, triangles, and the peak memory allocated during one build (tracemalloc, which sees
NumPy's allocations; measured in a separate build because tracemalloc slows Python down) plus
the process's peak RSS so far (includes the DEM, albedo and the meshes before).

Run::

    DRJIT_LIBLLVM_PATH=/lib/x86_64-linux-gnu/libLLVM.so.19.1 .venv/bin/python benchmarks/dem.py
    .venv/bin/python benchmarks/dem.py --ppd 16 --ranges 60000 10000 --repeats 5
"""

from __future__ import annotations

import argparse
import logging
import math
import resource
import statistics
import time
import tracemalloc

from starnav.camera import Camera
from starnav.dem.mesh import view_mesh
from starnav.dem.procedural import procedural_moon
from starnav.dem.schema import ProceduralDemConfig
from starnav.geometry import static_geometry

logger = logging.getLogger("benchmarks.dem")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ppd", type=float, default=8.0, help="procedural DEM resolution [px/deg]")
    ap.add_argument("--ranges", type=float, nargs="+",
                    default=[80_000.0, 60_000.0, 40_000.0, 10_000.0, 2_000.0],
                    help="camera ranges from the Moon centre [km]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--edge-px", type=float, default=1.0)
    ap.add_argument("--source", choices=("lola", "procedural"), default="lola",
                    help="the packaged LOLA LDEM_4 + LROC map (default, with sub-posting "
                    "detail) or the procedural Moon")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    from starnav.dem.mesh import MeshOptions

    cam = Camera.preset("aa-str")
    t0 = time.perf_counter()
    detail = None
    if args.source == "procedural":
        moon = procedural_moon(ProceduralDemConfig(pixels_per_degree=args.ppd))
        dem, albedo = moon.dem, moon.albedo
        label = f"procedural DEM ({args.ppd:g} px/deg)"
    else:
        from starnav.dem.detail import sub_posting_detail
        from starnav.dem.load import load_albedo, load_dem
        from starnav.dem.schema import DemConfig

        cfg = DemConfig(source="lola", albedo={"source": "lroc"})
        dem, albedo = load_dem(cfg), load_albedo(cfg)
        detail = sub_posting_detail(dem, cfg.detail)
        label = "LOLA LDEM_4 + LROC albedo + sub-posting detail"
    t_dem = time.perf_counter() - t0
    print(f"{label}: {dem.shape[0]} x {dem.shape[1]}, loaded in {t_dem:.2f} s, "
          f"{dem.values.nbytes / 2**20:.0f} MB (+ albedo)")
    opts = MeshOptions(edge_px=args.edge_px)
    t0 = time.perf_counter()
    import trimesh  # noqa: F401  (imported once per process by view_mesh; timed apart)

    print(f"import trimesh: {time.perf_counter() - t0:.2f} s (once per process, not counted)")
    print(f"{'range km':>9} {'cold s':>8} {'warm s':>8} {'vertices':>10} {'triangles':>10} "
          f"{'peak MB':>8} {'RSS MB':>8}")
    for r_km in args.ranges:
        geom = static_geometry(cam, r_km * 1e3, math.radians(30.0))
        kw = dict(camera_to_body=geom.R_cam_to_inertial, options=opts, cache=None,
                  detail=detail)
        t0 = time.perf_counter()
        m = view_mesh(dem, cam, geom.camera_position, albedo, **kw)
        cold = time.perf_counter() - t0
        nv, nf = len(m.vertices), len(m.faces)
        del m
        warm = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            view_mesh(dem, cam, geom.camera_position, albedo, **kw)
            warm.append(time.perf_counter() - t0)
        tracemalloc.start()
        m = view_mesh(dem, cam, geom.camera_position, albedo, **kw)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        del m
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{r_km:>9.0f} {cold:>8.3f} {statistics.median(warm):>8.3f} "
              f"{nv:>10d} {nf:>10d} {peak / 2**20:>8.0f} {rss:>8.0f}")

if __name__ == "__main__":
    main()
