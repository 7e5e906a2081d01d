#!/usr/bin/env python3
"""The peers of scripts/bench_server.py, each run as its own process (``--role``):

* ``reference``: a bare websockets (asyncio API) + uvloop server that pre-loads
  the frame files and, for each ``xviz/transform_log``, sends them all then a
  done message: the best any Python server can do on this machine;
* ``client``: the clients, the same code against both servers: a minimal
  WebSocket client ("raw", asyncio on uvloop, counting bytes in place), and the
  websockets asyncio client; they stream whole logs or time point-in-time
  answers, and print what they measured as JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import statistics
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import uvloop
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import serve

REPO = Path(__file__).resolve().parents[1]
KITTI = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-2011_09_26_drive_0001-head"
MB = 1e6  # rates in MB/s are 10^6 bytes per second
MIB = 1 << 20  # memory in MiB, like --cache-mb
QUIET = 0.25  # a trial is "quiet" when other processes used fewer cores than this

from benchkit import percentile  # noqa: E402

# ================================================================ helpers


def transform_log(request_id: str) -> str:
    return json.dumps({"type": "xviz/transform_log", "data": {"id": request_id}})




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



def main() -> None:
    parser = argparse.ArgumentParser(description="A peer of scripts/bench_server.py")
    parser.add_argument("--role", choices=["reference", "client"], required=True)
    parser.add_argument("spec", help="the peer's JSON spec, or - for standard input")
    args = parser.parse_args()
    (reference_main if args.role == "reference" else client_main)(args.spec)


if __name__ == "__main__":
    main()
