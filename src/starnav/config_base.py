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
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, MutableMapping, Sequence
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from starnav.errors import ConfigError

#: A rejected mapping is shown by at most this many of its keys.
_SHOWN_KEYS = 6


class StrictModel(BaseModel):
    """Base of every configuration model: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


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
