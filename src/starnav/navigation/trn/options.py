"""Settings of the fly-by front end (kept apart from OpenCV so that reading a scenario does not
import it; the table of their effects is in :mod:`starnav.navigation.trn.frontend`)."""

from __future__ import annotations

from dataclasses import dataclass

from starnav.detector.products import MAX_WINDOWS
from starnav.errors import ConfigError


@dataclass(frozen=True)
class FrontEndOptions:
    """Settings of the fly-by front end (module table; pixels, counts, fractions, radians);
    the error terms are the rendered-frame calibration (tools/calibrate_flyby_model_error.py,
    the defaults of ``navigation.trn.front_end``)."""

    n_windows: int = 8
    core_px: int = 16
    template_half_px: int = 7
    search_margin_px: int = 5
    max_window_px: int = 64
    limb_margin_px: float = 6.0
    min_tracks_per_window: int = 3
    max_tracks_per_window: int = 6
    quality: float = 0.05
    min_distance_px: float = 5.0
    block_px: int = 7
    fb_max_px: float = 0.3
    epipolar_px: float = 1.0
    ransac_iterations: int = 100
    min_body_area_px: int = 50
    sigma_detect_px: float = 1.51
    drift_px_per_rad: float = 3.75
    centroid_sigma_fraction: float = 0.000326
    radius_sigma_fraction: float = 0.000208
    correlation_factor: float = 3.0
    max_track_turn: float = 0.08726646259971647  # 5 deg

    def __post_init__(self) -> None:
        if not 1 <= self.n_windows <= MAX_WINDOWS:
            raise ConfigError("navigation.trn.front_end.n_windows", self.n_windows,
                              f"1..{MAX_WINDOWS} windows (AA-STR windows mode)")
        for name in ("core_px", "template_half_px", "max_window_px", "min_tracks_per_window",
                     "max_tracks_per_window", "block_px", "ransac_iterations",
                     "min_body_area_px"):
            if getattr(self, name) < 1:
                raise ConfigError(f"navigation.trn.front_end.{name}", getattr(self, name),
                                  "an integer >= 1")
        if not self.correlation_factor >= 1.0:
            raise ConfigError("navigation.trn.front_end.correlation_factor",
                              self.correlation_factor, ">= 1 (a factor on the feature sigma)")
        if not self.max_track_turn > 0:
            raise ConfigError("navigation.trn.front_end.max_track_turn_deg",
                              self.max_track_turn, "> 0 (the view change a track may live)")
        if self.search_margin_px < 0:
            raise ConfigError("navigation.trn.front_end.search_margin_px",
                              self.search_margin_px, "an integer >= 0")
        if self.max_tracks_per_window < self.min_tracks_per_window:
            raise ConfigError("navigation.trn.front_end.max_tracks_per_window",
                              self.max_tracks_per_window,
                              f">= min_tracks_per_window ({self.min_tracks_per_window})")
        if self.max_window_px < self.birth_window_px:
            raise ConfigError("navigation.trn.front_end.max_window_px", self.max_window_px,
                              f">= a birth window's side core_px + 2 (template_half_px + "
                              f"search_margin_px + 1) = {self.birth_window_px}")

    @property
    def patch_half_px(self) -> int:
        """Half side of the tracking patch: template + search margin + 1 [px]."""
        return self.template_half_px + self.search_margin_px + 1

    @property
    def template_store_half_px(self) -> int:
        """Half side of the template kept from a frame for the next: the LK window plus 2 px
        for its image derivatives [px]."""
        return self.template_half_px + 2

    @property
    def birth_window_px(self) -> int:
        return self.core_px + 2 * self.patch_half_px
