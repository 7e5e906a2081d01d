"""A scripted XVIZ client for smoke tests: ``xviz-server probe URL``.

It connects the way streetscape.gl does (the log in the URL, no start
message), waits for the metadata, asks for a range with ``transform_log``
(and an instant with ``transform_point_in_time`` if told), checks what comes
back, and reports. The session is *clean* when nothing went wrong: no
``xviz/error``, every message decodes, every state update has an
``update_type`` and a ``timestamp`` inside the range, in time order, with a
pose within 0.4 s of it (streetscape.gl draws nothing without one), the
reply ends with the request's ``transform_log_done``, and with ``validate``
every message matches the XVIZ schema.
"""

from __future__ import annotations

import asyncio
import math
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from .codec import Format, decode, encode_json
from .exceptions import DecodeError, MessageError, SchemaValidationError, XVIZError
from .messages import unwrap
from .state import update_streams
from .validation import get_validator

__all__ = ["ProbeReport", "probe", "Instant"]

POSE_WINDOW = 0.4  # seconds between a frame and its pose within which streetscape.gl draws


@dataclass(frozen=True)
class Instant:
    """A time given on the command line: absolute seconds, or an offset from the log start."""

    seconds: float
    relative: bool = False

    @classmethod
    def parse(cls, text: str) -> Instant:
        """``"1317042146.5"`` or ``"+1.5"`` (seconds after the log's start)."""
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"{text!r} is not a time: give seconds, or +seconds from the log's start") from None
        if not math.isfinite(value):
            raise ValueError(f"{text!r} is not a finite time")
        return cls(value, text.strip().startswith("+"))

    def resolve(self, log_start: float | None) -> float:
        if not self.relative:
            return self.seconds
        if log_start is None:
            raise XVIZError("a +offset time needs the log's start_time, which the metadata lacks")
        return log_start + self.seconds


@dataclass
class ProbeReport:
    """What a probe saw."""

    url: str
    messages: Counter[str] = field(default_factory=Counter)
    bytes: Counter[str] = field(default_factory=Counter)
    updates: int = 0
    first_time: float | None = None
    last_time: float | None = None
    streams: set[str] = field(default_factory=set)
    log_info: dict[str, Any] = field(default_factory=dict)
    declared_streams: int = 0
    elapsed: float = 0.0
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def clean(self) -> bool:
        return not self.errors and self.messages["xviz/metadata"] > 0

    def as_dict(self) -> dict[str, Any]:
        total = sum(self.bytes.values())
        return {
            "url": self.url,
            "clean": self.clean,
            "messages": dict(self.messages),
            "state_updates": self.updates,
            "bytes": {"total": total, **self.bytes},
            "time_range": [self.first_time, self.last_time],
            "streams": sorted(self.streams),
            "log_info": self.log_info,
            "declared_streams": self.declared_streams,
            "elapsed_s": round(self.elapsed, 3),
            "mb_per_s": round(total / 1e6 / self.elapsed, 1) if self.elapsed else None,
            "errors": self.errors,
            "warnings": self.warnings,
        }

    def render(self) -> str:
        data = self.as_dict()
        lines = [
            f"probe      {self.url}",
            f"result     {'clean' if self.clean else 'UNCLEAN'}",
            f"log_info   start {self.log_info.get('start_time')}  end {self.log_info.get('end_time')}  "
            f"({self.declared_streams} streams declared)",
            "messages   " + "  ".join(f"{kind.removeprefix('xviz/')} {count}" for kind, count in sorted(self.messages.items())),
            f"bytes      {data['bytes']['total']:,} in {data['elapsed_s']} s ({data['mb_per_s']} MB/s)",
            f"frames     {self.updates} from {self.first_time} to {self.last_time}",
            f"streams    {len(self.streams)}: {', '.join(sorted(self.streams))}",
        ]
        lines += [f"error      {text}" for text in self.errors]
        lines += [f"warning    {text}" for text in self.warnings]
        return "\n".join(lines)


def with_format(url: str, fmt: Format | None) -> str:
    """``url`` with ``message_format`` in its query when ``fmt`` is given."""
    if fmt is None:
        return url
    parts = urlsplit(url)
    query = [(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True) if k != "message_format"]
    return urlunsplit(parts._replace(query=urlencode([*query, ("message_format", fmt.value)])))


class _Session:
    """The checks on one connection, message by message."""

    def __init__(self, report: ProbeReport, validate: bool) -> None:
        self.report = report
        self.validate = validate
        self.declared: set[str] = set()

    def receive(self, data: bytes | str) -> tuple[str, Any]:
        """Decode, count and check one message; return its type and data."""
        kind_label = "binary" if isinstance(data, bytes) else "text"
        try:
            kind, content = unwrap(decode(data))
        except (DecodeError, MessageError) as exc:
            self.report.errors.append(f"a {kind_label} message does not decode: {exc}")
            return "undecodable", None
        self.report.messages[kind] += 1
        self.report.bytes[kind] += len(data)
        if kind == "xviz/error":
            self.report.errors.append(f"server error: {content.get('message') if isinstance(content, dict) else content}")
        if self.validate:
            try:
                get_validator().validate_message({"type": kind, "data": content})
            except SchemaValidationError as exc:
                self.report.errors += [f"{kind} #{self.report.messages[kind]}: {p}" for p in exc.problems[:5]]
        return kind, content

    def metadata(self, data: dict[str, Any]) -> None:
        info = data.get("log_info") or {}
        self.report.log_info = {k: info.get(k) for k in ("start_time", "end_time")}
        self.declared = set(data.get("streams") or ())
        self.report.declared_streams = len(self.declared)
        if "version" not in data:
            self.report.errors.append("metadata has no 'version': the client falls back to XVIZ v1")
        for key in ("start_time", "end_time"):
            value = info.get(key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value != 0):
                self.report.errors.append(f"metadata log_info.{key} is {value!r}: streetscape.gl needs it to play the log")

    def update(self, data: Any, low: float | None, high: float | None, where: str) -> None:
        report = self.report
        report.updates += 1
        if not isinstance(data, dict) or not data.get("updates"):
            report.errors.append(f"{where}: state update without 'updates'")
            return
        if "update_type" not in data:
            report.errors.append(f"{where}: state update without 'update_type' (the client throws)")
        times = [u.get("timestamp") for u in data["updates"]]
        if not all(isinstance(t, (int, float)) and not isinstance(t, bool) for t in times):
            report.errors.append(f"{where}: an update has no numeric 'timestamp'")
            return
        first, last = min(times), max(times)
        if report.last_time is not None and first < report.last_time:
            report.errors.append(f"{where}: timestamp {first} comes after {report.last_time}: out of time order")
        if (low is not None and last < low) or (high is not None and first > high):
            report.errors.append(f"{where}: timestamp {first} is outside the requested range [{low}, {high}]")
        report.first_time = first if report.first_time is None else min(report.first_time, first)
        report.last_time = last if report.last_time is None else max(report.last_time, last)
        self.check_pose(data, where)
        streams = update_streams(data)
        report.streams |= streams
        if undeclared := sorted(streams - self.declared):
            warning = f"streams not declared in the metadata: {', '.join(undeclared)}"
            if warning not in report.warnings:
                report.warnings.append(warning)

    def check_pose(self, data: dict[str, Any], where: str) -> None:
        for stream_set in data["updates"]:
            poses = stream_set.get("poses") or {}
            t = stream_set["timestamp"]
            near = [p for p in poses.values() if isinstance(p, dict) and abs(p.get("timestamp", t) - t) <= POSE_WINDOW]
            if not near:
                self.report.errors.append(f"{where}: no pose within {POSE_WINDOW} s of {t}: streetscape.gl draws nothing")
                return


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
    """Run one session against ``url`` and report on it.

    Raises :class:`ValueError` for a URL that is not a WebSocket URL; every
    other problem ends up in the report's ``errors``.
    """
    target = with_format(url, fmt)
    report = ProbeReport(target)
    session = _Session(report, validate)
    started = time.perf_counter()
    try:
        async with connect(target, max_size=None, open_timeout=timeout) as websocket:
            await asyncio.wait_for(_converse(websocket, session, start, end, streams, point_in_time), timeout)
    except InvalidURI as exc:
        raise ValueError(f"not a WebSocket URL: {exc}") from None
    except asyncio.TimeoutError:
        report.errors.append(f"timed out after {timeout:g} s")
    except ConnectionClosed as exc:
        report.errors.append(f"the server closed the connection early: {exc}")
    except (OSError, InvalidHandshake) as exc:
        report.errors.append(f"cannot connect: {exc}")
    except XVIZError as exc:
        report.errors.append(str(exc))
    report.elapsed = time.perf_counter() - started
    return report


def _text(message: dict[str, Any]) -> str:
    return encode_json(message).decode()


async def _converse(
    websocket: Any,
    session: _Session,
    start: Instant | None,
    end: Instant | None,
    streams: Sequence[str] | None,
    point_in_time: Instant | None,
) -> None:
    report = session.report
    while True:
        kind, data = session.receive(await websocket.recv())
        if kind == "xviz/metadata" and isinstance(data, dict):
            session.metadata(data)
            break
        if kind == "xviz/error":
            return  # no log: nothing to ask for
    log_start = report.log_info.get("start_time")
    low = start.resolve(log_start) if start else None
    high = end.resolve(log_start) if end else None
    request_id = uuid.uuid4().hex[:8]
    request: dict[str, Any] = {"id": request_id}
    if low is not None:
        request["start_timestamp"] = low
    if high is not None:
        request["end_timestamp"] = high
    if streams:
        request["desired_streams"] = list(streams)
    await websocket.send(_text({"type": "xviz/transform_log", "data": request}))
    while True:
        kind, data = session.receive(await websocket.recv())
        if kind == "xviz/state_update":
            session.update(data, low, high, f"frame {report.updates + 1}")
        elif kind == "xviz/transform_log_done":
            done = data.get("id") if isinstance(data, dict) else None
            if done != request_id:
                report.errors.append(f"transform_log_done for id {done!r}, expected {request_id!r}")
            break
    if point_in_time is not None:
        instant = point_in_time.resolve(log_start)
        query = {"id": f"{request_id}-p", "query_timestamp": instant}
        if streams:
            query["desired_streams"] = list(streams)
        await websocket.send(_text({"type": "xviz/transform_point_in_time", "data": query}))
        kind, data = session.receive(await websocket.recv())
        if kind == "xviz/state_update":
            if data.get("update_type") != "COMPLETE_STATE":
                report.errors.append(f"point in time {instant}: update_type {data.get('update_type')!r}, not COMPLETE_STATE")
            report.streams |= update_streams(data)
        elif kind != "xviz/error":
            report.errors.append(f"point in time {instant}: answered with {kind}")
