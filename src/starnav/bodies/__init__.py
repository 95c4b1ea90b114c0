"""starnav.bodies: the target body a frame looks at, behind one interface, and the data model
the renderer draws (:mod:`~starnav.bodies.model`, :mod:`~starnav.bodies.mesh`; the renderer
imports this package, never the reverse).

A :class:`~starnav.bodies.base.TargetBody` answers what the rest of starnav asks of the body:

* **geometry** - its reference ellipsoid (``radii_m``: the navigation fix's shape and the limb
  truth), a bounding radius, and its orientation (body-fixed -> J2000) at given epochs;
* **rendering** - :meth:`~starnav.bodies.base.TargetBody.render_model`: the renderer's
  :class:`~starnav.bodies.model.TargetModel` (shape, photometric model and its albedo
  parameter, colour), with every file it needs read before any frame is rendered;
* **truth** - the limb of the reference ellipsoid (the navigation metrics' conic) and, for
  shape models, the surface points the renderer's AOVs report per pixel.

Bodies: :class:`~starnav.bodies.moon.Moon` (sphere, icosphere or the real/procedural DEM, DE421
librations), :class:`~starnav.bodies.ellipsoid.TriaxialBody` (a triaxial ellipsoid with an
IAU rotation model: the simplest small body) and
:class:`~starnav.bodies.small_body.ShapeModelBody` (a shape model: the packaged Itokawa radar
and Eros plate models or a ``.tab``/``.obj`` file, :mod:`starnav.bodies.shape`).
:func:`starnav.simulate.body_from_scenario` picks one from the scenario's ``target`` section.
"""

from __future__ import annotations

from starnav.bodies.base import TargetBody, iau_orientation
from starnav.bodies.ellipsoid import TriaxialBody, ellipsoid_mesh
from starnav.bodies.mesh import BodyMesh, icosphere_mesh
from starnav.bodies.model import AlbedoMap, TargetModel, load_albedo_map
from starnav.bodies.moon import Moon, mean_normal_albedo
from starnav.bodies.schema import (
    AlbedoMapConfig,
    EllipsoidConfig,
    MoonConfig,
    PhotometryConfig,
    ShapeModelConfig,
    TargetConfig,
)
from starnav.bodies.shape import ShapeModel, ShapeModelError, read_shape_model, shape_model_path
from starnav.bodies.small_body import SMALL_BODY_FACTS, ShapeModelBody

__all__ = ["SMALL_BODY_FACTS", "AlbedoMap", "AlbedoMapConfig", "BodyMesh", "EllipsoidConfig",
           "Moon", "MoonConfig", "PhotometryConfig", "ShapeModel", "ShapeModelBody",
           "ShapeModelConfig", "ShapeModelError", "TargetBody", "TargetConfig", "TargetModel",
           "TriaxialBody", "ellipsoid_mesh", "icosphere_mesh", "iau_orientation",
           "load_albedo_map", "mean_normal_albedo", "read_shape_model", "shape_model_path"]
