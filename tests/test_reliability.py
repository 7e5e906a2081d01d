"""The server as a hostile operator meets it: dying workers, logs that change, odd clients.

Real sockets on loopback, real files, real worker processes killed with a signal.
"""

from __future__ import annotations

import asyncio
import os
import signal
from pathlib import Path

from helpers import client, running_server, ten_hz, timestamps, write_log
from xviz_server.codec import Format


async def http(port: int, request: bytes, timeout: float = 10) -> bytes:
    """Send ``request`` as it is and read the answer until the server closes or stops sending."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        await writer.drain()
        answer = b""
        with_timeout = asyncio.timeout(timeout)
        async with with_timeout:
            while chunk := await reader.read(65536):
                answer += chunk
                head, _, body = answer.partition(b"\r\n\r\n")
                length = next((int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:")), None)
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
        victim = await server.workers.cpu(os.getpid)
        assert victim != os.getpid()
        os.kill(victim, signal.SIGKILL)
        status, body = 200, b""
        for _ in range(100):
            status, body = await get(server.port, "/healthz")
            if status != 200:
                break
            await asyncio.sleep(0.05)
        assert status == 503 and b"a worker process died" in body
        assert await transform(server, "/clouds", desired_streams=["/points"]) == expected
        for _ in range(100):
            if await get(server.port, "/healthz") == (200, b"ok\n"):
                break
            await asyncio.sleep(0.05)
        assert await get(server.port, "/healthz") == (200, b"ok\n")
        assert await server.workers.cpu(os.getpid) != os.getpid()  # processes again, not the stand-in thread
