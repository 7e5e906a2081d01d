"""Frames sent without copying their payload: the same bytes as websockets, the same limits.

The wire tests run a stock websockets server and one with
:class:`~xviz_server.framing.FramingConnection` side by side, on the standard
event loop and on uvloop (the server's loop), and read each with a client
that does the handshake itself and keeps every byte the server sent after it.
"""

from __future__ import annotations

import asyncio
import base64
import json
import ssl
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import trustme
import uvloop
from websockets.asyncio.client import connect
from websockets.asyncio.server import ServerConnection, serve
from websockets.frames import Frame, Opcode
from websockets.protocol import OPEN
from websockets.server import ServerProtocol

from helpers import close_received, eventually, paused_viewer, running_server
from xviz_server.codec import Format, decode, encode
from xviz_server.events import Variant
from xviz_server.framing import (
    SEPARATE_PAYLOAD,
    FramingConnection,
    FramingProtocol,
    frame_header,
    ready_to_write,
    write_message,
)

OP_TEXT, OP_BINARY, OP_CONT = Opcode.TEXT, Opcode.BINARY, Opcode.CONT
SIZES = [0, 125, 126, 65535, 65536]
KEY = base64.b64encode(b"sixteen byte key").decode()
LOOPS: dict[str, Callable[[Awaitable[Any]], Any]] = {"asyncio": asyncio.run, "uvloop": uvloop.run}


@pytest.fixture(scope="module")
def kitti_frame(kitti_log: Path) -> bytes:
    """A real 2.1 MB GLB frame: a lidar sweep and four camera images."""
    return (kitti_log / "2-frame.glb").read_bytes()


@pytest.fixture(scope="module")
def kitti_json(kitti_frame: bytes) -> bytes:
    """The same frame as JSON, as the server sends it to JSON viewers."""
    return encode(decode(kitti_frame), Format.JSON)


# ------------------------------------------------------------------ headers


@pytest.mark.parametrize("opcode", [OP_TEXT, OP_BINARY, OP_CONT])
@pytest.mark.parametrize("fin", [True, False])
def test_header_is_websockets_header(opcode, fin: bool, kitti_frame: bytes):
    for size in [*SIZES, 65537, len(kitti_frame)]:
        frame = Frame(opcode, kitti_frame[:size] if size <= len(kitti_frame) else bytes(size), fin)
        assert frame_header(frame) + frame.data == frame.serialize(mask=False), size


def test_header_encodings_are_rfc_6455():
    assert frame_header(Frame(OP_BINARY, b"")) == b"\x82\x00"
    assert frame_header(Frame(OP_TEXT, bytes(125))) == b"\x81\x7d"
    assert frame_header(Frame(OP_BINARY, bytes(126))) == b"\x82\x7e\x00\x7e"
    assert frame_header(Frame(OP_BINARY, bytes(65535))) == b"\x82\x7e\xff\xff"
    assert frame_header(Frame(OP_CONT, bytes(65536), fin=False)) == b"\x00\x7f" + (65536).to_bytes(8, "big")


def open_protocol() -> FramingProtocol:
    protocol = FramingProtocol()
    protocol.state = OPEN  # as after the opening handshake
    return protocol


def test_large_payload_is_queued_by_reference(kitti_frame: bytes):
    protocol = open_protocol()
    protocol.send_binary(kitti_frame)
    header, payload = protocol.data_to_send()
    assert payload is kitti_frame and header == b"\x82\x7f" + len(kitti_frame).to_bytes(8, "big")


@pytest.mark.parametrize(
    "payload", [bytes(SEPARATE_PAYLOAD - 1), bytearray(SEPARATE_PAYLOAD), memoryview(bytes(SEPARATE_PAYLOAD))]
)
def test_small_or_mutable_payloads_take_websockets_path(payload: Any):
    protocol = open_protocol()
    protocol.send_binary(payload)
    (written,) = protocol.data_to_send()
    assert written == Frame(OP_BINARY, bytes(payload)).serialize(mask=False)


# ------------------------------------------------------------------ the wire


def parse_frames(stream: bytes) -> tuple[list[tuple[bool, bool, int, int, bytes]], int]:
    """Unmasked frames in ``stream`` (RFC 6455, 5.2) as (fin, rsv1, opcode, length, header), and bytes used."""
    frames, position = [], 0
    while len(stream) - position >= 2:
        first, second = stream[position], stream[position + 1]
        assert not second & 0x80, "a server must not mask"
        length, size = second & 0x7F, 2
        if length == 126:
            size = 4
            length = int.from_bytes(stream[position + 2 : position + 4], "big") if len(stream) - position >= 4 else -1
        elif length == 127:
            size = 10
            length = int.from_bytes(stream[position + 2 : position + 10], "big") if len(stream) - position >= 10 else -1
        if length < 0 or len(stream) - position < size + length:
            break
        frames.append(
            (bool(first & 0x80), bool(first & 0x40), first & 0x0F, length, bytes(stream[position : position + size]))
        )
        position += size + length
    return frames, position


async def capture(
    port: int, *, deflate: bool, tls: ssl.SSLContext | None
) -> tuple[bytes, list[tuple[bool, bool, int, int, bytes]]]:
    """Every byte a server sends after its handshake response, until it closes; and its frames."""
    reader, writer = await asyncio.open_connection(
        "127.0.0.1", port, ssl=tls, server_hostname="localhost" if tls else None, limit=1 << 24
    )
    offer = "Sec-WebSocket-Extensions: permessage-deflate\r\n" if deflate else ""
    writer.write(
        f"GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {KEY}\r\nSec-WebSocket-Version: 13\r\n{offer}\r\n".encode()
    )
    head = await reader.readuntil(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 101 ") and (b"permessage-deflate" in head) == deflate, head
    stream = bytearray()
    frames: list[tuple[bool, bool, int, int, bytes]] = []
    while not frames or frames[-1][2] != 0x8:
        chunk = await reader.read(1 << 20)
        assert chunk, "the server closed before its close frame"
        stream += chunk
        frames, _ = parse_frames(stream)
    writer.write(b"\x88\x82\x00\x00\x00\x00\x03\xe8")  # close 1000, masked with a zero key
    try:
        stream += await reader.read()
    except (ConnectionError, ssl.SSLError):
        pass  # a TLS server may end without close_notify
    writer.close()
    frames, used = parse_frames(stream)
    assert used == len(stream), "trailing bytes after the last frame"
    return bytes(stream), frames


def script(
    kitti_frame: bytes, kitti_json: bytes, protocols: list[type]
) -> Callable[[ServerConnection], Awaitable[None]]:
    """A server handler sending every size, text and binary, with control frames between large frames."""

    async def handler(websocket: ServerConnection) -> None:
        protocols.append(type(websocket.protocol))
        for size in SIZES:
            await websocket.send(kitti_json[:size], text=True)
            await websocket.send(kitti_frame[:size])
        await websocket.send(kitti_frame)
        await websocket.ping(b"between")
        await websocket.send(kitti_json, text=True)
        await websocket.pong(b"unsolicited")
        await websocket.send(kitti_frame)
        await websocket.send([kitti_frame[: 1 << 20], kitti_frame[1 << 20 :]])  # binary, continuations
        await websocket.send(kitti_frame)
        await websocket.close(1000, "done")

    return handler


async def both_servers(
    handler: Any, deflate_offered: bool, tls: tuple[ssl.SSLContext, ssl.SSLContext] | None
) -> list[tuple[bytes, list]]:
    streams = []
    for create_connection in (None, FramingConnection):
        async with serve(
            handler,
            "127.0.0.1",
            0,
            ping_interval=None,
            compression="deflate",
            max_size=None,
            ssl=tls[0] if tls else None,
            create_connection=create_connection,
        ) as server:
            port = server.sockets[0].getsockname()[1]
            streams.append(await capture(port, deflate=deflate_offered, tls=tls[1] if tls else None))
    return streams


@pytest.fixture(scope="module")
def tls_contexts() -> tuple[ssl.SSLContext, ssl.SSLContext]:
    authority = trustme.CA()
    server = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    authority.issue_cert("localhost").configure_cert(server)
    client = ssl.create_default_context()
    authority.configure_trust(client)
    return server, client


@pytest.mark.parametrize("loop", LOOPS)
@pytest.mark.parametrize("deflate", [False, True], ids=["plain", "deflate"])
@pytest.mark.parametrize("tls", [False, True], ids=["ws", "wss"])
def test_bytes_on_the_wire_are_websockets_bytes(
    loop: str, deflate: bool, tls: bool, kitti_frame: bytes, kitti_json: bytes, tls_contexts
):
    protocols: list[type] = []
    handler = script(kitti_frame, kitti_json, protocols)
    (stock, stock_frames), (ours, our_frames) = LOOPS[loop](
        both_servers(handler, deflate, tls_contexts if tls else None)
    )
    assert protocols == [ServerProtocol, FramingProtocol]
    assert ours == stock
    assert our_frames == stock_frames
    kinds = [(opcode, fin) for fin, _, opcode, _, _ in our_frames]
    assert kinds == [
        *[(op, True) for _ in SIZES for op in (0x1, 0x2)],
        (0x2, True),
        (0x9, True),
        (0x1, True),
        (0xA, True),
        (0x2, True),
        (0x2, False),
        (0x0, False),
        (0x0, True),
        (0x2, True),
        (0x8, True),
    ]
    if deflate:
        assert all(rsv1 == (opcode in (0x1, 0x2)) for _, rsv1, opcode, _, _ in our_frames)
        assert sum(length for _, _, opcode, length, _ in our_frames if opcode == 0x2) < 5 * len(kitti_frame)
    else:
        lengths = [length for _, _, _, length, _ in our_frames]
        assert lengths[: 2 * len(SIZES)] == [size for size in SIZES for _ in (0, 1)]
        assert lengths[10:] == [
            len(kitti_frame),
            7,
            len(kitti_json),
            11,
            len(kitti_frame),
            1 << 20,
            len(kitti_frame) - (1 << 20),
            0,
            len(kitti_frame),
            6,
        ]
        headers = [header for _, _, opcode, _, header in our_frames if opcode == 0x2][:5]
        assert headers == [
            b"\x82\x00",
            b"\x82\x7d",
            b"\x82\x7e\x00\x7e",
            b"\x82\x7e\xff\xff",
            b"\x82\x7f" + (65536).to_bytes(8, "big"),
        ]


# ------------------------------------------------------------------ the server


def test_a_message_written_at_once_arrives_whole_and_only_while_the_connection_keeps_up(kitti_frame: bytes):
    # As a live feed's publish writes to a viewer who keeps up: no coroutine, no wait.
    async def main() -> dict[str, Any]:
        seen: dict[str, Any] = {}

        async def handler(connection: ServerConnection) -> None:
            seen["open"] = ready_to_write(connection)
            write_message(connection, kitti_frame, text=False)
            write_message(connection, b'{"type": "xviz/state_update"}', text=True)
            writes = 2
            while ready_to_write(connection) and writes < 40:  # the client stops reading: the buffer fills
                write_message(connection, kitti_frame, text=False)
                writes += 1
            seen["writes before the buffer is full"] = writes
            await connection.wait_closed()
            seen["closed"] = ready_to_write(connection)

        async with serve(handler, "127.0.0.1", 0, create_connection=FramingConnection, max_size=None) as server:
            port = server.sockets[0].getsockname()[1]
            async with connect(f"ws://127.0.0.1:{port}/", max_size=None, max_queue=1) as client:
                assert await client.recv() == kitti_frame
                assert await client.recv() == '{"type": "xviz/state_update"}'
                while "writes before the buffer is full" not in seen:
                    await asyncio.sleep(0.01)
                for _ in range(
                    seen["writes before the buffer is full"] - 2
                ):  # the rest: the close is not held up behind it
                    assert await client.recv() == kitti_frame
        return seen

    seen = uvloop.run(main())
    assert seen["open"] and not seen["closed"]
    assert 2 < seen["writes before the buffer is full"] < 40


def transform_log(request_id: str) -> str:
    return json.dumps({"type": "xviz/transform_log", "data": {"id": request_id}})


def test_stalled_clients_keep_evicted_frames_and_bounded_buffers(kitti_root: Path, kitti_log: Path):
    """Ten clients stop reading mid-log while a small cache evicts the frames they wait on; they get every byte."""
    files = [(kitti_log / f"{i}-frame.glb").read_bytes() for i in range(2, 27)]
    largest = max(map(len, files))

    async def scenario() -> None:
        async with running_server(kitti_root, cache_mb=3, read_ahead=1) as server:
            stalled = []
            for i in range(10):
                websocket = await connect(f"ws://127.0.0.1:{server.port}/kitti", max_size=None, max_queue=1)
                await websocket.recv()
                await websocket.send(transform_log(f"s{i}"))
                websocket.transport.pause_reading()
                stalled.append(websocket)
            # Each stops mid-log: the server holds bytes it cannot write to it.
            await eventually(
                lambda: (
                    sum(bool(session.websocket.transport.get_write_buffer_size()) for session in server.sessions) == 10
                )
            )
            for i in range(2):  # another client streams the log twice: the cache evicts what the others wait on
                async with connect(f"ws://127.0.0.1:{server.port}/kitti", max_size=None) as websocket:
                    await websocket.recv()
                    await websocket.send(transform_log(f"g{i}"))
                    received = [await websocket.recv() for _ in range(26)]
                    assert received[:25] == files
            assert server.cache.size <= 3 * 2**20
            buffered = [
                session.websocket.transport.get_write_buffer_size()
                for session in server.sessions
                if session.frames_sent < 25
            ]
            assert len(buffered) == 10
            # each holds at most the frame being written plus the high-water mark
            assert all(0 < size <= largest + 2**16 for size in buffered), buffered
            for websocket in stalled:
                websocket.transport.resume_reading()
            for websocket in stalled:
                received = [await asyncio.wait_for(websocket.recv(), 30) for _ in range(26)]
                assert received[:25] == files
                await websocket.close()

    uvloop.run(scenario())


def test_a_live_viewer_that_stops_reading_large_frames_is_closed_by_the_lag_limit(
    kitti_root: Path, kitti_log: Path, kitti_frame: bytes
):
    metadata = decode((kitti_log / "1-frame.glb").read_bytes())["data"]

    async def scenario() -> None:
        async with running_server(kitti_root, live_queue=2, live_lag_timeout=0.5) as server:
            feed = server.live.feed("car")
            feed.set_metadata(metadata)
            slow = await paused_viewer(server, "/?log=car&session_type=live")
            for _ in range(20):
                await feed.publish(kitti_frame)
                await asyncio.sleep(0.1)
            slow.transport.resume_reading()
            assert (await close_received(slow)).code == 1013
            await eventually(lambda: not server.sessions)

    uvloop.run(scenario())


def test_live_fan_out_shares_one_payload_and_every_viewer_gets_it(
    kitti_root: Path, kitti_log: Path, kitti_frame: bytes
):
    metadata = (kitti_log / "1-frame.glb").read_bytes()

    async def scenario() -> None:
        async with running_server(kitti_root) as server:
            feed = server.live.feed("car")
            feed.set_metadata(decode(metadata)["data"])
            viewers = [
                await connect(f"ws://127.0.0.1:{server.port}/?log=car&session_type=live", max_size=None)
                for _ in range(20)
            ]
            for viewer in viewers:
                assert decode(await viewer.recv())["type"] == "xviz/metadata"
            await eventually(lambda: all(session._live_idle for session in server.sessions))  # each waits for it
            update = await feed.publish(kitti_frame)
            assert await update.encoded(Variant(Format.BINARY), server.workers) is kitti_frame
            for viewer in viewers:
                assert await asyncio.wait_for(viewer.recv(), 10) == kitti_frame
                await viewer.close()

    uvloop.run(scenario())
