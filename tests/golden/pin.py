"""Golden outputs of the public commands, and what they promise across machines.

``outputs(workdir)`` runs, through the command line a user types, a small static render, a
2-frame dataset at 0.015 and 7.7 ms, navigation on it and a 1-point sweep, and returns what they
wrote as plain data (arrays and JSON-like values), with what depends on the clock, the machine
or the software version removed. ``tools/pin_golden.py`` stores it in ``tests/golden/reference``;
``tests/test_golden.py`` compares a fresh run with it through :func:`compare_outputs`.

What is pinned, and how tightly
-------------------------------
Dr.Jit compiles the renderer's kernels for the CPU it runs on (vector width, AVX2 or AVX-512,
the hardware's reciprocal and square-root approximations), so the same render differs between
machines in the last bits of float32; a DN that sits on a rounding boundary then flips by one,
and a Poisson draw whose acceptance test flips draws anew (a few DN in a dim pixel). The
tolerances cover that and nothing more. They were set from the spread between Dr.Jit targets
forced on one machine (``STARNAV_LLVM_TARGET``: the host's AVX-512 at 16 lanes, ``znver3`` and
``haswell`` AVX2 at 8 and 4 lanes, ``skylake-avx512``) and from the values a +-1 DN change
moves (``tools/golden_spread.py``: +-1 DN at 0.5 % of the DN read, twelve draws),
each with a margin of 4 or more:

==========================  ====================================  =========================
what                        tolerance                             largest seen (targets and
                                                                  +-1 DN draws)
==========================  ====================================  =========================
float images (radiance,     every pixel within 1e-6 of the        7e-6 of max; 0.33 % of
AOVs)                       image's max but <= 2 % of pixels,     pixels beyond 1e-6 (AOVs
                            those within 1e-4; NaN where the      at grazing pixels); sums
                            reference has NaN; sums within 1e-6   9e-8
                            of the sum of magnitudes
DN images and the DN of     <= 1 % of pixels differ, <= 0.2 % by  0.18 % differ, 0.03 % by
segments and windows        more than 1 DN; of the windows'       more than 1 DN, 4 DN at
                            entries, which sit on the limb,       most (dim pixels whose
                            <= 4 % and 1 %; none by more than     Poisson draw flipped);
                            16 DN; DN sums within 1e-4            windows 0.62 %, by 1 DN
electron ledgers of the     1e-6 of the ledger's largest entry    4e-8 (3e-7 of an entry
readout                     (entries are sums and differences     that is a difference:
                            of one budget); other readout         the optics' losses)
                            floats relative 1e-6
navigation (``navigate``,   by unit: 10 km, 0.02 m/s, 5e-4 px,    1.2 km, 1.5e-3 m/s,
``sweep``)                  0.02 %; NIS/NEES 0.1 + 1 %;           6.7e-5 px, 3.4e-4 %;
                            limb-point counts +-2; a fraction     NIS 0.035; counts 0 (+-1
                            of frames by one frame of the two     DN can move a limb point
                                                                  across a threshold)
everything else (geometry,  relative 1e-9 (double precision,      0
truth, counts, statuses)    NumPy on the same inputs), strings
                            and integers exactly
==========================  ====================================  =========================

The differences an AMD EPYC (AVX2) machine gave against pins made on an AVX-512 Intel one
(electron ledgers 2-4e-8, a few DN by 1) lie inside. Forced targets reproduce the instruction
set and the vector width, not a vendor's hardware estimates (Dr.Jit refines the CPU's
reciprocal-square-root estimate), hence the margins.

A deliberate 0.5 % change of a render fails (``tests/test_golden.py``): every lit pixel moves
by 5e-3 of its value, far beyond the per-pixel and sum tolerances, and every DN above ~200.
Exact equality stays where the code controls every bit, on one machine: the detector chain
on a given radiance (``tests/detector/test_chain.py``), the dataset writer's resume
(``tests/dataset/test_resume_kill.py``), 0 and 2 workers (``tests/dataset/test_generate.py``).

A moved line of code must not change what a user gets; a difference beyond these tolerances
is either a bug or is explained in the commit that re-pins the reference with
``tools/pin_golden.py`` (``git log tests/golden/reference`` holds every explanation).
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
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
            "sha256", "bytes", "hostname", "python", "starnav_version", "mitsuba_version",
            "llvm")
#: CSV columns that are timings.
VOLATILE_COLUMNS = ("t_limb_ms", "t_ransac_ms", "t_refine_ms", "t_fix_ms", "t_ekf_ms", "cpu_ms")

# ---------------------------------------------------------------- tolerances (docstring table)
#: Float images: per-pixel tolerance and the fraction of pixels allowed up to the looser one
#: [fractions of the image's largest value]; image sums [relative].
IMAGE_PIXEL_TOL = 1e-6
IMAGE_OUTLIER_TOL = 1e-4
IMAGE_OUTLIER_FRACTION = 0.02
IMAGE_SUM_RTOL = 1e-6
#: DN: fraction of pixels (entries) that may differ, that may differ by more than 1 DN (images;
#: window entries, which sit on the limb), the largest difference [DN], sums [relative].
DN_DIFF_FRACTION = 0.01
DN_BIG_FRACTION = 0.002
DN_DIFF_FRACTION_WINDOWS = 0.04
DN_BIG_FRACTION_WINDOWS = 0.01
DN_MAX_DIFF = 16
DN_SUM_RTOL = 1e-4
#: Floats of the readout (electron ledgers) [relative].
RADIOMETRIC_RTOL = 1e-6
#: Everything computed in double precision from the same inputs [relative, absolute].
EXACT_RTOL, EXACT_ATOL = 1e-9, 1e-12
#: Navigation outputs (``navigate/``, ``sweep/``): (pattern on the value's path, absolute,
#: relative); the first match applies, an unmatched float is held to EXACT_RTOL.
DOWNSTREAM: tuple[tuple[str, float, float], ...] = (
    (r"(epoch|index|\.point$|\.run$|frames|fixes|accepted|exposure_time|albedo_scale)",
     0.0, EXACT_RTOL),
    (r"windows_planned_fraction", 0.0, EXACT_RTOL),
    (r"fraction", 0.5, 0.0),
    (r"(limb_points|saturated_pixels|\.count$)", 2.0, 0.0),
    (r"dn_max", 1.0, 0.0),
    (r"_px(\.|$)", 5e-4, 0.0),
    (r"pct_", 2e-2, 0.0),
    (r"_m_s(\[\d+\])?$", 2e-2, 0.0),
    (r"_m(\[\d+\])?$", 1e4, 0.0),
    (r"(nees|nis)", 0.1, 1e-2),
)
_SEGMENT_VALUES = re.compile(r"segments\.values$")
_WINDOWS = re.compile(r"windows\.windows$")


def _starnav(*args: str, cwd: Path, env: dict[str, str] | None = None) -> None:
    exe = str(Path(sys.executable).with_name("starnav"))
    env = {**os.environ, "COLUMNS": "200", **(env or {})}
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


def render_outputs(workdir: Path, *extra: str, env: dict[str, str] | None = None
                   ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``starnav render`` of the static scenario (``extra``: more arguments, e.g. ``--set``;
    ``env``: more environment variables, e.g. ``STARNAV_LLVM_TARGET``)."""
    from starnav.radiance import read_exr

    workdir = Path(workdir)
    (workdir / "static.yaml").write_text(STATIC)
    arrays: dict[str, np.ndarray] = {}
    values: dict[str, Any] = {}
    _starnav("render", "static.yaml", "--out", "render", *extra, cwd=workdir, env=env)
    for p in sorted((workdir / "render").glob("*.exr")):
        for k, v in _exr(p).items():
            arrays[f"render/{p.stem}/{k}"] = v
        values[f"render/{p.stem}/meta"] = scrub(json.loads(json.dumps(read_exr(p).meta,
                                                                     default=str)))
    return arrays, values


def outputs(workdir: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Run the commands in ``workdir``; returns (arrays, JSON-like values)."""
    workdir = Path(workdir)
    (workdir / "sc.yaml").write_text(SCENARIO)
    arrays, values = render_outputs(workdir)

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


# ---------------------------------------------------------------------------- comparison
def _all_int(x: list[Any]) -> bool:
    return all(isinstance(v, int) and not isinstance(v, bool) for v in x)


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _number_tolerance(path: str) -> tuple[float, float]:
    """(absolute, relative) tolerance of the float at ``path`` (module table)."""
    if path.startswith(("navigate/", "sweep/")):
        for pattern, atol, rtol in DOWNSTREAM:
            if re.search(pattern, path):
                return atol, rtol
        return EXACT_ATOL, EXACT_RTOL
    if re.search(r"/readout\.", path):
        return 0.0, RADIOMETRIC_RTOL
    return EXACT_ATOL, EXACT_RTOL


def _dn_differences(a: np.ndarray, b: np.ndarray, what: str,
                    diff_fraction: float = DN_DIFF_FRACTION,
                    big_fraction: float = DN_BIG_FRACTION) -> list[str]:
    """The DN rule (module table) on two integer arrays of one shape."""
    d = np.abs(a.astype(np.int64) - b.astype(np.int64))
    n = d.size
    out = []
    if n == 0 or not d.any():
        return out
    if (d > 0).sum() > diff_fraction * n:
        out.append(f"{what}: {int((d > 0).sum())} of {n} values differ "
                   f"(at most {diff_fraction:.1%} may)")
    if (d > 1).sum() > big_fraction * n:
        out.append(f"{what}: {int((d > 1).sum())} of {n} values differ by more than 1 DN "
                   f"(at most {big_fraction:.1%} may)")
    if d.max() > DN_MAX_DIFF:
        out.append(f"{what}: a value differs by {int(d.max())} DN (at most {DN_MAX_DIFF})")
    sa, sb = float(a.sum()), float(b.sum())
    if abs(sa - sb) > DN_SUM_RTOL * max(abs(sb), 1.0):
        out.append(f"{what}: DN sum {sa:.0f} != {sb:.0f}")
    return out


def compare(a: Any, b: Any, path: str = "") -> list[str]:
    """Differences between a fresh value ``a`` and the reference ``b`` (module table)."""
    if isinstance(b, dict):
        if not isinstance(a, dict) or set(a) != set(b):
            ka = set(a) if isinstance(a, dict) else set()
            return [f"{path}: keys differ: only new {sorted(ka - set(b))}, "
                    f"only reference {sorted(set(b) - ka)}"]
        sep = "." if path else ""
        if path.endswith("ledger_e") and all(_is_number(v) for v in (*a.values(),
                                                                      *b.values())):
            # an electron ledger: its entries are sums and differences of one budget, each
            # held to RADIOMETRIC_RTOL of the budget's largest entry
            scale = max(abs(v) for v in b.values()) if b else 0.0
            return [f"{path}{sep}{k}: {a[k]!r} != {b[k]!r} (tolerance {RADIOMETRIC_RTOL:g} of "
                    f"the ledger's largest entry {scale:.6g})" for k in b
                    if abs(a[k] - b[k]) > RADIOMETRIC_RTOL * scale]
        return [d for k in b for d in compare(a[k], b[k], f"{path}{sep}{k}")]
    if isinstance(b, list):
        if not isinstance(a, list) or len(a) != len(b):
            return [f"{path}: length {len(a) if isinstance(a, list) else a!r} != {len(b)}"]
        if _SEGMENT_VALUES.search(path) and _all_int(a) and _all_int(b):
            return _dn_differences(np.asarray(a), np.asarray(b), path)
        if _WINDOWS.search(path) and all(isinstance(w, dict) and "dn" in w for w in a + b):
            out = [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                   for d in compare({k: v for k, v in x.items() if k != "dn"},
                                    {k: v for k, v in y.items() if k != "dn"}, f"{path}[{i}]")]
            dn_a = [np.asarray(w["dn"]) for w in a]
            dn_b = [np.asarray(w["dn"]) for w in b]
            if any(x.shape != y.shape for x, y in zip(dn_a, dn_b, strict=True)):
                return out + [f"{path}: the windows' shapes differ"]
            if dn_a:
                out += _dn_differences(np.concatenate([x.ravel() for x in dn_a]),
                                       np.concatenate([y.ravel() for y in dn_b]),
                                       f"{path}[*].dn", DN_DIFF_FRACTION_WINDOWS,
                                       DN_BIG_FRACTION_WINDOWS)
            return out
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                for d in compare(x, y, f"{path}[{i}]")]
    if isinstance(b, bool) or b is None or isinstance(b, str):
        return [] if a == b else [f"{path}: {a!r} != {b!r}"]
    if isinstance(b, int) and isinstance(a, int) and not path.startswith(("navigate/",
                                                                           "sweep/")):
        return [] if a == b else [f"{path}: {a} != {b}"]
    if _is_number(b) and _is_number(a):
        if math.isnan(b) or math.isnan(a):
            return [] if math.isnan(a) and math.isnan(b) else [f"{path}: {a!r} != {b!r}"]
        atol, rtol = _number_tolerance(path)
        ok = abs(a - b) <= atol + rtol * abs(b)
        return [] if ok else [f"{path}: {a!r} != {b!r} (tolerance {atol:g} + {rtol:g} x |ref|)"]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def compare_arrays(new: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> list[str]:
    """Differences between fresh and reference arrays (module table)."""
    if set(new) != set(ref):
        return [f"arrays differ: only new {sorted(set(new) - set(ref))}, "
                f"only reference {sorted(set(ref) - set(new))}"]
    out = []
    for k in sorted(ref):
        a, b = np.asarray(new[k]), np.asarray(ref[k])
        if a.shape != b.shape:
            out.append(f"{k}: shape {a.shape} != {b.shape}")
        elif np.issubdtype(b.dtype, np.floating):
            out += _image_differences(a, b, k)
        elif k.endswith("/dn"):
            out += _dn_differences(a, b, k)
        elif not np.array_equal(a, b):
            out.append(f"{k}: {int((a != b).sum())} pixels differ "
                       f"(largest {int(np.max(np.abs(a.astype(np.int64) - b)))})")
    return out


def _image_differences(a: np.ndarray, b: np.ndarray, what: str) -> list[str]:
    """The float-image rule (module table)."""
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if not np.array_equal(nan_a, nan_b):
        return [f"{what}: {int((nan_a != nan_b).sum())} pixels are NaN in one image only"]
    ok = ~nan_b
    scale = float(np.max(np.abs(b[ok]))) if ok.any() else 0.0
    diff = np.abs(a[ok].astype(np.float64) - b[ok])
    out = []
    loose = (diff > IMAGE_PIXEL_TOL * scale).sum()
    if loose > IMAGE_OUTLIER_FRACTION * diff.size:
        out.append(f"{what}: {int(loose)} of {diff.size} pixels differ by more than "
                   f"{IMAGE_PIXEL_TOL:g} of max (at most {IMAGE_OUTLIER_FRACTION:.0%} may)")
    if diff.size and diff.max() > IMAGE_OUTLIER_TOL * scale:
        out.append(f"{what}: a pixel differs by {diff.max():.3g}, more than "
                   f"{IMAGE_OUTLIER_TOL:g} of max {scale:.3g}")
    sa, sb = float(np.sum(a[ok], dtype=np.float64)), float(np.sum(b[ok], dtype=np.float64))
    # relative to the sum of magnitudes: signed channels (normals, latitudes) cancel
    mag = max(float(np.sum(np.abs(b[ok]), dtype=np.float64)), np.finfo(np.float32).tiny)
    if abs(sa - sb) > IMAGE_SUM_RTOL * mag:
        out.append(f"{what}: sum {sa:.9g} != {sb:.9g} ({abs(sa - sb) / mag:.2g} of the sum "
                   f"of magnitudes, at most {IMAGE_SUM_RTOL:g})")
    return out


def compare_outputs(arrays: dict[str, np.ndarray], values: dict[str, Any],
                    ref_arrays: dict[str, np.ndarray], ref_values: dict[str, Any]) -> list[str]:
    """Every difference between a fresh run and the reference beyond the module's tolerances
    (both sides scrubbed of volatile keys, the fresh values round-tripped through JSON)."""
    fresh = json.loads(json.dumps(scrub(values), sort_keys=True))
    return compare(fresh, scrub(ref_values)) + compare_arrays(arrays, ref_arrays)


def load_reference(ref: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The pinned (arrays, values) in ``ref``."""
    values = json.loads((ref / "values.json").read_text())
    with np.load(ref / "arrays.npz") as z:
        arrays = {k: z[k] for k in z.files}
    return arrays, values
