"""The cost of the star field per frame: cone query, radiometry, injection through the PSF.

AA-STR (1024 x 1024, 20.6 deg), default PSF, 200 ms, stars to V = 6.5 and 7.5 at a few
pointings (sparse and Milky Way fields); the catalogue read (once per process) is timed apart.
Prints one JSON document. Usage::

    .venv/bin/python benchmarks/stars.py
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
    from starnav.detector import DetectorConfig
    from starnav.detector.chain import ChainContext, add_point_sources
    from starnav.geometry import FrameGeometry, look_rotation
    from starnav.spectra import sensor_response
    from starnav.stars import StarsConfig, frame_stars
    from starnav.stars.catalogue import hipparcos

    t0 = time.perf_counter()
    hipparcos()
    t_read = time.perf_counter() - t0
    cam = Camera.preset("aa-str")
    det = DetectorConfig()
    resp = sensor_response("aa-str")
    frame_stars(FrameGeometry(np.array([0.0, 0.0, 1e12]), np.eye(3), np.array([1e11, 0, 0])),
                cam, StarsConfig(enabled=True), resp, exposure_time=0.2)  # k-d tree, pyphot
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
            rows.append({"field": name, "v_limit": vlim, "stars_drawn": len(f.point_sources()),
                         "stars_in_frame": len(f.visible()),
                         "query_radiometry_ms": round(statistics.median(tq) * 1e3, 1),
                         "injection_ms": round(statistics.median(ti) * 1e3, 1)})
    print(json.dumps({"catalogue_read_s": round(t_read, 2), "frames": rows}, indent=1))


if __name__ == "__main__":
    main()
