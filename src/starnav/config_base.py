"""What every configuration schema shares: the base model, dotted overrides, error messages.

This module sits below every schema (``starnav.config`` for the scenario,
``starnav.calibration.schema`` for the bench, ``starnav.dem.schema`` for a DEM section, the sweep
grid of ``starnav.batch.grid``) and imports none of them, so each can use it without an import
cycle. It holds the three things they would otherwise each write again:

1. :class:`StrictModel`, the frozen pydantic base that rejects unknown keys, so a typo is an
   error and not a silently ignored setting.
2. Dotted keys: ``a.b.c=value`` items (the CLI's ``--set``, a dataset's per-exposure overrides,
   a sweep's grid values) parsed by :func:`parse_override` (the value is YAML, an empty value is
   ``None``) and written into a nested mapping by :func:`set_dotted`, which creates missing
   sections; :func:`apply_overrides` does both on a copy.
3. :func:`format_validation_error`, which turns a pydantic ``ValidationError`` into a
   :class:`~starnav.errors.ConfigError` naming the first offending field (dotted, optionally
   under a prefix such as ``moon.dem``), the value received and what was expected, and counting
   the other problems. A missing required key reads ``<missing>``; a whole section that was
   rejected is shown by its keys rather than dumped.
4. SI at the edge: a scenario key carries its unit in its name (``row_time_us``,
   ``range_km``, ``phase_angle_deg``); :meth:`StrictModel.to_si` is the one place where those
   units become SI. It returns an :class:`SIView`, a frozen tree of the same sections whose
   keys drop the unit suffix and whose values are in m, s, rad, K, m/s, rad/s, W/m^2
   (``row_time_us=174`` -> ``row_time=1.74e-4``; the suffix table is :data:`SI_SUFFIXES`).
   Keys in counting units (``_px``, ``_e``, ``_dn``, ``_fraction``) and wavelengths in nm (the
   spectral convention of :mod:`starnav.spectra` and Mitsuba) keep their names and values.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, MutableMapping, Sequence
from typing import Any, ClassVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from starnav.constants import AU, DAY, DEG
from starnav.errors import ConfigError

#: A rejected mapping is shown by at most this many of its keys.
_SHOWN_KEYS = 6


#: Unit suffix of a scenario key -> (factor, offset) to SI: ``si = value * factor + offset``.
#: Longest suffix first; a suffix mapped to ``None`` is a unit kept as it is (the key keeps its
#: name). Checked against astropy.units in tests/test_config.py.
SI_SUFFIXES: dict[str, tuple[float, float] | None] = {
    "_e_per_s": None, "_e_per_dn": None, "_km_s": (1e3, 0.0), "_deg_s": (DEG, 0.0),
    "_m_s": (1.0, 0.0), "_m2_s3": (1.0, 0.0), "_w_m2": (1.0, 0.0),
    "_km": (1e3, 0.0), "_mm": (1e-3, 0.0), "_um": (1e-6, 0.0), "_m": (1.0, 0.0),
    "_au": (AU, 0.0), "_deg": (DEG, 0.0), "_arcsec": (DEG / 3600.0, 0.0),
    "_days": (DAY, 0.0), "_s": (1.0, 0.0), "_ms": (1e-3, 0.0), "_us": (1e-6, 0.0),
    "_c": (1.0, 273.15), "_k": (1.0, 0.0),
}
_SUFFIX_ORDER = sorted(SI_SUFFIXES, key=len, reverse=True)


def si_name(key: str) -> tuple[str, tuple[float, float] | None]:
    """The SI view's name of a scenario ``key`` and its conversion (``None``: kept as is)."""
    for suffix in _SUFFIX_ORDER:
        if key.endswith(suffix) and len(key) > len(suffix):
            conv = SI_SUFFIXES[suffix]
            return (key, None) if conv is None else (key[: -len(suffix)], conv)
    return key, None


class SIView:
    """A frozen, read-only tree of one configuration section in SI (:meth:`StrictModel.to_si`).

    Attribute access as on the model, with the unit suffixes dropped; nested sections are
    views, tuples of sections tuples of views; ``None`` stays ``None``.
    """

    __slots__ = ("_values",)

    def __init__(self, values: dict[str, Any]) -> None:
        object.__setattr__(self, "_values", values)

    def __getattr__(self, name: str) -> Any:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(f"SI view has no key {name!r}; keys: "
                                 f"{', '.join(self._values)}") from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("an SI view is read-only")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SIView) and self._values == other._values

    def __hash__(self) -> int:
        return hash(tuple(self._values.items()))

    def __repr__(self) -> str:
        return f"SIView({', '.join(f'{k}={v!r}' for k, v in self._values.items())})"

    def keys(self) -> tuple[str, ...]:
        return tuple(self._values)


def _to_si(value: Any, conv: tuple[float, float] | None) -> Any:
    if isinstance(value, StrictModel):
        return value.to_si()
    if isinstance(value, (tuple, list)):
        return tuple(_to_si(v, conv) for v in value)
    if conv is None or value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        return float(value) * conv[0] + conv[1]
    return value


class StrictModel(BaseModel):
    """Base of every configuration model: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)

    #: SI-view names for keys whose plain name is taken by another key (``roll`` the mode,
    #: ``roll_deg`` the angle -> ``roll_angle``).
    si_names: ClassVar[dict[str, str]] = {}

    def to_si(self) -> SIView:
        """This section in SI, keys without their unit suffix (module essay, item 4)."""
        out: dict[str, Any] = {}
        for key in type(self).model_fields:
            name, conv = si_name(key)
            name = self.si_names.get(key, name)
            if name in out:
                raise TypeError(f"{type(self).__name__}: keys {key!r} and {name!r} have the same "
                                "SI name; give one an entry in si_names")
            out[name] = _to_si(getattr(self, key), conv)
        return SIView(out)


# --------------------------------------------------------------------------- dotted keys
def set_dotted(data: MutableMapping[str, Any], key: str | Sequence[str], value: Any) -> None:
    """Set the dotted ``key`` (``"a.b.c"`` or ``["a", "b", "c"]``) of a nested mapping to
    ``value``, in place, creating (or replacing non-mapping values by) the sections on the way.

    ``value`` is stored as given (not copied).
    """
    path = key.split(".") if isinstance(key, str) else list(key)
    node = data
    for part in path[:-1]:
        nxt = node.get(part)
        if not isinstance(nxt, dict):
            nxt = {}
            node[part] = nxt
        node = nxt
    node[path[-1]] = value


def parse_override(item: str) -> tuple[list[str], Any]:
    """``"a.b.c=VALUE"`` -> ``(["a", "b", "c"], value)``, the value parsed as YAML (an empty
    value is ``None``).

    Raises
    ------
    ConfigError
        No ``=``, or an empty key (named as ``--set``).
    """
    if "=" not in item:
        raise ConfigError("--set", item, "KEY.PATH=VALUE")
    key, raw = item.split("=", 1)
    if not key.strip():
        raise ConfigError("--set", item, "KEY.PATH=VALUE with a non-empty key")
    value = yaml.safe_load(raw) if raw.strip() else None
    return key.strip().split("."), value


def apply_overrides(data: dict[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Return a copy of ``data`` with ``a.b.c=value`` overrides applied (value parsed as YAML)."""
    out = copy.deepcopy(data)
    for item in overrides:
        path, value = parse_override(item)
        set_dotted(out, path, value)
    return out


# --------------------------------------------------------------------------- errors
def format_validation_error(err: ValidationError, prefix: str = "") -> ConfigError:
    """The :class:`~starnav.errors.ConfigError` that reports ``err``'s first problem.

    Parameters
    ----------
    err : pydantic.ValidationError
        The error of a ``model_validate`` call.
    prefix : str
        Dotted location of the validated mapping inside its file (``"moon.dem"``), put before
        the field's own location; ``""`` for a whole file.

    Returns
    -------
    ConfigError
        ``field`` the dotted location (``<root>`` for the file itself), ``value`` the input
        (``<missing>`` for a required key, the keys of a rejected mapping), ``expected``
        pydantic's message, plus the number of further problems.
    """
    problems = err.errors()
    first = problems[0]
    loc = ".".join(str(p) for p in first["loc"])
    field = ".".join(p for p in (prefix, loc) if p) or "<root>"
    value = first.get("input")
    expected = first["msg"].removeprefix("Value error, ")
    if first.get("type") == "missing":
        value, expected = "<missing>", "a value (required key)"
    elif isinstance(value, dict):
        keys = [str(k) for k in value]
        value = ("{" + ", ".join(keys[:_SHOWN_KEYS])
                 + (", ..." if len(keys) > _SHOWN_KEYS else "") + "}")
    if len(problems) > 1:
        expected += f" (and {len(problems) - 1} more problem(s))"
    return ConfigError(field, value, expected)


__all__ = ["StrictModel", "apply_overrides", "format_validation_error", "parse_override",
           "set_dotted"]
