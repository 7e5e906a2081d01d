"""The asyncio side of a Foxglove session: carry out what :class:`~xviz_server.foxglove.session.FoxgloveSession` decides.

One :class:`FoxgloveConnection` per WebSocket connection that chose a
Foxglove subprotocol. It reads the client's messages into the session,
opens the log the session names, and runs this connection's player: the
log's messages from a time on, each sent at its log time (paced at the
session's speed) to the subscriptions that want it, after a ``time``
message of that time (Foxglove and Lichtblick stamp a message with the last
time they were sent): each frame's Foxglove messages (converted once per frame and kept
in the frame cache, see :meth:`~xviz_server.logs.Log.derived`) at the
frame's time and, for a log read from a ROS bag or MCAP file, its original
messages at theirs (see :mod:`~xviz_server.foxglove.frame`). ``send``
waits while the socket's write buffer is full, so a client that reads
slowly slows its own playback and nobody else's.

A live feed is followed as an XVIZ live viewer follows it: a bounded
subscription (``live_queue`` updates, the oldest dropped when the client
falls behind), each update's messages converted once for every Foxglove
client of the feed (:mod:`.live`).

Frames and live updates are converted at the session's level of detail,
chosen from samples of this connection's link (:mod:`xviz_server.linkwatch`)
as for an XVIZ session.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from operator import itemgetter
from typing import Any

import numpy as np

from ..detail import Sample
from ..events import SubscribeLive
from ..exceptions import XVIZError
from ..face import FaceConnection
from ..linkwatch import is_loopback, sample_link
from ..live import FeedEvent, LiveUpdate
from ..logs import Log
from ..records import unpack
from ..version import __version__
from ..xviz.session import DetailChanged
from .frame import Message, frame_messages, log_plan
from .live import LivePlan, converted, feed_plan, update_time
from .protocol import message_header, time_message
from .session import FoxgloveSession, Play, SendLatest, SendLive, Stop
from .translate import Channel, Plan, nanoseconds

__all__ = ["FoxgloveConnection"]

logger = logging.getLogger("xviz_server.session")


@dataclass
class _OpenLog:
    """A log with its Foxglove channels, as the session sees it."""

    log: Log
    plan: Plan

    @property
    def name(self) -> str:
        return self.log.name

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

    @property
    def frames(self) -> int:
        return len(self.times)


class FoxgloveConnection(FaceConnection[FoxgloveSession]):
    """One WebSocket connection speaking the Foxglove protocol, with its own playback of one log, or a live feed."""

    def _make_session(self, path: str, query: dict[str, str]) -> FoxgloveSession:
        self._log: _OpenLog | None = None
        self._player: asyncio.Task[None] | None = None
        self._update: tuple[LiveUpdate, LivePlan] | None = None  # the live update the session is deciding about
        self._measure: asyncio.Task[None] | None = None  # sampling the link, while the level depends on it
        self._offered: Callable[[], int] | None = None  # updates a live feed offered this client so far
        return FoxgloveSession(
            path=path,
            query=query,
            available=self.shelf.available(),
            server_name=f"xviz-server {__version__}",
            lag_timeout=self.settings.live_lag_timeout,
            detail=self.settings.detail == "auto",
            local=is_loopback(self.websocket),
            repeated=self.repeated,
        )

    def _start_fields(self) -> dict[str, Any]:
        return {"protocol": self.websocket.subprotocol}

    def _end_fields(self) -> dict[str, Any]:
        log = self._log.name if self._log else self.session.feed
        return {"log": log, "format": "foxglove", "messages": self.messages_sent, "bytes": self.bytes_written}

    async def _step(self, what: str, step: Callable[..., Sequence[object]], *args: Any) -> None:
        await super()._step(what, step, *args)
        self._follow_link()

    async def _carry_out(self, event: object) -> None:
        if isinstance(event, Play):
            await self._stop()
            self._player = self._spawn("playing the log", self._play(event))
        elif isinstance(event, Stop):
            await self._stop()
        elif isinstance(event, SendLatest):
            await self._send_frame(event.place, event.targets)
        elif isinstance(event, SubscribeLive):
            self._spawn("following the live feed", self._follow(event.name), fatal=True)
        elif isinstance(event, SendLive):
            await self._send_live(event)
        elif isinstance(event, DetailChanged):
            self._log_detail_changed(event)

    def _follow_link(self) -> None:
        """Sample the connection's delivery for the session's level of detail once it depends on it."""
        if self._measure is None and self.session.chooser.measures:

            async def sampled(sample: Sample) -> None:
                await self._execute(
                    self.session.link_sampled(sample, None if self._offered is None else self._offered())
                )

            sampling = sample_link(
                self.websocket.transport, lambda: self.bytes_written, sampled, lambda: self.session.chooser.measures
            )
            self._measure = self._spawn("measuring the link", sampling)
            self._measure.add_done_callback(lambda _: setattr(self, "_measure", None))

    async def _log_opened(self, log: Log) -> None:
        self._log = _OpenLog(log, await log_plan(log))
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
        times = self._log.times
        first = max(0, int(np.searchsorted(times, request.start, side="right")) - 1)
        skip_before = request.start if not request.seek and len(times) and request.start > times[first] else None
        loop = asyncio.get_running_loop()
        clock = loop.time()
        for position in range(first, len(times)):
            for at, group in _by_time(int(times[position]), await self._messages(position)):
                if skip_before is not None and at < skip_before:
                    continue
                if request.once and at > request.start:
                    return
                await asyncio.sleep(max(0.0, clock + (at - request.start) / 1e9 / request.speed - loop.time()))
                # The time first: the apps stamp a message with the last time they were sent.
                await self._write(time_message(at), text=False)
                await self._send_messages(group, self.session.frame(at, position))
            if request.once:
                return
        await self._execute(self.session.ended())

    async def _messages(self, position: int, *, report: bool = True) -> list[Message]:
        """The messages of the frame at ``position``, in time order; with ``report``, a status for a part missing."""
        assert self._log is not None
        level = self.session.level
        messages, errors = await frame_messages(
            self._log.log, self._log.plan, int(self._log.log.index.frames[position]), level
        )
        self.session.update_made(level, sum(len(payload) for _, _, payload in messages))
        for error in errors if report else ():
            await self._execute(self.session.frame_failed(error))
        return messages

    async def _send_frame(self, position: int, targets: Mapping[int, int]) -> None:
        """Send the messages of the frame at ``position`` up to the playback's time to ``targets``, subscriptions by channel."""
        until = self.session.position
        await self._send_messages([m for m in await self._messages(position, report=False) if m[1] <= until], targets)

    async def _send_messages(self, messages: list[Message], targets: Mapping[int, int]) -> None:
        for channel, stamp, payload in messages:
            subscription = targets.get(channel)
            if subscription is not None:
                await self._write(message_header(subscription, stamp) + payload, text=False)

    # -- live feeds ---------------------------------------------------------------

    async def _follow(self, name: str) -> None:
        """Follow live feed ``name`` (once a source creates it): tell the session what it does, send what it says."""
        subscribed = await self._subscribe(name)
        if subscribed is None:
            return
        feed, subscription = subscribed
        self._offered = lambda: subscription.offered
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
                    channels = feed_plan(feed, item) or channels
                    self._update = item, channels
                    behind = subscription.lagging_since is not None
                    await self._execute(self.session.live_update(update_time(item), subscription.take_drops(), behind))
        finally:
            subscription.close()
            self._update = None

    async def _send_live(self, event: SendLive) -> None:
        """Send the live update at hand to ``event.targets``, converted once for every client of the feed."""
        assert self._update is not None
        update, channels = self._update
        if event.time is not None:
            await self._write(time_message(event.time), text=False)
        if event.targets:
            level = self.session.level
            try:
                packed = await converted(update, channels, self.live.workers, level)
            except XVIZError as exc:
                await self._execute(self.session.frame_failed(exc))
            else:
                self.session.update_made(level, len(packed))
                await self._send_messages(list(unpack(packed)), event.targets)


def _by_time(tick: int, messages: list[Message]) -> Iterator[tuple[int, list[Message]]]:
    """Messages in time order, grouped by time; the frame's ``tick`` is a time of its own even without one."""
    groups: dict[int, list[Message]] = {tick: []}
    for message in messages:
        groups.setdefault(message[1], []).append(message)
    yield from sorted(groups.items(), key=itemgetter(0))
