"""starnav.detector: the AA-STR detector chain and its star-tracker readout.

Radiance image -> mean photo-electrons -> optics (PSF, distortion, smear, stray light, ghosts)
-> PRNU, dark current, shot noise -> saturation and blooming -> crosstalk, non-linearity, read
noise -> ADC -> segments / windows / full frame (see :mod:`starnav.detector.chain` for the
order and docs/detector.md for every parameter).

Example (``radiance_image`` from :func:`starnav.radiance.read_exr`)::

    from starnav.detector import expose, DetectorConfig
    frame = expose(radiance_image, camera, DetectorConfig(), seed=7, frame_index=0)
    frame.dn, frame.segments, frame.windows, frame.timing
"""

from __future__ import annotations

from starnav.detector.chain import CHAIN_ORDERS, EFFECTS, Exposure, expose, get_effect
from starnav.detector.io import write_exposure
from starnav.detector.optics import PointSources
from starnav.detector.products import MAX_WINDOWS, Segments, Window
from starnav.detector.readout import ReadoutTiming, extract_segments, min_exposure, read_windows
from starnav.detector.schema import DetectorConfig, WindowSpec

__all__ = [
    "CHAIN_ORDERS",
    "EFFECTS",
    "MAX_WINDOWS",
    "PointSources",
    "DetectorConfig",
    "Exposure",
    "ReadoutTiming",
    "Segments",
    "Window",
    "WindowSpec",
    "expose",
    "extract_segments",
    "get_effect",
    "min_exposure",
    "read_windows",
    "write_exposure",
]
