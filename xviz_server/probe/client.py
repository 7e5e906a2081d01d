"""A scripted XVIZ client for smoke tests: ``xviz-server probe URL``.

:func:`probe` opens a session the way streetscape.gl does (the log named in
the URL, no ``xviz/start``), waits for the metadata, asks for a range with
``xviz/transform_log`` and, when told, for an instant with
``xviz/transform_point_in_time``, checks every message that comes back, and
returns a :class:`ProbeReport`.

The session is *clean* when the report holds no error. Errors are:

* an ``xviz/error`` from the server, a message that does not decode, a
  timeout, the connection closing before the answers are in;
* metadata without ``version`` or with a ``log_info.start_time`` or
  ``end_time`` that is missing, zero or not finite (streetscape.gl never
  requests anything then);
* a state update without ``update_type`` or ``timestamp``, out of time
  order, outside the requested range, or without a pose within
  :data:`POSE_WINDOW` seconds of its timestamp (the viewer draws nothing);
* a ``transform_log_done`` for another request, a point-in-time answer that
  is not one ``COMPLETE_STATE`` update at or before the instant;
* with ``validate=True``, any violation of the XVIZ v2 schema.

Streams that frames carry but the metadata does not declare are warnings.

Schema validation stays fast on JSON point clouds: the validator checks the
first rows of long lists of numbers, as it does for numpy arrays (see
:mod:`xviz_server.validation`), so nothing is converted here.
"""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Sequence
from typing import Any, NamedTuple
from urllib.parse import urlsplit, urlunsplit

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
from websockets.uri import parse_uri

from ..codec import Format, decode, encode_json
from ..exceptions import DecodeError, MessageError, SchemaValidationError
from ..messages import envelope, is_number, unwrap
from ..state import update_streams
from ..validation import get_validator
from .report import Instant, ProbeReport, Problem

__all__ = ["POSE_WINDOW", "probe", "with_format"]

#: Seconds between a frame and its pose beyond which streetscape.gl draws nothing.
POSE_WINDOW = 0.4

#: Schema violations reported per message; the rest are counted.
SHOWN_VIOLATIONS = 5

#: Seconds of silence after an ``xviz/error`` (or a message that does not decode)
#: that end the wait for an answer: a request the server rejects gets no other.
AFTER_ERROR = 2.0

#: The type under which messages that do not decode are counted.
UNDECODABLE = "undecodable"


def with_format(url: str, fmt: Format | None) -> str:
    """``url`` asking for ``message_format=fmt`` in its query, the rest of it as written.

    Raises :class:`ValueError` if ``url`` is not a WebSocket URL.
    """
    try:
        parse_uri(url)
    except InvalidURI as exc:
        raise ValueError(f"{url!r} is not a WebSocket URL like ws://HOST:PORT/?log=NAME ({exc})") from None
    if fmt is None:
        return url
    parts = urlsplit(url)
    query = [item for item in parts.query.split("&") if item and item.partition("=")[0] != "message_format"]
    query.append(f"message_format={fmt.value}")
    return urlunsplit(parts._replace(query="&".join(query)))


async def probe(
    url: str,
    *,
    fmt: Format | None = None,
    start: Instant | None = None,
    end: Instant | None = None,
    streams: Sequence[str] | None = None,
    point_in_time: Instant | None = None,
    validate: bool = False,
    timeout: float = 30.0,
) -> ProbeReport:
    """Run one session against the server at ``url`` and report on it.

    ``fmt`` adds ``message_format`` to the URL; ``start`` and ``end`` bound the
    ``transform_log`` (the whole log by default); ``streams`` fills its
    ``desired_streams``; ``point_in_time`` also asks for the complete state
    at that instant; ``validate`` checks every message against the XVIZ
    schema; the session must be over within ``timeout`` seconds.

    Raises :class:`ValueError` for a URL that is not a WebSocket URL or a
    range that ends before it starts; every other problem is in the report.
    """
    target = with_format(url, fmt)
    if start is not None and end is not None and start.relative == end.relative and start.seconds > end.seconds:
        raise ValueError(f"the range starts at {start}, after its end at {end}")
    session = _Session(ProbeReport(target), validate)
    began = time.perf_counter()
    try:
        await asyncio.wait_for(session.run(start, end, streams, point_in_time), timeout)
    except asyncio.TimeoutError:
        session.error(f"timed out after {timeout:g} s")
    except ConnectionClosed as exc:
        session.error(f"the server closed the connection: {exc}")
    except (OSError, InvalidHandshake) as exc:
        session.error(f"cannot connect to {target}: {exc}")
    session.report.elapsed = time.perf_counter() - began
    return session.report


class _Received(NamedTuple):
    """A decoded message: its type, its data, and which one it was (``state_update #3``)."""

    kind: str
    data: Any
    where: str


class _Session:
    """One probe session: the conversation, and the checks on what it brings."""

    def __init__(self, report: ProbeReport, validate: bool) -> None:
        self.report = report
        self.validate = validate
        self.step = "connect"  # what the session is doing: where timeouts and closures happen
        self.failures = 0  # xviz/error messages and messages that do not decode
        self.failures_before_step = 0
        self.declared: set[str] = set()
        self.pose_streams: set[str] = set()
        self.check_poses = True
        self.log_start: float | None = None

    def error(self, what: str, where: str | None = None) -> None:
        """Record an error seen at ``where``, by default in the current step."""
        self.report.errors.append(Problem(where or self.step, what))

    async def run(
        self,
        start: Instant | None,
        end: Instant | None,
        streams: Sequence[str] | None,
        point_in_time: Instant | None,
    ) -> None:
        """Connect, then ask and check: the metadata, the range, the instant."""
        async with connect(self.report.url, max_size=None, open_timeout=None) as websocket:
            if not await self.await_metadata(websocket):
                return
            times = (start, end, point_in_time)
            try:
                low, high, instant = [None if t is None else t.resolve(self.log_start) for t in times]
            except ValueError as exc:
                self.error(str(exc))
                return
            # Without a pose stream among those asked for, frames have none, rightly.
            self.check_poses = streams is None or not self.pose_streams.isdisjoint(streams)
            await self.transform_log(websocket, low, high, streams)
            if instant is not None:
                await self.transform_point_in_time(websocket, instant, streams)

    def begin(self, step: str) -> None:
        """Start waiting for the answers of ``step``."""
        self.step = step
        self.failures_before_step = self.failures

    async def next_answer(self, websocket: ClientConnection) -> _Received | None:
        """The next message that decodes, or ``None`` when the server has nothing more to say.

        After an ``xviz/error`` in this step, the server has nothing more to
        say when it stays quiet for :data:`AFTER_ERROR` seconds.
        """
        while True:
            quiet = AFTER_ERROR if self.failures > self.failures_before_step else None
            try:
                received = await self.receive(websocket, quiet)
            except asyncio.TimeoutError:
                return None
            if received is not None:
                return received

    async def receive(self, websocket: ClientConnection, timeout: float | None = None) -> _Received | None:
        """The next message, counted and checked; ``None`` if it does not decode.

        Raises :class:`asyncio.TimeoutError` if none comes within ``timeout`` seconds.
        """
        message = await asyncio.wait_for(websocket.recv(decode=False), timeout)
        number = sum(self.report.messages.values()) + 1
        try:
            kind, data = unwrap(decode(message))
        except (DecodeError, MessageError) as exc:
            kind, data = UNDECODABLE, None
            self.failures += 1
            self.error(f"the message does not decode: {exc}", f"message #{number}")
        self.report.messages[kind] += 1
        self.report.bytes_by_type[kind] += len(message)
        if kind == UNDECODABLE:
            return None
        where = f"{kind.removeprefix('xviz/')} #{self.report.messages[kind]}"
        if kind == "xviz/error":
            self.failures += 1
            self.error(f"xviz/error: {data.get('message') if isinstance(data, dict) else data}")
        if self.validate:
            self.check_schema(kind, data, where)
        return _Received(kind, data, where)

    async def send(self, websocket: ClientConnection, name: str, data: dict[str, Any]) -> None:
        """Send ``xviz/<name>`` as a JSON text frame, as the JavaScript clients do."""
        await websocket.send(encode_json(envelope(name, data)).decode())

    async def await_metadata(self, websocket: ClientConnection) -> bool:
        """Wait for the metadata and check it; ``False`` if it never comes."""
        self.begin("metadata")
        while (received := await self.next_answer(websocket)) is not None:
            if received.kind == "xviz/metadata":
                self.check_metadata(received.data, received.where)
                return True
            if received.kind != "xviz/error":
                self.error(f"{received.kind} came before the metadata", received.where)
        return False

    def check_metadata(self, data: Any, where: str) -> None:
        """Note the log's streams and start; check what streetscape.gl needs to play it."""
        if not isinstance(data, dict):
            self.error("the metadata is not a JSON object", where)
            return
        info = data.get("log_info")
        self.report.log_info = info if isinstance(info, dict) else {}
        streams = data.get("streams")
        if isinstance(streams, dict):
            self.declared = set(streams)
            self.pose_streams = {
                name
                for name, stream in streams.items()
                if isinstance(stream, dict) and stream.get("category") == "POSE"
            }
        self.report.declared_streams = len(self.declared)
        if "version" not in data:
            self.error("no 'version': clients then read the log as XVIZ v1 and fail on every update", where)
        for key in ("start_time", "end_time"):
            value = self.report.log_info.get(key)
            if not is_number(value) or value == 0:
                what = f"log_info.{key} is {value!r}: streetscape.gl needs finite, non-zero times to play the log"
                self.error(what, where)
            elif key == "start_time":
                self.log_start = value

    async def transform_log(
        self, websocket: ClientConnection, low: float | None, high: float | None, streams: Sequence[str] | None
    ) -> None:
        """Ask for the frames from ``low`` to ``high`` and check them, up to the request's done."""
        request_id = _fresh_id()
        self.begin(f"transform_log {request_id}")
        request: dict[str, Any] = {"id": request_id}
        if low is not None:
            request["start_timestamp"] = low
        if high is not None:
            request["end_timestamp"] = high
        if streams:
            request["desired_streams"] = list(streams)
        await self.send(websocket, "transform_log", request)
        while (received := await self.next_answer(websocket)) is not None:
            if received.kind == "xviz/state_update":
                self.check_frame(received, low, high)
            elif received.kind == "xviz/transform_log_done":
                done = received.data.get("id") if isinstance(received.data, dict) else None
                if done != request_id:
                    self.error(f"the done is for request {done!r}, not {request_id!r}", received.where)
                return

    async def transform_point_in_time(
        self, websocket: ClientConnection, instant: float, streams: Sequence[str] | None
    ) -> None:
        """Ask for the complete state at ``instant`` and check the answer."""
        request_id = _fresh_id()
        self.begin(f"transform_point_in_time {request_id}")
        query: dict[str, Any] = {"id": request_id, "query_timestamp": instant}
        if streams:
            query["desired_streams"] = list(streams)
        await self.send(websocket, "transform_point_in_time", query)
        received = await self.next_answer(websocket)
        if received is None or received.kind == "xviz/error":
            return
        if received.kind != "xviz/state_update":
            self.error(f"answered with {received.kind}, not a state update", received.where)
            return
        times = self.check_update(received)
        if not times:
            return
        update_type = received.data.get("update_type")
        if update_type != "COMPLETE_STATE":
            self.error(f"update_type is {update_type!r}, not 'COMPLETE_STATE'", received.where)
        if max(times) > instant:
            self.error(f"the state at {max(times)} is after the instant asked for, {instant}", received.where)

    def check_frame(self, received: _Received, low: float | None, high: float | None) -> None:
        """Check a frame of the range, and its place: in time order, inside the range."""
        report = self.report
        report.frames += 1
        times = self.check_update(received)
        if not times:
            return
        first, last = min(times), max(times)
        if report.last_time is not None and first < report.last_time:
            self.error(f"timestamp {first} comes after {report.last_time}: out of time order", received.where)
        if (low is not None and last < low) or (high is not None and first > high):
            self.error(f"timestamp {first} is outside the range asked for, {_span(low, high)}", received.where)
        report.first_time = first if report.first_time is None else min(report.first_time, first)
        report.last_time = last if report.last_time is None else max(report.last_time, last)

    def check_update(self, received: _Received) -> list[float]:
        """Check a state update on its own; return its timestamps (none when unreadable)."""
        data, where = received.data, received.where
        if not isinstance(data, dict):
            self.error("the state update is not a JSON object", where)
            return []
        if "update_type" not in data:
            self.error("no 'update_type': the client throws on such an update", where)
        stream_sets = data.get("updates")
        if not (isinstance(stream_sets, list) and stream_sets and all(isinstance(s, dict) for s in stream_sets)):
            self.error("'updates' must be a non-empty list of stream sets", where)
            return []
        times = [stream_set.get("timestamp") for stream_set in stream_sets]
        if not all(is_number(t) for t in times):
            self.error(f"'timestamp' must be a finite number in every stream set, not {times}", where)
            return []
        if self.check_poses:
            self.check_pose(stream_sets, where)
        self.note_streams(update_streams(data), where)
        return times

    def check_pose(self, stream_sets: list[dict[str, Any]], where: str) -> None:
        """Check that every stream set has a pose within :data:`POSE_WINDOW` of its timestamp."""
        poses = [
            pose.get("timestamp", stream_set["timestamp"])
            for stream_set in stream_sets
            if isinstance(stream_set.get("poses"), dict)
            for pose in stream_set["poses"].values()
            if isinstance(pose, dict)
        ]
        for stream_set in stream_sets:
            t = stream_set["timestamp"]
            if not any(is_number(p) and abs(p - t) <= POSE_WINDOW for p in poses):
                self.error(f"no pose within {POSE_WINDOW} s of timestamp {t}: streetscape.gl draws nothing", where)
                return

    def note_streams(self, names: set[str], where: str) -> None:
        """Add ``names`` to the streams seen, with a warning for each one the metadata lacks."""
        for name in sorted(names - self.declared - self.report.streams):
            self.report.warnings.append(Problem(where, f"stream {name!r} is not declared in the metadata"))
        self.report.streams |= names

    def check_schema(self, kind: str, data: Any, where: str) -> None:
        """Check a message against the XVIZ schema."""
        try:
            get_validator().validate_message(envelope(kind.removeprefix("xviz/"), data))
        except SchemaValidationError as exc:
            for violation in exc.problems[:SHOWN_VIOLATIONS]:
                self.error(f"schema: {violation}", where)
            if len(exc.problems) > SHOWN_VIOLATIONS:
                self.error(f"schema: {len(exc.problems) - SHOWN_VIOLATIONS} more violations", where)


def _span(low: float | None, high: float | None) -> str:
    return f"{'the start' if low is None else low} to {'the end' if high is None else high}"


def _fresh_id() -> str:
    """A request id no other request of the session has."""
    return uuid.uuid4().hex[:8]
