"""Real SMART-1 AMIE frames of the Moon (ESA PSA ``S1-L/X-AMIE-2-EDR-EEP-V1.1``), shipped in
``starnav/data/amie`` (see its ``PROVENANCE.md``).

Public API (imported lazily; this package imports nothing heavy)::

    from starnav.reference.amie import calibrate, moon_signal, packaged_frame, read_amie

    frame = read_amie(packaged_frame("041111_00070"))   # AmieFrame: dn [DN], valid, label in SI
    cal = calibrate(frame)                              # AmieCalibrated: DN, e-, e-/s, valid
    moon_signal(cal).e_per_s                            # pixels above background + 5 sigma [e-/s]

* :mod:`starnav.reference.amie.frame` - the PDS3 reader (``DN = stored >> 6``), the validity
  mask (marker, saturation, the dark top band) and the calibration (bias, sky background with
  the column stripes, flat, gain, exposure).
* :mod:`starnav.reference.amie.geometry`, :mod:`~starnav.reference.amie.presets`,
  :mod:`~starnav.reference.amie.validate` - the view rebuilt from a label, the AMIE camera as a
  scenario, and the real-versus-simulated comparison (import them directly).
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_LAZY = {
    "AMIE_FRAMES": "frame",
    "BIAS_LAWS": "frame",
    "AmieCalibrated": "frame",
    "AmieCalibrationOptions": "frame",
    "AmieFrame": "frame",
    "MoonSignal": "frame",
    "calibrate": "frame",
    "dark_band_rows": "frame",
    "moon_signal": "frame",
    "packaged_frame": "frame",
    "read_amie": "frame",
    "silicon_thermal_factor": "frame",
}

__all__ = [*_LAZY]
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
