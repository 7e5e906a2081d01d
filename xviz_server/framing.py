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

Use it with ``serve(..., create_connection=FramingConnection, open_timeout=None)``
(:class:`FramingConnection` times the opening handshake itself, see below).

HTTP answers of any length go out as they are made: ``process_request`` may
return a :func:`streamed` response, whose head is sent as any answer's and
whose body then follows (in chunked transfer encoding when its length is not
known beforehand), piece by piece from an
asynchronous iterator, each piece written once the transport's buffer is
below its high-water mark (so what waits for a slow client is that buffer
and one piece). websockets ends every answer other than a switch to
WebSocket right after writing it, so the protocol here holds back that end
for a streamed one and the connection sends the body after the handshake:
the handshake proper (request, ``process_request``, head) keeps a time limit
of :data:`OPEN_TIMEOUT`, the body has none but its stall timeout. A
``process_request`` that has read a request it answers after a long wait
(a file made on first request) grants it more time with
:meth:`FramingConnection.allow`.

:func:`ready_to_write` and :func:`write_message` write one message to a
connection at once, from a live feed's publish, the way
``websockets.broadcast`` does, so that a fan-out to viewers who keep up does
not go through a coroutine per viewer (see docs/performance.md#live-fan-out:
this server against ``websockets.broadcast`` and raw writes).

This module overrides a private method of websockets (``send_frame``) and
the protocol's ``send_response``, relies on how the protocol queues outgoing
data (``writes``, ``data_to_send``), ends a response as ``send_response``
does (``send_eof``, ``discard``), registers a connection sending a body in
the server's ``all_connections``, and writes as ``websockets.broadcast`` does (the
protocol's ``state``, ``send_text``/``send_binary``, the connection's
``send_in_progress`` and ``send_data``); importing it raises
:exc:`~xviz_server.exceptions.DependencyError` unless the installed
websockets is a version it was tested with (:data:`TESTED_WEBSOCKETS`).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import struct
from collections.abc import AsyncGenerator, Awaitable, Callable
from http import HTTPStatus
from typing import Any

from websockets.asyncio.server import Server, ServerConnection
from websockets.datastructures import Headers
from websockets.frames import DATA_OPCODES, Frame
from websockets.http11 import SERVER, Request, Response
from websockets.protocol import State
from websockets.server import ServerProtocol
from websockets.typing import StatusLike
from websockets.version import version as websockets_version

from .exceptions import XVIZError
from .flow import watch_progress
from .version import require_tested
from .viewer import HEADERS

__all__ = [
    "close_body",
    "TESTED_WEBSOCKETS",
    "SEPARATE_PAYLOAD",
    "OPEN_TIMEOUT",
    "frame_header",
    "StreamedResponse",
    "streamed",
    "FramingProtocol",
    "FramingConnection",
    "ready_to_write",
    "write_message",
]

logger = logging.getLogger(__name__)

#: The websockets releases (major, minor) this module was tested with.
TESTED_WEBSOCKETS = frozenset({(17, 4)})

#: Smallest payload sent as a buffer of its own; below it, copying the
#: payload behind its header costs less than a second buffer.
SEPARATE_PAYLOAD = 16 * 1024

#: Seconds a connection has from its start to send its request and be sent
#: the head of the answer (websockets' own default ``open_timeout``).
OPEN_TIMEOUT = 10.0

_LAST_CHUNK = b"0\r\n\r\n"


#: How websockets' refusals begin, and the statuses of a request refused before it is read.
_WEBSOCKET_REFUSAL = "Failed to open a WebSocket connection"
_UNREAD = (HTTPStatus.REQUEST_URI_TOO_LONG, HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE)

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


@dataclasses.dataclass
class StreamedResponse(Response):
    """An HTTP answer whose body is sent in chunked transfer encoding as ``chunks`` yields it; see :func:`streamed`."""

    chunks: AsyncGenerator[bytes, None] | None = None
    #: Seconds the client may read nothing of the body before it is dropped.
    stall_timeout: float = 60.0
    #: The body's length, when known beforehand: then it is sent as it is, not in chunks.
    length: int | None = None


def streamed(
    response: Response, chunks: AsyncGenerator[bytes, None], stall_timeout: float, length: int | None = None
) -> StreamedResponse:
    """``response``'s status and headers, with a body sent as ``chunks`` yields it.

    Its ``Content-Length`` is replaced by ``Transfer-Encoding: chunked``, or,
    when the body's ``length`` is known, set to it: then ``chunks`` must
    yield exactly that many bytes (fewer or more: the body is cut short as
    when ``chunks`` raises). Once the head is sent, the pieces go out in order, each when the
    transport's buffer is below its high-water mark; an empty piece is
    skipped. The body ends early, the connection aborted so that the client
    sees a body cut short (no last chunk), when ``chunks`` raises (logged),
    when the client reads nothing for ``stall_timeout`` seconds, and when
    the server stops serving (at the next piece, or with the connections
    still open at its shutdown deadline). ``chunks`` is closed in every case.
    A response that is not sent (the client left, a ``HEAD``) never starts
    ``chunks``.
    """
    headers = Headers((key, value) for key, value in response.headers.raw_items() if key.lower() != "content-length")
    if length is None:
        headers["Transfer-Encoding"] = "chunked"
    else:
        headers["Content-Length"] = str(length)
    return StreamedResponse(
        response.status_code, response.reason_phrase, headers, chunks=chunks, stall_timeout=stall_timeout, length=length
    )


async def close_body(response: Response | None) -> None:
    """Close the body of ``response`` if it is a :class:`StreamedResponse` that has one: it will not be sent."""
    if isinstance(response, StreamedResponse) and response.chunks is not None:
        await response.chunks.aclose()


class FramingProtocol(ServerProtocol):
    """websockets' server protocol, queueing large data payloads by reference, holding back the end of a streamed
    answer; every HTTP answer it makes carries :data:`~xviz_server.viewer.HEADERS`."""

    def reject(self, status: StatusLike, text: str) -> Response:
        """An HTTP answer other than the handshake's 101, with :data:`~xviz_server.viewer.HEADERS`: the one place
        that builds them (:meth:`ServerConnection.respond` calls it, and websockets for its own refusals).

        A request refused unread (its line or headers too long) may be no
        WebSocket handshake: its body says the request could not be read,
        not that a WebSocket failed to open.
        """
        if status in _UNREAD and text.startswith(_WEBSOCKET_REFUSAL):
            text = "cannot read this request" + text[len(_WEBSOCKET_REFUSAL) :]
        response = super().reject(status, text)
        response.headers.update(HEADERS)
        return response

    def send_response(self, response: Response) -> None:
        """Queue ``response``; a :class:`StreamedResponse`'s head only, the stream left open for its body."""
        if not isinstance(response, StreamedResponse):
            super().send_response(response)
            return
        self.writes.append(response.serialize())
        self.logger.info("HTTP response started (%d %s)", response.status_code, response.reason_phrase)

    def end_response(self) -> None:
        """End the stream after a streamed answer's body, as websockets ends every other answer."""
        self.send_eof()
        self.parser = self.discard()
        next(self.parser)

    def send_frame(self, frame: Frame) -> None:
        data = frame.data
        if (
            self.extensions
            or frame.opcode not in DATA_OPCODES
            or type(data) is not bytes
            or len(data) < SEPARATE_PAYLOAD
        ):
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

    protocol: FramingProtocol
    _patience: float = 0.0  # seconds beyond OPEN_TIMEOUT that this handshake may take

    def __init__(self, protocol: ServerProtocol, server: Server, **kwargs: Any) -> None:
        protocol.__class__ = FramingProtocol
        super().__init__(protocol, server, **kwargs)

    def allow(self, seconds: float) -> None:
        """Let the handshake (``process_request`` answering) take up to ``seconds`` in all, rather than :data:`OPEN_TIMEOUT`."""
        self._patience = max(self._patience, seconds - OPEN_TIMEOUT)

    async def handshake(
        self,
        process_request: Callable[[ServerConnection, Request], Awaitable[Response | None] | Response | None]
        | None = None,
        process_response: Callable[[ServerConnection, Request, Response], Awaitable[Response | None] | Response | None]
        | None = None,
        server_header: str | None = SERVER,
    ) -> None:
        """websockets' opening handshake within :data:`OPEN_TIMEOUT` seconds (or what :meth:`allow` allowed), then a
        streamed answer's body."""
        handshake = asyncio.ensure_future(super().handshake(process_request, process_response, server_header))
        try:
            await asyncio.wait_for(asyncio.shield(handshake), OPEN_TIMEOUT)
        except asyncio.TimeoutError:
            if not self._patience:
                handshake.cancel()
                raise
            await asyncio.wait_for(handshake, self._patience)
        except BaseException:
            handshake.cancel()
            await close_body(getattr(self, "response", None))  # a body never sent is closed all the same
            raise
        response = self.response
        if isinstance(response, StreamedResponse) and response.chunks is not None:
            if self.protocol.state is State.CONNECTING:
                await self._send_body(response, response.chunks)
            else:
                await close_body(response)

    async def _send_body(self, response: StreamedResponse, chunks: AsyncGenerator[bytes, None]) -> None:
        transport = self.transport
        transport.pause_reading()  # the request is read: nothing after it is (a pipelined request is not answered)
        self.server.all_connections.add(self)  # aborted with the open ones when the server's shutdown runs late
        sent = 0
        left = response.length  # bytes still to send, when the length was given
        watchdog = asyncio.ensure_future(watch_progress(self, response.stall_timeout, lambda: sent))
        complete = False
        try:
            async for piece in chunks:
                if transport.is_closing():
                    break
                if not self.server.is_serving():
                    logger.info(
                        "%s: the answer to %s is cut short: the server is stopping", self.remote_address, self._path()
                    )
                    break
                if piece:
                    if left is None:
                        transport.writelines((b"%x\r\n" % len(piece), piece, b"\r\n"))
                    elif len(piece) > left:
                        raise XVIZError(f"the body is longer than its Content-Length, {response.length} bytes")
                    else:
                        transport.write(piece)
                        left -= len(piece)
                    sent += 1
                    await self.drain()
            else:
                if left:
                    raise XVIZError(f"the body ended {left} bytes short of its Content-Length, {response.length} bytes")
                complete = not transport.is_closing()
        except Exception as exc:
            if not transport.is_closing():
                logger.warning(
                    "%s: the body of the answer to %s failed: %s",
                    self.remote_address,
                    self._path(),
                    exc,
                    exc_info=not isinstance(exc, XVIZError),
                )
        finally:
            watchdog.cancel()
            self.server.all_connections.discard(self)
            if not complete:
                transport.abort()
            await chunks.aclose()
        if not complete:
            return
        if left is None:
            transport.write(_LAST_CHUNK)
        transport.resume_reading()
        if self.protocol.state is State.CONNECTING:  # else the client left: nothing to end
            async with self.send_context(expected_state=State.CONNECTING):
                self.protocol.end_response()

    def _path(self) -> str:
        """The request's path, without its query (which may hold a token)."""
        return self.request.path.partition("?")[0] if self.request is not None else "?"

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
