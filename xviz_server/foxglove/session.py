"""The Foxglove protocol state of one connection, as a pure state machine (sans-I/O).

Like :class:`xviz_server.xviz.session.Session`, a :class:`FoxgloveSession` takes
what happened (the connection opened, a message came, the log opened, the
player reached a time) and answers with events for the asyncio side to carry
out. It owns every decision of the protocol: which log the URL names, what
``serverInfo`` and ``advertise`` say, which subscription gets which channel,
what a playback control request does, and the ``status`` message that
answers anything wrong. Nothing a client sends closes the connection (a
live client that stays behind is closed, see below).

Each connection has its own playback: a client that only subscribes gets the
log from its start at real time, from its first subscription on; play,
pause, seek and speed (``foxglove.sdk.v1``'s playback control request) change
this connection's playback only.

Live feeds (``?session_type=live&log=NAME``, or ``?log=NAME`` naming no
recorded log but a running feed) follow the XVIZ live viewer's rules: the
session decides from what the feed registry reports (:meth:`live_found`)
whether to follow a feed, wait for it or refuse. Its channels are those of
the feed's metadata, advertised again (with new ids) when the metadata
changes; each update's messages go to the subscriptions, then a ``time``
message. A client that falls behind is told once per run of dropped updates
(the oldest go first) and closed once it has been dropping them for
``lag_timeout`` seconds. A live feed plays as its source sends: no
``playbackControl`` capability, and a playback control request is answered
with a status.

Level of detail, as on the XVIZ face (see :mod:`xviz_server.detail`): the
session owns a :class:`~xviz_server.detail.DetailChooser`, fed the
connection's delivery (:meth:`FoxgloveSession.link_sampled`) and the bytes
of the frames made for it (:meth:`FoxgloveSession.update_made`); frames
are converted at :attr:`FoxgloveSession.level`. The client pins a level
with ``?profile=NAME`` (or ``auto``) and caps the link with
``?max_mbps=N`` in the URL, or sets the parameter :data:`PROFILE_PARAMETER`
(the ``parameters`` capability: the Foxglove app's Parameters panel);
:data:`LEVEL_PARAMETER` tells the level sent now, to clients that get or
subscribe to it (``parametersSubscribe``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, TypeGuard

from websockets.frames import CloseCode

from ..budget import MAX_ITEMS, Problems, shown, too_many
from ..detail import DetailChooser, Sample
from ..events import Close, LiveFacts, LookUpLive, OpenLog, Send, SubscribeLive
from ..exceptions import FoxgloveProtocolError, LogNotFound, XVIZError
from ..levels import Level, profile_level
from ..params import given_twice
from ..xviz.session import DetailChanged
from .protocol import (
    CLIENT_MESSAGE_DATA,
    ENDED,
    PAUSED,
    PLAYBACK_CONTROL_REQUEST,
    PLAYING,
    SERVICE_CALL_REQUEST,
    PlaybackControl,
    parse_playback_control,
    parse_text,
    playback_state,
    text,
    time_message,
)
from .translate import Channel

__all__ = [
    "FoxgloveLog",
    "Play",
    "Stop",
    "SendLatest",
    "SendLive",
    "FoxgloveSession",
    "CAPABILITIES",
    "LIVE_CAPABILITIES",
    "MAX_SPEED",
    "PROFILE_PARAMETER",
    "LEVEL_PARAMETER",
]

#: What ``serverInfo`` says this server does for a recorded log.
CAPABILITIES = ("time", "playbackControl", "parameters", "parametersSubscribe")
#: What it says for a live feed, which plays as its source sends.
LIVE_CAPABILITIES = ("time", "parameters", "parametersSubscribe")

#: The parameter that pins the level of detail (a level's name) or leaves it to the link (``auto``).
PROFILE_PARAMETER = "/xviz_server/profile"
#: The parameter that tells the level sent now (read only).
LEVEL_PARAMETER = "/xviz_server/level"

#: The fastest playback a client may ask for, as a factor of real time.
MAX_SPEED = 100.0

#: Client operations of the protocol that this server does not offer (their capability is not advertised).
_UNOFFERED = frozenset(
    {"advertise", "unadvertise", "subscribeConnectionGraph", "unsubscribeConnectionGraph", "fetchAsset"}
)

_UINT32 = 1 << 32

# Status levels.
INFO, WARNING, ERROR = 0, 1, 2


class FoxgloveLog(Protocol):
    """What the session needs of an open log."""

    @property
    def name(self) -> str: ...

    @property
    def channels(self) -> Sequence[Channel]: ...

    @property
    def start_time(self) -> int: ...  # nanoseconds

    @property
    def end_time(self) -> int: ...  # nanoseconds

    @property
    def frames(self) -> int: ...  # how many frames it has


@dataclass(frozen=True)
class Play:
    """Play the log from ``start`` (nanoseconds) at ``speed`` times real time, replacing any playback."""

    start: int
    speed: float
    #: The playback follows a seek: the frame at ``start`` is sent at once, even if it began before.
    seek: bool = False
    #: Send only that frame, then stop (a seek while paused).
    once: bool = False


@dataclass(frozen=True)
class Stop:
    """Stop playing."""


@dataclass(frozen=True)
class SendLatest:
    """Send the messages of the frame the player sends now (``place``, see :meth:`FoxgloveSession.frame`) to ``targets``.

    ``targets`` are subscriptions by channel: those made during playback,
    which the frame being played did not go to.
    """

    place: int
    targets: Mapping[int, int]


@dataclass(frozen=True)
class SendLive:
    """Send the messages of the live update at hand to ``targets`` (subscriptions by channel), then a ``time``
    message of ``time`` (nanoseconds) unless it is ``None``.

    Channels are numbered as :func:`~xviz_server.foxglove.translate.plan`
    numbers those of the feed's metadata.
    """

    targets: Mapping[int, int]
    time: int | None


Event = Send | OpenLog | Play | Stop | SendLatest | LookUpLive | SubscribeLive | SendLive | Close | DetailChanged


@dataclass
class FoxgloveSession:
    """The protocol state of one Foxglove connection; ``query`` is its URL's query, ``available`` the logs."""

    path: str
    query: Mapping[str, str]
    available: Sequence[str] = ()
    server_name: str = "xviz-server"
    #: Seconds a live client may keep dropping updates before it is closed.
    lag_timeout: float = 30.0
    #: Whether levels of detail are on (``--detail auto``); ``local``: the client is on this host.
    detail: bool = True
    local: bool = False
    #: Names the URL's query gives more than once: refused, and taken as not given.
    repeated: frozenset[str] = frozenset()
    chooser: DetailChooser = field(init=False)
    log: FoxgloveLog | None = field(init=False, default=None)
    #: The live feed followed (or waited for), once the session chose one.
    feed: str | None = field(init=False, default=None)
    #: Where playback is (nanoseconds), its speed, and whether it plays.
    position: int = field(init=False, default=0)
    speed: float = field(init=False, default=1.0)
    playing: bool = field(init=False, default=False)
    _started: bool = field(init=False, default=False)
    _controlled: bool = field(init=False, default=False)  # the client sent a playback control request
    _shown: int | None = field(init=False, default=None)  # where the frame at ``position`` is, once the player sends it
    _channels: dict[int, Channel] = field(init=False, default_factory=dict)
    _subscriptions: dict[int, int] = field(init=False, default_factory=dict)  # subscription id -> channel id
    _by_channel: dict[int, int] = field(init=False, default_factory=dict)  # channel id -> subscription id
    _live: bool = field(init=False, default=False)  # the URL asks for a live feed
    _asked: str | None = field(init=False, default=None)  # the name the URL gives
    _unfound: XVIZError | None = field(init=False, default=None)  # no log of that name: a live feed, if one runs
    _base: int = field(init=False, default=0)  # a live channel's id is its number in the feed's plan plus this
    _behind: bool = field(init=False, default=False)  # the live client is dropping updates
    _profile: str = field(init=False, default="auto")  # the level asked for (a level's name), or auto
    _watched: set[str] = field(init=False, default_factory=set)  # parameters the client subscribed to
    _url_errors: list[Send] = field(init=False, default_factory=list)  # about the URL's parameters
    _clock: float = field(init=False, default=0.0)  # the time of the last sample
    _live_updates: int = field(init=False, default=0)  # live updates at hand so far

    def __post_init__(self) -> None:
        self.chooser = DetailChooser(enabled=self.detail, local=self.local)

    # -- inputs -------------------------------------------------------------

    def connect(self) -> list[Event]:
        """The connection opened: open the log its URL names, or look up the live feed it names."""
        self._url_errors = [
            self._status(ERROR, given_twice(name), kind="url") for name in sorted(self.repeated & _URL_KEYS)
        ]
        self.query = {key: value for key, value in self.query.items() if key not in self.repeated}
        name = self._asked = self.query.get("log") or self.query.get("logGuid") or self.path.strip("/") or None
        self._url_errors += self._url_detail()
        if self.query.get("session_type", "").upper() == "LIVE":
            self._live = True
            return [LookUpLive(name)]
        if name is None:
            if len(self.available) != 1:
                shown = ", ".join(repr(n) for n in self.available[:20]) or "none"
                return [
                    *self._opening(),
                    self._status(ERROR, f"no log named: add ?log=NAME to the URL; available: {shown}", kind="log"),
                ]
            name = self.available[0]
        return [OpenLog(name)]

    def log_opened(self, log: FoxgloveLog) -> list[Event]:
        """The log is open: say what the server offers, the log's start time, and advertise the log's channels.

        The time comes before the channels: Lichtblick starts its timeline at
        the time it has when the channels come (else at 0).
        """
        self.log = log
        self.position = log.start_time
        self._channels = {channel.id: channel for channel in log.channels}
        self._set_rate()
        advertise = text("advertise", channels=[channel.advertisement() for channel in log.channels])
        return [
            *self._opening(),
            Send(time_message(log.start_time), text=False),
            Send(advertise, text=True),
        ]

    def log_failed(self, error: XVIZError) -> list[Event]:
        """The log cannot be served; a name that is no recorded log may be a running live feed's."""
        if isinstance(error, LogNotFound) and self._asked is not None and not self._live and self._unfound is None:
            self._unfound = error
            return [LookUpLive(self._asked)]
        return [*self._opening(), self._status(ERROR, str(error), kind="log")]

    def receive(self, data: bytes | str) -> list[Event]:
        """A message arrived from the client."""
        try:
            if isinstance(data, str):
                return self._on_text(parse_text(data))
            return self._on_binary(data)
        except FoxgloveProtocolError as exc:
            return [self._status(ERROR, str(exc), kind="invalid")]

    def frame(self, time: int, place: int) -> dict[int, int]:
        """The player sends the frame at ``time`` (nanoseconds) now: to these subscriptions, by channel.

        ``place`` is where the frame is in the player's order. A subscription
        made while the frame is sent gets it from :class:`SendLatest`, so
        that no channel misses it or gets it twice.
        """
        self.position = time
        self._shown = place
        return dict(self._by_channel)

    def ended(self) -> list[Event]:
        """The player sent the log's last frame."""
        self.playing = False
        # A client that never asked for playback control may not know the playback state message.
        return [self._state(ENDED, False, None)] if self._controlled else []

    def internal_error(self, what: str, error: BaseException) -> list[Event]:
        """Something unexpected failed while handling ``what``; the session goes on."""
        return [self._status(ERROR, f"internal server error while handling {what}: {error!r}", kind="internal")]

    def frame_failed(self, error: XVIZError) -> list[Event]:
        """A frame (or live update) could not be read or converted; playback goes on with the next."""
        return [self._status(WARNING, str(error), kind="frame")]

    # -- live feeds -------------------------------------------------------------

    def live_found(self, facts: LiveFacts) -> list[Event]:
        """What the registry knows of the feed the URL names (see :class:`LookUpLive`): follow it, wait, or refuse.

        A named feed is that feed only, waited for if no source has created
        it yet; with no name, the only running feed is followed. A name that
        is no recorded log is followed only if its feed runs.
        """
        name = self._asked
        if self._unfound is not None:
            if name not in facts.running:
                return [*self._opening(), self._status(ERROR, str(self._unfound), kind="log")]
            self._live = True
            return self._follow(name)
        if not facts.allowed:
            return self.live_failed(name)
        if name is None:
            return self._follow(facts.running[0]) if len(facts.running) == 1 else self.live_failed(None, facts.running)
        if facts.exists:
            return self._follow(name)
        info, subscribe = self._follow(name)
        return [info, self._waiting(name), subscribe]

    def live_failed(self, name: str | None, running: Sequence[str] = ()) -> list[Event]:
        """No live feed answers to what the client asked for (or too many are waited for)."""
        shown = ", ".join(repr(n) for n in running[:20]) or "none"
        what = f"named {name!r} can be followed" if name is not None else "named: add ?log=NAME to the URL"
        return [
            *self._opening(),
            self._status(ERROR, f"no live feed {what}; running live feeds: {shown}", kind="live"),
        ]

    def live_joined(self, channels: Sequence[Channel] | None) -> list[Event]:
        """The connection follows the feed; ``channels`` are those of its metadata (``None``: it has none yet)."""
        if channels is None:
            assert self.feed is not None
            return [self._waiting(self.feed)]
        return self.live_started(channels)

    def live_started(self, channels: Sequence[Channel]) -> list[Event]:
        """The feed has (new) metadata whose channels are ``channels``: advertise them unless they are advertised.

        Channels that change are unadvertised (their subscriptions end) and
        the new ones advertised with ids never used on this connection.
        """
        current = [(c.id - self._base, c.topic, c.schema) for c in self._channels.values()]
        if current == [(c.id, c.topic, c.schema) for c in channels]:
            return []
        events: list[Event] = []
        if self._channels:
            events.append(Send(text("unadvertise", channelIds=list(self._channels)), text=True))
            self._base = max(self._channels)
        self._subscriptions.clear()
        self._by_channel.clear()
        shown = [replace(channel, id=channel.id + self._base) for channel in channels]
        self._channels = {channel.id: channel for channel in shown}
        events.append(Send(text("advertise", channels=[channel.advertisement() for channel in shown]), text=True))
        return events

    def live_gone(self) -> list[Event]:
        """The feed's source went away."""
        message = f"live feed {self.feed!r} went away; this connection stays open and resumes when it comes back"
        return [self._status(WARNING, message, kind="gone")]

    def live_update(self, time: int | None, dropped: int, behind: bool) -> list[Event]:
        """The feed's next update for this client is at hand; its time is ``time`` (nanoseconds, if it has one).

        ``dropped`` updates were dropped since the last call because the
        client fell behind; ``behind`` tells whether it still is.
        """
        events: list[Event] = []
        if dropped and not self._behind:
            message = (
                f"live feed {self.feed!r}: this client is behind; {dropped} updates were dropped "
                "(the oldest go first; clients that stay behind are disconnected)"
            )
            events.append(self._status(WARNING, message, kind="behind"))
        self._behind = behind
        if time is not None:
            self.position = time
        self._live_updates += 1
        if self._live_updates % self.chooser.level.every:  # a level that sends every n-th update skips this one
            events.append(SendLive({}, time))
            return events
        events.append(SendLive({cid - self._base: sid for cid, sid in self._by_channel.items()}, time))
        return events

    def live_lagging(self, seconds: float) -> list[Event]:
        """The client has been dropping live updates for ``seconds``."""
        if seconds <= self.lag_timeout:
            return []
        return [Close(CloseCode.TRY_AGAIN_LATER, f"too slow: dropped live updates for over {self.lag_timeout:g} s")]

    # -- client messages ------------------------------------------------------

    def _on_text(self, message: dict[str, Any]) -> list[Event]:
        op = message["op"]
        if op == "subscribe":
            return self._on_subscribe(message.get("subscriptions"))
        if op == "unsubscribe":
            return self._on_unsubscribe(message.get("subscriptionIds"))
        if op == "getParameters":
            return [self._parameter_values(_names(message, "getParameters"), message.get("id"))]
        if op == "setParameters":
            return self._on_set_parameters(message)
        if op == "subscribeParameterUpdates":
            names = _names(message, "subscribeParameterUpdates")
            self._watched |= set(names or _PARAMETERS)
            return []
        if op == "unsubscribeParameterUpdates":
            names = _names(message, "unsubscribeParameterUpdates")
            self._watched -= set(names or _PARAMETERS)
            return []
        if op in _UNOFFERED:
            raise FoxgloveProtocolError(f"{op!r} is not offered by this server (its capability is not in serverInfo)")
        raise FoxgloveProtocolError(f"unknown op {shown(op)}")

    def _on_binary(self, data: bytes) -> list[Event]:
        if not data:
            raise FoxgloveProtocolError("an empty binary message")
        opcode = data[0]
        if opcode == PLAYBACK_CONTROL_REQUEST:
            return self._on_playback_control(parse_playback_control(data))
        if opcode in (CLIENT_MESSAGE_DATA, SERVICE_CALL_REQUEST):
            what = "client message data" if opcode == CLIENT_MESSAGE_DATA else "service call request"
            raise FoxgloveProtocolError(
                f"{what} is not offered by this server (clientPublish and services are not in serverInfo)"
            )
        raise FoxgloveProtocolError(f"unknown binary opcode 0x{opcode:02x}")

    def _on_subscribe(self, subscriptions: Any) -> list[Event]:
        if not isinstance(subscriptions, list):
            raise FoxgloveProtocolError("subscribe: 'subscriptions' must be a list of {id, channelId}")
        _check_count("subscribe", subscriptions)
        events: list[Event] = []
        problems = Problems()
        added: set[int] = set()
        for item in subscriptions:
            sid = item.get("id") if isinstance(item, dict) else None
            cid = item.get("channelId") if isinstance(item, dict) else None
            if not _uint32(sid) or not _uint32(cid):
                problems.add(f"{shown(item)} is not {{id, channelId}} with unsigned 32-bit integers")
            elif cid not in self._channels:
                problems.add(f"no channel {cid}{self._where()}")
            elif sid in self._subscriptions:
                problems.add(f"subscription id {sid} is in use (channel {self._subscriptions[sid]})")
            elif cid in self._by_channel:
                problems.add(f"channel {cid} is subscribed already (subscription {self._by_channel[cid]})")
            else:
                self._subscriptions[sid] = cid
                self._by_channel[cid] = sid
                added.add(cid)
        if (summary := problems.summary("subscribe", len(subscriptions))) is not None:
            events.append(self._status(ERROR, summary, kind="invalid"))
        if self._subscriptions and not self._started and self.log is not None:
            self._started = self.playing = True
            events.append(self._play(self.position))
        elif added and self._shown is not None:
            # Clients subscribe one channel at a time: the later ones get the frame on screen too.
            events.append(SendLatest(self._shown, {channel: self._by_channel[channel] for channel in added}))
        return events

    def _on_unsubscribe(self, ids: Any) -> list[Event]:
        if not isinstance(ids, list):
            raise FoxgloveProtocolError("unsubscribe: 'subscriptionIds' must be a list")
        _check_count("unsubscribe", ids)
        problems = Problems()
        for sid in ids:
            cid = self._subscriptions.pop(sid, None) if _uint32(sid) else None
            if cid is None:
                problems.add(f"no subscription {shown(sid)}")
            else:
                del self._by_channel[cid]
        summary = problems.summary("unsubscribe", len(ids))
        return [] if summary is None else [self._status(WARNING, summary, kind="invalid")]

    def _on_playback_control(self, request: PlaybackControl) -> list[Event]:
        self._controlled = True
        if self._live:
            message = (
                f"playback control request {request.request_id!r}: live feed {self.feed!r} plays as its source "
                "sends; it cannot be paused, sought or sped up (playbackControl is not in serverInfo)"
            )
            return [self._status(ERROR, message, kind="invalid"), self._state(PLAYING, False, request.request_id)]
        if self.log is None:
            raise FoxgloveProtocolError(f"playback control request {request.request_id!r}: no log is open")
        if not (math.isfinite(request.speed) and 0 < request.speed <= MAX_SPEED):
            return [
                self._status(
                    ERROR,
                    f"playback control request {request.request_id!r}: speed {request.speed} is not in (0, {MAX_SPEED}]",
                    kind="invalid",
                ),
                self._state(PLAYING if self.playing else PAUSED, False, request.request_id),
            ]
        seek = request.seek
        if seek is not None and not self.log.start_time <= seek <= self.log.end_time:
            message = (
                f"playback control request {request.request_id!r}: seek to {seek} ns is outside the log "
                f"{self.log.name!r} ({self.log.start_time} to {self.log.end_time} ns)"
            )
            return [
                self._status(ERROR, message, kind="invalid"),
                self._state(PLAYING if self.playing else PAUSED, False, request.request_id),
            ]
        if seek is not None:
            self.position = seek
        changed = seek is not None or request.play != self.playing or request.speed != self.speed
        self.speed = request.speed
        self._set_rate()
        self.playing = request.play
        self._started = True  # the client controls playback: subscribing no longer starts it
        events: list[Event] = []
        if self.playing and changed:
            # Without a seek, playing goes on after the frame on screen.
            start = self.position + 1 if seek is None and self._shown is not None else self.position
            events.append(self._play(start, seek=seek is not None))
        elif not self.playing:
            # Paused: a seek shows the frame at the new time and stays there.
            events.append(self._play(self.position, seek=True, once=True) if seek is not None else Stop())
        events.append(self._state(PLAYING if self.playing else PAUSED, seek is not None, request.request_id))
        return events

    # -- level of detail ---------------------------------------------------------

    @property
    def level(self) -> Level:
        """The level of detail frames are made at now (see :attr:`xviz_server.detail.DetailChooser.sending`)."""
        return self.chooser.sending

    def link_sampled(self, sample: Sample, offered: int | None = None) -> list[Event]:
        """A sample of the connection's delivery (see :class:`xviz_server.detail.Sample`); for a live feed, the
        updates it ``offered`` this client so far (for its rate)."""
        self._clock = sample.time
        if offered is not None:
            self.chooser.offered(sample.time, offered)
        previous = self.chooser.level
        return self._detail_changed(previous, self.chooser.sample(sample))

    def update_made(self, level: Level, size: int) -> None:
        """A frame (or live update) of ``size`` bytes was made at ``level`` for this client."""
        self.chooser.made(level, size)

    def _url_detail(self) -> list[Send]:
        """Apply the URL's ``profile`` and ``max_mbps``; a status for each that cannot be used."""
        errors = []
        fixed: Level | None = None
        profile = self.query.get("profile")
        if profile is not None:
            try:
                fixed = profile_level(profile)
                self._profile = profile if fixed is not None else "auto"
            except ValueError as exc:
                errors.append(
                    self._status(ERROR, f"profile: {exc}; the level of detail is chosen from the link", kind="profile")
                )
        cap: float | None = None
        given = self.query.get("max_mbps")
        if given is not None:
            try:
                cap = float(given)
                if not (math.isfinite(cap) and cap > 0):
                    raise ValueError(given)
            except ValueError:
                cap = None
                message = f"bad connection URL parameter 'max_mbps': {given[:60]!r} is not a positive number of Mbit/s; no cap"
                errors.append(self._status(ERROR, message, kind="max_mbps"))
        self.chooser.choose(fixed, None if cap is None else cap * 125_000, self._clock)
        return errors

    def _opening(self) -> list[Send]:
        """``serverInfo``, then a status for each URL parameter that cannot be used (once: then none)."""
        errors, self._url_errors = self._url_errors, []
        return [self._server_info(), *errors]

    def _set_rate(self) -> None:
        """The content's updates a second, for the chooser: a log's frames a second times the speed."""
        log = self.log
        if log is not None and log.frames > 1 and log.end_time > log.start_time:
            self.chooser.rate = (log.frames - 1) / ((log.end_time - log.start_time) / 1e9) * self.speed

    def _detail_changed(self, previous: Level, level: Level | None) -> list[Event]:
        if level is None:
            return []
        events: list[Event] = [DetailChanged(level, previous, self.chooser.auto, self.chooser.estimate)]
        if LEVEL_PARAMETER in self._watched:
            events.append(self._parameter_values([LEVEL_PARAMETER], None))
        return events

    def _on_set_parameters(self, message: dict[str, Any]) -> list[Event]:
        parameters = message.get("parameters")
        if not isinstance(parameters, list) or not all(
            isinstance(p, dict) and isinstance(p.get("name"), str) for p in parameters
        ):
            raise FoxgloveProtocolError("setParameters: 'parameters' must be a list of {name, value}")
        _check_count("setParameters", parameters)
        events: list[Event] = []
        names = []
        for parameter in parameters:
            name, value = parameter["name"], parameter.get("value")
            names.append(name)
            if name != PROFILE_PARAMETER:
                what = "is read only" if name == LEVEL_PARAMETER else "is no parameter of this server"
                events.append(self._status(ERROR, f"setParameters: {name[:100]!r} {what}", kind="invalid"))
                continue
            try:
                fixed = profile_level(value if isinstance(value, str) else "auto" if value is None else repr(value))
            except ValueError as exc:
                events.append(self._status(ERROR, f"setParameters: {PROFILE_PARAMETER}: {exc}", kind="invalid"))
                continue
            self._profile = value if fixed is not None else "auto"
            previous = self.chooser.level
            events += self._detail_changed(previous, self.chooser.choose(fixed, self.chooser.cap, self._clock))
            if PROFILE_PARAMETER in self._watched:
                events.append(self._parameter_values([PROFILE_PARAMETER], None))
        request = message.get("id")
        if isinstance(request, str):
            events.append(self._parameter_values(names, request))
        return events

    def _parameter_values(self, names: list[str] | None, request: Any) -> Send:
        values = {PROFILE_PARAMETER: self._profile, LEVEL_PARAMETER: self.chooser.level.name}
        shown = [{"name": name, "value": values[name]} for name in (names or _PARAMETERS) if name in values]
        fields: dict[str, Any] = {"parameters": shown}
        if isinstance(request, str):
            fields["id"] = request
        return Send(text("parameterValues", **fields), text=True)

    # -- helpers ----------------------------------------------------------------

    def _play(self, start: int, *, seek: bool = False, once: bool = False) -> Play:
        self._shown = None
        return Play(start, self.speed, seek=seek, once=once)

    def _follow(self, name: str) -> list[Event]:
        self.feed = name
        self.chooser.live = True
        return [*self._opening(), SubscribeLive(name)]

    def _waiting(self, name: str) -> Send:
        return self._status(INFO, f"live feed {name!r} has not started yet; waiting for it", kind="waiting")

    def _server_info(self) -> Send:
        info: dict[str, Any] = {
            "name": self.server_name,
            "capabilities": list(LIVE_CAPABILITIES if self._live else CAPABILITIES),
        }
        if self.feed is not None:
            info["metadata"] = {"live": self.feed}
        elif self.log is not None:
            info["metadata"] = {"log": self.log.name}
            info["dataStartTime"] = _time(self.log.start_time)
            info["dataEndTime"] = _time(self.log.end_time)
        return Send(text("serverInfo", **info), text=True)

    def _state(self, status: int, did_seek: bool, request_id: str | None) -> Send:
        return Send(playback_state(status, self.position, self.speed, did_seek, request_id), text=False)

    def _status(self, level: int, message: str, *, kind: str) -> Send:
        data = text("status", level=level, message=message)
        if level == ERROR:
            return Send(data, text=True, error=kind, message=message)
        return Send(data, text=True, notice=kind, message=message)

    def _where(self) -> str:
        if self.feed is not None:
            return f" in live feed {self.feed!r}"
        return f" in log {self.log.name!r}" if self.log is not None else ""


#: Every parameter a session reads from its URL.
_URL_KEYS = frozenset(("log", "logGuid", "session_type", "profile", "max_mbps"))
#: The parameters this server has.
_PARAMETERS = (PROFILE_PARAMETER, LEVEL_PARAMETER)


def _names(message: dict[str, Any], op: str) -> list[str]:
    """The ``parameterNames`` of a parameters op (empty: all)."""
    names = message.get("parameterNames", [])
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise FoxgloveProtocolError(f"{op}: 'parameterNames' must be a list of strings")
    _check_count(op, names)
    return names


def _check_count(op: str, items: list[Any]) -> None:
    """Refuse a list of more items than a message may hold (see :mod:`xviz_server.budget`), before any is looked at."""
    if too_many(items):
        raise FoxgloveProtocolError(
            f"{op}: {len(items)} items, more than the {MAX_ITEMS} one message may hold: refused whole"
        )


def _uint32(value: Any) -> TypeGuard[int]:
    return type(value) is int and 0 <= value < _UINT32


def _time(nanoseconds: int) -> dict[str, int]:
    return {"sec": nanoseconds // 1_000_000_000, "nsec": nanoseconds % 1_000_000_000}
