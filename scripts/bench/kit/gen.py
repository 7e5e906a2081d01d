"""Generated data for the benchmarks, and the rate at which a dataset is served on demand.

- :func:`generate_bag`: a ROS 1 bag, or a ROS 2 bag in sqlite3 or MCAP, of
  ``frames`` frames of 120 000 points and a 1242x375 rgb8 image, written with
  rosbags' own writers;
- :func:`served`: the first frame and the whole stream of a dataset that a
  freshly started server converts on demand.

Synthetic logs are :func:`kit.write_log`; Waymo frames are :mod:`devkit.waymo_frames`.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import websockets

from kit.proc import start_server
from xviz_server.codec import decode

__all__ = ["POINTS", "WIDTH", "HEIGHT", "frame_messages", "generate_bag", "served"]

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
        header=header("velodyne"),
        height=1,
        width=POINTS,
        is_bigendian=False,
        point_step=16,
        row_step=16 * POINTS,
        fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(("x", "y", "z", "intensity"))],
        data=cloud.view(np.uint8).reshape(-1),
        is_dense=True,
    )
    pixels = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    pixels[..., 0] = np.arange(WIDTH, dtype=np.uint32) * 255 // WIDTH
    pixels[..., 1] = (np.arange(HEIGHT, dtype=np.uint32) * 255 // HEIGHT)[:, None]
    image = types["sensor_msgs/msg/Image"](
        header=header("camera"),
        height=HEIGHT,
        width=WIDTH,
        encoding="rgb8",
        is_bigendian=0,
        step=WIDTH * 3,
        data=pixels.reshape(-1),
    )
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    return (bytes(serialize(message, "sensor_msgs/msg/PointCloud2")), bytes(serialize(image, "sensor_msgs/msg/Image")))


def generate_bag(path: Path, container: str, frames: int) -> Path:
    """A bag at ``path`` (``container``: ``mcap``, ``ros1`` or ``sqlite3``) of ``frames`` frames at 10 Hz."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ros1 = container == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    cloud, image = frame_messages(store, ros1)
    writer: Any = (
        Writer1(path)
        if ros1
        else Writer2(
            path, version=9, storage_plugin=StoragePlugin.SQLITE3 if container == "sqlite3" else StoragePlugin.MCAP
        )
    )
    with writer:
        clouds = writer.add_connection("/velodyne_points", "sensor_msgs/msg/PointCloud2", typestore=store)
        images = writer.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=store)
        for frame in range(frames):
            t = START + frame * 100_000_000
            writer.write(clouds, t, cloud)
            writer.write(images, t + 1_000_000, image)
    return path


async def served(dataset: str, settle: float) -> tuple[float, float, int]:
    """Serve ``dataset`` (``KIND:PATH``) from a fresh server, wait ``settle`` s, stream it whole once.

    Returns the seconds to the first frame and to the end, and the frames received.
    """
    with start_server(None, "--dataset", dataset) as server:
        await asyncio.sleep(settle)
        async with websockets.connect(server.url(), max_size=None) as websocket:
            await websocket.recv()
            started = time.perf_counter()
            await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "1"}}))
            frames, first = 0, 0.0
            while True:
                message = await websocket.recv()
                if len(message) < 200 and decode(message)["type"] == "xviz/transform_log_done":
                    break
                frames += 1
                first = first or time.perf_counter() - started
            return first, time.perf_counter() - started, frames
