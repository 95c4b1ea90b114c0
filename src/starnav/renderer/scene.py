"""Mitsuba scene pieces for a Moon frame: the Moon (exact sphere or triangle mesh), the Sun,
the sensor and its spectral film.

Scene units are kilometres (Moon-centred, inertial axes). The camera's convention (+z
boresight, +x right, +y down) becomes Mitsuba's sensor by ``diag(-1, -1, 1)``
(:func:`to_world_matrix`). At long range the float32 intersection of the JIT variants needs the
near clip plane just in front of the Moon (:func:`clip_planes`): why, and what it leaves,
in docs/methods.md, "starnav.renderer.scene". Only this subpackage imports Mitsuba and Dr.Jit.

Index
-----
:func:`to_world_matrix`, :func:`clip_planes`,
:func:`sensor_fov_deg`, :func:`principal_point_offsets`, :func:`check_camera_for_render`,
:func:`regular_spectrum_dict`, :func:`film_channels`, :class:`FilmChannels`,
:func:`flat_irradiance_in_band`, :func:`sun_irradiance_in_band`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

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
#: Nearest near clip plane [km]: used when the Moon is close to (or around) the camera.
NEAR_CLIP_MIN_KM = 1e-3
#: Default far clip plane [km] (Mitsuba's own default is 1e4 scene units).
FAR_CLIP_KM = 1e9
#: Gap left between the near clip plane and the Moon's bounding sphere [bounding radii].
NEAR_CLIP_MARGIN = 0.05


def to_world_matrix(geom: FrameGeometry) -> NDArray[np.float64]:
    """4 x 4 camera-to-world transform for Mitsuba's sensor (scene units: km)."""
    M = np.eye(4)
    M[:3, :3] = geom.R_cam_to_inertial @ MITSUBA_FROM_CAMERA
    M[:3, 3] = geom.camera_position / KM
    return M


def clip_planes(moon_centre_camera: NDArray[np.float64], bounding_radius: float
                ) -> tuple[float, float]:
    """Near and far clip distances [km] for a Moon inside a sphere of ``bounding_radius`` [m]
    centred at ``moon_centre_camera`` [m] (camera frame, +z the boresight).

    Mitsuba's perspective sensor starts the rays on the near plane, so the near plane is put
    within one bounding radius ``R_b`` in front of the Moon (module docstring: float32 hit points
    from a far ray origin shadow themselves). Every point of the bounding sphere has
    ``z >= c_z - R_b``; the near plane is the largest multiple of ``R_b`` at or below
    ``c_z - (1 + NEAR_CLIP_MARGIN) R_b`` (a grid, so that the value, a literal in the compiled
    kernels, changes only when the range changes by about a radius), and never less than
    :data:`NEAR_CLIP_MIN_KM`. The far plane is :data:`FAR_CLIP_KM` or, for a sphere reaching
    beyond half of it, the power of two just above four times the sphere's farthest ``z``.
    """
    r_b = bounding_radius / KM
    z_c = float(moon_centre_camera[2]) / KM
    near = NEAR_CLIP_MIN_KM
    if r_b > 0.0:
        near = max(near, r_b * math.floor((z_c - (1.0 + NEAR_CLIP_MARGIN) * r_b) / r_b))
    z_max = z_c + r_b
    far = FAR_CLIP_KM if 2.0 * z_max < FAR_CLIP_KM else 2.0 ** math.ceil(math.log2(4.0 * z_max))
    return float(near), float(far)


def sensor_fov_deg(camera: Camera) -> float:
    """Mitsuba ``fov`` along x [deg] for the pinhole with a centred principal point."""
    return math.degrees(2.0 * math.atan(camera.width / (2.0 * camera.fx)))


def principal_point_offsets(camera: Camera) -> tuple[float, float]:
    """Mitsuba ``principal_point_offset_x/y`` [fractions of the film width and height].

    Mitsuba 3's ``perspective`` sensor (``sample_ray`` in ``src/sensors/perspective.cpp``)
    traces, for the film position ``s`` (in [0, 1] across the film), the ray of the centred
    pinhole at ``s + offset``: the image content moves by ``-offset * film size``, so the
    optical axis lands on film position ``0.5 - offset``. Film columns and rows run along
    starnav's +u and +v once the sensor is turned as in :data:`MITSUBA_FROM_CAMERA`, and pixel
    ``u`` covers film coordinates ``[u, u + 1]`` [px], so the axis at ``(cx, cy)`` needs::

        offset_x = -(cx - (W - 1) / 2) / W,    offset_y = -(cy - (H - 1) / 2) / H

    (measured: the opposite sign moved the rendered disc by twice the offset, mirrored).
    """
    return (-(camera.cx - (camera.width - 1) / 2.0) / camera.width,
            -(camera.cy - (camera.height - 1) / 2.0) / camera.height)


#: Most samples one render pass traces: Mitsuba traces a frame's width x height x spp samples
#: as one wavefront, and a Dr.Jit array holds at most 2^32 entries.
MAX_WAVEFRONT = 1 << 32


def check_camera_for_render(camera: Camera, spp: int | None = None) -> None:
    """The renderer's pinhole needs square pixels (distortion is applied by the detector);
    with ``spp``, the frame's samples must fit one wavefront (:data:`MAX_WAVEFRONT`)."""
    if abs(camera.pitch_x - camera.pitch_y) > 1e-12 * camera.pitch_x:
        raise ConfigError("camera.pixel_pitch", (camera.pitch_x, camera.pitch_y),
                          "square pixels for rendering")
    if spp is not None and camera.width * camera.height * spp > MAX_WAVEFRONT:
        most = MAX_WAVEFRONT // (camera.width * camera.height)
        raise ConfigError("render.spp", spp, f"at most {most} samples per pixel on a "
                          f"{camera.width} x {camera.height} px frame ({spp} would trace "
                          f"{camera.width * camera.height * spp:.3g} samples in one pass; a "
                          f"pass holds at most 2^32 = {MAX_WAVEFRONT:.3g})")


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


def film_channels(response: SensorResponse, colour: Spectrum | None = None) -> FilmChannels:
    """The film's ``L`` and ``Le`` responses and the factors that scale its output back.

    Without ``colour``: ``L`` is the unit box over the band and ``Le`` is ``QE T lambda / hc``;
    the emitter carries the solar spectrum, so each sample's weight carries its structure.

    With ``colour`` (Sun irradiance times the surface's spectral shape, for a separable
    surface as every plugin of :mod:`.bsdfs`): ``Le(x) = r(x) int colour QE T lambda / hc``
    and ``L(x) = kappa Le(x)``, ``kappa = int colour box / int colour QE T lambda / hc``. Both
    channels carry the electron response times ``colour`` and ``L``'s scale carries
    ``kappa``: the wavelengths are drawn by the integrand's spectrum and every sample has the
    same spectral weight. The emitter is flat (:func:`flat_irradiance_in_band`) and the BSDF
    drops its spectral shape.
    """
    box = response.box()
    epj = response.electrons_per_joule()
    if colour is None:
        k = float(np.max(epj.values))
        return FilmChannels(box, epj.scaled(1.0 / k), 1.0, k)
    weighted = product(epj, colour)
    k = float(np.max(weighted.values))
    kappa = product(box, colour).integral() / weighted.integral()
    channel = weighted.scaled(1.0 / k)
    return FilmChannels(channel, channel, k * kappa, k)


def flat_irradiance_in_band(response: SensorResponse, margin_nm: float = 2.0) -> Spectrum:
    """A unit irradiance over the sensor band (plus a margin): the emitter when the film's
    responses carry the solar spectrum (:func:`film_channels` with ``colour``)."""
    lo, hi = response.band
    return Spectrum(np.array([lo - margin_nm, hi + margin_nm]), np.ones(2))


def sun_irradiance_in_band(sun: Spectrum, response: SensorResponse, margin_nm: float = 2.0
                           ) -> Spectrum:
    """The solar spectrum restricted to the sensor band (plus a margin) for the emitter."""
    return product(sun, flat_irradiance_in_band(response, margin_nm))
