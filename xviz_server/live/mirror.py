"""A feed held by another replica, read from the broker into a local :class:`~xviz_server.live.feed.LiveFeed`.

One reader per feed and replica, however many viewers it has here: it
publishes what the owner wrote (metadata, updates, the source leaving) into
the local feed, whose fan-out serves this replica's viewers as it serves a
local source's. It starts at the newest complete state the owner pointed
to, so the local feed can give a late viewer a complete state at once.

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

from ..exceptions import BrokerError, XVIZError
from .feed import LiveFeed
from .link import FAILURES, Link, cancel
from .streams import Entry, before, registration, updates

__all__ = ["Mirror"]

logger = logging.getLogger("xviz_server.broker")

#: Entries read at once.
READ_COUNT = 16
#: Seconds between two attempts to read while the broker does not answer, at first and at most.
RETRY, MAX_RETRY = 0.2, 2.0


class Mirror:
    """Reads ``feed``'s stream from the broker into ``feed`` until closed."""

    def __init__(self, link: Link, feed: LiveFeed) -> None:
        self.link = link
        self.feed = feed
        self._owner = b""
        self._number: int | None = None  # of the owner's newest update read
        self._garbage = False  # a skipped entry was logged, and no good entry followed yet
        self._closed = False
        self._task = asyncio.ensure_future(self._read())

    async def _read(self) -> None:
        last: bytes | None = None
        delay = RETRY
        while not self._closed:
            try:
                if last is None:
                    last = await self._start()
                entries = await self.link.read(updates(self.feed.name), last, READ_COUNT)
            except FAILURES as exc:
                if self._closed:
                    return
                self.link.failed(exc)
                await asyncio.sleep(delay)
                delay = min(2 * delay, MAX_RETRY)
                continue
            delay = RETRY
            for entry_id, fields in entries:
                last = entry_id
                await self._apply(entry_id, fields)

    async def _start(self) -> bytes:
        """Take the registered metadata; the stream id to read from (that of the newest complete state)."""
        meta, connected, key = await self.link.fields(registration(self.feed.name), "meta", "connected", "key")
        if meta is not None:
            try:
                self.feed.set_metadata(Entry(b"meta", b"?", data=meta).json())
            except BrokerError as exc:
                self._skip(b"registration", exc)
            if connected == b"0":
                self.feed.disconnect()
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
        await cancel([self._task])
