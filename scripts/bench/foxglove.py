#!/usr/bin/env python3
"""Benchmark the Foxglove face: converting a frame, and streaming a cached log against the XVIZ path.

    .venv/bin/python scripts/bench/foxglove.py [--repeats 5] [--quick]

1. Converting: each of the 25 real KITTI frames (2.2 MB GLB) into its
   Foxglove messages (:func:`xviz_server.foxglove.convert.convert`), in this
   process, beside decoding the same frame alone (the bare codec's share).
2. Streaming: one server process (``xviz-server serve``) serving the KITTI
   log from a warm frame cache; one client at a time reads as fast as it can:
   an XVIZ client asks for the whole log (``xviz/transform_log``, GLB), a
   Foxglove client subscribes to every channel and plays the log at the
   fastest speed the server allows. Reported: MB/s of payload received (the
   median of ``--repeats``), and Foxglove's MB/s over XVIZ's in each repeat.
3. Seeking: ``--clients`` Foxglove clients of the same log at once, each
   seeking (paused) to random frames ``--seeks`` times; the time from
   sending the request to the first message of the frame sought, p50 and p99
   over every seek of every client.

"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import struct
import tempfile
import time
from pathlib import Path

from websockets.asyncio.client import connect
from websockets.typing import Subprotocol

from kit import KITTI, parse, percentile
from kit.proc import start_server
from xviz_server.codec import decode
from xviz_server.foxglove.convert import convert, plan
from xviz_server.foxglove.session import MAX_SPEED

MB = 1e6


def converting(repeats: int) -> None:
    frames = sorted(KITTI.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))
    channels = plan(decode(frames[0].read_bytes())["data"])
    updates = [path.read_bytes() for path in frames[1:]]
    converted, decoded = [], []
    for _ in range(repeats):
        for data in updates:
            began = time.perf_counter()
            convert(data, channels)
            converted.append((time.perf_counter() - began) * 1e3)
            began = time.perf_counter()
            decode(data)
            decoded.append((time.perf_counter() - began) * 1e3)
    print("| converting a KITTI frame (2.2 MB GLB) | median ms | p95 ms |")
    print("|---|---|---|")
    print(f"| into Foxglove messages | {statistics.median(converted):.2f} | {percentile(converted, 95):.2f} |")
    print(f"| decoding it alone (the codec's share) | {statistics.median(decoded):.2f} | {percentile(decoded, 95):.2f} |")


async def xviz_log(port: int) -> tuple[int, float]:
    """Bytes of the whole log as an XVIZ client gets it, and the seconds it took."""
    async with connect(f"ws://127.0.0.1:{port}/?log=kitti&message_format=BINARY", max_size=None) as websocket:
        await websocket.recv()  # metadata
        began, received = time.perf_counter(), 0
        await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "all"}}))
        while True:
            message = await websocket.recv()
            if len(message) < 4096 and b"transform_log_done" in (message.encode() if isinstance(message, str) else message):
                return received, time.perf_counter() - began
            received += len(message)


async def foxglove_log(port: int) -> tuple[int, float]:
    """Bytes of the whole log as a Foxglove client playing it at the fastest speed gets it, and the seconds it took."""
    async with connect(f"ws://127.0.0.1:{port}/?log=kitti", subprotocols=[Subprotocol("foxglove.sdk.v1")], max_size=None) as websocket:
        json.loads(await websocket.recv())
        channels = json.loads(await websocket.recv())["channels"]
        await websocket.send(struct.pack("<BBfBQI", 3, 1, 1.0, 0, 0, 0))  # take control: paused
        await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]}))
        began, received = time.perf_counter(), 0
        await websocket.send(struct.pack("<BBfBQI", 3, 0, MAX_SPEED, 0, 0, 0))  # play from the start
        while True:
            message = await websocket.recv()
            if isinstance(message, bytes):
                if message[0] == 0x05 and message[1] == 3:  # playback state: ended
                    return received, time.perf_counter() - began
                if message[0] == 0x01:
                    received += len(message) - 13


async def seeker(port: int, seeks: int, seed: int) -> list[float]:
    """Seconds from each seek request to the first message at the frame sought."""
    rng = random.Random(seed)
    async with connect(f"ws://127.0.0.1:{port}/?log=kitti", subprotocols=[Subprotocol("foxglove.sdk.v1")], max_size=None) as websocket:
        info = json.loads(await websocket.recv())
        channels = json.loads(await websocket.recv())["channels"]
        await websocket.send(struct.pack("<BBfBQI", 3, 1, 1.0, 0, 0, 0))  # paused
        await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]}))
        start = info["dataStartTime"]["sec"] * 10**9 + info["dataStartTime"]["nsec"]
        end = info["dataEndTime"]["sec"] * 10**9 + info["dataEndTime"]["nsec"]
        waits = []
        for number in range(seeks):
            target = rng.randrange(start, end)
            began = time.perf_counter()
            await websocket.send(struct.pack("<BBfBQI", 3, 1, 1.0, 1, target, 1) + b"s")
            while True:
                message = await websocket.recv()
                if isinstance(message, bytes) and message[0] == 0x01:
                    waits.append(time.perf_counter() - began)
                    break
            await asyncio.sleep(rng.uniform(0.0, 0.05))
            while True:  # the rest of the frame
                try:
                    await asyncio.wait_for(websocket.recv(), 0.05)
                except asyncio.TimeoutError:
                    break
        return waits


async def streaming(repeats: int, clients: int, seeks: int) -> None:
    with tempfile.TemporaryDirectory() as data:
        (Path(data) / "kitti").symlink_to(KITTI)
        with start_server(data) as server:
            port = server.port
            await xviz_log(port)  # warm the cache, both ways
            await foxglove_log(port)
            rates: dict[str, list[float]] = {"xviz": [], "foxglove": []}
            for _ in range(repeats):
                for name, run in (("xviz", xviz_log), ("foxglove", foxglove_log)):
                    size, seconds = await run(port)
                    rates[name].append(size / seconds / MB)
            waits = [wait for each in await asyncio.gather(*(seeker(port, seeks, seed) for seed in range(clients))) for wait in each]
    ratios = [f / x for f, x in zip(rates["foxglove"], rates["xviz"])]
    print()
    print("| streaming the cached KITTI log to one client | MB/s (median) |")
    print("|---|---|")
    print(f"| XVIZ, transform_log of the whole log (GLB) | {statistics.median(rates['xviz']):.0f} |")
    print(f"| Foxglove, every channel, played at {MAX_SPEED:g}x | {statistics.median(rates['foxglove']):.0f} |")
    print(f"| Foxglove / XVIZ (median of the repeats) | x{statistics.median(ratios):.2f} |")
    print()
    print(f"| {clients} Foxglove clients seeking in one log, {len(waits)} seeks | p50 ms | p99 ms |")
    print("|---|---|---|")
    print(f"| request to the first message at the new time | {statistics.median(waits) * 1e3:.1f} | {percentile(waits, 99) * 1e3:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--clients", type=int, default=20, help="Foxglove clients seeking at once")
    parser.add_argument("--seeks", type=int, default=20, help="seeks per client")
    args = parse(parser, {"repeats": 1, "clients": 2, "seeks": 3})
    converting(args.repeats)
    asyncio.run(streaming(args.repeats, args.clients, args.seeks))


if __name__ == "__main__":
    main()
