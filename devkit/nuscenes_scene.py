"""nuScenes roots for the tests, written in the dataset's layout: version folder of JSON tables, samples/, sweeps/.

The tables have the devkit's fields and their relations (scene, sample,
sample_data with key frames and sweeps, ego_pose, calibrated_sensor, sensor,
sample_annotation, instance, category); lidar sweeps are ``.pcd.bin`` float32
x, y, z, intensity, ring in the sensor frame; camera images are JPEG. The
vehicle drives along x, turning slowly; one car drives beside it through every
key frame, a pedestrian is seen in the first two only.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from devkit.waymo_frames import jpeg_image

T0 = 1_532_402_927_647_951  # microseconds, a nuScenes-like start
LIDAR_PERIOD = 50_000  # 20 Hz
CAMERA_PERIOD = 83_333  # 12 Hz
SWEEPS_PER_KEY = 10  # key frames at 2 Hz
LIDAR_ON_CAR = (0.94, 0.0, 1.84)  # LIDAR_TOP's translation on the vehicle, turned by 90 degrees as nuScenes' is
CAMERAS = ("CAM_FRONT", "CAM_BACK")


def quaternion(yaw: float) -> list[float]:
    """w, x, y, z of a turn by ``yaw`` about z."""
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def ego(micros: int, start: int) -> tuple[list[float], float]:
    """The vehicle's world position and heading at a time: 5 m/s along a slow left turn."""
    seconds = (micros - start) / 1e6
    return [600.0 + 5 * seconds, 1600.0 + 0.2 * seconds, 0.0], 0.1 + 0.02 * seconds


def car(micros: int, start: int) -> tuple[list[float], float]:
    """The car beside the vehicle: 6 m/s, 4 m to its left."""
    seconds = (micros - start) / 1e6
    return [610.0 + 6 * seconds, 1604.0, 0.8], 0.05


def sweep_points(index: int) -> np.ndarray:
    """A sweep in the sensor frame: a ring of 360 points at 10 m, its height and intensity by index."""
    angles = np.radians(np.arange(360, dtype=np.float64))
    cloud = np.zeros((360, 5), np.float32)
    cloud[:, 0], cloud[:, 1] = 10 * np.cos(angles), 10 * np.sin(angles)
    cloud[:, 2] = -1.5 + 0.01 * index
    cloud[:, 3] = (np.arange(360) * 7 + index) % 256
    cloud[:, 4] = np.arange(360) % 32
    return cloud


@dataclass
class Written:
    """What a written root holds, for the tests to check against."""

    root: Path
    #: Per scene: lidar capture times (µs), key frame flags, camera captures (channel, time).
    lidar: dict[str, list[int]] = field(default_factory=dict)
    keys: dict[str, list[bool]] = field(default_factory=dict)
    images: dict[str, list[tuple[str, int]]] = field(default_factory=dict)
    starts: dict[str, int] = field(default_factory=dict)


def write_nuscenes(
    root: Path, scenes: tuple[str, ...] = ("scene-0061",), keys: int = 3, version: str = "v1.0-mini"
) -> Written:
    """A nuScenes root with ``scenes``, each ``keys`` key frames long with the sweeps between them."""
    tables: dict[str, list[dict]] = {
        name: []
        for name in (
            "scene",
            "sample",
            "sample_data",
            "ego_pose",
            "calibrated_sensor",
            "sensor",
            "sample_annotation",
            "instance",
            "category",
            "log",
        )
    }
    written = Written(root)
    tables["category"] = [
        {"token": "cat-car", "name": "vehicle.car", "description": ""},
        {"token": "cat-ped", "name": "human.pedestrian.adult", "description": ""},
    ]
    sensors = {"LIDAR_TOP": "lidar", **{camera: "camera" for camera in CAMERAS}}
    for channel, modality in sensors.items():
        tables["sensor"].append({"token": f"sensor-{channel}", "channel": channel, "modality": modality})
        rotation = quaternion(math.pi / 2) if channel == "LIDAR_TOP" else quaternion(0.0)
        tables["calibrated_sensor"].append(
            {
                "token": f"calib-{channel}",
                "sensor_token": f"sensor-{channel}",
                "translation": list(LIDAR_ON_CAR) if channel == "LIDAR_TOP" else [1.7, 0.0, 1.5],
                "rotation": rotation,
                "camera_intrinsic": [] if modality == "lidar" else [[1266.4, 0, 816.3], [0, 1266.4, 491.5], [0, 0, 1]],
            }
        )
    colours = {"CAM_FRONT": jpeg_image(160, 90, (200, 40, 40)), "CAM_BACK": jpeg_image(160, 90, (40, 40, 200))}
    for number, scene in enumerate(scenes):
        start = T0 + number * 60_000_000
        written.starts[scene] = start
        samples = [f"{scene}-sample-{k}" for k in range(keys)]
        tables["scene"].append(
            {
                "token": f"{scene}-token",
                "log_token": "log-1",
                "nbr_samples": keys,
                "name": scene,
                "description": "a test drive",
                "first_sample_token": samples[0],
                "last_sample_token": samples[-1],
            }
        )
        for k, sample in enumerate(samples):
            tables["sample"].append(
                {
                    "token": sample,
                    "timestamp": start + k * SWEEPS_PER_KEY * LIDAR_PERIOD,
                    "scene_token": f"{scene}-token",
                    "prev": samples[k - 1] if k else "",
                    "next": samples[k + 1] if k + 1 < keys else "",
                }
            )
        span = (keys - 1) * SWEEPS_PER_KEY * LIDAR_PERIOD
        captures: list[tuple[str, int, bool]] = []
        for i in range(-2, (keys - 1) * SWEEPS_PER_KEY + 3):  # sweeps before the first key frame and after the last
            captures.append(
                (
                    "LIDAR_TOP",
                    start + i * LIDAR_PERIOD,
                    i >= 0 and i % SWEEPS_PER_KEY == 0 and i <= span // LIDAR_PERIOD,
                )
            )
        for camera in CAMERAS:
            for j in range(-1, span // CAMERA_PERIOD + 3):
                captures.append((camera, start + 5_000 + j * CAMERA_PERIOD, False))
        written.lidar[scene] = [t for c, t, _ in captures if c == "LIDAR_TOP"]
        written.keys[scene] = [key for c, _, key in captures if c == "LIDAR_TOP"]
        written.images[scene] = [(c, t) for c, t, _ in captures if c != "LIDAR_TOP"]
        for channel, micros, key in captures:
            nearest = min(range(keys), key=lambda k: abs(start + k * SWEEPS_PER_KEY * LIDAR_PERIOD - micros))
            kind = "samples" if key else "sweeps"
            suffix = ".pcd.bin" if channel == "LIDAR_TOP" else ".jpg"
            filename = f"{kind}/{channel}/n015-2018-07-24-11-22-45+0800__{channel}__{micros}{suffix}"
            path = root / filename
            path.parent.mkdir(parents=True, exist_ok=True)
            if channel == "LIDAR_TOP":
                path.write_bytes(sweep_points(written.lidar[scene].index(micros)).tobytes())
            else:
                path.write_bytes(colours[channel])
            token = f"{scene}-{channel}-{micros}"
            position, heading = ego(micros, start)
            tables["ego_pose"].append(
                {"token": f"ego-{token}", "timestamp": micros, "translation": position, "rotation": quaternion(heading)}
            )
            tables["sample_data"].append(
                {
                    "token": token,
                    "sample_token": samples[nearest],
                    "ego_pose_token": f"ego-{token}",
                    "calibrated_sensor_token": f"calib-{channel}",
                    "timestamp": micros,
                    "fileformat": "pcd" if channel == "LIDAR_TOP" else "jpg",
                    "is_key_frame": key,
                    "height": 0 if channel == "LIDAR_TOP" else 900,
                    "width": 0 if channel == "LIDAR_TOP" else 1600,
                    "filename": filename,
                    "prev": "",
                    "next": "",
                }
            )
        tables["instance"] += [
            {"token": f"{scene}-car-instance-0001", "category_token": "cat-car", "nbr_annotations": keys},
            {"token": f"{scene}-ped-instance-0002", "category_token": "cat-ped", "nbr_annotations": 2},
        ]
        for k, sample in enumerate(samples):
            micros = start + k * SWEEPS_PER_KEY * LIDAR_PERIOD
            position, heading = car(micros, start)
            tables["sample_annotation"].append(
                {
                    "token": f"{sample}-car",
                    "sample_token": sample,
                    "instance_token": f"{scene}-car-instance-0001",
                    "translation": position,
                    "size": [1.9, 4.5, 1.6],
                    "rotation": quaternion(heading),
                    "num_lidar_pts": 100,
                    "num_radar_pts": 0,
                    "prev": "",
                    "next": "",
                    "visibility_token": "4",
                    "attribute_tokens": [],
                }
            )
            if k < 2:
                tables["sample_annotation"].append(
                    {
                        "token": f"{sample}-ped",
                        "sample_token": sample,
                        "instance_token": f"{scene}-ped-instance-0002",
                        "translation": [605.0, 1598.0, 0.9],
                        "size": [0.6, 0.7, 1.8],
                        "rotation": quaternion(1.0),
                        "num_lidar_pts": 20,
                        "num_radar_pts": 0,
                        "prev": "",
                        "next": "",
                        "visibility_token": "4",
                        "attribute_tokens": [],
                    }
                )
    tables["log"].append(
        {
            "token": "log-1",
            "logfile": "n015-2018-07-24-11-22-45+0800",
            "vehicle": "n015",
            "location": "singapore-onenorth",
        }
    )
    folder = root / version
    folder.mkdir(parents=True, exist_ok=True)
    for name, rows in tables.items():
        (folder / f"{name}.json").write_text(json.dumps(rows, indent=0))
    return written
