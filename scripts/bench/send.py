#!/usr/bin/env python3
"""Benchmark sending a whole log: xviz-server against raw TCP and bare websockets, in one run.

    .venv/bin/python scripts/bench/send.py [--frames 154] [--repeats 4] [--trials 5] [--clients 1 4] [--quick]

A longer log is made from the 25 real KITTI GLB frames (2.1 MB each), repeated
with shifted timestamps (``--frames``). Three servers, each its own process on
uvloop, send it whole, ``--repeats`` times per reader and measurement:

* raw TCP: ``transport.write(frame)`` per frame, no framing, flow control
  like websockets' (the reference: what the machine moves);
* bare websockets (asyncio API, no compression): ``await websocket.send(frame)``;
* xviz-server: ``xviz/transform_log`` of the whole log, from a warm cache;
* xviz-server with framing off: the same, each frame copied behind its header
  by websockets as the bare library does (``xviz_server.framing`` undone in
  that process), to show what sending payloads by reference saves.

Readers are separate processes (``--clients`` of them at once) that read with
``recv_into`` a reused buffer, parsing only the WebSocket headers, so that
the server is the bottleneck. Each trial measures every (server, readers)
pair, in turn. Reported per pair: MB/s of payload (10^6 B/s; median trial),
server CPU seconds per GB, and the medians of the per-trial ratios to raw TCP.
The machine may be shared with other work: the cores other processes used
during each measurement are shown.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from kit import KITTI, parse
from kit.proc import Process, cpu_seconds, other_cores, other_cpu, start_server
from kit.ws import Reader

MB = 1e6
HIGH_WATER = 2**15  # websockets' default write limit, for the raw server's flow control

# ================================================================ the log


def long_log(source: Path, target: Path, frames: int) -> list[Path]:
    """``frames`` state updates: the source's, repeated with their timestamps shifted; the frame files in order."""
    from xviz_server.codec import edit_glb

    originals = sorted(source.glob("*-frame.glb"), key=lambda p: int(p.name.split("-")[0]))[1:]
    index = json.loads((source / "0-frame.json").read_text())
    period = index["endTime"] - index["startTime"] + 0.1

    def shifted(value: Any, offset: float) -> Any:
        if isinstance(value, dict):
            return {
                k: (v + offset if k == "timestamp" and isinstance(v, (int, float)) else shifted(v, offset))
                for k, v in value.items()
            }
        if isinstance(value, list):
            return [shifted(v, offset) for v in value]
        return value

    target.mkdir(parents=True)
    shutil.copy(source / "1-frame.glb", target / "1-frame.glb")
    timing, paths = [], []
    for k in range(frames):
        offset = (k // len(originals)) * period
        original = originals[k % len(originals)]
        path = target / f"{k + 2}-frame.glb"
        path.write_bytes(edit_glb(original.read_bytes(), lambda envelope: shifted(envelope, offset)))
        start, end, *_ = index["timing"][k % len(originals)]
        timing.append([start + offset, end + offset, k, path.stem])
        paths.append(path)
    (target / "0-frame.json").write_text(
        json.dumps({"startTime": timing[0][0], "endTime": timing[-1][1], "timing": timing})
    )
    return paths


# ================================================================ servers


async def raw_server(frames: list[bytes]) -> None:
    """Per request line: an 8-byte length, then every frame with ``transport.write``."""
    total = sum(map(len, frames)).to_bytes(8, "big")

    class Sender(asyncio.Protocol):
        def connection_made(self, transport: Any) -> None:
            self.transport = transport
            transport.set_write_buffer_limits(HIGH_WATER)
            self.resume = asyncio.Event()
            self.resume.set()
            self.requests: asyncio.Queue[None] = asyncio.Queue()
            self.task = asyncio.ensure_future(self.serve())

        def data_received(self, data: bytes) -> None:
            for _ in range(data.count(b"\n")):
                self.requests.put_nowait(None)

        def pause_writing(self) -> None:
            self.resume.clear()

        def resume_writing(self) -> None:
            self.resume.set()

        def connection_lost(self, exc: Exception | None) -> None:
            self.task.cancel()

        async def serve(self) -> None:
            while True:
                await self.requests.get()
                self.transport.write(total)
                for frame in frames:
                    self.transport.write(frame)
                    await self.resume.wait()

    server = await asyncio.get_running_loop().create_server(Sender, "127.0.0.1", 0)
    print(f"listening on ws://127.0.0.1:{server.sockets[0].getsockname()[1]}/", file=sys.stderr, flush=True)
    await asyncio.Future()


async def websockets_server(frames: list[bytes]) -> None:
    """Per text message: every frame with ``send``, then ``done``."""
    from websockets.asyncio.server import serve

    async def handler(websocket: Any) -> None:
        async for _ in websocket:
            for frame in frames:
                await websocket.send(frame)
            await websocket.send("done")

    async with serve(handler, "127.0.0.1", 0, compression=None, max_size=None) as server:
        print(f"listening on ws://127.0.0.1:{server.sockets[0].getsockname()[1]}/", file=sys.stderr, flush=True)
        await asyncio.Future()


# ================================================================ readers


def reader_main(kind: str, port: int, repeats: int) -> None:
    """Connect, say ``ready``, wait for ``go`` on stdin, read ``repeats`` responses, print the result."""
    reader = Reader(port)
    if kind != "raw":
        reader.handshake("/kitti" if kind == "xviz-server" else "/")
    if kind == "xviz-server":
        reader.frame()  # metadata
    print("ready", flush=True)
    sys.stdin.readline()
    started, total = time.time(), 0
    for r in range(repeats):
        if kind == "raw":
            reader.sock.sendall(b"go\n")
            length = int.from_bytes(reader.take(8), "big")
            reader.skip(length)
            total += length
        else:
            reader.send_text(
                json.dumps({"type": "xviz/transform_log", "data": {"id": str(r)}}) if kind == "xviz-server" else "go"
            )
            total += reader.websocket_response()
    print(json.dumps({"start": started, "end": time.time(), "bytes": total}), flush=True)


def measure(kind: str, server: Process, clients: int, repeats: int) -> dict[str, float]:
    readers = [
        subprocess.Popen(
            [sys.executable, __file__, "--role", "reader", kind, str(server.port), str(repeats)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(clients)
    ]
    for reader in readers:
        assert reader.stdout is not None and reader.stdout.readline().strip() == "ready", f"{kind}: a reader failed"
    cpu, others, wall = cpu_seconds(server.pid), other_cpu(), time.perf_counter()
    for reader in readers:
        assert reader.stdin is not None
        reader.stdin.write("go\n")
        reader.stdin.flush()
    results = [json.loads(reader.communicate()[0]) for reader in readers]
    cpu = cpu_seconds(server.pid) - cpu
    busy = other_cores(others, wall)
    total = sum(r["bytes"] for r in results)
    seconds = max(r["end"] for r in results) - min(r["start"] for r in results)
    return {"mb_s": total / seconds / MB, "cpu_s_per_gb": cpu / (total / 1e9), "others": busy, "bytes": total}


# ================================================================ main


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--frames", type=int, default=154, help="state updates in the log (the 25 KITTI frames repeated)"
    )
    parser.add_argument("--repeats", type=int, default=4, help="times each reader reads the log per measurement")
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--kitti", type=Path, default=KITTI)
    parser.add_argument("--json", type=Path, help="write the results here")
    parser.add_argument("--role", nargs="+", help=argparse.SUPPRESS)
    args = parse(parser, quick={"frames": 26, "repeats": 1, "trials": 1, "clients": [1]})
    if args.role:
        role, *rest = args.role
        if role == "reader":
            reader_main(rest[0], int(rest[1]), int(rest[2]))
            return
        import uvloop

        if role == "unframed":
            from websockets.asyncio.server import ServerConnection

            from xviz_server import cli, framing

            # websockets' own protocol and writes: each frame serialized into one new bytes, as the bare library sends.
            framing.FramingConnection.__init__ = ServerConnection.__init__  # type: ignore[method-assign, assignment]
            framing.FramingConnection.send_data = ServerConnection.send_data  # type: ignore[method-assign]
            sys.exit(
                cli.main(["serve", "--data-dir", rest[0], "--cache-mb", rest[1], "--host", "127.0.0.1", "--port", "0"])
            )
        frames = [Path(p).read_bytes() for p in json.loads(Path(rest[0]).read_text())]
        uvloop.run(raw_server(frames) if role == "raw" else websockets_server(frames))
        return

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "logs"
        paths = long_log(args.kitti, root / "kitti", args.frames)
        listing = Path(tmp) / "frames.json"
        listing.write_text(json.dumps([str(p) for p in paths]))
        log_mb = sum(p.stat().st_size for p in paths) / MB
        print(
            f"log: {args.frames} frames, {log_mb:.0f} MB; each reader reads it {args.repeats} times per measurement; "
            f"{args.trials} trials; {os.cpu_count()} cores"
        )
        cache_mb = str(int(log_mb * 1.2 + 64))
        with (
            Process(
                [sys.executable, __file__, "--role", "raw", str(listing)], r"ws://127\.0\.0\.1:(\d+)/", "raw"
            ) as raw,
            Process(
                [sys.executable, __file__, "--role", "websockets", str(listing)],
                r"ws://127\.0\.0\.1:(\d+)/",
                "websockets",
            ) as bare,
            start_server(root, "--cache-mb", cache_mb) as ours,
            Process(
                [sys.executable, __file__, "--role", "unframed", str(root), cache_mb],
                r"listening on ws://127\.0\.0\.1:(\d+)/",
                "framing off",
            ) as unframed,
        ):
            servers = {
                "raw TCP": ("raw", raw),
                "websockets": ("websockets", bare),
                "xviz-server": ("xviz-server", ours),
                "framing off": ("xviz-server", unframed),
            }
            measure("xviz-server", ours, 1, 1)  # warm the caches
            measure("xviz-server", unframed, 1, 1)
            runs: dict[tuple[str, int], list[dict[str, float]]] = {
                (name, n): [] for name in servers for n in args.clients
            }
            for trial in range(args.trials):
                for clients in args.clients:
                    for name, (kind, process) in servers.items():
                        result = measure(kind, process, clients, args.repeats)
                        runs[name, clients].append(result)
                        print(
                            f"  trial {trial + 1} {name:>12} x{clients}: {result['mb_s']:7.0f} MB/s "
                            f"{result['cpu_s_per_gb']:.3f} CPU s/GB (others used {result['others']:.2f} cores)",
                            flush=True,
                        )
    print()
    print(f"{'server':>12} {'readers':>7} {'MB/s':>7} {'x raw':>6} {'CPU s/GB':>9} {'x raw':>6}")
    table = {}
    for (name, clients), results in runs.items():
        reference = runs["raw TCP", clients]
        row = {
            "mb_s": statistics.median(r["mb_s"] for r in results),
            "cpu_s_per_gb": statistics.median(r["cpu_s_per_gb"] for r in results),
            "speed_ratio": statistics.median(r["mb_s"] / ref["mb_s"] for r, ref in zip(results, reference)),
            # A run too short for the reference's CPU time to register (--quick) has no CPU ratio.
            "cpu_ratio": statistics.median(
                r["cpu_s_per_gb"] / ref["cpu_s_per_gb"] if ref["cpu_s_per_gb"] else math.nan
                for r, ref in zip(results, reference)
            ),
            "trials": results,
        }
        table[f"{name} x{clients}"] = row
        print(
            f"{name:>12} {clients:>7} {row['mb_s']:7.0f} {row['speed_ratio']:6.2f} {row['cpu_s_per_gb']:9.3f} {row['cpu_ratio']:6.2f}"
        )
    if args.json:
        args.json.write_text(json.dumps(table, indent=2))


if __name__ == "__main__":
    main()
