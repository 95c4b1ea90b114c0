"""Render benchmark (issues 2, 18): 1024 x 1024, 16 spp, at 60 000 km (Moon ~2 % of the frame)
and at 9 715 km (the Moon fills the field).

For each Moon (``real``: the default scenario's LDEM_4 mesh built for each view, LROC albedo,
calibrated Hapke, ROLO colour; ``mesh``: a 327 680-triangle icosphere with Hapke; ``sphere``:
Mitsuba's exact sphere with Hapke) it prints, in the same run:

* ``first_s``: the first frame (mesh and scene build, JIT compilation or disk-cache load);
* ``steady_s``: the median of frames 2..N, camera moving (the Moon's place, size and phase
  change every frame, as in a sequence), with the renderer's own loop (``fused``) and, with
  ``--compare``, with Mitsuba's ``mi.render`` loop (``mitsuba``: the loop before issue 18);
  its parts ``mesh_s`` (view mesh, or the cached one), ``scene_s`` (Mitsuba scene and BVH,
  0 when the frame reuses the loaded scene), ``rad_s`` (the render kernel and its AOVs), and
  ``rebuilds``: frames 2..N that built a scene. ``--rebuild`` adds the real Moon with
  ``cache_quantum_px = 0`` (a mesh and a scene per frame: before the sequence reuse);
* ``compiles``: kernels compiled or loaded from Dr.Jit's disk cache during the steady frames
  (``dr.kernel_history``): each new crop window did so with ``mi.render``;
* ``floor_s``: casting the same number of camera rays over the same crop window
  (``scene.ray_intersect`` on sensor rays, one kernel): the floor of any renderer that casts
  16 rays in every pixel;
* ``spp``: ``16`` (every pixel of the crop), or ``a16/4`` and ``a16/1``: the adaptive render
  (``render.adaptive``: 16 samples at the limb, the terminator, shadow and albedo edges, 4 or
  1 in the flat interior, none outside the body's bounding sphere), with ``full%`` (its
  pixels at 16 spp, of those with samples) and ``Msamples`` (radiance samples of the last
  frame; a non-adaptive frame's is 16 times the crop). Each Moon is rendered each way in the
  same run with the same renderer (scene, mesh and kernels: the ``first_s`` of an adaptive
  row is its first frame with the scene loaded, compiling or loading its own kernels);
  ``--no-adaptive`` leaves the adaptive rows out, ``--interior-spp`` chooses them. Under an
  adaptive row, ``steps``: its centre pass (pixel-centre rays, AOVs, radiance proxy), the
  sample map (NumPy) and each sample count's radiance pass (``spp_16``, ``spp_4``), medians,
  and the floor of that frame's own camera rays (one per pixel centre plus one per sample of
  its last frame, one kernel, no shadow ray and no shading).

The Moon's place is offset by ``--place-seed`` (default: from the clock), so that the frames'
crop windows are new to Dr.Jit's on-disk kernel cache, as in a new sequence. Blender Cycles,
the paper's engine, renders the real Moon's frames (same mesh, poses, Sun and crop windows,
direct light, a Lambert surface; ``benchmarks/cycles_frame.py``) where a Python with ``bpy`` is
given (``--cycles-python``, ``make bench-cycles``; ``bpy`` pins ``numpy < 2``, so it has its own
venv): a row ``cycles`` per sample count (``--cycles-spp``, default 16 and 2) with the IoU of its
Moon mask with starnav's and its interior noise (measured like ``render_noise.py`` measures
starnav's, with a mask Cycles can give), then
each real-Moon row's steady time as a fraction of Cycles'.

Usage: .venv/bin/python benchmarks/render.py [--frames N] [--compare] [--rebuild] [--place-seed S]
       [--shapes real,mesh,sphere] [--ranges-km 60000,9715] [--no-adaptive] [--interior-spp 4,1]
       [--cycles-python PYTHON_WITH_BPY] [--cycles-spp 16,2]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import os
import platform
import statistics
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from starnav.bodies.mesh import icosphere_mesh
from starnav.bodies.model import TargetModel
from starnav.camera import Camera
from starnav.config import scenario_from_dict
from starnav.geometry import static_geometry
from starnav.renderer.render import MoonRenderer, RenderSettings, moon_bounding_box
from starnav.simulate import renderer_from_scenario
from starnav.spectra import sensor_response, solar_spectrum


def make_renderer(shape: str, fused: bool, quantum_px: float | None = None) -> MoonRenderer:
    cam = Camera.preset("aa-str")
    extra = {}
    # a renderer from before issue 18 has no fused loop: Mitsuba's loop is its only one
    if "fused_loop" in {f.name for f in dataclasses.fields(RenderSettings)}:
        extra["fused_loop"] = fused
    if _HAS_ADAPTIVE:
        extra["adaptive"] = False
    if shape == "real":
        sc: dict = {"render": {"spp": 16}}
        if quantum_px is not None:
            sc["moon"] = {"dem": {"mesh": {"cache_quantum_px": quantum_px}}}
        r = renderer_from_scenario(scenario_from_dict(sc))
        r.settings = dataclasses.replace(r.settings, **extra)
        return r
    mesh = icosphere_mesh(1737.4e3, 7) if shape == "mesh" else None
    moon = TargetModel(shape=shape, mesh=mesh, model="hapke")
    return MoonRenderer(cam, sensor_response(), solar_spectrum(), moon,
                        RenderSettings(spp=16, **extra))


_HAS_ADAPTIVE = "adaptive" in {f.name for f in dataclasses.fields(RenderSettings)}
_RENDERERS: dict[tuple, MoonRenderer] = {}


def geometry(cam: Camera, range_m: float, k: int, place: tuple[float, float]):
    # a moving camera: the Moon's place, size and the phase change every frame
    return static_geometry(cam, range_m * (1.0 + 0.002 * k), math.radians(20 + 3 * k),
                           (place[0] + 5.0 * k, place[1] - 3.0 * k), roll=0.01 * k)


def _cast_floor(r: MoonRenderer, box: tuple[int, int, int, int], pix: np.ndarray) -> float:
    """Best of 3: seconds to generate and intersect one jittered camera ray through each crop
    pixel listed in ``pix`` (indices into the ``box`` crop, repeated per ray) with the
    renderer's loaded scene, one kernel, the renderer's sensor pose."""
    u0, v0, bw, _ = box
    scene = r.scene
    sensor = scene.sensors()[0]
    n = int(pix.size)
    best = math.inf
    for _ in range(3):
        idx = mi.UInt32(pix)
        rng = mi.PCG32(n)
        pos = mi.Vector2f(mi.Float(idx % bw + u0) + rng.next_float32(),
                          mi.Float(idx // bw + v0) + rng.next_float32())
        film = sensor.film().size()
        ray, _ = sensor.sample_ray(0.0, 0.5, pos / mi.ScalarVector2f(film), mi.Point2f(0.5))
        t0 = time.perf_counter()
        si = scene.ray_intersect(ray)
        hits = dr.count(si.is_valid())
        dr.eval(hits)
        dr.sync_thread()
        best = min(best, time.perf_counter() - t0)
    return best


def ray_cast_floor(r: MoonRenderer, g, spp: int) -> float:
    """Seconds to cast ``spp`` camera rays per pixel of the frame's crop window."""
    box = moon_bounding_box(r.camera, g, r.moon.radius + r.moon.max_height, 4.0)
    n_pix = box[2] * box[3]
    return _cast_floor(r, box, np.repeat(np.arange(n_pix, dtype=np.uint32), spp))


def ray_cast_floor_counts(r: MoonRenderer, box: tuple[int, int, int, int],
                          counts: np.ndarray) -> float:
    """Seconds to cast the camera rays of an adaptive frame: one through each pixel of the
    crop ``box`` (its centre pass) plus ``counts[v, u]`` (its radiance samples); no shadow ray,
    no shading."""
    u0, v0, bw, bh = box
    c = np.asarray(counts[v0:v0 + bh, u0:u0 + bw], np.int64).ravel() + 1
    return _cast_floor(r, box, np.repeat(np.arange(c.size, dtype=np.uint32), c))


def run(shape: str, range_m: float, frames: int, fused: bool, place: tuple[float, float],
        quantum_px: float | None = None, interior_spp: int | None = None) -> dict:
    """``interior_spp``: the adaptive render with that many samples in the interior (the
    renderer of the same Moon and loop is reused: its scene, mesh and kernels)."""
    key = (shape, fused, quantum_px)
    if key not in _RENDERERS:
        _RENDERERS.clear()  # one Moon's scene in memory at a time
        _RENDERERS[key] = make_renderer(shape, fused, quantum_px)
    r = _RENDERERS[key]
    if _HAS_ADAPTIVE:
        r.settings = dataclasses.replace(r.settings, adaptive=interior_spp is not None,
                                         interior_spp=interior_spp or r.settings.interior_spp)
    cam = r.camera
    times, compiles, parts, geoms, crops = [], 0, [], [], []
    for k in range(frames):
        g = geometry(cam, range_m, k, place)
        geoms.append(g)
        if k == 1:
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()
        t0 = time.perf_counter()
        img = r.render(g, seed=k)
        times.append(time.perf_counter() - t0)
        crops.append(img.meta["render"]["crop_box_uvwh"])
        if k >= 1:
            parts.append(r.last_timing)
    compiles = sum(1 for h in dr.kernel_history()
                   if h["type"] == dr.KernelType.JIT and (not h["cache_hit"] or h["cache_disk"]))
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    def steady(name: str) -> float:
        return statistics.median(p.get(name, 0.0) for p in parts)

    return {
        "shape": shape,
        "loop": ("fused" if fused else "mitsuba") if hasattr(r.settings, "fused_loop")
        else "before",
        "quantum": "-" if quantum_px is None else f"{quantum_px:g}",
        "rebuilds": sum(1 for p in parts if "scene_build_s" in p),
        "steady_mesh_s": steady("mesh_s"),
        "steady_scene_s": steady("scene_build_s"),
        "steady_radiance_s": steady("radiance_s"),
        "triangles": img.meta["moon"]["triangles"],
        "range_km": range_m / 1e3,
        "variant": img.meta["render"]["variant"],
        "crop": img.meta["render"]["crop_box_uvwh"],
        "first_s": times[0],
        "steady_s": statistics.median(times[1:]),
        "compiles": compiles,
        "floor_s": ray_cast_floor(r, g, 16) if hasattr(r, "scene") else float("nan"),
        # the adaptive frame's own camera rays (centre pass + its samples)
        "floor_frame_s": (ray_cast_floor_counts(r, img.meta["render"]["crop_box_uvwh"],
                                                r.last_sample_counts)
                          if getattr(r, "last_sample_counts", None) is not None
                          else float("nan")),
        "spp": "16" if interior_spp is None else f"a16/{interior_spp}",
        "full_pct": (100.0 * img.meta["render"]["adaptive"]["fraction_full"]
                     if img.meta["render"].get("adaptive") else 100.0),
        "msamples": ((img.meta["render"]["adaptive"]["samples"]
                      if img.meta["render"].get("adaptive")
                      else 16 * img.meta["render"]["crop_box_uvwh"][2]
                      * img.meta["render"]["crop_box_uvwh"][3]) / 1e6),
        "moon_px": int(img.mask.sum()),
        "timing": {k: round(v, 3) for k, v in r.last_timing.items()},
        # the adaptive render's steps (medians of frames 2..N): centre pass, sample map, and
        # each sample count's radiance pass
        "adaptive_parts": {k: steady(k) for k in parts[-1]
                           if k == "centre_s" or k == "map_s" or k.startswith("spp_")},
        "geoms": geoms,
        "crops": crops,
        "mask": img.mask,
        "renderer": r,
    }


def cycles_scene(res: dict, path: str, spp: int = 16) -> None:
    """Write what ``benchmarks/cycles_frame.py`` needs to render ``res``'s frames with Blender
    Cycles: the last frame's view mesh (body-fixed, km), every frame's camera pose and Sun
    direction in the Moon's body-fixed frame, the pinhole, and the last frame's Moon mask."""
    from starnav.renderer.scene import principal_point_offsets, sensor_fov_deg

    r: MoonRenderer = res["renderer"]
    cam = r.camera
    surf = r.surface(res["geoms"][-1])
    if surf is None:
        raise SystemExit("--cycles-python: the exact sphere has no triangle surface to export")
    mesh, albedo = surf
    poses, positions, suns = [], [], []
    for g in res["geoms"]:
        R_body = g.R_body_to_inertial
        poses.append(R_body.T @ g.R_cam_to_inertial)
        positions.append(R_body.T @ g.camera_position / 1e3)
        suns.append(R_body.T @ g.sun_direction)  # the frame is Moon-centred
    ox, oy = principal_point_offsets(cam)
    # Blender's shift moves the frustum (units: the wider side); its y axis points up
    np.savez(path, vertices_km=mesh.vertices / 1e3, faces=mesh.faces, normals=mesh.normals,
             albedo=albedo, spp=spp, width=cam.width, height=cam.height,
             fov_x_rad=math.radians(sensor_fov_deg(cam)), shift_x=ox * cam.width
             / max(cam.width, cam.height), shift_y=-oy * cam.height / max(cam.width, cam.height),
             clip_start_km=0.1, clip_end_km=1e6, cam_R=np.array(poses),
             cam_pos_km=np.array(positions), sun_dir=np.array(suns), mask=res["mask"],
             crop_uvwh=np.array(res["crops"]))


def run_cycles(python: str, res: dict, spp: int = 16) -> dict:
    """Render ``res``'s frames with Blender Cycles under ``python`` (which has ``bpy``),
    ``spp`` samples a pixel."""
    import json
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "scene.npz")
        cycles_scene(res, path, spp)
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "cycles_frame.py")
        out = subprocess.run([python, script, path, "--threads", str(os.cpu_count())],
                             capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def miss_cost(frames: int, place: tuple[float, float]) -> None:
    """What a sample that misses the Moon costs: the exact sphere at 60 000 km traced over its
    crop window (~78 % of the samples hit) and over the whole frame (~2 % hit), same frames.
    Solving ``t = n_hit c_hit + n_miss c_miss`` for the two gives each sample's cost."""
    rows = []
    for crop in (True, False):
        cam = Camera.preset("aa-str")
        r = MoonRenderer(cam, sensor_response(), solar_spectrum(),
                         TargetModel(shape="sphere", model="hapke"),
                         RenderSettings(spp=16, crop=crop,
                                        **({"adaptive": False} if _HAS_ADAPTIVE else {})))
        ts = []
        for k in range(frames):
            img = r.render(geometry(cam, 6.0e7, k, place), seed=k)
            ts.append(r.last_timing["radiance_s"])
        box = img.meta["render"]["crop_box_uvwh"]
        n = box[2] * box[3] * 16
        hits = int(img.mask.sum()) * 16
        rows.append((statistics.median(ts[1:]), hits, n - hits))
    (t1, h1, m1), (t2, h2, m2) = rows
    c_hit, c_miss = np.linalg.solve([[h1, m1], [h2, m2]], [t1, t2])
    print(f"miss cost (sphere, 60 000 km, 16 spp): crop {t1:.3f} s ({h1} hit / {m1} missed "
          f"samples), whole frame {t2:.3f} s ({h2} / {m2}): {c_hit * 1e9:.0f} ns a hit, "
          f"{c_miss * 1e9:.0f} ns a miss", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--compare", action="store_true", help="also Mitsuba's mi.render loop")
    ap.add_argument("--place-seed", type=int, default=None)
    ap.add_argument("--shapes", default="real,mesh,sphere")
    ap.add_argument("--ranges-km", default="60000,9715")
    ap.add_argument("--rebuild", action="store_true",
                    help="real Moon: also with cache_quantum_px = 0 (a mesh and a scene built "
                    "for every frame: the renderer before the sequence reuse)")
    ap.add_argument("--no-adaptive", action="store_true",
                    help="leave out the adaptive render (render.adaptive)")
    ap.add_argument("--interior-spp", default="2,4,1",
                    help="the adaptive render's samples per interior pixel, one row each "
                    "(comma-separated)")
    ap.add_argument("--cycles-python", default=os.environ.get("STARNAV_CYCLES_PYTHON"),
                    help="a Python with bpy (Blender as a module): render the real Moon's "
                    "frames with Cycles too (benchmarks/cycles_frame.py; default: "
                    "$STARNAV_CYCLES_PYTHON, or this Python if it has bpy)")
    ap.add_argument("--cycles-spp", default="16,2",
                    help="Cycles' samples a pixel, one row each (comma-separated)")
    ap.add_argument("--miss-cost", action="store_true",
                    help="also the cost of a sample missing the Moon (sphere, crop vs frame)")
    args = ap.parse_args()
    seed = args.place_seed if args.place_seed is not None else time.time_ns() % 2**32
    place = tuple(np.random.default_rng(seed).uniform(-20.0, 20.0, 2))
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, python "
          f"{platform.python_version()}, mitsuba {mi.__version__}, drjit {dr.__version__}, "
          f"load {os.getloadavg()[0]:.1f} (1 min), place seed {seed}")
    cycles_python = args.cycles_python or (sys.executable if importlib.util.find_spec("bpy")
                                           else None)
    print("Blender Cycles: " + (f"run under {cycles_python} (benchmarks/cycles_frame.py)"
                                if cycles_python else "not installed (no --cycles-python, "
                                "no bpy in this Python)"))
    print("steady = median of frames 2..N; mesh/scene/radiance = its parts (medians); "
          "rebuilds = frames 2..N that built a Mitsuba scene; q = the real Moon's "
          "cache_quantum_px (-: the scenario default)")
    print(f"{'shape':6s} {'loop':7s} {'q':>3s} {'spp':>6s} {'triangles':>9s} {'range_km':>8s} "
          f"{'first_s':>8s} {'steady_s':>8s} {'mesh_s':>7s} {'scene_s':>7s} {'rad_s':>7s} "
          f"{'rebuilds':>8s} {'compiles':>8s} {'floor_s':>8s} {'moon_px':>8s} {'full%':>6s} "
          f"{'Msamples':>8s}  load")
    spps: tuple[int | None, ...] = (None,)
    if _HAS_ADAPTIVE and not args.no_adaptive:
        spps = (None, *(int(x) for x in args.interior_spp.split(",")))
    loops = (True, False) if args.compare else (True,)
    for range_km in args.ranges_km.split(","):
        range_m = float(range_km) * 1e3
        for shape in args.shapes.split(","):
            quanta = (None, 0.0) if (shape == "real" and args.rebuild) else (None,)
            rows: list[dict] = []
            for fused in loops:
                for q in quanta:
                    for ispp in (spps if fused else (None,)):
                        res = run(shape, range_m, args.frames, fused, place, q, ispp)
                        print(f"{res['shape']:6s} {res['loop']:7s} {res['quantum']:>3s} "
                              f"{res['spp']:>6s} {str(res['triangles']):>9s} "
                              f"{res['range_km']:8.0f} "
                              f"{res['first_s']:8.3f} {res['steady_s']:8.3f} "
                              f"{res['steady_mesh_s']:7.3f} {res['steady_scene_s']:7.3f} "
                              f"{res['steady_radiance_s']:7.3f} {res['rebuilds']:8d} "
                              f"{res['compiles']:8d} {res['floor_s']:8.3f} "
                              f"{res['moon_px']:8d} {res['full_pct']:6.1f} "
                              f"{res['msamples']:8.2f}  "
                              f"{os.getloadavg()[0]:.1f} {res['variant']}", flush=True)
                        rows.append(res)
                        if res["adaptive_parts"]:
                            print("         steps (s): " + ", ".join(
                                f"{k[:-2]} {v:.3f}" for k, v in res["adaptive_parts"].items())
                                + f"; floor of its own camera rays (centre + samples, no "
                                f"shadow ray) {res['floor_frame_s']:.3f}", flush=True)
            for c_spp in (args.cycles_spp.split(",") if cycles_python and shape == "real"
                          and rows else ()):
                c = run_cycles(cycles_python, rows[0], int(c_spp))
                print(f"{'real':6s} {'cycles':7s} {'-':>3s} {c_spp:>6s} "
                      f"{str(rows[0]['triangles']):>9s} {float(range_km):8.0f} "
                      f"{c['first_s']:8.3f} {c['steady_s']:8.3f}  Blender {c['blender']} "
                      f"Cycles, {c['threads']} threads, same frames and mesh (import "
                      f"{c['import_s']:.1f} s, not counted), Moon pixels {c['moon_px']} "
                      f"(IoU with starnav's mask {c['iou']:.4f}), interior noise (median "
                      f"std / mean over {c['noise']['seeds']} seeds, {c['noise']['pixels']} lit "
                      f"interior pixels, like benchmarks/render_noise.py) "
                      f"{100 * c['noise']['median_rel_std']:.2f} %, load "
                      f"{os.getloadavg()[0]:.1f}", flush=True)
                print(f"         steady time as a fraction of Cycles' at {c_spp} spp: " + ", ".join(
                    f"{res['loop']} {res['spp']} {res['steady_s'] / c['steady_s']:.3f} "
                    f"({c['steady_s'] / res['steady_s']:.1f}x faster)" for res in rows),
                    flush=True)
    if args.miss_cost:
        miss_cost(args.frames, place)


if __name__ == "__main__":
    main()
