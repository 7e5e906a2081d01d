"""PandaSet sequences for the tests, in the dataset's layout: gzipped pickles of pandas DataFrames, JSON, JPEG.

As the PandaSet devkit documents them: sweeps ``lidar/NN.pkl.gz`` with
columns ``x, y, z, i, t, d`` in the world frame, ``lidar/poses.json``
(``position`` and ``heading``) and ``timestamps.json`` in seconds, cameras
``camera/{name}/NN.jpg`` with ``timestamps.json``, cuboids
``annotations/cuboids/NN.pkl.gz`` with ``uuid, label, yaw, stationary,
camera_used, position.{x,y,z}, dimensions.{x,y,z}`` in the world frame, and
``meta/gps.json``, ``meta/timestamps.json``. The vehicle drives along a turning
path; one car is parked.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from devkit.waymo_frames import jpeg_image

T0 = 1_557_540_000.0  # seconds
PERIOD = 0.1
CAMERAS = ("front_camera", "back_camera")
PARKED_POSITION, PARKED_DIMENSIONS, PARKED_YAW = (30.0, 4.0, 0.8), (4.5, 1.9, 1.6), 0.4


def pose(index: int) -> tuple[tuple[float, float, float], float]:
    return (10.0 + 2.0 * index, 1.0 + 0.1 * index, 1.8), 0.02 * index


def local_points(index: int) -> np.ndarray:
    """A sweep's points in the lidar's own frame: a ring at 12 m."""
    angles = np.radians(np.arange(0, 360, 3, dtype=np.float64))
    return np.column_stack([12 * np.cos(angles), 12 * np.sin(angles), np.full(len(angles), -1.5 + 0.01 * index)])


def write_sequence(folder: Path, sweeps: int = 4) -> Path:
    """A sequence folder of ``sweeps`` sweeps; its camera images come 20 ms after each sweep."""
    import pandas as pd

    for part in ("lidar", "annotations/cuboids", "meta", *(f"camera/{c}" for c in CAMERAS)):
        (folder / part).mkdir(parents=True, exist_ok=True)
    poses, times = [], []
    for index in range(sweeps):
        (x, y, z), yaw = pose(index)
        poses.append(
            {
                "position": {"x": x, "y": y, "z": z},
                "heading": {"w": math.cos(yaw / 2), "x": 0.0, "y": 0.0, "z": math.sin(yaw / 2)},
            }
        )
        times.append(T0 + index * PERIOD)
        local = local_points(index)
        world = local @ np.array(
            [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
        ).T + (x, y, z)
        count = len(world)
        pd.DataFrame(
            {
                "x": world[:, 0],
                "y": world[:, 1],
                "z": world[:, 2],
                "i": np.arange(count, dtype=np.float64) % 256,
                "t": np.full(count, times[-1]),
                "d": np.zeros(count, dtype=np.int64),
            }
        ).to_pickle(folder / "lidar" / f"{index:02d}.pkl.gz", compression="gzip")
        pd.DataFrame(
            {
                "uuid": ["2a1e8b0c-9d3f-4c56-a7b8-0e1f2a3b4c5d"],
                "label": ["Car"],
                "yaw": [PARKED_YAW],
                "stationary": [True],
                "camera_used": [0],
                **{f"position.{k}": [v] for k, v in zip("xyz", PARKED_POSITION)},
                **{f"dimensions.{k}": [v] for k, v in zip("xyz", PARKED_DIMENSIONS)},
                "attributes.object_motion": ["Parked"],
                "cuboids.sibling_id": ["-"],
                "cuboids.sensor_id": [-1],
            }
        ).to_pickle(folder / "annotations" / "cuboids" / f"{index:02d}.pkl.gz", compression="gzip")
    (folder / "lidar" / "poses.json").write_text(json.dumps(poses))
    (folder / "lidar" / "timestamps.json").write_text(json.dumps(times))
    for number, camera in enumerate(CAMERAS):
        for index in range(sweeps):
            (folder / "camera" / camera / f"{index:02d}.jpg").write_bytes(
                jpeg_image(192, 108, (60 * number + 40, 90, 140))
            )
        (folder / "camera" / camera / "timestamps.json").write_text(json.dumps([t + 0.02 for t in times]))
    (folder / "meta" / "timestamps.json").write_text(json.dumps(times))
    (folder / "meta" / "gps.json").write_text(
        json.dumps([{"lat": 37.776, "long": -122.42, "height": 2.0, "xvel": 5.0, "yvel": 0.1}] * sweeps)
    )
    return folder
