"""A thread-safe LRU map with a size budget that loads each missing key once.

The server keeps several things of built meshes in memory (loaded progressive meshes,
encoded levels, stored split streams, records that can no longer change); they share
this one map: entries are weighed by ``size`` against ``budget``, the least recently used
go first, an entry over ``max_entry`` is handed out but not kept (one huge value must not
flush everything), and concurrent misses on one key run its loader once while the others
wait for it.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Generic, TypeVar

__all__ = ["CacheStats", "LruCache"]

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


@dataclass(frozen=True)
class CacheStats:
    """entries and bytes (or count) held; hits: lookups that found their value; misses:
    values that had to be loaded or made and were put in (what the cache saved is hits)."""

    entries: int
    used: int
    budget: int
    hits: int
    misses: int


class LruCache(Generic[K, V]):
    """budget : total size kept; size(value) : an entry's weight (default 1: a count);
    max_entry : the largest entry kept (default: budget)."""

    def __init__(
        self,
        budget: int,
        size: Callable[[V], int] = lambda value: 1,
        max_entry: int | None = None,
    ) -> None:
        self._budget = budget
        self._size = size
        self._max_entry = budget if max_entry is None else max_entry
        self._lock = threading.Lock()
        self._entries: OrderedDict[K, V] = OrderedDict()
        self._used = 0
        self._loading: dict[K, threading.Lock] = {}
        self._hits = 0
        self._misses = 0

    def stats(self) -> CacheStats:
        with self._lock:
            return CacheStats(
                len(self._entries), self._used, self._budget, self._hits, self._misses
            )

    def peek(self, key: K) -> V | None:
        """The value if present (marked as used), else None; never blocks on a load."""
        with self._lock:
            value = self._entries.get(key)
            if value is not None:
                self._entries.move_to_end(key)
                self._hits += 1
            return value

    def get(self, key: K, load: Callable[[], V]) -> V:
        """The value of ``key``, loaded by ``load()`` if missing; a load that raises
        leaves nothing behind (the next call tries again)."""
        value = self.peek(key)
        if value is not None:
            return value
        with self._lock:
            loading = self._loading.setdefault(key, threading.Lock())
        with loading:
            value = self.peek(key)
            if value is not None:
                return value
            try:
                value = load()
            finally:
                with self._lock:
                    self._loading.pop(key, None)
            self.put(key, value)
            return value

    def put(self, key: K, value: V) -> None:
        size = self._size(value)
        if size > self._max_entry:
            with self._lock:
                self._misses += 1  # made, handed out, not kept
            return
        with self._lock:
            if key in self._entries:
                return
            self._misses += 1
            self._entries[key] = value
            self._used += size
            while self._used > self._budget and self._entries:
                _, dropped = self._entries.popitem(last=False)
                self._used -= self._size(dropped)

    def drop(self, matches: Callable[[K], bool]) -> None:
        """Forget every entry whose key ``matches``."""
        with self._lock:
            for key in [key for key in self._entries if matches(key)]:
                self._used -= self._size(self._entries.pop(key))
