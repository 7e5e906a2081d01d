#!/usr/bin/env python3
"""Benchmark the broker hop: a 2.1 MB frame from XADD in one process to the whole XREAD reply in another.

    python scripts/bench/wire.py [--frames 50] [--rate 10] [--rounds 3] [--quick]

Starts Debian's ``redis-server`` on a free loopback port. A writer process
adds a real KITTI frame (2.1 MB of GLB) to a stream at ``--rate`` Hz with
``live/redis_wire.py``, its send time in a field before the frame; a reader in
another process waits in ``XREAD BLOCK`` and notes when each reply is whole.
Three readers take turns, ``--rounds`` times:

* ``wire``: this server's reader (``live/redis_wire.py``: the socket reads into
  its buffer, the frame copied out once);
* ``redis-py``: the bare library, ``redis.asyncio`` with hiredis;
* ``raw socket``: the machine's limit, a blocking socket that reads the
  reply with ``recv_into`` into one buffer and parses nothing.

Reported per reader: p50 and p90, over every frame of every round, of the
time from the writer's XADD to the whole reply, and of the time from the
reply's first byte to its last (``wire`` and ``raw socket`` only).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import struct
import subprocess
import sys
import tempfile
import time
from typing import Any

from kit import KITTI_FRAME as FRAME
from kit import parse, percentile
from kit.proc import address, resp, start_redis

STREAM = b"bench"
READERS = ("wire", "redis-py", "raw socket")


async def write(url: str, frames: int, rate: float) -> None:
    from xviz_server.live.redis_wire import Wire

    frame = FRAME.read_bytes()
    wire = await Wire.open(url, "bench-writer", 5)
    start = time.perf_counter()
    for k in range(frames):
        await asyncio.sleep(max(0.0, start + k / rate - time.perf_counter()))
        await wire.send(
            b"XADD", STREAM, b"MAXLEN", b"~", b"10", b"*", b"t", struct.pack("d", time.perf_counter()), b"d", frame
        )
    wire.close()


def stamp(fields: list[bytes]) -> float:
    """The send time in an entry's fields ``[b"t", time, b"d", frame]``."""
    return float(struct.unpack("d", fields[1])[0])


async def read_wire(url: str, frames: int) -> tuple[list[float], list[float]]:
    from xviz_server.live.redis_wire import Wire

    class Timed(Wire):
        first = 0.0

        def buffer_updated(self, nbytes: int) -> None:
            self.first = self.first or time.perf_counter()
            super().buffer_updated(nbytes)

    wire = await Timed.open(url, "bench-reader", 5)
    assert isinstance(wire, Timed)
    whole, spread, last = [], [], b"$"
    for _ in range(frames):
        wire.first = 0.0
        answer = await wire.send(b"XREAD", b"COUNT", b"1", b"BLOCK", b"5000", b"STREAMS", STREAM, last)
        done = time.perf_counter()
        last, fields = answer[0][1][0]
        whole.append(done - stamp(fields))
        spread.append(done - wire.first)
    wire.close()
    return whole, spread


async def read_redis_py(url: str, frames: int) -> tuple[list[float], list[float]]:
    from redis.asyncio import Redis

    client = Redis.from_url(url, protocol=2)
    whole, last = [], "$"
    for _ in range(frames):
        answer: Any = await client.xread({STREAM: last}, count=1, block=5000)
        done = time.perf_counter()
        last, fields = answer[0][1][0]
        whole.append(done - struct.unpack("d", fields[b"t"])[0])
    await client.aclose()
    return whole, []


def read_raw(url: str, frames: int) -> tuple[list[float], list[float]]:
    size = len(FRAME.read_bytes())
    header = b"$%d\r\n" % size  # the frame's bulk string; the reply ends 2 bytes after it
    buffer = bytearray(size + 4096)
    view = memoryview(buffer)
    whole, spread, last = [], [], b"$"
    with socket.create_connection(address(url)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(frames):
            sock.sendall(resp(b"XREAD", b"COUNT", b"1", b"BLOCK", b"5000", b"STREAMS", STREAM, last))
            got = sock.recv_into(view)
            first = time.perf_counter()
            while (at := buffer.find(header, 0, got)) < 0:
                got += sock.recv_into(view[got:])
            end = at + len(header) + size + 2
            while got < end:
                got += sock.recv_into(view[got:end])
            done = time.perf_counter()
            # the entry id is the first bulk string of length > 1 in the reply head: "$<n>\r\n<ms>-<seq>\r\n"
            head = bytes(buffer[:at])
            last = next(part for part in head.split(b"\r\n") if b"-" in part and part[:1].isdigit())
            stamped = head.index(b"\r\nt\r\n$8\r\n") + len(b"\r\nt\r\n$8\r\n")
            sent = struct.unpack("d", head[stamped : stamped + 8])[0]
            whole.append(done - sent)
            spread.append(done - first)
    return whole, spread


def role(args: argparse.Namespace) -> None:
    if args.role == "writer":
        asyncio.run(write(args.url, args.frames, args.rate))
        return
    if args.role == "raw socket":
        result = read_raw(args.url, args.frames)
    else:
        result = asyncio.run((read_wire if args.role == "wire" else read_redis_py)(args.url, args.frames))
    print(json.dumps(result))


def hop(url: str, reader: str, args: argparse.Namespace) -> tuple[list[float], list[float]]:
    """One round: ``reader`` in a process waiting, then the writer; the reader's times."""
    command = [sys.executable, __file__, "--url", url, "--frames", str(args.frames), "--rate", str(args.rate), "--role"]
    reading = subprocess.Popen([*command, reader], stdout=subprocess.PIPE)
    time.sleep(1.0)  # the reader is waiting in XREAD
    subprocess.run([*command, "writer"], check=True)
    out, _ = reading.communicate(timeout=60)
    whole, spread = json.loads(out)
    return whole, spread


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--role", choices=["writer", *READERS], help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    args = parse(parser, quick={"frames": 5, "rounds": 1})
    if args.role:
        role(args)
        return
    times: dict[str, tuple[list[float], list[float]]] = {reader: ([], []) for reader in READERS}
    with tempfile.TemporaryDirectory() as scratch:
        redis, url = start_redis(scratch)
        try:
            for _ in range(args.rounds):
                for reader in READERS:
                    whole, spread = hop(url, reader, args)
                    times[reader][0].extend(whole)
                    times[reader][1].extend(spread)
        finally:
            redis.terminate()
            redis.wait()
    print(
        f"{len(FRAME.read_bytes())} B frames at {args.rate:g} Hz, {args.frames} frames x {args.rounds} rounds, readers interleaved"
    )
    print(f"{'reader':<12} {'XADD to whole reply p50 / p90 ms':>34} {'first byte to last p50 / p90 ms':>34}")
    for reader, (whole, spread) in times.items():
        ms = [1000 * t for t in whole]
        line = f"{reader:<12} {percentile(ms, 50):>19.2f} / {percentile(ms, 90):<12.2f}"
        if spread:
            ms = [1000 * t for t in spread]
            line += f" {percentile(ms, 50):>19.2f} / {percentile(ms, 90):.2f}"
        print(line)


if __name__ == "__main__":
    main()
