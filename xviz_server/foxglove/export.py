"""A clip of a log as an MCAP file: the Foxglove channels and messages of a time range.

``GET /api/logs/NAME/export?start=S&end=E&format=mcap`` answers with an
indexed, chunked MCAP file (zstd) holding the same channels that a Foxglove
client of the log is offered, and the messages of every frame that starts in
``[S, E]`` (seconds, the log's own times; either may be left out), each with
its XVIZ time as log and publish time. Foxglove and Lichtblick open it
offline. The frames' messages come from the frame cache, converted once as
for a Foxglove session; a log read from a ROS bag or MCAP file has its
original topics too, each message of a frame's span unchanged.

The file is made whole before it is sent, so a clip is bounded: one whose
messages pass ``export_max_mb`` is refused (HTTP 413) before it is written,
with the size it reached.

The file is written with the published ``mcap`` package (Foxglove's own
writer), in a thread.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass
from urllib.parse import unquote

from mcap.writer import CompressionType, Writer

from ..exceptions import ExportError
from ..logs import Log
from ..work import Workers
from .convert import Plan
from .frame import Message, frame_messages

__all__ = ["FORMATS", "ExportRange", "export_path", "parse_range", "export"]

_PREFIX, _SUFFIX = "/api/logs/", "/export"

#: The formats ``format=`` may name.
FORMATS = ("mcap",)


@dataclass(frozen=True)
class ExportRange:
    """The part of a log to export: frames starting in ``[start, end]`` seconds (``None``: the log's bound)."""

    start: float | None
    end: float | None


def export_path(path: str) -> str | None:
    """The log an export URL path (``/api/logs/NAME/export``, percent-decoded) names, or ``None``."""
    if not (path.startswith(_PREFIX) and path.endswith(_SUFFIX)) or len(path) <= len(_PREFIX) + len(_SUFFIX):
        return None
    return unquote(path[len(_PREFIX):-len(_SUFFIX)])


def parse_range(query: Mapping[str, str]) -> ExportRange:
    """``start``, ``end`` and ``format`` from a query; raises :class:`ExportError` naming a bad one."""
    fmt = query.get("format", "mcap")
    if fmt not in FORMATS:
        raise ExportError(f"format={fmt!r}: this server exports {', '.join(FORMATS)}")
    bounds: dict[str, float | None] = {}
    for key in ("start", "end"):
        text = query.get(key)
        try:
            bounds[key] = None if text in (None, "") else float(text)
        except ValueError:
            raise ExportError(f"{key}={text!r} is not a number of seconds") from None
        value = bounds[key]
        if value is not None and not math.isfinite(value):
            raise ExportError(f"{key}={text!r} is not a finite number of seconds")
    start, end = bounds["start"], bounds["end"]
    if start is not None and end is not None and start > end:
        raise ExportError(f"start={start} is after end={end}")
    return ExportRange(start, end)


async def export(log: Log, plan: Plan, span: ExportRange, workers: Workers, max_bytes: int) -> bytes:
    """The MCAP file of ``span`` of ``log``; raises :class:`ExportError` when it would pass ``max_bytes``."""
    positions = log.index.range(span.start, span.end)
    if span.start is not None:  # frames that start in the range, not those that only overlap it
        positions = positions[log.index.start[positions] >= span.start]
    frames: list[list[Message]] = []
    size = 0
    for number in log.index.frames[positions].tolist():
        messages, errors = await frame_messages(log, plan, number)
        if errors:
            raise errors[0]
        size += sum(len(payload) for _, _, payload in messages)
        if size > max_bytes:
            raise ExportError(
                f"log {log.name!r}: the clip passes {max_bytes >> 20} MB of messages (export_max_mb) "
                f"after {len(frames)} of {len(positions)} frames; export a shorter range", too_large=True,
            )
        frames.append(messages)
    return await workers.io(_write, plan, frames, log.name)


def _write(plan: Plan, frames: list[list[Message]], name: str) -> bytes:
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="xviz-server")
    channels: dict[int, int] = {}
    for channel in plan.channels:
        schema = channel.schema
        data = base64.b64decode(schema.schema) if schema.schema_encoding == "protobuf" else schema.schema.encode()
        schema_id = writer.register_schema(schema.name, schema.schema_encoding, data)
        channels[channel.id] = writer.register_channel(channel.topic, schema.encoding, schema_id)
    sequence = 0
    for messages in frames:
        for channel_id, time, payload in messages:
            writer.add_message(channels[channel_id], log_time=time, data=bytes(payload), publish_time=time, sequence=sequence)
            sequence += 1
    writer.add_metadata("xviz", {"log": name})
    writer.finish()
    return out.getvalue()
