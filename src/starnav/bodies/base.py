"""The target-body interface (:class:`TargetBody`) and the IAU rotation model.

Orientation
-----------
A body's orientation is the rotation ``R`` with ``v_J2000 = R v_body``. For bodies given by the
IAU/IAG convention (Archinal et al. 2018, Celest. Mech. Dyn. Astr. 130:22, section 2): the pole
at right ascension ``alpha0`` and declination ``delta0`` and the prime meridian angle
``W = W0 + W_dot d`` (``d`` days past J2000 TDB), the rotation J2000 -> body is

    R_z(W) R_x(90 deg - delta0) R_z(90 deg + alpha0)

(passive rotations), and ``R`` is its transpose (:func:`iau_orientation`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.bodies.mesh import BodyMesh
from starnav.bodies.model import TargetModel
from starnav.constants import DAY
from starnav.geometry import frame_rotation_x, frame_rotation_z
from starnav.photometry import albedo_parameter
from starnav.typing import FloatArray


def iau_orientation(epochs_tdb: ArrayLike, pole_ra: float, pole_dec: float, w0: float,
                    w_dot: float) -> FloatArray:
    """Body-fixed -> J2000 rotations ``(..., 3, 3)`` of the IAU model (module docstring).

    Parameters
    ----------
    epochs_tdb : float or array
        [TDB s past J2000].
    pole_ra, pole_dec : float
        Pole right ascension and declination [rad] (J2000).
    w0 : float
        Prime meridian angle at J2000 [rad].
    w_dot : float
        Rotation rate [rad/day] (negative for retrograde rotators).
    """
    t = np.asarray(epochs_tdb, float)
    W = w0 + w_dot * (t / DAY)
    A = np.full_like(t, math.pi / 2 + pole_ra)
    B = np.full_like(t, math.pi / 2 - pole_dec)
    j2000_to_body = frame_rotation_z(W) @ frame_rotation_x(B) @ frame_rotation_z(A)
    return np.swapaxes(j2000_to_body, -1, -2)


class TargetBody(ABC):
    """What starnav needs of the body a frame looks at (package docstring)."""

    #: Short name, e.g. ``"moon"``.
    name: str = "body"
    #: Gravitational parameter [m^3 s^-2] where the body needs one (a hyperbolic fly-by);
    #: 0 when unknown or unused.
    gm: float = 0.0

    @property
    @abstractmethod
    def radii_m(self) -> tuple[float, float, float]:
        """Semi-axes of the reference ellipsoid along the body-fixed x, y, z axes [m]: the
        shape the navigation fix assumes and the limb truth is measured against."""

    @property
    def reference_radius_m(self) -> float:
        """Radius of the reference sphere used by the frame geometry: the largest semi-axis
        (an observer closer than that is inside the body) [m]."""
        return float(max(self.radii_m))

    @abstractmethod
    def orientation(self, epochs_tdb: ArrayLike, ephemeris: Any = None) -> FloatArray:
        """Body-fixed -> J2000 rotations ``(n, 3, 3)`` at the epochs [TDB s]; ``ephemeris`` the
        scene's :class:`~starnav.scenes.ephemeris.Ephemeris` where the body needs one."""

    @abstractmethod
    def render_model(self) -> TargetModel:
        """The renderer's :class:`~starnav.bodies.model.TargetModel` of this body (files read
        here, so that a bad one is reported before any frame is rendered)."""

    def describe(self) -> dict[str, Any]:
        """JSON-safe description (for manifests and reports)."""
        return {"name": self.name, "radii_m": list(self.radii_m)}


def mesh_render_model(photometry: Any, normal_albedo: float, radius: float, mesh: BodyMesh,
                      body_fixed_aovs: bool = False) -> TargetModel:
    """The renderer's model of a body given as a mesh: its photometric model (a
    ``PhotometryConfig``) with the model's albedo parameter reached from the body's normal
    albedo (``target.albedo``), a bounding ``radius`` [m] and the facets."""
    model = photometry.model
    params = photometry.resolved_params()
    albedo = float(albedo_parameter(normal_albedo, "normal_albedo", model, params,
                                    "target.albedo"))
    return TargetModel("mesh", radius=radius, model=model, params=params, albedo=albedo,
                     mesh=mesh, body_fixed_aovs=body_fixed_aovs)
