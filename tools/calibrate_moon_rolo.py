#!/usr/bin/env python
"""Calibrate starnav's real Moon against the ROLO lunar model, once; writes
``src/starnav/data/moon/rolo_calibration.json``.

What is fitted, and why (see :mod:`starnav.lunar_calibration` for the full story):

* ``k``  mean normal albedo (550 nm) of the LROC map, area-weighted over the globe;
* ``q``  contrast exponent of the map's relative grey values (constrained by ROLO's waxing /
  waning asymmetry, i.e. its dependence on the Sun's selenographic longitude);
* Hapke ``b, c`` (double Henyey-Greenstein phase function) and ``B_S0, h_S`` (shadow-hiding
  opposition surge); roughness 23.66 deg and no coherent backscatter stay at Sato et al. (2014).

Model: the disc-equivalent reflectance of a sphere with the map, observer at infinity on the
sub-observer point (0, 0), ``A = integral r(i, e, g) cos(e) dOmega`` over the lit and visible
unit sphere (midpoint rule on the map's cells), times the band-averaged spectral shape. Target:
ROLO's A(lambda, g, Phi = +-g) band-averaged over the AA-STR band (425-1025 nm) with the
ASTM G-173 Sun: ``A_band = int A E dlambda / int E dlambda``. Geometries: phases 4, 10, ..., 94
deg, Sun east and west (32 points; none at the phases the tests score, 5, 15, ..., 90 deg, and
the tests look from another libration). The fit minimises the log ratio (scipy least_squares).

Terrain: the smooth-sphere quadrature knows nothing of the LOLA relief the renderer draws (its
cast shadows darken the disc at large phase by a few per cent). So, after a first fit, the real
Moon is *rendered* (Mitsuba, LDEM_4 mesh, 60 000 km, the AA-STR) at every fit geometry with the
fitted constants, the ratio render / quadrature is taken as a terrain factor per geometry, and
the constants are fitted again with the quadrature times that factor (``--no-terrain`` skips
it). One iteration suffices: the factor depends on the constants only weakly (printed).

Usage::

    .venv/bin/python tools/calibrate_moon_rolo.py            # fit, print, write the JSON
    .venv/bin/python tools/calibrate_moon_rolo.py --dry-run  # fit and print only
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from starnav.atomic import atomic_write_text
from starnav.data import packaged_path
from starnav.dem.readers import read_albedo
from starnav.dem.schema import AlbedoConfig
from starnav.lunar_calibration import CALIBRATION_FILE
from starnav.photometry import HAPKE_LUNAR_DEFAULTS, hapke, model_albedo_parameter
from starnav.reference.rolo import ROLO_WAVELENGTHS_NM, rolo_reflectance
from starnav.spectra import sensor_response, solar_spectrum

REFERENCE_NM = 550.0
FIT_PHASES_DEG = np.arange(4.0, 95.0, 6.0)
#: Range of the terrain renders [m] (LUMIO: 40 000-80 000 km).
TERRAIN_RANGE_M = 6.0e7
MAP_PX_PER_DEG = 1.0
#: Free parameters, start values (Sato et al. 2014 for Hapke) and bounds.
FREE = ("k", "q", "b", "c", "bs0", "hs")
START = (0.12, 0.5, 0.25, 0.30, 2.2, 0.07)
LOWER = (0.03, 0.2, 0.05, 0.0, 0.0, 0.01)
UPPER = (0.40, 1.5, 0.60, 1.0, 4.0, 0.30)
FIXED = {"theta_bar_deg": HAPKE_LUNAR_DEFAULTS["theta_bar_deg"], "bc0": 0.0, "hc": 1.0}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class DiscModel:
    """Disc-equivalent reflectance of a sphere carrying a relative albedo map."""

    def __init__(self, relative: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> None:
        self.relative = relative
        LAT, LON = np.meshgrid(lat, lon, indexing="ij")
        self.n = np.stack([np.cos(LAT) * np.cos(LON), np.cos(LAT) * np.sin(LON), np.sin(LAT)],
                          axis=-1)
        dlat, dlon = math.pi / lat.size, 2 * math.pi / lon.size
        self.dA = np.cos(LAT) * dlat * dlon
        self.weights = np.cos(lat)

    def normal_albedo(self, k: float, q: float) -> np.ndarray:
        a = self.relative ** q
        return k * a / np.average(a.mean(axis=1), weights=self.weights)

    def reflectance(self, geoms: list[tuple[float, float]], k: float, q: float,
                    params: dict[str, float]) -> np.ndarray:
        """Grey disc-equivalent reflectance at (phase, Sun longitude) pairs [rad]."""
        w = model_albedo_parameter("hapke", self.normal_albedo(k, q), **params)
        v = np.array([1.0, 0.0, 0.0])
        mu = self.n @ v
        out = []
        for g, phi in geoms:
            s = np.array([math.cos(phi), math.sin(phi), 0.0])
            mu0 = self.n @ s
            m = (mu0 > 0) & (mu > 0)
            i = np.arccos(np.clip(mu0[m], -1, 1))
            e = np.arccos(np.clip(mu[m], -1, 1))
            r = hapke(i, e, np.full(i.shape, g), w[m], **params)
            out.append(float(np.sum(r * mu[m] * self.dA[m])))
        return np.array(out)


def terrain_factor(geoms: list[tuple[float, float]], k: float, q: float,
                   params: dict[str, float], disc: DiscModel) -> np.ndarray:
    """Rendered real Moon (LDEM_4 mesh, grey) / smooth-sphere quadrature, per geometry."""
    from starnav.config import build_camera, scenario_from_dict
    from starnav.simulate import frame_geometries, renderer_from_scenario

    out = []
    renderer = None
    for g, phi in geoms:
        sc = scenario_from_dict({
            "render": {"spp": 8},
            "moon": {"shape": "dem", "albedo": k,
                     "photometry": {"model": "hapke", "preset": "sato2014",
                                    "params": {n: params[n] for n in ("b", "c", "bs0", "hs")},
                                    "spectral_shape": "grey"},
                     "dem": {"source": "lola", "albedo": {"source": "lroc",
                                                          "contrast_exponent": q}}},
            "geometry": {"range_km": TERRAIN_RANGE_M / 1e3, "phase_angle_deg": math.degrees(g),
                         "sun_azimuth_deg": 0.0 if phi > 0 else 180.0}})
        if renderer is None:
            renderer = renderer_from_scenario(sc)
        geom = frame_geometries(sc)[0]
        img = renderer.render(geom, seed=7)
        e_render = float(np.sum(img.L * build_camera(sc.camera).pixel_solid_angles()))
        e_band = img.meta["sun"]["band_irradiance_w_m2"]
        a_quad = disc.reflectance([(g, phi)], k, q, params)[0]
        out.append(e_render / (a_quad * e_band * (renderer.moon.radius / geom.range) ** 2))
    return np.array(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dry-run", action="store_true", help="fit and print, write nothing")
    ap.add_argument("--no-terrain", action="store_true",
                    help="fit the smooth sphere only (no rendered terrain factor)")
    args = ap.parse_args(argv)

    map_path = packaged_path("albedo/lroc_wac_grey_2048.tif")
    grid = read_albedo(map_path, AlbedoConfig(source=str(map_path), quantity="relative",
                                              contrast_exponent=1.0, decoding="linear"))
    grid = grid.resampled(MAP_PX_PER_DEG)
    lat, lon = grid.lat_centres(), grid.lon_centres()
    disc = DiscModel(np.asarray(grid.values, float), lat, lon)

    response = sensor_response("aa-str")
    lo, hi = response.band
    lam = np.arange(lo, hi + 0.5, 1.0)
    sun = solar_spectrum()(lam)
    sun_int = np.trapezoid(sun, lam)

    geoms = [(math.radians(g), sgn * math.radians(g)) for g in FIT_PHASES_DEG for sgn in (1, -1)]
    # spectral shape: ROLO A(lambda) / A(550), geometric mean over the fit phases
    ratios = []
    for g in FIT_PHASES_DEG:
        a = rolo_reflectance(math.radians(g), math.radians(g))
        ratios.append(np.log(a / np.interp(REFERENCE_NM, ROLO_WAVELENGTHS_NM, a)))
    shape = np.exp(np.mean(ratios, axis=0))
    band_shape = float(np.trapezoid(np.interp(lam, ROLO_WAVELENGTHS_NM, shape) * sun, lam)
                       / sun_int)
    target = np.array([np.trapezoid(rolo_reflectance(g, phi, wavelength_nm=lam) * sun, lam)
                       / sun_int for g, phi in geoms])

    def unpack(x: np.ndarray) -> tuple[float, float, dict[str, float]]:
        d = dict(zip(FREE, x, strict=True))
        params = {"b": d["b"], "c": d["c"], "bs0": d["bs0"], "hs": d["hs"], **FIXED}
        return d["k"], d["q"], params

    terrain = np.ones(len(geoms))

    def residual(x: np.ndarray) -> np.ndarray:
        k, q, params = unpack(x)
        return np.log(disc.reflectance(geoms, k, q, params) * terrain * band_shape / target)

    r0 = residual(np.array(START))
    sol = least_squares(residual, START, bounds=(LOWER, UPPER), diff_step=1e-3)
    if not args.no_terrain:
        k, q, params = unpack(sol.x)
        print(f"smooth-sphere fit: rms {np.sqrt(np.mean(np.expm1(sol.fun) ** 2)):.4f}; "
              "rendering the terrain factor ...")
        terrain = terrain_factor(geoms, k, q, params, disc)
        print("  terrain factor (render / quadrature): "
              + " ".join(f"{t:.3f}" for t in terrain))
        sol = least_squares(residual, sol.x, bounds=(LOWER, UPPER), diff_step=1e-3)
        k2, q2, params2 = unpack(sol.x)
        again = terrain_factor(geoms, k2, q2, params2, disc)
        print(f"  terrain factor with the refitted constants differs by at most "
              f"{np.max(np.abs(again / terrain - 1)):.4f}")
    k, q, params = unpack(sol.x)
    ratio = np.exp(sol.fun)
    print(f"ROLO fit over {len(geoms)} geometries (phase {FIT_PHASES_DEG[0]:g}-"
          f"{FIT_PHASES_DEG[-1]:g} deg, Sun east and west), band {lo:g}-{hi:g} nm")
    print(f"  start (Sato 2014, k 0.12, q 0.5): rms log ratio {np.sqrt(np.mean(r0**2)):.4f}")
    for name, v in zip(FREE, sol.x, strict=True):
        print(f"  {name:4s} = {v:.5f}")
    print(f"  band-averaged spectral shape {band_shape:.5f} (1 at {REFERENCE_NM:g} nm)")
    print("  phase  Sun   model/ROLO")
    for (g, phi), rr in zip(geoms, ratio, strict=True):
        print(f"  {math.degrees(g):5.1f}  {'east' if phi > 0 else 'west'}  {rr:.4f}")
    print(f"  rms {np.sqrt(np.mean((ratio - 1) ** 2)):.4f}, max |dev| "
          f"{np.max(np.abs(ratio - 1)):.4f}")
    w = model_albedo_parameter("hapke", disc.normal_albedo(k, q), **params)
    print(f"  Hapke w over the map: {w.min():.4f}..{w.max():.4f}")
    at_bound = [n for n, v, lo_, hi_ in zip(FREE, sol.x, LOWER, UPPER, strict=True)
                if min(v - lo_, hi_ - v) < 1e-3 * (hi_ - lo_)]
    if at_bound:
        print(f"  WARNING: at a bound: {at_bound}")
    if args.dry_run:
        return 0

    coeffs = packaged_path("rolo/rolo_coefficients.csv")
    out = {
        "hapke": params,
        "mean_normal_albedo": k,
        "contrast_exponent": q,
        "reference_wavelength_nm": REFERENCE_NM,
        "spectral_wavelengths_nm": [float(x) for x in ROLO_WAVELENGTHS_NM],
        "spectral_factor": [float(x) for x in shape],
        "fit": {
            "free": list(FREE), "start": list(START), "lower": list(LOWER),
            "upper": list(UPPER), "fixed": FIXED,
            "phases_deg": [float(x) for x in FIT_PHASES_DEG],
            "sun_longitude": "+phase and -phase (observer at selenographic 0, 0)",
            "band_nm": [lo, hi], "band_shape_factor": band_shape,
            "map_px_per_deg": MAP_PX_PER_DEG,
            "terrain_factor": [float(x) for x in terrain],
            "terrain_renders": None if args.no_terrain else
            f"LDEM_4 mesh, AA-STR, {TERRAIN_RANGE_M / 1e3:g} km, 8 spp",
            "model_over_rolo": [float(x) for x in ratio],
            "rms": float(np.sqrt(np.mean((ratio - 1) ** 2))),
            "max_abs_dev": float(np.max(np.abs(ratio - 1))),
            "hapke_w_range": [float(w.min()), float(w.max())],
        },
        "provenance": {
            "script": "tools/calibrate_moon_rolo.py",
            "date_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d"),
            "reference": "ROLO model 311g, Kieffer & Stone 2005, AJ 129:2887 (Table 4)",
            "rolo_coefficients_sha256": _sha256(coeffs),
            "albedo_map": "starnav/data/albedo/lroc_wac_grey_2048.tif",
            "albedo_map_sha256": _sha256(map_path),
            "solar_spectrum": "ASTM G-173 extraterrestrial (colour-science), 1 AU",
        },
    }
    dest = Path(__file__).resolve().parents[1] / "src" / "starnav" / CALIBRATION_FILE
    atomic_write_text(dest, json.dumps(out, indent=1) + "\n")
    print(f"wrote {dest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
