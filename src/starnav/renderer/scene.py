"""Mitsuba scene pieces for a Moon frame: the Moon (exact sphere or triangle mesh), the Sun,
the sensor and its spectral film.

Scene units are **kilometres** (Moon-centred, inertial axes); radiance does not depend on the
length unit. The camera follows starnav's convention (+z boresight, +x right, +y down); Mitsuba's
sensor looks along its local +z with +x to the *left* of the image and +y up, so the sensor's
``to_world`` is the camera attitude times ``diag(-1, -1, 1)`` (a 180 deg turn about z).

Only this subpackage imports Mitsuba and Dr.Jit.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from starnav.camera import Camera
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.spectra import SensorResponse, Spectrum, product

log = logging.getLogger(__name__)

KM = 1e3
#: Mitsuba sensor frame relative to starnav's camera frame.
MITSUBA_FROM_CAMERA = np.diag([-1.0, -1.0, 1.0])


@dataclass(frozen=True)
class MoonMesh:
    """A triangle mesh of the Moon in **body-fixed** coordinates [m].

    Attributes
    ----------
    vertices : (n, 3) float
        Vertex positions [m].
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    normals : (n, 3) float
        Unit vertex normals.
    albedo : (n,) float or None
        Per-vertex albedo (model's meaning), or ``None`` to use the scenario's albedo.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    normals: NDArray[np.float64]
    albedo: NDArray[np.float64] | None = None
    key: object = None

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    @classmethod
    def from_trimesh(cls, tm, albedo: NDArray[np.float64] | None = None,
                     key: object = None) -> MoonMesh:
        """From a ``trimesh.Trimesh`` in body-fixed metres (its vertex normals are used;
        ``vertex_attributes['albedo']`` is used when ``albedo`` is not given). ``key``
        identifies the mesh for the renderer's scene cache (the same key: the same mesh)."""
        if albedo is None:
            albedo = tm.vertex_attributes.get("albedo") if hasattr(tm, "vertex_attributes") \
                else None
        return cls(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64),
                   np.asarray(tm.vertex_normals, float),
                   None if albedo is None else np.asarray(albedo, float), key)


@lru_cache(maxsize=4)
def _icosphere(subdivisions: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    import trimesh

    tm = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64)


def icosphere_mesh(radius: float, subdivisions: int) -> MoonMesh:
    """A geodesic sphere of ``20 * 4**subdivisions`` triangles with vertices on the sphere of
    ``radius`` [m] and exact radial normals."""
    v, f = _icosphere(int(subdivisions))
    return MoonMesh(v * radius, f, v.copy(), None)


def to_world_matrix(geom: FrameGeometry) -> NDArray[np.float64]:
    """4 x 4 camera-to-world transform for Mitsuba's sensor (scene units: km)."""
    M = np.eye(4)
    M[:3, :3] = geom.R_cam_to_inertial @ MITSUBA_FROM_CAMERA
    M[:3, 3] = geom.camera_position / KM
    return M


def sensor_fov_deg(camera: Camera) -> float:
    """Mitsuba ``fov`` along x [deg] for the pinhole with a centred principal point."""
    return math.degrees(2.0 * math.atan(camera.width / (2.0 * camera.fx)))


def principal_point_offsets(camera: Camera) -> tuple[float, float]:
    """Mitsuba ``principal_point_offset_x/y`` (fractions of the film size).

    Mitsuba shifts the image centre by ``offset * film size`` in film coordinates, with +x to
    the image right and +y down once the sensor frame is turned as in :data:`MITSUBA_FROM_CAMERA`.
    """
    return ((camera.cx - (camera.width - 1) / 2.0) / camera.width,
            (camera.cy - (camera.height - 1) / 2.0) / camera.height)


def check_camera_for_render(camera: Camera) -> None:
    """The renderer's pinhole needs square pixels (distortion is applied by the detector)."""
    if abs(camera.pitch_x - camera.pitch_y) > 1e-12 * camera.pitch_x:
        raise ConfigError("camera.pixel_pitch", (camera.pitch_x, camera.pitch_y),
                          "square pixels for rendering")


def regular_spectrum_dict(sp: Spectrum, step_nm: float = 1.0) -> dict:
    """Mitsuba ``regular`` spectrum sampling ``sp`` on a uniform grid over its own support.

    A regular grid is looked up in O(1) inside the kernels, where an ``irregular`` one needs a
    binary search per wavelength: on a full-field frame this halves the render time. The grid
    spans exactly ``[first, last]`` wavelength of ``sp`` (so a box channel stays a box), with
    intervals of at most ``step_nm``. Steps of ``sp`` that fall on grid nodes (the AA-STR's
    50 nm bands on a 1 nm grid) keep their integral exactly (the trapezoid of a node at the mid
    value); steps between nodes are smeared over one interval.
    """
    lo, hi = float(sp.wavelengths[0]), float(sp.wavelengths[-1])
    n = max(1, math.ceil((hi - lo) / step_nm - 1e-9))
    grid = np.linspace(lo, hi, n + 1)
    return {
        "type": "regular",
        "wavelength_min": lo,
        "wavelength_max": hi,
        "values": ",".join(f"{x:.9g}" for x in sp(grid)),
    }


@dataclass(frozen=True)
class FilmChannels:
    """Film responses handed to ``specfilm`` and the factors that undo their normalisation.

    Each channel's response is divided by its maximum so that both channels weigh alike in
    the film's wavelength sampling; ``scale`` multiplies the film output back.
    """

    L: Spectrum
    Le: Spectrum
    scale_L: float
    scale_Le: float


def film_channels(response: SensorResponse) -> FilmChannels:
    """Responses of the ``L`` (unit box over the band) and ``Le`` (QE T lambda / hc) channels."""
    box = response.box()
    epj = response.electrons_per_joule()
    k = float(np.max(epj.values))
    return FilmChannels(box, epj.scaled(1.0 / k), 1.0, k)


def sun_irradiance_in_band(sun: Spectrum, response: SensorResponse, margin_nm: float = 2.0
                           ) -> Spectrum:
    """The solar spectrum restricted to the sensor band (plus a margin) for the emitter."""
    lo, hi = response.band
    box = Spectrum(np.array([lo - margin_nm, hi + margin_nm]), np.ones(2))
    return product(sun, box)
