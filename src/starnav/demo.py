"""``make demo`` / ``starnav demo``: the main job on built-in defaults.

Renders the default scenario's frame (AA-STR at 60 000 km, phase 30 deg, Lambert albedo 0.12),
writes the radiance EXR, a preview PNG and a JSON summary that compares the disc-integrated
irradiance at the aperture with the Lambert-sphere closed form.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from starnav.atomic import atomic_write_text
from starnav.config import Scenario, build_camera, write_resolved
from starnav.photometry import lambert_sphere_irradiance


def aperture_irradiance(L: np.ndarray, camera) -> float:
    """``sum L * Omega_pixel`` with each pixel's exact solid angle [W m^-2]."""
    u, v = camera.pixel_grid()
    x = (u - camera.cx) / camera.fx
    y = (v - camera.cy) / camera.fy
    omega = camera.pixel_solid_angle / (1.0 + x * x + y * y) ** 1.5
    return float(np.sum(L * omega))


def write_preview_png(L: np.ndarray, path: Path) -> Path:
    """8-bit preview, linear, scaled to the 99.9th percentile of the lit pixels."""
    import imageio.v3 as iio

    lit = L[L > 0]
    top = float(np.percentile(lit, 99.9)) if lit.size else 1.0
    img = np.clip(L / max(top, 1e-30) * 255.0, 0, 255).astype(np.uint8)
    tmp = path.with_name(f".{path.name}.tmp.png")
    iio.imwrite(tmp, img)
    tmp.replace(path)
    return path


def run_demo(sc: Scenario | None, out: str | Path) -> dict:
    """Run the demo on ``sc`` (default: built-in scenario); returns the summary dict."""
    from starnav.radiance import write_exr
    from starnav.renderer.pipeline import describe_frame, render_scenario

    sc = sc or Scenario()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    camera = build_camera(sc.camera)
    img = next(iter(render_scenario(sc)))
    write_exr(img, out / "frame_000000.exr")
    write_preview_png(img.L, out / "frame_000000_L.png")
    write_resolved(sc, out)
    summary = describe_frame(img)
    g = img.meta["geometry"]
    e_cam = aperture_irradiance(img.L, camera)
    summary["aperture_irradiance_W_m2"] = e_cam
    if sc.moon.photometry.model == "lambert" and isinstance(sc.moon.albedo, float):
        ref = float(lambert_sphere_irradiance(img.meta["sun"]["band_irradiance_w_m2"],
                                              sc.moon.albedo * sc.moon.albedo_scale,
                                              g["moon_radius_m"], g["range_m"],
                                              g["phase_angle_rad"]))
        summary["lambert_closed_form_W_m2"] = ref
        summary["rendered_over_closed_form"] = e_cam / ref
        summary["note"] = ("closed form assumes a distant observer; at range d the perspective "
                           f"difference is O(R/d) = {g['moon_radius_m'] / g['range_m']:.3f}")
    summary["phase_deg"] = math.degrees(g["phase_angle_rad"])
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    return summary
