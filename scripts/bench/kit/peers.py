#!/usr/bin/env python3
"""The peers of the benchmarks (``server.py``, ``store.py``), each run as its own process (``python -m kit.peers --role``):

* ``reference``: a bare websockets (asyncio API) + uvloop server that pre-loads
  the frame files and, for each ``xviz/transform_log``, sends them all then a
  done message: the best any Python server can do on this machine;
* ``foxglove-sdk``: the published ``foxglove-sdk`` WebSocket server (Rust,
  MIT) playing a KITTI log's Foxglove messages, converted in advance: the
  reference for one Foxglove client playing a log;
* ``client``: the clients, the same code against both servers (:mod:`kit.ws`:
  the raw client and the websockets client, on uvloop); they stream whole logs
  or time point-in-time answers, and print what they measured as JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import uvloop
from websockets.asyncio.server import serve

from kit import percentile
from kit.ws import CLIENTS, RawClient, envelope_of

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
        "bytes": sum(r[0] for r in results),
        "wire_bytes": wire,
        "frames": sum(r[1] for r in results),
        "errors": sum(r[2] for r in results),
        "started": started,
        "ended": ended,
        "seconds": ended - started,
        "client_cpu_s": cpu,
        "first_frame_list": [r[3] * 1000 for r in results],
        "first_frame_ms": statistics.median(r[3] * 1000 for r in results),
        "frames_per_request": sorted({n for r in results for n in r[4]}),
        "extensions": extensions,
    }


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
            request = json.dumps(
                {"type": "xviz/transform_point_in_time", "data": {"id": str(number), "query_timestamp": instant}}
            )
            sent = time.perf_counter()
            await session.send(request)
            length, head, when = await session.recv()
            elapsed = (when - sent) * 1000
            self.latencies.append(elapsed)
            self.sizes.append(length)
            if self.classify:
                message = envelope_of(head)
                if message.get("type") != "xviz/state_update":
                    raise RuntimeError(
                        f"{self.name}: point in time {instant}: got {message.get('type')}: {str(message)[:300]}"
                    )
                stamp = message["data"]["updates"][0]["timestamp"]
                (self.cached if stamp in self.seen else self.uncached).append(elapsed)
                self.seen.add(stamp)

    def result(self) -> dict[str, Any]:
        return {
            "to_metadata_ms": self.to_metadata_ms,
            "all": summary(self.latencies),
            "values_ms": self.latencies,
            "uncached": summary(self.uncached),
            "cached": summary(self.cached),
            "answer_bytes": statistics.median(self.sizes) if self.sizes else None,
        }


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


# ================================================================ the foxglove-sdk server


def foxglove_sdk_main(directory: str) -> None:
    """The foxglove-sdk server with one channel per channel this server advertises for the KITTI log in ``directory``.

    Every frame is converted first (``xviz_server.foxglove.translate``, what the
    server's warm cache holds). A play request starts a thread that logs every
    message in time order as fast as the SDK takes them (its queue per client
    holds the whole log: none is dropped), then broadcasts the state *ended*.
    The SDK has one timeline for every client: one client at a time here.
    """
    import importlib
    import threading

    # The benchmark foxglove.py shadows the package here, on the path and for mypy: imported by name, untyped.
    bench = Path(__file__).resolve().parents[1]
    sys.path[:] = [entry for entry in sys.path if Path(entry or ".").resolve() != bench]
    foxglove: Any = importlib.import_module("foxglove")
    websocket: Any = importlib.import_module("foxglove.websocket")
    Capability, PlaybackCommand = websocket.Capability, websocket.PlaybackCommand
    PlaybackState, PlaybackStatus = websocket.PlaybackState, websocket.PlaybackStatus

    from xviz_server.codec import decode
    from xviz_server.foxglove.translate import convert, plan
    from xviz_server.records import unpack

    frames = sorted(Path(directory).glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))
    channels = plan(decode(frames[0].read_bytes())["data"])
    messages = [
        (c, t, bytes(data)) for path in frames[1:] for c, t, data in unpack(convert(path.read_bytes(), channels))
    ]
    start, end = messages[0][1], messages[-1][1]
    sdk = {
        channel.id: foxglove.Channel(
            channel.topic,
            message_encoding=channel.schema.encoding,
            schema=foxglove.Schema(
                name=channel.schema.name, encoding=channel.schema.schema_encoding, data=channel.schema.data()
            ),
        )
        for channel in channels.channels
    }

    def play(speed: float) -> None:
        for channel_id, time_ns, data in messages:
            sdk[channel_id].log(data, log_time=time_ns)
        server.broadcast_playback_state(PlaybackState(PlaybackStatus.Ended, end, speed, False, ""))

    class Listener:
        def on_playback_control_request(self, request: Any) -> Any:
            if request.playback_command == PlaybackCommand.Play:
                threading.Thread(target=play, args=(request.playback_speed,), daemon=True).start()
                return PlaybackState(PlaybackStatus.Playing, start, request.playback_speed, False, request.request_id)
            return PlaybackState(PlaybackStatus.Paused, start, request.playback_speed, False, request.request_id)

    server = foxglove.start_server(
        name="foxglove-sdk reference",
        host="127.0.0.1",
        port=0,
        capabilities=[Capability.Time],
        server_listener=Listener(),
        playback_time_range=(start, end),
        message_backlog_size=len(messages) + 64,
    )
    print(
        f"foxglove-sdk listening on ws://127.0.0.1:{server.port}/ ({len(messages)} messages)",
        file=sys.stderr,
        flush=True,
    )
    threading.Event().wait()


def main() -> None:
    parser = argparse.ArgumentParser(description="A peer of the benchmarks")
    parser.add_argument("--role", choices=["reference", "foxglove-sdk", "client"], required=True)
    parser.add_argument("spec", help="the peer's JSON spec (a log folder for foxglove-sdk), or - for standard input")
    args = parser.parse_args()
    {"reference": reference_main, "foxglove-sdk": foxglove_sdk_main, "client": client_main}[args.role](args.spec)


if __name__ == "__main__":
    main()
