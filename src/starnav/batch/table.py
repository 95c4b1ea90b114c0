"""The sweep result table: one row per (grid point, Monte Carlo run), Parquet and CSV.

Every column is declared once in :data:`COLUMNS` with its unit and meaning; docs/sweep.md
reproduces the table (a test keeps them in sync) and the Parquet file carries the unit and the
description of each field in its schema metadata (``unit``, ``description``). Grid keys are
added as columns named by the key itself (``detector.exposure_time_s``; the unit is in the
key's name).

Determinism: for one seed the table is identical whatever the number of workers, except the
``time_*_s`` columns, which are wall-clock measurements (:data:`TIMING_COLUMNS`). CSV floats are
written with Python's shortest round-trip ``repr`` (``nan`` for missing values).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starnav.atomic import atomic_path, atomic_write_text
from starnav.batch.tasks import TIMED_STAGES


@dataclass(frozen=True)
class Column:
    """A documented column: name, type (``int``, ``float``, ``bool``, ``str``), unit, meaning."""

    name: str
    kind: str
    unit: str
    description: str


_C = Column
#: Every fixed column of the table, in order (grid-key columns follow ``label``).
COLUMNS: tuple[Column, ...] = (
    _C("point", "int", "-", "grid point index (product of the --grid axes, last axis fastest)"),
    _C("run", "int", "-", "Monte Carlo run (0: the dataset's noise streams; each run has its "
       "own detector temporal noise, RANSAC stream and filter initial error)"),
    _C("label", "str", "-", "the point's grid values, key=value"),
    _C("exposure_time_s", "float", "s", "detector.exposure_time_s of the point"),
    _C("albedo_scale", "float", "-", "moon.albedo_scale of the point"),
    _C("frames", "int", "-", "frames along the arc"),
    _C("fixes", "int", "-", "frames that gave a Christian-Robinson fix"),
    _C("accepted", "int", "-", "fixes accepted by the EKF's chi-square gate"),
    _C("windows_planned_fraction", "float", "-", "fraction of frames where the on-board chain "
       "placed windows (1 when windows are used and the limb was found)"),
    _C("saturated_pixels_median", "float", "px", "median over frames of the pixels at full "
       "well in the segments acquisition"),
    _C("dn_max", "int", "DN", "largest DN over all frames"),
    _C("readout_feasible", "bool", "-", "every acquisition satisfies the AA-STR readout law "
       "t >= a + b N_pix (false: a fictitious exposure, as the paper's 7.7 ms and 0.015 ms)"),
    _C("limb_points", "int", "-", "limb points used by the fixes, all frames"),
    _C("limb_bias_px", "float", "px", "mean signed distance of the used limb points to the "
       "true limb (> 0 outside), all frames"),
    _C("limb_std_px", "float", "px", "standard deviation of that distance"),
    _C("limb_rms_px", "float", "px", "RMS of that distance"),
    _C("final_position_error_m", "float", "m", "norm of (estimated - true) position at the last "
       "frame (EMB-centred J2000)"),
    _C("final_velocity_error_m_s", "float", "m/s", "norm of (estimated - true) velocity at the "
       "last frame"),
    _C("final_position_error_pct_range", "float", "%", "final position error / distance to "
       "the Moon centre x 100"),
    _C("final_velocity_error_pct_speed", "float", "%", "final velocity error / EMB-centred "
       "speed x 100"),
    _C("rms_position_error_m", "float", "m", "RMS over frames of the position error norm "
       "(posterior, initial transient included)"),
    _C("rms_velocity_error_m_s", "float", "m/s", "RMS over frames of the velocity error norm"),
    _C("final_position_3sigma_m", "float", "m", "norm of the filter's per-axis 3-sigma "
       "position bounds at the last frame"),
    _C("final_velocity_3sigma_m_s", "float", "m/s", "norm of the 3-sigma velocity bounds at "
       "the last frame"),
    _C("nees_mean", "float", "-", "mean over frames of the 6-state NEES (consistent filter: "
       "~6)"),
    _C("nees_position_mean", "float", "-", "mean over frames of the position NEES (its 3x3 "
       "covariance; consistent filter: ~3)"),
    _C("nees_velocity_mean", "float", "-", "mean over frames of the velocity NEES (consistent "
       "filter: ~3)"),
) + tuple(
    _C(f"time_{s}_s", "float", "s", f"median over frames of the wall time of the {s} stage"
       + {"render": " (shared by the render group: not divided among its points)",
          "detector": " (both acquisitions)", "plan": " (on-board window plan)",
          "ekf": " (one predict + update)"}.get(s, " (navigation chain)"))
    for s in TIMED_STAGES)

#: The attitude side, present when the points draw the stars (``stars.enabled``): the
#: attitude each fix used and what the navigation frame's own stars give at its exposure
#: (:func:`starnav.batch.tasks.attitude_columns`).
STAR_COLUMNS: tuple[Column, ...] = (
    _C("attitude_source", "str", "-", "navigation.attitude.source of the run: assumed (the "
       "pointing knowledge error and the fix's assumed sigma) or stars (the tracker's own "
       "attitude: star acquisitions, the navigation frames' stars, the gyro between them)"),
    _C("attitude_solved_fraction", "float", "-", "fraction of frames whose attitude was "
       "solved from stars at that frame (a star acquisition or the navigation frame)"),
    _C("attitude_error_cross_rms_arcsec", "float", "arcsec", "RMS over frames of the "
       "cross-boresight error of the attitude the fixes used"),
    _C("attitude_error_roll_rms_arcsec", "float", "arcsec", "RMS over frames of its roll "
       "error (about the boresight)"),
    _C("attitude_sigma_cross_arcsec", "float", "arcsec", "mean over frames of its predicted "
       "cross-boresight 1-sigma (hypot of the x and y sigmas)"),
    _C("attitude_sigma_roll_arcsec", "float", "arcsec", "mean over frames of its predicted "
       "roll 1-sigma"),
    _C("attitude_nees_mean", "float", "-", "mean over frames of its NEES (3 dof; consistent: "
       "~3)"),
    _C("stars_detected_median", "float", "-", "median over frames of the star candidates "
       "accepted by the centroiding in the navigation frame (segments acquisition, Moon "
       "and ghosts excluded)"),
    _C("stars_identified_median", "float", "-", "median over frames of the stars identified "
       "in a lost-in-space solve of the navigation frame (0 when not solved)"),
    _C("frame_attitude_solved_fraction", "float", "-", "fraction of navigation frames whose "
       "own stars give an attitude (lost in space)"),
    _C("frame_attitude_sigma_cross_arcsec", "float", "arcsec", "median over solved navigation "
       "frames of the predicted cross-boresight 1-sigma (nan: none solved)"),
    _C("frame_attitude_sigma_roll_arcsec", "float", "arcsec", "median over solved navigation "
       "frames of the predicted roll 1-sigma (nan: none solved)"),
    _C("frame_attitude_error_cross_rms_arcsec", "float", "arcsec", "RMS over solved navigation "
       "frames of the cross-boresight error"),
    _C("frame_attitude_error_roll_rms_arcsec", "float", "arcsec", "RMS over solved navigation "
       "frames of the roll error"),
    _C("time_stars_s", "float", "s", "median over frames of the wall time of the star work "
       "(star acquisition and solves)"),
)

#: Columns that are wall-clock measurements (not reproducible).
TIMING_COLUMNS: tuple[str, ...] = tuple(f"time_{s}_s" for s in TIMED_STAGES) + ("time_stars_s",)


def column_names(grid_keys: Sequence[str] = (), stars: bool = False) -> list[str]:
    """Column order: ``point, run, label``, the grid keys, then the rest of :data:`COLUMNS`
    (and :data:`STAR_COLUMNS` with ``stars``)."""
    names = [c.name for c in COLUMNS]
    extra = [c.name for c in STAR_COLUMNS] if stars else []
    return names[:3] + [k for k in grid_keys if k not in names] + names[3:] + extra


def columns_of(stars: bool) -> tuple[Column, ...]:
    """The documented columns of a table (:data:`STAR_COLUMNS` with ``stars``)."""
    return COLUMNS + (STAR_COLUMNS if stars else ())


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    if isinstance(v, list | tuple | dict):
        return json.dumps(v, sort_keys=True)
    return str(v)


def to_csv(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """CSV text of ``rows`` (header = ``columns``)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_fmt(r.get(c)) for c in columns])
    return buf.getvalue()


def _arrow_type(values: list[Any]):
    import pyarrow as pa

    vs = [v for v in values if v is not None]
    if vs and all(isinstance(v, bool) for v in vs):
        return pa.bool_()
    if vs and all(isinstance(v, int) and not isinstance(v, bool) for v in vs):
        return pa.int64()
    if vs and all(isinstance(v, int | float) and not isinstance(v, bool) for v in vs):
        return pa.float64()
    return pa.string()


def to_arrow(rows: Sequence[dict[str, Any]], columns: Sequence[str]):
    """A ``pyarrow.Table`` with unit and description metadata on every documented field."""
    import pyarrow as pa

    doc = {c.name: c for c in COLUMNS}
    fields, arrays = [], []
    for name in columns:
        vals = [r.get(name) for r in rows]
        t = _arrow_type(vals)
        if t == pa.string():
            vals = [None if v is None else (v if isinstance(v, str) else _fmt(v)) for v in vals]
        c = doc.get(name)
        meta = ({"unit": c.unit, "description": c.description} if c else
                {"unit": "see the key name", "description": f"grid key {name}"})
        fields.append(pa.field(name, t, metadata=meta))
        arrays.append(pa.array(vals, type=t))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def write_table(rows: Sequence[dict[str, Any]], columns: Sequence[str],
                directory: str | os.PathLike[str], stem: str = "results") -> dict[str, Path]:
    """Write ``<stem>.parquet`` and ``<stem>.csv`` atomically; returns their paths."""
    import pyarrow.parquet as pq

    d = Path(directory)
    paths = {"parquet": d / f"{stem}.parquet", "csv": d / f"{stem}.csv"}
    table = to_arrow(rows, columns)
    with atomic_path(paths["parquet"], suffix=".parquet") as tmp:
        pq.write_table(table, tmp)
    atomic_write_text(paths["csv"], to_csv(rows, columns))
    return paths


def read_table(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of a results Parquet file (list of dicts)."""
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()
