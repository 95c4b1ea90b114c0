"""PNG summary of a trajectory arc: Moon range and phase angle vs time, 3-D path in the
Earth-Moon rotating frame.

Matplotlib's object API with the Agg canvas is used directly (no global backend switch, no
display needed). The rotating frame is the instantaneous Earth-Moon frame of
:func:`starnav.scenes.trajectory.emb_to_rotating`, scaled by the CR3BP length unit and centred
on the Moon.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from starnav.atomic import atomic_path
from starnav.scenes.cr3bp import LU, MU_EARTH_MOON, l2_position
from starnav.scenes.ephemeris import Ephemeris, format_epoch
from starnav.scenes.trajectory import Trajectory, emb_to_rotating
from starnav.timeaxis import format_duration, time_unit

log = logging.getLogger(__name__)


def plot_trajectory(traj: Trajectory, path: str | os.PathLike[str],
                    ephemeris: Ephemeris | None = None, title: str | None = None,
                    max_points: int = 4000, dpi: int = 110) -> Path:
    """Write the PNG summary of ``traj`` to ``path`` (temporary file + rename).

    Parameters
    ----------
    traj : Trajectory
        EMB-centred J2000 states [m, m/s].
    path : path
        Output ``.png``.
    ephemeris : Ephemeris, optional
        Default DE421.
    title : str, optional
    max_points : int
        Nodes plotted at most (evenly decimated).
    dpi : int
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    eph = ephemeris or Ephemeris.default()
    step = max(1, math.ceil(len(traj) / max_points))
    t = traj.times[::step]
    x = traj.states[::step]
    moon = eph.state("moon", t, center="emb")
    sun = eph.state("sun", t, center="emb")
    rel = x[:, :3] - moon[:, :3]
    rng = np.linalg.norm(rel, axis=1)
    sm = sun[:, :3] - moon[:, :3]
    phase = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", sm, rel)
                                         / (np.linalg.norm(sm, axis=1) * rng), -1, 1)))
    sym, unit = time_unit(float(t[-1] - t[0]))
    elapsed = (t - t[0]) / unit
    rot = emb_to_rotating(eph, t, x)[:, :3] * LU / 1e3
    rot[:, 0] -= (1.0 - MU_EARTH_MOON) * LU / 1e3

    fig = Figure(figsize=(12, 5.5), dpi=dpi)
    FigureCanvasAgg(fig)
    ax1 = fig.add_subplot(2, 2, 1)
    ax1.plot(elapsed, rng / 1e3, lw=1.2)
    ax1.set_ylabel("Moon range [km]")
    ax1.grid(alpha=0.3)
    ax2 = fig.add_subplot(2, 2, 3, sharex=ax1)
    ax2.plot(elapsed, phase, lw=1.2, color="tab:orange")
    ax2.set_ylabel("phase angle [deg]")
    ax2.set_xlabel(f"time since {format_epoch(t[0], precision=0)} [{sym}]")
    ax2.grid(alpha=0.3)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    ax3.plot(rot[:, 0], rot[:, 1], rot[:, 2], lw=1.0)
    ax3.scatter([0.0], [0.0], [0.0], color="0.4", s=40, label="Moon")
    xl2 = (l2_position() - (1.0 - MU_EARTH_MOON)) * LU / 1e3
    ax3.scatter([xl2], [0.0], [0.0], color="tab:red", marker="x", s=30, label="L2")
    ax3.scatter(rot[:1, 0], rot[:1, 1], rot[:1, 2], color="tab:green", s=20, label="start")
    ax3.set_xlabel("x [km]")
    ax3.set_ylabel("y [km]")
    ax3.set_zlabel("z [km]")
    span = np.vstack([rot, np.zeros((1, 3)), [[xl2, 0.0, 0.0]]])
    ax3.set_box_aspect(tuple(np.maximum(np.ptp(span, axis=0), 1.0)))
    ax3.set_title("Earth-Moon rotating frame, Moon-centred", fontsize=9)
    ax3.legend(fontsize=8, loc="upper left")
    fig.suptitle(title or f"{traj.object_name}: {format_duration(traj.duration)}, "
                 f"{rng.min() / 1e3:.0f}-{rng.max() / 1e3:.0f} km from the Moon")
    fig.tight_layout()

    out = Path(path)
    with atomic_path(out, suffix=".png") as tmp:
        fig.savefig(tmp, format="png")
    log.info("trajectory plot written to %s", out)
    return out
