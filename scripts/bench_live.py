#!/usr/bin/env python3
"""Benchmark live fan-out: latency from source to viewers, and throughput.

    python scripts/bench_live.py [--viewers 50] [--rate 10] [--seconds 20] [--processes 2] [--runs 1] [--most]

The server (``xviz-server serve``), the source and the viewers are separate
processes. The source pushes a real KITTI frame (2.1 MB of GLB: 121k points,
four images) to ``/ingest/bench`` at ``--rate`` Hz, its send time patched into
the encoded frame just before it goes; ``--viewers`` viewers, spread over
``--processes`` processes, take the feed by the live loader's URL and note
when each update's last byte arrives. They are minimal WebSocket clients
that read each frame's JSON chunk and only count the rest of its bytes, so
that the viewers' own decoding is not what is measured. Reported: latency
p50/p99/max over every update every viewer got, updates lost, and the bytes
fanned out per second. The same source and viewers run against two
references, websockets servers on uvloop that forward each pushed message to
every viewer (no decoding, no queues, no checks): ``broadcast``, with
``websockets.broadcast`` (the bare library), and ``writes``, writing the
frame's header and the message itself to each viewer's transport (raw TCP
with WebSocket framing: the machine's limit for a Python server). Each of
``--runs`` runs the three in a rotated order; this server's p99 is reported
as a ratio to each reference's in the same run, and raw writes' p99 as a
ratio to the broadcast's (how far below the bare library the machine lets
any server go). With ``--most``, the
viewers go up by 10 until no server delivers every update with p99 under
100 ms, and the most each held is reported.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

import websockets
from websockets.frames import Frame, Opcode

from benchkit import percentile
from xviz_server.framing import frame_header

REPO = Path(__file__).resolve().parents[1]
FRAME = REPO.parent / "shared" / "data" / "kitti-2011_09_26_drive_0001-head" / "2-frame.glb"
METADATA = FRAME.with_name("1-frame.glb")


#: The send time travels in the frame as this many characters, patched into the encoded bytes.
STAMP = 16


async def source(url: str, rate: float, seconds: float) -> None:
    from xviz_server.codec import decode_glb, encode_glb

    message = decode_glb(FRAME.read_bytes())
    sentinel = b"8" * 9 + b"." + b"8" * 6  # 15 digits: written back as read
    message["data"]["updates"][0]["timestamp"] = float(sentinel)
    frame = bytearray(encode_glb(message))  # encoded once: the source's encoding is no part of the latency
    at = frame.index(sentinel)
    async with websockets.connect(url, max_size=None, compression=None) as websocket:
        await websocket.send(METADATA.read_bytes())
        await asyncio.sleep(1.0)  # let the viewers subscribe
        start = time.perf_counter()
        for k in range(int(rate * seconds)):
            await asyncio.sleep(max(0.0, start + k / rate - time.perf_counter()))
            # perf_counter is the system's monotonic clock, the same in every process; padded with spaces (valid JSON)
            frame[at:at + STAMP] = f"{time.perf_counter():>{STAMP}.6f}".encode()
            await websocket.send(bytes(frame))


async def viewers(url: str, count: int, seconds: float) -> dict:
    """``count`` minimal WebSocket clients (benchpeers.RawClient) that read each frame's JSON chunk and count the rest.

    A frame's arrival is when its last byte is read; the viewers do no more
    work per frame than that, so that they measure the server, not their own
    decoding.
    """
    from benchpeers import RawClient, envelope_of

    latencies: list[float] = []
    received = [0] * count
    size = [0]

    async def view(i: int) -> None:
        viewer = await RawClient.open(url, keep=65536)
        deadline = time.perf_counter() + seconds
        try:
            while time.perf_counter() < deadline:
                try:
                    length, head, arrived = await asyncio.wait_for(viewer.recv(), max(0.1, deadline - time.perf_counter()))
                except asyncio.TimeoutError:
                    break
                if length > 100_000:
                    sent = envelope_of(head)["data"]["updates"][0]["timestamp"]
                    latencies.append((arrived - sent) * 1000)
                    received[i] += 1
                    size[0] += length
        finally:
            viewer.abort()

    await asyncio.gather(*(view(i) for i in range(count)))
    return {"latencies": latencies, "received": received, "bytes": size[0]}


def raw_writes(viewers: set, message: bytes | memoryview) -> None:
    """Write a binary frame of ``message`` to each viewer: its header, then the message itself."""
    head = frame_header(Frame(Opcode.BINARY, message))
    for viewer in viewers:
        viewer.transport.writelines((head, message))


async def forward(viewers: set, pushed: Callable[[bytes], None]) -> None:
    """Serve WebSocket on a free loopback port: each message pushed to ``/ingest/...`` goes to ``pushed``,
    every other connection is in ``viewers`` while it is open."""

    async def handler(websocket) -> None:
        if websocket.request.path.startswith("/ingest/"):
            async for message in websocket:
                pushed(message)
            return
        viewers.add(websocket)
        try:
            await websocket.wait_closed()
        finally:
            viewers.discard(websocket)

    async with websockets.serve(handler, "127.0.0.1", 0, max_size=None, compression=None) as server:
        print(f"listening on ws://127.0.0.1:{server.sockets[0].getsockname()[1]}/", file=sys.stderr, flush=True)
        await asyncio.Future()


async def reference_server(kind: str) -> None:
    """Forward every message from ``/ingest/...`` to every other connection.

    ``broadcast``: with ``websockets.broadcast``, the bare library. ``writes``:
    :func:`raw_writes` (what raw TCP with WebSocket framing costs: the machine's
    limit for a Python server); websockets only does the handshakes.
    """
    viewers: set = set()
    if kind == "broadcast":
        await forward(viewers, lambda message: websockets.broadcast(viewers, message))
    else:
        await forward(viewers, lambda message: raw_writes(viewers, message))


def run(command: list[str], args: argparse.Namespace) -> dict:
    """Start a server with ``command``, run the source and viewers against it, stop it."""
    server = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=REPO)
    assert server.stderr is not None
    port = next(int(m.group(1)) for line in server.stderr if (m := re.search(r"ws://127\.0\.0\.1:(\d+)/", line)))
    threading.Thread(target=server.stderr.read, daemon=True).start()  # drained: a full pipe would stall the server
    try:
        watch = args.seconds + 3
        share = [args.viewers // args.processes + (i < args.viewers % args.processes) for i in range(args.processes)]
        with tempfile.TemporaryDirectory() as scratch:
            outputs = [Path(scratch) / f"viewers-{i}.json" for i in range(len(share))]
            viewer_processes = [
                subprocess.Popen([sys.executable, __file__, "--role", "viewers", f"ws://127.0.0.1:{port}/?logGuid=bench",
                                  str(n), str(watch), str(output)], cwd=REPO)
                for n, output in zip(share, outputs)
            ]
            time.sleep(0.5)
            subprocess.run([sys.executable, __file__, "--role", "source", f"ws://127.0.0.1:{port}/ingest/bench",
                            str(args.rate), str(args.seconds)], cwd=REPO, check=True)
            for process in viewer_processes:
                if process.wait() != 0:
                    raise RuntimeError(f"a viewer process failed (exit {process.returncode})")
            results = [json.loads(output.read_text()) for output in outputs]
    finally:
        server.terminate()
        server.wait(10)
    latencies = sorted(x for r in results for x in r["latencies"])
    return {
        "received": [n for r in results for n in r["received"]],
        "p50": statistics.median(latencies),
        "p99": percentile(latencies, 99),
        "max": latencies[-1],
        "mb_s": sum(r["bytes"] for r in results) / args.seconds / 1e6,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--viewers", type=int, default=50)
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--processes", type=int, default=2, help="viewer processes")
    parser.add_argument("--runs", type=int, default=1, help="runs of the three servers, in rotated order")
    parser.add_argument("--most", action="store_true",
                        help="find the most viewers (in steps of 10) each server holds at --rate with p99 under 100 ms")
    parser.add_argument("--role", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role:
        role, url, *rest = args.role
        import uvloop

        if role in ("broadcast", "writes"):
            uvloop.run(reference_server(role))
        elif role == "source":
            asyncio.run(source(url, float(rest[0]), float(rest[1])))
        else:
            Path(rest[2]).write_text(json.dumps(uvloop.run(viewers(url, int(rest[0]), float(rest[1])))))
        return

    if args.most:
        most(args)
        return
    sent = int(args.rate * args.seconds)
    frame_mb = FRAME.stat().st_size / 1e6
    print(f"live fan-out: {args.viewers} viewers in {args.processes} processes, "
          f"{frame_mb:.1f} MB frames at {args.rate:g} Hz for {args.seconds:g} s ({sent} updates), {args.runs} run(s)")
    ratios: dict[str, list[float]] = {name: [] for name in SERVERS[1:]}
    limit: list[float] = []  # the machine's limit against the bare library: how far below the broadcast any server can go
    for number in range(args.runs):
        results = run_all(args, number)
        print(f"run {number + 1}: {'':>10} {'got (min-max)':>14} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'MB/s out':>9}")
        for name, result in results.items():
            print(f"{'':>6} {name:>10} {min(result['received']):>6}-{max(result['received']):<7} "
                  f"{result['p50']:8.1f} {result['p99']:8.1f} {result['max']:8.1f} {result['mb_s']:9.0f}")
        for name in ratios:
            ratios[name].append(results["server"]["p99"] / results[name]["p99"])
        limit.append(results["writes"]["p99"] / results["broadcast"]["p99"])
        print("       server p99 x" + ", x".join(f"{ratios[name][-1]:.2f} {name}" for name in ratios)
              + f"; raw writes p99 x{limit[-1]:.2f} broadcast")
    print("median over runs: server p99 x" + ", x".join(
        f"{statistics.median(values):.2f} {name}" for name, values in ratios.items())
        + f"; raw writes p99 x{statistics.median(limit):.2f} broadcast (lowest x{min(limit):.2f})")


#: The servers compared: this one, then the references (the ``--role`` of each).
SERVERS = ("server", "broadcast", "writes")


def run_all(args: argparse.Namespace, number: int = 0) -> dict[str, dict]:
    """This server, the bare broadcast and raw writes with the same source and viewers, in an order rotated by ``number``."""
    results: dict[str, dict] = {}
    turn = number % len(SERVERS)
    for name in SERVERS[turn:] + SERVERS[:turn]:
        if name == "server":
            with tempfile.TemporaryDirectory() as empty:
                results[name] = run([sys.executable, "-m", "xviz_server", "serve", "--data-dir", empty, "--port", "0",
                                     "--live-queue", "8"], args)
        else:
            results[name] = run([sys.executable, __file__, "--role", name, "-"], args)
    return {name: results[name] for name in SERVERS}


def most(args: argparse.Namespace) -> None:
    """Raise the viewers by 10 until no server holds the rate with p99 under 100 ms; the most each held."""
    sent = int(args.rate * args.seconds)
    held = dict.fromkeys(SERVERS, 0)
    args.viewers = 10
    while True:
        kept = False
        for name, result in run_all(args).items():
            ok = min(result["received"]) == sent and result["p99"] < 100
            print(f"{args.viewers:4} viewers {name:>10}: p99 {result['p99']:7.1f} ms, "
                  f"got {min(result['received'])}-{max(result['received'])} of {sent}{'' if ok else '  (not held)'}")
            if ok and held[name] == args.viewers - 10:
                held[name], kept = args.viewers, True
        if not kept:
            break
        args.viewers += 10
    print(f"most viewers held at {args.rate:g} Hz with p99 under 100 ms: "
          + ", ".join(f"{name} {count}" for name, count in held.items()))


if __name__ == "__main__":
    main()
