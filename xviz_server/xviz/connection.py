"""The asyncio side of a session: carry out what :class:`~xviz_server.xviz.session.Session` decides.

One :class:`Connection` per WebSocket connection reads client messages,
feeds them to the session and carries out the events it answers with:
sending, opening logs, streaming frames, answering point-in-time queries,
following a live feed. It makes no protocol decision of its own; it reports
back to the session what happened (a stream ended, a frame failed, a live
update came) and carries out the answer.

A stream reads ``read_ahead`` frames ahead of the socket (or as far as the
log's store says, see :mod:`xviz_server.readahead`) and sends them as
fast as the client reads (``send`` waits while the socket's write buffer is
full), or at the log's rate times ``speed``. Memory per connection is
bounded: the frames read ahead (usually shared with the cache), a live
subscription's bounded queue, and the socket's write buffer.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from websockets.exceptions import ConnectionClosed

from ..codec import Format
from ..detail import Sample
from ..events import SubscribeLive
from ..exceptions import XVIZError
from ..face import FaceConnection
from ..framing import ready_to_write, write_message
from ..levels import LEVELS, Level
from ..linkwatch import is_loopback, sample_link
from ..live import FeedEvent, LiveUpdate, Subscription
from ..logfmt import peer
from ..logs import Log
from ..readahead import ReadAhead, Window
from .session import (
    CancelStream,
    ConfigureLive,
    DetailChanged,
    QueryInstant,
    SendLiveMetadata,
    SendLiveUpdate,
    Session,
    SkipToState,
    StreamFrames,
)

__all__ = ["Connection"]

logger = logging.getLogger("xviz_server.session")


class Connection(FaceConnection[Session]):
    """One WebSocket connection running one XVIZ session."""

    def _make_session(self, path: str, query: dict[str, str]) -> Session:
        self._logs: dict[str, Log] = {}
        self._stream: tuple[StreamFrames, asyncio.Event] | None = None
        self._subscription: Subscription | None = None
        self._held: LiveUpdate | None = None  # the live update the session is deciding about
        self._live_idle = False  # the live task waits for the next update: the feed may hand it over at once
        self._measuring = False  # the link is sampled (see _follow_link)
        self.frames_sent = 0
        self.bytes_sent = 0
        return Session(
            path=path,
            query=query,
            available=self.shelf.available(),
            live=self.live.names(),
            lag_timeout=self.settings.live_lag_timeout,
            detail=self.settings.detail == "auto",
            local=is_loopback(self.websocket),
            repeated=self.repeated,
        )

    def _opened(self) -> None:
        self.metrics.sessions_by_detail.labels(self.session.chooser.level.name).inc()
        self._follow_link()

    def _closing(self) -> None:
        if self._subscription is not None:
            self._subscription.close()

    def _closed(self) -> None:
        self.metrics.sessions_by_detail.labels(self.session.chooser.level.name).dec()

    def _end_fields(self) -> dict[str, Any]:
        log = self.session.log.name if self.session.log else None
        return {"log": log, "format": self.session.format.value, "frames": self.frames_sent, "bytes": self.bytes_sent}

    # -- carrying events out ----------------------------------------------

    async def _step(self, what: str, step: Callable[..., Sequence[object]], *args: Any) -> None:
        await super()._step(what, step, *args)
        self._follow_link()

    async def _carry_out(self, event: object) -> None:
        if isinstance(event, SendLiveUpdate):
            update = self._held
            assert update is not None and update.number == event.number
            assert self._subscription is not None
            data = await update.encoded(event.variant, self.live.workers)
            self.session.update_made(event.variant.level, len(data))
            await self._send_update(data, event.variant.fmt)
        elif isinstance(event, SkipToState):
            assert self._subscription is not None
            await self._execute(self.session.live_skipped(self._hold(self._subscription.feed.state())))
        elif isinstance(event, SendLiveMetadata):
            assert self._subscription is not None
            metadata = self._subscription.feed.metadata_message(event.fmt)
            if metadata is not None:
                await self._write(metadata, event.fmt is Format.JSON)
        elif isinstance(event, StreamFrames):
            stop = asyncio.Event()
            self._stream = (event, stop)
            self._spawn(f"transform_log {event.request_id!r}", self._run_stream(event, stop))
        elif isinstance(event, CancelStream):
            if self._stream is not None and self._stream[0].request_id == event.request_id:
                self._stream[1].set()
        elif isinstance(event, QueryInstant):
            self._spawn(f"transform_point_in_time {event.request_id!r}", self._run_query(event))
        elif isinstance(event, SubscribeLive):
            self._spawn("the live feed", self._run_live(event), fatal=True)
        elif isinstance(event, ConfigureLive):
            await self._configure_live(event)
        elif isinstance(event, DetailChanged):
            self._detail_changed(event)

    async def _send_update(self, data: bytes, fmt: Format) -> None:
        """Send a state update and count it."""
        await self._write(data, fmt is Format.JSON)
        self._count_update(data, fmt)

    def _count_update(self, data: bytes, fmt: Format) -> None:
        self.frames_sent += 1
        self.bytes_sent += len(data)
        self.metrics.update_sent(fmt.value, len(data))

    # -- recorded logs ------------------------------------------------------

    async def _log_opened(self, log: Log) -> None:
        self._logs[log.name] = log
        await self._execute(self.session.log_opened(log))

    async def _run_stream(self, request: StreamFrames, stop: asyncio.Event) -> None:
        received = time.perf_counter()
        log = self._logs[request.log]
        loop = asyncio.get_running_loop()
        clock_start = loop.time()
        numbers = request.frames.tolist()
        limits = log.read_ahead or ReadAhead(self.settings.read_ahead)

        made_at: dict[int, Level] = {}

        async def load(number: int, level: Level | None = None) -> bytes:
            level = level or self.session.level  # the level when the frame is read ahead
            data = await log.frame(number, request.fmt, request.streams, level)
            self.session.update_made(level, len(data))
            made_at[number] = level
            return data

        ahead = Window(numbers, load, limits, log.stored_size)
        try:
            for position in range(len(numbers)):
                loading = ahead.next()
                if request.speed is not None:
                    due = clock_start + (request.times[position] - request.times[0]) / request.speed
                    await _wait(stop, due - loop.time())
                if stop.is_set():
                    loading.cancel()
                    break
                try:
                    data = await loading
                    if LEVELS.index(made_at[numbers[position]]) < LEVELS.index(level := self.session.level):
                        data = await load(numbers[position], level)  # read ahead before the level went down
                except XVIZError as exc:
                    await self._execute(self.session.frame_failed(request.request_id, exc))
                    continue
                await self._send_update(data, request.fmt)
                if position == 0:
                    self.metrics.first_frame_seconds.observe(time.perf_counter() - received)
            self.metrics.request_seconds.labels("transform_log").observe(time.perf_counter() - received)
        except ConnectionClosed:
            raise
        except Exception as exc:  # still ends with its done, and the next request starts
            await self._failed(f"transform_log {request.request_id!r}", exc)
        finally:
            ahead.cancel()
        self._stream = None
        await self._step("the end of a stream", self.session.stream_ended, request.request_id)

    async def _run_query(self, request: QueryInstant) -> None:
        received = time.perf_counter()
        log = self._logs[request.log]
        try:
            data = await log.complete_state(request.instant, request.fmt, request.streams, self.settings.lookback)
        except XVIZError as exc:
            await self._execute(self.session.query_failed(request.request_id, exc))
            return
        await self._send_update(data, request.fmt)
        self.metrics.request_seconds.labels("transform_point_in_time").observe(time.perf_counter() - received)

    # -- live feeds ---------------------------------------------------------

    async def _run_live(self, event: SubscribeLive) -> None:
        """Follow a feed (once a source creates it): tell the session what it does, send what the session says."""
        asked = self.session.start.log
        if asked is not None and asked != event.name:
            logger.info("live session asked for %r; serving the only live feed %r", asked, event.name)
        subscribed = await self._subscribe(event.name, decimate=self.session.decimate, deliver=self._deliver)
        if subscribed is None:
            return
        feed, subscription = subscribed
        self._subscription = subscription
        state = self._hold(feed.state())
        await self._execute(self.session.live_joined(feed.name, state, feed.metadata is not None))
        while True:
            self._live_idle = True
            try:
                item = await subscription.next()
            finally:
                self._live_idle = False
            if isinstance(item, FeedEvent):
                if item.kind == "metadata":
                    await self._execute(self.session.live_started(self._hold(feed.state())))
                else:
                    await self._execute(self.session.live_gone())
                continue
            number = self._hold(item)
            assert number is not None
            behind = subscription.lagging_since is not None
            await self._execute(
                self.session.live_update(number, subscription.take_drops(), behind, subscription.queued)
            )

    def _deliver(self, update: LiveUpdate) -> bool:
        """Send ``update`` now, from the feed's publish, if nothing stands in the way; whether it was sent.

        Nothing does when the live task waits for the next update (so that
        every message before this one has been written), the connection is
        ready to write (:func:`~xviz_server.framing.ready_to_write`), and the
        update's bytes for this viewer are made. The session decides as for
        a queued update. Otherwise the update is queued and the live task
        sends it, waiting for the buffer to drain like any other send.
        """
        websocket = self.websocket
        if not self._live_idle or not ready_to_write(websocket):
            return False
        variant = self.session.variant
        data = update.ready(variant)
        if data is None:
            return False
        events = self.session.live_update(update.number, 0, False)
        if not all(isinstance(event, SendLiveUpdate) for event in events):
            return False  # the live task carries out anything else (asking the session again gives the same answer)
        for _ in events:
            try:
                write_message(websocket, data, text=variant.fmt is Format.JSON)
            except Exception as exc:  # the connection broke: its reader ends the session
                logger.debug("live update to %s not sent: %s", peer(websocket), exc)
                return True
            self.messages_sent += 1
            self.bytes_written += len(data)
            self.session.update_made(variant.level, len(data))
            self._count_update(data, variant.fmt)
        return True

    def _hold(self, update: LiveUpdate | None) -> int | None:
        """Keep ``update`` at hand while the session decides about it; its number."""
        if update is None:
            return None
        self._held = update
        return update.number

    async def _configure_live(self, event: ConfigureLive) -> None:
        if (subscription := self._subscription) is not None:
            subscription.decimate = event.decimate
            if event.forward and not await subscription.feed.reconfigure(event.forward):
                logger.info("live feed %r does not accept configuration", subscription.feed.name)

    # -- the level of detail --------------------------------------------------

    def _follow_link(self) -> None:
        """Start sampling the connection's delivery once the session's level depends on it."""
        if not self._measuring and self.session.chooser.measures:
            self._measuring = True
            self._spawn("measuring the link", self._measure())

    async def _measure(self) -> None:
        """Sample the connection's delivery for the session, which chooses the level of detail from it, while
        the level depends on it."""
        try:
            await sample_link(
                self.websocket.transport,
                lambda: self.bytes_written,
                self._sampled,
                lambda: self.session.chooser.measures,
            )
        finally:
            self._measuring = False

    async def _sampled(self, sample: Sample) -> None:
        offered = None if self._subscription is None else self._subscription.offered
        await self._execute(
            self.session.link_sampled(sample.time, sample.written, sample.backlog, sample.reader, offered, sample.busy)
        )

    def _detail_changed(self, event: DetailChanged) -> None:
        self.metrics.sessions_by_detail.labels(event.previous.name).dec()
        self.metrics.sessions_by_detail.labels(event.level.name).inc()
        self._log_detail_changed(event)


async def _wait(stop: asyncio.Event, seconds: float) -> None:
    """Sleep for ``seconds``, or less if ``stop`` is set meanwhile."""
    if seconds > 0:
        try:
            await asyncio.wait_for(stop.wait(), seconds)
        except asyncio.TimeoutError:
            pass
