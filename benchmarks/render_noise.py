"""Monte Carlo noise of the full-field real-Moon frame against samples per pixel and the
spectral sampling (issue 18): what ``render.spectral_sampling`` and the adaptive render's
``render.interior_spp`` default were chosen from.

The frame: the default scenario's real Moon (LDEM_4 mesh, LROC albedo, calibrated Hapke, ROLO
colour) on the 1024 x 1024 AA-STR at 9 715 km, phase 30 deg, centred (it fills the field).
For each spectral sampling (``response``: wavelengths drawn by the sensor's band box plus its
electron response, the renderer before issue 18; ``electrons``: by the electron spectrum of
the lit surface) and each ``spp`` (every pixel, non-adaptive), ``--seeds`` renders give each
pixel's mean and standard deviation of ``Le``; printed is the median of std / mean over the
lit interior (the disc eroded by 3 px, incidence < 80 deg), and, for ``electrons``, that median
per bin of the adaptive render's radiance-proxy spread (the quantity its sample map
thresholds at 0.3). Also printed: the disc sums of the two samplings' 16-spp means (they must
agree: both are unbiased) and the seconds per frame.

Usage: .venv/bin/python benchmarks/render_noise.py [--seeds 6] [--spp 1,2,4,16]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import statistics
import time

import numpy as np
from scipy.ndimage import binary_erosion

from starnav.config import scenario_from_dict
from starnav.geometry import static_geometry
from starnav.renderer.render import ADAPTIVE_SPREAD
from starnav.simulate import renderer_from_scenario

BINS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8)


def spread_map(r, g) -> np.ndarray:
    """The adaptive render's 3 x 3 proxy spread of each pixel (from its centre pass)."""
    from starnav.renderer import render as R

    seen = {}
    real = R.adaptive_sample_counts

    def capture(hit, proxy, inside, spp, interior_spp, spread):
        seen["proxy"] = proxy
        return real(hit, proxy, inside, spp, interior_spp, spread)

    R.adaptive_sample_counts = capture
    try:
        r.settings = dataclasses.replace(r.settings, adaptive=True, spp=16)
        img = r.render(g, seed=0)
    finally:
        R.adaptive_sample_counts = real
    p = seen["proxy"]
    pad = np.pad(p, 1, mode="edge")
    win = np.stack([pad[i:i + p.shape[0], j:j + p.shape[1]] for i in range(3) for j in range(3)])
    hi, lo = win.max(0), win.min(0)
    spread = np.where(hi > 0, (hi - lo) / np.where(hi > 0, hi, 1.0), 0.0)
    u0, v0, bw, bh = img.meta["render"]["crop_box_uvwh"]
    out = np.zeros(img.mask.shape)
    out[v0:v0 + bh, u0:u0 + bw] = spread
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--spp", default="1,2,4,16")
    args = ap.parse_args()
    spps = [int(x) for x in args.spp.split(",")]
    now = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, "
          f"load {os.getloadavg()[0]:.1f} (1 min), {now}")
    r = renderer_from_scenario(scenario_from_dict({"render": {"spp": 16}}))
    g = static_geometry(r.camera, 9.715e6, math.radians(30.0), (0.0, 0.0))
    sums = {}
    inner = None
    for mode in ("response", "electrons"):
        for spp in spps:
            r.settings = dataclasses.replace(r.settings, spp=spp, spectral_sampling=mode,
                                             adaptive=False)
            stack, times = [], []
            for seed in range(args.seeds):
                t0 = time.perf_counter()
                img = r.render(g, seed=seed)
                times.append(time.perf_counter() - t0)
                stack.append(img.Le.astype(np.float64))
            a = np.stack(stack)
            m, s = a.mean(0), a.std(0, ddof=1)
            if inner is None:
                inner = (binary_erosion(img.mask, iterations=3)
                         & (img.aovs["incidence"] < math.radians(80.0)) & (m > 0))
            rel = s[inner] / m[inner]
            if spp == 16:
                sums[mode] = (m[inner].sum(), math.sqrt((s[inner] ** 2).sum() / args.seeds))
            line = (f"{mode:9s} spp {spp:2d}: interior noise median {100 * np.median(rel):.2f} %"
                    f"  ({inner.sum()} px)  {statistics.median(times[1:]):.3f} s/frame")
            print(line, flush=True)
            if mode == "electrons":
                if "spread" not in sums:
                    sums["spread"] = spread_map(r, g)
                    r.settings = dataclasses.replace(r.settings, adaptive=False)
                sp = sums["spread"][inner]
                cells = []
                for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
                    sel = (sp >= lo) & (sp < hi)
                    cells.append(f"{lo:.2f}-{hi:.2f}: {100 * np.median(rel[sel]):.2f} % "
                                 f"({sel.sum()})" if sel.any() else f"{lo:.2f}-{hi:.2f}: -")
                print(f"           by spread (threshold {ADAPTIVE_SPREAD:.1f}): "
                      + "; ".join(cells), flush=True)
    if "response" in sums and "electrons" in sums:
        (a, sa), (b, sb) = sums["response"], sums["electrons"]
        print(f"16-spp interior sums: response {a:.6g}, electrons {b:.6g}: ratio {b / a:.6f}, "
              f"z = {(b - a) / math.hypot(sa, sb):.2f}")


if __name__ == "__main__":
    main()
