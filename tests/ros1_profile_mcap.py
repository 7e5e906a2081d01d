"""A real ROS 1 bag as an MCAP file of the ``ros1`` profile, written by the published ROS 1 writer.

``mcap convert`` (the MCAP CLI, in Go and Rust: neither runs here) makes such a file of a bag: profile ``ros1``,
one schema per message type (its ``ros1msg`` definition as the bag records it), channels of message encoding
``ros1``, every message's bytes unchanged with its record time as log and publish time. :func:`write_ros1_mcap`
does the same with ``mcap-ros1-support``'s ``mcap_ros1.writer.Writer``, reading the bag with rosbags: the writer
takes a message object with a ROS 1 type name, its full definition and a ``serialize`` method, which here writes
the recorded bytes as they are. What differs from the CLI's output: the writer's chunking and compression (zstd
chunks of 1 MiB), one channel per topic (the CLI makes one per bag connection, with the connection's other header
fields, such as ``callerid`` and ``latching``, as the channel's metadata; this writer leaves it empty) and
sequence numbers (0 here, counted by the CLI).
"""

from __future__ import annotations

from io import BytesIO
from pathlib import Path

from mcap_ros1.writer import Writer
from rosbags.rosbag1 import Reader


class _Recorded:
    """One recorded message for the writer: the bag's type name and definition, its bytes as recorded."""

    _type: str
    _full_text: str

    def __init__(self, data: bytes) -> None:
        self.data = data

    def serialize(self, buffer: BytesIO) -> None:
        buffer.write(self.data)


def write_ros1_mcap(bag: Path, target: Path) -> Path:
    """Write every message of the ROS 1 ``bag`` to ``target``, an MCAP file of the ``ros1`` profile."""
    with Reader(bag) as reader, target.open("wb") as output:
        kinds: dict[str, type[_Recorded]] = {}
        for connection in reader.connections:  # the ROS 1 name: rosbags spells pkg/Name as pkg/msg/Name
            name = connection.msgtype.replace("/msg/", "/", 1)
            definition = {"_type": name, "_full_text": connection.msgdef.data}
            kinds.setdefault(name, type(name.replace("/", "_"), (_Recorded,), definition))
        writer = Writer(output)
        for connection, time, data in reader.messages():
            message = kinds[connection.msgtype.replace("/msg/", "/", 1)](bytes(data))
            writer.write_message(connection.topic, message, log_time=time, publish_time=time)
        writer.finish()
    return target
