"""Dataset generation: render, expose and read out every frame of a scenario, crash-safe and
resumable, byte-identical for one seed whatever the number of workers or interruptions.

Technique
---------
1. Validate the scenario, exposures, windows mode and output directory before writing.
2. Write the manifest's head (everything frame-independent, ``"complete": false``) and
   ``scenario.resolved.yaml``.
3. One frame = one task (:func:`make_frame`): render and expose into a temporary directory,
   renamed whole (a frame is on disk whole or not at all); in-process, :data:`FRAME_THREADS`
   frames at once, landing in index order.
4. Rewrite the manifest atomically as frames land; the last write sets ``"complete": true``
   only if the whole dataset verifies. Files and directories are fsynced (:mod:`starnav.atomic`).
5. Resume: same head required; whole frames kept, the others made again: byte-identical to an
   uninterrupted run.

A lock file (:data:`LOCK`, ``flock``) stops two processes from writing one dataset. A fly-by
scenario stores per frame the radiance with its AOVs and its truth, no exposures (its windows
follow the tracks of each Monte Carlo run): docs/dataset.md.

Index
-----
:func:`generate`, :class:`DatasetOptions`, :class:`DatasetSummary`, :class:`FrameMaker`,
:func:`frame_maker`, :func:`make_frame`, :func:`dataset_head`, :func:`manifest`,
:func:`frame_entry`, :func:`camera_to_manifest`, :func:`check_output_dir`,
:class:`DatasetLockedError`.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from starnav import __version__
from starnav.atomic import current_umask, sync_directory
from starnav.cache import BoundedCache
from starnav.config import (
    Scenario,
    build_camera,
    scenario_from_dict,
    scenario_to_dict,
    write_resolved,
)
from starnav.dataset import format as F
from starnav.dataset.reader import verify_manifest
from starnav.dataset.runner import InProcessRunner, TaskRunner
from starnav.detector.io import write_dn_png
from starnav.errors import ConfigError, DataFileError, StarnavError
from starnav.quicklook import write_dn_quicklook, write_radiance_quicklook
from starnav.radiance import write_exr
from starnav.renderer import backend
from starnav.simulate import (
    Simulator,
    body_from_scenario,
    check_windows_mode,
    readout_feasibility,
    scene_from_scenario,
)
from starnav.simulate.acquire import sensor_seed_of
from starnav.simulate.attitude import is_star_frame, star_acquisition_dn, uses_star_attitude
from starnav.simulate.flyby import check_flyby_scenario, is_flyby_scenario
from starnav.spectra import (
    band_integrals,
    sensor_response_from_config,
    solar_spectrum_from_config,
)

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

#: ``options.windows`` of a fly-by dataset: the windows are placed by the closed loop.
FLYBY_WINDOWS = "closed-loop"
#: ``target_kind`` of a fly-by dataset's manifest (a limb dataset's manifest has no such key).
FLYBY_KIND = "flyby"

#: Frames made at once by in-process generation (:meth:`FrameMaker.making_ahead`): the
#: machine's cores, at most 2 (the demo dataset's peak RSS with 2: 1.08-1.18 GB; 0.74 GB
#: before, one frame at a time; docs/performance.md).
FRAME_THREADS = max(1, min(2, os.cpu_count() or 1))

#: Default minimum time between two manifest rewrites while frames land [s].
MANIFEST_INTERVAL_S = 2.0
LOCK = ".lock"


class DatasetLockedError(StarnavError, RuntimeError):
    """Another process is writing the dataset."""


# ============================================================================ options
@dataclass(frozen=True)
class DatasetOptions:
    """What a dataset stores besides the scenario.

    Attributes
    ----------
    exposures_s : tuple of float, optional
        Exposure times [s], each in its own ``exposure_<ms>ms`` directory; default the
        scenario's ``detector.exposure_time_s``.
    windows : {"second", "same", "none"}
        How the windows are read (:mod:`starnav.simulate.acquire`, step 3).
    radiance : bool
        Store ``radiance.exr`` (the renderer's output, with AOVs if ``render.aovs``).
    limb_points : int
        Points of the true limb stored in ``truth.json``.
    exposure_overrides : tuple of (exposure_time, tuple of str)
        ``--set``-style overrides of ``detector.*`` / ``navigation.*`` keys for one exposure
        (e.g. a higher segment threshold for a saturated exposure, as the paper tuned its image
        processing to each scenario).
    """

    exposures_s: tuple[float, ...] | None = None
    windows: str = "second"
    radiance: bool = True
    limb_points: int = 360
    exposure_overrides: tuple[tuple[float, tuple[str, ...]], ...] = ()

    def resolved(self, scenario: Scenario) -> DatasetOptions:
        """Validated options with the exposures filled in (a fly-by: no exposure, windows
        ``closed-loop``, radiance stored; module "Fly-by datasets")."""
        if is_flyby_scenario(scenario):
            check_flyby_scenario(scenario)
            return self._resolved_flyby()
        exps = (scenario.detector.exposure_time_s,) if self.exposures_s is None \
            else self.exposures_s
        check_windows_mode(self.windows)
        if not (isinstance(self.limb_points, int) and 8 <= self.limb_points <= 100_000):
            raise ConfigError("limb_points", self.limb_points, "an integer in 8..100000")
        exps = F.check_exposures(exps)
        over = []
        for t, items in self.exposure_overrides:
            match = [e for e in exps if abs(e - float(t)) <= 1e-9 * abs(e)]
            if not match:
                raise ConfigError("exposure_overrides", t, "one of the exposures "
                                  + ", ".join(repr(e) for e in exps))
            for it in items:
                key = str(it).split("=", 1)[0].strip()
                if not key.startswith(("detector.", "navigation.")) or "=" not in str(it):
                    raise ConfigError("exposure_overrides", it, "KEY=VALUE with a detector.* "
                                      "or navigation.* key (what acts after the renderer)")
            over.append((match[0], tuple(str(i) for i in items)))
        out = DatasetOptions(exps, self.windows, bool(self.radiance), int(self.limb_points),
                             tuple(sorted(over)))
        for t in exps:
            out.scenario_for(scenario, t)  # validates the overrides
        return out

    def _resolved_flyby(self) -> DatasetOptions:
        why = ("a fly-by dataset stores the radiance and the truth only: the closed loop "
               "exposes its segments and windows at navigate time")
        if self.exposures_s not in (None, ()):
            raise ConfigError("exposures", list(self.exposures_s),
                              f"none for a fly-by ({why}; its exposure is "
                              "detector.exposure_time_s)")
        if self.exposure_overrides:
            raise ConfigError("exposure_overrides", [t for t, _ in self.exposure_overrides],
                              f"none for a fly-by ({why})")
        if self.windows not in ("second", FLYBY_WINDOWS):
            raise ConfigError("windows", self.windows, f"the default for a fly-by ({why})")
        if not self.radiance:
            raise ConfigError("radiance", False, f"stored for a fly-by ({why}, from it)")
        if not (isinstance(self.limb_points, int) and 8 <= self.limb_points <= 100_000):
            raise ConfigError("limb_points", self.limb_points, "an integer in 8..100000")
        return DatasetOptions((), FLYBY_WINDOWS, True, int(self.limb_points), ())

    def overrides_for(self, exposure_time: float) -> tuple[str, ...]:
        """The overrides of one exposure (empty if none)."""
        for t, items in self.exposure_overrides:
            if abs(t - exposure_time) <= 1e-9 * abs(t):
                return items
        return ()

    def scenario_for(self, scenario: Scenario, exposure_time: float) -> Scenario:
        """``scenario`` with the overrides of ``exposure_time`` applied."""
        items = self.overrides_for(exposure_time)
        if not items:
            return scenario

        try:
            return scenario_from_dict(scenario_to_dict(scenario), list(items))
        except ConfigError as err:
            raise ConfigError(f"exposure_overrides[{exposure_time!r}]: {err.field}", err.value,
                              err.expected) from None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["exposures_s"] = list(d["exposures_s"]) if d["exposures_s"] is not None else None
        d["exposure_overrides"] = [[t, list(i)] for t, i in self.exposure_overrides]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DatasetOptions:
        e = d.get("exposures_s")
        over = tuple((float(t), tuple(str(x) for x in i))
                     for t, i in d.get("exposure_overrides", ()))
        return cls(None if e is None else tuple(float(x) for x in e), str(d["windows"]),
                   bool(d["radiance"]), int(d["limb_points"]), over)


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`generate` did.

    Attributes
    ----------
    path : Path
    frames, frames_made : int
        Frames in the dataset; made by this call (the others were there: resume).
    exposures_s : tuple of float
    elapsed_s, setup_s : float
        Wall time of this call, and of its set-up (validation, trajectory, backend, manifest) [s].
    frames_per_s : float
        ``frames_made / time spent making them`` [1/s].
    per_exposure : dict
        Per exposure directory: median saturated pixels, fraction of frames with windows
        planned, whether the readout law allows the exposure.
    runner : str
    """

    path: Path
    frames: int
    frames_made: int
    exposures_s: tuple[float, ...]
    elapsed_s: float
    frames_per_s: float
    setup_s: float
    per_exposure: dict[str, dict[str, Any]] = field(default_factory=dict)
    runner: str = ""


# ============================================================================ head
def _canonical_key(*parts: Any) -> str:
    return hashlib.sha256(F.dumps(list(parts), compact=True).encode()).hexdigest()[:16]


def dataset_head(scenario: Scenario, options: DatasetOptions, n_frames: int) -> dict[str, Any]:
    """The frame-independent part of the manifest (module step 2); deterministic."""
    sc = scenario
    opts = options.resolved(sc)
    info = backend.activate(tuple(sc.render.variants))
    cam = build_camera(sc.camera)
    band = band_integrals(solar_spectrum_from_config(sc.sun),
                          sensor_response_from_config(sc.sensor_response))
    exposures = []
    for t in opts.exposures_s or ():
        exposures.append({"exposure_s": t, "directory": F.exposure_dirname(t),
                          "overrides": list(opts.overrides_for(t)),
                          "readout_law": readout_feasibility(opts.scenario_for(sc, t), t)})
    head = {
        "schema": F.SCHEMA,
        "schema_version": F.SCHEMA_VERSION,
        "software": {"starnav": __version__, "mitsuba": info.mitsuba_version,
                     "drjit": info.drjit_version, "variant": info.variant,
                     "numpy": np.__version__},
        "config": scenario_to_dict(sc),
        "options": opts.to_dict(),
        "camera": camera_to_manifest(cam),
        "target": body_from_scenario(sc).describe(),
        "sun": {"spectrum": sc.sun.spectrum,
                "band_irradiance_1au_w_m2": band.irradiance,
                "band_electron_irradiance_1au_e_s_m2": band.electron_irradiance,
                "band_nm": list(band.band_nm)},
        "seeds": {"seed": sc.seed, "sensor_seed": sensor_seed_of(sc),
                  "render": "seed_u32(seed, STAGE_RENDER=1, frame)",
                  "pointing": "starnav.scenes.pointing.frame_generators(seed, frame)",
                  "acquisitions": "starnav.simulate.acquire.acquisition_seed(seed, run=0, a)"},
        "exposures": exposures,
        "frames_expected": int(n_frames),
        "layout": {"frames": f"{F.FRAMES_DIR}/NNNNNN", "truth": F.TRUTH,
                   "frame_files": F.FRAME_FILES,
                   "radiance": F.RADIANCE if opts.radiance else None,
                   "radiance_quicklook": F.RADIANCE_QUICKLOOK if opts.radiance else None,
                   "per_exposure": [F.DN, F.DN_QUICKLOOK, F.SEGMENTS, F.WINDOWS, F.READOUT]},
    }
    if is_flyby_scenario(sc):  # a limb dataset's head is unchanged (its bytes are pinned)
        flyby = scene_from_scenario(sc).flyby
        assert flyby is not None
        head["target_kind"] = FLYBY_KIND
        head["flyby"] = {"epoch_ca_tdb_s": float(flyby.epoch_ca),
                         "sun_direction_j2000": np.asarray(flyby.sun_direction, float),
                         "navigate": "starnav navigate DATASET: the closed loop of "
                                     "starnav.batch.flyby on the stored radiance"}
        head["layout"]["per_exposure"] = []
    return head


def camera_to_manifest(cam: Any) -> dict[str, Any]:
    """Camera block of the manifest (:func:`starnav.dataset.format.camera_to_dict`)."""
    return F.camera_to_dict(cam)


def manifest(head: dict[str, Any], entries: dict[int, dict[str, Any]],
             complete: bool) -> dict[str, Any]:
    """Full manifest: head, ``complete`` flag and frames sorted by index."""
    out = dict(head)
    out["complete"] = bool(complete)
    out["frames_done"] = len(entries)
    out["frames"] = [entries[i] for i in sorted(entries)]
    return out


# ============================================================================ frames
class FrameMaker:
    """Writes the frames of one scenario; the frames themselves come from a
    :class:`~starnav.simulate.Simulator` (camera, scene and renderer built once per process)."""

    def __init__(self, scenario: Scenario, options: DatasetOptions) -> None:
        self.scenario = scenario
        self.options = options.resolved(scenario)
        self.simulator = Simulator(scenario)
        self.camera = self.simulator.camera
        self._per_exposure = {t: self.options.scenario_for(scenario, t)
                              for t in self.options.exposures_s or ()}
        self._order: list[int] = []   # frames to come, in order (making_ahead)
        self._order_pos: dict[int, int] = {}   # their positions in it
        self._root: Path | None = None
        self._threads = 1
        self._started: dict[int, Future] = {}   # frames made ahead, by index
        self._claimed: set[int] = set()   # ... whose result the caller took
        self._pool: ThreadPoolExecutor | None = None
        # positions (in the announced order) of the frames made ahead that have not written
        # their files yet: the first of them writes (frames land in order)
        self._unwritten: set[int] = set()
        self._position: dict[int, int] = {}
        self._turn = threading.Condition()
        self._render_lock = threading.Lock()   # one render at a time
        self._stars = {t: uses_star_attitude(sc) for t, sc in self._per_exposure.items()}
        self.flyby = is_flyby_scenario(scenario)

    def __len__(self) -> int:
        return len(self.simulator)

    def render(self, index: int) -> tuple[Any, Any]:
        """Geometry and RadianceImage of frame ``index`` (one render at a time)."""
        with self._render_lock:
            return self.simulator.render(index)

    @contextlib.contextmanager
    def making_ahead(self, order: Sequence[int], root: Path,
                     threads: int = FRAME_THREADS) -> Iterator[None]:
        """While open, :meth:`write_frame` of a frame in ``order`` makes it and the next ones
        of ``order`` in ``threads`` threads (module step 3) and returns its entry when it is
        on disk; the calls should come in that order (in-process generation). The frames are
        computed (render, acquisitions) at the same time but write their files one frame at a
        time, in that order, so they land in index order as in a serial run (a run stopped by
        an error, a full disk say, keeps the frames before it). A frame asked for out of order
        is made in the calling thread. On exit the frames started and not asked for are
        cancelled if they have not begun, else waited for (they land, or clean up after
        themselves on an error); ``threads <= 1`` makes every frame in the calling thread."""
        self._order = [int(i) for i in order]
        self._order_pos = {i: k for k, i in enumerate(self._order)}
        self._root = Path(root)
        self._threads = max(1, int(threads))
        try:
            yield
        finally:
            self._order, self._order_pos, self._root, self._threads = [], {}, None, 1
            started = {i: f for i, f in self._started.items() if i not in self._claimed}
            self._started, self._claimed = {}, set()
            for i, fut in started.items():
                if fut.cancel():   # never begun: it will not take its turn
                    self._end_turn(i)
            for fut in started.values():
                if not fut.cancelled():
                    with contextlib.suppress(Exception):   # its frame was never asked for
                        fut.result()
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
            with self._turn:
                self._unwritten.clear()
                self._position.clear()

    def _claim(self, index: int, root: Path) -> Future | None:
        """The future of frame ``index`` when it is made ahead, after starting the frames
        that follow it in the announced order (``threads`` running and one queued)."""
        k = self._order_pos.get(index)
        if self._threads <= 1 or self._root is None or Path(root) != self._root or k is None \
                or index in self._claimed:
            return None
        with self._turn:
            behind = index not in self._started and k < max(self._position.values(),
                                                            default=-1)
        if behind:   # behind frames already started: made here (the pool stays in order)
            return None
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="starnav-frame")
        for pos, i in enumerate(self._order[k : k + self._threads + 1], k):
            if i not in self._started:
                with self._turn:
                    self._position[i] = pos
                    self._unwritten.add(pos)
                self._started[i] = self._pool.submit(self._write_frame, i, self._root)
        self._claimed.add(index)
        return self._started[index]

    def _wait_turn(self, index: int) -> None:
        """Wait until every frame made ahead before ``index`` (in the announced order) has
        written its files (or failed); at once for a frame not made ahead."""
        with self._turn:
            pos = self._position.get(index)
            if pos is not None:
                self._turn.wait_for(lambda: min(self._unwritten, default=pos) >= pos)

    def _end_turn(self, index: int) -> None:
        """Frame ``index`` has written its files, or will not: the next one may write."""
        with self._turn:
            pos = self._position.pop(index, None)
            if pos is not None:
                self._unwritten.discard(pos)
                self._turn.notify_all()

    def write_frame(self, index: int, root: Path) -> dict[str, Any]:
        """Make frame ``index`` and move it into ``root/frames`` whole (module step 3).

        Returns
        -------
        dict
            The frame's manifest entry.
        """
        fut = self._claim(int(index), root)
        if fut is not None:
            return fut.result()
        return self._write_frame(int(index), root)

    def _write_frame(self, index: int, root: Path) -> dict[str, Any]:
        """:meth:`write_frame` in this thread: compute the frame (render, truth,
        acquisitions), then, at its turn (:meth:`making_ahead`), write it."""
        try:
            frames = root / F.FRAMES_DIR
            frames.mkdir(parents=True, exist_ok=True)
            final = frames / F.frame_dirname(index)
            if final.exists():
                return frame_entry(root, index)
            geom, img = self.render(index)
            truth = F.truth_to_dict(geom, self.camera, self.options.limb_points)
            if self.flyby:
                rel = self.simulator.scene.relative_states[index]
                truth["flyby"] = {"relative_position_m": rel[:3],
                                  "relative_velocity_m_s": rel[3:],
                                  "frame": "J2000 axes, spacecraft relative to the body",
                                  "sun_direction_j2000": self.simulator.scene.flyby.sun_direction,
                                  "per_pixel": "radiance.exr AOVs (hit mask, body-fixed "
                                               "coordinates)"}
            acqs = {t: self.simulator.acquire(img, geom, exposure_time=t, run=0,
                                              windows=self.options.windows,
                                              scenario=self._per_exposure[t])
                    for t in self.options.exposures_s or ()}
            stars = {t: star_acquisition_dn(img, geom, self.camera, self._per_exposure[t], 0)
                     for t in acqs
                     if self._stars[t] and is_star_frame(self._per_exposure[t], index)}
            self._wait_turn(index)
            self._write_files(index, frames, geom, img, truth, acqs, stars)
        finally:
            self._end_turn(index)
        return frame_entry(root, index)

    def _write_files(self, index: int, frames: Path, geom: Any, img: Any,
                     truth: dict[str, Any], acqs: dict[float, Any],
                     stars: dict[float, Any]) -> None:
        """Write frame ``index`` into a temporary directory and rename it into ``frames``."""
        final = frames / F.frame_dirname(index)
        tmp = Path(tempfile.mkdtemp(prefix=f"{F.TMP_PREFIX}{F.frame_dirname(index)}-",
                                    dir=frames))
        try:
            F.write_json(tmp / F.TRUTH, truth)
            if self.options.radiance:
                write_exr(img, tmp / F.RADIANCE)
                write_radiance_quicklook(img, tmp / F.RADIANCE_QUICKLOOK, index=index)
            for t, acq in acqs.items():
                d = tmp / F.exposure_dirname(t)
                d.mkdir()
                write_dn_png(F.uint16_image(acq.segments_exposure.dn), d / F.DN)
                write_dn_quicklook(acq.segments_exposure.dn, d / F.DN_QUICKLOOK, index=index,
                                   exposure_time=t, range_m=geom.range,
                                   phase_angle_rad=geom.phase_angle)
                seg = acq.segments
                if seg is not None:
                    F.write_json(d / F.SEGMENTS, F.segments_to_dict(seg), compact=True)
                F.write_json(d / F.WINDOWS, F.windows_to_dict(
                    acq.windows, None if not acq.windows else
                    (1 if acq.windows_exposure is not None else 0)), compact=True)
                if t in stars:
                    write_dn_png(F.uint16_image(stars[t]), d / F.STAR_DN)
                F.write_json(d / F.READOUT, {**acq.summary(),
                                             "overrides": list(self.options.overrides_for(t))})
            F.write_json(tmp / F.FRAME_FILES, {"files": F.file_record(tmp)})  # last
            os.chmod(tmp, 0o777 & ~current_umask())
            sync_directory(tmp)  # its entries (the exposure directories) reach the disk
            os.rename(tmp, final)
            sync_directory(frames)  # and so does the rename
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


def frame_entry(root: Path, index: int) -> dict[str, Any]:
    """Manifest entry of a finished frame, rebuilt from its files (deterministic)."""
    d = root / F.FRAMES_DIR / F.frame_dirname(index)
    truth = F.read_json(d / F.TRUTH)
    files: dict[str, dict[str, Any]] = {}
    for p in sorted(d.rglob("*")):
        if p.is_file():
            rel = p.relative_to(d).as_posix()
            files[rel] = {"bytes": p.stat().st_size, "sha256": F.sha256_file(p)}
    exposures: dict[str, Any] = {}
    for sub in sorted(x for x in d.iterdir() if x.is_dir()):
        ro = F.read_json(sub / F.READOUT)
        a0 = ro["acquisitions"][0]
        exposures[sub.name] = {
            "exposure_s": ro["exposure_s"],
            "saturated_pixels": a0.get("saturated_pixels"),
            "dn_max": a0.get("dn_max"),
            "segment_runs": (a0.get("segments") or {}).get("runs"),
            "windows": len(ro["window_plan"]["windows_row0_col0_height_width"]),
            "plan_status": ro["window_plan"]["status"],
            "feasible": ro["feasible"],
        }
    return {"index": int(index), "directory": f"{F.FRAMES_DIR}/{F.frame_dirname(index)}",
            "epoch_tdb_s": truth["epoch_tdb_s"], "epoch_tdb_iso": truth["epoch_tdb_iso"],
            "range_m": truth["moon"]["range_m"],
            "phase_angle_rad": truth["moon"]["phase_angle_rad"],
            "exposures": exposures, "files": files}


#: Frame makers of this process, by scenario and options (workers keep theirs).
#: Frame makers of this process by (scenario, options): a worker builds its renderer once.
_MAKERS: BoundedCache[str, FrameMaker] = BoundedCache(4, policy="fifo")


def frame_maker(config: dict[str, Any], options: dict[str, Any] | None = None) -> FrameMaker:
    """The :class:`FrameMaker` of a resolved scenario dict and options, cached per process (a
    worker builds its renderer and scene once per configuration)."""
    options = options if options is not None else DatasetOptions().to_dict()
    key = _canonical_key(config, options)

    return _MAKERS.get_or_make(key, lambda: FrameMaker(scenario_from_dict(config),
                                                       DatasetOptions.from_dict(options)))


def make_frame(config: dict[str, Any], options: dict[str, Any], root: str,
               index: int) -> dict[str, Any]:
    """Task: make frame ``index`` of the dataset at ``root`` (picklable; runs on workers).

    Parameters
    ----------
    config : dict
        Resolved scenario (``scenario_to_dict``).
    options : dict
        ``DatasetOptions.to_dict()`` (resolved).
    root : str
        Dataset directory (shared file system when the workers are remote).
    index : int

    Returns
    -------
    dict
        The frame's manifest entry.
    """
    return frame_maker(config, options).write_frame(int(index), Path(root))


# ============================================================================ directory
@contextlib.contextmanager
def _locked(root: Path) -> Iterator[None]:
    import fcntl

    path = root / LOCK
    fh = open(path, "a+")  # noqa: SIM115 - held for the whole run
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise DatasetLockedError(f"{str(root)!r} is being written by another process "
                                     "(its .lock is held); wait for it or stop it") from None
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
    finally:
        fh.close()


def check_output_dir(out: Path) -> None:
    """Raise a clear error if ``out`` cannot be created or written (nothing is created)."""
    p = out
    while not p.exists():
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir():
        raise DataFileError(f"output {str(out)!r}: {str(p)!r} exists and is not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise DataFileError(f"output {str(out)!r} is not writable ({str(p)!r} does not allow "
                            "writing for this user)")


def _diff_keys(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            out += _diff_keys(va, vb, f"{prefix}{k}.")
        elif F.dumps(va) != F.dumps(vb):
            out.append(f"{prefix}{k}")
    return out


def _prepare(out: Path, head: dict[str, Any], resume: bool) -> dict[int, dict[str, Any]]:
    """Check the directory against ``head`` (module step 5); returns the entries to keep."""
    man = out / F.MANIFEST
    if man.exists():
        if not resume:
            raise DataFileError(f"{str(out)!r} already holds a dataset; use --resume to "
                                "continue it or choose another output directory")
        old = F.read_json(man)
        old_head = {k: v for k, v in old.items() if k not in ("complete", "frames",
                                                                "frames_done")}
        diff = _diff_keys(old_head, F.plain(head))
        if diff:
            shown = ", ".join(diff[:6]) + (" ..." if len(diff) > 6 else "")
            raise ConfigError("--resume", str(out),
                              f"the same scenario, options and software as the dataset being "
                              f"resumed; these differ: {shown}")
        return {int(e["index"]): e for e in old.get("frames", [])}
    if out.exists():
        if not out.is_dir():
            raise DataFileError(f"output {str(out)!r} exists and is not a directory")
        extra = [p.name for p in out.iterdir() if p.name != LOCK]
        if extra:
            raise DataFileError(f"{str(out)!r} is not empty and holds no {F.MANIFEST}: not a "
                                "starnav dataset; choose an empty or new directory")
    return {}


def _clean_temporaries(out: Path) -> None:
    """Remove the temporary files an interrupted atomic write of the manifest or of the
    resolved scenario left in ``out`` (``.manifest.json.*``, ``.scenario.resolved.yaml.*``)."""
    for name in (F.MANIFEST, F.RESOLVED):
        for p in out.glob(f".{name}.*"):
            log.info("removing the temporary file %s", p.name)
            p.unlink(missing_ok=True)


def _remove_temporaries(out: Path, index: int) -> None:
    """Remove what earlier attempts at frame ``index`` left (``frames/.tmp-NNNNNN-*``: a worker
    killed while writing it); called once the frame has landed."""
    for p in (out / F.FRAMES_DIR).glob(f"{F.TMP_PREFIX}{F.frame_dirname(index)}-*"):
        log.info("removing %s, left by an interrupted attempt at frame %d", p.name, index)
        shutil.rmtree(p, ignore_errors=True)


def _scan(out: Path, listed: dict[int, dict[str, Any]], n: int,
          opts: DatasetOptions) -> dict[int, dict[str, Any]]:
    """Remove temporary frame directories; keep the frames found whole on disk (a listed one:
    its files as its manifest entry says; one the manifest does not list yet: as its own
    record says, :func:`starnav.dataset.format.frame_problems`, its entry rebuilt from its
    files) and remove the others, which are then made again."""
    frames = out / F.FRAMES_DIR
    parts = {"exposures": [F.exposure_dirname(t) for t in opts.exposures_s or ()],
             "radiance": opts.radiance}
    entries: dict[int, dict[str, Any]] = {}
    if not frames.is_dir():
        return entries
    for p in frames.iterdir():
        if p.name.startswith(F.TMP_PREFIX):
            log.info("removing the unfinished frame %s", p.name)
            shutil.rmtree(p, ignore_errors=True)
    for p in sorted(frames.iterdir()):
        if not (p.is_dir() and F.is_frame_dirname(p.name)):
            continue
        i = int(p.name)
        if i >= n:
            raise DataFileError(f"{str(p)!r}: frame {i} is outside the scenario's {n} frames")
        bad = F.frame_problems(p, listed[i]["files"] if i in listed else None, **parts)
        if bad:
            log.warning("frame %d is damaged (%s): making it again", i, "; ".join(bad))
            aside = p.with_name(f"{F.TMP_PREFIX}{p.name}-damaged")
            shutil.rmtree(aside, ignore_errors=True)
            os.rename(p, aside)  # out of the frames before it goes: a crash leaves a temporary
            shutil.rmtree(aside, ignore_errors=True)
            continue
        entries[i] = listed[i] if i in listed else frame_entry(out, i)
    return entries


# ============================================================================ generate
def generate(scenario: Scenario, out: str | os.PathLike[str], *,
             options: DatasetOptions | None = None, resume: bool = False,
             runner: TaskRunner | None = None, progress: Progress | None = None,
             manifest_interval_s: float = MANIFEST_INTERVAL_S) -> DatasetSummary:
    """Make (or finish) the dataset of ``scenario`` in ``out`` (module steps 1-5).

    Parameters
    ----------
    scenario : Scenario
    out : path
        Dataset directory (created; must be new, empty, or a dataset to ``resume``).
    options : DatasetOptions, optional
        Exposures, windows mode, what to store.
    resume : bool
        Continue an interrupted dataset (same scenario and options).
    runner : TaskRunner, optional
        Where frames are made; default this process. A Dask runner
        (:func:`starnav.batch.cluster.open_runner`) needs ``out`` on a file system its workers
        share.
    progress : callable, optional
        ``progress(done, total)`` after set-up and after each frame.
    manifest_interval_s : float
        Minimum time between manifest rewrites [s] (the last one always happens).

    Returns
    -------
    DatasetSummary

    Raises
    ------
    ConfigError, DataFileError, DatasetLockedError
        Bad options, an unwritable or foreign directory, a resume with another scenario.
    """
    t_start = time.perf_counter()
    opts = (options or DatasetOptions()).resolved(scenario)
    for t in opts.exposures_s or ():  # source: stars needs the stars drawn
        uses_star_attitude(opts.scenario_for(scenario, t))
    out = Path(out)
    check_output_dir(out)
    scene = scene_from_scenario(scenario)
    n = len(scene)
    if n == 0:
        raise ConfigError("trajectory", None, "at least one frame")
    scene.geometries()  # every frame's geometry and pointing, before anything is written
    head = dataset_head(scenario, opts, n)
    listed = _prepare(out, head, resume)
    out.mkdir(parents=True, exist_ok=True)
    runner = runner or InProcessRunner()
    with _locked(out):
        _clean_temporaries(out)
        fresh = not (out / F.MANIFEST).exists()
        if fresh:
            F.write_json(out / F.MANIFEST, manifest(head, {}, False))
        write_resolved(scenario, out)
        entries = _scan(out, listed, n, opts)
        done0 = len(entries)
        if progress:
            progress(done0, n)
        todo = [i for i in range(n) if i not in entries]
        cfg = head["config"]
        od = opts.to_dict()
        t_frames = time.perf_counter()
        setup_s = t_frames - t_start
        last = time.monotonic()
        # in this process the frames are made in order, FRAME_THREADS at a time
        ahead = (frame_maker(cfg, od).making_ahead(todo, out.absolute(), FRAME_THREADS)
                 if todo and isinstance(runner, InProcessRunner) else contextlib.nullcontext())
        try:
            handles = [runner.submit(make_frame, cfg, od, str(out.absolute()), i,
                                     key=f"frame-{i:06d}")
                       for i in todo]
            with ahead:
                for _, entry in runner.as_completed(handles):
                    entries[int(entry["index"])] = entry
                    _remove_temporaries(out, int(entry["index"]))
                    if progress:
                        progress(len(entries), n)
                    if time.monotonic() - last >= manifest_interval_s:
                        F.write_json(out / F.MANIFEST, manifest(head, entries, False))
                        last = time.monotonic()
        except BaseException:
            try:  # what has landed is kept for --resume
                F.write_json(out / F.MANIFEST, manifest(head, entries, False))
            except OSError as err:  # e.g. the disk that stopped the frames is full: keep that
                log.warning("could not rewrite the manifest of %s (%s)", out, err)
            raise
        made_s = time.perf_counter() - t_frames
        final = manifest(head, entries, len(entries) == n)
        problems = verify_manifest(out, final) if final["complete"] else []
        final["complete"] = not problems and len(entries) == n
        F.write_json(out / F.MANIFEST, final)
        if problems:
            raise DataFileError(
                f"dataset {str(out)!r} does not verify after its frames were made, left "
                f"incomplete: {'; '.join(problems[:3])}"
                + (f" (and {len(problems) - 3} more)" if len(problems) > 3 else "")
                + "; see `starnav dataset verify DIR`")
    per = _per_exposure(entries)
    made = len(entries) - done0
    return DatasetSummary(path=out, frames=len(entries), frames_made=made,
                          exposures_s=tuple(opts.exposures_s or ()),
                          elapsed_s=time.perf_counter() - t_start,
                          frames_per_s=made / made_s if made and made_s > 0 else float("nan"),
                          setup_s=setup_s, per_exposure=per, runner=runner.description)


def _per_exposure(entries: dict[int, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    names = sorted({k for e in entries.values() for k in e.get("exposures", {})})
    for name in names:
        rows = [e["exposures"][name] for e in entries.values() if name in e["exposures"]]
        sat = [r["saturated_pixels"] for r in rows if r["saturated_pixels"] is not None]
        out[name] = {
            "exposure_s": rows[0]["exposure_s"] if rows else None,
            "saturated_pixels_median": float(np.median(sat)) if sat else None,
            "windows_planned_fraction": float(np.mean([r["plan_status"] == "ok"
                                                       for r in rows])) if rows else None,
            "feasible": all(r["feasible"] for r in rows),
        }
    return out
