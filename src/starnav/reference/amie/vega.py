"""The AMIE's absolute efficiency and its PSF, measured on a star: Vega in frame 040326.

The user manual gives the efficiency only as "> 15 % at 640 nm" and the PSF is not published;
both are measured on the data set's one stellar frame (:data:`VEGA_FRAME`), not on the Moon
frames that score the simulation:

1. Measured signal: the frame calibrated like the Moon frames, Vega's aperture photometry with
   a flat growth curve (:func:`star_photometry`).
2. Predicted signal: Vega's CALSPEC spectrum (Bohlin 2014) through the AMIE aperture and its
   measured NONE-filter curve (:func:`vega_spectrum`, :func:`photon_rate`).
3. Efficiency: the flat QE that makes the two equal.
4. PSF core: a pixel-integrated circular Gaussian fitted within ``psf_fit_px``.

``tools/calibrate_amie_vega.py`` writes the packaged :data:`VEGA_CALIBRATION_FILE`;
:func:`stellar_calibration` recomputes it (a test checks they agree).

References
----------
R. C. Bohlin (2014), "Hubble Space Telescope CALSPEC flux standards: Sirius (and Vega)",
AJ 147, 127.

Index
-----
:func:`stellar_calibration`, :class:`StellarCalibration`, :func:`load_calibration`,
:func:`write_calibration`, :func:`star_photometry`, :func:`vega_spectrum`, :func:`photon_rate`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, special

from starnav.camera import Camera
from starnav.data import packaged_path
from starnav.errors import StarnavError
from starnav.reference.amie.frame import calibrate, packaged_frame, read_amie
from starnav.spectra import AMIE_RESPONSE_SCALE, AMIE_RESPONSE_TABLE
from starnav.typing import FloatArray

#: The stellar frame of the data set (Vega, 200 ms).
VEGA_FRAME = "040326_00034"
#: Packaged result of :func:`stellar_calibration` (package-relative).
VEGA_CALIBRATION_FILE = "amie/vega_calibration.json"
#: CALSPEC flavour of Vega's spectrum in ``pyphot``.
VEGA_CALSPEC = "stis_011"

_H = 6.62607015e-34
_C = 2.99792458e8


@dataclass(frozen=True)
class StellarCalibration:
    """What the Vega frame gives (units in the names)."""

    frame: str
    exposure_s: float
    gain_e_per_dn: float
    centroid_px: tuple[float, float]
    aperture_px: float
    sky_annulus_px: tuple[float, float]
    sky_dn: float
    measured_dn: float
    measured_e_per_s: float
    predicted_e_per_s_at_unit_qe: float
    quantum_efficiency: float
    psf_sigma_px: float
    psf_sigma_err_px: float
    peak_dn: float
    growth_curve_dn: dict[str, float] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)


def vega_spectrum() -> tuple[FloatArray, FloatArray]:
    """Vega's spectral irradiance at the top of the atmosphere: wavelengths [nm] and
    ``F_lambda`` [W m^-2 nm^-1] (CALSPEC ``alpha_lyr_stis_011``, via ``pyphot``)."""
    from pyphot.vega import Vega

    with Vega(flavor=VEGA_CALSPEC) as v:
        wl = np.asarray(v.wavelength.to("nm").value, float)
        fl = np.asarray(v.flux.to("W / (m2 nm)").value, float)
    return wl, fl


def photon_rate(wl_nm: FloatArray, f_lambda: FloatArray, response_wl_nm: FloatArray,
                response: FloatArray, area_m2: float) -> float:
    """Photo-electrons per second [e-/s] of a source of spectral irradiance ``f_lambda``
    [W m^-2 nm^-1] through an aperture of ``area_m2`` and a response [e-/photon] tabulated
    piecewise linearly (zero outside its support); integrated on a 0.5 nm grid."""
    g = np.arange(float(response_wl_nm[0]), float(response_wl_nm[-1]) + 0.25, 0.5)
    r = np.interp(g, response_wl_nm, response, left=0.0, right=0.0)
    photons = np.interp(g, wl_nm, f_lambda, left=0.0, right=0.0) * g * 1e-9 / (_H * _C)
    return float(np.trapezoid(photons * r, g) * area_m2)


def _gauss_pixels(dx: FloatArray, dy: FloatArray, sigma: float) -> FloatArray:
    s = math.sqrt(2.0) * sigma
    gx = 0.5 * (special.erf((dx + 0.5) / s) - special.erf((dx - 0.5) / s))
    gy = 0.5 * (special.erf((dy + 0.5) / s) - special.erf((dy - 0.5) / s))
    return gx * gy


def star_photometry(dn: FloatArray, valid: NDArray[np.bool_], noise_dn: float, *,
                    aperture_px: float = 10.0, sky_annulus_px: tuple[float, float] = (30.0, 100.0),
                    psf_fit_px: int = 4) -> dict[str, Any]:
    """Aperture photometry and a Gaussian PSF-core fit of the brightest star in ``dn``
    (calibrated DN, sky-subtracted to first order; invalid pixels excluded).

    Raises
    ------
    StarnavError
        No star (the brightest pixel below 20 times ``noise_dn``) or the aperture leaves the
        frame.
    """
    img = np.where(valid, dn, np.nan)
    iy, ix = np.unravel_index(int(np.nanargmax(img)), img.shape)
    peak = float(img[iy, ix])
    if not peak > 20.0 * noise_dn:
        raise StarnavError(f"no star: brightest pixel {peak:.1f} DN, sky noise {noise_dn:.2f} DN")
    R = int(math.ceil(sky_annulus_px[1])) + 1
    if iy < R or ix < R or iy + R >= img.shape[0] or ix + R >= img.shape[1]:
        raise StarnavError(f"star at ({ix}, {iy}) too close to the edge for a {R} px annulus")
    win = img[iy - 2:iy + 3, ix - 2:ix + 3]
    yy, xx = np.mgrid[iy - 2:iy + 3, ix - 2:ix + 3]
    w = np.nan_to_num(np.clip(win, 0.0, None))
    cx, cy = float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum())
    Y, X = np.mgrid[:img.shape[0], :img.shape[1]]
    r = np.hypot(X - cx, Y - cy)
    ok = np.isfinite(img)
    ann = ok & (r >= sky_annulus_px[0]) & (r < sky_annulus_px[1])
    # the aperture sum takes every pixel, so the sky is the plain mean of a wide annulus: the
    # dark sky is skewed by sparse positive outliers (hot pixels, cosmic rays), its mean lies
    # ~0.1 DN above its median and clipped mean, and they fall inside the aperture too
    sky = float(np.mean(img[ann]))

    def total(rad: float) -> float:
        m = ok & (r <= rad)
        return float(np.sum(img[m]) - m.sum() * sky)

    growth = {f"{rad:g}": total(rad) for rad in (3.0, 5.0, 7.0, 10.0, 15.0, 20.0)}

    # Gaussian core: flux, centre, sigma, sky on the pixels within psf_fit_px
    m = ok & (np.abs(X - cx) <= psf_fit_px) & (np.abs(Y - cy) <= psf_fit_px)
    dx, dy, z = X[m] - cx, Y[m] - cy, img[m] - sky

    def resid(p: FloatArray) -> FloatArray:
        return (p[0] * _gauss_pixels(dx - p[1], dy - p[2], p[3]) + p[4] - z) / noise_dn

    fit = optimize.least_squares(resid, [total(aperture_px), 0.0, 0.0, 0.8, 0.0],
                                 bounds=([0, -2, -2, 0.1, -10], [np.inf, 2, 2, 5, 10]))
    dof = max(1, z.size - 5)
    cov = np.linalg.pinv(fit.jac.T @ fit.jac) * float(np.sum(fit.fun**2)) / dof
    return {"centroid_px": (cx, cy), "sky_dn": sky, "total_dn": total(aperture_px),
            "growth_dn": growth, "peak_dn": peak, "psf_sigma_px": float(fit.x[3]),
            "psf_sigma_err_px": float(math.sqrt(max(cov[3, 3], 0.0)))}


def stellar_calibration(path: str | Path | None = None, *, aperture_px: float = 10.0,
                        sky_annulus_px: tuple[float, float] = (30.0, 100.0)
                        ) -> StellarCalibration:
    """Measure the AMIE's flat quantum efficiency and PSF core on a Vega frame (module
    steps 1-4); ``path`` defaults to the packaged :data:`VEGA_FRAME`."""
    p = Path(path) if path is not None else packaged_frame(VEGA_FRAME)
    frame = read_amie(p)
    cal = calibrate(frame)
    phot = star_photometry(np.asarray(cal.dn, float), np.asarray(cal.valid, bool),
                           float(cal.background_rms_dn), aperture_px=aperture_px,
                           sky_annulus_px=sky_annulus_px)
    table = np.loadtxt(packaged_path(AMIE_RESPONSE_TABLE), delimiter=",", comments="#",
                       skiprows=2, ndmin=2)
    cam = Camera.preset("amie")
    wl, fl = vega_spectrum()
    rate_unit = photon_rate(wl, fl, table[:, 0], table[:, 1] * AMIE_RESPONSE_SCALE,
                            cam.pupil_area)
    gain = float(cal.gain_e_per_dn)
    measured_e_s = phot["total_dn"] * gain / frame.exposure_s
    return StellarCalibration(
        frame=p.stem, exposure_s=frame.exposure_s, gain_e_per_dn=gain,
        centroid_px=tuple(phot["centroid_px"]), aperture_px=aperture_px,
        sky_annulus_px=tuple(sky_annulus_px), sky_dn=phot["sky_dn"],
        measured_dn=phot["total_dn"], measured_e_per_s=measured_e_s,
        predicted_e_per_s_at_unit_qe=rate_unit,
        quantum_efficiency=measured_e_s / rate_unit,
        psf_sigma_px=phot["psf_sigma_px"], psf_sigma_err_px=phot["psf_sigma_err_px"],
        peak_dn=phot["peak_dn"], growth_curve_dn=phot["growth_dn"],
        sources={"spectrum": f"HST CALSPEC alpha_lyr_{VEGA_CALSPEC} (Bohlin 2014, AJ 147:127), "
                             "via pyphot",
                 "response": AMIE_RESPONSE_TABLE, "aperture": "amie camera preset, f / N",
                 "frame": p.name})


def write_calibration(cal: StellarCalibration, path: str | Path) -> Path:
    """Write ``cal`` as JSON (temporary file + rename)."""
    out = Path(path)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(json.dumps(asdict(cal), indent=2, sort_keys=True) + "\n")
    tmp.replace(out)
    return out


def load_calibration() -> dict[str, Any]:
    """The packaged stellar calibration (:data:`VEGA_CALIBRATION_FILE`) as a dict."""
    return json.loads(packaged_path(VEGA_CALIBRATION_FILE).read_text())
