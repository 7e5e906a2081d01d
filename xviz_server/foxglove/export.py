"""A clip of a log as an MCAP file: the Foxglove channels and messages of a time range, made as it is sent.

``GET /api/logs/NAME/export?start=S&end=E&format=mcap`` answers with an
indexed, chunked MCAP file (zstd) holding the same channels that a Foxglove
client of the log is offered, and the messages of every frame that starts in
``[S, E]`` (seconds, the log's own times; either may be left out), each with
its XVIZ time as log and publish time. Foxglove and Lichtblick open it
offline. The frames' messages come from the frame cache, converted once as
for a Foxglove session; a log read from a ROS bag or MCAP file has its
original topics too, each message of a frame's span unchanged.

:func:`export` yields the file in pieces as it is written: its start (magic
and header) at once, then each MCAP chunk (about :data:`CHUNK_BYTES` of
messages, compressed) with its message indexes as soon as it is full, then
the summary and footer. What it holds at a time is the chunk being filled
and the index of the chunks written (a few dozen bytes each), whatever the
length of the clip; the server sends it with
:func:`~xviz_server.framing.streamed`, so that a client that reads slowly
slows the writing down rather than making it buffer.

The file is written with the published ``mcap`` package (Foxglove's own
writer), in a thread.
"""

from __future__ import annotations

from collections.abc import AsyncGenerator, Mapping, Sequence
from dataclasses import dataclass
from typing import IO, cast
from urllib.parse import unquote

from mcap.writer import CompressionType, Writer

from ..exceptions import ExportError
from ..logs import Log
from ..params import SHOWN, seconds, single
from ..work import Workers
from .convert import Plan
from .frame import Message, frame_messages

__all__ = ["FORMATS", "CHUNK_BYTES", "ExportRange", "export_path", "parse_range", "export"]

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


def parse_range(parameters: Mapping[str, Sequence[str]]) -> ExportRange:
    """``start``, ``end`` and ``format`` from a query's parameters (each name with its values), read by
    :mod:`xviz_server.params`; raises :class:`~xviz_server.exceptions.QueryError` naming a bad one."""
    values = single(parameters, ("start", "end", "format"))
    fmt = values.get("format", "mcap")
    if fmt not in FORMATS:
        raise ExportError("format", f"format={fmt[:SHOWN]!r}: this server exports {', '.join(FORMATS)}")
    start, end = (seconds(key, values[key]) if values.get(key) else None for key in ("start", "end"))
    if start is not None and end is not None and start > end:
        raise ExportError("start", f"start={start} is after end={end}")
    return ExportRange(start, end)


#: Bytes of messages an MCAP chunk holds before it is compressed and sent (the writer's default).
CHUNK_BYTES = 1 << 20


async def export(log: Log, plan: Plan, span: ExportRange, workers: Workers) -> AsyncGenerator[bytes, None]:
    """The MCAP file of ``span`` of ``log``, in pieces as they are written.

    A frame that cannot be read or converted raises its
    :class:`~xviz_server.exceptions.XVIZError` (the file is then cut short).
    """
    positions = log.index.range(span.start, span.end)
    if span.start is not None:  # frames that start in the range, not those that only overlap it
        positions = positions[log.index.start[positions] >= span.start]
    out = _Pieces()
    writer = Writer(cast(IO[bytes], out), chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
    writer.start(profile="", library="xviz-server")
    yield out.take()
    channels = _register(writer, plan)
    sequence = 0
    for number in log.index.frames[positions].tolist():
        messages, errors = await frame_messages(log, plan, number)
        if errors:
            raise errors[0]
        sequence = await workers.io(_add, writer, channels, messages, sequence)
        yield out.take()
    writer.add_metadata("xviz", {"log": log.name})
    await workers.io(writer.finish)
    yield out.take()


class _Pieces:
    """A stream for the MCAP writer (it calls ``write``, ``tell`` and ``flush``) that keeps what was written until it is taken."""

    def __init__(self) -> None:
        self._pieces: list[bytes] = []
        self._offset = 0

    def write(self, data: bytes) -> int:
        self._pieces.append(bytes(data))
        self._offset += len(data)
        return len(data)

    def tell(self) -> int:
        return self._offset

    def flush(self) -> None:
        pass

    def take(self) -> bytes:
        """What was written since the last call."""
        data = b"".join(self._pieces)
        self._pieces.clear()
        return data


def _register(writer: Writer, plan: Plan) -> dict[int, int]:
    """Register the schema and channel of each of the plan's channels; the MCAP channel id of each channel id."""
    channels: dict[int, int] = {}
    for channel in plan.channels:
        schema = channel.schema
        schema_id = writer.register_schema(schema.name, schema.schema_encoding, schema.data())
        channels[channel.id] = writer.register_channel(channel.topic, schema.encoding, schema_id)
    return channels


def _add(writer: Writer, channels: Mapping[int, int], messages: list[Message], sequence: int) -> int:
    """Add a frame's messages (see :func:`~xviz_server.foxglove.frame.frame_messages`); the next sequence number."""
    for channel_id, time, payload in messages:
        writer.add_message(channels[channel_id], log_time=time, data=bytes(payload), publish_time=time, sequence=sequence)
        sequence += 1
    return sequence
