"""The XVIZ session protocol, without I/O.

A :class:`Session` is fed what happens on one connection (it opened, a
message arrived, the log it asked for was opened) and answers with events
that say what to do: :class:`Send` bytes, :class:`OpenLog`,
:class:`StreamFrames` for a ``transform_log``, :class:`QueryInstant` for a
``transform_point_in_time``, :class:`Cancel` the running stream. The asyncio
layer (:mod:`xviz_server.connection`) carries them out. Every decision about
the protocol lives here and can be tested by feeding messages, with no
socket.

Overlapping requests: a new ``transform_log`` cancels the one still
streaming; the cancelled request stops after the frame in flight and still
gets its ``transform_log_done``, before any frame of the new request.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol, Sequence, Union

import numpy as np
import pydantic

from .codec import Format, decode, encode
from .exceptions import DecodeError, MessageError, XVIZError
from .index import TimeIndex
from .messages import (
    Error,
    Reconfigure,
    SessionType,
    Start,
    TransformLog,
    TransformLogDone,
    TransformPointInTime,
    parse_client_message,
)

__all__ = [
    "Session",
    "SessionConfig",
    "LogView",
    "Send",
    "OpenLog",
    "StreamFrames",
    "QueryInstant",
    "Cancel",
    "SubscribeLive",
    "ConfigureLive",
    "Event",
]


class LogView(Protocol):
    """What a session needs to know of an open log (see :class:`xviz_server.logs.Log`)."""

    name: str
    format: Format
    index: TimeIndex

    def metadata_message(self, fmt: Format) -> bytes: ...


# ----------------------------------------------------------------- events


@dataclass(frozen=True)
class Send:
    """Send ``data``; as a text frame when ``text``. ``error`` names the kind of an error message."""

    data: bytes
    text: bool
    error: str | None = None


@dataclass(frozen=True)
class OpenLog:
    """Open the log a client asked for, then call :meth:`Session.log_opened` or :meth:`Session.log_failed`."""

    name: str


@dataclass(frozen=True, eq=False)
class StreamFrames:
    """Send these frames of ``log`` in order, then ``done``.

    ``times`` are the frames' start times, for pacing at ``speed`` times the
    log's rate; ``speed`` ``None`` means as fast as the client reads.
    """

    request_id: str
    log: LogView
    frames: np.ndarray
    times: np.ndarray
    fmt: Format
    streams: frozenset[str] | None
    speed: float | None
    done: Send


@dataclass(frozen=True, eq=False)
class QueryInstant:
    """Send the complete state of ``log`` at ``instant`` as one message."""

    request_id: str
    log: LogView
    instant: float
    fmt: Format
    streams: frozenset[str] | None


@dataclass(frozen=True)
class Cancel:
    """Stop the running stream after its frame in flight; it still sends its ``done``."""


@dataclass(frozen=True)
class SubscribeLive:
    """Join the live feed a client asked for, then push its updates.

    With a single feed running, a session gets it whatever it asked for;
    a named feed that has not started is waited for. If no feed answers
    (no name, several feeds), call :meth:`Session.live_failed`.
    """

    name: str | None


@dataclass(frozen=True)
class ConfigureLive:
    """The live session's configuration changed: use it for later updates.

    ``forward`` is the client's ``config_update``, for a source that accepts
    configuration.
    """

    fmt: Format
    streams: frozenset[str] | None
    decimate: int
    max_points: int | None
    forward: dict[str, Any]


Event = Union[Send, OpenLog, StreamFrames, QueryInstant, Cancel, SubscribeLive, ConfigureLive]


# ------------------------------------------------------------ configuration


class SessionConfig(pydantic.BaseModel):
    """What a session is sent, changed by ``xviz/reconfigure``.

    ``desired_streams``: streams sent (``None`` or empty: all), applied on top
    of each request's own filter. ``message_format``: format of later
    messages (``None``: the session's start format). ``speed``: pace streams
    at this multiple of the log's rate (``None``: as fast as the client reads).
    Live sessions only: ``decimate``, send every n-th update; ``max_points``,
    thin every point cloud to at most this many points.
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)
    desired_streams: list[str] | None = None
    message_format: Format | None = None
    speed: float | None = pydantic.Field(default=None, gt=0, allow_inf_nan=False)
    decimate: int | None = pydantic.Field(default=None, ge=1)
    max_points: int | None = pydantic.Field(default=None, ge=1)

    @pydantic.field_validator("message_format", mode="before")
    @classmethod
    def _upper(cls, value: Any) -> Any:
        return value.upper() if isinstance(value, str) else value


def _merge_patch(target: Any, patch: Any) -> Any:
    """RFC 7386 JSON merge patch: ``null`` removes a key, objects merge, the rest replaces."""
    if not isinstance(patch, dict):
        return patch
    result = dict(target) if isinstance(target, dict) else {}
    for key, value in patch.items():
        if value is None:
            result.pop(key, None)
        else:
            result[key] = _merge_patch(result.get(key), value)
    return result


def _stream_filter(*filters: Sequence[str] | None) -> frozenset[str] | None:
    """Intersect stream filters; ``None`` or empty means every stream."""
    result: frozenset[str] | None = None
    for names in filters:
        if names:
            result = frozenset(names) if result is None else result & frozenset(names)
    return result


# ----------------------------------------------------------------- session

URL_START_KEYS = ("version", "profile", "session_type", "message_format", "log")


@dataclass
class Session:
    """The protocol state of one connection.

    ``path`` and ``query`` come from the URL the client connected to;
    ``available`` lists the logs the server can open (to pick the only one
    when the client names none, and to list them when it must choose);
    ``live`` lists the live feeds.

    A session is LIVE when the client says so (``session_type=live``), or
    when it names its log only by ``logGuid`` (as streetscape.gl's
    ``XVIZLiveLoader`` does) and that name is not a recorded log. A live
    session waits for a feed that has not started yet.
    """

    path: str
    query: Mapping[str, str]
    available: Sequence[str]
    live: Sequence[str] = ()
    start: Start = field(init=False, default_factory=Start)
    config: SessionConfig = field(init=False, default_factory=SessionConfig)
    log: LogView | None = field(init=False, default=None)
    _requested_log: str | None = field(init=False, default=None)

    # -- inputs ---------------------------------------------------------

    def connect(self) -> list[Event]:
        """The connection opened: read the start parameters from the URL."""
        params = {key: self.query[key] for key in URL_START_KEYS if key in self.query}
        if "log" not in params:
            name = self.query.get("logGuid") or self.path.strip("/")
            if name:
                params["log"] = name
        speed = self.query.get("speed")
        events: list[Event] = []
        try:
            self.start = Start.model_validate(params)
            if speed is not None:
                self.config = SessionConfig(speed=speed)  # type: ignore[arg-type]
        except pydantic.ValidationError as exc:
            events.append(self._error("start", f"bad connection URL parameter: {_first_problem(exc)}"))
            self.start = Start(log=params.get("log"))
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

    def log_opened(self, log: LogView) -> list[Event]:
        """The log asked for with :class:`OpenLog` is open: send its metadata."""
        self.log = log
        return [Send(log.metadata_message(self.format), text=self.format is Format.JSON)]

    def live_failed(self, name: str | None) -> list[Event]:
        """No live feed answers to the name the client asked for."""
        shown = ", ".join(repr(n) for n in self.live) or "none"
        return [self._error("live", f"no live feed named {name!r}; live feeds: {shown}")]

    def live_notice(self, text: str) -> Send:
        """Tell a live viewer about the feed (it went away, updates were dropped)."""
        return self._error("live", text)

    def live_config(self, forward: dict[str, Any] | None = None) -> ConfigureLive:
        """The live configuration now in force."""
        return ConfigureLive(
            fmt=self.format,
            streams=_stream_filter(self.config.desired_streams),
            decimate=self.config.decimate or 1,
            max_points=self.config.max_points,
            forward=forward or {},
        )

    def log_failed(self, error: XVIZError) -> list[Event]:
        """The log asked for with :class:`OpenLog` cannot be served."""
        self.log = None
        return [self._error("log", str(error))]

    def frame_failed(self, request: StreamFrames, error: XVIZError) -> Send:
        """One frame of a ``transform_log`` could not be sent; the request goes on."""
        return self._error("frame", f"xviz/transform_log (id {request.request_id!r}) on log {request.log.name!r}: {error}")

    def query_failed(self, request: QueryInstant, error: XVIZError | str) -> Send:
        """A ``transform_point_in_time`` could not be answered."""
        return self._error(
            "query", f"xviz/transform_point_in_time (id {request.request_id!r}) on log {request.log.name!r}: {error}"
        )

    def internal_error(self, what: str, error: BaseException) -> Send:
        """Something unexpected failed while handling ``what``; the session goes on."""
        return self._error("internal", f"internal server error while handling {what}: {error!r}")

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
        return Format.BINARY if self.start.session_type is SessionType.LIVE else Format.JSON

    # -- handlers -------------------------------------------------------

    def _begin(self) -> list[Event]:
        name = self.start.log
        guid_only = "logGuid" in self.query and "log" not in self.query and self.start.session_type is None
        if guid_only and name not in self.available:
            self.start = self.start.model_copy(update={"session_type": SessionType.LIVE})
        if self.start.session_type is SessionType.LIVE:
            if name is None and not self.live:
                return [self._error("live", "session_type LIVE: this server has no live feeds; name one to wait for it")]
            return [SubscribeLive(name)]
        if name is None:
            if len(self.available) == 1:
                name = self.available[0]
            else:
                return [self._error("log", self._choose_a_log())]
        self._requested_log = name
        return [OpenLog(name)]

    def _choose_a_log(self) -> str:
        if not self.available:
            return "this server has no logs to serve"
        shown = ", ".join(repr(n) for n in self.available[:20])
        more = f" and {len(self.available) - 20} more" if len(self.available) > 20 else ""
        return f"no log named: add ?log=NAME to the URL or send xviz/start with 'log'; available: {shown}{more}"

    def _on_start(self, start: Start) -> list[Event]:
        # What the message leaves out keeps its value from the URL.
        self.start = self.start.model_copy(update=start.model_dump(exclude_unset=True))
        if self.log is not None and self.start.log in (None, self._requested_log):
            return self.log_opened(self.log)  # same log, maybe a new format: metadata again
        self.log = None
        return self._begin()

    def _on_transform_log(self, request: TransformLog) -> list[Event]:
        log = self._require_log("xviz/transform_log", request.id)
        if isinstance(log, Send):
            return [log]
        positions = log.index.range(request.start_timestamp, request.end_timestamp)
        fmt = self.format
        done = Send(encode(TransformLogDone(id=request.id).to_envelope(), fmt), text=fmt is Format.JSON)
        stream = StreamFrames(
            request_id=request.id,
            log=log,
            frames=log.index.frames[positions],
            times=log.index.start[positions],
            fmt=fmt,
            streams=_stream_filter(self.config.desired_streams, request.desired_streams),
            speed=self.config.speed,
            done=done,
        )
        return [Cancel(), stream]

    def _on_point_in_time(self, request: TransformPointInTime) -> list[Event]:
        log = self._require_log("xviz/transform_point_in_time", request.id)
        if isinstance(log, Send):
            return [log]
        return [
            QueryInstant(
                request_id=request.id,
                log=log,
                instant=request.query_timestamp,
                fmt=self.format,
                streams=_stream_filter(self.config.desired_streams, request.desired_streams),
            )
        ]

    def _on_reconfigure(self, request: Reconfigure) -> list[Event]:
        current = self.config.model_dump(mode="json", exclude_none=True)
        proposed = request.config_update if request.update_type == "FULL" else _merge_patch(current, request.config_update)
        try:
            self.config = SessionConfig.model_validate(proposed)
        except pydantic.ValidationError as exc:
            known = ", ".join(SessionConfig.model_fields)
            return [self._error("reconfigure", f"xviz/reconfigure: {_first_problem(exc)} (supported keys: {known}); configuration unchanged")]
        if self.start.session_type is SessionType.LIVE:
            return [self.live_config(request.config_update)]
        return []

    # -- helpers --------------------------------------------------------

    def _require_log(self, kind: str, request_id: str) -> LogView | Send:
        if self.start.session_type is SessionType.LIVE:
            return self._error(
                "live",
                f"{kind} (id {request_id!r}): not available in a LIVE session, whose updates are pushed "
                "as they happen; connect without session_type=live to request ranges of a log",
            )
        if self.log is None:
            return self._error("log", f"{kind} (id {request_id!r}): no log is open; {self._choose_a_log()}")
        return self.log

    def _error(self, kind: str, message: str) -> Send:
        fmt = self.format
        return Send(encode(Error(message=message).to_envelope(), fmt), text=fmt is Format.JSON, error=kind)


def _first_problem(exc: pydantic.ValidationError) -> str:
    error = exc.errors()[0]
    field_name = ".".join(str(part) for part in error["loc"]) or "value"
    if error["type"] == "extra_forbidden":
        return f"unknown key {field_name!r}"
    return f"{field_name!r}: {error['msg']} (got {error['input']!r})"
