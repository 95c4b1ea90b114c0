"""Radiometric calibration of the bench against a reference instrument, its products with their
covariance, and a validation of the tracker's DN that can fail. Each step in full:
docs/methods.md, "starnav.calibration.radiometric_lab".

Technique
---------
1. Session (:func:`calibrate_radiometry`): the reference spectroradiometer at the camera's
   pupil reads full white on axis (monitor), the grey ``lut_counts``, full white over a field
   grid and the monitor again; readings are drift-corrected by the monitor.
2. Products (:class:`RadiometricCalibration`): the screen LUT with its covariance by term
   (absolute scale per luminance class, repeatability, spectral), the field factor with its
   sigma, the monitor reading, the albedo-exposure plan (:func:`plausibility`).
3. Validation (:func:`validate_radiometry`) at hold-out counts, exposures and field points: the
   tracker's dark-subtracted DN against the prediction, one budget line per term of
   :data:`TERMS`; **consistent** when no point exceeds the Bonferroni bound at a 1 % family
   false-alarm rate, **meets the paper's use** when ``coverage_k`` sigma is within
   ``tolerance`` everywhere.

The ``radiometric_lab`` switches (``model_field``, ``through_collimator``, ``measure_lut``,
``monitor``) turn a term off, as a lab that ignores it would: the tests' negative controls.

References
----------
Seed paper, "Radiometric Calibration"; JCGM 100:2008 (GUM), first order, uncorrelated terms
within a point.

Index
-----
:func:`calibrate_radiometry`, :func:`validate_radiometry`, :func:`plausibility`,
:func:`radiometric_lab`, :class:`RadiometricCalibration`, :data:`TERMS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats
from scipy.interpolate import RectBivariateSpline

from starnav.calibration.bench import Bench, DetectorStage
from starnav.calibration.radiometric_truth import ReferenceInstrument, TruthScreen
from starnav.calibration.scaling import bench_min_exposure
from starnav.errors import ConfigError
from starnav.spectra import band_integrals, solar_spectrum_from_config
from starnav.typing import FloatArray

FORMAT = "starnav-bench-radiometry"
VERSION = 1
#: Family false-alarm rate of the validation's consistency verdict [-].
FAMILY_ALPHA = 0.01
#: The paper's Moon: visual geometric albedo (docs/facts.md section 2) [-].
PAPER_ALBEDO = 0.12
#: Longest hold-out exposure whose brightest pixel stays below this share of the well [-].
FILL_FRACTION = 0.9
#: Budget terms, in the order they are reported.
TERMS = ("reference absolute", "reference repeatability", "reference spectral",
         "reference aperture",
         "LUT interpolation", "field factor", "field interpolation", "monitor / drift",
         "tracker patch", "tracker linearity")


# =========================================================================== products
@dataclass(frozen=True)
class RadiometricCalibration:
    """The radiometric calibration products (module essay, step 2).

    Attributes
    ----------
    counts : (n,) int array
        Calibrated grey counts (on axis).
    le : (n,) array
        Electron radiance at the camera, on axis, at the end of the session
        [e- s^-1 m^-2 sr^-1].
    covariance : dict of str -> (n, n) array
        Covariance of ``le`` by term (``absolute``, ``repeatability``, ``spectral``)
        [(e- s^-1 m^-2 sr^-1)^2].
    field_u, field_v : (nx,), (ny,) arrays
        Pinhole pixel coordinates of the field grid [px].
    field, field_sigma : (ny, nx) arrays
        Full white at a field point / on axis (ones if not measured), and its 1-sigma [-].
    monitor_le, monitor_sigma : float
        On-axis full white at the end of the session [e- s^-1 m^-2 sr^-1]; relative 1-sigma
        of its repeatability [-].
    session_end_s, drift_per_s : float
        End of the session after power-on [s]; relative drift of the monitor [1/s].
    options : dict
        The lab switches used (``model_field``, ``through_collimator``, ``measure_lut``,
        ``monitor``).
    provenance : dict
        Instrument, bench seed, method (free form).
    albedo_exposure : dict or None
        The paper's albedo-exposure plan made with this calibration (:func:`plausibility`).
    """

    counts: FloatArray
    le: FloatArray
    covariance: dict[str, FloatArray]
    field_u: FloatArray
    field_v: FloatArray
    field: FloatArray
    field_sigma: FloatArray
    monitor_le: float
    monitor_sigma: float
    session_end_s: float
    drift_per_s: float
    options: dict[str, bool]
    provenance: dict[str, Any] = field(default_factory=dict)
    albedo_exposure: dict[str, Any] | None = None

    @property
    def total_covariance(self) -> FloatArray:
        """Sum of the covariance terms [(e- s^-1 m^-2 sr^-1)^2]."""
        return sum(self.covariance.values(), np.zeros((len(self.le), len(self.le))))

    # ................................................................ the LUT
    def lut(self, counts: ArrayLike, le: ArrayLike | None = None) -> FloatArray:
        """On-axis electron radiance at (non-integer) grey counts: black level plus a power
        law between calibrated counts [e- s^-1 m^-2 sr^-1]."""
        y = self.le if le is None else np.asarray(le, float)
        n = np.asarray(counts, float)
        x = self.counts.astype(float)
        s = np.clip(y - y[0], 1e-300, None)
        lx = np.log(np.clip(x[1:], 1e-300, None))
        ls = np.log(s[1:])
        with np.errstate(divide="ignore"):
            ln = np.log(np.clip(n, 1e-300, None))
        # below the first non-zero count: the first segment's power law
        out = np.exp(np.interp(ln, lx, ls, left=np.nan))
        slope = (ls[1] - ls[0]) / (lx[1] - lx[0])
        out = np.where(ln < lx[0], np.exp(ls[0] + slope * (ln - lx[0])), out)
        return y[0] + np.where(n > 0, out, 0.0)

    def lut_sigma(self, count: float, term: str) -> float:
        """1-sigma of ``lut(count) - lut(0)`` from one covariance term [e- s^-1 m^-2 sr^-1]."""
        J = self.lut_jacobian(count)
        return math.sqrt(max(float(J @ self.covariance[term] @ J), 0.0))

    def lut_jacobian(self, count: ArrayLike) -> FloatArray:
        """``d (lut(count) - lut(0)) / d le`` over the calibrated counts: ``(..., n)`` for
        counts of shape ``(...)`` [-]."""
        count = np.asarray(count, float)
        J = np.zeros(count.shape + (len(self.le),))
        for i in range(len(self.le)):
            h = max(1e-6 * abs(self.le[i]), 1e-300)
            up = self.le.copy()
            up[i] += h
            dn = self.le.copy()
            dn[i] -= h
            J[..., i] = ((self.lut(count, up) - self.lut(0, up)) - (self.lut(count, dn)
                                                                      - self.lut(0, dn))) / (
                2 * h)
        return J

    def interpolation_sigma(self, count: float) -> float:
        """Estimated error of the power-law interpolation at ``count``: the difference from a
        quadratic in log-log through the three nearest calibrated counts [-] (relative)."""
        x = self.counts[1:].astype(float)
        if count <= 0 or np.any(np.isclose(count, self.counts)) or len(x) < 3:
            return 0.0
        s = self.le[1:] - self.le[0]
        i = int(np.clip(np.searchsorted(x, count) - 1, 0, len(x) - 3))
        lx, ls = np.log(x[i:i + 3]), np.log(np.clip(s[i:i + 3], 1e-300, None))
        quad = np.polyval(np.polyfit(lx, ls, 2), math.log(count))
        lin = math.log(max(float(self.lut(count) - self.le[0]), 1e-300))
        return abs(quad - lin)

    def continuous_count(self, le: float) -> float:
        """Non-integer grey count whose LUT radiance is ``le`` (on axis) [-]."""
        grid = np.linspace(0.0, float(self.counts[-1]), 20001)
        return float(np.interp(le, self.lut(grid), grid))

    # ................................................................ the field
    def field_factor(self, uv: ArrayLike, order: int = 3) -> FloatArray:
        """Field factor at pinhole pixels ``(..., 2)`` (bicubic over the grid, or bilinear
        with ``order`` 1) [-]."""
        uv = np.asarray(uv, float)
        k = min(order, len(self.field_u) - 1, len(self.field_v) - 1)
        sp = RectBivariateSpline(self.field_v, self.field_u, self.field, kx=k, ky=k)
        return sp.ev(uv[..., 1], uv[..., 0])

    def field_factor_sigma(self, uv: ArrayLike) -> FloatArray:
        """1-sigma of the field factor at ``uv`` (of the nearest grid point) [-]."""
        uv = np.asarray(uv, float)
        j = np.abs(self.field_u - uv[..., 0][..., None]).argmin(-1)
        i = np.abs(self.field_v - uv[..., 1][..., None]).argmin(-1)
        return self.field_sigma[i, j]

    # ................................................................ file
    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION,
                "counts": [int(c) for c in self.counts],
                "le_e_s_m2_sr": [float(v) for v in self.le],
                "covariance": {k: [[float(x) for x in row] for row in v]
                               for k, v in self.covariance.items()},
                "field_u_px": [float(v) for v in self.field_u],
                "field_v_px": [float(v) for v in self.field_v],
                "field": [[float(x) for x in row] for row in self.field],
                "field_sigma": [[float(x) for x in row] for row in self.field_sigma],
                "monitor_le_e_s_m2_sr": self.monitor_le, "monitor_sigma": self.monitor_sigma,
                "session_end_s": self.session_end_s, "drift_per_s": self.drift_per_s,
                "options": dict(self.options), "provenance": self.provenance,
                "albedo_exposure": self.albedo_exposure}

    @classmethod
    def from_dict(cls, d: Any, source: str = "radiometric") -> RadiometricCalibration:
        """Read the section written by :meth:`to_dict`; a malformed one raises an error naming
        the entry."""
        if not isinstance(d, dict):
            raise ConfigError(source, type(d).__name__, "a radiometric calibration mapping")
        if d.get("format") != FORMAT:
            raise ConfigError(f"{source}: format", d.get("format"), repr(FORMAT))
        if d.get("version") != VERSION:
            raise ConfigError(f"{source}: version", d.get("version"), f"{VERSION}")
        try:
            counts = np.asarray(d["counts"], int)
            le = np.asarray(d["le_e_s_m2_sr"], float)
            cov = {str(k): np.asarray(v, float) for k, v in d["covariance"].items()}
            fu = np.asarray(d["field_u_px"], float)
            fv = np.asarray(d["field_v_px"], float)
            f = np.asarray(d["field"], float)
            fs = np.asarray(d["field_sigma"], float)
            out = cls(counts, le, cov, fu, fv, f, fs, float(d["monitor_le_e_s_m2_sr"]),
                      float(d["monitor_sigma"]), float(d["session_end_s"]),
                      float(d["drift_per_s"]), {str(k): bool(v) for k, v in
                                                d["options"].items()},
                      dict(d.get("provenance") or {}), d.get("albedo_exposure"))
        except KeyError as err:
            raise ConfigError(f"{source}: {err.args[0]}", "missing", "an entry of the "
                              "radiometric calibration") from None
        except (TypeError, ValueError) as err:
            raise ConfigError(source, "malformed", f"numbers of the documented shapes ({err})"
                              ) from None
        n = len(counts)
        if le.shape != (n,) or any(v.shape != (n, n) for v in cov.values()) or \
                f.shape != (len(fv), len(fu)) or fs.shape != f.shape:
            raise ConfigError(f"{source}: shapes", f"{n} counts, field {f.shape}",
                              "le (n,), covariance terms (n, n), field (ny, nx) like its sigma")
        return out


# =========================================================================== session
def _grid(n: int, size: int, margin: float, between: bool = False) -> FloatArray:
    pts = np.linspace(margin, size - 1 - margin, n)
    if between:
        pts = 0.5 * (pts[:-1] + pts[1:])
    return pts


def calibrate_radiometry(bench: Bench, truth: TruthScreen | None = None,
                         instrument: ReferenceInstrument | None = None
                         ) -> RadiometricCalibration:
    """The lab session against the reference instrument (module essay, steps 1-2).

    Raises
    ------
    ConfigError
        ``lut_counts`` do not end at the screen's full count.
    """
    cfg = bench.config
    lab = cfg.radiometric_lab
    n_max = cfg.screen.max_count
    lut_counts, _ = lab.counts_for(n_max)
    truth = truth if truth is not None else TruthScreen(bench)
    inst = instrument if instrument is not None else ReferenceInstrument(bench, truth)
    cam = bench.camera
    centre = np.array([cam.cx, cam.cy])
    n_read = lab.readings_per_point
    thru = lab.through_collimator
    clock = [cfg.radiometric_truth.power_on_min * 60.0]

    def point(count: int, uv: FloatArray) -> tuple[float, float, int, float]:
        rs = []
        for _ in range(n_read):
            rs.append(inst.read(count, uv, clock[0], thru))
            clock[0] += lab.reading_time_s
        le = float(np.mean([r.le for r in rs]))
        return le, float(np.mean([r.time_s for r in rs])), rs[0].level_class, rs[0].luminance

    m0, t0, cls_w, lum_w = point(n_max, centre)
    lut_raw = [point(int(c), centre) if lab.measure_lut or c in (0, n_max) else None
               for c in lut_counts]
    fu = _grid(lab.flat_grid[0], cam.width, lab.flat_margin_px)
    fv = _grid(lab.flat_grid[1], cam.height, lab.flat_margin_px)
    flat_raw = ([[point(n_max, np.array([u, v])) for u in fu] for v in fv]
                if lab.model_field else None)
    m1, t1, _, _ = point(n_max, centre)
    rate = (m1 / m0 - 1.0) / (t1 - t0)
    session_end = clock[0]

    # a bare-screen reading is carried to the camera with the datasheet transmission
    carry = 1.0 if thru else cfg.collimator.transmission * 10.0 ** (
        -cfg.collimator.nd_optical_density)

    def corrected(le: float, t: float) -> float:
        return carry * (le * (1.0 + rate * (t1 - t)) if lab.monitor else le)

    rep_w = inst.relative_sigma(lum_w, n_read)[1]
    counts = np.asarray(lut_counts, int)
    if lab.measure_lut:
        le = np.array([corrected(r[0], r[1]) for r in lut_raw])
        lums = [r[3] for r in lut_raw]
    else:
        # the datasheet's gamma scaled by the measured black and full white
        lo = corrected(lut_raw[0][0], lut_raw[0][1])
        hi = corrected(lut_raw[-1][0], lut_raw[-1][1])
        em = cfg.screen.emittance
        assert em is not None
        nominal = bench.radiometry.channel_le[:, -1]
        w = nominal / nominal.sum()
        g = (counts[:, None] / n_max) ** np.asarray(em.gamma)[None, :] @ w
        le = lo + (hi - lo) * g
        lums = [lut_raw[0][3] + (lut_raw[-1][3] - lut_raw[0][3]) * x for x in g]
    raw_cls = [inst.level_class(x) if x > 0 else -1 for x in lums]
    # a count the instrument cannot see is not a LUT point (count 0 stays: its floor is known)
    keep = [i for i, c in enumerate(raw_cls) if c >= 0 or counts[i] == 0]
    if len(keep) < 3:
        raise ConfigError("radiometric_lab.lut_counts", counts.tolist(),
                          ">= 3 counts within the reference instrument's range (lower bound "
                          f"{inst.config.level_bounds_cd_m2[0]:g} cd/m^2)")
    counts, le = counts[keep], le[keep]
    raw_cls = [raw_cls[i] for i in keep]
    # covariance by term
    n = len(counts)
    cls = np.array([max(c, 0) for c in raw_cls])
    acc = np.asarray(inst.config.accuracy_2sigma) / 2.0
    rep = np.asarray(inst.config.repeatability_2sigma) / 2.0
    absolute = np.outer(le, le) * acc[np.maximum.outer(cls, cls)] ** 2
    repeat = np.diag((le * rep[cls]) ** 2 / n_read + (le * rep_w) ** 2 * lab.monitor
                     + (np.array([x < 0 for x in raw_cls]) * carry * inst.floor_le()) ** 2)
    # spectral consider parameters through the nominal channel mix
    em = cfg.screen.emittance
    assert em is not None
    mix = (counts[:, None] / n_max) ** np.asarray(em.gamma)[None, :]
    k0 = inst.channel_factors()
    spectral = np.zeros((n, n))
    for kw, sig in (({"shift_nm": 0.5}, inst.config.wavelength_2sigma_nm / 2.0 / 0.5),
                    ({"tilt": 0.01}, inst.config.spectral_tilt_2sigma / 2.0 / 0.01)):
        dk = inst.channel_factors(**kw) - k0
        rel = (mix @ dk) / np.clip(mix @ k0, 1e-300, None)
        j = le * rel * sig
        spectral += np.outer(j, j)
    if not lab.measure_lut:
        absolute = np.outer(le, le) * acc[cls_w] ** 2
        repeat = np.diag((le * rep_w) ** 2)
    cov = {"absolute": absolute, "repeatability": repeat, "spectral": spectral}
    if flat_raw is not None:
        m_ax = corrected(m1, t1)
        fld = np.array([[corrected(r[0], r[1]) / m_ax for r in row] for row in flat_raw])
        fsig = np.full(fld.shape, math.sqrt(2.0) * rep_w)
    else:
        fld = np.ones((len(fv), len(fu)))
        fsig = np.zeros_like(fld)
    return RadiometricCalibration(
        counts, le, cov, fu, fv, fld, fsig, float(m1), float(rep_w), float(session_end),
        float(rate), {"model_field": lab.model_field, "through_collimator": thru,
                      "measure_lut": lab.measure_lut, "monitor": lab.monitor},
        {"method": "reference spectroradiometer through the collimator" if thru else
         "reference spectroradiometer at the bare screen, datasheet transmission",
         "bench_seed": int(cfg.seed), "truth_seed": int(cfg.radiometric_truth.truth_seed),
         "instrument": inst.config.model_dump(mode="json")})


# =========================================================================== validation
@dataclass(frozen=True)
class ValidationPoint:
    """One hold-out acquisition: count, exposure, field point, error and its budget."""

    count: int
    exposure_s: float
    uv: tuple[float, float]
    measured_dn: float
    predicted_dn: float
    budget: dict[str, float]

    @property
    def error(self) -> float:
        """``measured / predicted - 1`` [-]."""
        return self.measured_dn / self.predicted_dn - 1.0

    @property
    def sigma(self) -> float:
        """Combined relative 1-sigma of the prediction [-]."""
        return math.sqrt(sum(v * v for v in self.budget.values()))


@dataclass(frozen=True)
class RadiometricValidation:
    """The hold-out validation (module essay, step 3)."""

    points: tuple[ValidationPoint, ...]
    tolerance: float
    coverage_k: float

    @property
    def z(self) -> FloatArray:
        return np.array([p.error / p.sigma for p in self.points])

    @property
    def z_crit(self) -> float:
        """Bonferroni bound on ``|z|`` at :data:`FAMILY_ALPHA` over the points [-]."""
        return float(stats.norm.isf(FAMILY_ALPHA / (2 * len(self.points))))

    @property
    def consistent(self) -> bool:
        return bool(np.max(np.abs(self.z)) <= self.z_crit)

    @property
    def meets_use(self) -> bool:
        return self.consistent and all(self.coverage_k * p.sigma <= self.tolerance
                                       for p in self.points)

    def budget_rms(self) -> dict[str, float]:
        """RMS over the points of each budget term [-]."""
        return {k: float(np.sqrt(np.mean([p.budget[k] ** 2 for p in self.points])))
                for k in TERMS}

    def summary(self) -> dict[str, Any]:
        e = np.array([p.error for p in self.points])
        s = np.array([p.sigma for p in self.points])
        by_count: dict[str, Any] = {}
        for c in sorted({p.count for p in self.points}):
            sel = [p for p in self.points if p.count == c]
            ee = np.array([p.error for p in sel])
            by_count[str(c)] = {"exposure_s": sel[0].exposure_s,
                                "mean_error": float(ee.mean()),
                                "max_abs_error": float(np.abs(ee).max()),
                                "sigma_mean": float(np.mean([p.sigma for p in sel]))}
        return {"points": len(self.points), "rms_error": float(np.sqrt(np.mean(e**2))),
                "max_abs_error": float(np.abs(e).max()), "mean_error": float(e.mean()),
                "sigma_rms": float(np.sqrt(np.mean(s**2))),
                "max_abs_z": float(np.abs(self.z).max()), "z_crit": self.z_crit,
                "family_false_alarm": FAMILY_ALPHA, "consistent": self.consistent,
                "tolerance": self.tolerance, "coverage_k": self.coverage_k,
                "meets_paper_use": self.meets_use, "budget_rms": self.budget_rms(),
                "by_count": by_count}


def _exposure_for(lab_exposures: tuple[float, ...], le: float, etendue: float,
                  full_well: float) -> float:
    ts = sorted(t * 1e-3 for t in lab_exposures)
    ok = [t for t in ts if le * t * etendue <= FILL_FRACTION * full_well]
    return ok[-1] if ok else ts[0]


def aperture_sigma(bench: Bench, instrument: ReferenceInstrument) -> float:
    """Relative 1-sigma between what the camera's pupil and the reference's aperture receive
    from a panel of unmeasured angular emission [-].

    A panel radiating as cos^p, averaged over a disc of radius R at the collimator's focal
    distance f, falls by p R^2 / (4 f^2); p is known to ``emission_exponent_sigma``."""
    f_coll = bench.geometry.focal_length
    r_cam = bench.camera.pupil_diameter / 2.0
    r_ref = instrument.config.aperture_mm * 1e-3 / 2.0
    return (bench.config.radiometric_lab.emission_exponent_sigma * abs(r_cam**2 - r_ref**2)
            / (4 * f_coll**2))


def nonlinearity_beta(detector: DetectorStage | None) -> float:
    """``beta`` of the tracker's charge-to-voltage response ``S / (1 + beta S / FWC)`` (0 for
    a detector without that stage) [-]."""
    dcfg = getattr(detector, "config", None)
    if dcfg is None or not dcfg.signal.nonlinearity.enabled:
        return 0.0
    dfc = dcfg.signal.nonlinearity.full_well_deficit_fraction
    return dfc / (1.0 - dfc)


def validate_radiometry(bench: Bench, cal: RadiometricCalibration,
                        truth: TruthScreen | None = None,
                        instrument: ReferenceInstrument | None = None,
                        detector: DetectorStage | None = None,
                        frame_base: int = 900) -> RadiometricValidation:
    """Hold-out validation of ``cal`` on the truth bench (module essay, step 3).

    Parameters
    ----------
    detector : DetectorStage, optional
        The tracker: full frames of the truth image through it (e.g.
        :meth:`Bench.chain_detector`); default ``None`` evaluates the patches in closed form
        (mean charge of the truth at each patch, its pixel scatter; no detector noise).

    Raises
    ------
    ConfigError
        A validation count above the screen's full count or among the calibration's.
    """
    cfg = bench.config
    lab = cfg.radiometric_lab
    n_max = cfg.screen.max_count
    _, validation_counts = lab.counts_for(n_max)
    truth = truth if truth is not None else TruthScreen(bench)
    inst = instrument if instrument is not None else ReferenceInstrument(bench, truth)
    cam = bench.camera
    t_val = cal.session_end_s + lab.validation_delay_min * 60.0
    centre = np.array([cam.cx, cam.cy])
    if cal.options.get("monitor", True):
        rs = [inst.read(n_max, centre, t_val, cal.options.get("through_collimator", True))
              for _ in range(lab.readings_per_point)]
        scale = float(np.mean([r.le for r in rs])) / cal.monitor_le
        drift_sigma = math.sqrt(2.0) * cal.monitor_sigma
    else:
        scale = 1.0
        drift_sigma = abs(cal.drift_per_s) * (t_val - cal.session_end_s)
    a_sigma = aperture_sigma(bench, inst)
    gu = _grid(lab.validation_grid[0] + 1, cam.width, lab.flat_margin_px, between=True)
    gv = _grid(lab.validation_grid[1] + 1, cam.height, lab.flat_margin_px, between=True)
    uvs = np.array([(u, v) for v in gv for u in gu])
    h = lab.patch_half_px
    offs = np.arange(-h, h + 1)
    npx = len(offs) ** 2
    gain = detector.gain_e_per_dn if detector is not None else 1.0
    full_well = detector.full_well_e if detector is not None else 1e5
    scatter = truth.pixel_scatter((len(uvs),), average_px=npx)
    # the tracker's charge-to-voltage non-linearity S / (1 + beta S / FWC): on the bench the
    # stimulus rides on the black level's pedestal, in orbit it does not
    beta = nonlinearity_beta(detector)
    dark_frames: dict[float, Any] = {}
    points = []
    for ic, count in enumerate(validation_counts):
        le_ax = float(cal.lut(count) - cal.lut(0)) * scale
        t_exp = _exposure_for(lab.validation_exposures_ms, float(cal.lut(count)) * scale,
                              cam.etendue, full_well)
        if detector is not None:
            img = truth.camera_image(count, t_val)
            sig = detector.expose(img, t_exp, frame_base + 2 * ic).dn
            if t_exp not in dark_frames:
                dark_frames[t_exp] = detector.expose(truth.camera_image(0, t_val), t_exp,
                                                     frame_base + 1 + 2 * ic).dn
            diff = sig - dark_frames[t_exp]
        base = float(cal.lut(count) - cal.lut(0))
        lut_terms = {"reference absolute": cal.lut_sigma(count, "absolute") / base,
                     "reference repeatability": cal.lut_sigma(count, "repeatability") / base,
                     "reference spectral": cal.lut_sigma(count, "spectral") / base,
                     "LUT interpolation": cal.interpolation_sigma(count),
                     "reference aperture": a_sigma}
        if detector is None:
            le_t = (truth.electron_radiance(count, uvs, t_val)
                    - truth.electron_radiance(0, uvs, t_val))
        f_all = cal.field_factor(uvs)
        f_lin = cal.field_factor(uvs, 1)
        f_sig = cal.field_factor_sigma(uvs)
        for k, (u, v) in enumerate(uvs):
            iu, iv = int(round(u)), int(round(v))
            rr = np.clip(iv + offs, 0, cam.height - 1)
            cc = np.clip(iu + offs, 0, cam.width - 1)
            uu, vv = np.meshgrid(cc.astype(float), rr.astype(float))
            ri = float(cam.relative_illumination(uu, vv).mean())
            if detector is not None:
                patch = diff[np.ix_(rr, cc)]
                measured = float(patch.mean())
                patch_sigma = float(patch.std(ddof=1) / math.sqrt(npx)) / max(abs(measured),
                                                                            1e-300)
            else:
                measured = float(le_t[k]) * (1.0 + scatter[k]) * t_exp * cam.etendue * ri
                # what the patch's own pixel-to-pixel spread would show
                patch_sigma = truth.pixel_rms * min(
                    1.0, bench.geometry.screen_pixel_scale()) / math.sqrt(npx)
            f = float(f_all[k])
            predicted = le_ax * f * t_exp * cam.etendue * ri / gain
            budget = dict(lut_terms)
            budget.update({
                "field factor": float(f_sig[k]) / max(f, 1e-300),
                "field interpolation": abs(f - float(f_lin[k])) / f
                if cal.options.get("model_field", True) else 0.0,
                "monitor / drift": drift_sigma,
                "tracker patch": patch_sigma,
                "tracker linearity": beta * float(cal.lut(count) + cal.lut(0)) * scale * f
                * t_exp * cam.etendue * ri / full_well,
            })
            points.append(ValidationPoint(int(count), float(t_exp), (float(u), float(v)),
                                          measured, predicted, budget))
    return RadiometricValidation(tuple(points), lab.tolerance, lab.coverage_k)


# =========================================================================== plausibility
def plausibility(bench: Bench, cal: RadiometricCalibration,
                 truth: TruthScreen | None = None) -> dict[str, Any]:
    """The paper's plausibility numbers on the calibrated bench: how much too dim the screen is
    for the Moon at albedo 0.12, and the count of the k = 200 ms / 0.015 ms stimulus peak --
    with their 1-sigma from the calibration, the truth's values and the datasheet's.

    The count is the one whose radiance *above count 0* is the Moon's peak / k (the bench's
    dark frame, a black screen, is subtracted from every acquisition).

    The Moon's peak electron radiance is the closed form ``rho E_e / pi`` (Lambert surface lit
    head-on, the Sun at 1 AU through the camera response)."""
    cfg = bench.config
    truth = truth if truth is not None else TruthScreen(bench)
    sun = solar_spectrum_from_config(cfg.scenario.sun)
    peak = PAPER_ALBEDO * band_integrals(sun, bench.response).electron_irradiance / math.pi
    cam = bench.camera
    centre = (cam.cx, cam.cy)
    t_end = cal.session_end_s
    white = float(cal.le[-1])
    white_sig = math.sqrt(float(cal.total_covariance[-1, -1]))
    k = bench_min_exposure(bench) / (cfg.scaling.render_exposure_ms * 1e-3)
    target = peak / k
    # the stimulus is dark-subtracted: the count whose radiance above count 0 is the target
    n_cal = cal.continuous_count(target + float(cal.le[0]))
    # sigma of the count: the LUT's relative sigma there over the log-slope of the LUT
    n_lo = max(int(math.floor(n_cal)), 1)
    dle = float(cal.lut(n_lo + 1) - cal.lut(n_lo))
    rel = math.sqrt(sum(cal.lut_sigma(n_cal, t) ** 2 for t in cal.covariance)) / max(
        float(cal.lut(n_cal) - cal.lut(0)), 1e-300)
    n_sig = rel * float(cal.lut(n_cal) - cal.lut(0)) / max(dle, 1e-300)
    grid = np.arange(cfg.screen.max_count + 1)
    true_lut = truth.electron_radiance(grid, np.broadcast_to(centre, (len(grid), 2)), t_end)
    nominal = bench.radiometry
    return {
        "moon_peak_le_e_s_m2_sr": peak, "albedo": PAPER_ALBEDO, "k": k,
        "screen_too_dim": {"calibrated": peak / white, "sigma": peak / white * white_sig / white,
                           "truth": peak / float(true_lut[-1]),
                           "datasheet": peak / nominal.le_max},
        "k_peak_count": {"calibrated": n_cal, "sigma": n_sig,
                         "truth": float(np.interp(target, true_lut - true_lut[0], grid)),
                         "black_plus_ambient_over_target": float(true_lut[0]) / target,
                         "datasheet": float(nominal.continuous_count(target))},
    }


@dataclass(frozen=True)
class RadiometricLabResult:
    """What :func:`radiometric_lab` returns."""

    calibration: RadiometricCalibration
    validation: RadiometricValidation
    plausibility: dict[str, Any]
    truth: TruthScreen
    instrument: ReferenceInstrument

    def summary(self) -> dict[str, Any]:
        return {"validation": self.validation.summary(), "plausibility": self.plausibility,
                "truth": self.truth.summary(), "instrument": self.instrument.summary(),
                "calibration": {"counts": self.calibration.counts.tolist(),
                                "le_e_s_m2_sr": self.calibration.le.tolist(),
                                "le_sigma_rel": (np.sqrt(np.diag(
                                    self.calibration.total_covariance))
                                    / self.calibration.le).tolist(),
                                "field_min": float(self.calibration.field.min()),
                                "field_max": float(self.calibration.field.max())}}


def radiometric_lab(bench: Bench, detector: DetectorStage | None = None) -> RadiometricLabResult:
    """Calibrate against the reference, validate on hold-outs, and the plausibility numbers."""
    truth = TruthScreen(bench)
    inst = ReferenceInstrument(bench, truth)
    cal = calibrate_radiometry(bench, truth, inst)
    val = validate_radiometry(bench, cal, truth, inst, detector)
    pl = plausibility(bench, cal, truth)
    cal = replace(cal, albedo_exposure={
        "k": pl["k"], "albedo": pl["albedo"],
        "moon_peak_le_e_s_m2_sr": pl["moon_peak_le_e_s_m2_sr"],
        "peak_count": pl["k_peak_count"]["calibrated"],
        "peak_count_sigma": pl["k_peak_count"]["sigma"],
        "screen_too_dim": pl["screen_too_dim"]["calibrated"],
        "screen_too_dim_sigma": pl["screen_too_dim"]["sigma"]})
    return RadiometricLabResult(cal, val, pl, truth, inst)


__all__ = ["RadiometricCalibration", "RadiometricLabResult", "RadiometricValidation",
           "ValidationPoint", "aperture_sigma", "calibrate_radiometry", "nonlinearity_beta",
           "plausibility", "radiometric_lab", "validate_radiometry"]
