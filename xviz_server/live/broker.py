"""Live feeds across replicas, through a broker (Redis Streams).

With ``--broker redis://...`` on every replica, a source may connect to any
of them and its viewers to any other. The replica that holds the source
*owns* the feed: it checks and records the source and serves its own viewers
as without a broker, and writes the feed to the broker (:mod:`.outbox`).
Every other replica lists the feed with its own and, while it has viewers
of it, reads it once into a local feed (:mod:`.mirror`) that they follow
like any other.

A :class:`Broker` hooks into a :class:`~xviz_server.live.feed.LiveRegistry`
at its edges only (what is published, metadata changes and departures, and
the claims of sources) and polls the broker every :attr:`Broker.interval`
seconds: it renews the registrations of the feeds it owns and follows those
of the others. A feed whose owner stops renewing it (a replica killed) is
gone after the TTL: its viewers here are told, and it leaves the catalog.

The broker is never on the path of a source or of this replica's viewers:
when it is down the server says so once, serves recorded logs and its own
feeds, and tries again with backoff.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, cast

import orjson
from redis.exceptions import ResponseError

from ..exceptions import XVIZError
from ..layout import check_log_name
from ..metrics import Metrics
from ..work import Workers
from .feed import GRACE, FeedEvent, LiveFeed, LiveRegistry, LiveUpdate
from .link import COMMAND_TIMEOUT, FAILURES, Link, cancel
from .mirror import Mirror
from .outbox import Outbox
from .streams import FEEDS, Entry, control, registration

__all__ = ["Broker"]

logger = logging.getLogger("xviz_server.broker")

#: Longest wait between two attempts to reach a broker that is down, s (and at most half the TTL).
MAX_BACKOFF = 5.0
#: Entries a feed's control stream keeps (viewers' reconfigures).
CONTROL_ENTRIES = 64
#: Feeds of replicas that went away kept for their viewers, who resume if the feed comes back.
DEPARTED = 256


class Broker:
    """Shares the feeds of ``registry`` with the other replicas using the broker at ``url``.

    ``ttl`` (s): how long a feed stays registered unless renewed;
    ``max_bytes``: most bytes of updates kept per feed; ``max_update_bytes``:
    what an update read from the broker may expand to, as a source's at ingest.
    """

    def __init__(
        self,
        url: str,
        registry: LiveRegistry,
        metrics: Metrics,
        workers: Workers,
        *,
        ttl: float,
        max_bytes: int,
        max_update_bytes: int,
    ) -> None:
        self.link = Link(url, metrics)
        self.registry = registry
        self.workers = workers
        self.ttl = ttl
        #: Seconds between two polls of the broker while it answers, and at most while it does not.
        self.interval, self.backoff = min(1.0, ttl / 4), min(MAX_BACKOFF, ttl / 2)
        self._max_bytes = max_bytes
        self._max_update_bytes = max_update_bytes
        self._outboxes: dict[str, Outbox] = {}
        self._mirrors: dict[str, Mirror] = {}
        self._departed: dict[str, LiveFeed] = {}  # oldest first
        self._conflicts: set[str] = set()  # feeds with a source here and on another replica, logged once
        self._run_id: str | None = None
        self._hold_until = 0.0  # keep mirrors whose registration is missing until then (the broker restarted)
        self._task: asyncio.Task[None] | None = None
        self._closed = False
        registry.listeners.append(self._published)
        registry.watchers.append(self._changed)
        registry.claims.append(self._claim)

    def start(self) -> None:
        """Start polling the broker; returns at once, whether it answers or not."""
        self._task = asyncio.ensure_future(self._run())

    async def close(self) -> None:
        self._closed = True
        await cancel([] if self._task is None else [self._task])
        for outbox in self._outboxes.values():
            await outbox.close()
        for mirror in self._mirrors.values():
            await mirror.close()
        await self.link.close()

    def health(self) -> str:
        """Lines on the broker's state, for ``/healthz``: the broker's, then each reader's that keeps failing."""
        problems = [problem for mirror in self._mirrors.values() if (problem := mirror.problem()) is not None]
        return "\n".join([self.link.health(), *problems])

    # -- hooks of the registry --------------------------------------------------

    def _outbox(self, feed: LiveFeed) -> Outbox:
        outbox = self._outboxes.get(feed.name)
        if outbox is None or outbox.feed is not feed:  # new, or a feed of that name that was dropped
            if outbox is not None:
                asyncio.ensure_future(outbox.close())
            outbox = self._outboxes[feed.name] = Outbox(
                self.link, feed, self.workers, max_bytes=self._max_bytes, ttl=self.ttl
            )
        return outbox

    def _published(self, feed: LiveFeed, update: LiveUpdate) -> None:
        if feed.origin is None:
            self._outbox(feed).put(update)

    def _changed(self, feed: LiveFeed, event: FeedEvent) -> None:
        if feed.origin is None:
            self._outbox(feed).put(event)

    async def _claim(self, feed: LiveFeed) -> None:
        """Refuse a source for ``feed`` when another replica holds it (unknown while the broker is down)."""
        if not self.link.up:
            return
        outbox = self._outbox(feed)
        try:
            holder = await asyncio.wait_for(outbox.claim(), COMMAND_TIMEOUT)
        except ResponseError as exc:  # full: the source is served here, and the claim tried again later
            outbox.refused(exc)
            return
        except FAILURES as exc:
            self.link.failed(exc)
            return
        if holder is not None:
            if (refused := self._outboxes.pop(feed.name, None)) is not None:
                await refused.close()
            raise XVIZError(f"live feed {feed.name!r} already has a source, on replica {holder}")

    async def _forward(self, name: str, config_update: dict[str, Any]) -> None:
        """Send a viewer's ``config_update`` to the replica of the feed's source."""
        entry = Entry(b"reconfigure", self.link.id, data=orjson.dumps(config_update))
        try:
            await self.link.redis.xadd(control(name), entry.fields(), maxlen=CONTROL_ENTRIES)  # type: ignore[arg-type]
        except FAILURES as exc:
            logger.warning("live feed %r: cannot pass a reconfigure to its source: %s", name, exc)

    # -- polling ----------------------------------------------------------------

    async def _run(self) -> None:
        delay = self.interval
        while not self._closed:
            try:
                await self._poll()
            except FAILURES as exc:
                if self._closed:
                    return
                self.link.failed(exc)
                delay = min(2 * delay, self.backoff)
            else:
                delay = self.interval
            await asyncio.sleep(delay)

    async def _poll(self) -> None:
        loop = asyncio.get_running_loop()
        run_id = str((await self.link.redis.info("server"))["run_id"])
        if not self.link.up or run_id != self._run_id:
            # Back after an outage, or a broker that restarted empty: the owners, back within their
            # backoff, register again within a TTL.
            self._hold_until = loop.time() + self.ttl + self.backoff
        self._run_id = run_id
        self.link.succeeded()
        await self._renew()
        await self._follow(holding=loop.time() < self._hold_until)

    async def _renew(self) -> None:
        """Renew the registration of each feed this replica holds; forget those whose source left long ago."""
        now = asyncio.get_running_loop().time()
        for name, outbox in list(self._outboxes.items()):
            if outbox.left_at is not None and now - outbox.left_at > GRACE:
                del self._outboxes[name]
                await outbox.close()
            else:
                try:
                    await outbox.claim()
                except ResponseError as exc:  # the broker is full
                    outbox.refused(exc)

    async def _follow(self, holding: bool) -> None:
        """Mirror every feed another replica holds (readers start with viewers: :mod:`.mirror`), from its
        registration; end the mirrors of feeds no longer registered."""
        names = sorted(cast(set[bytes], await self.link.redis.smembers(FEEDS)))
        pipeline = self.link.redis.pipeline(transaction=False)
        for name in names:
            pipeline.hmget(registration(name.decode(errors="replace")), ["owner", "connected", "meta"])
        owners: dict[str, list[bytes | None]] = {}
        unregistered = []
        found: list[list[bytes | None]] = await pipeline.execute()
        for name, (owner, *registered) in zip(names, found):
            if owner is None:
                unregistered.append(name)
            elif owner != self.link.id:
                owners[name.decode(errors="replace")] = [owner, *registered]
        for feed, (holder, connected, meta) in owners.items():
            mirror = self._mirror(feed, cast(bytes, holder).decode(errors="replace"))
            if mirror is not None:
                mirror.registered(meta, connected)
        if holding:
            return
        for feed in [feed for feed in self._mirrors if feed not in owners]:
            await self._unmirror(feed)
        if unregistered:
            await self.link.redis.srem(FEEDS, *unregistered)

    def _mirror(self, name: str, owner: str) -> Mirror | None:
        """The mirror of the feed ``name`` that replica ``owner`` holds, made if new (``None`` if refused)."""
        mirror = self._mirrors.get(name)
        if mirror is not None:
            mirror.feed.origin = owner  # another replica took it over: its entries follow
            return mirror
        try:
            check_log_name(name)
        except XVIZError as exc:
            if name not in self._conflicts:
                logger.warning("broker %s: ignored a feed registered as %r: %s", self.link.url, name, exc)
                self._conflicts.add(name)
            return None
        feed = self.registry.get(name)
        if feed is not None and feed.origin is None and (feed.connected or name in self._outboxes):
            if (
                name not in self._conflicts
            ):  # this replica's source (or one within its grace period), or one claiming it
                logger.error(
                    "live feed %r has a source here and on replica %s: each replica serves its own", name, owner
                )
                self._conflicts.add(name)
            return None
        if feed is None:
            departed = self._departed.pop(name, None)
            feed = self.registry.feed(name) if departed is None else self.registry.add(departed)
        feed.origin = owner

        async def forward(config_update: dict[str, Any]) -> None:
            await self._forward(name, config_update)

        feed.on_reconfigure = forward
        mirror = self._mirrors[name] = Mirror(self.link, feed, self.workers, self._max_update_bytes)
        logger.info("live feed %r of replica %s: following it through the broker", name, owner)
        return mirror

    async def _unmirror(self, name: str) -> None:
        mirror = self._mirrors.pop(name)
        await mirror.close()
        feed = mirror.feed
        logger.warning("live feed %r: replica %s stopped renewing it; it is gone from this replica", name, feed.origin)
        if feed.connected:
            feed.disconnect()
        self.registry.drop(feed)
        self._conflicts.discard(name)
        self._departed[name] = feed
        if len(self._departed) > DEPARTED:
            del self._departed[next(iter(self._departed))]
