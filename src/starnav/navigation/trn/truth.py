"""Truth of tracked features, from the renderer's per-pixel body-fixed points (metrics only).

A track is right when it follows one *surface point*. :class:`FeatureTruthBook` fixes that
point at the track's first detection: the body-fixed point ``(x_body, y_body, z_body)`` the
renderer reports for the pixel-centre ray under the detected position (the AOVs of
:class:`~starnav.bodies.small_body.ShapeModelBody`), interpolated bilinearly between the four
pixel centres around it (exact at a pixel centre, where the front end's detections lie; the
detected position is first undistorted, as the render is the pinhole image). In every frame the
point is projected with the *true* camera pose and body orientation of that frame
(``Camera.project``, distorted detector coordinates, as the measurements): the track's
``uv_true``. The front end never sees this book.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from starnav.camera import Camera
from starnav.geometry import FrameGeometry
from starnav.navigation.trn.measurements import FeatureTruth, FlybyMeasurement
from starnav.typing import FloatArray

#: AOV channels of the body-fixed surface point [m].
BODY_AOVS = ("x_body", "y_body", "z_body")


def surface_point(aovs: Mapping[str, NDArray], mask: NDArray[np.bool_], uv: FloatArray
                  ) -> FloatArray:
    """Body-fixed point [m] under pinhole pixel position ``uv`` (bilinear over the four
    surrounding pixel centres on the body; the nearest one when some are off it; NaN when
    none is on it)."""
    H, W = mask.shape
    u, v = float(uv[0]), float(uv[1])
    u0, v0 = math.floor(u), math.floor(v)
    fu, fv = u - u0, v - v0
    pts, wts = [], []
    for dv, du, w in ((0, 0, (1 - fu) * (1 - fv)), (0, 1, fu * (1 - fv)),
                      (1, 0, (1 - fu) * fv), (1, 1, fu * fv)):
        r, c = v0 + dv, u0 + du
        if 0 <= r < H and 0 <= c < W and mask[r, c]:
            pts.append([float(aovs[k][r, c]) for k in BODY_AOVS])
            wts.append(w)
    if not pts:
        return np.full(3, np.nan)
    if len(pts) < 4:
        r, c = int(round(v)), int(round(u))
        if 0 <= r < H and 0 <= c < W and mask[r, c]:
            return np.array([float(aovs[k][r, c]) for k in BODY_AOVS])
        return np.array(pts[int(np.argmax(wts))])
    return np.average(np.array(pts), axis=0, weights=np.array(wts))


def project_body_point(point_body: FloatArray, geom: FrameGeometry, camera: Camera
                       ) -> FloatArray:
    """Pixel ``(u, v)`` (distorted) of a body-fixed point with the frame's true pose."""
    p_cam = geom.R_cam_to_inertial.T @ (geom.R_body_to_inertial @ point_body) \
        + geom.moon_centre_camera()
    return camera.project(p_cam, distort=True)


class FeatureTruthBook:
    """The surface point of every track, fixed at its first detection (module docstring)."""

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self.points: dict[int, FloatArray] = {}
        self.first_frame: dict[int, int] = {}

    def annotate(self, measurement: FlybyMeasurement, geom: FrameGeometry,
                 aovs: Mapping[str, NDArray], mask: NDArray[np.bool_]) -> FlybyMeasurement:
        """``measurement`` with its ``truth``: one :class:`FeatureTruth` per feature."""
        out = []
        for f in measurement.features:
            if f.track_id not in self.points:
                uv_pin = (self.camera.project(self.camera.unproject(f.uv), distort=False)
                          if self.camera.has_distortion else f.uv)
                self.points[f.track_id] = surface_point(aovs, mask, uv_pin)
                self.first_frame[f.track_id] = measurement.frame_index
            p = self.points[f.track_id]
            uv = (project_body_point(p, geom, self.camera) if np.all(np.isfinite(p))
                  else np.full(2, np.nan))
            out.append(FeatureTruth(track_id=f.track_id, point_body=p.copy(), uv_true=uv))
        return dataclasses.replace(measurement, truth=tuple(out))
