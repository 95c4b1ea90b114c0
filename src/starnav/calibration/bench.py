"""Emulated hardware-in-the-loop bench: screen -> collimator -> camera -> detector.

The bench model in full: docs/calibration.md, "2. Emulated acquisition".

Technique
---------
1. Geometry (:class:`BenchGeometry`): screen pixel -> misaligned screen point -> collimated
   beam (tangent, collimator distortion) -> camera pixel; the inverse by Newton iterations.
2. Radiance at the camera (:meth:`Bench.radiance_at_camera`): radiance is conserved through
   the collimator; each screen pixel's footprint is splatted with its exact box overlap
   (:func:`splat`), flux conserving, on the camera's pinhole grid (the radiance before the
   camera's optics, as a render).
3. Collimator spot and the defocus of a tilted screen, varying over the field, by input-side
   blending of Gaussians (:func:`field_varying_blur`): flux and centroid conserved.
4. Detector: the scenario's chain (:class:`ChainDetector`) or a noise-free one
   (:class:`IdealDetector`); each applies the camera's distortion once.
5. Check (:func:`check_bench`): eq. 2 with the stated and the derived field, plus the actual
   detector coverage.

References
----------
Seed paper, "Hardware-in-the-loop testing preparation", and its refs. 7 and 18 (the TinyV3RSE
facility).

Index
-----
:class:`Bench`, :class:`Acquisition`, :class:`BenchGeometry`, :func:`as_built_camera`,
:func:`splat`, :func:`field_varying_blur`, :class:`DetectorStage`, :class:`ChainDetector`,
:class:`IdealDetector`, :class:`DetectorFrame`, :func:`check_bench`, :class:`BenchCheck`,
:func:`angle_between`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from scipy.interpolate import RectBivariateSpline

from starnav.calibration.collimator import (
    SpotModel,
    StimulatorCondition,
    distort_tangent,
    stimulator_condition,
    vignetting,
)
from starnav.calibration.schema import BenchConfig
from starnav.calibration.screen import ScreenRadiometry
from starnav.camera import Camera
from starnav.config import build_camera
from starnav.detector import DetectorConfig, expose
from starnav.detector.optics import distort
from starnav.errors import ConfigError
from starnav.spectra import SensorResponse, sensor_response_from_config
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Newton iterations and tolerance [screen px] of the camera-pixel -> screen-pixel inverse.
INVERSE_MAX_ITER = 20
INVERSE_TOL_PX = 1e-7
#: Nodes per axis of the coarse camera grid on which the inverse map is solved exactly.
INVERSE_GRID_NODES = 33
#: Screen-grid step of the sampled forward map (Jacobians, dense stimuli) [screen px].
FORWARD_GRID_STEP_PX = 8
#: Up to this many lit screen pixels the forward map is evaluated exactly.
EXACT_FORWARD_MAX = 200_000


# =========================================================================== rotations
def _rx(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rz(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# =========================================================================== geometry
@dataclass(frozen=True)
class BenchGeometry:
    """Where each screen pixel appears to the camera (SI inside).

    Attributes
    ----------
    camera : Camera
    focal_length, pitch : float
        Collimator focal length; screen pixel pitch [m].
    shape : (rows, cols)
        Screen size [px].
    k1, k2 : float
        Collimator distortion [-].
    shift : (2,) array
        Screen in-plane shift [m].
    defocus : float
        Screen distance from the focal plane, + towards the lens [m].
    R_screen, R_cam : (3, 3) arrays
        Screen roll and tilt (screen plane -> collimator frame); collimator -> camera frame.
    focal_length_design, k1_design : float, optional
        The collimator's design focal length [m] and distortion [-] when the as-built ones
        above differ (:meth:`nominal`, :meth:`design`).
    """

    camera: Camera
    focal_length: float
    pitch: float
    shape: tuple[int, int]
    k1: float = 0.0
    k2: float = 0.0
    shift: FloatArray = field(default_factory=lambda: np.zeros(2))
    defocus: float = 0.0
    R_screen: FloatArray = field(default_factory=lambda: np.eye(3))
    R_cam: FloatArray = field(default_factory=lambda: np.eye(3))
    focal_length_design: float | None = None
    k1_design: float | None = None

    @classmethod
    def from_config(cls, cfg: BenchConfig, camera: Camera) -> BenchGeometry:
        m = cfg.misalignment
        r = math.radians
        R_screen = _ry(r(m.screen_tilt_deg[1])) @ _rx(r(m.screen_tilt_deg[0])) \
            @ _rz(r(m.screen_roll_deg))
        R_cam = _rz(r(m.camera_roll_deg)) @ _ry(r(m.camera_tilt_deg[1])) \
            @ _rx(r(m.camera_tilt_deg[0]))
        f_design = cfg.collimator.focal_length_mm * 1e-3
        return cls(camera, f_design * (1.0 + m.collimator_focal_length_error),
                   cfg.screen.pitch_mm * 1e-3, (cfg.screen.height_px, cfg.screen.width_px),
                   cfg.collimator.distortion_k1 + m.collimator_k1_error,
                   cfg.collimator.distortion_k2, np.asarray(m.screen_shift_mm, float) * 1e-3,
                   m.screen_defocus_mm * 1e-3, R_screen, R_cam, f_design,
                   cfg.collimator.distortion_k1)

    def nominal(self) -> BenchGeometry:
        """The same bench as designed, without distortion: the design focal length, no
        misalignment."""
        f = self.focal_length if self.focal_length_design is None else self.focal_length_design
        return BenchGeometry(self.camera, f, self.pitch, self.shape)

    def design(self) -> BenchGeometry:
        """The bench as designed, with the collimator's design distortion: what a calibration
        may assume."""
        k1 = self.k1 if self.k1_design is None else self.k1_design
        return replace(self.nominal(), k1=k1, k2=self.k2)

    # ............................................................ screen coordinates
    @property
    def centre(self) -> tuple[float, float]:
        """Screen centre ``(c_j, c_i)`` [screen px]."""
        return ((self.shape[1] - 1) / 2.0, (self.shape[0] - 1) / 2.0)

    def screen_to_nominal_tangent(self, ji: ArrayLike) -> FloatArray:
        """Screen pixels ``(..., 2)`` as (column, row) -> nominal tangent ``(a, b) / f`` [-]."""
        ji = np.asarray(ji, float)
        cj, ci = self.centre
        s = self.pitch / self.focal_length
        return np.stack([(ji[..., 0] - cj) * s, (ji[..., 1] - ci) * s], -1)

    def nominal_tangent_to_screen(self, st: ArrayLike) -> FloatArray:
        """Inverse of :meth:`screen_to_nominal_tangent` [screen px]."""
        st = np.asarray(st, float)
        cj, ci = self.centre
        s = self.focal_length / self.pitch
        return np.stack([st[..., 0] * s + cj, st[..., 1] * s + ci], -1)

    def screen_points(self, ji: ArrayLike) -> FloatArray:
        """3-D position ``(..., 3)`` of screen pixels in the collimator frame [m]."""
        ji = np.asarray(ji, float)
        cj, ci = self.centre
        a = (ji[..., 0] - cj) * self.pitch
        b = (ji[..., 1] - ci) * self.pitch
        R = self.R_screen
        x = R[0, 0] * a + R[0, 1] * b + self.shift[0]
        y = R[1, 0] * a + R[1, 1] * b + self.shift[1]
        z = R[2, 0] * a + R[2, 1] * b + self.defocus
        return np.stack([x, y, z], -1)

    def beam_tangent(self, ji: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Beam direction tangent ``(..., 2)`` in the collimator frame, distorted, and the
        axial offset ``z`` [m] of the screen point (for the defocus blur)."""
        P = self.screen_points(ji)
        denom = self.focal_length - P[..., 2]
        t = P[..., :2] / denom[..., None]
        if self.k1 != 0.0 or self.k2 != 0.0:
            t = distort_tangent(t, self.k1, self.k2)
        return t, P[..., 2]

    def screen_to_los(self, ji: ArrayLike) -> FloatArray:
        """Unit line of sight ``(..., 3)`` in the camera frame of screen pixels."""
        t, _ = self.beam_tangent(ji)
        v = np.concatenate([t, np.ones(t.shape[:-1] + (1,))], -1)
        v = v @ self.R_cam.T
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def screen_to_pixel(self, ji: ArrayLike, distort: bool = True) -> FloatArray:
        """Detector pixel ``(..., 2)`` where screen pixels appear, through the camera's own
        distortion; with ``distort=False`` the pinhole pixel (where the radiance reaching the
        camera is drawn, before the camera's optics)."""
        return self.camera.project(self.screen_to_los(ji), distort=distort)

    def pixel_to_screen(self, uv: ArrayLike, distort: bool = True) -> FloatArray:
        """Screen pixel ``(..., 2)`` seen at detector pixels ``uv`` (pinhole pixels with
        ``distort=False``) (Newton inverse of :meth:`screen_to_pixel`; converges to
        :data:`INVERSE_TOL_PX`)."""
        uv = np.asarray(uv, float)
        xy = self.camera.pixel_to_normalized(uv, undistort=distort)
        v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1) @ self.R_cam  # -> collimator
        t = v[..., :2] / v[..., 2:3]
        r2 = (t * t).sum(-1)
        t = t / (1.0 + r2 * (self.k1 + self.k2 * r2))[..., None]
        ji = self.nominal_tangent_to_screen(t)
        h = 0.5
        for _ in range(INVERSE_MAX_ITER):
            f0 = self.screen_to_pixel(ji, distort) - uv
            fj = self.screen_to_pixel(ji + np.array([h, 0.0]), distort) - uv
            fi = self.screen_to_pixel(ji + np.array([0.0, h]), distort) - uv
            J = np.stack([(fj - f0) / h, (fi - f0) / h], -1)  # (..., 2 uv, 2 ji)
            step = np.linalg.solve(J, f0[..., None])[..., 0]
            ji = ji - step
            if np.max(np.abs(step), initial=0.0) < INVERSE_TOL_PX:
                break
        return ji

    def screen_pixel_scale(self) -> float:
        """Size of one screen pixel on the detector near the axis [camera px]."""
        return self.pitch / self.focal_length * self.camera.fx


# =========================================================================== splatting
def splat(values: ArrayLike, uv: ArrayLike, width: ArrayLike, shape: tuple[int, int],
          jac: ArrayLike | None = None, area: ArrayLike | None = None) -> FloatArray:
    """Deposit rectangular footprints on a pixel grid with their exact box overlap.

    Parameters
    ----------
    values : (N,) array
        Radiance of each element (any unit).
    uv : (N, 2) array
        Footprint centres on the pixel grid [px]; pixel ``(0, 0)`` covers [-0.5, 0.5]^2.
    width : (N,) or (N, 2) array
        Footprint side, or sides along u and v [px].
    shape : (rows, cols)
    jac : (N, 2, 2) array, optional
        ``d(u, v) / d(j, i)`` per element, used to subdivide elements wider than a pixel.
    area : (N,) array, optional
        Footprint area [px^2] (default ``width_u width_v``); the overlap fractions are those of
        the rectangle, the deposited flux is ``value x area``.

    Returns
    -------
    (rows, cols) array
        ``sum value x overlap area`` [value x px^2] (= pixel-averaged radiance for radiance
        values): the area integral of the piecewise-constant screen over each pixel.
        The flux is conserved exactly (less what falls off the grid); first moments are those
        of the pixelated image (a single sub-pixel element is moved to its pixel's centre, a
        source wider than a pixel keeps its centroid to < 0.01 px).
    """
    val = np.asarray(values, float).ravel()
    uv = np.asarray(uv, float).reshape(-1, 2)
    w = np.asarray(width, float)
    w = np.repeat(w.reshape(-1, 1), 2, axis=1) if w.ndim <= 1 else w.reshape(-1, 2)
    ar = w[:, 0] * w[:, 1] if area is None else np.asarray(area, float).ravel()
    H, W = shape
    out = np.zeros(H * W)
    if val.size == 0:
        return out.reshape(H, W)
    n_sub = int(math.ceil(float(w.max()) - 1e-9))
    if n_sub > 1:
        if jac is None:
            raise ConfigError("splat.jac", None, "the Jacobian to subdivide footprints > 1 px")
        J = np.asarray(jac, float).reshape(-1, 2, 2)
        offs = (np.arange(n_sub) + 0.5) / n_sub - 0.5
        for dj in offs:
            for di in offs:
                c = uv + J @ np.array([dj, di])
                out += splat(val, c, w / n_sub, shape, area=ar / (n_sub * n_sub)).ravel()
        return out.reshape(H, W)
    parts = []
    for axis in (0, 1):
        x = uv[:, axis]
        wa = w[:, axis]
        left = x - 0.5 * wa
        k0 = np.floor(left + 0.5)
        ov0 = np.minimum(x + 0.5 * wa, k0 + 0.5) - left
        f0 = np.where(wa > 0, ov0 / np.where(wa > 0, wa, 1.0), 1.0)
        parts.append((k0.astype(np.int64), f0))
    (ku, fu), (kv, fv) = parts
    for du, wu in ((0, fu), (1, 1.0 - fu)):
        for dv, wv in ((0, fv), (1, 1.0 - fv)):
            cu = ku + du
            cv = kv + dv
            wt = val * ar * wu * wv
            ok = (cu >= 0) & (cu < W) & (cv >= 0) & (cv < H) & (wt != 0)
            out += np.bincount(cv[ok] * W + cu[ok], weights=wt[ok], minlength=H * W)
    return out.reshape(H, W)


# =========================================================================== blur
def field_varying_blur(image: ArrayLike, sigma_map: ArrayLike, levels: int) -> FloatArray:
    """Convolve with a Gaussian whose sigma [px] varies per *source* pixel (input-side
    blending over ``levels`` widths; flux and each source's centroid are conserved)."""
    img = np.asarray(image, float)
    sig = np.asarray(sigma_map, float)
    nz = np.nonzero(img)
    if nz[0].size == 0:
        return img.copy()
    margin = int(math.ceil(4.0 * float(sig.max()))) + 2
    r0 = max(int(nz[0].min()) - margin, 0)
    r1 = min(int(nz[0].max()) + margin + 1, img.shape[0])
    c0 = max(int(nz[1].min()) - margin, 0)
    c1 = min(int(nz[1].max()) + margin + 1, img.shape[1])
    sub = img[r0:r1, c0:c1]
    ssub = sig[r0:r1, c0:c1]
    lit = sub != 0
    smin, smax = float(ssub[lit].min()), float(ssub[lit].max())
    out = np.zeros_like(img)
    if levels <= 1 or smax - smin < 1e-3:
        s = 0.5 * (smin + smax)
        out[r0:r1, c0:c1] = ndimage.gaussian_filter(sub, s, mode="constant") if s > 0 else sub
        return out
    sl = np.linspace(smin, smax, levels)
    pos = np.clip((ssub - smin) / (smax - smin) * (levels - 1), 0, levels - 1)
    k = np.minimum(np.floor(pos).astype(int), levels - 2)
    frac = pos - k
    acc = np.zeros_like(sub)
    for lvl in range(levels):
        wgt = np.where(k == lvl, 1.0 - frac, 0.0) + np.where(k == lvl - 1, frac, 0.0)
        part = sub * wgt
        if not np.any(part):
            continue
        acc += ndimage.gaussian_filter(part, sl[lvl], mode="constant") if sl[lvl] > 0 else part
    out[r0:r1, c0:c1] = acc
    return out


# =========================================================================== detector stages
@dataclass
class DetectorFrame:
    """What a detector stage returns.

    Attributes
    ----------
    dn : (H, W) float array
        Digital numbers, offset included [DN].
    electrons : (H, W) float array
        Collected charge [e-].
    exposure : Any
        The detector's own result object (e.g. :class:`starnav.detector.Exposure`), if any.
    """

    dn: FloatArray
    electrons: FloatArray
    exposure: Any = None


class DetectorStage(Protocol):
    """Turns a pinhole electron-radiance image into DN (the pluggable end of the bench)."""

    camera: Camera
    full_well_e: float
    gain_e_per_dn: float
    offset_dn: float

    def expose(self, le: FloatArray, exposure_time: float, frame_index: int) -> DetectorFrame:
        """``le`` [e- s^-1 m^-2 sr^-1], ``exposure_time`` [s] -> frame."""
        ...


class ChainDetector:
    """The scenario's detector chain (:func:`starnav.detector.expose`).

    Parameters
    ----------
    camera : Camera
    config : DetectorConfig, optional
        Chain settings (default: AA-STR).
    seed : int
        Dataset seed of the chain (fixed pattern and temporal noise streams).
    readout_policy : {"ignore", "warn", "enforce"} or None
        Override of the readout-law policy: bench calibration frames are analysis frames (the
        DN frame is always kept), so the bench workflows pass ``"ignore"``; ``None`` keeps the
        configured policy.
    """

    def __init__(self, camera: Camera, config: DetectorConfig | None = None, seed: int = 0,
                 readout_policy: str | None = "ignore") -> None:
        cfg = config if config is not None else DetectorConfig()
        if readout_policy is not None and cfg.readout.timing.policy != readout_policy:
            d = cfg.model_dump()
            d["readout"]["timing"]["policy"] = readout_policy
            cfg = DetectorConfig.model_validate(d)
        self.camera = camera
        self.config = cfg
        self.seed = int(seed)
        self.full_well_e = float(cfg.saturation.full_well_e)
        self.gain_e_per_dn = float(cfg.gain_e_per_dn)
        self.offset_dn = float(cfg.adc.offset_dn)
        self.max_dn = float(2**cfg.adc.bits - 1)

    def expose(self, le: FloatArray, exposure_time: float, frame_index: int) -> DetectorFrame:
        ex = expose(np.asarray(le, np.float32), self.camera, self.config, seed=self.seed,
                    frame_index=int(frame_index), exposure_time=float(exposure_time))
        return DetectorFrame(ex.dn.astype(float), ex.electrons.astype(float), ex)


class IdealDetector:
    """Mean photo-electrons ``t A Omega Le [cos^4]`` resampled through the camera's
    distortion (as the chain does) and ``DN = e- / gain``: no PSF, noise, saturation, offset or
    quantisation (for noise-free checks of the bench itself)."""

    def __init__(self, camera: Camera, full_well_e: float = 1e5, gain_e_per_dn: float = 1.0,
                 relative_illumination: bool = True) -> None:
        self.camera = camera
        self.full_well_e = float(full_well_e)
        self.gain_e_per_dn = float(gain_e_per_dn)
        self.offset_dn = 0.0
        self.max_dn = math.inf
        self._ri = None
        if relative_illumination:
            u, v = camera.pixel_grid()
            self._ri = camera.relative_illumination(u, v)

    def expose(self, le: FloatArray, exposure_time: float, frame_index: int) -> DetectorFrame:
        e = np.asarray(le, float) * exposure_time * self.camera.etendue
        if self._ri is not None:
            e = e * self._ri
        if self.camera.has_distortion:
            e = distort(e.astype(np.float32), self.camera).astype(float)
        return DetectorFrame(e / self.gain_e_per_dn, e)


# =========================================================================== acquisition
@dataclass
class Acquisition:
    """One emulated acquisition.

    Attributes
    ----------
    le : (H, W) array
        Electron radiance reaching the camera, pinhole grid, after the collimator spot
        [e- s^-1 m^-2 sr^-1].
    dn : (H, W) array
        Detector output [DN].
    electrons : (H, W) array
        Collected charge [e-].
    exposure_time : float
        [s].
    frame_index : int
    """

    le: FloatArray
    dn: FloatArray
    electrons: FloatArray
    exposure_time: float
    frame_index: int


def as_built_camera(config: BenchConfig) -> Camera:
    """The scenario's camera with the bench's as-built departures (``misalignment.camera_*``):
    the camera the emulated bench really has, which a calibration must estimate."""
    cam = build_camera(config.scenario.camera)
    m = config.misalignment
    dx, dy = m.camera_principal_point_offset_px
    return replace(cam, focal_length=cam.focal_length * (1.0 + m.camera_focal_length_error),
                   cx=cam.cx + dx, cy=cam.cy + dy, k1=cam.k1 + m.camera_k1_error)


class Bench:
    """An emulated bench: its geometry, screen radiometry, collimator and camera.

    Parameters
    ----------
    config : BenchConfig
    camera : Camera, optional
        Default: the camera of ``config.scenario`` as built (:func:`as_built_camera`).
    response : SensorResponse, optional
        Default: the sensor response of ``config.scenario``.
    """

    def __init__(self, config: BenchConfig, camera: Camera | None = None,
                 response: SensorResponse | None = None) -> None:
        self.config = config
        self.camera = camera if camera is not None else as_built_camera(config)
        self.response = (response if response is not None
                         else sensor_response_from_config(config.scenario.sensor_response))
        self.geometry = BenchGeometry.from_config(config, self.camera)
        self.spot = SpotModel.from_config(config.collimator)

    # ............................................................ basics
    @property
    def screen_shape(self) -> tuple[int, int]:
        """(rows, cols) of the screen."""
        return self.geometry.shape

    @cached_property
    def radiometry(self) -> ScreenRadiometry:
        """Counts <-> radiance at the camera (raises if the screen has no emittance data)."""
        return ScreenRadiometry.from_config(self.config.screen, self.config.collimator,
                                            self.response)

    def chain_detector(self, readout_policy: str | None = "ignore") -> ChainDetector:
        """The scenario's detector chain with the bench seed."""
        return ChainDetector(self.camera, self.config.scenario.detector, self.config.seed,
                             readout_policy)

    # ............................................................ inverse map on the detector
    @cached_property
    def _inverse_splines(self) -> tuple[RectBivariateSpline, RectBivariateSpline]:
        cam = self.camera
        n = INVERSE_GRID_NODES
        us = np.linspace(-0.5, cam.width - 0.5, max(4, min(n, cam.width + 1)))
        vs = np.linspace(-0.5, cam.height - 0.5, max(4, min(n, cam.height + 1)))
        U, V = np.meshgrid(us, vs)
        ji = self.geometry.pixel_to_screen(np.stack([U, V], -1), distort=False)
        return (RectBivariateSpline(vs, us, ji[..., 0], kx=3, ky=3),
                RectBivariateSpline(vs, us, ji[..., 1], kx=3, ky=3))

    def screen_coordinates_of_pixels(self) -> FloatArray:
        """Screen point ``(H, W, 2)`` (column, row) seen at each camera pixel centre (pinhole)
        [screen px] (exact on a coarse grid, bicubic in between)."""
        sj, si = self._inverse_splines
        rows = np.arange(self.camera.height, dtype=float)
        cols = np.arange(self.camera.width, dtype=float)
        return np.stack([sj(rows, cols), si(rows, cols)], -1)

    @cached_property
    def stimulated_mask(self) -> NDArray[np.bool_]:
        """Pinhole-grid pixels whose centre sees the screen ``(H, W)``."""
        ji = self.screen_coordinates_of_pixels()
        H, W = self.screen_shape
        return ((ji[..., 0] >= -0.5) & (ji[..., 0] <= W - 0.5)
                & (ji[..., 1] >= -0.5) & (ji[..., 1] <= H - 0.5))

    @cached_property
    def sigma_map(self) -> FloatArray:
        """Per-axis sigma of the collimator spot + screen defocus at each pinhole-grid pixel
        [camera px]."""
        cam = self.camera
        u, v = cam.pixel_grid()
        xy = cam.pixel_to_normalized(np.stack([u, v], -1), undistort=False)   # pinhole grid
        los = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
        b = los @ self.geometry.R_cam
        theta = np.arctan2(np.hypot(b[..., 0], b[..., 1]), b[..., 2])
        s_spot = self.spot.sigma_at(theta)
        ji = self.screen_coordinates_of_pixels()
        z = self.geometry.screen_points(ji)[..., 2]
        f = self.geometry.focal_length
        s_def = cam.pupil_diameter * np.abs(z) / (f * f) / 4.0
        return np.hypot(s_spot, s_def) / cam.ifov

    # ............................................................ the screen region in view
    @cached_property
    def screen_window(self) -> tuple[int, int, int, int]:
        """Screen box ``(j0, i0, j1, i1)`` (exclusive ends) that can reach the detector (the
        field plus a margin for the spot's spill)."""
        ji = self.screen_coordinates_of_pixels()
        H, W = self.screen_shape
        pad = 32
        j0 = int(max(math.floor(ji[..., 0].min()) - pad, 0))
        j1 = int(min(math.ceil(ji[..., 0].max()) + pad + 1, W))
        i0 = int(max(math.floor(ji[..., 1].min()) - pad, 0))
        i1 = int(min(math.ceil(ji[..., 1].max()) + pad + 1, H))
        return j0, i0, max(j1, j0), max(i1, i0)

    @cached_property
    def _forward_grid(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Exact forward map on a coarse grid over the screen window:
        ``(js, is, uv[ni, nj, 2], J[ni, nj, 2, 2])`` with ``J = d(u, v)/d(j, i)``."""
        j0, i0, j1, i1 = self.screen_window
        step = FORWARD_GRID_STEP_PX
        js = np.arange(j0 - step, j1 + 2 * step, step, dtype=float)
        is_ = np.arange(i0 - step, i1 + 2 * step, step, dtype=float)
        J_, I_ = np.meshgrid(js, is_)
        uv = self.geometry.screen_to_pixel(np.stack([J_, I_], -1), distort=False)
        du_di, du_dj = np.gradient(uv[..., 0], step)
        dv_di, dv_dj = np.gradient(uv[..., 1], step)
        J = np.stack([np.stack([du_dj, du_di], -1), np.stack([dv_dj, dv_di], -1)], -2)
        return js, is_, uv, J

    def _forward(self, ji: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Pinhole position ``(N, 2)`` and Jacobian ``(N, 2, 2)`` of screen pixels ``(N, 2)``.

        Exact positions for up to :data:`EXACT_FORWARD_MAX` pixels, else bilinear interpolation
        of the exact map sampled every :data:`FORWARD_GRID_STEP_PX` screen px (error < 1e-4 px
        for the default bench); the Jacobian is always interpolated."""
        js, is_, uvg, Jg = self._forward_grid
        cj = (ji[:, 0] - js[0]) / (js[1] - js[0])
        ci = (ji[:, 1] - is_[0]) / (is_[1] - is_[0])

        def interp(grid: FloatArray) -> FloatArray:
            return ndimage.map_coordinates(grid, [ci, cj], order=1, mode="nearest")

        if len(ji) <= EXACT_FORWARD_MAX:
            uv = self.geometry.screen_to_pixel(ji, distort=False)
        else:
            uv = np.stack([interp(uvg[..., 0]), interp(uvg[..., 1])], -1)
        J = np.empty((len(ji), 2, 2))
        for a in range(2):
            for b in range(2):
                J[:, a, b] = interp(Jg[..., a, b])
        return uv, J

    # ............................................................ radiance at the camera
    def screen_electron_radiance(self, counts: ArrayLike) -> FloatArray:
        """Electron radiance at the camera of each screen pixel, grey ``(rows, cols)`` or RGB
        ``(rows, cols, 3)`` counts [e- s^-1 m^-2 sr^-1].

        Raises
        ------
        ConfigError
            Wrong shape, counts out of ``[0, max_count]``, no emittance data.
        """
        c = np.asarray(counts)
        H, W = self.screen_shape
        if c.shape[:2] != (H, W) or c.ndim not in (2, 3) or (c.ndim == 3 and c.shape[2] != 3):
            raise ConfigError("screen counts", f"shape {c.shape}",
                              f"({H}, {W}) grey or ({H}, {W}, 3) RGB counts (screen rows, cols)")
        rad = self.radiometry
        return rad.electron_radiance_rgb(c) if c.ndim == 3 else rad.electron_radiance(c)

    def radiance_at_camera(self, counts: ArrayLike) -> FloatArray:
        """Pinhole electron-radiance image ``(H, W)`` the camera receives from a screen image
        [e- s^-1 m^-2 sr^-1] (geometry, collimator transmission, vignetting, spot): the
        camera's own distortion is not in it, the detector stage applies it (once)."""
        le_s = self.screen_electron_radiance(counts)
        rad = self.radiometry
        out = self.screen_to_camera(le_s - rad.le_min)
        if rad.le_min > 0:
            out += rad.le_min * self.stimulated_mask
        if self.config.acquisition.include_spot_psf:
            out = field_varying_blur(out, self.sigma_map, self.config.acquisition.psf_levels)
        return np.maximum(out, 0.0)

    def screen_to_camera(self, le_screen: ArrayLike) -> FloatArray:
        """Pinhole image ``(H, W)`` of a screen electron-radiance image ``(rows, cols)`` given
        at the camera (the screen pixels' geometry and the collimator's vignetting; no spot
        blur, no black level) [e- s^-1 m^-2 sr^-1]. Linear in ``le_screen``; only its positive
        pixels are drawn."""
        cam = self.camera
        le_screen = np.asarray(le_screen, float)
        if le_screen.shape != self.screen_shape:
            raise ConfigError("screen radiance image", f"shape {le_screen.shape}",
                              f"the screen's {self.screen_shape} (rows, cols)")
        j0, i0, j1, i1 = self.screen_window
        sub = le_screen[i0:i1, j0:j1]
        ii, jj = np.nonzero(sub > 0)
        vals = sub[ii, jj]
        ji = np.stack([jj + j0, ii + i0], -1).astype(float)
        out = np.zeros((cam.height, cam.width))
        if vals.size:
            uv, J = self._forward(ji)
            area = np.abs(J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0])
            # axis-aligned rectangles with the element spacing along u and v: they tile the
            # image exactly for a sheared lattice, to O(rotation^2) for a rotated one
            width = np.stack([np.abs(J[:, 0, 0]), np.abs(J[:, 1, 1])], -1)
            if self.config.collimator.clear_aperture_mm is not None:
                t, _ = self.geometry.beam_tangent(ji)
                vals = vals * vignetting(self.config.collimator, cam.pupil_diameter,
                                         np.hypot(t[:, 0], t[:, 1]))
            out = splat(vals, uv, width, (cam.height, cam.width), J, area)
        return out

    def acquire(self, counts: ArrayLike, exposure_time: float, detector: DetectorStage,
                frame_index: int = 0) -> Acquisition:
        """Display ``counts`` and acquire them with ``detector`` for ``exposure_time`` [s]."""
        if not (math.isfinite(exposure_time) and exposure_time > 0):
            raise ConfigError("exposure_time_s", exposure_time, "a finite exposure > 0 s")
        le = self.radiance_at_camera(counts)
        fr = detector.expose(le, exposure_time, frame_index)
        return Acquisition(le, fr.dn, fr.electrons, float(exposure_time), int(frame_index))


# =========================================================================== check
@dataclass
class BenchCheck:
    """Does the bench stimulate the whole field, and how well.

    Attributes
    ----------
    conditions : list of StimulatorCondition
        Eq. 2 with the stated FoV (if configured) and the derived vertical and horizontal FoV.
    stimulated_fraction : float
        Share of detector pixels whose centre sees the screen (full bench model) [-].
    unstimulated_rows : dict
        Width of the unstimulated band along each detector edge, over its middle half
        (``top``, ``bottom`` in rows, ``left``, ``right`` in columns) [px].
    edge_margin_mm : dict
        Smallest distance from the screen edge to where each detector edge lands on the screen
        (negative: outside the screen) [mm].
    screen_pixel_camera_px : float
        One screen pixel on the detector [camera px] (< 1: the screen is not resolved).
    spot_rms_px : dict
        Collimator spot RMS radius at the centre, the edge middle and the corner [camera px].
    corner_vignetting : float
        Share of the pupil filled at the field corner [-].
    fills_field : bool
        Every detector pixel is stimulated (full model).
    verdict : str
    """

    conditions: list[StimulatorCondition]
    stimulated_fraction: float
    unstimulated_rows: dict[str, int]
    edge_margin_mm: dict[str, float]
    screen_pixel_camera_px: float
    spot_rms_px: dict[str, float]
    corner_vignetting: float
    fills_field: bool
    verdict: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "conditions": [c.to_dict() | {"sentence": c.sentence()} for c in self.conditions],
            "stimulated_fraction": self.stimulated_fraction,
            "unstimulated_rows": self.unstimulated_rows,
            "edge_margin_mm": self.edge_margin_mm,
            "screen_pixel_camera_px": self.screen_pixel_camera_px,
            "spot_rms_px": self.spot_rms_px,
            "corner_vignetting": self.corner_vignetting,
            "fills_field": self.fills_field,
            "verdict": self.verdict,
        }

    def raise_if_unfit(self, focal_length_mm: float) -> None:
        """Raise :class:`ConfigError` when the collimator cannot fill the field."""
        if self.fills_field:
            return
        derived = [c for c in self.conditions if c.fov_source.startswith("derived")]
        fmax = min(c.max_focal_length_mm for c in derived) if derived else float("nan")
        raise ConfigError("collimator.focal_length_mm", focal_length_mm,
                          f"<= {fmax:.1f} mm so that the screen fills the camera's field "
                          f"(eq. 2 with the derived FoV); {self.verdict}")


def check_bench(bench: Bench) -> BenchCheck:
    """Optical-stimulator condition (eq. 2) with the stated and derived FoV, and the coverage of
    the detector by the screen with the full bench model (distortion, misalignments)."""
    cfg = bench.config
    cam = bench.camera
    sc = cfg.screen
    f_mm = cfg.collimator.focal_length_mm
    conds: list[StimulatorCondition] = []
    if cfg.check.stated_camera_fov_deg is not None:
        conds.append(stimulator_condition(cfg.check.stated_camera_fov_deg, sc.height_mm, f_mm,
                                          "stated by the paper, vs screen height"))
    conds.append(stimulator_condition(math.degrees(cam.fov_y), sc.height_mm, f_mm,
                                      "derived, vertical, vs screen height"))
    conds.append(stimulator_condition(math.degrees(cam.fov_x), sc.width_mm, f_mm,
                                      "derived, horizontal, vs screen width"))
    mask = bench.stimulated_mask
    frac = float(mask.mean())
    H, W = mask.shape
    off = ~mask

    # depth of the unstimulated band at each edge, over the middle half of that edge (the
    # corners are in the stimulated fraction)

    def depth(a: NDArray[np.bool_]) -> int:
        mid = a[:, a.shape[1] // 4: max(3 * a.shape[1] // 4, a.shape[1] // 4 + 1)]
        lead = np.where(mid.all(axis=0), mid.shape[0], np.argmin(mid, axis=0))
        return int(lead.max()) if lead.size else 0

    unst = {"top": depth(off), "bottom": depth(off[::-1]), "left": depth(off.T),
            "right": depth(off.T[::-1])}
    # where each detector edge lands on the screen
    n = 65
    s = np.linspace(-0.5, W - 0.5, n)
    t = np.linspace(-0.5, H - 0.5, n)
    edges = {"top": np.stack([s, np.full(n, -0.5)], -1),
             "bottom": np.stack([s, np.full(n, H - 0.5)], -1),
             "left": np.stack([np.full(n, -0.5), t], -1),
             "right": np.stack([np.full(n, W - 0.5), t], -1)}
    Hs, Ws = bench.screen_shape
    p = sc.pitch_mm
    margin = {}
    for name, uv in edges.items():
        ji = bench.geometry.pixel_to_screen(uv)
        if name == "top":
            m = (ji[:, 1] + 0.5).min()
        elif name == "bottom":
            m = (Hs - 0.5 - ji[:, 1]).min()
        elif name == "left":
            m = (ji[:, 0] + 0.5).min()
        else:
            m = (Ws - 0.5 - ji[:, 0]).min()
        margin[name] = float(m * p)
    corner = math.atan(math.hypot(W * cam.pitch_x, H * cam.pitch_y) / 2 / cam.focal_length)
    edge = math.atan(H * cam.pitch_y / 2 / cam.focal_length)
    to_px = 1.0 / cam.ifov
    spot = {"centre": float(bench.spot.rms_radius_at(0.0) * to_px),
            "edge": float(bench.spot.rms_radius_at(edge) * to_px),
            "corner": float(bench.spot.rms_radius_at(corner) * to_px)}
    vig = float(vignetting(cfg.collimator, cam.pupil_diameter, math.tan(corner)))
    fills = bool(mask.all())
    scale = bench.geometry.screen_pixel_scale()
    if fills:
        verdict = (f"the screen fills the whole {W} x {H} detector (smallest edge margin "
                   f"{min(margin.values()):.2f} mm on the screen)")
    else:
        verdict = (f"the screen does NOT fill the field: {100 * (1 - frac):.2f} % of the "
                   f"detector is not stimulated (bands of {unst['top']}/{unst['bottom']} rows "
                   f"at the top/bottom, {unst['left']}/{unst['right']} columns at the "
                   "left/right)")
    if scale >= 1.0:
        verdict += (f"; screen pixels are {scale:.2f} camera px wide: the camera resolves the "
                    "screen's pixel grid")
    if vig < 0.999:
        verdict += f"; the collimator vignettes the field corner to {100 * vig:.1f} %"
    log.info("bench check: %s", verdict)
    return BenchCheck(conds, frac, unst, margin, scale, spot, vig, fills, verdict)


def angle_between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Angle between unit vectors ``(..., 3)`` [rad] (atan2 form, accurate at small angles)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1))


__all__ = ["Acquisition", "Bench", "BenchCheck", "BenchGeometry", "ChainDetector",
           "DetectorFrame", "DetectorStage", "IdealDetector", "angle_between",
           "as_built_camera", "check_bench", "field_varying_blur", "splat"]
