"""The SMART-1 AMIE camera as a starnav scenario: camera, sensor response and detector.

Each value with its source and trust (the instrument kernel SMART1_AMIE_V01.TI, the frames'
labels, the ABRAM AMIE validation's response curve, the in-flight plate scale of
:mod:`.plate_scale`, the QE and PSF core measured on Vega by :mod:`.vega`): docs/real-images.md
and docs/methods.md, "starnav.reference.amie.presets". The real frames are bias- and
flat-corrected, so the simulation is made bias-free and flat; dark current, PRNU, stray light,
ghosts and smear are off.

Index
-----
:func:`amie_scenario`, :func:`amie_detector`, :func:`amie_plate_scale`,
:func:`amie_psf_sigma_px`, :data:`AMIE_NOMINAL_FOCAL_LENGTH_M`, :data:`AMIE_GAIN_E_PER_DN`,
:data:`AMIE_READ_NOISE_E`, :data:`AMIE_BITS`, :data:`PLATE_SCALE_FILE`.
"""

from __future__ import annotations

import json
from typing import Any

from starnav.camera import CAMERA_PRESETS
from starnav.data import packaged_path
from starnav.reference.amie.vega import load_calibration

#: The instrument kernel's focal length [m] (the ``amie`` camera preset).
AMIE_NOMINAL_FOCAL_LENGTH_M = CAMERA_PRESETS["amie"].focal_length
#: The in-flight plate scale (``starnav/data/amie/plate_scale.json``, written by
#: ``tools/calibrate_amie_plate_scale.py``; :mod:`starnav.reference.amie.plate_scale`).
PLATE_SCALE_FILE = "amie/plate_scale.json"


def amie_plate_scale() -> dict[str, Any]:
    """The packaged in-flight plate scale: ``focal_scale`` (calibrated / nominal focal
    length), its standard error ``focal_scale_sigma``, a frame's predictive range 1-sigma
    ``frame_range_sigma_fraction``, ``focal_length_m``, the per-frame and per-epoch values
    and the ``method``."""
    return json.loads(packaged_path(PLATE_SCALE_FILE).read_text())


def amie_psf_sigma_px() -> float:
    """The PSF core's Gaussian sigma [px], measured on Vega (``amie/vega_calibration.json``,
    :mod:`starnav.reference.amie.vega`)."""
    return float(load_calibration()["psf_sigma_px"])
#: Gain [e-/DN] (label).
AMIE_GAIN_E_PER_DN = 280.0
#: Read noise [e-]: the calibrated dark sky's rms (0.51-0.62 DN) x the gain.
AMIE_READ_NOISE_E = 0.55 * AMIE_GAIN_E_PER_DN
#: ADC resolution [bit].
AMIE_BITS = 10


def amie_detector(exposure_s: float) -> dict[str, Any]:
    """The ``detector`` section of an AMIE scenario (values and sources: docs/methods.md)."""
    sigma = amie_psf_sigma_px()
    return {
        "exposure_time_s": float(exposure_s),
        "optics": {
            "radiometry": {"relative_illumination": False},
            "aberration": {"enabled": True, "defocus_radius_px": 0.0,
                           "defocus_radius_edge_px": 0.0, "sigma_px": sigma,
                           "sigma_radial_edge_px": sigma, "sigma_tangential_edge_px": sigma},
            "distortion": {"enabled": False},
            "stray_light": {"enabled": False},
            "ghosts": {"enabled": False},
        },
        "smear": {"rolling_shutter": {"enabled": False}, "transfer": {"enabled": False}},
        "charge": {"prnu": {"enabled": False}, "dark_current": {"enabled": False}},
        "saturation": {"full_well_e": 300_000.0, "blooming": {"enabled": False}},
        "signal": {"ipc": {"enabled": False}, "electrical_crosstalk": {"enabled": False},
                   "nonlinearity": {"enabled": False},
                   "read_noise": {"sigma_e": AMIE_READ_NOISE_E}},
        "adc": {"bits": AMIE_BITS, "gain_e_per_dn": AMIE_GAIN_E_PER_DN, "offset_dn": 0.0},
        "readout": {"modes": ["full_frame"], "timing": {"policy": "ignore"}},
    }


def amie_scenario(exposure_s: float, spp: int = 16, *,
                  calibrated_focal_length: bool = False) -> dict[str, Any]:
    """A scenario dict for an AMIE frame: the ``amie`` camera and response, the AMIE detector,
    the default (real, ROLO-calibrated) Moon. The geometry is given per frame.
    ``calibrated_focal_length``: the in-flight focal length (:func:`amie_plate_scale`) instead
    of the instrument kernel's."""
    camera: dict[str, Any] = {"preset": "amie"}
    if calibrated_focal_length:
        camera["focal_length_mm"] = amie_plate_scale()["focal_length_m"] * 1e3
    return {
        "camera": camera,
        "sensor_response": {"preset": "amie"},
        "detector": amie_detector(exposure_s),
        "render": {"spp": int(spp)},
    }
