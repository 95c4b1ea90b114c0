"""Pinhole camera with Brown-Conrady distortion, and its analytic Jacobians.

Conventions
-----------
* Camera frame: +z along the boresight, +x to the right (increasing column ``u``), +y down
  (increasing row ``v``).
* Pixel ``(u, v) = (0, 0)`` is the *centre* of the top-left pixel (OpenCV convention), so the
  detector spans ``u`` in ``[-0.5, width - 0.5]``.
* Normalised image coordinates ``x = X / Z``, ``y = Y / Z``; distortion acts on them
  (Brown 1966; Conrady 1919; the OpenCV parametrisation ``k1, k2, k3, p1, p2``)::

      r2 = x^2 + y^2
      x_d = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
      y_d = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y
      u = fx x_d + cx,   v = fy y_d + cy

  with ``fx = f / pitch_x`` and ``fy = f / pitch_y`` in pixels.

Units: metres for the focal length and pitch, pixels for ``u, v, fx, fy, cx, cy``, radians for
angles, steradians for solid angles.

The field of view is always *derived* from the focal length and the detector size (the AA-STR
paper's "FoV 10 deg" is the half-angle or an error; docs/facts.md section 1).

Example
-------
>>> from starnav.camera import Camera
>>> cam = Camera.preset("aa-str")
>>> round(float(cam.fov_x_deg), 2)
20.6
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Annotated, Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field

from starnav.config_base import StrictModel
from starnav.errors import ConfigError, GeometryError, UnknownNameError
from starnav.fields import PositiveCount, PositiveFloat
from starnav.typing import FloatArray

#: Iterations and tolerance [normalised units] of the fixed-point undistortion.
UNDISTORT_MAX_ITER = 50
UNDISTORT_TOL = 1e-14


def _undistort_step(x, y, xd, yd, k1, k2, k3, p1, p2):  # type: ignore[no-untyped-def]
    """One Newton step of :meth:`Camera.undistort` at ``(x, y)`` towards the distorted
    ``(xd, yd)`` (floats or arrays alike): the new ``(x, y)`` and the step ``(sx, sy)``.
    :meth:`Camera.distort` and its 2 x 2 Jacobian together, the step by Cramer's rule."""
    xx, yy, xy2 = x * x, y * y, 2.0 * x * y
    r2 = xx + yy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dr = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
    rx = x * radial + p1 * xy2 + p2 * (r2 + 2.0 * xx) - xd
    ry = y * radial + p1 * (r2 + 2.0 * yy) + p2 * xy2 - yd
    a = radial + xx * dr + 2.0 * p1 * y + 6.0 * p2 * x
    b = 0.5 * xy2 * dr + 2.0 * p1 * x + 2.0 * p2 * y
    d = radial + yy * dr + 6.0 * p1 * y + 2.0 * p2 * x
    det = a * d - b * b
    sx = (d * rx - b * ry) / det
    sy = (a * ry - b * rx) / det
    return x - sx, y - sy, sx, sy


#: Largest lens distortion accepted, as a fraction of a detector corner's distance from the
#: principal point: beyond it the Brown-Conrady polynomial no longer describes a real lens
#: (its inverse, used to place the stars and the limb, stops converging).
MAX_CORNER_DISTORTION = 0.5


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with Brown-Conrady distortion.

    Parameters
    ----------
    width, height : int
        Detector size [pixels].
    focal_length : float
        Effective focal length [m].
    pitch_x, pitch_y : float
        Pixel pitch [m].
    f_number : float
        Working f-number N (entrance pupil diameter ``D = f / N``) [-].
    cx, cy : float, optional
        Principal point [pixels]; default the detector centre ``((W - 1)/2, (H - 1)/2)``.
    k1, k2, k3, p1, p2 : float
        Brown-Conrady radial and tangential coefficients [-], on normalised coordinates.
    name : str
        Free label.
    """

    width: int
    height: int
    focal_length: float
    pitch_x: float
    pitch_y: float
    f_number: float
    cx: float | None = None
    cy: float | None = None
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = "custom"

    def __post_init__(self) -> None:
        checks: list[tuple[str, float, bool, str]] = [
            ("camera.width", self.width, int(self.width) == self.width and self.width >= 1,
             "a positive integer number of pixels"),
            ("camera.height", self.height, int(self.height) == self.height and self.height >= 1,
             "a positive integer number of pixels"),
            ("camera.focal_length", self.focal_length,
             math.isfinite(self.focal_length) and self.focal_length > 0,
             "a finite focal length > 0 m"),
            ("camera.pitch_x", self.pitch_x, math.isfinite(self.pitch_x) and self.pitch_x > 0,
             "a finite pixel pitch > 0 m"),
            ("camera.pitch_y", self.pitch_y, math.isfinite(self.pitch_y) and self.pitch_y > 0,
             "a finite pixel pitch > 0 m"),
            ("camera.f_number", self.f_number, math.isfinite(self.f_number) and self.f_number > 0,
             "a finite f-number > 0"),
        ]
        for field, value, ok, expected in checks:
            if not ok:
                raise ConfigError(field, value, expected)
        if self.cx is None:
            object.__setattr__(self, "cx", (self.width - 1) / 2.0)
        if self.cy is None:
            object.__setattr__(self, "cy", (self.height - 1) / 2.0)
        cx, cy = float(self.cx), float(self.cy)  # type: ignore[arg-type]
        if not (-0.5 <= cx <= self.width - 0.5 and -0.5 <= cy <= self.height - 0.5):
            raise ConfigError("camera.principal_point_px", (cx, cy), "a point on the detector: "
                              f"u in -0.5..{self.width - 0.5}, v in -0.5..{self.height - 0.5} px "
                              "(where the optical axis meets it)")
        shift = self.corner_distortion()
        if not (math.isfinite(shift) and shift <= MAX_CORNER_DISTORTION):
            raise ConfigError("camera.distortion", (self.k1, self.k2, self.k3, self.p1, self.p2),
                              "Brown-Conrady coefficients that move the detector corner by at "
                              f"most {MAX_CORNER_DISTORTION:.0%} of its distance from the "
                              f"principal point (these: {shift:.3g} times it; a star tracker's "
                              "lens stays well under 1 %)")

    def corner_distortion(self) -> float:
        """The Brown-Conrady displacement at the detector corner farthest from the principal
        point, as a fraction of that corner's distance from it: ``|k1 r^2 + k2 r^4 + k3 r^6|
        + 2 (|p1| + |p2|) r`` (an upper bound of the tangential term), ``r`` the corner's
        normalized radius [-]."""
        fx = self.focal_length / self.pitch_x
        fy = self.focal_length / self.pitch_y
        x = max(abs(-0.5 - float(self.cx)), abs(self.width - 0.5 - float(self.cx))) / fx
        y = max(abs(-0.5 - float(self.cy)), abs(self.height - 0.5 - float(self.cy))) / fy
        r2 = x * x + y * y
        radial = abs(self.k1 * r2 + self.k2 * r2**2 + self.k3 * r2**3)
        return radial + 2.0 * (abs(self.p1) + abs(self.p2)) * math.sqrt(r2)

    # ------------------------------------------------------------------ presets
    @classmethod
    def preset(cls, name: str, **overrides: Any) -> Camera:
        """A named camera; ``overrides`` replace any field.

        Known presets: ``aa-str`` (Leonardo AA-STR MK II with the HAS2 detector:
        f = 50.7 mm, 1024 x 1024 pixels of 18 um, N = 1.495575; docs/facts.md section 1).
        """
        try:
            base = CAMERA_PRESETS[name]
        except KeyError:
            raise UnknownNameError("camera preset", name, list(CAMERA_PRESETS)) from None
        if not overrides:
            return base
        # the principal point follows the detector size unless it is given explicitly
        overrides.setdefault("cx", None if "width" in overrides else base.cx)
        overrides.setdefault("cy", None if "height" in overrides else base.cy)
        return replace(base, **overrides)

    # ------------------------------------------------------------- properties
    @property
    def fx(self) -> float:
        """Focal length in pixels along x [px]."""
        return self.focal_length / self.pitch_x

    @property
    def fy(self) -> float:
        """Focal length in pixels along y [px]."""
        return self.focal_length / self.pitch_y

    @property
    def K(self) -> FloatArray:
        """Intrinsic matrix (3 x 3) [px]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(c != 0.0 for c in (self.k1, self.k2, self.k3, self.p1, self.p2))

    @property
    def fov_x(self) -> float:
        """Full horizontal field of view of the pinhole [rad] (principal point centred)."""
        return 2.0 * math.atan(self.width * self.pitch_x / (2.0 * self.focal_length))

    @property
    def fov_y(self) -> float:
        """Full vertical field of view of the pinhole [rad]."""
        return 2.0 * math.atan(self.height * self.pitch_y / (2.0 * self.focal_length))

    @property
    def fov_diagonal(self) -> float:
        """Full diagonal field of view of the pinhole [rad]."""
        half = math.hypot(self.width * self.pitch_x, self.height * self.pitch_y) / 2.0
        return 2.0 * math.atan(half / self.focal_length)

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(self.fov_x)

    @property
    def ifov(self) -> float:
        """Instantaneous field of view of one pixel on the axis, ``pitch_x / f`` [rad]."""
        return self.pitch_x / self.focal_length

    @property
    def pixel_solid_angle(self) -> float:
        """Solid angle of the on-axis pixel, ``pitch_x pitch_y / f^2`` [sr]."""
        return self.pitch_x * self.pitch_y / self.focal_length**2

    @property
    def pupil_diameter(self) -> float:
        """Entrance pupil diameter ``f / N`` [m]."""
        return self.focal_length / self.f_number

    @property
    def pupil_area(self) -> float:
        """Entrance pupil area [m^2]."""
        return math.pi * self.pupil_diameter**2 / 4.0

    @property
    def etendue(self) -> float:
        """On-axis pixel etendue ``A_pupil * Omega_pix = pi p^2 / (4 N^2)`` [m^2 sr]."""
        return self.pupil_area * self.pixel_solid_angle

    def relative_illumination(self, u: ArrayLike, v: ArrayLike) -> FloatArray:
        """Natural vignetting ``cos^4(theta)`` of pixel ``(u, v)`` for the pinhole [-].

        The flux a pixel collects from a scene of radiance ``L`` is
        ``L * etendue * cos^4(theta)``: the pixel's solid angle shrinks as ``cos^3`` and the
        pupil's projected area as ``cos``.
        """
        x = (np.asarray(u, float) - self.cx) / self.fx
        y = (np.asarray(v, float) - self.cy) / self.fy
        cos2 = 1.0 / (1.0 + x * x + y * y)
        return cos2 * cos2

    # ------------------------------------------------------------ distortion
    def distort(self, xy: ArrayLike) -> FloatArray:
        """Apply Brown-Conrady distortion to normalised coordinates ``(..., 2)`` [-]."""
        xy = np.asarray(xy, dtype=float)
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def distortion_jacobian(self, xy: ArrayLike) -> FloatArray:
        """Jacobian ``d(x_d, y_d) / d(x, y)`` of :meth:`distort`, shape ``(..., 2, 2)``."""
        xy = np.asarray(xy, dtype=float)
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial_dr2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)
        J = np.empty(xy.shape[:-1] + (2, 2))
        J[..., 0, 0] = radial + 2 * x * x * dradial_dr2 + 2 * self.p1 * y + 6 * self.p2 * x
        J[..., 0, 1] = 2 * x * y * dradial_dr2 + 2 * self.p1 * x + 2 * self.p2 * y
        J[..., 1, 0] = 2 * x * y * dradial_dr2 + 2 * self.p1 * x + 2 * self.p2 * y
        J[..., 1, 1] = radial + 2 * y * y * dradial_dr2 + 6 * self.p1 * y + 2 * self.p2 * x
        return J

    def undistort(self, xy_d: ArrayLike) -> FloatArray:
        """Invert :meth:`distort` by Newton iterations on normalised coordinates [-]."""
        xy_d = np.asarray(xy_d, dtype=float)
        if not self.has_distortion:
            return xy_d.copy()
        coeffs = (self.k1, self.k2, self.k3, self.p1, self.p2)
        if xy_d.size == 2:
            # one point (the Moon's image position): the same steps on Python floats, free
            # of the per-operation cost of arrays
            xd, yd = float(xy_d.flat[0]), float(xy_d.flat[1])
            x, y = xd, yd
            for _ in range(UNDISTORT_MAX_ITER):
                x, y, sx, sy = _undistort_step(x, y, xd, yd, *coeffs)
                if max(abs(sx), abs(sy)) < UNDISTORT_TOL:
                    break
            return np.array([x, y]).reshape(xy_d.shape)
        xd, yd = xy_d[..., 0], xy_d[..., 1]
        x, y = xd.copy(), yd.copy()
        for _ in range(UNDISTORT_MAX_ITER):
            x, y, sx, sy = _undistort_step(x, y, xd, yd, *coeffs)
            if max(np.max(np.abs(sx), initial=0.0), np.max(np.abs(sy), initial=0.0)) \
                    < UNDISTORT_TOL:
                break
        return np.stack([x, y], axis=-1)

    # ------------------------------------------------------------ projection
    def project(self, points: ArrayLike, distort: bool = True) -> FloatArray:
        """Project camera-frame points ``(..., 3)`` [any length unit] to pixels ``(..., 2)``.

        Raises :class:`~starnav.errors.GeometryError` for points at or behind ``z = 0``.
        """
        p = np.asarray(points, dtype=float)
        z = p[..., 2]
        if np.any(z <= 0.0):
            raise GeometryError("cannot project points at or behind the camera plane (z <= 0)")
        xy = p[..., :2] / z[..., None]
        if distort and self.has_distortion:
            xy = self.distort(xy)
        return np.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    def project_jacobian(self, points: ArrayLike, distort: bool = True) -> FloatArray:
        """Jacobian ``d(u, v) / d(X, Y, Z)`` of :meth:`project`, shape ``(..., 2, 3)`` [px/unit]."""
        p = np.asarray(points, dtype=float)
        X, Y, Z = p[..., 0], p[..., 1], p[..., 2]
        # d(x, y)/d(X, Y, Z) for x = X/Z, y = Y/Z
        dn = np.zeros(p.shape[:-1] + (2, 3))
        dn[..., 0, 0] = 1.0 / Z
        dn[..., 0, 2] = -X / Z**2
        dn[..., 1, 1] = 1.0 / Z
        dn[..., 1, 2] = -Y / Z**2
        if distort and self.has_distortion:
            xy = np.stack([X / Z, Y / Z], -1)
            dn = self.distortion_jacobian(xy) @ dn
        F = np.diag([self.fx, self.fy])
        return F @ dn

    def pixel_to_normalized(self, uv: ArrayLike, undistort: bool = True) -> FloatArray:
        """Pixels ``(..., 2)`` to undistorted normalised coordinates ``(..., 2)``."""
        uv = np.asarray(uv, dtype=float)
        xy = np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)
        if undistort and self.has_distortion:
            xy = self.undistort(xy)
        return xy

    def unproject(self, uv: ArrayLike, undistort: bool = True) -> FloatArray:
        """Unit line-of-sight vectors ``(..., 3)`` in the camera frame for pixels ``(..., 2)``."""
        xy = self.pixel_to_normalized(uv, undistort=undistort)
        rays = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def unproject_jacobian(self, uv: ArrayLike, undistort: bool = True) -> FloatArray:
        """Jacobian ``d(s) / d(u, v)`` of :meth:`unproject` (unit vector s), ``(..., 3, 2)``."""
        return self.unproject_with_jacobian(uv, undistort)[1]

    def unproject_with_jacobian(self, uv: ArrayLike, undistort: bool = True
                                ) -> tuple[FloatArray, FloatArray]:
        """:meth:`unproject` and :meth:`unproject_jacobian` together (one undistortion):
        ``(s (..., 3), d(s) / d(u, v) (..., 3, 2))``."""
        uv = np.asarray(uv, dtype=float)
        xy = self.pixel_to_normalized(uv, undistort=undistort)
        # d(xy)/d(uv): inverse of d(uv)/d(xy) = F Jd
        F = np.diag([self.fx, self.fy])
        if undistort and self.has_distortion:
            dxy_duv = np.linalg.inv(F @ self.distortion_jacobian(xy))
        else:
            dxy_duv = np.broadcast_to(np.linalg.inv(F), xy.shape[:-1] + (2, 2))
        m = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        n = np.linalg.norm(m, axis=-1)[..., None, None]
        s = m[..., :, None] / n
        # d(m/|m|)/dm = (I - s s^T)/|m|; dm/dxy = [[1,0],[0,1],[0,0]]
        P = (np.eye(3) - s @ np.swapaxes(s, -1, -2)) / n
        return np.ascontiguousarray(s[..., 0]), P[..., :, :2] @ dxy_duv

    def pixel_grid(self) -> tuple[FloatArray, FloatArray]:
        """Pixel-centre coordinates ``(u, v)``, each ``(height, width)`` [px]."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(float)
        return u, v

    def pixel_solid_angles(self) -> FloatArray:
        """Solid angle of every pixel of the pinhole, ``(height, width)`` [sr]: the on-axis
        value times ``cos^3`` of the pixel centre's off-axis angle (distortion ignored: the
        renderer's image is undistorted). Summed with a radiance image it gives the irradiance
        at the aperture."""
        u, v = self.pixel_grid()
        x = (u - self.cx) / self.fx
        y = (v - self.cy) / self.fy
        return self.pixel_solid_angle / (1.0 + x * x + y * y) ** 1.5

    def describe(self) -> dict[str, float | int | str]:
        """Derived optical figures, for logs, manifests and ``starnav info``."""
        return {
            "name": self.name,
            "width_px": self.width,
            "height_px": self.height,
            "focal_length_mm": self.focal_length * 1e3,
            "pitch_um": self.pitch_x * 1e6,
            "f_number": self.f_number,
            "pupil_diameter_mm": self.pupil_diameter * 1e3,
            "fov_x_deg": math.degrees(self.fov_x),
            "fov_y_deg": math.degrees(self.fov_y),
            "fov_diagonal_deg": math.degrees(self.fov_diagonal),
            "ifov_urad": self.ifov * 1e6,
            "ifov_arcsec": math.degrees(self.ifov) * 3600.0,
            "pixel_solid_angle_sr": self.pixel_solid_angle,
            "etendue_m2sr": self.etendue,
        }


#: Named cameras. ``aa-str``: docs/facts.md section 1 (seed paper Table 1 and the ABRAM AA-STR
#: configuration for the f-number).
CAMERA_PRESETS: dict[str, Camera] = {
    "aa-str": Camera(
        width=1024,
        height=1024,
        focal_length=50.7e-3,
        pitch_x=18e-6,
        pitch_y=18e-6,
        f_number=1.495575,
        name="aa-str",
    ),
    # SMART-1 AMIE, the 512 x 512 quadrant read through the NONE filter (NAIF ID -238110), from
    # the instrument kernel data/amie/calib/SMART1_AMIE_V01.TI (version 0.1 of January 2005):
    #   INS-238110_FOCAL_LENGTH = 154.7 (mm)      INS-238110_F/RATIO = 10.0
    #   INS-238110_PIXEL_SIZE = (14, 14) (um)     INS-238110_PIXEL_SAMPLES/_LINES = 512
    #   INS-238110_CCD_CENTER = (256.5, 256.5): 1-based, counted from the quadrant's origin, i.e.
    #     the detector centre (255.5, 255.5) in starnav's 0-based pixel-centre convention
    #   INS-238110_FOV_REF_ANGLE = INS-238110_FOV_CROSS_ANGLE = 1.325 deg (half-angles: 2.65 deg)
    #   INS-238110_IFOV = 0.000090 rad (rounded; 14 um / 154.7 mm = 9.05e-5 rad)
    # No distortion model is published ("Optical Distortion": not available).
    "amie": Camera(
        width=512,
        height=512,
        focal_length=154.7e-3,
        pitch_x=14e-6,
        pitch_y=14e-6,
        f_number=10.0,
        name="amie",
    ),
}


# --------------------------------------------------------------------------- schema
#: Largest detector side [px]: the largest CMOS sensors made are ~15 000 px on a side; one
#: frame's radiance and its AOVs at this size already take gigabytes.
MAX_DETECTOR_PX = 16384


class CameraConfig(StrictModel):
    """Camera optics and detector geometry. ``None`` keeps the preset's value."""

    preset: str = Field("aa-str", description="named camera whose values the keys below "
                        f"override: {', '.join(CAMERA_PRESETS)}")
    focal_length_mm: Annotated[float, Field(gt=0, le=2e5)] | None = Field(
        None, description="effective focal length [mm], at most 200 m (longer than any "
        "telescope flown: JWST's is 131.4 m); null: the preset's")
    pixel_pitch_um: PositiveFloat | None = Field(
        None, description="pixel pitch [um]; null: the preset's")
    width: Annotated[PositiveCount, Field(le=MAX_DETECTOR_PX)] | None = Field(
        None, description="detector columns [px]; null: the preset's")
    height: Annotated[PositiveCount, Field(le=MAX_DETECTOR_PX)] | None = Field(
        None, description="detector rows [px]; null: the preset's")
    f_number: PositiveFloat | None = Field(
        None, description="f-number N = f / D [-]; null: the preset's")
    principal_point_px: tuple[float, float] | None = Field(
        None, description="principal point (u, v) [px]; default the detector centre"
    )
    distortion: tuple[float, float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0, 0.0), description="Brown-Conrady (k1, k2, k3, p1, p2) [-]"
    )


def camera_from_config(cfg: CameraConfig) -> Camera:
    """The :class:`~starnav.camera.Camera` described by ``cfg`` (SI inside)."""
    over: dict[str, Any] = {}
    si = cfg.to_si()
    if si.focal_length is not None:
        over["focal_length"] = si.focal_length
    if si.pixel_pitch is not None:
        over["pitch_x"] = over["pitch_y"] = si.pixel_pitch
    if cfg.width is not None:
        over["width"] = cfg.width
    if cfg.height is not None:
        over["height"] = cfg.height
    if cfg.f_number is not None:
        over["f_number"] = cfg.f_number
    if cfg.principal_point_px is not None:
        over["cx"], over["cy"] = cfg.principal_point_px
    k1, k2, k3, p1, p2 = cfg.distortion
    over.update(k1=k1, k2=k2, k3=k3, p1=p1, p2=p2)
    return Camera.preset(cfg.preset, **over)
