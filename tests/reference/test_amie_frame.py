"""Raw SMART-1 AMIE frames: decoding, label values, masks and calibration.

Sources of the numbers (next to each test):
* the PDS3 labels of the six packaged frames, read by eye (``head -c 20480 FILE``): every label
  value below is typed from the label line quoted next to it, not read by the code under test;
* the data README (section amie/): the marker, the ~5 saturated pixels of 040504, Vega's peak;
* measurements made while writing the module (quoted as "measured"), for the regression bounds.

Only packaged files are read (``starnav/data/amie``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
import pytest

from starnav.errors import ConfigError, DataFileError, UnknownNameError
from starnav.reference.amie.frame import (
    AMIE_FRAMES,
    AmieCalibrationOptions,
    calibrate,
    dark_band_rows,
    moon_signal,
    packaged_frame,
    read_amie,
    silicon_thermal_factor,
)

DEG = math.pi / 180.0
#: Label values are converted by a product with 1e-3 or pi/180: exact to float rounding.
EXACT_RTOL = 1e-12
#: Label vectors and distances are rounded to 0.1 km: |vector| = distance to this [km].
LABEL_ROUNDING_KM = 0.1
#: ^IMAGE = 36865 <BYTES> in every label: 1-based, so the image starts at byte 36 864.
IMAGE_OFFSET = 36865 - 1
LINES = SAMPLES = 512          # IMAGE: LINES = 512, LINE_SAMPLES = 512
SHIFT = 6                      # IMAGE: SCALING_FACTOR = 0.015625 = 2^-6


@dataclass(frozen=True)
class Label:
    start: str
    exposure_ms: float
    gain: float
    sc_to_moon_km: tuple[float, float, float]
    distance_km: float
    boresight_deg: tuple[float, float]
    reticle_ra_deg: tuple[float, float, float, float]
    reticle_dec_deg: tuple[float, float, float, float]
    phase_deg: float | None
    temperature_k: float


LABELS = {
    "040819_00208": Label(
        start="2004-08-19T23:42:43.134",                 # START_TIME = 2004-08-19T23:42:43.134
        exposure_ms=30,                                  # EXPOSURE_DURATION = 30 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(-146915.0, -122553.1, -50748.3),
        # SC_TARGET_POSITION_VECTOR = (-146915.0, -122553.1, -50748.3)
        distance_km=197936.0,                            # TARGET_CENTER_DISTANCE = 197936.0 <KM>
        boresight_deg=(219.71, -14.84),   # RIGHT_ASCENSION = 219.71 <DEG>, DECLINATION = -14.84
        reticle_ra_deg=(220.60, 221.43, 218.83, 217.98),
        # RETICLE_POINT_RA = (220.60, 221.43, 218.83, 217.98)
        reticle_dec_deg=(-16.50, -13.98, -13.17, -15.68),
        # RETICLE_POINT_DECLINATION = (-16.50, -13.98, -13.17, -15.68)
        phase_deg=105.18,                                # PHASE_ANGLE = 105.18 <DEG>
        temperature_k=285.86,                            # FOCAL_PLANE_TEMPERATURE = 285.86 <K>
    ),
    "041028_00269": Label(
        start="2004-10-28T05:35:10.428",                 # START_TIME = 2004-10-28T05:35:10.428
        exposure_ms=5,                                   # EXPOSURE_DURATION = 5 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(587808.9, 313502.5, 86398.7),
        # SC_TARGET_POSITION_VECTOR = (587808.9, 313502.5, 86398.7)
        distance_km=671764.7,                            # TARGET_CENTER_DISTANCE = 671764.7 <KM>
        boresight_deg=(28.07, 7.39),      # RIGHT_ASCENSION = 28.07 <DEG>, DECLINATION = 7.39
        reticle_ra_deg=(29.92, 27.65, 26.23, 28.49),
        # RETICLE_POINT_RA = (29.92, 27.65, 26.23, 28.49)
        reticle_dec_deg=(7.80, 9.22, 6.97, 5.56),
        # RETICLE_POINT_DECLINATION = (7.80, 9.22, 6.97, 5.56)
        phase_deg=7.45,                                  # PHASE_ANGLE = 7.45 <DEG>
        temperature_k=297.11,                            # FOCAL_PLANE_TEMPERATURE = 297.11 <K>
    ),
    "041111_00070": Label(
        start="2004-11-11T23:30:21.877",                 # START_TIME = 2004-11-11T23:30:21.877
        exposure_ms=18,                                  # EXPOSURE_DURATION = 18 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(-30566.3, -34731.6, -67445.7),
        # SC_TARGET_POSITION_VECTOR = (-30566.3, -34731.6, -67445.7)
        distance_km=81789.4,                             # TARGET_CENTER_DISTANCE = 81789.4 <KM>
        boresight_deg=(228.65, -55.55),   # RIGHT_ASCENSION = 228.65 <DEG>, DECLINATION = -55.55
        reticle_ra_deg=(226.26, 231.11, 230.88, 226.35),
        # RETICLE_POINT_RA = (226.26, 231.11, 230.88, 226.35)
        reticle_dec_deg=(-56.87, -56.83, -54.19, -54.22),
        # RETICLE_POINT_DECLINATION = (-56.87, -56.83, -54.19, -54.22)
        phase_deg=142.14,                                # PHASE_ANGLE = 142.14 <DEG>
        temperature_k=290.20,                            # FOCAL_PLANE_TEMPERATURE = 290.20 <K>
    ),
    "041111_00072": Label(
        start="2004-11-11T23:30:41.877",                 # START_TIME = 2004-11-11T23:30:41.877
        exposure_ms=40,                                  # EXPOSURE_DURATION = 40 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(-30564.4, -34729.5, -67444.7),
        # SC_TARGET_POSITION_VECTOR = (-30564.4, -34729.5, -67444.7)
        distance_km=81787.0,                             # TARGET_CENTER_DISTANCE = 81787.0 <KM>
        boresight_deg=(228.65, -55.55),   # RIGHT_ASCENSION = 228.65 <DEG>, DECLINATION = -55.55
        reticle_ra_deg=(226.26, 231.11, 230.88, 226.35),
        # RETICLE_POINT_RA = (226.26, 231.11, 230.88, 226.35)
        reticle_dec_deg=(-56.87, -56.83, -54.19, -54.23),
        # RETICLE_POINT_DECLINATION = (-56.87, -56.83, -54.19, -54.23)
        phase_deg=142.14,                                # PHASE_ANGLE = 142.14 <DEG>
        temperature_k=290.19,                            # FOCAL_PLANE_TEMPERATURE = 290.19 <K>
    ),
    "040504_00013": Label(
        start="2004-05-04T08:05:00.284",                 # START_TIME = 2004-05-04T08:05:00.284
        exposure_ms=20,                                  # EXPOSURE_DURATION = 20 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(-194727.3, -199671.3, -91190.2),
        # SC_TARGET_POSITION_VECTOR = (-194727.3, -199671.3, -91190.2)
        distance_km=293433.1,                            # TARGET_CENTER_DISTANCE = 293433.1 <KM>
        boresight_deg=(226.90, -19.36),   # RIGHT_ASCENSION = 226.90 <DEG>, DECLINATION = -19.36
        reticle_ra_deg=(226.28, 225.00, 227.53, 228.77),
        # RETICLE_POINT_RA = (226.28, 225.00, 227.53, 228.77)
        reticle_dec_deg=(-17.58, -19.94, -21.13, -18.76),
        # RETICLE_POINT_DECLINATION = (-17.58, -19.94, -21.13, -18.76)
        phase_deg=None,                                  # PHASE_ANGLE = "N/A"
        temperature_k=292.18,                            # FOCAL_PLANE_TEMPERATURE = 292.18 <K>
    ),
    "040326_00034": Label(
        start="2004-03-26T07:06:21.702",                 # START_TIME = 2004-03-26T07:06:21.702
        exposure_ms=200,                                 # EXPOSURE_DURATION = 200 <MS>
        gain=280,                                        # GAIN_NUMBER = 280 <E/DN>
        sc_to_moon_km=(233395.1, 332724.4, 157048.6),
        # SC_TARGET_POSITION_VECTOR = (233395.1, 332724.4, 157048.6)
        distance_km=435709.8,                            # TARGET_CENTER_DISTANCE = 435709.8 <KM>
        boresight_deg=(279.23, 38.78),    # RIGHT_ASCENSION = 279.23 <DEG>, DECLINATION = 38.78
        reticle_ra_deg=(277.52, 277.55, 280.88, 280.98),
        # RETICLE_POINT_RA = (277.52, 277.55, 280.88, 280.98)
        reticle_dec_deg=(40.11, 37.46, 37.43, 40.08),
        # RETICLE_POINT_DECLINATION = (40.11, 37.46, 37.43, 40.08)
        phase_deg=None,                                  # PHASE_ANGLE = "N/A"
        temperature_k=289.86,                            # FOCAL_PLANE_TEMPERATURE = 289.86 <K>
    ),
}
FRAMES = list(LABELS)


@pytest.fixture(scope="module")
def frames():
    return {k: read_amie(packaged_frame(k)) for k in FRAMES}


@pytest.fixture(scope="module")
def calibrated(frames):
    return {k: calibrate(f) for k, f in frames.items()}


def _stored(path) -> np.ndarray:
    """The image words, read here with numpy alone at the label's pointer (IMAGE_OFFSET)."""
    return np.fromfile(path, dtype="<u2", count=LINES * SAMPLES,
                       offset=IMAGE_OFFSET).reshape(LINES, SAMPLES)


# --------------------------------------------------------------------------- label values
@pytest.mark.parametrize("key", FRAMES)
def test_label_values_against_typed_label(frames, key):
    f, lab = frames[key], LABELS[key]
    assert f.product_id == packaged_frame(key).stem
    assert f.filter_name == "NONE"                              # FILTER_NAME = "NONE"
    assert f.image_offset == IMAGE_OFFSET
    assert f.start_time_utc == lab.start
    assert f.start_time == datetime.fromisoformat(lab.start).replace(tzinfo=UTC)
    assert f.exposure_s == pytest.approx(lab.exposure_ms / 1000.0, rel=EXACT_RTOL)
    assert f.gain_e_per_dn == lab.gain
    assert f.focal_plane_temperature_k == pytest.approx(lab.temperature_k, rel=EXACT_RTOL)
    np.testing.assert_allclose(f.sc_to_moon_m, np.array(lab.sc_to_moon_km) * 1e3,
                               rtol=EXACT_RTOL)
    assert f.target_center_distance_m == pytest.approx(lab.distance_km * 1e3, rel=EXACT_RTOL)
    np.testing.assert_allclose(f.boresight_radec_deg, lab.boresight_deg, rtol=EXACT_RTOL)
    np.testing.assert_allclose(f.boresight_radec_rad, np.array(lab.boresight_deg) * DEG,
                               rtol=EXACT_RTOL)
    corners = np.column_stack([lab.reticle_ra_deg, lab.reticle_dec_deg])
    np.testing.assert_allclose(f.reticle_radec_deg, corners, rtol=EXACT_RTOL)
    np.testing.assert_allclose(f.reticle_radec_rad, corners * DEG, rtol=EXACT_RTOL)
    if lab.phase_deg is None:
        assert f.phase_angle_rad is None
    else:
        assert f.phase_angle_rad == pytest.approx(lab.phase_deg * DEG, rel=EXACT_RTOL)
    # the raw label stays available, with its units
    assert f.label["EXPOSURE_DURATION"].units == "MS"
    assert f.label["EXPOSURE_DURATION"].value == lab.exposure_ms


@pytest.mark.parametrize("key", FRAMES)
def test_sc_target_vector_is_the_centre_distance(frames, key):
    """SC_TARGET_POSITION_VECTOR is spacecraft -> Moon centre in km: its norm is the label's
    TARGET_CENTER_DISTANCE to the labels' 0.1 km rounding (measured: < 0.04 km)."""
    f = frames[key]
    assert abs(np.linalg.norm(f.sc_to_moon_m) - f.target_center_distance_m) \
        < LABEL_ROUNDING_KM * 1e3


def test_041111_pair_is_20_s_apart(frames):
    """START_TIME 23:30:21.877 and 23:30:41.877: the same geometry 20 s apart."""
    a, b = frames["041111_00070"], frames["041111_00072"]
    assert (b.start_time - a.start_time).total_seconds() == pytest.approx(20.0, abs=1e-6)


# --------------------------------------------------------------------------- decoding
@pytest.mark.parametrize("key", FRAMES)
def test_dn_is_stored_shifted_by_6_exactly(frames, key):
    f = frames[key]
    stored = _stored(f.path)
    assert not np.any(stored & ((1 << SHIFT) - 1))       # SCALING_FACTOR is an exact shift
    expected = (stored >> SHIFT).astype(np.int64)
    assert np.issubdtype(f.dn.dtype, np.integer)
    np.testing.assert_array_equal(f.dn, expected)
    np.testing.assert_array_equal(f.dn, stored * 0.015625)  # SCALING_FACTOR = 0.015625
    assert f.dn.shape == (LINES, SAMPLES)
    assert 0 <= f.dn.min() and f.dn.max() <= 1023         # 10-bit data
    assert not f.dn.flags.writeable and not f.valid.flags.writeable


@pytest.mark.parametrize("key", FRAMES)
def test_marker_and_saturated_pixels_are_invalid(frames, key):
    """data README: the last two pixels of row 511 are always 1023 (a marker)."""
    f = frames[key]
    np.testing.assert_array_equal(f.dn[511, 510:], [1023, 1023])
    assert not f.valid[511, 510] and not f.valid[511, 511]
    assert not np.any(f.valid & (f.dn == 1023))


def test_040504_saturated_pixels(frames):
    """data README: 040504_00013 has ~5 saturated px (measured: 5 besides the marker)."""
    f = frames["040504_00013"]
    sat = f.dn == 1023
    sat[511, 510:] = False
    assert 3 <= sat.sum() <= 8
    assert not np.any(f.valid & sat)


def test_vega_peak(frames):
    """data README: Vega near the centre, peak ~188 DN over ~50 background."""
    f = frames["040326_00034"]
    dn = np.where(f.valid, f.dn, 0)
    r, c = np.unravel_index(np.argmax(dn), dn.shape)
    assert dn[r, c] == 188
    assert math.hypot(r - 255.5, c - 255.5) < 10
    assert 40 <= np.median(f.dn) <= 55


# --------------------------------------------------------------------------- the dark band
def test_dark_band_rule_on_a_synthetic_frame():
    """A ramp with column stripes and noise, darkened by 4 DN above a ragged edge (12-24 rows):
    the rule finds the edge within its 5-row smoothing (+-2 rows); without the band, (almost)
    no column is flagged."""
    rng = np.random.default_rng(7)
    rows = np.arange(512)[:, None]
    stripes = rng.normal(0.0, 1.0, 512)
    edge = np.round(18 + 6 * np.sin(2 * np.pi * np.arange(512) / 170)).astype(int)
    sky = 40 + 0.05 * rows + stripes[None, :]
    banded = np.round(sky + rng.normal(0.0, 1.0, sky.shape) - 4.0 * (rows < edge[None, :]))
    found = dark_band_rows(banded.astype(int))
    assert np.max(np.abs(found - edge)) <= 2
    plain = dark_band_rows(np.round(sky + rng.normal(0.0, 1.0, sky.shape)).astype(int))
    assert np.count_nonzero(plain) <= 0.02 * plain.size


def test_dark_band_in_the_041111_frames(frames):
    """The band shows where the sky carries stray light: 041111 (measured 21-30 rows at 18 ms,
    26-32 at 40 ms, median 24 and 29); the dark-sky frames show none (040819: <= 3 rows in 5
    columns, a 0.7 DN band under the 1 DN threshold)."""
    for key, lo, hi in (("041111_00070", 18, 32), ("041111_00072", 22, 32)):
        band = frames[key].dark_band_rows
        assert lo <= np.median(band) <= hi
        rows = np.arange(512)[:, None]
        assert not np.any(frames[key].valid & (rows < band[None, :]))
    assert np.median(frames["041111_00072"].dark_band_rows) \
        >= np.median(frames["041111_00070"].dark_band_rows)
    for key in ("041028_00269", "040504_00013", "040326_00034"):
        assert not frames[key].dark_band_rows.any()
    assert frames["040819_00208"].dark_band_rows.max() <= 4


# --------------------------------------------------------------------------- calibration
def _stripe_rms(image, ok) -> float:
    """Column stripes of the dark sky: rows 48-207 (no Moon in any frame; below the band),
    columns 16-511 (right of the vignetted edge); each row's median removed (the ramp), then
    the rms over columns of the column medians [DN]."""
    x = np.where(ok, image, np.nan)[48:208, 16:]
    x = x - np.nanmedian(x, axis=1, keepdims=True)
    return float(np.nanstd(np.nanmedian(x, axis=0)))


@pytest.mark.parametrize("key", FRAMES)
def test_calibrate_removes_the_column_stripes(frames, calibrated, key):
    """Measured: 0.8-1.7 DN before, 0.10-0.36 DN after (ratio 0.10-0.28)."""
    before = _stripe_rms(frames[key].dn.astype(float), frames[key].valid)
    after = _stripe_rms(calibrated[key].dn, calibrated[key].valid)
    assert before > 0.5
    assert after < 0.4 * before


def test_column_stripes_are_a_fixed_pattern(calibrated):
    """The stripes belong to the detector: the offsets fitted on a star field at 200 ms
    (2004-03-26, 289.9 K) and on a full Moon at 5 ms (2004-10-28, 297.1 K) agree
    (correlation measured 0.96)."""
    a = calibrated["040326_00034"].column_offsets_dn[16:]
    b = calibrated["041028_00269"].column_offsets_dn[16:]
    assert np.corrcoef(a, b)[0, 1] > 0.9


@pytest.mark.parametrize("key", FRAMES)
def test_calibrated_sky_and_units(frames, calibrated, key):
    """Dark sky at 0 (measured |bg| < 0.001 DN), rms < 1 DN (measured 0.51-0.63 DN); e- = DN x
    GAIN_NUMBER, e-/s = e- / EXPOSURE_DURATION; invalid pixels stay invalid."""
    cal, lab = calibrated[key], LABELS[key]
    assert abs(cal.background_dn) < 0.05
    assert 0.3 < cal.background_rms_dn < 1.0
    assert cal.sky.mean() > 0.6
    np.testing.assert_allclose(cal.electrons, cal.dn * lab.gain, rtol=EXACT_RTOL)
    np.testing.assert_allclose(cal.signal_e_per_s, cal.dn * lab.gain / (lab.exposure_ms * 1e-3),
                               rtol=EXACT_RTOL)
    assert not np.any(cal.valid & ~frames[key].valid)
    assert cal.bias_scale == 1.0


def test_bias_temperature_law_adds_noise(frames):
    """The default leaves the master bias unscaled; amiextractor's silicon law scales it by
    k(297.11 K) ~ 8.1 for 041028 and raises the dark sky's rms (measured 0.61 -> 0.95 DN)."""
    f = frames["041028_00269"]
    plain = calibrate(f)
    scaled = calibrate(f, options=AmieCalibrationOptions(bias_law="silicon-thermal"))
    assert scaled.bias_scale == pytest.approx(silicon_thermal_factor(297.11), rel=EXACT_RTOL)
    assert scaled.background_rms_dn > 1.2 * plain.background_rms_dn


def test_silicon_thermal_factor_transcription():
    """amiextractor amie_thermal_noise_factor.m: T0 = 273.15 K, k = 8.6171e-5 eV/K,
    Eg(T) = 1.11557 - 7.021e-4 T^2/(1108 + T), K = (T/T0)^1.5 exp(Eg(T0)/(2 k T0) - Eg(T)/(2 k T))
    (typed here from that file)."""
    assert silicon_thermal_factor(273.15) == 1.0

    def eg(t):
        return 1.11557 - 7.021e-4 * t**2 / (1108 + t)

    t = 290.2
    k = (t / 273.15) ** 1.5 * math.exp(eg(273.15) / (2 * 8.6171e-5 * 273.15)
                                       - eg(t) / (2 * 8.6171e-5 * t))
    assert silicon_thermal_factor(t) == pytest.approx(k, rel=1e-12)
    with pytest.raises(UnknownNameError, match="silicon-thermal"):
        AmieCalibrationOptions(bias_law="arrhenius")


def test_linearity_of_the_041111_pair(calibrated):
    """18 and 40 ms of the same crescent 20 s apart: the Moon's electrons should scale as
    40/18 = 2.222. Summed over one aperture for both (the union of their 5-sigma pixels, grown
    by 3 px, valid in both): measured 2.2468 (+1.1 %); over each frame's own 5-sigma pixels
    2.2533 (+1.4 %). Within 2 % of the exposure ratio."""
    from scipy import ndimage

    a, b = calibrated["041111_00070"], calibrated["041111_00072"]
    aperture = ndimage.binary_dilation(moon_signal(a).mask | moon_signal(b).mask, iterations=3)
    aperture &= a.valid & b.valid
    sa, sb = moon_signal(a, aperture=aperture), moon_signal(b, aperture=aperture)
    assert sa.n_pixels == sb.n_pixels > 20_000
    ratio = sb.electrons / sa.electrons
    assert ratio == pytest.approx(40.0 / 18.0, rel=0.02)
    assert moon_signal(b).electrons / moon_signal(a).electrons == pytest.approx(40 / 18, rel=0.02)


# --------------------------------------------------------------------------- bad inputs
@pytest.fixture(scope="module")
def blob():
    return packaged_frame("041111_00070").read_bytes()


def _write(tmp_path, name, data):
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_truncated_file(tmp_path, blob):
    """One pixel short of LINES x LINE_SAMPLES x 2 bytes after the pointer."""
    p = _write(tmp_path, "short.IMG", blob[:IMAGE_OFFSET + LINES * SAMPLES * 2 - 2])
    with pytest.raises(DataFileError, match="LINES x LINE_SAMPLES") as err:
        read_amie(p)
    assert "short.IMG" in str(err.value) and "^IMAGE" in str(err.value)


def test_label_without_image_pointer(tmp_path, blob):
    data = re.sub(rb"\^IMAGE\s*=\s*36865 <BYTES>", lambda m: b" " * len(m.group()), blob)
    assert len(data) == len(blob) and data != blob
    p = _write(tmp_path, "nopointer.IMG", data)
    with pytest.raises(DataFileError, match=r"\^IMAGE") as err:
        read_amie(p)
    assert "nopointer.IMG" in str(err.value)


def test_unknown_filter(tmp_path, blob):
    data = re.sub(rb'FILTER_NAME(\s*)= "NONE" ', rb'FILTER_NAME\1= "VIS_X"', blob)
    assert len(data) == len(blob) and data != blob
    p = _write(tmp_path, "visx.IMG", data)
    with pytest.raises(ConfigError, match="FILTER_NAME") as err:
        read_amie(p)
    assert "visx.IMG" in str(err.value) and "VIS_X" in str(err.value)


@pytest.mark.parametrize("data", [b"SIMPLE  =                    T" + b" " * 2850, b""],
                         ids=["fits", "empty"])
def test_not_a_pds_file(tmp_path, data):
    p = _write(tmp_path, "other.fits", data)
    with pytest.raises(DataFileError, match="not a PDS3 file") as err:
        read_amie(p)
    assert "other.fits" in str(err.value)


def test_inexact_scaling_is_refused(tmp_path, blob):
    data = bytearray(blob)
    data[IMAGE_OFFSET] |= 1                 # a low bit of the first pixel (little-endian)
    p = _write(tmp_path, "lowbit.IMG", bytes(data))
    with pytest.raises(DataFileError, match="SCALING_FACTOR") as err:
        read_amie(p)
    assert "lowbit.IMG" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(DataFileError, match="nothere.IMG"):
        read_amie(tmp_path / "nothere.IMG")


# --------------------------------------------------------------------------- packaged frames
def test_packaged_frames():
    assert len(AMIE_FRAMES) == 6
    for name, text in AMIE_FRAMES.items():
        p = packaged_frame(name)
        assert p.is_file() and p.name == name and text
        assert packaged_frame(p.stem) == p == packaged_frame(p.stem[8:20].lower())
    assert {packaged_frame(k).stem[8:20] for k in FRAMES} == set(FRAMES)
    with pytest.raises(UnknownNameError, match="AMI_EE3_041111_00070_00018.IMG"):
        packaged_frame("041111_00071")


# --------------------------------------------------------------------------- PDS3 value forms
LABEL_BYTES = 1024 * 20        # RECORD_BYTES x LABEL_RECORDS in every packaged label


def _relabel(blob: bytes, subs: dict[str, str]) -> bytes:
    """The packaged file with label lines rewritten (``KEYWORD -> 'KEYWORD = value'``), the
    label padded back to its records: a small label written by the test on the real image."""
    text = blob[:LABEL_BYTES].decode("ascii")
    end = re.search(r"(?m)^END\s*$", text).end()
    head = text[:end]
    for key, line in subs.items():
        pat = re.compile(rf"(?m)^{re.escape(key)}\s*=.*$")
        assert pat.search(head), key
        head = pat.sub(lambda m, line=line: line, head, count=1)
    out = head.encode("ascii")
    assert len(out) <= LABEL_BYTES
    return out + b" " * (LABEL_BYTES - len(out)) + blob[LABEL_BYTES:]


#: One label keyword written in each value form PDS3 allows, and what the reader must make of it
#: (the original 041111_00070 values: RA corners 226.26 231.11 230.88 226.35, exposure 18 ms,
#: distance 81 789.4 km, start 2004-11-11T23:30:21.877 = day 316).
VALUE_FORMS = {
    "units on the sequence": ({"RETICLE_POINT_RA":
                               "RETICLE_POINT_RA = (226.26, 231.11, 230.88, 226.35) <DEG>"},
                              "reticle_radec_deg", [226.26, 231.11, 230.88, 226.35]),
    "units on each element": ({"RETICLE_POINT_RA": "RETICLE_POINT_RA = (226.26 <DEG>, "
                               "231.11 <deg>, 230.88 <DEGREES>, 226.35 <DEG>)"},
                              "reticle_radec_deg", [226.26, 231.11, 230.88, 226.35]),
    "quoted elements": ({"RETICLE_POINT_RA":
                         'RETICLE_POINT_RA = ("226.26", "231.11", "230.88", "226.35")'},
                        "reticle_radec_deg", [226.26, 231.11, 230.88, 226.35]),
    "radians on a sequence": ({"SC_TARGET_POSITION_VECTOR":
                               "SC_TARGET_POSITION_VECTOR = (-30566300.0, -34731600.0, "
                               "-67445700.0) <M>"},
                              "sc_to_moon_m", [-30566.3e3, -34731.6e3, -67445.7e3]),
    "seconds on a scalar": ({"EXPOSURE_DURATION": "EXPOSURE_DURATION = 0.018 <S>"},
                            "exposure_s", 0.018),
    "a quoted number with no units": ({"EXPOSURE_DURATION": 'EXPOSURE_DURATION = "18"'},
                                      "exposure_s", 0.018),
    "a one-element set": ({"GAIN_NUMBER": "GAIN_NUMBER = {280 <E/DN>}"}, "gain_e_per_dn", 280.0),
    "a one-element sequence": ({"TARGET_CENTER_DISTANCE": "TARGET_CENTER_DISTANCE = (81789.4)"},
                               "target_center_distance_m", 81789.4e3),
    "an unquoted symbol": ({"FILTER_NAME": "FILTER_NAME = NONE"}, "filter_name", "NONE"),
    "a set of one symbol": ({"IMAGE_OBSERVATION_TYPE": "IMAGE_OBSERVATION_TYPE = {REGULAR}"},
                            "observation_type", "REGULAR"),
    "a quoted time": ({"START_TIME": 'START_TIME = "2004-11-11T23:30:21.877Z"'},
                      "start_time_utc", "2004-11-11T23:30:21.877"),
    "a day-of-year time": ({"START_TIME": "START_TIME = 2004-316T23:30:21.877"},
                           "start_time_utc", "2004-11-11T23:30:21.877"),
    "a quoted day-of-year time": ({"START_TIME": 'START_TIME = "2004-316T23:30:21.877"'},
                                  "start_time_utc", "2004-11-11T23:30:21.877"),
}


@pytest.mark.parametrize("form", list(VALUE_FORMS))
def test_label_value_forms_read(tmp_path, blob, form):
    subs, attr, want = VALUE_FORMS[form]
    frame = read_amie(_write(tmp_path, "forms.IMG", _relabel(blob, subs)))
    got = getattr(frame, attr)
    if attr == "reticle_radec_deg":
        got = got[:, 0]
    if isinstance(want, str):
        assert got == want
    else:
        np.testing.assert_allclose(got, want, rtol=EXACT_RTOL)


def test_label_forms_leave_the_frame_unchanged(tmp_path, blob):
    """Units, quotes and sets change nothing but the text: the same frame comes out."""
    subs = {k: v for form in ("units on the sequence", "a quoted time", "an unquoted symbol")
            for k, v in VALUE_FORMS[form][0].items()}
    a = read_amie(packaged_frame("041111_00070"))
    b = read_amie(_write(tmp_path, "forms.IMG", _relabel(blob, subs)))
    np.testing.assert_array_equal(a.dn, b.dn)
    np.testing.assert_array_equal(a.reticle_radec_rad, b.reticle_radec_rad)
    assert a.start_time == b.start_time and a.filter_name == b.filter_name


#: Malformed values: each must give one line naming the keyword.
MALFORMED = {
    "unclosed sequence": ("RETICLE_POINT_RA", "RETICLE_POINT_RA = (226.26, 231.11, 230.88"),
    "unclosed units": ("EXPOSURE_DURATION", "EXPOSURE_DURATION = 18 <MS"),
    "empty element": ("RETICLE_POINT_DECLINATION",
                      "RETICLE_POINT_DECLINATION = (-56.87, , -54.19, -54.22)"),
    "text for a number": ("EXPOSURE_DURATION", "EXPOSURE_DURATION = eighteen <MS>"),
    "wrong units": ("TARGET_CENTER_DISTANCE", "TARGET_CENTER_DISTANCE = 81789.4 <DEG>"),
    "three corners": ("RETICLE_POINT_RA", "RETICLE_POINT_RA = (226.26, 231.11, 230.88) <DEG>"),
    "an unordered set": ("RETICLE_POINT_RA", "RETICLE_POINT_RA = {226.26, 231.11, 230.88, 226.35}"),
    "not a time": ("START_TIME", 'START_TIME = "yesterday"'),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_label_value_names_the_keyword(tmp_path, blob, case):
    key, line = MALFORMED[case]
    p = _write(tmp_path, "bad.IMG", _relabel(blob, {key: line}))
    with pytest.raises(DataFileError) as err:
        read_amie(p)
    msg = str(err.value)
    assert "\n" not in msg and "bad.IMG" in msg and key in msg
