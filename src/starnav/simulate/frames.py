"""The frames of a scenario: geometry -> radiance -> the tracker's acquisitions.

:class:`Simulator` is the one place where a frame is made. It builds the camera, the scene
and the renderer once per process and then, for frame ``i``:

1. **geometry** (:meth:`Simulator.geometry`): the frame's :class:`~starnav.geometry.FrameGeometry`;
2. **radiance** (:meth:`Simulator.render`): seed ``seed_u32(seed, STAGE_RENDER, i)``;
3. **acquisitions** (:meth:`Simulator.acquire`): :mod:`starnav.simulate.acquire` for run ``r``
   (run 0 is the dataset's);
4. **observation** (:meth:`Simulator.observe`): the acquisitions and the attitude the
   spacecraft believes (run 0 the frame's own knowledge error, later runs a fresh draw:
   :func:`starnav.scenes.pointing.knowledge_for_run`).

``starnav render`` (step 2), :mod:`starnav.dataset` (steps 1-3, on disk) and
:mod:`starnav.batch` (steps 1-4, in memory) therefore see the same frames and truth.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from starnav.cache import BoundedCache
from starnav.camera import Camera, camera_from_config
from starnav.config import Scenario, scenario_from_dict
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.navigation.frames import Frame
from starnav.quicklook import write_radiance_quicklook
from starnav.radiance import RadianceImage, write_exr
from starnav.renderer.render import MoonRenderer
from starnav.scenes.frames import Scene
from starnav.scenes.pointing import knowledge_for_run
from starnav.seeding import STAGE_RENDER, seed_u32
from starnav.simulate.acquire import Acquisition, acquire
from starnav.simulate.build import renderer_from_scenario, scene_from_scenario
from starnav.simulate.outdir import check_render_directory

log = logging.getLogger(__name__)


class Observation(NamedTuple):
    """Run ``run`` of one frame as the navigation chain receives it.

    Attributes
    ----------
    acquisition : Acquisition
        Segments, windows and their exposures.
    frame : starnav.navigation.frames.Frame
        The chain's input: readouts, believed attitude, Sun direction, and the truth.
    """

    acquisition: Acquisition
    frame: Frame


class Simulator:
    """Makes the frames of one scenario (camera, scene and renderer built once).

    Parameters
    ----------
    scenario : Scenario
    camera : Camera, optional
        The scenario's camera when already built.
    """

    def __init__(self, scenario: Scenario, camera: Camera | None = None) -> None:
        self.scenario = scenario
        self.camera = camera_from_config(scenario.camera) if camera is None else camera
        self.scene: Scene = scene_from_scenario(scenario, camera=self.camera)
        self._renderer: MoonRenderer | None = None
        self.knowledge_sigma = np.array(scenario.pointing.knowledge_sigma)

    def __len__(self) -> int:
        return len(self.scene)

    @property
    def renderer(self) -> MoonRenderer:
        """The scenario's renderer (built, and its files read, on first use)."""
        if self._renderer is None:
            self._renderer = renderer_from_scenario(self.scenario, camera=self.camera)
        return self._renderer

    def geometry(self, index: int) -> FrameGeometry:
        """Step 1: the geometry and truth of frame ``index``."""
        return self.scene.geometry(index)

    def render(self, index: int) -> tuple[FrameGeometry, RadianceImage]:
        """Steps 1-2: geometry and rendered radiance of frame ``index``."""
        geom = self.geometry(index)
        img = self.renderer.render(geom, seed=seed_u32(self.scenario.seed, STAGE_RENDER, index))
        return geom, img

    def acquire(self, radiance: RadianceImage | Any, geom: FrameGeometry, *,
                exposure_time: float | None = None, run: int = 0, windows: str = "second",
                scenario: Scenario | None = None) -> Acquisition:
        """Step 3: the acquisitions of run ``run`` (:func:`starnav.simulate.acquire.acquire`);
        ``scenario`` a variant of this one (e.g. one exposure's overrides), default itself."""
        return acquire(radiance, geom, self.camera, scenario or self.scenario,
                       exposure_time=exposure_time, run=run, windows=windows)

    def measured_attitude(self, geom: FrameGeometry, run: int = 0,
                          seed: int | None = None) -> NDArray[np.float64]:
        """The tracker's measured attitude (camera -> inertial) of frame ``geom`` in run
        ``run``: every run after the first samples the attitude knowledge error afresh, as it
        samples the detector noise (run 0 keeps the frame's own draw)."""
        if run == 0:
            return np.asarray(geom.R_cam_to_inertial_known, float)
        return knowledge_for_run(geom.R_cam_to_inertial, self.knowledge_sigma,
                                 self.scenario.seed if seed is None else seed, geom.index, run)

    def observe(self, radiance: RadianceImage | Any, geom: FrameGeometry, *, run: int = 0,
                windows: str = "second", exposure_time: float | None = None,
                scenario: Scenario | None = None) -> Observation:
        """Steps 3-4: the acquisitions of run ``run`` and the chain's input frame."""
        sc = scenario or self.scenario
        acq = self.acquire(radiance, geom, exposure_time=exposure_time, run=run, windows=windows,
                           scenario=sc)
        R = self.measured_attitude(geom, run, sc.seed)
        frame = Frame(index=geom.index, epoch_tdb=geom.epoch_tdb, R_cam_to_inertial_measured=R,
                      sun_direction_inertial=geom.sun_position, segments=acq.segments,
                      windows=acq.windows, truth=geom, R_body_to_inertial=geom.R_body_to_inertial)
        return Observation(acq, frame)


#: Simulators of this process by resolved scenario (a worker builds its renderer once).
_SIMULATORS: BoundedCache[str, Simulator] = BoundedCache(4, policy="fifo")


def simulator_for(config: dict[str, Any]) -> Simulator:
    """The :class:`Simulator` of a resolved scenario dict (``scenario_to_dict``), cached per
    process: workers receive plain dicts and build the camera, scene and renderer once."""
    key = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()
    return _SIMULATORS.get_or_make(key, lambda: Simulator(scenario_from_dict(config)))


def render_scenario(sc: Scenario, frames: list[FrameGeometry] | None = None
                    ) -> Iterator[RadianceImage]:
    """Render every frame of ``sc`` (validated up front); yields RadianceImages in order.
    ``frames``: geometries to render instead of the scenario's (their ``index`` seeds them)."""
    sim = Simulator(sc)
    renderer = sim.renderer
    geoms = sim.scene.geometries() if frames is None else frames
    for g in geoms:
        yield renderer.render(g, seed=seed_u32(sc.seed, STAGE_RENDER, g.index))


def quicklook_name(index: int) -> str:
    """File name of frame ``index``'s quick look in a ``render`` directory."""
    return f"frame_{index:06d}_quicklook.png"


def render_to_directory(sc: Scenario, out: str | Path,
                        progress: Callable[[int, int], None] | None = None,
                        overwrite: bool = False) -> list[Path]:
    """Render the scenario's frames to ``out/frame_NNNNNN.exr`` (the data) and, next to each,
    its 8-bit quick look ``out/frame_NNNNNN_quicklook.png`` (the picture:
    :func:`starnav.quicklook.write_radiance_quicklook`); atomic writes. Returns the EXR paths.
    An earlier render in ``out`` is refused, or removed first with ``overwrite``
    (:func:`starnav.simulate.outdir.check_render_directory`)."""
    out = Path(out)
    sim = Simulator(sc)
    if len(sim) == 0:
        raise ConfigError("trajectory", None, "at least one frame")
    sim.scene.geometries()  # every frame's pointing, before anything is written
    sim.renderer  # noqa: B018  (build and validate before the first frame)
    check_render_directory(out, overwrite)
    created = not out.exists()
    paths = []
    try:
        for k in range(len(sim)):
            geom, img = sim.render(k)
            paths.append(write_exr(img, out / f"frame_{geom.index:06d}.exr"))
            write_radiance_quicklook(img, out / quicklook_name(geom.index), index=geom.index)
            if progress is not None:
                progress(k + 1, len(sim))
            log.info("frame %d: L max %.4g W m^-2 sr^-1", geom.index, float(img.L.max()))
    except BaseException:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed first frame leaves nothing behind, not an empty directory
        raise
    return paths
