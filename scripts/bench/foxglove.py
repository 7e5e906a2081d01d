#!/usr/bin/env python3
"""Benchmark the Foxglove face: converting a frame, and streaming a cached log against the XVIZ path.

    .venv/bin/python scripts/bench/foxglove.py [--repeats 5] [--rate 10] [--seconds 20] [--live-clients 3] [--quick]

1. Converting: each of the 25 real KITTI frames (2.2 MB GLB) into its
   Foxglove messages (:func:`xviz_server.foxglove.translate.convert`), in this
   process, beside decoding the same frame alone (the bare codec's share).
2. Streaming: one server process (``xviz-server serve``) serving the KITTI
   log from a warm frame cache; one client at a time reads as fast as it can:
   an XVIZ client asks for the whole log (``xviz/transform_log``, GLB), a
   Foxglove client subscribes to every channel and plays the log at the
   fastest speed the server allows. Reported: MB/s of payload received (the
   median of ``--repeats``), and Foxglove's MB/s over XVIZ's in each repeat.
   The reference, in the same run: the published ``foxglove-sdk`` server
   (Foxglove's own, in Rust) in a process of its own, holding the same
   messages converted in advance, logging them all as fast as it takes them
   when the client asks to play (it has no pacing and one timeline for
   every client); the same client receives them all.
3. Exporting: ``GET /api/logs/kitti/export`` (the whole log as an MCAP
   file), ``--repeats`` times: the time to the first byte of the file and
   to its end, beside ``GET /healthz`` on the same server (the bare HTTP
   round trip).
4. Seeking: ``--clients`` Foxglove clients of the same log at once, each
   seeking (paused) to random frames ``--seeks`` times; the time from
   sending the request to the first message of the frame sought, p50 and p99
   over every seek of every client.
4. Live: a source process pushes a real KITTI frame (2.1 MB of GLB) to
   ``/ingest/bench`` at ``--rate`` Hz for ``--seconds`` (``kit.live``'s
   source, each update's timestamp unique); one XVIZ live viewer and
   ``--live-clients`` Foxglove clients (every channel subscribed) of that
   feed, all minimal clients (``kit.ws.RawClient``) in this process, note
   when each update's last byte arrives: for the Foxglove clients, its
   ``time`` message, which follows its messages. Reported: a Foxglove
   client's arrival minus the XVIZ viewer's, for the same update, p50 and
   p99 over every update of every client (goal: at most 20 ms), and the
   updates each got.

"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import statistics
import struct
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from kit import KITTI, parse, percentile
from kit.live import ROLE
from kit.proc import BENCH, start_foxglove_sdk, start_server
from kit.ws import RawClient, envelope_of
from websockets.asyncio.client import connect
from websockets.typing import Subprotocol

from xviz_server.codec import decode
from xviz_server.foxglove.session import MAX_SPEED
from xviz_server.foxglove.translate import convert, nanoseconds, plan
from xviz_server.records import unpack

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
    print(
        f"| decoding it alone (the codec's share) | {statistics.median(decoded):.2f} | {percentile(decoded, 95):.2f} |"
    )


async def xviz_log(port: int) -> tuple[int, float]:
    """Bytes of the whole log as an XVIZ client gets it, and the seconds it took."""
    async with connect(f"ws://127.0.0.1:{port}/?log=kitti&message_format=BINARY", max_size=None) as websocket:
        await websocket.recv()  # metadata
        began, received = time.perf_counter(), 0
        await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "all"}}))
        while True:
            message = await websocket.recv()
            if len(message) < 4096 and b"transform_log_done" in (
                message.encode() if isinstance(message, str) else message
            ):
                return received, time.perf_counter() - began
            received += len(message)


async def foxglove_log(port: int, expected: int) -> tuple[int, float]:
    """Bytes of the whole log (``expected`` messages) as a Foxglove client playing it at the fastest speed gets it,
    and the seconds from asking to play to the last message."""
    async with connect(
        f"ws://127.0.0.1:{port}/?log=kitti", subprotocols=[Subprotocol("foxglove.sdk.v1")], max_size=None
    ) as websocket:
        _, channels = await opened(websocket)
        await websocket.send(struct.pack("<BBfBQI", 3, 1, 1.0, 0, 0, 0))  # take control: paused
        await websocket.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]})
        )
        began, received, count = time.perf_counter(), 0, 0
        await websocket.send(struct.pack("<BBfBQI", 3, 0, MAX_SPEED, 0, 0, 0))  # play from the start
        while count < expected:
            message = await websocket.recv()
            if isinstance(message, bytes) and message[0] == 0x01:
                received += len(message) - 13
                count += 1
        return received, time.perf_counter() - began


async def http_get(port: int, path: str) -> tuple[float, float, int]:
    """Seconds to the first byte of the body of ``GET path`` and to its end, and the body's bytes (chunked or not)."""
    began = time.perf_counter()
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    head = (await reader.readuntil(b"\r\n\r\n")).lower()
    first, size = 0.0, 0
    if b"transfer-encoding: chunked" in head:
        while length := int((await reader.readline()).strip(), 16):
            size += len(await reader.readexactly(length + 2)) - 2
            first = first or time.perf_counter() - began
    else:
        size = len(await reader.read())
        first = time.perf_counter() - began
    writer.close()
    return first, time.perf_counter() - began, size


async def opened(websocket: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``serverInfo`` and the advertised channels (the log's start time, a binary time message, comes between)."""
    info = json.loads(await websocket.recv())
    while isinstance(message := await websocket.recv(), bytes):
        pass
    return info, json.loads(message)["channels"]


async def seeker(port: int, seeks: int, seed: int) -> list[float]:
    """Seconds from each seek request to the first message at the frame sought."""
    rng = random.Random(seed)
    async with connect(
        f"ws://127.0.0.1:{port}/?log=kitti", subprotocols=[Subprotocol("foxglove.sdk.v1")], max_size=None
    ) as websocket:
        info, channels = await opened(websocket)
        await websocket.send(struct.pack("<BBfBQI", 3, 1, 1.0, 0, 0, 0))  # paused
        await websocket.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]})
        )
        start = info["dataStartTime"]["sec"] * 10**9 + info["dataStartTime"]["nsec"]
        end = info["dataEndTime"]["sec"] * 10**9 + info["dataEndTime"]["nsec"]
        waits = []
        for _number in range(seeks):
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


def messages_in_log() -> int:
    """How many Foxglove messages the KITTI log makes (what a client of every channel receives)."""
    frames = sorted(KITTI.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))
    channels = plan(decode(frames[0].read_bytes())["data"])
    return sum(len(list(unpack(convert(path.read_bytes(), channels)))) for path in frames[1:])


async def streaming(repeats: int, clients: int, seeks: int) -> None:
    expected = messages_in_log()
    before = os.getloadavg()
    with tempfile.TemporaryDirectory() as data:
        (Path(data) / "kitti").symlink_to(KITTI)
        with start_server(data) as server, start_foxglove_sdk(KITTI) as sdk:
            port = server.port
            await xviz_log(port)  # warm the cache, both ways
            await foxglove_log(port, expected)
            rates: dict[str, list[float]] = {"xviz": [], "foxglove": [], "sdk": []}
            for _ in range(repeats):
                for name, run in (
                    ("xviz", xviz_log(port)),
                    ("foxglove", foxglove_log(port, expected)),
                    ("sdk", foxglove_log(sdk.port, expected)),
                ):
                    size, seconds = await run
                    rates[name].append(size / seconds / MB)
            exports = [await http_get(port, "/api/logs/kitti/export") for _ in range(repeats)]
            health = [await http_get(port, "/healthz") for _ in range(repeats)]
            waits = [
                wait
                for each in await asyncio.gather(*(seeker(port, seeks, seed) for seed in range(clients)))
                for wait in each
            ]
    after = os.getloadavg()
    ratios = [f / x for f, x in zip(rates["foxglove"], rates["xviz"])]
    against_sdk = [f / r for f, r in zip(rates["foxglove"], rates["sdk"])]
    print()
    print(f"load average {before[0]:.2f} before, {after[0]:.2f} after (1 min; 2 cores)")
    print()
    print("| streaming the cached KITTI log to one client | MB/s (median) |")
    print("|---|---|")
    print(f"| XVIZ, transform_log of the whole log (GLB) | {statistics.median(rates['xviz']):.0f} |")
    print(f"| Foxglove, every channel, played at {MAX_SPEED:g}x | {statistics.median(rates['foxglove']):.0f} |")
    print(f"| foxglove-sdk server, the same {expected} messages, unpaced | {statistics.median(rates['sdk']):.0f} |")
    print(f"| Foxglove / XVIZ (median of the repeats) | x{statistics.median(ratios):.2f} |")
    print(f"| Foxglove / foxglove-sdk (median of the repeats) | x{statistics.median(against_sdk):.2f} |")
    print()
    size = exports[0][2]
    print(f"| GET, {repeats} times | first byte p50 ms | max ms | whole answer p50 ms | MB/s |")
    print("|---|---|---|---|---|")
    for label, runs in (
        (f"/api/logs/kitti/export (MCAP, {size / MB:.1f} MB)", exports),
        ("/healthz (reference)", health),
    ):
        firsts, wholes = [run[0] * 1e3 for run in runs], [run[1] for run in runs]
        rate = statistics.median(run[2] / run[1] / MB for run in runs)
        print(
            f"| {label} | {statistics.median(firsts):.1f} | {max(firsts):.1f} | {statistics.median(wholes) * 1e3:.0f} | {rate:.1f} |"
        )
    print()
    print(f"| {clients} Foxglove clients seeking in one log, {len(waits)} seeks | p50 ms | p99 ms |")
    print("|---|---|---|")
    print(
        f"| request to the first message at the new time | {statistics.median(waits) * 1e3:.1f} | {percentile(waits, 99) * 1e3:.1f} |"
    )


async def live_viewer(url: str, seconds: float, subscribed: asyncio.Event, foxglove: bool) -> dict[int, float]:
    """When each update of the feed at ``url`` arrives (by its time in nanoseconds), at an XVIZ viewer or a Foxglove
    client subscribed to every channel (then: when its ``time`` message arrives); ``subscribed`` is set once it is."""
    setup = 1 << 22  # room for the advertise message (its schemas) while setting up
    client = await RawClient.open(url, keep=setup, subprotocol="foxglove.sdk.v1" if foxglove else None)
    arrivals: dict[int, float] = {}
    try:
        if foxglove:
            while True:
                _, head, _ = await client.recv()
                message = json.loads(head) if head[:1] == b"{" else {}
                if message.get("op") == "advertise":
                    subscriptions = [{"id": c["id"], "channelId": c["id"]} for c in message["channels"]]
                    await client.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
                    break
        client.protocol.keep = 16 if foxglove else 65536
        current: int | None = None
        subscribed.set()
        deadline = time.perf_counter() + seconds
        while (left := deadline - time.perf_counter()) > 0:
            try:
                length, head, arrived = await asyncio.wait_for(client.recv(), left)
            except asyncio.TimeoutError:
                break
            if foxglove and head[:1] == b"\x02":  # a time message: the update's messages follow it
                current = struct.unpack_from("<Q", head, 1)[0]
                arrivals[current] = arrived
            elif foxglove and head[:1] == b"\x01" and current is not None:  # the update is in once its last message is
                arrivals[current] = arrived
            elif not foxglove and length > 100_000:
                arrivals[nanoseconds(envelope_of(head)["data"]["updates"][0]["timestamp"])] = arrived
    finally:
        client.abort()
    return arrivals


async def live(rate: float, seconds: float, clients: int) -> None:
    with start_server(None) as server:
        url = f"ws://127.0.0.1:{server.port}/?session_type=live&log=bench"
        ready = [asyncio.Event() for _ in range(clients + 1)]
        watch = seconds + 4
        viewers = [asyncio.ensure_future(live_viewer(url, watch, ready[i], foxglove=i > 0)) for i in range(clients + 1)]
        source = await asyncio.create_subprocess_exec(
            *ROLE,
            "source",
            f"ws://127.0.0.1:{server.port}/ingest/bench",
            str(rate),
            str(seconds),
            cwd=BENCH,
        )
        await asyncio.wait_for(asyncio.gather(*(event.wait() for event in ready)), 30)  # the source waits 1 s for them
        if await source.wait() != 0:
            raise subprocess.CalledProcessError(source.returncode or 1, "kit.live source")
        xviz, *foxes = await asyncio.gather(*viewers)
    behind = [(fox[stamp] - arrived) * 1e3 for fox in foxes for stamp, arrived in xviz.items() if stamp in fox]
    sent = int(rate * seconds)
    print()
    print(
        f"| a live feed of KITTI frames at {rate:g} Hz, {sent} updates; {clients} Foxglove clients beside one XVIZ viewer "
        "| p50 ms | p99 ms | updates got (XVIZ; Foxglove min-max) |"
    )
    print("|---|---|---|---|")
    got = [len(fox) for fox in foxes]
    print(
        f"| Foxglove client's arrival minus the XVIZ viewer's, per update | {statistics.median(behind):.1f} "
        f"| {percentile(behind, 99):.1f} | {len(xviz)}; {min(got)}-{max(got)} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--clients", type=int, default=20, help="Foxglove clients seeking at once")
    parser.add_argument("--seeks", type=int, default=20, help="seeks per client")
    parser.add_argument("--rate", type=float, default=10.0, help="live updates a second")
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds the live source sends")
    parser.add_argument("--live-clients", type=int, default=3, help="Foxglove clients of the live feed")
    args = parse(parser, {"repeats": 1, "clients": 2, "seeks": 3, "seconds": 1.5, "live_clients": 1})
    converting(args.repeats)
    asyncio.run(streaming(args.repeats, args.clients, args.seeks))
    asyncio.run(live(args.rate, args.seconds, args.live_clients))


if __name__ == "__main__":
    main()
