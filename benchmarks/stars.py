"""The cost of the star field per frame: cone query, radiometry, injection through the PSF,
and the attitude from the frame (centroids, lost-in-space identification, SVD/QUEST).

The injection is printed before (part A: four node kernels per star sampled and FFT-convolved,
``optics.point_source_kernel_sampled``, timed per star) and after (cached integral image per
node, batched: ``optics.point_source_image``).

AA-STR (1024 x 1024, 20.6 deg), default PSF, 200 ms, stars to V = 6.5 and 7.5 at a few
pointings (sparse and Milky Way fields); the catalogue read (once per process) is timed apart.
Prints one JSON document. Usage::

    .venv/bin/python benchmarks/stars.py
    .venv/bin/python benchmarks/stars.py --navigation   # the attitude schedule (part C)

``--survey [N]``: lost-in-space identification over ``N`` (default 1000) random pointings of
the sky, each rendered at 200 ms through the whole detector chain and solved without a prior
(:func:`starnav.stars.survey.identification_survey`), then ``N / 5`` with a saturated Moon in the
field (false-star rate), with and without the Moon's exclusion discs: counts, rates and the
per-frame times (drawing + exposing, solving).

``--monte-carlo [R]``: the navigation Monte Carlo with the solved attitude
(:func:`starnav.batch.attitude_study.attitude_monte_carlo`: ``R`` runs, default 20, each on its
own terrain; 13 frames of the demo's arc at 1024 px, 8 spp, both demo exposures); prints the
table and writes the JSON next to the working directory (``attitude_monte_carlo.json``).

``--real``: the real night-sky frames of ``tests/data/stars`` (the tetra3 test set, another
camera: 35 mm, 6.9 um pixels) plate-solved with only that camera described
(:func:`starnav.stars.plate.solve_plate`, index warm: built or read once before timing), beside
cedar-solve on the same images in the same run (run from the throwaway venv
``/tmp/venv-cedar`` by subprocess, its own extraction and database; skipped with a message
when that venv is missing; ``--cedar-python PATH`` to use another). Per image: solved or not,
matched stars, residual rms, extraction and solve times (median of ``--repeat`` runs, default
5), and the boresight and FOV differences between the two.

``--extraction``: star extraction alone on the same real frames (median of ``--repeat`` runs):
starnav's :func:`~starnav.stars.centroid.find_stars` at full resolution (the AA-STR path) and
with detection on the 2 x 2 binned frame (the plate solver's), beside the well-kept libraries
when importable (``sep``: SExtractor's background and extraction, ``photutils``:
``Background2D`` + ``DAOStarFinder``), each at a 5-sigma threshold; detections and how many of
cedar-solve's matched stars each finds within 1 px. ``--site DIR`` adds DIR to ``sys.path``
(the libraries installed there with ``pip install --target DIR``, not into the project's venv;
repeatable).

``--navigation``: the per-frame cost of the attitude schedule on the demo's arc (5 frames,
1024 px, 8 spp, star acquisitions at 200 ms every 2nd frame, both demo exposures): the star
acquisition (stars drawn + exposed), the solves (lost in space, tracking, the navigation
frame's failed or tracking solve), then the comparison table of
:func:`starnav.batch.attitude_study.attitude_comparison`.
"""

from __future__ import annotations

import json
import math
import statistics
import time

import numpy as np

#: (name, RA, Dec) [deg] of the pointings.
POINTINGS = (("Orion belt", 84.05, -1.2), ("north galactic pole", 192.86, 27.13),
             ("Cygnus (Milky Way)", 305.0, 40.0), ("Crux (Milky Way)", 187.0, -60.0))


def main() -> None:
    from starnav.camera import Camera
    from starnav.detector import DetectorConfig, expose
    from starnav.detector.chain import ChainContext, add_point_sources
    from starnav.detector.optics import _node_parameters, point_source_kernel_sampled
    from starnav.geometry import FrameGeometry, look_rotation
    from starnav.spectra import sensor_response
    from starnav.stars import StarsConfig, frame_stars
    from starnav.stars.attitude import solve_attitude
    from starnav.stars.catalogue import hipparcos

    t0 = time.perf_counter()
    cat = hipparcos()
    t_read = time.perf_counter() - t0
    cam = Camera.preset("aa-str")
    det = DetectorConfig()
    resp = sensor_response("aa-str")
    frame_stars(FrameGeometry(np.array([0.0, 0.0, 1e12]), np.eye(3), np.array([1e11, 0, 0])),
                cam, StarsConfig(enabled=True), resp, exposure_time=0.2)  # k-d tree, pyphot
    from starnav.stars.identify import IdentifyOptions, star_index
    t0 = time.perf_counter()
    star_index(cat, IdentifyOptions().index_v_limit, cam.fov_diagonal, 2000.0)
    t_index = time.perf_counter() - t0
    rows = []
    for vlim in (6.5, 7.5):
        for name, ra, dec in POINTINGS:
            a, d = math.radians(ra), math.radians(dec)
            bore = np.array([math.cos(d) * math.cos(a), math.cos(d) * math.sin(a), math.sin(d)])
            geom = FrameGeometry(camera_position=1e12 * bore,
                                 R_cam_to_inertial=look_rotation(np.array([0, 0, 1.0]), bore),
                                 sun_position=np.array([1.5e11, 0.0, 0.0]))
            cfg = StarsConfig(enabled=True, magnitude_limit=vlim)
            tq, ti = [], []
            for _ in range(5):
                t0 = time.perf_counter()
                f = frame_stars(geom, cam, cfg, resp, exposure_time=0.2, detector=det)
                t1 = time.perf_counter()
                ctx = ChainContext(cam, det, 0.2, 0, 0, 0)
                add_point_sources(np.zeros((cam.height, cam.width), np.float32), ctx,
                                  f.point_sources())
                t2 = time.perf_counter()
                tq.append(t1 - t0)
                ti.append(t2 - t1)
            # before: the part-A per-star kernels (4 nodes, sampled + FFT), on 10 stars
            _, _, par = _node_parameters(cam, det.optics.aberration)
            t0 = time.perf_counter()
            for k in range(10):
                for p in (par[0][0], par[0][1], par[1][0], par[1][1]):
                    point_source_kernel_sampled(*p, det.optics.aberration.oversample,
                                                0.1 * k - 0.45, 0.3)
            before_ms = (time.perf_counter() - t0) / 10 * 1e3
            e = expose(np.zeros((cam.height, cam.width), np.float32), cam, det,
                       exposure_time=0.2, point_sources=f.point_sources(), seed=1)
            ta, sol = [], None
            for rep in range(3):
                t0 = time.perf_counter()
                sol = solve_attitude(e.dn, cam, det, epoch_jyear=f.epoch_jyear)
                ta.append(time.perf_counter() - t0)
                if rep == 0:  # split: centroids alone
                    from starnav.stars.centroid import (
                        CentroidOptions,
                        background,
                        find_stars,
                        saturation_dn,
                    )
                    t0 = time.perf_counter()
                    find_stars(e.dn, gain_e_per_dn=det.gain_e_per_dn,
                               saturation_dn=saturation_dn(det))
                    tc = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    background(np.asarray(e.dn, float), CentroidOptions().block_px)
                    tb = time.perf_counter() - t0
            n_ps = max(len(f.point_sources()), 1)
            rows.append({"per_star_before_ms": round(before_ms, 2),
                         "per_star_after_ms": round(statistics.median(ti) * 1e3 / n_ps, 3),
                         "centroids_ms": round(tc * 1e3, 1),
                         "of_which_background_ms": round(tb * 1e3, 1),
                         "attitude_total_ms": round(statistics.median(ta) * 1e3, 1),
                         "attitude_ok": sol.ok,
                         "stars_identified": sol.identification.n_matched
                         if sol.identification else 0,
                         "sigma_arcsec_xyz": [round(float(x), 2) for x in sol.sigma_arcsec],
                         "field": name, "v_limit": vlim, "stars_drawn": len(f.point_sources()),
                         "stars_in_frame": len(f.visible()),
                         "query_radiometry_ms": round(statistics.median(tq) * 1e3, 1),
                         "injection_ms": round(statistics.median(ti) * 1e3, 1)})
    print(json.dumps({"catalogue_read_s": round(t_read, 2), "pair_index_s": round(t_index, 2),
                      "frames": rows}, indent=1))


def navigation(frames: int = 5) -> None:
    from starnav.batch.attitude_study import (
        attitude_comparison,
        comparison_markdown,
        reduced_demo,
    )

    res = attitude_comparison(reduced_demo(frames=frames, size_px=1024, spp=8),
                              attitude={"schedule_every": 2})
    rows = []
    for key, recs in res["records"].items():
        for r in recs:
            rows.append({"exposure_ms": float(key) * 1e3, "frame": r["frame"],
                         "source": r["source"], "mode": r["mode"],
                         "star_exposure_ms": round(r["timings_ms"]["star_exposure"], 1),
                         "solve_ms": round(r["timings_ms"]["solve"], 1)})
    print(json.dumps({"frames": rows, "wall_time_s": round(res["wall_time_s"], 1)}, indent=1))
    print(comparison_markdown(res))


def survey(n: int = 1000) -> None:
    from starnav.stars.survey import identification_survey

    out = {}
    for name, kw, count, seed in (("open sky", {}, n, 17),
                                  ("Moon in the field", {"moon": True}, max(n // 5, 1), 18),
                                  ("Moon, no exclusions", {"moon": True, "exclude_body": False},
                                   max(n // 5, 1), 18)):
        t0 = time.perf_counter()
        res = identification_survey(count, np.random.default_rng(seed),
                                    first_seed=0 if not kw else 1000, **kw)
        s = res.summary()
        s["wall_time_s"] = round(time.perf_counter() - t0, 1)
        s["not_correct"] = [{"index": p.index, "outcome": p.outcome, "reason": p.reason,
                             "stars_in_frame": p.stars_in_frame, "candidates": p.candidates}
                            for p in res.pointings if p.outcome != "correct"]
        out[name] = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()}
    print(json.dumps(out, indent=1))


def monte_carlo(runs: int = 20) -> None:
    import os

    from starnav.batch.attitude_study import (
        attitude_monte_carlo,
        monte_carlo_markdown,
        reduced_demo,
    )

    res = attitude_monte_carlo(reduced_demo(frames=13, size_px=1024, spp=8), runs,
                               attitude={"schedule_every": 2})
    print(monte_carlo_markdown(res))
    print(json.dumps({"wall_time_s": round(res["wall_time_s"], 1),
                      "run_wall_time_median_s": round(statistics.median(
                          res["run_wall_times_s"]), 1),
                      "load_average": os.getloadavg()}))
    with open("attitude_monte_carlo.json", "w") as fh:
        json.dump(res, fh, indent=1)


CEDAR_SCRIPT = r"""
import json, sys, time, statistics
from PIL import Image
import tetra3
t3 = tetra3.Tetra3("default_database")
out = []
for path in sys.argv[2:]:
    img = Image.open(path)
    runs = []
    for _ in range(int(sys.argv[1])):
        t0 = time.perf_counter()
        sol = t3.solve_from_image(img, fov_estimate=11.4, fov_max_error=1.14,
                                  distortion=(-0.2, 0.1))
        runs.append((time.perf_counter() - t0, sol))
    wall = statistics.median(r[0] for r in runs)
    sol = runs[-1][1]
    out.append({"image": path, "solved": sol.get("RA") is not None, "wall_s": wall,
                "extract_s": statistics.median(r[1]["T_extract"] for r in runs) / 1e3,
                "solve_s": statistics.median(r[1]["T_solve"] for r in runs) / 1e3,
                "ra": sol.get("RA"), "dec": sol.get("Dec"), "fov": sol.get("FOV"),
                "matches": sol.get("Matches"), "rmse": sol.get("RMSE")})
print(json.dumps(out))
"""


def real(repeat: int = 5, cedar_python: str = "/tmp/venv-cedar/bin/python") -> None:
    import os
    import subprocess
    from pathlib import Path

    from starnav.camera import Camera
    from starnav.stars.catalogue import hipparcos
    from starnav.stars.images import read_star_image
    from starnav.stars.plate import solve_plate

    data = Path(__file__).resolve().parents[1] / "tests" / "data" / "stars"
    paths = sorted(data.glob("*.tiff"))
    cam = Camera(width=1024, height=768, focal_length=35e-3, pitch_x=6.9e-6, pitch_y=6.9e-6,
                 f_number=1.9)
    cat = hipparcos()
    t0 = time.perf_counter()
    first = read_star_image(paths[0])
    solve_plate(first.data, cam, epoch_jyear=2019.58, catalogue=cat)  # index built or read
    t_first = time.perf_counter() - t0
    ours = []
    for p in paths:
        img = read_star_image(p)
        runs = [solve_plate(img.data, cam, epoch_jyear=2019.58, catalogue=cat,
                            saturation_dn=img.saturation_dn) for _ in range(repeat)]
        s = runs[-1]
        ours.append({"image": p.name, "solved": s.ok, "matched": s.n_matched,
                     "rms_arcsec": round(s.rms_arcsec, 2),
                     "extract_s": round(statistics.median(r.time_extract_s for r in runs), 4),
                     "solve_s": round(statistics.median(r.time_solve_s for r in runs), 4),
                     "total_s": round(statistics.median(r.time_extract_s + r.time_solve_s
                                                        for r in runs), 4),
                     "ra_dec_roll_deg": [round(x, 5) for x in s.ra_dec_roll_deg] if s.ok
                     else None, "fov_x_deg": round(s.fov_x_deg, 5) if s.ok else None})
    cedar: list | str
    if not os.path.exists(cedar_python):
        cedar = (f"cedar-solve skipped: {cedar_python} missing (python3 -m venv /tmp/venv-cedar "
                 "&& /tmp/venv-cedar/bin/pip install cedar-solve)")
    else:
        r = subprocess.run([cedar_python, "-c", CEDAR_SCRIPT, str(repeat),
                            *map(str, paths)], capture_output=True, text=True, check=False)
        cedar = json.loads(r.stdout) if r.returncode == 0 else f"cedar-solve failed: {r.stderr}"
    for o, c in zip(ours, cedar if isinstance(cedar, list) else [None] * len(ours),
                    strict=True):
        if c and c["solved"] and o["solved"]:
            ra, dec = (math.radians(x) for x in o["ra_dec_roll_deg"][:2])
            rc, dc = math.radians(c["ra"]), math.radians(c["dec"])
            u = np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra),
                          math.sin(dec)])
            v = np.array([math.cos(dc) * math.cos(rc), math.cos(dc) * math.sin(rc),
                          math.sin(dc)])
            o["boresight_vs_cedar_arcsec"] = round(
                math.degrees(math.acos(min(1.0, float(u @ v)))) * 3600, 2)
            o["fov_vs_cedar_pct"] = round(100 * (o["fov_x_deg"] / c["fov"] - 1), 4)
    print(json.dumps({"first_solve_with_index_s": round(t_first, 3), "repeat": repeat,
                      "starnav": ours, "cedar_solve": cedar,
                      "load_average": os.getloadavg()}, indent=1))


def extraction(repeat: int = 5) -> None:
    import importlib
    import os
    from pathlib import Path

    from starnav.stars.centroid import CentroidOptions, find_stars
    from starnav.stars.images import read_star_image
    from starnav.stars.plate import PlateOptions

    data = Path(__file__).resolve().parents[1] / "tests" / "data" / "stars"
    ref = {r["image"]: r for r in json.loads((data / "reference_cedar.json").read_text())
           ["images"]}

    def timed(fn):
        runs = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            out = fn()
            runs.append(time.perf_counter() - t0)
        return statistics.median(runs), out

    def found(xy, r):
        want = np.array([m for m in r.get("matched_uv_px", [])], float)
        if want.size == 0 or len(xy) == 0:
            return None
        d = np.hypot(*(want[:, None, :] - np.asarray(xy)[None]).transpose(2, 0, 1))
        return int(np.count_nonzero(d.min(axis=1) < 1.0))

    out = []
    for p in sorted(data.glob("*.tiff")):
        img = read_star_image(p)
        a = img.data
        r = ref[p.name]
        row = {"image": p.name, "cedar_matched": len(r["matched_hip"])}
        for name, opt in (("starnav_full_res", CentroidOptions(weight_sigma_px=1.0)),
                          ("starnav_binned", PlateOptions().centroid)):
            t, c = timed(lambda opt=opt, a=a, sat=img.saturation_dn: find_stars(
                a, gain_e_per_dn=1.0, saturation_dn=sat, options=opt))
            row[name] = {"ms": round(1e3 * t, 1), "n": len(c),
                         "cedar_stars_found": found(c.uv, r)}
        try:
            sep = importlib.import_module("sep")

            def run_sep(a=a, sep=sep):
                f = np.ascontiguousarray(a, np.float32)
                bkg = sep.Background(f, bw=32, bh=32)
                return sep.extract(f - bkg.back(), 5.0, err=bkg.globalrms, minarea=3)

            t, o = timed(run_sep)
            row["sep"] = {"ms": round(1e3 * t, 1), "n": len(o),
                          "cedar_stars_found": found(np.c_[o["x"], o["y"]], r),
                          "version": sep.__version__}
        except ImportError:
            row["sep"] = "not installed"
        try:
            import photutils
            from photutils.background import Background2D, MedianBackground
            from photutils.detection import DAOStarFinder

            photutils.future_column_names = True

            def run_phot(a=a):
                f = np.asarray(a, float)
                bkg = Background2D(f, 32, filter_size=3, bkg_estimator=MedianBackground())
                sub = f - bkg.background
                return DAOStarFinder(5.0 * bkg.background_rms_median, fwhm=2.0)(sub)

            t, o = timed(run_phot)
            n = 0 if o is None else len(o)
            xy = np.zeros((0, 2)) if o is None else np.c_[o["x_centroid"], o["y_centroid"]]
            row["photutils"] = {"ms": round(1e3 * t, 1), "n": n,
                                "cedar_stars_found": found(xy, r),
                                "version": photutils.__version__}
        except ImportError:
            row["photutils"] = "not installed"
        out.append(row)
    print(json.dumps({"repeat": repeat, "images": out, "load_average": os.getloadavg()},
                     indent=1))


if __name__ == "__main__":
    import sys

    def _arg(flag: str, default: int) -> int:
        i = sys.argv.index(flag)
        return int(sys.argv[i + 1]) if len(sys.argv) > i + 1 else default

    for i, flag in enumerate(sys.argv):
        if flag == "--site":
            sys.path.insert(0, sys.argv[i + 1])
    if "--extraction" in sys.argv:
        extraction(_arg("--repeat", 5) if "--repeat" in sys.argv else 5)
    elif "--real" in sys.argv:
        real(_arg("--repeat", 5) if "--repeat" in sys.argv else 5,
             sys.argv[sys.argv.index("--cedar-python") + 1] if "--cedar-python" in sys.argv
             else "/tmp/venv-cedar/bin/python")
    elif "--navigation" in sys.argv:
        navigation()
    elif "--survey" in sys.argv:
        survey(_arg("--survey", 1000))
    elif "--monte-carlo" in sys.argv:
        monte_carlo(_arg("--monte-carlo", 20))
    else:
        main()
