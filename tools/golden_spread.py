"""Measure what the golden tolerances (tests/golden/pin.py) must cover, and print the largest
value of each rule's statistic next to its tolerance.

1. Across CPUs: the golden commands run once per Dr.Jit LLVM target forced on this machine
   (``STARNAV_LLVM_TARGET``), each compared with the first (the host's own target).
2. Downstream of the DN: a dataset made once, then navigated again after +-1 DN at a fraction
   of the segment and window values (never past the threshold or the ADC's full scale), per
   seeded draw.

Run it before changing a tolerance or re-pinning for a new kind of output (several minutes)::

    .venv/bin/python tools/golden_spread.py [--draws 12] [--fraction 0.005]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import re
import shutil
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.golden import pin  # noqa: E402

#: Targets forced after the host's own (x86-64; Dr.Jit needs fused multiply-adds).
TARGETS = ("znver3;+avx2,+fma;8", "haswell;+avx2,+fma;4", "skylake-avx512;+avx512f,+avx2,+fma;16")


def _flat(x, p=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _flat(v, f"{p}.{k}" if p else k)
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _flat(v, f"{p}[{i}]")
    else:
        yield p, x


def spread(a_arr, a_val, b_arr, b_val, seen: dict[str, float]) -> None:
    """Update ``seen`` (rule -> largest statistic) with run ``a`` against run ``b``."""
    for k in b_arr:
        a, b = np.asarray(a_arr[k]), np.asarray(b_arr[k])
        if np.issubdtype(b.dtype, np.floating):
            ok = ~np.isnan(b)
            scale = float(np.max(np.abs(b[ok]))) if ok.any() else 1.0
            d = np.abs(a[ok].astype(float) - b[ok]) / scale
            seen["image: largest pixel difference / max"] = max(
                seen["image: largest pixel difference / max"], float(d.max(initial=0)))
            seen["image: fraction of pixels beyond 1e-6 of max"] = max(
                seen["image: fraction of pixels beyond 1e-6 of max"],
                float((d > pin.IMAGE_PIXEL_TOL).mean()))
            mag = float(np.abs(b[ok]).sum())
            seen["image: sum difference / sum of magnitudes"] = max(
                seen["image: sum difference / sum of magnitudes"],
                abs(float(a[ok].sum(dtype=float) - b[ok].sum(dtype=float))) / max(mag, 1e-300))
        elif k.endswith("/dn"):
            d = np.abs(a.astype(int) - b.astype(int))
            seen["DN image: fraction differing"] = max(seen["DN image: fraction differing"],
                                                       float((d > 0).mean()))
            seen["DN image: fraction beyond 1 DN"] = max(seen["DN image: fraction beyond 1 DN"],
                                                         float((d > 1).mean()))
            seen["DN: largest difference"] = max(seen["DN: largest difference"], float(d.max()))
    fa = dict(_flat(json.loads(json.dumps(pin.scrub(a_val)))))
    fb = dict(_flat(pin.scrub(b_val)))
    win = defaultdict(lambda: [0, 0, 0])
    for k, vb in fb.items():
        va = fa.get(k)
        if not (isinstance(vb, int | float) and isinstance(va, int | float)) \
                or isinstance(vb, bool) or (isinstance(vb, float) and math.isnan(vb)):
            continue
        m = re.search(r"(.*windows\.windows)\[\d+\]\.dn", k)
        if m:
            w = win[m.group(1)]
            w[0] += 1
            w[1] += va != vb
            w[2] += abs(va - vb) > 1
            continue
        if re.search(r"segments\.values", k):
            continue
        if k.startswith(("navigate/", "sweep/")):
            for pattern, atol, _rtol in pin.DOWNSTREAM:
                if re.search(pattern, k):
                    rule = f"navigation /{pattern}/ (tolerance {atol:g})"
                    seen[rule] = max(seen[rule], abs(va - vb))
                    break
        elif "/readout." in k:
            m = re.search(r"(.*ledger_e)\.", k)
            scale = abs(vb) if m is None else max(
                abs(v) for kk, v in fb.items() if kk.startswith(m.group(1) + "."))
            seen["readout: difference / the ledger's largest entry"] = max(
                seen["readout: difference / the ledger's largest entry"],
                abs(va - vb) / max(scale, 1e-300))
    for n, diff, big in win.values():
        seen["windows: fraction of entries differing"] = max(
            seen["windows: fraction of entries differing"], diff / n)
        seen["windows: fraction beyond 1 DN"] = max(seen["windows: fraction beyond 1 DN"],
                                                     big / n)


def across_targets(seen: dict[str, float]) -> None:
    import os

    runs = []
    for target in ("",) + (TARGETS if platform.machine() == "x86_64" else ()):
        os.environ.pop("STARNAV_LLVM_TARGET", None)
        if target:
            os.environ["STARNAV_LLVM_TARGET"] = target
        with tempfile.TemporaryDirectory() as d:
            try:
                runs.append((target or "host", *pin.outputs(Path(d))))
            except RuntimeError as err:  # e.g. AVX-512 forced on a CPU without it
                print(f"target {target}: not run ({str(err).splitlines()[-1][:100]})")
    os.environ.pop("STARNAV_LLVM_TARGET", None)
    for name, arr, val in runs[1:]:
        print(f"target {name} against the host's")
        spread(arr, val, runs[0][1], runs[0][2], seen)


def downstream_of_dn(seen: dict[str, float], draws: int, fraction: float) -> None:
    with tempfile.TemporaryDirectory() as d:
        w = Path(d)
        (w / "sc.yaml").write_text(pin.SCENARIO)
        pin._starnav("dataset", "sc.yaml", "--out", "ds", "--exposures", "1.5e-5,7.7e-3",
                     "--exposure-set", "7.7e-3:detector.readout.segments.thresholds_dn=[2048]",
                     cwd=w)

        def navigate(ds: str) -> dict:
            out = {}
            for ms in ("0.015", "7.7"):
                o = w / f"nav_{ms}"
                shutil.rmtree(o, ignore_errors=True)
                pin._starnav("navigate", ds, "--out", o.name, "--exposure", f"{ms}ms",
                             "--no-plots", cwd=w)
                out[f"navigate/{ms}/metrics"] = pin.scrub(json.loads(
                    (o / "metrics.json").read_text()))
                out[f"navigate/{ms}/estimates"] = pin._read_csv(o / "estimates.csv")
            return out

        base = navigate("ds")
        full_scale = 4095
        for t in range(draws):
            rng = np.random.default_rng(1000 + t)
            shutil.rmtree(w / "ds_p", ignore_errors=True)
            shutil.copytree(w / "ds", w / "ds_p")
            for f in sorted((w / "ds_p" / "frames").glob("*/exposure_*")):
                s = json.loads((f / "segments.json").read_text())
                v = np.array(s["values"])
                nv = v + rng.choice([-1, 1], v.size) * (rng.random(v.size) < fraction)
                keep = (nv >= min(s["thresholds_dn"])) & (v < full_scale) & (nv <= full_scale)
                s["values"] = np.where(keep, nv, v).tolist()
                (f / "segments.json").write_text(json.dumps(s))
                wj = json.loads((f / "windows.json").read_text())
                for win in wj["windows"]:
                    a = np.array(win["dn"])
                    m = (rng.random(a.shape) < fraction) & (a < full_scale)
                    win["dn"] = np.clip(a + rng.choice([-1, 1], a.shape) * m, 0,
                                        full_scale).tolist()
                (f / "windows.json").write_text(json.dumps(wj))
            spread({}, navigate("ds_p"), {}, base, seen)
            print(f"+-1 DN draw {t + 1} of {draws}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--fraction", type=float, default=0.005)
    args = ap.parse_args()
    seen: dict[str, float] = defaultdict(float)
    across_targets(seen)
    downstream_of_dn(seen, args.draws, args.fraction)
    print(f"\n{'statistic':<62} largest seen")
    for k in sorted(seen):
        print(f"{k:<62} {seen[k]:.3g}")
    print(f"\ntolerances: image pixel {pin.IMAGE_PIXEL_TOL:g} (outliers {pin.IMAGE_OUTLIER_TOL:g} "
          f"at <= {pin.IMAGE_OUTLIER_FRACTION:.0%}), image sum {pin.IMAGE_SUM_RTOL:g}; DN "
          f"differing <= {pin.DN_DIFF_FRACTION:.1%}, beyond 1 DN <= {pin.DN_BIG_FRACTION:.1%} "
          f"(windows {pin.DN_DIFF_FRACTION_WINDOWS:.0%}, {pin.DN_BIG_FRACTION_WINDOWS:.1%}), "
          f"largest {pin.DN_MAX_DIFF} DN; readout {pin.RADIOMETRIC_RTOL:g}")


if __name__ == "__main__":
    main()
