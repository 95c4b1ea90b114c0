"""The AMIE's in-flight plate scale, calibrated once on the packaged Moon frames.

With the instrument kernel's focal length the range measured on every real Moon frame is
short by 1.2-1.8 % (docs/real-images.md says why), so the focal length is calibrated in flight
and shipped with the ``amie`` preset (:func:`starnav.reference.amie.presets.amie_plate_scale`).

:func:`calibrate_plate_scale`:

1. the chain's range ``rho_i`` on each frame with the nominal camera against the label's
   ``D_i`` gives ``k_i = D_i / rho_i``;
2. frames grouped by day (one geometry, one measurement), ``k_e`` per epoch;
3. the scale is the epochs' mean; a new frame's predictive 1-sigma ``std(k_e) sqrt(1 + 1/n)``;
4. leave-one-epoch-out scores each epoch with the others' scale.

``tools/calibrate_amie_plate_scale.py`` writes the packaged JSON (:func:`write_plate_scale`).

Index
-----
:func:`calibrate_plate_scale`, :class:`PlateScale`, :func:`write_plate_scale`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from starnav.atomic import atomic_write_text
from starnav.errors import StarnavError
from starnav.reference.amie.frame import AMIE_FRAMES, packaged_frame
from starnav.reference.amie.presets import AMIE_NOMINAL_FOCAL_LENGTH_M
from starnav.reference.amie.validate import AmieOptions, RealLimbFix, real_limb_fix

__all__ = ["PlateScale", "calibrate_plate_scale", "write_plate_scale"]

DAY_S = 86400.0


@dataclass(frozen=True)
class PlateScale:
    """The in-flight plate scale of the AMIE (module method).

    Attributes
    ----------
    focal_scale, focal_scale_sigma : float
        Calibrated / nominal focal length and its standard error [-].
    frame_range_sigma_fraction : float
        Predictive 1-sigma of one frame's range with the calibrated focal length [-].
    focal_length_m, focal_length_sigma_m, nominal_focal_length_m : float
        The calibrated focal length, its standard error, the instrument kernel's [m].
    frames : dict
        Per frame: ``k`` (label / measured range), the range error with the nominal and the
        calibrated focal length [%], the leave-one-epoch-out error [%], the epoch (UTC day).
    epochs : dict
        Per epoch: its mean ``k``.
    method : str
        How it was made.
    """

    focal_scale: float
    focal_scale_sigma: float
    frame_range_sigma_fraction: float
    focal_length_m: float
    focal_length_sigma_m: float
    nominal_focal_length_m: float
    frames: dict[str, dict[str, Any]] = field(default_factory=dict)
    epochs: dict[str, float] = field(default_factory=dict)
    method: str = ""


def calibrate_plate_scale(paths: list[str | Path] | None = None,
                          options: AmieOptions | None = None) -> PlateScale:
    """The plate scale from the real frames (default: the packaged Moon frames).

    Raises
    ------
    StarnavError
        Fewer than two epochs with a fix (no scatter, no uncertainty).
    """
    if paths is None:
        paths = [packaged_frame(n) for n in AMIE_FRAMES if "040326" not in n]
    fixes: list[RealLimbFix] = [real_limb_fix(p, options) for p in paths]
    fixes = [f for f in fixes if math.isfinite(f.limb.range_m)]
    by_epoch: dict[int, list[RealLimbFix]] = {}
    for f in fixes:
        by_epoch.setdefault(int(f.epoch_tdb // DAY_S), []).append(f)
    if len(by_epoch) < 2:
        raise StarnavError(f"plate scale: {len(by_epoch)} epoch(s) with a fix: at least 2 "
                           "are needed for an uncertainty")
    k_e = {e: float(np.mean([f.focal_scale for f in fs])) for e, fs in by_epoch.items()}
    ks = np.array(list(k_e.values()))
    n = ks.size
    k = float(ks.mean())
    sd = float(ks.std(ddof=1))
    frames: dict[str, dict[str, Any]] = {}
    for e, fs in by_epoch.items():
        k_other = float(np.mean([v for ee, v in k_e.items() if ee != e]))
        for f in fs:
            frames[f.name] = {
                "k": f.focal_scale,
                "epoch_day": fs[0].name.split("_")[2],
                "range_error_nominal_pct": f.range_error_pct,
                "range_error_calibrated_pct":
                    100.0 * (f.limb.range_m * k - f.label_range_m) / f.label_range_m,
                "range_error_other_epochs_pct":
                    100.0 * (f.limb.range_m * k_other - f.label_range_m) / f.label_range_m,
            }
    f0 = AMIE_NOMINAL_FOCAL_LENGTH_M
    return PlateScale(
        focal_scale=k, focal_scale_sigma=sd / math.sqrt(n),
        frame_range_sigma_fraction=sd * math.sqrt(1.0 + 1.0 / n),
        focal_length_m=k * f0, focal_length_sigma_m=f0 * sd / math.sqrt(n),
        nominal_focal_length_m=f0, frames=frames,
        epochs={fs[0].name.split("_")[2]: k_e[e] for e, fs in by_epoch.items()},
        method=(f"mean over {n} epochs (UTC days) of label range / range fixed by the "
                "navigation chain on the real limb with the nominal focal length "
                "(frames of one day averaged first); sigma: standard error over the epochs; "
                "frame_range_sigma_fraction: std(epochs) sqrt(1 + 1/n), a new frame's "
                "predictive 1-sigma"))


def write_plate_scale(cal: PlateScale, path: str | Path) -> Path:
    """The calibration as JSON (atomic)."""
    doc = asdict(cal) | {"sources": {
        "frames": sorted(cal.frames),
        "tool": "tools/calibrate_amie_plate_scale.py",
        "chain": "starnav.reference.amie.validate.real_limb_fix (default AmieOptions)"}}
    return atomic_write_text(Path(path), json.dumps(doc, indent=2, sort_keys=True) + "\n")
