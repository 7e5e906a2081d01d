"""The server as a hostile operator meets it: dying workers, logs that change, odd clients.

Real sockets on loopback, real files, real worker processes killed with a signal.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import ssl
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.client import connect

from helpers import client, eventually, running_server, ten_hz, timestamps, update, write_log
from xviz_server.codec import Format, encode


async def http(port: int, request: bytes, timeout: float = 10) -> bytes:
    """Send ``request`` as it is and read the answer until the server closes or its body is whole."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        await writer.drain()
        answer = b""
        while chunk := await asyncio.wait_for(reader.read(65536), timeout):
            answer += chunk
            head, _, body = answer.partition(b"\r\n\r\n")
            length = next(
                (
                    int(line.split(b":")[1])
                    for line in head.split(b"\r\n")
                    if line.lower().startswith(b"content-length:")
                ),
                None,
            )
            if length is not None and len(body) >= length:
                break
        return answer
    finally:
        writer.close()


async def get(port: int, path: str) -> tuple[int, bytes]:
    """Status and body of ``GET path``."""
    answer = await http(port, f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    head, _, body = answer.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


# ------------------------------------------------------------------ workers


async def transform(server, path: str, **request) -> list[float]:
    async with client(server, path) as c:
        await c.recv()
        await c.send("transform_log", {"id": "t", **request})
        messages = await c.until("transform_log_done", "t")
        assert [m["type"] for m in messages if m["type"] == "xviz/error"] == []
        return timestamps(messages)


async def test_a_killed_worker_process_is_replaced_and_healthz_says_so_meanwhile(tmp_path: Path):
    # Frames of 20 000 points as JSON are heavy: read, checked and transcoded in worker processes.
    write_log(tmp_path / "clouds", ten_hz(3, points=20_000), fmt=Format.JSON)
    async with running_server(tmp_path) as server:
        await server.workers.warm()
        expected = [100.0, 100.1, 100.2]

        # A job sent to the broken pool is tried again in a new one.
        os.kill(await server.workers.cpu(os.getpid), signal.SIGKILL)
        await asyncio.sleep(0.5)  # long enough for the pool to notice
        assert await transform(server, "/clouds?message_format=BINARY") == expected
        assert await get(server.port, "/healthz") == (200, b"ok\n")

        # Killed again, with no job to notice: /healthz does, and the pool is replaced.
        await server.workers.warm()  # the replacement is up (until then jobs run in a stand-in thread)
        victim = await server.workers.cpu(os.getpid)
        assert victim != os.getpid()
        os.kill(victim, signal.SIGKILL)
        health: list[tuple[int, bytes]] = []

        async def unhealthy() -> bool:
            health.append(await get(server.port, "/healthz"))
            return health[-1][0] != 200

        await eventually(unhealthy, 60)  # a loaded machine starts a pool slowly
        status, body = health[-1]
        assert status == 503 and b"a worker process died" in body
        assert await transform(server, "/clouds", desired_streams=["/points"]) == expected

        async def healthy() -> bool:
            return await get(server.port, "/healthz") == (200, b"ok\n")

        await eventually(healthy, 60)  # healthy while the replacement starts: jobs run in the stand-in thread
        await server.workers.warm()
        assert await server.workers.cpu(os.getpid) != os.getpid()  # processes again, not the stand-in thread


# ------------------------------------------------------------------ logs as found


async def test_an_index_whose_times_go_back_is_rebuilt_and_frames_come_in_time_order(tmp_path: Path):
    log = write_log(tmp_path / "reversed", ten_hz(5), fmt=Format.JSON)
    index = json.loads((log / "0-frame.json").read_text())
    times = [row[0] for row in index["timing"]]
    for row, t in zip(index["timing"], reversed(times)):  # the right frames, times reversed
        row[0] = row[1] = t
    (log / "0-frame.json").write_text(json.dumps(index))
    async with running_server(tmp_path) as server:
        assert await transform(server, "/reversed") == times


async def test_a_glb_frame_is_served_without_the_bytes_after_its_declared_end(tmp_path: Path):
    log = write_log(tmp_path / "padded", ten_hz(3))
    whole = (log / "3-frame.glb").read_bytes()
    (log / "3-frame.glb").write_bytes(whole + b"\x00junk" * 1000)
    async with running_server(tmp_path) as server, client(server, "/padded") as c:
        await c.recv()
        await c.send("transform_log", {"id": "t"})
        messages = await c.until("transform_log_done", "t")
        assert timestamps(messages) == [100.0, 100.1, 100.2]
        assert messages[1]["_bytes"] == len(whole)


async def test_a_frame_of_random_bytes_is_named_as_neither_glb_nor_json(tmp_path: Path):
    log = write_log(tmp_path / "noise", ten_hz(3))
    (log / "3-frame.glb").write_bytes(np.random.default_rng(17).bytes(4096))
    async with running_server(tmp_path) as server, client(server, "/noise") as c:
        await c.recv()
        await c.send("transform_log", {"id": "t"})
        messages = await c.until("transform_log_done", "t")
        errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
        assert len(errors) == 1 and "3-frame.glb" in errors[0] and "not a GLB or JSON frame" in errors[0], errors
        assert "UTF-8" not in errors[0]
        assert timestamps(messages) == [100.0, 100.2]


async def test_an_ingest_error_names_the_feed_once(tmp_path: Path):
    async with running_server(tmp_path) as server:
        async with connect(f"ws://127.0.0.1:{server.port}/ingest/car2") as source:
            await source.send(encode({"type": "xviz/state_update", "data": update(1.0)}, Format.JSON))
            error = json.loads(await asyncio.wait_for(source.recv(), 10))
            assert error["type"] == "xviz/error"
            assert error["data"]["message"].count("live feed 'car2'") == 1, error


# ------------------------------------------------------------------ what is not a GET


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"POST / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 5\r\n\r\nhello",  # curl -d hello
        b"POST / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",  # curl -X POST
        b"PUT /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    ],
)
async def test_a_request_other_than_get_is_answered_405(tmp_path: Path, request_bytes: bytes):
    write_log(tmp_path / "small", ten_hz(3))
    async with running_server(tmp_path) as server:
        head, _, body = (await http(server.port, request_bytes)).partition(b"\r\n\r\n")
        lines = head.split(b"\r\n")
        assert lines[0] == b"HTTP/1.1 405 Method Not Allowed"
        assert b"Allow: GET, HEAD" in lines and b"only GET and HEAD" in body
        assert await get(server.port, "/healthz") == (200, b"ok\n")
        assert await transform(server, "/small") == [100.0, 100.1, 100.2]


def _headers(head: bytes) -> dict[str, str]:
    return {
        name.lower(): value for name, _, value in (line.decode().partition(": ") for line in head.split(b"\r\n")[1:])
    }


async def test_head_answers_as_get_without_the_body_and_options_says_what_is_allowed(tmp_path: Path):
    write_log(tmp_path / "small", ten_hz(3))
    async with running_server(tmp_path) as server:
        for path, accept in [
            ("/healthz", "*/*"),
            ("/api/logs", "application/json"),
            ("/metrics", "*/*"),
            ("/nowhere", "*/*"),
        ]:
            heads = []
            for method in ("GET", "HEAD"):
                answer = await http(
                    server.port, f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: {accept}\r\n\r\n".encode()
                )
                head, _, body = answer.partition(b"\r\n\r\n")
                heads.append((head.split(b"\r\n")[0], _headers(head), body))
            (got, got_headers, got_body), (headed, head_headers, head_body) = heads
            assert headed == got and head_body == b"" and len(got_body) == int(head_headers["content-length"]) > 0, path
            assert head_headers["content-type"] == got_headers["content-type"], path
        # A HEAD that asks for a WebSocket handshake is no handshake.
        handshake = (
            b"HEAD /small HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        head, _, body = (await http(server.port, handshake)).partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 405 Method Not Allowed") and body == b""
        head, _, body = (await http(server.port, b"OPTIONS * HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")).partition(
            b"\r\n\r\n"
        )
        assert head.startswith(b"HTTP/1.1 204 No Content") and _headers(head)["allow"] == "GET, HEAD" and body == b""
        assert await transform(server, "/small") == [100.0, 100.1, 100.2]


async def test_a_tls_handshake_on_a_plain_port_is_closed_and_logged(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    async with running_server(tmp_path) as server:
        context = ssl.create_default_context()
        with pytest.raises((ssl.SSLError, ConnectionError)):
            await asyncio.wait_for(
                asyncio.open_connection("127.0.0.1", server.port, ssl=context, server_hostname="localhost"), 10
            )
        assert any(
            "TLS handshake" in record.getMessage() and "--certfile" in record.getMessage() for record in caplog.records
        )
        assert await get(server.port, "/healthz") == (200, b"ok\n")
        head, _, body = (await http(server.port, b"\x00\x01\x02\x03 garbage\r\n\r\n")).partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 400 Bad Request") and b"not an HTTP request" in body


# ------------------------------------------------------------------ logs that change


async def test_a_log_copied_in_while_served_is_read_again_and_a_removed_one_goes(tmp_path: Path):
    complete = write_log(tmp_path / "source", ten_hz(10))
    growing = tmp_path / "logs" / "growing"
    growing.mkdir(parents=True)
    # The copy has reached the metadata and four frames; the index comes last.
    for file in ["1-frame.glb", "2-frame.glb", "3-frame.glb", "4-frame.glb", "5-frame.glb"]:
        shutil.copy(complete / file, growing / file)
    async with running_server(tmp_path / "logs", settled=False) as server:
        assert await transform(server, "/growing") == [100.0, 100.1, 100.2, 100.3]
        for file in sorted(complete.iterdir()):
            shutil.copy(file, growing / file.name)
        assert await transform(server, "/growing") == [round(100 + i / 10, 3) for i in range(10)]
        await server.indexer.settled()  # the catalog reads again what the session found changed
        status, body = await get(server.port, "/")
        assert [(log["name"], log["frames"]) for log in json.loads(body)["logs"]] == [("growing", 10)]

        shutil.rmtree(growing)
        async with client(server, "/growing") as c:
            error = await c.recv()
            assert error["type"] == "xviz/error" and "'growing' is gone" in error["data"]["message"], error
        await server.indexer.settled()
        status, body = await get(server.port, "/")
        assert json.loads(body)["logs"] == []
