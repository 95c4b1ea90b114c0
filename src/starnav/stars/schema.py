"""The ``stars`` section of a scenario: the star field in the frames (off by default)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from starnav.config_base import StrictModel


class StarsConfig(StrictModel):
    """Stars in the frames: Hipparcos stars brighter than ``magnitude_limit``, in physical
    units through the sensor response, spread by the detector's PSF (docs/stars.md)."""

    enabled: bool = Field(
        False, description="put the Hipparcos stars in the frames (off: a black sky, the frames "
        "exactly as before)")
    magnitude_limit: Annotated[float, Field(ge=-2.0, le=12.0)] = Field(
        6.5, description="faintest Johnson V magnitude drawn [mag]; the Hipparcos catalogue is "
        "complete to about V = 7.3")
    margin_px: Annotated[float, Field(ge=0.0, le=100.0)] = Field(
        8.0, description="stars up to this far outside the frame are drawn too, so their PSF "
        "wings enter it [px]")
    epoch_jyear: Annotated[float, Field(ge=1000, le=3000)] | None = Field(
        None, description="epoch of the star positions (proper motion) [Julian year], 1000 to "
        "3000 (the catalogue's linear proper motion from J1991.25 holds for centuries, not "
        "millennia); null: each frame's own epoch (J2000.0 for a static frame)")
    aberration: bool = Field(
        True, description="draw the stars at their apparent directions, aberrated by the "
        "camera's barycentric velocity (DE421 Earth-Moon barycentre + Moon + spacecraft; up to "
        "20.5 arcsec), and let the tracker correct for it; false: astrometric (ICRS) places "
        "drawn and solved, the behaviour before aberration was modelled")
    aberration_correction: bool = Field(
        True, description="with aberration on: the tracker corrects its catalogue to apparent "
        "directions with its own velocity (false, for comparison: the uncorrected tracker, "
        "its attitude biased by up to 20.5 arcsec)")
