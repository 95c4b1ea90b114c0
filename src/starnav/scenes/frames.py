"""Per-frame geometry and truth: epochs, trajectory, ephemeris, pointing.

1. The trajectory (:func:`build_trajectory`): the LUMIO-like halo arc or an OEM file,
   EMB-centred J2000 at TDB epochs.
2. Frame epochs every ``cadence_s`` inside the arc.
3. At each epoch the spacecraft (Hermite interpolation), Moon and Sun (DE421), the relative
   states and the Moon's orientation.
4. Attitude (:mod:`starnav.scenes.pointing`) from the frame's own generators: any frame is the
   same whatever the order or subset built.
5. A small-body fly-by has no ephemeris: body-centred truth from its closed form
   (:attr:`Scene.relative_states`).
6. Without a trajectory, the static ``geometry`` gives one frame.

Positions are geometric (no light time or aberration: the Moon's 0.2 s light time is a
hundredth of a pixel at 60 000 km).

Index
-----
:class:`Scene`, :func:`build_trajectory`, :func:`truth_force_model`,
:func:`trajectory_summary`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from starnav.cache import BoundedCache
from starnav.constants import DAY, MOON_RADIUS
from starnav.errors import ConfigError, GeometryError
from starnav.geometry import FrameGeometry, StaticGeometryConfig, static_geometry_from_config
from starnav.scenes.cr3bp import LU
from starnav.scenes.dynamics import PointMassModel
from starnav.scenes.ephemeris import Ephemeris, parse_epoch
from starnav.scenes.flyby import Flyby, flyby_from_config
from starnav.scenes.forces import SrpParameters, TruthForceModel
from starnav.scenes.oem import check_continuous, check_outside_moon, read_oem, tdb_to_iso
from starnav.scenes.pointing import frame_generators, pointing_from_config, rotation_from_vector
from starnav.scenes.schema import (
    DEFAULT_EPOCH,
    FlybyConfig,
    PointingConfig,
    SpacecraftConfig,
    TrajectoryConfig,
)
from starnav.scenes.trajectory import ShootingOptions, Trajectory, ephemeris_halo_arc
from starnav.typing import FloatArray

if TYPE_CHECKING:
    from starnav.camera import Camera

log = logging.getLogger(__name__)

#: Halo arcs built in this process (the shooting takes seconds), by every input.
_ARC_MEMO: BoundedCache[tuple, Trajectory] = BoundedCache(8, policy="fifo")


def truth_force_model(cfg: TrajectoryConfig, ephemeris: Ephemeris,
                      spacecraft: SpacecraftConfig | None = None) -> PointMassModel:
    """The truth arc's force model: the filter's point masses, plus what
    ``cfg.forces`` switches on (:class:`~starnav.scenes.forces.TruthForceModel`)."""
    f = cfg.forces
    if not (f.planets or f.srp or f.j2):
        return PointMassModel(ephemeris)
    sc = spacecraft if spacecraft is not None else SpacecraftConfig()
    srp = SrpParameters(sc.area_m2, sc.mass_kg, sc.reflectivity) if f.srp else None
    return TruthForceModel(ephemeris, planets=f.planets, srp=srp, eclipses=f.eclipses, j2=f.j2)


def build_trajectory(cfg: TrajectoryConfig, ephemeris: Ephemeris | None = None,
                     cache_dir: str | Path | None = None,
                     spacecraft: SpacecraftConfig | None = None) -> Trajectory:
    """The trajectory a ``trajectory`` section describes (SI, EMB-centred J2000, TDB).

    Parameters
    ----------
    cfg : TrajectoryConfig
    ephemeris : Ephemeris, optional
        Default DE421.
    cache_dir : path, optional
        Keep the halo arc on disk there (it takes about a second to build; also memoised in
        this process).
    spacecraft : SpacecraftConfig, optional
        Mass, area and reflectivity for ``cfg.forces.srp`` (default its defaults).

    Raises
    ------
    ConfigError, EphemerisRangeError, OEMFormatError, ConvergenceError
    """
    eph = ephemeris or Ephemeris.default()
    if cfg.source == "flyby":
        raise ConfigError("trajectory.source", "flyby", "a halo or OEM arc here: a fly-by has "
                          "no EMB-centred trajectory (starnav.scenes.flyby, Scene)")
    if cfg.source == "oem":
        traj = read_oem(cfg.oem_path, ephemeris=eph)  # type: ignore[arg-type]
        t0 = traj.t_start if cfg.epoch is None else parse_epoch(cfg.epoch, "trajectory.epoch")
        t1 = min(traj.t_end, t0 + cfg.to_si().duration)
        if not (traj.t_start - 1e-6 <= t0 < traj.t_end):
            raise ConfigError("trajectory.epoch", cfg.epoch,
                              f"an epoch inside the OEM span ({traj.t_start:.3f}.."
                              f"{traj.t_end:.3f} s TDB)")
        inside = (traj.times > t0) & (traj.times < t1)
        ts = np.concatenate([[t0], traj.times[inside], [t1]])
        used = Trajectory(ts, traj.sample(ts), traj.object_name, dict(traj.meta))
        check_outside_moon(used, f"OEM file {str(cfg.oem_path)!r}", eph)
        check_continuous(used, f"OEM file {str(cfg.oem_path)!r}")
        return used

    t0 = parse_epoch(cfg.epoch or DEFAULT_EPOCH, "trajectory.epoch")
    model = truth_force_model(cfg, eph, spacecraft)
    si = cfg.to_si()
    options = ShootingOptions(segment=si.shooting_segment, step=si.step,
                              range_min=si.range_min, range_max=si.range_max)
    memo_key = (eph.directory, t0, si.duration, si.halo_z0, si.halo_phase, options,
                repr(sorted(model.key().items())))
    return _ARC_MEMO.get_or_make(memo_key, lambda: ephemeris_halo_arc(
        model, t0, si.duration, z0=si.halo_z0 / LU,
        phase=cfg.halo_phase_deg / 360.0, options=options,  # unit: turns, exact
        cache_dir=cache_dir if cache_dir is not None else False))


class Scene:
    """Frames of a trajectory (or of one static geometry): epochs, spacecraft truth and
    :class:`FrameGeometry` per frame (assembled from a scenario by
    :func:`starnav.simulate.scene_from_scenario`).

    Parameters
    ----------
    camera : Camera
    pointing : PointingConfig
    trajectory : TrajectoryConfig, optional
        The arc and the frame cadence; ``None`` (and no ``arc``) gives one frame of ``static``.
    static : StaticGeometryConfig, optional
        The one frame without a trajectory.
    body_radius : float
        Reference radius of the target body [m] (its bounding sphere for a small body).
    seed : int
        Scenario seed (per-frame pointing streams, :func:`frame_generators`).
    ephemeris : Ephemeris, optional
        Default DE421.
    arc : Trajectory, optional
        Use this instead of building ``trajectory``'s.
    cache_dir, spacecraft : optional
        Forwarded to :func:`build_trajectory`.
    orientation : callable, optional
        ``f(epochs) -> (n, 3, 3)`` body-fixed -> J2000 rotations of the target body; default
        the Moon's DE421 librations in ``trajectory.moon_frame`` axes.
    gm : float
        The target body's gravitational parameter [m^3 s^-2] (a hyperbolic fly-by).
    """

    def __init__(self, camera: Camera, pointing: PointingConfig, *,
                 trajectory: TrajectoryConfig | None = None,
                 static: StaticGeometryConfig | None = None,
                 body_radius: float = MOON_RADIUS, seed: int = 0,
                 ephemeris: Ephemeris | None = None, arc: Trajectory | None = None,
                 cache_dir: str | Path | None = None,
                 orientation: Callable[[FloatArray], FloatArray] | None = None,
                 gm: float = 0.0, spacecraft: SpacecraftConfig | None = None) -> None:
        self.camera = camera
        self.pointing = pointing
        self.static_config = static if static is not None else StaticGeometryConfig()
        self.body_radius = float(body_radius)
        self.seed = int(seed)
        self.ephemeris = ephemeris or Ephemeris.default()
        cfg = trajectory
        self.static = cfg is None and arc is None
        self.flyby: Flyby | None = None
        # the Earth, for its shadow: from the ephemeris (none for static and fly-by frames)
        self._earth: FloatArray | None = None
        if self.static:
            self.trajectory = None
            self.epochs = np.zeros(1)
            self._states = None
            return
        cfg = cfg or TrajectoryConfig()
        if cfg.source == "flyby" and arc is None:
            self._init_flyby(cfg, orientation, gm)
            return
        self.trajectory = arc or build_trajectory(cfg, self.ephemeris, cache_dir, spacecraft)
        start = self.trajectory.t_start + cfg.frame_offset_s
        if start > self.trajectory.t_end:
            raise ConfigError("trajectory.frame_offset_s", cfg.frame_offset_s,
                              f"an offset within the arc ({self.trajectory.duration:.0f} s)")
        self.epochs = self.trajectory.epochs_at_cadence(cfg.cadence_s, start, cfg.frames)
        self._states = self.trajectory.sample(self.epochs)
        self._moon = self.ephemeris.state("moon", self.epochs, center="emb")
        self._sun = self.ephemeris.state("sun", self.epochs, center="emb")
        self._earth = self.ephemeris.state("earth", self.epochs, center="emb")
        self._R_body = (orientation(self.epochs) if orientation is not None else
                        self.ephemeris.moon_orientation(self.epochs, frame=cfg.moon_frame))
        # between the arc's nodes too: no frame is taken from inside the target
        r = np.linalg.norm(self._states[:, :3] - self._moon[:, :3], axis=1)
        bad = np.flatnonzero(r < self.body_radius)
        if bad.size:
            k = int(bad[0])
            raise GeometryError(
                f"trajectory ({self.trajectory.meta.get('source', cfg.source)}): frame {k} at "
                f"{tdb_to_iso(float(self.epochs[k]), 3)} TDB is {r[k] / 1e3:.0f} km from the "
                f"target's centre, inside it: expected every frame at least its radius "
                f"({self.body_radius / 1e3:.1f} km) from its centre")

    def _init_flyby(self, cfg: TrajectoryConfig, orientation, gm: float) -> None:
        """Epochs, relative states, Sun and body orientation of a fly-by (step 5)."""
        if orientation is None:
            raise ConfigError("trajectory.source", "flyby",
                              "a small-body target (target.kind: shape_model or ellipsoid)")
        fc = cfg.flyby or FlybyConfig()
        t_ca = parse_epoch(cfg.epoch or DEFAULT_EPOCH, "trajectory.epoch")
        self.trajectory = None
        self.flyby = flyby_from_config(fc, t_ca, gm)
        self.epochs = self.flyby.frame_epochs(fc.start_s, fc.end_s, cfg.cadence_s, cfg.frames)
        rel = self.flyby.states(self.epochs)
        if self.flyby.closest_approach <= self.body_radius:
            raise ConfigError("trajectory.flyby.closest_approach_km",
                              fc.closest_approach_km,  # unit: the user's value, quoted
                              f"a closest approach outside the body's bounding sphere "
                              f"({self.body_radius / 1e3:.4g} km)")
        self._states = None
        self._relative = rel
        n = self.epochs.size
        self._moon = np.zeros((n, 6))
        self._sun = np.tile(np.concatenate([self.flyby.sun_position, np.zeros(3)]), (n, 1))
        self._R_body = np.asarray(orientation(self.epochs))

    def __len__(self) -> int:
        return int(self.epochs.size)

    @property
    def relative_states(self) -> FloatArray:
        """Spacecraft states relative to the target body ``(n, 6)``, J2000 axes [m, m/s]:
        the truth of a fly-by's navigation (for a trajectory: relative to the Moon)."""
        if self.flyby is not None:
            return self._relative
        if self._states is None:
            raise ConfigError("trajectory", None, "a trajectory section for relative states")
        return self._states - self._moon

    @property
    def states_emb(self) -> FloatArray:
        """Spacecraft states ``(n, 6)``, EMB-centred J2000 [m, m/s] (navigation truth).

        Raises
        ------
        ConfigError
            For a static scene (no trajectory).
        """
        if self.flyby is not None:
            raise ConfigError("trajectory.source", "flyby", "a halo or OEM trajectory for "
                              "EMB-centred states (a fly-by has Scene.relative_states)")
        if self._states is None:
            raise ConfigError("trajectory", None, "a trajectory section for EMB-centred states")
        return self._states

    def geometry(self, index: int) -> FrameGeometry:
        """:class:`FrameGeometry` of frame ``index`` (Moon-centred SI; see starnav.geometry)."""
        n = len(self)
        if not (0 <= int(index) < n):
            raise ConfigError("frame index", index, f"0 <= index < {n}")
        i = int(index)
        pc = self.pointing
        if self.static:
            g = static_geometry_from_config(self.camera, self.static_config, self.body_radius)
            _, krng = frame_generators(self.seed, i)
            err = krng.standard_normal(3) * np.array(pc.knowledge_sigma)
            return FrameGeometry(
                camera_position=g.camera_position, R_cam_to_inertial=g.R_cam_to_inertial,
                sun_position=g.sun_position, R_body_to_inertial=g.R_body_to_inertial,
                epoch_tdb=g.epoch_tdb, camera_velocity=g.camera_velocity,
                R_cam_to_inertial_measured=g.R_cam_to_inertial @ rotation_from_vector(err),
                body_radius=g.body_radius, index=i)
        rel = self.relative_states[i]
        sun = self._sun[i, :3] - self._moon[i, :3]
        # a fly-by rolls about its plane's normal: north-up flips where the line of sight
        # passes the pole (starnav.scenes.pointing, step 3)
        p = pointing_from_config(self.camera, rel[:3], pc, self.seed, i,
                                 body_radius=self.body_radius, sun_position=sun,
                                 down_hint=None if self.flyby is None else self.flyby.z_hat)
        return FrameGeometry(
            camera_position=rel[:3], R_cam_to_inertial=p.R_true, sun_position=sun,
            R_body_to_inertial=self._R_body[i], epoch_tdb=float(self.epochs[i]),
            camera_velocity=rel[3:], R_cam_to_inertial_measured=p.R_measured,
            body_radius=self.body_radius, index=i,
            camera_state_emb=None if self._states is None else self._states[i],
            earth_position=(None if self._earth is None
                            else self._earth[i, :3] - self._moon[i, :3]))

    def geometries(self, indices: list[int] | range | None = None) -> list[FrameGeometry]:
        """Geometries of ``indices`` (default all frames)."""
        idx = range(len(self)) if indices is None else indices
        return [self.geometry(i) for i in idx]

    def __iter__(self) -> Iterator[FrameGeometry]:
        for i in range(len(self)):
            yield self.geometry(i)


def trajectory_summary(traj: Trajectory, ephemeris: Ephemeris | None = None) -> dict[str, float]:
    """Moon range, EMB-centred inertial speed and phase-angle extremes of a trajectory
    (SI: m, m/s, rad; times in TDB s)."""
    eph = ephemeris or Ephemeris.default()
    moon = eph.state("moon", traj.times, center="emb")
    sun = eph.state("sun", traj.times, center="emb")
    rel = traj.states - moon
    rng = np.linalg.norm(rel[:, :3], axis=1)
    sm = sun[:, :3] - moon[:, :3]
    cosp = np.einsum("ij,ij->i", sm, rel[:, :3]) / (np.linalg.norm(sm, axis=1) * rng)
    phase = np.arccos(np.clip(cosp, -1.0, 1.0))
    speed = np.linalg.norm(traj.states[:, 3:], axis=1)
    return {"t_start": traj.t_start, "t_end": traj.t_end, "nodes": float(len(traj)),
            "moon_range_min": float(rng.min()), "moon_range_max": float(rng.max()),
            "emb_speed_min": float(speed.min()), "emb_speed_max": float(speed.max()),
            "phase_min": float(phase.min()), "phase_max": float(phase.max()),
            "duration_days": traj.duration / DAY}
