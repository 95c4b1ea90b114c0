"""``starnav stars solve``: plate solutions of image files, with results, a report and overlays.

For each image: read it (:mod:`starnav.stars.images`), describe the camera (a preset and
``camera.*`` overrides), solve it (:func:`starnav.stars.plate.solve_plate`) and record the
attitude (RA, Dec, roll, quaternion, covariance), the refined focal length, field of view and
``k1``, and the matched stars. One bad image is recorded with its reason; the others go on.

Outputs: ``results.json``, ``report.md`` and ``overlay_<image stem>.png`` (identified
detections circled and labelled, their catalogue projections as crosses, other detections as
squares, the boresight and celestial north). A non-empty output directory is refused unless
``overwrite``, which replaces only those files.
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from starnav.atomic import atomic_path, atomic_write_text
from starnav.camera import Camera, CameraConfig, camera_from_config
from starnav.config_base import apply_overrides, format_validation_error
from starnav.errors import ConfigError, DataFileError, StarnavError
from starnav.stars.catalogue import StarCatalogue, hipparcos
from starnav.stars.centroid import background
from starnav.stars.images import StarImage, read_star_image
from starnav.stars.plate import ARCSEC, PlateOptions, PlateSolution, solve_plate

log = logging.getLogger(__name__)

RESULTS = "results.json"
REPORT = "report.md"
OVERLAY = re.compile(r"^overlay_.+\.png$")
#: Epoch used when neither the command line nor the file gives one [Julian year].
DEFAULT_EPOCH_JYEAR = 2000.0


def camera_config(preset: str | None, overrides: list[str] | tuple[str, ...]) -> CameraConfig:
    """The camera section from a preset name and ``camera.*=value`` overrides.

    Raises
    ------
    ConfigError
        An override outside ``camera.``, an unknown key or value, an unknown preset.
    """
    for item in overrides:
        if not item.split("=", 1)[0].strip().startswith("camera."):
            raise ConfigError("--set", item, "camera.KEY=VALUE (only the camera is set here)")
    data: dict[str, Any] = {"camera": {} if preset is None else {"preset": preset}}
    data = apply_overrides(data, overrides)
    try:
        cfg = CameraConfig.model_validate(data["camera"])
    except ValidationError as err:
        raise format_validation_error(err, "camera") from None
    Camera.preset(cfg.preset)  # an unknown preset fails here, before any image is read
    return cfg


def camera_for_image(cfg: CameraConfig, shape: tuple[int, int]) -> Camera:
    """The camera of ``cfg`` with the image's size unless the configuration gives one."""
    h, w = shape
    given = (cfg.width, cfg.height)
    if given[0] is not None and given[0] != w or given[1] is not None and given[1] != h:
        raise ConfigError("camera.width/height", given, f"the image's {w} x {h} px")
    return camera_from_config(cfg.model_copy(update={"width": w, "height": h}))


def parse_epoch(text: str | None) -> float | None:
    """``--epoch``: a Julian year (``2019.58``) or an ISO date-time (UTC) -> Julian year."""
    if text is None:
        return None
    try:
        v = float(text)
    except ValueError:
        v = None
    if v is not None:
        if not (math.isfinite(v) and 1800.0 <= v <= 2200.0):
            raise ConfigError("--epoch", text, "a Julian year between 1800 and 2200 or an ISO "
                              "date-time")
        return v
    from astropy.time import Time

    try:
        return float(Time(text, scale="utc").jyear)
    except ValueError:
        raise ConfigError("--epoch", text, "a Julian year (2019.58) or an ISO date-time "
                          "(2019-07-29T20:47:26)") from None


def check_output(out: Path, overwrite: bool) -> list[Path]:
    """Refuse a non-empty ``out`` without ``overwrite``; return the earlier run's files to
    replace (module docstring)."""
    if out.exists() and not out.is_dir():
        raise DataFileError(f"output {str(out)!r} exists and is not a directory")
    if not out.is_dir():
        return []
    entries = sorted(out.iterdir())
    if not entries:
        return []
    if not overwrite:
        shown = ", ".join(p.name for p in entries[:3]) + (" ..." if len(entries) > 3 else "")
        raise DataFileError(f"output {str(out)!r} is not empty ({shown}): expected a new or "
                            "empty directory; use --overwrite to replace an earlier solve "
                            "there, or choose another --out")
    return [p for p in entries
            if p.is_file() and (p.name in (RESULTS, REPORT) or OVERLAY.match(p.name))]


@dataclass
class ImageResult:
    """One image's outcome (``solution`` None when the image could not be read or solved)."""

    path: Path
    error: str | None
    image: StarImage | None = None
    solution: PlateSolution | None = None
    epoch_jyear: float = DEFAULT_EPOCH_JYEAR
    epoch_source: str = ""
    overlay: str | None = None


def _result_dict(r: ImageResult, cat: StarCatalogue) -> dict[str, Any]:
    out: dict[str, Any] = {"image": str(r.path), "epoch_jyear": r.epoch_jyear,
                           "epoch_source": r.epoch_source,
                           "limiting_v": None if r.image is None else r.image.limiting_v}
    s = r.solution
    if s is None:
        out.update(status="error", reason=r.error)
        return out
    out.update(status=s.status, reason=s.reason, n_detections=len(s.centroids),
               detections_uv_px=np.round(s.centroids.uv, 4).tolist(),
               settings=s.settings.as_dict(), time_extract_s=s.time_extract_s,
               time_solve_s=s.time_solve_s, overlay=r.overlay)
    if not s.ok:
        return out
    ra, dec, roll = s.ra_dec_roll_deg
    cam = s.camera
    d = cat.directions(r.epoch_jyear, s.catalogue_row)
    c = d @ s.R_cam_to_inertial
    predicted = cam.project(c / c[:, 2:], distort=True)
    det = s.centroids.uv[s.detection_index]
    out.update(
        ra_deg=ra, dec_deg=dec, roll_deg=roll,
        quaternion_xyzw=s.quaternion_xyzw.tolist(),
        R_cam_to_inertial=np.asarray(s.R_cam_to_inertial).tolist(),
        covariance_rad2=np.asarray(s.covariance_rad2).tolist(),
        sigma_arcsec=dict(zip(("x", "y", "roll"), s.sigma_arcsec.tolist(), strict=True)),
        focal_length_mm=cam.focal_length * 1e3,
        focal_length_sigma_mm=s.focal_length_sigma_m * 1e3,
        fov_x_deg=math.degrees(cam.fov_x), fov_y_deg=math.degrees(cam.fov_y),
        k1=cam.k1, k1_sigma=None if math.isnan(s.k1_sigma) else s.k1_sigma,
        n_matched=s.n_matched, rms_arcsec=s.rms_arcsec,
        n_required=s.n_required, poisson_lambda=s.lam, hypotheses=s.hypotheses,
        matched=[{"hip": int(h), "v_mag": round(float(v), 3),
                  "detection_uv_px": [round(float(x), 4) for x in du],
                  "detection_sigma_px": [round(float(x), 4) for x in sd],
                  "predicted_uv_px": [round(float(x), 4) for x in cu],
                  "residual_px": [round(float(x), 4) for x in rp],
                  "residual_arcsec": round(float(ra_), 3)}
                 for h, v, du, sd, cu, rp, ra_ in zip(
                     s.hip, s.v_mag, det, s.centroids.sigma_px[s.detection_index], predicted,
                     s.residual_px, s.residual_arcsec, strict=True)],
    )
    return out


#: Overlay marks [px of the frame; the overlay is drawn on the frame's own pixel grid, pixel
#: (row v, column u) centred at (u, v)]: the identified detection's circle radius and line
#: width, the catalogue star's diagonal cross half-length and line width.
CIRCLE_RADIUS_PX = 7.0
CIRCLE_WIDTH_PX = 1.5
CROSS_HALF_PX = 3.5
CROSS_WIDTH_PX = 1.2
#: Overlay colours (RGB). The circle and cross colours are drawn last, anti-aliased, and are
#: the only pure green and pure magenta in the picture (the frame is grey, labels and other
#: marks have other hues), so their places can be measured back from the PNG.
CIRCLE_RGB = (0, 255, 0)
CROSS_RGB = (255, 0, 255)
LABEL_RGB = (130, 255, 255)
DETECTION_RGB = (255, 200, 0)
BORESIGHT_RGB = (255, 60, 60)
LEGEND = ("green circle: detection identified (centred on its centroid; Hipparcos number)   "
          "magenta x: the catalogue star through the solved attitude and camera",
          "yellow square: detection not identified   red +: boresight, arrow to north")


def _paint(rgb: np.ndarray, cu: float, cv: float, reach: float, colour: tuple[int, int, int],
           alpha_of: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> None:
    """Blend ``colour`` into ``rgb`` (float, H x W x 3) with the coverage ``alpha_of(du, dv)``
    of the pixels within ``reach`` of (cu, cv); ``du, dv``: pixel centre minus (cu, cv)."""
    h, w = rgb.shape[:2]
    u0, u1 = max(int(math.floor(cu - reach)), 0), min(int(math.ceil(cu + reach)) + 1, w)
    v0, v1 = max(int(math.floor(cv - reach)), 0), min(int(math.ceil(cv + reach)) + 1, h)
    if u0 >= u1 or v0 >= v1:
        return
    dv, du = np.mgrid[v0:v1, u0:u1].astype(float)
    a = alpha_of(du - cu, dv - cv)[..., None]
    win = rgb[v0:v1, u0:u1]
    win *= 1.0 - a
    win += a * np.asarray(colour, float)


def _ring_alpha(du: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Coverage of the circle's line: 1 within its half width, a 1 px linear edge."""
    return np.clip(0.5 * CIRCLE_WIDTH_PX + 0.5 - np.abs(np.hypot(du, dv) - CIRCLE_RADIUS_PX),
                   0.0, 1.0)


def _cross_alpha(du: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Coverage of a diagonal cross (two segments of half-length ``CROSS_HALF_PX``)."""
    c = math.sqrt(0.5)
    d = np.full(du.shape, np.inf)
    for ax, ay in ((c, c), (c, -c)):
        t = np.clip(du * ax + dv * ay, -CROSS_HALF_PX, CROSS_HALF_PX)
        d = np.minimum(d, np.hypot(du - t * ax, dv - t * ay))
    return np.clip(0.5 * CROSS_WIDTH_PX + 0.5 - d, 0.0, 1.0)


def write_overlay(path: Path, image: StarImage, result: dict[str, Any]) -> None:
    """The overlay picture of one solved or unsolved frame (module docstring): the identified
    detections' circles centred on their centroids (``detection_uv_px``) and the catalogue
    stars' crosses at ``predicted_uv_px`` of ``result["matched"]``."""
    from PIL import Image, ImageDraw

    a = np.asarray(image.data, float)
    bkg, noise = background(a, 32)
    sub = a - bkg  # the sky's gradient and the vignetting removed: stars on a flat floor
    hi = max(float(np.percentile(sub, 99.95)), 1e-9)
    x = np.clip((sub - noise) / hi, 0.0, None)  # the noise floor black
    g = np.arcsinh(10.0 * x) / math.asinh(10.0)
    rgb = np.repeat((255 * np.clip(g, 0, 1)).astype(np.uint8)[..., None], 3, axis=2)
    im = Image.fromarray(rgb, "RGB")
    dr = ImageDraw.Draw(im)
    matched = result.get("matched", [])
    circles = np.array([m["detection_uv_px"] for m in matched], float).reshape(-1, 2)
    crosses = np.array([m["predicted_uv_px"] for m in matched], float).reshape(-1, 2)
    # the pixel-grid marks and text first, the anti-aliased circles and crosses over them
    dets = np.array(result.get("detections_uv_px", []), float).reshape(-1, 2)
    for u, v in dets:
        if circles.size and np.min(np.hypot(*(circles - (u, v)).T)) < 1e-6:
            continue  # identified: circled instead
        dr.rectangle([u - 2, v - 2, u + 2, v + 2], outline=DETECTION_RGB)
    for m, (u, v) in zip(matched, circles, strict=True):
        dr.text((u + CIRCLE_RADIUS_PX + 2, v - 6), f"HIP {m['hip']}", fill=LABEL_RGB)
    h, w = a.shape
    if result.get("status") == "ok":
        R = np.asarray(result["R_cam_to_inertial"])
        cu, cv = (w - 1) / 2.0, (h - 1) / 2.0
        dr.line([cu - 12, cv, cu + 12, cv], fill=BORESIGHT_RGB)
        dr.line([cu, cv - 12, cu, cv + 12], fill=BORESIGHT_RGB)
        n_cam = R.T @ np.array([0.0, 0.0, 1.0])
        nx, ny = n_cam[0], n_cam[1]
        norm = math.hypot(nx, ny) or 1.0
        L = 0.12 * min(w, h)
        tip = (cu + L * nx / norm, cv + L * ny / norm)
        dr.line([cu, cv, *tip], fill=BORESIGHT_RGB, width=2)
        dr.text((tip[0] + 4, tip[1] + 4), "N", fill=BORESIGHT_RGB)
        dr.text((8, 8), f"RA {result['ra_deg']:.4f}  Dec {result['dec_deg']:+.4f}  roll "
                f"{result['roll_deg']:.3f} deg  FOV {result['fov_x_deg']:.4f} deg  "
                f"{result['n_matched']} stars, rms {result['rms_arcsec']:.1f} arcsec",
                fill=(255, 255, 255))
        dr.rectangle([4, h - 32, min(w - 1, 12 + max(map(dr.textlength, LEGEND))), h - 4],
                     fill=(0, 0, 0))
        for k, line in enumerate(LEGEND):
            dr.text((8, h - 30 + 13 * k), line, fill=(255, 255, 255))
    else:
        dr.text((8, 8), f"not solved: {result.get('reason', '')}", fill=(255, 80, 80))
    canvas = np.asarray(im, float).copy()
    for u, v in circles:
        _paint(canvas, u, v, CIRCLE_RADIUS_PX + CIRCLE_WIDTH_PX, CIRCLE_RGB, _ring_alpha)
    for u, v in crosses:
        _paint(canvas, u, v, CROSS_HALF_PX + CROSS_WIDTH_PX, CROSS_RGB, _cross_alpha)
    with atomic_path(path) as tmp:
        Image.fromarray(np.round(canvas).astype(np.uint8), "RGB").save(tmp, format="PNG")


def _report(rows: list[dict[str, Any]]) -> str:
    lines = ["# Star images solved", "",
             "| image | status | RA [deg] | Dec [deg] | roll [deg] | 1-sigma x / y / roll "
             "[arcsec] | focal length [mm] | FOV [deg] | k1 | matched / detected | rms "
             "[arcsec] | extract / solve [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        name = Path(r["image"]).name
        if r["status"] != "ok":
            lines.append(f"| {name} | {r['status']}: {r.get('reason', '')} |" + " - |" * 10)
            continue
        s = r["sigma_arcsec"]
        lines.append(
            f"| {name} | ok | {r['ra_deg']:.5f} | {r['dec_deg']:+.5f} | {r['roll_deg']:.4f} | "
            f"{s['x']:.2f} / {s['y']:.2f} / {s['roll']:.1f} | {r['focal_length_mm']:.4f} +- "
            f"{r['focal_length_sigma_mm']:.4f} | {r['fov_x_deg']:.4f} | {r['k1']:.4f} | "
            f"{r['n_matched']} / {r['n_detections']} | {r['rms_arcsec']:.2f} | "
            f"{r['time_extract_s']:.2f} / {r['time_solve_s']:.2f} |")
    lines += ["", "RA, Dec: the principal point's direction (ICRS, at each image's epoch); roll: "
              "celestial north from the image's up, counter-clockwise; 1-sigma in camera axes "
              "(x right, y down, roll about the boresight), scaled by the residuals."]
    return "\n".join(lines) + "\n"


def solve_images(paths: list[Path], out: Path, *, camera: CameraConfig,
                 epoch_jyear: float | None = None, overwrite: bool = False,
                 options: PlateOptions | None = None,
                 catalogue: StarCatalogue | None = None,
                 reader: Callable[[Path], StarImage] = read_star_image) -> dict[str, Any]:
    """Solve every image of ``paths`` and write the outputs (module docstring).

    ``reader`` reads one file (default :func:`~starnav.stars.images.read_star_image`; the
    command line adds raw AMIE ``.IMG`` frames).

    Returns ``{"results": [per-image dicts], "results_path", "report"}``; an image that cannot
    be read, has no stars or does not fit the camera is recorded with ``status "error"``.

    Raises
    ------
    DataFileError
        ``out`` refused (before any image is read).
    """
    if not paths:
        raise ConfigError("IMAGE", [], "at least one image file")
    old = check_output(out, overwrite)
    cat = catalogue if catalogue is not None else hipparcos()
    results: list[ImageResult] = []
    for p in paths:
        r = ImageResult(Path(p), None)
        try:
            img = reader(Path(p))
            r.image = img
            cam = camera_for_image(camera, img.data.shape)
            if epoch_jyear is not None:
                r.epoch_jyear, r.epoch_source = epoch_jyear, "command line"
            elif img.epoch_jyear is not None:
                r.epoch_jyear, r.epoch_source = img.epoch_jyear, img.epoch_source
            else:
                r.epoch_source = (f"J{DEFAULT_EPOCH_JYEAR:.1f} assumed ({img.epoch_source}; "
                                  "give --epoch)")
            sol = solve_plate(img.data, cam, epoch_jyear=r.epoch_jyear,
                              saturation_dn=img.saturation_dn, catalogue=cat, options=options,
                              limiting_v=img.limiting_v)
            r.solution = sol
            if sol.status == "too-few-stars":
                what = "no stars" if len(sol.centroids) == 0 else "too few stars"
                r.error = f"{p}: {what}: {sol.reason}"
        except StarnavError as err:
            r.error = f"{p}: {err}" if str(p) not in str(err) else str(err)
        results.append(r)
    for f in old:
        f.unlink()
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    used_names: set[str] = set()
    for r in results:
        if r.image is not None and r.solution is not None:
            stem = r.path.stem
            name = f"overlay_{stem}.png"
            k = 1
            while name in used_names:
                k += 1
                name = f"overlay_{stem}_{k}.png"
            used_names.add(name)
            r.overlay = name
        row = _result_dict(r, cat)
        if r.error is not None and r.solution is not None:
            row["status"], row["reason"] = "error", r.error
        rows.append(row)
        if r.overlay is not None and r.image is not None:
            write_overlay(out / r.overlay, r.image, row)
    doc = {"camera": camera.model_dump(mode="json"), "images": rows}
    atomic_write_text(out / RESULTS, json.dumps(_plain(doc), indent=1, sort_keys=True,
                                                allow_nan=False) + "\n")
    atomic_write_text(out / REPORT, _report(rows))
    return {"results": rows, "results_path": out / RESULTS, "report": out / REPORT}


def _plain(x: Any) -> Any:
    """JSON-ready: numpy scalars to Python, NaN and infinities to null."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


__all__ = ["ARCSEC", "camera_config", "check_output", "parse_epoch", "solve_images"]
