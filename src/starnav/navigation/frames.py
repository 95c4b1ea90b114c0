"""What the navigation chain reads per frame and per dataset: two small protocols.

A dataset reader (``starnav.dataset``) or a user's own loader only has to provide
objects of these shapes; nothing else of a dataset is used by :mod:`starnav.navigation`.

:class:`NavFrame` - one frame, as seen on board plus its truth:

==============================  ====================  ==========================================
attribute                       type                  meaning
==============================  ====================  ==========================================
``index``                       int                   frame number in the sequence
``epoch_tdb``                   float                 exposure mid-time [TDB s past J2000]
``R_cam_to_inertial_measured``  (3, 3) array          on-board attitude, camera -> J2000
``sun_direction_inertial``      (3,) array            direction to the Sun (from the Moon or the
                                                      spacecraft), J2000, any length
``segments``                    Segments or None      full-image-compressed readout (None: none)
``windows``                     sequence of Window    windows readout (empty: none)
``truth``                       FrameGeometry / None  true pose (Moon-centred), for metrics only
==============================  ====================  ==========================================

Optional: ``R_body_to_inertial`` ((3, 3) array) for a triaxial body (a sphere needs none).

:class:`NavDataset` - a sequence of frames with its camera: ``camera`` (a
:class:`~starnav.camera.Camera`), ``len()`` and iteration in time order.

:class:`Frame` is a plain frozen implementation of :class:`NavFrame`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from starnav.camera import Camera
from starnav.detector.products import Segments, Window
from starnav.geometry import FrameGeometry
from starnav.typing import FloatArray


@runtime_checkable
class NavFrame(Protocol):
    """One frame for the navigation chain (see the module table)."""

    index: int
    epoch_tdb: float
    R_cam_to_inertial_measured: FloatArray
    sun_direction_inertial: FloatArray
    segments: Segments | None
    windows: Sequence[Window]
    truth: FrameGeometry | None


@runtime_checkable
class NavDataset(Protocol):
    """A time-ordered sequence of :class:`NavFrame` with its camera."""

    camera: Camera

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[NavFrame]: ...


@dataclass(frozen=True)
class Frame:
    """A plain :class:`NavFrame`."""

    index: int
    epoch_tdb: float
    R_cam_to_inertial_measured: FloatArray
    sun_direction_inertial: FloatArray
    segments: Segments | None
    windows: Sequence[Window] = ()
    truth: FrameGeometry | None = None
    R_body_to_inertial: FloatArray | None = None


@dataclass
class FrameList:
    """A :class:`NavDataset` held in memory."""

    camera: Camera
    frames: list[NavFrame] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def __iter__(self) -> Iterator[NavFrame]:
        return iter(self.frames)
