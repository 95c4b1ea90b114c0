"""One rule for the time axis of every figure and summary: hours below two days, days above.

A 12-hour arc in days reads ``0.0 .. 0.5`` and a 14-day halo in hours reads ``0 .. 336``; both
hide what a person wants to see. Every plot of a quantity against time (navigation errors,
consistency, the sweep's error-vs-time, the trajectory plot) takes its unit from
:func:`time_unit` of the plotted span, so two figures of the same arc always agree.

Example
-------
>>> time_unit(0.05 * 86400.0)
('h', 3600.0)
>>> format_duration(0.05 * 86400.0)
'1.2 h'
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starnav.constants import DAY

#: Spans shorter than this are shown in hours, longer ones in days [s].
HOURS_BELOW_S = 2.0 * DAY
HOUR = 3600.0


def time_unit(span_s: float) -> tuple[str, float]:
    """The unit of a time axis spanning ``span_s`` seconds: ``("h", 3600)`` below two days,
    else ``("d", 86400)`` (the symbol and the unit in seconds)."""
    return ("h", HOUR) if abs(float(span_s)) < HOURS_BELOW_S else ("d", DAY)


def elapsed_axis(epochs_s: ArrayLike) -> tuple[NDArray[np.float64], str]:
    """Time since the first epoch in the unit of :func:`time_unit` of the span, and the axis
    label (``"time since the first frame [h]"``).

    Parameters
    ----------
    epochs_s : (K,) array
        Epochs [s] (any origin, e.g. TDB seconds past J2000).
    """
    t = np.asarray(epochs_s, float).ravel()
    if t.size == 0:
        return t, "time [h]"
    rel = t - t[0]
    sym, unit = time_unit(float(np.nanmax(rel)) if rel.size else 0.0)
    return rel / unit, f"time since the first frame [{sym}]"


def format_duration(span_s: float, digits: int = 2) -> str:
    """``span_s`` [s] in the axis unit with ``digits`` significant digits: ``"1.2 h"``,
    ``"14 d"``."""
    sym, unit = time_unit(span_s)
    return f"{float(span_s) / unit:.{digits}g} {sym}"
