"""One CLI convention for times (issue 14): seconds or a number with its unit."""

from __future__ import annotations

import pytest

from starnav.cli._units import parse_time, parse_times
from starnav.errors import ConfigError


@pytest.mark.parametrize("text, seconds", [
    ("1.5e-5", 1.5e-5), ("15us", 1.5e-5), ("15 µs", 1.5e-5), ("0.015ms", 1.5e-5),
    ("7.7ms", 7.7e-3), ("7.7e-3", 7.7e-3), ("0.2s", 0.2), (".5 s", 0.5), ("200ns", 2e-7)])
def test_times_with_and_without_units(text, seconds):
    assert parse_time(text, "--exposure") == pytest.approx(seconds, rel=1e-12)


@pytest.mark.parametrize("text", ["x", "7.7 min", "-1ms", "0", "nan", "1e400", ""])
def test_bad_times_name_the_flag_and_the_value(text):
    with pytest.raises(ConfigError, match="--exposure") as e:
        parse_time(text, "--exposure")
    assert repr(text) in str(e.value) or text in str(e.value)


def test_a_time_with_a_unit_is_the_same_float_as_the_plain_literal():
    assert parse_time("15us", "--exposure") == 1.5e-5
    assert parse_time("7.7ms", "--exposure") == 7.7e-3
    assert parse_time("0.015ms", "--exposure") == 1.5e-5


def test_lists():
    assert parse_times("15us, 7.7ms", "--exposures") == pytest.approx((1.5e-5, 7.7e-3))
    with pytest.raises(ConfigError, match="--exposures"):
        parse_times(" , ", "--exposures")
