"""A 3-D look at a scenario: the Moon, the trajectory and the camera frusta (pyvista, offscreen).

Technique
---------
1. Frames of the scenario (:class:`starnav.scenes.Scene`); the trajectory is drawn in the
   Moon-centred J2000 frame (spacecraft minus Moon, DE421), in km, to scale.
2. The Moon is a sphere of the scenario's radius (or the icosphere/DEM mesh when
   ``moon.shape`` is ``mesh``), lit by a light placed along the Sun direction of the middle
   frame, so the phase seen from the arc is visible.
3. ``frusta`` frames, evenly spread along the arc, get their camera frustum: four rays through
   the detector corners (pinhole intrinsics), cut at ``frustum_fraction`` of the range to the
   Moon, the boresight drawn as a line; the Sun and Earth directions are arrows at the Moon.
4. Rendering is offscreen. VTK needs an OpenGL context (EGL, OSMesa or an X server): a tiny
   probe render runs first in a subprocess, so that a machine without one gets a clear
   :class:`ShowUnavailableError` (what is missing and how to fix it) instead of a crash.

Example
-------
>>> from starnav.config import load_scenario
>>> from starnav.show import render_scene
>>> render_scene(load_scenario("scenario.yaml"), "scene.png")          # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from starnav.atomic import atomic_path
from starnav.errors import ConfigError, StarnavError
from starnav.renderer.scene import icosphere_mesh
from starnav.simulate import scene_from_scenario

if TYPE_CHECKING:
    from starnav.config import Scenario

log = logging.getLogger(__name__)

#: How long the offscreen probe may take [s].
PROBE_TIMEOUT_S = 90.0

_PROBE = """
import pyvista as pv
pv.OFF_SCREEN = True
pl = pv.Plotter(off_screen=True, window_size=(16, 16))
pl.add_mesh(pv.Sphere())
img = pl.screenshot(return_img=True)
pl.close()
assert img is not None and img.shape[0] == 16
print("ok")
"""


class ShowUnavailableError(StarnavError, RuntimeError):
    """pyvista/VTK cannot render offscreen on this machine."""


def check_offscreen(timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Run a tiny offscreen render in a subprocess; raise :class:`ShowUnavailableError` with
    the reason and the fixes if it fails (module step 4)."""
    try:
        import pyvista  # noqa: F401
    except ImportError as err:
        raise ShowUnavailableError(f"pyvista is not installed ({err}); install starnav's "
                                   "dependencies (pip install pyvista)") from None
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                           timeout=timeout_s, env=dict(os.environ))
    except subprocess.TimeoutExpired:
        raise ShowUnavailableError(f"the offscreen probe render did not finish in "
                                   f"{timeout_s:g} s (OpenGL context hangs)") from None
    if r.returncode != 0 or "ok" not in r.stdout:
        tail = " ".join((r.stderr or r.stdout).strip().splitlines()[-3:])[-400:]
        raise ShowUnavailableError(
            "pyvista cannot render offscreen on this machine (no usable OpenGL context: "
            f"exit {r.returncode}: {tail}). Fixes: run under a virtual display "
            "(`xvfb-run -a starnav show ...`), or install a VTK with EGL or OSMesa "
            "(e.g. the `vtk-osmesa` wheel, or the system packages libegl1 / libosmesa6).")


def _moon_mesh(sc: Scenario, pv: Any) -> Any:
    R = sc.moon.radius_km
    if sc.moon.shape == "mesh":
        m = icosphere_mesh(R * 1e3, min(sc.moon.mesh_subdivisions, 6))
        faces = np.hstack([np.full((m.faces.shape[0], 1), 3), m.faces]).ravel()
        return pv.PolyData(m.vertices / 1e3, faces)
    return pv.Sphere(radius=R, theta_resolution=120, phi_resolution=60)


def _frustum(geom: Any, camera: Any, length_km: float, pv: Any) -> tuple[Any, Any]:
    """Lines of the frustum and the boresight of one frame (Moon-centred J2000, km)."""
    apex = geom.camera_position / 1e3
    W, H = camera.width, camera.height
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    x = (corners[:, 0] - camera.cx) / camera.fx
    y = (corners[:, 1] - camera.cy) / camera.fy
    rays = np.column_stack([x, y, np.ones(4)])
    pts_cam = rays * length_km
    pts = apex + (geom.R_cam_to_inertial @ pts_cam.T).T
    verts = np.vstack([apex, pts])
    lines = []
    for k in range(4):
        lines += [2, 0, k + 1]
        lines += [2, k + 1, (k + 1) % 4 + 1]
    frustum = pv.PolyData(verts, lines=np.array(lines))
    bore = pv.Line(apex, apex + geom.R_cam_to_inertial @ np.array([0.0, 0.0, 1.0])
                   * length_km * 1.15)
    return frustum, bore


def _view(pl: Any, pts: Any) -> None:
    """Look at the arc and the Moon from above the orbit plane, tilted by ~35 deg."""
    pts = np.vstack([np.asarray(pts, float).reshape(-1, 3), np.zeros((1, 3))])
    c = 0.5 * pts.mean(axis=0)
    if pts.shape[0] >= 4:
        _, _, vt = np.linalg.svd(pts - pts.mean(axis=0))
        normal, along = vt[2], vt[0]
    else:
        normal, along = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    d = 0.82 * normal + 0.57 * along
    span = float(np.max(np.linalg.norm(pts - c, axis=1)))
    pl.camera.focal_point = tuple(c)
    pl.camera.position = tuple(c + d / np.linalg.norm(d) * span * 3.2)
    pl.camera.up = tuple(np.cross(d, along) / (np.linalg.norm(np.cross(d, along)) or 1.0))
    pl.reset_camera_clipping_range()


def render_scene(scenario: Scenario, out: str | os.PathLike[str], *, frusta: int = 8,
                 frustum_fraction: float = 0.35, window_size: tuple[int, int] = (1400, 1000),
                 probe: bool = True) -> Path:
    """Draw the Moon, the trajectory and camera frusta into a PNG (module steps 1-4).

    Parameters
    ----------
    scenario : Scenario
    out : path
        PNG file (written atomically).
    frusta : int
        Number of camera frusta along the arc (>= 1).
    frustum_fraction : float
        Frustum length as a fraction of the range to the Moon centre [-].
    window_size : (width, height)
        Image size [px].
    probe : bool
        Run the offscreen probe first (:func:`check_offscreen`).

    Raises
    ------
    ShowUnavailableError
        No offscreen OpenGL context on this machine (with the fixes).
    ConfigError
        Bad arguments.
    """
    if frusta < 1:
        raise ConfigError("frusta", frusta, "an integer >= 1")
    if not 0 < frustum_fraction <= 1:
        raise ConfigError("frustum_fraction", frustum_fraction, "a fraction in (0, 1]")
    scene = scene_from_scenario(scenario)
    if probe:
        check_offscreen()
    import pyvista as pv

    pv.OFF_SCREEN = True
    n = len(scene)
    idx = sorted({int(round(k)) for k in np.linspace(0, n - 1, min(frusta, n))})
    geoms = [scene.geometry(i) for i in idx]
    mid = scene.geometry(n // 2)
    pl = pv.Plotter(off_screen=True, window_size=list(window_size), lighting="none")
    pl.set_background("black")
    sun_dir = mid.sun_direction
    pl.add_light(pv.Light(position=tuple(sun_dir * 1e7), focal_point=(0, 0, 0),
                          light_type="scene light", intensity=1.0))
    pl.add_mesh(_moon_mesh(scenario, pv), color="lightgray", smooth_shading=True,
                ambient=0.03, diffuse=0.97, specular=0.0)
    R = scenario.moon.radius_km
    if scene.trajectory is not None:
        moon = scene.ephemeris.state("moon", scene.trajectory.times, center="emb")
        rel = (scene.trajectory.states[:, :3] - moon[:, :3]) / 1e3
        pl.add_mesh(pv.lines_from_points(rel), color="deepskyblue", line_width=3,
                    label="trajectory")
        ep = scene.epochs
        e_moon = scene.ephemeris.state("moon", ep, center="emb")
        pts = (scene.states_emb[:, :3] - e_moon[:, :3]) / 1e3
        pl.add_points(pts, color="white", point_size=4, render_points_as_spheres=True,
                      label="frames")
        earth = -e_moon[n // 2, :3]
        earth_dir = earth / np.linalg.norm(earth)
    else:
        earth_dir = None
    for k, g in enumerate(geoms):
        fr, bore = _frustum(g, scene.camera, g.range / 1e3 * frustum_fraction, pv)
        pl.add_mesh(fr, color="orange", line_width=2, label="frusta" if k == 0 else None)
        pl.add_mesh(bore, color="orange", line_width=1, opacity=0.6)
    ranges = np.array([g.range for g in geoms]) / 1e3
    arrow = 0.5 * float(np.median(ranges))
    pl.add_mesh(pv.Arrow(start=(0, 0, 0), direction=tuple(sun_dir), scale=arrow,
                         shaft_radius=0.015, tip_radius=0.04), color="gold", label="Sun",
                lighting=False)
    if earth_dir is not None:
        pl.add_mesh(pv.Arrow(start=(0, 0, 0), direction=tuple(earth_dir), scale=arrow,
                             shaft_radius=0.015, tip_radius=0.04), color="dodgerblue",
                    label="Earth", lighting=False)
    pl.add_legend(bcolor=(0.1, 0.1, 0.1), face=None, size=(0.16, 0.2), loc="upper right")
    cam = scene.camera
    title = (f"{cam.name}: {cam.width}x{cam.height} px, f {cam.focal_length * 1e3:.4g} mm; "
             f"{n} frame(s); Moon radius {R:g} km (to scale), axes J2000 [km]")
    pl.add_text(title, font_size=9, color="white")
    pl.show_axes()
    _view(pl, np.array([g.camera_position for g in geoms]) / 1e3 if scene.trajectory is None
          else rel)
    p = Path(out)
    with atomic_path(p, suffix=".png") as tmp:
        pl.screenshot(str(tmp))
    pl.close()
    log.info("wrote %s (%d frusta)", p, len(geoms))
    return p
