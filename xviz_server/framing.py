"""WebSocket data frames sent without copying their payload.

websockets' sans-I/O protocol serializes each frame into one new ``bytes``,
header and payload together. The frames this server sends are mostly cached
frames of megabytes, shared by every session that sends them: copying each
one per send costs about as much CPU as the kernel's own copy to the socket
(see docs/performance.md#sending-frames).

:class:`FramingProtocol` is websockets' server protocol, except that a data
frame (text, binary or continuation) whose payload is a ``bytes`` object of
at least :data:`SEPARATE_PAYLOAD` bytes is queued as two buffers: its 2-10
byte header and the payload object itself. :class:`FramingConnection` hands
them to the transport in one ``writelines`` call. The bytes on the wire are
the same as websockets writes. Everything else takes websockets' own path:
control frames, small frames, payloads that are not ``bytes`` (a
``bytearray`` could change while it waits in the transport) and every frame
of a connection that negotiated an extension (permessage-deflate transforms
the frames it compresses).

The transport holds a reference to the payload until the kernel has taken
all of it, so a frame evicted from the cache meanwhile stays valid (``bytes``
are immutable), and the transport's write buffer size counts it: the flow
control and limits of websockets work as before. uvloop writes the buffers
with one ``writev`` and keeps what the kernel did not take by reference, as
does the standard library's transport from Python 3.12; before 3.12 it joins
them, which is the copy websockets made anyway. TLS transports encrypt from
the buffers they are given.

Use it with ``serve(..., create_connection=FramingConnection)``.

:func:`ready_to_write` and :func:`write_message` write one message to a
connection at once, from a live feed's publish, the way
``websockets.broadcast`` does, so that a fan-out to viewers who keep up does
not go through a coroutine per viewer (see docs/performance.md#live-fan-out:
this server against ``websockets.broadcast`` and raw writes).

This module overrides a private method of websockets (``send_frame``),
relies on how the protocol queues outgoing data (``writes``,
``data_to_send``), and writes as ``websockets.broadcast`` does (the
protocol's ``state``, ``send_text``/``send_binary``, the connection's
``send_in_progress`` and ``send_data``); importing it raises
:exc:`~xviz_server.exceptions.DependencyError` unless the installed
websockets is a version it was tested with (:data:`TESTED_WEBSOCKETS`).
"""

from __future__ import annotations

import struct
from typing import Any

from websockets.asyncio.server import Server, ServerConnection
from websockets.frames import DATA_OPCODES, Frame
from websockets.protocol import State
from websockets.server import ServerProtocol
from websockets.version import version as websockets_version

from .version import require_tested

__all__ = [
    "TESTED_WEBSOCKETS", "SEPARATE_PAYLOAD", "frame_header", "FramingProtocol", "FramingConnection", "ready_to_write",
    "write_message",
]

#: The websockets releases (major, minor) this module was tested with.
TESTED_WEBSOCKETS = frozenset({(17, 4)})

#: Smallest payload sent as a buffer of its own; below it, copying the
#: payload behind its header costs less than a second buffer.
SEPARATE_PAYLOAD = 16 * 1024


require_tested(__name__, "websockets", websockets_version, TESTED_WEBSOCKETS, "pip install -e .")


def frame_header(frame: Frame) -> bytes:
    """The header of an unmasked ``frame`` without reserved bits (RFC 6455, 5.2)."""
    head = (0x80 if frame.fin else 0) | frame.opcode
    length = len(frame.data)
    if length < 126:
        return struct.pack("!BB", head, length)
    if length < 65536:
        return struct.pack("!BBH", head, 126, length)
    return struct.pack("!BBQ", head, 127, length)


class FramingProtocol(ServerProtocol):
    """websockets' server protocol, queueing large data payloads by reference."""

    def send_frame(self, frame: Frame) -> None:
        data = frame.data
        if self.extensions or frame.opcode not in DATA_OPCODES or type(data) is not bytes or len(data) < SEPARATE_PAYLOAD:
            super().send_frame(frame)
            return
        frame.check()
        if self.debug:
            self.logger.debug("> %s", frame)
        self.writes += (frame_header(frame), data)


class FramingConnection(ServerConnection):
    """A server connection whose protocol is a :class:`FramingProtocol`.

    websockets builds the :class:`~websockets.server.ServerProtocol` before
    the connection; it becomes a :class:`FramingProtocol`, a subclass that
    adds no state, at once.
    """

    def __init__(self, protocol: ServerProtocol, server: Server, **kwargs: Any) -> None:
        protocol.__class__ = FramingProtocol
        super().__init__(protocol, server, **kwargs)

    def send_data(self) -> None:
        """Write the protocol's outgoing data, several buffers in one call."""
        writes = self.protocol.data_to_send()
        if len(writes) > 1 and all(writes):
            self.transport.writelines(writes)
        else:  # one buffer, or an end of stream among them: websockets' own way
            self.protocol.writes[:0] = writes
            super().send_data()


def ready_to_write(connection: ServerConnection) -> bool:
    """Whether a message written to ``connection`` now goes out without waiting.

    It does when the connection is open, is not in the middle of a fragmented
    message (as ``websockets.broadcast`` checks), and its transport's write
    buffer is at most at its high-water mark (so that a viewer who fell
    behind is not sent more than a send that waits for the buffer would).
    """
    transport = connection.transport
    return (
        connection.protocol.state is State.OPEN
        and connection.send_in_progress is None
        and transport.get_write_buffer_size() <= transport.get_write_buffer_limits()[1]
    )


def write_message(connection: ServerConnection, data: bytes, text: bool) -> None:
    """Write ``data`` to ``connection`` as one text or binary message, at once, as ``websockets.broadcast`` does.

    Check :func:`ready_to_write` first. Raises what the write raises when the
    connection broke (its reader then ends it).
    """
    if text:
        connection.protocol.send_text(data)
    else:
        connection.protocol.send_binary(data)
    connection.send_data()
