"""Published references the rendered Moon is measured against.

Public API (imported lazily; this module imports nothing heavy)::

    from starnav.reference import rolo_reflectance, rolo_irradiance_for_frame

    A = rolo_reflectance(phase, sun_lon)                  # (32,) disc reflectance A_k [-]
    r = rolo_irradiance_for_frame(geom, response=resp)    # RoloIrradiance: W m^-2, e- s^-1 m^-2

* :mod:`starnav.reference.rolo` - the ROLO lunar disc-reflectance model (Kieffer & Stone 2005,
  model 311g): ``A(lambda, g, Phi, theta, phi)``, the Moon's irradiance at an observer, the
  ROLO geometry of a :class:`~starnav.geometry.FrameGeometry`.
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_LAZY = {
    "ROLO_WAVELENGTHS_NM": "starnav.reference.rolo",
    "ROLO_PHASE_RANGE": "starnav.reference.rolo",
    "RoloCoefficients": "starnav.reference.rolo",
    "RoloGeometry": "starnav.reference.rolo",
    "RoloIrradiance": "starnav.reference.rolo",
    "rolo_coefficients": "starnav.reference.rolo",
    "rolo_extrapolation": "starnav.reference.rolo",
    "rolo_reflectance": "starnav.reference.rolo",
    "rolo_spectrum": "starnav.reference.rolo",
    "rolo_irradiance": "starnav.reference.rolo",
    "rolo_geometry": "starnav.reference.rolo",
    "rolo_irradiance_for_frame": "starnav.reference.rolo",
}

__all__ = [*_LAZY]
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
