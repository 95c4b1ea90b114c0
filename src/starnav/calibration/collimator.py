"""The collimator: optical-stimulator condition, aberration spot over the field, distortion,
vignetting.

1. Optical-stimulator condition (seed paper eq. 2): the field is filled when
   ``f_coll <= h_s / (2 tan(FoV / 2))`` (:func:`stimulator_condition`); evaluated for the
   stated and the derived field in docs/calibration.md, "1. The collimator condition".
2. Aberration spot (Table 2): an angular RMS radius over the field, as a Gaussian
   (:class:`SpotModel`).
3. Distortion of the screen-to-angle map on the tangent (:func:`distort_tangent`).
4. Vignetting: overlap of the displaced beam with the camera pupil (:func:`vignetting`).

References
----------
Seed paper, "TinyV3RSE customization" (eq. 2, Table 2).

Index
-----
:func:`stimulator_condition`, :class:`StimulatorCondition`, :func:`implied_fov_deg`,
:class:`SpotModel`, :func:`distort_tangent`, :func:`vignetting`, :func:`disc_overlap_fraction`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from starnav.calibration.schema import CollimatorConfig
from starnav.constants import ARCSEC
from starnav.typing import FloatArray


# --------------------------------------------------------------------------- eq. 2
@dataclass(frozen=True)
class StimulatorCondition:
    """Seed paper eq. 2 for one field of view along one screen axis.

    Attributes
    ----------
    fov_deg : float
        Full field of view put in the condition [deg].
    fov_source : str
        Where it comes from (``"stated by the paper"``, ``"derived, vertical"``, ...).
    screen_extent_mm, focal_length_mm : float
        Screen size along that axis; collimator focal length [mm].
    lhs, rhs : float
        ``tan(FoV / 2)`` and ``h_s / (2 f_coll)`` [-].
    satisfied : bool
    max_focal_length_mm : float
        Longest collimator that still fills the field ``h_s / (2 tan(FoV/2))`` [mm].
    required_extent_mm : float
        Screen size needed ``2 f_coll tan(FoV/2)`` [mm].
    shortfall_mm : float
        ``required - available`` (> 0: not filled) [mm].
    """

    fov_deg: float
    fov_source: str
    screen_extent_mm: float
    focal_length_mm: float
    lhs: float
    rhs: float
    satisfied: bool
    max_focal_length_mm: float
    required_extent_mm: float
    shortfall_mm: float

    def to_dict(self) -> dict:
        return asdict(self)

    def sentence(self) -> str:
        """One line for reports."""
        if self.satisfied:
            return (f"FoV {self.fov_deg:.2f} deg ({self.fov_source}): tan(FoV/2) = "
                    f"{self.lhs:.5f} <= h/(2f) = {self.rhs:.5f}: the screen fills the field "
                    f"(f_coll <= {self.max_focal_length_mm:.1f} mm; margin "
                    f"{-self.shortfall_mm:.2f} mm)")
        return (f"FoV {self.fov_deg:.2f} deg ({self.fov_source}): tan(FoV/2) = {self.lhs:.5f} "
                f"> h/(2f) = {self.rhs:.5f}: the screen does NOT fill the field (needs "
                f"f_coll <= {self.max_focal_length_mm:.1f} mm or a screen of "
                f"{self.required_extent_mm:.2f} mm; short by {self.shortfall_mm:.2f} mm)")


def stimulator_condition(fov_deg: float, screen_height_mm: float, focal_length_mm: float,
                         fov_source: str = "") -> StimulatorCondition:
    """Evaluate ``tan(FoV/2) <= h_s / (2 f_coll)`` (seed paper eq. 2).

    Parameters
    ----------
    fov_deg : float
        Full field of view [deg].
    screen_height_mm : float
        Screen extent along the axis considered [mm].
    focal_length_mm : float
        Collimator focal length [mm].
    """
    lhs = math.tan(math.radians(fov_deg) / 2.0)
    rhs = screen_height_mm / (2.0 * focal_length_mm)
    required = 2.0 * focal_length_mm * lhs
    return StimulatorCondition(
        fov_deg=float(fov_deg), fov_source=fov_source, screen_extent_mm=float(screen_height_mm),
        focal_length_mm=float(focal_length_mm), lhs=lhs, rhs=rhs, satisfied=bool(lhs <= rhs),
        max_focal_length_mm=screen_height_mm / (2.0 * lhs), required_extent_mm=required,
        shortfall_mm=required - screen_height_mm)


def implied_fov_deg(screen_height_mm: float, max_focal_length_mm: float) -> float:
    """The full FoV [deg] for which eq. 2 gives ``max_focal_length_mm`` (e.g. the paper's
    180.07 mm with 65 mm: 20.46 deg)."""
    return 2.0 * math.degrees(math.atan(screen_height_mm / (2.0 * max_focal_length_mm)))


# --------------------------------------------------------------------------- the spot
@dataclass(frozen=True)
class SpotModel:
    """Angular RMS radius of the collimator's aberration spot over the field.

    Attributes
    ----------
    field : (n,) array
        Field angles of the table [rad].
    rms_radius : (n,) array
        RMS spot radius [rad].
    model : {"quadratic", "linear"}
    coef : (2,) array
        ``(a, b)`` of ``r = a + b theta^2`` [rad, rad^-1] (quadratic model).
    """

    field: FloatArray
    rms_radius: FloatArray
    model: str
    coef: FloatArray

    @classmethod
    def from_config(cls, cfg: CollimatorConfig) -> SpotModel:
        f = np.radians(np.asarray(cfg.spot_field_deg, float))
        r = np.asarray(cfg.spot_rms_radius_px, float) * cfg.spot_reference_ifov_arcsec * ARCSEC
        if cfg.spot_model == "quadratic":
            A = np.stack([np.ones_like(f), f * f], axis=1)
            coef = np.linalg.lstsq(A, r, rcond=None)[0]
        else:
            coef = np.array([np.nan, np.nan])
        return cls(f, r, cfg.spot_model, coef)

    def rms_radius_at(self, theta: ArrayLike) -> FloatArray:
        """RMS spot radius at field angle ``theta`` [rad] -> [rad] (never negative)."""
        t = np.abs(np.asarray(theta, float))
        if self.model == "quadratic":
            out = self.coef[0] + self.coef[1] * t * t
        else:
            out = np.interp(t, self.field, self.rms_radius)
        return np.maximum(out, 0.0)

    def sigma_at(self, theta: ArrayLike) -> FloatArray:
        """Per-axis Gaussian sigma ``r_rms / sqrt(2)`` at field angle ``theta`` [rad] -> [rad]."""
        return self.rms_radius_at(theta) / math.sqrt(2.0)


# --------------------------------------------------------------------------- distortion
def distort_tangent(t: ArrayLike, k1: float, k2: float = 0.0) -> FloatArray:
    """Collimator distortion on tangent-plane coordinates ``(..., 2)``: ``t (1 + k1 r^2 +
    k2 r^4)``, ``r = |t|`` [-]."""
    t = np.asarray(t, float)
    r2 = t[..., 0] ** 2 + t[..., 1] ** 2
    f = 1.0 + r2 * (k1 + k2 * r2)
    return t * f[..., None]


# --------------------------------------------------------------------------- vignetting
def disc_overlap_fraction(aperture_radius: float, pupil_radius: float,
                          separation: ArrayLike) -> FloatArray:
    """Fraction of a disc of ``pupil_radius`` covered by a disc of ``aperture_radius`` whose
    centre is ``separation`` away (any consistent length unit) [-]."""
    R, r = float(aperture_radius), float(pupil_radius)
    sep = np.asarray(separation, float)
    d = np.abs(np.atleast_1d(sep)).astype(float)
    out = np.zeros_like(d)
    inside = d <= abs(R - r)
    out[inside] = 1.0 if R >= r else (R / r) ** 2
    part = (~inside) & (d < R + r)
    if np.any(part):
        dd = d[part]
        a1 = r * r * np.arccos(np.clip((dd * dd + r * r - R * R) / (2 * dd * r), -1, 1))
        a2 = R * R * np.arccos(np.clip((dd * dd + R * R - r * r) / (2 * dd * R), -1, 1))
        a3 = 0.5 * np.sqrt(np.maximum((-dd + r + R) * (dd + r - R) * (dd - r + R)
                                      * (dd + r + R), 0.0))
        out[part] = (a1 + a2 - a3) / (math.pi * r * r)
    return out.reshape(sep.shape)


def vignetting(cfg: CollimatorConfig, pupil_diameter: float, tan_theta: ArrayLike) -> FloatArray:
    """Share of the camera pupil (diameter [m]) filled by the collimated beam at field
    ``tan_theta`` [-]; 1 everywhere when ``clear_aperture_mm`` is not set."""
    t = np.asarray(tan_theta, float)
    if cfg.clear_aperture_mm is None:
        return np.ones_like(t)
    sep = cfg.pupil_distance_mm * 1e-3 * t
    return disc_overlap_fraction(cfg.clear_aperture_mm * 0.5e-3, pupil_diameter / 2.0, sep)
