"""Vega on the real AMIE frame 040326: the star field of :mod:`starnav.stars` against pixels.

1. **Real.** Frame ``AMI_EE3_040326_00034_00200`` calibrated like the Moon frames, Vega
   measured by :func:`~starnav.reference.amie.vega.star_photometry`.
2. **Simulated.** HIP 91262 at the frame's epoch, its electrons from
   :mod:`starnav.stars.radiometry`, through the AMIE camera, response and detector
   (:mod:`~starnav.reference.amie.presets`), drawn at the real centroid on a black sky and
   measured by the same photometry.
3. **Circularity.** The AMIE QE and PSF core were measured on this very frame
   (:mod:`~starnav.reference.amie.vega`), so ``total sim / real`` with that QE tests only the
   star radiometry (catalogue V, black body, zero point) against Vega's spectrum. The
   independent numbers are returned too: the same ratio with the user manual's efficiency
   bound (0.15) and with the QE the ROLO-calibrated Moon frames imply
   (:data:`MOON_SIGNAL_RATIO`, docs/real-images.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from starnav.camera import Camera
from starnav.detector import DetectorConfig, expose
from starnav.geometry import FrameGeometry, look_rotation
from starnav.reference.amie.frame import calibrate, packaged_frame, read_amie
from starnav.reference.amie.presets import amie_detector
from starnav.reference.amie.vega import VEGA_FRAME, load_calibration, star_photometry
from starnav.spectra import (
    AMIE_QUANTUM_EFFICIENCY_MANUAL,
    amie_quantum_efficiency,
    sensor_response,
)
from starnav.stars.catalogue import hipparcos
from starnav.stars.centroid import CentroidOptions, background
from starnav.stars.field import frame_stars
from starnav.stars.images import StarImage
from starnav.stars.radiometry import electron_rate
from starnav.stars.schema import StarsConfig

#: Vega's Hipparcos number.
VEGA_HIP = 91262
#: Median simulated / real disc signal of the four REGULAR AMIE Moon frames with the Vega QE
#: (0.918, 0.944, 0.976, 0.966: docs/real-images.md, ``starnav real amie``):
#: the Moon (ROLO) says the QE is 0.212 / 0.955 = 0.222.
MOON_SIGNAL_RATIO = 0.955


@dataclass(frozen=True)
class VegaCheck:
    """Vega simulated against the real frame (units in the names)."""

    real_total_dn: float
    real_peak_dn: float
    sim_total_dn: float
    sim_peak_dn: float
    sim_electrons_e: float
    vega_v_mag: float
    quantum_efficiency: float

    @property
    def total_ratio(self) -> float:
        """Simulated / real total signal with the Vega-measured QE (circular for the QE)."""
        return self.sim_total_dn / self.real_total_dn

    @property
    def peak_ratio(self) -> float:
        return self.sim_peak_dn / self.real_peak_dn

    @property
    def total_ratio_manual_qe(self) -> float:
        """The same with the AMIE manual's efficiency bound 0.15 (independent of this frame)."""
        return self.total_ratio * AMIE_QUANTUM_EFFICIENCY_MANUAL / self.quantum_efficiency

    @property
    def total_ratio_moon_qe(self) -> float:
        """The same with the QE the ROLO-calibrated Moon frames imply (independent of this
        frame): ``QE_vega / MOON_SIGNAL_RATIO``."""
        return self.total_ratio / MOON_SIGNAL_RATIO


def vega_check(seed: int = 0) -> VegaCheck:
    """Module steps 1-2 on the packaged frame."""
    frame = read_amie(packaged_frame(VEGA_FRAME))
    cal = calibrate(frame)
    noise = float(cal.background_rms_dn)
    real = star_photometry(np.asarray(cal.dn, float), np.asarray(cal.valid, bool), noise)
    cam = Camera.preset("amie")
    det = DetectorConfig.model_validate(amie_detector(frame.exposure_s))
    stored = load_calibration()
    cu, cv = stored["centroid_px"]
    cat = hipparcos()
    t = frame.start_time
    epoch = t.year + (t.timetuple().tm_yday - 1 + t.hour / 24.0) / 365.25
    d = cat.directions(epoch, [cat.index_of(VEGA_HIP)])[0]
    R = look_rotation(cam.unproject(np.array([cu, cv])), d)
    # a black sky: the Moon far behind the camera
    geom = FrameGeometry(camera_position=1e9 * d, R_cam_to_inertial=R,
                         sun_position=np.array([1.5e11, 0.0, 0.0]))
    field = frame_stars(geom, cam, StarsConfig(enabled=True, magnitude_limit=4.0,
                                               epoch_jyear=epoch),
                        sensor_response("amie"), exposure_time=frame.exposure_s, detector=det)
    vega = field.hip == VEGA_HIP
    e = expose(np.zeros((cam.height, cam.width), np.float32), cam, det, seed=seed,
               point_sources=field.point_sources())
    dn = e.dn.astype(float) - det.adc.offset_dn
    sim = star_photometry(dn, np.ones(dn.shape, bool), noise)
    return VegaCheck(real_total_dn=real["total_dn"], real_peak_dn=real["peak_dn"],
                     sim_total_dn=sim["total_dn"], sim_peak_dn=sim["peak_dn"],
                     sim_electrons_e=float(field.electrons[vega][0]),
                     vega_v_mag=float(field.v[vega][0]),
                     quantum_efficiency=amie_quantum_efficiency())


def amie_star_image(path) -> StarImage:
    """A raw AMIE ``.IMG`` as a star image for :mod:`starnav.stars.plate` (``starnav stars
    solve``): the 10-bit DN (saturation 1023) with the invalid pixels (marker, dark band) set
    to the valid pixels' median, the epoch from the label's ``START_TIME`` (UTC)."""
    from astropy.time import Time

    f = read_amie(path)
    fill = int(np.median(f.dn[f.valid]))
    dn = np.where(f.valid, f.dn, fill)
    # the faintest star this frame can show: all its light in one pixel at the detection
    # threshold over the frame's background noise (a bound: a real PSF needs more), its
    # electrons from the camera's pupil, the AMIE response and the label's exposure and gain
    _, noise = background(dn.astype(float), 32)
    floor_dn = CentroidOptions().threshold_sigma * float(np.median(noise))
    cam = Camera.preset("amie")
    v0_dn = (electron_rate(0.0, 0.0, sensor_response("amie"), cam.pupil_area) * f.exposure_s
             / f.gain_e_per_dn)
    v_lim = 2.5 * math.log10(v0_dn / floor_dn)
    return StarImage(Path(path), dn, 1023.0, float(Time(f.start_time).jyear),
                     "PDS label START_TIME", v_lim,
                     f"AMIE camera and response, label EXPOSURE_DURATION {f.exposure_s:g} s "
                     f"and gain {f.gain_e_per_dn:g} e-/DN, {floor_dn:.1f} DN in one pixel")
