"""What both protocol faces' connections share: one way to run a session, carry out its events and fail.

A connection runs one sans-I/O session (the XVIZ :class:`~xviz_server.xviz.session.Session`
or the Foxglove :class:`~xviz_server.foxglove.session.FoxgloveSession`) on
one WebSocket: it feeds the session what happens and carries out the events
it answers with. :class:`FaceConnection` does for both faces what does not
depend on the protocol: it parses the request target, keeps the session's
books (metrics, the ``session start`` and ``session end`` log lines), carries
out the shared events (:mod:`xviz_server.events`: send, close, open a log,
look up a live feed) and subscribes to a feed. Each face's connection carries
out its own events (:meth:`FaceConnection._carry_out`).

One failure policy: an unexpected error while the session handles an input,
or in a task beside it (a stream, a player, a live feed), is logged with its
traceback and reported to the client as the session words it
(``internal_error``); the session goes on. A task that cannot go on without
what failed (following a live feed) closes the connection with 1011 and a
reason. No task ends silently.

One slow-client policy: whatever a connection writes waits while its write
buffer is above the high-water mark (``send``), so each writer (the reader
answering the client's messages, a stream or player, a live feed) has at
most one message beyond it; a connection whose buffer does not shrink for
``idle_timeout`` seconds is aborted (:func:`~xviz_server.flow.watch_progress`);
a live subscription queues at most ``live_queue`` updates, drops the oldest
when the client falls behind, and the session closes the connection with
1013 once it has been dropping them for ``live_lag_timeout`` seconds
(:func:`~xviz_server.live.watch_lag`).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar
from urllib.parse import parse_qsl, unquote, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode

from .budget import LogThrottle
from .events import Close, LiveFacts, LookUpLive, OpenLog, Send
from .exceptions import XVIZError
from .flow import close, watch_progress
from .live import LiveFeed, LiveRegistry, Subscription, watch_lag
from .logfmt import ending, log_event, peer, redact_url
from .logs import Log, LogShelf
from .metrics import Metrics
from .params import repeated
from .settings import Settings

if TYPE_CHECKING:
    from .xviz.session import DetailChanged

__all__ = ["FaceConnection", "FaceSession", "request_target"]

logger = logging.getLogger("xviz_server.session")


class FaceSession(Protocol):
    """The inputs every face's session takes (each answers with a list of its events)."""

    def connect(self) -> Sequence[object]: ...

    def receive(self, data: bytes | str) -> Sequence[object]: ...

    def internal_error(self, what: str, error: BaseException) -> Sequence[object]: ...

    def log_failed(self, error: XVIZError) -> Sequence[object]: ...

    def live_found(self, facts: LiveFacts) -> Sequence[object]: ...

    def live_failed(self, name: str | None) -> Sequence[object]: ...

    def live_lagging(self, seconds: float) -> Sequence[object]: ...


S = TypeVar("S", bound=FaceSession)


class FaceConnection(Generic[S]):
    """One WebSocket connection running one session of either face; subclasses make the session and carry out
    the events of their face."""

    def __init__(
        self, websocket: ServerConnection, shelf: LogShelf, live: LiveRegistry, metrics: Metrics, settings: Settings
    ) -> None:
        self.websocket = websocket
        self.shelf = shelf
        self.live = live
        self.metrics = metrics
        self.settings = settings
        self.path, path, query = request_target(websocket)
        #: Names the URL's query gives more than once: the session refuses them (see :func:`~xviz_server.params.repeated`).
        self.repeated = repeated(urlsplit(self.path).query)
        self.session: S = self._make_session(path, query)
        self._tasks: set[asyncio.Task[None]] = set()
        self.messages_sent = 0
        self.bytes_written = 0  # every message's bytes, as handed to the connection
        self._mistakes = LogThrottle()  # lines logged about the errors and notices the client is sent

    def _make_session(self, path: str, query: dict[str, str]) -> S:
        """The session of this connection, for the request target's percent-decoded ``path`` and ``query``."""
        raise NotImplementedError

    async def run(self) -> None:
        """Serve the session until the client goes away or the server shuts down."""
        started = time.monotonic()
        self.metrics.sessions.inc()
        self.metrics.sessions_open.inc()
        self._opened()
        remote = peer(self.websocket)
        log_event(logger, "session start", remote=remote, path=redact_url(self.path), **self._start_fields())
        try:
            stalled = watch_progress(self.websocket, self.settings.idle_timeout, lambda: self.messages_sent)
            self._spawn("a stalled send", stalled)
            await self._step("the connection", self.session.connect)
            async for message in self.websocket:
                await self._step("a message", self.session.receive, message)
        except ConnectionClosed:
            pass
        finally:
            self._closing()
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            self.metrics.sessions_open.dec()
            self._closed()
            duration = round(time.monotonic() - started, 3)
            log_event(
                logger, "session end", remote=remote, **self._end_fields(), duration=duration, **ending(self.websocket)
            )

    # -- what each face adds ---------------------------------------------------

    def _start_fields(self) -> dict[str, Any]:
        """Fields of the ``session start`` log line after the path."""
        return {}

    def _end_fields(self) -> dict[str, Any]:
        """Fields of the ``session end`` log line before its duration."""
        return {}

    def _opened(self) -> None:
        """The connection starts serving (count what the face counts)."""

    def _closing(self) -> None:
        """The connection ends: release what its tasks hold before they are cancelled."""

    def _closed(self) -> None:
        """The connection ended and its tasks with it."""

    async def _carry_out(self, event: object) -> None:
        """Carry out ``event``, one of the face's own events."""
        raise NotImplementedError

    async def _log_opened(self, log: Log) -> None:
        """The log an :class:`~xviz_server.events.OpenLog` named is open: tell the session."""
        raise NotImplementedError

    # -- carrying events out ---------------------------------------------------

    async def _step(self, what: str, step: Callable[..., Sequence[object]], *args: Any) -> None:
        """Feed the session one input and carry out its answer; a bug is reported to the client, not fatal."""
        try:
            await self._execute(step(*args))
        except (ConnectionClosed, asyncio.CancelledError):
            raise
        except Exception as exc:
            await self._failed(what, exc)

    async def _failed(self, what: str, exc: Exception) -> None:
        """Log an unexpected error while handling ``what``, with its traceback, and tell the client."""
        logger.exception("error handling %s from %s", what, peer(self.websocket), exc_info=exc)
        await self._quietly(self._execute(self.session.internal_error(what, exc)))

    async def _execute(self, events: Sequence[object]) -> None:
        for event in events:
            if isinstance(event, Send):
                await self._send(event)
            elif isinstance(event, OpenLog):
                await self._open_log(event.name)
            elif isinstance(event, LookUpLive):
                await self._execute(self.session.live_found(self.live.facts(event.name)))
            elif isinstance(event, Close):
                await close(self.websocket, event.code, event.reason)
            else:
                await self._carry_out(event)

    def _log_detail_changed(self, event: DetailChanged) -> None:
        """Log the session's change of level of detail, with the link's estimate (Mbit/s) it was chosen by."""
        mbps = None if event.capacity is None else round(event.capacity * 8 / 1e6, 2)
        log_event(
            logger,
            "detail changed",
            remote=peer(self.websocket),
            detail=event.level.name,
            previous=event.previous.name,
            auto=event.auto,
            link_mbps=mbps,
        )

    def _spawn(self, what: str, coroutine: Coroutine[Any, Any, None], fatal: bool = False) -> asyncio.Task[None]:
        """Run ``coroutine`` beside the session; if it fails, the client is told (and, if ``fatal``, closed)."""

        async def guarded() -> None:
            try:
                await coroutine
            except ConnectionClosed:
                pass
            except Exception as exc:
                await self._failed(what, exc)
                if fatal:
                    await close(self.websocket, CloseCode.INTERNAL_ERROR, f"{what} failed")

        task = asyncio.ensure_future(guarded())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        task.add_done_callback(lambda _: coroutine.close())  # cancelled before it started: never awaited, not a leak
        return task

    async def _write(self, data: bytes, text: bool) -> None:
        self.bytes_written += len(data)  # before: the bytes are in the transport while send waits
        await self.websocket.send(data, text=text)
        self.messages_sent += 1

    async def _send(self, event: Send) -> None:
        await self._write(event.data, event.text)
        if event.error is not None:
            self.metrics.errors.labels(event.error).inc()
            self._mistakes.log(
                logger, "error sent", remote=peer(self.websocket), kind=event.error, message=event.message
            )
        elif event.notice is not None:
            self._mistakes.log(
                logger, "notice sent", remote=peer(self.websocket), kind=event.notice, message=event.message
            )

    async def _quietly(self, awaitable: Awaitable[None]) -> None:
        """Run ``awaitable`` unless the connection is gone."""
        try:
            await awaitable
        except ConnectionClosed:
            pass

    # -- recorded logs and live feeds ------------------------------------------

    async def _open_log(self, name: str) -> None:
        try:
            log = await self.shelf.open(name)
        except XVIZError as exc:
            await self._execute(self.session.log_failed(exc))
        else:
            await self._log_opened(log)

    async def _subscribe(self, name: str, **options: Any) -> tuple[LiveFeed, Subscription] | None:
        """Subscribe to live feed ``name`` once a source creates it, its lag watched (see the slow-client policy);
        ``None`` (and the session told) if it cannot be waited for. ``options`` go to :meth:`LiveFeed.subscribe`."""
        try:
            feed = await self.live.wait_for(name)
        except XVIZError:  # too many names waited for
            await self._execute(self.session.live_failed(name))
            return None
        subscription = feed.subscribe(self.settings.live_queue, **options)
        lag = watch_lag(subscription, self.websocket.transport, self.settings.live_lag_timeout, self._lagging)
        self._spawn("a slow live viewer", lag)
        return feed, subscription

    async def _lagging(self, seconds: float) -> None:
        """Tell the session how long the client has been dropping live updates."""
        await self._execute(self.session.live_lagging(seconds))


def request_target(websocket: ServerConnection) -> tuple[str, str, dict[str, str]]:
    """What a session's handshake asked for: the request target as sent, its path percent-decoded, and its query."""
    target = websocket.request.path if websocket.request else "/"
    url = urlsplit(target)
    return target, unquote(url.path), dict(parse_qsl(url.query, keep_blank_values=True))
