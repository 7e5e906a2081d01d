#!/usr/bin/env python3
"""Benchmark live fan-out: latency from source to viewers, and throughput.

    python scripts/bench/live.py [--viewers 50] [--rate 10] [--seconds 20] [--processes 2] [--runs 1] [--most] [--quick]

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
import json
import re
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from kit import KITTI_FRAME as FRAME
from kit import REPO, parse, percentile
from kit.live import ROLE
from kit.proc import BENCH


def run(command: list[str], args: argparse.Namespace) -> dict:
    """Start a server with ``command``, run the source and viewers against it, stop it."""
    server = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=BENCH if command[:3] == ROLE else REPO)
    assert server.stderr is not None
    port = next(int(m.group(1)) for line in server.stderr if (m := re.search(r"ws://127\.0\.0\.1:(\d+)/", line)))
    threading.Thread(target=server.stderr.read, daemon=True).start()  # drained: a full pipe would stall the server
    try:
        watch = args.seconds + 3
        share = [args.viewers // args.processes + (i < args.viewers % args.processes) for i in range(args.processes)]
        with tempfile.TemporaryDirectory() as scratch:
            outputs = [Path(scratch) / f"viewers-{i}.json" for i in range(len(share))]
            viewer_processes = [
                subprocess.Popen(
                    [*ROLE, "viewers", f"ws://127.0.0.1:{port}/?logGuid=bench", str(n), str(watch), str(output)],
                    cwd=BENCH,
                )
                for n, output in zip(share, outputs)
            ]
            subprocess.run(
                [
                    *ROLE,
                    "source",
                    f"ws://127.0.0.1:{port}/ingest/bench",
                    str(args.rate),
                    str(args.seconds),
                    *map(str, outputs),
                ],
                cwd=BENCH,
                check=True,
            )
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
    parser.add_argument(
        "--most",
        action="store_true",
        help="find the most viewers (in steps of 10) each server holds at --rate with p99 under 100 ms",
    )
    args = parse(parser, quick={"viewers": 4, "seconds": 1.0, "processes": 1})

    if args.most:
        most(args)
        return
    sent = int(args.rate * args.seconds)
    frame_mb = FRAME.stat().st_size / 1e6
    print(
        f"live fan-out: {args.viewers} viewers in {args.processes} processes, "
        f"{frame_mb:.1f} MB frames at {args.rate:g} Hz for {args.seconds:g} s ({sent} updates), {args.runs} run(s)"
    )
    ratios: dict[str, list[float]] = {name: [] for name in SERVERS[1:]}
    limit: list[
        float
    ] = []  # the machine's limit against the bare library: how far below the broadcast any server can go
    for number in range(args.runs):
        results = run_all(args, number)
        print(
            f"run {number + 1}: {'':>10} {'got (min-max)':>14} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'MB/s out':>9}"
        )
        for name, result in results.items():
            print(
                f"{'':>6} {name:>10} {min(result['received']):>6}-{max(result['received']):<7} "
                f"{result['p50']:8.1f} {result['p99']:8.1f} {result['max']:8.1f} {result['mb_s']:9.0f}"
            )
        for name in ratios:
            ratios[name].append(results["server"]["p99"] / results[name]["p99"])
        limit.append(results["writes"]["p99"] / results["broadcast"]["p99"])
        print(
            "       server p99 x"
            + ", x".join(f"{ratios[name][-1]:.2f} {name}" for name in ratios)
            + f"; raw writes p99 x{limit[-1]:.2f} broadcast"
        )
    print(
        "median over runs: server p99 x"
        + ", x".join(f"{statistics.median(values):.2f} {name}" for name, values in ratios.items())
        + f"; raw writes p99 x{statistics.median(limit):.2f} broadcast (lowest x{min(limit):.2f})"
    )


#: The servers compared: this one, then the references (the ``--role`` of each).
SERVERS = ("server", "broadcast", "writes")


def run_all(args: argparse.Namespace, number: int = 0) -> dict[str, dict]:
    """This server, the bare broadcast and raw writes with the same source and viewers, in an order rotated by ``number``."""
    results: dict[str, dict] = {}
    turn = number % len(SERVERS)
    for name in SERVERS[turn:] + SERVERS[:turn]:
        if name == "server":
            with tempfile.TemporaryDirectory() as empty:
                results[name] = run(
                    [
                        sys.executable,
                        "-m",
                        "xviz_server",
                        "serve",
                        "--data-dir",
                        empty,
                        "--port",
                        "0",
                        "--live-queue",
                        "8",
                    ],
                    args,
                )
        else:
            results[name] = run([*ROLE, name, "-"], args)
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
            print(
                f"{args.viewers:4} viewers {name:>10}: p99 {result['p99']:7.1f} ms, "
                f"got {min(result['received'])}-{max(result['received'])} of {sent}{'' if ok else '  (not held)'}"
            )
            if ok and held[name] == args.viewers - 10:
                held[name], kept = args.viewers, True
        if not kept:
            break
        args.viewers += 10
    print(
        f"most viewers held at {args.rate:g} Hz with p99 under 100 ms: "
        + ", ".join(f"{name} {count}" for name, count in held.items())
    )


if __name__ == "__main__":
    main()
