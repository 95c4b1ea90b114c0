"""starnav.calibration: emulation of the hardware-in-the-loop bench of the seed paper.

A screen in the focal plane of a collimator stimulates the star tracker as if it looked at the
Moon in orbit. This subpackage models that bench before any hardware exists and runs its
procedures end to end in software:

* :mod:`~starnav.calibration.schema` -- the ``BENCH`` file (:class:`BenchConfig`), TinyV3RSE
  defaults;
* :mod:`~starnav.calibration.collimator` -- optical-stimulator condition (eq. 2), Table 2
  spot, distortion, vignetting;
* :mod:`~starnav.calibration.screen` -- counts <-> radiance at the camera;
* :mod:`~starnav.calibration.bench` -- geometry, emulated acquisition, pluggable detector,
  :func:`check_bench`;
* :mod:`~starnav.calibration.geometric` -- dot-pattern calibration, pre-warping;
* :mod:`~starnav.calibration.intrinsics` -- the camera's focal length, principal point and
  distortion with their covariance (the file navigation reads);
* :mod:`~starnav.calibration.star_field` -- that camera's hold-out on the star-field stimulus;
* :mod:`~starnav.calibration.radiometric` -- count <-> Moon flux, calibrated stimuli and their
  validation;
* :mod:`~starnav.calibration.scaling` -- albedo-exposure scaling, KS equivalence, end to end;
* :mod:`~starnav.calibration.radiometric_truth` -- the screen and collimator as they really are,
  and the reference instrument that reads them;
* :mod:`~starnav.calibration.radiometric_lab` -- the radiometric calibration against that
  instrument, its products with their covariance and its hold-out validation;
* :mod:`~starnav.calibration.workflows` -- what ``starnav hil`` runs.

Names are imported lazily (nothing heavy at ``import starnav.calibration``).

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
