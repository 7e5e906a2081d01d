#!/usr/bin/env python3
"""Benchmark live feeds across replicas through the broker (Redis Streams).

    python scripts/bench/broker.py [--viewers 4] [--cpu-viewers 12] [--rate 10] [--seconds 10] [--runs 1] [--quick]

Starts Debian's ``redis-server`` on a free loopback port (``--save "" --appendonly
no``) and ``xviz-server serve --broker`` replicas, each a process. The source
(``kit.live``'s: a real KITTI frame, 2.1 MB of GLB, stamped with its
send time) pushes to replica A at ``--rate`` Hz.

1. Latency: ``--viewers`` viewers on A (served by A directly) and as many on B
   (through the broker), in the same run: p50 and p99 from the source's send
   to each viewer, B against A, and the CPU each replica used. The same source
   and viewers also go through the machine's limit for this path, a pair of
   bare relays (``relay``): A' adds each pushed message to a Redis stream
   (trimmed as the server trims it) and writes it to its own viewers; B' reads the stream with a blocking socket
   into a ring of buffers, parsing nothing but where the frame is, and writes
   each frame to its viewers. Both write the frame's header and the message to
   each viewer's transport (``kit.ws.raw_writes``): no checks, no state, no
   queues. ``--runs`` times, the two in a rotated order, and the medians over
   the runs of B - A (p50) and B / A (p99) for each (on a shared machine one
   run says little).
2. Broker CPU: the CPU seconds redis-server used for the feed read by one
   replica with ``--cpu-viewers`` viewers, then by three replicas sharing
   as many viewers: each replica reads the feed once, whatever its viewers.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from kit import KITTI_FRAME as FRAME
from kit import parse, percentile
from kit.live import ROLE
from kit.proc import BENCH, MIB, Process, address, cpu_seconds, other_cores, other_cpu, resp, start_redis, start_server
from kit.ws import forward, raw_writes

#: The latency runs' pairs of replicas: this server's, and the bare relays (the machine's limit).
PAIRS = ("server", "relay")


#: Where the frame starts in an XREAD reply of the relays' entries (one field, ``d``).
FIELD = b"\r\n$1\r\nd\r\n$"


def read_stream(broker: str, key: bytes, deliver: Callable[[memoryview], None]) -> None:
    """B' of the bare relays: ``XREAD BLOCK`` on a blocking socket, each reply read into the next buffer of a
    ring, and ``deliver`` called with the frame's bytes in it (from this thread)."""
    ring = [bytearray(2 * FRAME.stat().st_size) for _ in range(8)]  # 800 ms at 10 Hz before one is read into again
    last = b"$"
    with socket.create_connection(address(broker)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for buffer in itertools.cycle(ring):
            view = memoryview(buffer)
            sock.sendall(resp(b"XREAD", b"COUNT", b"1", b"BLOCK", b"0", b"STREAMS", key, last))
            got = sock.recv_into(view)
            while (at := buffer.find(FIELD, 0, got)) < 0 or (line := buffer.find(b"\r\n", at + len(FIELD), got)) < 0:
                got += sock.recv_into(view[got:])
            start = line + 2
            end = start + int(buffer[at + len(FIELD) : line])
            while got < end + 2:
                got += sock.recv_into(view[got : end + 2])
            # the entry id is the one part of the reply's head with a "-" that starts with a digit
            last = next(part for part in bytes(buffer[:at]).split(b"\r\n") if b"-" in part and part[:1].isdigit())
            deliver(view[start:end])


async def relay(kind: str, broker: str, name: str) -> None:
    """One of the bare relays (``owner``, A', or ``reader``, B'), serving viewers on a free loopback port.

    The owner trims the stream as the server does (``--broker-max-mb``'s default): how much Redis keeps
    changes how long it takes to pass an entry on."""
    from xviz_server.live.outbox import kept
    from xviz_server.settings import Settings

    key = f"relay:{name}".encode()
    viewers: set = set()
    if kind == "reader":
        loop = asyncio.get_running_loop()
        deliver = lambda frame: loop.call_soon_threadsafe(raw_writes, viewers, frame)  # noqa: E731
        threading.Thread(target=read_stream, args=(broker, key, deliver), daemon=True).start()
        await forward(viewers, lambda message: None)
        return
    replies, redis = await asyncio.open_connection(*address(broker))
    redis.transport.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    drained = asyncio.ensure_future(replies.read(-1))  # the replies, never looked at
    max_bytes = int(Settings.model_fields["broker_max_mb"].default * MIB)  # kept in Redis as the server keeps it

    def pushed(message: bytes) -> None:
        maxlen = b"%d" % kept(max_bytes, len(message))
        head = resp(b"XADD", key, b"MAXLEN", b"~", maxlen, b"*", b"d", more=1)
        redis.writelines((head, b"$%d\r\n" % len(message), message, b"\r\n"))
        raw_writes(viewers, message)

    try:
        await forward(viewers, pushed)
    finally:
        drained.cancel()


def replicas_of(pair: str, broker: str, empty: str, count: int, name: str) -> list[Process]:
    """``count`` replicas of ``pair`` (``server`` or ``relay``; a relay pair has 2), the first the source's."""
    if pair == "server":
        return [
            start_server(Path(empty), "--broker", broker, "--broker-ttl", "2", "--live-queue", "8")
            for _ in range(count)
        ]
    return [
        Process(
            [sys.executable, __file__, "--role", kind, broker, name], r"listening on ws://127\.0\.0\.1:(\d+)/", kind
        )
        for kind in ("owner", "reader")
    ]


def run(
    broker: str,
    empty: str,
    viewers_on: list[int],
    args: argparse.Namespace,
    name: str,
    cpu: list[float] | None = None,
    pair: str = "server",
) -> list[list[float]]:
    """Start one replica of ``pair`` with the source and one per entry of ``viewers_on`` (its viewer count; the
    first is the source's replica); push; the latencies seen by the viewers of each replica (and, into ``cpu``,
    the CPU seconds each replica used while the source pushed)."""
    replicas = replicas_of(pair, broker, empty, len(viewers_on), name)
    try:
        watch = args.seconds + 4
        with tempfile.TemporaryDirectory() as scratch:
            counts = [(replica, count) for replica, count in zip(replicas, viewers_on) if count]
            outputs = [Path(scratch) / f"viewers-{i}.json" for i in range(len(counts))]
            groups = [
                subprocess.Popen(
                    [*ROLE, "viewers", replica.url(f"?logGuid={name}"), str(count), str(watch), str(output)], cwd=BENCH
                )
                for (replica, count), output in zip(counts, outputs)
            ]
            used = [cpu_seconds(replica.pid) for replica in replicas]
            # The source pushes once every viewer follows its feed (on B: through the broker).
            subprocess.run(
                [
                    *ROLE,
                    "source",
                    replicas[0].url(f"ingest/{name}"),
                    str(args.rate),
                    str(args.seconds),
                    *map(str, outputs),
                ],
                cwd=BENCH,
                check=True,
            )
            if cpu is not None:
                cpu[:] = [cpu_seconds(replica.pid) - before for replica, before in zip(replicas, used)]
            if any(group.wait() for group in groups):
                raise RuntimeError("a viewer process failed")
            return [json.loads(output.read_text())["latencies"] for output in outputs]
    finally:
        for replica in replicas:
            replica.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--viewers", type=int, default=4, help="viewers on A and as many on B (latency)")
    parser.add_argument("--cpu-viewers", type=int, default=12, help="viewers in all (broker CPU)")
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=1, help="latency runs (0: only the broker CPU part)")
    parser.add_argument("--no-cpu", action="store_true", help="skip the broker CPU part")
    parser.add_argument("--role", nargs=3, help=argparse.SUPPRESS)
    args = parse(parser, quick={"viewers": 1, "seconds": 1.0, "no_cpu": True})
    if args.role:
        import uvloop

        uvloop.run(relay(*args.role))
        return
    sent = int(args.rate * args.seconds)
    print(
        f"{FRAME.stat().st_size / 1e6:.1f} MB KITTI frames at {args.rate:g} Hz for {args.seconds:g} s ({sent} updates)"
    )

    with tempfile.TemporaryDirectory() as empty:
        redis, url = start_redis(empty)
        try:
            # 1. the source on A; viewers on A (direct) and on B (through the broker), same run, both pairs
            print(f"latency, {args.viewers} viewers on A (the source's replica) and {args.viewers} on B:")
            print(f"{'run':>4} {'pair':>7} {'':>2} {'updates':>8} {'p50 ms':>8} {'p99 ms':>8} {'CPU s':>8}")
            differences: dict[str, list[float]] = {pair: [] for pair in PAIRS}
            ratios: dict[str, list[float]] = {pair: [] for pair in PAIRS}
            for number in range(1, args.runs + 1):
                before = other_cpu(), time.perf_counter()
                for pair in PAIRS[number % 2 :] + PAIRS[: number % 2]:
                    cpu: list[float] = []
                    on_a, on_b = run(
                        url, empty, [args.viewers, args.viewers], args, f"latency{number}{pair}", cpu, pair
                    )
                    for name, latencies, used in (("A", on_a, cpu[0]), ("B", on_b, cpu[1])):
                        if not latencies:
                            raise SystemExit(
                                f"the viewers on {name} ({pair}) received no update: see the replicas' log lines"
                            )
                        print(
                            f"{number:>4} {pair:>7} {name:>2} {len(latencies):>8} {statistics.median(latencies):8.1f} "
                            f"{percentile(latencies, 99):8.1f} {used:8.2f}"
                        )
                    differences[pair].append(statistics.median(on_b) - statistics.median(on_a))
                    ratios[pair].append(percentile(on_b, 99) / percentile(on_a, 99))
                print(
                    f"{'':>4} B - A: p50 "
                    + ", ".join(f"{differences[pair][-1]:+.1f} ms {pair}" for pair in PAIRS)
                    + "; B / A: p99 "
                    + ", ".join(f"x{ratios[pair][-1]:.2f} {pair}" for pair in PAIRS)
                    + f" (other processes used {other_cores(*before):.2f} cores meanwhile)"
                )
            if args.runs:
                print(
                    f"median of {args.runs} run(s): B - A p50 "
                    + ", ".join(f"{statistics.median(differences[pair]):+.1f} ms {pair}" for pair in PAIRS)
                    + "; B / A p99 "
                    + ", ".join(f"x{statistics.median(ratios[pair]):.2f} {pair}" for pair in PAIRS)
                )

            # 2. broker CPU: the source on A (no viewers there), viewers on 1 replica, then on 3
            if args.no_cpu:
                return
            print(f"broker CPU, {args.cpu_viewers} viewers in all, on replicas other than the source's:")
            for readers in (1, 3):
                share = [args.cpu_viewers // readers + (i < args.cpu_viewers % readers) for i in range(readers)]
                cpu_before, others_before, wall = cpu_seconds(redis.pid), other_cpu(), time.perf_counter()
                groups = run(url, empty, [0, *share], args, f"cpu{readers}")
                used = cpu_seconds(redis.pid) - cpu_before
                got = sum(len(group) for group in groups)
                print(
                    f"  {readers} replica(s) x {share[0]} viewers: redis-server {used:.2f} CPU s "
                    f"({used / args.seconds * 100:.0f}% of a core), {got}/{sent * args.cpu_viewers} updates delivered, "
                    f"p99 {percentile([x for group in groups for x in group], 99):.1f} ms; "
                    f"other processes used {other_cores(others_before, wall):.2f} cores meanwhile"
                )
        finally:
            redis.terminate()
            redis.wait()


if __name__ == "__main__":
    main()
