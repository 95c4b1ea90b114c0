"""A dataset's frames with the tracker's own attitude (``navigation.attitude.source: stars``).

A ``source: stars`` dataset records, at every scheduled star frame and for each exposure, the
star acquisition's DN frame (``stars_dn.png``, run 0's stream:
:func:`starnav.simulate.attitude.star_acquisition_dn`). Navigating it, the run's
:class:`~starnav.simulate.attitude.StarAttitudeTracker` steps through the frames in time order
with the recorded acquisitions (:meth:`~starnav.simulate.attitude.StarAttitudeTracker.advance`,
the code path of the in-memory runs, so ``starnav navigate DATASET`` gives run 0's numbers),
and each frame goes to the chain with the record's attitude and covariance
(:func:`~starnav.simulate.attitude.with_attitude`).

:func:`navigate_with_star_attitude` runs the navigation on them and writes ``attitude.json``:
every frame's attitude source, error and predicted 1-sigma, and why the better sources failed.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from starnav.atomic import atomic_write_text
from starnav.errors import DataFileError
from starnav.navigation.frames import Frame
from starnav.navigation.report import navigate_dataset
from starnav.simulate.attitude import (
    AttitudeRecord,
    StarAttitudeTracker,
    check_star_attitude,
    is_star_frame,
    with_attitude,
)
from starnav.simulate.build import chain_options
from starnav.simulate.frames import Simulator


def star_attitude_frames(dataset: Any, scenario: Any) -> tuple[list[Frame], list[Any],
                                                              list[AttitudeRecord]]:
    """The dataset's frames (at its selected exposure) with the tracker's attitude, the chain
    options of each (the attitude covariance in its fix) and the attitude records.

    Parameters
    ----------
    dataset : starnav.dataset.Dataset
    scenario : Scenario
        The dataset's scenario at its exposure (``navigation.attitude.source: stars``).

    Raises
    ------
    ConfigError
        ``source`` is not ``stars`` or ``stars.enabled`` is false.
    DataFileError
        A scheduled star frame has no ``stars_dn.png`` (the dataset was made with another
        ``navigation.attitude``): before any frame is solved.
    """
    check_star_attitude(scenario)
    frames = list(dataset)
    missing = [f.index for f in frames if is_star_frame(scenario, f.index)
               and not (f.exposure_dir / "stars_dn.png").is_file()]
    if missing:
        raise DataFileError(
            f"dataset {str(dataset.path)!r}: star frames {missing[:5]} have no stars_dn.png "
            f"(navigation.attitude.schedule_every {scenario.navigation.attitude.schedule_every}"
            "); make the dataset with navigation.attitude.source: stars and this schedule")
    sim = Simulator(scenario, camera=dataset.camera)
    tracker = StarAttitudeTracker(sim, 0, scenario)
    chain = chain_options(scenario)
    out_f, out_c, recs = [], [], []
    t = float(dataset.exposure_time)
    for f in frames:
        geom = f.truth
        rec = tracker.advance(geom, f.star_dn, f.dn(), t, chain)
        frame = Frame(index=f.index, epoch_tdb=f.epoch_tdb,
                      R_cam_to_inertial_measured=f.R_cam_to_inertial_measured,
                      sun_direction_inertial=f.sun_direction_inertial, segments=f.segments,
                      windows=f.windows, truth=geom, R_body_to_inertial=f.R_body_to_inertial)
        fr, ch = with_attitude(frame, chain, rec)
        out_f.append(fr)
        out_c.append(ch)
        recs.append(rec)
    return out_f, out_c, recs


def navigate_with_star_attitude(dataset: Any, out_dir: str | os.PathLike[str], scenario: Any,
                                *, plots: bool = True, measure_memory: bool = True
                                ) -> dict[str, Any]:
    """:func:`starnav.navigation.report.navigate_dataset` on the dataset's frames with the
    tracker's attitude (:func:`star_attitude_frames`), plus ``attitude.json`` (one row per
    frame: :meth:`~starnav.simulate.attitude.AttitudeRecord.summary`).

    Returns
    -------
    dict
        The navigation summary with ``attitude``: the count of frames per attitude source.
    """
    frames, chains, recs = star_attitude_frames(dataset, scenario)
    summary = navigate_dataset(dataset, out_dir, config=scenario.navigation,
                               seed=int(scenario.seed), plots=plots, scenario=scenario,
                               frames=frames, chains=chains, measure_memory=measure_memory)
    p = Path(out_dir) / "attitude.json"
    rows = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
             for k, v in r.summary().items()} for r in recs]
    atomic_write_text(p, json.dumps(rows, indent=1, allow_nan=False) + "\n")
    summary["paths"]["attitude"] = str(p)
    summary["attitude"] = {s: sum(r.source == s for r in recs)
                           for s in dict.fromkeys(r.source for r in recs)}
    return summary
