"""The frames a stream loads ahead of the socket, bounded in count and in bytes.

A stream from a local log keeps the server's ``read_ahead`` frames loading.
A log in an object store says how far to read ahead of it
(:class:`ReadAhead`), and the sizes its listing gave bound the bytes in
flight too: a session then streams at the store's throughput rather than at
one frame per round trip, and never holds more than ``max_bytes`` of frames
still arriving.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass

__all__ = ["ReadAhead", "Window"]


@dataclass(frozen=True)
class ReadAhead:
    """How far a stream may read ahead: frames loading at once, and their bytes."""

    count: int
    #: Most bytes loading at once, by the sizes known before reading; a larger frame loads alone.
    max_bytes: int | None = None


class Window:
    """Frames ``numbers`` loaded in order, at most ``limits`` of them at a time.

    :meth:`next` starts what the limits allow and hands out the next frame's
    load; :meth:`cancel` stops the loads still running. ``size`` gives a
    frame's size before it is read, or ``None`` (which counts as nothing).
    """

    def __init__(
        self,
        numbers: Sequence[int],
        load: Callable[[int], Awaitable[bytes]],
        limits: ReadAhead,
        size: Callable[[int], int | None],
    ) -> None:
        self._numbers = numbers
        self._load = load
        self._limits = limits
        self._size = size
        self._loading: deque[tuple[asyncio.Future[bytes], int]] = deque()
        self._bytes = 0
        self._following = 0

    def next(self) -> asyncio.Future[bytes]:
        """The load of the next frame (started now if the limits held it back)."""
        count, max_bytes = self._limits.count, self._limits.max_bytes
        while self._following < len(self._numbers) and len(self._loading) < count:
            number = self._numbers[self._following]
            size = self._size(number) or 0
            if self._loading and max_bytes is not None and self._bytes + size > max_bytes:
                break
            self._loading.append((asyncio.ensure_future(self._load(number)), size))
            self._bytes += size
            self._following += 1
        future, size = self._loading.popleft()
        self._bytes -= size
        return future

    def cancel(self) -> None:
        """Cancel the loads started and not handed out."""
        for future, _ in self._loading:
            future.cancel()
        self._loading.clear()
        self._bytes = 0
