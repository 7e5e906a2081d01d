#!/usr/bin/env python3
"""Benchmark ROS bags served as logs: per frame, opening a big bag, and streaming on demand.

    python scripts/bench/rosbag.py [--container mcap|ros1|sqlite3] [--gigabytes 2] [--repeat 3] [--quick]

Bags are generated in a temporary folder (deleted at the end) with rosbags'
writers: each frame a 120 000-point ``PointCloud2`` (x, y, z, intensity)
and a 1242x375 ``rgb8`` camera ``Image``, at 10 Hz.

1. One frame (read from the bag, build, encode GLB) in this process: median
   ms, against the KITTI converter's frame on the real excerpt measured in
   the same run (ratio); and one frame's original messages read and packed
   (what a Foxglove client's original topics cost), against that frame.
2. Opening a bag of ``--gigabytes`` to its first encoded frame (index,
   metadata, frame 0), in this process with the modules imported: ms.
3. That bag served on demand (``xviz-server serve --dataset rosbag:BAG``, a
   separate process): the first 10 s of the drive streamed with
   transform_log, frames/s as a ratio to real time (10 Hz), asked 3 s after
   the server listens; and the KITTI excerpt served the same way, as the
   reference.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import websockets
from kit import KITTI_RAW, parse
from kit.gen import HEIGHT, POINTS, WIDTH, frame_messages, generate_bag, served
from kit.proc import start_server

from xviz_server.codec import Format, decode, encode
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.ros import RosBag
from xviz_server.messages import envelope


def per_frame(dataset: RosBag | KittiDrive, repeat: int) -> float:
    """Median ms of one frame read, built and encoded as GLB."""
    metadata = dataset.metadata()
    return median_ms(
        lambda frame: encode(envelope("state_update", dataset.convert(frame, metadata)), Format.BINARY),
        len(dataset),
        repeat,
    )


def median_ms(job: Callable[[int], Any], frames: int, repeat: int) -> float:
    """Median ms of ``job(frame)`` over every frame, ``repeat`` times."""
    times = []
    for _ in range(repeat):
        for frame in range(frames):
            started = time.perf_counter()
            job(frame)
            times.append(time.perf_counter() - started)
    return statistics.median(times) * 1000


async def streamed(bag: Path, seconds: float, settle: float) -> tuple[float, int]:
    with start_server(None, "--dataset", f"rosbag:{bag}") as server:
        await asyncio.sleep(settle)
        async with websockets.connect(server.url(), max_size=None) as websocket:
            metadata = decode(await websocket.recv())["data"]
            start = metadata["log_info"]["start_time"]
            request = {"id": "1", "start_timestamp": start, "end_timestamp": start + seconds}
            started = time.perf_counter()
            await websocket.send(json.dumps({"type": "xviz/transform_log", "data": request}))
            frames = 0
            while True:
                message = await websocket.recv()
                if len(message) < 200 and decode(message)["type"] == "xviz/transform_log_done":
                    break
                frames += 1
            return time.perf_counter() - started, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--container", choices=["mcap", "ros1", "sqlite3"], default="mcap")
    parser.add_argument("--gigabytes", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--settle", type=float, default=3.0, help="seconds between the server listening and the stream")
    args = parse(parser, quick={"gigabytes": 0.02, "repeat": 1, "settle": 0.5})
    folder = Path(tempfile.mkdtemp(prefix="bench_rosbag_"))
    suffix = {"mcap": "", "ros1": ".bag", "sqlite3": ""}[args.container]
    try:
        small = RosBag(generate_bag(folder / f"small{suffix}", args.container, 30))
        ours, theirs = per_frame(small, args.repeat), per_frame(KittiDrive(KITTI_RAW), args.repeat)
        print(
            f"1. one frame ({POINTS} points + {WIDTH}x{HEIGHT} rgb8 image; read, build, encode GLB), one process, "
            f"{args.container}: median {ours:.1f} ms (target under 15 ms); the KITTI converter's frame in this run: "
            f"{theirs:.1f} ms; ratio {ours / theirs:.2f}"
        )
        originals = median_ms(small.original_messages, len(small), args.repeat)
        print(
            f"   one frame's original messages (read and packed as a Foxglove client gets them): median {originals:.1f} ms; "
            f"ratio to the frame above {originals / ours:.2f}"
        )
        frame_bytes = len(frame_messages(*_store(args.container))[0]) + WIDTH * HEIGHT * 3
        frames = int(args.gigabytes * 1e9 / frame_bytes)
        started = time.perf_counter()
        big = generate_bag(folder / f"big{suffix}", args.container, frames)
        size = sum(p.stat().st_size for p in ([big] if big.is_file() else big.iterdir()))
        print(f"   generated {size / 1e9:.2f} GB, {frames} frames, in {time.perf_counter() - started:.0f} s")
        started = time.perf_counter()
        bag = RosBag(big)
        encode(envelope("state_update", bag.convert(0, bag.metadata())), Format.BINARY)
        print(
            f"2. opening the {size / 1e9:.2f} GB bag to its first encoded frame: {(time.perf_counter() - started) * 1000:.0f} ms "
            f"(target under 1 s)"
        )
        total, count = asyncio.run(streamed(big, 10.0, args.settle))
        rate = count / total
        _, kitti_total, kitti_count = asyncio.run(served(f"kitti:{KITTI_RAW}", args.settle))
        kitti_rate = kitti_count / kitti_total
        print(
            f"3. served on demand: {count} frames of 10 s in {total:.1f} s = {rate:.1f} frames/s = "
            f"{rate / 10:.1f}x real time (10 Hz; target 3x); the KITTI excerpt served in this run: "
            f"{kitti_rate:.1f} frames/s, ratio {rate / kitti_rate:.2f}"
        )
    finally:
        shutil.rmtree(folder)


def _store(container: str) -> tuple[Any, bool]:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE), container == "ros1"


if __name__ == "__main__":
    main()
