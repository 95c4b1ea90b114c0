"""starnav.simulate: the one place where a frame is made from a scenario.

geometry -> render -> acquisitions (expose, read out, on-board window planning) -> the
navigation chain's input. :mod:`starnav.dataset` writes what it returns, :mod:`starnav.batch`
runs it in memory, ``starnav render`` writes its radiance.

Modules: :mod:`~starnav.simulate.build` (scenario sections -> camera, scene, Moon model,
renderer), :mod:`~starnav.simulate.acquire` (the tracker's acquisitions of one frame),
:mod:`~starnav.simulate.frames` (:class:`Simulator`).
"""

from __future__ import annotations

from starnav.simulate.acquire import (
    WINDOWS_MODES,
    Acquisition,
    acquire,
    acquisition_seed,
    check_windows_mode,
    readout_feasibility,
)
from starnav.simulate.build import (
    body_from_scenario,
    chain_options,
    describe_frame,
    frame_geometries,
    frame_mesh,
    frame_states,
    renderer_from_scenario,
    scene_from_scenario,
    target_model_from_scenario,
)
from starnav.simulate.frames import (
    Observation,
    Simulator,
    render_scenario,
    render_to_directory,
    simulator_for,
)

__all__ = ["WINDOWS_MODES", "Acquisition", "Observation", "Simulator", "acquire",
           "acquisition_seed", "body_from_scenario", "chain_options", "check_windows_mode",
           "describe_frame", "frame_geometries", "frame_mesh", "frame_states",
           "readout_feasibility", "render_scenario",
           "render_to_directory", "renderer_from_scenario", "scene_from_scenario",
           "simulator_for", "target_model_from_scenario"]
