"""Emulated star-tracker acquisitions of one frame: segments, then windows along the limb.

The AA-STR cannot read a full frame below 200 ms, so the STAR Nav subpixel algorithm
alternates its two readout modes:

1. Acquisition 0 (segments): :func:`starnav.detector.expose` at the exposure time.
2. Window plan: the on-board pixel-level chain on the segments alone, then
   :func:`starnav.navigation.refine.plan_windows` (:func:`plan_windows_from_segments`).
3. Acquisition 1 (windows): the same radiance with its own temporal noise (``"second"``), cut
   from acquisition 0 (``"same"``), or none (:data:`WINDOWS_MODES`); it starts from
   acquisition 0's mean charge.

Random streams are keyed by :mod:`starnav.seeding` (:func:`acquisition_seed`,
:data:`ACQUISITION_STREAM`, :data:`PLAN_STREAM`), independent of the exposure time (common
random numbers across exposures): docs/dataset.md.

Index
-----
:func:`acquire`, :class:`Acquisition`, :func:`plan_windows_from_segments`,
:func:`readout_feasibility`, :func:`check_windows_mode`, :func:`acquisition_seed`,
:func:`sensor_seed_of`, :func:`quiet_timing`, :func:`star_field`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from starnav.config import Scenario, build_camera
from starnav.detector import DetectorConfig, Exposure, Window, expose
from starnav.detector.readout import read_windows, readout_timing
from starnav.detector.schema import WindowSpec
from starnav.errors import ConfigError, UnknownNameError
from starnav.navigation.frames import Frame
from starnav.navigation.pipeline import process_frame
from starnav.navigation.refine import plan_windows
from starnav.radiance import RadianceImage
from starnav.seeding import STAGE_DETECTOR_TEMPORAL, STAGE_NAVIGATION, generator, seed_u32
from starnav.simulate.build import chain_options
from starnav.spectra import sensor_response_from_config
from starnav.stars import StarField, frame_stars

if TYPE_CHECKING:
    from starnav.camera import Camera
    from starnav.geometry import FrameGeometry

log = logging.getLogger(__name__)

WindowsMode = Literal["second", "same", "none"]
#: Known ways of reading the windows (module docstring, step 3).
WINDOWS_MODES: tuple[str, ...] = ("second", "same", "none")

#: Sub-key of the acquisition seeds inside the detector's temporal stage (never change).
ACQUISITION_STREAM = 1000
#: Last key of the window-plan RANSAC stream (never change).
PLAN_STREAM = 1


def check_windows_mode(mode: str) -> WindowsMode:
    """Validate a windows mode name."""
    if mode not in WINDOWS_MODES:
        raise UnknownNameError("windows mode", mode, list(WINDOWS_MODES))
    return mode  # type: ignore[return-value]


def acquisition_seed(seed: int, run: int, acquisition: int) -> int:
    """Dataset seed of acquisition ``acquisition`` of Monte Carlo run ``run`` (the table of
    streams: docs/dataset.md)."""
    if run < 0 or acquisition < 0:
        raise ConfigError("run/acquisition", (run, acquisition), "non-negative integers")
    if run == 0 and acquisition == 0:
        return int(seed)
    return seed_u32(seed, STAGE_DETECTOR_TEMPORAL, ACQUISITION_STREAM, run, acquisition)


def sensor_seed_of(scenario: Scenario) -> int:
    """Seed of the fixed-pattern maps: ``detector.sensor_seed`` or the scenario seed."""
    s = scenario.detector.sensor_seed
    return int(scenario.seed if s is None else s)


def quiet_timing(cfg: DetectorConfig) -> DetectorConfig:
    """``cfg`` with the readout-law policy ``warn`` turned into ``ignore`` (the dataset reports
    infeasible exposures once, in :func:`readout_feasibility`, instead of once per frame);
    ``enforce`` is kept."""
    t = cfg.readout.timing
    if t.policy != "warn":
        return cfg
    readout = cfg.readout.model_copy(update={"timing": t.model_copy(update={"policy": "ignore"})})
    return cfg.model_copy(update={"readout": readout})


def readout_feasibility(scenario: Scenario, exposure_time: float) -> list[dict[str, Any]]:
    """Readout-law check of the two acquisitions at ``exposure_time`` [s] (seed paper eq. 1).

    Returns one dict per readout (``mode``, ``n_pixels``, ``min_exposure_s``, ``feasible``):
    the segments readout scans the whole array; the windows readout reads
    ``n_windows x window_size_px^2`` pixels.
    """
    cam = build_camera(scenario.camera)
    shape = (cam.height, cam.width)
    timing = scenario.detector.readout.timing
    r = scenario.navigation.refine
    s = min(r.window_size_px, cam.height, cam.width)
    wins = [WindowSpec(row0=0, col0=0, height=s, width=s)] * r.n_windows
    return [readout_timing("segments", shape, exposure_time, timing).to_dict(),
            readout_timing("windows", shape, exposure_time, timing, wins).to_dict()]


@dataclass(frozen=True)
class Acquisition:
    """The emulated readouts of one frame at one exposure time.

    Attributes
    ----------
    exposure_time : float
        Exposure time [s].
    run : int
        Monte Carlo run (0 for datasets).
    segments_exposure : Exposure
        Acquisition 0: DN frame, segments, charge ledger, readout timing.
    windows : tuple of Window
        The windows read (empty when none could be planned or ``windows_mode == "none"``).
    windows_exposure : Exposure or None
        Acquisition 1 when ``windows_mode == "second"`` and windows were planned.
    windows_mode : str
        ``second``, ``same`` or ``none``.
    plan_status, plan_message : str
        ``ok`` or why no window was planned (e.g. ``no-moon``), and the reason in words.
    planned : tuple of (row0, col0, height, width)
        Window requests [px].
    timings_s : dict
        Wall time of ``detector`` (both acquisitions), ``plan`` and ``stars`` [s].
    stars : StarField or None
        The frame's true stars when ``stars.enabled`` (:func:`starnav.stars.frame_stars`).
    """

    exposure_time: float
    run: int
    segments_exposure: Exposure
    windows: tuple[Window, ...]
    windows_exposure: Exposure | None
    windows_mode: str
    plan_status: str
    plan_message: str
    planned: tuple[tuple[int, int, int, int], ...]
    timings_s: dict[str, float]
    stars: StarField | None = None

    @property
    def segments(self):
        """Segments of acquisition 0."""
        return self.segments_exposure.segments

    def summary(self) -> dict[str, Any]:
        """JSON-safe, deterministic description (no wall-clock times): what ``readout.json``
        stores."""
        def acq(e: Exposure, role: str, index: int) -> dict[str, Any]:
            s = e.summary()
            s.pop("effect_time_ms", None)
            return {"acquisition": index, "role": role, **s}

        acqs = [acq(self.segments_exposure, "segments", 0)]
        if self.windows_exposure is not None:
            acqs.append(acq(self.windows_exposure, "windows", 1))
        out = {
            "format": "starnav-readout",
            "version": 1,
            "exposure_s": self.exposure_time,
            "run": self.run,
            "windows_mode": self.windows_mode,
            "windows_acquisition": (1 if self.windows_exposure is not None
                                    else (0 if self.windows else None)),
            "window_plan": {
                "status": self.plan_status,
                "message": self.plan_message,
                "method": "segments of acquisition 0 -> navigation limb scan (measured "
                          "attitude) -> RANSAC -> navigation.refine.plan_windows",
                "windows_row0_col0_height_width": [list(p) for p in self.planned],
            },
            "acquisitions": acqs,
            "feasible": all(e.feasible for e in
                            [self.segments_exposure]
                            + ([self.windows_exposure] if self.windows_exposure else [])),
        }
        if self.stars is not None:  # absent when stars are off: the file stays as it was
            vis = self.stars.visible()
            out["stars"] = {"count_in_frame": len(vis),
                            "magnitude_limit_brightest_v": (float(vis.v.min()) if len(vis)
                                                            else None)}
        return out


def plan_windows_from_segments(segments: Any, geom: FrameGeometry, camera: Camera,
                               scenario: Scenario, rng: np.random.Generator
                               ) -> tuple[str, str, list[tuple[int, int, int, int]]]:
    """On-board window plan from one segments readout (module step 2).

    Returns
    -------
    status, message, windows
        ``("ok", "", [(row0, col0, height, width), ...])`` or the chain's failure status.
    """
    chain = chain_options(scenario)
    chain = dataclasses.replace(chain, use_windows=False)
    R_meas = geom.R_cam_to_inertial_known
    frame = Frame(index=int(geom.index), epoch_tdb=float(geom.epoch_tdb),
                  R_cam_to_inertial_measured=R_meas, sun_direction_inertial=geom.sun_position,
                  segments=segments, windows=(), truth=None)
    m = process_frame(frame, camera, options=chain, rng=rng)
    if m.limb is None or m.inliers is None or not np.any(m.inliers):
        return m.status, m.message or "no limb in the segments", []
    pts = m.limb.uv[m.inliers]
    reqs = plan_windows(pts, m.limb.centre_px, shape=(camera.height, camera.width),
                        options=chain.refine)
    wins = [(int(q.row0), int(q.col0), int(q.height), int(q.width)) for q in reqs]
    if not wins:
        return "no-windows", "the window planner returned no window", []
    return "ok", "", wins


def acquire(radiance: RadianceImage | Any, geom: FrameGeometry, camera: Camera,
            scenario: Scenario, *, exposure_time: float | None = None, run: int = 0,
            windows: str = "second") -> Acquisition:
    """Emulate the segments acquisition, the window plan and the windows acquisition of one
    frame (module steps 1-3).

    Parameters
    ----------
    radiance : RadianceImage or (H, W) array
        The rendered frame (its ``Le`` is used) or an electron radiance
        [e- s^-1 m^-2 sr^-1].
    geom : FrameGeometry
        The frame's geometry: ``index`` selects the noise streams; the measured attitude and
        the Sun position drive the on-board limb scan.
    camera : Camera
    scenario : Scenario
        ``seed``, ``detector`` and ``navigation`` (limb scan, RANSAC, window plan) are used.
    exposure_time : float, optional
        Exposure time [s]; default ``detector.exposure_time_s``.
    run : int
        Monte Carlo run (0: the dataset's streams).
    windows : {"second", "same", "none"}
        How the windows are read (module step 3).
    """
    mode = check_windows_mode(windows)
    t_exp = float(scenario.detector.exposure_time_s if exposure_time is None else exposure_time)
    seed = int(scenario.seed)
    index = int(geom.index)
    cfg = quiet_timing(scenario.detector).model_copy(
        update={"sensor_seed": sensor_seed_of(scenario)})
    cfg0 = cfg.model_copy(update={"readout": cfg.readout.model_copy(
        update={"windows": (), "modes": tuple(m for m in cfg.readout.modes if m != "windows")
                or ("segments",)})})
    t0 = time.perf_counter()
    stars = star_field(radiance, geom, camera, scenario, t_exp)
    t_stars = time.perf_counter() - t0
    sources = stars.point_sources() if stars is not None else None
    t0 = time.perf_counter()
    e0 = expose(radiance, camera, cfg0, seed=acquisition_seed(seed, run, 0), frame_index=index,
                exposure_time=t_exp, windows=(), point_sources=sources,
                keep_mean_charge=mode == "second")
    t_det = time.perf_counter() - t0
    status, message, planned = "skipped", "windows mode 'none'", []
    t_plan = 0.0
    wins: tuple[Window, ...] = ()
    e1 = None
    if mode != "none":
        t0 = time.perf_counter()
        if e0.segments is None:
            status, message = "no-segments", "the segments readout is not enabled"
        else:
            rng = generator(seed, STAGE_NAVIGATION, run, index, PLAN_STREAM)
            status, message, planned = plan_windows_from_segments(e0.segments, geom, camera,
                                                                  scenario, rng)
        t_plan = time.perf_counter() - t0
        if planned:
            if mode == "same":
                wins = read_windows(e0.dn, planned)
            else:
                cfg1 = cfg.model_copy(update={"readout": cfg.readout.model_copy(
                    update={"modes": ("windows",), "windows": ()})})
                t0 = time.perf_counter()
                e1 = expose(radiance, camera, cfg1, seed=acquisition_seed(seed, run, 1),
                            frame_index=index, exposure_time=t_exp, windows=planned,
                            point_sources=sources, mean_charge=e0.mean_charge)
                t_det += time.perf_counter() - t0
                wins = e1.windows
    e0.mean_charge = None   # (4 MB; the acquisitions are made)
    if status != "ok":
        log.debug("frame %d, %.4g ms: no windows (%s: %s)", index, t_exp * 1e3, status, message)
    return Acquisition(exposure_time=t_exp, run=int(run), segments_exposure=e0, windows=wins,
                       windows_exposure=e1, windows_mode=mode, plan_status=status,
                       plan_message=message, planned=tuple(tuple(p) for p in planned),
                       timings_s={"detector": t_det, "plan": t_plan, "stars": t_stars},
                       stars=stars)


def star_field(radiance: RadianceImage | Any, geom: FrameGeometry, camera: Camera,
               scenario: Scenario, exposure_time: float) -> StarField | None:
    """The frame's stars when ``scenario.stars.enabled`` (else None): the scenario's sensor
    response and detector, the renderer's hit mask occulting them
    (:func:`starnav.stars.frame_stars`)."""
    if not scenario.stars.enabled:
        return None
    return frame_stars(geom, camera, scenario.stars,
                       sensor_response_from_config(scenario.sensor_response),
                       exposure_time=exposure_time, detector=scenario.detector,
                       radiance=radiance if isinstance(radiance, RadianceImage) else None)
