"""The on-disk dataset format: layout, names, and the JSON encodings of truth and readouts.

A dataset is a directory any OpenEXR, PNG and JSON tool can read; its layout, file by file:
docs/dataset.md. Values are SI with the unit in the name; pixels ``(u, v) = (column, row)``
from the centre of the top-left pixel; attitude matrices map camera to inertial;
quaternions are scalar-last.

The same scenario and seed give the same bytes, whatever the workers, the order or the
interruptions: JSON with sorted keys and shortest round-trip floats (no NaN), no time stamps,
host names or wall-clock times in any file, frames listed by index.

Index
-----
Names: :data:`SCHEMA_VERSION`, :data:`MANIFEST`, :data:`FRAME_FILES`, :func:`frame_dirname`,
:func:`exposure_dirname`, :func:`check_exposures`; JSON: :func:`dumps`, :func:`plain`,
:func:`write_json`, :func:`read_json`, :func:`json_value`; integrity: :func:`sha256_file`,
:func:`file_record`, :func:`frame_problems`; encodings: :func:`truth_to_dict`,
:func:`geometry_of_truth`, :func:`segments_to_dict`, :func:`segments_from_dict`,
:func:`windows_to_dict`, :func:`windows_from_dict`, :func:`camera_to_dict`,
:func:`camera_from_dict`, :func:`uint16_image`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_write_text
from starnav.camera import Camera
from starnav.detector.products import Segments, Window
from starnav.eclipse import disc_mean_sunlit_fraction
from starnav.errors import ConfigError, DataFileError
from starnav.geometry import geometry_from_dict, geometry_to_dict, quat_xyzw_from_matrix
from starnav.scenes.ephemeris import format_epoch

#: Name and version of the format (bump the version on any incompatible change).
SCHEMA = "starnav-dataset"
SCHEMA_VERSION = 3

MANIFEST = "manifest.json"
RESOLVED = "scenario.resolved.yaml"
FRAMES_DIR = "frames"
TRUTH = "truth.json"
RADIANCE = "radiance.exr"
DN = "dn.png"
#: The star acquisition's DN frame at a scheduled star frame (``navigation.attitude.source:
#: stars``; 16-bit PNG, :func:`starnav.simulate.attitude.star_acquisition_dn`, run 0).
STAR_DN = "stars_dn.png"
#: 8-bit quick looks (pictures for a person; the data are ``dn.png`` and ``radiance.exr``).
DN_QUICKLOOK = "dn_quicklook.png"
RADIANCE_QUICKLOOK = "radiance_quicklook.png"
SEGMENTS = "segments.json"
WINDOWS = "windows.json"
READOUT = "readout.json"
#: The frame's own record of its other files (relative path -> ``bytes``, ``sha256``), written
#: last into the frame before it is renamed into place: what a frame left on disk by a crash
#: (not yet in the manifest) is checked against before a resume adopts it.
FRAME_FILES = "files.json"

#: Prefix of temporary frame directories (removed on resume; never listed as frames).
TMP_PREFIX = ".tmp-"

_FRAME_RE = re.compile(r"^\d{6,}$")


# ----------------------------------------------------------------------------- names
def frame_dirname(index: int) -> str:
    """Directory name of frame ``index`` (six digits, more if needed)."""
    if index < 0:
        raise ConfigError("frame index", index, "an integer >= 0")
    return f"{index:06d}"


def is_frame_dirname(name: str) -> bool:
    """True for a finished frame directory name (not a temporary one)."""
    return bool(_FRAME_RE.match(name))


def exposure_dirname(exposure_time: float) -> str:
    """Directory of one exposure time, in milliseconds with 6 significant digits:
    ``1.5e-5`` s -> ``exposure_0.015ms``, ``0.2`` s -> ``exposure_200ms``."""
    if not (math.isfinite(exposure_time) and exposure_time > 0):
        raise ConfigError("exposure", exposure_time, "a finite exposure time > 0 s")
    return f"exposure_{exposure_time * 1e3:.6g}ms"


def check_exposures(exposures_s: Sequence[float]) -> tuple[float, ...]:
    """Validate a list of exposure times [s]: non-empty, finite, > 0, distinct directories."""
    if len(exposures_s) == 0:
        raise ConfigError("exposures", "[]", "at least one exposure time [s]")
    out = []
    seen: dict[str, float] = {}
    for t in exposures_s:
        try:
            v = float(t)
        except (TypeError, ValueError):
            raise ConfigError("exposures", t, "exposure times in seconds, e.g. 1.5e-5") from None
        name = exposure_dirname(v)
        if name in seen:
            raise ConfigError("exposures", list(exposures_s),
                              f"distinct exposure times ({seen[name]!r} and {v!r} both map to "
                              f"{name})")
        seen[name] = v
        out.append(v)
    return tuple(out)


# ----------------------------------------------------------------------------- JSON
def plain(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays to Python, non-finite floats to None."""
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "biu" or (obj.dtype.kind == "f" and np.isfinite(obj).all()):
            return obj.tolist()   # already Python bools, ints and finite floats
        return plain(obj.tolist())
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        v = float(obj)
        return v if math.isfinite(v) else None
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot store {type(obj).__name__} in a dataset JSON file")


def dumps(obj: Any, compact: bool = False) -> str:
    """Canonical JSON text: sorted keys, shortest round-trip floats, ``null`` for NaN/inf,
    a final newline. ``compact`` drops the indentation (large arrays)."""
    if compact:
        return json.dumps(plain(obj), sort_keys=True, separators=(",", ":"),
                          allow_nan=False) + "\n"
    return json.dumps(plain(obj), sort_keys=True, indent=1, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike[str], obj: Any, compact: bool = False) -> Path:
    """Write canonical JSON atomically."""
    return atomic_write_text(path, dumps(obj, compact))


def read_json(path: str | os.PathLike[str]) -> Any:
    """Read a JSON file; a missing or corrupt file raises :class:`DataFileError`."""
    p = Path(path)
    if not p.is_file():
        raise DataFileError(f"{str(p)!r} does not exist")
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataFileError(f"{str(p)!r} is not valid JSON ({err})") from None


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_record(root: Path) -> dict[str, dict[str, Any]]:
    """Size and SHA-256 of every file under ``root`` except its :data:`FRAME_FILES` (relative
    POSIX path -> ``{"bytes", "sha256"}``, sorted)."""
    return {p.relative_to(root).as_posix(): {"bytes": p.stat().st_size,
                                             "sha256": sha256_file(p)}
            for p in sorted(root.rglob("*"))
            if p.is_file() and p.relative_to(root).as_posix() != FRAME_FILES}


def frame_problems(d: Path, files: Mapping[str, Mapping[str, Any]] | None = None,
                   exposures: Sequence[str] = (), radiance: bool | None = None) -> list[str]:
    """What is wrong with the frame directory ``d`` (empty: whole and as written).

    ``files`` is what the frame should hold (its manifest entry's files); by default the
    frame's own record (:data:`FRAME_FILES`), which must then exist and be valid JSON. Checked:
    the file names (none missing, none extra), each file's size and recomputed SHA-256, that
    the JSON files parse, and, when given, that the frame has its expected parts (every
    exposure directory with its DN frame, readout and windows; the radiance when stored).
    """
    problems: list[str] = []
    if files is None:
        rec = d / FRAME_FILES
        try:
            files = json.loads(rec.read_text(encoding="utf-8"))["files"]
            if not isinstance(files, dict):
                raise TypeError("files is not a mapping")
        except FileNotFoundError:
            return [f"{FRAME_FILES} (its record of its files) is missing"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            return [f"{FRAME_FILES} is unreadable ({type(err).__name__}: {err})"]
    else:
        files = {k: v for k, v in files.items() if k != FRAME_FILES}
    on_disk = {p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file()}
    on_disk.discard(FRAME_FILES)
    need = [TRUTH] + ([RADIANCE] if radiance else []) + [
        f"{e}/{n}" for e in exposures for n in (DN, READOUT, WINDOWS)]
    problems += [f"{n} is missing" for n in need if n not in files and n not in on_disk]
    problems += [f"{n} is missing" for n in sorted(set(files) - on_disk)]
    problems += [f"{n} is not in its record" for n in sorted(on_disk - set(files))]
    for n in sorted(set(files) & on_disk):
        p, meta = d / n, files[n]
        if p.stat().st_size != meta.get("bytes"):
            problems.append(f"{n} has {p.stat().st_size} bytes, its record {meta.get('bytes')}")
        elif sha256_file(p) != meta.get("sha256"):
            problems.append(f"{n} differs from its record (SHA-256)")
        elif p.suffix == ".json":
            try:
                json.loads(p.read_text(encoding="utf-8"))
            except (ValueError, UnicodeDecodeError) as err:
                problems.append(f"{n} is not valid JSON ({err})")
    return problems


# ----------------------------------------------------------------------------- segments
def segments_to_dict(seg: Any) -> dict[str, Any]:
    """JSON form of :class:`~starnav.detector.products.Segments`.

    Run ``k`` covers row ``row[k]``, columns ``col_start[k] .. col_start[k] + length[k] - 1``;
    its DN are ``values[offset_k : offset_k + length[k]]`` with ``offset_k`` the sum of the
    previous lengths; ``level[k]`` is the index of the highest threshold reached. The arrays
    stay NumPy arrays (:func:`dumps` writes them as JSON lists in one ``tolist`` each instead of
    walking every element).
    """
    return {
        "format": "starnav-segments",
        "version": 1,
        "shape": [int(seg.shape[0]), int(seg.shape[1])],
        "thresholds_dn": [int(t) for t in seg.thresholds],
        "truncated": bool(seg.truncated),
        "runs": len(seg),
        "row": np.asarray(seg.row),
        "col_start": np.asarray(seg.col_start),
        "length": np.asarray(seg.length),
        "level": np.asarray(seg.level),
        "values": np.asarray(seg.values),
    }


def segments_from_dict(d: Mapping[str, Any]) -> Any:
    """Inverse of :func:`segments_to_dict`."""
    length = np.asarray(d["length"], np.int32)
    offset = np.zeros(length.size, np.int64)
    if length.size:
        offset[1:] = np.cumsum(length[:-1], dtype=np.int64)
    return Segments(row=np.asarray(d["row"], np.int32),
                    col_start=np.asarray(d["col_start"], np.int32),
                    length=length, offset=offset,
                    values=np.asarray(d["values"], np.uint16),
                    level=np.asarray(d["level"], np.int8),
                    thresholds=tuple(int(t) for t in d["thresholds_dn"]),
                    shape=(int(d["shape"][0]), int(d["shape"][1])),
                    truncated=bool(d["truncated"]))


def windows_to_dict(windows: Sequence[Any], acquisition: int | None) -> dict[str, Any]:
    """JSON form of a windows readout: per window its top-left pixel, size and DN rows (a
    NumPy array; :func:`dumps` writes it as a list of rows)."""
    return {
        "format": "starnav-windows",
        "version": 1,
        "acquisition": acquisition,
        "windows": [{"row0": int(w.row0), "col0": int(w.col0), "height": int(w.height),
                     "width": int(w.width), "dn": np.asarray(w.dn)} for w in windows],
    }


def windows_from_dict(d: Mapping[str, Any]) -> tuple[Any, ...]:
    """Inverse of :func:`windows_to_dict`."""
    out = []
    for w in d["windows"]:
        dn = np.asarray(w["dn"], np.uint16).reshape(int(w["height"]), int(w["width"]))
        out.append(Window(int(w["row0"]), int(w["col0"]), dn))
    return tuple(out)


# ----------------------------------------------------------------------------- truth
def truth_to_dict(geom: Any, camera: Any, limb_points: int = 360) -> dict[str, Any]:
    """The truth of one frame (see docs/dataset.md, ``truth.json``).

    Parameters
    ----------
    geom : FrameGeometry
        The frame's geometry (Moon-centred inertial, SI).
    camera : Camera
        Used to project the Moon centre and the true limb (with the lens distortion: these
        are where the detector sees them).
    limb_points : int
        Number of points sampled on the true limb (equal steps in the tangency circle).
    """
    g = geom
    centre_cam = g.moon_centre_camera()
    static = g.camera_state_emb is None
    out: dict[str, Any] = {
        "format": "starnav-truth",
        "version": 1,
        "index": int(g.index),
        "epoch_tdb_s": float(g.epoch_tdb),
        "epoch_tdb_iso": None if static else format_epoch(float(g.epoch_tdb), "TDB"),
        "spacecraft_emb": None if static else {
            "position_m": g.camera_state_emb[:3], "velocity_m_s": g.camera_state_emb[3:]},
        "spacecraft_moon": {"position_m": g.camera_position,
                            "velocity_m_s": g.camera_velocity},
        "attitude": {
            "R_cam_to_inertial_true": g.R_cam_to_inertial,
            "q_cam_to_inertial_true_xyzw": quat_xyzw_from_matrix(g.R_cam_to_inertial),
            "R_cam_to_inertial_measured": g.R_cam_to_inertial_measured,
            "q_cam_to_inertial_measured_xyzw": None if g.R_cam_to_inertial_measured is None
            else quat_xyzw_from_matrix(g.R_cam_to_inertial_measured),
        },
        "sun": {
            "position_from_moon_m": g.sun_position,
            "direction_from_moon": g.sun_direction,
            "direction_camera": g.sun_direction_camera(),
            "distance_m": g.sun_distance,
        },
        "moon": {
            "radius_m": g.body_radius,
            "R_moon_to_inertial": g.R_body_to_inertial,
            "centre_camera_m": centre_cam,
            "centre_pixel_px": g.moon_centre_pixel(camera, distort=True),
            "centre_pixel_pinhole_px": g.moon_centre_pixel(camera, distort=False),
            "apparent_radius_rad": g.apparent_radius,
            "range_m": g.range,
            "phase_angle_rad": g.phase_angle,
        },
        "limb": {
            "points_px": g.limb_points(camera, n=limb_points, distort=True),
            "description": "true limb of the reference sphere seen from the true pose, "
                           "projected with the lens distortion [px]; points behind the camera "
                           "are omitted",
        },
        "eclipse": None if g.earth_position is None else {
            "disc_mean_sunlit_fraction": disc_mean_sunlit_fraction(
                g.camera_position, g.body_radius, g.sun_position, g.earth_position),
            "description": "fraction of the solar disc the Earth does not hide, averaged over "
                           "the visible disc (uniform in projected area; uniform solar disc, "
                           "the Earth's radius + 1/85): 1 outside the penumbra, 0 in the "
                           "umbra; null for frames without an Earth (static, fly-by)",
        },
        "geometry": geometry_to_dict(g),
    }
    return out


def json_value(d: Mapping[str, Any], key: str, path: str | os.PathLike[str],
               shape: tuple[int, ...] | None = None) -> Any:
    """``d[k1][k2]...`` for the dotted ``key`` of the JSON file ``path``; with ``shape``, as
    a finite float array of that shape. A missing key or a value of another form is a
    :class:`DataFileError` naming the file and the key (never a bare ``KeyError``)."""
    v: Any = d
    for k in key.split("."):
        if not isinstance(v, Mapping) or k not in v:
            raise DataFileError(f"{str(path)!r}: key {key!r} is missing (a malformed or "
                                "foreign file)")
        v = v[k]
    if shape is None:
        return v
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != shape or not np.isfinite(a).all():
        raise DataFileError(f"{str(path)!r}: key {key!r} = {str(v)[:60]}: expected finite "
                            f"numbers of shape {shape}")
    return a


#: The keys of a ``truth.json``'s ``geometry`` and their shapes (None: a scalar).
_GEOMETRY_KEYS = {"camera_position_m": (3,), "R_cam_to_inertial": (3, 3),
                  "sun_position_m": (3,), "R_moon_to_inertial": (3, 3), "epoch_tdb_s": (),
                  "camera_velocity_m_s": (3,), "moon_radius_m": (), "index": ()}


def geometry_of_truth(d: Mapping[str, Any], path: str | os.PathLike[str] = TRUTH) -> Any:
    """The :class:`~starnav.geometry.FrameGeometry` stored in a ``truth.json`` (``path``
    names the file in the error a missing or malformed key raises)."""
    for k, shape in _GEOMETRY_KEYS.items():
        json_value(d, f"geometry.{k}", path, shape)
    return geometry_from_dict(dict(d["geometry"]))


def camera_to_dict(camera: Any) -> dict[str, Any]:
    """Intrinsics of a :class:`~starnav.camera.Camera` (SI; enough to rebuild it) plus its
    derived figures (``describe``)."""
    c = camera
    return {
        "name": c.name, "width_px": c.width, "height_px": c.height,
        "focal_length_m": c.focal_length, "pitch_x_m": c.pitch_x, "pitch_y_m": c.pitch_y,
        "f_number": c.f_number, "cx_px": c.cx, "cy_px": c.cy, "fx_px": c.fx, "fy_px": c.fy,
        "distortion_k1_k2_k3_p1_p2": [c.k1, c.k2, c.k3, c.p1, c.p2],
        "derived": c.describe(),
    }


def camera_from_dict(d: Mapping[str, Any]) -> Any:
    """Inverse of :func:`camera_to_dict`."""
    k1, k2, k3, p1, p2 = (float(x) for x in d["distortion_k1_k2_k3_p1_p2"])
    return Camera(width=int(d["width_px"]), height=int(d["height_px"]),
                  focal_length=float(d["focal_length_m"]), pitch_x=float(d["pitch_x_m"]),
                  pitch_y=float(d["pitch_y_m"]), f_number=float(d["f_number"]),
                  cx=float(d["cx_px"]), cy=float(d["cy_px"]), k1=k1, k2=k2, k3=k3, p1=p1,
                  p2=p2, name=str(d.get("name", "custom")))


def uint16_image(arr: NDArray[Any]) -> NDArray[np.uint16]:
    """Checked conversion to uint16 (the DN PNG)."""
    a = np.asarray(arr)
    if a.ndim != 2:
        raise ConfigError("dn", a.shape, "a 2-D image")
    return np.ascontiguousarray(a, dtype=np.uint16)
