"""Many sessions, each opening a different ROS bag at once: the server's memory and /healthz while they play.

Writes one real ROS 1 bag of the KITTI excerpt (lz4 chunks, with rosbags' writer, as the tests do), serves
``--sessions`` copies of it under different names from a server run as its own process, and opens one session on
each at the same moment, each playing its whole log. Reports the growth of the peak RSS of the server process and of
each worker process over their RSS once warm, and the time of ``GET /healthz`` during the storm as a ratio against
the same request on the idle server (the reference, in the same run).

    python scripts/bench/bomb_sessions.py            # 30 sessions
    python scripts/bench/bomb_sessions.py --quick    # 6 sessions, a few seconds
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "tests")]

from rosbag_kitti import RAW, write_bag  # noqa: E402
from test_bombs import served  # noqa: E402
from xviz_server.datasets.kitti import KittiDrive  # noqa: E402

_MiB = 1 << 20


async def healthz_times(server, count: int) -> list[float]:
    times = []
    for _ in range(count):
        started = time.perf_counter()
        status, _ = await server.get("/healthz")
        assert status == 200
        times.append(time.perf_counter() - started)
        await asyncio.sleep(0.05)
    return times


async def main(sessions: int, frames: int) -> None:
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch) / "data"
        root.mkdir()
        bag = write_bag(Path(scratch) / "drive.bag", "ros1", drive=KittiDrive(ROOT.parent / "shared" / "data" / RAW),
                        frames=frames, compression="lz4")
        for number in range(sessions):
            (root / f"drive-{number:02d}.bag").write_bytes(bag.read_bytes())
        async with served(root) as server:
            await server.session("drive-00")
            idle = await healthz_times(server, 10)
            before = server.rss()
            started = time.perf_counter()
            storm = asyncio.gather(*(server.session(f"drive-{n:02d}") for n in range(sessions)))
            busy = await healthz_times(server, 10)
            played = await storm
            took = time.perf_counter() - started
            peaks = server.peaks()
        updates = [sum(m["type"] == "xviz/state_update" for m in messages) for messages in played]
        errors = sum(m["type"] == "xviz/error" for messages in played for m in messages)
        grown = sorted(((peaks[pid] - rss) / _MiB for pid, rss in before.items() if pid in peaks and pid != server.process.pid), reverse=True)
        print(f"{sessions} sessions on {sessions} different bags of {frames} frames: {sum(updates)} frames played, "
              f"{errors} errors, in {took:.1f} s")
        print("peak RSS growth over RSS once warm, by process (server first, then the workers by size): "
              + ", ".join(f"{g:.0f} MiB" for g in [(peaks[server.process.pid] - before[server.process.pid]) / _MiB] + grown))
        print(f"GET /healthz median during / idle: {statistics.median(busy) * 1e3:.1f} ms / "
              f"{statistics.median(idle) * 1e3:.1f} ms = x{statistics.median(busy) / statistics.median(idle):.1f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=30)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--quick", action="store_true", help="6 sessions on bags of 4 frames")
    options = parser.parse_args()
    asyncio.run(main(6, 4) if options.quick else main(options.sessions, options.frames))
