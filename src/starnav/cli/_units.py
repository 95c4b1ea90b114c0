"""One convention for times on the command line: a number in seconds, or a number with its unit.

``1.5e-5``, ``15us``, ``15 µs``, ``0.015ms``, ``7.7 ms``, ``0.2s`` are all accepted by every flag
that takes an exposure time (``dataset --exposures``, ``dataset --exposure-set``, ``navigate
--exposure``, ``expose --exposure``); inside starnav the value is in seconds. Scenario keys keep
their unit in the name (``detector.exposure_time_s``).
"""

from __future__ import annotations

import math
import re
from decimal import Decimal, InvalidOperation

from starnav.errors import ConfigError

#: Accepted units and their factor to seconds (decimal: ``15us`` is exactly the float
#: ``1.5e-5``, so the same exposure written either way names the same dataset).
TIME_UNITS = {"": "1", "s": "1", "ms": "1e-3", "us": "1e-6", "µs": "1e-6", "μs": "1e-6",
              "ns": "1e-9"}
_TIME = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµμ]*)\s*$")


def parse_time(text: str, flag: str) -> float:
    """A positive duration [s] from ``text`` (module docstring); a :class:`ConfigError` naming
    ``flag`` otherwise."""
    m = _TIME.match(str(text))
    unit = m.group(2) if m else None
    if m is None or unit not in TIME_UNITS:
        raise ConfigError(flag, text, "a time in seconds or with a unit (s, ms, us, ns), e.g. "
                          "1.5e-5 or 15us or 7.7ms")
    try:
        value = float(Decimal(m.group(1)) * Decimal(TIME_UNITS[unit]))
    except InvalidOperation:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(flag, text, "a time > 0")
    return value


def parse_times(text: str, flag: str) -> tuple[float, ...]:
    """``"15us,7.7ms"`` -> ``(1.5e-05, 0.0077)`` [s]."""
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    if not parts:
        raise ConfigError(flag, text, "a comma-separated list of times, e.g. 15us,7.7ms")
    return tuple(parse_time(p, flag) for p in parts)
