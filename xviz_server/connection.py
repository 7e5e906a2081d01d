"""The asyncio side of a session: carry out what :class:`~xviz_server.session.Session` decides.

One :class:`Connection` per WebSocket connection reads client messages,
feeds them to the session and runs the resulting events: sends, log
opening, a streaming task for ``transform_log`` and a task per point-in-time
query. A stream reads a few frames ahead of the socket and sends them as
fast as the client reads (``send`` waits while the socket's write buffer is
full), or at the log's rate times ``speed``.

Memory per connection is bounded: the frames read ahead (``read_ahead``
frames, usually shared with the cache) plus the socket's write buffer.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode

from .codec import Format, decode
from .exceptions import XVIZError
from .logfmt import log_event, redact_url
from .live import FeedEvent, LiveRegistry, LiveSource, LiveUpdate, Subscription, Variant
from .logs import Catalog, check_log_name
from .metrics import Metrics
from .session import (
    Cancel,
    ConfigureLive,
    Event,
    OpenLog,
    QueryInstant,
    Send,
    Session,
    StreamFrames,
    SubscribeLive,
)
from .settings import Settings

__all__ = ["Connection"]

logger = logging.getLogger("xviz_server.session")


class Connection:
    """One WebSocket connection running one XVIZ session."""

    def __init__(
        self,
        websocket: ServerConnection,
        catalog: Catalog,
        live: LiveRegistry,
        metrics: Metrics,
        settings: Settings,
    ) -> None:
        self.websocket = websocket
        self.catalog = catalog
        self.live = live
        self.metrics = metrics
        self.settings = settings
        url = urlsplit(websocket.request.path if websocket.request else "/")
        self.session = Session(
            path=unquote(url.path),
            query=dict(parse_qsl(url.query, keep_blank_values=True)),
            available=catalog.names(),
            live=live.names(),
        )
        self._subscription: Subscription | None = None
        self._live_config: ConfigureLive | None = None
        self._stream: asyncio.Task[None] | None = None
        self._stop_stream: asyncio.Event | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.frames_sent = 0
        self.bytes_sent = 0

    async def run(self) -> None:
        """Serve the session until the client goes away or the server shuts down."""
        started = time.monotonic()
        self.metrics.sessions.inc()
        self.metrics.sessions_open.inc()
        log_event(logger, "session start", remote=_remote(self.websocket), path=redact_url(self.websocket.request.path if self.websocket.request else "/"))
        try:
            await self._guarded("the connection", self.session.connect)
            async for message in self.websocket:
                await self._guarded("a message", self.session.receive, message)
        except ConnectionClosed:
            pass
        finally:
            if self._subscription is not None:
                self._subscription.close()
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            self.metrics.sessions_open.dec()
            code, reason = self.websocket.close_code, self.websocket.close_reason
            log_event(
                logger,
                "session end",
                remote=_remote(self.websocket),
                log=self.session.log.name if self.session.log else None,
                format=self.session.format.value,
                frames=self.frames_sent,
                bytes=self.bytes_sent,
                duration=round(time.monotonic() - started, 3),
                reason=f"{code} {reason}".strip() if code is not None else "connection lost",
            )

    async def _guarded(self, what: str, step: Any, *args: Any) -> None:
        """Run a session step and its events; a bug is reported to the client, not fatal."""
        try:
            await self._execute(step(*args))
        except ConnectionClosed:
            raise
        except Exception as exc:
            logger.exception("error handling %s from %s", what, _remote(self.websocket))
            await self._send(self.session.internal_error(what, exc))

    async def _execute(self, events: list[Event]) -> None:
        for event in events:
            if isinstance(event, Send):
                await self._send(event)
            elif isinstance(event, OpenLog):
                try:
                    log = await self.catalog.open(event.name)
                except XVIZError as exc:
                    await self._execute(self.session.log_failed(exc))
                else:
                    await self._execute(self.session.log_opened(log))
            elif isinstance(event, Cancel):
                if self._stop_stream is not None:
                    self._stop_stream.set()
            elif isinstance(event, StreamFrames):
                self._stop_stream = stop = asyncio.Event()
                self._stream = self._spawn(self._run_stream(event, stop, self._stream))
            elif isinstance(event, QueryInstant):
                self._spawn(self._run_query(event))
            elif isinstance(event, SubscribeLive):
                try:
                    if event.name is not None:
                        check_log_name(event.name)
                    feed = self.live.find(event.name)
                except XVIZError:
                    feed = None
                if feed is None:
                    await self._execute(self.session.live_failed(event.name))
                else:
                    self._start_live(feed)
            elif isinstance(event, ConfigureLive):
                self._live_config = event
                if self._subscription is not None:
                    self._subscription.decimate = event.decimate
                    if event.forward and not await self._subscription.feed.reconfigure(event.forward):
                        logger.info("live feed %r does not accept configuration", self._subscription.feed.name)

    def _spawn(self, coroutine: Any) -> asyncio.Task[None]:
        task = asyncio.ensure_future(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _send(self, event: Send) -> None:
        await self.websocket.send(event.data, text=event.text)
        if event.error is not None:
            self.metrics.errors.labels(event.error).inc()
            log_event(logger, "error sent", remote=_remote(self.websocket), kind=event.error, message=decode_message(event))

    async def _run_stream(self, request: StreamFrames, stop: asyncio.Event, previous: asyncio.Task[None] | None) -> None:
        if previous is not None:
            await asyncio.wait([previous])  # its done goes out before our first frame
        received = time.perf_counter()
        loop = asyncio.get_running_loop()
        clock_start = loop.time()
        numbers = request.frames.tolist()
        ahead: deque[asyncio.Future[bytes]] = deque()
        following = 0
        try:
            for position in range(len(numbers)):
                while len(ahead) < self.settings.read_ahead and following < len(numbers):
                    ahead.append(asyncio.ensure_future(request.log.frame(numbers[following], request.fmt, request.streams)))
                    following += 1
                loading = ahead.popleft()
                if request.speed is not None:
                    due = clock_start + (request.times[position] - request.times[0]) / request.speed
                    await _wait(stop, due - loop.time())
                if stop.is_set():
                    loading.cancel()
                    break
                try:
                    data = await loading
                except XVIZError as exc:
                    await self._send(self.session.frame_failed(request, exc))
                    continue
                await self._send_update(data, request.fmt)
                if position == 0:
                    self.metrics.first_frame_seconds.observe(time.perf_counter() - received)
            await self._send(request.done)
            self.metrics.request_seconds.labels("transform_log").observe(time.perf_counter() - received)
        except ConnectionClosed:
            pass
        except Exception as exc:
            logger.exception("error streaming transform_log %r", request.request_id)
            await self._send_quietly(self.session.internal_error(f"transform_log {request.request_id!r}", exc))
            await self._send_quietly(request.done)
        finally:
            for loading in ahead:
                loading.cancel()

    def _start_live(self, feed: LiveSource) -> None:
        if self._subscription is not None:
            self._subscription.close()
        config = self._live_config = self.session.live_config()
        self._subscription = subscription = feed.subscribe(self.settings.live_queue, config.decimate)
        self._spawn(self._run_live(subscription))
        self._spawn(self._watch_lag(subscription))

    async def _run_live(self, subscription: Subscription) -> None:
        """Send the feed's metadata and latest state, then every update as it comes."""
        feed = subscription.feed
        behind = False
        covered = -1  # the number of the last update in the state sent: queued ones up to it are skipped
        try:
            if feed.metadata is None:
                await self._send(self.session.live_notice(f"live feed {feed.name!r} has not started yet; waiting for it"))
            else:
                covered = await self._send_live_start(feed)
            while True:
                item = await subscription.next()
                dropped = subscription.take_drops()
                if dropped and not behind:
                    await self._send(self.session.live_notice(
                        f"live feed {feed.name!r}: this viewer is behind; {dropped} updates were dropped "
                        "(the oldest go first; viewers that stay behind are disconnected)"
                    ))
                behind = subscription.lagging_since is not None
                if isinstance(item, FeedEvent):
                    if item.kind == "metadata":
                        covered = await self._send_live_start(feed)
                    else:
                        await self._send(self.session.live_notice(
                            f"live feed {feed.name!r} went away; this session stays open and resumes when it comes back"
                        ))
                    continue
                if item.number > covered:
                    await self._send_live_update(item)
        except ConnectionClosed:
            pass
        finally:
            subscription.close()

    async def _send_live_start(self, feed: LiveSource) -> int:
        """Send the feed's metadata and latest state; the number of the last update in that state (-1: none)."""
        config = self._live_config or self.session.live_config()
        metadata = feed.metadata_message(config.fmt)
        if metadata is not None:
            await self.websocket.send(metadata, text=config.fmt is Format.JSON)
        state = feed.state()
        if state is None:
            return -1
        await self._send_live_update(state)
        return state.number

    async def _send_live_update(self, update: LiveUpdate) -> None:
        config = self._live_config or self.session.live_config()
        variant = Variant(config.fmt, config.streams, config.max_points)
        await self._send_update(await update.encoded(variant, self.live.workers), config.fmt)

    async def _watch_lag(self, subscription: Subscription) -> None:
        """Disconnect a viewer that keeps dropping updates for ``live_lag_timeout``."""
        limit = self.settings.live_lag_timeout
        while True:
            await asyncio.sleep(min(1.0, limit / 4))
            since = subscription.lagging_since
            if since is not None and time.monotonic() - since > limit:
                logger.warning("live viewer %s too slow on %r: disconnecting", _remote(self.websocket), subscription.feed.name)
                await self.websocket.close(
                    CloseCode.TRY_AGAIN_LATER, f"too slow: dropped live updates for over {limit:g} s"
                )
                return

    async def _run_query(self, request: QueryInstant) -> None:
        received = time.perf_counter()
        try:
            try:
                data = await request.log.complete_state(request.instant, request.fmt, request.streams, self.settings.lookback)
            except XVIZError as exc:
                await self._send(self.session.query_failed(request, exc))
                return
            await self._send_update(data, request.fmt)
            self.metrics.request_seconds.labels("transform_point_in_time").observe(time.perf_counter() - received)
        except ConnectionClosed:
            pass
        except Exception as exc:
            logger.exception("error answering transform_point_in_time %r", request.request_id)
            await self._send_quietly(self.session.internal_error(f"transform_point_in_time {request.request_id!r}", exc))

    async def _send_update(self, data: bytes, fmt: Format) -> None:
        """Send a state update and count it."""
        await self.websocket.send(data, text=fmt is Format.JSON)
        self.frames_sent += 1
        self.bytes_sent += len(data)
        self.metrics.frames_sent.labels(fmt.value).inc()
        self.metrics.bytes_sent.labels(fmt.value).inc(len(data))

    async def _send_quietly(self, event: Send) -> None:
        """Send, unless the connection is gone."""
        try:
            await self._send(event)
        except ConnectionClosed:
            pass


async def _wait(stop: asyncio.Event, seconds: float) -> None:
    """Sleep for ``seconds``, or less if ``stop`` is set meanwhile."""
    if seconds > 0:
        try:
            await asyncio.wait_for(stop.wait(), seconds)
        except asyncio.TimeoutError:
            pass


def decode_message(event: Send) -> str:
    """The text of an ``xviz/error`` being sent, for the log."""
    try:
        return str(decode(event.data)["data"]["message"])
    except Exception:  # the log line must not fail over a message it only describes
        return "?"


def _remote(websocket: ServerConnection) -> str:
    address = websocket.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"
