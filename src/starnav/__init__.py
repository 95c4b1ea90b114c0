"""starnav: a star tracker used as a navigation camera, from photons to navigation.

Subpackages follow the data flow: ``scenes`` -> ``dem`` -> ``renderer`` ->
``detector`` -> ``calibration`` -> ``dataset`` -> ``navigation`` -> ``batch``; ``cli`` sits on
top. Importing :mod:`starnav` is cheap: nothing heavy (Mitsuba, Dask) is imported here.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("starnav")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
