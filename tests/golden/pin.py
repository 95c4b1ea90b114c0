"""Golden outputs of the public commands, pinned before the redesign (issue 14).

``outputs(workdir)`` runs, through the command line a user types, a small static render, a
2-frame dataset at 0.015 and 7.7 ms, navigation on it and a 1-point sweep, and returns what they
wrote as plain data (arrays and JSON-like values), with what depends on the clock, the machine
or the software version removed. ``tools/pin_golden.py`` stores it in ``tests/golden/reference``;
``tests/test_golden.py`` compares a fresh run with it:

* integer images (DN) and every count and status: exactly;
* float images (radiance, AOVs): relative 1e-6 of the image's largest value;
* every other number: relative 1e-9 (absolute 1e-12).

A moved line of code must not change what a user gets; a difference is either a bug or is named
in the issue's closing note and the reference re-pinned with ``tools/pin_golden.py``.

Re-pinned (each time the only difference, explained):

* 2026-11-24, ``starnav.simulate``: ``starnav render`` of a static scenario now writes the
  measured attitude (``R_cam_to_inertial_measured``, with the pointing knowledge error) in
  its geometry metadata, as ``starnav dataset`` always did: both come from the same
  :class:`starnav.simulate.Simulator`. Every image and every other value is unchanged.
* 2026-11-24, one navigation run: ``starnav navigate`` draws its initial state error and its
  RANSAC streams from ``starnav.seeding`` with the scenario's seed (before: ``default_rng(0)``
  split per frame), the streams of the sweep's run 0: the filter states and errors of
  ``estimates.csv`` changed (the fixes, the sigmas and the sweep did not), and equal the
  sweep's now (``tests/dataset/test_one_navigation_run.py``). ``metrics.json`` uses the
  :class:`starnav.navigation.metrics.NavMetrics` names shared with the sweep table
  (``final_position_error_m`` for ``final.position_error_norm_m``, ``nees_mean`` for
  ``nees.mean``, ``final_position_error_pct_range`` [%] for
  ``final.position_error_fraction_of_range``, now over the true final range instead of the
  median fix range).
* 2026-11-25, dataset format 2 (issue 15): every dataset frame also holds its 8-bit quick
  looks, ``radiance_quicklook.png`` and ``exposure_*/dn_quicklook.png``, so each frame's
  ``files`` list in the manifest has three more names. Every data file (``dn.png``,
  ``radiance.exr``, the JSON) and every other value is unchanged.
* 2026-11-25, the batched subpixel refinement (issue 18): the 16 windows are fitted together
  (normal equations instead of ``lstsq`` per evaluation, a window converged once a step moves
  its edge < 1e-4 px instead of after eight damped retries at the minimum), so the refined
  points move by ~1e-5 px (sweep ``limb_bias_px`` 0.0196450 -> 0.0196434 px, ``limb_std_px``
  by 2e-5 relative) and the navigation numbers downstream by as much: fixes by ~40 m at
  78 000 km (5e-7), the final position error by 7-9 m (1e-4 of it; 3e-5 of its 3-sigma). The
  images, the dataset and every count are unchanged; the points agree with the per-window fit
  to 3e-5 px on ``tests/navigation/test_refine_regression.py``'s pinned frames.
* 2026-11-25, the renderer's fused loop and the cheaper Hapke plugin (issue 18): on the JIT
  variants the renderer traces Mitsuba's own samples (same sampler, seed and sample order) but
  forms each ray from full-frame film coordinates and moves its origin to the near plane
  itself (crop window, seed and near plane no longer literals of the compiled kernels), and
  Hapke's shadowing and phase function use half-angle identities and ``rsqrt`` instead of
  ``sin``/``tan``/``power``, and the geometric AOV channels are computed in that kernel
  (float32, as the NumPy code did): the same numbers to float32 rounding. Radiance moves by
  <= 1.8e-6 of each image's maximum (400-1 100 pixels differ), the AOVs by float32 ulps
  (angles <= 1.1e-5 rad, longitude <= 8e-5 rad near a pole, normals <= 7e-6, range <= 32 m
  at 8e7 m), 10 of 65 536 DN values by 1 DN, the electron ledgers by
  <= 3.3e-7 relative, the limb bias by 7e-7 px, the fixes by ~35 m at 78 000 km (4e-7) and
  the final position error by 21 m (73 625 -> 73 603 m; 8e-5 of its 3-sigma). The same
  renders agree with the renderer before the change within Monte Carlo noise and to float32
  rounding seed for seed (``tests/renderer/test_speed_agreement.py``).
* 2026-11-25, the refinement's convergence test (issue 18, chain within 5 ms): a rejected
  Levenberg-Marquardt step shorter than 2e-4 px now ends a window's fit (it brackets the
  minimum within half its length, 1e-4 px, the accepted-step threshold) instead of up to
  seven more damped retries, so a window that stopped there moves by < 1e-4 px. The second
  0.015 ms frame's fix moved by 240 m at 79 000 km (3e-6; 0.3 % of its 1-sigma), the 7.7 ms
  fixes by up to 7 m (1e-7), the first 0.015 ms fix not at all, and the numbers downstream:
  sweep ``limb_bias_px`` 0.0196434 -> 0.0196387 px, the final position error by 36 m (5e-4
  of it), NEES by 1.5e-5 relative. Images, dataset and counts are unchanged; the other speed
  work of that change (limb scan, fix stage, filter) is pinned to 1e-9 by
  ``tests/navigation/test_chain_regression.py``.
* 2026-11-25, same issue: the unweighted first pass of a noise-weighted refinement (it only
  sets the weights) stops once a step moves the edge < 1e-2 px instead of 1e-4 px (not for
  saturated windows): the weights change by < 1e-3, the points by < 2e-5 px on the pinned
  refinement frames. The first 0.015 ms fix moved by 230 m at 79 000 km (2.9e-6), the second
  by 8 m, the 7.7 ms fixes not at all; sweep ``limb_bias_px`` 0.0196387 -> 0.0196341 px,
  the final position error +28 m (4e-4 of it) and -5 m at the second sweep point, NEES by
  4e-5 relative. Images, dataset and counts unchanged.
* 2026-11-25, the two changes above merged, re-pinned on the merged code: the images and DN
  equal the renderer change's pins exactly; the navigation numbers differ from either
  branch's pins by at most 1.4e-3 relative (final position error 73 603 m with the renderer
  change, 73 689 m with the refinement change, 73 668 m merged; 125 of 13 269 values moved,
  each by the two changes' own amounts combined).
* 2026-11-25, a frame sequence shares the real Moon's view mesh (issue 18, steady state):
  ``moon.dem.mesh.cache_quantum_px`` defaults to 8 px (was 0), so each frame's DEM mesh is
  the one of its cell (sub-camera direction to 8 nadir pixels, at most 1 deg; range to 1/8
  octave), made conservative for the cell: finer (the static render's 3 035 -> 3 357
  triangles) and from another set of vertex places and DEM levels. Nothing else changed; the
  differences are those of another tessellation of the same terrain: radiance sums by
  <= 8e-4 relative (1 100 of the static render's pixels, ~440 of each dataset frame's, mostly
  at the limb and on slopes), one limb pixel centre of the second frame, the electron ledgers
  by <= 8e-4, DN sums by <= 8e-4, the AOV normals and angles at those pixels. On this 128 px
  camera the limb (a disc of ~15 px radius) is a few dozen pixels, so the navigation numbers
  downstream move by as much as a new tessellation moves the limb: sweep ``limb_bias_px``
  0.0196 -> 0.0254 and 0.0218 -> 0.0269 px, final position errors 73.7 -> 74.3 km and
  7.1 -> 12.1 km (within their 3-sigma), NEES means 17.1 -> 19.5 and 11.3 -> 15.1. The exact
  meshes of two neighbouring frames differed as much before this change
  (``tests/renderer/test_sequence_reuse.py``); ``cache_quantum_px: 0`` gives the old pins.
* 2026-11-26, the refinement's fit (issue 18, whole chain within 5 ms): the detector-psf
  model's step and ramp are the exact integrals of the linearly interpolated line spread
  function (quadratic between the table's 0.02 px samples instead of linear: up to 2.5e-5 of
  the step, and the cost smooth in the edge's position), and the fit is Levenberg-Marquardt
  on the reduced (amplitudes solved) normal equations with a secant rescaling of its steps,
  its last step of < 1e-4 px taken unevaluated and a rejected step's parabola as the
  stopping test (refine module, step 4). The refined points move by ~1e-4 px (on
  ``tests/navigation/test_refine_regression.py``'s frames <= 9e-5 px; saturated windows,
  whose old cost was rough, by up to 2.2e-3 px), on this 128 px camera's ~15 px disc
  ``limb_bias_px`` 0.025361 -> 0.025426 and 0.026928 -> 0.027010 px, so the fixes by
  1.1-1.6e-5 relative at 0.015 ms (0.8-1.2 km at 79 000 km; their 1-sigma 18-67 km) and
  2.8-3.3e-5 at 7.7 ms, the final position errors 74.31 -> 74.03 km and 12.13 -> 11.85 km
  (3-sigma 255 km), NEES means 19.501 -> 19.509 and 15.074 -> 15.091. Images, dataset and
  counts unchanged.
* 2026-11-27, the renderer's spectral sampling and adaptive samples per pixel (issue 18):
  the wavelengths of each sample are drawn by the lit surface's electron spectrum
  (``render.spectral_sampling: electrons``; the film carries Sun x colour, ``L`` is
  ``kappa Le``) and the adaptive render is on by default (``interior_spp`` 2 in the flat
  interior, 4 = ``spp`` at the limb and terminator here). Every radiance image is another
  Monte Carlo realisation with less noise: the static frame's disc sum moves by -0.25 %
  (4-spp limb noise on a ~12 px disc), the dataset frames' by +0.08 % and -0.30 %; DN with
  them (``dn_max`` 1309 -> 1344 and 1296 -> 1276 at 0.015 ms). The AOVs are unchanged. The
  0.015 ms limb points are less noisy (``limb_error_px.std`` 0.0428 -> 0.0293 px, bias
  0.0254 -> 0.0287 px), the navigation downstream another realisation: final position
  error 74.0 -> 15.3 km (3-sigma 255 km), NEES mean 19.5 -> 15.3; at 7.7 ms one limb point
  fewer (32 -> 31), the filter unchanged. The renders agree with the renders before issue 18
  within Monte Carlo noise (``tests/renderer/test_speed_agreement.py``, seven radiometric
  cases) and ``L / Le`` is the frame's constant in every pixel
  (``tests/renderer/test_spectral_sampling.py``); the frame metadata's ``render`` has a new
  key ``spectral_sampling``, and ``adaptive`` (the sample counts' summary).
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

SCENARIO = """\
camera: {width: 128, height: 128, focal_length_mm: 12.5}
render: {spp: 4}
trajectory: {frames: 2, cadence_s: 1800.0, duration_days: 1.0}
pointing: {moon_offset_max_px: 20.0}
"""
STATIC = """\
camera: {width: 96, height: 96, focal_length_mm: 12.5}
render: {spp: 4}
geometry: {range_km: 60000.0, phase_angle_deg: 40.0}
"""
#: Keys whose values depend on the clock, the machine or the software version.
VOLATILE = ("timing_ms", "memory_kb", "software", "versions", "created", "wall_s", "elapsed",
            "sha256", "bytes", "hostname", "python", "starnav_version", "mitsuba_version")
#: CSV columns that are timings.
VOLATILE_COLUMNS = ("t_limb_ms", "t_ransac_ms", "t_refine_ms", "t_fix_ms", "t_ekf_ms", "cpu_ms")


def _starnav(*args: str, cwd: Path) -> None:
    exe = str(Path(sys.executable).with_name("starnav"))
    env = {**os.environ, "COLUMNS": "200"}
    env.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    r = subprocess.run([exe, *args], cwd=cwd, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"starnav {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")


def scrub(value: Any) -> Any:
    """``value`` without the volatile keys (recursively)."""
    if isinstance(value, dict):
        return {k: scrub(v) for k, v in value.items()
                if not any(s in k.lower() for s in VOLATILE)}
    if isinstance(value, list):
        return [scrub(v) for v in value]
    return value


def _read_csv(path: Path, drop: tuple[str, ...] = VOLATILE_COLUMNS) -> list[dict[str, Any]]:
    def num(s: str) -> Any:
        try:
            return float(s)
        except ValueError:
            return s

    with open(path, newline="") as fh:
        return [{k: num(v) for k, v in row.items()
                 if k not in drop and not any(s in k.lower() for s in VOLATILE)}
                for row in csv.DictReader(fh)]


def _exr(path: Path) -> dict[str, np.ndarray]:
    from starnav.radiance import read_exr

    img = read_exr(path)
    out = {"L": np.asarray(img.L), "Le": np.asarray(img.Le), "mask": np.asarray(img.mask)}
    for k, v in (img.aovs or {}).items():
        out[f"aov_{k}"] = np.asarray(v)
    return out


def _png(path: Path) -> np.ndarray:
    from starnav.detector.io import read_dn_png

    return np.asarray(read_dn_png(path))


def outputs(workdir: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Run the commands in ``workdir``; returns (arrays, JSON-like values)."""
    workdir = Path(workdir)
    (workdir / "sc.yaml").write_text(SCENARIO)
    (workdir / "static.yaml").write_text(STATIC)
    arrays: dict[str, np.ndarray] = {}
    values: dict[str, Any] = {}

    _starnav("render", "static.yaml", "--out", "render", cwd=workdir)
    from starnav.radiance import read_exr

    for p in sorted((workdir / "render").glob("*.exr")):
        for k, v in _exr(p).items():
            arrays[f"render/{p.stem}/{k}"] = v
        values[f"render/{p.stem}/meta"] = scrub(json.loads(json.dumps(read_exr(p).meta,
                                                                     default=str)))

    _starnav("dataset", "sc.yaml", "--out", "ds", "--exposures", "1.5e-5,7.7e-3",
             "--exposure-set", "7.7e-3:detector.readout.segments.thresholds_dn=[2048]",
             cwd=workdir)
    ds = workdir / "ds"
    values["dataset/manifest_frames"] = scrub(json.loads((ds / "manifest.json").read_text())
                                              ["frames"])
    for f in sorted((ds / "frames").iterdir()):
        values[f"dataset/{f.name}/truth"] = scrub(json.loads((f / "truth.json").read_text()))
        for k, v in _exr(f / "radiance.exr").items():
            arrays[f"dataset/{f.name}/radiance/{k}"] = v
        for e in sorted(p for p in f.iterdir() if p.is_dir()):
            arrays[f"dataset/{f.name}/{e.name}/dn"] = _png(e / "dn.png")
            for j in ("readout", "segments", "windows"):
                values[f"dataset/{f.name}/{e.name}/{j}"] = scrub(
                    json.loads((e / f"{j}.json").read_text()))

    for ms in ("0.015", "7.7"):
        out = f"nav_{ms}"
        _starnav("navigate", "ds", "--out", out, "--exposure", f"{ms}ms", "--no-plots", cwd=workdir)
        values[f"navigate/{ms}/metrics"] = scrub(
            json.loads((workdir / out / "metrics.json").read_text()))
        values[f"navigate/{ms}/estimates"] = _read_csv(workdir / out / "estimates.csv")

    _starnav("sweep", "sc.yaml", "--grid", "detector.exposure_time_s=1.5e-5", "--runs", "2",
             "--workers", "0", "--out", "sweep", "--no-figures", cwd=workdir)
    from starnav.batch.table import TIMING_COLUMNS

    values["sweep/results"] = _read_csv(workdir / "sweep" / "results.csv",
                                        drop=tuple(TIMING_COLUMNS) + VOLATILE_COLUMNS)
    return arrays, values


def compare(a: Any, b: Any, path: str = "") -> list[str]:
    """Differences between a fresh value ``a`` and the reference ``b`` (tolerances above)."""
    if isinstance(b, dict):
        if not isinstance(a, dict) or set(a) != set(b):
            ka = set(a) if isinstance(a, dict) else set()
            return [f"{path}: keys differ: only new {sorted(ka - set(b))}, "
                    f"only reference {sorted(set(b) - ka)}"]
        return [d for k in b for d in compare(a[k], b[k], f"{path}.{k}")]
    if isinstance(b, list):
        if not isinstance(a, list) or len(a) != len(b):
            return [f"{path}: length {len(a) if isinstance(a, list) else a!r} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                for d in compare(x, y, f"{path}[{i}]")]
    if isinstance(b, bool) or b is None or isinstance(b, str):
        return [] if a == b else [f"{path}: {a!r} != {b!r}"]
    if isinstance(b, int) and isinstance(a, int):
        return [] if a == b else [f"{path}: {a} != {b}"]
    if isinstance(b, int | float) and isinstance(a, int | float):
        if np.isnan(b) and np.isnan(a):
            return []
        ok = abs(a - b) <= 1e-12 + 1e-9 * abs(b)
        return [] if ok else [f"{path}: {a!r} != {b!r}"]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def compare_arrays(new: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> list[str]:
    """Differences between fresh and reference arrays (tolerances above)."""
    if set(new) != set(ref):
        return [f"arrays differ: only new {sorted(set(new) - set(ref))}, "
                f"only reference {sorted(set(ref) - set(new))}"]
    out = []
    for k in sorted(ref):
        a, b = np.asarray(new[k]), np.asarray(ref[k])
        if a.shape != b.shape:
            out.append(f"{k}: shape {a.shape} != {b.shape}")
        elif np.issubdtype(b.dtype, np.floating):
            scale = float(np.nanmax(np.abs(b))) if b.size else 0.0
            bad = ~(np.abs(a - b) <= 1e-6 * scale) & ~(np.isnan(a) & np.isnan(b))
            if bad.any():
                out.append(f"{k}: {int(bad.sum())} pixels differ by more than 1e-6 of max "
                           f"(largest {float(np.nanmax(np.abs(a - b))):.3g}, max {scale:.3g})")
        elif not np.array_equal(a, b):
            out.append(f"{k}: {int((a != b).sum())} pixels differ "
                       f"(largest {int(np.max(np.abs(a.astype(np.int64) - b)))})")
    return out
