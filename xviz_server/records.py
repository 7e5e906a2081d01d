"""Messages packed into one ``bytes``, and the original topics of a recording.

A frame's Foxglove messages (converted from XVIZ) and a frame's original
messages (read unchanged from a ROS bag or an MCAP file) are each kept in
the frame cache as one ``bytes``: records of (channel, log time, payload),
made by :func:`pack` in a worker and read by :func:`unpack` without a copy.
What a channel number means is up to the maker: a Foxglove channel id for
converted messages, the index of an :class:`OriginalTopic` in the log's
list for original ones.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

__all__ = ["OriginalTopic", "RECORD_BYTES", "pack", "unpack"]

_RECORD = struct.Struct("<IQI")  # channel, log time (ns), payload length

#: What a record takes besides its payload.
RECORD_BYTES = _RECORD.size


@dataclass(frozen=True)
class OriginalTopic:
    """A topic of a recording as the file holds it: how its messages are encoded and their schema (picklable)."""

    topic: str
    encoding: str  #: the message encoding: ``ros1``, ``cdr``
    schema_name: str  #: ``sensor_msgs/PointCloud2`` (ROS 1), ``sensor_msgs/msg/PointCloud2`` (ROS 2)
    schema_encoding: str  #: ``ros1msg``, ``ros2msg`` or ``ros2idl``
    schema: str  #: the definition text, with the definitions it depends on


def pack(messages: Iterable[tuple[int, int, bytes | memoryview]]) -> bytes:
    """Messages as (channel, log time in ns, payload), packed into one ``bytes``."""
    parts: list[bytes | memoryview] = []
    for channel, time, payload in messages:
        parts += (_RECORD.pack(channel, time, len(payload)), payload)
    return b"".join(parts)


def unpack(packed: bytes) -> Iterator[tuple[int, int, memoryview]]:
    """The messages :func:`pack` packed, in order, their payloads as views of ``packed``."""
    view, offset = memoryview(packed), 0
    while offset < len(view):
        channel, time, size = _RECORD.unpack_from(view, offset)
        offset += _RECORD.size
        yield channel, time, view[offset : offset + size]
        offset += size
