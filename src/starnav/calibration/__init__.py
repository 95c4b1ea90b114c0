"""starnav.calibration: emulation of the hardware-in-the-loop bench of the seed paper.

A screen in the focal plane of a collimator stimulates the star tracker as if it looked at the
Moon in orbit; this subpackage models that bench and runs its procedures end to end:

* :mod:`~starnav.calibration.schema`: the ``BENCH`` file (:class:`BenchConfig`);
* :mod:`~starnav.calibration.collimator`: stimulator condition (eq. 2), spot, distortion,
  vignetting; :mod:`~starnav.calibration.screen`: counts <-> radiance at the camera;
* :mod:`~starnav.calibration.bench`: geometry, emulated acquisition, :func:`check_bench`;
* :mod:`~starnav.calibration.geometric`: dot-pattern calibration, pre-warping;
* :mod:`~starnav.calibration.intrinsics`: the camera's intrinsics with their covariance (the
  file navigation reads); :mod:`~starnav.calibration.star_field`: their star-field hold-out;
* :mod:`~starnav.calibration.radiometric`: count <-> Moon flux, calibrated stimuli;
* :mod:`~starnav.calibration.scaling`: albedo-exposure scaling, KS equivalence, end to end;
* :mod:`~starnav.calibration.radiometric_truth`, :mod:`~starnav.calibration.radiometric_lab`:
  the screen as it really is, the reference instrument, and the calibration against it;
* :mod:`~starnav.calibration.workflows`: what ``starnav hil`` runs.

Names are imported lazily.

>>> from starnav.calibration import Bench, BenchConfig, check_bench
>>> check_bench(Bench(BenchConfig())).fills_field
False
"""

from __future__ import annotations

from starnav._lazy import lazy_exports

_EXPORTS = {
    "BenchConfig": "schema", "load_bench": "schema", "bench_from_dict": "schema",
    "bench_to_dict": "schema", "representative_emittance": "schema",
    "Bench": "bench", "BenchGeometry": "bench", "BenchCheck": "bench", "check_bench": "bench",
    "ChainDetector": "bench", "IdealDetector": "bench", "DetectorStage": "bench",
    "Acquisition": "bench",
    "stimulator_condition": "collimator", "SpotModel": "collimator",
    "ScreenRadiometry": "screen",
    "calibrate_geometry": "geometric", "GeometricCalibration": "geometric",
    "GeometricCalibrationResult": "geometric", "NominalMapping": "geometric",
    "TrueMapping": "geometric", "prewarp": "geometric", "stimulus_counts": "geometric",
    "CalibrationError": "geometric",
    "estimate_camera": "intrinsics", "calibrate_camera": "intrinsics",
    "IntrinsicsResult": "intrinsics", "as_built_camera": "bench",
    "run_star_field_holdout": "star_field", "star_field_holdout": "star_field",
    "moon_flux": "radiometric", "count_flux_mapping": "radiometric",
    "compare_stimulus": "radiometric",
    "plan_scaling": "scaling", "albedo_exposure_experiment": "scaling",
    "end_to_end": "scaling", "bench_min_exposure": "scaling",
    "TruthScreen": "radiometric_truth", "ReferenceInstrument": "radiometric_truth",
    "calibrate_radiometry": "radiometric_lab", "validate_radiometry": "radiometric_lab",
    "RadiometricCalibration": "radiometric_lab",
    "compare_moon_stimulus": "moon_stimulus", "MoonStimulusComparison": "moon_stimulus",
    "run_check": "workflows", "run_geometric": "workflows", "run_radiometric": "workflows",
    "run_stimulate": "workflows", "HilReport": "workflows",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
