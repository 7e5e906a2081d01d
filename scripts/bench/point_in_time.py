"""Point-in-time latency on a long JSON log of small frames, against a short one in the same run.

    .venv/bin/python scripts/bench/point_in_time.py [--frames 20000] [--rounds 2000] [--seed 17] [--quick]

1. A server (``xviz-server serve``, its own process) serves two generated JSON
   logs of the same small frames (a pose, a 10-point cloud, a time series):
   one of ``--frames`` frames and one of 11. One websockets client holds a
   session on each and, ``--rounds`` times, asks each in turn for the state
   at a random instant (``transform_point_in_time``), awaiting each answer.
   This runs twice: at once after the sessions start, while the server
   reads the long log into its frame cache (``--preload-mb``), where
   nearly every answer on the long log is a first read of its frame, some
   from the disk; and again once the server says it has read the log. The
   short log's answers are cached after the first few. The goal: p99 on
   the long log at most 5 ms and at most twice the short log's p50.
2. Where JSON work should run: the time a frame check holds the GIL against
   the round trip of the same job through a thread and through a worker
   process, by frame size (what ``frames.INLINE_BYTES`` and
   ``frames.HEAVY_JSON_BYTES`` are set from).

Percentiles are by nearest rank (``kit.percentile``), over the measured round trips.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from kit import parse, percentile, update, write_log
from kit.proc import Process, start_server
from websockets.asyncio.client import ClientConnection, connect

from xviz_server import frames
from xviz_server.codec import Format, encode
from xviz_server.work import Workers


async def ask(websocket: ClientConnection, request_id: str, instant: float) -> float:
    """Seconds from sending a point-in-time request to receiving its answer."""
    started = time.perf_counter()
    await websocket.send(
        json.dumps({"type": "xviz/transform_point_in_time", "data": {"id": request_id, "query_timestamp": instant}})
    )
    answer = json.loads(await websocket.recv())
    elapsed = time.perf_counter() - started
    if answer["type"] != "xviz/state_update":
        raise RuntimeError(f"expected a state update, got {answer}")
    return elapsed


async def latencies(
    server: Process, logs: dict[str, tuple[float, float]], rounds: int, seed: int
) -> tuple[list[dict[str, np.ndarray]], str]:
    """Per phase (before and after the server has read the long log into memory), ms by log; and what the server said of the read-in."""
    rng = np.random.default_rng(seed)
    sessions = {}
    for name in logs:
        sessions[name] = await connect(server.url(name), max_size=None)
        await sessions[name].recv()  # metadata
    phases, said = [], ""
    try:
        for phase in range(2):
            if phase == 1:
                said = await preloaded(server, "long")
            measured: dict[str, list[float]] = {name: [] for name in logs}
            for round_number in range(rounds):
                for name, (start, end) in logs.items():
                    instant = float(rng.uniform(start, end))
                    measured[name].append(await ask(sessions[name], f"{name}-{phase}-{round_number}", instant))
            phases.append({name: np.array(values) * 1e3 for name, values in measured.items()})
    finally:
        for websocket in sessions.values():
            await websocket.close()
    return phases, said


async def preloaded(server: Process, name: str, timeout: float = 120) -> str:
    """Wait until the server logs that it has read log ``name`` into its frame cache; that log line."""
    deadline = time.monotonic() + timeout
    while True:
        said = [line for line in list(server.tail) if f"read log {name!r} into the frame cache" in line]
        if said:
            return said[0].strip().split(": ", 1)[-1]
        if time.monotonic() > deadline:
            raise RuntimeError(
                f"the server did not read log {name!r} into its cache in {timeout} s:\n{''.join(server.tail)}"
            )
        await asyncio.sleep(0.05)


async def job_costs(points: list[int]) -> list[tuple[float, ...]]:
    """For frames of each cloud size: bytes, and median ms the check holds the GIL, of its thread round trip, of its worker-process round trip."""
    workers = Workers(processes=1)
    await workers.warm()
    rows = []
    try:
        for count in points:
            data = encode({"type": "xviz/state_update", "data": update(100.0, points=count)}, Format.JSON)
            repeats = max(20, min(300, 3_000_000 // len(data)))
            held, thread, hop = [], [], []
            for _ in range(repeats):
                started = time.perf_counter()
                frames.check(data)
                held.append(time.perf_counter() - started)
                started = time.perf_counter()
                await workers.io(frames.check, data)
                thread.append(time.perf_counter() - started)
                started = time.perf_counter()
                await workers.cpu(frames.check, data)
                hop.append(time.perf_counter() - started)
            rows.append((len(data), *(float(np.median(values)) * 1e3 for values in (held, thread, hop))))
    finally:
        workers.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=2_000)
    parser.add_argument("--seed", type=int, default=17)
    args = parse(parser, quick={"frames": 200, "rounds": 50})

    with tempfile.TemporaryDirectory() as directory:
        root = Path(directory)
        started = time.perf_counter()
        counts = {"long": args.frames, "short": 11}
        spans = {}
        for name, count in counts.items():
            write_log(root / name, count, fmt=Format.JSON)
            spans[name] = (100.0, round(100.0 + (count - 1) / 10, 3) + 0.1)
        frame_bytes = (root / "long" / "2-frame.json").stat().st_size
        print(
            f"generated {args.frames} + 11 JSON frames of {frame_bytes} bytes in {time.perf_counter() - started:.1f} s"
        )
        with start_server(root) as server:
            phases, said = asyncio.run(latencies(server, spans, args.rounds, args.seed))
            print("server:", said)

    print(f"\n1. transform_point_in_time, {args.rounds} random instants a log, answers awaited one by one (ms)")
    print(f"{'log':<40}{'p50':>8}{'p90':>8}{'p99':>8}{'max':>8}")
    for phase, measured in zip(("while reading the long log in", "after"), phases):
        for name, label in (("long", f"{args.frames} frames"), ("short", "11 frames")):
            values = measured[name]
            print(
                f"{phase + ', ' + label:<40}"
                + "".join(f"{percentile(values, q):8.2f}" for q in (50, 90, 99))
                + f"{values.max():8.2f}"
            )
        p99_long = percentile(measured["long"], 99)
        p50_short = percentile(measured["short"], 50)
        print(
            f"  p99 of the long log / p50 of the short log: {p99_long / p50_short:.2f} (goal <= 2); p99 {p99_long:.2f} ms (goal <= 5)"
        )

    print(
        f"\n2. frames.check on a JSON frame: GIL held in this process vs a thread and a worker-process round trip"
        f" (median ms); INLINE_BYTES = {frames.INLINE_BYTES}, HEAVY_JSON_BYTES = {frames.HEAVY_JSON_BYTES}"
    )
    print(f"{'frame bytes':>12}{'GIL held':>10}{'thread':>10}{'process':>10}")
    rows = asyncio.run(job_costs([1, 10, 30, 60, 100, 300, 1000, 3000, 8000]))
    for size, held, thread, hop in rows:
        print(f"{size:12d}{held:10.3f}{thread:10.3f}{hop:10.3f}")
    for label, column in (("a thread", 2), ("a process", 3)):
        crossing = next((row[0] for row in rows if row[1] > row[column]), None)
        print(f"smallest frame whose check holds the GIL longer than the round trip to {label}: {crossing} bytes")


if __name__ == "__main__":
    main()
