"""What the fly-by front end hands to the estimator, one record per frame.

The contract between feature tracking (:mod:`~starnav.navigation.trn.features`) and the filter
(:mod:`~starnav.navigation.trn.filter`): pixel measurements with their 1-sigma, the tracker's
own (measured) attitude, and the body's centroid and apparent size from the segments read.
Pixel coordinates follow :class:`~starnav.camera.Camera`: ``(u, v)`` = (column, row), pixel
centres at integers, distorted detector coordinates (``Camera.project`` with ``distort=True``).
Truth is kept apart (:class:`FeatureTruth`) and never read by the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from starnav.typing import FloatArray


@dataclass(frozen=True)
class FeatureObservation:
    """One tracked feature in one frame.

    Attributes
    ----------
    track_id : int
        Identity of the track across frames (a re-acquired feature gets a new id).
    uv : (2,) array
        Measured pixel position [px].
    sigma_px : float
        1-sigma of each pixel coordinate [px].
    window : int
        Index of the window it was measured in (-1: none; never for a windows-only run).
    """

    track_id: int
    uv: FloatArray
    sigma_px: float
    window: int = -1


@dataclass(frozen=True)
class FeatureTruth:
    """The truth of a feature observation (for metrics only): the body-fixed surface point the
    tracked pixel shows and its exact projection."""

    track_id: int
    point_body: FloatArray
    uv_true: FloatArray


@dataclass(frozen=True)
class FlybyMeasurement:
    """One frame of the fly-by front end.

    Attributes
    ----------
    frame_index : int
    epoch_tdb : float
        Mid-exposure epoch [s TDB].
    R_cam_to_inertial : (3, 3) array
        The tracker's measured attitude (camera -> inertial).
    attitude_sigma : (3,) array
        1-sigma of the attitude error about the camera x, y, z axes [rad].
    features : tuple of FeatureObservation
    centroid_uv : (2,) array or None
        Centre of the body's silhouette (not of its brightness) from the segments read [px].
    centroid_sigma_px : float
    apparent_radius_px : float or None
        Equivalent radius of the silhouette [px] (the scale measurement; see the filter's
        essay for what fixes the range).
    apparent_radius_sigma_px : float
    windows : tuple of (row0, col0, height, width)
        Windows read this frame (at most 16).
    pixels_read : int
        Pixels the gate array read (segments + windows), for the exposure law.
    truth : tuple of FeatureTruth
        Per-feature truth, same order as ``features`` (empty when unknown).
    sun_direction : (3,) array or None
        Body -> Sun unit vector, J2000 (the phase bias of the lit silhouette); None: the
        estimator's own ``sun_direction`` argument, else phase 0.
    """

    frame_index: int
    epoch_tdb: float
    R_cam_to_inertial: FloatArray
    attitude_sigma: FloatArray
    features: tuple[FeatureObservation, ...] = ()
    centroid_uv: FloatArray | None = None
    centroid_sigma_px: float = 1.0
    apparent_radius_px: float | None = None
    apparent_radius_sigma_px: float = 1.0
    windows: tuple[tuple[int, int, int, int], ...] = ()
    pixels_read: int = 0
    truth: tuple[FeatureTruth, ...] = field(default_factory=tuple)
    sun_direction: FloatArray | None = None
