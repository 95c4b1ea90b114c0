"""A camera as a calibration estimated it: the file the bench writes and navigation reads.

The flight software does not know the camera's focal length, principal point and distortion; it
knows what the ground calibration (:mod:`starnav.calibration`) estimated, with a covariance.
This module is that contract: a small versioned JSON file, its reader and writer, and what both
sides need (the calibrated camera, each parameter's 1-sigma, moved cameras, draws).

File layout (``format`` ``starnav-camera-calibration``, ``version`` 1)::

    {"format": "starnav-camera-calibration", "version": 1,
     "camera": {"name": "aa-str", "width": 1024, "height": 1024,
                "pitch_x_m": 1.8e-05, "pitch_y_m": 1.8e-05, "f_number": 1.495575},
     "parameters": ["focal_length_m", "cx_px", "cy_px", "k1", "k2"],
     "estimate": [0.0507, 511.5, 511.5, 0.0, 0.0],
     "covariance": [[...], ...],
     "fixed": {"k3": 0.0, "p1": 0.0, "p2": 0.0},
     "provenance": {...},
     "radiometric": {...}}

``parameters`` are estimated (in the covariance's order); ``fixed`` are taken as exact;
``provenance`` is free form; ``radiometric`` is :mod:`starnav.calibration`'s section, carried
untouched.

Index
-----
:data:`PARAMETERS`, :class:`CameraCalibration` (``camera``, ``sigma``, ``sample``),
:func:`with_parameters` (a camera with some parameters set), :func:`read_calibration`,
:func:`write_calibration`, :func:`star_alignment` (the rotation a star solve through a
calibrated camera absorbs), :func:`bench_calibration` (a run's camera knowledge from the
packaged bench emulations).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from starnav.atomic import atomic_write_text
from starnav.camera import Camera
from starnav.config_base import read_json_file
from starnav.data import packaged_path
from starnav.errors import ConfigError, DataFileError
from starnav.seeding import STAGE_CAMERA_CALIBRATION, generator
from starnav.typing import FloatArray

FORMAT = "starnav-camera-calibration"
VERSION = 1

#: Estimable parameters: file name -> (``Camera`` field, unit).
PARAMETERS: dict[str, tuple[str, str]] = {
    "focal_length_m": ("focal_length", "m"),
    "cx_px": ("cx", "px"),
    "cy_px": ("cy", "px"),
    "k1": ("k1", "-"),
    "k2": ("k2", "-"),
    "k3": ("k3", "-"),
    "p1": ("p1", "-"),
    "p2": ("p2", "-"),
}
_DISTORTION = ("k1", "k2", "k3", "p1", "p2")


def with_parameters(camera: Camera, values: dict[str, float]) -> Camera:
    """``camera`` with the named :data:`PARAMETERS` set to ``values``."""
    over: dict[str, float] = {}
    for name, value in values.items():
        if name not in PARAMETERS:
            raise ConfigError("calibration parameter", name, f"one of {list(PARAMETERS)}")
        over[PARAMETERS[name][0]] = float(value)
    return replace(camera, **over)


def parameter_values(camera: Camera, names: tuple[str, ...] | list[str]) -> FloatArray:
    """The named :data:`PARAMETERS` of ``camera``, in that order."""
    return np.array([float(getattr(camera, PARAMETERS[n][0])) for n in names])


@dataclass(frozen=True)
class CameraCalibration:
    """A camera as estimated by a calibration, with the covariance of its parameters.

    Parameters
    ----------
    camera : Camera
        The calibrated camera (estimated parameters at their estimate, the others fixed).
    parameters : tuple of str
        The estimated parameters (:data:`PARAMETERS` names), in the covariance's order.
    covariance : (n, n) array
        Covariance of the estimate [units of :data:`PARAMETERS`].
    provenance : dict
        How it was made (method, bench, seed, software); free form, JSON-serialisable.
    radiometric : dict or None
        The radiometric calibration's section, carried untouched.
    """

    camera: Camera
    parameters: tuple[str, ...]
    covariance: FloatArray
    provenance: dict[str, Any] = field(default_factory=dict)
    radiometric: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        names = tuple(self.parameters)
        object.__setattr__(self, "parameters", names)
        unknown = [n for n in names if n not in PARAMETERS]
        if unknown or len(set(names)) != len(names):
            raise ConfigError("calibration.parameters", list(names),
                              f"distinct names among {list(PARAMETERS)}")
        cov = np.array(self.covariance, dtype=float)
        n = len(names)
        if cov.shape != (n, n):
            raise ConfigError("calibration.covariance", f"shape {cov.shape}",
                              f"a {n} x {n} matrix (one row per parameter)")
        if not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T, rtol=1e-9,
                                                           atol=1e-300):
            raise ConfigError("calibration.covariance", "not finite and symmetric",
                              "a finite symmetric matrix")
        if n and np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-9 * max(
                float(np.max(np.abs(np.diag(cov)))), 1e-300):
            raise ConfigError("calibration.covariance", "an indefinite matrix",
                              "a positive semi-definite matrix")
        cov = 0.5 * (cov + cov.T)
        cov.setflags(write=False)
        object.__setattr__(self, "covariance", cov)

    @property
    def estimate(self) -> FloatArray:
        """The estimated parameters' values, in :attr:`parameters` order."""
        return parameter_values(self.camera, self.parameters)

    def sigma(self, name: str) -> float:
        """1-sigma of one parameter (0 for a parameter that is not estimated)."""
        if name not in PARAMETERS:
            raise ConfigError("calibration parameter", name, f"one of {list(PARAMETERS)}")
        if name not in self.parameters:
            return 0.0
        i = self.parameters.index(name)
        return math.sqrt(max(float(self.covariance[i, i]), 0.0))

    def camera_with(self, deltas: FloatArray) -> Camera:
        """The calibrated camera with its estimated parameters moved by ``deltas``."""
        values = self.estimate + np.asarray(deltas, dtype=float)
        return with_parameters(self.camera, dict(zip(self.parameters, values, strict=True)))

    def sample(self, rng: np.random.Generator) -> Camera:
        """A camera drawn from the estimate's Gaussian (the truth a calibration of this
        covariance is consistent with)."""
        if not self.parameters:
            return self.camera
        w, V = np.linalg.eigh(self.covariance)
        d = V @ (np.sqrt(np.clip(w, 0.0, None)) * rng.standard_normal(len(w)))
        return self.camera_with(d)

    def matches(self, camera: Camera) -> bool:
        """Whether ``camera`` has this calibration's detector (size and pitch)."""
        c = self.camera
        return (c.width, c.height) == (camera.width, camera.height) and math.isclose(
            c.pitch_x, camera.pitch_x, rel_tol=1e-9) and math.isclose(
            c.pitch_y, camera.pitch_y, rel_tol=1e-9)

    # ------------------------------------------------------------------ file
    def to_dict(self) -> dict[str, Any]:
        c = self.camera
        return {
            "format": FORMAT,
            "version": VERSION,
            "camera": {"name": c.name, "width": c.width, "height": c.height,
                       "pitch_x_m": c.pitch_x, "pitch_y_m": c.pitch_y,
                       "f_number": c.f_number},
            "parameters": list(self.parameters),
            "estimate": [float(v) for v in self.estimate],
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "fixed": {k: float(getattr(c, k)) for k in _DISTORTION
                      if k not in self.parameters},
            "provenance": self.provenance,
            "radiometric": self.radiometric,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "calibration") -> CameraCalibration:
        def need(key: str, kind: type | tuple[type, ...]) -> Any:
            if key not in d:
                raise ConfigError(f"{source}: {key}", "missing", f"a '{key}' entry")
            if not isinstance(d[key], kind):
                raise ConfigError(f"{source}: {key}", d[key], f"a {kind}")
            return d[key]

        if d.get("format") != FORMAT:
            raise ConfigError(f"{source}: format", d.get("format"), repr(FORMAT))
        if d.get("version") != VERSION:
            raise ConfigError(f"{source}: version", d.get("version"),
                              f"{VERSION} (this starnav reads version {VERSION})")
        cam = need("camera", dict)
        names = need("parameters", list)
        est = need("estimate", list)
        if len(est) != len(names):
            raise ConfigError(f"{source}: estimate", f"{len(est)} values",
                              f"one value per parameter ({len(names)})")
        fixed = d.get("fixed") or {}
        if not isinstance(fixed, dict) or any(k not in _DISTORTION for k in fixed):
            raise ConfigError(f"{source}: fixed", fixed, f"a mapping of {list(_DISTORTION)}")
        try:
            base = Camera(width=int(cam["width"]), height=int(cam["height"]),
                          focal_length=float(dict(zip(names, est, strict=True)).get(
                              "focal_length_m", cam.get("focal_length_m", float("nan")))),
                          pitch_x=float(cam["pitch_x_m"]), pitch_y=float(cam["pitch_y_m"]),
                          f_number=float(cam["f_number"]), name=str(cam.get("name", "custom")),
                          **{k: float(v) for k, v in fixed.items()})
        except KeyError as err:
            raise ConfigError(f"{source}: camera.{err.args[0]}", "missing",
                              "width, height, pitch_x_m, pitch_y_m, f_number") from None
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{source}: camera", cam, f"numbers ({err})") from None
        for n, v in zip(names, est, strict=True):
            if not isinstance(v, int | float) or not math.isfinite(float(v)):
                raise ConfigError(f"{source}: estimate.{n}", v, "a finite number")
        try:
            camera = with_parameters(base, dict(zip(names, est, strict=True)))
        except ConfigError as err:
            raise ConfigError(f"{source}: parameters", names, err.expected) from None
        return cls(camera=camera, parameters=tuple(names),
                   covariance=np.asarray(need("covariance", list), dtype=float).reshape(
                       len(names), len(names)) if names else np.zeros((0, 0)),
                   provenance=dict(d.get("provenance") or {}),
                   radiometric=d.get("radiometric"))


def write_calibration(path: str | Path, cal: CameraCalibration) -> Path:
    """Write ``cal`` to ``path`` (JSON, atomically)."""
    return atomic_write_text(path, json.dumps(cal.to_dict(), indent=1) + "\n")


def read_calibration(path: str | Path) -> CameraCalibration:
    """Read a calibration file; a malformed one raises an error naming the entry."""
    p = Path(path)
    d = read_json_file(p, "calibration file")
    if not isinstance(d, dict):
        raise ConfigError(str(p), type(d).__name__, "a JSON object")
    try:
        return CameraCalibration.from_dict(d, source=str(p))
    except ValueError as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f"{p}: covariance", "malformed", f"an n x n matrix ({err})") from None


def camera_fingerprint(camera: Camera) -> str:
    """A short SHA-256 of the camera's geometry (detector, focal length, principal point,
    distortion): which camera a packaged calibration was made for."""
    doc = [camera.width, camera.height, camera.pitch_x, camera.pitch_y, camera.focal_length,
           camera.cx, camera.cy, camera.k1, camera.k2, camera.k3, camera.p1, camera.p2]
    return hashlib.sha256(json.dumps([float(x) for x in doc]).encode()).hexdigest()[:16]


@functools.lru_cache(maxsize=256)
def star_alignment(camera: Camera, known: Camera, n: int = 9) -> FloatArray:
    """The rotation ``A`` (frame of ``camera`` -> frame of ``known``) that a star solve made
    through the model ``known`` absorbs when the optics are ``camera``.

    A star at direction ``c`` lands at pixel ``p = camera.project(c)``; the flight software
    reads it back as ``known.unproject(p)``. Over stars spread across the field, the attitude
    it solves is the true one turned by the rotation that best maps the one set of directions
    onto the other (least squares over an ``n x n`` grid of pixels): ``R_ci' = R_ci A^T``. A
    principal-point error is therefore common to the stars and to the Moon and cancels in the
    Moon's inertial direction; what stays is the field's scale (focal length) and shape
    (distortion)."""
    u = (np.arange(n) + 0.5) * camera.width / n
    v = (np.arange(n) + 0.5) * camera.height / n
    uv = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    rot, _ = Rotation.align_vectors(known.unproject(uv), camera.unproject(uv))
    A = rot.as_matrix()
    A.setflags(write=False)
    return A


#: The packaged pool of emulated bench calibrations of the default tracker
#: (``tools/calibrate_camera_bench.py``).
BENCH_POOL_FILE = "navigation/camera_bench.json"


@functools.lru_cache(maxsize=1)
def _bench_pool() -> dict[str, Any] | None:
    try:
        return json.loads(packaged_path(BENCH_POOL_FILE).read_text())
    except DataFileError:
        return None


def bench_calibration(camera: Camera, seed: int, run: int = 0) -> CameraCalibration | None:
    """How run ``run`` of a scenario of ``seed`` knows ``camera`` (the truth) from the bench.

    One emulated bench of the packaged pool (:data:`BENCH_POOL_FILE`: seeded benches with their
    screen, mount, collimator and camera departures drawn from the stated tolerances, each
    calibrated by :func:`starnav.calibration.intrinsics.calibrate_camera`) is picked by the
    run's own random stream; the knowledge is ``camera`` plus that bench's realised estimation
    error, with that bench's stated covariance. None when the pool was not made for ``camera``
    (its :func:`camera_fingerprint`) or is not installed."""
    pool = _bench_pool()
    if pool is None or pool.get("camera_fingerprint") != camera_fingerprint(camera):
        return None
    benches = pool["benches"]
    b = benches[int(generator(int(seed), STAGE_CAMERA_CALIBRATION, int(run)).integers(
        len(benches)))]
    names = tuple(pool["parameters"])
    values = parameter_values(camera, names) + np.asarray(b["error"], float)
    return CameraCalibration(
        camera=with_parameters(camera, dict(zip(names, values, strict=True))),
        parameters=names, covariance=np.asarray(b["covariance"], float),
        provenance={"method": "emulated bench (pool)", "bench_seed": b["seed"],
                    "tool": pool.get("tool", "")})
