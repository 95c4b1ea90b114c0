"""starnav.scenes: ephemerides, the LUMIO-like trajectory, pointing and per-frame geometry.

Public API (imports are lazy: importing :mod:`starnav.scenes` loads nothing heavy)::

    Ephemeris, parse_epoch, format_epoch            # starnav.scenes.ephemeris (DE421)
    PointMassModel, propagate, propagate_many       # starnav.scenes.dynamics (EKF model too)
    l2_halo, HaloOrbit                              # starnav.scenes.cr3bp
    Trajectory, ephemeris_halo_arc                  # starnav.scenes.trajectory
    read_oem, write_oem                             # starnav.scenes.oem (CCSDS OEM KVN)
    sample_pointing, moon_pointing                  # starnav.scenes.pointing
    Scene, build_trajectory, trajectory_summary      # starnav.scenes.frames
    plot_trajectory                                 # starnav.scenes.plot (PNG)
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_EXPORTS = {
    "Ephemeris": "ephemeris", "EphemerisRangeError": "ephemeris", "parse_epoch": "ephemeris",
    "format_epoch": "ephemeris",
    "PointMassModel": "dynamics", "propagate": "dynamics", "propagate_many": "dynamics",
    "HaloOrbit": "cr3bp", "l2_halo": "cr3bp", "ConvergenceError": "cr3bp",
    "Trajectory": "trajectory", "ephemeris_halo_arc": "trajectory",
    "ShootingOptions": "trajectory",
    "read_oem": "oem", "write_oem": "oem", "OEMFormatError": "oem",
    "Pointing": "pointing", "sample_pointing": "pointing", "moon_pointing": "pointing",
    "frame_generators": "pointing",
    "Scene": "frames", "build_trajectory": "frames", "trajectory_summary": "frames",
    "plot_trajectory": "plot",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
