"""Soak: hostile clients against a server started here on loopback; memory and file descriptors before and after.

    .venv/bin/python scripts/bench/soak.py [--aborted 1000] [--stalled 20] [--slowloris 50] [--hold 15] [--quick]

The server (``xviz-server serve``, its own process, ``--idle-timeout 5``)
serves the real KITTI log (../shared) when it is there, else a generated
GLB log. In turn:

1. ``--aborted`` sessions ask for the whole log and drop the connection
   (TCP reset) at once, 20 at a time;
2. ``--slowloris`` connections send their handshake one byte a second, for
   ``--hold`` seconds;
3. ``--stalled`` sessions with a 4 KB receive buffer ask for the whole log
   and never read, for ``--hold`` seconds, and are still there when the
   server gets SIGTERM.

After each phase: the server's resident memory and open file descriptors,
how many of the phase's connections the server had closed, and whether a
fresh client still gets a whole log. Every phase is bounded in count and
time; the script ends the server with SIGTERM and says how long it took.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import signal
import socket
import struct
import subprocess
import tempfile
import time
from pathlib import Path

from kit import KITTI, parse, write_log
from kit.proc import start_server
from kit.ws import handshake_request, masked_frame
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

REQUEST = json.dumps({"type": "xviz/transform_log", "data": {"id": "soak"}}).encode()


def usage(pid: int) -> tuple[float, int]:
    """Resident memory (MB) and open file descriptors of a process."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss_kb = int(re.search(r"VmRSS:\s+(\d+)", status).group(1))  # type: ignore[union-attr]
    return rss_kb / 1024, len(os.listdir(f"/proc/{pid}/fd"))


async def fresh_client(port: int, log: str) -> int:
    """State updates a new, well-behaved client gets for the whole log (0 when it gets none in 30 s)."""

    async def whole_log() -> int:
        async with connect(f"ws://127.0.0.1:{port}/{log}", max_size=None) as websocket:
            await websocket.recv()
            await websocket.send(REQUEST)
            count = 0
            while True:
                message = await websocket.recv()
                head = message[:400].encode() if isinstance(message, str) else message[:400]
                if b"xviz/transform_log_done" in head:
                    return count
                count += 1

    try:
        return await asyncio.wait_for(whole_log(), 30)
    except (asyncio.TimeoutError, OSError, ConnectionClosed) as exc:
        print(f"a fresh client failed: {exc!r}")
        return 0


async def aborted(port: int, log: str, count: int) -> int:
    """Sessions that ask for the log and reset the connection; returns how many were opened."""
    opened = 0
    limit = asyncio.Semaphore(20)

    async def one() -> None:
        nonlocal opened
        async with limit:
            try:
                websocket = await connect(f"ws://127.0.0.1:{port}/{log}", max_size=None, open_timeout=10)
            except (asyncio.TimeoutError, OSError, InvalidHandshake):
                return
            opened += 1
            await websocket.send(REQUEST)
            sock = websocket.transport.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close sends RST
            websocket.transport.abort()

    await asyncio.gather(*(one() for _ in range(count)))
    return opened


def open_socket(port: int, receive_buffer: int | None = None) -> socket.socket:
    sock = socket.socket()
    if receive_buffer is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    sock.connect(("127.0.0.1", port))
    return sock


def closed_by_server(sock: socket.socket) -> bool:
    """Whether the server has closed ``sock`` (reads what is pending without blocking)."""
    sock.setblocking(False)
    try:
        while True:
            data = sock.recv(1 << 20)
            if not data:
                return True
    except BlockingIOError:
        return False
    except OSError:
        return True


def stalled(port: int, log: str, count: int, hold: float) -> tuple[int, list[socket.socket]]:
    """Sessions that ask for the log and never read; returns how many the server closed within ``hold`` s."""
    sockets = []
    for _ in range(count):
        sock = open_socket(port, receive_buffer=4096)
        sock.sendall(handshake_request(f"/{log}"))
        sock.settimeout(10)
        head = b""
        while b"\r\n\r\n" not in head:
            head += sock.recv(1)  # the handshake answer only: nothing after it is read
        sock.sendall(masked_frame(0x1, REQUEST))
        sockets.append(sock)
    time.sleep(hold)
    return sum(closed_by_server(sock) for sock in sockets), sockets


def slowloris(port: int, count: int, hold: float) -> tuple[int, list[socket.socket]]:
    """Connections that send their handshake a byte a second; returns how many the server closed within ``hold`` s."""
    sockets = [open_socket(port) for _ in range(count)]
    request = handshake_request("/")
    deadline = time.monotonic() + hold
    sent = 0
    while time.monotonic() < deadline and sent < len(request) - 1:  # never the last byte
        for sock in sockets:
            try:
                sock.send(request[sent : sent + 1])
            except OSError:
                pass
        sent += 1
        time.sleep(1)
    return sum(closed_by_server(sock) for sock in sockets), sockets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--aborted", type=int, default=1000)
    parser.add_argument("--stalled", type=int, default=20)
    parser.add_argument("--slowloris", type=int, default=50)
    parser.add_argument("--hold", type=float, default=15.0)
    args = parse(parser, quick={"aborted": 20, "stalled": 2, "slowloris": 2, "hold": 1.0})

    with tempfile.TemporaryDirectory() as directory:
        root = Path(directory)
        if KITTI.is_dir():
            (root / "kitti").symlink_to(KITTI)
            log = "kitti"
        else:
            write_log(root / "generated", 25, points=100_000)
            log = "generated"
        server = start_server(root, "--idle-timeout", "5")
        port = server.port
        held: list[socket.socket] = []
        try:
            frames = asyncio.run(fresh_client(port, log))
            rss, fds = usage(server.pid)
            print(f"serving {log!r} ({frames} frames) on port {port}; server pid {server.pid}")
            print(f"{'after':<34}{'RSS MB':>8}{'fds':>6}   closed by server   fresh client frames")
            print(f"{'start (one whole log served)':<34}{rss:8.1f}{fds:6d}")

            started = time.perf_counter()
            opened = asyncio.run(aborted(port, log, args.aborted))
            took = time.perf_counter() - started
            time.sleep(1)
            rss, fds = usage(server.pid)
            print(
                f"{f'{opened} aborted sessions ({took:.1f} s)':<34}{rss:8.1f}{fds:6d}   {'-':>16}   {asyncio.run(fresh_client(port, log)):>19}"
            )

            closed, loris = slowloris(port, args.slowloris, args.hold)
            rss, fds = usage(server.pid)
            fresh = asyncio.run(fresh_client(port, log))
            print(
                f"{f'{args.slowloris} slowloris, {args.hold:g} s':<34}{rss:8.1f}{fds:6d}   {closed:>8} of {args.slowloris:<5}   {fresh:>19}"
            )
            for sock in loris:
                sock.close()
            time.sleep(2)
            rss, fds = usage(server.pid)
            print(f"{'slowloris closed, 2 s later':<34}{rss:8.1f}{fds:6d}")

            closed, held = stalled(port, log, args.stalled, args.hold)
            rss, fds = usage(server.pid)
            fresh = asyncio.run(fresh_client(port, log))
            print(
                f"{f'{args.stalled} stalled readers, {args.hold:g} s':<34}{rss:8.1f}{fds:6d}   {closed:>8} of {args.stalled:<5}   {fresh:>19}"
            )
            print("(the stalled readers stay connected through SIGTERM)")
        finally:
            started = time.perf_counter()
            server.popen.send_signal(signal.SIGTERM)
            try:
                server.popen.wait(30)
                print(f"SIGTERM: exited in {time.perf_counter() - started:.1f} s (code {server.popen.returncode})")
            except subprocess.TimeoutExpired:
                server.popen.kill()
                server.popen.wait()
                print("SIGTERM: still running after 30 s; killed")
            for sock in held:
                sock.close()


if __name__ == "__main__":
    main()
