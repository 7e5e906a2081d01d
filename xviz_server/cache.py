"""The frame cache shared by every session.

Encoded frames are immutable ``bytes``; the cache keeps the most recently
used ones within a total byte budget and makes sure that concurrent requests
for a frame that is not cached load it only once.
"""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Hashable

from .metrics import Metrics

__all__ = ["FrameCache"]


class FrameCache:
    """A least-recently-used map of keys to ``bytes``, bounded by total size.

    :meth:`get` returns the cached value or runs the loader; requests that
    arrive while a value is loading wait for the same load. A failed load is
    not cached: the next request tries again. A value larger than the whole
    budget is returned but not kept.
    """

    def __init__(self, max_bytes: int, metrics: Metrics) -> None:
        self.max_bytes = max_bytes
        self.size = 0
        self._entries: OrderedDict[Hashable, bytes] = OrderedDict()
        self._loading: dict[Hashable, asyncio.Task[bytes]] = {}
        self._metrics = metrics

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    async def get(self, key: Hashable, load: Callable[[], Awaitable[bytes]]) -> bytes:
        """Return the value of ``key``, loading it with ``load()`` if needed."""
        value = self._entries.get(key)
        if value is not None:
            self._entries.move_to_end(key)
            self._metrics.cache_hits.inc()
            return value
        task = self._loading.get(key)
        if task is None:
            self._metrics.cache_misses.inc()
            task = asyncio.ensure_future(load())
            self._loading[key] = task
            task.add_done_callback(lambda done: self._loaded(key, done))
        # A waiter that is cancelled must not cancel the load other waiters share.
        return await asyncio.shield(task)

    def _loaded(self, key: Hashable, task: asyncio.Task[bytes]) -> None:
        del self._loading[key]
        if task.cancelled() or task.exception() is not None:
            return
        value = task.result()
        if len(value) > self.max_bytes:
            return
        self._entries[key] = value
        self.size += len(value)
        while self.size > self.max_bytes:
            _, evicted = self._entries.popitem(last=False)
            self.size -= len(evicted)
            self._metrics.cache_evictions.inc()
        self._metrics.cache_bytes.set(self.size)
        self._metrics.cache_entries.set(len(self._entries))
