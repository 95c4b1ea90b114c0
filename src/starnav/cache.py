"""A small bounded in-memory cache: the one way starnav keeps expensive results around.

Several things are slow to make and often asked for again with the same inputs: a DEM read
from disk, the procedural Moon, a view-adapted mesh, the sub-posting detail of a DEM, the
spectrum of a PSF kernel. Each is kept in memory under a hashable key that names everything the
result depends on (a file stamp, a configuration's JSON, a grid's ``uid``), and only a few of
them: the objects are large (a global grid is hundreds of megabytes), so the cache must forget.

:class:`BoundedCache` holds at most ``maxsize`` entries and forgets the *least recently used*
one (``policy="lru"``, the default: a hit refreshes the entry) or the *oldest* one
(``policy="fifo"``: insertion order only). A hit returns the very object that was stored, not a
copy, so callers may rely on identity (``view_mesh(...) is view_mesh(...)`` when nothing
changed) and must treat cached objects as read-only. ``maxsize <= 0`` turns caching off; the
bound may be changed at any time and applies at the next insertion. ``hits`` and ``misses``
count lookups, for tests and logs.

The cache is not thread-safe and lives in one process (a worker of a process pool has its own).
Results that depend only on arguments and are small stay with :func:`functools.lru_cache`.
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
