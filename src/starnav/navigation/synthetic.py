"""Analytic Moon frames for tests, examples and benchmarks of the navigation chain.

The chain is checkable without the renderer and the detector chain: :func:`draw_moon` casts
``supersample^2`` rays per pixel at an exact sphere (the disc anti-aliased by area), shades the
hits by ``lambert`` or ``lommel-seeliger`` (:data:`SHADING_LAWS`), blurs by a Gaussian PSF,
scales to ``peak_dn`` with background and optional read noise, and rounds and clips to the full
scale; :func:`threshold_segments` reads it out as segments. The truth limb of such a frame is
the exact conic of :func:`~starnav.navigation.christian_robinson.limb_conic_pixels`.

Index
-----
:func:`synthetic_frame`, :func:`draw_moon`, :func:`threshold_segments`,
:func:`pointing_geometry`, :data:`SHADING_LAWS`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from starnav.camera import Camera
from starnav.constants import MOON_RADIUS
from starnav.detector.products import Segments
from starnav.geometry import FrameGeometry, look_rotation
from starnav.navigation.frames import Frame
from starnav.navigation.limb import (
    LimbNotFoundError,
    limb_points_from_segments,
    segments_centroid,
    sun_direction_in_image,
)
from starnav.navigation.refine import RefineConfig, cut_windows, plan_windows
from starnav.registry import Registry
from starnav.typing import FloatArray


def _lambert(mu0: FloatArray, nrm: FloatArray, ray: FloatArray) -> FloatArray:
    return np.maximum(mu0, 0.0)


def _lommel_seeliger(mu0: FloatArray, nrm: FloatArray, ray: FloatArray) -> FloatArray:
    mu = np.maximum(-(nrm * ray).sum(-1), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(mu0 > 0, mu0 / (mu0 + mu), 0.0)


#: Photometric laws known to :func:`draw_moon`: ``f(mu0, normal, ray)``, the relative radiance.
SHADING_LAWS: Registry[Callable[[FloatArray, FloatArray, FloatArray], FloatArray]] = Registry(
    "shading law", {"lambert": _lambert, "lommel-seeliger": _lommel_seeliger})


def draw_moon(
    camera: Camera,
    geometry: FrameGeometry,
    *,
    peak_dn: float = 3000.0,
    psf_sigma_px: float = 0.7,
    supersample: int = 8,
    shading: str = "lambert",
    background_dn: float = 0.0,
    read_noise_dn: float = 0.0,
    full_scale_dn: int = 4095,
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint16]:
    """Full-frame DN image of the Moon sphere (module steps 1-3).

    Parameters
    ----------
    camera : Camera
    geometry : FrameGeometry
        Uses the *true* attitude, camera position, Sun position and Moon radius.
    peak_dn : float
        DN of the brightest pixel before background and noise [DN].
    psf_sigma_px : float
        Gaussian PSF sigma [px]; 0 disables the blur.
    supersample : int
        Samples per pixel side (``supersample^2`` per pixel).
    shading : str
        ``lambert`` or ``lommel-seeliger``.
    background_dn, read_noise_dn : float
        Offset and Gaussian noise sigma [DN]; noise needs ``rng``.
    full_scale_dn : int
        Clip level [DN] (a saturated pixel reads this value).
    rng : numpy.random.Generator, optional
        Noise source.

    Returns
    -------
    (height, width) uint16 array
    """
    law = SHADING_LAWS.get(shading)
    from scipy.ndimage import gaussian_filter

    H, W = camera.height, camera.width
    img = np.zeros((H, W))
    c = geometry.moon_centre_camera()
    R = geometry.body_radius
    s = geometry.sun_direction_camera()
    uv = camera.project(c, distort=True)
    d = float(np.linalg.norm(c))
    r_px = camera.fx * math.tan(math.asin(min(R / d, 1.0))) * 1.2 + 4.0 * psf_sigma_px + 3.0
    u0 = int(max(0, math.floor(uv[0] - r_px)))
    u1 = int(min(W - 1, math.ceil(uv[0] + r_px)))
    v0 = int(max(0, math.floor(uv[1] - r_px)))
    v1 = int(min(H - 1, math.ceil(uv[1] + r_px)))
    if u1 >= u0 and v1 >= v0:
        S = supersample
        off = (np.arange(S) + 0.5) / S - 0.5
        acc = np.zeros((v1 - v0 + 1, u1 - u0 + 1))
        vv, uu = np.mgrid[v0:v1 + 1, u0:u1 + 1].astype(float)
        cc = float(c @ c) - R * R
        for dv in off:
            for du in off:
                ray = camera.unproject(np.stack([uu + du, vv + dv], -1))
                b = ray @ c
                disc = b * b - cc
                hit = disc >= 0.0
                t = b - np.sqrt(np.where(hit, disc, 0.0))
                X = ray * t[..., None]
                nrm = (X - c) / R
                mu0 = nrm @ s
                val = law(mu0, nrm, ray)
                acc += np.where(hit, val, 0.0)
        img[v0:v1 + 1, u0:u1 + 1] = acc / (S * S)
    if psf_sigma_px > 0:
        img = gaussian_filter(img, psf_sigma_px, mode="constant", truncate=5.0)
    mx = float(img.max())
    if mx > 0:
        img *= peak_dn / mx
    img += background_dn
    if read_noise_dn > 0:
        if rng is None:
            raise ValueError("draw_moon: read_noise_dn > 0 needs rng")
        img += rng.normal(0.0, read_noise_dn, img.shape)
    return np.clip(np.round(img), 0, full_scale_dn).astype(np.uint16)


def threshold_segments(dn: NDArray, thresholds: Sequence[int]) -> Segments:
    """Run-length encode pixels ``>= thresholds[0]`` row by row (module step 4).

    ``level[k]`` is the index of the highest threshold reached by a pixel of run ``k``. The
    detector's readout (:func:`starnav.detector.readout.extract_segments`) instead splits a run
    wherever the level changes; with a single threshold both encodings are identical, and the
    limb scan gives the same points for either (tests/navigation/test_limb.py).
    """
    img = np.asarray(dn)
    th = tuple(int(t) for t in sorted(thresholds))
    mask = img >= th[0]
    H, W = mask.shape
    pad = np.zeros((H, W + 2), dtype=np.int8)
    pad[:, 1:-1] = mask
    diff = np.diff(pad, axis=1)
    rs, cs = np.nonzero(diff == 1)
    re, ce = np.nonzero(diff == -1)
    length = (ce - cs).astype(np.int32)
    offset = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    values = img[mask].astype(np.uint16)  # row-major order == run order
    peak = (np.maximum.reduceat(values, offset) if values.size else
            np.zeros(0, np.uint16))
    level = (np.searchsorted(np.asarray(th), peak, side="right") - 1).astype(np.int8)
    return Segments(row=rs.astype(np.int32), col_start=cs.astype(np.int32), length=length,
                    offset=offset, values=values, level=level, thresholds=th, shape=(H, W))


def pointing_geometry(
    camera: Camera,
    camera_position: NDArray,
    sun_position: NDArray,
    *,
    camera_velocity: NDArray | None = None,
    epoch_tdb: float = 0.0,
    index: int = 0,
    moon_offset_px: tuple[float, float] = (0.0, 0.0),
    roll: float = 0.0,
    attitude_error_rad: NDArray | None = None,
    body_radius: float | None = None,
) -> FrameGeometry:
    """A frame whose camera points at the Moon (centre at ``moon_offset_px`` from the principal
    point), from Moon-centred J2000 positions [m].

    ``attitude_error_rad`` (3,) is a small rotation vector [rad] applied to the true attitude to
    give the measured one (``R_meas = R_true Exp([e]x)``, camera-frame error).
    """
    from scipy.spatial.transform import Rotation

    p = np.asarray(camera_position, float)
    los_cam = camera.unproject(np.array([camera.cx + moon_offset_px[0],
                                         camera.cy + moon_offset_px[1]]), undistort=False)
    R = look_rotation(los_cam, -p / np.linalg.norm(p), roll=roll)
    Rm = None
    if attitude_error_rad is not None:
        Rm = R @ Rotation.from_rotvec(np.asarray(attitude_error_rad, float)).as_matrix()
    return FrameGeometry(
        camera_position=p, R_cam_to_inertial=R, sun_position=np.asarray(sun_position, float),
        epoch_tdb=float(epoch_tdb),
        camera_velocity=np.zeros(3) if camera_velocity is None else np.asarray(camera_velocity),
        R_cam_to_inertial_measured=Rm, index=int(index),
        body_radius=MOON_RADIUS if body_radius is None else float(body_radius))


def synthetic_frame(
    camera: Camera,
    geometry: FrameGeometry,
    *,
    thresholds: Sequence[int] = (300,),
    windows: bool = True,
    n_windows: int = 16,
    window_size_px: int = 11,
    rng: np.random.Generator | None = None,
    **draw_kw: object,
):
    """A :class:`~starnav.navigation.frames.Frame` drawn analytically from ``geometry``.

    The segments come from :func:`threshold_segments`; with ``windows`` the window positions are
    planned on the pixel-level limb of those segments (as the tracker would, from the true
    attitude's Sun direction) and cut from the same image. Keyword arguments go to
    :func:`draw_moon`.
    """
    dn = draw_moon(camera, geometry, rng=rng, **draw_kw)  # type: ignore[arg-type]
    seg = threshold_segments(dn, thresholds)
    R_meas = geometry.R_cam_to_inertial_known
    wins: list = []
    if windows and len(seg):
        try:
            c0 = segments_centroid(seg)
            d = sun_direction_in_image(camera, R_meas, geometry.sun_direction, c0)
            lp = limb_points_from_segments(seg, d)
            req = plan_windows(lp.uv, lp.centre_px, shape=dn.shape,
                               options=RefineConfig(n_windows=n_windows,
                                                    window_size_px=window_size_px).to_si())
            wins = cut_windows(dn, req)
        except LimbNotFoundError:
            wins = []
    return Frame(index=geometry.index, epoch_tdb=geometry.epoch_tdb,
                 R_cam_to_inertial_measured=R_meas, sun_direction_inertial=geometry.sun_direction,
                 segments=seg, windows=tuple(wins), truth=geometry,
                 R_body_to_inertial=geometry.R_body_to_inertial)
