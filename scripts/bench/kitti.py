#!/usr/bin/env python3
"""Benchmark KITTI reading and conversion: per frame, with the pool, and served on demand.

    python scripts/bench/kitti.py [RAW_DIR] [--repeat N] [--quick]

1. Reading one frame's raw data in this process: velodyne points with their
   colours, the OXTS record, the four camera images: median ms, and each part.
2. One frame (read raw files, build, encode GLB) in this process: median ms.
3. The whole drive with a process pool of one process per core: frames/s.
4. The drive served on demand (``xviz-server serve --dataset kitti:RAW``, a
   separate process, fresh): time to the first frame of a transform_log on
   the unconverted drive, and the streaming rate over the drive as a ratio
   to real time (10 Hz); asked the moment the server listens (its worker
   processes still starting) and 3 s later.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from kit import KITTI_RAW, parse
from kit.gen import served

from xviz_server.codec import Format, encode
from xviz_server.datasets import convert_frame
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.shared import reflectance_colors
from xviz_server.messages import envelope


def read_frame(drive: KittiDrive, frame: int) -> dict[str, float]:
    """Read a frame's raw data as the converter does; seconds taken by each part."""
    times: dict[str, float] = {}
    started = time.perf_counter()
    sweep = drive.velodyne(frame)
    reflectance_colors(sweep[:, 3])
    times["points"] = time.perf_counter() - started
    started = time.perf_counter()
    drive.oxts(frame)
    times["oxts"] = time.perf_counter() - started
    started = time.perf_counter()
    for camera in drive.cameras:
        drive.image(camera, frame)
    times["images"] = time.perf_counter() - started
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("raw", nargs="?", type=Path, default=KITTI_RAW)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument(
        "--settle", type=float, default=3.0, help="seconds after the server listens for the second stream"
    )
    args = parse(parser, quick={"repeat": 1, "settle": 0.5})
    drive = KittiDrive(args.raw)
    metadata = drive.metadata()

    parts = [read_frame(drive, frame) for _ in range(args.repeat) for frame in range(len(drive))]
    reading = statistics.median(sum(p.values()) for p in parts) * 1000
    each = ", ".join(f"{name} {statistics.median(p[name] for p in parts) * 1000:.2f}" for name in parts[0])
    print(f"drive {drive.name}: {len(drive)} frames")
    print(
        f"1. reading one frame (points with colours, OXTS, {len(drive.cameras)} images), one process: "
        f"median {reading:.2f} ms ({each} ms)"
    )

    times = []
    for _ in range(args.repeat):
        for frame in range(len(drive)):
            fresh = KittiDrive(args.raw)  # no cached OXTS: every file read, as in a cold worker
            started = time.perf_counter()
            encode(envelope("state_update", fresh.convert(frame, metadata)), Format.BINARY)
            times.append(time.perf_counter() - started)
    single = statistics.median(times) * 1000
    print(
        f"2. one frame (read, build, encode GLB), one process: median {single:.1f} ms "
        f"(target under 30 ms; the official converter: 150-800 ms)"
    )

    processes = os.cpu_count() or 1
    with ProcessPoolExecutor(processes) as pool:
        list(
            pool.map(
                convert_frame,
                ["kitti"] * processes,
                [str(drive.path)] * processes,
                [{}] * processes,
                range(processes),
                [metadata] * processes,
            )
        )  # start the workers
        started = time.perf_counter()
        list(
            pool.map(
                convert_frame,
                ["kitti"] * len(drive),
                [str(drive.path)] * len(drive),
                [{}] * len(drive),
                range(len(drive)),
                [metadata] * len(drive),
            )
        )
        pooled = len(drive) / (time.perf_counter() - started)
    print(f"3. whole drive, {processes} processes: {pooled:.0f} frames/s ({1000 / pooled:.1f} ms per frame)")

    for settle, when in (
        (0.0, "the moment the server listens"),
        (args.settle, f"{args.settle:g} s after start (worker processes up)"),
    ):
        first, total, frames = asyncio.run(served(f"kitti:{args.raw}", settle))
        rate = frames / total
        print(
            f"4. served on demand, asked {when}: first frame after {first * 1000:.0f} ms; "
            f"{rate:.0f} frames/s over the drive = {rate / 10:.1f}x real time (10 Hz)"
        )


if __name__ == "__main__":
    main()
