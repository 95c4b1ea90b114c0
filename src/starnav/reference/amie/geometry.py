"""Geometry of a SMART-1 AMIE frame from its PDS3 label: epoch, attitude, Sun and Moon.

The labels carry no attitude quaternion: they give the epoch (UTC), the spacecraft-to-Moon
vector, the boresight and the four corners of the field (J2000, degrees). This module turns them
into a :class:`~starnav.geometry.FrameGeometry` (SI, Moon-centred, ICRF axes). Evidence for the
corner ordering and the choice of the Moon frame: docs/methods.md,
"starnav.reference.amie.geometry".

Technique
---------
1. Epoch: ``START_TIME`` (UTC) to TDB seconds past J2000 (:func:`amie_epoch_tdb`).
2. Attitude: Wahba's problem on the five label directions paired with the camera rays of the
   principal point and the corner pixels, solved by SVD (:func:`wahba_svd`).
3. Corner ordering: all eight fitted; handedness fixed by the residual, ties to
   :data:`AMIE_CORNER_ORDERING` (upper-left, upper-right, lower-right, lower-left).
4. Sun and Moon from DE421 at the epoch; the Moon in the mean-Earth/polar-axis frame.
5. :func:`refine_attitude`: the smallest rotation moving the predicted Moon centre onto the
   measured one, keeping the label's roll.

References
----------
G. Wahba (1965), *A least squares estimate of satellite attitude*, SIAM Review 7(3):409.
F. L. Markley (1988), *Attitude determination using vector observations and the singular value
decomposition*, J. Astronaut. Sci. 36(3):245-258.

Index
-----
:func:`frame_geometry`, :func:`attitude_from_reticle`, :func:`fit_reticle`,
:class:`ReticleFit`, :func:`refine_attitude`, :func:`amie_epoch_tdb`, :func:`radec_to_unit`,
:func:`wahba_svd`, :func:`detector_corners`, :func:`surface_point`, :class:`SurfacePoint`,
:func:`subsolar_point`, :func:`solar_elongation`.
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from starnav.camera import Camera
from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError, GeometryError
from starnav.geometry import FrameGeometry
from starnav.scenes.ephemeris import Ephemeris, parse_epoch
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Orderings of the label's reticle corners: ``ordering[i]`` is the detector corner (index into
#: :func:`detector_corners`: 0 upper-left, 1 upper-right, 2 lower-right, 3 lower-left) that
#: label corner ``i`` marks. The first four keep the handedness of the image (rotations by
#: multiples of 90 deg), the last four mirror it. The first one is the order the AMIE labels use.
CORNER_ORDERINGS: tuple[tuple[int, int, int, int], ...] = (
    (0, 1, 2, 3), (1, 2, 3, 0), (2, 3, 0, 1), (3, 0, 1, 2),
    (0, 3, 2, 1), (3, 2, 1, 0), (2, 1, 0, 3), (1, 0, 3, 2),
)
#: The ordering of the AMIE labels: upper-left, upper-right, lower-right, lower-left.
AMIE_CORNER_ORDERING = CORNER_ORDERINGS[0]
#: Orderings whose rms Wahba residual is within this of the best one are indistinguishable
#: from the label alone (which rounds to 0.01 deg = 36 arcsec) [rad] (1 arcsec).
ORDERING_TIE_TOL = math.radians(1.0 / 3600.0)


# --------------------------------------------------------------------------- time
def amie_epoch_tdb(start_time_utc: str | _dt.datetime) -> float:
    """TDB seconds past J2000 of an AMIE label's ``START_TIME``.

    Parameters
    ----------
    start_time_utc : str or datetime.datetime
        ``START_TIME`` in UTC, ISO format (``"2004-10-28T05:35:10.428"``, an optional trailing
        ``Z``), or a datetime (naive = UTC; an aware one is converted to UTC).

    Returns
    -------
    float
        Epoch [TDB s past J2000 = 2000-01-01T12:00:00 TDB].
    """
    if isinstance(start_time_utc, _dt.datetime):
        t = start_time_utc
        if t.tzinfo is not None:
            t = t.astimezone(_dt.UTC).replace(tzinfo=None)
        text = t.isoformat(timespec="microseconds")
    else:
        text = str(start_time_utc).strip()
        if text.upper().endswith("Z"):
            text = text[:-1]
    return parse_epoch(f"{text} UTC", field="START_TIME")


# --------------------------------------------------------------------------- attitude
def radec_to_unit(ra_deg: ArrayLike, dec_deg: ArrayLike) -> FloatArray:
    """Unit vectors ``(..., 3)`` (J2000 / ICRF axes) of right ascensions and declinations [deg]."""
    ra = np.radians(np.asarray(ra_deg, float))
    dec = np.radians(np.asarray(dec_deg, float))
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], -1)


def wahba_svd(inertial: ArrayLike, camera: ArrayLike,
              weights: ArrayLike | None = None) -> FloatArray:
    """The rotation ``R`` (camera -> inertial) that best maps ``camera`` onto ``inertial``.

    Minimises ``sum_i w_i |b_i - R r_i|^2`` over proper rotations (Wahba 1965) by the SVD of
    the attitude profile matrix ``B = sum_i w_i b_i r_i^T`` (Markley 1988).

    Parameters
    ----------
    inertial : (n, 3) array
        Unit vectors ``b_i`` in the inertial frame.
    camera : (n, 3) array
        The same directions ``r_i`` in the camera frame (unit vectors).
    weights : (n,) array, optional
        Non-negative weights ``w_i`` (default 1).

    Returns
    -------
    (3, 3) array
        ``R_cam_to_inertial``.

    Raises
    ------
    GeometryError
        Fewer than two directions, or all of them parallel (the attitude is not determined).
    """
    b = np.asarray(inertial, float)
    r = np.asarray(camera, float)
    if b.ndim != 2 or b.shape[1] != 3 or b.shape != r.shape or b.shape[0] < 2:
        raise GeometryError(f"wahba_svd: expected two (n >= 2, 3) arrays of directions, got "
                            f"{b.shape} and {r.shape}")
    w = np.ones(b.shape[0]) if weights is None else np.asarray(weights, float)
    B = (b * w[:, None]).T @ r
    U, s, Vt = np.linalg.svd(B)
    if s[1] <= 1e-12 * max(s[0], 1e-300):
        raise GeometryError("wahba_svd: the directions are all parallel; the attitude about "
                            "them is not determined")
    d = np.linalg.det(U) * np.linalg.det(Vt)
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def detector_corners(camera: Camera) -> FloatArray:
    """Centres of the four corner pixels ``(4, 2)`` [px]: upper-left ``(0, 0)``, upper-right
    ``(W-1, 0)``, lower-right ``(W-1, H-1)``, lower-left ``(0, H-1)`` (row 0 = upper)."""
    w, h = camera.width - 1.0, camera.height - 1.0
    return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])


def _corners_array(corners_radec_deg: ArrayLike) -> FloatArray:
    c = np.asarray(corners_radec_deg, float)
    if c.shape == (2, 4):  # the label's RA list and Dec list
        c = c.T
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise ConfigError("reticle corners", c.tolist(),
                          "four finite (RA, Dec) pairs [deg], shape (4, 2) (or (2, 4))")
    return c


@dataclass(frozen=True)
class ReticleFit:
    """Attitude fitted to a label's boresight and reticle corners.

    Attributes
    ----------
    R_cam_to_inertial : (3, 3) array
        Camera -> inertial (J2000) rotation.
    ordering : tuple of 4 int
        Detector corner (0 upper-left, 1 upper-right, 2 lower-right, 3 lower-left) matched to
        each label corner.
    residuals : (5,) array
        Angle between each label direction (boresight, corners 1-4) and the fitted ray [rad].
    rms : float
        Root mean square of ``residuals`` [rad].
    candidates : tuple of (ordering, rms)
        Every ordering tried with its rms residual [rad], best first.
    ambiguous : tuple of orderings
        The orderings that fit as well as the chosen one (within :data:`ORDERING_TIE_TOL`),
        the chosen one included: rolls the label cannot distinguish.
    """

    R_cam_to_inertial: FloatArray
    ordering: tuple[int, int, int, int]
    residuals: FloatArray
    rms: float
    candidates: tuple[tuple[tuple[int, int, int, int], float], ...]
    ambiguous: tuple[tuple[int, int, int, int], ...]


def _fit_one(b: FloatArray, camera: Camera, ordering: tuple[int, ...]
             ) -> tuple[FloatArray, FloatArray]:
    px = detector_corners(camera)[list(ordering)]
    uv = np.vstack([[camera.cx, camera.cy], px])
    r = camera.unproject(uv)
    R = wahba_svd(b, r)
    rr = r @ R.T
    # atan2 of sine and cosine keeps the precision of small angles (arccos would lose it)
    return R, np.arctan2(np.linalg.norm(np.cross(b, rr), axis=1), np.einsum("ij,ij->i", b, rr))


def fit_reticle(
    boresight_radec_deg: ArrayLike,
    corners_radec_deg: ArrayLike,
    camera: Camera,
    ordering: tuple[int, int, int, int] | None = None,
) -> ReticleFit:
    """Camera attitude from the label's boresight and reticle corners (module step 2 and 3).

    Parameters
    ----------
    boresight_radec_deg : (2,) array
        Boresight right ascension and declination, J2000 [deg] (label ``RIGHT_ASCENSION``,
        ``DECLINATION``); paired with the principal point ``(cx, cy)``.
    corners_radec_deg : (4, 2) array
        ``(RA, Dec)`` of the four reticle corners in label order [deg] (label
        ``RETICLE_POINT_RA``, ``RETICLE_POINT_DECLINATION``; a ``(2, 4)`` array of the RA list and
        the Dec list is accepted too).
    camera : Camera
        The camera (its corner pixels and principal point; distortion is applied if present).
    ordering : tuple of 4 int, optional
        Impose the corner ordering (see :data:`CORNER_ORDERINGS`); default: try all eight and
        keep the smallest residual, ties going to the earliest in :data:`CORNER_ORDERINGS`.
    """
    bs = np.asarray(boresight_radec_deg, float).reshape(-1)
    if bs.shape != (2,) or not np.all(np.isfinite(bs)):
        raise ConfigError("boresight", bs.tolist(), "a finite (RA, Dec) pair [deg]")
    c = _corners_array(corners_radec_deg)
    b = np.vstack([radec_to_unit(bs[0], bs[1]), radec_to_unit(c[:, 0], c[:, 1])])
    tried = CORNER_ORDERINGS if ordering is None else (tuple(ordering),)
    fits = []
    for k, o in enumerate(tried):
        if sorted(o) != [0, 1, 2, 3]:
            raise ConfigError("reticle ordering", o, "a permutation of (0, 1, 2, 3)")
        R, res = _fit_one(b, camera, o)
        fits.append((float(np.sqrt(np.mean(res**2))), k, tuple(int(i) for i in o), R, res))
    best_rms = min(f[0] for f in fits)
    ties = sorted((f for f in fits if f[0] <= best_rms + ORDERING_TIE_TOL), key=lambda f: f[1])
    rms, _, o, R, res = ties[0]
    if len(ties) > 1:
        log.debug("reticle fit: orderings %s fit alike (rms %.2f arcsec); taking %s",
                  [t[2] for t in ties], math.degrees(rms) * 3600.0, o)
    ranked = tuple((f[2], f[0]) for f in sorted(fits, key=lambda f: (f[0], f[1])))
    return ReticleFit(R_cam_to_inertial=R, ordering=o, residuals=res, rms=rms,
                      candidates=ranked, ambiguous=tuple(t[2] for t in ties))


def attitude_from_reticle(
    boresight_radec_deg: ArrayLike,
    corners_radec_deg: ArrayLike,
    camera: Camera,
) -> FloatArray:
    """``R_cam_to_inertial`` (camera +z boresight, +x right, +y down -> J2000) from the label's
    boresight and four reticle corners: ``fit_reticle(...).R_cam_to_inertial``, all eight
    corner orderings tried.
    """
    return fit_reticle(boresight_radec_deg, corners_radec_deg, camera).R_cam_to_inertial


def refine_attitude(
    R_cam_to_inertial: ArrayLike,
    measured_centre_direction_cam: ArrayLike,
    predicted_centre_direction_cam: ArrayLike,
) -> FloatArray:
    """Attitude corrected so that the Moon centre appears where it is measured.

    The smallest rotation ``Q`` (about ``m x p``, 2 degrees of freedom, no roll about the line
    of sight) taking the measured direction ``m`` onto the predicted one ``p``, both in the
    camera frame of ``R``, gives ``R' = R Q``: then ``R' m = R p``, the inertial Moon-centre
    direction, so the corrected attitude predicts the Moon centre along ``m``.

    Parameters
    ----------
    R_cam_to_inertial : (3, 3) array
        Attitude to correct (e.g. from :func:`attitude_from_reticle`).
    measured_centre_direction_cam : (3,) array
        Moon-centre direction measured on the image (limb fit), camera frame (any length).
    predicted_centre_direction_cam : (3,) array
        Moon-centre direction predicted with ``R_cam_to_inertial``
        (``FrameGeometry.moon_centre_camera()``), camera frame (any length).

    Returns
    -------
    (3, 3) array
        The corrected ``R_cam_to_inertial``.

    Raises
    ------
    GeometryError
        Zero or opposite directions (the smallest rotation is not unique).
    """
    R = np.asarray(R_cam_to_inertial, float)
    m = np.asarray(measured_centre_direction_cam, float)
    p = np.asarray(predicted_centre_direction_cam, float)
    nm, npred = np.linalg.norm(m), np.linalg.norm(p)
    if not (nm > 0 and npred > 0 and np.isfinite(nm) and np.isfinite(npred)):
        raise GeometryError("refine_attitude: the Moon-centre directions must be finite and "
                            "non-zero")
    m, p = m / nm, p / npred
    axis = np.cross(m, p)
    s, c = float(np.linalg.norm(axis)), float(np.dot(m, p))
    if s < 1e-15:
        if c > 0:
            return R.copy()
        raise GeometryError("refine_attitude: measured and predicted directions are opposite")
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    Q = np.eye(3) + s * K + (1.0 - c) * (K @ K)  # Rodrigues: Q m = p
    return R @ Q


# --------------------------------------------------------------------------- frame geometry
def frame_geometry(
    epoch_tdb: float,
    sc_to_moon_j2000_m: ArrayLike,
    R_cam_to_inertial: ArrayLike,
    moon_radius: float = MOON_RADIUS,
    *,
    sc_to_moon_velocity_m_s: ArrayLike | None = None,
    moon_frame: Literal["ME", "PA"] = "ME",
    ephemeris: Ephemeris | None = None,
    index: int = 0,
) -> FrameGeometry:
    """The :class:`~starnav.geometry.FrameGeometry` of an AMIE frame (module step 4).

    Parameters
    ----------
    epoch_tdb : float
        Epoch [TDB s past J2000] (:func:`amie_epoch_tdb`).
    sc_to_moon_j2000_m : (3,) array
        Spacecraft-to-Moon-centre vector, J2000 [m] (label ``SC_TARGET_POSITION_VECTOR`` x 1e3).
    R_cam_to_inertial : (3, 3) array
        Camera attitude (:func:`attitude_from_reticle`, :func:`refine_attitude`).
    moon_radius : float
        Reference sphere radius [m] (LOLA's 1737.4 km).
    sc_to_moon_velocity_m_s : (3,) array, optional
        Moon velocity relative to the spacecraft [m/s] (label ``SC_TARGET_VELOCITY_VECTOR`` x
        1e3); the camera velocity is its negative. Default zero.
    moon_frame : {"ME", "PA"}
        Moon body-fixed frame of ``R_body_to_inertial``: DE421 mean-Earth/polar axes (default,
        the frame of the lunar maps) or principal axes.
    ephemeris : Ephemeris, optional
        Default :meth:`starnav.scenes.ephemeris.Ephemeris.default` (DE421).
    index : int
        Frame number.

    Returns
    -------
    FrameGeometry
        Camera at ``-sc_to_moon`` and the Sun and the Earth (DE421, geometric) relative to the
        Moon centre, J2000/ICRF axes [m]; ``R_body_to_inertial`` from the DE421 librations.
    """
    eph = ephemeris or Ephemeris.default()
    t = float(epoch_tdb)
    if not math.isfinite(t):
        raise ConfigError("epoch_tdb", epoch_tdb, "finite TDB seconds past J2000")
    v = np.asarray(sc_to_moon_j2000_m, float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError("sc_to_moon_j2000_m", v.tolist(), "a finite 3-vector [m]")
    vel = np.zeros(3) if sc_to_moon_velocity_m_s is None \
        else -np.asarray(sc_to_moon_velocity_m_s, float).reshape(-1)
    sun = np.asarray(eph.state("sun", t, center="moon"), float)[:3]
    earth = np.asarray(eph.state("earth", t, center="moon"), float)[:3]
    R_moon = np.asarray(eph.moon_orientation(t, frame=moon_frame), float)
    return FrameGeometry(
        camera_position=-v,
        R_cam_to_inertial=np.asarray(R_cam_to_inertial, float),
        sun_position=sun,
        R_body_to_inertial=R_moon,
        epoch_tdb=t,
        camera_velocity=vel,
        body_radius=float(moon_radius),
        index=int(index),
        earth_position=earth,
    )


@dataclass(frozen=True)
class SurfacePoint:
    """Where a line of sight from the camera meets the Moon's reference sphere.

    Attributes
    ----------
    position : (3,) array
        The point relative to the Moon centre, inertial axes [m].
    latitude, longitude : float
        Selenographic planetocentric latitude and east longitude in the frame of
        ``R_body_to_inertial`` [rad], longitude in ``[-pi, pi)``.
    incidence, emission, phase : float
        Sun-normal, camera-normal and Sun-point-camera angles [rad] (label
        ``INCIDENCE_ANGLE``, ``EMISSION_ANGLE``, ``PHASE_ANGLE``).
    """

    position: FloatArray
    latitude: float
    longitude: float
    incidence: float
    emission: float
    phase: float


def _angle(a: FloatArray, b: FloatArray) -> float:
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b)))


def _latlon(R_moon_to_inertial: FloatArray, v: FloatArray) -> tuple[float, float]:
    b = np.asarray(R_moon_to_inertial, float).T @ v
    lat = math.asin(max(-1.0, min(1.0, float(b[2] / np.linalg.norm(b)))))
    lon = (math.atan2(float(b[1]), float(b[0])) + math.pi) % (2.0 * math.pi) - math.pi
    return lat, lon


def surface_point(geom: FrameGeometry, direction_inertial: ArrayLike) -> SurfacePoint | None:
    """The first intersection of a line of sight with the Moon sphere, and its angles.

    Parameters
    ----------
    geom : FrameGeometry
        The frame (camera position, Sun, Moon orientation and radius).
    direction_inertial : (3,) array
        Line of sight from the camera, inertial axes (any length), e.g. the label boresight
        ``radec_to_unit(RIGHT_ASCENSION, DECLINATION)``.

    Returns
    -------
    SurfacePoint or None
        ``None`` when the line of sight misses the sphere (the label then says ``N/A``).
    """
    d = np.asarray(direction_inertial, float)
    d = d / np.linalg.norm(d)
    o = geom.camera_position
    b = float(np.dot(o, d))
    disc = b * b - (float(np.dot(o, o)) - geom.body_radius**2)
    if disc < 0.0 or -b - math.sqrt(disc) <= 0.0:
        return None
    p = o + (-b - math.sqrt(disc)) * d
    to_sun = geom.sun_position - p
    to_cam = o - p
    lat, lon = _latlon(geom.R_body_to_inertial, p)
    return SurfacePoint(position=p, latitude=lat, longitude=lon, incidence=_angle(p, to_sun),
                        emission=_angle(p, to_cam), phase=_angle(to_sun, to_cam))


def subsolar_point(geom: FrameGeometry) -> tuple[float, float]:
    """Selenographic latitude and east longitude of the subsolar point [rad] (label
    ``SUB_SOLAR_LATITUDE``, ``SUB_SOLAR_LONGITUDE``), in the frame of ``R_body_to_inertial``."""
    return _latlon(geom.R_body_to_inertial, geom.sun_position)


def solar_elongation(geom: FrameGeometry, direction_inertial: ArrayLike) -> float:
    """Angle between the Sun and a line of sight, seen from the camera [rad] (the label's
    ``SOLAR_ELONGATION`` is that of the boresight)."""
    return _angle(geom.sun_position - geom.camera_position,
                  np.asarray(direction_inertial, float))
