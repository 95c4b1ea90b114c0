"""The star field of a frame: which stars, where on the detector, how many electrons.

1. Query: the catalogue's cone about the true boresight, moved to apparent directions when
   ``aberration`` is on (:mod:`starnav.stars.aberration`).
2. Project with the true attitude through the pinhole (``pinhole_px``) and the distortion
   (``pixel_px``).
3. Occult by the body: the renderer's hit mask when a rendered image is given, else the
   reference sphere.
4. Electrons through the scenario's sensor response and the camera's pupil
   (:func:`~starnav.stars.radiometry.electron_rates`), times the exposure.

:func:`frame_stars` returns a :class:`StarField` (the truth for solvers and tests);
:meth:`StarField.point_sources` is what :func:`starnav.detector.expose` takes.

Index
-----
:func:`frame_stars`, :class:`StarField`, :func:`field_radius`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.camera import Camera
from starnav.detector import DetectorConfig, PointSources
from starnav.geometry import FrameGeometry
from starnav.radiance import RadianceImage
from starnav.spectra import SensorResponse
from starnav.stars.aberration import ABERRATION_MARGIN, apparent_directions
from starnav.stars.aberration import observer_velocity as observer_velocity_of
from starnav.stars.catalogue import StarCatalogue, hipparcos, jyear_from_tdb
from starnav.stars.radiometry import electron_rates
from starnav.stars.schema import StarsConfig
from starnav.typing import FloatArray


@dataclass(frozen=True)
class StarField:
    """The stars of one frame (arrays of equal length, brightest first).

    Attributes
    ----------
    hip : (n,) int array
        Hipparcos numbers.
    v, b_v : (n,) arrays
        Johnson V and B - V [mag].
    direction_inertial, direction_camera : (n, 3) arrays
        Unit vectors, inertial (ICRS) at the epoch and in the camera frame (true attitude):
        apparent directions when aberration is on, else the catalogue places.
    pinhole_px, pixel_px : (n, 2) arrays
        ``(u, v)`` in the undistorted pinhole image, and on the detector (distortion included
        when the chain applies it: where the PSF centroid lands) [px].
    rate, electrons : (n,) arrays
        Photo-electrons per second through the on-axis pupil [e-/s], and of the exposure
        before the PSF [e-].
    occulted, in_frame : (n,) bool arrays
        Behind the body; ``pixel_px`` inside the detector.
    epoch_jyear, exposure_time : float
        [Julian year], [s].
    observer_velocity_m_s : tuple of 3 floats
        The barycentric velocity of the aberration, ICRF axes [m/s] (zeros: catalogue places).
    """

    hip: NDArray[np.int64]
    v: FloatArray
    b_v: FloatArray
    direction_inertial: FloatArray
    direction_camera: FloatArray
    pinhole_px: FloatArray
    pixel_px: FloatArray
    rate: FloatArray
    electrons: FloatArray
    occulted: NDArray[np.bool_]
    in_frame: NDArray[np.bool_]
    epoch_jyear: float
    exposure_time: float
    observer_velocity_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __len__(self) -> int:
        return int(self.hip.size)

    def subset(self, keep: NDArray[np.bool_]) -> StarField:
        """The stars where ``keep`` is true."""
        vals = {f.name: getattr(self, f.name) for f in fields(self)}
        return StarField(**{k: (v[keep] if isinstance(v, np.ndarray) else v)
                            for k, v in vals.items()})

    def visible(self) -> StarField:
        """Stars on the detector and not behind the body: the frame's true star list."""
        return self.subset(self.in_frame & ~self.occulted)

    def point_sources(self) -> PointSources:
        """What the detector chain draws: every star not occulted, margin included."""
        keep = ~self.occulted
        return PointSources(self.pinhole_px[keep, 0], self.pinhole_px[keep, 1], self.rate[keep])


def field_radius(camera: Camera, margin_px: float) -> float:
    """Half-angle [rad] of the cone holding the whole detector plus ``margin_px``."""
    corners = np.array([[-0.5 - margin_px, -0.5 - margin_px],
                        [camera.width - 0.5 + margin_px, -0.5 - margin_px],
                        [-0.5 - margin_px, camera.height - 0.5 + margin_px],
                        [camera.width - 0.5 + margin_px, camera.height - 0.5 + margin_px]])
    rays = camera.unproject(corners, undistort=camera.has_distortion)
    return float(np.max(np.arccos(np.clip(rays[:, 2], -1.0, 1.0))))


def _occulted(dirs_cam: FloatArray, pinhole: FloatArray, geom: FrameGeometry,
              radiance: RadianceImage | None) -> NDArray[np.bool_]:
    if isinstance(radiance, RadianceImage) and "mask" in radiance.aovs:
        mask = radiance.aovs["mask"] > 0.5
        H, W = mask.shape
        iu = np.floor(pinhole[:, 0] + 0.5).astype(np.int64)
        iv = np.floor(pinhole[:, 1] + 0.5).astype(np.int64)
        inside = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
        out = np.zeros(len(iu), bool)
        out[inside] = mask[iv[inside], iu[inside]]
        return out
    centre = geom.moon_centre_camera()
    d = float(np.linalg.norm(centre))
    cos_limb = math.sqrt(max(0.0, 1.0 - (geom.body_radius / d) ** 2))
    return dirs_cam @ (centre / d) > cos_limb


def frame_stars(geom: FrameGeometry, camera: Camera, config: StarsConfig,
                response: SensorResponse, *, exposure_time: float,
                detector: DetectorConfig | None = None, radiance: RadianceImage | None = None,
                catalogue: StarCatalogue | None = None,
                observer_velocity: ArrayLike | None = None) -> StarField:
    """The star field of one frame (module steps 1-4).

    Parameters
    ----------
    geom : FrameGeometry
        True attitude and epoch (``epoch_tdb``) of the frame.
    camera : Camera
    config : StarsConfig
        Magnitude limit, margin, epoch override, ``aberration`` (``enabled`` is not read
        here).
    response : SensorResponse
        The sensor's QE x T (the Moon's).
    exposure_time : float
        [s].
    detector : DetectorConfig, optional
        Whether the chain distorts and applies relative illumination (default AA-STR chain).
    radiance : RadianceImage, optional
        The rendered frame: its ``mask`` AOV occults stars; else the reference sphere.
    catalogue : StarCatalogue, optional
        Default: :func:`~starnav.stars.catalogue.hipparcos`.
    observer_velocity : (3,) array, optional
        Barycentric velocity [m/s] of the camera, ICRF axes, when ``config.aberration``;
        default :func:`~starnav.stars.aberration.observer_velocity` of ``geom`` (DE421).
    """
    det = detector if detector is not None else DetectorConfig()
    cat = catalogue if catalogue is not None else hipparcos()
    epoch = (config.epoch_jyear if config.epoch_jyear is not None
             else jyear_from_tdb(geom.epoch_tdb))
    R = geom.R_cam_to_inertial
    vel = np.zeros(3)
    if config.aberration:
        vel = (observer_velocity_of(geom) if observer_velocity is None
               else np.asarray(observer_velocity, float))
    radius = field_radius(camera, config.margin_px) + (ABERRATION_MARGIN if config.aberration
                                                       else 0.0)
    sel = cat.cone(R[:, 2], radius, epoch, config.magnitude_limit)
    dirs = apparent_directions(sel.directions, vel) if config.aberration else sel.directions
    dcam = dirs @ R  # rows: R^T d
    front = dcam[:, 2] > 1e-6
    dcam, keep_ix = dcam[front], np.nonzero(front)[0]
    pin = camera.project(dcam, distort=False) if dcam.size else np.zeros((0, 2))
    distorts = det.optics.distortion.enabled and camera.has_distortion
    pix = camera.project(dcam, distort=True) if (distorts and dcam.size) else pin.copy()
    m = config.margin_px
    near = ((pin[:, 0] >= -0.5 - m) & (pin[:, 0] < camera.width - 0.5 + m)
            & (pin[:, 1] >= -0.5 - m) & (pin[:, 1] < camera.height - 0.5 + m))
    dcam, pin, pix, keep_ix = dcam[near], pin[near], pix[near], keep_ix[near]
    rate = (electron_rates(sel.v[keep_ix], sel.b_v[keep_ix], response, camera.pupil_area)
            if keep_ix.size else np.zeros(0))
    el = rate * exposure_time
    if det.optics.radiometry.relative_illumination and keep_ix.size:
        el = el * dcam[:, 2]  # cos(theta) of the pupil
    in_frame = ((pix[:, 0] >= -0.5) & (pix[:, 0] < camera.width - 0.5)
                & (pix[:, 1] >= -0.5) & (pix[:, 1] < camera.height - 0.5))
    occ = _occulted(dcam, pin, geom, radiance) if keep_ix.size else np.zeros(0, bool)
    return StarField(hip=sel.hip[keep_ix], v=sel.v[keep_ix], b_v=sel.b_v[keep_ix],
                     direction_inertial=dirs[keep_ix], direction_camera=dcam,
                     pinhole_px=pin, pixel_px=pix, rate=rate, electrons=el, occulted=occ,
                     in_frame=in_frame, epoch_jyear=float(epoch),
                     exposure_time=float(exposure_time),
                     observer_velocity_m_s=tuple(float(x) for x in vel))
