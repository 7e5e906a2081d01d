#!/usr/bin/env python3
"""Benchmark live feeds across replicas through the broker (Redis Streams).

    python scripts/bench_broker.py [--viewers 4] [--cpu-viewers 12] [--rate 10] [--seconds 10] [--runs 1]

Starts Debian's ``redis-server`` on a free loopback port (``--save "" --appendonly
no``) and ``xviz-server serve --broker`` replicas, each a process. The source
(scripts/bench_live.py's: a real KITTI frame, 2.1 MB of GLB, stamped with its
send time) pushes to replica A at ``--rate`` Hz.

1. Latency: ``--viewers`` viewers on A (served by A directly) and as many on B
   (through the broker), in the same run: p50 and p99 from the source's send
   to each viewer, B against A, and the CPU each replica used; ``--runs`` times, and the medians of B - A
   (p50) and B / A (p99) over the runs (on a shared machine one run says little).
2. Broker CPU: the CPU seconds redis-server used for the feed read by one
   replica with ``--cpu-viewers`` viewers, then by three replicas sharing
   as many viewers: each replica reads the feed once, whatever its viewers.
"""

from __future__ import annotations

import argparse
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import json
from pathlib import Path

from bench_live import FRAME
from benchkit import percentile
from benchproc import REPO, cpu_seconds, other_cores, other_cpu, start_server


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def start_redis(directory: str) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    process = subprocess.Popen(
        ["redis-server", "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no", "--dir", directory],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
            break
        except OSError:
            time.sleep(0.05)
    return process, f"redis://127.0.0.1:{port}/0"


def run(broker: str, empty: str, viewers_on: list[int], args: argparse.Namespace, name: str,
        cpu: list[float] | None = None) -> list[list[float]]:
    """Start one replica with the source and one per entry of ``viewers_on`` (its viewer count; the first is
    the source's replica); push; the latencies seen by the viewers of each replica (and, into ``cpu``, the
    CPU seconds each replica used while the source pushed)."""
    replicas = [start_server(Path(empty), "--broker", broker, "--broker-ttl", "2", "--live-queue", "8")
                for _ in viewers_on]
    try:
        time.sleep(1.5)  # the replicas find each other's feeds when the source starts
        watch = args.seconds + 4
        with tempfile.TemporaryDirectory() as scratch:
            counts = [(replica, count) for replica, count in zip(replicas, viewers_on) if count]
            outputs = [Path(scratch) / f"viewers-{i}.json" for i in range(len(counts))]
            groups = [
                subprocess.Popen([sys.executable, str(REPO / "scripts" / "bench_live.py"), "--role", "viewers",
                                  replica.url(f"?logGuid={name}"), str(count), str(watch), str(output)], cwd=REPO)
                for (replica, count), output in zip(counts, outputs)
            ]
            used = [cpu_seconds(replica.pid) for replica in replicas]
            subprocess.run([sys.executable, str(REPO / "scripts" / "bench_live.py"), "--role", "source",
                            replicas[0].url(f"ingest/{name}"), str(args.rate), str(args.seconds)], cwd=REPO, check=True)
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
    args = parser.parse_args()
    sent = int(args.rate * args.seconds)
    print(f"{FRAME.stat().st_size / 1e6:.1f} MB KITTI frames at {args.rate:g} Hz for {args.seconds:g} s ({sent} updates)")

    with tempfile.TemporaryDirectory() as empty:
        redis, url = start_redis(empty)
        try:
            # 1. the source on A; viewers on A (direct) and on B (through the broker), same run
            print(f"latency, {args.viewers} viewers on A (the source's replica) and {args.viewers} on B:")
            print(f"{'run':>4} {'':>2} {'updates':>8} {'p50 ms':>8} {'p99 ms':>8} {'CPU s':>8}")
            differences, ratios = [], []
            for number in range(1, args.runs + 1):
                before = other_cpu(), time.perf_counter()
                cpu: list[float] = []
                on_a, on_b = run(url, empty, [args.viewers, args.viewers], args, f"latency{number}", cpu)
                for name, latencies, used in (("A", on_a, cpu[0]), ("B", on_b, cpu[1])):
                    print(f"{number:>4} {name:>2} {len(latencies):>8} {statistics.median(latencies):8.1f} "
                          f"{percentile(latencies, 99):8.1f} {used:8.2f}")
                differences.append(statistics.median(on_b) - statistics.median(on_a))
                ratios.append(percentile(on_b, 99) / percentile(on_a, 99))
                print(f"{'':>4} B - A: p50 {differences[-1]:+.1f} ms; B / A: p99 x{ratios[-1]:.2f} "
                      f"(other processes used {other_cores(*before):.2f} cores meanwhile)")
            if differences:
                print(f"median of {args.runs} run(s): B - A p50 {statistics.median(differences):+.1f} ms, "
                      f"B / A p99 x{statistics.median(ratios):.2f}")

            # 2. broker CPU: the source on A (no viewers there), viewers on 1 replica, then on 3
            if args.no_cpu:
                return
            print(f"broker CPU, {args.cpu_viewers} viewers in all, on replicas other than the source's:")
            for readers in (1, 3):
                share = [args.cpu_viewers // readers + (i < args.cpu_viewers % readers) for i in range(readers)]
                cpu_before, others_before, wall = cpu_seconds(redis.pid), other_cpu(), time.perf_counter()
                latencies = run(url, empty, [0, *share], args, f"cpu{readers}")
                used = cpu_seconds(redis.pid) - cpu_before
                got = sum(len(group) for group in latencies)
                print(f"  {readers} replica(s) x {share[0]} viewers: redis-server {used:.2f} CPU s "
                      f"({used / args.seconds * 100:.0f}% of a core), {got}/{sent * args.cpu_viewers} updates delivered, "
                      f"p99 {percentile([x for group in latencies for x in group], 99):.1f} ms; "
                      f"other processes used {other_cores(others_before, wall):.2f} cores meanwhile")
        finally:
            redis.terminate()
            redis.wait()


if __name__ == "__main__":
    main()
