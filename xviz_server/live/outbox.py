"""The owner's side of a feed shared through the broker: writes it, takes viewers' reconfigures back.

The replica whose source feeds a feed writes, in order, its metadata (and
each change), every update and the source's departure to the feed's stream
(see :mod:`.streams`), and keeps the feed registered. Writing happens in a
task of its own behind a short queue: the source and this replica's viewers
never wait for the broker. Entries go through a connection of the outbox's
own (:mod:`.wire`); an update that finds it idle is written at once, from
the feed's publish, before the feed's fan-out to this replica's viewers.
Updates that cannot be written (the broker is down or full, or slower than
the source) are dropped and counted; readers on other replicas see the gap
in the numbers and tell their viewers.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from typing import Any, cast

import orjson
from redis.exceptions import OutOfMemoryError, ResponseError

from ..codec import Format
from ..events import Variant
from ..exceptions import BrokerError
from ..state import COMPLETE_TYPES
from ..work import Workers
from .feed import FeedEvent, LiveFeed, LiveUpdate
from .link import BLOCK_MS, COMMAND_TIMEOUT, FAILURES, Link, cancel
from .redis_wire import Wire
from .streams import CLAIM, FEEDS, Entry, control, registration, updates

__all__ = ["Outbox", "kept"]

logger = logging.getLogger("xviz_server.broker")

GLB = Variant(Format.BINARY)
#: Updates of one feed that may wait to be written.
QUEUE = 4
#: The largest viewer's reconfigure passed to the source through the broker (a ``config_update`` is a few
#: hundred bytes).
MAX_RECONFIGURE_BYTES = 64 * 1024
#: Milliseconds a feed's stream outlives its registration's time to live, unless written to again.
STREAM_EXTRA_MS = 30_000
#: Fewest and most entries a feed's stream keeps (within its bytes).
MIN_ENTRIES, MAX_ENTRIES = 4, 1000
#: Sets fields of a registration if this replica holds it. KEYS: registration; ARGV: replica, field, value, ...
SET_IF_OWNER = """
if redis.call('HGET', KEYS[1], 'owner') ~= ARGV[1] then return 0 end
redis.call('HSET', KEYS[1], unpack(ARGV, 2))
return 1
"""
#: Deletes a registration if this replica holds it. KEYS: registration; ARGV: replica.
RELEASE = """
if redis.call('HGET', KEYS[1], 'owner') ~= ARGV[1] then return 0 end
return redis.call('DEL', KEYS[1])
"""


def kept(max_bytes: int, size: int) -> int:
    """How many entries of ``size`` bytes a feed's stream keeps within ``max_bytes`` (its ``XADD``'s ``MAXLEN ~``)."""
    return max(MIN_ENTRIES, min(MAX_ENTRIES, max_bytes // max(1, size)))


class Outbox:
    """Writes ``feed``, held by this replica, to the broker.

    ``max_bytes`` bounds the bytes its stream keeps; ``ttl`` (s) is how long
    its registration lives unless renewed (:meth:`claim`).
    """

    def __init__(self, link: Link, feed: LiveFeed, workers: Workers, *, max_bytes: int, ttl: float) -> None:
        self.link = link
        self.feed = feed
        self.workers = workers
        #: Whether this replica holds the feed's registration, as far as it knows.
        self.claimed = False
        #: The replica that holds it instead, when the broker said so.
        self.refused_by: str | None = None
        #: When the feed's source left (monotonic), or None while it is there.
        self.left_at: float | None = None
        self._max_bytes = max_bytes
        self._ttl_ms = int(ttl * 1000)
        self._items: deque[LiveUpdate | FeedEvent] = deque()
        self._ready = asyncio.Event()
        self._since_key = 0  # updates written since the last complete one
        self._full = False  # the broker refused the last write for want of memory
        self._wire: Wire | None = None
        self._busy = False  # the writing task is on an item
        self._early: tuple[LiveUpdate, asyncio.Future[tuple[Any, Any]]] | None = None  # an update written from put()
        self._claim = link.redis.register_script(CLAIM)
        self._set = link.redis.register_script(SET_IF_OWNER)
        self._release = link.redis.register_script(RELEASE)
        self._closed = False
        self._tasks = [asyncio.ensure_future(self._write()), asyncio.ensure_future(self._take_reconfigures())]

    # -- what the feed does ---------------------------------------------------

    def put(self, item: LiveUpdate | FeedEvent) -> None:
        """Queue an update or a feed event for the broker; never waits."""
        if isinstance(item, FeedEvent):
            self.left_at = asyncio.get_running_loop().time() if item.kind == "gone" else None
            if self._items and self._items[-1] == item:
                return  # queued already (events are written from the feed as it is then)
        elif self.link.down or self.refused_by is not None:
            self.link.metrics.drops.labels("down" if self.link.down else "error").inc()
            return
        elif sum(isinstance(i, LiveUpdate) for i in self._items) >= QUEUE:
            self._items.remove(next(i for i in self._items if isinstance(i, LiveUpdate)))
            self.link.metrics.drops.labels("behind").inc()
        elif not self._items and not self._busy and self.claimed and self._wire is not None and not self._wire.closed:
            data = item.ready(GLB)
            if data is not None:
                self._early = item, self._add(self._entry(item, data))
        self._items.append(item)
        self._ready.set()

    # -- the registration -----------------------------------------------------

    async def claim(self) -> str | None:
        """Register the feed as this replica's, or renew it; the replica that holds it instead, if any."""
        name = self.feed.name
        answer = await self._claim(
            keys=[registration(name), FEEDS, updates(name)], args=[self.link.id, self._ttl_ms, name]
        )
        if isinstance(answer, bytes):
            holder = answer.decode(errors="replace")
            if self.refused_by != holder:
                logger.error("live feed %r is held by replica %s: this replica's source is not shared", name, holder)
            self.refused_by, self.claimed = holder, False
            return holder
        if answer == 1 and self.claimed:  # the registration was lost (the broker restarted): write it again
            logger.info("live feed %r: registered again after the broker lost it", name)
            self._resend()
        self.claimed, self.refused_by = True, None
        if self._items:  # what could not be written while the broker was away
            self._ready.set()
        return None

    def _resend(self) -> None:
        if not self.feed.connected:
            self._items.appendleft(FeedEvent("gone"))
        if self.feed.metadata is not None:
            self._items.appendleft(FeedEvent("metadata"))
        self._since_key = MAX_ENTRIES  # a keyframe with the next update
        self._ready.set()

    # -- writing --------------------------------------------------------------

    async def _write(self) -> None:
        while not self._closed:
            await self._ready.wait()
            self._ready.clear()
            while self._items:
                item = self._items.popleft()
                self._busy = True
                try:
                    if not self.claimed and await self.claim() is not None:
                        continue
                    if isinstance(item, LiveUpdate):
                        await self._write_update(item)
                    elif item.kind == "metadata":
                        await self._write_metadata()
                    else:
                        await self._append((Entry(b"gone", self.link.id), MIN_ENTRIES))
                        await self._set(keys=[registration(self.feed.name)], args=[self.link.id, "connected", 0])
                    if self._full:
                        logger.info("broker %s: writing live feed %r again", self.link.url, self.feed.name)
                        self._full = False
                except ResponseError as exc:
                    self.refused(exc, item)
                except FAILURES as exc:
                    if self._closed:
                        return
                    self.link.failed(exc)
                    if isinstance(item, LiveUpdate):
                        self.link.metrics.drops.labels("down").inc()
                    else:  # metadata and departures are written once the broker is back
                        self._items.appendleft(item)
                        break
                finally:
                    self._busy = False

    def _entry(self, update: LiveUpdate, data: bytes) -> tuple[Entry, int]:
        """The entry of ``update`` (``data``, its GLB), and the length to trim the stream to."""
        maxlen = kept(self._max_bytes, len(data))
        complete = str(update.message["data"].get("update_type", "")).upper() in COMPLETE_TYPES
        return Entry(b"update", self.link.id, update.number, data, complete), maxlen

    async def _write_update(self, update: LiveUpdate) -> None:
        early, self._early = self._early, None
        data = await update.encoded(GLB, self.workers)
        entry, maxlen = self._entry(update, data)
        if early is not None and early[0] is update:
            entry_id = await self._added(early[1])
        else:
            entry_id = await self._append((entry, maxlen))
        self.link.metrics.written_bytes.inc(len(data))
        if entry.complete:
            self._since_key = 0
        else:
            self._since_key += 1
            state = self.feed.state()
            if self._since_key < maxlen // 2 or state is None or state.number != update.number:
                return
            # A source of incremental updates: its complete state, where a new reader can start.
            data = await state.encoded(GLB, self.workers)
            entry_id = await self._append((Entry(b"key", self.link.id, state.number, data, True), maxlen))
            self._since_key = 0
        await self._set(keys=[registration(self.feed.name)], args=[self.link.id, "key", entry_id])

    async def _write_metadata(self) -> None:
        if self.feed.metadata is None:
            return
        data = orjson.dumps(self.feed.metadata)
        await self._append((Entry(b"meta", self.link.id, data=data), MIN_ENTRIES))
        await self._set(keys=[registration(self.feed.name)], args=[self.link.id, "meta", data, "connected", 1])

    async def _append(self, trimmed: tuple[Entry, int]) -> bytes:
        """Add the entry of ``trimmed`` to the feed's stream, trimmed to about as many entries as it says; its id."""
        if self._wire is None or self._wire.closed:
            self._wire = await self.link.wire(f"xviz-writer:{self.feed.name}")
        return await self._added(self._add(trimmed))

    def _add(self, trimmed: tuple[Entry, int]) -> asyncio.Future[tuple[Any, Any]]:
        """Write the commands that add the entry of ``trimmed`` to the feed's stream now; a future for their replies."""
        assert self._wire is not None
        entry, maxlen = trimmed
        stream = updates(self.feed.name).encode()
        fields = [part for field in entry.fields().items() for part in field]
        added = self._wire.send(b"XADD", stream, b"MAXLEN", b"~", b"%d" % maxlen, b"*", *fields)
        expiring = self._wire.send(b"PEXPIRE", stream, b"%d" % (self._ttl_ms + STREAM_EXTRA_MS))
        return asyncio.gather(added, expiring, return_exceptions=True)

    async def _added(self, replies: asyncio.Future[tuple[Any, Any]]) -> bytes:
        """The id of the entry whose commands' ``replies`` these are; raises what the broker answered instead."""
        try:
            entry_id, expired = await asyncio.wait_for(replies, COMMAND_TIMEOUT)
        except FAILURES:
            if self._wire is not None:
                self._wire.close()
            raise
        for answer in (entry_id, expired):
            if isinstance(answer, BaseException):
                if not isinstance(answer, ResponseError) and self._wire is not None:
                    self._wire.close()
                raise answer
        self.link.metrics.writes.inc()
        return bytes(entry_id)

    def refused(self, exc: ResponseError, item: LiveUpdate | FeedEvent | None = None) -> None:
        """The broker refused a write of ``item`` (``maxmemory`` reached, ...): dropped, said once until a write succeeds."""
        if isinstance(item, LiveUpdate):
            self.link.metrics.drops.labels("full" if isinstance(exc, OutOfMemoryError) else "error").inc()
        if not self._full:
            logger.warning(
                "broker %s refuses writes of live feed %r (%s): dropping them, the source goes on",
                self.link.url,
                self.feed.name,
                exc,
            )
            self._full = True

    # -- the other way: viewers elsewhere reconfiguring the source --------------

    async def _take_reconfigures(self) -> None:
        """Pass each ``config_update`` that viewers on other replicas send to the feed's source."""
        stream, last = control(self.feed.name), None
        while not self._closed:
            try:
                if last is None:  # after the newest entry, whichever is newest between two reads
                    newest = cast(list[tuple[bytes, Any]], await self.link.redis.xrevrange(stream, count=1))
                    last = newest[0][0] if newest else b"0-0"
                entries = await self.link.read(stream, last, 16)
            except FAILURES:
                if self._closed:
                    return
                await asyncio.sleep(BLOCK_MS / 1000)
                continue
            for entry_id, fields in entries:
                last = entry_id
                try:
                    entry = Entry.parse(fields)
                    if len(entry.data) > MAX_RECONFIGURE_BYTES:
                        raise BrokerError(
                            f"a reconfigure of {len(entry.data)} bytes, more than {MAX_RECONFIGURE_BYTES}"
                        )
                    await self.feed.reconfigure(entry.json())
                except BrokerError as exc:
                    logger.warning("live feed %r: skipped a reconfigure entry %s: %s", self.feed.name, entry_id, exc)
                except Exception as exc:  # the source went away while it was sent one: that one is lost, not the task
                    logger.warning(
                        "live feed %r: cannot pass reconfigure entry %s to the source: %r",
                        self.feed.name,
                        entry_id,
                        exc,
                    )

    async def close(self) -> None:
        """Stop writing; if this replica holds the feed, tell the others its source left and unregister it."""
        self._closed = True
        await cancel(self._tasks)
        if self.claimed and self.link.up:
            try:
                await asyncio.wait_for(self._unregister(), COMMAND_TIMEOUT)
            except FAILURES as exc:
                logger.warning("live feed %r: cannot unregister it from the broker: %s", self.feed.name, exc)
        if self._wire is not None:
            self._wire.close()

    async def _unregister(self) -> None:
        if await self._release(keys=[registration(self.feed.name)], args=[self.link.id]):
            await self._append((Entry(b"gone", self.link.id), MIN_ENTRIES))
