"""The XVIZ session protocol, without I/O.

A :class:`Session` is fed what happens on one connection and answers with
the events that carry its decisions out, as ``websockets``' sans-I/O
protocol does: every method named after something that happened (the
connection opened, a message arrived, a log was opened, a stream ended, a
live update came) returns a list of :data:`Event`. The asyncio layer
(:mod:`xviz_server.xviz.connection`) carries them out and reports back. Events
name logs and frames by name and number; they hold no I/O object.

Recorded logs: a ``transform_log`` becomes :class:`StreamFrames`. A newer
``transform_log`` cancels the one still streaming: the older request stops
after its frame in flight (:class:`CancelStream`) and still gets its
``transform_log_done``, before the first frame of the newer one; a request
that was waiting its turn when an even newer one came gets its done without
frames. A ``transform_point_in_time`` becomes :class:`QueryInstant`.

Live feeds: a session is LIVE when the client says so (``session_type=live``),
or when it names its log only by ``logGuid`` (as streetscape.gl's
``XVIZLiveLoader`` does) and no recorded log of that name can be opened.
Which feed it follows, or waits for, the session decides from what the feed
registry reports (:meth:`Session.live_found`). A
live viewer gets the feed's metadata, then its latest complete state, then
every update that state does not already hold; it is told when it fell
behind (once per run of dropped updates) and when the source went away, and
it is closed once it has been dropping updates for ``lag_timeout`` seconds.

Level of detail: the session owns a
:class:`~xviz_server.detail.DetailChooser`. The asyncio layer reports the
samples of the connection's delivery (:meth:`Session.link_sampled`) and the
size of each update made for it (:meth:`Session.update_made`); frames and
live updates go out at :attr:`Session.level`. The client fixes a level, or
asks for ``auto``, with ``profile`` (URL, ``xviz/start``, ``xviz/reconfigure``;
streetscape.gl's ``default`` is ``auto``) and caps the session with
``max_mbps`` (URL, ``xviz/reconfigure``). A change of level is a
:class:`DetailChanged`. A client that asks with ``?detail_notices=1`` (the
built-in viewer) is also told the level, when the session starts and
whenever it changes or the client chooses, in a text message of its own
type, ``xviz-server/detail`` (``{"level", "auto", "levels", "link_mbps"}``):
standard XVIZ clients, which do not ask, never get one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pydantic
from websockets.frames import CloseCode

from ..codec import Format, decode, encode
from ..detail import DetailChooser, Sample
from ..events import Close, LiveFacts, LookUpLive, OpenLog, Send, SubscribeLive, Variant
from ..exceptions import DecodeError, LogNotFound, MessageError, XVIZError
from ..levels import FULL, Level, profile_level
from ..messages import (
    Error,
    Reconfigure,
    SessionConfig,
    SessionType,
    Start,
    TransformLog,
    TransformLogDone,
    TransformPointInTime,
    describe_validation_error,
    merge_patch,
    parse_client_message,
    stream_filter,
)
from ..params import given_twice
from ..timeindex import TimeIndex

__all__ = [
    "Session",
    "LogView",
    "Event",
    "StreamFrames",
    "CancelStream",
    "QueryInstant",
    "ConfigureLive",
    "SendLiveMetadata",
    "SendLiveUpdate",
    "SkipToState",
    "DetailChanged",
]


class LogView(Protocol):
    """What a session needs to know of an open log (see :class:`xviz_server.logs.Log`)."""

    name: str
    format: Format
    index: TimeIndex

    def metadata_message(self, fmt: Format) -> bytes: ...


# ----------------------------------------------------------------- events of this face (the shared ones: events.py)


@dataclass(frozen=True, eq=False)
class StreamFrames:
    """Send frames ``frames`` of log ``log`` in order, then call :meth:`Session.stream_ended`.

    ``times`` are the frames' start times, for pacing at ``speed`` times the
    log's rate; ``speed`` ``None`` means as fast as the client reads. A frame
    that cannot be had is reported with :meth:`Session.frame_failed`.
    """

    request_id: str
    log: str
    frames: np.ndarray
    times: np.ndarray
    fmt: Format
    streams: frozenset[str] | None
    speed: float | None


@dataclass(frozen=True)
class CancelStream:
    """Stop the stream of ``request_id`` after its frame in flight; then call :meth:`Session.stream_ended`."""

    request_id: str


@dataclass(frozen=True)
class QueryInstant:
    """Send the complete state of log ``log`` at ``instant`` as one message (or :meth:`Session.query_failed`)."""

    request_id: str
    log: str
    instant: float
    fmt: Format
    streams: frozenset[str] | None


@dataclass(frozen=True)
class ConfigureLive:
    """The live configuration changed: ``decimate`` for the subscription, ``forward`` for a source that accepts it."""

    decimate: int
    forward: dict[str, Any]


@dataclass(frozen=True)
class SendLiveMetadata:
    """Send the feed's metadata in ``fmt``."""

    fmt: Format


@dataclass(frozen=True)
class SendLiveUpdate:
    """Send live update ``number`` (or the complete state whose newest update it is) encoded for ``variant``."""

    number: int
    variant: Variant


@dataclass(frozen=True)
class SkipToState:
    """Send the feed's latest complete state instead of the updates queued for this viewer (it is behind).

    Answer with :meth:`Session.live_skipped`.
    """


@dataclass(frozen=True)
class DetailChanged:
    """The session's level of detail changed from ``previous`` to ``level``.

    ``auto``: chosen from the link (else by the user); ``capacity``: what the
    link was measured to carry, bytes a second (``None``: not measured).
    """

    level: Level
    previous: Level
    auto: bool
    capacity: float | None


Event = (
    Send
    | Close
    | OpenLog
    | StreamFrames
    | CancelStream
    | QueryInstant
    | LookUpLive
    | SubscribeLive
    | ConfigureLive
    | SendLiveMetadata
    | SendLiveUpdate
    | SkipToState
    | DetailChanged
)


# ----------------------------------------------------------------- session

URL_START_KEYS = ("version", "profile", "session_type", "message_format", "log")
#: Every parameter a session reads from its URL.
_URL_KEYS = frozenset(URL_START_KEYS + ("logGuid", "speed", "max_mbps", "detail_notices"))
#: The type of the message that tells a client that asked for it (``?detail_notices=1``) its level of detail.
DETAIL_NOTICE = "xviz-server/detail"
#: Updates queued for a live viewer after its level went down that are skipped for the latest complete state.
STALE_QUEUE = 3
#: Configuration keys about the level of detail: the session's own, never passed on to a live source.
DETAIL_KEYS = ("profile", "max_mbps")


@dataclass
class Session:
    """The protocol state of one connection.

    ``path`` and ``query`` come from the URL the client connected to;
    ``available`` lists the recorded logs (to pick the only one when the
    client names none, and to list them when it must choose); ``live`` lists
    the live feeds; ``lag_timeout`` is how long a live viewer may keep
    dropping updates before it is closed; ``detail`` false keeps the
    session at full detail whatever its link or its client asks; ``local``:
    the client is on this host (a loopback address), with no link to fit.
    """

    path: str
    query: Mapping[str, str]
    available: Sequence[str] = ()
    live: Sequence[str] = ()
    lag_timeout: float = 30.0
    detail: bool = True
    local: bool = False
    #: Names the URL's query gives more than once: refused, and taken as not given.
    repeated: frozenset[str] = frozenset()
    start: Start = field(init=False, default_factory=Start)
    config: SessionConfig = field(init=False, default_factory=SessionConfig)
    log: LogView | None = field(init=False, default=None)
    _requested_log: str | None = field(init=False, default=None)
    _streaming: StreamFrames | None = field(init=False, default=None)
    _waiting: list[StreamFrames] = field(init=False, default_factory=list)
    _feed: str | None = field(init=False, default=None)
    _exact_feed: bool = field(init=False, default=False)
    _covered: int = field(init=False, default=-1)
    _behind: bool = field(init=False, default=False)
    _stale: bool = field(init=False, default=False)  # updates queued for the viewer were meant for a higher level
    chooser: DetailChooser = field(init=False)
    _url_cap: float | None = field(init=False, default=None)
    _clock: float = field(init=False, default=0.0)  # time of the latest sample

    def __post_init__(self) -> None:
        self.chooser = DetailChooser(enabled=self.detail, local=self.local)

    # -- inputs: the connection and its messages -----------------------

    def connect(self) -> list[Event]:
        """The connection opened: read the start parameters from the URL (each at most once)."""
        events: list[Event] = [self._error("start", given_twice(name)) for name in sorted(self.repeated & _URL_KEYS)]
        self.query = {key: value for key, value in self.query.items() if key not in self.repeated}
        params = {key: self.query[key] for key in URL_START_KEYS if key in self.query}
        if "log" not in params:
            name = self.query.get("logGuid") or self.path.strip("/")
            if name:
                params["log"] = name
        speed = self.query.get("speed")
        try:
            self.start = Start.model_validate(params)
            if speed is not None:
                self.config = SessionConfig.model_validate({"speed": speed})
        except pydantic.ValidationError as exc:
            problem = describe_validation_error(exc.errors()[0])
            events.append(self._error("start", f"bad connection URL parameter: {problem}"))
            self.start = Start(log=params.get("log"), profile=params.get("profile"))
        cap = self.query.get("max_mbps")
        if cap is not None:
            try:
                self._url_cap = SessionConfig.model_validate({"max_mbps": cap}).max_mbps
            except pydantic.ValidationError:
                text = (
                    f"bad connection URL parameter 'max_mbps': {cap[:60]!r} is not a positive number of Mbit/s; no cap"
                )
                events.append(self._error("start", text))
        events += self._apply_detail()
        return events + self._begin()

    def receive(self, data: bytes | str) -> list[Event]:
        """A message arrived from the client."""
        try:
            request = parse_client_message(decode(data))
        except DecodeError as exc:
            return [self._error("malformed", f"malformed message: {exc}")]
        except MessageError as exc:
            where = f" (log {self.log.name!r})" if self.log is not None else ""
            return [self._error("invalid", f"{exc}{where}")]
        if isinstance(request, Start):
            return self._on_start(request)
        if isinstance(request, TransformLog):
            return self._on_transform_log(request)
        if isinstance(request, TransformPointInTime):
            return self._on_point_in_time(request)
        return self._on_reconfigure(request)

    def link_sampled(
        self,
        time: float,
        written: int,
        backlog: int,
        reader: bool = False,
        offered: int | None = None,
        busy: float | None = None,
    ) -> list[Event]:
        """A sample of the connection's delivery at ``time`` (monotonic seconds): bytes ``written`` so far,
        ``backlog`` of them not yet delivered, ``reader`` whether they waited for the client to read (see
        :class:`xviz_server.detail.Sample`), ``busy`` the seconds so far its link was busy, as the kernel
        counts them; for a live session, the updates its feed ``offered`` it so far (for the feed's rate)."""
        self._clock = time
        if offered is not None:
            self.chooser.offered(time, offered, self.config.decimate or 1)
        previous = self.chooser.level
        return self._detail_changed(previous, self.chooser.sample(Sample(time, written, backlog, reader, busy)))

    def update_made(self, level: Level, size: int) -> None:
        """An update of ``size`` bytes was made at ``level`` for this session."""
        self.chooser.made(level, size)

    def internal_error(self, what: str, error: BaseException) -> list[Event]:
        """Something unexpected failed while handling ``what``; the session goes on."""
        return [self._error("internal", f"internal server error while handling {what}: {error!r}")]

    # -- inputs: recorded logs -------------------------------------------

    def log_opened(self, log: LogView) -> list[Event]:
        """The log asked for with :class:`OpenLog` is open: send its metadata."""
        self.log = log
        index = log.index
        if (
            len(index) > 1
            and index.end_time is not None
            and index.start_time is not None
            and index.end_time > index.start_time
        ):
            self.chooser.rate = (len(index) - 1) / (index.end_time - index.start_time) * (self.config.speed or 1.0)
        return [Send(log.metadata_message(self.format), text=self.format is Format.JSON)]

    def log_failed(self, error: XVIZError) -> list[Event]:
        """The log asked for with :class:`OpenLog` cannot be served.

        A name given only as ``logGuid`` that is no recorded log is a live feed.
        """
        self.log = None
        if isinstance(error, LogNotFound) and self._guid_only() and self.start.log is not None:
            return self._go_live(exact=False)
        return [self._error("log", str(error))]

    def stream_ended(self, request_id: str) -> list[Event]:
        """The stream of ``request_id`` sent its last frame, or stopped when cancelled."""
        ended = self._streaming
        if ended is None or ended.request_id != request_id:
            return []
        events: list[Event] = [self._done(ended)]
        self._streaming = None
        if self._waiting:
            *skipped, newest = self._waiting
            self._waiting = []
            events += [self._done(request) for request in skipped]
            self._streaming = newest
            events.append(newest)
        return events

    def frame_failed(self, request_id: str, error: XVIZError) -> list[Event]:
        """One frame of a stream could not be had; the stream goes on."""
        return [self._error("frame", f"xviz/transform_log (id {request_id!r}) on log {self._log_name()!r}: {error}")]

    def query_failed(self, request_id: str, error: XVIZError) -> list[Event]:
        """A :class:`QueryInstant` could not be answered."""
        return [
            self._error(
                "query", f"xviz/transform_point_in_time (id {request_id!r}) on log {self._log_name()!r}: {error}"
            )
        ]

    # -- inputs: live feeds ----------------------------------------------

    def live_found(self, facts: LiveFacts) -> list[Event]:
        """What the registry knows of the feed asked for (see :class:`LookUpLive`): follow a feed, wait, or fail.

        A feed named in the URL's ``log`` (or a ``start`` message) is that
        feed only, waited for if no source has created it yet. A client that
        named none, or named one only by ``logGuid``, gets that feed if it has
        started, else the only running feed if there is just one
        (streetscape.gl's live loader example asks for ``mock``, whatever the
        feed is called), else that feed, waited for.
        """
        name = self.start.log
        if not facts.allowed:
            return self.live_failed(name)
        if not self._exact_feed and not facts.started and len(facts.running) == 1:
            return [SubscribeLive(facts.running[0])]
        if name is None:
            return self.live_failed(None)
        if facts.exists:
            return [SubscribeLive(name)]
        return [self._waiting_notice(name), SubscribeLive(name)]

    def live_failed(self, name: str | None) -> list[Event]:
        """No live feed answers to what the client asked for."""
        shown = ", ".join(repr(n) for n in self.live) or "none"
        what = f"named {name!r}" if name is not None else "to serve (several are running; name one)"
        return [self._error("live", f"no live feed {what}; live feeds: {shown}")]

    def live_joined(self, feed: str, state: int | None, started: bool) -> list[Event]:
        """The session subscribed to ``feed``; ``state`` is the number of the update its latest complete state ends at."""
        self._feed = feed
        if not started:
            return [self._waiting_notice(feed)]
        return self.live_started(state)

    def live_started(self, state: int | None) -> list[Event]:
        """The feed (re)started with new metadata; ``state`` as for :meth:`live_joined`."""
        self._covered = -1 if state is None else state
        events: list[Event] = [SendLiveMetadata(self.format)]
        if state is not None:
            events.append(SendLiveUpdate(state, self.variant))
        return events

    def live_gone(self) -> list[Event]:
        """The feed's source went away."""
        text = f"live feed {self._feed!r} went away; this session stays open and resumes when it comes back"
        return [self._error("gone", text, notice=True)]

    def live_update(self, number: int, dropped: int, behind: bool, queued: int = 0) -> list[Event]:
        """Update ``number`` of the feed is next for this viewer.

        ``dropped`` updates were dropped since the last call because the
        viewer fell behind; ``behind`` tells whether it still is; ``queued``
        more updates wait after this one. Those that queued up while the
        level of detail was too high for the link (at least
        :data:`STALE_QUEUE` of them, after a step down) are skipped: the
        viewer gets the feed's latest complete state instead
        (:class:`SkipToState`), and is back in real time.
        """
        events: list[Event] = []
        if dropped and not self._behind:
            events.append(
                self._error(
                    "behind",
                    f"live feed {self._feed!r}: this viewer is behind; {dropped} updates were dropped "
                    "(the oldest go first; viewers that stay behind are disconnected)",
                    notice=True,
                )
            )
        self._behind = behind
        stale, self._stale = self._stale, False
        if stale and queued >= STALE_QUEUE:
            events.append(SkipToState())
        elif number > self._covered:
            events.append(SendLiveUpdate(number, self.variant))
        return events

    def live_skipped(self, state: int | None) -> list[Event]:
        """Answer to :class:`SkipToState`: ``state`` is the number of the update the feed's latest complete state
        ends at (``None``: it has none); the updates up to it are not sent."""
        if state is None:
            return []
        self._covered = max(self._covered, state)
        return [SendLiveUpdate(state, self.variant)]

    def live_lagging(self, seconds: float) -> list[Event]:
        """The viewer has been dropping updates for ``seconds``."""
        if seconds <= self.lag_timeout:
            return []
        return [Close(CloseCode.TRY_AGAIN_LATER, f"too slow: dropped live updates for over {self.lag_timeout:g} s")]

    # -- state ----------------------------------------------------------

    @property
    def format(self) -> Format:
        """Format of the messages sent now."""
        chosen = self.config.message_format or self.start.message_format
        if chosen is not None:
            return chosen
        if self.log is not None:
            return self.log.format
        # Live point clouds are far cheaper as GLB; before a log opens, errors are JSON.
        return Format.BINARY if self.is_live else Format.JSON

    @property
    def is_live(self) -> bool:
        return self.start.session_type is SessionType.LIVE

    @property
    def variant(self) -> Variant:
        """How this live viewer wants updates now."""
        return Variant(self.format, stream_filter(self.config.desired_streams), self.config.max_points, self.level)

    @property
    def decimate(self) -> int:
        """A live viewer gets every ``decimate``-th update: its own choice times its level's."""
        return (self.config.decimate or 1) * self.chooser.level.every

    @property
    def level(self) -> Level:
        """The level of detail of what is sent now: the session's, or a level up being probed
        (see :attr:`xviz_server.detail.DetailChooser.sending`)."""
        return self.chooser.sending

    # -- handlers -------------------------------------------------------

    def _guid_only(self) -> bool:
        return "logGuid" in self.query and "log" not in self.query and self.start.session_type is None

    def _begin(self) -> list[Event]:
        name = self.start.log
        if self.is_live:
            if name is None and not self.live:
                return [
                    self._error("live", "session_type LIVE: this server has no live feeds; name one to wait for it")
                ]
            return self._go_live(exact=name is not None)
        if name is None:
            if len(self.available) != 1:
                return [self._error("log", self._choose_a_log())]
            name = self.available[0]
        self._requested_log = name
        return [OpenLog(name)]

    def _go_live(self, exact: bool) -> list[Event]:
        self.start = self.start.model_copy(update={"session_type": SessionType.LIVE})
        self._exact_feed = exact
        self.chooser.live = True
        return [LookUpLive(self.start.log)]

    def _waiting_notice(self, feed: str) -> Send:
        return self._error("waiting", f"live feed {feed!r} has not started yet; waiting for it", notice=True)

    def _choose_a_log(self) -> str:
        if not self.available:
            return "this server has no logs to serve"
        shown = ", ".join(repr(n) for n in self.available[:20])
        more = f" and {len(self.available) - 20} more" if len(self.available) > 20 else ""
        return f"no log named: add ?log=NAME to the URL or send xviz/start with 'log'; available: {shown}{more}"

    def _on_start(self, start: Start) -> list[Event]:
        # What the message leaves out keeps its value from the URL.
        self.start = self.start.model_copy(update=start.model_dump(exclude_unset=True))
        events = self._apply_detail() if "profile" in start.model_fields_set else []
        if self.log is not None and self.start.log in (None, self._requested_log):
            return events + self.log_opened(self.log)  # same log, maybe a new format: metadata again
        self.log = None
        return events + self._begin()

    def _on_transform_log(self, request: TransformLog) -> list[Event]:
        log = self._require_log("xviz/transform_log", request.id)
        if isinstance(log, Send):
            return [log]
        positions = log.index.range(request.start_timestamp, request.end_timestamp)
        stream = StreamFrames(
            request_id=request.id,
            log=log.name,
            frames=log.index.frames[positions],
            times=log.index.start[positions],
            fmt=self.format,
            streams=stream_filter(self.config.desired_streams, request.desired_streams),
            speed=self.config.speed,
        )
        if self._streaming is None:
            self._streaming = stream
            return [stream]
        cancel: list[Event] = [] if self._waiting else [CancelStream(self._streaming.request_id)]
        self._waiting.append(stream)
        return cancel

    def _on_point_in_time(self, request: TransformPointInTime) -> list[Event]:
        log = self._require_log("xviz/transform_point_in_time", request.id)
        if isinstance(log, Send):
            return [log]
        return [
            QueryInstant(
                request_id=request.id,
                log=log.name,
                instant=request.query_timestamp,
                fmt=self.format,
                streams=stream_filter(self.config.desired_streams, request.desired_streams),
            )
        ]

    def _on_reconfigure(self, request: Reconfigure) -> list[Event]:
        current = self.config.model_dump(mode="json", exclude_none=True)
        proposed = (
            request.config_update if request.update_type == "FULL" else merge_patch(current, request.config_update)
        )
        try:
            self.config = SessionConfig.model_validate(proposed)
        except pydantic.ValidationError as exc:
            problem, known = describe_validation_error(exc.errors()[0]), ", ".join(SessionConfig.model_fields)
            return [
                self._error(
                    "reconfigure", f"xviz/reconfigure: {problem} (supported keys: {known}); configuration unchanged"
                )
            ]
        events = self._apply_detail()
        if self.is_live:
            forward = {key: value for key, value in request.config_update.items() if key not in DETAIL_KEYS}
            events.append(ConfigureLive(self.decimate, forward))
        return events

    # -- helpers --------------------------------------------------------

    def _apply_detail(self) -> list[Event]:
        """Give the chooser what the client asked: a level or auto (``profile``), a cap (``max_mbps``)."""
        profile = self.config.profile or self.start.profile
        events: list[Event] = []
        fixed: Level | None = None
        if profile is not None:
            try:
                fixed = profile_level(profile)
            except ValueError as exc:  # only the start's can be wrong: reconfigure checks its own
                events.append(self._error("profile", f"profile: {exc}; the level of detail is chosen from the link"))
                self.start = self.start.model_copy(update={"profile": None})
        cap = self.config.max_mbps or self._url_cap
        previous = self.chooser.level
        changed = self.chooser.choose(fixed, None if cap is None else cap * 125_000, self._clock)
        events += self._detail_changed(previous, changed)
        if changed is None and self.query.get("detail_notices") == "1":
            events.append(self._detail_notice())
        return events

    def _detail_changed(self, previous: Level, level: Level | None) -> list[Event]:
        if level is None:
            return []
        events: list[Event] = [DetailChanged(level, previous, self.chooser.auto, self.chooser.estimate)]
        if self.is_live and level.every != previous.every:
            events.append(ConfigureLive(self.decimate, {}))
        if self.is_live and self.chooser.levels.index(level) > self.chooser.levels.index(previous):
            self._stale = True
        if self.query.get("detail_notices") == "1":
            events.append(self._detail_notice())
        return events

    def _detail_notice(self) -> Send:
        capacity = self.chooser.estimate
        data = {
            "level": self.chooser.level.name,
            "auto": self.chooser.auto,
            "levels": [level.name for level in self.chooser.levels] if self.chooser.enabled else [FULL.name],
            "link_mbps": None if capacity is None else round(capacity * 8 / 1e6, 1),
        }
        return Send(encode({"type": DETAIL_NOTICE, "data": data}, Format.JSON), text=True)

    def _require_log(self, kind: str, request_id: str) -> LogView | Send:
        if self.is_live:
            return self._error(
                "live",
                f"{kind} (id {request_id!r}): not available in a LIVE session, whose updates are pushed "
                "as they happen; connect without session_type=live to request ranges of a log",
            )
        if self.log is None:
            return self._error("log", f"{kind} (id {request_id!r}): no log is open; {self._choose_a_log()}")
        return self.log

    def _log_name(self) -> str | None:
        return self.log.name if self.log is not None else self._requested_log

    def _done(self, request: StreamFrames) -> Send:
        return Send(
            encode(TransformLogDone(id=request.request_id).to_envelope(), request.fmt), text=request.fmt is Format.JSON
        )

    def _error(self, kind: str, message: str, notice: bool = False) -> Send:
        fmt = self.format
        data = encode(Error(message=message).to_envelope(), fmt)
        if notice:
            return Send(data, text=fmt is Format.JSON, notice=kind, message=message)
        return Send(data, text=fmt is Format.JSON, error=kind, message=message)
