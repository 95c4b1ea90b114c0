"""Synthetic fly-by measurements from truth: the estimator without rendering.

The records the front end would hand the filter, made from the shape model and the fly-by's
closed forms, so that the filter, its consistency and its Monte Carlo run in seconds through
the same :func:`~starnav.navigation.trn.filter.run_filter` as the rendered pipeline.

1. Truth geometry (:func:`flyby_truth`, once for all runs): relative states, a boresight on the
   body, a pool of surface candidates, per frame the visible, lit and well-seen ones with their
   pixels, and the lit silhouette's centroid and radius.
2. One run (:func:`synthetic_measurements`): tracks born on candidates and dying geometrically
   or when unseen; Gaussian pixel noise, outlier jumps, an attitude error
   ``R_true = R_m exp([dtheta]x)``, noisy centroid and radius.

Seeds: run ``r`` draws its measurements from ``generator(s, STAGE_FLYBY_SYNTHETIC, r, 0)``
(:data:`STREAM_MEASUREMENTS`), its initial error from ``(..., r, 1)``, the candidate pool from
``(..., 0, 2)`` for every run.

Index
-----
:func:`run_measurements`, :func:`synthetic_measurements`, :func:`flyby_truth`,
:class:`FlybyTruth`, :class:`SyntheticOptions`, :func:`initial_estimate`,
:func:`boresight_attitude`, :func:`surface_samples`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from starnav.camera import Camera
from starnav.errors import ConfigError
from starnav.navigation.trn.body_view import BodyInCamera, lit_silhouette, visible
from starnav.navigation.trn.filter import ShapeBodyLike
from starnav.navigation.trn.measurements import (
    FeatureObservation,
    FeatureTruth,
    FlybyMeasurement,
)
from starnav.scenes.flyby import Flyby
from starnav.seeding import STAGE_FLYBY_SYNTHETIC, generator
from starnav.typing import FloatArray

#: Stream keys under ``STAGE_FLYBY_SYNTHETIC`` (never renumber).
STREAM_MEASUREMENTS = 0
STREAM_INITIAL_ERROR = 1
STREAM_CANDIDATES = 2
#: A run's draw of the estimator's shape-model scale error (trn.body_model; never change).
STREAM_SHAPE_SCALE = 3

ARCSEC = math.pi / 180.0 / 3600.0

#: A candidate is visible when the first hit of its ray is within this of it [m].
VISIBILITY_TOLERANCE = 0.01


@dataclass(frozen=True)
class SyntheticOptions:
    """Knobs of the synthetic front end (SI; module essay).

    Attributes
    ----------
    pixel_sigma_px : float
        1-sigma of a tracked feature's pixel coordinates [px].
    attitude_sigma : (3,) tuple
        1-sigma of the attitude error about camera x, y, z [rad] (default 5, 5, 30 arcsec:
        a star tracker's cross-boresight and roll accuracy).
    centroid_sigma_px, radius_sigma_px : float
        1-sigma of the silhouette centroid (each coordinate) and equivalent radius [px].
    max_features : int
        Tracks at once (the windows' capacity).
    mean_track_length : float
        Mean lifetime of a track [frames] (geometric).
    min_radius_px : float
        No features while the body's apparent radius is below this [px].
    candidates : int
        Surface points a tracker could lock on.
    max_incidence, max_emission : float
        Largest Sun incidence / viewing emission angle of a trackable point [rad].
    border_px : float
        Margin to the detector edge [px].
    outlier_fraction : float
        Fraction of observations displaced by ``outlier_px`` [-].
    outlier_px : float
    """

    pixel_sigma_px: float = 0.3
    attitude_sigma: tuple[float, float, float] = (5 * ARCSEC, 5 * ARCSEC, 30 * ARCSEC)
    centroid_sigma_px: float = 0.3
    radius_sigma_px: float = 0.3
    max_features: int = 30
    mean_track_length: float = 12.0
    min_radius_px: float = 8.0
    candidates: int = 500
    max_incidence: float = math.radians(80.0)
    max_emission: float = math.radians(70.0)
    border_px: float = 4.0
    outlier_fraction: float = 0.0
    outlier_px: float = 15.0

    def __post_init__(self) -> None:
        for name in ("pixel_sigma_px", "centroid_sigma_px", "radius_sigma_px", "min_radius_px",
                     "border_px", "outlier_px"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"synthetic.{name}", getattr(self, name), ">= 0")
        if len(self.attitude_sigma) != 3 or min(self.attitude_sigma) < 0:
            raise ConfigError("synthetic.attitude_sigma", self.attitude_sigma,
                              "3 non-negative values [rad]")
        if not self.mean_track_length >= 1:
            raise ConfigError("synthetic.mean_track_length", self.mean_track_length, ">= 1")
        if not 0 <= self.outlier_fraction < 1:
            raise ConfigError("synthetic.outlier_fraction", self.outlier_fraction, "in [0, 1)")
        if self.candidates < 1 or self.max_features < 0:
            raise ConfigError("synthetic.candidates", self.candidates, ">= 1")


@dataclass(frozen=True)
class FlybyTruth:
    """The deterministic geometry of a synthetic fly-by (module step 1).

    Attributes
    ----------
    epochs : (K,) array [TDB s]
    epoch_ca : float
    states : (K, 6) array
        True ``(r, v)`` relative to the body, J2000 [m, m/s].
    R_cam_to_inertial : (K, 3, 3) array
        True camera attitude.
    R_body_to_inertial : (K, 3, 3) array
    sun_direction : (3,) array
    candidates : (M, 3) array
        Body-fixed surface points [m].
    trackable : (K, M) bool array
    uv : (K, M, 2) array
        Exact pixels of the candidates (NaN where not trackable).
    centroid_uv : (K, 2) array
        Lit silhouette centroid [px].
    radius_px : (K,) array
        Lit silhouette equivalent radius [px].
    """

    epochs: FloatArray
    epoch_ca: float
    states: FloatArray
    R_cam_to_inertial: FloatArray
    R_body_to_inertial: FloatArray
    sun_direction: FloatArray
    candidates: FloatArray
    trackable: NDArray[np.bool_]
    uv: FloatArray
    centroid_uv: FloatArray
    radius_px: FloatArray


def boresight_attitude(r: ArrayLike, up: ArrayLike) -> FloatArray:
    """Camera -> J2000 rotation with ``+z`` from the spacecraft at ``r`` (body-centred) to the
    body centre and ``+x`` along ``up x z`` (``up`` not parallel to ``r``)."""
    z = -np.asarray(r, float)
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def surface_samples(shape: object, count: int, rng: np.random.Generator
                    ) -> tuple[FloatArray, FloatArray]:
    """``count`` points uniform over the facets' area and their facet normals (body-fixed)."""
    V = np.asarray(shape.vertices, float)  # type: ignore[attr-defined]
    F = np.asarray(shape.faces, np.int64)  # type: ignore[attr-defined]
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(n, axis=1)
    f = rng.choice(F.shape[0], size=count, p=area / area.sum())
    u, w = rng.random(count), rng.random(count)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    pts = a[f] + u[:, None] * (b[f] - a[f]) + w[:, None] * (c[f] - a[f])
    return pts, n[f] / np.linalg.norm(n[f], axis=1, keepdims=True)


def flyby_truth(flyby: Flyby, body: ShapeBodyLike, camera: Camera, epochs: ArrayLike,
                options: SyntheticOptions | None = None, seed: int = 0) -> FlybyTruth:
    """The truth geometry of a synthetic fly-by at ``epochs`` [TDB s] (module step 1)."""
    opt = options if options is not None else SyntheticOptions()
    t = np.asarray(epochs, float)
    if t.ndim != 1 or t.size == 0 or np.any(np.diff(t) <= 0):
        raise ConfigError("epochs", t.tolist()[:5], "a non-empty, increasing 1-D array [s]")
    X = flyby.states(t)
    shape = body.shape
    pts, nrm = surface_samples(shape, opt.candidates,
                               generator(seed, STAGE_FLYBY_SYNTHETIC, 0, STREAM_CANDIDATES))
    s = np.asarray(flyby.sun_direction, float)
    K, M = t.size, pts.shape[0]
    Rc = np.zeros((K, 3, 3))
    Rb = np.asarray(body.orientation(t), float).reshape(K, 3, 3)
    ok = np.zeros((K, M), bool)
    uv = np.full((K, M, 2), np.nan)
    cen = np.zeros((K, 2))
    rad = np.zeros(K)
    for k in range(K):
        r = X[k, :3]
        Rc[k] = boresight_attitude(r, flyby.z_hat)
        R_bc = Rc[k].T @ Rb[k]
        placed = BodyInCamera.place(shape.vertices, shape.faces, R_bc, Rc[k].T @ (-r))
        sil = lit_silhouette(placed, Rc[k].T @ s, camera)
        cen[k], rad[k] = sil.centroid_uv, sil.radius_px
        if sil.radius_px < opt.min_radius_px:
            continue
        p_i = pts @ Rb[k].T - r                       # spacecraft -> point, J2000
        n_i = nrm @ Rb[k].T
        view = -p_i / np.linalg.norm(p_i, axis=1, keepdims=True)
        good = ((n_i @ s) > math.cos(opt.max_incidence)) & (
            np.einsum("ij,ij->i", n_i, view) > math.cos(opt.max_emission))
        idx = np.flatnonzero(good)
        if idx.size == 0:
            continue
        p_c = p_i[idx] @ Rc[k]
        vis = visible(placed, p_c, tolerance=VISIBILITY_TOLERANCE)
        idx, p_c = idx[vis], p_c[vis]
        q = camera.project(p_c)
        b = opt.border_px
        inside = ((q[:, 0] >= b) & (q[:, 0] <= camera.width - 1 - b)
                  & (q[:, 1] >= b) & (q[:, 1] <= camera.height - 1 - b))
        ok[k, idx[inside]] = True
        uv[k, idx[inside]] = q[inside]
    return FlybyTruth(t, float(flyby.epoch_ca), X, Rc, Rb, s, pts, ok, uv, cen, rad)


def synthetic_measurements(truth: FlybyTruth, options: SyntheticOptions | None = None,
                           rng: np.random.Generator | None = None) -> list[FlybyMeasurement]:
    """One run's measurements from the truth geometry (module step 2)."""
    opt = options if options is not None else SyntheticOptions()
    g = rng if rng is not None else np.random.default_rng(0)
    sig = np.asarray(opt.attitude_sigma, float)
    active: dict[int, tuple[int, int]] = {}   # track id -> (candidate, frames left)
    tracked: set[int] = set()
    next_id = 0
    out = []
    p_death = 1.0 / opt.mean_track_length
    for k in range(truth.epochs.size):
        ok = truth.trackable[k]
        # deaths: point lost or lifetime over
        for tid in list(active):
            c, left = active[tid]
            if not ok[c] or left <= 0:
                del active[tid]
                tracked.discard(c)
        # births
        room = opt.max_features - len(active)
        free = np.flatnonzero(ok & ~np.isin(np.arange(ok.size), list(tracked)))
        if room > 0 and free.size:
            for c in g.permutation(free)[:room]:
                active[next_id] = (int(c), int(g.geometric(p_death)))
                tracked.add(int(c))
                next_id += 1
        feats, tru = [], []
        for tid in sorted(active):
            c, left = active[tid]
            active[tid] = (c, left - 1)
            uv_t = truth.uv[k, c]
            uv_m = uv_t + opt.pixel_sigma_px * g.standard_normal(2)
            if opt.outlier_fraction > 0 and g.random() < opt.outlier_fraction:
                a = g.uniform(0, 2 * math.pi)
                uv_m = uv_m + opt.outlier_px * np.array([math.cos(a), math.sin(a)])
            feats.append(FeatureObservation(tid, uv_m, opt.pixel_sigma_px))
            tru.append(FeatureTruth(tid, truth.candidates[c].copy(), uv_t.copy()))
        dth = sig * g.standard_normal(3)
        R_m = truth.R_cam_to_inertial[k] @ Rotation.from_rotvec(-dth).as_matrix()
        cen = truth.centroid_uv[k] + opt.centroid_sigma_px * g.standard_normal(2)
        rad = truth.radius_px[k] + opt.radius_sigma_px * g.standard_normal()
        out.append(FlybyMeasurement(
            frame_index=k, epoch_tdb=float(truth.epochs[k]), R_cam_to_inertial=R_m,
            attitude_sigma=sig.copy(), features=tuple(feats), centroid_uv=cen,
            centroid_sigma_px=max(opt.centroid_sigma_px, 1e-6), apparent_radius_px=float(rad),
            apparent_radius_sigma_px=max(opt.radius_sigma_px, 1e-6), truth=tuple(tru),
            sun_direction=np.asarray(truth.sun_direction, float).copy()))
    return out


def run_measurements(truth: FlybyTruth, seed: int, run: int,
                     options: SyntheticOptions | None = None) -> list[FlybyMeasurement]:
    """The measurements of Monte Carlo run ``run`` of ``seed`` (module seed table)."""
    return synthetic_measurements(
        truth, options, generator(seed, STAGE_FLYBY_SYNTHETIC, run, STREAM_MEASUREMENTS))


def initial_estimate(truth: FlybyTruth, P0: ArrayLike, seed: int, run: int) -> FloatArray:
    """The run's initial state: the first true state plus a draw from ``P0`` (6, 6)."""
    L = np.linalg.cholesky(np.asarray(P0, float))
    g = generator(seed, STAGE_FLYBY_SYNTHETIC, run, STREAM_INITIAL_ERROR)
    return truth.states[0] + L @ g.standard_normal(6)
