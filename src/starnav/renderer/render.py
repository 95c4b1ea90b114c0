"""Radiometric spectral rendering of the Moon with Mitsuba 3.

The scene is built once in the Moon's body-fixed frame; a frame changes only the sensor pose
and the Sun direction. Each step in full: docs/methods.md, "starnav.renderer.render".

Technique
---------
1. One loaded scene serves every frame of a sequence (``mi.traverse`` moves sensor and Sun).
2. The Sun is a ``directional`` emitter of the tabulated solar spectrum at 1 AU, scaled by
   ``(1 AU / d_sun)^2`` afterwards.
3. The surface is a starnav photometric plugin (:mod:`.bsdfs`); the ``direct`` integrator
   gives the single-scattering radiance with cast shadows.
4. The ``specfilm`` integrates the band radiance ``L`` and the electron radiance ``Le`` in one
   pass; by default the wavelengths are drawn by the lit surface's electron spectrum.
5. Only the Moon's projected bounding box is traced (crop window).
6. One ray through each pixel centre gives the geometric channels (AOVs).
7. On the JIT variants one compiled wavefront loop serves every frame (:func:`_render_fused`).
8. ``adaptive``: the pixel-centre rays decide each pixel's sample count
   (:func:`adaptive_sample_counts`); every pixel stays an unbiased mean.
9. The Earth's shadow multiplies each pixel by the visible fraction of the solar disc
   (:mod:`starnav.eclipse`).

The knobs are :class:`RenderSettings` (scenario: ``renderer.schema.RenderConfig``); what is
drawn is the body's :class:`~starnav.bodies.model.TargetModel`.

Index
-----
:class:`MoonRenderer`, :class:`RenderSettings`, :func:`moon_bounding_box`,
:func:`adaptive_sample_counts`, :class:`AdaptivePlan`, :class:`AovFrame`, :data:`SAMPLERS`,
:data:`SPECTRAL_SAMPLINGS`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.bodies.mesh import BodyMesh
from starnav.bodies.model import AlbedoMap, TargetModel
from starnav.camera import Camera
from starnav.constants import AU
from starnav.eclipse import could_be_eclipsed, disc_mean_sunlit_fraction, sunlit_fraction
from starnav.errors import ConfigError
from starnav.geometry import FrameGeometry, geometry_to_dict
from starnav.photometry import validity_warning
from starnav.radiance import AOV_CHANNELS, BODY_FIXED_AOV_CHANNELS, RadianceImage
from starnav.renderer import backend
from starnav.renderer.scene import (
    FAR_CLIP_KM,
    KM,
    NEAR_CLIP_MIN_KM,
    FilmChannels,
    check_camera_for_render,
    clip_planes,
    film_channels,
    flat_irradiance_in_band,
    principal_point_offsets,
    regular_spectrum_dict,
    sensor_fov_deg,
    sun_irradiance_in_band,
    to_world_matrix,
)
from starnav.renderer.schema import DEFAULT_INTERIOR_SPP
from starnav.spectra import SensorResponse, Spectrum, band_integrals, product

log = logging.getLogger(__name__)


#: Mitsuba samplers allowed for the radiance pass. Jittered strata (``multijitter``,
#: ``stratified``) cut the per-pixel noise at 16 spp from 2.1 % (``independent``) to 0.7 %
#: at the same cost (measured on the default frame); all are unbiased.
SAMPLERS = ("multijitter", "stratified", "independent", "ldsampler")
#: How the film draws each sample's wavelengths: ``electrons``, by the spectrum of the
#: electrons the lit surface gives (Sun x surface colour x QE T lambda / hc: no spectral
#: noise; :func:`~starnav.renderer.scene.film_channels`); or ``response``, by the sensor's
#: band box plus its electron response (the emitter carries the solar spectrum, the BSDF the
#: colour: the reference the other is tested against).
SPECTRAL_SAMPLINGS = ("electrons", "response")

#: Relative spread of the pixel-centre radiance proxy over a pixel's 3 x 3 neighbourhood,
#: ``(max - min) / max``, above which the adaptive render gives the pixel the full ``spp``
#: (:func:`adaptive_sample_counts`: below it, the noise at 4 spp does not depend on it).
ADAPTIVE_SPREAD = 0.3


@dataclass(frozen=True)
class RenderSettings:
    """Rendering knobs, SI; each is declared with its meaning in
    :class:`~starnav.renderer.schema.RenderConfig`."""

    spp: int = 16
    crop: bool = True
    crop_margin_px: float = 4.0
    aovs: bool = True
    variants: tuple[str, ...] = ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")
    sampler: str = "multijitter"
    wavelength_step_nm: float = 1.0
    fused_loop: bool = True
    adaptive: bool = True
    interior_spp: int | None = None
    spectral_sampling: str = "electrons"
    earth_shadow: bool = True
    sun_limb_darkening: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.earth_shadow, bool)):
            raise ConfigError("render.earth_shadow", self.earth_shadow, "true or false")
        if not 0.0 <= self.sun_limb_darkening <= 1.0:
            raise ConfigError("render.sun_limb_darkening", self.sun_limb_darkening,
                              "a coefficient in [0, 1]")
        if self.spectral_sampling not in SPECTRAL_SAMPLINGS:
            raise ConfigError("render.spectral_sampling", self.spectral_sampling,
                              f"one of {SPECTRAL_SAMPLINGS}")
        if not (math.isfinite(self.wavelength_step_nm) and 0 < self.wavelength_step_nm <= 50):
            raise ConfigError("render.wavelength_step_nm", self.wavelength_step_nm,
                              "a grid step in (0, 50] nm")
        if self.sampler not in SAMPLERS:
            raise ConfigError("render.sampler", self.sampler, f"one of {SAMPLERS}")
        if int(self.spp) != self.spp or self.spp < 1:
            raise ConfigError("render.spp", self.spp, "an integer >= 1")
        if not (self.crop_margin_px >= 0):
            raise ConfigError("render.crop_margin_px", self.crop_margin_px, "a margin >= 0 px")
        if not isinstance(self.adaptive, bool):
            raise ConfigError("render.adaptive", self.adaptive, "true or false")
        if self.interior_spp is None:
            return
        if (isinstance(self.interior_spp, bool) or int(self.interior_spp) != self.interior_spp
                or self.interior_spp < 1):
            raise ConfigError("render.interior_spp", self.interior_spp, "an integer >= 1")
        if self.adaptive and self.interior_spp > self.spp:
            raise ConfigError("render.interior_spp", self.interior_spp,
                              f"at most render.spp = {self.spp} with render.adaptive on (the "
                              f"samples of an interior pixel, fewer than a full pixel's)")

    @property
    def interior_samples(self) -> int:
        """Samples of a flat interior pixel of the adaptive render: ``interior_spp``, or
        :data:`~starnav.renderer.schema.DEFAULT_INTERIOR_SPP` (at most ``spp``) when unset."""
        if self.interior_spp is None:
            return min(DEFAULT_INTERIOR_SPP, int(self.spp))
        return int(self.interior_spp)


# ---------------------------------------------------------------------------- crop window
def moon_bounding_box(camera: Camera, geom: FrameGeometry, radius: float, margin_px: float
                      ) -> tuple[int, int, int, int] | None:
    """Pixel box ``(u0, v0, width, height)`` covering the projected sphere of ``radius`` [m]
    plus ``margin_px``; the whole frame if the sphere reaches behind the camera; ``None`` if
    the sphere is entirely outside the field."""
    c_cam = geom.moon_centre_camera()
    d = float(np.linalg.norm(c_cam))
    W, H = camera.width, camera.height
    if d <= radius * 1.0000001:
        return (0, 0, W, H)
    sin_rho = radius / d
    cos_rho = math.sqrt(1.0 - sin_rho * sin_rho)
    ch = c_cam / d
    # If any point of the cone reaches z <= small, fall back to the whole frame.
    # Angle between the boresight and the centre direction:
    cos_b = ch[2]
    beta = math.acos(max(-1.0, min(1.0, cos_b)))
    rho = math.asin(sin_rho)
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    corner_rays = camera.unproject(corners, undistort=False)
    half_diag = float(np.max(np.arccos(np.clip(corner_rays[:, 2], -1.0, 1.0))))
    if beta - rho > half_diag + margin_px * camera.ifov:
        return None
    if beta + rho >= math.radians(89.0):
        if beta - rho >= math.radians(89.0):
            return None
        return (0, 0, W, H)
    a = np.cross(ch, [0.0, 0.0, 1.0] if abs(ch[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(ch, a)
    t = np.linspace(0.0, 2 * math.pi, 256, endpoint=False)
    rays = cos_rho * ch + sin_rho * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    # the projected cone boundary is a conic; sampling 256 points plus 1 px covers chord sag
    uv = camera.project(rays, distort=False)
    m = margin_px + 1.0
    u0 = math.floor(uv[:, 0].min() - m + 0.5)
    u1 = math.ceil(uv[:, 0].max() + m + 0.5)
    v0 = math.floor(uv[:, 1].min() - m + 0.5)
    v1 = math.ceil(uv[:, 1].max() + m + 0.5)
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, W), min(v1, H)
    if u1 <= u0 or v1 <= v0:
        return None
    return (int(u0), int(v0), int(u1 - u0), int(v1 - v0))


# ---------------------------------------------------------------------------- the renderer
class MoonRenderer:
    """Renders :class:`~starnav.geometry.FrameGeometry` frames into RadianceImages.

    Parameters
    ----------
    camera : Camera
        Pinhole camera (distortion is applied later, by the detector chain).
    response : SensorResponse
        QE x T of the sensor.
    sun_1au : Spectrum
        Solar spectral irradiance at 1 AU [W m^-2 nm^-1].
    moon : TargetModel
        Shape, photometry and albedo.
    settings : RenderSettings
        Samples per pixel, crop, AOVs, variant preference.
    """

    def __init__(self, camera: Camera, response: SensorResponse, sun_1au: Spectrum,
                 moon: TargetModel, settings: RenderSettings | None = None) -> None:
        check_camera_for_render(camera)
        self.camera = camera
        self.response = response
        self.sun_1au = sun_1au
        self.moon = moon
        self.settings = settings or RenderSettings()
        self.band_1au = band_integrals(sun_1au, response)
        self._scene = None
        self._scene_key: Any = None
        self._mesh_key_ref: Any = None
        self.last_timing: dict[str, float] = {}
        #: Samples per pixel of the last frame, (H, W) int32, when it was rendered adaptively
        #: (``render.adaptive`` on a JIT variant); ``None`` otherwise (``spp`` everywhere in
        #: the crop window).
        self.last_sample_counts: NDArray[np.int32] | None = None
        self._warned: set[str] = set()
        self._clip: dict[int, tuple[float, float]] = {}
        self._crop: dict[int, tuple[int, int, int, int]] = {}
        self._spectra: dict[Any, tuple[Spectrum, dict]] = {}
        # spectra derived per spectral sampling, keyed by the identities of their inputs
        # (kept alive next to each entry): the same objects every frame, so that
        # _spectrum_dict formats each once
        self._derived: dict[Any, tuple[Any, tuple]] = {}

    def _memo(self, key: tuple, make: Callable[[], Any], inputs: tuple) -> Any:
        full = (*key, *(id(x) for x in inputs))
        if full not in self._derived:
            self._derived[full] = (make(), inputs)
        return self._derived[full][0]

    @property
    def channels(self) -> FilmChannels:
        """The film's two responses for the current ``settings.spectral_sampling``."""
        shape = self.moon.spectral_shape
        if self.settings.spectral_sampling == "response":
            return self._memo(("channels", "response"),
                              lambda: film_channels(self.response), (self.response,))
        return self._memo(
            ("channels", "electrons"),
            lambda: film_channels(self.response, self.sun_1au if shape is None
                                  else product(self.sun_1au, shape)),
            (self.response, self.sun_1au, shape))

    def _emitter_irradiance(self) -> Spectrum:
        """The Sun emitter's spectrum: flat when the film carries the solar spectrum."""
        if self.settings.spectral_sampling == "electrons":
            return self._memo(("emitter", "electrons"),
                              lambda: flat_irradiance_in_band(self.response), (self.response,))
        return self._memo(("emitter", "response"),
                          lambda: sun_irradiance_in_band(self.sun_1au, self.response),
                          (self.response, self.sun_1au))

    # .................................................................. backend / scene
    @property
    def scene(self) -> Any:
        """The loaded Mitsuba scene of the last frame (``None`` before the first)."""
        return self._scene

    def _activate(self):
        return backend.activate(self.settings.variants)

    def _albedo_texture(self, mesh: BodyMesh | None) -> dict:
        import mitsuba as mi

        moon = self.moon
        if mesh is not None and (mesh.albedo is not None or isinstance(moon.albedo, AlbedoMap)):
            return {"type": "mesh_attribute", "name": "vertex_albedo"}
        if isinstance(moon.albedo, AlbedoMap):
            arr = np.ascontiguousarray(moon.albedo.values[:, :, None], dtype=np.float32)
            return {
                "type": "bitmap",
                "bitmap": mi.Bitmap(arr),
                "raw": True,
                "filter_type": "bilinear",
                "wrap_mode": "repeat",
                # Mitsuba's sphere has u = lon / 2pi with lon in [0, 2pi); the map starts at
                # -180 deg: shift u by one half.
                "to_uv": mi.ScalarTransform4f().translate([0.5, 0.0, 0.0]),
            }
        return {"type": "uniform", "value": float(moon.albedo)}

    def _mitsuba_mesh(self, mesh: BodyMesh, bsdf: dict):
        import drjit as dr
        import mitsuba as mi

        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf)
        m = mi.Mesh("moon", int(mesh.vertices.shape[0]), int(mesh.faces.shape[0]), props=props,
                    has_vertex_normals=True)
        params = mi.traverse(m)
        params["vertex_positions"] = dr.ravel(mi.TensorXf(
            (mesh.vertices / KM).astype(np.float32)))
        params["faces"] = dr.ravel(mi.TensorXu(mesh.faces.astype(np.uint32)))
        params["vertex_normals"] = dr.ravel(mi.TensorXf(mesh.normals.astype(np.float32)))
        params.update()
        if mesh.albedo is not None or isinstance(self.moon.albedo, AlbedoMap):
            m.add_attribute("vertex_albedo", 1,
                            mi.Float(self._vertex_albedo(mesh).astype(np.float32)))
        return m

    def surface(self, geom: FrameGeometry) -> tuple[BodyMesh, NDArray[np.float64]] | None:
        """The triangle surface this renderer puts in frame ``geom``'s scene, to export it to
        another engine (``benchmarks/render.py --cycles-python`` hands it to Blender Cycles).

        Returns
        -------
        (mesh, albedo) or None
            The body-fixed mesh [m] as rendered (for a ``mesh_provider`` the view mesh of this
            frame) and the albedo parameter of the photometric model at each vertex, with
            ``albedo_scale`` applied: the mesh's own albedo, the albedo map bilinearly
            sampled at the vertices (the renderer interpolates these values over each
            triangle), or the uniform albedo. ``None`` for ``shape: sphere`` (the exact
            sphere is an analytic primitive, not triangles).
        """
        mesh, _ = self._mesh(geom)
        if mesh is None:
            return None
        moon = self.moon
        if mesh.albedo is not None or isinstance(moon.albedo, AlbedoMap):
            albedo = self._vertex_albedo(mesh)
        else:
            albedo = np.full(len(mesh.vertices), float(moon.albedo))
        return mesh, albedo * float(moon.albedo_scale)

    def _vertex_albedo(self, mesh: BodyMesh) -> NDArray[np.float64]:
        """The albedo parameter per vertex: the mesh's own, or the map's at the vertices."""
        if mesh.albedo is not None:
            return np.asarray(mesh.albedo, float)
        v = mesh.vertices
        r = np.linalg.norm(v, axis=1)
        lat = np.arcsin(np.clip(v[:, 2] / r, -1, 1))
        lon = np.arctan2(v[:, 1], v[:, 0])
        return self.moon.albedo.sample(lat, lon)

    def _build_scene(self, mesh: BodyMesh | None):
        import mitsuba as mi

        from starnav.renderer.bsdfs import PLUGIN_NAMES  # lazy: mitsuba (bsdfs imports it)

        cam = self.camera
        bsdf = {"type": PLUGIN_NAMES[self.moon.model], "albedo": self._albedo_texture(mesh),
                "scale": float(self.moon.albedo_scale)}
        if self.moon.spectral_shape is not None and self.settings.spectral_sampling == "response":
            bsdf["spectral_shape"] = self._spectrum_dict("shape", self.moon.spectral_shape)
        if self.moon.model == "hapke":
            bsdf.update(self.moon.params)
        if mesh is None:
            moon_shape: Any = {
                "type": "sphere",
                "radius": self.moon.radius / KM,
                "bsdf": bsdf,
            }
        else:
            moon_shape = self._mitsuba_mesh(mesh, bsdf)
        px, py = principal_point_offsets(cam)
        common = {
            "type": "perspective",
            "fov": sensor_fov_deg(cam),
            "fov_axis": "x",
            "principal_point_offset_x": px,
            "principal_point_offset_y": py,
            # both clip planes are set per frame in render() (see scene.clip_planes)
            "near_clip": NEAR_CLIP_MIN_KM,
            "far_clip": FAR_CLIP_KM,
            "to_world": mi.ScalarTransform4f(np.eye(4)),
        }
        ch = self.channels
        radiance_sensor = dict(common)
        radiance_sensor.update({
            "sampler": {"type": self.settings.sampler, "sample_count": self.settings.spp},
            "film": {
                "type": "specfilm",
                "width": cam.width,
                "height": cam.height,
                "rfilter": {"type": "box"},
                "L": self._spectrum_dict("L", ch.L),
                "Le": self._spectrum_dict("Le", ch.Le),
            },
        })
        aov_sensor = dict(common)
        aov_sensor.update({
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        })
        sun = self._emitter_irradiance()
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
            "sun": {"type": "directional", "direction": [0.0, 0.0, 1.0],
                    "irradiance": self._spectrum_dict("sun", sun)},
            "moon": moon_shape,
            "sensor": radiance_sensor,
            "sensor_aov": aov_sensor,
        })
        self._aov_integrator = mi.load_dict({
            "type": "aov", "aovs": "pp:position,nn:sh_normal"})
        return scene

    def _spectrum_dict(self, name: str, sp: Spectrum) -> dict:
        """:func:`regular_spectrum_dict` of ``sp``, formatted once per renderer (the scene is
        rebuilt for every view-adapted mesh)."""
        key = (name, id(sp), self.settings.wavelength_step_nm)
        if key not in self._spectra:
            self._spectra[key] = (sp, regular_spectrum_dict(sp, self.settings.wavelength_step_nm))
        return dict(self._spectra[key][1])

    def _scene_for(self, mesh: BodyMesh | None, mesh_key: Any):
        info = self._activate()
        key = (info.variant, mesh_key, self.moon.model, tuple(sorted(self.moon.params.items())),
               self.moon.albedo_key(), self.settings.spp, self.settings.sampler,
               self.settings.wavelength_step_nm, self.settings.spectral_sampling,
               id(self.moon.spectral_shape))   # the film (electrons) or the BSDF carries it
        if self._scene is None or key != self._scene_key:
            t0 = time.perf_counter()
            self._scene = self._build_scene(mesh)
            self._scene_key = key
            self.last_timing["scene_build_s"] = time.perf_counter() - t0
        return self._scene, info

    # .................................................................. mesh choice
    def _mesh(self, geom: FrameGeometry) -> tuple[BodyMesh | None, Any]:
        moon = self.moon
        if moon.shape == "sphere":
            return None, "sphere"
        if moon.mesh is not None:
            return moon.mesh, ("mesh", id(moon.mesh))
        mesh = moon.mesh_provider(self.camera, geom)
        # the provider's key (e.g. the cached trimesh object) says when the mesh is the same;
        # the renderer holds a reference to it, so its id cannot be recycled meanwhile
        self._mesh_key_ref = mesh.key if mesh.key is not None else mesh
        return mesh, ("mesh", id(self._mesh_key_ref))

    def _check_validity(self, geom: FrameGeometry) -> None:
        """Log once per renderer each way the photometric model is outside its validity."""
        why = validity_warning(self.moon.model, geom.phase_angle, self.moon.calibrated)
        if why is not None:
            key = why.split(" at phase")[0]
            if key not in self._warned:
                self._warned.add(key)
                log.warning("%s (first frame: %d; reported once)", why, geom.index)

    # .................................................................. render
    def render(self, geom: FrameGeometry, seed: int = 0) -> RadianceImage:
        """Render one frame; ``seed`` seeds Mitsuba's sampler (deterministic per seed)."""
        import drjit as dr
        import mitsuba as mi

        t_start = time.perf_counter()
        self.last_timing = {}
        cam = self.camera
        W, H = cam.width, cam.height
        L = np.zeros((H, W), np.float32)
        Le = np.zeros((H, W), np.float32)
        aovs: dict[str, NDArray[np.float32]] = {}
        sample_counts: NDArray[np.int32] | None = None
        eclipse_meta: dict[str, Any] | None = None
        box = moon_bounding_box(cam, geom, self.moon.radius + self.moon.max_height,
                                self.settings.crop_margin_px)
        if box is not None and not self.settings.crop:
            box = (0, 0, W, H)
        self._check_validity(geom)
        t0 = time.perf_counter()
        mesh, mesh_key = self._mesh(geom)
        self.last_timing["mesh_s"] = time.perf_counter() - t0
        scene, info = self._scene_for(mesh, mesh_key)
        sun_scale = (AU / geom.sun_distance) ** 2
        if box is not None:
            u0, v0, bw, bh = box
            R_body = geom.R_body_to_inertial
            # everything in the Moon body-fixed frame
            pos_b = R_body.T @ geom.camera_position
            R_cam_b = R_body.T @ geom.R_cam_to_inertial
            body_geom = FrameGeometry(pos_b, R_cam_b, R_body.T @ geom.sun_position,
                                      body_radius=geom.body_radius)
            M = to_world_matrix(body_geom)
            T = mi.ScalarTransform4f(M)
            sun_dir_b = body_geom.sun_direction
            params = mi.traverse(scene)
            params["sensor.to_world"] = T
            params["sensor_aov.to_world"] = T
            params["sun.to_world"] = mi.ScalarTransform4f().look_at(
                origin=[0.0, 0.0, 0.0], target=(-sun_dir_b).tolist(),
                up=_any_perpendicular(sun_dir_b).tolist())
            # rays start on the near plane, put just in front of the Moon: float32 hit points
            # from a far ray origin would shadow themselves (scene.py module docstring)
            r_b = self.moon.radius + self.moon.max_height
            if mesh is not None:
                r_b = max(r_b, mesh.bounding_radius)
            clip = clip_planes(geom.moon_centre_camera(), r_b)
            # the clip distances are literals in the compiled kernels: touching them (even with
            # the same value) recompiles, so they are set only when they change
            fused = self.settings.fused_loop and dr.is_jit_v(mi.Float)
            near_shift = 0.0
            if fused:
                # the fused loop moves the ray origins to the near plane itself and traces the
                # crop on a full-frame film: both stay out of the compiled kernels
                near_shift = clip[0] - NEAR_CLIP_MIN_KM
                clip = (NEAR_CLIP_MIN_KM, clip[1])
            set_clip = clip != self._clip.get(id(scene))
            crop = (0, 0, W, H) if fused else box
            set_crop = crop != self._crop.get(id(scene))
            for name in ("sensor", "sensor_aov"):
                if set_crop:
                    params[f"{name}.film.crop_offset"] = mi.ScalarPoint2u(crop[0], crop[1])
                    params[f"{name}.film.crop_size"] = mi.ScalarVector2u(crop[2], crop[3])
                if set_clip:
                    params[f"{name}.near_clip"] = clip[0]
                    params[f"{name}.far_clip"] = clip[1]
            self._clip = {id(scene): clip}
            self._crop = {id(scene): crop}
            params.update()
            t0 = time.perf_counter()
            if fused:
                frame = None
                if self.settings.aovs:
                    frame = AovFrame(R_body, pos_b, body_geom.sun_position,
                                     self.moon.body_fixed_aovs)
                plan = None
                if self.settings.adaptive:
                    plan = AdaptivePlan(self.settings.interior_samples, r_b / KM,
                                        max(1.0 / cam.fx, 1.0 / cam.fy))
                img, crop_aovs, counts = _render_fused(
                    scene, box, int(seed) & 0xFFFFFFFF, self.settings.spp, frame, near_shift,
                    M[:3, 2], plan, self.last_timing)
                self.last_timing["radiance_s"] = time.perf_counter() - t0
                if counts is not None:
                    sample_counts = np.zeros((H, W), np.int32)
                    sample_counts[v0:v0 + bh, u0:u0 + bw] = counts
                raw = None
                if crop_aovs is not None:
                    t0 = time.perf_counter()
                    # one (channels, H, W) block: the channels are views of it
                    block = np.zeros((len(crop_aovs), H, W), np.float32)
                    for c, v in enumerate(crop_aovs.values()):
                        block[c, v0:v0 + bh, u0:u0 + bw] = v
                    aovs = dict(zip(crop_aovs, block, strict=True))
                    self.last_timing["aov_numpy_s"] = time.perf_counter() - t0
            else:
                img = np.asarray(mi.render(scene, sensor=0, seed=int(seed) & 0xFFFFFFFF,
                                           spp=self.settings.spp))
                self.last_timing["radiance_s"] = time.perf_counter() - t0
                raw = None
                if self.settings.aovs:
                    t0 = time.perf_counter()
                    raw = np.asarray(mi.render(scene, sensor=1, integrator=self._aov_integrator,
                                               seed=0, spp=1))
                    self.last_timing["aov_s"] = time.perf_counter() - t0
            ch = self.channels
            img = img.astype(np.float64)
            L[v0:v0 + bh, u0:u0 + bw] = img[:, :, 0] * ch.scale_L * sun_scale
            Le[v0:v0 + bh, u0:u0 + bw] = img[:, :, 1] * ch.scale_Le * sun_scale
            # the Earth's shadow: only a frame that can be in it is touched (outside, the
            # render is bit for bit the one without the model)
            eclipse = self._earth_shadow(geom, box)
            if eclipse is not None:
                factor, eclipse_meta = eclipse
                L[v0:v0 + bh, u0:u0 + bw] *= factor
                Le[v0:v0 + bh, u0:u0 + bw] *= factor
            if raw is not None:
                t0 = time.perf_counter()
                aovs = _aov_channels(raw, geom, box, (H, W),
                                     body_fixed=self.moon.body_fixed_aovs)
                self.last_timing["aov_numpy_s"] = time.perf_counter() - t0
        if self.settings.aovs and not aovs:
            names = AOV_CHANNELS + (BODY_FIXED_AOV_CHANNELS if self.moon.body_fixed_aovs
                                    else ())
            aovs = {k: np.zeros((H, W), np.float32) for k in names}
        self.last_timing["total_s"] = time.perf_counter() - t_start
        self.last_sample_counts = sample_counts
        band = band_integrals(self.sun_1au.scaled(sun_scale), self.response)
        meta = {
            "geometry": geometry_to_dict(geom),
            "camera": cam.describe() | {"cx": cam.cx, "cy": cam.cy, "k1": cam.k1, "k2": cam.k2,
                                        "k3": cam.k3, "p1": cam.p1, "p2": cam.p2,
                                        "pitch_x_m": cam.pitch_x, "pitch_y_m": cam.pitch_y,
                                        "focal_length_m": cam.focal_length},
            "sun": {
                "band_irradiance_w_m2": band.irradiance,
                "band_electron_irradiance_e_s_m2": band.electron_irradiance,
                "band_irradiance_1au_w_m2": self.band_1au.irradiance,
                "band_electron_irradiance_1au_e_s_m2": self.band_1au.electron_irradiance,
                "band_nm": list(band.band_nm),
                "distance_m": geom.sun_distance,
            },
            "moon": {
                "shape": self.moon.shape,
                "radius_m": self.moon.radius,
                "photometric_model": self.moon.model,
                "params": self.moon.params,
                "albedo": (self.moon.albedo.source if isinstance(self.moon.albedo, AlbedoMap)
                           else float(self.moon.albedo)),
                "albedo_scale": self.moon.albedo_scale,
                "spectral_shape": "grey" if self.moon.spectral_shape is None else "rolo",
                "triangles": None if mesh is None else mesh.n_triangles,
            },
            "render": {
                "variant": info.variant,
                "llvm_path": info.llvm_path,
                "llvm_target": info.llvm_target,
                "mitsuba_version": info.mitsuba_version,
                "drjit_version": info.drjit_version,
                "spp": self.settings.spp,
                "spectral_sampling": self.settings.spectral_sampling,
                "seed": int(seed),
                "crop_box_uvwh": None if box is None else list(box),
                "units": {"L": "W m^-2 sr^-1", "Le": "e- s^-1 m^-2 sr^-1", "range": "m",
                          "lat": "rad", "lon": "rad", "incidence": "rad", "emission": "rad",
                          "phase": "rad"},
            },
        }
        if sample_counts is not None:
            # only adaptive frames carry the key: the metadata of the others is as pinned
            meta["render"]["adaptive"] = _sample_summary(sample_counts, self.settings)
        if eclipse_meta is not None:
            # only frames the Earth's shadow can reach carry the key
            meta["eclipse"] = eclipse_meta
        return RadianceImage(L, Le, aovs, meta)

    def _earth_shadow(self, geom: FrameGeometry, box: tuple[int, int, int, int]
                      ) -> tuple[NDArray[np.float32], dict[str, Any]] | None:
        """Per-pixel sunlit fraction of the crop window (:mod:`starnav.eclipse`), or None when
        the body is wholly outside the Earth's penumbra (or no Earth, or the model is off).

        The radiance of one distant Sun is proportional to its irradiance, so the shadow is a
        factor on the rendered radiance: the fraction seen from the reference sphere's point
        under each pixel centre (the tangent point for a ray beside it). It changes over
        thousands of km (the penumbra is ~3 600 km wide at the Moon), a pixel's footprint is
        tens of km: constant over a pixel; cast shadows and terrain are the render's.
        """
        if not self.settings.earth_shadow or geom.earth_position is None:
            return None
        radius = self.moon.radius + self.moon.max_height
        if not could_be_eclipsed(radius, geom.sun_position, geom.earth_position):
            return None
        cam = self.camera
        u0, v0, bw, bh = box
        uu, vv = np.meshgrid(np.arange(u0, u0 + bw, dtype=float),
                             np.arange(v0, v0 + bh, dtype=float))
        rays = cam.unproject(np.stack([uu.ravel(), vv.ravel()], axis=1))
        d = rays @ np.asarray(geom.R_cam_to_inertial, float).T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.asarray(geom.camera_position, float)
        R = float(self.moon.radius)
        b = d @ o
        disc = b * b - (o @ o - R * R)
        t = np.where(disc >= 0.0, -b - np.sqrt(np.maximum(disc, 0.0)), -b)
        p = o[None, :] + t[:, None] * d
        p *= (R / np.linalg.norm(p, axis=1))[:, None]
        u = self.settings.sun_limb_darkening
        frac = sunlit_fraction(p, geom.sun_position, geom.earth_position, u)
        factor = frac.reshape(bh, bw).astype(np.float32)
        mean = disc_mean_sunlit_fraction(geom.camera_position, R, geom.sun_position,
                                         geom.earth_position, u)
        if mean < 1.0:
            log.warning("frame %d is in the Earth's shadow: %.4f of the sunlight on its visible "
                        "disc on average (min %.4f)", geom.index, mean, float(frac.min()))
        meta = {"disc_mean_sunlit_fraction": mean, "min_sunlit_fraction": float(frac.min()),
                "sun_limb_darkening": u,
                "model": "solar disc occulted by the Earth (radius + 1/85), no refracted "
                         "light in the umbra"}
        return factor, meta


def _sample_summary(counts: NDArray[np.int32], settings: RenderSettings) -> dict[str, Any]:
    """The metadata ``render.adaptive`` of an adaptive frame's sample counts. A frame without
    it has ``spp`` in every pixel of the crop window: the non-adaptive render, also when
    ``render.adaptive`` is asked for on the scalar variant or with ``fused_loop`` off."""
    n_full = int(np.count_nonzero(counts == settings.spp))
    n_any = int(np.count_nonzero(counts))
    return {
        "spp_full": int(settings.spp),
        "spp_interior": settings.interior_samples,
        "pixels_full": n_full,
        "pixels_interior": n_any - n_full if settings.interior_samples != settings.spp else 0,
        "fraction_full": n_full / n_any if n_any else 0.0,
        "samples": int(counts.sum(dtype=np.int64)),
        "spread": ADAPTIVE_SPREAD,
    }


@dataclass(frozen=True)
class AovFrame:
    """What the geometric channels need besides the hit points: the Moon's attitude
    (body-fixed to inertial), the camera and the Sun in the body-fixed frame [m]."""

    R_body_to_inertial: NDArray[np.float64]
    camera_body: NDArray[np.float64]
    sun_body: NDArray[np.float64]
    body_fixed: bool = False


class _CropRays:
    """The rays of a crop ``box`` on the full-frame film, as the fused loops trace them
    (:func:`_render_fused`, :func:`_render_adaptive`): the crop's origin and width and the
    near-plane shift enter the kernels as opaque data (one compiled kernel per pass serves
    every frame), film coordinates are the whole frame's (the film's crop stays the full
    frame: Mitsuba's sensor folds the crop into literals of its sample-to-camera transform)."""

    def __init__(self, scene, box: tuple[int, int, int, int], near_shift: float,
                 boresight: NDArray[np.float64] | None) -> None:
        import mitsuba as mi

        self.sensor = scene.sensors()[0]
        self.film = self.sensor.film()
        # sets the film's channels (L, Le, weight) that prepare_sample writes, as mi.render
        if self.film.prepare([]) != 3:
            raise RuntimeError(f"specfilm has {self.film.prepare([])} channels, expected L, "
                               "Le, W")
        self.sampler = self.sensor.sampler()
        self.scene = scene
        u0, v0, bw, _ = box
        i32 = _uniforms(mi.Int32, [bw, u0, v0])
        axis = np.zeros(3) if boresight is None else np.asarray(boresight, float)
        f32 = _uniforms(mi.Float, [near_shift, *axis.tolist()])
        self._shift, self._axis = f32[0], mi.Vector3f(f32[1], f32[2], f32[3])
        self._near_shift = near_shift
        self._width, self._origin = i32[0], mi.Vector2i(i32[1], i32[2])
        frame = self.film.size()
        self._inv_size = mi.ScalarVector2f(1.0 / frame[0], 1.0 / frame[1])

    def to_near_plane(self, ray):
        """``ray`` started on the frame's near plane instead of the sensor's."""
        import drjit as dr

        if self._near_shift == 0.0:
            return ray
        t = self._shift / dr.dot(ray.d, self._axis)
        ray.o = dr.fma(ray.d, t, ray.o)
        ray.maxt = ray.maxt - t
        return ray

    def pixel(self, idx):
        """Pixel (column, row) of the crop's pixel index ``idx``, in frame pixels."""
        import mitsuba as mi

        i = mi.Int32(idx)
        row = i // self._width
        return mi.Vector2f(mi.Vector2i(i - self._width * row, row) + self._origin)

    def centre_rays(self, n_pixels: int):
        """The pixel-centre rays of the crop's ``n_pixels`` pixels, from the sensor (not yet
        on the near plane): Mitsuba's 1-spp non-jittered stratified sample is at +0.5."""
        import drjit as dr
        import mitsuba as mi

        centre = self.pixel(dr.arange(mi.UInt32, n_pixels)) + 0.5
        ray, _ = self.sensor.sample_ray(0.0, 0.5, centre * self._inv_size, mi.Point2f(0.5))
        return ray

    def radiance(self, pixel_of_sample, slot, n_slots: int) -> list:
        """One radiance sample per entry of ``pixel_of_sample`` (crop pixel indices; the
        sampler seeded for them), the film's ``L`` and ``Le`` channels summed per ``slot``
        into ``n_slots`` accumulators (box filter, every sample of weight 1, accumulated in
        the kernel as Mitsuba's image block does)."""
        import drjit as dr
        import mitsuba as mi

        sample_pos = self.pixel(pixel_of_sample) + self.sampler.next_2d()
        wavelength_sample = self.sampler.next_1d()
        ray, ray_weight = self.sensor.sample_ray(
            0.0, wavelength_sample, sample_pos * self._inv_size, mi.Point2f(0.5))
        ray = self.to_near_plane(ray)
        spec, valid = _direct_lighting(self.scene, self.sampler, mi.RayDifferential3f(ray))
        channels = self.film.prepare_sample(ray_weight * spec, ray.wavelengths, 3, 1.0,
                                            dr.select(valid, 1.0, 0.0), valid)
        out = []
        for c in channels[:2]:
            acc = dr.zeros(mi.Float, n_slots)
            dr.scatter_reduce(dr.ReduceOp.Add, acc, c, slot, mode=dr.ReduceMode.Local)
            out.append(acc)
        return out


def _render_fused(scene, box: tuple[int, int, int, int], seed: int, spp: int,
                  aov_frame: AovFrame | None, near_shift: float = 0.0,
                  boresight: NDArray[np.float64] | None = None,
                  adaptive: AdaptivePlan | None = None, timing: dict[str, float] | None = None
                  ) -> tuple[NDArray[np.float32], dict[str, NDArray[np.float32]] | None,
                             NDArray[np.int32] | None]:
    """The radiance pass and the AOV pass over the crop ``box`` as Mitsuba's own wavefront
    render does them (``SamplingIntegrator::render`` / ``render_sample``, JIT variants), with
    differences that change no number:

    * the crop window's offset and size and the seed enter the kernels as *opaque* values, so
      one compiled kernel serves every frame (Mitsuba bakes them in and recompiles);
    * the near clip plane stays at :data:`NEAR_CLIP_MIN_KM` and each ray's origin is moved by
      ``near_shift`` [km] along the ``boresight``, as ``perspective`` does with its near clip;
    * each pixel's ``spp`` consecutive samples are summed in the kernel (no image block);
    * the AOV pass (:func:`_aov_channels`, float32) runs in the same ``dr.eval``.

    The images equal ``mi.render``'s to float32 rounding. Returns the ``(bh, bw, 2)`` film
    channels (``L``, ``Le``, normalised responses), with an ``aov_frame`` the crop's geometric
    channels (zero where the centre ray misses), float32, and ``None`` (the sample counts of
    :func:`_render_adaptive`).
    """
    import drjit as dr
    import mitsuba as mi

    if adaptive is not None:
        return _render_adaptive(scene, box, seed, spp, aov_frame, near_shift, boresight,
                                adaptive, timing)
    u0, v0, bw, bh = box
    rays = _CropRays(scene, box, near_shift, boresight)
    sampler = rays.sampler
    sampler.set_sample_count(spp)
    sampler.set_samples_per_wavefront(spp)
    n = bw * bh * spp
    # Every frame-dependent value is read from one evaluated array per type: single opaque
    # values that happen to be equal (u0 = v0, bw = bh, a seed equal to log2 spp) would be
    # merged into one kernel parameter, which changes the kernel and recompiles it.
    log_spp = spp.bit_length() - 1
    pow2 = (1 << log_spp) == spp
    u32 = _uniforms(mi.UInt32, [seed, log_spp if pow2 else spp])
    sampler.seed(u32[0], n)
    idx = dr.arange(mi.UInt32, n)
    idx = (idx >> u32[1]) if pow2 else (idx // u32[1])
    out = rays.radiance(idx, mi.UInt32(idx), bw * bh)
    names: list[str] = []
    if aov_frame is not None:
        si = scene.ray_intersect(rays.to_near_plane(rays.centre_rays(bw * bh)),
                                 mi.RayFlags.All, True)
        channels = _aov_kernel(si, aov_frame)
        names = list(channels)
        out += list(channels.values())
    dr.eval(out)
    out[0] = out[0] / float(spp)
    out[1] = out[1] / float(spp)
    arr = np.stack([np.asarray(c, dtype=np.float32) for c in out]).reshape(len(out), bh, bw)
    img = np.moveaxis(arr[:2], 0, -1)
    return (img, (dict(zip(names, arr[2:], strict=True)) if aov_frame is not None else None),
            None)


@dataclass(frozen=True)
class AdaptivePlan:
    """The adaptive render's inputs besides the scene (:func:`_render_adaptive`).

    Parameters
    ----------
    interior_spp : int
        Samples of a pixel whose neighbourhood is flat (``<= spp``).
    bound_radius_km : float
        Radius of a sphere about the body-frame origin that holds the whole body [km] (the
        scene's unit): pixels whose every ray misses it get no sample.
    pixel_angle : float
        Angular size of the largest pixel [rad] (a pinhole's pixels are largest at the
        principal point: ``max(1 / fx, 1 / fy)``); it exceeds the half-diagonal of every pixel.
    spread : float
        :data:`ADAPTIVE_SPREAD`.
    """

    interior_spp: int
    bound_radius_km: float
    pixel_angle: float
    spread: float = ADAPTIVE_SPREAD


def adaptive_sample_counts(hit: NDArray[np.bool_], proxy: NDArray[np.float32],
                           inside: NDArray[np.bool_], spp: int, interior_spp: int,
                           spread: float = ADAPTIVE_SPREAD) -> NDArray[np.int32]:
    """Samples per pixel of the adaptive render, from the pixel-centre rays alone.

    Each pixel's value is the mean of its own samples, an unbiased estimate of its pixel
    integral whatever their number, as long as that number does not depend on the samples: it
    is decided from deterministic information only, the ray through each pixel centre and
    the frame geometry.

    1. Outside ``inside`` (the pixel's cone misses the bounding sphere): **0** samples, every
       ray misses.
    2. ``hit`` disagrees within the 3 x 3 neighbourhood (limb, silhouettes, holes): **spp**.
    3. ``proxy`` (the centre ray's radiance, zero in shadow or off the surface) spreads over
       the 3 x 3 neighbourhood by more than ``spread`` of its largest value
       (``max - min > spread * max``; the terminator, shadow edges, the lit limb, albedo
       edges): **spp**.
    4. Every other pixel inside: **interior_spp**.

    The choice of :data:`ADAPTIVE_SPREAD` and of the default ``interior_spp`` (noise per spread
    bin): docs/methods.md, "starnav.renderer.render".

    Parameters
    ----------
    hit, proxy, inside : (h, w) arrays
        Centre ray hits the body; its radiance proxy (any unit, >= 0); the pixel's cone meets
        the bounding sphere.
    spp, interior_spp : int
        Samples of a full and of an interior pixel.
    spread : float
        Relative spread of ``proxy`` that asks for the full ``spp``.

    Returns
    -------
    (h, w) int32 array of ``0``, ``interior_spp`` or ``spp``.
    """
    def box3(a, op):
        """``op`` (np.maximum or np.minimum) over each pixel's 3 x 3 neighbourhood (edges
        replicated), separably."""
        p = np.pad(a, 1, mode="edge")
        r = op(op(p[:, :-2], p[:, 1:-1]), p[:, 2:])
        return op(op(r[:-2], r[1:-1]), r[2:])

    h8 = hit.astype(np.uint8)
    limb = box3(h8, np.maximum) != box3(h8, np.minimum)
    pr = np.where(hit, proxy, 0).astype(np.float32)
    pmax = box3(pr, np.maximum)
    steep = (pmax - box3(pr, np.minimum)) > np.float32(spread) * pmax
    counts = np.where(limb | steep, np.int32(spp), np.int32(interior_spp))
    counts[~inside] = 0
    return counts


_Z_ORDER: dict[tuple[int, int], NDArray[np.uint32]] = {}


def _z_order(bw: int, bh: int) -> NDArray[np.uint32]:
    """The pixel indices of a ``bw`` x ``bh`` crop along a Z-order (Morton) curve, cached for
    the last crop size (a full-field sequence keeps its crop; 0.03 s for 1024 x 1024).

    The adaptive render's pixel lists follow it instead of the rows: neighbouring pixels are
    then neighbours in the wavefront in both directions, and their rays share more of the
    BVH, which makes the interior pass faster than in row order. The order of a list changes
    no pixel's samples' distribution: each pixel keeps its count and its consecutive samples.
    """
    key = (bw, bh)
    if key not in _Z_ORDER:
        def spread(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
            v = v & np.uint64(0xFFFF)
            for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333),
                                (1, 0x55555555)):
                v = (v | (v << np.uint64(shift))) & np.uint64(mask)
            return v

        i = np.arange(bw * bh, dtype=np.uint64)
        key_z = spread(i % np.uint64(bw)) | (spread(i // np.uint64(bw)) << np.uint64(1))
        _Z_ORDER.clear()
        _Z_ORDER[key] = np.argsort(key_z, kind="stable").astype(np.uint32)
    return _Z_ORDER[key]


def _centre_radiance(scene, si, ray):
    """The radiance proxy of the adaptive render's sample map: the BSDF value (cosine
    included) towards the Sun of each pixel-centre hit ``si``, summed over the ray's fixed
    wavelengths, zero where the Sun is below the surface's or the camera's horizon or the
    shadow ray is blocked (the shadow test of :func:`_direct_lighting` on one deterministic
    sample: a directional emitter's direction does not depend on the sample)."""
    import drjit as dr
    import mitsuba as mi

    hit = si.is_valid()
    bsdf = si.bsdf(ray)
    ds, _ = scene.sample_emitter_direction(si, mi.Point2f(0.5), False, hit)
    wo = si.to_local(ds.d)
    lit = (hit & (ds.pdf != 0.0) & (mi.Frame3f.cos_theta(wo) > 0.0)
           & (mi.Frame3f.cos_theta(si.wi) > 0.0))
    lit &= ~scene.ray_test(si.spawn_ray_to(ds.p), lit)
    value = bsdf.eval(mi.BSDFContext(), si, wo, lit)
    total = value[0]
    for k in range(1, len(value)):
        total = total + value[k]
    return dr.select(lit, total, 0.0)


def _render_adaptive(scene, box: tuple[int, int, int, int], seed: int, spp: int,
                     aov_frame: AovFrame | None, near_shift: float,
                     boresight: NDArray[np.float64] | None, plan: AdaptivePlan,
                     timing: dict[str, float] | None = None
                     ) -> tuple[NDArray[np.float32], dict[str, NDArray[np.float32]] | None,
                                NDArray[np.int32]]:
    """:func:`_render_fused` with samples where the signal needs them.

    1. **Centre pass**: the pixel-centre rays, their AOV channels, the radiance proxy of
       :func:`_centre_radiance` and whether the pixel's cone meets the bounding sphere.
    2. **Sample map**: :func:`adaptive_sample_counts`.
    3. **Radiance passes**, one kernel per sample count: a count's pixels, listed in Z-order
       (:func:`_z_order`), traced as :func:`_render_fused` traces the crop, each pixel's ``n``
       samples consecutive in the wavefront. The passes use different seeds (the interior's
       offset by 0x9E3779B9) so that no two pixels share a stream; seeds, list length and
       crop enter as data, and each pass is its own ``dr.eval``.

    Returns ``_render_fused``'s image and AOVs and the ``(bh, bw)`` sample counts; ``timing``
    (optional) receives the seconds of each step (``centre_s``, ``map_s``, ``spp_<n>_s``).
    """
    import drjit as dr
    import mitsuba as mi

    u0, v0, bw, bh = box
    rays = _CropRays(scene, box, near_shift, boresight)
    sampler = rays.sampler
    interior_spp = int(plan.interior_spp)
    counts_used = (spp,) if interior_spp == spp else (spp, interior_spp)
    seeds = [seed, (seed + 0x9E3779B9) & 0xFFFFFFFF]
    u32_vals: list[int] = []
    for k, n in enumerate(counts_used):
        log_n = n.bit_length() - 1
        u32_vals += [seeds[k], log_n if (1 << log_n) == n else n]
    u32 = _uniforms(mi.UInt32, u32_vals)

    # 1. the centre pass
    t0 = time.perf_counter()
    cray = rays.centre_rays(bw * bh)
    cam = mi.Vector3f(cray.o)  # the camera: the sensor's ray origin before the near shift
    d = mi.Vector3f(cray.d)
    cray = rays.to_near_plane(cray)
    si = scene.ray_intersect(cray, mi.RayFlags.All, True)
    proxy = _centre_radiance(scene, si, mi.RayDifferential3f(cray))
    hit = si.is_valid()
    bounds = _uniforms(mi.Float, [plan.bound_radius_km, plan.pixel_angle])
    dist = dr.norm(cam)
    # angle between the ray and the direction to the body's centre (the body-frame origin),
    # through its sine (float32 cosines near 1 resolve only ~3e-4 rad)
    sin_a = dr.norm(dr.cross(d, -cam)) / dist
    sin_rho = dr.minimum(bounds[0] / dist, 1.0)
    alpha = dr.asin(sin_rho) + bounds[1]
    inside = ((dist <= bounds[0]) | (alpha >= 0.5 * dr.pi)
              | ((dr.dot(d, -cam) > 0.0) & (sin_a <= dr.sin(dr.minimum(alpha, 0.5 * dr.pi)))))
    centre_out = [hit, proxy, inside]
    names: list[str] = []
    if aov_frame is not None:
        channels = _aov_kernel(si, aov_frame)
        names = list(channels)
        centre_out += list(channels.values())
    dr.eval(centre_out)
    hit_np = np.asarray(centre_out[0], dtype=bool).reshape(bh, bw)
    proxy_np = np.asarray(centre_out[1], dtype=np.float32).reshape(bh, bw)
    inside_np = np.asarray(centre_out[2], dtype=bool).reshape(bh, bw)
    aovs = None
    if aov_frame is not None:
        aovs = {k: np.asarray(v, dtype=np.float32).reshape(bh, bw)
                for k, v in zip(names, centre_out[3:], strict=True)}

    t1 = time.perf_counter()
    # 2. the sample map
    counts = adaptive_sample_counts(hit_np, proxy_np, inside_np, spp, interior_spp, plan.spread)
    steps = {"centre_s": t1 - t0, "map_s": time.perf_counter() - t1}

    # 3. one radiance pass per sample count
    img = np.zeros((bh * bw, 2), np.float32)
    order = _z_order(bw, bh)
    counts_z = counts.ravel()[order]
    for k, n_spp in enumerate(counts_used):
        t0 = time.perf_counter()
        pix = order[counts_z == n_spp]
        if pix.size == 0:
            continue
        sampler.set_sample_count(n_spp)
        sampler.set_samples_per_wavefront(n_spp)
        n = int(pix.size) * n_spp
        sampler.seed(u32[2 * k], n)
        pix_d = mi.UInt32(pix)
        j = dr.arange(mi.UInt32, n)
        j = (j >> u32[2 * k + 1]) if (1 << (n_spp.bit_length() - 1)) == n_spp \
            else (j // u32[2 * k + 1])
        p = dr.gather(mi.UInt32, pix_d, j)
        acc = rays.radiance(p, j, int(pix.size))
        dr.eval(acc)
        for c in range(2):
            img[pix, c] = np.asarray(acc[c], dtype=np.float32) / np.float32(n_spp)
        steps[f"spp_{n_spp}_s"] = time.perf_counter() - t0
    if timing is not None:
        timing.update(steps)
    sampler.set_sample_count(spp)
    sampler.set_samples_per_wavefront(spp)
    return img.reshape(bh, bw, 2), aovs, counts


def _direct_lighting(scene, sampler, ray):
    """Mitsuba's ``direct`` integrator with one emitter sample and no BSDF sample, casting the
    shadow ray only where the BSDF is non-zero.

    Every starnav BSDF is zero with the Sun or the camera below the horizon (:mod:`.bsdfs`),
    so the emitter is sampled without the visibility test and Mitsuba's own occlusion ray is
    cast only where it can matter. The sampler draws the same numbers in the same order: the
    radiance is Mitsuba's sample for sample. No emitter is hit by camera rays (the Sun is
    ``directional``). Returns the spectral radiance and the hit mask.
    """
    import drjit as dr
    import mitsuba as mi

    si = scene.ray_intersect(ray, mi.RayFlags.All, True)
    valid = si.is_valid()
    bsdf = si.bsdf(ray)
    active = valid & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    ds, emitter_val = scene.sample_emitter_direction(si, sampler.next_2d(active), False, active)
    active &= ds.pdf != 0.0
    wo = si.to_local(ds.d)
    lit = active & (mi.Frame3f.cos_theta(wo) > 0.0) & (mi.Frame3f.cos_theta(si.wi) > 0.0)
    occluded = scene.ray_test(si.spawn_ray_to(ds.p), lit)
    lit &= ~occluded
    value = bsdf.eval(mi.BSDFContext(), si, wo, lit)
    # a delta emitter (the Sun): multiple-importance weight 1, as in Mitsuba's integrator
    return dr.select(lit, value * emitter_val, 0.0), valid


def _aov_kernel(si, frame: AovFrame) -> dict:
    """:func:`_aov_channels` on Dr.Jit arrays (float32, zero where ``si`` is a miss): range,
    inertial normal, lat/lon, incidence, emission and phase of the hit points of ``si`` (scene
    in body-fixed km)."""
    import drjit as dr
    import mitsuba as mi

    hit = si.is_valid()
    f = _uniforms(mi.Float, [*frame.R_body_to_inertial.ravel().tolist(),
                             *frame.camera_body.tolist(), *frame.sun_body.tolist()])
    R = [f[3 * i:3 * i + 3] for i in range(3)]
    cam = mi.Vector3f(*f[9:12])
    sun = mi.Vector3f(*f[12:15])
    pos = si.p * KM
    n_b = dr.normalize(si.sh_frame.n)
    n_i = [dr.fma(R[i][0], n_b.x, dr.fma(R[i][1], n_b.y, R[i][2] * n_b.z)) for i in range(3)]
    to_cam = cam - pos
    rng = dr.norm(to_cam)
    v_hat = to_cam / rng
    s_hat = dr.normalize(sun - pos)
    r_b = dr.norm(pos)

    def ang(a, b):
        return dr.acos(dr.clip(dr.dot(a, b), -1.0, 1.0))

    values = {
        "range": rng, "nx": n_i[0], "ny": n_i[1], "nz": n_i[2],
        "lat": dr.asin(dr.clip(pos.z / r_b, -1.0, 1.0)), "lon": dr.atan2(pos.y, pos.x),
        "incidence": ang(n_b, s_hat), "emission": ang(n_b, v_hat), "phase": ang(s_hat, v_hat),
        "mask": mi.Float(1.0),
    }
    if frame.body_fixed:
        values.update({"x_body": pos.x, "y_body": pos.y, "z_body": pos.z})
    return {k: dr.select(hit, v, 0.0) for k, v in values.items()}


def _uniforms(dtype, values: list) -> list:
    """``values`` as one evaluated Dr.Jit array of ``dtype`` read back element by element: kernel
    inputs whose values change between frames without changing the compiled kernel."""
    import drjit as dr

    arr = dtype(values)
    dr.make_opaque(arr)
    return [dr.gather(dtype, arr, i) for i in range(len(values))]


def _any_perpendicular(v: NDArray[np.float64]) -> NDArray[np.float64]:
    a = np.array([0.0, 0.0, 1.0]) if abs(v[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    p = np.cross(v, a)
    return p / np.linalg.norm(p)


def _aov_channels(raw: NDArray[np.float64], geom: FrameGeometry,
                  box: tuple[int, int, int, int], shape: tuple[int, int],
                  body_fixed: bool = False) -> dict[str, NDArray[np.float32]]:
    """Geometric channels from the AOV pass (positions/normals in body-fixed km); computed
    only at the pixels whose centre ray hits the Moon, zero elsewhere. ``body_fixed`` adds the
    body-fixed surface point [m] (:data:`starnav.radiance.BODY_FIXED_AOV_CHANNELS`)."""
    u0, v0, bw, bh = box
    H, W = shape
    f32 = np.float32
    pos_all = raw[:, :, 0:3].astype(np.float64)
    # a miss reports the origin; any surface point of a star-shaped body is far from it (a
    # fraction of the reference radius would drop the ends of a triaxial body's short axis)
    hit = np.einsum("ijk,ijk->ij", pos_all, pos_all) > (1e-3 * geom.body_radius / KM) ** 2
    sel = raw[hit].astype(f32, copy=False)  # (n, 6) float32: ample for image channels
    pos_b = sel[:, 0:3] * f32(KM)
    R = geom.R_body_to_inertial.astype(f32)
    pos_i = pos_b @ R.T
    n_i = sel[:, 3:6] @ R.T
    n_i /= np.maximum(np.linalg.norm(n_i, axis=1, keepdims=True), f32(1e-30))
    # differences to the camera and the Sun are formed in float64 (ranges of 1e7-1e11 m)
    to_cam = (geom.camera_position[None, :] - pos_i).astype(f32)
    rng = np.linalg.norm(to_cam, axis=1)
    v_hat = to_cam / rng[:, None]
    s_hat = (geom.sun_position[None, :] - pos_i).astype(f32)
    s_hat /= np.linalg.norm(s_hat, axis=1, keepdims=True)
    r_b = np.linalg.norm(pos_b, axis=1)

    def ang(a, b):
        return np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))

    values = {
        "range": rng,
        "nx": n_i[:, 0], "ny": n_i[:, 1], "nz": n_i[:, 2],
        "lat": np.arcsin(np.clip(pos_b[:, 2] / r_b, -1.0, 1.0)),
        "lon": np.arctan2(pos_b[:, 1], pos_b[:, 0]),
        "incidence": ang(n_i, s_hat), "emission": ang(n_i, v_hat), "phase": ang(s_hat, v_hat),
        "mask": np.ones(pos_b.shape[0], f32),
    }
    if body_fixed:
        values.update({"x_body": pos_b[:, 0], "y_body": pos_b[:, 1], "z_body": pos_b[:, 2]})
    # one (channels, H, W) block, filled through the crop's boolean mask (faster than
    # scattering each channel by index)
    block = np.zeros((len(values), H, W), np.float32)
    crop = block[:, v0:v0 + bh, u0:u0 + bw]
    for c, v in enumerate(values.values()):
        crop[c][hit] = v
    return dict(zip(values, block, strict=True))
