"""The detector chain: radiance image -> electrons -> DN -> star-tracker readout products.

Each effect is a pure array function (:mod:`~starnav.detector.optics`,
:mod:`~starnav.detector.charge`, :mod:`~starnav.detector.blooming`,
:mod:`~starnav.detector.smear`, :mod:`~starnav.detector.crosstalk`,
:mod:`~starnav.detector.readout`) with explicit parameters and, when random, an explicit
generator; this module wraps each in a thin adapter (:class:`Effect`, registry
:data:`EFFECTS`) that reads its settings from :class:`~starnav.detector.schema.DetectorConfig`,
and runs them in a fixed order of Pyxel's stages (photons -> charge -> pixel -> signal ->
image; :data:`CHAIN_ORDERS`: ``physical`` by default, the seed paper's order as ``paper``).
The order and why each effect stands where it does: docs/detector.md, "Stage order".

Fixed-pattern maps come from the sensor seed, temporal noise from ``(seed, frame_index,
effect)`` (:mod:`starnav.detector.seeding`): frames can be made in any order by any number of
workers with identical DN. Everything before the first temporal-noise effect
(:data:`TEMPORAL_EFFECTS`) is deterministic and can be kept (:class:`MeanCharge`) for a second
acquisition of the same radiance.

Index
-----
:func:`expose`, :class:`Exposure`, :class:`MeanCharge`, :func:`add_point_sources`,
:class:`Effect`, :class:`ChainContext`, :func:`get_effect`, :func:`chain_order`,
:func:`first_temporal`, :data:`STAGES`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.camera import Camera
from starnav.config_base import SIView
from starnav.detector import blooming, charge, crosstalk, optics, readout, smear
from starnav.detector.optics import PointSources
from starnav.detector.products import Segments, Window
from starnav.detector.schema import DetectorConfig, WindowSpec
from starnav.detector.seeding import temporal_rng
from starnav.errors import ConfigError
from starnav.radiance import RadianceImage
from starnav.registry import Registry
from starnav.typing import Float32Array

logger = logging.getLogger(__name__)


STAGES = ("photons", "charge", "pixel", "signal", "image")


# =========================================================================== context
@dataclass
class ChainContext:
    """What an effect adapter may read besides the frame.

    Attributes
    ----------
    camera : Camera
    config : DetectorConfig
    si : SIView
        ``config`` in SI, built once per frame.
    exposure_time : float
        Integration time [s].
    seed : int
        Dataset seed (temporal noise).
    sensor_seed : int
        Sensor seed (fixed-pattern maps).
    frame_index : int
    ledger : dict
        Charge book-keeping [e-]: ``photoelectrons_e`` (after radiometry), ``optics_lost_e``
        (moved off the array by the PSF, distortion, motion, halo and ghosts; distortion's
        small resampling error included), ``drained_e`` and ``left_array_e`` (blooming).
    """

    camera: Camera
    config: DetectorConfig
    exposure_time: float
    seed: int
    sensor_seed: int
    frame_index: int
    ledger: dict[str, float] = field(default_factory=dict)
    #: ``config`` in SI (:meth:`~starnav.config_base.StrictModel.to_si`): what adapters read
    #: for any quantity with a unit other than px, e- or DN.
    si: SIView = field(init=False)
    _last_total: tuple[Float32Array, float] | None = field(default=None, init=False,
                                                            repr=False)

    def __post_init__(self) -> None:
        self.si = self.config.to_si()

    def temporal(self, effect: str) -> np.random.Generator:
        """Temporal generator of ``effect`` for this frame."""
        return temporal_rng(self.seed, self.frame_index, effect)

    def book(self, key: str, value: float) -> None:
        self.ledger[key] = self.ledger.get(key, 0.0) + float(value)

    def total(self, image: Float32Array) -> float:
        """``image.sum(dtype=float64)`` [e-]; the last image's sum is kept, so an effect's
        input, which is the previous effect's output, is summed once."""
        last = self._last_total
        if last is not None and last[0] is image:
            return last[1]
        t = float(image.sum(dtype=np.float64))
        self._last_total = (image, t)
        return t


@dataclass(frozen=True)
class Effect:
    """A named effect: its stage, whether it is on, and its adapter.

    ``apply(image, ctx) -> image`` takes and returns ``(H, W)`` float32 in e-, except
    ``photoelectrons`` which takes the electron radiance.
    """

    name: str
    stage: str
    description: str
    enabled: Callable[[DetectorConfig, Camera], bool]
    apply: Callable[[Float32Array, ChainContext], Float32Array]


# =========================================================================== adapters
def _photoelectrons(le: Float32Array, ctx: ChainContext) -> Float32Array:
    ri = (optics.relative_illumination_map(ctx.camera)
          if ctx.config.optics.radiometry.relative_illumination else None)
    out = optics.photoelectrons(le, ctx.exposure_time, ctx.camera.etendue, ri)
    ctx.book("photoelectrons_e", ctx.total(out))
    return out


def _aberration(img: Float32Array, ctx: ChainContext) -> Float32Array:
    grid = optics.psf_grid(ctx.camera, ctx.config.optics.aberration)
    out, lost = optics.apply_psf_grid(img, grid)
    ctx.book("optics_lost_e", lost)
    return out


#: The effect after whose place in every chain order the point sources join the frame.
POINT_SOURCES_AFTER = "aberration_psf"


def add_point_sources(img: Float32Array, ctx: ChainContext, sources: PointSources
                      ) -> Float32Array:
    """Add ``sources`` (rate x exposure [x cos(theta)]) spread by the field-varying PSF at
    their sub-pixel pinhole positions (:func:`~starnav.detector.optics.point_source_image`)."""
    e = sources.rate * ctx.exposure_time
    if ctx.config.optics.radiometry.relative_illumination:
        x = (sources.u - ctx.camera.cx) / ctx.camera.fx
        y = (sources.v - ctx.camera.cy) / ctx.camera.fy
        e = e / np.sqrt(1.0 + x * x + y * y)  # the pupil seen at the field angle: cos(theta)
    stars, lost = optics.point_source_image(img.shape, sources, e, ctx.camera,
                                            ctx.config.optics.aberration)
    ctx.book("photoelectrons_e", float(np.sum(e)))
    ctx.book("optics_lost_e", lost)
    return img + stars


def _book_loss(ctx: ChainContext, before: Float32Array, after: Float32Array) -> None:
    """Book what a conserving-except-at-the-edges effect moved off the array [e-]."""
    ctx.book("optics_lost_e", ctx.total(before) - ctx.total(after))


def _distortion(img: Float32Array, ctx: ChainContext) -> Float32Array:
    out = optics.distort(img, ctx.camera)
    _book_loss(ctx, img, out)
    return out


def _row_time(ctx: ChainContext) -> float:
    rs = ctx.si.smear.rolling_shutter
    if rs.row_time is not None:
        return rs.row_time
    t = ctx.si.readout.timing
    return t.b * ctx.camera.width / t.n_pix_unit


def _rolling_shutter(img: Float32Array, ctx: ChainContext) -> Float32Array:
    vel = smear.image_velocity(ctx.si.smear.rolling_shutter.angular_rate, ctx.camera.fx,
                               ctx.camera.fy)
    out = smear.rolling_shutter(img, vel, ctx.exposure_time, _row_time(ctx))
    _book_loss(ctx, img, out)
    return out


def _stray_light(img: Float32Array, ctx: ChainContext) -> Float32Array:
    out = optics.stray_light(img, ctx.config.optics.stray_light)
    _book_loss(ctx, img, out)
    return out


def _ghosts(img: Float32Array, ctx: ChainContext) -> Float32Array:
    out = optics.ghost_images(img, ctx.config.optics.ghosts.ghosts,
                              (float(ctx.camera.cx), float(ctx.camera.cy)),
                              ctx.config.optics.stray_light.binning)
    _book_loss(ctx, img, out)
    return out


def _transfer_smear(img: Float32Array, ctx: ChainContext) -> Float32Array:
    return smear.transfer_smear(img, ctx.exposure_time, ctx.si.smear.transfer.row_transfer_time)


def _prnu(img: Float32Array, ctx: ChainContext) -> Float32Array:
    g = charge.prnu_map(ctx.sensor_seed, img.shape, ctx.config.charge.prnu.sigma_fraction)
    return img * g


def _dark(img: Float32Array, ctx: ChainContext) -> Float32Array:
    d = ctx.config.charge.dark_current
    pattern = charge.dark_pattern(ctx.sensor_seed, img.shape, d.dsnu_fraction,
                                  d.hot_pixel_fraction, d.hot_pixel_factor)
    t = ctx.si.charge.dark_current
    rate = charge.dark_rate_at(d.rate_e_per_s, t.temperature, t.reference_temperature,
                               t.doubling_temperature)
    return charge.add_dark_current(img, pattern, rate, ctx.exposure_time)


def _shot(img: Float32Array, ctx: ChainContext) -> Float32Array:
    return charge.shot_noise(img, ctx.temporal("shot_noise"),
                             ctx.config.charge.shot_noise.gaussian_above_e)


def _saturation(img: Float32Array, ctx: ChainContext) -> Float32Array:
    s = ctx.config.saturation
    b = s.blooming
    mode = b.mode if b.enabled else "drain"
    r = blooming.bloom(img, s.full_well_e, mode, b.spill_fraction, b.max_margin_px)
    ctx.book("drained_e", r.drained)
    ctx.book("left_array_e", r.left_array)
    return r.charge


def _ipc(img: Float32Array, ctx: ChainContext) -> Float32Array:
    c = ctx.config.signal.ipc
    return crosstalk.interpixel_capacitance(img, c.nearest_fraction, c.diagonal_fraction)


def _electrical(img: Float32Array, ctx: ChainContext) -> Float32Array:
    c = ctx.config.signal.electrical_crosstalk
    thr = c.threshold_fraction * ctx.config.saturation.full_well_e
    return crosstalk.electrical_crosstalk(img, thr, c.row_coefficient, c.column_coefficient)


def _nonlinearity(img: Float32Array, ctx: ChainContext) -> Float32Array:
    return readout.nonlinearity(img, ctx.config.saturation.full_well_e,
                                ctx.config.signal.nonlinearity.full_well_deficit_fraction)


def _read_noise(img: Float32Array, ctx: ChainContext) -> Float32Array:
    return readout.read_noise(img, ctx.config.signal.read_noise.sigma_e,
                              ctx.temporal("read_noise"))


def _always(cfg: DetectorConfig, cam: Camera) -> bool:
    return True


#: Every effect by name.
EFFECTS: Registry[Effect] = Registry("detector effect", {e.name: e for e in (
    Effect("photoelectrons", "photons", "t A Omega Le [cos^4]", _always, _photoelectrons),
    Effect("aberration_psf", "photons", "field-varying defocus + aberration PSF",
           lambda c, cam: c.optics.aberration.enabled, _aberration),
    Effect("distortion", "photons", "Brown-Conrady resampling onto the detector grid",
           lambda c, cam: c.optics.distortion.enabled and cam.has_distortion, _distortion),
    Effect("rolling_shutter", "photons", "motion blur and rolling-shutter skew",
           lambda c, cam: c.smear.rolling_shutter.enabled
           and any(w != 0 for w in c.smear.rolling_shutter.to_si().angular_rate),
           _rolling_shutter),
    Effect("stray_light", "photons", "Harvey halo with a set TIS",
           lambda c, cam: c.optics.stray_light.enabled
           and c.optics.stray_light.total_integrated_scatter > 0, _stray_light),
    Effect("ghosts", "photons", "scaled, defocused, displaced copies",
           lambda c, cam: c.optics.ghosts.enabled and len(c.optics.ghosts.ghosts) > 0, _ghosts),
    Effect("transfer_smear", "photons", "CCD frame-transfer smear",
           lambda c, cam: c.smear.transfer.enabled, _transfer_smear),
    Effect("prnu", "charge", "photo-response non-uniformity",
           lambda c, cam: c.charge.prnu.enabled and c.charge.prnu.sigma_fraction > 0, _prnu),
    Effect("dark_current", "charge", "dark current, DSNU, hot pixels, temperature",
           lambda c, cam: c.charge.dark_current.enabled, _dark),
    Effect("shot_noise", "charge", "Poisson shot noise",
           lambda c, cam: c.charge.shot_noise.enabled, _shot),
    Effect("saturation", "pixel", "full well and blooming",
           lambda c, cam: c.saturation.enabled, _saturation),
    Effect("ipc", "signal", "3 x 3 inter-pixel capacitance",
           lambda c, cam: c.signal.ipc.enabled, _ipc),
    Effect("electrical_crosstalk", "signal", "row/column crosstalk of bright pixels",
           lambda c, cam: c.signal.electrical_crosstalk.enabled, _electrical),
    Effect("nonlinearity", "signal", "charge-to-voltage non-linearity",
           lambda c, cam: c.signal.nonlinearity.enabled
           and c.signal.nonlinearity.full_well_deficit_fraction > 0, _nonlinearity),
    Effect("read_noise", "signal", "Gaussian read noise",
           lambda c, cam: c.signal.read_noise.enabled and c.signal.read_noise.sigma_e > 0,
           _read_noise),
)})

#: Fixed stage orders by name (module essay).
CHAIN_ORDERS: Registry[tuple[str, ...]] = Registry("detector chain order", {
    "physical": ("photoelectrons", "aberration_psf", "distortion", "rolling_shutter",
                 "stray_light", "ghosts", "transfer_smear", "prnu", "dark_current",
                 "shot_noise", "saturation", "ipc", "electrical_crosstalk", "nonlinearity",
                 "read_noise"),
    "paper": ("photoelectrons", "aberration_psf", "stray_light", "ghosts", "rolling_shutter",
              "transfer_smear", "saturation", "distortion", "prnu", "dark_current",
              "shot_noise", "ipc", "electrical_crosstalk", "nonlinearity", "read_noise"),
})


#: Effects that draw from the frame's temporal streams; the chain before the first of them is
#: deterministic (:class:`MeanCharge`).
TEMPORAL_EFFECTS = ("shot_noise", "read_noise")


def first_temporal(order: Sequence[str]) -> int:
    """Position in ``order`` of the first temporal-noise effect (``len(order)`` if none)."""
    return next((k for k, n in enumerate(order) if n in TEMPORAL_EFFECTS), len(order))


def get_effect(name: str) -> Effect:
    """The effect registered as ``name``."""
    return EFFECTS.get(name)


def chain_order(name: str) -> tuple[str, ...]:
    """The effect names of order ``name`` (``physical`` or ``paper``)."""
    return CHAIN_ORDERS.get(name)


# =========================================================================== result
def _prefix_settings(cfg: DetectorConfig) -> dict[str, Any]:
    """The settings the deterministic part of the chain may read: all but the readout modes,
    windows and segment thresholds, the temporal seeds and the debug switches."""
    return cfg.model_dump(exclude={"readout": {"modes", "windows", "segments"},
                                   "debug": True})


@dataclass(frozen=True)
class MeanCharge:
    """The frame before the chain's first temporal-noise effect and what made it: another
    acquisition of the same radiance, camera, exposure, stars and sensor can start from it
    (``expose(..., mean_charge=...)``).

    Attributes
    ----------
    image : (H, W) float32, read-only
        The frame at that point of the chain [e-].
    position : int
        Index in the chain order of the first effect not applied.
    ledger, stages : dict
        Charge ledger so far [e-]; copies after each applied effect (when kept).
    electrons : (H, W) float32 or None
        The charge at the end of the pixel stage, if that came before ``position``.
    radiance, camera, point_sources : object
        The inputs, held by identity.
    settings : dict
        :func:`_prefix_settings` of the detector configuration.
    exposure_time : float
        [s].
    sensor_seed : int
    """

    image: Float32Array
    position: int
    ledger: dict[str, float]
    stages: dict[str, NDArray[Any]]
    electrons: Float32Array | None
    radiance: Any
    camera: Camera
    point_sources: PointSources | None
    settings: dict[str, Any]
    exposure_time: float
    sensor_seed: int

    def check(self, radiance: Any, camera: Camera, cfg: DetectorConfig, exposure_time: float,
              point_sources: PointSources | None, sensor_seed: int) -> None:
        """Raise :class:`~starnav.errors.ConfigError` unless an exposure with these inputs
        would have computed this very frame."""
        same = (radiance is self.radiance and camera is self.camera
                and point_sources is self.point_sources
                and exposure_time == self.exposure_time and sensor_seed == self.sensor_seed
                and _prefix_settings(cfg) == self.settings)
        if not same:
            raise ConfigError("mean_charge", "the mean charge of another exposure",
                              "the MeanCharge of an exposure of the same radiance object, "
                              "camera, stars, exposure time, sensor seed and detector "
                              "settings (readout modes, windows and thresholds aside)")


@dataclass
class Exposure:
    """One exposed frame.

    Attributes
    ----------
    dn : (H, W) uint16
        Full DN frame (always kept, for analysis).
    electrons : (H, W) float32
        Collected charge at the end of the pixel stage (after saturation and blooming) [e-].
    signal : (H, W) float32
        Signal entering the ADC (after crosstalk, non-linearity, read noise) [e-].
    segments : Segments or None
        Full-image compressed readout (if ``segments`` is among the readout modes).
    windows, timing : tuple of Window, tuple of ReadoutTiming
        Windows readout; readout-law check of every requested readout.
    ledger : dict
        Charge book-keeping [e-] (as :class:`ChainContext`'s).
    stages, timings_ms : dict
        Copy of the frame after each effect (when kept), in chain order; wall time of each
        effect [ms].
    exposure_time, gain : float
        [s], [e-/DN].
    seed, sensor_seed, frame_index : int
    config : DetectorConfig
    mean_charge : MeanCharge or None
        The frame before the first temporal-noise effect (``keep_mean_charge``).
    """

    dn: NDArray[np.uint16]
    electrons: Float32Array
    signal: Float32Array
    segments: Segments | None
    windows: tuple[Window, ...]
    timing: tuple[readout.ReadoutTiming, ...]
    ledger: dict[str, float]
    stages: dict[str, NDArray[Any]]
    timings_ms: dict[str, float]
    exposure_time: float
    gain: float
    seed: int
    sensor_seed: int
    frame_index: int
    config: DetectorConfig
    mean_charge: MeanCharge | None = None

    @property
    def feasible(self) -> bool:
        """Every requested readout is compatible with the exposure (readout law)."""
        return all(t.feasible for t in self.timing)

    def summary(self) -> dict[str, Any]:
        """JSON-safe description (no arrays)."""
        return {
            "exposure_time_s": self.exposure_time,
            "gain_e_per_dn": self.gain,
            "seed": self.seed,
            "sensor_seed": self.sensor_seed,
            "frame_index": self.frame_index,
            "order": self.config.order,
            "shape": list(self.dn.shape),
            "dn_max": int(self.dn.max()) if self.dn.size else 0,
            "saturated_pixels": int(np.count_nonzero(
                self.electrons >= self.config.saturation.full_well_e)),
            "ledger_e": dict(self.ledger),
            "timing": [t.to_dict() for t in self.timing],
            "feasible": self.feasible,
            "segments": None if self.segments is None else {
                "runs": len(self.segments), "pixels": self.segments.n_pixels,
                "thresholds_dn": list(self.segments.thresholds),
                "truncated": self.segments.truncated},
            "windows": [{"row0": w.row0, "col0": w.col0, "height": w.height, "width": w.width}
                        for w in self.windows],
            "effect_time_ms": dict(self.timings_ms),
        }


# =========================================================================== entry point
def _check_exposure(t: Any) -> float:
    try:
        v = float(t)
    except (TypeError, ValueError):
        raise ConfigError("exposure_time_s", t, "a finite exposure time > 0 s") from None
    if not math.isfinite(v) or v <= 0:
        raise ConfigError("exposure_time_s", t, "a finite exposure time > 0 s")
    return v


def _electron_radiance(radiance: RadianceImage | NDArray[Any], camera: Camera) -> Float32Array:
    le = radiance.Le if isinstance(radiance, RadianceImage) else radiance
    le = np.asarray(le)
    shape = (camera.height, camera.width)
    if le.shape != shape:
        raise ConfigError("radiance.Le", f"shape {le.shape}",
                          f"the camera's {shape[0]} x {shape[1]} (rows x columns)")
    le = le.astype(np.float32, copy=False)
    bad = ~np.isfinite(le)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise ConfigError("radiance.Le", f"{int(bad.sum())} non-finite pixel(s), first "
                          f"{le[r, c]} at (row {r}, col {c})",
                          "finite electron radiance >= 0 [e- s^-1 m^-2 sr^-1]")
    if (le < 0).any():
        r, c = np.argwhere(le < 0)[0]
        raise ConfigError("radiance.Le", f"{le[r, c]} at (row {r}, col {c})",
                          "electron radiance >= 0 [e- s^-1 m^-2 sr^-1]")
    return le


def expose(radiance: RadianceImage | NDArray[Any], camera: Camera,
           config: DetectorConfig | None = None, *, seed: int = 0, frame_index: int = 0,
           exposure_time: float | None = None,
           windows: Sequence[WindowSpec | Sequence[int] | dict] | None = None,
           keep_stages: bool | None = None,
           point_sources: PointSources | None = None,
           keep_mean_charge: bool = False,
           mean_charge: MeanCharge | None = None) -> Exposure:
    """Expose the detector to a radiance image and read it out like the AA-STR.

    Parameters
    ----------
    radiance : RadianceImage or (H, W) array
        The renderer's output (its ``Le`` channel is used) or an electron-radiance array
        [e- s^-1 m^-2 sr^-1]; undistorted pinhole image of ``camera``.
    camera : Camera
    config : DetectorConfig, optional
        Chain settings; defaults to the AA-STR values.
    seed, frame_index : int
        Dataset seed (temporal noise, and the fixed pattern when ``config.sensor_seed`` is
        None) and frame number (the temporal noise stream).
    exposure_time : float, optional
        Integration time [s]; default ``config.exposure_time_s``.
    windows : sequence, optional
        ``WindowSpec`` or ``(row0, col0, height, width)``; default ``config.readout.windows``.
    keep_stages : bool, optional
        Keep a copy of the frame after every effect; default ``config.debug.keep_stages``.
    point_sources : PointSources, optional
        Stars (pinhole positions [px], rates [e-/s]), added after the aberration PSF
        (docs/detector.md, "Stage order").
    keep_mean_charge : bool
        Keep :attr:`Exposure.mean_charge` for another acquisition of the same radiance.
    mean_charge : MeanCharge, optional
        Start from that frame (made from the same inputs, readout settings aside): the result
        is the one of a full run.

    Returns
    -------
    Exposure

    Raises
    ------
    ConfigError
        Exposure not > 0 s; exposure shorter than a requested readout needs (policy
        ``enforce``); more than 16 windows or a window outside the array; radiance with NaN,
        negative values or the wrong shape; a ``mean_charge`` made from other inputs.
    """
    cfg = config if config is not None else DetectorConfig()
    t_exp = _check_exposure(cfg.exposure_time_s if exposure_time is None else exposure_time)
    shape = (camera.height, camera.width)
    win = readout.check_windows(cfg.readout.windows if windows is None else windows, shape)
    modes = cfg.readout.modes
    timings = []
    for mode in modes:
        if mode == "windows" and not win:
            continue
        timings.append(readout.readout_timing(mode, shape, t_exp, cfg.readout.timing, win))
    if win and "windows" not in modes:
        timings.append(readout.readout_timing("windows", shape, t_exp, cfg.readout.timing, win))
    readout.check_timing(timings, cfg.readout.timing.policy)
    sensor_seed = int(cfg.sensor_seed if cfg.sensor_seed is not None else seed)
    keep = cfg.debug.keep_stages if keep_stages is None else keep_stages
    if mean_charge is not None:
        mean_charge.check(radiance, camera, cfg, t_exp, point_sources, sensor_seed)
        if keep and not mean_charge.stages and mean_charge.position:
            mean_charge = None   # stage copies wanted, and not kept by the first run
    le = (_electron_radiance(radiance, camera) if mean_charge is None
          else mean_charge.image)   # (the radiance was checked by the first run)
    ctx = ChainContext(camera, cfg, t_exp, int(seed), sensor_seed, int(frame_index),
                       {"photoelectrons_e": 0.0, "optics_lost_e": 0.0, "drained_e": 0.0,
                        "left_array_e": 0.0})
    # validate the seeds early (clear message instead of a numpy error mid-chain)
    ctx.temporal("shot_noise")
    stages: dict[str, NDArray[Any]] = {}
    times: dict[str, float] = {}
    img = le
    electrons: Float32Array | None = None
    order = chain_order(cfg.order)
    start, mean_at = 0, first_temporal(order)
    if mean_charge is not None:   # the deterministic part, as the first run made it
        start, img, electrons = mean_charge.position, mean_charge.image, mean_charge.electrons
        ctx.ledger = dict(mean_charge.ledger)
        if keep:
            stages.update(mean_charge.stages)
    kept: MeanCharge | None = None
    for k in range(start, len(order) + 1):
        if k == mean_at and keep_mean_charge:
            if img is le:   # no effect before it: never lock the caller's radiance
                img = img.copy()
            img.flags.writeable = False   # shared with the next acquisition: never changed
            kept = MeanCharge(img, k, dict(ctx.ledger), dict(stages) if keep else {},
                              electrons, radiance, camera, point_sources,
                              _prefix_settings(cfg), t_exp, sensor_seed)
        if k == len(order):
            break
        name = order[k]
        eff = get_effect(name)
        if electrons is None and eff.stage in ("signal", "image"):
            electrons = img
        if eff.enabled(cfg, camera):
            t0 = time.perf_counter()
            img = eff.apply(img, ctx)
            times[name] = (time.perf_counter() - t0) * 1e3
            if keep:
                stages[name] = img.copy()
        if name == POINT_SOURCES_AFTER and point_sources is not None and len(point_sources):
            t0 = time.perf_counter()
            img = add_point_sources(img, ctx, point_sources)
            times["point_sources"] = (time.perf_counter() - t0) * 1e3
            if keep:
                stages["point_sources"] = img.copy()
    if electrons is None:
        electrons = img
    t0 = time.perf_counter()
    dn = readout.adc(img, cfg.gain_e_per_dn, cfg.adc.offset_dn, cfg.adc.bits)
    times["adc"] = (time.perf_counter() - t0) * 1e3
    if keep:
        stages["adc"] = dn.copy()
    t0 = time.perf_counter()
    segs = None
    if "segments" in modes:
        sc = cfg.readout.segments
        segs = readout.extract_segments(dn, sc.thresholds_dn, sc.max_runs, sc.max_pixels)
    wins = readout.read_windows(dn, win) if win else ()
    times["readout"] = (time.perf_counter() - t0) * 1e3
    return Exposure(dn=dn, electrons=electrons, signal=img, segments=segs, windows=wins,
                    timing=tuple(timings), ledger=ctx.ledger, stages=stages, timings_ms=times,
                    exposure_time=t_exp, gain=cfg.gain_e_per_dn, seed=int(seed),
                    sensor_seed=int(sensor_seed), frame_index=int(frame_index), config=cfg,
                    mean_charge=kept)
