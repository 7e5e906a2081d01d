"""A clip of a log as an MCAP file: the Foxglove channels and messages of a time range, made as it is sent.

``GET /api/logs/NAME/export?start=S&end=E&format=mcap`` answers with an
indexed, chunked MCAP file (zstd) holding the same channels that a Foxglove
client of the log is offered, and the messages of every frame that starts in
``[S, E]``, each with its XVIZ time as log and publish time. ``S`` and ``E``
are read as ``xviz-server probe`` reads its times (see
:class:`~xviz_server.probe.Instant`): seconds in the log's own times, or
``+seconds`` after the log's start (its metadata's ``start_time``); either
may be left out. A range in which no frame starts (a time outside the log)
is refused with the log's span, never answered with an empty clip. Foxglove and Lichtblick open it
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

import logging
from collections.abc import AsyncGenerator, Mapping, Sequence
from dataclasses import dataclass
from typing import IO, cast
from urllib.parse import unquote

import numpy as np
from mcap.writer import CompressionType, Writer

from ..exceptions import ExportError, XVIZError
from ..logs import Log
from ..params import SHOWN, seconds, single
from ..probe.report import Instant
from ..work import Workers
from .frame import Message, frame_messages
from .translate import Plan

__all__ = [
    "FORMATS",
    "CHUNK_BYTES",
    "LIGHT_BYTES",
    "HELD_BYTES",
    "CUT_SHORT",
    "ExportRange",
    "export_path",
    "log_path",
    "parse_range",
    "first_error",
    "export",
]

logger = logging.getLogger(__name__)

_PREFIX, _SUFFIX = "/api/logs/", "/export"

#: The name of the metadata record of a clip that ends early: ``{"frame": N, "error": TEXT}``.
CUT_SHORT = "xviz-server.cut-short"
#: The formats ``format=`` may name.
FORMATS = ("mcap",)


@dataclass(frozen=True)
class ExportRange:
    """The part of a log to export: frames starting in ``[start, end]`` (``None``: the log's bound)."""

    start: Instant | None
    end: Instant | None

    def frames(self, log: Log) -> np.ndarray:
        """The positions in ``log.index`` of the frames of the range, in order.

        Raises :class:`ExportError` saying the log's span when a bound is
        given and no frame starts in the range.
        """
        index = log.index
        begins = (log.metadata.get("log_info") or {}).get("start_time")
        try:
            start, end = (None if bound is None else bound.resolve(begins) for bound in (self.start, self.end))
        except ValueError as exc:
            raise ExportError("start" if self.start is not None and self.start.relative else "end", str(exc)) from None
        if start is not None and end is not None and start > end:
            raise ExportError("start", f"start={self.start} is after end={self.end}")
        positions = index.range(start, end)
        if start is not None:  # frames that start in the range, not those that only overlap it
            positions = positions[index.start[positions] >= start]
        if not len(positions) and (start is not None or end is not None):
            asked = f"[{_shown(self.start, 'its start')}, {_shown(self.end, 'its end')}]"
            where = "start" if start is not None else "end"
            raise ExportError(where, f"no frame of log {log.name!r} starts in {asked}: {_span(log, begins)}")
        return positions


def _shown(bound: Instant | None, otherwise: str) -> str:
    return otherwise if bound is None else str(bound)


def _span(log: Log, begins: float | None) -> str:
    """The frame times of ``log``, absolute and after its start, as an error tells them."""
    if not len(log.index):
        return "it has no frames"
    first, last = float(log.index.start.min()), float(log.index.start.max())
    after = "" if begins is None else f" ({first - begins:+.6g} to {last - begins:+.6g} s after its start)"
    return (
        f"its frames start from {first!r} to {last!r} s{after}; give seconds in that span, or +seconds after the start"
    )


def log_path(path: str, suffix: str) -> str | None:
    """The log a URL path ``/api/logs/NAME`` + ``suffix`` (percent-decoded) names, or ``None``."""
    if not (path.startswith(_PREFIX) and path.endswith(suffix)) or len(path) <= len(_PREFIX) + len(suffix):
        return None
    return unquote(path[len(_PREFIX) : -len(suffix)])


def export_path(path: str) -> str | None:
    """The log an export URL path (``/api/logs/NAME/export``, percent-decoded) names, or ``None``."""
    return log_path(path, _SUFFIX)


def parse_range(parameters: Mapping[str, Sequence[str]]) -> ExportRange:
    """``start``, ``end`` and ``format`` from a query's parameters (each name with its values), read by
    :mod:`xviz_server.params`; raises :class:`~xviz_server.exceptions.QueryError` naming a bad one.

    ``start`` and ``end`` are seconds, or ``+seconds`` after the log's start (a
    ``+`` in the query must reach here as such, not as a space).
    """
    values = single(parameters, ("start", "end", "format"))
    fmt = values.get("format", "mcap")
    if fmt not in FORMATS:
        raise ExportError("format", f"format={fmt[:SHOWN]!r}: this server exports {', '.join(FORMATS)}")
    start, end = (_instant(key, values[key]) if values.get(key) else None for key in ("start", "end"))
    return ExportRange(start, end)


def _instant(name: str, text: str) -> Instant:
    """The time ``text`` of parameter ``name``: seconds, or ``+seconds`` after the log's start."""
    relative = text.startswith("+")
    return Instant(seconds(name, text[1:] if relative else text), relative=relative)


#: Bytes of messages an MCAP chunk holds before it is compressed and sent (the writer's default).
CHUNK_BYTES = 1 << 20
#: A message of at most this many bytes is light: it goes in chunks of its channel alone (see :class:`_Chunks`).
LIGHT_BYTES = 16 * 1024
#: Bytes of messages held for the chunks being filled at most (the group holding the most is written then).
HELD_BYTES = 4 * CHUNK_BYTES


async def first_error(log: Log, plan: Plan, positions: np.ndarray) -> XVIZError | None:
    """Why the first of the frames at ``positions`` cannot be read or converted, if it cannot: the export is then
    refused before its head is sent. Its messages stay in the frame cache for :func:`export`."""
    if not len(positions):
        return None
    _, errors = await frame_messages(log, plan, int(log.index.frames[positions[0]]))
    return errors[0] if errors else None


async def export(
    log: Log, plan: Plan, positions: np.ndarray, workers: Workers, *, strict: bool = False
) -> AsyncGenerator[bytes, None]:
    """The MCAP file of the frames at ``positions`` of ``log.index`` (see :meth:`ExportRange.frames`), in pieces as they
    are written.

    A frame that cannot be read or converted ends the clip before it: the
    file is finished there (summary and footer, readable), with a metadata
    record named :data:`CUT_SHORT` that names the frame and the error, and a
    warning is logged. With ``strict`` (a file kept for later requests) it
    raises the frame's :class:`~xviz_server.exceptions.XVIZError` instead.
    """
    out = _Pieces()
    # The chunks are cut by _Chunks, not by the writer's own size.
    writer = Writer(cast(IO[bytes], out), chunk_size=_NEVER, compression=CompressionType.ZSTD)
    writer.start(profile="", library="xviz-server")
    yield out.take()
    chunks = _Chunks(writer, _register(writer, plan))
    sequence = 0
    for number in log.index.frames[positions].tolist():
        messages, errors = await frame_messages(log, plan, number)
        if errors and strict:
            raise errors[0]
        if errors:
            logger.warning(
                "the export of log %r ends before frame %d, which cannot be read: %s", log.name, number, errors[0]
            )
            writer.add_metadata(CUT_SHORT, {"frame": str(number), "error": str(errors[0])})
            break
        sequence = await workers.io(chunks.add, messages, sequence)
        yield out.take()
    await workers.io(chunks.close)
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


#: The group of the heavy messages, which share their chunks (no MCAP channel has the id 0).
_SHARED = 0
#: The least a group written alone to bring the messages held under :data:`HELD_BYTES` holds: below it, all held
#: groups are written as one chunk (so that many light channels make no host of tiny chunks).
_SMALLEST = CHUNK_BYTES // 16
#: A chunk size the writer never reaches: :class:`_Chunks` cuts the chunks.
_NEVER = 1 << 62


class _Chunks:
    """A file's messages cut into chunks by weight: each light message (at most :data:`LIGHT_BYTES`: a pose, a
    transform, a value) in chunks of its channel alone, the heavy ones (point clouds, images) together, in time order.

    Readers read only the chunks whose index lists a channel they want
    (``@mcap/core``'s indexed reader, which Foxglove and Lichtblick use, and
    ``mcap``'s Python reader): a light channel read over the whole log costs
    its own bytes, not the log's, and a seek costs the heavy chunk of that
    time and the light chunks that hold it. A group's messages are held until
    they make :data:`CHUNK_BYTES`, or until all held pass :data:`HELD_BYTES`
    (the group holding the most is written then, or, if it holds less than
    :data:`_SMALLEST`, all groups in one chunk), or the end: a light chunk
    may span the whole log and come after the heavy chunks of its times, as
    MCAP allows (indexed readers merge overlapping chunks in time order).
    """

    def __init__(self, writer: Writer, channels: Mapping[int, int]) -> None:
        self._writer, self._channels = writer, channels
        self._groups: dict[int, list[tuple[int, int, bytes, int]]] = {}
        self._sizes: dict[int, int] = {}
        self._held = 0

    def add(self, messages: list[Message], sequence: int) -> int:
        """Add a frame's messages (see :func:`~xviz_server.foxglove.frame.frame_messages`), numbered from
        ``sequence``; the next sequence number. Writes the chunks that are full (it blocks)."""
        for channel_id, time, payload in messages:
            channel = self._channels[channel_id]
            group = channel if len(payload) <= LIGHT_BYTES else _SHARED
            self._groups.setdefault(group, []).append((channel, time, bytes(payload), sequence))
            self._sizes[group] = self._sizes.get(group, 0) + len(payload)
            self._held += len(payload)
            sequence += 1
            if self._sizes[group] >= CHUNK_BYTES:
                self._write(group)
        while self._held > HELD_BYTES:
            group = max(self._sizes, key=self._sizes.__getitem__)
            self._write(*([group] if self._sizes[group] >= _SMALLEST else self._groups))
        return sequence

    def close(self) -> None:
        """Write the chunks of the messages held: the heavy ones', then each light channel's (it blocks)."""
        for group in sorted(self._groups):
            self._write(group)

    def _write(self, *groups: int) -> None:
        """Write the held messages of ``groups`` as one chunk."""
        for group in groups:
            for channel, time, data, sequence in self._groups.pop(group):
                self._writer.add_message(channel, log_time=time, data=data, publish_time=time, sequence=sequence)
            self._held -= self._sizes.pop(group)
        self._writer.flush()
