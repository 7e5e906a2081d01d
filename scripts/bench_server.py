#!/usr/bin/env python3
"""Benchmark the session server against a bare websockets server, in one run.

    python scripts/bench_server.py [--quick] [--json FILE] [--kitti DIR]

Every party is its own process: the server under test (``xviz-server serve``),
the reference (a bare websockets + uvloop server that sends the same frame
bytes, pre-loaded, for each request: the best any Python server can do
here), and the clients. Sections:

1. whole-log throughput of the real KITTI log for 1 and 20 clients, GLB as
   stored and transcoded to JSON, as a ratio to the reference;
2. time to first frame, cold (first request after start) and warm;
3. point-in-time latency p50/p99 on a generated long log and on KITTI,
   beside the loopback round trip of a trivial message;
4. server peak RSS with 20 clients of which 5 stop reading, against the
   bound: cache size + per-session budget;
5. permessage-deflate on and off.

The process runs itself in other roles (``--role``) for the reference server
and the clients.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import random
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import websockets

REPO = Path(__file__).resolve().parents[1]
KITTI = REPO.parent / "shared" / "data" / "kitti-2011_09_26_drive_0001-head"
TRANSFORM_LOG = json.dumps({"type": "xviz/transform_log", "data": {"id": "bench"}})


# ---------------------------------------------------------------- processes


def spawn(args: list[str], ready: str) -> tuple[subprocess.Popen, int]:
    """Start a process that prints ``ready`` with a port on stderr; return it and the port."""
    process = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, cwd=REPO)
    assert process.stderr is not None
    for line in process.stderr:
        match = re.search(ready, line)
        if match:
            return process, int(match.group(1))
    raise RuntimeError(f"{args[:4]} exited before listening")


def start_server(root: Path, *extra: str) -> tuple[subprocess.Popen, int]:
    return spawn(
        [sys.executable, "-m", "xviz_server", "serve", "--data-dir", str(root), "--port", "0", *extra],
        r"listening on ws://127\.0\.0\.1:(\d+)/",
    )


def start_reference(log: Path) -> tuple[subprocess.Popen, int]:
    return spawn([sys.executable, __file__, "--role", "reference", "--kitti", str(log)], r"reference on (\d+)")


def stop(process: subprocess.Popen) -> None:
    process.terminate()
    process.wait(10)


def client(*args: str) -> dict[str, Any]:
    """Run a client process and return what it measured."""
    output = subprocess.run([sys.executable, __file__, "--role", *args], capture_output=True, text=True, check=True, cwd=REPO)
    return json.loads(output.stdout)


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


# ------------------------------------------------------------------ roles


def is_done(message: bytes | str) -> bool:
    """Whether a message is a transform_log_done (small, so the test is cheap)."""
    if len(message) > 200:
        return False
    return "transform_log_done" in (message.decode(errors="replace") if isinstance(message, bytes) else message)


async def reference_server(log: Path) -> None:
    frames = [(log / f"{i}-frame.glb").read_bytes() for i in range(2, 2 + len(list(log.glob("*-frame.glb"))) - 1)]
    metadata = (log / "1-frame.glb").read_bytes()

    async def handler(websocket: Any) -> None:
        await websocket.send(metadata)
        async for message in websocket:
            request = json.loads(message)
            if request["type"] == "xviz/transform_point_in_time":
                await websocket.send(frames[0])  # the same size as an answer from the server
                continue
            for frame in frames:
                await websocket.send(frame)
            await websocket.send(json.dumps({"type": "xviz/transform_log_done", "data": {"id": request["data"]["id"]}}))

    async with websockets.serve(handler, "127.0.0.1", 0, compression=None, max_size=None) as server:
        print(f"reference on {server.sockets[0].getsockname()[1]}", file=sys.stderr, flush=True)
        await asyncio.Future()


async def throughput_client(url: str, clients: int, repeats: int, stalled: int = 0) -> dict[str, Any]:
    """``clients`` sessions each fetch the whole log ``repeats`` times; ``stalled`` more stop reading."""
    async def one() -> tuple[int, int, float]:
        async with websockets.connect(url, max_size=None) as websocket:
            await websocket.recv()
            size = frames = 0
            first = None
            started = time.perf_counter()
            for _ in range(repeats):
                await websocket.send(TRANSFORM_LOG)
                while True:
                    message = await websocket.recv()
                    if first is None:
                        first = time.perf_counter() - started
                    if is_done(message):
                        break
                    size += len(message)
                    frames += 1
            return size, frames, first or 0.0

    sleepers = []
    for _ in range(stalled):
        websocket = await websockets.connect(url, max_size=None, max_queue=1)
        await websocket.recv()
        await websocket.send(TRANSFORM_LOG)
        websocket.transport.pause_reading()
        sleepers.append(websocket)
    started = time.perf_counter()
    results = await asyncio.gather(*(one() for _ in range(clients)))
    elapsed = time.perf_counter() - started
    for websocket in sleepers:
        websocket.transport.abort()
    size = sum(r[0] for r in results)
    return {"bytes": size, "frames": sum(r[1] for r in results), "seconds": elapsed,
            "mb_s": size / 1e6 / elapsed, "frames_s": sum(r[1] for r in results) / elapsed,
            "first_frame_ms": statistics.median(r[2] for r in results) * 1000}


async def first_frame_client(url: str, repeats: int) -> dict[str, Any]:
    times = []
    async with websockets.connect(url, max_size=None) as websocket:
        await websocket.recv()
        for _ in range(repeats):
            started = time.perf_counter()
            await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "f"}}))
            await websocket.recv()
            times.append((time.perf_counter() - started) * 1000)
            while not is_done(await websocket.recv()):
                pass
    return {"cold_ms": times[0], "warm_ms": statistics.median(times[1:]) if len(times) > 1 else None}


async def point_in_time_client(url: str, count: int, seed: int) -> dict[str, Any]:
    rng = random.Random(seed)
    latencies = []
    async with websockets.connect(url, max_size=None) as websocket:
        metadata = await websocket.recv()
        from xviz_server.codec import decode

        info = decode(metadata)["data"].get("log_info") or {"start_time": 0.0, "end_time": 1.0}
        start, end = info["start_time"], info["end_time"]
        for i in range(count):
            instant = rng.uniform(start, end)
            started = time.perf_counter()
            await websocket.send(json.dumps({"type": "xviz/transform_point_in_time", "data": {"id": str(i), "query_timestamp": instant}}))
            await websocket.recv()
            latencies.append((time.perf_counter() - started) * 1000)
    latencies.sort()
    return {"p50_ms": statistics.median(latencies), "p99_ms": latencies[int(len(latencies) * 0.99) - 1], "count": count}


async def ping_client(url: str, count: int) -> dict[str, Any]:
    latencies = []
    async with websockets.connect(url, max_size=None) as websocket:
        await websocket.recv()
        for _ in range(count):
            started = time.perf_counter()
            await (await websocket.ping())
            latencies.append((time.perf_counter() - started) * 1000)
    latencies.sort()
    return {"p50_ms": statistics.median(latencies), "p99_ms": latencies[int(len(latencies) * 0.99) - 1]}


def run_role(args: argparse.Namespace) -> None:
    role, *rest = args.role
    if role == "reference":
        asyncio.run(reference_server(args.kitti))
        return
    coroutine = {
        "throughput": lambda: throughput_client(rest[0], int(rest[1]), int(rest[2]), int(rest[3])),
        "first": lambda: first_frame_client(rest[0], int(rest[1])),
        "pit": lambda: point_in_time_client(rest[0], int(rest[1]), 7),
        "ping": lambda: ping_client(rest[0], int(rest[1])),
    }[role]()
    print(json.dumps(asyncio.run(coroutine)))


# ---------------------------------------------------------------- the run


def long_log(directory: Path, frames: int) -> Path:
    """A log of ``frames`` small GLB state updates at 10 Hz, in the reference layout."""
    from xviz_server.codec import Format, encode

    directory.mkdir(parents=True)
    metadata = {"version": "2.0.0", "streams": {"/vehicle_pose": {"category": "POSE"}}}
    (directory / "1-frame.glb").write_bytes(encode({"type": "xviz/metadata", "data": metadata}, Format.BINARY))
    timing = []
    for i in range(frames):
        t = round(1000 + i / 10, 3)
        pose = {"timestamp": t, "position": [float(i), 0.0, 0.0], "orientation": [0.0, 0.0, 0.0]}
        update = {"update_type": "SNAPSHOT", "updates": [{"timestamp": t, "poses": {"/vehicle_pose": pose}}]}
        (directory / f"{i + 2}-frame.glb").write_bytes(encode({"type": "xviz/state_update", "data": update}, Format.BINARY))
        timing.append([t, t, i, f"{i + 2}-frame"])
    (directory / "0-frame.json").write_text(json.dumps({"startTime": timing[0][0], "endTime": timing[-1][0], "timing": timing}))
    return directory


def section(title: str) -> None:
    print(f"\n== {title}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", type=Path, default=KITTI, help="the KITTI GLB log")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a 10 000-frame long log")
    parser.add_argument("--json", type=Path, help="also write the numbers to this file")
    parser.add_argument("--role", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role:
        run_role(args)
        return

    began = time.perf_counter()
    repeats = 2 if args.quick else 6
    long_frames = 10_000 if args.quick else 100_000
    results: dict[str, Any] = {}
    print(f"machine: {os.cpu_count()} cores, Python {platform.python_version()}, websockets {websockets.__version__}")
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch) / "logs"
        root.mkdir()
        (root / "kitti").symlink_to(args.kitti.resolve())
        server, port = start_server(root)
        reference, reference_port = start_reference(args.kitti)
        ours = f"ws://127.0.0.1:{port}/kitti"
        bare = f"ws://127.0.0.1:{reference_port}/"
        try:
            section("1. whole-log throughput, KITTI (25 frames, 2.1 MB each)")
            client("throughput", ours, "1", "1", "0")  # warm the cache
            print(f"{'clients':>7} {'server':>18} {'reference':>18} {'ratio':>6}  {'JSON-transcoded':>18}")
            for clients in (1, 20):
                count = repeats if clients == 1 else max(1, repeats // 2)
                mine = client("throughput", ours, str(clients), str(count), "0")
                theirs = client("throughput", bare, str(clients), str(count), "0")
                as_json = client("throughput", ours + "?message_format=JSON", str(clients), "1", "0")
                ratio = mine["mb_s"] / theirs["mb_s"]
                results[f"throughput_{clients}"] = {"server": mine, "reference": theirs, "ratio": ratio, "json": as_json}
                print(f"{clients:>7} {mine['mb_s']:8.0f} MB/s {mine['frames_s']:4.0f} f/s "
                      f"{theirs['mb_s']:8.0f} MB/s {theirs['frames_s']:4.0f} f/s {ratio:6.2f}  "
                      f"{as_json['mb_s']:8.0f} MB/s {as_json['frames_s']:4.0f} f/s")
        finally:
            stop(server)

        section("2. time to first frame (transform_log sent -> first state update received)")
        server, port = start_server(root)
        try:
            first = client("first", f"ws://127.0.0.1:{port}/kitti", "10")
            reference_first = client("first", bare, "10")
        finally:
            stop(server)
        results["first_frame"] = {"server": first, "reference": reference_first}
        print(f"server: cold {first['cold_ms']:.1f} ms, warm {first['warm_ms']:.2f} ms; "
              f"reference (pre-loaded): {reference_first['warm_ms']:.2f} ms")

        section("3. point-in-time latency (random instants, one client, sequential)")
        started = time.perf_counter()
        long_log(root / "long", long_frames)
        print(f"generated a {long_frames}-frame log in {time.perf_counter() - started:.1f} s")
        server, port = start_server(root)
        try:
            count = 500 if args.quick else 2000
            floor = client("ping", bare, str(count))
            one_frame = client("pit", bare, str(min(count, 500)))
            short = client("pit", f"ws://127.0.0.1:{port}/kitti", str(min(count, 500)))
            long = client("pit", f"ws://127.0.0.1:{port}/long", str(count))
        finally:
            stop(server)
        results["point_in_time"] = {"kitti": short, "long": long, "loopback_ping": floor, "reference_one_frame": one_frame}
        print(f"{'log':>22} {'p50 ms':>8} {'p99 ms':>8}")
        print(f"{'loopback ping (floor)':>22} {floor['p50_ms']:8.2f} {floor['p99_ms']:8.2f}")
        print(f"{'reference, one frame':>22} {one_frame['p50_ms']:8.2f} {one_frame['p99_ms']:8.2f}   (floor for 2.1 MB answers)")
        print(f"{'KITTI, 25 frames':>22} {short['p50_ms']:8.2f} {short['p99_ms']:8.2f}   (2.1 MB answers)")
        print(f"{f'long, {long_frames} frames':>22} {long['p50_ms']:8.2f} {long['p99_ms']:8.2f}")

        section("4. server memory with 20 clients, 5 of which stop reading")
        cache_mb, read_ahead = 256, 4
        largest = max(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / 2**20
        server, port = start_server(root, "--cache-mb", str(cache_mb), "--read-ahead", str(read_ahead))
        try:
            baseline = rss_mb(server.pid)
            peak = baseline
            done = asyncio.Event()

            async def sample() -> None:
                nonlocal peak
                while not done.is_set():
                    peak = max(peak, rss_mb(server.pid))
                    await asyncio.sleep(0.05)

            async def measure(stalled: int) -> dict[str, Any]:
                sampler = asyncio.ensure_future(sample())
                outcome = await asyncio.to_thread(client, "throughput", f"ws://127.0.0.1:{port}/kitti", "15", str(repeats), str(stalled))
                done.set()
                await sampler
                done.clear()
                return outcome

            alone = asyncio.run(measure(0))
            with_stalled = asyncio.run(measure(5))
        finally:
            stop(server)
        budget = 20 * (read_ahead * largest + largest + 0.1)
        results["memory"] = {"baseline_mb": baseline, "peak_mb": peak, "cache_mb": cache_mb, "session_budget_mb": budget,
                             "active_mb_s_alone": alone["mb_s"], "active_mb_s_with_stalled": with_stalled["mb_s"]}
        print(f"RSS after start {baseline:.0f} MB, peak {peak:.0f} MB; bound: baseline + cache {cache_mb} MB + "
              f"20 sessions x ({read_ahead} read ahead + 1 in the socket) x {largest:.1f} MB = {baseline + cache_mb + budget:.0f} MB")
        print(f"15 active clients: {alone['mb_s']:.0f} MB/s alone, {with_stalled['mb_s']:.0f} MB/s beside 5 stalled "
              f"(ratio {with_stalled['mb_s'] / alone['mb_s']:.2f})")

        section("5. permessage-deflate")
        rows = {}
        for flag in ("--no-compression", "--compression"):
            server, port = start_server(root, flag)
            try:
                glb = client("throughput", f"ws://127.0.0.1:{port}/kitti", "1", "1", "0")
                text = client("throughput", f"ws://127.0.0.1:{port}/kitti?message_format=JSON", "1", "1", "0")
            finally:
                stop(server)
            rows[flag] = (glb, text)
            print(f"{flag:>16}: GLB {glb['mb_s']:7.1f} MB/s   JSON {text['mb_s']:7.1f} MB/s   (payload MB/s, after inflating)")
        results["deflate"] = {k: {"glb": v[0], "json": v[1]} for k, v in rows.items()}
        stop(reference)

    results["seconds"] = time.perf_counter() - began
    print(f"\nran in {results['seconds']:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
