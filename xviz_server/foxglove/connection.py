"""The asyncio side of a Foxglove session: carry out what :class:`~xviz_server.foxglove.session.FoxgloveSession` decides.

One :class:`FoxgloveConnection` per WebSocket connection that chose a
Foxglove subprotocol. It reads the client's messages into the session,
opens the log the session names, and runs this connection's player: the
log's messages from a time on, each sent at its log time (paced at the
session's speed) to the subscriptions that want it, then a ``time``
message: each frame's Foxglove messages (converted once per frame and kept
in the frame cache, see :meth:`~xviz_server.logs.Log.derived`) at the
frame's time and, for a log read from a ROS bag or MCAP file, its original
messages at theirs (see :mod:`~xviz_server.foxglove.frame`). ``send``
waits while the socket's write buffer is full, so a client that reads
slowly slows its own playback and nobody else's.

A live feed is followed as an XVIZ live viewer follows it: a bounded
subscription (``live_queue`` updates, the oldest dropped when the client
falls behind), each update's messages converted once for every Foxglove
client of the feed (:mod:`.live`).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from operator import itemgetter

import numpy as np

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode

from ..budget import LogThrottle
from ..connection import request_target
from ..exceptions import XVIZError
from ..flow import close, watch_progress
from ..live import FeedEvent, LiveRegistry, LiveUpdate, watch_lag
from ..logfmt import ending, log_event, peer, redact_url
from ..logs import Catalog, Log
from ..metrics import Metrics
from ..records import unpack
from ..session import Close, LookUpLive, OpenLog, Send, SubscribeLive
from ..settings import Settings
from ..version import __version__
from .convert import Channel, Plan, nanoseconds, plan
from .frame import Message, frame_messages
from .live import LivePlan, converted, feed_plan, update_time
from .session import Event, FoxgloveSession, Play, SendLatest, SendLive, Stop
from .wire import message_header, time_message

__all__ = ["FoxgloveConnection"]

logger = logging.getLogger("xviz_server.session")

@dataclass
class _OpenLog:
    """A log with its Foxglove channels, as the session sees it."""

    log: Log

    @property
    def name(self) -> str:
        return self.log.name

    @cached_property
    def plan(self) -> Plan:
        return plan(self.log.metadata, self.log.originals)

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self.plan.channels

    @cached_property
    def times(self) -> np.ndarray:
        """When each frame starts, in nanoseconds, in time order: the times the messages carry."""
        return np.array([nanoseconds(start) for start in self.log.index.start.tolist()], dtype=np.int64)

    @property
    def start_time(self) -> int:
        return int(self.times[0]) if len(self.times) else 0

    @property
    def end_time(self) -> int:
        end = self.log.index.end_time
        return 0 if end is None else nanoseconds(end)


class FoxgloveConnection:
    """One WebSocket connection speaking the Foxglove protocol, with its own playback of one log, or a live feed."""

    def __init__(
        self, websocket: ServerConnection, catalog: Catalog, live: LiveRegistry, metrics: Metrics, settings: Settings
    ) -> None:
        self.websocket = websocket
        self.catalog = catalog
        self.live = live
        self.metrics = metrics
        self.settings = settings
        self.path, path, query = request_target(websocket)
        self.session = FoxgloveSession(
            path=path,
            query=query,
            available=catalog.available(),
            server_name=f"xviz-server {__version__}",
            lag_timeout=settings.live_lag_timeout,
        )
        self._log: _OpenLog | None = None
        self._player: asyncio.Task[None] | None = None
        self._follower: asyncio.Task[None] | None = None
        self._update: tuple[LiveUpdate, LivePlan] | None = None  # the live update the session is deciding about
        self._watch: asyncio.Task[None] | None = None
        self.messages_sent = 0
        self.bytes_sent = 0
        self._mistakes = LogThrottle()  # lines logged about the client's mistakes

    async def run(self) -> None:
        """Serve the session until the client goes away or the server shuts down."""
        started = time.monotonic()
        self.metrics.sessions.inc()
        self.metrics.sessions_open.inc()
        remote = peer(self.websocket)
        log_event(logger, "session start", remote=remote, path=redact_url(self.path), protocol=self.websocket.subprotocol)
        self._watch = asyncio.ensure_future(watch_progress(self.websocket, self.settings.idle_timeout, lambda: self.messages_sent))
        try:
            await self._execute(self.session.connect())
            async for message in self.websocket:
                await self._execute(self.session.receive(message))
        except ConnectionClosed:
            pass
        finally:
            tasks = [task for task in (self._player, self._watch, self._follower) if task is not None]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            self.metrics.sessions_open.dec()
            log_event(logger, "session end", remote=remote, log=self._log.name if self._log else self.session.feed, format="foxglove",
                      messages=self.messages_sent, bytes=self.bytes_sent, duration=round(time.monotonic() - started, 3),
                      **ending(self.websocket))

    async def _execute(self, events: list[Event]) -> None:
        for event in events:
            if isinstance(event, Send):
                await self._write(event.data, event.text)
                if event.error is not None:
                    self.metrics.errors.labels(event.error).inc()
                    self._mistakes.log(logger, "error sent", remote=peer(self.websocket), kind=event.error, message=event.message)
            elif isinstance(event, OpenLog):
                await self._open(event.name)
            elif isinstance(event, Play):
                await self._stop()
                self._player = asyncio.ensure_future(self._play(event))
            elif isinstance(event, Stop):
                await self._stop()
            elif isinstance(event, SendLatest):
                await self._send_frame(event.place, event.targets)
            elif isinstance(event, LookUpLive):
                await self._execute(self.session.live_found(self.live.facts(event.name)))
            elif isinstance(event, SubscribeLive):
                self._follower = asyncio.ensure_future(self._follow(event.name))
            elif isinstance(event, SendLive):
                await self._send_live(event)
            elif isinstance(event, Close):
                await close(self.websocket, event.code, event.reason)

    async def _write(self, data: bytes, text: bool) -> None:
        await self.websocket.send(data, text=text)
        self.messages_sent += 1
        self.bytes_sent += len(data)

    async def _open(self, name: str) -> None:
        try:
            log = await self.catalog.open(name)
        except XVIZError as exc:
            await self._execute(self.session.log_failed(exc))
            return
        self._log = _OpenLog(log)
        await self._execute(self.session.log_opened(self._log))

    async def _stop(self) -> None:
        if self._player is not None and self._player is not asyncio.current_task():
            self._player.cancel()
            await asyncio.gather(self._player, return_exceptions=True)
        self._player = None

    async def _play(self, request: Play) -> None:
        """Send the log's messages from ``request.start`` on, each at its time, at ``request.speed`` times real time.

        The frame at ``request.start`` is played from there: after a seek
        whole (its state at the new time), else from ``request.start`` on
        (what comes before was sent), unless nothing of it was.
        """
        assert self._log is not None
        log, times = self._log.log, self._log.times
        first = max(0, int(np.searchsorted(times, request.start, side="right")) - 1)
        skip_before = request.start if not request.seek and len(times) and request.start > times[first] else None
        loop = asyncio.get_running_loop()
        clock = loop.time()
        try:
            for position in range(first, len(times)):
                for at, group in _by_time(int(times[position]), await self._messages(position)):
                    if skip_before is not None and at < skip_before:
                        continue
                    if request.once and at > request.start:
                        return
                    await asyncio.sleep(max(0.0, clock + (at - request.start) / 1e9 / request.speed - loop.time()))
                    await self._send(group, self.session.frame(at, position))
                    await self._write(time_message(at), text=False)
                if request.once:
                    return
            await self._execute(self.session.ended())
        except ConnectionClosed:
            pass
        except Exception as exc:
            logger.exception("error playing log %r to %s", log.name, peer(self.websocket), exc_info=exc)

    async def _messages(self, position: int, *, report: bool = True) -> list[Message]:
        """The messages of the frame at ``position``, in time order; with ``report``, a status for a part missing."""
        assert self._log is not None
        messages, errors = await frame_messages(self._log.log, self._log.plan, int(self._log.log.index.frames[position]))
        for error in errors if report else ():
            await self._execute(self.session.frame_failed(error))
        return messages

    async def _send_frame(self, position: int, targets: Mapping[int, int]) -> None:
        """Send the messages of the frame at ``position`` up to the playback's time to ``targets``, subscriptions by channel."""
        until = self.session.position
        await self._send([m for m in await self._messages(position, report=False) if m[1] <= until], targets)

    async def _send(self, messages: list[Message], targets: Mapping[int, int]) -> None:
        for channel, stamp, payload in messages:
            subscription = targets.get(channel)
            if subscription is not None:
                await self._write(message_header(subscription, stamp) + payload, text=False)

    # -- live feeds ---------------------------------------------------------------

    async def _follow(self, name: str) -> None:
        """Follow live feed ``name`` (once a source creates it): tell the session what it does, send what it says."""
        try:
            feed = await self.live.wait_for(name)
        except XVIZError:  # too many names waited for
            await self._execute(self.session.live_failed(name))
            return
        subscription = feed.subscribe(self.settings.live_queue)
        lag = asyncio.ensure_future(watch_lag(subscription, self.websocket.transport, self.settings.live_lag_timeout, self._lagging))
        try:
            channels = feed_plan(feed)
            await self._execute(self.session.live_joined(None if channels is None else channels.plan.channels))
            while True:
                item = await subscription.next()
                if isinstance(item, FeedEvent):
                    channels = feed_plan(feed)
                    if item.kind == "metadata" and channels is not None:
                        await self._execute(self.session.live_started(channels.plan.channels))
                    elif item.kind == "gone":
                        await self._execute(self.session.live_gone())
                elif channels is not None:
                    self._update = item, channels
                    behind = subscription.lagging_since is not None
                    await self._execute(self.session.live_update(update_time(item), subscription.take_drops(), behind))
        except ConnectionClosed:
            pass
        except Exception as exc:
            logger.exception("error following live feed %r for %s", name, peer(self.websocket), exc_info=exc)
            await close(self.websocket, CloseCode.INTERNAL_ERROR, "following the live feed failed")
        finally:
            subscription.close()
            lag.cancel()
            self._update = None

    async def _lagging(self, seconds: float) -> None:
        await self._execute(self.session.live_lagging(seconds))

    async def _send_live(self, event: SendLive) -> None:
        """Send the live update at hand to ``event.targets``, converted once for every client of the feed."""
        assert self._update is not None
        update, channels = self._update
        if event.targets:
            try:
                packed = await converted(update, channels, self.live.workers)
            except XVIZError as exc:
                await self._execute(self.session.frame_failed(exc))
            else:
                await self._send(list(unpack(packed)), event.targets)
        if event.time is not None:
            await self._write(time_message(event.time), text=False)


def _by_time(tick: int, messages: list[Message]) -> Iterator[tuple[int, list[Message]]]:
    """Messages in time order, grouped by time; the frame's ``tick`` is a time of its own even without one."""
    groups: dict[int, list[Message]] = {tick: []}
    for message in messages:
        groups.setdefault(message[1], []).append(message)
    yield from sorted(groups.items(), key=itemgetter(0))
