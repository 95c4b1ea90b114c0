"""Raw SMART-1 AMIE frames (PDS3): decoding, masking and calibration to electrons per second.

AMIE reads, through its clear ``NONE`` filter, one 512 x 512 quadrant of a 1024 x 1024 CCD
(14 um pixels, 154.7 mm f/10). starnav ships six raw frames of the ESA PSA data set
``S1-L/X-AMIE-2-EDR-EEP-V1.1`` (:data:`AMIE_FRAMES`) with the NONE quadrant of the master bias
and flat (``starnav/data/amie/PROVENANCE.md``). The file format, the ``valid`` mask (marker,
saturation, the dark top band), the calibration stages and what is not corrected:
docs/methods.md, "starnav.reference.amie.frame".

Calibration (:func:`calibrate`), in this fixed order: 1 bias, 2 sky background (row and column
terms by median polish on the dark sky), 3 flat field (unit median; ``flat < min_flat``
invalid), 4 electrons (label gain), 5 rate (label exposure). The knobs are
:class:`AmieCalibrationOptions`.

References
----------
* The PDS3 labels of ``S1-L/X-AMIE-2-EDR-EEP-V1.1`` (ESA Planetary Science Archive); the AMIE
  EAICD (``doc/EAICD.pdf`` in amiextractor) for the vector frame (``frames.csv``: section 5.2.3).
* andrepiz/amiextractor (MIT), ``functions/img/mf2imgcorr.m``,
  ``amie_thermal_noise_factor.m``: the master frames, the quadrant, the temperature factor.

Index
-----
:func:`read_amie`, :class:`AmieFrame`, :func:`packaged_frame`; :func:`calibrate`,
:class:`AmieCalibrated`, :class:`AmieCalibrationOptions`, :data:`BIAS_LAWS`,
:func:`silicon_thermal_factor`, :func:`dark_band_rows`; :func:`moon_signal`,
:class:`MoonSignal`.
"""

from __future__ import annotations

import logging
import math
import re
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.data import packaged_path
from starnav.errors import ConfigError, DataFileError, UnknownNameError
from starnav.registry import Registry
from starnav.typing import FloatArray

__all__ = [
    "AMIE_FRAMES",
    "BIAS_LAWS",
    "AmieCalibrated",
    "AmieCalibrationOptions",
    "AmieFrame",
    "MoonSignal",
    "calibrate",
    "dark_band_rows",
    "moon_signal",
    "packaged_frame",
    "read_amie",
    "silicon_thermal_factor",
]

log = logging.getLogger(__name__)

IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: The packaged raw frames (``starnav/data/amie/img``), file name -> what it shows (data README).
AMIE_FRAMES: Mapping[str, str] = MappingProxyType({
    "AMI_EE3_040819_00208_00030.IMG": "30 ms; phase 105 deg, 198 000 km: the lit part under the "
                                      "terminator, r ~ 97 px, limb and craters sharp",
    "AMI_EE3_041028_00269_00005.IMG": "5 ms; phase 7.4 deg, 672 000 km: full disc, r ~ 29 px, "
                                      "centred",
    "AMI_EE3_041111_00070_00018.IMG": "18 ms; phase 142 deg, 82 000 km: large thin crescent, "
                                      "r ~ 235 px; pair of 041111_00072 (linearity)",
    "AMI_EE3_041111_00072_00040.IMG": "40 ms; phase 142 deg, 82 000 km: large thin crescent, "
                                      "r ~ 235 px; 20 s after 041111_00070 (linearity)",
    "AMI_EE3_040504_00013_00020.IMG": "20 ms; near full Moon, r ~ 66 px, off centre, maria "
                                      "visible, ~5 saturated px; label pointing ~1 deg off",
    "AMI_EE3_040326_00034_00200.IMG": "200 ms; Vega near the centre (peak ~188 DN over ~50 "
                                      "background), no Moon: a star-photometry check",
})

#: The only filter supported: the calibration files are the NONE quadrant.
SUPPORTED_FILTER = "NONE"
#: Shape of a NONE-filter image (lines, samples) [px].
FRAME_SHAPE = (512, 512)
#: Largest (saturated) 10-bit value [DN].
DN_MAX = 1023
#: The marker pixels (row, column), always ``DN_MAX``.
MARKER_PIXELS = ((511, 510), (511, 511))
#: Package-relative calibration files (``starnav.data.packaged_path``).
BIAS_FILE = "amie/calib/mfbias_NONE_512.npy"
FLAT_FILE = "amie/calib/ff_NONE_512.npy"
#: Temperature of the master bias [K] (data README).
BIAS_REFERENCE_TEMPERATURE = 273.15
#: The label ends within this many bytes, or the file is refused [bytes].
MAX_LABEL_BYTES = 1 << 20

# dark band rule (module docstring, dark_band_rows)
BAND_SEARCH_ROWS = 32
BAND_REFERENCE_ROWS = (32, 96)
BAND_SMOOTH = (5, 15)
BAND_MIN_DEPTH_DN = 1.0
BAND_NSIGMA = 3.0
BAND_SKY_CLIP_DN = 8.0

_PDS_MAGIC = b"PDS_VERSION_ID"
_END_RE = re.compile(rb"(?m)^END[ \t]*\r?$")
_BOLTZMANN_EV = 8.6171e-5   # k_B [eV/K], as in amiextractor


# --------------------------------------------------------------------------- the raw frame
@dataclass(frozen=True, eq=False)
class AmieFrame:
    """One raw AMIE frame: decoded DN, validity mask and label values (SI; the label's own
    keyword in capitals).

    Attributes
    ----------
    path : pathlib.Path
        The ``.IMG`` file.
    product_id, target_name, observation_type, filter_name : str
        ``PRODUCT_ID``, ``TARGET_NAME`` (``MOON``, ``STAR``), ``IMAGE_OBSERVATION_TYPE``
        (empty if absent), ``FILTER_NAME`` (always ``NONE``).
    label : mapping
        The parsed PDS3 label (a :class:`pvl.PVLModule`): every raw value, with its units.
    image_offset : int
        0-based byte offset of the image (``^IMAGE`` - 1) [bytes].
    dn : (512, 512) int32 array, read-only
        ``stored >> 6``, 0..1023 [DN]; row 0 is the first line of the file.
    valid : (512, 512) bool array, read-only
        False at the marker pixels, saturated pixels and the dark top band.
    dark_band_rows : (512,) int array, read-only
        Rows of the dark band per column (the band is ``dn[:dark_band_rows[c], c]``) [px].
    start_time_utc, start_time : str, datetime.datetime
        ``START_TIME`` as in the label (UTC, ISO 8601) and timezone-aware.
    exposure_s, gain_e_per_dn, focal_plane_temperature_k : float
        ``EXPOSURE_DURATION`` [s], ``GAIN_NUMBER`` [e-/DN], ``FOCAL_PLANE_TEMPERATURE`` [K].
    sc_to_moon_m : (3,) float array, read-only
        ``SC_TARGET_POSITION_VECTOR``: spacecraft to Moon centre, Earth mean equator J2000 [m].
    target_center_distance_m : float
        ``TARGET_CENTER_DISTANCE`` [m].
    phase_angle_rad : float or None
        ``PHASE_ANGLE`` [rad]; None where the label says ``N/A``.
    boresight_radec_rad, boresight_radec_deg : (2,) float array, read-only
        ``RIGHT_ASCENSION``, ``DECLINATION`` of the boresight, J2000 [rad] and [deg].
    reticle_radec_rad, reticle_radec_deg : (4, 2) float array, read-only
        ``(RETICLE_POINT_RA[i], RETICLE_POINT_DECLINATION[i])``, the four reticle corners in
        label order, J2000 [rad] and [deg].
    """

    path: Path
    product_id: str
    target_name: str
    observation_type: str
    label: Mapping[str, Any]
    image_offset: int
    dn: NDArray[np.int32]
    valid: BoolArray
    dark_band_rows: IntArray
    start_time_utc: str
    start_time: datetime
    exposure_s: float
    gain_e_per_dn: float
    filter_name: str
    focal_plane_temperature_k: float
    sc_to_moon_m: FloatArray
    target_center_distance_m: float
    phase_angle_rad: float | None
    boresight_radec_rad: FloatArray
    boresight_radec_deg: FloatArray
    reticle_radec_rad: FloatArray
    reticle_radec_deg: FloatArray


def _readonly(a: NDArray[Any]) -> NDArray[Any]:
    a.flags.writeable = False
    return a


def _missing(path: Path, key: str, what: str = "") -> DataFileError:
    return DataFileError(f"{path}: {key} missing from the PDS3 label{what}")


# Units a label value may carry for each unit the reader expects: name -> factor to the
# expected unit (PDS3 units are case-insensitive; a value without units is in the expected one).
_UNIT_FACTORS: Mapping[str, Mapping[str, float]] = MappingProxyType({
    "MS": {"MS": 1.0, "MSEC": 1.0, "MILLISECOND": 1.0, "MILLISECONDS": 1.0,
           "S": 1e3, "SEC": 1e3, "SECOND": 1e3, "SECONDS": 1e3},
    "KM": {"KM": 1.0, "KILOMETER": 1.0, "KILOMETERS": 1.0, "KILOMETRE": 1.0,
           "KILOMETRES": 1.0, "M": 1e-3, "METER": 1e-3, "METERS": 1e-3, "METRE": 1e-3,
           "METRES": 1e-3},
    "DEG": {"DEG": 1.0, "DEGREE": 1.0, "DEGREES": 1.0,
            "RAD": 180.0 / math.pi, "RADIAN": 180.0 / math.pi, "RADIANS": 180.0 / math.pi},
    "K": {"K": 1.0, "KELVIN": 1.0, "DEGK": 1.0},
    "E/DN": {"E/DN": 1.0, "E-/DN": 1.0, "ELECTRONS/DN": 1.0, "ELECTRON/DN": 1.0},
})
_NULLS = ("N/A", "UNK", "NULL", "UNKNOWN")


def _split_units(value: Any) -> tuple[Any, str | None]:
    """``(value, units)`` of a pvl ``Quantity`` (units upper-case, spaces removed), else
    ``(value, None)``."""
    if hasattr(value, "units") and hasattr(value, "value"):
        return value.value, re.sub(r"\s+", "", str(value.units)).upper()
    return value, None


def _single(value: Any) -> Any:
    """A one-element sequence or set stands for its element (PDS3 allows ``(x)`` and ``{x}``)."""
    while isinstance(value, (list, tuple, set, frozenset)) and len(value) == 1:
        value = next(iter(value))
    return value


def _number(value: Any, key: str, path: Path, unit: str | None,
            units: str | None = None) -> float:
    """A label number in the expected ``unit`` (None: a pure number), from any PDS3 form: bare,
    with units, quoted, a one-element sequence or set; units it carries are converted."""
    expected = f" <{unit}>" if unit else ""
    value = _single(value)
    value, own = _split_units(value)
    value = _single(value)
    units = own or units
    if isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError:
            raise DataFileError(f"{path}: {key} = {value!r}: expected a number{expected}"
                                ) from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataFileError(f"{path}: {key} = {value!r}: expected a number{expected}")
    if units is None:
        return float(value)
    if unit is None:
        raise DataFileError(f"{path}: {key} in <{units}>: expected a pure number")
    factor = _UNIT_FACTORS.get(unit, {unit: 1.0}).get(units)
    if factor is None:
        raise DataFileError(f"{path}: {key} in <{units}>: expected <{unit}>")
    return float(value) * factor


def _quantity(label: Mapping[str, Any], key: str, path: Path, unit: str, *,
              optional: bool = False) -> float | None:
    value = label.get(key)
    if value is None:
        if optional:
            return None
        raise _missing(path, key)
    if isinstance(_single(value), str) and _single(value).strip().upper() in _NULLS:
        if optional:
            return None
        raise DataFileError(f"{path}: {key} = {value!r}: expected a number <{unit}>")
    return _number(value, key, path, unit)


def _vector(label: Mapping[str, Any], key: str, path: Path, n: int,
            unit: str | None = None) -> FloatArray:
    """An ordered sequence of ``n`` numbers in ``unit``: units on the sequence (pvl gives a
    ``Quantity`` whose value is the list) or on each element, quoted or bare elements."""
    value = label.get(key)
    if value is None:
        raise _missing(path, key)
    value, units = _split_units(value)
    if isinstance(value, (set, frozenset)) and n > 1:
        raise DataFileError(f"{path}: {key} = {value!r}: a set is unordered: expected a "
                            f"sequence of {n} numbers (x1, ..., x{n})")
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise DataFileError(f"{path}: {key} = {value!r}: expected a sequence of {n} numbers")
    return np.array([_number(v, key, path, unit, units) for v in value], dtype=float)


def _text(label: Mapping[str, Any], key: str, path: Path) -> str:
    """A text value: quoted or unquoted (a symbol), or a one-element sequence or set of one."""
    value = label.get(key)
    if value is None:
        raise _missing(path, key)
    value = _single(value)
    if not isinstance(value, (str, int, float)) or isinstance(value, bool):
        raise DataFileError(f"{path}: {key} = {value!r}: expected a text value")
    return str(value).strip()


def _time(label: Mapping[str, Any], key: str, path: Path) -> datetime:
    """A PDS3 time, unquoted (pvl gives a ``datetime``) or quoted text: calendar
    ``YYYY-MM-DDThh:mm:ss[.fff][Z]`` or day-of-year ``YYYY-DDDThh:mm:ss[.fff][Z]``."""
    value = label.get(key)
    if value is None:
        raise _missing(path, key)
    value = _single(value)
    if isinstance(value, datetime):
        return value
    text = str(value).strip().rstrip("Zz")
    try:
        if re.fullmatch(r"\d{4}-\d{3}(T.*)?", text):
            day, _, clock = text.partition("T")
            clock = clock or "00:00:00"
            fmt = "%Y-%jT%H:%M:%S.%f" if "." in clock else "%Y-%jT%H:%M:%S"
            return datetime.strptime(f"{day}T{clock}", fmt)
        return datetime.fromisoformat(text)
    except ValueError:
        raise DataFileError(f"{path}: {key} = {value!r}: expected a PDS3 UTC time "
                            "(YYYY-MM-DDThh:mm:ss.fff or YYYY-DDDThh:mm:ss.fff)") from None


def _count(label: Mapping[str, Any], key: str, path: Path, where: str = "") -> int:
    """A positive integer keyword (``RECORD_BYTES``, ``LINES``, ...), bare or in <BYTES>."""
    value = label.get(key)
    if value is None:
        raise _missing(path, where + key)
    if hasattr(value, "units") and hasattr(value, "value"):
        value = value.value
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise DataFileError(f"{path}: {where}{key} = {value!r}: expected a positive integer")
    return value


_STATEMENT_RE = re.compile(r"(?m)^[ \t]*(\^?[A-Za-z][A-Za-z0-9_:]*)[ \t]*=")


def _parse_error(text: str, err: ValueError) -> str:
    """One line naming the keyword whose value pvl could not read: the last statement that
    starts before the position of the error (pvl reports where it stopped, which may be the
    start of the next statement)."""
    pos = getattr(err, "pos", None)
    key, line = None, None
    if isinstance(pos, int):
        for m in _STATEMENT_RE.finditer(text, 0, max(pos, 0)):
            if m.start(1) < pos:
                key, line = m.group(1), text.count("\n", 0, m.start(1)) + 1
    what = " ".join(str(getattr(err, "msg", "") or err).split())
    if len(what) > 120:
        what = what[:117] + "..."
    if key is None:
        return f"the PDS3 label does not parse: {what}"
    return (f"the PDS3 label does not parse: the value of {key} (line {line}) is not a PDS3 "
            f"value ({what})")


def _check_units(block: Mapping[str, Any], path: Path, where: str = "") -> None:
    """Refuse units that swallowed statements: pvl reads an unclosed ``<`` up to the next
    ``>``, lines later, so a units text holding ``=`` or a line break is a malformed value."""
    for key, value in block.items():
        if isinstance(value, Mapping):
            _check_units(value, path, f"{where}{key}.")
            continue
        items = value if isinstance(value, (list, tuple, set, frozenset)) else [value]
        for v in [value, *items]:
            units = getattr(v, "units", None)
            if units is not None and ("=" in str(units) or "\n" in str(units)):
                first = str(units).split("\n", 1)[0].strip()
                raise DataFileError(f"{path}: {where}{key}: units <{first} are not closed by "
                                    "'>' on their line: expected e.g. '18 <MS>'")


def _keys(block: Mapping[str, Any]) -> set[str]:
    out = set()
    for key, value in block.items():
        out.add(str(key).upper())
        if isinstance(value, Mapping):
            out |= _keys(value)
    return out


def _check_complete(label: Mapping[str, Any], text: str, path: Path) -> None:
    """Refuse a label pvl stopped reading early: a malformed value (e.g. ``18 <MS`` without
    its ``>``) can make it drop every statement after it without an error. Every statement
    of the text (outside quoted strings) must be in the parsed label; the one before the first
    dropped statement is named."""
    known = _keys(label) | {"OBJECT", "END_OBJECT", "GROUP", "END_GROUP"}
    previous = None
    for m in _STATEMENT_RE.finditer(text):
        if text.count('"', 0, m.start(1)) % 2:
            continue                                  # inside a quoted string
        key = m.group(1).upper()
        if key not in known:
            if previous is None:
                raise DataFileError(f"{path}: the PDS3 label does not parse at {key}")
            line = text.count("\n", 0, previous.start(1)) + 1
            raise DataFileError(
                f"{path}: the PDS3 label does not parse: the value of {previous.group(1)} "
                f"(line {line}) is not a PDS3 value (the statements after it were not read)")
        previous = m


def _parse_label(path: Path, blob: bytes) -> tuple[Mapping[str, Any], int]:
    """The attached PDS3 label and its length [bytes] (RECORD_BYTES x LABEL_RECORDS)."""
    with warnings.catch_warnings():      # pvl 1.x warns about its own Units class on import
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import pvl

    if not blob.lstrip()[:len(_PDS_MAGIC)].upper() == _PDS_MAGIC:
        raise DataFileError(f"{path}: not a PDS3 file: PDS_VERSION_ID missing at the start "
                            f"(first bytes {blob[:24]!r})")
    end = _END_RE.search(blob, 0, MAX_LABEL_BYTES)
    if end is None:
        raise DataFileError(f"{path}: PDS3 label without an END statement in its first "
                            f"{MAX_LABEL_BYTES} bytes")
    try:
        text = blob[:end.end()].decode("ascii")
    except UnicodeDecodeError as err:
        raise DataFileError(f"{path}: the PDS3 label is not ASCII (byte {err.start})"
                            ) from None
    try:
        label = pvl.loads(text)
    except ValueError as err:     # pvl's lexer and parser errors are ValueErrors
        raise DataFileError(f"{path}: {_parse_error(text, err)}") from None
    _check_units(label, path)
    _check_complete(label, text, path)
    label_bytes = _count(label, "RECORD_BYTES", path) * _count(label, "LABEL_RECORDS", path)
    if end.end() > label_bytes:
        raise DataFileError(f"{path}: the PDS3 label ends at byte {end.end()}, beyond "
                            f"RECORD_BYTES x LABEL_RECORDS = {label_bytes}")
    return label, label_bytes


def _image_offset(label: Mapping[str, Any], path: Path, record_bytes: int) -> int:
    """0-based byte offset of ``^IMAGE`` (``<BYTES>``: 1-based bytes; bare: 1-based records)."""
    ptr = label.get("^IMAGE")
    if ptr is None:
        raise _missing(path, "^IMAGE", " (expected e.g. '^IMAGE = 36865 <BYTES>')")
    if hasattr(ptr, "units") and hasattr(ptr, "value"):
        if str(ptr.units).strip().upper() != "BYTES" or not isinstance(ptr.value, int):
            raise DataFileError(f"{path}: ^IMAGE = {ptr!r}: expected an integer <BYTES>")
        offset = ptr.value - 1
    elif isinstance(ptr, int) and not isinstance(ptr, bool):
        offset = (ptr - 1) * record_bytes
    else:
        raise DataFileError(f"{path}: ^IMAGE = {ptr!r}: only a pointer into this file is "
                            "supported (1-based <BYTES> or record number)")
    if offset < 0:
        raise DataFileError(f"{path}: ^IMAGE = {ptr!r}: pointers are 1-based (>= 1)")
    return offset


def _decode_image(blob: bytes, offset: int, image: Mapping[str, Any], path: Path
                  ) -> NDArray[np.int32]:
    """``stored >> shift`` with the shift from ``SCALING_FACTOR``; exact or refused."""
    lines = _count(image, "LINES", path, "IMAGE.")
    samples = _count(image, "LINE_SAMPLES", path, "IMAGE.")
    if (lines, samples) != FRAME_SHAPE:
        raise DataFileError(f"{path}: IMAGE LINES x LINE_SAMPLES = {lines} x {samples}: "
                            f"expected {FRAME_SHAPE[0]} x {FRAME_SHAPE[1]} (the NONE quadrant)")
    bits = image.get("SAMPLE_BITS")
    kind = str(image.get("SAMPLE_TYPE", "")).strip().upper()
    byteorder = {"LSB_UNSIGNED_INTEGER": "<", "MSB_UNSIGNED_INTEGER": ">",
                 "UNSIGNED_INTEGER": ">"}.get(kind)
    if bits != 16 or byteorder is None:
        raise DataFileError(f"{path}: IMAGE SAMPLE_TYPE = {kind or None!r}, SAMPLE_BITS = "
                            f"{bits!r}: expected 16-bit LSB_UNSIGNED_INTEGER")
    for key in ("LINE_PREFIX_BYTES", "LINE_SUFFIX_BYTES", "OFFSET"):
        if image.get(key, 0) != 0:
            raise DataFileError(f"{path}: IMAGE {key} = {image.get(key)!r}: expected 0")
    factor = _number(image.get("SCALING_FACTOR", 1.0), "IMAGE.SCALING_FACTOR", path, None)
    shift = round(-math.log2(factor)) if factor > 0 else -1
    if not (0 <= shift < 16 and 2.0 ** -shift == factor):
        raise DataFileError(f"{path}: IMAGE SCALING_FACTOR = {factor!r}: expected 2^-n, "
                            "0 <= n < 16 (an exact bit shift)")
    need = lines * samples * 2
    have = len(blob) - offset
    if have < need:
        raise DataFileError(f"{path}: truncated: ^IMAGE at byte {offset} needs LINES x "
                            f"LINE_SAMPLES x 2 = {need} bytes, the file holds {max(have, 0)}")
    stored = np.frombuffer(blob, dtype=np.dtype(f"{byteorder}u2"), count=lines * samples,
                           offset=offset).reshape(lines, samples)
    low = int(np.count_nonzero(stored & ((1 << shift) - 1)))
    if low:
        raise DataFileError(f"{path}: IMAGE SCALING_FACTOR = {factor!r}: {low} stored values "
                            f"are not multiples of {1 << shift}, the decoding would not be exact")
    return (stored >> shift).astype(np.int32)


def read_amie(path: str | Path) -> AmieFrame:
    """Read a raw AMIE ``.IMG`` (attached PDS3 label, NONE filter).

    Parameters
    ----------
    path : str or pathlib.Path
        The file, e.g. ``packaged_frame("041111_00070")``.

    Returns
    -------
    AmieFrame
        ``dn`` [DN] and ``valid`` (marker, saturated and dark-band pixels False), the label
        values in SI units (exposure [s], distances [m], angles [rad]) and the parsed label.

    Raises
    ------
    DataFileError
        Missing or unreadable file, not a PDS3 file, a label without ``^IMAGE`` or another
        needed keyword, an unsupported image layout, or a file shorter than ``LINES x
        LINE_SAMPLES x 2`` bytes after the pointer; the message names the file and the field.
    ConfigError
        ``FILTER_NAME`` other than ``NONE`` (the calibration files are the NONE quadrant).
    """
    path = Path(path)
    try:
        blob = path.read_bytes()
    except OSError as err:
        raise DataFileError(f"{path}: cannot read the AMIE frame ({err.strerror or err})"
                            ) from err
    label, _ = _parse_label(path, blob)
    record_bytes = _count(label, "RECORD_BYTES", path)
    filter_name = _text(label, "FILTER_NAME", path)
    if filter_name.upper() != SUPPORTED_FILTER:
        raise ConfigError(f"{path}: FILTER_NAME", filter_name,
                          f"{SUPPORTED_FILTER!r} (the calibration files are the NONE quadrant)")
    offset = _image_offset(label, path, record_bytes)
    image = label.get("IMAGE")
    if not isinstance(image, Mapping):
        raise _missing(path, "IMAGE object")
    dn = _decode_image(blob, offset, image, path)

    start_dt = _time(label, "START_TIME", path)
    if start_dt.tzinfo is None:
        start_dt = start_dt.replace(tzinfo=UTC)
    spec = "milliseconds" if start_dt.microsecond % 1000 == 0 else "microseconds"
    start_utc = start_dt.replace(tzinfo=None).isoformat(timespec=spec)

    deg = math.pi / 180.0
    ra = _quantity(label, "RIGHT_ASCENSION", path, "DEG")
    dec = _quantity(label, "DECLINATION", path, "DEG")
    boresight_deg = np.array([ra, dec], dtype=float)
    reticle_deg = np.stack([_vector(label, "RETICLE_POINT_RA", path, 4, "DEG"),
                            _vector(label, "RETICLE_POINT_DECLINATION", path, 4, "DEG")], axis=1)
    phase = _quantity(label, "PHASE_ANGLE", path, "DEG", optional=True)

    marker_ok = all(dn[r, c] == DN_MAX for r, c in MARKER_PIXELS)
    if not marker_ok:
        log.warning("%s: marker pixels %s read %s, expected %d", path, MARKER_PIXELS,
                    [int(dn[r, c]) for r, c in MARKER_PIXELS], DN_MAX)
    valid = dn < DN_MAX
    for r, c in MARKER_PIXELS:
        valid[r, c] = False
    band = dark_band_rows(dn, valid)
    rows = np.arange(dn.shape[0])[:, None]
    valid &= rows >= band[None, :]

    return AmieFrame(
        path=path,
        product_id=_text(label, "PRODUCT_ID", path),
        target_name=_text(label, "TARGET_NAME", path) if "TARGET_NAME" in label else "",
        observation_type=(_text(label, "IMAGE_OBSERVATION_TYPE", path)
                          if "IMAGE_OBSERVATION_TYPE" in label else ""),
        label=label,
        image_offset=offset,
        dn=_readonly(dn),
        valid=_readonly(valid),
        dark_band_rows=_readonly(band),
        start_time_utc=start_utc,
        start_time=start_dt,
        exposure_s=float(_quantity(label, "EXPOSURE_DURATION", path, "MS")) * 1e-3,
        gain_e_per_dn=float(_quantity(label, "GAIN_NUMBER", path, "E/DN")),
        filter_name=filter_name,
        focal_plane_temperature_k=float(_quantity(label, "FOCAL_PLANE_TEMPERATURE", path, "K")),
        sc_to_moon_m=_readonly(_vector(label, "SC_TARGET_POSITION_VECTOR", path, 3, "KM") * 1e3),
        target_center_distance_m=float(_quantity(label, "TARGET_CENTER_DISTANCE", path, "KM"))
        * 1e3,
        phase_angle_rad=None if phase is None else phase * deg,
        boresight_radec_rad=_readonly(boresight_deg * deg),
        boresight_radec_deg=_readonly(boresight_deg),
        reticle_radec_rad=_readonly(reticle_deg * deg),
        reticle_radec_deg=_readonly(reticle_deg),
    )


# --------------------------------------------------------------------------- the dark band
def _robust_sigma(x: NDArray[Any], clip: float = 4.0, iterations: int = 5) -> float:
    """Standard deviation after iterated ``clip``-sigma clipping about the median (works on
    integer data, where the MAD is often 0)."""
    x = np.asarray(x, float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 2:
        return math.nan
    keep = x
    s = float(np.std(keep))
    for _ in range(iterations):
        med = float(np.median(keep))
        new = x[np.abs(x - med) <= clip * s] if s > 0 else keep
        if new.size < 2 or new.size == keep.size:
            break
        keep = new
        s = float(np.std(keep))
    return s


def _fill(values: FloatArray, good: BoolArray) -> FloatArray:
    """``values`` with the entries not ``good`` linearly interpolated from the good ones
    (constant beyond the ends); all zero if none is good."""
    if good.all():
        return values
    if not good.any():
        return np.zeros_like(values)
    idx = np.arange(values.size)
    return np.interp(idx, idx[good], values[good])


def dark_band_rows(dn: NDArray[Any], usable: BoolArray | None = None, *,
                   search_rows: int = BAND_SEARCH_ROWS,
                   reference_rows: tuple[int, int] = BAND_REFERENCE_ROWS,
                   smooth: tuple[int, int] = BAND_SMOOTH,
                   min_depth_dn: float = BAND_MIN_DEPTH_DN,
                   n_sigma: float = BAND_NSIGMA,
                   sky_clip_dn: float = BAND_SKY_CLIP_DN) -> IntArray:
    """Depth of the dark top band of each column, detected from the data (module docstring).

    Parameters
    ----------
    dn : (lines, samples) array
        The raw frame [DN].
    usable : (lines, samples) bool array, optional
        Pixels that may be used (e.g. not saturated); default all.
    search_rows : int
        The band lies within the top ``search_rows`` rows [px].
    reference_rows : (int, int)
        Rows ``[start, stop)`` below the band where the sky ramp and the column offsets are
        measured [px].
    smooth : (int, int)
        Running-median window (rows, columns) applied to the residual [px].
    min_depth_dn, n_sigma : float
        The band ends where the smoothed residual rises to ``-max(min_depth_dn, n_sigma x
        sigma)`` [DN], [-].
    sky_clip_dn : float
        Reference pixels more than this above the ramp are not sky [DN].

    Returns
    -------
    (samples,) int array
        Rows of the band per column: rows ``0 .. band[c] - 1`` of column ``c`` (0: no band).
    """
    from scipy import ndimage

    x = np.asarray(dn, float)
    n_rows, n_cols = x.shape
    ok = np.ones(x.shape, bool) if usable is None else np.asarray(usable, bool)
    r0, r1 = reference_rows
    ref, ref_ok = x[r0:r1], ok[r0:r1]
    rows = np.arange(r0, r1, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # all-masked rows/columns
        profile = np.nanmedian(np.where(ref_ok, ref, np.nan), axis=1)
        fin = np.isfinite(profile)
        if fin.sum() < 2:
            return np.zeros(n_cols, dtype=np.int64)
        slope, icpt = np.polyfit(rows[fin], profile[fin], 1)
        line = icpt + slope * np.arange(r1, dtype=float)
        dref = ref - line[r0:r1, None]
        sky = ref_ok & (dref < sky_clip_dn)
        offsets = np.nanmedian(np.where(sky, dref, np.nan), axis=0)
    reliable = sky.sum(axis=0) >= (r1 - r0) // 2
    offsets = _fill(np.where(reliable, offsets, 0.0), reliable)
    resid = x[:r1] - line[:, None] - offsets[None, :]
    smoothed = ndimage.median_filter(resid, size=smooth, mode="nearest")
    sigma = _robust_sigma(smoothed[r0:r1][:, reliable])
    thr = max(min_depth_dn, n_sigma * sigma) if math.isfinite(sigma) else min_depth_dn
    risen = smoothed[:search_rows] >= -thr
    band = np.where(risen.any(axis=0), risen.argmax(axis=0), search_rows).astype(np.int64)
    band[~reliable] = 0
    return band


# --------------------------------------------------------------------------- calibration
def _no_scaling(temperature_k: float) -> float:
    return 1.0


def silicon_thermal_factor(temperature_k: float) -> float:
    """Thermal-generation factor of silicon relative to 273.15 K, as amiextractor scales the
    master bias (``amie_thermal_noise_factor.m``).

    ``k(T) = (T/T0)^1.5 exp(Eg(T0)/(2 k_B T0) - Eg(T)/(2 k_B T))`` with
    ``Eg(T) = 1.11557 - 7.021e-4 T^2 / (1108 + T)`` eV (amiextractor's constants), ``T0`` =
    273.15 K, ``k_B`` = 8.6171e-5 eV/K.

    Parameters
    ----------
    temperature_k : float
        Focal-plane temperature [K].

    Returns
    -------
    float
        ``k(T)`` [-]: 1 at 273.15 K, about 4.5 at 290 K.
    """
    def eg(t: float) -> float:
        return 1.11557 - 7.021e-4 * t * t / (1108.0 + t)

    t0, t = BIAS_REFERENCE_TEMPERATURE, float(temperature_k)
    if not t > 0:
        raise ConfigError("temperature_k", temperature_k, "a temperature > 0 [K]")
    return (t / t0) ** 1.5 * math.exp(eg(t0) / (2 * _BOLTZMANN_EV * t0)
                                      - eg(t) / (2 * _BOLTZMANN_EV * t))


#: Temperature laws of the master bias: name -> factor(T [K]) applied to it [-].
BIAS_LAWS: Registry[Callable[[float], float]] = Registry("bias law", {
    "none": _no_scaling,
    "silicon-thermal": silicon_thermal_factor,
})


@dataclass(frozen=True)
class AmieCalibrationOptions:
    """Knobs of :func:`calibrate`.

    Attributes
    ----------
    bias_law : str
        Temperature law of the master bias, a key of :data:`BIAS_LAWS`.
    sky_nsigma : float
        Source threshold of the 5 x 5 median-smoothed residual [its rms].
    sky_margin_px : int
        Dark sky lies farther than this from a source pixel [px].
    hot_nsigma : float
        Single pixels beyond this many rms are left out of the sky [-].
    min_sky_pixels, sky_iterations : int
        Rows/columns with fewer dark-sky pixels take interpolated terms; fit / selection rounds.
    min_flat : float
        Pixels whose unit-median flat is below this are invalid [-].
    """

    bias_law: str = "none"
    sky_nsigma: float = 3.0
    sky_margin_px: int = 5
    hot_nsigma: float = 5.0
    min_sky_pixels: int = 32
    sky_iterations: int = 3
    min_flat: float = 0.5

    def __post_init__(self) -> None:
        BIAS_LAWS.check(self.bias_law)
        for name in ("sky_nsigma", "hot_nsigma"):
            if not getattr(self, name) > 0:
                raise ConfigError(name, getattr(self, name), "a number > 0 [sigma]")
        for name in ("sky_margin_px", "min_sky_pixels", "sky_iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < (1 if name != "sky_margin_px"
                                                                     else 0):
                raise ConfigError(name, v, "a non-negative integer (iterations, pixels: >= 1)")
        if not 0.0 <= self.min_flat < 1.0:
            raise ConfigError("min_flat", self.min_flat, "a fraction in [0, 1)")


@dataclass(frozen=True, eq=False)
class AmieCalibrated:
    """A calibrated AMIE frame (:func:`calibrate`).

    Attributes
    ----------
    frame : AmieFrame
    dn : (512, 512) float array, read-only
        Bias-, background- and flat-corrected signal [DN]: 0 on average over the dark sky.
    electrons, signal_e_per_s : (512, 512) float array, read-only
        ``dn x gain`` [e-] and ``electrons / exposure`` [e-/s].
    valid : (512, 512) bool array, read-only
        ``frame.valid`` and the flat at least ``min_flat``.
    sky : (512, 512) bool array, read-only
        The dark-sky pixels the background was fitted to.
    row_background_dn : (512,) float array, read-only
        Row term ``R`` of the sky background, including the columns' median offset [DN].
    column_offsets_dn : (512,) float array, read-only
        Column stripes ``C - median(C)`` [DN].
    background_dn, background_rms_dn : float
        Median and clipped rms (the noise) of ``dn`` over the dark sky after calibration [DN].
    bias_scale, gain_e_per_dn : float
        Factor applied to the master bias [-]; the frame's gain [e-/DN].
    options : AmieCalibrationOptions
    """

    frame: AmieFrame
    dn: FloatArray
    electrons: FloatArray
    signal_e_per_s: FloatArray
    valid: BoolArray
    sky: BoolArray
    row_background_dn: FloatArray
    column_offsets_dn: FloatArray
    background_dn: float
    background_rms_dn: float
    bias_scale: float
    gain_e_per_dn: float
    options: AmieCalibrationOptions


def _load_calibration(name: str) -> FloatArray:
    a = np.load(packaged_path(name)).astype(float)
    if a.shape != FRAME_SHAPE or not np.all(np.isfinite(a)):
        raise DataFileError(f"calibration file starnav/data/{name}: shape {a.shape} or "
                            f"non-finite values: expected finite {FRAME_SHAPE}")
    return a


def _median_polish(x: FloatArray, sky: BoolArray, min_pixels: int, iterations: int = 4
                   ) -> tuple[FloatArray, FloatArray]:
    """Row and column terms, ``x ~ R[:, None] + C[None, :]`` over ``sky`` (alternate medians)."""
    xm = np.where(sky, x, np.nan)
    rows_ok = sky.sum(axis=1) >= min_pixels
    cols_ok = sky.sum(axis=0) >= min_pixels
    col = np.zeros(x.shape[1])
    row = np.zeros(x.shape[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # all-NaN rows/columns
        for _ in range(iterations):
            row = _fill(np.nan_to_num(np.nanmedian(xm - col[None, :], axis=1)), rows_ok)
            col = _fill(np.nan_to_num(np.nanmedian(xm - row[:, None], axis=0)), cols_ok)
    return row, col


def _sky_background(x: FloatArray, usable: BoolArray, saturated: BoolArray,
                    opt: AmieCalibrationOptions) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Row and column background terms and the dark-sky mask (module docstring, stage 2)."""
    from scipy import ndimage

    sky = usable.copy()
    square = np.ones((3, 3), bool)
    for _ in range(opt.sky_iterations):
        row, col = _median_polish(x, sky, opt.min_sky_pixels)
        resid = x - row[:, None] - col[None, :]
        sigma = _robust_sigma(resid[sky])
        smoothed = ndimage.median_filter(resid, size=5, mode="nearest")
        s_sigma = _robust_sigma(smoothed[sky])
        source = (smoothed > opt.sky_nsigma * s_sigma) | saturated
        if opt.sky_margin_px > 0:
            source = ndimage.binary_dilation(source, structure=square,
                                             iterations=opt.sky_margin_px)
        sky = usable & ~source & (np.abs(resid) <= opt.hot_nsigma * sigma)
    row, col = _median_polish(x, sky, opt.min_sky_pixels)
    return row, col, sky


def calibrate(frame: AmieFrame, *, options: AmieCalibrationOptions | None = None
              ) -> AmieCalibrated:
    """Bias, sky background (row ramp and column stripes), flat, electrons, rate.

    The master bias (``calib/mfbias_NONE_512.npy``, DN at 273.15 K) is subtracted without
    temperature scaling by default: neither the data README nor the label gives a law, and the
    master's pattern is found in the frames at scale ~1 whatever their temperature (the
    silicon law, ``options.bias_law = "silicon-thermal"``, raises the dark sky's rms); the row
    ramp that does scale with temperature is measured on each frame's dark sky (stage 2).

    Parameters
    ----------
    frame : AmieFrame
    options : AmieCalibrationOptions, optional
    """
    opt = options or AmieCalibrationOptions()
    bias = _load_calibration(BIAS_FILE)
    ff = _load_calibration(FLAT_FILE)
    flat = ff / float(np.median(ff))
    bias_scale = float(BIAS_LAWS[opt.bias_law](frame.focal_plane_temperature_k))

    x = frame.dn.astype(float) - bias_scale * bias                                # stage 1
    saturated = frame.dn >= DN_MAX
    for r, c in MARKER_PIXELS:
        saturated[r, c] = False
    row, col, sky = _sky_background(x, np.asarray(frame.valid), saturated, opt)
    x = x - row[:, None] - col[None, :]                                         # stage 2
    valid = np.asarray(frame.valid) & (flat >= opt.min_flat)
    dn = x / flat                                                               # stage 3
    sky &= valid
    background = float(np.median(dn[sky])) if sky.any() else math.nan
    rms = _robust_sigma(dn[sky]) if sky.any() else math.nan
    electrons = dn * frame.gain_e_per_dn                                        # stage 4
    rate = electrons / frame.exposure_s                                         # stage 5
    col_median = float(np.median(col))
    log.debug("%s: bias x %.3f, background %.3f DN, rms %.3f DN, sky %.1f %%",
              frame.product_id, bias_scale, background, rms, 100.0 * sky.mean())
    return AmieCalibrated(
        frame=frame, dn=_readonly(dn), electrons=_readonly(electrons),
        signal_e_per_s=_readonly(rate), valid=_readonly(valid), sky=_readonly(sky),
        row_background_dn=_readonly(row + col_median),
        column_offsets_dn=_readonly(col - col_median),
        background_dn=background, background_rms_dn=rms, bias_scale=bias_scale,
        gain_e_per_dn=frame.gain_e_per_dn, options=opt)


# --------------------------------------------------------------------------- the Moon's signal
@dataclass(frozen=True, eq=False)
class MoonSignal:
    """Background-subtracted signal summed over a set of pixels (:func:`moon_signal`).

    Attributes
    ----------
    mask : (512, 512) bool array
        The pixels summed (``n_pixels`` of them).
    n_pixels : int
    dn, electrons, e_per_s : float
        Sum of ``dn - background`` [DN], times the gain [e-], over the exposure [e-/s].
    """

    mask: BoolArray
    n_pixels: int
    dn: float
    electrons: float
    e_per_s: float


def moon_signal(cal: AmieCalibrated, *, n_sigma: float = 5.0,
                aperture: BoolArray | None = None) -> MoonSignal:
    """The Moon's (or a star's) signal: ``dn - background`` summed over the valid pixels above
    ``background + n_sigma x rms``, or over a given ``aperture`` (and ``cal.valid``; e.g. one
    aperture for two frames).
    """
    if aperture is None:
        if not n_sigma > 0:
            raise ConfigError("n_sigma", n_sigma, "a number > 0 [sigma]")
        mask = cal.valid & (cal.dn > cal.background_dn + n_sigma * cal.background_rms_dn)
    else:
        aperture = np.asarray(aperture, bool)
        if aperture.shape != cal.dn.shape:
            raise ConfigError("aperture", aperture.shape, f"a bool mask of shape {cal.dn.shape}")
        mask = aperture & cal.valid
    total = float(np.sum(cal.dn[mask] - cal.background_dn))
    electrons = total * cal.gain_e_per_dn
    return MoonSignal(mask=mask, n_pixels=int(mask.sum()), dn=total, electrons=electrons,
                      e_per_s=electrons / cal.frame.exposure_s)


# --------------------------------------------------------------------------- packaged frames
def packaged_frame(name_or_id: str) -> Path:
    """Path of a packaged AMIE frame.

    Parameters
    ----------
    name_or_id : str
        A key of :data:`AMIE_FRAMES` (``"AMI_EE3_041111_00070_00018.IMG"``), its product id
        (``"AMI_EE3_041111_00070_00018"``) or the data README's short name
        (``"041111_00070"``); case-insensitive.

    Returns
    -------
    pathlib.Path
        The ``.IMG`` inside the installed package.

    Raises
    ------
    UnknownNameError
        Not a packaged frame; the message lists them.
    DataFileError
        The file is missing from the installation.
    """
    key = str(name_or_id).strip().upper()
    for name in AMIE_FRAMES:
        stem = name[:-len(".IMG")]
        if key in (name.upper(), stem.upper(), stem[len("AMI_EE3_"):-len("_00000")].upper()):
            return packaged_path(f"amie/img/{name}")
    raise UnknownNameError("AMIE frame", str(name_or_id), list(AMIE_FRAMES))
