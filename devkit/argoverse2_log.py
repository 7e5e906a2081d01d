"""Argoverse 2 sensor logs for the tests, in the dataset's layout: Feather sweeps, poses and cuboids, JPEG cameras.

Columns and types are those the av2 devkit documents: sweeps with float16
``x, y, z``, uint8 ``intensity`` and ``laser_number``, uint32 ``offset_ns``;
``city_SE3_egovehicle.feather`` and ``annotations.feather`` with quaternions
``qw, qx, qy, qz`` and translations ``tx_m, ty_m, tz_m``. The vehicle drives
along x at 10 m/s turning slowly; a car drives ahead of it, a pedestrian
stands still (both annotated at every sweep, in the vehicle frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from devkit.waymo_frames import jpeg_image

T0 = 1_315_966_000_000_000_000  # nanoseconds
SWEEP_PERIOD = 100_000_000  # 10 Hz
CAMERA_PERIOD = 50_000_000  # 20 Hz
CAMERAS = ("ring_front_center", "ring_side_left")


def ego(stamp: int) -> tuple[tuple[float, float, float], float]:
    seconds = (stamp - T0) / 1e9
    return (100.0 + 10 * seconds, 200.0 + 0.5 * seconds, 0.0), 0.3 + 0.05 * seconds


def sweep(index: int) -> dict[str, np.ndarray]:
    angles = np.radians(np.arange(0, 360, 2, dtype=np.float64))
    return {
        "x": (8 * np.cos(angles)).astype(np.float16),
        "y": (8 * np.sin(angles)).astype(np.float16),
        "z": np.full(len(angles), -1.0 + 0.125 * index, np.float16),
        "intensity": (np.arange(len(angles)) % 256).astype(np.uint8),
        "laser_number": (np.arange(len(angles)) % 32).astype(np.uint8),
        "offset_ns": np.arange(len(angles), dtype=np.uint32) * 1000,
    }


def quaternion(yaw: float) -> tuple[float, float, float, float]:
    return math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)


@dataclass
class Written:
    folder: Path
    sweeps: list[int] = field(default_factory=list)
    images: list[tuple[str, int]] = field(default_factory=list)


def write_av2_log(folder: Path, sweeps: int = 5, annotated: bool = True) -> Written:
    """An Argoverse 2 log of ``sweeps`` sweeps, its cameras beginning before the first and ending after the last."""
    import pyarrow as pa
    import pyarrow.feather as feather

    written = Written(folder)
    (folder / "sensors" / "lidar").mkdir(parents=True)
    for i in range(sweeps):
        stamp = T0 + i * SWEEP_PERIOD
        written.sweeps.append(stamp)
        feather.write_feather(pa.table(sweep(i)), folder / "sensors" / "lidar" / f"{stamp}.feather")
    colours = {
        "ring_front_center": jpeg_image(2048 // 8, 1550 // 8, (30, 160, 30)),
        "ring_side_left": jpeg_image(1550 // 8, 2048 // 8, (160, 30, 160)),
    }
    for number, camera in enumerate(CAMERAS):
        (folder / "sensors" / "cameras" / camera).mkdir(parents=True)
        for j in range(-1, 2 * sweeps + 1):
            stamp = T0 + 7_000_000 * (number + 1) + j * CAMERA_PERIOD
            written.images.append((camera, stamp))
            (folder / "sensors" / "cameras" / camera / f"{stamp}.jpg").write_bytes(colours[camera])
    stamps = sorted({*written.sweeps, *(stamp for _, stamp in written.images)})
    poses = [(stamp, *quaternion(ego(stamp)[1]), *ego(stamp)[0]) for stamp in stamps]
    columns = ("timestamp_ns", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
    feather.write_feather(
        pa.table({c: [p[k] for p in poses] for k, c in enumerate(columns)}), folder / "city_SE3_egovehicle.feather"
    )
    if annotated:
        rows = []
        for stamp in written.sweeps:
            seconds = (stamp - T0) / 1e9
            rows.append(
                (
                    stamp,
                    "8f4a4fd6-5c34-4a4d-bb7e-0a3a1c2d3e4f",
                    "REGULAR_VEHICLE",
                    4.6,
                    1.9,
                    1.5,
                    *quaternion(0.1),
                    12.0 + 2 * seconds,
                    1.0,
                    0.75,
                )
            )
            rows.append(
                (
                    stamp,
                    "0b1c2d3e-aaaa-4bbb-8ccc-123456789abc",
                    "PEDESTRIAN",
                    0.6,
                    0.6,
                    1.8,
                    *quaternion(0.0),
                    5.0 - 10 * seconds,
                    -3.0,
                    0.9,
                )
            )
        names = (
            "timestamp_ns",
            "track_uuid",
            "category",
            "length_m",
            "width_m",
            "height_m",
            "qw",
            "qx",
            "qy",
            "qz",
            "tx_m",
            "ty_m",
            "tz_m",
        )
        table = {c: [r[k] for r in rows] for k, c in enumerate(names)}
        table["num_interior_pts"] = [50] * len(rows)
        feather.write_feather(pa.table(table), folder / "annotations.feather")
    (folder / "calibration").mkdir()
    return written
