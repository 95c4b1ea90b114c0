"""A small bounded in-memory cache: the one way starnav keeps expensive results around.

A DEM read from disk, the procedural Moon, a view-adapted mesh, the sub-posting detail, a PSF
kernel's spectrum: each is kept under a hashable key naming everything it depends on (a file
stamp, a configuration's JSON, a grid's ``uid``), and only a few, since they are large.

:class:`BoundedCache` holds at most ``maxsize`` entries and forgets the least recently used
(``policy="lru"``, a hit refreshes the entry) or the oldest (``"fifo"``). A hit returns the
stored object itself (callers may rely on identity and must treat it as read-only);
``maxsize <= 0`` turns caching off; ``hits`` and ``misses`` count lookups. Not thread-safe;
one per process. Small results of arguments alone stay with :func:`functools.lru_cache`.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, Literal, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

#: Eviction policies of :class:`BoundedCache`.
POLICIES = ("lru", "fifo")


class BoundedCache(Generic[K, V]):
    """At most ``maxsize`` values by key, evicting the least recently used (or the oldest).

    Parameters
    ----------
    maxsize : int
        Largest number of entries kept; ``<= 0`` keeps none.
    policy : {"lru", "fifo"}
        ``lru``: a hit makes the entry the most recent; ``fifo``: entries leave in the order
        they came.

    Examples
    --------
    >>> c = BoundedCache(2)
    >>> c.get_or_make("a", lambda: [1]) is c.get_or_make("a", lambda: [2])
    True
    >>> c.put("b", [3]); c.put("c", [4]); "a" in c
    False
    """

    def __init__(self, maxsize: int, policy: Literal["lru", "fifo"] = "lru") -> None:
        if policy not in POLICIES:
            raise ValueError(f"cache policy = {policy!r}: expected one of {', '.join(POLICIES)}")
        self.maxsize = int(maxsize)
        self.policy = policy
        self._d: OrderedDict[K, V] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, key: K, default: V | None = None) -> V | None:
        """The value stored under ``key`` (a hit), else ``default`` (a miss)."""
        try:
            value = self._d[key]
        except KeyError:
            self.misses += 1
            return default
        self.hits += 1
        if self.policy == "lru":
            self._d.move_to_end(key)
        return value

    def put(self, key: K, value: V) -> None:
        """Store ``value`` under ``key`` (the most recent entry) and evict down to ``maxsize``."""
        if self.maxsize <= 0:
            return
        self._d[key] = value
        self._d.move_to_end(key)
        while len(self._d) > self.maxsize:
            self._d.popitem(last=False)

    def get_or_make(self, key: K, make: Callable[[], V]) -> V:
        """The value under ``key``, or ``make()`` stored under it and returned."""
        try:
            value = self._d[key]
        except KeyError:
            self.misses += 1
            value = make()
            self.put(key, value)
            return value
        self.hits += 1
        if self.policy == "lru":
            self._d.move_to_end(key)
        return value

    def clear(self) -> None:
        """Forget every entry and reset the counters."""
        self._d.clear()
        self.hits = self.misses = 0

    def keys(self) -> tuple[K, ...]:
        """The keys, oldest (next to be evicted) first."""
        return tuple(self._d)

    def __contains__(self, key: object) -> bool:
        return key in self._d

    def __len__(self) -> int:
        return len(self._d)

    def __repr__(self) -> str:
        return (f"BoundedCache(maxsize={self.maxsize}, policy={self.policy!r}, "
                f"size={len(self._d)}, hits={self.hits}, misses={self.misses})")


__all__ = ["POLICIES", "BoundedCache"]
