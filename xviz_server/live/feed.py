"""Live feeds: updates pushed by a running system, fanned out to viewers.

A :class:`LiveFeed` is one named feed. Whatever feeds it (a program in the
same process, a vehicle over the ingest WebSocket, a log replayed in real
time) calls :meth:`LiveFeed.set_metadata` and :meth:`LiveFeed.publish`.
Each viewer holds a :class:`Subscription`: a bounded queue that drops its
oldest updates when the viewer falls behind, so that neither the source nor
the other viewers ever wait for it. A viewer that keeps up takes each update
as it is published instead, without a queue (the ``deliver`` callback given
to :meth:`LiveFeed.subscribe`):
one publish then writes the update to every such viewer's connection in one
pass, as ``websockets.broadcast`` does.

An update is decoded once and encoded once per :class:`Variant` (format,
stream filter, point budget, level of detail) that some viewer asked for; the bytes are
shared. The feed also keeps the latest complete state, so that a viewer
who joins late draws at once.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable, Hashable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from ..codec import Format, decode, detect_format, encode
from ..events import LiveFacts, Variant
from ..exceptions import XVIZError
from ..frames import placement, render, render_message
from ..layout import check_log_name
from ..levels import FULL, Level
from ..messages import XVIZ_VERSION, envelope, unwrap
from ..state import COMPLETE_TYPES, complete_state
from ..work import Workers

__all__ = ["LiveUpdate", "Subscription", "FeedEvent", "LiveFeed", "LiveRegistry", "watch_lag"]

logger = logging.getLogger(__name__)

#: Seconds a feed's name and latest state are kept for a source that left.
GRACE = 30.0


class LiveUpdate:
    """One state update of a feed, decoded once and encoded once per variant."""

    def __init__(self, number: int, message: dict[str, Any], original: bytes | None = None) -> None:
        self.number = number
        self.message = message
        self._encodings: dict[Variant, asyncio.Future[bytes]] = {}
        self._derived: dict[Hashable, asyncio.Future[bytes]] = {}
        #: What each derived product was asked with: (name, job, args, level), by its key.
        self.recipes: dict[Hashable, tuple[Hashable, Callable[..., bytes], tuple[Any, ...], Level]] = {}
        if original is not None:
            future = asyncio.get_running_loop().create_future()
            future.set_result(original)
            self._encodings[Variant(detect_format(original))] = future

    def ready(self, variant: Variant) -> bytes | None:
        """The bytes of this update for ``variant`` if they are made already, else ``None``."""
        future = self._encodings.get(variant)
        return future.result() if future is not None and future.done() and not future.exception() else None

    async def encoded(self, variant: Variant, workers: Workers) -> bytes:
        """The bytes of this update for ``variant``; the first viewer to ask encodes them."""
        return await asyncio.shield(self.prepare(variant, workers))

    def prepare(self, variant: Variant, workers: Workers) -> asyncio.Future[bytes]:
        """Start making the bytes of this update for ``variant``, unless made or being made; their future."""
        future = self._encodings.get(variant)
        if future is None:
            future = asyncio.ensure_future(self._encode(variant, workers))
            future.add_done_callback(lambda done: done.cancelled() or done.exception())  # a viewer that asks is told
            self._encodings[variant] = future
        return future

    def derived(
        self, name: Hashable, job: Callable[..., bytes], *args: Any, workers: Workers, level: Level = FULL
    ) -> asyncio.Future[bytes]:
        """This update made into something else by ``job(glb, *args)`` (``glb``: its GLB bytes at ``level``, the
        encoding XVIZ viewers at that level share), made once.

        ``name`` tells what ``job`` makes (of the update at ``level``): the
        first viewer to ask for it starts the job, the others get its future.
        ``job`` runs where a frame job of that size runs (:func:`~xviz_server.frames.placement`).
        """
        key = (name, level.name)
        future = self._derived.get(key)
        if future is None:
            future = asyncio.ensure_future(self._derive(job, args, workers, level))
            self.recipes[key] = (name, job, args, level)
            future.add_done_callback(lambda done: done.cancelled() or done.exception())  # a viewer that asks is told
            self._derived[key] = future
        return future

    @property
    def variants(self) -> list[Variant]:
        """The variants asked for so far."""
        return list(self._encodings)

    async def _derive(self, job: Callable[..., bytes], args: tuple[Any, ...], workers: Workers, level: Level) -> bytes:
        glb = await self.encoded(Variant(Format.BINARY, level=level), workers)
        return await workers.run(placement(len(glb), Format.BINARY), job, glb, *args)

    async def _encode(self, variant: Variant, workers: Workers) -> bytes:
        if variant.fmt is Format.BINARY and variant.level is FULL:
            return await workers.io(render_message, self.message, variant.fmt, variant.streams, variant.max_points)
        # JSON and levels of detail hold the GIL for long: a worker process makes them
        # from GLB bytes, which pickle cheaply where decoded messages (views into a frame) do not.
        glb = await self.encoded(Variant(Format.BINARY), workers)
        return await workers.cpu(render, glb, variant.fmt, variant.streams, variant.max_points, variant.level)


@dataclass(frozen=True)
class FeedEvent:
    """Something happened to the feed itself, in a subscription's queue."""

    kind: str  # "metadata" (new metadata) or "gone" (the source went away)


class Subscription:
    """A viewer's bounded queue of a feed's updates.

    When full, the oldest update is dropped; :attr:`dropped` counts them
    until the viewer is told (:meth:`take_drops`). :attr:`lagging_since` is
    when the current run of drops began, for disconnecting a viewer that
    stays hopelessly behind.

    ``deliver``, when given, is offered each update while the queue is
    empty and nothing was dropped; it returns whether it took the update
    (sent it at once), else the update is queued as usual.
    """

    def __init__(
        self, feed: LiveFeed, size: int, decimate: int = 1, deliver: Callable[[LiveUpdate], bool] | None = None
    ) -> None:
        self.feed = feed
        self.decimate = decimate
        self._queue: deque[LiveUpdate | FeedEvent] = deque()
        self._size = size
        self._ready = asyncio.Event()
        self._seen = 0
        self.dropped = 0
        self.lagging_since: float | None = None
        self._deliver = deliver

    def offer(self, item: LiveUpdate | FeedEvent) -> None:
        """Queue an update (every ``decimate``-th) or a feed event; never waits."""
        if isinstance(item, LiveUpdate):
            self._seen += 1
            if (self._seen - 1) % self.decimate:
                return
            if not self._queue and not self.dropped and self._deliver is not None and self._deliver(item):
                return
            if self.queued >= self._size:
                oldest = next(i for i in self._queue if isinstance(i, LiveUpdate))
                self._queue.remove(oldest)
                self.dropped += 1
                self.feed.registry.on_drop()
                if self.lagging_since is None:
                    self.lagging_since = time.monotonic()
        self._queue.append(item)
        self._ready.set()

    async def next(self) -> LiveUpdate | FeedEvent:
        """The next update or feed event, waiting for one."""
        while not self._queue:
            self._ready.clear()
            await self._ready.wait()
        item = self._queue.popleft()
        if not self._queue:
            self.lagging_since = None  # caught up
        return item

    @property
    def queued(self) -> int:
        """Updates waiting in the queue."""
        return sum(isinstance(item, LiveUpdate) for item in self._queue)

    @property
    def offered(self) -> int:
        """Updates the feed offered this subscription so far, with those that decimation skipped."""
        return self._seen

    def take_drops(self) -> int:
        """Updates dropped since the last call."""
        dropped, self.dropped = self.dropped, 0
        return dropped

    def close(self) -> None:
        self.feed.unsubscribe(self)


class LiveFeed:
    """A named live feed.

    Feed it with :meth:`set_metadata` then :meth:`publish`; call
    :meth:`disconnect` when the system feeding it stops (viewers stay and
    resume when it comes back). ``on_reconfigure``, when set, receives the
    ``config_update`` of every ``xviz/reconfigure`` a viewer sends: the
    source then "accepts configuration".
    """

    def __init__(self, name: str, registry: LiveRegistry) -> None:
        self.name = name
        self.registry = registry
        self.metadata: dict[str, Any] | None = None
        self.on_reconfigure: Callable[[dict[str, Any]], Awaitable[None]] | None = None
        self.connected = False
        #: Who feeds it (a source's address), kept for :data:`GRACE` seconds after the source leaves.
        self.owner: str | None = None
        #: The replica whose source feeds it, when this feed mirrors one held elsewhere (see :mod:`.broker`).
        self.origin: str | None = None
        #: Called with the number of viewers after each one joins or leaves (a mirror reads while there are any).
        self.on_viewers: Callable[[int], None] | None = None
        self._left_at = -math.inf
        self._metadata_messages: dict[Format, bytes] = {}
        self._state: dict[str, Any] | None = None
        self._state_number = -1  # number of the latest update in _state
        self._latest: LiveUpdate | None = None  # the latest update published
        self._subscribers: set[Subscription] = set()
        self._numbers = itertools.count()

    # -- the source side ------------------------------------------------

    def set_metadata(self, metadata: Mapping[str, Any]) -> None:
        """Set the feed's metadata (the data of ``xviz/metadata``); viewers get it if it changed."""
        data = dict(metadata)
        data.setdefault("version", XVIZ_VERSION)
        self.connected = True
        if data == self.metadata:
            return
        self.metadata = data
        self._metadata_messages = {fmt: encode(envelope("metadata", data), fmt) for fmt in Format}
        self._state = None
        for subscriber in self._subscribers:
            subscriber.offer(FeedEvent("metadata"))
        self.registry.feed_event(self, FeedEvent("metadata"))

    async def publish(self, frame: Mapping[str, Any] | bytes) -> LiveUpdate:
        """Send a state update to every viewer.

        ``frame`` is the data of an ``xviz/state_update`` (as the builder makes
        it), an envelope, or an encoded message (GLB or JSON bytes, kept as
        they are for viewers of that format). Raises
        :class:`~xviz_server.exceptions.XVIZError` if it is not a state update
        or no metadata was set.
        """
        if self.metadata is None:
            raise XVIZError(f"live feed {self.name!r}: set the metadata before publishing updates")
        original = bytes(frame) if isinstance(frame, (bytes, bytearray, memoryview)) else None
        if original is not None:
            decoded = (
                decode(original)
                if detect_format(original) is Format.BINARY
                else await self.registry.workers.cpu(decode, original)
            )
        else:
            decoded = frame
        kind, data = unwrap(decoded)
        if kind != "xviz/state_update" or not isinstance(data, dict) or not data.get("updates"):
            raise XVIZError(f"live feed {self.name!r}: expected an xviz/state_update with updates, got {kind!r}")
        data.setdefault("update_type", "INCREMENTAL")
        message = envelope("state_update", data)
        update = LiveUpdate(next(self._numbers), message, original)
        if original is None and self._subscribers:  # GLB, the live default, made once before the viewers ask
            await update.encoded(Variant(Format.BINARY), self.registry.workers)
        self._remember(update)
        # the levels of detail viewers took of the previous update: made now, before they ask, beside the others
        for variant in self._latest.variants if self._latest is not None and self._subscribers else ():
            if variant.level is not FULL:
                update.prepare(variant, self.registry.workers)
        for name, job, args, level in (
            self._latest.recipes.values() if self._latest is not None and self._subscribers else ()
        ):
            if level is not FULL:  # and what Foxglove clients made of those levels
                update.derived(name, job, *args, workers=self.registry.workers, level=level)
        self._latest = update
        for listener in self.registry.listeners:  # first: the broker's write then goes on beside the fan-out
            listener(self, update)
        for subscriber in self._subscribers:
            subscriber.offer(update)
        return update

    def disconnect(self) -> None:
        """The system feeding this feed went away; viewers are told and wait for it.

        Its latest state is kept for :data:`GRACE` seconds (a source that
        comes back goes on where it was), then freed.
        """
        self.connected = False
        self._left_at = time.monotonic()
        for subscriber in self._subscribers:
            subscriber.offer(FeedEvent("gone"))
        self.registry.feed_event(self, FeedEvent("gone"))
        asyncio.get_running_loop().call_later(GRACE, self._forget, self._left_at)
        if self.metadata is None:  # it never started: nothing to keep
            self.registry.drop(self)

    def claim(self, source: str) -> None:
        """Let ``source`` feed this feed; raises :class:`~xviz_server.exceptions.XVIZError` if it may not.

        A feed has one source at a time, and the name stays its previous
        source's for :data:`GRACE` seconds after that one left. A different
        source taking over starts afresh: its viewers get its metadata as new.
        """
        if self.origin is not None:
            raise XVIZError(f"live feed {self.name!r} already has a source, on replica {self.origin}")
        if self.connected:
            raise XVIZError(f"live feed {self.name!r} already has a source")
        if self.owner not in (None, source):
            if time.monotonic() - self._left_at < GRACE:
                raise XVIZError(
                    f"live feed {self.name!r} is kept for its previous source for {GRACE:g} s after it left; "
                    "use another name or try again later"
                )
            logger.warning("live feed %r taken over by %s (its source was %s)", self.name, source, self.owner)
            self.metadata, self._state = None, None
        self.owner = source

    def skipped(self, count: int) -> None:
        """``count`` updates of the source never reached this feed (lost between replicas): each viewer is told
        of them as of updates dropped because it fell behind."""
        for subscriber in self._subscribers:
            subscriber.dropped += count

    def _forget(self, left_at: float) -> None:
        if not self.connected and self._left_at == left_at:
            self._state = None

    # -- the viewer side --------------------------------------------------

    def metadata_message(self, fmt: Format) -> bytes | None:
        """The metadata, encoded, or ``None`` before the source set any."""
        return self._metadata_messages.get(fmt)

    def state(self) -> LiveUpdate | None:
        """The latest complete state, as an update a late viewer can draw at once.

        Its number is that of the latest update it includes: a viewer that
        subscribed before taking it skips the queued updates up to that one.
        """
        return None if self._state is None else LiveUpdate(self._state_number, self._state)

    @property
    def viewers(self) -> int:
        """How many viewers follow the feed."""
        return len(self._subscribers)

    def subscribe(
        self, size: int, decimate: int = 1, deliver: Callable[[LiveUpdate], bool] | None = None
    ) -> Subscription:
        """A new viewer's :class:`Subscription` (``deliver`` as described there)."""
        subscription = Subscription(self, size, decimate, deliver)
        self._subscribers.add(subscription)
        if self.on_viewers is not None:
            self.on_viewers(len(self._subscribers))
        return subscription

    def unsubscribe(self, subscription: Subscription) -> None:
        if subscription in self._subscribers:
            self._subscribers.discard(subscription)
            if self.on_viewers is not None:
                self.on_viewers(len(self._subscribers))

    def forget_state(self) -> None:
        """Forget the latest complete state (a mirror that stops reading the feed: it would go stale)."""
        self._state = None

    async def reconfigure(self, config_update: dict[str, Any]) -> bool:
        """Pass a viewer's configuration change to the source; whether it accepts any."""
        if self.on_reconfigure is None:
            return False
        await self.on_reconfigure(config_update)
        return True

    def _remember(self, update: LiveUpdate) -> None:
        message = update.message
        if str(message["data"].get("update_type", "")).upper() in COMPLETE_TYPES or self._state is None:
            merged = [message]
        else:
            merged = [message, self._state]
        self._state, _ = complete_state(merged)
        self._state_number = update.number


@dataclass
class _Waited:
    """A feed name viewers wait for, and how many."""

    future: asyncio.Future[LiveFeed]
    viewers: int = 0


class LiveRegistry:
    """Every live feed of a server, by name.

    Feeds are created by their sources (:meth:`feed`), never by viewers: a
    viewer asking for a feed that does not exist yet waits for it
    (:meth:`wait_for`), and the names waited for are bounded in number.
    """

    #: Most feed names that viewers may wait for at once.
    MAX_WAITED = 1024

    def __init__(self, workers: Workers, on_drop: Callable[[], None] = lambda: None) -> None:
        self.workers = workers
        self._feeds: dict[str, LiveFeed] = {}
        #: Called for every update dropped for a viewer that fell behind.
        self.on_drop = on_drop
        #: Called with every feed and update published, synchronously (for recording).
        self.listeners: list[Callable[[LiveFeed, LiveUpdate], None]] = []
        #: Called with every feed whose metadata changed or whose source left, synchronously (for the broker).
        self.watchers: list[Callable[[LiveFeed, FeedEvent], None]] = []
        #: Awaited with every feed a source claims here; each may refuse it (the broker: another replica holds it).
        self.claims: list[Callable[[LiveFeed], Awaitable[None]]] = []
        self._waited: dict[str, _Waited] = {}

    def __iter__(self) -> Iterator[LiveFeed]:
        return iter(self._feeds.values())

    def names(self) -> list[str]:
        return sorted(self._feeds)

    def feed(self, name: str) -> LiveFeed:
        """The feed called ``name``, created if new (for sources)."""
        source = self._feeds.get(name)
        return source if source is not None else self.add(LiveFeed(name, self))

    def add(self, feed: LiveFeed) -> LiveFeed:
        """Serve ``feed`` under its name: a new feed, or one that :meth:`drop` forgot and whose viewers stayed."""
        self._feeds[feed.name] = feed
        logger.info("live feed %r created", feed.name)
        waited = self._waited.pop(feed.name, None)
        if waited is not None:
            waited.future.set_result(feed)
        return feed

    def feed_event(self, feed: LiveFeed, event: FeedEvent) -> None:
        """Tell the :attr:`watchers` what happened to ``feed``."""
        for watcher in self.watchers:
            watcher(feed, event)

    async def claim(self, feed: LiveFeed, source: str) -> None:
        """Let ``source`` feed ``feed``, as :meth:`LiveFeed.claim`, if every one of :attr:`claims` agrees."""
        previous = feed.owner
        feed.claim(source)
        try:
            for check in self.claims:
                await check(feed)
        except XVIZError:
            feed.owner = previous
            raise

    def drop(self, feed: LiveFeed) -> None:
        """Forget ``feed``: one that never started and has no source, or the mirror of a replica that went away."""
        if self._feeds.get(feed.name) is feed:
            del self._feeds[feed.name]

    def get(self, name: str) -> LiveFeed | None:
        """The feed called ``name``, if a source created it."""
        return self._feeds.get(name)

    def facts(self, name: str | None) -> LiveFacts:
        """What is known now of the feed ``name`` and of the running feeds, for a viewer's session to decide on."""
        named = self._feeds.get(name) if name is not None else None
        return LiveFacts(
            allowed=name is None or _allowed(name),
            exists=named is not None,
            started=named is not None and named.metadata is not None,
            running=tuple(feed.name for feed in self._feeds.values() if feed.connected and feed.metadata is not None),
        )

    async def wait_for(self, name: str) -> LiveFeed:
        """The feed ``name`` once a source creates it.

        Raises :class:`~xviz_server.exceptions.XVIZError` when viewers already
        wait for :attr:`MAX_WAITED` other names. A name nobody waits for any
        more is forgotten.
        """
        feed = self._feeds.get(name)
        if feed is not None:
            return feed
        waited = self._waited.get(name)
        if waited is None:
            if len(self._waited) >= self.MAX_WAITED:
                raise XVIZError(
                    f"too many live feeds are waited for ({self.MAX_WAITED}); try again when one has started"
                )
            waited = self._waited[name] = _Waited(asyncio.get_running_loop().create_future())
        waited.viewers += 1
        try:
            return await asyncio.shield(waited.future)
        finally:
            waited.viewers -= 1
            if not waited.viewers and self._waited.get(name) is waited:
                del self._waited[name]


async def watch_lag(
    subscription: Subscription,
    transport: asyncio.BaseTransport,
    timeout: float,
    report: Callable[[float], Awaitable[None]],
) -> None:
    """Report how long the viewer of ``subscription`` has been dropping updates, while it drops them.

    ``report`` is awaited with the seconds, every quarter of ``timeout`` (a
    second at most), until ``transport`` closes.
    """
    interval = min(1.0, timeout / 4)
    while not transport.is_closing():
        await asyncio.sleep(interval)
        since = subscription.lagging_since
        if since is not None:
            await report(time.monotonic() - since)


def _allowed(name: str) -> bool:
    """Whether a feed may be called ``name`` (as a log may, see :func:`~xviz_server.layout.check_log_name`)."""
    try:
        check_log_name(name)
    except XVIZError:
        return False
    return True
