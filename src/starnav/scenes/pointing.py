"""Moon-pointing attitude: the Moon centre on a chosen pixel, random placement and roll, and
the attitude as known on board.

1. The Moon centre on pixel ``(u, v)`` (:func:`moon_pointing`, through the distortion), then a
   roll about that line of sight.
2. Random placement (:func:`sample_pointing`): offsets drawn uniformly, accepted only if the
   exact limb stays ``margin`` pixels inside the detector.
3. Roll: uniform or fixed (north up, or a ``down_hint``; a fly-by passes its plane's normal, so
   the body crosses the image smoothly through closest approach).
4. Knowledge error ``R_measured = R_true exp([e]x)``, ``e`` Gaussian in camera axes
   (:func:`knowledge_for_run`).
5. Randomness only through generators passed in; per-frame streams from
   :func:`frame_generators` (the same numbers whatever the order frames are made in).

The knobs are :class:`~starnav.scenes.schema.PointingConfig`.

Index
-----
:func:`pointing_from_config`, :func:`sample_pointing`, :func:`moon_pointing`, :class:`Pointing`,
:func:`knowledge_for_run`, :func:`frame_generators`, :func:`rotation_from_vector`,
:func:`disc_inside`, :func:`disc_radius_px`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from starnav.camera import Camera
from starnav.constants import MOON_RADIUS
from starnav.errors import ConfigError, GeometryError
from starnav.geometry import FrameGeometry, look_rotation
from starnav.seeding import STAGE_POINTING, generator
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: Draws allowed before the random placement gives up.
MAX_PLACEMENT_DRAWS = 1000
#: Limb points used to check that the disc is inside the detector.
LIMB_CHECK_POINTS = 256

#: Spawn-key stream identifiers of the scene's random effects (stable across versions).
STREAM_POINTING = 0
STREAM_KNOWLEDGE = 1
STREAM_KNOWLEDGE_RUN = 2


def frame_generators(seed: int, index: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators ``(pointing, knowledge)`` of frame ``index``.

    ``SeedSequence(seed, spawn_key=(STAGE_POINTING, index, stream))`` from
    :mod:`starnav.seeding`, the one registry of stage keys, so that no other subpackage
    (rendering, detector noise) can draw the same numbers.
    """
    if seed < 0 or index < 0:
        raise ConfigError("seed/index", (seed, index), "non-negative integers")
    return (generator(seed, STAGE_POINTING, int(index), STREAM_POINTING),
            generator(seed, STAGE_POINTING, int(index), STREAM_KNOWLEDGE))


def knowledge_for_run(R_true: FloatArray, sigma_rad: FloatArray, seed: int, index: int,
                      run: int) -> FloatArray:
    """The measured attitude of frame ``index`` in Monte Carlo run ``run`` >= 1: the true
    attitude with a fresh knowledge error ``e ~ N(0, diag(sigma^2))`` (camera axes), from its
    own stream ``(STAGE_POINTING, index, STREAM_KNOWLEDGE_RUN, run)``; run 0 keeps the frame's
    own draw. Monte Carlo runs thus sample the attitude error as they sample detector noise."""
    if run < 1:
        raise ConfigError("run", run, "a Monte Carlo run >= 1 (run 0 is the frame's own draw)")
    rng = generator(seed, STAGE_POINTING, int(index), STREAM_KNOWLEDGE_RUN, int(run))
    err = rng.standard_normal(3) * np.asarray(sigma_rad, float)
    return np.asarray(R_true, float) @ rotation_from_vector(err)


@dataclass(frozen=True)
class Pointing:
    """One frame's attitude.

    Attributes
    ----------
    R_true : (3, 3) array
        Camera -> inertial, true.
    R_measured : (3, 3) array
        Camera -> inertial as known on board.
    moon_pixel : (2,) array
        Requested Moon-centre pixel ``(u, v)`` [px].
    roll : float
        Roll about the Moon line [rad].
    knowledge_error : (3,) array
        Rotation vector of the knowledge error, camera axes [rad].
    """

    R_true: FloatArray
    R_measured: FloatArray
    moon_pixel: FloatArray
    roll: float
    knowledge_error: FloatArray


def _skew(w: FloatArray) -> FloatArray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rotation_from_vector(w: ArrayLike) -> FloatArray:
    """Rotation matrix ``exp([w]x)`` of a rotation vector ``w`` [rad] (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    th = float(np.linalg.norm(w))
    K = _skew(w)
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + math.sin(th) / th * K + (1.0 - math.cos(th)) / th**2 * K @ K


def moon_pointing(camera: Camera, camera_position: ArrayLike, moon_pixel: ArrayLike,
                  roll: float = 0.0, down_hint: ArrayLike | None = None) -> FloatArray:
    """Attitude (camera -> inertial) that puts the Moon centre on ``moon_pixel``.

    Parameters
    ----------
    camera : Camera
    camera_position : (3,) array
        Camera relative to the Moon centre, inertial [m].
    moon_pixel : (2,) array
        Wanted Moon-centre pixel ``(u, v)`` [px], in the camera's (distorted) image.
    roll : float
        Rotation about the Moon line [rad]; 0 puts inertial north (+z) towards the top.
    down_hint : (3,) array, optional
        Inertial direction put towards the bottom of the image (camera +y) at roll 0 instead
        of inertial south (module step 3).

    Returns
    -------
    (3, 3) array
    """
    pos = np.asarray(camera_position, dtype=float)
    los_cam = camera.unproject(np.asarray(moon_pixel, dtype=float), undistort=True)
    hint = None if down_hint is None else np.asarray(down_hint, dtype=float)
    return look_rotation(los_cam, -pos, roll=roll, down_hint=hint)


def disc_inside(geom: FrameGeometry, camera: Camera, margin: float) -> bool:
    """True when the whole limb of ``geom`` is at least ``margin`` [px] inside the detector."""
    if geom.moon_centre_camera()[2] <= 0:
        return False
    try:
        pts = geom.limb_points(camera, n=LIMB_CHECK_POINTS, distort=camera.has_distortion)
    except GeometryError:
        return False
    if pts.shape[0] < LIMB_CHECK_POINTS:  # part of the limb behind the camera plane
        return False
    lo = -0.5 + margin
    return bool(np.all(pts[:, 0] >= lo) and np.all(pts[:, 0] <= camera.width - 0.5 - margin)
                and np.all(pts[:, 1] >= lo) and np.all(pts[:, 1] <= camera.height - 0.5 - margin))


def disc_radius_px(camera: Camera, range_m: float, body_radius: float = MOON_RADIUS) -> float:
    """On-axis apparent radius of the Moon ``fx tan(asin(R/d))`` [px]."""
    s = body_radius / range_m
    return camera.fx * s / math.sqrt(1.0 - s * s)


def sample_pointing(camera: Camera, camera_position: ArrayLike, rng: np.random.Generator,
                    knowledge_rng: np.random.Generator, *, moon_offset: str = "random",
                    moon_offset_px: tuple[float, float] = (0.0, 0.0),
                    max_offset: float = 512.0, margin: float = 8.0, roll: str = "random",
                    roll_angle: float = 0.0, knowledge_sigma: ArrayLike = (0.0, 0.0, 0.0),
                    body_radius: float = MOON_RADIUS,
                    sun_position: ArrayLike | None = None,
                    down_hint: ArrayLike | None = None) -> Pointing:
    """Draw one frame's attitude (module docstring).

    Parameters
    ----------
    camera : Camera
    camera_position : (3,) array
        Camera relative to the Moon centre, inertial [m].
    rng, knowledge_rng : numpy.random.Generator
        Placement and roll draws; knowledge-error draws.
    moon_offset, roll : {"random", "fixed"}
    moon_offset_px : (du, dv)
        Offset from the principal point for ``fixed`` [px].
    max_offset, margin : float
        Largest random offset; limb to detector-edge clearance [px].
    roll_angle : float
        Roll for ``fixed`` [rad].
    knowledge_sigma : (3,) array
        1-sigma knowledge error about camera x, y, z [rad].
    body_radius : float
        [m].
    sun_position : (3,) array, optional
        Sun relative to the Moon [m] (only to build the trial geometry).
    down_hint : (3,) array, optional
        The roll law's reference (:func:`moon_pointing`; default inertial south).

    Raises
    ------
    GeometryError
        When no placement keeps the disc inside the detector.
    """
    pos = np.asarray(camera_position, dtype=float)
    rng_m = float(np.linalg.norm(pos))
    sun = np.asarray(sun_position if sun_position is not None else pos * 1e4, dtype=float)
    sigma = np.asarray(knowledge_sigma, dtype=float)
    if sigma.shape != (3,) or np.any(sigma < 0) or not np.all(np.isfinite(sigma)):
        raise ConfigError("knowledge_sigma", sigma, "three finite 1-sigma values >= 0 rad")
    if moon_offset not in ("random", "fixed"):
        raise ConfigError("pointing.moon_offset", moon_offset, "'random' or 'fixed'")
    if roll not in ("random", "fixed"):
        raise ConfigError("pointing.roll", roll, "'random' or 'fixed'")

    def trial(pixel: FloatArray, phi: float) -> tuple[FloatArray, bool]:
        R = moon_pointing(camera, pos, pixel, phi, down_hint)
        g = FrameGeometry(camera_position=pos, R_cam_to_inertial=R, sun_position=sun,
                          body_radius=body_radius)
        return R, disc_inside(g, camera, margin)

    phi = float(rng.uniform(0.0, 2.0 * math.pi)) if roll == "random" else float(roll_angle)
    centre = np.array([camera.cx, camera.cy])
    if moon_offset == "fixed":
        pixel = centre + np.asarray(moon_offset_px, dtype=float)
        R, ok = trial(pixel, phi)
        if not ok:
            raise GeometryError(
                f"pointing.moon_offset_px = {tuple(moon_offset_px)}: the Moon disc (radius "
                f"{disc_radius_px(camera, rng_m, body_radius):.1f} px at {rng_m / 1e3:.0f} km) "
                f"is not {margin} px inside the detector; expected a smaller offset")
    else:
        r_px = disc_radius_px(camera, rng_m, body_radius)
        lo_u, hi_u = r_px + margin - 0.5, camera.width - 0.5 - r_px - margin
        lo_v, hi_v = r_px + margin - 0.5, camera.height - 0.5 - r_px - margin
        lo_u, hi_u = max(lo_u, camera.cx - max_offset), min(hi_u, camera.cx + max_offset)
        lo_v, hi_v = max(lo_v, camera.cy - max_offset), min(hi_v, camera.cy + max_offset)
        if lo_u > hi_u or lo_v > hi_v:
            raise GeometryError(
                f"the Moon disc (radius {r_px:.1f} px at {rng_m / 1e3:.0f} km) does not fit "
                f"{margin} px inside the {camera.width} x {camera.height} detector; expected a "
                "larger range or a smaller pointing.edge_margin_px")
        for _ in range(MAX_PLACEMENT_DRAWS):
            pixel = np.array([rng.uniform(lo_u, hi_u), rng.uniform(lo_v, hi_v)])
            if np.hypot(*(pixel - centre)) > max_offset:
                continue
            R, ok = trial(pixel, phi)
            if ok:
                break
        else:
            raise GeometryError(
                f"no Moon placement kept the disc (radius {r_px:.1f} px) {margin} px inside "
                f"the detector in {MAX_PLACEMENT_DRAWS} draws; expected a smaller "
                "pointing.edge_margin_px or moon_offset_max_px")
    err = knowledge_rng.standard_normal(3) * sigma
    R_meas = R @ rotation_from_vector(err)
    return Pointing(R_true=R, R_measured=R_meas, moon_pixel=pixel, roll=phi, knowledge_error=err)


def pointing_from_config(camera: Camera, camera_position: ArrayLike, cfg, seed: int, index: int,
                         body_radius: float = MOON_RADIUS,
                         sun_position: ArrayLike | None = None,
                         down_hint: ArrayLike | None = None) -> Pointing:
    """:func:`sample_pointing` for frame ``index`` from a
    :class:`~starnav.scenes.schema.PointingConfig` and the scenario seed (``down_hint``: the
    roll law's reference, module step 3)."""
    rng, krng = frame_generators(seed, index)
    return sample_pointing(
        camera, camera_position, rng, krng,
        moon_offset=cfg.moon_offset, moon_offset_px=tuple(cfg.moon_offset_px),
        max_offset=cfg.moon_offset_max_px, margin=cfg.edge_margin_px, roll=cfg.roll,
        roll_angle=cfg.to_si().roll_angle, knowledge_sigma=cfg.knowledge_sigma,
        body_radius=body_radius, sun_position=sun_position, down_hint=down_hint)
