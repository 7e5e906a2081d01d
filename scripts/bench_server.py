#!/usr/bin/env python3
"""Benchmark the XVIZ server against a bare websockets server, in one run.

    .venv/bin/python scripts/bench_server.py [--quick] [--json FILE] [--kitti DIR] [--client-procs N] [--tmp DIR]

Every party is its own process:

* the server under test, ``python -m xviz_server serve --data-dir ROOT --port 0``;
* the reference: a bare websockets (asyncio API) + uvloop server that pre-loads
  the same frame files and, for each ``xviz/transform_log``, sends them all
  then a done message: the best any Python server can do on this machine;
* the clients, the same code against both: a minimal WebSocket client ("raw",
  asyncio on uvloop, counting bytes in place) with which the server is the
  bottleneck, and the websockets asyncio client, itself the bottleneck near
  1 GB/s per process, for what a Python viewer sees. 20 clients share one
  client process unless a row says otherwise: with 2 cores, server and
  clients compete for them, and the report shows each one's CPU use.

Sections:

1. whole-log throughput of the KITTI log, 1 and 20 clients, GLB as stored and
   transcoded to JSON, as a ratio to the reference (target: >= 0.8);
2. time to first frame, cold (first request after start) and warm;
3. point-in-time latency p50/p99 on a generated 100 000-frame log (10 000 with
   --quick), on the same generator's 25-frame log and on KITTI, beside the
   loopback round trip (target: p99 < 5 ms, nearly independent of log length);
4. server peak RSS with 20 clients of which 5 stop reading, against the bound
   cache + 20 x (read-ahead + 1) x largest frame;
5. permessage-deflate off (the default) and on: payload and wire rates, bytes
   ratio, CPU cost.

The script runs itself with ``--role`` for the reference server and the clients.
Speed is reported as numbers and ratios against the reference measured in the
same run; nothing here asserts a time. The machine may be shared: each
measurement also says how many cores other processes used meanwhile.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import platform
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Self
from urllib.parse import parse_qsl, urlsplit

import uvloop
import websockets
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import serve

REPO = Path(__file__).resolve().parents[1]
KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-2011_09_26_drive_0001-head"
MB = 1e6  # rates in MB/s are 10^6 bytes per second
MIB = 1 << 20  # memory in MiB, like --cache-mb
QUIET = 0.25  # a trial is "quiet" when other processes used fewer cores than this

# ================================================================ helpers


def transform_log(request_id: str) -> str:
    return json.dumps({"type": "xviz/transform_log", "data": {"id": request_id}})


def percentile(values: list[float], q: float) -> float:
    """The ``q``-th percentile, nearest rank (p99 of 500 values is the 5th largest)."""
    ordered = sorted(values)
    return ordered[max(0, math.ceil(q / 100 * len(ordered)) - 1)]


def summary(values: list[float]) -> dict[str, float]:
    if not values:
        return {"count": 0}
    return {
        "count": len(values),
        "p50_ms": percentile(values, 50),
        "p99_ms": percentile(values, 99),
        "max_ms": max(values),
        "mean_ms": statistics.fmean(values),
    }


# ================================================================ processes


def _clean_env() -> dict[str, str]:
    """The environment without XVIZ_* settings (flags here say everything) and proxies."""
    return {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_") and "proxy" not in k.lower()}


class Process:
    """A child process that prints ``ready`` (a regex with the port) on stderr; stderr is drained after."""

    def __init__(self, args: list[str], ready: str, name: str) -> None:
        self.name = name
        self.started = time.perf_counter()
        self.popen = subprocess.Popen(
            args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True, cwd=REPO, env=_clean_env(),
        )
        self.tail: deque[str] = deque(maxlen=30)
        assert self.popen.stderr is not None
        for text in self.popen.stderr:
            self.tail.append(text)
            match = re.search(ready, text)
            if match:
                self.port = int(match.group(1))
                break
        else:
            raise RuntimeError(f"{name} exited before listening:\n{''.join(self.tail)}")
        self.startup_s = time.perf_counter() - self.started
        # Keep draining: a server logging one line per session would block on a full pipe.
        self._drain = threading.Thread(target=self._read_rest, daemon=True)
        self._drain.start()

    def _read_rest(self) -> None:
        assert self.popen.stderr is not None
        for text in self.popen.stderr:
            self.tail.append(text)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def url(self, path: str = "") -> str:
        return f"ws://127.0.0.1:{self.port}/{path}"

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(15)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_server(root: Path, *extra: str) -> Process:
    args = [sys.executable, "-m", "xviz_server", "serve", "--data-dir", str(root),
            "--host", "127.0.0.1", "--port", "0", *extra]
    return Process(args, r"listening on ws://127\.0\.0\.1:(\d+)/", "xviz-server")


def start_reference(logs: dict[str, Path]) -> Process:
    spec = json.dumps({name: str(path) for name, path in logs.items()})
    return Process([sys.executable, __file__, "--role", "reference", spec], r"reference listening on ws://127\.0\.0\.1:(\d+)/", "reference")


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (the server's worker processes, if any)."""
    found, todo = [], [pid]
    while todo:
        current = todo.pop()
        found.append(current)
        try:
            for task in os.listdir(f"/proc/{current}/task"):
                with open(f"/proc/{current}/task/{task}/children") as children:
                    todo.extend(int(c) for c in children.read().split())
        except OSError:
            pass
    return found


def rss_mib(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _own_cpu(pid: int) -> float:
    """User + system CPU time of one process (all its threads)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def cpu_seconds(pid: int) -> float:
    """CPU time of ``pid`` and its live descendants (the server's worker processes, if any)."""
    return sum(_own_cpu(each) for each in descendants(pid))


def other_cpu() -> float:
    """CPU seconds used so far on the machine by processes outside this benchmark's tree.

    The machine may be shared: the difference of two readings says how much
    of it others took meanwhile. Busy time (from /proc/stat, interrupts
    included) minus this process, its reaped children and its live
    descendants; short-lived processes are counted too. Approximate: tick
    sampled, and interrupt work done for our sockets counts as "others".
    """
    with open("/proc/stat") as stat:
        fields = [int(x) for x in stat.readline().split()[1:]]
    busy = sum(fields[i] for i in (0, 1, 2, 5, 6)) / os.sysconf("SC_CLK_TCK")  # user nice system irq softirq
    times = os.times()
    ours = times.user + times.system + times.children_user + times.children_system
    ours += sum(_own_cpu(pid) for pid in descendants(os.getpid())[1:])
    return busy - ours


def other_cores(cpu_before: float, wall_before: float) -> float:
    """Cores used by other processes since :func:`other_cpu` read ``cpu_before`` at ``wall_before``.

    Readings are tick sampled, so an idle machine can come out a little
    below zero; that is reported as 0.
    """
    return max(0.0, (other_cpu() - cpu_before) / (time.perf_counter() - wall_before))


class RssSampler:
    """Samples the RSS of a process (and, separately, its descendants) every few ms in a thread."""

    def __init__(self, pid: int, interval: float = 0.01) -> None:
        self.pid, self.interval = pid, interval
        self.peak = self.peak_total = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            main = rss_mib(self.pid)
            total = main + sum(rss_mib(p) for p in descendants(self.pid)[1:])
            self.peak, self.peak_total = max(self.peak, main), max(self.peak_total, total)
            self._stop.wait(self.interval)

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def run_clients(spec: dict[str, Any], procs: int = 1, server_pid: int | None = None) -> dict[str, Any]:
    """Run ``spec`` in ``procs`` client processes started together; aggregate what they measured.

    Each process connects its clients, says ``ready``, and starts on ``go``, so
    that process start-up and connection set-up are outside the measured time.
    """
    counts = [spec.get("clients", 1) // procs + (i < spec.get("clients", 1) % procs) for i in range(procs)]
    stalled = [spec.get("stalled", 0) // procs + (i < spec.get("stalled", 0) % procs) for i in range(procs)]
    children = []
    for clients, stalls in zip(counts, stalled):
        part = {**spec, "clients": clients, "stalled": stalls}
        child = subprocess.Popen(
            [sys.executable, __file__, "--role", "client", "-"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO, env=_clean_env(),
        )
        assert child.stdin is not None
        child.stdin.write(json.dumps(part) + "\n")  # the spec, on stdin: a schedule can be long
        child.stdin.flush()
        children.append(child)
    try:
        for child in children:
            assert child.stdout is not None
            text = child.stdout.readline()
            if text.strip() != "ready":
                raise RuntimeError(f"client process failed before starting: {text!r} (spec {spec})")
        cpu_before = cpu_seconds(server_pid) if server_pid else 0.0
        other_before, wall_before = other_cpu(), time.perf_counter()
        for child in children:
            assert child.stdin is not None
            child.stdin.write("go\n")
            child.stdin.flush()
        parts = []
        for child in children:
            assert child.stdout is not None
            text = child.stdout.readline()
            if child.wait() or not text:
                raise RuntimeError(f"client process exited with {child.returncode} (spec {spec})")
            parts.append(json.loads(text))
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
                child.wait()
    server_cpu = cpu_seconds(server_pid) - cpu_before if server_pid else None
    other = other_cores(other_before, wall_before)
    if spec["task"] != "stream":
        return {**parts[0], "other_cpu": other}
    if len(parts) == 1:
        result = parts[0]
    else:
        result = {key: sum(p[key] for p in parts) for key in ("bytes", "wire_bytes", "frames", "errors", "client_cpu_s")}
        result["started"] = min(p["started"] for p in parts)
        result["ended"] = max(p["ended"] for p in parts)
        result["seconds"] = result["ended"] - result["started"]
        result["first_frame_ms"] = statistics.median(x for p in parts for x in p["first_frame_list"])
        result["frames_per_request"] = sorted({x for p in parts for x in p["frames_per_request"]})
        result["extensions"] = parts[0]["extensions"]
    seconds = result["seconds"]
    result["client_procs"] = procs
    result["other_cpu"] = other  # cores used by other processes on the machine meanwhile
    result["mb_s"] = result["bytes"] / MB / seconds
    result["wire_mb_s"] = result["wire_bytes"] / MB / seconds
    result["frames_s"] = result["frames"] / seconds
    result["client_cpu"] = result["client_cpu_s"] / seconds  # in cores
    if server_cpu is not None:
        result["server_cpu_s"] = server_cpu
        result["server_cpu"] = server_cpu / seconds
    result.pop("first_frame_list", None)
    return result


# ================================================================ reference server


def reference_main(spec: str) -> None:
    """A bare websockets + uvloop server sending pre-loaded frames: the best case for Python here."""
    from xviz_server.codec import Format, decode, encode

    logs: dict[str, dict[str, Any]] = {}
    for name, directory in json.loads(spec).items():
        directory = Path(directory)
        numbers = sorted(int(p.name.split("-")[0]) for p in directory.glob("*-frame.glb"))
        numbers = [n for n in numbers if n >= 2][:25]  # a long log: its first 25 frames are enough here
        glb = [(directory / f"{n}-frame.glb").read_bytes() for n in numbers]
        metadata = (directory / "1-frame.glb").read_bytes()
        as_json = [encode(decode(frame), Format.JSON) for frame in glb]  # what the server's JSON transcoding gives
        logs[name] = {
            "BINARY": (metadata, glb, False),
            "JSON": (encode(decode(metadata), Format.JSON), as_json, True),
        }
    first = next(iter(logs))

    async def handler(websocket: Any) -> None:
        url = urlsplit(websocket.request.path)
        query = dict(parse_qsl(url.query))
        log = logs.get(url.path.strip("/") or first, logs[first])
        metadata, frames, text = log["JSON" if query.get("message_format", "").upper() == "JSON" else "BINARY"]
        await websocket.send(metadata, text=text)  # one small message on connect, like the server
        answered = 0
        async for message in websocket:
            request = json.loads(message)
            request_id = (request.get("data") or {}).get("id")
            if request.get("type") == "xviz/transform_point_in_time":
                await websocket.send(frames[answered % len(frames)], text=text)
                answered += 1
            elif request.get("type") == "xviz/transform_log":
                for frame in frames:
                    await websocket.send(frame, text=text)
                await websocket.send(json.dumps({"type": "xviz/transform_log_done", "data": {"id": request_id}}))

    async def main() -> None:
        async with serve(handler, "127.0.0.1", 0, compression=None, max_size=1 << 20) as server:
            port = server.sockets[0].getsockname()[1]
            print(f"reference listening on ws://127.0.0.1:{port}/", file=sys.stderr, flush=True)
            await asyncio.Future()

    uvloop.run(main())


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
    async def open(cls, url: str, keep: int = 512, compression: str | None = "deflate", max_queue: int = 16) -> WebsocketsClient:
        websocket = await connect(url, max_size=None, compression=compression, create_connection=CountingConnection,
                                  ping_interval=None, proxy=None, open_timeout=60, max_queue=max_queue)
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
            response, rest = bytes(self.handshake[:end]), bytes(self.handshake[end + 4:])
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
                    self.control_payload += view[pos:pos + take]
                else:
                    room = self.keep - len(self.head)
                    if room > 0:
                        self.head += view[pos:pos + min(take, room)]
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
                header += view[pos:pos + take]
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
        n = len(payload)
        header = bytes([0x80 | opcode])
        header += bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big") if n < 65536 \
            else bytes([0x80 | 127]) + n.to_bytes(8, "big")
        key = os.urandom(4)
        mask = (key * (n // 4 + 1))[:n]
        masked = (int.from_bytes(payload, "big") ^ int.from_bytes(mask, "big")).to_bytes(n, "big") if n else b""
        assert self.transport is not None
        self.transport.write(header + key + masked)

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
    async def open(cls, url: str, keep: int = 512, compression: str | None = None, max_queue: int = 16) -> RawClient:
        if compression:
            raise ValueError("the raw client does not do compression")
        parts = urlsplit(url)
        loop = asyncio.get_running_loop()
        _, protocol = await loop.create_connection(lambda: RawProtocol(keep), parts.hostname, parts.port)
        target = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
        key = __import__("base64").b64encode(os.urandom(16)).decode()
        request = (f"GET {target} HTTP/1.1\r\nHost: {parts.netloc}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                   f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
        assert protocol.transport is not None
        protocol.transport.write(request.encode())
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


CLIENTS = {"raw": RawClient, "websockets": WebsocketsClient}


async def wait_for_go(spec: dict[str, Any]) -> None:
    if spec.get("sync", True):
        print("ready", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)


async def stream_task(spec: dict[str, Any]) -> dict[str, Any]:
    """``clients`` sessions each fetch the whole log ``repeats`` times; ``stalled`` more stop reading."""
    kind = CLIENTS[spec.get("client", "raw")]
    url, repeats = spec["url"], spec["repeats"]
    compression = spec.get("compression")
    sessions = [await kind.open(url, compression=compression) for _ in range(spec["clients"])]
    for session in sessions:
        await session.recv()  # metadata
    extensions = sessions[0].extensions if sessions else None
    sleepers = []
    for i in range(spec.get("stalled", 0)):
        session = await kind.open(url, compression=compression, max_queue=1)
        await session.recv()
        await session.send(transform_log(f"stalled-{i}"))
        session.pause()  # never reads again: the server's sends back up
        sleepers.append(session)

    async def one(session: Any, number: int) -> tuple[int, int, int, float, list[int]]:
        size = frames = errors = 0
        first = 0.0
        per_request = []
        for r in range(repeats):
            sent = time.perf_counter()
            await session.send(transform_log(f"c{number}-r{r}"))
            count = 0
            while True:
                length, head, when = await session.recv()
                if is_done(length, head):
                    break
                if length < 4000 and b"xviz/error" in head:
                    errors += 1
                    continue
                if count == 0 and r == 0:
                    first = when - sent
                count += 1
                size += length
            frames += count
            per_request.append(count)
        return size, frames, errors, first, per_request

    await wait_for_go(spec)
    wire_before = kind.wire()
    cpu_before = time.process_time()
    started = time.perf_counter()
    results = await asyncio.gather(*(one(session, i) for i, session in enumerate(sessions)))
    ended = time.perf_counter()
    cpu = time.process_time() - cpu_before
    wire = kind.wire() - wire_before
    for session in sleepers:
        session.abort()
    for session in sessions:
        await session.close()
    return {
        "bytes": sum(r[0] for r in results), "wire_bytes": wire, "frames": sum(r[1] for r in results),
        "errors": sum(r[2] for r in results), "started": started, "ended": ended, "seconds": ended - started,
        "client_cpu_s": cpu, "first_frame_list": [r[3] * 1000 for r in results],
        "first_frame_ms": statistics.median(r[3] * 1000 for r in results),
        "frames_per_request": sorted({n for r in results for n in r[4]}), "extensions": extensions,
    }


def envelope_of(head: bytes) -> dict[str, Any]:
    """The XVIZ envelope of a GLB message (from its JSON chunk, which comes first) or a JSON one."""
    if head[:4] in (b"glTF", b"XVIZ"):
        length = int.from_bytes(head[12:16], "little")
        if len(head) < 20 + length:
            raise RuntimeError("kept too little of the message to read its JSON chunk")
        document = json.loads(head[20:20 + length])
        return document.get("xviz") or document["extensions"]["AVS_xviz"]
    return json.loads(head)


def is_done(length: int, head: bytes) -> bool:
    return length < 400 and b"transform_log_done" in head


class Target:
    """One connection of a latency run and what was measured on it."""

    def __init__(self, spec: dict[str, Any], session: Any, metadata: bytes, to_metadata: float) -> None:
        self.name, self.op, self.classify = spec["name"], spec["op"], spec.get("classify", False)
        self.session = session
        self.to_metadata_ms = to_metadata
        self.latencies: list[float] = []
        self.uncached: list[float] = []
        self.cached: list[float] = []
        self.sizes: list[int] = []
        self.seen: set[float] = set()
        self.sent = 0
        if self.op == "pit":
            info = envelope_of(metadata)["data"].get("log_info") or {}
            self.start, self.end = info.get("start_time", 0.0), info.get("end_time", 1.0)
            self.rng = random.Random(f"{spec.get('seed', 7)}-{self.name}")  # str seeds are stable across runs

    async def once(self) -> None:
        session, number = self.session, self.sent
        self.sent += 1
        if self.op == "ping":
            sent = time.perf_counter()
            await session.ping()
            self.latencies.append((time.perf_counter() - sent) * 1000)
        elif self.op == "first":  # transform_log: time to its first message, then read up to its done
            sent = time.perf_counter()
            await session.send(transform_log(f"first-{number}"))
            length, head, when = await session.recv()
            self.latencies.append((when - sent) * 1000)
            while not is_done(length, head):
                length, head, when = await session.recv()
        else:  # transform_point_in_time at a random instant
            instant = self.rng.uniform(self.start, self.end)
            request = json.dumps({"type": "xviz/transform_point_in_time", "data": {"id": str(number), "query_timestamp": instant}})
            sent = time.perf_counter()
            await session.send(request)
            length, head, when = await session.recv()
            elapsed = (when - sent) * 1000
            self.latencies.append(elapsed)
            self.sizes.append(length)
            if self.classify:
                message = envelope_of(head)
                if message.get("type") != "xviz/state_update":
                    raise RuntimeError(f"{self.name}: point in time {instant}: got {message.get('type')}: {str(message)[:300]}")
                stamp = message["data"]["updates"][0]["timestamp"]
                (self.cached if stamp in self.seen else self.uncached).append(elapsed)
                self.seen.add(stamp)

    def result(self) -> dict[str, Any]:
        return {"to_metadata_ms": self.to_metadata_ms, "all": summary(self.latencies), "values_ms": self.latencies,
                "uncached": summary(self.uncached), "cached": summary(self.cached),
                "answer_bytes": statistics.median(self.sizes) if self.sizes else None}


async def latency_task(spec: dict[str, Any]) -> dict[str, Any]:
    """Requests on several connections, one at a time, each awaited, in the order of ``schedule``.

    Interleaving the server's requests with the reference's makes both see
    the same load from other processes. Operations: ``ping`` (a WebSocket
    ping), ``first`` (time to the first frame of a ``transform_log``), ``pit``
    (a ``transform_point_in_time`` at a random instant, fixed seed; with
    ``classify``, each answer's timestamp, the frame it ends at and which the
    server caches answers by, tells whether it is the first answer ending at
    that frame in this server's life: "uncached", or "cached").
    """
    targets = {}
    for target in spec["targets"]:
        started = time.perf_counter()
        session = await RawClient.open(target["url"], keep=1 << 20)
        _, metadata, _ = await session.recv()
        targets[target["name"]] = Target(target, session, metadata, (time.perf_counter() - started) * 1000)
    await wait_for_go(spec)
    for name in spec["schedule"]:
        await targets[name].once()
    for target in targets.values():
        await target.session.close()
    return {name: target.result() for name, target in targets.items()}


def client_main(spec_text: str) -> None:
    spec = json.loads(sys.stdin.readline() if spec_text == "-" else spec_text)
    task = {"stream": stream_task, "latency": latency_task}[spec["task"]]
    result = uvloop.run(task(spec))
    print(json.dumps(result), flush=True)


# ================================================================ the generated log


def generate_log(directory: Path, count: int) -> Path:
    """A log of ``count`` small GLB state updates at 10 Hz, in the reference layout (with ``0-frame.json``).

    Each frame is tests/serving.py's ``update(t)`` (a pose, a 10-point cloud, a
    time series; SNAPSHOT), encoded once with a placeholder time whose digits
    are then replaced, at equal width, in each copy: 100 000 frames in seconds.
    """
    sys.path.insert(0, str(REPO / "tests"))
    from serving import metadata, update

    from xviz_server.codec import Format, decode, encode

    placeholder = 123456.7
    template = encode({"type": "xviz/state_update", "data": update(placeholder)}, Format.BINARY)
    token, double = b"123456.7", b"246913.4"  # t, and the time series value 2t
    if template.count(token) < 2 or template.count(double) != 1:
        raise RuntimeError("cannot patch the frame template: the placeholder time is not where expected")
    if count > 100_000:
        raise ValueError("the fixed-width times cover at most 100 000 frames")
    directory.mkdir(parents=True)
    times = [f"{100000 + i / 10:.1f}" for i in range(count)]  # 100000.0 ... 109999.9: always 8 characters
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC

    def write(numbers: range) -> None:
        for i in numbers:
            text = times[i]
            data = template.replace(token, text.encode()).replace(double, f"{2 * float(text):.1f}".encode())
            fd = os.open(f"{directory}/{i + 2}-frame.glb", flags, 0o644)
            try:
                os.write(fd, data)
            finally:
                os.close(fd)

    with ThreadPoolExecutor(4) as pool:  # file creation is system calls: threads overlap them
        list(pool.map(write, [range(k, count, 4) for k in range(4)]))
    start, end = float(times[0]), float(times[-1])
    meta = metadata(start_time=start, end_time=end)
    (directory / "1-frame.glb").write_bytes(encode({"type": "xviz/metadata", "data": meta}, Format.BINARY))
    timing = [[float(t), float(t), i, f"{i + 2}-frame"] for i, t in enumerate(times)]
    (directory / "0-frame.json").write_text(json.dumps({"startTime": start, "endTime": end, "timing": timing}))
    last = decode((directory / f"{count + 1}-frame.glb").read_bytes())
    assert last["data"]["updates"][0]["timestamp"] == end, "generated frames carry the wrong time"
    return directory


# ================================================================ the run


def machine() -> dict[str, Any]:
    model = "?"
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            model = next((line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name")), "?")
    except OSError:
        pass
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], check=False, capture_output=True, text=True, cwd=REPO).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "xviz_server", "providers"],
                           check=False, capture_output=True, text=True, cwd=REPO).stdout.strip()
    return {
        "cores": os.cpu_count(), "cpu": model, "kernel": platform.release(), "python": platform.python_version(),
        "websockets": websockets.__version__, "uvloop": uvloop.__version__,
        "server_code": f"git {commit}" + (" + uncommitted changes under xviz_server/ or providers/" if dirty else ""),
    }


def line(text: str = "") -> None:
    print(text, flush=True)


def section(title: str) -> None:
    line()
    line(title)
    line("-" * len(title))


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT MET"


def median_run(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The median of several runs by MB/s, with every run's MB/s as the spread."""
    rates = [r["mb_s"] for r in runs]
    middle = sorted(runs, key=lambda r: r["mb_s"])[len(runs) // 2]
    return {**middle, "trials_mb_s": rates}


def throughput_section(args: argparse.Namespace, root: Path, reference: Process, results: dict[str, Any], quick: bool) -> None:
    frames_in_log = len(list(args.kitti.glob("*-frame.glb"))) - 1
    n_trials = 2 if quick else 5
    # Bytes each trial moves: a window of about a second at the rates seen here.
    volume = {"raw": 2.5e9, "websockets": 0.8e9}
    if quick:
        volume = {kind: v / 2 for kind, v in volume.items()}
    section(f"1. Whole-log throughput, KITTI ({frames_in_log} frames)")
    line(f"Each client fetches the whole log N times after its metadata (N chosen so that a trial moves ~{volume['raw'] / 1e9:.1f} GB "
         f"with the raw client, ~{volume['websockets'] / 1e9:.1f} GB with websockets); {n_trials} trials, each a server run "
         "next to a reference run (order alternating); MB/s: median trial, all trials listed; ratio: median of the "
         "trials' server/reference ratios (robust to load from other processes changing during the run). MB/s counts message payload (10^6 B). CPU columns: cores used during the "
         "window by the server (or reference) process, by the client process(es), and by other processes on the machine "
         "(of the median trial; 1.00 is one core).")
    with start_server(root) as server:
        kitti = server.url("kitti")
        # Warm: open the log, fill the cache with the GLB frames and their JSON transcoding.
        glb_bytes = run_clients({"task": "stream", "url": kitti, "clients": 1, "repeats": 1})["bytes"]
        json_bytes = run_clients({"task": "stream", "url": kitti + "?message_format=JSON", "clients": 1, "repeats": 1})["bytes"]
        configs = [("raw", 1, 1), ("raw", 20, 1), ("websockets", 1, 1), ("websockets", 20, 1)]
        if not quick:
            configs += [("raw", 20, 2), ("websockets", 20, 2)]
        if args.client_procs > 2:
            configs += [("raw", 20, args.client_procs), ("websockets", 20, args.client_procs)]
        rows = []
        for kind, clients, procs in configs:
            for fmt, query, log_bytes in (("GLB", "", glb_bytes), ("JSON", "?message_format=JSON", json_bytes)):
                repeats = max(1, round(volume[kind] / (clients * log_bytes)))
                spec = {"task": "stream", "clients": clients, "repeats": repeats, "client": kind}
                ours_runs, bare_runs = [], []
                for trial in range(n_trials):
                    for who in ("server", "reference") if trial % 2 == 0 else ("reference", "server"):
                        if who == "server":
                            ours_runs.append(run_clients({**spec, "url": kitti + query}, procs, server.pid))
                        else:
                            bare_runs.append(run_clients({**spec, "url": reference.url("kitti") + query}, procs, reference.pid))
                mine, theirs = median_run(ours_runs), median_run(bare_runs)
                ratios = [a["mb_s"] / b["mb_s"] for a, b in zip(ours_runs, bare_runs)]
                quiet = [a["mb_s"] / b["mb_s"] for a, b in zip(ours_runs, bare_runs)
                         if max(a["other_cpu"], b["other_cpu"]) < QUIET]
                for r in ours_runs + bare_runs:
                    if r["frames_per_request"] != [frames_in_log] or r["errors"]:
                        raise RuntimeError(f"a request did not get {frames_in_log} frames: {r['frames_per_request']}, "
                                           f"{r['errors']} errors")
                rows.append({"client": kind, "clients": clients, "client_procs": procs, "format": fmt, "repeats": repeats,
                             "server": mine, "reference": theirs, "ratio": statistics.median(ratios),
                             "trial_ratios": ratios, "quiet_ratio": statistics.median(quiet) if quiet else None,
                             "quiet_trials": len(quiet)})
    line()
    width = 5 * n_trials + 1
    line(f"{'client':<11}{'clients':<14}{'format':<7}{'':>10}{'MB/s':>7}{'frames/s':>9}  {'trials MB/s':<{width}}"
         f"{'srv CPU':>8}{'cli CPU':>8}{'others':>7}{'ratio':>7}{'quiet':>7}")
    for row in rows:
        label = f"{row['clients']} x{row['repeats']}" + (f" {row['client_procs']}p" if row["client_procs"] > 1 else "")
        for who in ("server", "reference"):
            r = row[who]
            spread = "/".join(f"{x:.0f}" for x in r["trials_mb_s"])
            first = who == "server"
            line(f"{row['client'] if first else '':<11}{label if first else '':<14}{row['format'] if first else '':<7}{who:>10}"
                 f"{r['mb_s']:7.0f}{r['frames_s']:9.0f}  {spread:<{width}}{r['server_cpu']:8.2f}{r['client_cpu']:8.2f}"
                 f"{r['other_cpu']:7.2f}"
                 + (f"{row['ratio']:7.2f}" if first else "")
                 + ((f"{row['quiet_ratio']:7.2f}" if row["quiet_ratio"] is not None else f"{'-':>7}") if first else ""))
    line("(clients 'N xR Kp': N clients each fetching the log R times, spread over K client processes; quiet: median "
         f"ratio of the trials in which other processes used under {QUIET} cores during both runs.)")
    line()
    line("Trial ratios server/reference:")
    for row in rows:
        line(f"  {row['client']:<11}{row['clients']:>3} client(s){' ' + str(row['client_procs']) + ' procs' if row['client_procs'] > 1 else '':<8}"
             f" {row['format']:<5}" + " ".join(f"{x:.2f}" for x in row["trial_ratios"]))
    glb_rows = [r for r in rows if r["format"] == "GLB" and r["client_procs"] == 1]
    ok = all(r["ratio"] >= 0.8 for r in glb_rows)
    line()
    line("GLB ratio server/reference: " + ", ".join(f"{r['client']} {r['clients']} client(s) {r['ratio']:.2f}" for r in glb_rows)
         + f"; target >= 0.8: {verdict(ok)}")
    json_rows = [r for r in rows if r["format"] == "JSON" and r["client_procs"] == 1]
    line("JSON-transcoded (transcoded once, then served from the cache; the reference sends the same JSON bytes, pre-encoded): "
         + ", ".join(f"{r['client']} {r['clients']} {r['ratio']:.2f}" for r in json_rows))
    line(f"Average message: GLB {glb_bytes / frames_in_log / MB:.2f} MB, JSON {json_bytes / frames_in_log / MB:.2f} MB.")
    results["throughput"] = {"rows": rows, "target_met": ok}


def first_frame_section(root: Path, reference: Process, results: dict[str, Any], quick: bool) -> None:
    restarts = 3 if quick else 7
    warm = 5
    section("2. Time to first frame (transform_log sent -> first state update received)")
    line(f"Cold: the first request after server start (median of {restarts} fresh servers; frame files in the OS page cache). "
         f"Warm: the next {warm} requests on the same connection, interleaved with requests to the reference (pre-loaded), so "
         "both see the same load. JSON cold: then the first request of a JSON session (the first transcoding).")
    values: dict[str, list[float]] = {"server GLB, cold": [], "server GLB, warm": [], "server JSON-transcoded, cold": [],
                                      "reference": []}
    other = []
    for _ in range(restarts):
        with start_server(root) as server:
            targets = [{"name": "glb", "url": server.url("kitti"), "op": "first"},
                       {"name": "json", "url": server.url("kitti") + "?message_format=JSON", "op": "first"},
                       {"name": "ref", "url": reference.url("kitti"), "op": "first"}]
            schedule = ["glb"] + ["ref", "glb"] * warm + ["ref", "json"]
            outcome = run_clients({"task": "latency", "targets": targets, "schedule": schedule})
        glb = outcome["glb"]["values_ms"]
        values["server GLB, cold"].append(glb[0])
        values["server GLB, warm"].extend(glb[1:])
        values["server JSON-transcoded, cold"].extend(outcome["json"]["values_ms"])
        values["reference"].extend(outcome["ref"]["values_ms"])
        other.append(outcome["other_cpu"])
    line()
    line(f"{'':<32}{'median ms':>10}{'min':>8}{'max':>8}{'n':>5}")
    for name, series in values.items():
        line(f"{name:<32}{statistics.median(series):10.2f}{min(series):8.2f}{max(series):8.2f}{len(series):>5}")
    line(f"(a first frame is a whole 2.1 MB message; other processes used {statistics.median(other):.2f} cores meanwhile, median)")
    results["first_frame"] = {name: {"median_ms": statistics.median(v), "all_ms": v} for name, v in values.items()}


def point_in_time_section(root: Path, reference: Process, results: dict[str, Any], quick: bool, long_frames: int) -> None:
    rounds = 500 if quick else 2000
    section("3. Point-in-time latency (random instants, fixed seed, one client, each answer awaited)")
    line(f"One fresh server serving all three logs; one client, one connection per row below, {rounds} rounds in which each "
         "connection in turn sends one request and awaits its answer (server and reference interleaved: same load for all).")
    line("Uncached: the first answer ending at a given frame (read, merged, encoded); cached: answers for a frame already "
         "asked about (the server caches answers by the frame they end at). Then a second pass on KITTI, all cached.")
    long_name = f"generated, {long_frames} frames"
    with start_server(root) as server:
        targets = [
            {"name": "loopback ping, reference", "url": reference.url("kitti"), "op": "ping"},
            {"name": "reference, one small frame", "url": reference.url("short"), "op": "pit"},
            {"name": "reference, one KITTI frame", "url": reference.url("kitti"), "op": "pit"},
            {"name": long_name, "url": server.url("long"), "op": "pit", "classify": True},
            {"name": "generated, 25 frames", "url": server.url("short"), "op": "pit", "classify": True},
            {"name": "KITTI, 25 frames", "url": server.url("kitti"), "op": "pit", "classify": True},
        ]
        names = [t["name"] for t in targets]
        first = run_clients({"task": "latency", "targets": targets, "schedule": names * rounds})
        again = [{**t, "name": t["name"] + ", 2nd pass"} for t in targets if t["name"] in
                 ("reference, one KITTI frame", "KITTI, 25 frames")]
        second = run_clients({"task": "latency", "targets": again,
                              "schedule": [t["name"] for t in again] * (rounds // 2)})
        # The second pass is a new connection on the same server: its "uncached" list counts answers new to this
        # connection, all of which the server has cached by now.
        kitti_again = second["KITTI, 25 frames, 2nd pass"]
        kitti_again["cached"], kitti_again["uncached"] = kitti_again["all"], {"count": 0}
    rows = {name: first[name] for name in names}
    rows["reference, one KITTI frame, 2nd pass"] = second["reference, one KITTI frame, 2nd pass"]
    rows["KITTI, 25 frames, 2nd pass"] = kitti_again

    def pair(s: dict[str, Any]) -> str:
        return f"{s['p50_ms']:.2f}/{s['p99_ms']:.2f} ({s['count']})" if s.get("count") else "-"

    line()
    line(f"{'':<38}{'answer':>9}  {'p50 ms':>7}{'p99 ms':>8}{'max ms':>8}   {'uncached p50/p99 (n)':>22}   {'cached p50/p99 (n)':>20}")
    for name, r in rows.items():
        s = r["all"]
        size = f"{r['answer_bytes'] / 1e3:7.1f}kB" if r.get("answer_bytes") else f"{'':9}"
        line(f"{name:<38}{size}  {s['p50_ms']:7.2f}{s['p99_ms']:8.2f}{s['max_ms']:8.2f}   "
             f"{pair(r['uncached']) if r['uncached'].get('count') or name.startswith(('gen', 'KITTI')) else '':>22}   "
             f"{pair(r['cached']) if r['cached'].get('count') or name.startswith(('gen', 'KITTI')) else '':>20}")
    long_r, short_r, kitti_r = rows[long_name], rows["generated, 25 frames"], rows["KITTI, 25 frames"]
    line(f"(other processes used {first['other_cpu']:.2f} cores during the first pass, {second['other_cpu']:.2f} during the second)")
    line()
    line(f"Time from connect to metadata (the log is opened on first use): {long_frames}-frame log "
         f"{long_r['to_metadata_ms']:.0f} ms, 25-frame log {short_r['to_metadata_ms']:.0f} ms, KITTI {kitti_r['to_metadata_ms']:.0f} ms.")
    ok_long = long_r["all"]["p99_ms"] < 5
    ok_kitti = kitti_r["all"]["p99_ms"] < 5
    uncached_p50 = long_r["uncached"]["p50_ms"] / short_r["uncached"]["p50_ms"]
    ok_uncached = kitti_r["uncached"]["p99_ms"] < 5
    line(f"Target p99 < 5 ms: {long_frames}-frame log {long_r['all']['p99_ms']:.2f} ms: {verdict(ok_long)}; KITTI, all "
         f"{kitti_r['all']['count']} queries {kitti_r['all']['p99_ms']:.2f} ms: {verdict(ok_kitti)}; KITTI, the "
         f"{kitti_r['uncached']['count']} uncached answers alone {kitti_r['uncached']['p99_ms']:.2f} ms (p50 "
         f"{kitti_r['uncached']['p50_ms']:.2f}): {verdict(ok_uncached)}; KITTI all cached (2nd pass) "
         f"{kitti_again['all']['p99_ms']:.2f} ms: {verdict(kitti_again['all']['p99_ms'] < 5)}.")
    line(f"(The KITTI p99 over all queries depends on how many there are: 25 uncached answers are {25 / kitti_r['all']['count']:.1%} "
         "of them here, so the p99 sits at the edge of the uncached ones.)")
    line(f"Length independence (same small frames, {long_frames} vs 25 frames): uncached p50 {long_r['uncached']['p50_ms']:.2f} vs "
         f"{short_r['uncached']['p50_ms']:.2f} ms (ratio {uncached_p50:.2f}), uncached p99 {long_r['uncached']['p99_ms']:.2f} vs "
         f"{short_r['uncached']['p99_ms']:.2f} ms; all-request p50/p99 differ because nearly every query of the long log is "
         "uncached and nearly every one of the short log cached.")
    results["point_in_time"] = {"rows": {k: {kk: vv for kk, vv in v.items() if kk != "values_ms"} for k, v in rows.items()},
                                "other_cpu": [first["other_cpu"], second["other_cpu"]],
                                "target_met": ok_long and ok_kitti, "kitti_uncached_target_met": ok_uncached,
                                "uncached_p50_ratio_long_to_short": uncached_p50}


def memory_section(args: argparse.Namespace, root: Path, results: dict[str, Any], quick: bool) -> None:
    read_ahead = 4
    repeats = 3 if quick else 4
    n_trials = 1 if quick else 3
    frames_in_log = len(list(args.kitti.glob("*-frame.glb"))) - 1
    largest = max(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MIB
    log_size = sum(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MIB
    section("4. Server memory: 20 clients on KITTI, 5 of which stop reading after their first message")
    line(f"The 5 receive the metadata, send transform_log and never read again (transport paused); the 15 others (raw "
         f"client) fetch the whole log {repeats} times; {n_trials} trial(s) of each, alternating, on one server per cache size. "
         "RSS of the server process sampled every 10 ms (/proc/PID/status VmRSS); peak over all trials, MB/s median.")
    rows = []
    for cache_mb in (256, 16):
        with start_server(root, "--cache-mb", str(cache_mb), "--read-ahead", str(read_ahead)) as server:
            time.sleep(0.5)
            baseline = rss_mib(server.pid)
            runs: dict[str, list[dict[str, Any]]] = {"15 alone": [], "15 + 5 stalled": []}
            for _ in range(n_trials):
                for name, stalled in (("15 alone", 0), ("15 + 5 stalled", 5)):
                    with RssSampler(server.pid) as sampler:
                        outcome = run_clients({"task": "stream", "url": server.url("kitti"), "clients": 15,
                                               "repeats": repeats, "stalled": stalled}, 1, server.pid)
                    if outcome["frames_per_request"] != [frames_in_log] or outcome["errors"]:
                        raise RuntimeError(f"active clients did not get every frame: {outcome['frames_per_request']}")
                    runs[name].append({**outcome, "peak_mib": sampler.peak, "peak_with_children_mib": sampler.peak_total})
            phases = {}
            for name, outcomes in runs.items():
                middle = median_run(outcomes)
                phases[name] = {"peak_mib": max(o["peak_mib"] for o in outcomes),
                                "peak_with_children_mib": max(o["peak_with_children_mib"] for o in outcomes),
                                "mb_s": middle["mb_s"], "trials_mb_s": middle["trials_mb_s"], "other_cpu": middle["other_cpu"]}
            active_ratio = statistics.median(b["mb_s"] / a["mb_s"] for a, b in zip(runs["15 alone"], runs["15 + 5 stalled"]))
            after = rss_mib(server.pid)
        # Bound: the cache, plus per session the frames read ahead and one serialized frame in the socket's buffer.
        session_budget = (read_ahead + 1) * largest
        bound = baseline + cache_mb + 20 * session_budget
        rows.append({"cache_mb": cache_mb, "baseline_mib": baseline, "after_mib": after, "phases": phases,
                     "active_ratio": active_ratio,
                     "session_budget_mib": session_budget, "bound_mib": bound,
                     "within_bound": all(p["peak_mib"] <= bound for p in phases.values())})
    line()
    line(f"Largest frame {largest:.2f} MiB, whole log {log_size:.0f} MiB; read-ahead {read_ahead}. "
         f"Bound = RSS after start + cache + 20 x (read-ahead + 1) x largest frame.")
    line(f"{'--cache-mb':>10}{'after start':>12}{'peak 15 alone':>15}{'peak 15+5 stalled':>19}{'bound':>8}  "
         "15 active clients' MB/s: alone / beside 5 stalled (median trial ratio)")
    for row in rows:
        a, b = row["phases"]["15 alone"], row["phases"]["15 + 5 stalled"]
        line(f"{row['cache_mb']:>10}{row['baseline_mib']:>10.0f}Mi{a['peak_mib']:>13.0f}Mi{b['peak_mib']:>17.0f}Mi"
             f"{row['bound_mib']:>6.0f}Mi  {a['mb_s']:.0f} / {b['mb_s']:.0f} ({row['active_ratio']:.2f}); trials "
             + " ".join(f"{x:.0f}" for x in a["trials_mb_s"]) + " / " + " ".join(f"{x:.0f}" for x in b["trials_mb_s"]))
    ok = all(r["within_bound"] for r in rows)
    line()
    line(f"Peak within the bound: {verdict(ok)}. (--cache-mb 16 holds fewer frames than the log: sessions then keep "
         "their own read-ahead copies, which is what the per-session budget is for.)")
    results["memory"] = {"rows": rows, "read_ahead": read_ahead, "largest_frame_mib": largest, "target_met": ok}


def deflate_section(root: Path, results: dict[str, Any], quick: bool) -> None:
    repeats_off = 2 if quick else 4
    section("5. permessage-deflate (1 client, KITTI; the client offers deflate, as websockets does by default)")
    rows = []
    for label, flags in (("off (default)", ()), ("--compression", ("--compression",))):
        with start_server(root, *flags) as server:
            for fmt, query in (("GLB", ""), ("JSON", "?message_format=JSON")):
                url = server.url("kitti") + query
                run_clients({"task": "stream", "url": url, "clients": 1, "repeats": 1})  # warm the cache (raw client)
                outcome = run_clients({"task": "stream", "url": url, "clients": 1, "client": "websockets",
                                       "compression": "deflate", "repeats": 1 if flags else repeats_off}, 1, server.pid)
                rows.append({"deflate": label, "format": fmt, **outcome})
    line()
    line(f"{'server':<15}{'format':<7}{'negotiated':<12}{'payload MB/s':>13}{'wire MB/s':>10}{'frames/s':>9}"
         f"{'wire/payload':>13}{'srv CPU ms/frame':>17}{'cli CPU ms/frame':>17}{'others':>7}")
    for r in rows:
        negotiated = "deflate" if r["extensions"] and "permessage-deflate" in r["extensions"] else "no"
        line(f"{r['deflate']:<15}{r['format']:<7}{negotiated:<12}{r['mb_s']:13.1f}{r['wire_mb_s']:10.1f}{r['frames_s']:9.1f}"
             f"{r['wire_bytes'] / r['bytes']:13.3f}{r['server_cpu_s'] / r['frames'] * 1000:17.1f}"
             f"{r['client_cpu_s'] / r['frames'] * 1000:17.1f}{r['other_cpu']:7.2f}")
    by = {(r["deflate"], r["format"]): r for r in rows}
    line()
    for fmt in ("GLB", "JSON"):
        off, on = by[("off (default)", fmt)], by[("--compression", fmt)]
        line(f"{fmt}: deflate sends {on['wire_bytes'] / on['bytes']:.0%} of the bytes at {on['mb_s'] / off['mb_s']:.2f}x the "
             f"payload rate; it delivers more only over links slower than the ~{on['mb_s']:.0f} MB/s (~{on['mb_s'] * 8:.0f} Mbit/s) "
             "of payload it sustains, and that is one server core's worth, shared by every deflate session.")
    line("(The 'off' rows are limited by the websockets client, about one core per GB/s, and by other processes: 'others' "
         "is the cores they used meanwhile.)")
    results["deflate"] = {"rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", type=Path, default=KITTI, help=f"the KITTI GLB log (default {KITTI})")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a 10 000-frame long log (under ~2 minutes)")
    parser.add_argument("--json", type=Path, help="also write the numbers to this file")
    parser.add_argument("--client-procs", type=int, default=1,
                        help="also run the 20-client throughput rows with this many client processes (rows with 1, and "
                        "2 in a full run, are always there)")
    parser.add_argument("--long-frames", type=int, help="frames of the generated long log (default 100 000; 10 000 with --quick)")
    shm = Path("/dev/shm")
    parser.add_argument("--tmp", type=Path, default=shm if shm.is_dir() and os.access(shm, os.W_OK) else None,
                        help="where to write the generated logs (default /dev/shm, a RAM disk: 100 000 small files are "
                        "written in ~2 s there and can take a minute on a busy disk)")
    parser.add_argument("--role", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role:
        role, spec = args.role
        (reference_main if role == "reference" else client_main)(spec)
        return

    began = time.perf_counter()
    quick = args.quick
    long_frames = args.long_frames or (10_000 if quick else 100_000)
    info = machine()
    results: dict[str, Any] = {"machine": info, "quick": quick, "long_frames": long_frames, "sections": {},
                               "load_average_at_start": os.getloadavg()}
    line(f"xviz-server benchmark ({'quick' if quick else 'full'} run), {time.strftime('%Y-%m-%d %H:%M:%S')}")
    line(f"machine: {info['cores']} cores ({info['cpu']}), Linux {info['kernel']}, Python {info['python']}, "
         f"websockets {info['websockets']}, uvloop {info['uvloop']}; load average at start "
         + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    line(f"server under test: {info['server_code']}, run as `python -m xviz_server serve` (uvloop)")
    line("reference: a bare websockets + uvloop server sending the same frames, pre-loaded in memory.")
    line("clients: separate processes, asyncio on uvloop: 'raw' (a minimal WebSocket client that counts bytes in place: the "
         "server is the bottleneck) and 'websockets' (the websockets client: about one core per ~1 GB/s, so the client is the "
         "bottleneck). Server, reference and clients share the 2 cores; 20 clients run in 1 client process unless a row "
         "says otherwise.")
    with tempfile.TemporaryDirectory(prefix="xviz-bench-", dir=args.tmp) as scratch:
        # Two data roots: KITTI alone, and KITTI with the generated logs (100 000 files to list at start).
        root, pit_root = Path(scratch) / "logs", Path(scratch) / "pit-logs"
        for directory in (root, pit_root):
            directory.mkdir()
            (directory / "kitti").symlink_to(args.kitti.resolve())
        started = time.perf_counter()
        generate_log(pit_root / "long", long_frames)
        generated_s = time.perf_counter() - started
        generate_log(pit_root / "short", 25)
        frames = len(list(args.kitti.glob("*-frame.glb"))) - 1
        total = sum(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MB
        line(f"KITTI log: {args.kitti} ({frames} frames + metadata, {total:.1f} MB); generated a {long_frames}-frame log "
             f"(small GLB frames, SNAPSHOT) in {generated_s:.1f} s under {scratch}")
        results["generate_seconds"] = generated_s

        def timed(name: str, function: Any, *arguments: Any) -> None:
            started, cpu = time.perf_counter(), other_cpu()
            function(*arguments)
            seconds, other = time.perf_counter() - started, other_cores(cpu, started)
            line(f"[{seconds:.0f} s; other processes on the machine used {other:.2f} cores on average meanwhile]")
            results["sections"][name] = {"seconds": seconds, "other_cores": other}

        with start_reference({"kitti": args.kitti, "short": pit_root / "short"}) as reference:
            timed("throughput", throughput_section, args, root, reference, results, quick)
            timed("first_frame", first_frame_section, root, reference, results, quick)
            timed("point_in_time", point_in_time_section, pit_root, reference, results, quick, long_frames)
        timed("memory", memory_section, args, root, results, quick)
        timed("deflate", deflate_section, root, results, quick)
    results["seconds"] = time.perf_counter() - began
    line()
    line(f"ran in {results['seconds']:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))
        line(f"numbers written to {args.json}")

if __name__ == "__main__":
    main()
