"""The tracker's own attitude per navigation frame: star acquisitions on a schedule, the gyro
between them (``navigation.attitude.source: stars``).

For frame ``k`` (:meth:`StarAttitudeTracker.step`), in this order:

1. Star acquisition (frames that are multiples of ``schedule_every``): the same radiance
   exposed at ``star_exposure_s`` with the stars, solved by
   :func:`starnav.stars.attitude.solve_attitude` (tracking, else lost in space), the Moon's
   disc and ghosts excluded around its true image position.
2. The navigation frame's own stars when step 1 is not scheduled or failed.
3. Propagation by the gyro (:func:`starnav.stars.gyro.propagate`) when neither solves.
4. Assumed: the scenario's attitude knowledge, only before the first solution.

Each :class:`AttitudeRecord` says which source gave the attitude and why the others did not.
Every user-facing path shares these steps on DN frames (:meth:`StarAttitudeTracker.advance`,
:func:`star_acquisition_dn`, :class:`StarSolver`); random streams: :data:`STAR_ACQUISITION`
and :data:`GYRO_STREAM` under :mod:`starnav.seeding`. Usage: docs/stars.md.

Index
-----
:class:`StarAttitudeTracker`, :class:`AttitudeRecord`, :class:`StarSolver`,
:func:`star_acquisition_dn`, :func:`frame_attitude_summary`, :func:`assumed_covariance`,
:func:`with_attitude`, :func:`check_star_attitude`, :func:`uses_star_attitude`,
:func:`is_star_frame`, :data:`SOURCES`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from starnav.detector import expose
from starnav.errors import ConfigError
from starnav.navigation.pipeline import ChainOptions
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate.acquire import (
    Acquisition,
    acquisition_seed,
    quiet_timing,
    sensor_seed_of,
    star_field,
)
from starnav.simulate.build import chain_options
from starnav.stars.aberration import observer_velocity
from starnav.stars.attitude import ARCSEC, AttitudeSolution, error_rotation, solve_attitude
from starnav.stars.catalogue import hipparcos, jyear_from_tdb
from starnav.stars.centroid import body_exclusions
from starnav.stars.gyro import GyroErrors, GyroModel, propagate
from starnav.typing import FloatArray

if TYPE_CHECKING:
    from starnav.geometry import FrameGeometry
    from starnav.radiance import RadianceImage
    from starnav.simulate.frames import Simulator

#: Acquisition number of the star acquisition (0: segments, 1: windows; never change).
STAR_ACQUISITION = 2
#: Last key of the gyro error stream (never change).
GYRO_STREAM = 7
#: Attitude sources, best first (module steps 1-4).
SOURCES = ("star-frame", "navigation-frame", "propagated", "assumed")


@dataclass(frozen=True)
class AttitudeRecord:
    """The attitude one navigation frame used, and where it came from.

    Attributes
    ----------
    index : int
    epoch_tdb : float
        [TDB s past J2000].
    source : str
        One of :data:`SOURCES`.
    R_cam_to_inertial : (3, 3) array
    covariance_rad2 : (3, 3) array
        Error covariance, camera axes (z roll) [rad^2].
    star_frame : bool
        A star acquisition was scheduled at this frame.
    reasons : tuple of str
        Why the better sources gave no attitude.
    mode : str
        ``lost-in-space`` or ``tracking`` for a solved frame, else empty.
    stars_matched : int
        Identified stars of the solve (0 otherwise).
    since_solution_s : float
        Age of the solution the attitude comes from [s] (0 for a solved frame).
    error_rad : (3,) array
        Error rotation against the truth, camera axes [rad].
    timings_s : dict
        ``star_exposure`` and ``solve`` [s].
    """

    index: int
    epoch_tdb: float
    source: str
    R_cam_to_inertial: FloatArray
    covariance_rad2: FloatArray
    star_frame: bool
    reasons: tuple[str, ...]
    mode: str
    stars_matched: int
    since_solution_s: float
    error_rad: FloatArray
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def sigma_arcsec(self) -> FloatArray:
        """1-sigma per camera axis (x, y cross-boresight, z roll) [arcsec]."""
        return np.sqrt(np.diag(self.covariance_rad2)) / ARCSEC

    @property
    def nees(self) -> float:
        """``e^T P^-1 e`` of the attitude error (3 dof)."""
        return float(self.error_rad @ np.linalg.solve(self.covariance_rad2, self.error_rad))

    def summary(self) -> dict[str, Any]:
        """JSON-safe row (arcsec)."""
        e = self.error_rad / ARCSEC
        return {"frame": self.index, "source": self.source, "star_frame": self.star_frame,
                "mode": self.mode, "stars_matched": self.stars_matched,
                "since_solution_s": self.since_solution_s,
                "error_cross_arcsec": float(math.hypot(e[0], e[1])),
                "error_roll_arcsec": float(e[2]),
                "sigma_arcsec_xyz": [float(x) for x in self.sigma_arcsec],
                "nees": self.nees, "reasons": list(self.reasons),
                "timings_ms": {k: 1e3 * v for k, v in self.timings_s.items()}}


def assumed_covariance(chain: ChainOptions) -> FloatArray:
    """The chain's assumed attitude covariance [rad^2] (its ``fix.attitude_sigma_rad``: one
    sigma, three, or a 3x3 matrix)."""
    a = np.asarray(chain.fix.attitude_sigma_rad, float)
    if a.ndim == 2:
        return a
    return np.diag(np.broadcast_to(a, (3,)) ** 2)


class StarSolver:
    """Solves one DN frame of a scenario for the tracker's attitude: the Moon's disc and its
    ghosts excluded around its predicted image position (module note), the catalogue at the
    scenario's star epoch (or the frame's), tracking from a prior when one is given and lost
    in space when tracking fails or there is none. The one place where the attitude of a
    frame is solved: the tracker's star and navigation frames, and the exposure study's
    attitude side (:mod:`starnav.batch.tasks`).

    Parameters
    ----------
    camera : Camera
    scenario : Scenario
        ``stars.epoch_jyear``, ``detector`` (gain, saturation, distortion, ghosts).
    """

    def __init__(self, camera: Any, scenario: Any) -> None:
        self.camera, self.scenario = camera, scenario
        self.detector = quiet_timing(scenario.detector).model_copy(
            update={"sensor_seed": sensor_seed_of(scenario)})
        self.catalogue = hipparcos()

    def exclusions(self, geom: FrameGeometry) -> tuple:
        """The Moon's disc and its ghosts around its image position in ``geom``."""
        rel = geom.moon_centre_camera()
        if rel[2] <= 0:
            return ()
        uv = geom.moon_centre_pixel(self.camera,
                                    distort=bool(self.detector.optics.distortion.enabled))
        r_px = self.camera.fx * math.tan(geom.apparent_radius)
        return body_exclusions(uv, r_px, (self.camera.cx, self.camera.cy),
                               self.detector.optics.ghosts.ghosts)

    def observer_velocity(self, geom: FrameGeometry) -> FloatArray | None:
        """The tracker's knowledge of its barycentric velocity [m/s] when it corrects stellar
        aberration (``stars.aberration`` and ``stars.aberration_correction``), else None. It is
        the truth geometry's (DE421 + the camera's velocity relative to the Moon): a knowledge
        error of ``dv`` would leave at most ``|dv| / c`` = 0.69 arcsec per km/s."""
        st = self.scenario.stars
        if not (st.aberration and st.aberration_correction):
            return None
        return observer_velocity(geom)

    def solve(self, dn: Any, geom: FrameGeometry,
              prior: tuple[FloatArray, FloatArray] | None = None) -> AttitudeSolution:
        """The attitude of DN frame ``dn`` taken at ``geom``; ``prior`` = (attitude,
        covariance [rad^2]) for tracking."""
        ex = self.exclusions(geom)
        e = self.scenario.stars.epoch_jyear
        ep = float(e) if e is not None else jyear_from_tdb(float(geom.epoch_tdb))
        kw = dict(epoch_jyear=ep, exclusions=ex, catalogue=self.catalogue,
                  observer_velocity=self.observer_velocity(geom))
        if prior is not None:
            sig = float(np.sqrt(np.max(np.linalg.eigvalsh(prior[1]))))
            sol = solve_attitude(dn, self.camera, self.detector, prior=prior[0],
                                 prior_sigma_rad=sig, **kw)  # type: ignore[arg-type]
            if sol.ok or "candidates detected" in sol.reason:
                return sol
        return solve_attitude(dn, self.camera, self.detector, **kw)  # type: ignore[arg-type]


def frame_attitude_summary(sol: AttitudeSolution, geom: FrameGeometry) -> dict[str, float]:
    """What one solve says about its frame: ``stars_detected`` (accepted centroids),
    ``stars_identified`` (0 unless solved), ``solved`` (0/1), the predicted 1-sigma
    ``sigma_x``, ``sigma_y``, ``sigma_roll`` and the error ``error_x``, ``error_y``,
    ``error_roll`` against the truth, camera axes [rad] (NaN when not solved)."""
    ok = sol.ok and sol.covariance_rad2 is not None and sol.R_cam_to_inertial is not None
    sig = np.sqrt(np.diag(sol.covariance_rad2)) if ok else np.full(3, np.nan)
    err = (error_rotation(sol.R_cam_to_inertial, geom.R_cam_to_inertial) if ok
           else np.full(3, np.nan))
    n_id = sol.identification.n_matched if (ok and sol.identification is not None) else 0
    return {"stars_detected": float(len(sol.centroids)), "stars_identified": float(n_id),
            "solved": float(ok), "sigma_x": float(sig[0]), "sigma_y": float(sig[1]),
            "sigma_roll": float(sig[2]), "error_x": float(err[0]), "error_y": float(err[1]),
            "error_roll": float(err[2])}


class StarAttitudeTracker:
    """The schedule of star acquisitions and the gyro for one run over a sequence of frames
    (module steps 1-4). Frames must be stepped in time order; frame ``i`` has a star
    acquisition when ``i % schedule_every == 0`` (its index, so that a dataset's frames and
    an in-memory run agree).

    Parameters
    ----------
    sim : Simulator
        Camera, scenario (``navigation.attitude``, ``stars``, ``detector``, ``seed``).
    run : int
        Monte Carlo run (its noise and gyro streams).
    scenario : Scenario, optional
        A variant of ``sim.scenario`` (one exposure's overrides); default ``sim.scenario``.

    Raises
    ------
    ConfigError
        ``navigation.attitude.source`` is not ``stars``, or ``stars.enabled`` is false:
        before any frame is made.
    """

    def __init__(self, sim: Simulator, run: int = 0, scenario: Any | None = None) -> None:
        sc = scenario if scenario is not None else sim.scenario
        check_star_attitude(sc)
        si = sc.navigation.attitude.to_si()
        cfg = sc.navigation.attitude
        self.sim, self.scenario, self.run = sim, sc, int(run)
        self.camera = sim.camera
        self.star_exposure = float(si.star_exposure)
        self.every = int(cfg.schedule_every)
        self.navigation_frames = bool(cfg.navigation_frames)
        self.gyro = GyroModel(si.gyro_arw, si.gyro_bias)
        self.errors = GyroErrors(self.gyro, generator(int(sc.seed), STAGE_NAVIGATION, int(run),
                                                      GYRO_STREAM))
        self.solver = StarSolver(self.camera, sc)
        self.detector = self.solver.detector
        self._anchor: tuple[float, FloatArray, FloatArray, FloatArray] | None = None

    # ---------------------------------------------------------------- pieces
    def is_star_frame(self, index: int) -> bool:
        """Frame ``index`` has a star acquisition."""
        return is_star_frame(self.scenario, index)

    def star_exposure_dn(self, radiance: RadianceImage | Any, geom: FrameGeometry
                         ) -> NDArray[np.floating]:
        """The star acquisition's DN frame (module step 1)."""
        return star_acquisition_dn(radiance, geom, self.camera, self.scenario, self.run)

    def _propagated(self, geom: FrameGeometry) -> tuple[FloatArray, FloatArray, float] | None:
        if self._anchor is None:
            return None
        t_a, R_a, P_a, Rt_a = self._anchor
        dt = float(geom.epoch_tdb) - t_a
        g = self.errors.error(float(geom.epoch_tdb))
        R, P = propagate(R_a, P_a, Rt_a, geom.R_cam_to_inertial, dt, self.gyro, g)
        return R, P, dt

    # ---------------------------------------------------------------- the step
    def step(self, radiance: RadianceImage | Any, geom: FrameGeometry,
             acquisition: Acquisition | None, assumed_chain: ChainOptions | None = None
             ) -> AttitudeRecord:
        """The attitude of the next frame (module steps 1-4), its star acquisition exposed
        from ``radiance`` (:meth:`advance` with the frames as DN).

        Parameters
        ----------
        radiance, geom :
            The frame's render and geometry (the star acquisition re-exposes them).
        acquisition : Acquisition or None
            The navigation acquisitions (step 2 reads its segments DN frame).
        assumed_chain : ChainOptions, optional
            For step 4: the assumed sigma (default: the scenario's).
        """
        return self.advance(
            geom, lambda: self.star_exposure_dn(radiance, geom),
            None if acquisition is None else acquisition.segments_exposure.dn,
            None if acquisition is None else float(acquisition.exposure_time), assumed_chain)

    def advance(self, geom: FrameGeometry, star_dn: Callable[[], Any] | Any | None,
                navigation_dn: Any | None, navigation_exposure_s: float | None = None,
                assumed_chain: ChainOptions | None = None) -> AttitudeRecord:
        """The attitude of the next frame from its DN frames (module steps 1-4): the one
        code path of every user-facing run (in memory, a dataset's recorded acquisitions).

        Parameters
        ----------
        geom : FrameGeometry
            The frame's geometry (the gyro measures its true turn; the Moon's exclusion).
        star_dn : array, callable returning one, or None
            The star acquisition's DN frame (read only on a star frame).
        navigation_dn : array or None
            The navigation segments acquisition's DN frame (step 2).
        navigation_exposure_s : float, optional
            Its exposure [s] (for the reasons).
        assumed_chain : ChainOptions, optional
            For step 4: the assumed sigma (default: the scenario's).
        """
        star_frame = self.is_star_frame(int(geom.index))
        prop = self._propagated(geom)
        prior = None if prop is None else (prop[0], prop[1])
        reasons: list[str] = []
        tm: dict[str, float] = {"star_exposure": 0.0, "solve": 0.0}
        sol = None
        source = ""
        if star_frame:
            if star_dn is None:
                raise ConfigError("star acquisition", f"frame {geom.index}",
                                  "the star acquisition's DN frame of a scheduled star frame")
            t0 = time.perf_counter()
            dn = star_dn() if callable(star_dn) else star_dn
            tm["star_exposure"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            s = self.solver.solve(dn, geom, prior)
            tm["solve"] += time.perf_counter() - t0
            if s.ok:
                sol, source = s, "star-frame"
            else:
                reasons.append(f"star frame {self.star_exposure * 1e3:.4g} ms: {s.reason}")
        if sol is None and self.navigation_frames and navigation_dn is not None:
            t0 = time.perf_counter()
            s = self.solver.solve(navigation_dn, geom, prior)
            tm["solve"] += time.perf_counter() - t0
            if s.ok:
                sol, source = s, "navigation-frame"
            else:
                te = (f"{navigation_exposure_s * 1e3:.4g} ms" if navigation_exposure_s
                      is not None else "")
                reasons.append(f"navigation frame {te}: {s.reason}")
        t = float(geom.epoch_tdb)
        if sol is not None:
            R, P = sol.R_cam_to_inertial, sol.covariance_rad2
            self._anchor = (t, R, P, np.asarray(geom.R_cam_to_inertial, float))
            self.errors.reset(t)
            mode, n, age = sol.mode, (sol.identification.n_matched if sol.identification
                                      else 0), 0.0
        elif prop is not None:
            R, P, age = prop
            source, mode, n = "propagated", "", 0
        else:
            chain = assumed_chain if assumed_chain is not None else chain_options(self.scenario)
            R = self.sim.measured_attitude(geom, self.run, int(self.scenario.seed))
            P = assumed_covariance(chain)
            source, mode, n, age = "assumed", "", 0, math.nan
        err = error_rotation(R, geom.R_cam_to_inertial)
        return AttitudeRecord(int(geom.index), t, source, np.asarray(R, float),
                              np.asarray(P, float), star_frame, tuple(reasons), mode, int(n),
                              float(age), err, tm)


def check_star_attitude(scenario: Any) -> None:
    """``navigation.attitude.source`` is ``stars`` and ``stars.enabled`` is true, else a
    :class:`ConfigError` naming the field."""
    cfg = scenario.navigation.attitude
    if cfg.source != "stars":
        raise ConfigError("navigation.attitude.source", cfg.source,
                          "'stars' for a star attitude tracker")
    if not scenario.stars.enabled:
        raise ConfigError("stars.enabled", False, "true when navigation.attitude.source is "
                          "'stars' (the star acquisitions draw the stars section's stars)")


def uses_star_attitude(scenario: Any) -> bool:
    """The scenario navigates with the tracker's own attitude (checked:
    :func:`check_star_attitude`)."""
    if scenario.navigation.attitude.source != "stars":
        return False
    check_star_attitude(scenario)
    return True


def is_star_frame(scenario: Any, index: int) -> bool:
    """Frame ``index`` of a ``source: stars`` scenario has a star acquisition."""
    return int(index) % int(scenario.navigation.attitude.schedule_every) == 0


def star_acquisition_dn(radiance: RadianceImage | Any, geom: FrameGeometry, camera: Any,
                        scenario: Any, run: int = 0) -> NDArray[np.floating]:
    """The star acquisition of frame ``geom`` in run ``run`` (module step 1): the radiance
    exposed at ``navigation.attitude.star_exposure_s`` with the stars drawn, segments mode,
    its own temporal noise stream [DN]."""
    t = float(scenario.navigation.attitude.to_si().star_exposure)
    det = quiet_timing(scenario.detector).model_copy(
        update={"sensor_seed": sensor_seed_of(scenario)})
    stars = star_field(radiance, geom, camera, scenario, t)
    cfg = det.model_copy(update={"readout": det.readout.model_copy(
        update={"windows": (), "modes": ("segments",)})})
    e = expose(radiance, camera, cfg,
               seed=acquisition_seed(int(scenario.seed), int(run), STAR_ACQUISITION),
               frame_index=int(geom.index), exposure_time=t, windows=(),
               point_sources=stars.point_sources() if stars is not None else None)
    return e.dn


def with_attitude(frame: Any, chain: ChainOptions, record: AttitudeRecord
                  ) -> tuple[Any, ChainOptions]:
    """The navigation frame and chain options with the record's attitude and its 3x3
    covariance in the fix (``R_cam_to_inertial_measured``, ``fix.attitude_sigma_rad``)."""
    cov = tuple(tuple(float(x) for x in row) for row in record.covariance_rad2)
    fix = dataclasses.replace(chain.fix, attitude_sigma_rad=cov)
    return (dataclasses.replace(frame, R_cam_to_inertial_measured=record.R_cam_to_inertial),
            dataclasses.replace(chain, fix=fix))
