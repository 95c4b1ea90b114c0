"""starnav.navigation: the limb-based VBN chain (segments -> limb -> RANSAC -> fix -> EKF).

Public API (imports are light: numpy and scipy only, matplotlib only when plotting):

* :func:`process_frame` - one frame to a Christian-Robinson position fix;
* :func:`run_filter` - the EKF over a sequence of fixes;
* :func:`navigate` - both over a dataset, with timings and memory;
* the stages: :func:`limb_points_from_segments`, :func:`refine_limb`, :func:`ransac_limb`,
  :func:`christian_robinson`, :class:`NavigationEkf`;
* protocols for inputs: :class:`NavFrame`, :class:`NavDataset`, :class:`Dynamics`,
  :class:`MoonEphemeris`.

See ``docs/navigation.md``.
"""

from __future__ import annotations

from starnav.navigation.christian_robinson import (
    ChristianRobinsonOptions,
    FixError,
    LimbFix,
    christian_robinson,
)
from starnav.navigation.dynamics import Dynamics, MoonEphemeris, PointMassDynamics
from starnav.navigation.ekf import EkfPriors, FilterConfig, NavigationEkf
from starnav.navigation.frames import Frame, FrameList, NavDataset, NavFrame
from starnav.navigation.limb import (
    LimbConfig,
    LimbNotFoundError,
    LimbPoints,
    limb_points_from_segments,
    sun_direction_in_image,
)
from starnav.navigation.pipeline import (
    ChainOptions,
    FilterResult,
    FrameMeasurement,
    NavigationRun,
    navigate,
    process_frame,
    run_filter,
)
from starnav.navigation.ransac import RansacConfig, RansacError, ransac_limb
from starnav.navigation.refine import RefineConfig, RefineModels, plan_windows, refine_limb

__all__ = [
    "ChainOptions",
    "ChristianRobinsonOptions",
    "Dynamics",
    "EkfPriors",
    "FilterConfig",
    "FilterResult",
    "FixError",
    "Frame",
    "FrameList",
    "FrameMeasurement",
    "LimbFix",
    "LimbNotFoundError",
    "LimbPoints",
    "LimbConfig",
    "MoonEphemeris",
    "NavDataset",
    "NavFrame",
    "NavigationEkf",
    "NavigationRun",
    "PointMassDynamics",
    "RansacError",
    "RansacConfig",
    "RefineConfig",
    "RefineModels",
    "christian_robinson",
    "limb_points_from_segments",
    "navigate",
    "plan_windows",
    "process_frame",
    "ransac_limb",
    "refine_limb",
    "run_filter",
    "sun_direction_in_image",
]
