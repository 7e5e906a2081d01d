#!/usr/bin/env python3
"""Benchmark ROS bags served as logs: per frame, opening a big bag, and streaming on demand.

    python scripts/bench_rosbag.py [--container mcap|ros1|sqlite3] [--gigabytes 2] [--repeat 3]

Bags are generated in a temporary folder (deleted at the end) with rosbags'
writers: each frame a 120 000-point ``PointCloud2`` (x, y, z, intensity)
and a 1242x375 ``rgb8`` camera ``Image``, at 10 Hz.

1. One frame (read from the bag, build, encode GLB) in this process: median
   ms, against the KITTI converter's frame on the real excerpt measured in
   the same run (ratio).
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
from pathlib import Path
from typing import Any

import numpy as np
import websockets

from bench_kitti import RAW, served
from benchproc import start_server
from xviz_server.codec import Format, decode, encode
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.ros import RosBag
from xviz_server.messages import envelope

POINTS = 120_000
WIDTH, HEIGHT = 1242, 375
START = 1_700_000_000 * 10**9


def frame_messages(store: Any, ros1: bool) -> tuple[bytes, bytes]:
    """One serialized cloud and one serialized image, reused for every frame."""
    types = store.types
    rng = np.random.default_rng(0)
    cloud = np.empty((POINTS, 4), "<f4")
    cloud[:, :3] = rng.uniform(-60, 60, (POINTS, 3))
    cloud[:, 3] = rng.uniform(0, 1, POINTS)
    stamp = types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)

    def header(frame: str) -> Any:
        fields = {"seq": 0} if ros1 else {}
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **fields)

    field = types["sensor_msgs/msg/PointField"]
    message = types["sensor_msgs/msg/PointCloud2"](
        header=header("velodyne"), height=1, width=POINTS, is_bigendian=False, point_step=16, row_step=16 * POINTS,
        fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(("x", "y", "z", "intensity"))],
        data=cloud.view(np.uint8).reshape(-1), is_dense=True,
    )
    pixels = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    pixels[..., 0] = np.arange(WIDTH, dtype=np.uint32) * 255 // WIDTH
    pixels[..., 1] = (np.arange(HEIGHT, dtype=np.uint32) * 255 // HEIGHT)[:, None]
    image = types["sensor_msgs/msg/Image"](
        header=header("camera"), height=HEIGHT, width=WIDTH, encoding="rgb8", is_bigendian=0, step=WIDTH * 3,
        data=pixels.reshape(-1),
    )
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    return (bytes(serialize(message, "sensor_msgs/msg/PointCloud2")), bytes(serialize(image, "sensor_msgs/msg/Image")))


def generate(path: Path, container: str, frames: int) -> Path:
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ros1 = container == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    cloud, image = frame_messages(store, ros1)
    writer: Any = Writer1(path) if ros1 else Writer2(
        path, version=9, storage_plugin=StoragePlugin.SQLITE3 if container == "sqlite3" else StoragePlugin.MCAP
    )
    with writer:
        clouds = writer.add_connection("/velodyne_points", "sensor_msgs/msg/PointCloud2", typestore=store)
        images = writer.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=store)
        for frame in range(frames):
            t = START + frame * 100_000_000
            writer.write(clouds, t, cloud)
            writer.write(images, t + 1_000_000, image)
    return path


def per_frame(dataset: RosBag | KittiDrive, repeat: int) -> float:
    """Median ms of one frame read, built and encoded as GLB."""
    metadata = dataset.metadata()
    times = []
    for _ in range(repeat):
        for frame in range(len(dataset)):
            started = time.perf_counter()
            encode(envelope("state_update", dataset.convert(frame, metadata)), Format.BINARY)
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
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench_rosbag_"))
    suffix = {"mcap": "", "ros1": ".bag", "sqlite3": ""}[args.container]
    try:
        small = RosBag(generate(folder / f"small{suffix}", args.container, 30))
        ours, theirs = per_frame(small, args.repeat), per_frame(KittiDrive(RAW), args.repeat)
        print(f"1. one frame ({POINTS} points + {WIDTH}x{HEIGHT} rgb8 image; read, build, encode GLB), one process, "
              f"{args.container}: median {ours:.1f} ms (target under 15 ms); the KITTI converter's frame in this run: "
              f"{theirs:.1f} ms; ratio {ours / theirs:.2f}")
        frame_bytes = len(frame_messages(*_store(args.container))[0]) + WIDTH * HEIGHT * 3
        frames = int(args.gigabytes * 1e9 / frame_bytes)
        started = time.perf_counter()
        big = generate(folder / f"big{suffix}", args.container, frames)
        size = sum(p.stat().st_size for p in ([big] if big.is_file() else big.iterdir()))
        print(f"   generated {size / 1e9:.2f} GB, {frames} frames, in {time.perf_counter() - started:.0f} s")
        started = time.perf_counter()
        bag = RosBag(big)
        encode(envelope("state_update", bag.convert(0, bag.metadata())), Format.BINARY)
        print(f"2. opening the {size / 1e9:.2f} GB bag to its first encoded frame: {(time.perf_counter() - started) * 1000:.0f} ms "
              f"(target under 1 s)")
        total, count = asyncio.run(streamed(big, 10.0, 3.0))
        rate = count / total
        _, kitti_total, kitti_count = asyncio.run(served(RAW, 3.0))
        kitti_rate = kitti_count / kitti_total
        print(f"3. served on demand: {count} frames of 10 s in {total:.1f} s = {rate:.1f} frames/s = "
              f"{rate / 10:.1f}x real time (10 Hz; target 3x); the KITTI excerpt served in this run: "
              f"{kitti_rate:.1f} frames/s, ratio {rate / kitti_rate:.2f}")
    finally:
        shutil.rmtree(folder)


def _store(container: str) -> tuple[Any, bool]:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE), container == "ros1"


if __name__ == "__main__":
    main()
