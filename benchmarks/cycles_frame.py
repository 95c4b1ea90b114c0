"""Blender Cycles, the paper's engine, on the same frames as ``benchmarks/render.py``.

This script runs under a Python that has ``bpy`` (Blender as a module). ``bpy`` pins
``numpy < 2`` and Python 3.11, so it lives in its own environment, not in starnav's::

    python3.11 -m venv /work/cycles-venv && /work/cycles-venv/bin/pip install bpy

``benchmarks/render.py --cycles-python /work/cycles-venv/bin/python`` writes each scene it
rendered (the view mesh in the Moon's body-fixed frame [km] with its vertex normals and vertex
albedo, and for every frame the camera pose, the field
of view and the Sun direction) to an ``.npz`` and runs this script on it. What is rendered is
what starnav's renderer renders in those frames, as the paper's pipeline (CORTO) would: Cycles
path tracing on the CPU with both cores, ``spp`` samples a pixel, direct light only
(``max_bounces = 0``; starnav's ``direct`` integrator has no bounce either), a sun lamp, a
Lambert (Diffuse BSDF) surface coloured by the vertex albedo, a box pixel filter of one pixel,
no adaptive sampling, no denoising, no light tree (one lamp), one tile, the same crop window
as starnav's renderer (a render border on the Moon's bounding box), persistent data on
(the BVH is kept between frames when only the camera and the Sun move, Cycles' best case for a
sequence). Cycles has no Hapke BRDF: the Lambert surface is cheaper to shade than starnav's
Hapke, so the comparison favours Cycles.

Printed (one JSON line): ``import_s`` (mesh into Blender, not a render cost), ``first_s`` (the
first frame: scene sync and BVH build), ``steady_s`` (median of frames 2..N, camera and Sun
moving), ``frames_s``, and the last frame's Moon pixels (``moon_px``, alpha > 0.5) and their
agreement with starnav's mask of the same frame (``iou``, given ``mask`` in the input): the
check that both engines rendered the same view; ``noise``: the last frame rendered again with
``--noise-seeds`` other seeds, the median per-pixel std / mean over its lit interior, so that
speed can be compared at about equal noise (``benchmarks/render_noise.py`` measures starnav's
the same way, but selects the interior from starnav's AOVs, on its own centred phase-30 frame:
the two figures are alike, not identical).

Usage: <python with bpy> benchmarks/cycles_frame.py SCENE.npz [--threads 2] [--noise-seeds 4]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import bpy
import mathutils
import numpy as np


def _material() -> bpy.types.Material:
    """Lambert (Diffuse BSDF, roughness 0) coloured by the vertex attribute ``albedo``."""
    mat = bpy.data.materials.new("regolith")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Roughness"].default_value = 0.0
    col = nodes.new("ShaderNodeAttribute")
    col.attribute_name = "albedo"
    mat.node_tree.links.new(col.outputs["Color"], diffuse.inputs["Color"])
    mat.node_tree.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _colour(me: bpy.types.Mesh, albedo: np.ndarray) -> None:
    rgba = np.ones((len(me.vertices), 4), np.float32)
    rgba[:, :3] = np.clip(albedo, 0.0, 1.0).astype(np.float32)[:, None]
    attr = me.color_attributes.new("albedo", "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.ravel())
    me.polygons.foreach_set("use_smooth", np.ones(len(me.polygons), dtype=bool))
    me.materials.append(_material())


def _mesh_object(v: np.ndarray, f: np.ndarray, n: np.ndarray, albedo: np.ndarray) -> None:
    me = bpy.data.meshes.new("moon")
    me.vertices.add(len(v))
    me.vertices.foreach_set("co", v.astype(np.float32).ravel())
    me.loops.add(3 * len(f))
    me.loops.foreach_set("vertex_index", f.astype(np.int32).ravel())
    me.polygons.add(len(f))
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * len(f), 3, dtype=np.int32))
    me.update(calc_edges=True)
    _colour(me, albedo)
    # the view mesh's own vertex normals, with which starnav's renderer shades
    me.normals_split_custom_set_from_vertices(n.astype(np.float32))
    obj = bpy.data.objects.new("moon", me)
    bpy.context.scene.collection.objects.link(obj)


def _rotation_z_to(d: np.ndarray) -> np.ndarray:
    """A rotation whose +z column is the unit vector ``d``."""
    z = d / np.linalg.norm(d)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _set_matrix(obj: bpy.types.Object, R: np.ndarray, t: np.ndarray) -> None:
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    # a mathutils.Matrix is built from rows (a plain nested list would be read by columns)
    obj.matrix_world = mathutils.Matrix([list(map(float, row)) for row in M])


def _pixels(path: str, W: int, H: int) -> np.ndarray:
    """The render result as an (H, W, 4) float32 RGBA array, rows top-down."""
    bpy.data.images["Render Result"].save_render(filepath=path)
    img = bpy.data.images.load(path)
    px = np.empty(W * H * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(H, W, 4)[::-1]  # Blender's rows run bottom-up


def _interior_noise(first: np.ndarray, n: int, path: str, W: int, H: int) -> dict:
    """The last frame rendered with seeds 1..n as well: per pixel, the std / mean of the
    green channel over the ``n + 1`` renders (ddof 1); median over the lit interior (fully
    covered pixels whose 3 x 3 neighbourhood is too, above 5 % of the median level; Cycles
    gives no incidence angle, which ``benchmarks/render_noise.py`` uses instead)."""
    stack = [first[:, :, 1]]
    sc = bpy.context.scene
    sc.render.use_persistent_data = False  # a kept session keeps its seed
    for seed in range(1, n + 1):
        sc.cycles.seed = seed
        bpy.ops.render.render(write_still=False)
        stack.append(_pixels(f"{path}.{seed}.exr", W, H)[:, :, 1])
    g = np.stack(stack)
    full = first[:, :, 3] >= 0.999
    inner = full.copy()
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            inner &= np.roll(np.roll(full, dv, 0), du, 1)
    mean = g.mean(axis=0)
    lit = inner & (mean > 0.05 * np.median(mean[inner & (mean > 0)]))
    rel = g.std(axis=0, ddof=1)[lit] / mean[lit]
    return {"seeds": n + 1, "pixels": int(lit.sum()), "median_rel_std": float(np.median(rel))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--alpha-out", help="save the last frame's alpha (.npy, rows top-down)")
    ap.add_argument("--noise-seeds", type=int, default=4,
                    help="render the last frame this many more times with other seeds and "
                    "print its interior noise (0: no)")
    args = ap.parse_args()
    d = np.load(args.scene)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = int(d["spp"])
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.max_bounces = 0
    cy.diffuse_bounces = 0
    cy.glossy_bounces = 0
    cy.transmission_bounces = 0
    cy.transparent_max_bounces = 0
    cy.caustics_reflective = False
    cy.caustics_refractive = False
    cy.use_light_tree = False
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    cy.seed = 0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = args.threads
    sc.render.use_persistent_data = True
    sc.render.film_transparent = True
    # the result read back as linear 32-bit floats (the default output is an 8-bit PNG)
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.view_settings.view_transform = "Standard"
    W, H = int(d["width"]), int(d["height"])
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.render.resolution_percentage = 100
    # the same crop window as starnav's renderer (the Moon's bounding box), frame by frame
    sc.render.use_border = True
    sc.render.use_crop_to_border = False
    world = bpy.data.worlds.new("space")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    sc.world = world

    t0 = time.perf_counter()
    _mesh_object(d["vertices_km"], d["faces"], d["normals"], d["albedo"])
    import_s = time.perf_counter() - t0

    cam_data = bpy.data.cameras.new("tracker")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = float(d["fov_x_rad"])
    cam_data.shift_x = float(d["shift_x"])
    cam_data.shift_y = float(d["shift_y"])
    cam_data.clip_start = float(d["clip_start_km"])
    cam_data.clip_end = float(d["clip_end_km"])
    cam = bpy.data.objects.new("tracker", cam_data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy = 1.0
    sun_data.angle = 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    sc.collection.objects.link(sun)

    # Blender's camera looks along its -Z with +Y up; starnav's along +z with +v (rows) down
    flip = np.diag([1.0, -1.0, -1.0])
    times = []
    for k in range(len(d["cam_R"])):
        _set_matrix(cam, d["cam_R"][k] @ flip, d["cam_pos_km"][k])
        # the lamp shines along its -Z: +Z towards the Sun
        _set_matrix(sun, _rotation_z_to(d["sun_dir"][k]), np.zeros(3))
        u0, v0, bw, bh = (int(x) for x in d["crop_uvwh"][k])
        # Blender's border is in fractions of the frame, y from the bottom
        sc.render.border_min_x, sc.render.border_max_x = u0 / W, (u0 + bw) / W
        sc.render.border_min_y, sc.render.border_max_y = 1.0 - (v0 + bh) / H, 1.0 - v0 / H
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=False)
        times.append(time.perf_counter() - t0)

    out = {"import_s": import_s, "first_s": times[0],
           "steady_s": statistics.median(times[1:]) if len(times) > 1 else times[0],
           "frames_s": [round(t, 3) for t in times], "blender": bpy.app.version_string,
           "threads": args.threads}
    # the last frame's alpha: the Moon's pixels, to check the view is starnav's
    px = _pixels(args.scene + ".exr", W, H)
    alpha = px[:, :, 3] > 0.5
    out["moon_px"] = int(alpha.sum())
    if args.alpha_out:
        np.save(args.alpha_out, px.reshape(H, W, 4)[::-1])
    if "mask" in d:
        m = d["mask"].astype(bool)
        out["iou"] = float((alpha & m).sum() / max(1, (alpha | m).sum()))
    if args.noise_seeds > 0:
        out["noise"] = _interior_noise(px, args.noise_seeds, args.scene + ".exr", W, H)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
