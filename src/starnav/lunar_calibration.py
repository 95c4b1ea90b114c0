"""The real Moon's brightness: photometric constants calibrated once against the ROLO model.

The LROC WAC mosaic that starnav ships (``data/albedo/``) says where the Moon is brighter, not
how bright. Four constants make it the Moon's normal albedo and colour:

1. a **contrast exponent** ``q`` (grey ``Y`` becomes ``Y**q``): the mosaic's tone curve is not
   documented; ``q`` is set by ROLO's dependence on the Sun's selenographic longitude (waxing
   and waning Moons differ because the maria lie on the western near side), an independent
   measure of the albedo contrast;
2. the **mean normal albedo** ``k`` at the reference wavelength (area-weighted global mean);
3. the **Hapke phase-function and opposition parameters** ``b, c, B_S0, h_S``, fitted within
   their published ranges (Sato et al. 2014's fall off too steeply against ROLO); roughness
   and coherent backscatter keep Sato's values;
4. the **spectral shape** ``s(lambda)``, 1 at the reference wavelength: ROLO's
   A(lambda, g) / A(550 nm, g), geometric mean over the fitted phases (not fitted).

``tools/calibrate_moon_rolo.py`` fits the disc-integrated Hapke Moon with the map against ROLO
over the AA-STR band (waxing and waning, phases 3-93 deg) and writes
``data/moon/rolo_calibration.json`` with its provenance. Tests score the *rendered* Moon at
other geometries.

References
----------
* Kieffer, H. H. & Stone, T. C. (2005), The spectral irradiance of the Moon, AJ 129, 2887.
* Sato, H. et al. (2014), Resolved Hapke parameter maps of the Moon, JGR Planets 119,
  doi:10.1002/2013JE004580.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.resources import files
from typing import Any

import numpy as np

from starnav.errors import DataFileError
from starnav.spectra import Spectrum

#: Package-relative path of the calibration file.
CALIBRATION_FILE = "data/moon/rolo_calibration.json"


@dataclass(frozen=True)
class LunarCalibration:
    """The calibrated constants (see the module docstring).

    Attributes
    ----------
    hapke : dict
        Hapke parameters (``b, c, bs0, hs, bc0, hc, theta_bar_deg``).
    mean_normal_albedo : float
        Area-weighted global mean normal albedo of the map at the reference wavelength [-].
    contrast_exponent : float
        ``q`` applied to the map's relative linear grey values [-].
    reference_wavelength_nm : float
        Wavelength at which ``spectral_factor`` is 1 and the normal albedo is defined [nm].
    spectral_wavelengths_nm, spectral_factor : tuple of float
        The spectral shape ``s(lambda)`` [-].
    fit : dict
        Fit geometry, residuals and band (what the script printed).
    provenance : dict
        Inputs (files, their SHA-256), script, date.
    """

    hapke: dict[str, float]
    mean_normal_albedo: float
    contrast_exponent: float
    reference_wavelength_nm: float
    spectral_wavelengths_nm: tuple[float, ...]
    spectral_factor: tuple[float, ...]
    fit: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    def spectral_shape(self) -> Spectrum:
        """``s(lambda)`` as a :class:`~starnav.spectra.Spectrum` [-]."""
        return Spectrum(np.asarray(self.spectral_wavelengths_nm, float),
                        np.asarray(self.spectral_factor, float), unit="-")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LunarCalibration:
        return cls(hapke={k: float(v) for k, v in d["hapke"].items()},
                   mean_normal_albedo=float(d["mean_normal_albedo"]),
                   contrast_exponent=float(d["contrast_exponent"]),
                   reference_wavelength_nm=float(d["reference_wavelength_nm"]),
                   spectral_wavelengths_nm=tuple(float(x) for x in d["spectral_wavelengths_nm"]),
                   spectral_factor=tuple(float(x) for x in d["spectral_factor"]),
                   fit=dict(d.get("fit", {})), provenance=dict(d.get("provenance", {})))

    def to_dict(self) -> dict[str, Any]:
        return {"hapke": self.hapke, "mean_normal_albedo": self.mean_normal_albedo,
                "contrast_exponent": self.contrast_exponent,
                "reference_wavelength_nm": self.reference_wavelength_nm,
                "spectral_wavelengths_nm": list(self.spectral_wavelengths_nm),
                "spectral_factor": list(self.spectral_factor),
                "fit": self.fit, "provenance": self.provenance}


@lru_cache(maxsize=1)
def lunar_calibration() -> LunarCalibration:
    """The packaged calibration (read once)."""
    res = files("starnav").joinpath(CALIBRATION_FILE)
    try:
        text = res.read_text()
    except (FileNotFoundError, OSError):
        raise DataFileError(f"packaged file starnav/{CALIBRATION_FILE} is missing (re-install "
                            "starnav, or run tools/calibrate_moon_rolo.py)") from None
    return LunarCalibration.from_dict(json.loads(text))
