"""What-if grids: ``--grid key=v1,v2`` axes, their points, and which keys reach the renderer.

The one grid parser of ``starnav sweep`` and the fly-by sweeps.

1. Axes (:func:`parse_grid`): each ``--grid KEY=V1,V2,...`` is an axis of a dotted scenario
   key, the values parsed as YAML one by one (commas inside brackets do not split); keys
   joined by ``+`` vary together, one list entry per key (``--grid "a+b=[1,[2]],[3,[4]]"`` gives
   two points, not four).
2. Points (:func:`expand`): the Cartesian product of the axes, the last varying fastest; each
   point is the base scenario with its overrides, validated before any work.
3. Render groups (:func:`render_config`, :func:`render_groups`): points that differ only
   downstream of the renderer (:data:`DOWNSTREAM_SECTIONS`, not :data:`UPSTREAM_SECTIONS`)
   share their renders; ``moon.albedo_scale`` too: radiance is linear in it, so the group is
   rendered at scale 1 and each point scales the radiance.

Index
-----
:func:`parse_grid`, :func:`parse_axis`, :class:`GridAxis`, :func:`parse_value`,
:func:`split_values`, :func:`expand`, :class:`GridPoint`, :func:`render_config`,
:func:`render_key`, :func:`render_groups`, :func:`known_keys`, :func:`check_key`.
"""

from __future__ import annotations

import contextlib
import copy
import difflib
import hashlib
import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml

from starnav.bodies.schema import EllipsoidConfig, MoonTargetConfig, ShapeModelConfig
from starnav.config import Scenario, scenario_from_dict, scenario_to_dict
from starnav.config_base import apply_overrides, set_dotted
from starnav.dem.schema import DemConfig
from starnav.errors import ConfigError
from starnav.scenes.schema import TrajectoryConfig

#: Scenario sections that change the rendered radiance (module step 3).
UPSTREAM_SECTIONS: tuple[str, ...] = ("camera", "sensor_response", "moon", "target", "sun",
                                      "geometry", "trajectory", "spacecraft", "pointing",
                                      "render", "seed")
#: Sections that act after the renderer (the stars are drawn by the detector chain).
DOWNSTREAM_SECTIONS: tuple[str, ...] = ("detector", "stars", "navigation", "output")
#: Keys below which any sub-key is accepted (free-form mappings).
_FREE_FORM = ("moon.photometry.params",)


@dataclass(frozen=True)
class GridAxis:
    """One axis: a dotted scenario key (or linked keys joined by ``+``) and its values
    (module step 1); a linked axis' values are tuples with one entry per key."""

    key: str
    values: tuple[Any, ...]

    @property
    def keys(self) -> tuple[str, ...]:
        """The scenario keys this axis sets."""
        return tuple(self.key.split("+"))

    def assignments(self, value: Any) -> dict[str, Any]:
        """Key -> value of one of the axis' values."""
        ks = self.keys
        if len(ks) == 1:
            return {ks[0]: value}
        return dict(zip(ks, value, strict=True))


@dataclass(frozen=True)
class GridPoint:
    """One point of the grid (module step 2).

    Attributes
    ----------
    index : int
    values : dict
        Scenario key -> value (linked axes contribute one entry per key).
    scenario : Scenario
        The validated scenario of the point.
    label : str
        ``key=value, ...`` with the last component of each key.
    render_key : str
        Hash of the upstream configuration (points with equal keys share renders).
    albedo_factor : float
        Factor applied to the shared render's radiance (``moon.albedo_scale`` when it is
        downstream, else 1).
    """

    index: int
    values: dict[str, Any]
    scenario: Scenario
    label: str
    render_key: str
    albedo_factor: float


def split_values(text: str) -> list[str]:
    """Split ``text`` at commas outside brackets and quotes."""
    out, depth, cur, quote = [], 0, [], ""
    for ch in text:
        if quote:
            cur.append(ch)
            if ch == quote:
                quote = ""
            continue
        if ch in "\"'":
            quote = ch
        elif ch in "[({":
            depth += 1
        elif ch in "])}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return [v for v in out if v != ""]


def parse_axis(item: str) -> GridAxis:
    """``KEY=V1,V2`` -> :class:`GridAxis`; a clear error for a missing key or empty values."""
    if not isinstance(item, str) or "=" not in item:
        raise ConfigError("--grid", item, "KEY=V1,V2,... (e.g. detector.exposure_time_s="
                          "1.5e-5,7.7e-3)")
    key, raw = item.split("=", 1)
    key = "+".join(k.strip() for k in key.split("+"))
    keys = key.split("+")
    if any(not k or any(not part for part in k.split(".")) for k in keys):
        raise ConfigError("--grid", item, "a dotted scenario key (or keys joined by +) "
                          "before '='")
    if len(set(keys)) != len(keys):
        raise ConfigError("--grid", key, "distinct keys in a linked axis")
    texts = split_values(raw)
    if not texts:
        raise ConfigError(f"--grid {key}", raw, "at least one value (the grid is empty)")
    values = tuple(parse_value(key, t) for t in texts)
    if len(keys) > 1:
        for v in values:
            if not isinstance(v, list) or len(v) != len(keys):
                raise ConfigError(f"--grid {key}", v, f"a list of {len(keys)} values, one per "
                                  "linked key, e.g. [7.7e-3,[2048]]")
        values = tuple(tuple(v) for v in values)
    return GridAxis(key, values)


def _numbers(v: Any) -> Any:
    """Strings that are plain numbers (YAML 1.1 reads ``1e-4`` as a string) to floats."""
    if isinstance(v, list):
        return [_numbers(x) for x in v]
    if isinstance(v, dict):
        return {k: _numbers(x) for k, x in v.items()}
    if isinstance(v, str):
        try:
            return float(v) if v.strip().lower() not in ("nan", "inf", "-inf", "+inf",
                                                          "infinity") else v
        except ValueError:
            return v
    return v


def parse_value(key: str, text: str) -> Any:
    """One grid value: an int, else a float (``1e-4`` included, which YAML 1.1 reads as a
    string), else YAML."""
    for conv in (int, float):
        with contextlib.suppress(ValueError):
            return conv(text)
    try:
        return _numbers(yaml.safe_load(text))
    except yaml.YAMLError as err:
        raise ConfigError(f"--grid {key}", text, f"a number or a YAML value ({err})") from None


def parse_grid(items: Sequence[str | GridAxis]) -> list[GridAxis]:
    """Parse every ``--grid`` item; at least one axis, no key twice."""
    axes = [a if isinstance(a, GridAxis) else parse_axis(a) for a in items]
    if not axes:
        raise ConfigError("--grid", "none", "at least one --grid KEY=V1[,V2...] (a single value "
                          "gives a Monte Carlo of one scenario), or a preset")
    seen: set[str] = set()
    for a in axes:
        if not a.values:
            raise ConfigError(f"--grid {a.key}", "[]", "at least one value (the grid is empty)")
        for k in a.keys:
            if k in seen:
                raise ConfigError("--grid", k, "each key once (give all its values in one "
                                  "--grid)")
            seen.add(k)
    return axes


def _flatten(d: Any, prefix: str, out: set[str]) -> None:
    if isinstance(d, dict):
        for k, v in d.items():
            key = f"{prefix}{k}"
            out.add(key)
            _flatten(v, key + ".", out)


def known_keys() -> set[str]:
    """Every dotted key of a scenario (optional sections filled with their defaults)."""
    keys: set[str] = set()
    _flatten(scenario_to_dict(Scenario(trajectory=TrajectoryConfig())), "", keys)
    _flatten({"moon": {"dem": DemConfig().model_dump(mode="json")}}, "", keys)
    for target in (MoonTargetConfig, EllipsoidConfig, ShapeModelConfig):
        _flatten({"target": target().model_dump(mode="json")}, "", keys)
    return keys


def check_key(key: str, known: set[str] | None = None) -> None:
    """Raise :class:`ConfigError` with suggestions if ``key`` is not a scenario key."""
    known = known if known is not None else known_keys()
    if key in known or any(key.startswith(f + ".") for f in _FREE_FORM):
        return
    close = difflib.get_close_matches(key, sorted(known), n=3, cutoff=0.6)
    hint = f"; did you mean {' or '.join(close)}?" if close else ""
    raise ConfigError("--grid", key, f"a scenario key such as detector.exposure_time_s or "
                      f"moon.albedo_scale (unknown key{hint})")


def _dumps(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def render_config(scenario: Scenario) -> tuple[dict[str, Any], float]:
    """The scenario dict a shared render uses, and this point's albedo factor (module step 3).

    The dict keeps the upstream sections of ``scenario`` (AOVs off: a sweep never uses them;
    ``moon.albedo_scale`` at 1: it is a radiance factor for every model) and the defaults of the
    downstream ones, so that every point of a render group gives the same dict.
    """
    d = scenario_to_dict(scenario)
    blank = scenario_to_dict(Scenario())
    up = {k: d[k] for k in UPSTREAM_SECTIONS}
    up["render"] = dict(up["render"], aovs=False)
    factor = 1.0
    # moon.albedo_scale multiplies the reflectance of every model (renderer.bsdfs): downstream
    factor = float(scenario.moon.albedo_scale)
    up["moon"] = dict(up["moon"], albedo_scale=1.0)
    for k in DOWNSTREAM_SECTIONS:
        up[k] = blank[k]
    return up, factor


def render_key(config: dict[str, Any]) -> str:
    """Short hash of a render configuration."""
    return hashlib.sha256(_dumps(config).encode()).hexdigest()[:12]


def _label(values: dict[str, Any]) -> str:
    if not values:
        return "base"
    return ", ".join(f"{k.split('.')[-1]}={v!r}" if not isinstance(v, float)
                     else f"{k.split('.')[-1]}={v:g}" for k, v in values.items())


def expand(base: Scenario | dict[str, Any], axes: Sequence[GridAxis],
           overrides: Sequence[str] = ()) -> list[GridPoint]:
    """The grid points of ``axes`` over ``base`` (module step 2), each validated.

    ``overrides`` (``--set`` items) apply to the base, before the grid values.

    Raises
    ------
    ConfigError
        An unknown key (with suggestions) or a value the scenario rejects (named by key).
    """
    base_dict = scenario_to_dict(base) if isinstance(base, Scenario) else dict(base)
    base_dict = apply_overrides(base_dict, list(overrides))
    known = known_keys()
    for a in axes:
        for k in a.keys:
            check_key(k, known)
            if k.startswith("geometry.") and base_dict.get("trajectory") is not None:
                # a trajectory's frames take their geometry from the arc, not this section
                raise ConfigError("--grid", k, "a key the scenario reads: with a trajectory "
                                  "the frames' range and phase come from the arc (sweep "
                                  "trajectory.* keys, or set trajectory=null for a static "
                                  "geometry)")
    points = []
    for idx, combo in enumerate(itertools.product(*[a.values for a in axes])):
        values: dict[str, Any] = {}
        for a, v in zip(axes, combo, strict=True):
            values.update(a.assignments(v))
        data = copy.deepcopy(base_dict)
        for k, v in values.items():
            set_dotted(data, k, copy.deepcopy(v))
        try:
            sc = scenario_from_dict(data)
        except ConfigError as err:
            raise ConfigError(f"--grid point {idx} ({_label(values)}): {err.field}", err.value,
                              err.expected) from None
        cfg, factor = render_config(sc)
        points.append(GridPoint(idx, values, sc, _label(values), render_key(cfg), factor))
    return points


def render_groups(points: Sequence[GridPoint]) -> dict[str, list[GridPoint]]:
    """Points by render key, in first-appearance order."""
    groups: dict[str, list[GridPoint]] = {}
    for p in points:
        groups.setdefault(p.render_key, []).append(p)
    return groups
