"""The benchmarks' hand-written WebSocket client, in its two forms, and raw writes to viewers.

A benchmark that measures a server must not be limited by its client:

- :class:`RawClient` (asyncio, on a :class:`asyncio.BufferedProtocol`) reads
  into one reusable buffer and only counts payload bytes, keeping the first
  ``keep`` bytes of each message; :class:`WebsocketsClient` is the websockets
  asyncio client behind the same interface (what a Python viewer would use);
- :class:`Reader` is a blocking socket that reads responses into one reused
  buffer, for client processes that do nothing else.

Both write frames with :func:`masked_frame` after :func:`handshake_request`.
:func:`raw_writes` and :func:`forward` are the reference servers' side: raw
TCP with WebSocket framing, the machine's limit for a Python server.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import socket
import sys
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

import websockets
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import ServerConnection
from websockets.frames import Frame, Opcode

from xviz_server.framing import frame_header

__all__ = [
    "handshake_request",
    "masked_frame",
    "envelope_of",
    "WebsocketsClient",
    "RawClient",
    "CLIENTS",
    "Reader",
    "raw_writes",
    "forward",
]


def handshake_request(target: str, host: str = "127.0.0.1", subprotocol: str | None = None) -> bytes:
    """A client's opening handshake (RFC 6455 4.1) for ``target`` (path and query) on ``host``, offering ``subprotocol``."""
    key = base64.b64encode(os.urandom(16)).decode()
    offer = f"Sec-WebSocket-Protocol: {subprotocol}\r\n" if subprotocol else ""
    return (
        f"GET {target} HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n{offer}\r\n"
    ).encode()


def masked_frame(opcode: int, payload: bytes) -> bytes:
    """A client's final frame (RFC 6455 5.2) of ``opcode`` carrying ``payload``, masked as clients must."""
    n = len(payload)
    header = bytes([0x80 | opcode])
    header += (
        bytes([0x80 | n])
        if n < 126
        else bytes([0x80 | 126]) + n.to_bytes(2, "big")
        if n < 65536
        else bytes([0x80 | 127]) + n.to_bytes(8, "big")
    )
    key = os.urandom(4)
    mask = (key * (n // 4 + 1))[:n]
    masked = (int.from_bytes(payload, "big") ^ int.from_bytes(mask, "big")).to_bytes(n, "big") if n else b""
    return header + key + masked


def envelope_of(head: bytes) -> dict[str, Any]:
    """The XVIZ envelope of a GLB message (from its JSON chunk, which comes first) or a JSON one."""
    if head[:4] in (b"glTF", b"XVIZ"):
        length = int.from_bytes(head[12:16], "little")
        if len(head) < 20 + length:
            raise RuntimeError("kept too little of the message to read its JSON chunk")
        document = json.loads(head[20 : 20 + length])
        return document.get("xviz") or document["extensions"]["AVS_xviz"]
    return json.loads(head)


# ================================================================ clients
#
# Two client implementations behind one interface, both asyncio on uvloop:
#
# * "websockets": the websockets asyncio client, what a Python viewer would use.
#   Receiving a 2 MB message costs it about a millisecond of CPU (frames are
#   buffered and joined), so one such process tops out near what one core can
#   copy: it measures the client as much as the server.
# * "raw": a minimal RFC 6455 client on a BufferedProtocol: it reads into one
#   reusable buffer and only counts payload bytes, keeping the first ``keep``
#   bytes of each message. It needs far less CPU per byte, so the server (or
#   the reference) is what limits the rate. No compression.


class CountingConnection(ClientConnection):
    """A websockets client connection that counts the bytes it reads off the socket."""

    wire_bytes = 0

    def data_received(self, data: bytes) -> None:
        CountingConnection.wire_bytes += len(data)
        super().data_received(data)


class WebsocketsClient:
    def __init__(self, websocket: ClientConnection, keep: int) -> None:
        self.websocket, self.keep = websocket, keep
        self.extensions = websocket.response.headers.get("Sec-WebSocket-Extensions") if websocket.response else None

    @classmethod
    async def open(
        cls, url: str, keep: int = 512, compression: str | None = "deflate", max_queue: int = 16
    ) -> WebsocketsClient:
        websocket = await connect(
            url,
            max_size=None,
            compression=compression,
            create_connection=CountingConnection,
            ping_interval=None,
            proxy=None,
            open_timeout=60,
            max_queue=max_queue,
        )
        return cls(websocket, keep)

    async def recv(self) -> tuple[int, bytes, float]:
        message = await self.websocket.recv(decode=False)
        return len(message), message[: self.keep], time.perf_counter()

    async def send(self, text: str) -> None:
        await self.websocket.send(text)

    async def ping(self) -> None:
        await (await self.websocket.ping())

    def pause(self) -> None:
        self.websocket.transport.pause_reading()

    def abort(self) -> None:
        self.websocket.transport.abort()

    async def close(self) -> None:
        await self.websocket.close()

    @staticmethod
    def wire() -> int:
        return CountingConnection.wire_bytes


class RawProtocol(asyncio.BufferedProtocol):
    """The minimal WebSocket client: handshake, unmasked server frames counted in place, masked sends."""

    wire_bytes = 0

    def __init__(self, keep: int) -> None:
        self.keep = keep
        self.buffer = memoryview(bytearray(1 << 20))
        self.handshake: bytearray | None = bytearray()
        self.opened: asyncio.Future[str] = asyncio.get_running_loop().create_future()
        self.messages: asyncio.Queue[tuple[int, bytes, float] | None] = asyncio.Queue()
        self.header = bytearray()
        self.remaining = 0
        self.control: int | None = None  # opcode of the control frame being read
        self.control_payload = bytearray()
        self.fin = True
        self.size = 0
        self.head = bytearray()
        self.pong: asyncio.Future[None] | None = None
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def get_buffer(self, sizehint: int) -> memoryview:
        return self.buffer

    def buffer_updated(self, nbytes: int) -> None:
        RawProtocol.wire_bytes += nbytes
        view = self.buffer[:nbytes]
        if self.handshake is not None:
            self.handshake += view
            end = self.handshake.find(b"\r\n\r\n")
            if end < 0:
                return
            response, rest = bytes(self.handshake[:end]), bytes(self.handshake[end + 4 :])
            self.handshake = None
            if not response.startswith(b"HTTP/1.1 101"):
                self.opened.set_exception(RuntimeError(f"handshake refused: {response[:200]!r}"))
                return
            self.opened.set_result(response.decode("latin-1"))
            view = memoryview(rest)
        self._frames(view)

    def _frames(self, view: memoryview) -> None:
        pos, n = 0, len(view)
        while pos < n:
            if self.remaining:
                take = min(self.remaining, n - pos)
                if self.control is not None:
                    self.control_payload += view[pos : pos + take]
                else:
                    room = self.keep - len(self.head)
                    if room > 0:
                        self.head += view[pos : pos + min(take, room)]
                    self.size += take
                self.remaining -= take
                pos += take
                if not self.remaining:
                    self._frame_done()
                continue
            header = self.header
            need = 2
            while True:
                if len(header) >= 2:
                    short = header[1] & 0x7F
                    need = 2 + (2 if short == 126 else 8 if short == 127 else 0) + (4 if header[1] & 0x80 else 0)
                if len(header) >= need or pos >= n:
                    break
                take = min(need - len(header), n - pos)
                header += view[pos : pos + take]
                pos += take
            if len(header) < need:
                return
            opcode, short = header[0] & 0x0F, header[1] & 0x7F
            length = short if short < 126 else int.from_bytes(header[2:4] if short == 126 else header[2:10], "big")
            if opcode >= 8:
                self.control, self.control_payload = opcode, bytearray()
            else:
                self.control = None
                self.fin = bool(header[0] & 0x80)
                if opcode != 0:  # a new message (0 continues one)
                    self.size, self.head = 0, bytearray()
            self.header = bytearray()
            self.remaining = length
            if not length:
                self._frame_done()

    def _frame_done(self) -> None:
        if self.control is None:
            if self.fin:
                self.messages.put_nowait((self.size, bytes(self.head), time.perf_counter()))
            return
        opcode, payload, self.control = self.control, bytes(self.control_payload), None
        if opcode == 9:  # ping
            self._send_frame(10, payload)
        elif opcode == 10 and self.pong is not None and not self.pong.done():
            self.pong.set_result(None)
        elif opcode == 8 and self.transport is not None:
            self._send_frame(8, payload[:2])
            self.transport.close()

    def _send_frame(self, opcode: int, payload: bytes) -> None:
        assert self.transport is not None
        self.transport.write(masked_frame(opcode, payload))

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.opened.done():
            self.opened.set_exception(exc or ConnectionError("closed during the handshake"))
        self.messages.put_nowait(None)
        if self.pong is not None and not self.pong.done():
            self.pong.set_exception(ConnectionError("connection lost"))


class RawClient:
    def __init__(self, protocol: RawProtocol, response: str) -> None:
        self.protocol = protocol
        match = re.search(r"(?im)^sec-websocket-extensions:\s*(.*)$", response)
        self.extensions = match.group(1).strip() if match else None

    @classmethod
    async def open(
        cls,
        url: str,
        keep: int = 512,
        compression: str | None = None,
        max_queue: int = 16,
        subprotocol: str | None = None,
    ) -> RawClient:
        if compression:
            raise ValueError("the raw client does not do compression")
        parts = urlsplit(url)
        loop = asyncio.get_running_loop()
        assert parts.hostname and parts.port, url
        _, protocol = await loop.create_connection(lambda: RawProtocol(keep), parts.hostname, parts.port)
        target = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
        assert protocol.transport is not None
        protocol.transport.write(handshake_request(target, parts.netloc, subprotocol))
        response = await asyncio.wait_for(protocol.opened, 60)
        return cls(protocol, response)

    async def recv(self) -> tuple[int, bytes, float]:
        message = await self.protocol.messages.get()
        if message is None:
            raise ConnectionError("connection closed")
        return message

    async def send(self, text: str) -> None:
        self.protocol._send_frame(1, text.encode())

    async def ping(self) -> None:
        self.protocol.pong = asyncio.get_running_loop().create_future()
        self.protocol._send_frame(9, b"bench")
        await self.protocol.pong

    def pause(self) -> None:
        assert self.protocol.transport is not None
        self.protocol.transport.pause_reading()

    def abort(self) -> None:
        assert self.protocol.transport is not None
        self.protocol.transport.abort()

    async def close(self) -> None:
        self.protocol._send_frame(8, (1000).to_bytes(2, "big"))
        try:
            while await asyncio.wait_for(self.protocol.messages.get(), 5) is not None:
                pass
        except asyncio.TimeoutError:
            self.abort()

    @staticmethod
    def wire() -> int:
        return RawProtocol.wire_bytes


CLIENTS: dict[str, type[RawClient] | type[WebsocketsClient]] = {"raw": RawClient, "websockets": WebsocketsClient}


class Reader:
    """A blocking socket reading responses into one reused buffer."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.pending = bytearray()
        self.buffer = memoryview(bytearray(1 << 20))

    def take(self, n: int) -> bytes:
        while len(self.pending) < n:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise ConnectionError("the server closed the connection")
            self.pending += chunk
        data = bytes(self.pending[:n])
        del self.pending[:n]
        return data

    def skip(self, n: int) -> None:
        used = min(n, len(self.pending))
        del self.pending[:used]
        n -= used
        while n:
            got = self.sock.recv_into(self.buffer, min(n, len(self.buffer)))
            if not got:
                raise ConnectionError("the server closed the connection")
            n -= got

    def handshake(self, path: str) -> None:
        self.sock.sendall(handshake_request(path))
        while b"\r\n\r\n" not in self.pending:
            self.pending += self.sock.recv(1 << 16)
        head, _, rest = bytes(self.pending).partition(b"\r\n\r\n")
        if not head.startswith(b"HTTP/1.1 101"):
            raise ConnectionError(head.decode(errors="replace"))
        self.pending = bytearray(rest)

    def send_text(self, text: str) -> None:
        self.sock.sendall(masked_frame(0x1, text.encode()))

    def frame(self) -> tuple[int, int, bytes | None]:
        """The next frame's opcode, length and payload (``None`` for large payloads, skipped)."""
        first, second = self.take(2)
        length = second & 0x7F
        if length >= 126:
            length = int.from_bytes(self.take(2 if length == 126 else 8), "big")
        opcode = first & 0x0F
        if length >= 1 << 16:
            self.skip(length)
            return opcode, length, None
        payload = self.take(length)
        if opcode == 0x9:  # ping: answer, or the server closes us
            self.sock.sendall(masked_frame(0xA, payload))
        return opcode, length, payload

    def websocket_response(self) -> int:
        """Payload bytes of data frames until a small one saying done (xviz-server sends it as GLB or JSON)."""
        total = 0
        while True:
            opcode, length, payload = self.frame()
            if opcode in (0x1, 0x2) and payload is not None and b"done" in payload:
                return total
            if opcode in (0x0, 0x2):
                total += length


def raw_writes(viewers: set, message: bytes | memoryview) -> None:
    """Write a binary frame of ``message`` to each viewer: its header, then the message itself."""
    head = frame_header(Frame(Opcode.BINARY, message))
    for viewer in viewers:
        viewer.transport.writelines((head, message))


async def forward(viewers: set, pushed: Callable[[bytes], None]) -> None:
    """Serve WebSocket on a free loopback port: each message pushed to ``/ingest/...`` goes to ``pushed``,
    every other connection is in ``viewers`` while it is open."""

    async def handler(websocket: ServerConnection) -> None:
        assert websocket.request is not None
        if websocket.request.path.startswith("/ingest/"):
            async for message in websocket:
                assert isinstance(message, bytes), "a live source pushes GLB"
                pushed(message)
            return
        viewers.add(websocket)
        try:
            await websocket.wait_closed()
        finally:
            viewers.discard(websocket)

    async with websockets.serve(handler, "127.0.0.1", 0, max_size=None, compression=None) as server:
        print(f"listening on ws://127.0.0.1:{server.sockets[0].getsockname()[1]}/", file=sys.stderr, flush=True)
        await asyncio.Future()
