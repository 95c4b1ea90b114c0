"""The packaged ROLO calibration of the real Moon: consistent with the data it was made from.

The calibration itself is scored on renders in tests/renderer/test_real_moon.py; here: it belongs
to the packaged map and ROLO table (a changed map without a new calibration is caught), its
colour is ROLO's, and its values are physical.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from starnav import photometry as ph
from starnav.data import packaged_path
from starnav.lunar_calibration import lunar_calibration
from starnav.reference.rolo import ROLO_WAVELENGTHS_NM, rolo_reflectance


def _sha256(rel: str) -> str:
    return hashlib.sha256(packaged_path(rel).read_bytes()).hexdigest()


def test_calibration_belongs_to_the_packaged_data():
    prov = lunar_calibration().provenance
    assert prov["albedo_map_sha256"] == _sha256("albedo/lroc_wac_grey_2048.tif")
    assert prov["rolo_coefficients_sha256"] == _sha256("rolo/rolo_coefficients.csv")


def test_fitted_values_are_physical_and_inside_their_bounds():
    cal = lunar_calibration()
    fit = cal.fit
    values = {"k": cal.mean_normal_albedo, "q": cal.contrast_exponent, **cal.hapke}
    for name, lo, hi in zip(fit["free"], fit["lower"], fit["upper"], strict=True):
        assert lo < values[name] < hi, name
    w_lo, w_hi = fit["hapke_w_range"]
    assert 0.0 < w_lo < w_hi < 1.0
    # the Moon's mean normal albedo at 550 nm is of the order of its geometric albedo 0.12
    # (NASA fact sheet) and below the bright highlands' 0.25-0.30 (docs/facts.md section 2)
    assert 0.10 < cal.mean_normal_albedo < 0.25
    assert fit["max_abs_dev"] < 0.02
    # roughness and coherent backscatter are Sato's, not fitted
    assert cal.hapke["theta_bar_deg"] == ph.HAPKE_LUNAR_DEFAULTS["theta_bar_deg"]


def test_spectral_shape_is_rolos_reddening():
    cal = lunar_calibration()
    s = cal.spectral_shape()
    assert s(np.array([cal.reference_wavelength_nm]))[0] == pytest.approx(1.0, abs=1e-6)
    # ROLO at 30 deg (Kieffer & Stone 2005 via starnav.reference): A(745)/A(405) = 1.50
    a = rolo_reflectance(math.radians(30.0), math.radians(30.0), wavelength_nm=[405.0, 745.3])
    assert s(np.array([745.3]))[0] / s(np.array([405.0]))[0] == pytest.approx(
        a[1] / a[0], rel=0.03)
    assert np.array_equal(np.asarray(cal.spectral_wavelengths_nm), ROLO_WAVELENGTHS_NM)
