"""Lazy public names for subpackages: ``import starnav.x`` stays cheap, and ``starnav.x.Name``
imports the submodule that defines ``Name`` on first use (PEP 562 module ``__getattr__``)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, str], eager: tuple[str, ...] = ()
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : mapping
        Public name -> module defining it: a submodule name relative to ``package``
        (``"reader"``) or an absolute module (``"starnav.dem.grid"``).
    eager : tuple of str
        Names the package imports itself (listed by ``__dir__`` too).
    """
    names = sorted(set(exports) | set(eager))

    def __getattr__(name: str) -> Any:
        mod = exports.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        full = mod if mod.startswith("starnav.") else f"{package}.{mod}"
        return getattr(importlib.import_module(full), name)

    def __dir__() -> list[str]:
        return names

    return __getattr__, __dir__
