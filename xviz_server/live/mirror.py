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

The broker is a door like ingest: whatever can reach the broker can write
entries in a feed's stream, so each one passes the checks of
:mod:`~xviz_server.admission` (shape, the expansion limit) before any
viewer here sees it, and updates must be GLB, as owners write them. An
entry refused is skipped and counted (``xviz_broker_dropped_updates`` with
reason ``garbage``), with one log line until a good entry follows; the
reader goes on with the next.

Updates carry their owner's numbers (:class:`Numbering`): one already read
(a keyframe covers updates read before) is skipped, and a gap (updates the
owner could not write, or a broker that restarted) is told to the viewers
as updates dropped. An update numbered more than :data:`MAX_GAP` ahead of
the owner's newest, or below it, is not the owner's next and is refused,
unless the entry right after it follows it (the owner numbers afresh).

A reader that fails (an answer no check foresaw, a registration that names
no entry) starts again after a backoff, after the entry it was on; the
first failure of a run is logged, each one counted
(``xviz_broker_reader_restarts``), and after :data:`FAILING` failures in a
row, ``/healthz`` says the feed's reading is degraded, until it reads again.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from ..admission import admit, check
from ..exceptions import BrokerError, XVIZError
from ..work import Workers
from .feed import LiveFeed
from .link import BLOCK_MS, COMMAND_TIMEOUT, FAILURES, Link, cancel
from .redis_wire import Wire
from .streams import Entry, before, registration, updates

__all__ = ["Mirror", "Numbering"]

logger = logging.getLogger("xviz_server.broker")

#: Seconds a feed is still read after its last viewer here left (one who reloads the page finds it read).
LINGER = 3.0
#: Seconds between two attempts to read while the broker does not answer (or the reader failed), at first and at most.
RETRY, MAX_RETRY = 0.2, 2.0
#: Most updates of its owner an update may say were missed before it (more is not the owner's next).
MAX_GAP = 10_000
#: Failures of a reader in a row, without an answer read between them, that make ``/healthz`` say it is degraded.
FAILING = 3


class Numbering:
    """The numbers of a feed's updates as a reader takes them: which is the owner's next, what was missed."""

    def __init__(self) -> None:
        self.owner = b""
        self.number: int | None = None  # of the owner's newest update taken
        self._refused: tuple[bytes, int] | None = None  # the last update refused as not the owner's next

    def missing(self, owner: bytes, number: int) -> int | None:
        """How many of ``owner``'s updates were missed before its update ``number`` (0: it is the next), or
        ``None`` if it was taken already. Raises :class:`~xviz_server.exceptions.BrokerError` if it is not the
        owner's next (below its newest, or more than :data:`MAX_GAP` ahead), unless it follows the update
        refused last (the owner numbers afresh: then nothing is said missed)."""
        if owner != self.owner or self.number is None:
            return 0  # a new owner numbers its updates afresh
        if number == self.number:
            return None  # read already (a keyframe of updates read before it)
        if self.number < number <= self.number + 1 + MAX_GAP:
            return number - self.number - 1
        if self._refused == (owner, number - 1):
            return 0
        self._refused = owner, number
        raise BrokerError(
            f"update {number} of replica {owner[:60].decode(errors='replace')} is not the owner's next "
            f"(its newest is {self.number}; at most {MAX_GAP} may be missed)"
        )

    def take(self, owner: bytes, number: int) -> None:
        """``owner``'s update ``number`` was taken."""
        self.owner, self.number, self._refused = owner, number, None


class Mirror:
    """Reads ``feed``'s stream from the broker into ``feed`` while it has viewers, until closed.

    Its updates are checked as ingest checks a source's, in ``workers``' threads,
    against ``max_bytes`` (see :func:`~xviz_server.admission.admit`).
    """

    def __init__(self, link: Link, feed: LiveFeed, workers: Workers, max_bytes: int) -> None:
        self.link = link
        self.feed = feed
        self.workers = workers
        self.max_bytes = max_bytes
        self._numbering = Numbering()
        self._last: bytes | None = None  # the id of the stream's last entry read
        self._garbage = False  # a skipped entry was logged, and no good entry followed yet
        self._failures = 0  # of the reader, in a row
        self._failure = ""  # the last one
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
            self._metadata(Entry(b"meta", b"?", data=meta))
        except XVIZError as exc:
            self._skip(b"registration", exc)
        if connected == b"0" and self.feed.connected:
            self.feed.disconnect()

    def _viewers(self, count: int) -> None:
        if count:
            if self._stopping is not None:
                self._stopping.cancel()
                self._stopping = None
            if self._task is None and not self._closed:
                self._task = asyncio.ensure_future(self._run())
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
            self._numbering, self._last, self._failures = Numbering(), None, 0

    async def _run(self) -> None:
        """Read the feed until closed; start reading again, after a backoff, whenever the reader fails."""
        while not self._closed:
            try:
                await self._read()
            except Exception as exc:  # an answer no check foresaw, or a bug: the viewers here still want the feed
                self._failed(exc)
                await asyncio.sleep(min(RETRY * 2 ** (self._failures - 1), MAX_RETRY))

    def _failed(self, exc: Exception) -> None:
        self._failures += 1
        self._failure = f"{type(exc).__name__}: {exc}"
        self.link.metrics.restarts.inc()
        if self._failures == 1:
            logger.error(
                "live feed %r: reading it from the broker failed (%s); reading it again, with backoff",
                self.feed.name,
                self._failure,
                exc_info=not isinstance(exc, XVIZError),
            )

    def problem(self) -> str | None:
        """What is wrong with the reader, for ``/healthz``: ``None`` unless it failed :data:`FAILING` times in a row."""
        if self._failures < FAILING:
            return None
        return f"degraded: the reader of live feed {self.feed.name!r} failed {self._failures} times in a row (last: {self._failure})"

    async def _read(self) -> None:
        stream = updates(self.feed.name).encode()
        wire: Wire | None = None
        delay = RETRY
        try:
            while not self._closed:
                try:
                    if wire is None or wire.closed:
                        wire = await self.link.wire(f"xviz-reader:{_printable(self.feed.name)}")
                    if self._last is None:
                        self._last = await self._start()
                    reply = wire.send(
                        b"XREAD", b"COUNT", b"1", b"BLOCK", b"%d" % BLOCK_MS, b"STREAMS", stream, self._last
                    )
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
                if self._failures:
                    logger.info(
                        "live feed %r: reading it from the broker again (it failed %d times before)",
                        self.feed.name,
                        self._failures,
                    )
                    self._failures = 0
                for entry_id, fields in _entries(answer):
                    self._last = entry_id  # an entry the reader fails on is not read again
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
                self._metadata(entry)
            elif entry.kind == b"gone":
                if self.feed.connected:
                    self.feed.disconnect()
            elif entry.kind in (b"update", b"key"):
                await self._publish(entry_id, entry)
            else:
                raise BrokerError(f"{entry.kind.decode()} entry in a feed's stream")
        except XVIZError as exc:  # BrokerError, MessageError (refused as ingest refuses it), or refused by the feed
            self._skip(entry_id, exc)
        else:
            self._garbage = False

    def _metadata(self, entry: Entry) -> None:
        metadata = entry.json()
        check("xviz/metadata", metadata, self.max_bytes)
        self.feed.set_metadata(metadata)

    async def _publish(self, entry_id: bytes, entry: Entry) -> None:
        missing = self._numbering.missing(entry.owner, entry.number)
        if missing is None:
            return
        if entry.data[:4] != b"glTF":
            raise BrokerError(f"{entry.kind.decode()} entry that is not GLB (it starts with {entry.data[:8]!r})")
        kind, _ = await self.workers.io(admit, entry.data, self.max_bytes)
        if kind != "xviz/state_update":
            raise BrokerError(f"{entry.kind.decode()} entry holding {kind}, not xviz/state_update")
        if missing:
            self.link.metrics.drops.labels("gap").inc(missing)
            self.feed.skipped(missing)
        await self.feed.publish(entry.data)
        self._numbering.take(entry.owner, entry.number)
        self.link.metrics.reads.inc()
        self.link.metrics.lag.observe(max(0.0, time.time() - int(entry_id.partition(b"-")[0]) / 1000))

    def _skip(self, entry_id: bytes, exc: Exception) -> None:
        self.link.metrics.drops.labels("garbage").inc()
        if not self._garbage:
            logger.warning(
                "live feed %r: skipped entry %s from the broker: %s",
                self.feed.name,
                entry_id.decode(errors="replace"),
                exc,
            )
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
    return [
        (entry_id, dict(zip(fields[::2], fields[1::2]))) for _, entries in answer or [] for entry_id, fields in entries
    ]


def _printable(name: str) -> str:
    """``name`` as a connection name may hold it (no spaces, newlines or other special characters)."""
    return "".join(c if "!" <= c <= "~" else "_" for c in name)
