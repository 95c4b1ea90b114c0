"""A 3-D look at a scenario for a slide: the body, the observer, its field of view, the Sun.

1. Frames of the scenario, drawn in the body-centred J2000 frame, in km, to scale.
2. Two panels: an overview (body, trajectory, camera frusta, Sun and Earth arrows) and the body
   seen from the middle frame's camera, with the camera's own "up".
3. Framing (:func:`fit_view`, pure geometry): every point that matters projects inside the
   image with a margin; :meth:`View.project` is VTK's projection, so tests need no pixels.
4. Offscreen rendering without an X server: the first VTK window that works (EGL, OSMesa, X)
   found by a probe in a subprocess; where none works, :class:`ShowUnavailableError` says what
   to install.

Index
-----
:func:`render_scene`, :func:`layout_scene`, :class:`Layout`, :class:`View`, :func:`fit_view`,
:func:`body_view`, :func:`overview_direction`, :func:`frustum_corners`, :func:`sphere_points`,
:func:`offscreen_window`, :class:`ShowUnavailableError`.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from starnav.atomic import atomic_path
from starnav.bodies.mesh import icosphere_mesh
from starnav.errors import ConfigError, StarnavError
from starnav.simulate import scene_from_scenario
from starnav.typing import FloatArray

if TYPE_CHECKING:
    from starnav.config import Scenario

log = logging.getLogger(__name__)

#: How long one offscreen probe may take [s].
PROBE_TIMEOUT_S = 90.0
#: VTK render windows tried for offscreen rendering, in order (``VTK_DEFAULT_OPENGL_WINDOW``).
OFFSCREEN_WINDOWS = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow", "vtkXOpenGLRenderWindow")
#: Body diameter as a fraction of the "seen from the observer" panel's height [-].
BODY_FILL = 0.55
#: Margin kept free on each side of a panel, as a fraction of its half-size [-].
VIEW_MARGIN = 0.08
#: Margin of the overview (room for the axis labels) [-].
OVERVIEW_MARGIN = 0.18
#: VTK's default vertical view angle [deg].
VIEW_ANGLE_DEG = 30.0
#: Vertical view angle of the overview [deg]: narrow, for little perspective distortion.
OVERVIEW_ANGLE_DEG = 15.0
#: Colours: a light figure for slides.
BACKGROUND = "#eef1f5"
BODY_COLOUR = "#8f877c"
TEXT_COLOUR = "black"

_PROBE = """
import pyvista as pv
pv.OFF_SCREEN = True
pl = pv.Plotter(off_screen=True, window_size=(16, 16))
pl.add_mesh(pv.Sphere())
img = pl.screenshot(return_img=True)
name = type(pl.ren_win).__name__
pl.close()
assert img is not None and img.shape[0] == 16
print("ok", name)
"""


class ShowUnavailableError(StarnavError, RuntimeError):
    """pyvista/VTK cannot render offscreen on this machine."""


# --------------------------------------------------------------------------- offscreen context
def _probe(window: str | None, timeout_s: float) -> tuple[bool, str]:
    """Run the probe render with ``window`` as VTK's render window: (worked cleanly, why not)."""
    env = dict(os.environ)
    if window is not None:
        env["VTK_DEFAULT_OPENGL_WINDOW"] = window
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                           timeout=timeout_s, env=env)
    except subprocess.TimeoutExpired:
        return False, f"{window}: no answer in {timeout_s:g} s"
    if r.returncode == 0 and r.stdout.startswith("ok") and not r.stderr.strip():
        return True, ""
    tail = " ".join((r.stderr or r.stdout).strip().splitlines()[-2:])[-300:]
    return False, f"{window}: exit {r.returncode}: {tail}"


def offscreen_window(timeout_s: float = PROBE_TIMEOUT_S) -> str | None:
    """The VTK render window class that renders offscreen here without a warning (module
    step 4): the user's ``VTK_DEFAULT_OPENGL_WINDOW`` if set, else the first of
    :data:`OFFSCREEN_WINDOWS` whose probe render (in a subprocess, so a crash cannot take this
    process down) works with nothing on stderr.

    Raises
    ------
    ShowUnavailableError
        pyvista missing, or no window works (the reasons and the fixes).
    """
    try:
        import pyvista  # noqa: F401
    except ImportError as err:
        raise ShowUnavailableError(f"pyvista is not installed ({err}); install starnav's "
                                   "dependencies (pip install pyvista)") from None
    return _find_window(sys.executable, os.environ.get("VTK_DEFAULT_OPENGL_WINDOW"),
                        os.environ.get("DISPLAY"), timeout_s)


@functools.cache
def _find_window(executable: str, user: str | None, display: str | None,
                 timeout_s: float) -> str | None:
    """:func:`offscreen_window`, probed once per interpreter, user choice and display."""
    reasons = []
    for window in (user,) if user else OFFSCREEN_WINDOWS:
        ok, why = _probe(window, timeout_s)
        if ok:
            return window
        reasons.append(why)
    raise ShowUnavailableError(
        "pyvista cannot render offscreen on this machine (no usable OpenGL context: "
        f"{'; '.join(reasons)}). Fixes: install EGL or OSMesa (the system packages libegl1 / "
        "libosmesa6), or run under a virtual display (`xvfb-run -a starnav show ...`)")


@contextlib.contextmanager
def _vtk_window(window: str | None) -> Iterator[None]:
    """``VTK_DEFAULT_OPENGL_WINDOW`` set to ``window`` while a plotter is created."""
    old = os.environ.get("VTK_DEFAULT_OPENGL_WINDOW")
    if window is not None:
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = window
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
        else:
            os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = old


# --------------------------------------------------------------------------- framing
def _unit(v: ArrayLike) -> FloatArray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class View:
    """A perspective camera as VTK has it: position, focal point, view-up, vertical view
    angle [deg] (any unit of length, the same as the scene's)."""

    position: FloatArray
    focal_point: FloatArray
    up: FloatArray
    view_angle_deg: float = VIEW_ANGLE_DEG

    def axes(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(right, up, forward) unit vectors (view-up orthogonalised, as VTK does)."""
        f = _unit(self.focal_point - self.position)
        r = _unit(np.cross(f, self.up))
        return r, np.cross(r, f), f

    def project(self, points: ArrayLike, aspect: float = 1.0) -> FloatArray:
        """Image coordinates ``(n, 2)`` of ``points`` ``(n, 3)``: (x right, y up) in [0, 1]
        inside the image, for a viewport of width / height ``aspect``. Points behind the
        camera get NaN."""
        r, u, f = self.axes()
        d = np.atleast_2d(np.asarray(points, float)) - self.position
        z = d @ f
        t = math.tan(math.radians(self.view_angle_deg) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(z > 0, (d @ r) / (z * t * aspect), np.nan)
            y = np.where(z > 0, (d @ u) / (z * t), np.nan)
        return np.column_stack([(x + 1) / 2, (y + 1) / 2])


def sphere_points(centre: ArrayLike, radius: float, n: int = 400) -> FloatArray:
    """``n`` points spread evenly over a sphere (Fibonacci lattice), for framing."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = math.pi * (3 - math.sqrt(5)) * k
    rho = np.sqrt(1 - z * z)
    return np.asarray(centre, float) + radius * np.column_stack(
        [rho * np.cos(phi), rho * np.sin(phi), z])


def fit_view(points: ArrayLike, direction: ArrayLike, up: ArrayLike, *, aspect: float = 1.0,
             margin: float = VIEW_MARGIN, view_angle_deg: float = VIEW_ANGLE_DEG,
             iterations: int = 4) -> View:
    """The view from ``direction`` (unit vector from the scene towards the camera) in which
    all ``points`` project inside the image, ``margin`` (a fraction of the half-size) from
    its edges, as close as that allows (module step 3).

    The focal point is moved sideways to centre the projected extent, then the distance is
    solved exactly: a point at lateral offsets (x, y) and depth ``D - p.d`` is inside when
    ``|x| <= k_x (D - p.d)`` and ``|y| <= k_y (D - p.d)``, ``k = (1 - margin) tan(angle/2)``
    (times ``aspect`` for x).
    """
    pts = np.atleast_2d(np.asarray(points, float))
    d = _unit(direction)
    r = _unit(np.cross(-d, up))
    u = np.cross(r, -d)
    t = math.tan(math.radians(view_angle_deg) / 2) * (1 - margin)
    kx, ky = t * aspect, t
    c = pts.mean(axis=0)
    for _ in range(iterations):
        rel = pts - c
        x, y, depth = rel @ r, rel @ u, rel @ d
        dist = float(np.max(np.maximum(depth + np.abs(x) / kx, depth + np.abs(y) / ky)))
        # centre the projected extent: shift the focal point by the mid-offset at its depth
        ndc_x, ndc_y = x / ((dist - depth) * kx), y / ((dist - depth) * ky)
        mx = 0.5 * (ndc_x.max() + ndc_x.min())
        my = 0.5 * (ndc_y.max() + ndc_y.min())
        c = c + (mx * kx * r + my * ky * u) * dist
    rel = pts - c
    x, y, depth = rel @ r, rel @ u, rel @ d
    dist = float(np.max(np.maximum(depth + np.abs(x) / kx, depth + np.abs(y) / ky)))
    return View(position=c + dist * d, focal_point=c, up=u, view_angle_deg=view_angle_deg)


def body_view(body_centre: ArrayLike, radius: float, observer: ArrayLike, up: ArrayLike, *,
              fill: float = BODY_FILL, view_angle_deg: float = VIEW_ANGLE_DEG) -> View:
    """The view of a sphere from the observer's direction whose silhouette spans ``fill`` of
    the image height (module step 2, right panel): distance ``R / sin(fill * angle / 2)``."""
    c = np.asarray(body_centre, float)
    d = _unit(np.asarray(observer, float) - c)
    half = math.atan(fill * math.tan(math.radians(view_angle_deg) / 2))
    dist = radius / math.sin(half)
    u = _unit(np.asarray(up, float) - (np.asarray(up, float) @ d) * d)
    return View(position=c + dist * d, focal_point=c, up=u, view_angle_deg=view_angle_deg)


def overview_direction(points: ArrayLike, sun_tip: ArrayLike | None = None
                       ) -> tuple[FloatArray, FloatArray]:
    """(view direction, up) of the overview: from above the plane that best holds the scene
    (observer positions, Sun arrow tip, body centre at the origin), tilted ~35 deg along its
    long axis towards the Sun side (``sun_tip``, default the last point)."""
    pts = np.atleast_2d(np.asarray(points, float))
    centred = pts - pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred)
    if sv.size < 3 or sv[1] < 1e-9 * max(sv[0], 1e-300):
        normal, along = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    else:
        normal, along = vt[2], vt[0]
    sun_side = pts[-1] if sun_tip is None else np.asarray(sun_tip, float)
    if along @ sun_side < 0:  # look from the Sun's side (body at the origin): a lit body
        along, normal = -along, -normal
    d = _unit(0.82 * normal + 0.57 * along)
    return d, _unit(np.cross(d, along)) if np.linalg.norm(np.cross(d, along)) > 0 else normal


def frustum_corners(geom: Any, camera: Any, length: float) -> FloatArray:
    """The apex and the four far corners ``(5, 3)`` of a frame's frustum [km]: rays through
    the detector corners (pinhole intrinsics) cut at ``length`` along the boresight."""
    apex = np.asarray(geom.camera_position, float) / 1e3
    W, H = camera.width, camera.height
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    x = (corners[:, 0] - camera.cx) / camera.fx
    y = (corners[:, 1] - camera.cy) / camera.fy
    rays = np.column_stack([x, y, np.ones(4)]) * length
    return np.vstack([apex, apex + (geom.R_cam_to_inertial @ rays.T).T])


@dataclass(frozen=True)
class Layout:
    """Everything placed in the figure, in body-centred J2000 [km] (pure geometry, module
    steps 2-3)."""

    radius_km: float
    observers_km: FloatArray        # (n, 3) camera positions of the drawn frusta
    frusta_km: list[FloatArray]     # each (5, 3): apex + far corners
    path_km: FloatArray | None      # (m, 3) trajectory, or None for a static frame
    sun_dir: FloatArray             # unit, middle frame
    earth_dir: FloatArray | None
    arrow_km: float                 # arrow length
    overview: View
    close: View
    aspect: float                   # width / height of one panel

    @property
    def sun_tip_km(self) -> FloatArray:
        return self.arrow_km * self.sun_dir

    @property
    def close_arrow_km(self) -> float:
        """Sun arrow length in the close panel: from the centre to 1.6 radii."""
        return 1.6 * self.radius_km


def layout_scene(scene: Any, *, frusta: int = 8, frustum_fraction: float = 1.0,
                 aspect: float = 1.0) -> Layout:
    """Place the body, frusta, arrows and both views of ``scene`` (module steps 1-3)."""
    n = len(scene)
    idx = sorted({int(round(k)) for k in np.linspace(0, n - 1, min(frusta, n))})
    geoms = [scene.geometry(i) for i in idx]
    mid = scene.geometry(n // 2)
    R = mid.body_radius / 1e3
    fr = [frustum_corners(g, scene.camera, g.range / 1e3 * frustum_fraction) for g in geoms]
    observers = np.array([g.camera_position for g in geoms]) / 1e3
    path = earth = None
    if scene.trajectory is not None:
        moon = scene.ephemeris.state("moon", scene.trajectory.times, center="emb")
        path = (scene.trajectory.states[:, :3] - moon[:, :3]) / 1e3
        e_moon = scene.ephemeris.state("moon", scene.epochs, center="emb")
        earth = _unit(-e_moon[n // 2, :3])
    arrow = 0.5 * float(np.median(np.linalg.norm(observers, axis=1)))
    sun = _unit(mid.sun_direction)
    key = [sphere_points((0, 0, 0), R, 200), observers, *fr, arrow * sun[None, :]]
    if earth is not None:
        key.append(arrow * earth[None, :])
    if path is not None:
        key.append(path)
    key_pts = np.vstack(key)
    lo, hi = key_pts.min(axis=0), key_pts.max(axis=0)  # the labelled axes box around them
    box = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                    for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    key_pts = np.vstack([key_pts, box])
    direction, up = overview_direction(
        np.vstack([observers, np.zeros((1, 3)), arrow * sun[None, :]]
                  + ([] if path is None else [path])), arrow * sun)
    overview = fit_view(key_pts, direction, up, aspect=aspect, margin=OVERVIEW_MARGIN,
                        view_angle_deg=OVERVIEW_ANGLE_DEG)
    cam_up = mid.R_cam_to_inertial @ np.array([0.0, -1.0, 0.0])  # image "up": -v
    close = body_view((0, 0, 0), R, mid.camera_position / 1e3, cam_up)
    return Layout(R, observers, fr, path, sun, earth, arrow, overview, close, aspect)


# --------------------------------------------------------------------------- drawing
def _body_mesh(sc: Scenario, radius_km: float, pv: Any) -> Any:
    if sc.moon.shape == "mesh" and sc.target is None:
        m = icosphere_mesh(radius_km * 1e3, min(sc.moon.mesh_subdivisions, 6))
        faces = np.hstack([np.full((m.faces.shape[0], 1), 3), m.faces]).ravel()
        return pv.PolyData(m.vertices / 1e3, faces)
    return pv.Sphere(radius=radius_km, theta_resolution=120, phi_resolution=60)


def _frustum_lines(corners: FloatArray, pv: Any) -> tuple[Any, Any]:
    lines: list[int] = []
    for k in range(4):
        lines += [2, 0, k + 1, 2, k + 1, (k + 1) % 4 + 1]
    apex, far = corners[0], corners[1:].mean(axis=0)
    return pv.PolyData(corners, lines=np.array(lines)), pv.Line(apex, apex + 1.1 * (far - apex))


def _apply(pl: Any, view: View) -> None:
    pl.camera.position = tuple(view.position)
    pl.camera.focal_point = tuple(view.focal_point)
    pl.camera.up = tuple(view.up)
    pl.camera.view_angle = view.view_angle_deg
    pl.reset_camera_clipping_range()


def _arrow(pv: Any, direction: FloatArray, length: float) -> Any:
    return pv.Arrow(start=(0, 0, 0), direction=tuple(direction), scale=length,
                    shaft_radius=0.012, tip_radius=0.035, tip_length=0.12)


def render_scene(scenario: Scenario, out: str | os.PathLike[str], *, frusta: int = 8,
                 frustum_fraction: float = 1.0, window_size: tuple[int, int] = (1800, 900),
                 probe: bool = True) -> Path:
    """Draw the scenario into a two-panel PNG (module steps 1-4).

    Parameters
    ----------
    scenario : Scenario
    out : path
        PNG file (written atomically).
    frusta : int
        Number of camera frusta along the arc (>= 1).
    frustum_fraction : float
        Frustum length as a fraction of the range to the body centre [-].
    window_size : (width, height)
        Image size [px]; each panel is half the width.
    probe : bool
        Find the offscreen render window first (:func:`offscreen_window`); ``False`` uses
        VTK's default window.

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
    window = offscreen_window() if probe else None
    import pyvista as pv

    aspect = (window_size[0] / 2) / window_size[1]
    lay = layout_scene(scene, frusta=frusta, frustum_fraction=frustum_fraction, aspect=aspect)
    name = "Moon" if scenario.target is None or scenario.target.kind == "moon" \
        else scenario.target.name
    mid = scene.geometry(len(scene) // 2)
    cam = scene.camera
    R = lay.radius_km
    with _vtk_window(window):
        pv.OFF_SCREEN = True
        pl = pv.Plotter(off_screen=True, window_size=list(window_size), shape=(1, 2),
                        lighting="none", border=False)
    sun_light = dict(position=tuple(lay.sun_dir * 1e9), focal_point=(0, 0, 0),
                     light_type="scene light", intensity=0.9)
    body = _body_mesh(scenario, R, pv)
    body_kw = dict(color=BODY_COLOUR, smooth_shading=True, ambient=0.12, diffuse=0.95,
                   specular=0.0)
    # ---------------------------------------------------------------- overview
    pl.subplot(0, 0)
    pl.set_background(BACKGROUND)
    pl.add_light(pv.Light(**sun_light))
    pl.add_mesh(body, label=name, **body_kw)
    if lay.path_km is not None:
        pl.add_mesh(pv.lines_from_points(lay.path_km), color="#1f77b4", line_width=3,
                    label="trajectory", lighting=False)
    pl.add_points(lay.observers_km, color="black", point_size=9,
                  render_points_as_spheres=True, label="observer")
    for k, corners in enumerate(lay.frusta_km):
        fr, bore = _frustum_lines(corners, pv)
        pl.add_mesh(fr, color="#ff7f0e", line_width=2, lighting=False,
                    label="field of view" if k == 0 else None)
        pl.add_mesh(bore, color="#d62728", line_width=2, lighting=False,
                    label="boresight" if k == 0 else None)
    pl.add_mesh(_arrow(pv, lay.sun_dir, lay.arrow_km), color="#e6a800", lighting=False,
                label="Sun direction")
    tips, texts = [lay.sun_tip_km], ["Sun"]
    if lay.earth_dir is not None:
        pl.add_mesh(_arrow(pv, lay.earth_dir, lay.arrow_km), color="#2ca02c", lighting=False,
                    label="Earth direction")
        tips.append(lay.arrow_km * lay.earth_dir)
        texts.append("Earth")
    tips.append(lay.observers_km[len(lay.observers_km) // 2])
    texts.append("observer")
    pl.add_point_labels(np.array(tips), texts, font_size=16, text_color=TEXT_COLOUR,
                        shape=None, show_points=False, always_visible=True)
    pl.show_grid(xtitle="x J2000 [km]", ytitle="y J2000 [km]", ztitle="z J2000 [km]",
                 color="gray", font_size=10)
    pl.add_legend(bcolor="white", border=True, size=(0.26, 0.17), loc="lower right",
                  face="line")
    arc = (f"{len(scene)} frames, every {scenario.trajectory.cadence_s:g} s"
           if scenario.trajectory is not None else "one static frame")
    pl.add_text(f"Overview, {name}-centred J2000, to scale [km]: {arc}; {name} radius "
                f"{R:,.0f} km", font_size=11,
                color=TEXT_COLOUR, position="upper_left")
    _apply(pl, lay.overview)
    # ---------------------------------------------------------------- seen from the observer
    pl.subplot(0, 1)
    pl.set_background(BACKGROUND)
    pl.add_light(pv.Light(**sun_light))
    pl.add_mesh(body, **body_kw)
    pl.add_mesh(_arrow(pv, lay.sun_dir, lay.close_arrow_km), color="#e6a800",
                lighting=False)
    pl.add_point_labels(lay.close_arrow_km * lay.sun_dir[None, :], ["Sun"], font_size=16,
                        text_color=TEXT_COLOUR, shape=None, show_points=False,
                        always_visible=True)
    fov = 2 * math.degrees(math.atan(cam.width / 2 / cam.fx))
    pl.add_text(
        f"{name} seen from the observer (frame {mid.index}): range {mid.range / 1e3:,.0f} km, "
        f"phase {math.degrees(mid.phase_angle):.1f} deg\n"
        f"camera {cam.name}: {cam.width}x{cam.height} px, f {cam.focal_length * 1e3:.4g} mm, "
        f"FOV {fov:.1f} deg; the image's up is up", font_size=11, color=TEXT_COLOUR,
        position="upper_left")
    _apply(pl, lay.close)
    p = Path(out)
    with atomic_path(p, suffix=".png") as tmp:
        pl.screenshot(str(tmp))
    pl.close()
    log.info("wrote %s (%d frusta)", p, len(lay.frusta_km))
    return p
