"""What every configuration schema shares: the base model, dotted overrides, error messages.

Below every schema (scenario, bench, DEM, sweep grid), importing none of them:

1. :class:`StrictModel`, the frozen pydantic base that rejects unknown keys (a typo is an
   error, not an ignored setting).
2. Dotted keys ``a.b.c=value`` (``--set``, per-exposure overrides, grid values):
   :func:`parse_override` (the value is YAML, empty is ``None``), :func:`set_dotted`
   (creates missing sections), :func:`apply_overrides` (both, on a copy).
3. :func:`format_validation_error`: a pydantic ``ValidationError`` as a
   :class:`~starnav.errors.ConfigError` naming the first offending field, the value and what
   was expected.
4. SI at the edge: a key carries its unit in its name (``row_time_us``); :meth:`StrictModel.to_si`
   is the one place those become SI, an :class:`SIView` whose keys drop the suffix
   (``row_time_us=174`` -> ``row_time=1.74e-4``; :data:`SI_SUFFIXES`). Counting units
   (``_px``, ``_e``, ``_dn``, ``_fraction``) and wavelengths in nm keep their names and values.
5. :func:`commented_yaml`: a validated mapping as YAML with each field's description (and its
   choices or range) above it, so ``starnav init``'s file cannot drift from the schema.
"""

from __future__ import annotations

import copy
import json
import os
import textwrap
import types
import typing
from collections.abc import Iterable, Mapping, MutableMapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Literal

import annotated_types
import yaml
from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic.fields import FieldInfo

from starnav.constants import AU, DAY, DEG
from starnav.errors import ConfigError, not_a_file_error

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
    "_deg_rt_h": (DEG / 60.0, 0.0), "_deg_h": (DEG / 3600.0, 0.0),
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

    def __reduce__(self) -> tuple[type[SIView], tuple[dict[str, Any]]]:
        """Pickled (and copied) through its values: a view travels to worker processes."""
        return (SIView, (self._values,))

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

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True,
                              allow_inf_nan=False)  # no configured quantity is infinite

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
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except (yaml.YAMLError, ValueError) as err:  # ValueError: a YAML date that is none
        mark = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ConfigError("--set", item, f"KEY=VALUE with a valid YAML value ({mark})") from None
    return key.strip().split("."), value


#: Largest configuration file read [bytes]: a scenario or bench file is a few kB (its bulk data,
#: DEMs, shape models, OEMs, are files it names), and the pure-Python YAML parser takes seconds
#: per hundred kB, so a larger file is refused before it is parsed.
MAX_CONFIG_BYTES = 1 << 20


def read_config_text(path: str | os.PathLike[str], what: str) -> str:
    """The text of the configuration file ``path`` (``what``: ``scenario file``, ...).

    A file larger than :data:`MAX_CONFIG_BYTES` or not UTF-8 is a
    :class:`~starnav.errors.ConfigError` naming the file (a directory or a device: a
    :class:`~starnav.errors.DataFileError` saying what it is).
    """
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, what)
    size = p.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ConfigError(what, f"{size} bytes", f"a configuration file of at most "
                          f"{MAX_CONFIG_BYTES} bytes ({str(p)!r} is {size / MAX_CONFIG_BYTES:.3g} "
                          "times that): put bulk data in the files the scenario names")
    try:
        return p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        line = p.read_bytes()[: err.start].count(b"\n") + 1
        raise ConfigError(what, str(p), f"UTF-8 text (byte 0x{err.object[err.start]:02x} on "
                          f"line {line} is not UTF-8: save the file as UTF-8)") from None


def read_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """The YAML content of the configuration file ``path`` (:func:`read_config_text`); not
    valid YAML is a :class:`~starnav.errors.ConfigError` naming the file."""
    text = read_config_text(path, what)
    try:
        return yaml.safe_load(text)
    except (yaml.YAMLError, ValueError) as err:  # ValueError: a YAML date that is none
        msg = " ".join(str(err).split())
        raise ConfigError(what, str(path), f"valid YAML ({msg})") from None


def read_json_file(path: str | os.PathLike[str], what: str) -> Any:
    """The JSON content of the file ``path`` (:func:`read_config_text`: a calibration, a
    manifest); not valid JSON is a :class:`~starnav.errors.ConfigError` naming the file."""
    text = read_config_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise ConfigError(what, str(path), f"valid JSON ({err})") from None


M = typing.TypeVar("M", bound=BaseModel)


def model_from_mapping(model: type[M], data: Any, overrides: Sequence[str] = (), *,
                       root: str, expected: str,
                       prepare: typing.Callable[[dict[str, Any]], dict[str, Any]] | None = None
                       ) -> M:
    """Validate a configuration mapping as ``model``: the one path of every configuration
    file (scenario, bench) from its parsed content to its frozen model.

    ``data`` ``None`` is an empty mapping, anything else but a mapping is an error named
    ``root`` (``expected`` says what it should be); the ``a.b=value`` ``overrides`` apply
    first (:func:`apply_overrides`), then ``prepare`` (e.g. reading a file a key names),
    then validation, whose first problem is reported by :func:`format_validation_error`.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(root, type(data).__name__, expected)
    data = apply_overrides(data, overrides)
    if prepare is not None:
        data = prepare(data)
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise format_validation_error(err) from None


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


# --------------------------------------------------------------------------- commented YAML
#: Line width of :func:`commented_yaml`'s comments [characters].
COMMENT_WIDTH = 99


def field_models(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models a field's type can hold, in order (``A | B | None`` -> ``[A, B]``;
    ``tuple[A, ...]`` -> ``[A]``); ``[]`` for a plain value."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type[BaseModel]] = []
    for arg in typing.get_args(annotation):
        out += [m for m in field_models(arg) if m not in out]
    return out


def _choices(annotation: Any) -> list[Any]:
    """Values of the ``Literal`` types of a field's type (``None`` included when allowed)."""
    if typing.get_origin(annotation) is Literal:
        return list(typing.get_args(annotation))
    if annotation is type(None):
        return [None]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        parts = [_choices(a) for a in typing.get_args(annotation)]
        if all(parts):  # every alternative is a literal or None
            return [c for p in parts for c in p]
    if typing.get_origin(annotation) is typing.Annotated:
        return _choices(typing.get_args(annotation)[0])
    return []


def _bounds(annotation: Any, metadata: Sequence[Any]) -> str:
    """The numeric range of a scalar field (``"> 0"``, ``"[0, 1]"``), from its constraints
    (``Gt``, ``Ge``, ``Lt``, ``Le``) on the field or on its ``Annotated`` type; ``""`` for
    none. Constraints on the items of a tuple are not reported."""
    found = list(metadata)
    stack = [annotation]
    while stack:
        a = stack.pop()
        origin = typing.get_origin(a)
        if origin is typing.Annotated:  # Field(gt=0) inside a union is a FieldInfo
            for m in a.__metadata__:
                found += m.metadata if isinstance(m, FieldInfo) else [m]
            stack.append(typing.get_args(a)[0])
        elif origin in (typing.Union, types.UnionType):
            stack += list(typing.get_args(a))
    lo = hi = None
    for m in found:
        if isinstance(m, annotated_types.Gt):
            lo = ("(", m.gt)
        elif isinstance(m, annotated_types.Ge):
            lo = ("[", m.ge)
        elif isinstance(m, annotated_types.Lt):
            hi = (")", m.lt)
        elif isinstance(m, annotated_types.Le):
            hi = ("]", m.le)
    if lo and hi:
        return f"range {lo[0]}{lo[1]:g}, {hi[1]:g}{hi[0]}"
    if lo:
        return f"{'>' if lo[0] == '(' else '>='} {lo[1]:g}"
    if hi:
        return f"{'<' if hi[0] == ')' else '<='} {hi[1]:g}"
    return ""


def field_comment(field: FieldInfo) -> str:
    """A field's comment: its description, then what it accepts (``one of: a, b`` from a
    ``Literal``, the numeric range from its constraints, ``or null`` when optional)."""
    text = (field.description or "").strip()
    extra = []
    choices = _choices(field.annotation)
    if choices:
        extra.append("one of: " + ", ".join("null" if c is None else str(c) for c in choices))
    else:
        bounds = _bounds(field.annotation, field.metadata)
        if bounds:
            extra.append(bounds)
    return "; ".join(t for t in (text, *extra) if t)


def _scalar(value: Any) -> str:
    """One value in YAML flow style on one line (``1.0e-05``, ``[1, 2]``, ``null``)."""
    text = yaml.safe_dump(value, default_flow_style=True, width=float("inf"), sort_keys=False)
    return text.removesuffix("\n").removesuffix("\n...").strip()


def _pick_model(models: Sequence[type[BaseModel]], data: Mapping[str, Any]
                ) -> type[BaseModel] | None:
    """The model of a union that describes ``data``: all its keys are fields and its
    single-valued literal fields (a ``kind`` discriminator) match."""
    for m in models:
        if not set(data) <= set(m.model_fields):
            continue
        tags = {k: _choices(f.annotation) for k, f in m.model_fields.items()}
        if all(len(tags[k]) != 1 or data[k] == tags[k][0] for k in data if k in tags):
            return m
    return None


def _comment_lines(text: str, indent: str, commented: bool) -> list[str]:
    pre = "# " if commented else ""
    width = max(COMMENT_WIDTH - len(indent) - len(pre) - 2, 40)
    wrapped = textwrap.wrap(text, width, break_on_hyphens=False, break_long_words=False)
    return [f"{pre}{indent}# {line}" for line in wrapped]


def _emit(model: type[BaseModel] | None, data: Mapping[str, Any], indent: str,
          lines: list[str], *, item: bool = False, commented: bool = False) -> None:
    """Append the lines of mapping ``data`` (fields of ``model``) at ``indent``; ``item``: the
    mapping is an item of a list (its first key follows ``- ``)."""
    pre = "# " if commented else ""
    for n, (key, value) in enumerate(data.items()):
        field = None if model is None else model.model_fields.get(key)
        lead = indent + ("- " if item and n == 0 else ("  " if item else ""))
        pad = indent + ("  " if item else "")
        if not indent and not commented and lines:
            lines.append("")  # a blank line between the top-level sections
        if field is not None:
            lines += _comment_lines(field_comment(field), pad if n else indent, commented)
        models = [] if field is None else field_models(field.annotation)
        k = _scalar(key)
        if isinstance(value, Mapping) and value and models:
            lines.append(f"{pre}{lead}{k}:")
            _emit(_pick_model(models, value), value, pad + "  ", lines, commented=commented)
        elif (isinstance(value, list | tuple) and value and models
              and all(isinstance(v, Mapping) for v in value)):
            lines.append(f"{pre}{lead}{k}:")
            for v in value:
                _emit(_pick_model(models, v), v, pad + "  ", lines, item=True,
                      commented=commented)
        else:
            lines.append(f"{pre}{lead}{k}: {_scalar(value)}")
            if value is None and not commented:
                for m in models:  # an unused optional section: its defaults, commented out
                    try:
                        example = m().model_dump(mode="json")
                    except ValidationError:
                        continue  # no defaults to show (a required key)
                    if all(len(_choices(f.annotation)) == 1 for f in m.model_fields.values()):
                        continue  # a bare tag ({kind: moon}): the comment says it all
                    lines.append(f"{pad}# {k}:  (example: {m.__name__} at its defaults)")
                    _emit(m, example, pad + "  ", lines, commented=True)


def commented_yaml(model: type[BaseModel], data: Mapping[str, Any]) -> str:
    """``data`` (a mapping that ``model`` validates, e.g. ``model_dump(mode="json")``) as
    block YAML with each key's comment (:func:`field_comment`) on the lines above it.

    Values are written in flow style on one line (lists, free mappings), sections and lists
    of sections as blocks; an optional section that is ``null`` is followed by a commented-out
    copy of its defaults, to show its keys. ``yaml.safe_load`` of the result equals ``data``.
    """
    lines: list[str] = []
    _emit(model, data, "", lines)
    return "\n".join(lines) + "\n"


__all__ = ["COMMENT_WIDTH", "StrictModel", "apply_overrides", "commented_yaml", "field_comment",
           "field_models", "format_validation_error", "parse_override", "set_dotted"]
