"""starnav.bodies: the target body a frame looks at, behind one interface.

A :class:`~starnav.bodies.base.TargetBody` answers what the rest of starnav asks of the body:

* **geometry** - its reference ellipsoid (``radii_m``: the navigation fix's shape and the limb
  truth), a bounding radius, and its orientation (body-fixed -> J2000) at given epochs;
* **rendering** - :meth:`~starnav.bodies.base.TargetBody.render_model`: the renderer's
  :class:`~starnav.renderer.render.MoonModel` (shape, photometric model and its albedo
  parameter, colour), with every file it needs read before any frame is rendered;
* **truth** - the limb of the reference ellipsoid (the navigation metrics' conic) and, for
  shape models, the surface points the renderer's AOVs report per pixel.

Bodies: :class:`~starnav.bodies.moon.Moon` (sphere, icosphere or the real/procedural DEM, DE421
librations) and :class:`~starnav.bodies.ellipsoid.TriaxialBody` (a triaxial ellipsoid with an
IAU rotation model: the simplest small body, and the frame the small-body shape models of the
fly-by fit into). :func:`starnav.simulate.body_from_scenario` picks one from the scenario's
``target`` section.
"""

from __future__ import annotations

from starnav.bodies.base import TargetBody, iau_orientation
from starnav.bodies.ellipsoid import TriaxialBody, ellipsoid_mesh
from starnav.bodies.moon import Moon, mean_normal_albedo
from starnav.bodies.schema import EllipsoidConfig, TargetConfig

__all__ = ["EllipsoidConfig", "Moon", "TargetBody", "TargetConfig", "TriaxialBody",
           "ellipsoid_mesh", "iau_orientation", "mean_normal_albedo"]
