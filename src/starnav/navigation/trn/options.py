"""Settings of the fly-by front end, the scenario section ``navigation.trn.front_end`` (kept
apart from OpenCV so that reading a scenario does not import it).

Index
-----
:class:`TrnFrontEndConfig`, :func:`patch_half_px`, :func:`template_store_half_px`,
:func:`birth_window_px`, :data:`BLOCK_PX`, :data:`RANSAC_ITERATIONS`, :data:`MIN_BODY_AREA_PX`.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, model_validator

from starnav.config_base import StrictModel
from starnav.detector.products import MAX_WINDOWS
from starnav.fields import NonNegativeFloat, PositiveFloat

#: Neighbourhood of the Shi-Tomasi corner measure and of the segments' texture map [px].
BLOCK_PX = 7
#: Hypotheses of the epipolar RANSAC.
RANSAC_ITERATIONS = 100
#: Smallest lit body the segments analysis accepts [px].
MIN_BODY_AREA_PX = 50


def patch_half_px(o: Any) -> int:
    """Half side of the tracking patch of settings ``o``: template + search margin + 1 [px]."""
    return int(o.template_half_px + o.search_margin_px + 1)


def template_store_half_px(o: Any) -> int:
    """Half side of the template kept from a frame for the next: the LK window plus 2 px for
    its image derivatives [px]."""
    return int(o.template_half_px + 2)


def birth_window_px(o: Any) -> int:
    """Side of a birth window: the detection core and a tracking patch on each side [px]."""
    return int(o.core_px + 2 * patch_half_px(o))


class TrnFrontEndConfig(StrictModel):
    """Scenario section ``navigation.trn.front_end``: windows and feature tracking
    (:class:`~starnav.navigation.trn.frontend.FlybyFrontEnd` reads its SI view, ``to_si()``;
    the error terms are the rendered-frame calibration, tools/calibrate_flyby_model_error.py).
    """

    n_windows: Annotated[int, Field(ge=1, le=MAX_WINDOWS)] = Field(
        8, description="windows read per frame (AA-STR: at most 16)")
    core_px: Annotated[int, Field(ge=1)] = Field(
        16, description="side of the region a new window detects features in [px]")
    template_half_px: Annotated[int, Field(ge=1)] = Field(
        7, description="half side of the Lucas-Kanade template [px]")
    search_margin_px: Annotated[int, Field(ge=0)] = Field(
        5, description="room for the motion-prediction error around the template [px]")
    max_window_px: Annotated[int, Field(ge=1)] = Field(64, description="largest window side [px]")
    limb_margin_px: NonNegativeFloat = Field(
        6.0, description="clearance of features from the lit mask's edge (limb, terminator) [px]")
    min_tracks_per_window: Annotated[int, Field(ge=1)] = Field(
        3, description="a window with fewer tracks detects new features")
    max_tracks_per_window: Annotated[int, Field(ge=1)] = Field(
        6, description="tracks per window at most")
    quality: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.05, description="Shi-Tomasi quality level (fraction of the window's best corner) [-]")
    min_distance_px: PositiveFloat = Field(5.0, description="distance between features [px]")
    fb_max_px: PositiveFloat = Field(0.3, description="forward-backward tracking limit [px]")
    epipolar_px: PositiveFloat = Field(
        1.0, description="epipolar RANSAC threshold (known attitude) [px]")
    sigma_detect_px: NonNegativeFloat = Field(
        1.51, description="1-sigma of a feature at its first detection [px] (calibrated on "
        "rendered frames: tools/calibrate_flyby_model_error.py)")
    drift_px_per_rad: NonNegativeFloat = Field(
        3.75, description="growth of a feature's 1-sigma with the camera rotation summed "
        "along its track [px/rad] (the shading moves on the surface as the view turns)")

    correlation_factor: Annotated[float, Field(ge=1)] = Field(
        3.0, description="factor on every feature's 1-sigma for its error's correlation "
        "along a track (chosen on rendered frames by the pass's thirds: "
        "tools/calibrate_flyby_model_error.py) [-]")
    max_track_turn_deg: PositiveFloat = Field(
        5.0, description="a track ends once the view has turned this much along it (bounds "
        "its drift; the point is found again under a new id) [deg]")
    centroid_sigma_fraction: NonNegativeFloat = Field(
        0.000326, description="1-sigma of the segments' lit centroid per coordinate, times the "
        "apparent radius (its noise; calibrated) [-]")
    radius_sigma_fraction: NonNegativeFloat = Field(
        0.000208, description="1-sigma of the segments' apparent radius, times the radius (its "
        "noise; calibrated) [-]")

    @model_validator(mode="after")
    def _fits(self) -> TrnFrontEndConfig:
        if self.max_tracks_per_window < self.min_tracks_per_window:
            raise ValueError(f"max_tracks_per_window ({self.max_tracks_per_window}) must be >= "
                             f"min_tracks_per_window ({self.min_tracks_per_window})")
        if self.max_window_px < birth_window_px(self):
            raise ValueError(f"max_window_px ({self.max_window_px}) must be >= a birth "
                             "window's side core_px + 2 (template_half_px + search_margin_px "
                             f"+ 1) = {birth_window_px(self)}")
        return self
