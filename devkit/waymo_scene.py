"""A synthetic Waymo scene for the tests: two lidars in a room, written as a .tfrecord segment and as .npz files.

The points each laser must give are computed here ray by ray, independently of
the server's range image geometry, so a test can compare what the server
decodes against them.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from devkit.waymo_frames import calibration, frame, jpeg_image, pose_matrix, write_segment
from xviz_server.datasets.waymo import frame_pb2 as pb

T0 = 1_557_000_000_000_000
# The TOP lidar: 6 rows of listed beams, 24 columns, turned and raised on the car.
TOP_BEAMS = [-0.30, -0.20, -0.12, -0.05, 0.0, 0.04]
TOP_EXTRINSIC = pose_matrix(0.3, (1.4, 0.1, 2.1), roll=0.01, pitch=-0.02)
# The FRONT lidar: 5 uniform rows between -1.2 and 0.4 rad, 16 columns, looking forwards.
FRONT_EXTRINSIC = pose_matrix(0.05, (4.0, 0.0, 0.8))
# The room around the car, in the world: walls at x = X0 +- 25, y = Y0 +- 15, floor z = 0, ceiling z = 8.
X0, Y0 = 5000.0, -3000.0


def ray(extrinsic: np.ndarray, inclination: float, azimuth: float) -> tuple[np.ndarray, np.ndarray]:
    """Origin and unit direction, in the vehicle frame, of a lidar ray (one pixel at a time)."""
    local = np.array([math.cos(azimuth) * math.cos(inclination), math.sin(azimuth) * math.cos(inclination), math.sin(inclination)])
    return extrinsic[:3, 3], extrinsic[:3, :3] @ local


def hit_room(origin: np.ndarray, direction: np.ndarray) -> float:
    """Distance along a world ray to the first wall, floor or ceiling of the room."""
    distances = []
    for axis, planes in ((0, (X0 - 25, X0 + 25)), (1, (Y0 - 15, Y0 + 15)), (2, (0.0, 8.0))):
        for plane in planes:
            if abs(direction[axis]) > 1e-12:
                t = (plane - origin[axis]) / direction[axis]
                if t > 1e-9:
                    distances.append(t)
    return min(distances)


def pixel_angles(height: int, width: int, extrinsic: np.ndarray, beams: list[float] | None, low: float = 0, high: float = 0) -> tuple[list[float], list[float]]:
    """Inclination of each row and azimuth of each column, as Waymo's range image definition gives them."""
    pitches = beams if beams else [low + (r + 0.5) / height * (high - low) for r in range(height)]
    rows = list(reversed(pitches))
    correction = math.atan2(extrinsic[1, 0], extrinsic[0, 0])
    columns = [((width - c - 0.5) / width * 2 - 1) * math.pi - correction for c in range(width)]
    return rows, columns


def scene_frame(index: int, rng: np.random.Generator, rows_move: bool = False) -> tuple:
    """A frame seeing the room, and the points every laser must give, in the frame's vehicle frame.

    The TOP lidar's pose changes from column to column, as in Waymo's files, and also from row to row with
    ``rows_move``.
    """
    frame_pose = pose_matrix(0.2 + 0.05 * index, (X0 + index, Y0 + 2.0, 0.3))
    lasers, expected = {}, {}
    for name, extrinsic, (height, width), beams, low, high, moving in (
        ("TOP", TOP_EXTRINSIC, (6, 24), TOP_BEAMS, 0, 0, True),
        ("FRONT", FRONT_EXTRINSIC, (5, 16), None, -1.2, 0.4, False),
    ):
        rows, columns = pixel_angles(height, width, extrinsic, beams, low, high)
        first = np.zeros((height, width, 4), np.float32)
        second = np.zeros((height, width, 4), np.float32)
        first[..., 3] = second[..., 3] = -1
        pixel_pose = np.zeros((height, width, 6), np.float32)
        points: list[list] = [[], []]
        for r, inclination in enumerate(rows):
            for c, azimuth in enumerate(columns):
                if moving:  # the car turns and moves on during the sweep
                    roll, pitch, yaw = 0.001 * c, -0.002 * c, 0.2 + 0.05 * index + 0.004 * c
                    x, y, z = X0 + index + 0.05 * c, Y0 + 2.0 + 0.01 * c, 0.3
                    if rows_move:
                        pitch, yaw, x = pitch + 0.003 * r, yaw - 0.002 * r, x + 0.02 * r
                    pixel_pose[r, c] = (roll, pitch, yaw, x, y, z)
                    roll, pitch, yaw, x, y, z = pixel_pose[r, c].astype(float)  # as the file has them: float32
                    pose = pose_matrix(yaw, (x, y, z), roll, pitch)
                else:
                    pose = frame_pose
                origin, direction = ray(extrinsic, inclination, azimuth)
                world_origin, world_direction = pose[:3, :3] @ origin + pose[:3, 3], pose[:3, :3] @ direction
                distance = np.float32(hit_room(world_origin, world_direction))
                to_frame = np.linalg.inv(frame_pose)
                if (r + c) % 7 == 3:  # no return
                    first[r, c, 0] = -1 if c % 2 else 0
                    continue
                first[r, c, :3] = distance, rng.uniform(0, 2), 0.1
                first[r, c, 3] = 1 if (r, c) in ((1, 2), (2, 5)) else -1
                hit = world_origin + float(distance) * world_direction
                points[0].append((to_frame[:3, :3] @ hit + to_frame[:3, 3], first[r, c, 1], first[r, c, 3] > 0))
                if c % 5 == 0:  # a second, nearer echo on the same ray
                    near = np.float32(distance * 0.5)
                    second[r, c, :3] = near, 0.3, 0.2
                    hit = world_origin + float(near) * world_direction
                    points[1].append((to_frame[:3, :3] @ hit + to_frame[:3, 3], np.float32(0.3), False))
        lasers[name] = (first, second, pixel_pose if moving else None)
        expected[name] = points
    return frame_pose, lasers, expected


def scene_calibrations() -> list[pb.LaserCalibration]:
    return [calibration("TOP", TOP_EXTRINSIC, TOP_BEAMS), calibration("FRONT", FRONT_EXTRINSIC, (), -1.2, 0.4)]


LABELS = [((10.0, 5.0, 1.0, 4.0, 2.0, 1.6, math.radians(30)), 1, "car-a"), ((3.0, -2.0, 0.9, 0.8, 0.6, 1.8, 0.0), 2, "ped-b")]


def write_scene(directory: Path, frames: int = 3, rows_move: bool = False) -> tuple[Path, Path, list]:
    """The same frames as a .tfrecord segment and as a folder of .npz dictionaries; and the expected points."""
    rng = np.random.default_rng(15)
    directory.mkdir(parents=True, exist_ok=True)
    records, expectations = [], []
    npz = directory / "segment-15"
    npz.mkdir()
    camera = jpeg_image(64, 48, (200, 30, 30))
    for i in range(frames):
        pose, lasers, expected = scene_frame(i, rng, rows_move)
        records.append(frame(T0 + i * 100_000, pose, scene_calibrations(), lasers, {"FRONT": camera}, LABELS))
        expectations.append(expected)
        from PIL import Image

        arrays = {"POSE": pose.astype(np.float32), "FRONT_IMAGE": np.asarray(Image.open(io.BytesIO(camera)).convert("RGB")),
                  "LABEL_BOXES": np.array([box for box, _, _ in LABELS]), "LABEL_TYPES": np.array([k for _, k, _ in LABELS]),
                  "LABEL_IDS": np.array([n for _, _, n in LABELS])}
        for name, (first, second, _) in lasers.items():
            for suffix, zone_key, image, returns in (("FIRST_RETURN", "IN_NLZ", first, expected[name][0]),
                                                     ("SECOND_RETURN", "IN_NLZ_SECOND_RETURN", second, expected[name][1])):
                six = np.zeros(image.shape[:2] + (6,), np.float32)
                six[..., :3] = image[..., :3]
                six[image[..., 0] > 0, 3:6] = [p for p, _, _ in returns]
                arrays[f"{name}_RANGE_IMAGE_{suffix}"] = six
                arrays[f"{name}_{zone_key}"] = image[..., 3]
        np.savez(npz / f"{T0 + i * 100_000}.npz", **arrays)
    tfrecord = write_segment(directory / "segment-15.tfrecord", records)
    return tfrecord, npz, expectations
