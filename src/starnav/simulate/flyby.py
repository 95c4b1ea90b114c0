"""The frames of an asteroid fly-by scenario: what the closed loop's runs start from.

A fly-by scenario (``target.kind: shape_model``, ``trajectory.source: flyby``):

1. :func:`is_flyby_scenario` / :func:`check_flyby_scenario`: the one answer to "is this a
   fly-by?" (``trajectory.source: flyby``) and what its closed loop needs (a shape model).
2. :func:`render_flyby`: every frame rendered once, only the channels the loop reads kept.
3. :func:`dispersed_flyby`: run ``r``'s fly-by under ``navigation.trn.dispersion:
   orientation`` (its orientation relative to the body drawn from the run's stream).
4. :func:`segments_image`: the segments image run ``r``'s front end read in one frame.

The closed loop over Monte Carlo runs (front end and estimator per run, the sweep over fly-by
geometries) is :mod:`starnav.batch.flyby`; why the orientation is dispersed (the silhouette's
model error is a function of the aspect): docs/navigation.md.

Index
-----
:func:`is_flyby_scenario`, :func:`check_flyby_scenario`, :func:`render_flyby`,
:func:`dispersed_flyby`, :func:`segments_image`, :data:`KEPT_AOVS`, :data:`DISPERSION_STREAM`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import SIView, set_dotted
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry
from starnav.navigation.trn.frontend import FlybyFrontEnd
from starnav.navigation.trn.truth import BODY_AOVS
from starnav.navigation.trn.windows import WindowReader
from starnav.radiance import RadianceImage
from starnav.seeding import STAGE_NAVIGATION, generator
from starnav.simulate.frames import Simulator
from starnav.simulate.trn import flyby_exposures, flyby_frame_budget

#: Last key of a run's orientation draw ``(seed, STAGE_NAVIGATION, run, 0, 18)`` under
#: ``navigation.trn.dispersion: orientation`` (never change).
DISPERSION_STREAM = 18

Renders = Sequence[tuple[FrameGeometry, RadianceImage]]
#: The render channels the closed loop reads besides the radiance: the body mask and the
#: body-fixed surface points of the feature truth.
KEPT_AOVS = ("mask", *BODY_AOVS)


def is_flyby_scenario(sc: Scenario) -> bool:
    """Whether ``sc`` asks for a fly-by (``trajectory.source: flyby``): the scenarios the
    fly-by paths take (closed loop, fly-by sweep, fly-by dataset), where
    :func:`check_flyby_scenario` then demands what the closed loop needs, a shape model. A
    small body on any other trajectory is a limb scenario."""
    return sc.trajectory is not None and sc.trajectory.source == "flyby"


def check_flyby_scenario(sc: Scenario) -> None:
    """A fly-by closed loop needs a small body on a fly-by; anything else is one clear error,
    before any rendering."""
    flyby = sc.trajectory is not None and sc.trajectory.source == "flyby"
    small = sc.target is not None and sc.target.kind == "shape_model"
    if not flyby:
        src = None if sc.trajectory is None else sc.trajectory.source
        raise ConfigError("trajectory.source", src,
                          "'flyby' (with target.kind: shape_model) for the fly-by navigation; a "
                          "Moon scenario is navigated from its dataset (starnav dataset, then "
                          "starnav navigate DATASET)")
    if not small:
        raise ConfigError("target.kind", None if sc.target is None else sc.target.kind,
                          "'shape_model' (a small body's shape model) for the fly-by "
                          "navigation: the Moon is navigated from its limb")
    flyby_frame_budget(sc)     # a cadence the readout law refuses, under policy enforce


def render_flyby(sim: Simulator, progress: Callable[[int, int], None] | None = None
                 ) -> tuple[list[tuple[FrameGeometry, RadianceImage]], float]:
    """Module step 1: every frame rendered once; returns the renders and the mean render
    time per frame [s]. Each frame keeps only what the loop reads (the radiance, the mask and
    the body-fixed points of the truth: :data:`KEPT_AOVS`), 6 of the render's 15 channels:
    every frame of the pass is held."""
    check_flyby_scenario(sim.scenario)
    out = []
    t0 = time.perf_counter()
    for i in range(len(sim)):
        geom, img = sim.render(i)
        out.append((geom, dataclasses.replace(
            img, aovs={k: v for k, v in img.aovs.items() if k in KEPT_AOVS})))
        if progress is not None:
            progress(i + 1, len(sim))
    return out, (time.perf_counter() - t0) / max(len(sim), 1)


def dispersed_flyby(base: Scenario, run: int) -> tuple[Scenario, dict[str, float]]:
    """Run ``run``'s fly-by under ``navigation.trn.dispersion: orientation`` (module step 3):
    ``base`` with the fly-by's orientation relative to the body drawn uniformly over the
    rotations from ``generator(seed, STAGE_NAVIGATION, run, 0, DISPERSION_STREAM)``,
    ``u ~ U(0, 1)^3``: the CA velocity direction uniform on the sphere
    (``velocity_ra_deg = 360 u1``, ``velocity_dec_deg = asin(2 u2 - 1)``) and the B-plane
    angle uniform (``ca_angle_deg = 360 u3``). v_inf, CA distance, phase at CA and the Sun's
    azimuth are the base's. Returns the run's scenario (built and checked; a concrete
    fly-by, its ``navigation.trn.dispersion`` set to ``none``) and the three drawn values
    [deg]."""
    g = generator(int(base.seed), STAGE_NAVIGATION, int(run), 0, DISPERSION_STREAM)
    u = g.random(3)
    draw = {"velocity_ra_deg": 360.0 * float(u[0]),
            "velocity_dec_deg": math.degrees(math.asin(2.0 * float(u[1]) - 1.0)),
            "ca_angle_deg": 360.0 * float(u[2])}
    d = scenario_to_dict(base)
    for k, v in draw.items():
        set_dotted(d, f"trajectory.flyby.{k}", v)
    set_dotted(d, "navigation.trn.dispersion", "none")
    try:
        sc = scenario_from_dict(d)
    except ConfigError as err:
        raise ConfigError(f"dispersed run {run} {draw}: {err.field}", err.value,
                          err.expected) from None
    return sc, draw


def segments_image(sim: Simulator, render: tuple[FrameGeometry, RadianceImage], run: int = 0,
                   front_end: SIView | None = None) -> NDArray[np.float32]:
    """The segments DN of one frame of run ``run`` (0 where no run was read): the first
    acquisition again, with the same noise stream as the closed loop's, so the very image its
    front end read (the runs keep no image)."""
    geom, img = render
    fe = FlybyFrontEnd(sim.camera, front_end if front_end is not None
                       else sim.scenario.navigation.trn.front_end.to_si())
    e0, _, _, _ = flyby_exposures(sim, img, geom, fe, run=run)
    return WindowReader.from_exposures(e0).segments_image()




















