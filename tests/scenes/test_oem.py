"""CCSDS OEM KVN: round trip to the printed precision, centres and time systems, errors."""

from __future__ import annotations

import numpy as np
import pytest

from starnav.errors import DataFileError
from starnav.scenes.ephemeris import parse_epoch
from starnav.scenes.oem import (
    POSITION_DECIMALS,
    VELOCITY_DECIMALS,
    OEMFormatError,
    format_oem,
    parse_oem,
    read_oem,
    tdb_to_iso,
    write_oem,
)
from starnav.scenes.trajectory import Trajectory

CREATED = "2026-01-01T00:00:00"


@pytest.fixture(scope="module")
def short(arc):
    return Trajectory(arc.times[:50], arc.states[:50], arc.object_name)


def test_round_trip_exact_to_printed_precision(short, tmp_path):
    path = write_oem(tmp_path / "a.oem", short, creation_date=CREATED)
    back = read_oem(path)
    assert np.array_equal(back.times, short.times)  # epochs on whole microseconds
    half_p = 0.5 * 10.0**-POSITION_DECIMALS * 1e3  # half the last printed digit [m]
    half_v = 0.5 * 10.0**-VELOCITY_DECIMALS * 1e3  # [m/s]
    assert np.abs(back.states[:, :3] - short.states[:, :3]).max() <= half_p * (1 + 1e-6)
    assert np.abs(back.states[:, 3:] - short.states[:, 3:]).max() <= half_v * (1 + 1e-6)
    # and re-writing what was read gives the same text, character for character
    assert format_oem(back, creation_date=CREATED) == path.read_text()
    assert back.object_name == short.object_name


def test_moon_centred_utc_file_is_converted(short, eph):
    # the same states written Moon-centred, with epochs in UTC by hand
    moon = eph.state("moon", short.times, center="emb")
    lines = ["CCSDS_OEM_VERS = 2.0", "COMMENT hand-made", f"CREATION_DATE = {CREATED}",
             "ORIGINATOR = TEST", "", "META_START", "OBJECT_NAME = SC", "OBJECT_ID = 2027-001A",
             "CENTER_NAME = MOON", "REF_FRAME = EME2000", "TIME_SYSTEM = UTC",
             "START_TIME = 2027-03-01T00:00:00", "STOP_TIME = 2027-03-01T01:00:00",
             "META_STOP"]
    from starnav.scenes.ephemeris import format_epoch

    for t, x in zip(short.times[:10], short.states[:10] - moon[:10], strict=True):
        ep = format_epoch(t, "UTC", suffix=False)
        lines.append(ep + " " + " ".join(f"{c / 1e3:.6f}" for c in x[:3])
                     + " " + " ".join(f"{c / 1e3:.9f}" for c in x[3:]))
    back = parse_oem("\n".join(lines))
    assert np.allclose(back.times, short.times[:10], rtol=0, atol=2e-6)
    assert np.abs(back.states[:, :3] - short.states[:10, :3]).max() < 1e-2  # 1 cm
    assert np.abs(back.states[:, 3:] - short.states[:10, 3:]).max() < 1e-5


def test_day_of_year_epochs_and_covariance_blocks(short):
    text = format_oem(short, creation_date=CREATED)
    lines = text.splitlines()
    # 2027-03-01 is day 060
    lines = [ln.replace("2027-03-01T", "2027-060T") if ln[:4] == "2027" else ln for ln in lines]
    lines += ["COVARIANCE_START", "EPOCH = 2027-03-01T00:00:00", "COV_REF_FRAME = ICRF",
              "1.0", "COVARIANCE_STOP"]
    back = parse_oem("\n".join(lines))
    assert np.array_equal(back.times, short.times)


def test_tdb_iso_formatting():
    assert tdb_to_iso(0.0) == "2000-01-01T12:00:00.000000"
    assert tdb_to_iso(parse_epoch("2027-03-01T00:00:00.25 TDB")) == "2027-03-01T00:00:00.250000"


def _valid_text(short):
    return format_oem(Trajectory(short.times[:3], short.states[:3]), creation_date=CREATED)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda s: s.replace("CCSDS_OEM_VERS = 2.0", "CCSDS_OPM_VERS = 2.0"), "line 1.*header"),
        (lambda s: s.replace("META_STOP\n", ""), "line 16.*'KEY = value' in metadata"),
        (lambda s: s.split("META_STOP")[0], "META_START without META_STOP"),
        (lambda s: s.replace("REF_FRAME = ICRF", "REF_FRAME = ITRF"), "REF_FRAME.*ITRF"),
        (lambda s: s.replace("TIME_SYSTEM = TDB", "TIME_SYSTEM = MET"), "TIME_SYSTEM"),
        (lambda s: s.replace("CENTER_NAME = EARTH-MOON BARYCENTER", "CENTER_NAME = MARS"),
         "CENTER_NAME"),
        (lambda s: s.replace("OBJECT_ID = LUMIO-LIKE\n", ""), "missing OBJECT_ID"),
        (lambda s: s.rstrip("\n") + " 1.0\n", r"line 19.*6 \(or 9\) numbers"),
        (lambda s: s.replace(".000000 ", ".000000 abc ", 1).replace("abc -", "abc "),
         "line 17"),
        (lambda s: s.replace("2027-03-01T00:05:00.000000", "2027-03-01T25:05:00.000000"),
         "line 18: epoch"),
        (lambda s: s.replace("2027-03-01T00:10:00.000000", "2027-03-01T00:00:00.000000"),
         "line 19.*strictly increasing"),
        (lambda s: s.replace("ORIGINATOR = STARNAV\n", ""), "missing ORIGINATOR"),
        (lambda s: s.split("META_START")[0], "no META_START"),
        (lambda s: "", "header"),
    ],
)
def test_malformed_oem_is_a_clear_error(short, mutate, message):
    text = mutate(_valid_text(short))
    with pytest.raises(OEMFormatError, match=message):
        parse_oem(text, source="bad.oem")


def test_missing_file(tmp_path):
    with pytest.raises(DataFileError, match="does not exist"):
        read_oem(tmp_path / "nope.oem")
