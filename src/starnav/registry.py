"""Named registries: the one way starnav looks a thing up by name.

A detector effect, a blooming mode, a photometric model, a DEM format, a bias model, a sweep
preset: each is a table from a name to its implementation, and :class:`Registry` is that table
written once. It is filled at import, by decorator or call::

    BLOOMING_MODES = Registry[BloomFunction]("blooming mode")

    @BLOOMING_MODES.register("drain")
    def bloom_drain(...): ...

and read with :meth:`Registry.get` (or ``REGISTRY[name]``), ``in``, :meth:`Registry.names` and
iteration, in registration order. An unknown name raises
:class:`~starnav.errors.UnknownNameError` listing the known names (``unknown bias model 'x';
known: additive, none``); registering a name twice raises ``ValueError``. A plain set of
allowed strings is a registry too, a one-line description per name (:meth:`Registry.check`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any, Generic, TypeVar, overload

from starnav.errors import UnknownNameError

T = TypeVar("T")

_MISSING: Any = object()


class Registry(Generic[T]):
    """A table from names to objects, with one error for every unknown name.

    Parameters
    ----------
    kind : str
        What the names name, singular, as the error message shows it (``"bias model"``).
    entries : mapping or iterable of (name, object) pairs, optional
        Initial entries, registered in order.

    Examples
    --------
    >>> modes = Registry("shading law", {"lambert": "cos i"})
    >>> @modes.register("lommel-seeliger")
    ... def _ls(): ...
    >>> modes.names()
    ('lambert', 'lommel-seeliger')
    >>> modes.get("phong")
    Traceback (most recent call last):
    ...
    starnav.errors.UnknownNameError: unknown shading law 'phong'; known: lambert, lommel-seeliger
    """

    def __init__(self, kind: str,
                 entries: Mapping[str, T] | Iterable[tuple[str, T]] | None = None) -> None:
        self.kind = kind
        self._entries: dict[str, T] = {}
        pairs = entries.items() if isinstance(entries, Mapping) else (entries or ())
        for name, obj in pairs:
            self.register(name, obj)

    # ..................................................................... filling
    @overload
    def register(self, name: str) -> Callable[[T], T]: ...

    @overload
    def register(self, name: str, obj: T) -> T: ...

    def register(self, name: str, obj: Any = _MISSING) -> Any:
        """Register ``obj`` as ``name``; without ``obj``, a decorator that registers its target.

        Returns ``obj`` (or the decorator), so the decorated function stays usable as it is.

        Raises
        ------
        ValueError
            ``name`` is empty, not a string, or registered already.
        """
        if obj is _MISSING:
            def decorator(target: T) -> T:
                return self.register(name, target)

            return decorator
        if not isinstance(name, str) or not name:
            raise ValueError(f"{self.kind} name = {name!r}: expected a non-empty string")
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is registered already")
        self._entries[name] = obj
        return obj

    # ..................................................................... reading
    def get(self, name: str) -> T:
        """The object registered as ``name``.

        Raises
        ------
        UnknownNameError
            ``name`` is not registered; the message lists the known names, sorted.
        """
        try:
            return self._entries[name]
        except (KeyError, TypeError):  # TypeError: an unhashable "name"
            raise UnknownNameError(self.kind, name, list(self._entries)) from None

    __getitem__ = get

    def check(self, name: str) -> str:
        """``name`` itself if it is registered (validation of a choice), else
        :class:`~starnav.errors.UnknownNameError`."""
        self.get(name)
        return name

    def names(self) -> tuple[str, ...]:
        """The registered names, in the order they were registered."""
        return tuple(self._entries)

    def items(self) -> Iterator[tuple[str, T]]:
        """``(name, object)`` pairs, in the order of registration."""
        return iter(tuple(self._entries.items()))

    def values(self) -> Iterator[T]:
        """The registered objects, in the order of registration."""
        return iter(tuple(self._entries.values()))

    def __contains__(self, name: object) -> bool:
        try:
            return name in self._entries
        except TypeError:
            return False

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, names={list(self._entries)!r})"


__all__ = ["Registry"]
