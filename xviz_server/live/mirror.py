"""A feed held by another replica, read from the broker into a local :class:`~xviz_server.live.feed.LiveFeed`.

One reader per feed and replica, however many viewers it has here, and
only while it has any: the reader starts when the first viewer here joins
and stops :data:`LINGER` seconds after the last one left. It publishes what
the owner wrote (metadata, updates, the source leaving) into the local
feed, whose fan-out serves this replica's viewers as it serves a local
source's. It starts at the newest complete state the owner pointed to, so
that a viewer who joins draws at once. Without a reader, the feed's
metadata and whether its source is connected follow its registration
(:meth:`Mirror.registered`), for the catalog.

The reader has a connection of its own (:mod:`.wire`), named
``xviz-reader:<feed>`` in the broker's ``CLIENT LIST``, and waits in
``XREAD BLOCK`` for one entry at a time.

Updates carry their owner's numbers: one already read (a keyframe covers
updates read before) is skipped, and a gap (updates the owner could not
write, or a broker that restarted) is told to the viewers as updates
dropped. An entry that is not what an owner writes is skipped, with one log
line until a good entry follows.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from ..exceptions import BrokerError, XVIZError
from .feed import LiveFeed
from .link import BLOCK_MS, COMMAND_TIMEOUT, FAILURES, Link, cancel
from .streams import Entry, before, registration, updates
from .wire import Wire

__all__ = ["Mirror"]

logger = logging.getLogger("xviz_server.broker")

#: Seconds a feed is still read after its last viewer here left (one who reloads the page finds it read).
LINGER = 3.0
#: Seconds between two attempts to read while the broker does not answer, at first and at most.
RETRY, MAX_RETRY = 0.2, 2.0


class Mirror:
    """Reads ``feed``'s stream from the broker into ``feed`` while it has viewers, until closed."""

    def __init__(self, link: Link, feed: LiveFeed) -> None:
        self.link = link
        self.feed = feed
        self._owner = b""
        self._number: int | None = None  # of the owner's newest update read
        self._garbage = False  # a skipped entry was logged, and no good entry followed yet
        self._closed = False
        self._task: asyncio.Task[None] | None = None
        self._stopping: asyncio.TimerHandle | None = None
        feed.on_viewers = self._viewers
        self._viewers(feed.viewers)

    def registered(self, meta: bytes | None, connected: bytes | None) -> None:
        """Take the feed's registered metadata and state (``connected``: ``b"1"`` or ``b"0"``), unless it is read."""
        if self._task is None and meta is not None:
            self._registered(meta, connected)

    def _registered(self, meta: bytes, connected: bytes | None) -> None:
        if connected == b"0" and not self.feed.connected and self.feed.metadata is not None:
            return  # told already
        try:
            self.feed.set_metadata(Entry(b"meta", b"?", data=meta).json())
        except BrokerError as exc:
            self._skip(b"registration", exc)
        if connected == b"0" and self.feed.connected:
            self.feed.disconnect()

    def _viewers(self, count: int) -> None:
        if count:
            if self._stopping is not None:
                self._stopping.cancel()
                self._stopping = None
            if self._task is None and not self._closed:
                self._task = asyncio.ensure_future(self._read())
                self.link.metrics.readers.inc()
        elif self._task is not None and self._stopping is None:
            self._stopping = asyncio.get_running_loop().call_later(LINGER, self._stop)

    def _stop(self) -> None:
        self._stopping = None
        if self._task is not None:
            self._task.cancel()
            self._task = None
            self.link.metrics.readers.dec()
            self.feed.forget_state()  # a viewer who joins later draws from the stream, not from a stale state
            self._owner, self._number = b"", None

    async def _read(self) -> None:
        stream = updates(self.feed.name).encode()
        wire: Wire | None = None
        last: bytes | None = None
        delay = RETRY
        try:
            while not self._closed:
                try:
                    if wire is None or wire.closed:
                        wire = await self.link.wire(f"xviz-reader:{_printable(self.feed.name)}")
                    if last is None:
                        last = await self._start()
                    reply = wire.send(b"XREAD", b"COUNT", b"1", b"BLOCK", b"%d" % BLOCK_MS, b"STREAMS", stream, last)
                    answer = await asyncio.wait_for(reply, BLOCK_MS / 1000 + COMMAND_TIMEOUT)
                except FAILURES as exc:
                    if self._closed:
                        return
                    self.link.failed(exc)
                    if wire is not None:
                        wire.close()
                    await asyncio.sleep(delay)
                    delay = min(2 * delay, MAX_RETRY)
                    continue
                delay = RETRY
                for entry_id, fields in _entries(answer):
                    last = entry_id
                    await self._apply(entry_id, fields)
        finally:
            if wire is not None:
                wire.close()

    async def _start(self) -> bytes:
        """Take the registered metadata; the stream id to read from (that of the newest complete state)."""
        meta, connected, key = await self.link.fields(registration(self.feed.name), "meta", "connected", "key")
        if meta is not None:
            self._registered(meta, connected)
        return before(key) if key else b"0-0"

    async def _apply(self, entry_id: bytes, fields: dict[bytes, bytes]) -> None:
        try:
            entry = Entry.parse(fields)
            if entry.kind == b"meta":
                self.feed.set_metadata(entry.json())
            elif entry.kind == b"gone":
                if self.feed.connected:
                    self.feed.disconnect()
            elif entry.kind in (b"update", b"key"):
                await self._publish(entry_id, entry)
            else:
                raise BrokerError(f"{entry.kind.decode()} entry in a feed's stream")
        except XVIZError as exc:  # BrokerError, or an update the feed refuses
            self._skip(entry_id, exc)
        else:
            self._garbage = False

    async def _publish(self, entry_id: bytes, entry: Entry) -> None:
        number = self._number if entry.owner == self._owner else None  # a new owner numbers its updates afresh
        if number is not None and entry.number <= number:
            return  # read already (a keyframe of updates read before it)
        if number is not None and entry.number > number + 1:
            missing = entry.number - number - 1
            self.link.metrics.drops.labels("gap").inc(missing)
            self.feed.skipped(missing)
        await self.feed.publish(entry.data)
        self._owner, self._number = entry.owner, entry.number
        self.link.metrics.reads.inc()
        self.link.metrics.lag.observe(max(0.0, time.time() - int(entry_id.partition(b"-")[0]) / 1000))

    def _skip(self, entry_id: bytes, exc: Exception) -> None:
        self.link.metrics.drops.labels("garbage").inc()
        if not self._garbage:
            logger.warning("live feed %r: skipped entry %s from the broker: %s", self.feed.name, entry_id.decode(errors="replace"), exc)
            self._garbage = True

    async def close(self) -> None:
        self._closed = True
        self.feed.on_viewers = None
        if self._stopping is not None:
            self._stopping.cancel()
            self._stopping = None
        if self._task is not None:
            self.link.metrics.readers.dec()
            await cancel([self._task])
            self._task = None


def _entries(answer: Any) -> list[tuple[bytes, dict[bytes, bytes]]]:
    """The entries of an XREAD reply (``None`` when none came)."""
    return [(entry_id, dict(zip(fields[::2], fields[1::2]))) for _, entries in answer or [] for entry_id, fields in entries]


def _printable(name: str) -> str:
    """``name`` as a connection name may hold it (no spaces, newlines or other special characters)."""
    return "".join(c if "!" <= c <= "~" else "_" for c in name)
