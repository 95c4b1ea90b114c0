"""The target model the renderer draws: shape, photometric model, albedo and colour of a body.

A :class:`~starnav.bodies.base.TargetBody` makes its :class:`TargetModel`
(:meth:`~starnav.bodies.base.TargetBody.render_model`); the renderer draws it as it is.

Index
-----
:class:`TargetModel`, :class:`AlbedoMap`, :func:`load_albedo_map`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.bodies.mesh import BodyMesh
from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError, not_a_file_error
from starnav.photometry import get_model
from starnav.spectra import Spectrum


# ---------------------------------------------------------------------------- albedo maps
@dataclass(frozen=True)
class AlbedoMap:
    """Equirectangular single-channel albedo: row 0 at latitude +90 deg, column 0 at
    longitude -180 deg, pixel-area convention (cell edges at the borders) [-]."""

    values: NDArray[np.float32]
    source: str = "array"

    def sample(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bilinear value at selenographic ``lat``, ``lon`` [rad] (longitude wraps)."""
        h, w = self.values.shape
        x = (np.mod(lon + math.pi, 2 * math.pi) / (2 * math.pi)) * w - 0.5
        y = np.clip((math.pi / 2 - lat) / math.pi * h - 0.5, 0, h - 1)
        x0 = np.floor(x).astype(int)
        y0 = np.clip(np.floor(y).astype(int), 0, h - 1)
        fx, fy = x - x0, y - y0
        x0m, x1m = np.mod(x0, w), np.mod(x0 + 1, w)
        y1 = np.clip(y0 + 1, 0, h - 1)
        v = self.values
        return ((1 - fy) * ((1 - fx) * v[y0, x0m] + fx * v[y0, x1m])
                + fy * ((1 - fx) * v[y1, x0m] + fx * v[y1, x1m]))


def load_albedo_map(path: str | Path, scale: float = 1.0) -> AlbedoMap:
    """Read a single-channel albedo map: ``.npy`` (float reflectance), 8/16-bit PNG/TIFF
    (linear, full scale = 1) or float TIFF/EXR; multiplied by ``scale``.

    For the NASA SVS Moon-kit colour maps (gamma-encoded) use :mod:`starnav.dem`'s readers.
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, "moon.albedo.path")
    if p.suffix.lower() == ".npy":
        arr = np.load(p)
    else:
        import imageio.v3 as iio

        arr = iio.imread(p)
        if np.issubdtype(arr.dtype, np.integer):
            arr = arr.astype(np.float64) / np.iinfo(arr.dtype).max
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim == 3:
        if arr.shape[2] != 1:
            raise ConfigError("moon.albedo.path", str(p),
                              f"a single-channel map, got {arr.shape[2]} channels")
        arr = arr[:, :, 0]
    if arr.ndim != 2 or min(arr.shape) < 2:
        raise ConfigError("moon.albedo.path", str(p), "a 2-D map of at least 2 x 2 pixels")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError("moon.albedo.path", str(p), "finite, non-negative albedo values")
    return AlbedoMap((arr * scale).astype(np.float32), str(p))


# ---------------------------------------------------------------------------- the target model
@dataclass
class TargetModel:
    """What the renderer needs to know about the target body.

    Parameters
    ----------
    shape : {"sphere", "mesh"}
        Exact sphere of ``radius``, or a triangle mesh (``mesh`` or ``mesh_provider``).
    radius : float
        Reference radius [m].
    model : str
        Photometric model name (:data:`starnav.photometry.PHOTOMETRIC_MODELS`).
    params : dict
        Model parameters (defaults filled in and checked).
    albedo : float or AlbedoMap
        The **model's own** albedo parameter (constant or a map), as
        :func:`starnav.photometry.model_albedo_parameter` derives it from the normal albedo.
    albedo_scale : float
        Global multiplier of the reflectance: radiance is exactly proportional to it.
    spectral_shape : Spectrum, optional
        Reflectance factor versus wavelength (1 at the normal albedo's reference wavelength);
        ``None`` is grey.
    mesh : BodyMesh, optional
        Fixed body-fixed mesh (e.g. an icosphere).
    mesh_provider : callable, optional
        ``f(camera, geometry) -> BodyMesh`` for view-adapted meshes (DEMs).
    max_height : float
        Highest terrain above ``radius`` [m] (bounds the crop window).
    body_fixed_aovs : bool
        Add each pixel-centre ray's body-fixed surface point to the AOVs
        (:data:`starnav.radiance.BODY_FIXED_AOV_CHANNELS`, metres): the feature truth of
        shape-model bodies.
    """

    shape: str = "sphere"
    radius: float = MOON_RADIUS
    model: str = "lambert"
    params: dict[str, float] = field(default_factory=dict)
    albedo: float | AlbedoMap = 0.12
    albedo_scale: float = 1.0
    mesh: BodyMesh | None = None
    mesh_provider: Any = None
    max_height: float = 0.0
    spectral_shape: Spectrum | None = None
    calibrated: bool = False
    body_fixed_aovs: bool = False

    def __post_init__(self) -> None:
        if self.shape not in ("sphere", "mesh"):
            raise ConfigError("moon.shape", self.shape, "'sphere' or 'mesh'")
        self.params = get_model(self.model).check_params(self.params)
        if isinstance(self.albedo, int | float):
            if not (math.isfinite(self.albedo) and self.albedo >= 0):
                raise ConfigError("moon.albedo", self.albedo, "a finite albedo >= 0")
        if not (math.isfinite(self.albedo_scale) and self.albedo_scale > 0):
            raise ConfigError("moon.albedo_scale", self.albedo_scale, "a finite factor > 0")
        if self.shape == "mesh" and self.mesh is None and self.mesh_provider is None:
            raise ConfigError("moon.shape", "mesh", "a mesh or a mesh provider")

    def albedo_key(self) -> Any:
        spec = None if self.spectral_shape is None else id(self.spectral_shape)
        if isinstance(self.albedo, AlbedoMap):
            return ("map", id(self.albedo), self.albedo_scale, spec)
        return ("const", float(self.albedo), self.albedo_scale, spec)
