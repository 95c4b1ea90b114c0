"""RANSAC outlier rejection of limb points: the paper's circle model and a conic-aware model.

Limb points from a real frame carry outliers: terminator points that slipped past the lit-side
test, stars and hot pixels at the end of a row, blooming columns, the image border. RANSAC
(Fischler & Bolles 1981) finds the largest set of points consistent with one limb.

Technique
---------
1. **Hypotheses.** Draw minimal samples of 3 points with the caller's random generator, in
   batches of :data:`BATCH` hypotheses evaluated at once with numpy.
2. **Model per sample.**

   * ``"circle"`` (the STAR Nav model): the circle through the 3 points; a point's residual is
     ``| |p - c| - r |`` [px]. A sphere's limb is an ellipse off-axis, so the threshold must
     allow the misfit (up to ~1.7 px near the AA-STR field edge; docs/facts.md section 4).
   * ``"christian-robinson"`` (conic-aware): the exact Christian-Robinson solve of the 3 rays
     (``s_i^T n = 1``); a point's residual is the angle between its ray and the predicted limb
     cone, in pixels (:func:`~starnav.navigation.christian_robinson.cone_residual_px`). The
     ellipse is modelled exactly, so the threshold can be as tight as the point noise.

3. **Score.** MSAC (Torr & Zisserman 2000): ``sum_i min(r_i^2, t^2)``, lower is better; it
   ranks equal-count consensus sets by their fit.
4. **Stop.** After each batch the number of samples needed for confidence ``p`` at the best
   inlier ratio ``w`` is ``log(1 - p) / log(1 - w^3)``; stop when it is reached or at
   ``max_iterations``.
5. **Refit.** The model is refitted by least squares on the consensus set (Kasa circle, or
   Christian-Robinson on all inliers) and the inliers recomputed, :data:`REFITS` times.

Reference
---------
M. A. Fischler and R. C. Bolles, "Random sample consensus", Commun. ACM 24 (1981) 381-395.
P. H. S. Torr and A. Zisserman, "MLESAC: a new robust estimator with application to estimating
image geometry", Comput. Vis. Image Underst. 78 (2000) 138-156.

Index
-----
:func:`ransac_limb`, :class:`RansacConfig`, :class:`RansacResult`, :class:`RansacError`,
:data:`RANSAC_MODELS`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field

from starnav.camera import Camera
from starnav.config_base import SIView, StrictModel
from starnav.errors import ConfigError, StarnavError
from starnav.fields import PositiveFloat
from starnav.navigation.christian_robinson import (
    ChristianRobinsonOptions,
    cone_residual_px,
    scaled_rays,
    shape_transform,
)
from starnav.navigation.limb import fit_circle_kasa
from starnav.registry import Registry
from starnav.typing import FloatArray

log = logging.getLogger(__name__)


class RansacError(StarnavError, ValueError):
    """RANSAC found no consistent limb."""


#: Hypotheses drawn and scored at once (module step 1).
BATCH = 32
#: Least-squares refits on the consensus set (module step 5).
REFITS = 2


class RansacConfig(StrictModel):
    """Scenario section ``navigation.ransac``: outlier rejection among the limb points
    (:func:`ransac_limb` reads its SI view, ``to_si()``)."""

    model: Literal["circle", "christian-robinson"] = Field(
        "circle", description="model fitted to each sample: circle (3 points, fast) or "
        "christian-robinson (the limb ellipse of the Moon seen from a position)")
    threshold_px: PositiveFloat = Field(2.0, description="inlier threshold [px]")
    max_iterations: Annotated[int, Field(ge=1)] = Field(
        200, description="upper bound on the hypotheses drawn")
    confidence: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.999, description="probability of drawing at least one all-inlier sample, sets the "
        "number of hypotheses [-]")
    min_inlier_fraction: Annotated[float, Field(gt=0, le=1)] = Field(
        0.3, description="fewer inliers than this fraction of the points: no fix for the frame "
        "[-]")


#: The defaults' SI view.
_DEFAULT = RansacConfig().to_si()


@dataclass(frozen=True)
class RansacResult:
    """Outcome of :func:`ransac_limb`.

    Attributes
    ----------
    inliers : (N,) bool array
        Consensus set.
    residual_px : (N,) array
        Residual of every point to the final model [px].
    model : str
        Model name.
    params : (3,) array
        ``(cu, cv, r)`` [px] for the circle, ``n`` (scaled space) for Christian-Robinson.
    iterations : int
        Hypotheses drawn.
    """

    inliers: NDArray[np.bool_]
    residual_px: FloatArray
    model: str
    params: FloatArray
    iterations: int

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


# ------------------------------------------------------------------------ models
class _CircleModel:
    """Circle through 3 points; residual ``| |p - c| - r |`` [px]."""

    def __init__(self, uv: FloatArray, camera: Camera | None, B: FloatArray | None) -> None:
        self.uv = uv

    def hypotheses(self, idx: NDArray[np.intp]) -> FloatArray:
        p = self.uv[idx]  # (K, 3, 2)
        a, b, c = p[:, 0], p[:, 1], p[:, 2]
        ab, ac = b - a, c - a
        d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            nb, nc = np.sum(ab * ab, 1), np.sum(ac * ac, 1)
            ux = (ac[:, 1] * nb - ab[:, 1] * nc) / d
            uy = (ab[:, 0] * nc - ac[:, 0] * nb) / d
        r = np.hypot(ux, uy)
        return np.column_stack([a[:, 0] + ux, a[:, 1] + uy, r])

    def residuals(self, h: FloatArray) -> FloatArray:
        """``(N, K)`` residuals for ``K`` hypotheses."""
        du = self.uv[:, 0:1] - h[None, :, 0]
        dv = self.uv[:, 1:2] - h[None, :, 1]
        du *= du
        dv *= dv
        du += dv
        with np.errstate(invalid="ignore"):
            # (sqrt of the sum: np.hypot is 5x slower on the (N, K) batch, and within an ulp)
            np.sqrt(du, out=du)
            du -= h[None, :, 2]
            return np.abs(du, out=du)

    def refit(self, inl: NDArray[np.bool_]) -> FloatArray:
        c, r = fit_circle_kasa(self.uv[inl])
        return np.array([c[0], c[1], r])


class _ChristianRobinsonModel:
    """Exact Christian-Robinson solve of 3 rays; residual: angle to the limb cone [px]."""

    def __init__(self, uv: FloatArray, camera: Camera | None, B: FloatArray | None) -> None:
        if camera is None or B is None:
            raise ConfigError("ransac.model", "christian-robinson",
                              "a camera and the body's shape transform B")
        self.s, _ = scaled_rays(uv, camera, B)
        self.pix = 1.0 / camera.fx

    def hypotheses(self, idx: NDArray[np.intp]) -> FloatArray:
        S = self.s[idx]  # (K, 3, 3)
        det = np.linalg.det(S)
        good = np.abs(det) > 1e-18
        n = np.full((idx.shape[0], 3), np.nan)
        if np.any(good):
            n[good] = np.linalg.solve(S[good], np.ones((int(good.sum()), 3, 1)))[..., 0]
        return n

    def residuals(self, h: FloatArray) -> FloatArray:
        return np.abs(cone_residual_px(self.s, h, self.pix))

    def refit(self, inl: NDArray[np.bool_]) -> FloatArray:
        n, *_ = np.linalg.lstsq(self.s[inl], np.ones(int(inl.sum())), rcond=None)
        return n


#: Registry of RANSAC models by name.
RANSAC_MODELS: Registry[Callable[..., object]] = Registry("RANSAC model", {
    "circle": _CircleModel,
    "christian-robinson": _ChristianRobinsonModel,
})


def ransac_limb(
    uv: ArrayLike,
    camera: Camera | None = None,
    *,
    rng: np.random.Generator,
    options: SIView | None = None,
    fix_options: ChristianRobinsonOptions | None = None,
    R_body_to_cam: ArrayLike | None = None,
) -> RansacResult:
    """Reject outliers among limb points (module steps 1-5).

    Parameters
    ----------
    uv : (N, 2) array
        Limb points [px].
    camera : Camera, optional
        Needed by the ``christian-robinson`` model.
    rng : numpy.random.Generator
        Source of the random samples.
    options : SIView, optional
        The SI view of a :class:`RansacConfig` (model, threshold and limits); default its
        defaults.
    fix_options : ChristianRobinsonOptions, optional
        Body shape for the ``christian-robinson`` model.
    R_body_to_cam : (3, 3) array, optional
        Body -> camera rotation (triaxial body only).

    Returns
    -------
    RansacResult

    Raises
    ------
    RansacError
        Fewer than 3 points, or no consensus of at least ``min_inlier_fraction`` of them.
    """
    opt = options if options is not None else _DEFAULT
    uv = np.asarray(uv, float).reshape(-1, 2)
    N = uv.shape[0]
    if N < 3:
        raise RansacError(f"RANSAC: {N} limb points, need >= 3 (degenerate arc)")
    B = None
    if opt.model == "christian-robinson":
        fo = fix_options or ChristianRobinsonOptions()
        B = shape_transform(fo.radii_m, R_body_to_cam)
    model = RANSAC_MODELS[opt.model](uv, camera, B)
    t2 = opt.threshold_px**2
    best_score, best_h = math.inf, None
    done, needed = 0, opt.max_iterations
    while done < min(needed, opt.max_iterations):
        K = min(BATCH, opt.max_iterations - done)
        # three distinct indices per hypothesis
        i0 = rng.integers(0, N, K)
        i1 = (i0 + 1 + rng.integers(0, N - 1, K)) % N
        i2 = rng.integers(0, N - 2, K)
        lo, hi = np.minimum(i0, i1), np.maximum(i0, i1)
        i2 = i2 + (i2 >= lo)
        i2 = i2 + (i2 >= hi)
        idx = np.stack([i0, i1, i2], 1)
        h = model.hypotheses(idx)
        r = model.residuals(h)
        # a degenerate hypothesis (NaN or infinite residuals) scores t2 at every point:
        # fmin ignores the NaNs (r <= threshold is False for them below)
        score = np.fmin(r * r, t2).sum(axis=0)
        k = int(np.argmin(score))
        done += K
        if score[k] < best_score:
            best_score, best_h = float(score[k]), h[k]
            w = float(np.mean(r[:, k] <= opt.threshold_px))
            if w >= 1.0:
                needed = done
            elif w > 0:
                needed = int(math.ceil(math.log(1 - opt.confidence) / math.log(1 - w**3)))
    if best_h is None:
        raise RansacError("RANSAC: no valid hypothesis (collinear limb points)")
    res = model.residuals(best_h[None])[:, 0]
    inl = res <= opt.threshold_px
    params = best_h
    for _ in range(REFITS):
        if inl.sum() < 3:
            break
        try:
            params = model.refit(inl)
        except StarnavError:
            break
        res = model.residuals(params[None])[:, 0]
        new = res <= opt.threshold_px
        if np.array_equal(new, inl):
            break
        inl = new
    frac = float(inl.mean())
    if inl.sum() < 3 or frac < opt.min_inlier_fraction:
        raise RansacError(
            f"RANSAC ({opt.model}): {int(inl.sum())} of {N} limb points consistent with one "
            f"limb ({frac:.0%} < {opt.min_inlier_fraction:.0%}) at {opt.threshold_px} px")
    log.debug("RANSAC %s: %d/%d inliers after %d hypotheses", opt.model, int(inl.sum()), N,
              done)
    return RansacResult(inliers=inl, residual_px=res, model=opt.model,
                        params=np.asarray(params, float), iterations=done)
