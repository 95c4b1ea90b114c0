"""The bench as it really is, radiometrically, and the instrument a lab calibrates it against.

:class:`~starnav.calibration.screen.ScreenRadiometry` is the screen's datasheet (Lambertian,
uniform, stable, nominal gamma, catalogue transmission). :class:`TruthScreen` is what the camera
really receives; :class:`ReferenceInstrument` is the calibrated spectroradiometer that reads it,
with its own errors: :mod:`starnav.calibration.radiometric_lab` sees the truth only through it.

Technique
---------
1. **Truth radiance at the camera**, pixel ``(u, v)``, time ``t`` after power-on, count ``n``:

   ``Le = D(t) tau 10^-OD U(x, y) sum_c A_c g_c(n) K_c + Le_amb``

   ``K_c`` the channel's full-count radiance through the camera response;
   ``g_c(n) = b + (1 - b) (n / n_max)^gamma_c`` (per-channel gammas, black level ``b``);
   ``A_c`` the pupil mean of ``cos^p_c`` of the emission angle (a ray reaching pupil point
   ``q`` at distance ``d`` behind a collimator of focal length ``f`` left screen point ``r`` at
   tangent ``(q + d r / f - r) / f``); ``U`` a smooth random field (degree <= 3) times a
   pixel-level scatter; ``D(t) = (1 - a e^{-t / tau_w}) (1 + s t)`` warm-up and drift; ``tau``
   the as-built transmission; ``Le_amb`` stray light.
2. **The reference instrument** reads spectral radiance at the camera's place (or at the bare
   screen), averaged over its aperture and acceptance cone, with its specification's errors:
   an absolute scale per luminance class, a wavelength shift, a responsivity tilt, a
   repeatability per reading. The lab converts readings with the camera's nominal response.

Index
-----
:class:`TruthScreen` (uniform fields :meth:`~TruthScreen.camera_image`, any screen image
:meth:`~TruthScreen.radiance_at_camera`), :class:`ReferenceInstrument`, :class:`Reading`.

Reference: seed paper, "Radiometric Calibration"; docs/facts.md section 7 for the defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage
from scipy.interpolate import RectBivariateSpline

from starnav.calibration.bench import Bench, field_varying_blur
from starnav.calibration.schema import KM_LM_PER_W, photopic_efficiency
from starnav.calibration.streams import STREAMS
from starnav.errors import ConfigError
from starnav.seeding import STAGE_HIL, generator
from starnav.typing import FloatArray

#: Step of the exact grid of the truth's smooth factors in a full image [camera px].
IMAGE_GRID_PX = 16
#: Polynomial terms of the smooth non-uniformity field over the normalised screen [-].
_FIELD_TERMS = ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))


def _pupil_samples(radius: float, rings: int = 3) -> FloatArray:
    """Equal-area sample points ``(N, 2)`` over a disc of ``radius`` [m]."""
    pts = [np.zeros(2)]
    for k in range(1, rings + 1):
        r = radius * math.sqrt((k - 0.5) / rings)
        m = 6 * k
        a = 2 * math.pi * (np.arange(m) + 0.5 * (k % 2)) / m
        pts.extend(np.stack([r * np.cos(a), r * np.sin(a)], -1))
    return np.array(pts)


#: Integration step of the spectral products [nm] (fine against the response's band edges).
SPECTRAL_STEP_NM = 0.25


def _spectral_tables(bench: Bench) -> tuple[FloatArray, FloatArray]:
    """The screen's channel spectra resampled every :data:`SPECTRAL_STEP_NM` (linear)."""
    em = bench.config.screen.emittance
    if em is None:
        raise ConfigError("screen.emittance", None, "per-channel spectral radiance tables (the "
                          "radiometric truth and the reference instrument need the spectrum)")
    wl0 = np.asarray(em.wavelengths_nm, float)
    wl = np.arange(wl0[0], wl0[-1] + 0.5 * SPECTRAL_STEP_NM, SPECTRAL_STEP_NM)
    return wl, np.array([np.interp(wl, wl0, c) for c in em.channels()])


class TruthScreen:
    """The screen and collimator the camera really sees (module essay, step 1).

    Parameters
    ----------
    bench : Bench
    rng : numpy.random.Generator, optional
        Stream of the drawn departures; default the bench's ``"truth"`` stream with
        ``radiometric_truth.truth_seed`` added to the seed.
    points_cache : dict, optional
        Screen points of pinhole pixels already solved on this bench's geometry (shared by
        several truths drawn on one bench).
    """

    def __init__(self, bench: Bench, rng: np.random.Generator | None = None,
                 points_cache: dict[bytes, FloatArray] | None = None) -> None:
        self._points: dict[bytes, FloatArray] = {} if points_cache is None else points_cache
        self._base: FloatArray | None = None
        self._screen_scatter: FloatArray | None = None
        cfg = bench.config
        t = cfg.radiometric_truth
        self.bench = bench
        self.config = t
        wl, spectra = _spectral_tables(bench)
        self.wavelengths = wl
        self.spectra = spectra
        s_e = bench.response.electrons_per_joule()(wl)
        #: Channel electron radiance of the bare screen at full count [e- s^-1 m^-2 sr^-1].
        self.k_e = np.trapezoid(spectra * s_e, wl, axis=1)
        #: Channel luminance of the bare screen at full count [cd m^-2].
        self.k_v = KM_LM_PER_W * np.trapezoid(spectra * photopic_efficiency(wl), wl, axis=1)
        em = cfg.screen.emittance
        assert em is not None
        rng = rng if rng is not None else generator(
            int(cfg.seed) + int(t.truth_seed), STAGE_HIL, STREAMS.get("truth"))
        # every draw is made, in a fixed order, whether or not the truth is enabled
        d_gamma = rng.normal(0.0, t.gamma_sigma, 3)
        d_tau = rng.uniform(-t.transmission_tolerance, t.transmission_tolerance)
        coeffs = rng.standard_normal(len(_FIELD_TERMS))
        drift = rng.normal(0.0, t.drift_per_hour) / 3600.0
        self.pixel_seed = int(rng.integers(0, 2**31 - 1))
        on = t.enabled
        self.gamma = np.asarray(em.gamma, float) + (d_gamma if on else 0.0)
        self.angular_exponent = np.asarray(t.angular_exponent, float) * on
        self.transmission = cfg.collimator.transmission * (1.0 + (d_tau if on else 0.0))
        self.nd = 10.0 ** (-cfg.collimator.nd_optical_density)
        self.black_level = t.black_level_fraction if on else em.black_level_fraction
        self.ambient_fraction = t.ambient_fraction if on else 0.0
        self.warmup_amplitude = t.warmup_amplitude if on else 0.0
        self.warmup_tau = t.warmup_time_constant_min * 60.0
        self.drift_rate = drift if on else 0.0
        self.pixel_rms = t.pixel_nonuniformity_rms if on else 0.0
        # smooth field normalised to the stated rms over the screen
        g = np.linspace(-1, 1, 41)
        X, Y = np.meshgrid(g, g)
        basis = np.stack([X**a * Y**b for a, b in _FIELD_TERMS])
        raw = np.tensordot(coeffs, basis, 1)
        raw -= raw.mean()
        rms = float(np.sqrt(np.mean(raw**2)))
        self._field_coeffs = (coeffs * (t.smooth_nonuniformity_rms / rms if on and rms > 0
                                        else 0.0))
        self._field_mean = float(np.tensordot(self._field_coeffs, basis, 1).mean())
        geo = bench.geometry
        self._half = (geo.shape[1] * geo.pitch / 2.0, geo.shape[0] * geo.pitch / 2.0)
        self._cam_pupil = _pupil_samples(bench.camera.pupil_diameter / 2.0)
        self._pupil_distance = cfg.collimator.pupil_distance_mm * 1e-3

    # ............................................................ pieces of the truth
    def level(self, counts: ArrayLike) -> FloatArray:
        """``g_c(n)``: relative output of each channel ``(..., 3)`` at grey counts [-]."""
        n = np.asarray(counts, float)[..., None] / self.bench.config.screen.max_count
        b = self.black_level
        return b + (1.0 - b) * np.clip(n, 0.0, None) ** self.gamma

    def luminance_factor(self, time_s: ArrayLike) -> FloatArray:
        """``D(t)``: warm-up and drift at ``time_s`` after power-on [-]."""
        t = np.asarray(time_s, float)
        return (1.0 - self.warmup_amplitude * np.exp(-t / self.warmup_tau)) * (
            1.0 + self.drift_rate * t)

    def field(self, xy_m: ArrayLike) -> FloatArray:
        """``U``: smooth non-uniformity at screen points ``(..., 2)`` [m] from the centre
        [-] (mean 1 over the screen)."""
        p = np.asarray(xy_m, float)
        x = p[..., 0] / self._half[0]
        y = p[..., 1] / self._half[1]
        v = sum(c * x**a * y**b for c, (a, b) in zip(self._field_coeffs, _FIELD_TERMS,
                                                    strict=True))
        return 1.0 + v - self._field_mean

    def angular(self, points_m: ArrayLike, pupil_m: ArrayLike) -> FloatArray:
        """``A_c``: mean over a receiving pupil ``(K, 2)`` [m] of ``cos^p_c`` of the emission
        angle, for screen points ``(..., 3)`` in the collimator frame [m] -> ``(..., 3)``."""
        P = np.asarray(points_m, float)
        q = np.asarray(pupil_m, float)
        f = self.bench.geometry.focal_length
        d = self._pupil_distance
        r = P[..., None, :2]                                    # (..., 1, 2)
        lens = q + d * r / f                                    # (..., K, 2)
        tan = (lens - r) / (f - P[..., None, 2:3])
        cos2 = 1.0 / (1.0 + (tan * tan).sum(-1))                # (..., K)
        p = self.angular_exponent
        return (cos2[..., None] ** (p / 2.0)).mean(-2)

    def ambient_weights(self) -> FloatArray:
        """Stray light in the enclosure as multipliers of the channels' full-count spectra
        ``(3,)`` (white spectrum; a share of the nominal full white) [-]."""
        return np.full(3, self.ambient_fraction * self.bench.config.collimator.transmission
                       * self.nd)

    # ............................................................ what arrives
    def screen_points(self, uv: ArrayLike) -> FloatArray:
        """Screen points ``(..., 3)`` in the collimator frame seen at pinhole pixels
        ``uv (..., 2)`` [m] (solved once per set of pixels)."""
        uv = np.ascontiguousarray(uv, float)
        key = uv.tobytes() + bytes(str(uv.shape), "ascii")
        P = self._points.get(key)
        if P is None:
            geo = self.bench.geometry
            P = geo.screen_points(geo.pixel_to_screen(uv))
            if uv.size <= 4096:
                self._points[key] = P
        return P

    def channel_weights(self, counts: ArrayLike, uv: ArrayLike, time_s: ArrayLike,
                        pupil_m: ArrayLike | None = None, through_collimator: bool = True
                        ) -> FloatArray:
        """Multipliers ``(..., 3)`` of each channel's full-count spectral radiance ``S_c``
        arriving towards pinhole pixels ``uv (..., 2)`` (ambient included) [-].

        ``counts`` and ``time_s`` broadcast against ``uv[..., 0]``; ``pupil_m`` is the
        receiving aperture's sample points (default: the camera's pupil);
        ``through_collimator`` False gives the bare screen (no transmission, no ND).
        """
        P = self.screen_points(uv)
        pup = self._cam_pupil if pupil_m is None else np.asarray(pupil_m, float)
        tx = self.transmission * self.nd if through_collimator else 1.0
        amb = self.ambient_weights() * (1.0 if through_collimator else 0.0)
        w = (tx * self.luminance_factor(time_s)[..., None] * self.field(P[..., :2])[..., None]
             * self.angular(P, pup) * self.level(counts))
        return w + amb

    def electron_radiance(self, counts: ArrayLike, uv: ArrayLike, time_s: ArrayLike
                          ) -> FloatArray:
        """True electron radiance at the camera towards pinhole pixels ``uv`` [e- s^-1 m^-2
        sr^-1] (without the pixel-level scatter: see :meth:`pixel_scatter`)."""
        return self.channel_weights(counts, uv, time_s) @ self.k_e

    def pixel_scatter(self, shape: tuple[int, ...], average_px: float = 1.0) -> FloatArray:
        """Relative screen-pixel scatter seen by camera pixels (fixed pattern, seeded) [-].

        A camera pixel integrates ``1 / s^2`` screen pixels (``s`` the screen pixel size on
        the detector); an average over ``average_px`` camera pixels divides it further.
        """
        s = self.bench.geometry.screen_pixel_scale()
        sigma = self.pixel_rms * min(1.0, s) / math.sqrt(max(average_px, 1.0))
        rng = np.random.default_rng(self.pixel_seed)
        return sigma * rng.standard_normal(shape)

    def camera_image(self, count: int, time_s: float) -> FloatArray:
        """Pinhole electron-radiance image ``(H, W)`` of a uniform grey ``count`` (what the
        detector stage exposes) [e- s^-1 m^-2 sr^-1]."""
        base = self._image_base()                               # (H, W, 3): tau U A_c
        lev = self.level(count) * self.k_e                      # (3,)
        le = float(self.luminance_factor(time_s)) * (base @ lev)
        le += float(self.ambient_weights() @ self.k_e)
        scatter = self.pixel_scatter(le.shape)
        return le * (1.0 + scatter * (count > 0))

    def screen_pixel_scatter(self, rows: ArrayLike, cols: ArrayLike) -> FloatArray:
        """Relative luminance scatter of screen pixels ``(rows, cols)`` in the bench's screen
        window (the fixed pattern whose average over a camera pixel is
        :meth:`pixel_scatter`; seeded) [-]."""
        j0, i0, j1, i1 = self.bench.screen_window
        if self._screen_scatter is None:
            rng = np.random.default_rng(self.pixel_seed)
            self._screen_scatter = self.pixel_rms * rng.standard_normal((i1 - i0, j1 - j0))
        r = np.asarray(rows) - i0
        c = np.asarray(cols) - j0
        inside = (r >= 0) & (r < i1 - i0) & (c >= 0) & (c < j1 - j0)
        return np.where(inside, self._screen_scatter[np.clip(r, 0, i1 - i0 - 1),
                                                     np.clip(c, 0, j1 - j0 - 1)], 0.0)

    def radiance_at_camera(self, counts: ArrayLike, time_s: float) -> FloatArray:
        """Pinhole electron-radiance image ``(H, W)`` of a grey screen image ``counts (rows,
        cols)`` shown at ``time_s`` after power-on [e- s^-1 m^-2 sr^-1] (module essay, step 1,
        for a non-uniform image).

        Every lit screen pixel at point ``r`` radiates ``D(t) tau 10^-OD U(r) (1 + s_ij)
        sum_c A_c(r) (g_c(n) - g_c(0)) K_c`` above the black screen, carried to the camera by
        the bench's geometry, vignetting and spot (:meth:`Bench.screen_to_camera`); the black
        screen and the stray light are the pedestal of :meth:`camera_image` at count 0.
        """
        bench = self.bench
        c = np.asarray(counts)
        if c.shape != bench.screen_shape:
            raise ConfigError("screen counts", f"shape {c.shape}",
                              f"the screen's {bench.screen_shape} grey counts (rows, cols)")
        j0, i0, j1, i1 = bench.screen_window
        sub = bench.radiometry.check_counts(c) if not np.issubdtype(c.dtype, np.unsignedinteger) \
            or int(c.max()) > bench.config.screen.max_count else c
        ii, jj = np.nonzero(sub[i0:i1, j0:j1] > 0)
        ii, jj = ii + i0, jj + j0
        screen = np.zeros(c.shape)
        if ii.size:
            amp = self._screen_base(ii, jj) * (self.level(c[ii, jj]) - self.level(0))
            screen[ii, jj] = (amp @ self.k_e) * (1.0 + self.screen_pixel_scatter(ii, jj))
        le = bench.screen_to_camera(screen) * (
            self.transmission * self.nd * float(self.luminance_factor(time_s)))
        acq = bench.config.acquisition
        if acq.include_spot_psf:
            le = field_varying_blur(le, bench.sigma_map, acq.psf_levels)
        return np.maximum(le, 0.0) + self.camera_image(0, time_s)

    def _screen_base(self, rows: FloatArray, cols: FloatArray) -> FloatArray:
        """``U A_c`` of screen pixels ``(N,)`` -> ``(N, 3)``: exact on a grid every
        :data:`IMAGE_GRID_PX` screen pixels over their box, bilinear in between (smooth)."""
        s = IMAGE_GRID_PX
        i0, j0 = int(rows.min()), int(cols.min())
        ni = (int(rows.max()) - i0) // s + 2
        nj = (int(cols.max()) - j0) // s + 2
        J_, I_ = np.meshgrid(j0 + s * np.arange(nj, dtype=float),
                             i0 + s * np.arange(ni, dtype=float))
        P = self.bench.geometry.screen_points(np.stack([J_, I_], -1))
        grid = self.field(P[..., :2])[..., None] * self.angular(P, self._cam_pupil)
        coords = [(np.asarray(rows) - i0) / s, (np.asarray(cols) - j0) / s]
        return np.stack([ndimage.map_coordinates(grid[..., k], coords, order=1,
                                                 mode="nearest") for k in range(3)], -1)

    def _image_base(self) -> FloatArray:
        """``tau 10^-OD U A_c`` at every pixel ``(H, W, 3)``: exact on a grid every
        :data:`IMAGE_GRID_PX` pixels, bicubic in between (both factors are smooth)."""
        if self._base is None:
            cam = self.bench.camera
            us = np.unique(np.r_[np.arange(0, cam.width, IMAGE_GRID_PX), cam.width - 1])
            vs = np.unique(np.r_[np.arange(0, cam.height, IMAGE_GRID_PX), cam.height - 1])
            U, V = np.meshgrid(us.astype(float), vs.astype(float))
            P = self.screen_points(np.stack([U, V], -1))
            coarse = self.field(P[..., :2])[..., None] * self.angular(P, self._cam_pupil)
            rows = np.arange(cam.height, dtype=float)
            cols = np.arange(cam.width, dtype=float)
            base = np.empty((cam.height, cam.width, 3))
            k = min(3, len(us) - 1, len(vs) - 1)
            for c in range(3):
                base[..., c] = RectBivariateSpline(vs, us, coarse[..., c], kx=k, ky=k)(rows,
                                                                                      cols)
            self._base = base * self.transmission * self.nd
        return self._base

    def summary(self) -> dict[str, object]:
        """The drawn departures (JSON-safe)."""
        return {"gamma": self.gamma.tolist(), "transmission": self.transmission,
                "angular_exponent": self.angular_exponent.tolist(),
                "black_level_fraction": self.black_level,
                "ambient_fraction": self.ambient_fraction,
                "warmup_amplitude": self.warmup_amplitude,
                "warmup_time_constant_s": self.warmup_tau,
                "drift_per_hour": self.drift_rate * 3600.0,
                "smooth_field_coefficients": self._field_coeffs.tolist(),
                "pixel_nonuniformity_rms": self.pixel_rms}


@dataclass(frozen=True)
class Reading:
    """One reference reading converted to the camera's electron radiance.

    Attributes
    ----------
    le : float
        Measured electron radiance [e- s^-1 m^-2 sr^-1].
    luminance : float
        Measured luminance [cd m^-2] (selects the accuracy class).
    level_class : int
        0, 1, 2 from the lowest class; -1 below the instrument's range.
    time_s : float
        When it was taken (after power-on) [s].

    A luminance below the instrument's range reads 0 with class -1; its uncertainty is the
    range's floor (:meth:`ReferenceInstrument.floor_le`).
    """

    le: float
    luminance: float
    level_class: int
    time_s: float


class ReferenceInstrument:
    """A calibrated spectroradiometer (module essay, step 2).

    Parameters
    ----------
    bench : Bench
    truth : TruthScreen
    rng : numpy.random.Generator, optional
        Stream of the instrument's own errors and noise; default the bench's ``"reference"``
        stream (seed + ``radiometric_truth.truth_seed``).
    error_scale : float
        The instrument's real errors in units of its specification (1: as certified; > 1 an
        instrument worse than its certificate, for tests of the budget itself).
    """

    def __init__(self, bench: Bench, truth: TruthScreen,
                 rng: np.random.Generator | None = None, error_scale: float = 1.0) -> None:
        cfg = bench.config.reference_instrument
        self.config = cfg
        self.truth = truth
        self.bench = bench
        seed = int(bench.config.seed) + int(bench.config.radiometric_truth.truth_seed)
        self.rng = rng if rng is not None else generator(seed, STAGE_HIL,
                                                         STREAMS.get("reference"))
        acc = np.asarray(cfg.accuracy_2sigma) / 2.0 * error_scale
        # absolute scale of each class: the top class's error, plus what the lower classes add
        z = self.rng.standard_normal(3)
        extra = np.sqrt(np.clip(acc**2 - np.concatenate([acc[1:], [0.0]])**2, 0.0, None))
        e2 = acc[2] * z[2]
        e1 = e2 + extra[1] * z[1]
        e0 = e1 + extra[0] * z[0]
        self.scale_error = np.array([e0, e1, e2])
        self.wavelength_shift_nm = float(self.rng.normal(
            0.0, cfg.wavelength_2sigma_nm / 2.0 * error_scale))
        self.tilt = float(self.rng.normal(0.0, cfg.spectral_tilt_2sigma / 2.0 * error_scale))
        self.error_scale = float(error_scale)
        self.k_measured = self.channel_factors(self.wavelength_shift_nm, self.tilt)
        self._pupil = _pupil_samples(cfg.aperture_mm * 1e-3 / 2.0, rings=2)

    def channel_factors(self, shift_nm: float = 0.0, tilt: float = 0.0) -> FloatArray:
        """What the lab computes as each channel's camera electron radiance per unit weight
        from a spectrum read with a wavelength shift and a responsivity tilt ``(3,)``
        [e- s^-1 m^-2 sr^-1]. Zero shift and tilt give the truth's ``K_c`` over the band."""
        tr = self.truth
        lo, hi = self.config.band_nm
        wl = tr.wavelengths
        s_e = self.bench.response.electrons_per_joule()
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        # the instrument reports L(lambda - shift) with responsivity (1 + tilt x)
        lam = wl + shift_nm
        resp = 1.0 + tilt * (lam - mid) / half
        inband = (lam >= lo) & (lam <= hi)
        return np.trapezoid(tr.spectra * (s_e(lam) * resp * inband), wl, axis=1)

    def level_class(self, luminance: float) -> int:
        """Accuracy class of a luminance [cd m^-2] (-1: below range)."""
        b = self.config.level_bounds_cd_m2
        if luminance < b[0]:
            return -1
        return 0 if luminance < b[1] else (1 if luminance < b[2] else 2)

    def floor_le(self) -> float:
        """Electron radiance of the white spectrum at the bottom of the range [e- s^-1 m^-2
        sr^-1] (the uncertainty of a reading below range)."""
        tr = self.truth
        return float(self.config.level_bounds_cd_m2[0] * tr.k_e.sum() / tr.k_v.sum())

    def relative_sigma(self, luminance: float, readings: int = 1) -> tuple[float, float]:
        """Stated 1-sigma ``(absolute scale, repeatability of the mean of readings)`` [-]."""
        c = max(self.level_class(luminance), 0)
        return (self.config.accuracy_2sigma[c] / 2.0,
                self.config.repeatability_2sigma[c] / 2.0 / math.sqrt(readings))

    def read(self, count: int, uv: ArrayLike, time_s: float,
             through_collimator: bool = True) -> Reading:
        """One reading of a uniform grey ``count`` towards pinhole pixel ``uv`` at ``time_s``
        after power-on, averaged over the instrument's aperture and acceptance cone (below
        the instrument's range: a zero reading of class -1)."""
        uv = np.asarray(uv, float).reshape(2)
        cam = self.bench.camera
        r_px = math.tan(math.radians(self.config.acceptance_deg)) * cam.fx
        a = np.linspace(0, 2 * math.pi, 8, endpoint=False)
        field = np.concatenate([[uv], uv + 0.6 * r_px * np.stack([np.cos(a), np.sin(a)], -1)])
        w = self.truth.channel_weights(count, field, time_s, self._pupil,
                                       through_collimator).mean(0)
        lum = float(w @ self.truth.k_v)
        cls = self.level_class(lum)
        if cls < 0:
            # below the range the instrument shows nothing: the lab records zero
            return Reading(0.0, 0.0, -1, float(time_s))
        rep = self.config.repeatability_2sigma[cls] / 2.0 * self.error_scale
        le = float(w @ self.k_measured) * (1.0 + self.scale_error[cls]) * (
            1.0 + rep * self.rng.standard_normal())
        return Reading(le, lum * (1.0 + self.scale_error[cls]), cls, float(time_s))

    def summary(self) -> dict[str, object]:
        return {"scale_error_by_class": self.scale_error.tolist(),
                "wavelength_shift_nm": self.wavelength_shift_nm, "spectral_tilt": self.tilt}


__all__ = ["Reading", "ReferenceInstrument", "TruthScreen"]
