"""The shared helpers: the name registry, the bounded cache, dotted overrides, field types."""

from __future__ import annotations

import re

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError

from starnav.cache import BoundedCache
from starnav.config_base import (
    StrictModel,
    apply_overrides,
    format_validation_error,
    parse_override,
    set_dotted,
)
from starnav.errors import ConfigError, UnknownNameError
from starnav.fields import PositiveFloat, PositiveFraction, UnitInterval
from starnav.registry import Registry


# --------------------------------------------------------------------------- registry
def test_register_by_call_and_by_decorator_and_get():
    reg: Registry[object] = Registry("widget", {"b": 2})
    assert reg.register("a", 1) == 1

    @reg.register("c")
    def make_c():
        return 3

    assert make_c() == 3                       # the decorator returns its target unchanged
    assert reg.get("a") == 1 and reg["b"] == 2 and reg.get("c") is make_c
    assert reg.names() == ("b", "a", "c")      # registration order, not sorted
    assert list(reg) == ["b", "a", "c"] and len(reg) == 3
    assert dict(reg.items()) == {"b": 2, "a": 1, "c": make_c}
    assert list(reg.values()) == [2, 1, make_c]
    assert "a" in reg and "z" not in reg and ["a"] not in reg
    assert reg.check("c") == "c"


def test_unknown_name_lists_the_known_names_sorted():
    reg = Registry("bias model", {"range-scale": 1, "none": 0, "limb-common": 3, "additive": 3})
    with pytest.raises(UnknownNameError) as info:
        reg.get("scale")
    err = info.value
    assert str(err) == "unknown bias model 'scale'; known: additive, limb-common, none, range-scale"
    assert err.kind == "bias model" and err.name == "scale"
    assert err.known == ("additive", "limb-common", "none", "range-scale")
    assert isinstance(err, KeyError)           # callers catching KeyError keep working
    with pytest.raises(UnknownNameError, match="unknown bias model 'x'"):
        reg["x"]
    with pytest.raises(UnknownNameError):
        reg.check("x")
    with pytest.raises(UnknownNameError):      # an unhashable name is unknown, not a TypeError
        reg.get(["none"])  # type: ignore[arg-type]


def test_a_name_is_registered_once():
    reg = Registry("widget", {"a": 1})
    with pytest.raises(ValueError, match="'a' is registered already"):
        reg.register("a", 2)
    with pytest.raises(ValueError, match="registered already"):
        reg.register("a")(lambda: None)
    with pytest.raises(ValueError, match="non-empty string"):
        reg.register("", 3)
    assert reg.get("a") == 1                   # the first registration survives


def test_the_project_registries_use_the_shared_error():
    from starnav.detector.chain import EFFECTS, get_effect
    from starnav.navigation.ekf import BIAS_MODELS, measurement_model
    from starnav.photometry import PHOTOMETRIC_MODELS, get_model

    assert get_model("hapke") is PHOTOMETRIC_MODELS["hapke"]
    with pytest.raises(UnknownNameError, match="known: hapke, lambert, lommel_seeliger, "
                       "lunar_lambert$"):
        get_model("phong")
    with pytest.raises(UnknownNameError, match="unknown detector effect 'bloom'"):
        get_effect("bloom")
    assert "read_noise" in EFFECTS
    with pytest.raises(UnknownNameError, match=re.escape(", ".join(sorted(BIAS_MODELS)))):
        measurement_model(np.zeros(9), np.zeros(3), "scale")


def test_mitsuba_plugin_names_follow_the_model_registry():
    pytest.importorskip("mitsuba")
    from starnav.photometry import PHOTOMETRIC_MODELS
    from starnav.renderer.bsdfs import PLUGIN_NAMES

    assert PLUGIN_NAMES.names() == PHOTOMETRIC_MODELS.names()
    assert PLUGIN_NAMES["lommel_seeliger"] == "starnav_lommel_seeliger"


# --------------------------------------------------------------------------- cache
def test_cache_is_bounded_and_evicts_the_least_recently_used():
    c: BoundedCache[str, list[int]] = BoundedCache(2)
    c.put("a", [1])
    c.put("b", [2])
    assert c.get("a") == [1]                   # "a" becomes the most recent
    c.put("c", [3])                            # evicts "b", the least recently used
    assert len(c) == 2 and c.keys() == ("a", "c")
    assert "b" not in c and c.get("b") is None
    c.put("d", [4])                            # evicts "a"
    assert c.keys() == ("c", "d")


def test_fifo_cache_evicts_in_insertion_order_whatever_the_hits():
    c: BoundedCache[str, int] = BoundedCache(2, policy="fifo")
    c.put("a", 1)
    c.put("b", 2)
    assert c.get("a") == 1                     # a hit does not refresh a FIFO entry
    c.put("c", 3)
    assert c.keys() == ("b", "c")


def test_a_hit_returns_the_stored_object_and_counts():
    c: BoundedCache[tuple[int, str], dict[str, int]] = BoundedCache(4)
    calls = []

    def make() -> dict[str, int]:
        calls.append(1)
        return {"n": len(calls)}

    first = c.get_or_make((1, "x"), make)
    again = c.get_or_make((1, "x"), make)
    assert again is first and len(calls) == 1
    assert c.get((1, "x")) is first
    assert (c.hits, c.misses) == (2, 1)
    assert c.get((2, "y"), "default") == "default" and c.misses == 2
    c.clear()
    assert len(c) == 0 and (c.hits, c.misses) == (0, 0)
    assert c.get_or_make((1, "x"), make) is not first and len(calls) == 2


def test_cache_bound_can_change_and_zero_keeps_nothing():
    c: BoundedCache[int, int] = BoundedCache(3)
    for k in range(3):
        c.put(k, k)
    c.maxsize = 1
    c.put(9, 9)                                # the new bound applies at the next insertion
    assert c.keys() == (9,)
    off: BoundedCache[int, int] = BoundedCache(0)
    assert off.get_or_make(1, lambda: 5) == 5 and len(off) == 0
    with pytest.raises(ValueError, match="policy"):
        BoundedCache(2, policy="random")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- dotted keys
def test_set_dotted_creates_sections_and_apply_overrides_copies():
    d: dict = {"a": {"b": 1}, "x": 5}
    set_dotted(d, "a.c.d", [1, 2])
    set_dotted(d, ["x", "y"], 3)               # a non-mapping on the way is replaced
    assert d == {"a": {"b": 1, "c": {"d": [1, 2]}}, "x": {"y": 3}}
    base = {"moon": {"albedo": 0.1}}
    out = apply_overrides(base, ["moon.albedo=0.2", "detector.exposure_time_s=1.0e-3",
                                 "render.aovs=", "seed=7"])
    assert base == {"moon": {"albedo": 0.1}}   # the input is left alone
    assert out == {"moon": {"albedo": 0.2}, "detector": {"exposure_time_s": 1.0e-3},
                   "render": {"aovs": None}, "seed": 7}
    assert parse_override(" a.b =[1, 2]") == (["a", "b"], [1, 2])
    with pytest.raises(ConfigError, match="KEY.PATH=VALUE"):
        parse_override("a.b")
    with pytest.raises(ConfigError, match="non-empty key"):
        parse_override("=3")


# --------------------------------------------------------------------------- errors, fields
class _Inner(StrictModel):
    width: PositiveFloat
    share: UnitInterval = 0.5


class _Outer(BaseModel):
    inner: _Inner
    transmission: PositiveFraction = 1.0


def _error(data: dict) -> ValidationError:
    with pytest.raises(ValidationError) as info:
        _Outer.model_validate(data)
    return info.value


def test_validation_error_names_field_value_and_expectation():
    err = format_validation_error(_error({"inner": {"width": -1.0}}))
    assert err.field == "inner.width" and err.value == -1.0
    assert "greater than 0" in err.expected and "more problem" not in err.expected
    err = format_validation_error(_error({"inner": {"width": 1.0, "share": 2.0}}), "moon.dem")
    assert err.field == "moon.dem.inner.share"
    err = format_validation_error(_error({"inner": {}}))
    assert (err.field, err.value, err.expected) == ("inner.width", "<missing>",
                                                    "a value (required key)")
    err = format_validation_error(_error({"inner": {"width": 0.0, "typo": 1},
                                          "transmission": 0.0}))
    assert err.expected.endswith("(and 2 more problem(s))")
    many = {f"k{i}": i for i in range(8)}
    err = format_validation_error(_error({"inner": {"width": 1.0}, "transmission": many}))
    assert err.field == "transmission" and err.value == "{k0, k1, k2, k3, k4, k5, ...}"


def test_field_types_differ_where_their_meaning_does():
    assert _Outer.model_validate({"inner": {"width": 1.0, "share": 0.0}}).inner.share == 0.0
    _error({"inner": {"width": 1.0}, "transmission": 0.0})    # (0, 1]: zero is rejected
    _error({"inner": {"width": float("inf")}})                # no infinities
    _error({"inner": {"width": 1.0, "share": float("nan")}})  # no NaN
