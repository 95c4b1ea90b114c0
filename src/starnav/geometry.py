"""Per-frame geometry: the only geometric input of the renderer, and the truth of a frame.

Frames and units
----------------
* All positions are **Moon-centred**, along the inertial ICRF/J2000 axes, in metres; velocities
  in m/s; times in TDB seconds past J2000.
* ``R_cam_to_inertial`` maps camera-frame vectors (+z boresight, +x right, +y down) to inertial:
  ``v_inertial = R_cam_to_inertial @ v_camera``. Attitudes are stored as rotation matrices;
  where a quaternion is needed, :func:`quat_xyzw_from_matrix` gives it **scalar-last**
  ``(x, y, z, w)`` (the type name says so).
* ``R_body_to_inertial`` maps the target body's body-fixed vectors to inertial (the Moon's:
  selenographic, +x towards lon 0 on the equator, +z north pole).
* ``body_radius`` is the target body's reference sphere (the Moon's, or a small body's largest
  semi-axis).

:func:`static_geometry` builds one frame from a range, a phase angle and the Moon's offset in the
field (the ``geometry`` section of a scenario), with no trajectory or ephemeris.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field

from starnav.camera import Camera
from starnav.config_base import StrictModel
from starnav.constants import AU, MOON_RADIUS
from starnav.errors import GeometryError
from starnav.typing import FloatArray


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class FrameGeometry:
    """Geometry and truth of one frame (SI, Moon-centred inertial; see module docstring).

    Parameters
    ----------
    camera_position : (3,) array
        Camera position relative to the Moon centre [m].
    R_cam_to_inertial : (3, 3) array
        True attitude, camera to inertial.
    sun_position : (3,) array
        Sun position relative to the Moon centre [m].
    R_body_to_inertial : (3, 3) array
        Target body-fixed to inertial.
    epoch_tdb : float
        Epoch [TDB s past J2000] (0 for static frames).
    camera_velocity : (3,) array
        Camera velocity relative to the Moon [m/s].
    R_cam_to_inertial_measured : (3, 3) array or None
        Attitude as known on board (true attitude plus knowledge error), for navigation.
    body_radius : float
        Reference sphere radius of the target body [m].
    index : int
        Frame number in its sequence.
    camera_state_emb : (6,) array or None
        Spacecraft position and velocity relative to the Earth-Moon barycentre, J2000 axes
        [m, m/s]: the navigation filter's truth (``None`` for static frames).
    earth_position : (3,) array or None
        Earth centre relative to the Moon centre [m] (the ephemeris'; ``None`` for static
        frames): what casts the Earth's shadow (:mod:`starnav.eclipse`).
    """

    camera_position: FloatArray
    R_cam_to_inertial: FloatArray
    sun_position: FloatArray
    R_body_to_inertial: FloatArray = field(default_factory=lambda: np.eye(3))
    epoch_tdb: float = 0.0
    camera_velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    R_cam_to_inertial_measured: FloatArray | None = None
    body_radius: float = MOON_RADIUS
    index: int = 0
    camera_state_emb: FloatArray | None = None
    earth_position: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.earth_position is not None:
            e = np.asarray(self.earth_position, dtype=float)
            if e.shape != (3,) or not np.all(np.isfinite(e)):
                raise GeometryError(f"earth_position must be a finite 3-vector, got {e!r}")
            object.__setattr__(self, "earth_position", e)
        if self.camera_state_emb is not None:
            st = np.asarray(self.camera_state_emb, dtype=float)
            if st.shape != (6,) or not np.all(np.isfinite(st)):
                raise GeometryError(f"camera_state_emb must be a finite 6-vector, got {st!r}")
            object.__setattr__(self, "camera_state_emb", st)
        for name in ("camera_position", "sun_position", "camera_velocity"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (3,) or not np.all(np.isfinite(a)):
                raise GeometryError(f"{name} must be a finite 3-vector, got {a!r}")
            object.__setattr__(self, name, a)
        for name in ("R_cam_to_inertial", "R_body_to_inertial", "R_cam_to_inertial_measured"):
            R = getattr(self, name)
            if R is None:
                continue
            R = np.asarray(R, dtype=float)
            if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) \
                    or np.linalg.det(R) < 0:
                raise GeometryError(f"{name} must be a proper rotation matrix, got {R!r}")
            object.__setattr__(self, name, R)
        r = float(np.linalg.norm(self.camera_position))
        if r <= self.body_radius:
            raise GeometryError(
                f"geometry.camera_position: observer at {r / 1e3:.3f} km from the Moon centre is "
                f"inside the Moon (radius {self.body_radius / 1e3:.1f} km); expected a range > "
                "the Moon radius"
            )

    # ------------------------------------------------------------ derived truth
    @property
    def range(self) -> float:
        """Camera to Moon-centre distance [m]."""
        return float(np.linalg.norm(self.camera_position))

    @property
    def R_cam_to_inertial_known(self) -> FloatArray:
        """The attitude the spacecraft believes: the measured one when the frame carries a
        knowledge error, else the true one."""
        R = self.R_cam_to_inertial_measured
        return self.R_cam_to_inertial if R is None else R

    @property
    def sun_distance(self) -> float:
        """Sun to Moon-centre distance [m]."""
        return float(np.linalg.norm(self.sun_position))

    @property
    def sun_direction(self) -> FloatArray:
        """Unit vector from the Moon centre to the Sun (inertial)."""
        return _unit(self.sun_position)

    @property
    def phase_angle(self) -> float:
        """Sun-Moon-observer angle [rad]."""
        c = float(np.dot(self.sun_direction, _unit(self.camera_position)))
        return math.acos(max(-1.0, min(1.0, c)))

    @property
    def apparent_radius(self) -> float:
        """Angular radius of the Moon seen from the camera, ``asin(R / d)`` [rad]."""
        return math.asin(self.body_radius / self.range)

    def moon_centre_camera(self) -> FloatArray:
        """Moon centre in the camera frame [m]."""
        return self.R_cam_to_inertial.T @ (-self.camera_position)

    def moon_centre_pixel(self, camera: Camera, distort: bool = False) -> FloatArray:
        """Pixel of the Moon centre ``(u, v)`` [px] (pinhole unless ``distort``)."""
        return camera.project(self.moon_centre_camera(), distort=distort)

    def sun_direction_camera(self) -> FloatArray:
        """Unit vector to the Sun from the Moon centre, in the camera frame."""
        return self.R_cam_to_inertial.T @ self.sun_direction

    def limb_points(self, camera: Camera, n: int = 360, distort: bool = False) -> FloatArray:
        """The true limb of the reference sphere as pixel points ``(n, 2)`` [px].

        The limb is the circle of tangency of the cone from the camera to the sphere; its
        image is an ellipse in general (exact conic, not a circle fit).
        """
        c = -self.camera_position  # Moon centre relative to camera (inertial)
        d = np.linalg.norm(c)
        R = self.body_radius
        ch = c / d
        # tangency circle: centre at distance (d^2 - R^2)/d along ch, radius R sqrt(d^2-R^2)/d
        a = _unit(np.cross(ch, [0.0, 0.0, 1.0] if abs(ch[2]) < 0.9 else [1.0, 0.0, 0.0]))
        b = np.cross(ch, a)
        t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        along = (d * d - R * R) / d
        rad = R * math.sqrt(d * d - R * R) / d
        pts = along * ch + rad * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
        pc = (self.R_cam_to_inertial.T @ pts.T).T
        keep = pc[:, 2] > 0
        return camera.project(pc[keep], distort=distort)


# ---------------------------------------------------------------------------- rotations
def frame_rotation_x(a: ArrayLike) -> FloatArray:
    """Passive (frame) rotation about x by ``a`` [rad], stacked over ``a``'s shape
    (``v' = R v`` gives ``v``'s components in the rotated frame)."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, s], -1),
                     np.stack([z, -s, c], -1)], -2)


def frame_rotation_y(a: ArrayLike) -> FloatArray:
    """Passive (frame) rotation about y by ``a`` [rad], stacked over ``a``'s shape."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, -s], -1), np.stack([z, o, z], -1),
                     np.stack([s, z, c], -1)], -2)


def frame_rotation_z(a: ArrayLike) -> FloatArray:
    """Passive (frame) rotation about z by ``a`` [rad], stacked over ``a``'s shape."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def look_rotation(los_camera: FloatArray, los_inertial: FloatArray, roll: float = 0.0,
                  down_hint: FloatArray | None = None) -> FloatArray:
    """Rotation camera -> inertial that maps the camera-frame line of sight ``los_camera`` onto
    ``los_inertial``, with the camera's +y (down) as close as possible to ``down_hint`` (default
    inertial -z, i.e. north up) after a rotation by ``roll`` [rad] about the line of sight."""
    a1 = _unit(np.asarray(los_camera, float))
    b1 = _unit(np.asarray(los_inertial, float))
    y = np.array([0.0, 1.0, 0.0])
    a2 = y - np.dot(y, a1) * a1
    if np.linalg.norm(a2) < 1e-9:
        a2 = np.array([1.0, 0.0, 0.0]) - a1[0] * a1
    a2 = _unit(a2)
    a3 = np.cross(a1, a2)
    hint = np.array([0.0, 0.0, -1.0]) if down_hint is None else np.asarray(down_hint, float)
    b2 = hint - np.dot(hint, b1) * b1
    if np.linalg.norm(b2) < 1e-6:
        alt = np.array([1.0, 0.0, 0.0])
        b2 = alt - np.dot(alt, b1) * b1
    b2 = _unit(b2)
    b3 = np.cross(b1, b2)
    c, s = math.cos(roll), math.sin(roll)
    b2, b3 = c * b2 + s * b3, -s * b2 + c * b3
    A = np.stack([a1, a2, a3], axis=1)
    B = np.stack([b1, b2, b3], axis=1)
    return B @ A.T


def quat_xyzw_from_matrix(R: FloatArray) -> FloatArray:
    """Scalar-last unit quaternion ``(x, y, z, w)`` of a rotation matrix (w >= 0)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R, float)).as_quat()  # scalar-last
    return q if q[3] >= 0 else -q


def static_geometry(
    camera: Camera,
    range_m: float,
    phase_angle: float,
    moon_offset_px: tuple[float, float] = (0.0, 0.0),
    roll: float = 0.0,
    sun_azimuth: float = 0.0,
    sub_observer_lat: float = 0.0,
    sub_observer_lon: float = 0.0,
    sun_distance: float = AU,
    body_radius: float = MOON_RADIUS,
) -> FrameGeometry:
    """One frame from a range [m], a phase angle [rad] and the Moon centre's pixel offset.

    The Moon's body-fixed axes coincide with the inertial ones. The camera sits above the
    sub-observer point ``(lat, lon)`` [rad]; the subsolar point lies at angular distance
    ``phase_angle`` from it, in the direction ``sun_azimuth`` [rad] measured from local east
    towards north. The attitude puts the Moon centre at ``(cx + du, cy + dv)`` in the pinhole
    image, north up before ``roll``.
    """
    if not (math.isfinite(range_m) and range_m > body_radius):
        raise GeometryError(
            f"geometry.range_km = {range_m / 1e3!r}: the observer is inside the Moon; expected "
            f"a range > {body_radius / 1e3:.1f} km"
        )
    if not (0.0 <= phase_angle <= math.pi):
        raise GeometryError(
            f"geometry.phase_angle_deg = {math.degrees(phase_angle)!r}: expected 0..180 deg"
        )
    cl, sl = math.cos(sub_observer_lat), math.sin(sub_observer_lat)
    co, so = math.cos(sub_observer_lon), math.sin(sub_observer_lon)
    o_hat = np.array([cl * co, cl * so, sl])
    east = np.array([-so, co, 0.0])
    north = np.cross(o_hat, east)
    t_hat = math.cos(sun_azimuth) * east + math.sin(sun_azimuth) * north
    s_hat = math.cos(phase_angle) * o_hat + math.sin(phase_angle) * t_hat
    cam_pos = range_m * o_hat
    du, dv = moon_offset_px
    los_cam = camera.unproject(np.array([camera.cx + du, camera.cy + dv]), undistort=False)
    R = look_rotation(los_cam, -o_hat, roll=roll)
    geom = FrameGeometry(
        camera_position=cam_pos,
        R_cam_to_inertial=R,
        sun_position=sun_distance * s_hat,
        body_radius=body_radius,
    )
    return geom


class StaticGeometryConfig(StrictModel):
    """One frame without a trajectory: observer range, phase angle and the Moon's place."""

    range_km: Annotated[float, Field(gt=0, le=1.5e8)] = Field(
        60_000.0, description="camera to Moon-centre distance [km], at most 1.5e8 km (1 AU: "
        "no Moon-imaging spacecraft is farther)")
    phase_angle_deg: Annotated[float, Field(ge=0, le=180)] = Field(
        30.0, description="Sun-Moon-observer angle [deg]"
    )
    sun_azimuth_deg: float = Field(
        0.0, description="direction of the subsolar point seen from the sub-observer point, "
        "measured from selenographic east towards north [deg]"
    )
    moon_offset_px: tuple[float, float] = Field(
        (0.0, 0.0), description="Moon centre offset from the principal point (du, dv) [px]"
    )
    roll_deg: float = Field(0.0, description="rotation of the camera about the Moon line [deg]")
    sub_observer_lat_deg: Annotated[float, Field(ge=-90, le=90)] = Field(
        0.0, description="selenographic latitude of the point below the camera [deg]")
    sub_observer_lon_deg: float = Field(
        0.0, description="selenographic longitude of the point below the camera [deg]")
    sun_distance_au: Annotated[float, Field(ge=0.98, le=1.02)] = Field(
        1.0, description="Sun-Moon distance [AU]: 0.98 to 1.02 (the Earth's perihelion "
        "0.9833 AU and aphelion 1.0167 AU, plus or minus the Moon's 0.0027 AU)")


def static_geometry_from_config(camera: Camera, cfg: StaticGeometryConfig,
                                body_radius: float) -> FrameGeometry:
    """:func:`static_geometry` from a :class:`StaticGeometryConfig`."""
    si = cfg.to_si()
    return static_geometry(
        camera,
        range_m=si.range,
        phase_angle=si.phase_angle,
        moon_offset_px=tuple(si.moon_offset_px),
        roll=si.roll,
        sun_azimuth=si.sun_azimuth,
        sub_observer_lat=si.sub_observer_lat,
        sub_observer_lon=si.sub_observer_lon,
        sun_distance=si.sun_distance,
        body_radius=body_radius,
    )


def geometry_to_dict(g: FrameGeometry) -> dict:
    """JSON-safe dict of a frame's geometry and derived truth (SI, Moon-centred inertial).

    The keys are the file format's (dataset ``truth.json``, EXR metadata): ``R_moon_to_inertial``
    and ``moon_radius_m`` hold :attr:`FrameGeometry.R_body_to_inertial` and
    :attr:`FrameGeometry.body_radius`, whatever the body."""
    d = {
        "index": g.index,
        "epoch_tdb_s": g.epoch_tdb,
        "camera_position_m": g.camera_position.tolist(),
        "camera_velocity_m_s": g.camera_velocity.tolist(),
        "R_cam_to_inertial": g.R_cam_to_inertial.tolist(),
        "q_cam_to_inertial_xyzw": quat_xyzw_from_matrix(g.R_cam_to_inertial).tolist(),
        "sun_position_m": g.sun_position.tolist(),
        "R_moon_to_inertial": g.R_body_to_inertial.tolist(),
        "moon_radius_m": g.body_radius,
        "range_m": g.range,
        "phase_angle_rad": g.phase_angle,
        "apparent_radius_rad": g.apparent_radius,
    }
    if g.R_cam_to_inertial_measured is not None:
        d["R_cam_to_inertial_measured"] = g.R_cam_to_inertial_measured.tolist()
    if g.camera_state_emb is not None:
        d["camera_state_emb_m_m_s"] = g.camera_state_emb.tolist()
    if g.earth_position is not None:
        d["earth_position_m"] = g.earth_position.tolist()
    return d


def geometry_from_dict(d: dict) -> FrameGeometry:
    """Inverse of :func:`geometry_to_dict`."""
    meas = d.get("R_cam_to_inertial_measured")
    emb = d.get("camera_state_emb_m_m_s")
    earth = d.get("earth_position_m")
    return FrameGeometry(
        camera_position=np.array(d["camera_position_m"]),
        R_cam_to_inertial=np.array(d["R_cam_to_inertial"]),
        sun_position=np.array(d["sun_position_m"]),
        R_body_to_inertial=np.array(d["R_moon_to_inertial"]),
        epoch_tdb=float(d["epoch_tdb_s"]),
        camera_velocity=np.array(d["camera_velocity_m_s"]),
        R_cam_to_inertial_measured=None if meas is None else np.array(meas),
        body_radius=float(d["moon_radius_m"]),
        index=int(d["index"]),
        camera_state_emb=None if emb is None else np.array(emb),
        earth_position=None if earth is None else np.array(earth),
    )
