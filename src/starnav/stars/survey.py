"""Lost-in-space identification over the sky: random pointings, rendered and solved.

Measures, on rendered frames and through the tracker's own path, the share of random pointings
solved correctly, wrongly or not at all, and the false-star rate with the Moon in the field
(results: docs/stars.md, "Identification over the sky").

1. Pointings: boresight uniform on the sphere, roll uniform (:func:`random_pointing`).
2. Frame: the pointing's stars through the whole detector chain, a noise stream per pointing.
3. The Moon (``moon=True``): a saturated disc of :data:`MOON_LE` at a random range and
   position, occulting the stars behind it, with the tracker's exclusions.
4. Solve lost in space and classify: correct, wrong, unsolved; count false and foreign
   candidates.

Index
-----
:func:`identification_survey`, :class:`SurveyResult`, :class:`PointingResult`,
:func:`random_pointing`.
"""

from __future__ import annotations

import math
import re
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from starnav.camera import Camera
from starnav.constants import MOON_RADIUS
from starnav.detector import DetectorConfig, expose
from starnav.geometry import FrameGeometry, look_rotation
from starnav.spectra import SensorResponse, sensor_response
from starnav.stars.attitude import ARCSEC, error_rotation, solve_attitude
from starnav.stars.catalogue import StarCatalogue, hipparcos
from starnav.stars.centroid import body_exclusions
from starnav.stars.field import frame_stars
from starnav.stars.schema import StarsConfig
from starnav.typing import FloatArray

#: Electron radiance of the test Moon disc [e- s^-1 m^-2 sr^-1]: saturates the AA-STR at
#: 200 ms by a large factor (a blob with blooming, halo and ghosts).
MOON_LE = 1.0e19
#: Distance of the Sun used for the frames' geometry [m] (its direction does not matter).
SUN_POSITION = np.array([1.5e11, 0.0, 0.0])


def random_pointing(rng: np.random.Generator) -> FloatArray:
    """Camera -> inertial rotation with the boresight uniform on the sphere and a uniform
    roll (module step 1)."""
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    R = look_rotation(np.array([0.0, 0.0, 1.0]), z)
    roll = rng.uniform(0.0, 2.0 * math.pi)
    c, s = math.cos(roll), math.sin(roll)
    return R @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PointingResult:
    """One pointing of the survey.

    Attributes
    ----------
    index : int
    R_true : (3, 3) array
        True camera -> inertial attitude.
    outcome : str
        ``"correct"``, ``"wrong"`` or ``"unsolved"``.
    reason : str
        The solver's reason when unsolved.
    error_arcsec : (3,) array
        Error rotation, camera axes (x, y cross-boresight, z roll) [arcsec]; NaN unsolved.
    sigma_arcsec : (3,) array
        Predicted 1-sigma per axis [arcsec]; NaN unsolved.
    stars_in_frame, candidates, matched : int
        Drawn visible stars, accepted centroids, identified stars.
    false_candidates, false_matched, foreign_matched : int
        Module step 4.
    moon_radius_px : float
        0 without the Moon.
    rejected : dict
        The centroiding's rejected blobs by reason (``excluded``: inside the body's or a
        ghost's exclusion disc).
    time_frame_s, time_solve_s : float
        Drawing + exposing the frame, and the solve [s].
    """

    index: int
    R_true: FloatArray
    outcome: str
    reason: str
    error_arcsec: FloatArray
    sigma_arcsec: FloatArray
    stars_in_frame: int
    candidates: int
    matched: int
    false_candidates: int
    false_matched: int
    foreign_matched: int
    moon_radius_px: float
    rejected: dict[str, int]
    time_frame_s: float
    time_solve_s: float


@dataclass(frozen=True)
class SurveyResult:
    """All pointings of :func:`identification_survey` and their summary."""

    pointings: tuple[PointingResult, ...]
    exposure_time: float
    moon: bool
    exclude_body: bool = True

    def summary(self) -> dict[str, Any]:
        """Counts, rates, unsolved reasons (digits masked), false candidates per frame and
        the timings' medians [s]."""
        p = self.pointings
        n = len(p)
        out = Counter(x.outcome for x in p)
        reasons = Counter(re.sub(r"\d+", "#", x.reason) for x in p if x.outcome == "unsolved")
        fc = np.array([x.false_candidates for x in p], float)
        cand = np.array([x.candidates for x in p], float)
        ok = [x for x in p if x.outcome != "unsolved"]
        err = np.array([x.error_arcsec for x in ok]) if ok else np.full((0, 3), np.nan)
        return {"pointings": n, "exposure_s": self.exposure_time, "moon": self.moon,
                "exclude_body": self.exclude_body,
                "correct": out["correct"], "wrong": out["wrong"], "unsolved": out["unsolved"],
                "correct_fraction": out["correct"] / n if n else math.nan,
                "unsolved_reasons": dict(reasons),
                "false_candidates_per_frame": float(fc.mean()) if n else math.nan,
                "false_candidates_max": int(fc.max()) if n else 0,
                "frames_with_false_candidates": int((fc > 0).sum()),
                "false_candidate_fraction": float(fc.sum() / max(cand.sum(), 1.0)),
                "false_matched": int(sum(x.false_matched for x in p)),
                "rejected_per_frame": {k: float(np.mean([x.rejected.get(k, 0) for x in p]))
                                       for k in sorted({k for x in p for k in x.rejected})},
                "foreign_matched": int(sum(x.foreign_matched for x in p)),
                "matched_total": int(sum(x.matched for x in p)),
                "stars_in_frame_min": int(min((x.stars_in_frame for x in p), default=0)),
                "matched_median": float(np.median([x.matched for x in p])) if n else math.nan,
                "error_cross_rms_arcsec": float(np.sqrt(np.mean(err[:, 0] ** 2
                                                                + err[:, 1] ** 2)))
                if len(ok) else math.nan,
                "error_roll_rms_arcsec": float(np.sqrt(np.mean(err[:, 2] ** 2)))
                if len(ok) else math.nan,
                "error_max_arcsec": float(np.max(np.linalg.norm(err, axis=1)))
                if len(ok) else math.nan,
                "time_frame_median_s": float(np.median([x.time_frame_s for x in p])),
                "time_solve_median_s": float(np.median([x.time_solve_s for x in p])),
                "time_solve_max_s": float(np.max([x.time_solve_s for x in p]))}


def identification_survey(
    n_pointings: int,
    rng: np.random.Generator,
    *,
    camera: Camera | None = None,
    detector: DetectorConfig | None = None,
    exposure_time: float = 0.2,
    moon: bool = False,
    moon_range_m: tuple[float, float] = (4.0e7, 9.0e7),
    exclude_body: bool = True,
    correct_arcsec: float = 30.0,
    false_px: float = 2.0,
    first_seed: int = 0,
    catalogue: StarCatalogue | None = None,
    stars: StarsConfig | None = None,
    response: SensorResponse | None = None,
) -> SurveyResult:
    """Render and solve ``n_pointings`` random pointings lost in space (module steps 1-4).

    Parameters
    ----------
    n_pointings : int
    rng : numpy.random.Generator
        Draws the pointings and the Moon's place and range (the detector noise is seeded
        ``first_seed + k``).
    camera, detector : optional
        Default the AA-STR preset and the default detector.
    exposure_time : float
        [s].
    moon : bool
        A saturated lunar disc at random in every frame (module step 3).
    moon_range_m : (float, float)
        Range of the Moon's distance [m], drawn uniformly.
    exclude_body : bool
        Give the solver the Moon's and its ghosts' exclusion discs (the tracker's way);
        ``False`` is a stress test of the rejections and verification alone.
    correct_arcsec, false_px : float
        Largest error rotation of a correct solution [arcsec]; distance to the nearest drawn
        star beyond which a candidate is false [px].
    first_seed : int
        Temporal noise seed of pointing 0.
    catalogue : StarCatalogue, optional
        Default Hipparcos.
    stars : StarsConfig, optional
        Default ``StarsConfig(enabled=True)``.
    response : SensorResponse, optional
        QE x T of the sensor; default the AA-STR's.
    """
    cam = camera if camera is not None else Camera.preset("aa-str")
    det = detector if detector is not None else DetectorConfig()
    cat = catalogue if catalogue is not None else hipparcos()
    cfg = stars if stars is not None else StarsConfig(enabled=True)
    resp = response if response is not None else sensor_response("aa-str")
    distort = bool(det.optics.distortion.enabled and cam.has_distortion)
    rows = []
    for k in range(int(n_pointings)):
        R = random_pointing(rng)
        le = np.zeros((cam.height, cam.width), np.float32)
        ex: tuple = ()
        r_px = 0.0
        if moon:
            uv = rng.uniform([0.0, 0.0], [cam.width - 1.0, cam.height - 1.0])
            d = float(rng.uniform(*moon_range_m))
            xy = cam.pixel_to_normalized(uv[None], undistort=False)[0]
            los = R @ (np.r_[xy, 1.0] / np.linalg.norm(np.r_[xy, 1.0]))
            geom = FrameGeometry(camera_position=-d * los, R_cam_to_inertial=R,
                                 sun_position=SUN_POSITION, body_radius=MOON_RADIUS)
            r_px = cam.fx * math.tan(geom.apparent_radius)
            yy, xx = np.mgrid[:cam.height, :cam.width]
            le = np.where(np.hypot(xx - uv[0], yy - uv[1]) < r_px, MOON_LE, 0.0).astype(
                np.float32)
            centre = geom.moon_centre_pixel(cam, distort=distort)
            ex = body_exclusions(centre, r_px, (cam.cx, cam.cy), det.optics.ghosts.ghosts) \
                if exclude_body else ()
        else:  # the Moon far behind the camera
            geom = FrameGeometry(camera_position=1e12 * R[:, 2], R_cam_to_inertial=R,
                                 sun_position=SUN_POSITION)
        t0 = time.perf_counter()
        f = frame_stars(geom, cam, cfg, resp, exposure_time=exposure_time, detector=det,
                        catalogue=cat)
        e = expose(le, cam, det, seed=int(first_seed) + k, frame_index=int(first_seed) + k,
                   exposure_time=exposure_time, point_sources=f.point_sources())
        t1 = time.perf_counter()
        sol = solve_attitude(e.dn, cam, det, epoch_jyear=f.epoch_jyear, exclusions=ex,
                             catalogue=cat, observer_velocity=f.observer_velocity_m_s)
        t2 = time.perf_counter()
        vis = f.visible()
        cents = sol.centroids.uv
        if len(cents) and len(vis):
            dist = np.min(np.linalg.norm(cents[:, None] - vis.pixel_px[None], axis=2), axis=1)
        else:
            dist = np.full(len(cents), np.inf)
        false = dist > false_px
        ident = sol.identification
        n_match = ident.n_matched if (sol.ok and ident is not None) else 0
        if sol.ok:
            err = error_rotation(sol.R_cam_to_inertial, R) / ARCSEC
            outcome = "correct" if np.linalg.norm(err) < correct_arcsec else "wrong"
            f_m = int(false[ident.detection_index].sum())
            foreign = len(set(ident.hip.tolist()) - set(vis.hip.tolist()))
            sig = sol.sigma_arcsec
        else:
            err = sig = np.full(3, np.nan)
            outcome, f_m, foreign = "unsolved", 0, 0
        rows.append(PointingResult(k, R, outcome, sol.reason, err, sig, len(vis), len(cents),
                                   n_match, int(false.sum()), f_m, foreign, r_px,
                                   dict(sol.centroids.rejected), t1 - t0, t2 - t1))
    return SurveyResult(tuple(rows), float(exposure_time), bool(moon), bool(exclude_body))
