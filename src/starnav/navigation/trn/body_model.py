"""The body model the fly-by estimator navigates on, apart from the body that renders.

A mission reaching a small body for a fly-by has, at best, a shape model from its approach
images or from ground radar: coarser than the truth and of uncertain size (the radar model of
Itokawa is about 9 % too large in scale against Hayabusa's). The estimator therefore gets
(``navigation.trn.shape_model``):

* ``exact``: the rendered mesh itself (an idealised map; the truth and the model coincide);
* ``coarse``: :func:`~starnav.bodies.shape.coarse_shape_model` of the truth (quadric
  decimation to ``faces`` triangles, Taubin smoothing, the truth's volume), scaled by
  ``1 + e`` with ``e ~ N(0, scale_sigma^2)`` drawn per Monte Carlo run. The filter carries the
  scale as a consider state of sigma ``scale_sigma`` (filter step 4e) when ``estimate_scale``.
  The model's stated accuracy is its rms departure from the surface (``CoarseShape.height_rms``;
  docs/navigation.md gives it for the packaged bodies): its landmarks' height 1-sigma is
  ``height_sigma_ratio`` times it, and the silhouette's model-error sigmas, calibrated on one
  body's model, scale with its ratio to the mean radius (``ShapePrior.height_fraction``, filter
  ``map_error_factor``): an error model in metres, or in fractions of the radius, fitted on one
  body's map understates a map whose departure is relatively larger. No landmark is born on it
  while the position's largest 1-sigma exceeds ``birth_sigma_fraction`` of the mean radius
  (filter step 7a: a landmark cast
  from a loose position is a poor linearisation, and with the scale state the filter then
  gains information along the direction that only the priors fix, the trajectory's scale, and
  becomes overconfident: the known inconsistency of EKF-SLAM, Huang, Mourikis & Roumeliotis
  2008, "Analysis and improvement of the consistency of extended Kalman filter based SLAM").

:func:`estimator_model` builds it; the coarse shape of a truth is built once
(:data:`_COARSE`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from starnav.bodies.shape import CoarseShape, ShapeModel, coarse_shape_model
from starnav.bodies.small_body import ShapeModelBody
from starnav.cache import BoundedCache
from starnav.errors import ConfigError
from starnav.navigation.trn.filter import ShapePrior

#: Coarse models by (truth's source, faces, smoothing passes).
_COARSE: BoundedCache[tuple[str, int, int], CoarseShape] = BoundedCache(4)


@dataclass(frozen=True)
class EstimatorModel:
    """The body model of one run (module essay).

    Attributes
    ----------
    body : ShapeModelBody
        The truth's spin and ``gm`` on the model's shape.
    prior : ShapePrior
        What the model adds to the filter: its scale sigma, height error and birth threshold.
    scale_error : float
        The model's size over the truth's, minus 1 [-] (0 for ``exact``).
    info : dict
        ``map``, ``faces``, ``scale_error``, ``scale_truth`` (the filter's scale state at
        truth, ``1 / (1 + scale_error) - 1``); coarse: ``height_rms_m`` and ``height_max_m``
        of the truth's vertices from the model's surface (before scaling).
    """

    body: Any
    prior: ShapePrior
    scale_error: float
    info: dict[str, Any]


def coarse_of(truth: ShapeModelBody, faces: int, smoothing_iterations: int) -> CoarseShape:
    """The coarse shape of ``truth`` (built once per truth and settings)."""
    return _COARSE.get_or_make(
        (truth.shape.source, int(faces), int(smoothing_iterations)),
        lambda: coarse_shape_model(truth.shape, int(faces), int(smoothing_iterations)))


def estimator_model(truth: ShapeModelBody, config: Any, unit_draw: float) -> EstimatorModel:
    """The model of a run whose scale error is ``config.scale_sigma * unit_draw``
    (``config``: a :class:`~starnav.navigation.schema.TrnShapeModelConfig`; ``unit_draw`` a
    standard normal draw of the run's stream)."""
    if config.map == "exact":
        return EstimatorModel(truth, ShapePrior(), 0.0, {
            "map": "exact", "faces": truth.shape.n_faces, "scale_error": 0.0,
            "scale_truth": 0.0})
    if config.map != "coarse":
        raise ConfigError("navigation.trn.shape_model.map", config.map, "exact or coarse")
    coarse = coarse_of(truth, config.faces, config.smoothing_iterations)
    e = float(config.scale_sigma) * float(unit_draw)
    shape = ShapeModel(coarse.shape.vertices * (1.0 + e), coarse.shape.faces,
                       coarse.shape.source)
    prior = ShapePrior(
        scale_sigma=float(config.scale_sigma) if config.estimate_scale else 0.0,
        height_sigma=float(config.height_sigma_ratio) * coarse.height_rms,
        birth_sigma=float(config.birth_sigma_fraction) * coarse.mean_radius,
        height_fraction=coarse.height_rms / coarse.mean_radius)
    return EstimatorModel(ShapeModelBody(truth.config, shape=shape), prior, e, {
        "map": "coarse", "faces": shape.n_faces, "scale_error": e,
        "scale_truth": 1.0 / (1.0 + e) - 1.0, "height_rms_m": coarse.height_rms,
        "height_max_m": coarse.height_max})
