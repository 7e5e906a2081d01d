"""Many sessions, each opening a different ROS bag at once: the server's memory and /healthz while they play.

Generates one ROS 1 bag (:func:`kit.gen.generate_bag`: 120 000-point clouds and a camera image a frame), serves
``--sessions`` copies of it under different names from a server run as its own process, and opens one session on
each at the same moment, each playing its whole log. Reports the growth of the peak RSS (``VmHWM``) of the server
process and of each worker process over their RSS once warm, and the time of ``GET /healthz`` during the storm as a
ratio against the same request on the idle server (the reference, in the same run).

    .venv/bin/python scripts/bench/bomb_sessions.py            # 30 sessions
    .venv/bin/python scripts/bench/bomb_sessions.py --quick    # 4 sessions on bags of 2 frames
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import statistics
import tempfile
import time
import urllib.request
from pathlib import Path

import websockets
from kit import parse
from kit.gen import generate_bag
from kit.proc import Process, descendants, start_server

from xviz_server.codec import decode

_MiB = 1 << 20


def status_bytes(pid: int, field: str) -> int:
    """A ``/proc/PID/status`` field in bytes (``VmRSS``, ``VmHWM``: the peak RSS); 0 for a process gone."""
    try:
        match = re.search(rf"^{field}:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text(), re.MULTILINE)
    except OSError:
        return 0
    return int(match.group(1)) * 1024 if match else 0


async def healthz_times(server: Process, count: int) -> list[float]:
    def get() -> float:
        started = time.perf_counter()
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/healthz", timeout=60) as response:
            assert response.status == 200
        return time.perf_counter() - started

    times = []
    for _ in range(count):
        times.append(await asyncio.to_thread(get))
        await asyncio.sleep(0.05)
    return times


async def play(server: Process, log: str) -> tuple[int, int]:
    """Open ``log`` and play it all: the state updates and errors received."""
    updates = errors = 0
    async with websockets.connect(server.url(f"?log={log}"), max_size=None, open_timeout=120) as websocket:
        await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "all"}}))
        while True:
            message = decode(await asyncio.wait_for(websocket.recv(), 300))
            updates += message["type"] == "xviz/state_update"
            errors += message["type"] == "xviz/error"
            if message["type"] in ("xviz/transform_log_done", "xviz/error"):
                return updates, errors


async def run(sessions: int, frames: int) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch) / "data"
        root.mkdir()
        bag = generate_bag(Path(scratch) / "drive.bag", "ros1", frames)
        for number in range(sessions):
            (root / f"drive-{number:02d}.bag").write_bytes(bag.read_bytes())
        with start_server(root) as server:
            await play(server, "drive-00")  # the workers are up
            idle = await healthz_times(server, 10)
            family = descendants(server.pid)
            before = {pid: status_bytes(pid, "VmRSS") for pid in family}
            started = time.perf_counter()
            storm = asyncio.gather(*(play(server, f"drive-{n:02d}") for n in range(sessions)))
            busy = await healthz_times(server, 10)
            played = await storm
            took = time.perf_counter() - started
            grown = {pid: (status_bytes(pid, "VmHWM") - rss) / _MiB for pid, rss in before.items()}
    workers = sorted((g for pid, g in grown.items() if pid != server.pid), reverse=True)
    print(
        f"{sessions} sessions on {sessions} different bags of {frames} frames: {sum(u for u, _ in played)} frames "
        f"played, {sum(e for _, e in played)} errors, in {took:.1f} s"
    )
    print(
        f"peak RSS growth over RSS once warm: server {grown[server.pid]:.0f} MiB; other processes (fork server, "
        f"workers) {', '.join(f'{g:.0f}' for g in workers)} MiB"
    )
    print(
        f"GET /healthz median during / idle: {statistics.median(busy) * 1e3:.1f} ms / "
        f"{statistics.median(idle) * 1e3:.1f} ms = x{statistics.median(busy) / statistics.median(idle):.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=30, help="sessions, each on a bag of its own")
    parser.add_argument("--frames", type=int, default=8, help="frames of each bag")
    args = parse(parser, {"sessions": 4, "frames": 2})
    asyncio.run(run(args.sessions, args.frames))


if __name__ == "__main__":
    main()
