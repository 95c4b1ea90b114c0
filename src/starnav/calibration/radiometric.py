"""Radiometric calibration of the bench: screen count <-> Moon flux, calibrated stimuli, and
their validation against the in-orbit exposure of the rendered image.

The steps in full: docs/calibration.md, "4. Radiometric calibration".

Technique
---------
1. Screen electron radiance per count through the camera response and the collimator
   (:class:`~starnav.calibration.screen.ScreenRadiometry`).
2. The Moon's band and electron radiance from the renderer, with the same response
   (:func:`moon_flux`).
3. Mapping: a count stimulates the camera like a Moon of band radiance ``Le_s(n) / eps_moon``
   (:func:`count_flux_mapping`): electrons are matched, not watts.
4. Stimulus: the rendered ``Le`` image over ``k``, pre-warped and turned into counts.
5. Validation (:func:`compare_stimulus`): bench acquisition at ``k t`` against the in-orbit
   exposure at ``t``.

References
----------
Seed paper, "Radiometric Calibration" (steps 1-5, Figs. 14-17) and its ref. 20.

Index
-----
:func:`moon_flux`, :class:`MoonFlux`, :func:`count_flux_mapping`, :class:`CountFluxMapping`,
:func:`screen_limited_k`, :func:`compare_stimulus`, :class:`StimulusComparison`,
:func:`checked_render`, :func:`disc_regions`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from starnav.calibration.bench import Acquisition, Bench, DetectorStage
from starnav.calibration.geometric import (
    ScreenMapping,
    intensity_centroid,
    stimulus_counts,
)
from starnav.calibration.screen import ScreenRadiometry
from starnav.calibration.streams import bench_rng
from starnav.camera import Camera
from starnav.errors import ConfigError
from starnav.radiance import RadianceImage
from starnav.typing import FloatArray

log = logging.getLogger(__name__)

#: A pixel counts as saturated at this share of the full well [-].
SATURATION_FRACTION = 0.999
#: Inner-disc pixels for per-pixel ratios: eroded mask and above this share of the peak [-].
INNER_MIN_FRACTION = 0.2


# =========================================================================== Moon flux
@dataclass(frozen=True)
class MoonFlux:
    """The Moon's flux from a rendered image (same camera response as the screen's).

    Attributes
    ----------
    peak_le, peak_l : float
        Brightest pixel's electron radiance [e- s^-1 m^-2 sr^-1] and band radiance
        [W m^-2 sr^-1].
    electrons_per_joule : float
        ``sum Le / sum L`` over the disc [e- J^-1].
    disc_irradiance : float
        Band irradiance of the whole disc at the camera, ``sum L Omega_pix cos^3`` [W m^-2].
    disc_electron_rate : float
        Photo-electron rate of the whole disc through the pupil, ``sum Le etendue cos^4``
        [e- s^-1].
    peak_electron_rate_px : float
        Brightest pixel's rate ``Le etendue`` [e- s^-1].
    n_pixels : int
        Pixels with signal.
    """

    peak_le: float
    peak_l: float
    electrons_per_joule: float
    disc_irradiance: float
    disc_electron_rate: float
    peak_electron_rate_px: float
    n_pixels: int

    def to_dict(self) -> dict[str, float]:
        return {"peak_le_e_s_m2_sr": self.peak_le, "peak_l_w_m2_sr": self.peak_l,
                "electrons_per_joule_e_j": self.electrons_per_joule,
                "disc_irradiance_w_m2": self.disc_irradiance,
                "disc_electron_rate_e_s": self.disc_electron_rate,
                "peak_electron_rate_px_e_s": self.peak_electron_rate_px,
                "n_pixels": self.n_pixels}


def moon_flux(image: RadianceImage, camera: Camera) -> MoonFlux:
    """Flux figures of a rendered frame (paper radiometric steps 3-4).

    Raises
    ------
    ConfigError
        The image is empty (no Moon in the field).
    """
    L = np.asarray(image.L, float)
    Le = np.asarray(image.Le, float)
    lit = Le > 0
    if not np.any(lit):
        raise ConfigError("radiance image", "no lit pixel", "a frame with the Moon in the field")
    u, v = camera.pixel_grid()
    ri = camera.relative_illumination(u, v)  # cos^4
    cos3 = ri ** 0.75
    return MoonFlux(
        peak_le=float(Le.max()), peak_l=float(L.max()),
        electrons_per_joule=float(Le[lit].sum() / max(L[lit].sum(), 1e-300)),
        disc_irradiance=float((L * cos3).sum() * camera.pixel_solid_angle),
        disc_electron_rate=float((Le * ri).sum() * camera.etendue),
        peak_electron_rate_px=float(Le.max() * camera.etendue), n_pixels=int(lit.sum()))


# =========================================================================== Fig. 14
@dataclass(frozen=True)
class CountFluxMapping:
    """Screen count <-> equivalent Moon flux (paper Fig. 14), on-axis pixel.

    Attributes
    ----------
    counts : (n,) int array
    screen_le : (n,) array
        Electron radiance at the camera [e- s^-1 m^-2 sr^-1].
    screen_l : (n,) array
        The screen's own band radiance at the camera [W m^-2 sr^-1].
    electron_rate_px : (n,) array
        Photo-electron rate of an on-axis pixel [e- s^-1].
    moon_equivalent_l : (n,) array
        Band radiance of a Moon giving the same electrons [W m^-2 sr^-1].
    moon_equivalent_flux_px : (n,) array
        That Moon's radiant flux density collected by one pixel, ``L_eq Omega_pix`` [W m^-2].
    moon_electrons_per_joule : float
        ``eps_moon`` used [e- J^-1].
    """

    counts: NDArray[np.int64]
    screen_le: FloatArray
    screen_l: FloatArray
    electron_rate_px: FloatArray
    moon_equivalent_l: FloatArray
    moon_equivalent_flux_px: FloatArray
    moon_electrons_per_joule: float

    def count_for_moon_radiance(self, l_moon: ArrayLike) -> FloatArray:
        """Continuous count for a Moon band radiance [W m^-2 sr^-1] (NaN above full white)."""
        x = np.asarray(l_moon, float)
        out = np.interp(x, self.moon_equivalent_l, self.counts.astype(float))
        return np.where(x > self.moon_equivalent_l[-1] * (1 + 1e-12), np.nan, out)

    def to_dict(self) -> dict[str, Any]:
        return {"counts": self.counts.tolist(), "screen_le_e_s_m2_sr": self.screen_le.tolist(),
                "screen_l_w_m2_sr": self.screen_l.tolist(),
                "electron_rate_px_e_s": self.electron_rate_px.tolist(),
                "moon_equivalent_l_w_m2_sr": self.moon_equivalent_l.tolist(),
                "moon_equivalent_flux_px_w_m2": self.moon_equivalent_flux_px.tolist(),
                "moon_electrons_per_joule_e_j": self.moon_electrons_per_joule}


def count_flux_mapping(radiometry: ScreenRadiometry, camera: Camera,
                       moon_electrons_per_joule: float) -> CountFluxMapping:
    """The count <-> Moon-flux table (paper step 5, Fig. 14).

    Parameters
    ----------
    radiometry : ScreenRadiometry
    camera : Camera
        Gives the pixel etendue and solid angle.
    moon_electrons_per_joule : float
        ``Le / L`` of the rendered Moon [e- J^-1] (:attr:`MoonFlux.electrons_per_joule`).
    """
    if not (math.isfinite(moon_electrons_per_joule) and moon_electrons_per_joule > 0):
        raise ConfigError("moon_electrons_per_joule", moon_electrons_per_joule,
                          "a finite e-/J > 0 (from the rendered Le / L)")
    le = radiometry.le_lut
    l_eq = le / moon_electrons_per_joule
    return CountFluxMapping(np.arange(radiometry.max_count + 1), le, radiometry.l_lut,
                            le * camera.etendue, l_eq, l_eq * camera.pixel_solid_angle,
                            float(moon_electrons_per_joule))


# =========================================================================== comparison
def screen_limited_k(peak_le: float, radiometry: ScreenRadiometry, headroom: float) -> float:
    """Smallest albedo-exposure factor for which the stimulus peak fits under ``headroom`` x
    full white (at least 1) [-]."""
    return max(1.0, float(peak_le) / (headroom * radiometry.le_max))


@dataclass
class StimulusComparison:
    """A rendered image exposed in orbit, and its calibrated stimulus acquired on the bench.

    Attributes
    ----------
    le_orbit : (H, W) array
        Rendered pinhole electron radiance [e- s^-1 m^-2 sr^-1].
    counts : (rows, cols) uint16
        Screen stimulus.
    k : float
        Albedo-exposure factor ``t_bench / t_render`` [-].
    render_exposure_s, bench_exposure_s : float
        [s]
    orbit_dn, orbit_dark_dn, orbit_electrons : (H, W) arrays
        In-orbit exposure [DN], its dark frame [DN], collected charge [e-].
    bench : Acquisition
    bench_dark_dn : (H, W) array
    gain, full_well_e : float
        [e-/DN], [e-]
    region, inner : (H, W) bool
        The Moon mask dilated by ``disc_margin_px``; eroded and brighter than
        :data:`INNER_MIN_FRACTION` of the peak.
    """

    le_orbit: FloatArray
    counts: NDArray[np.uint16]
    k: float
    render_exposure_s: float
    bench_exposure_s: float
    orbit_dn: FloatArray
    orbit_dark_dn: FloatArray
    orbit_electrons: FloatArray
    bench: Acquisition
    bench_dark_dn: FloatArray
    gain: float
    full_well_e: float
    region: NDArray[np.bool_]
    inner: NDArray[np.bool_]

    @property
    def orbit_signal_e(self) -> FloatArray:
        """Dark-subtracted in-orbit signal [e-]."""
        return (self.orbit_dn - self.orbit_dark_dn) * self.gain

    @property
    def bench_signal_e(self) -> FloatArray:
        """Dark-subtracted bench signal [e-]."""
        return (self.bench.dn - self.bench_dark_dn) * self.gain

    def metrics(self) -> dict[str, Any]:
        """Disc ratio, per-pixel ratios, saturation, centroids and their offset."""
        so, sb = self.orbit_signal_e, self.bench_signal_e
        tot_o = float(so[self.region].sum())
        tot_b = float(sb[self.region].sum())
        with np.errstate(divide="ignore", invalid="ignore"):
            r = sb[self.inner] / so[self.inner]
        r = r[np.isfinite(r)]
        co = intensity_centroid(so, self.region)
        cb = intensity_centroid(sb, self.region)
        sat = SATURATION_FRACTION * self.full_well_e
        nz = self.counts[self.counts > 0]
        return {
            "k": self.k, "render_exposure_s": self.render_exposure_s,
            "bench_exposure_s": self.bench_exposure_s,
            "disc_electrons_orbit": tot_o, "disc_electrons_bench": tot_b,
            "disc_ratio": tot_b / tot_o if tot_o > 0 else float("nan"),
            "inner_pixels": int(self.inner.sum()),
            "inner_median_ratio": float(np.median(r)) if r.size else float("nan"),
            "inner_p95_abs_deviation": (float(np.percentile(np.abs(r - 1.0), 95)) if r.size
                                        else float("nan")),
            "saturated_pixels_orbit": int(np.count_nonzero(self.orbit_electrons >= sat)),
            "saturated_pixels_bench": int(np.count_nonzero(self.bench.electrons >= sat)),
            "peak_count": int(self.counts.max()) if self.counts.size else 0,
            "median_lit_count": float(np.median(nz)) if nz.size else 0.0,
            "centroid_orbit_px": co.tolist(), "centroid_bench_px": cb.tolist(),
            "centroid_offset_px": float(np.hypot(*(cb - co))),
        }


def checked_render(le: ArrayLike | RadianceImage, render_exposure_s: float) -> FloatArray:
    """The rendered radiance of a stimulus comparison as an array, refused when it holds no
    Moon or its exposure is not positive (:class:`~starnav.errors.ConfigError`)."""
    img = np.asarray(le.Le if isinstance(le, RadianceImage) else le, float)
    if not np.any(img > 0):
        raise ConfigError("radiance image Le", "all zero", "a frame with the Moon in the field")
    if not (math.isfinite(render_exposure_s) and render_exposure_s > 0):
        raise ConfigError("render_exposure_s", render_exposure_s, "an exposure > 0 s")
    return img


def disc_regions(img: FloatArray, margin_px: int) -> tuple[NDArray[np.bool_],
                                                           NDArray[np.bool_]]:
    """``(region, inner)`` of a comparison: the lit disc grown by ``margin_px`` (where the
    disc's electrons are summed) and the inner disc (3 px in from the limb, above
    :data:`INNER_MIN_FRACTION` of the peak: the per-pixel ratios)."""
    lit = img > 0
    region = ndimage.binary_dilation(lit, iterations=margin_px) if margin_px > 0 else lit
    inner = ndimage.binary_erosion(lit, iterations=3) & (img > INNER_MIN_FRACTION * img.max())
    return region, inner


def compare_stimulus(bench: Bench, le: ArrayLike | RadianceImage, render_exposure_s: float,
                     mapping: ScreenMapping, detector: DetectorStage | None = None, *,
                     bench_exposure_s: float | None = None,
                     le_displayed: ArrayLike | RadianceImage | None = None,
                     rng: np.random.Generator | None = None,
                     frame_base: int = 200) -> StimulusComparison:
    """Expose a rendered image in orbit and its calibrated stimulus on the bench (module essay,
    steps 4-5).

    Parameters
    ----------
    bench : Bench
    le : (H, W) array or RadianceImage
        Rendered pinhole electron radiance at the true albedo [e- s^-1 m^-2 sr^-1].
    render_exposure_s : float
        In-orbit exposure [s].
    mapping : ScreenMapping
        Geometric calibration (or :class:`~starnav.calibration.geometric.NominalMapping` for an
        uncalibrated display, :class:`~starnav.calibration.geometric.TrueMapping` as oracle).
    detector : DetectorStage, optional
        Default: the scenario's chain.
    bench_exposure_s : float, optional
        Bench exposure [s]; default the screen-limited ``k`` (peak at ``headroom_fraction`` of
        full white).
    le_displayed : array or RadianceImage, optional
        Image to display, e.g. rendered with albedo / k; default ``le / k`` (the renderer is
        linear in albedo).
    rng : numpy.random.Generator, optional
        Dithering stream; default the bench's ``"stimulus"`` stream.
    frame_base : int
        First of the four frame indices used (orbit, orbit dark, bench, bench dark).

    Raises
    ------
    ConfigError
        Empty image, non-positive exposure, or a stimulus brighter than the screen.
    """
    det = detector if detector is not None else bench.chain_detector()
    img = checked_render(le, render_exposure_s)
    rad = bench.radiometry
    cfg = bench.config.radiometric
    if bench_exposure_s is None:
        k = screen_limited_k(float(img.max()), rad, cfg.headroom_fraction)
        bench_exposure_s = k * render_exposure_s
    k = float(bench_exposure_s) / render_exposure_s
    if le_displayed is None:
        disp, scale = img, 1.0 / k
    else:
        disp = np.asarray(le_displayed.Le if isinstance(le_displayed, RadianceImage)
                          else le_displayed, float)
        scale = 1.0
    rng = rng if rng is not None else bench_rng(bench.config, "stimulus")
    counts = stimulus_counts(disp, mapping, bench, scale, cfg.quantization, rng)
    orbit = det.expose(img, render_exposure_s, frame_base)
    orbit_dark = det.expose(np.zeros_like(img), render_exposure_s, frame_base + 1)
    acq = bench.acquire(counts, bench_exposure_s, det, frame_base + 2)
    bench_dark = bench.acquire(np.zeros_like(counts), bench_exposure_s, det, frame_base + 3)
    region, inner = disc_regions(img, cfg.disc_margin_px)
    return StimulusComparison(img, counts, k, float(render_exposure_s), float(bench_exposure_s),
                              orbit.dn, orbit_dark.dn, orbit.electrons, acq, bench_dark.dn,
                              det.gain_e_per_dn, det.full_well_e, region, inner)


__all__ = ["CountFluxMapping", "MoonFlux", "StimulusComparison", "checked_render",
           "compare_stimulus", "count_flux_mapping", "disc_regions", "moon_flux",
           "screen_limited_k"]
