"""The PSF as the navigation side knows it: estimated from star images, with its covariance.

The subpixel limb refinement's ``detector-psf`` edge model blurs a step and a ramp with the
tracker's line spread function (:class:`starnav.navigation.refine.EdgeSpread`). A flight
tracker does not know its PSF from a setting: it measures it on stars, which are point sources.
:func:`estimate_psf` fits the field law of :class:`~starnav.detector.schema.AberrationPsfConfig`
(a defocus disc convolved with an elliptical Gaussian whose widths grow with the square of the
normalised field radius) to the stamps of isolated, unsaturated stars in DN frames:

1. stars are found and centroided by :func:`starnav.stars.centroid.find_stars`;
2. for a trial PSF every star's pixel-integrated image is drawn at its centroid by the same
   point-source integration the detector uses (:func:`starnav.detector.optics.point_source_image`)
   and coupled to its neighbours by the detector's inter-pixel capacitance (which the edge
   model applies on its own), and each stamp's flux and background are solved linearly
   (variable projection);
3. the five widths are found by weighted non-linear least squares (Poisson + read noise per
   pixel); their covariance is ``(J^T J)^-1`` scaled by the reduced chi-square when it exceeds
   one (what the field law does not capture widens the covariance instead of hiding in it).

The frames the estimate is made on are not the frames it is used on: :func:`star_calibration_frames`
exposes a seeded field of synthetic stars through the scenario's full detector chain (noise,
distortion resampling, inter-pixel capacitance, pixel response: everything the truth has and the
field law does not). :func:`estimated_psf` returns the estimate for a detector (the packaged one,
:data:`PSF_ESTIMATE_FILE`, when the detector and camera are the ones it was made for, else an
estimate made on the fly and cached).

Index
-----
:class:`PsfEstimate`, :func:`estimate_psf`, :func:`star_calibration_frames`,
:func:`estimated_psf`, :data:`PSF_PARAMETERS`.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from starnav.camera import Camera
from starnav.data import packaged_path
from starnav.detector import DetectorConfig, PointSources, expose
from starnav.detector.crosstalk import interpixel_capacitance
from starnav.detector.optics import point_source_image
from starnav.detector.schema import AberrationPsfConfig
from starnav.errors import ConfigError, DataFileError
from starnav.stars.centroid import find_stars, saturation_dn

#: The fitted widths of the field law, in this order [px].
PSF_PARAMETERS = ("defocus_radius_px", "defocus_radius_edge_px", "sigma_px",
                  "sigma_radial_edge_px", "sigma_tangential_edge_px")
#: Packaged estimate for the default tracker (written by ``tools/estimate_psf.py``).
PSF_ESTIMATE_FILE = "navigation/psf_estimate.json"
#: Where the fit starts: a round blur of 1 px everywhere in the field (nothing of the design).
GENERIC_START = AberrationPsfConfig(enabled=True, **{k: 1.0 for k in PSF_PARAMETERS})
#: Half-size of a star's stamp [px].
STAMP_HALF = 4


@dataclass(frozen=True)
class PsfEstimate:
    """A PSF estimated from star images.

    Attributes
    ----------
    aberration : AberrationPsfConfig
        The estimated field law (the widths of :data:`PSF_PARAMETERS`; grid and oversampling of
        the detector it was made for).
    covariance : 5 x 5 tuple of float
        Covariance of the widths [px^2].
    n_stars : int
        Stamps used.
    reduced_chi2 : float
        Weighted residual sum of squares per degree of freedom [-].
    fingerprint : str
        Which detector and camera it was made for (:func:`psf_fingerprint`).
    """

    aberration: AberrationPsfConfig
    covariance: tuple[tuple[float, ...], ...]
    n_stars: int
    reduced_chi2: float
    fingerprint: str = ""

    @property
    def sigma(self) -> dict[str, float]:
        """1-sigma of each width [px]."""
        return {k: math.sqrt(max(self.covariance[i][i], 0.0))
                for i, k in enumerate(PSF_PARAMETERS)}

    def to_dict(self) -> dict:
        return {"parameters": {k: getattr(self.aberration, k) for k in PSF_PARAMETERS},
                "grid_nodes": list(self.aberration.grid_nodes),
                "oversample": self.aberration.oversample,
                "covariance_px2": [list(r) for r in self.covariance],
                "n_stars": self.n_stars, "reduced_chi2": self.reduced_chi2,
                "fingerprint": self.fingerprint}

    @classmethod
    def from_dict(cls, doc: dict) -> PsfEstimate:
        ab = AberrationPsfConfig(enabled=True, grid_nodes=tuple(doc["grid_nodes"]),
                                 oversample=int(doc["oversample"]),
                                 **{k: float(doc["parameters"][k]) for k in PSF_PARAMETERS})
        return cls(ab, tuple(tuple(float(x) for x in r) for r in doc["covariance_px2"]),
                   int(doc["n_stars"]), float(doc["reduced_chi2"]), str(doc["fingerprint"]))


def psf_fingerprint(detector: DetectorConfig, camera: Camera) -> str:
    """What a star image's shape depends on: the detector's aberration, distortion and
    inter-pixel capacitance and the camera's geometry (a short SHA-256)."""
    d = detector.model_dump(mode="json")
    doc = {"aberration": d["optics"]["aberration"], "distortion": d["optics"]["distortion"],
           "ipc": d["signal"]["ipc"], "camera": [
        camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
        camera.k1, camera.k2, camera.k3, camera.p1, camera.p2]}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def star_calibration_frames(detector: DetectorConfig, camera: Camera, *, n_frames: int = 2,
                            n_stars: int = 80, seed: int = 9100) -> list[tuple[np.ndarray, float]]:
    """``n_frames`` DN frames of ``n_stars`` synthetic stars each, exposed through the full
    detector chain of ``detector`` (its PSF, distortion, noise and pixel response); stars at
    least 16 px apart and from the border, peak signal between ~5 % and ~60 % of full well.

    Returns ``[(dn, gain_e_per_dn), ...]``."""
    rng = np.random.default_rng(seed)
    full = float(detector.saturation.full_well_e)
    exposure = 0.25  # a full frame: the readout law allows it
    out = []
    for k in range(n_frames):
        uv = _separated_positions(rng, camera.width, camera.height, n_stars, 16.0)
        # a defocused star's brightest pixel holds roughly a tenth to a fifth of it
        electrons = full * np.exp(rng.uniform(np.log(0.25), np.log(3.0), len(uv)))
        src = PointSources(uv[:, 0], uv[:, 1], electrons / exposure)
        exp = expose(np.zeros((camera.height, camera.width), np.float32), camera, detector,
                     seed=seed + k, exposure_time=exposure, point_sources=src)
        out.append((np.asarray(exp.dn), float(exp.gain)))
    return out


def _separated_positions(rng: np.random.Generator, w: int, h: int, n: int,
                         sep: float) -> np.ndarray:
    pts: list[tuple[float, float]] = []
    for _ in range(50 * n):
        p = (rng.uniform(sep, w - 1 - sep), rng.uniform(sep, h - 1 - sep))
        if all((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 >= sep * sep for q in pts):
            pts.append(p)
            if len(pts) == n:
                break
    return np.array(pts, float)


def estimate_psf(frames: list[tuple[ArrayLike, float]], camera: Camera,
                 detector: DetectorConfig, *, start: AberrationPsfConfig | None = None,
                 min_stars: int = 10) -> PsfEstimate:
    """Fit the PSF's field law to the stars of DN ``frames`` (module steps 1-3).

    Parameters
    ----------
    frames : list of (dn, gain_e_per_dn)
        DN frames of the camera with stars and their conversion gain [e-/DN].
    camera : Camera
        The camera's geometry (the field law's centre and corner).
    detector : DetectorConfig
        Offset, read noise, saturation; its aberration section gives only the grid and the
        oversampling of the model (never its widths).
    start : AberrationPsfConfig, optional
        Starting widths; default :data:`GENERIC_START`.
    min_stars : int
        Fewer usable stars than this raises :class:`~starnav.errors.ConfigError`.
    """
    start = start or GENERIC_START.model_copy(update={
        "grid_nodes": detector.optics.aberration.grid_nodes,
        "oversample": detector.optics.aberration.oversample})
    sat = saturation_dn(detector)
    offset = float(detector.adc.offset_dn)
    rn = detector.signal.read_noise
    read_e = float(rn.sigma_e) if rn.enabled else 0.0
    h = STAMP_HALF
    stamps, weights, pos = [], [], []
    for frame, (dn, gain) in enumerate(frames):
        a = np.asarray(dn, float)
        c = find_stars(a, gain_e_per_dn=gain, saturation_dn=sat)
        for (u, v), pk in zip(c.uv, c.peak_dn, strict=True):
            iu, iv = int(round(u)), int(round(v))
            if not (h <= iu < a.shape[1] - h and h <= iv < a.shape[0] - h) or pk >= sat:
                continue
            s = (a[iv - h:iv + h + 1, iu - h:iu + h + 1] - offset) * gain
            var = np.maximum(s, 0.0) + read_e ** 2 + gain ** 2 / 12.0
            stamps.append(s)
            weights.append(1.0 / np.sqrt(var))
            pos.append((u, v, iu, iv, frame))
    if len(stamps) < min_stars:
        raise ConfigError("psf estimate", len(stamps),
                          f"at least {min_stars} isolated unsaturated stars")
    S, Wt = np.array(stamps), np.array(weights)
    P = np.array(pos)
    n = len(S)
    x0 = np.array([getattr(start, k) for k in PSF_PARAMETERS], float)
    H, W = camera.height, camera.width
    rows = np.arange(-h, h + 1)
    ipc = detector.signal.ipc

    def model_stamps(theta: np.ndarray) -> np.ndarray:
        ab = start.model_copy(update=dict(zip(PSF_PARAMETERS, map(float, theta),
                                              strict=True)) | {"enabled": True})
        ks = np.empty((n, 2 * h + 1, 2 * h + 1))
        # the stars of one frame are far apart: one canvas per frame, as the detector draws
        for f in np.unique(P[:, 4]).astype(int):
            sel = np.flatnonzero(P[:, 4] == f)
            img, _ = point_source_image((H, W), PointSources(P[sel, 0], P[sel, 1],
                                                             np.ones(sel.size)),
                                        1.0, camera, ab)
            if ipc.enabled:  # the coupling the edge model adds on its own (EdgeSpread.ipc)
                img = interpixel_capacitance(img, ipc.nearest_fraction, ipc.diagonal_fraction)
            ks[sel] = img[(P[sel, 3].astype(int)[:, None, None] + rows[None, :, None]),
                          (P[sel, 2].astype(int)[:, None, None] + rows[None, None, :])]
        return ks

    def residuals(theta: np.ndarray) -> np.ndarray:
        K = model_stamps(theta)
        r = np.empty_like(S)
        for i in range(n):
            A = np.stack([K[i].ravel(), np.ones(K[i].size)], axis=1) * Wt[i].ravel()[:, None]
            b = S[i].ravel() * Wt[i].ravel()
            coef, *_ = np.linalg.lstsq(A, b, rcond=None)
            r[i] = (b - A @ coef).reshape(K[i].shape)
        return r.ravel()

    fit = least_squares(residuals, x0, bounds=(np.full(5, 0.05), np.full(5, 6.0)),
                        diff_step=1e-3, x_scale=0.3)
    dof = max(fit.fun.size - 5 - 2 * n, 1)
    chi2 = float(fit.fun @ fit.fun) / dof
    J = fit.jac
    cov = np.linalg.pinv(J.T @ J) * max(chi2, 1.0)
    ab = start.model_copy(update=dict(zip(PSF_PARAMETERS, map(float, fit.x), strict=True))
                          | {"enabled": True})
    return PsfEstimate(ab, tuple(tuple(float(x) for x in r) for r in cov), n, chi2,
                       psf_fingerprint(detector, camera))


@functools.lru_cache(maxsize=8)
def _packaged() -> PsfEstimate | None:
    try:
        path = packaged_path(PSF_ESTIMATE_FILE)
    except DataFileError:
        return None
    return PsfEstimate.from_dict(json.loads(path.read_text()))


_MADE: dict[str, PsfEstimate] = {}


def estimated_psf(detector: DetectorConfig, camera: Camera) -> PsfEstimate:
    """The navigation side's PSF for ``detector`` and ``camera``: the packaged estimate
    (:data:`PSF_ESTIMATE_FILE`) when they are the ones it was made for, else one made on
    :func:`star_calibration_frames` of this detector (cached per :func:`psf_fingerprint`)."""
    key = psf_fingerprint(detector, camera)
    pk = _packaged()
    if pk is not None and pk.fingerprint == key:
        return pk
    if key not in _MADE:
        _MADE[key] = estimate_psf(star_calibration_frames(detector, camera), camera, detector)
    return _MADE[key]
