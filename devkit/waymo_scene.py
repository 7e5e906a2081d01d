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
    local = np.array(
        [math.cos(azimuth) * math.cos(inclination), math.sin(azimuth) * math.cos(inclination), math.sin(inclination)]
    )
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


def pixel_angles(
    height: int, width: int, extrinsic: np.ndarray, beams: list[float] | None, low: float = 0, high: float = 0
) -> tuple[list[float], list[float]]:
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


LABELS = [
    ((10.0, 5.0, 1.0, 4.0, 2.0, 1.6, math.radians(30)), 1, "car-a"),
    ((3.0, -2.0, 0.9, 0.8, 0.6, 1.8, 0.0), 2, "ped-b"),
]


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

        arrays = {
            "POSE": pose.astype(np.float32),
            "FRONT_IMAGE": np.asarray(Image.open(io.BytesIO(camera)).convert("RGB")),
            "LABEL_BOXES": np.array([box for box, _, _ in LABELS]),
            "LABEL_TYPES": np.array([k for _, k, _ in LABELS]),
            "LABEL_IDS": np.array([n for _, _, n in LABELS]),
        }
        for name, (first, second, _) in lasers.items():
            for suffix, zone_key, image, returns in (
                ("FIRST_RETURN", "IN_NLZ", first, expected[name][0]),
                ("SECOND_RETURN", "IN_NLZ_SECOND_RETURN", second, expected[name][1]),
            ):
                six = np.zeros(image.shape[:2] + (6,), np.float32)
                six[..., :3] = image[..., :3]
                six[image[..., 0] > 0, 3:6] = [p for p, _, _ in returns]
                arrays[f"{name}_RANGE_IMAGE_{suffix}"] = six
                arrays[f"{name}_{zone_key}"] = image[..., 3]
        np.savez(npz / f"{T0 + i * 100_000}.npz", **arrays)
    tfrecord = write_segment(directory / "segment-15.tfrecord", records)
    return tfrecord, npz, expectations


def write_v2_scene(directory: Path, frames: int = 3, rows_move: bool = False, segment: str = "15_000_020_000") -> Path:
    """The frames of :func:`write_scene` as a Waymo v2 segment: a Parquet file per component, in Waymo's columns.

    Returns the segment's ``vehicle_pose`` file. The columns and their types
    are those of Waymo's v2 files (``key.*`` and ``[Component].field``,
    flat); rows are written in Waymo's order, a frame's lasers and cameras
    together.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    rng = np.random.default_rng(15)  # the draws of write_scene, in its order: the same frames
    camera = jpeg_image(64, 48, (200, 30, 30))
    names = {"TOP": 1, "FRONT": 2}
    extrinsics = {"TOP": (TOP_EXTRINSIC, TOP_BEAMS, 0.0, 0.0), "FRONT": (FRONT_EXTRINSIC, [], -1.2, 0.4)}
    tables: dict[str, dict[str, list]] = {
        part: {} for part in ("vehicle_pose", "lidar", "lidar_pose", "lidar_calibration", "camera_image", "lidar_box")
    }

    def row(part: str, **values: object) -> None:
        for column, value in {"key.segment_context_name": segment, **values}.items():
            tables[part].setdefault(column, []).append(value)

    for i in range(frames):
        micros = T0 + i * 100_000
        pose, lasers, _ = scene_frame(i, rng, rows_move)
        row(
            "vehicle_pose",
            **{
                "key.frame_timestamp_micros": micros,
                "[VehiclePoseComponent].world_from_vehicle.transform": pose.reshape(16).tolist(),
            },
        )
        for name, (first, second, pixel_pose) in lasers.items():
            row(
                "lidar",
                **{
                    "key.frame_timestamp_micros": micros,
                    "key.laser_name": names[name],
                    "[LiDARComponent].range_image_return1.values": first.reshape(-1).tolist(),
                    "[LiDARComponent].range_image_return1.shape": list(first.shape),
                    "[LiDARComponent].range_image_return2.values": second.reshape(-1).tolist(),
                    "[LiDARComponent].range_image_return2.shape": list(second.shape),
                },
            )
            if pixel_pose is not None:
                row(
                    "lidar_pose",
                    **{
                        "key.frame_timestamp_micros": micros,
                        "key.laser_name": names[name],
                        "[LiDARPoseComponent].range_image_return1.values": pixel_pose.reshape(-1).tolist(),
                        "[LiDARPoseComponent].range_image_return1.shape": list(pixel_pose.shape),
                    },
                )
        row(
            "camera_image",
            **{"key.frame_timestamp_micros": micros, "key.camera_name": 1, "[CameraImageComponent].image": camera},
        )
        for (x, y, z, length, width, height, heading), kind, object_id in LABELS:
            row(
                "lidar_box",
                **{
                    "key.frame_timestamp_micros": micros,
                    "key.laser_object_id": object_id,
                    "[LiDARBoxComponent].box.center.x": x,
                    "[LiDARBoxComponent].box.center.y": y,
                    "[LiDARBoxComponent].box.center.z": z,
                    "[LiDARBoxComponent].box.size.x": length,
                    "[LiDARBoxComponent].box.size.y": width,
                    "[LiDARBoxComponent].box.size.z": height,
                    "[LiDARBoxComponent].box.heading": heading,
                    "[LiDARBoxComponent].type": kind,
                },
            )
    for name, (extrinsic, beams, low, high) in extrinsics.items():
        row(
            "lidar_calibration",
            **{
                "key.laser_name": names[name],
                "[LiDARCalibrationComponent].extrinsic.transform": extrinsic.reshape(16).tolist(),
                "[LiDARCalibrationComponent].beam_inclination.values": list(beams) or None,
                "[LiDARCalibrationComponent].beam_inclination.min": low,
                "[LiDARCalibrationComponent].beam_inclination.max": high,
            },
        )
    types = {
        "key.laser_name": pa.int8(),
        "key.camera_name": pa.int8(),
        "[LiDARBoxComponent].type": pa.int8(),
        "key.frame_timestamp_micros": pa.int64(),
    }
    for part, columns in tables.items():
        fields = []
        for column, values in columns.items():
            arrow_type: pa.DataType | None
            if column in types:
                arrow_type = types[column]
            elif column.endswith(".shape"):
                arrow_type = pa.list_(pa.int32())
            elif column.endswith(".values") and not column.startswith("[LiDARCalibration"):
                arrow_type = pa.list_(pa.float32())
            else:
                arrow_type = None
            fields.append(pa.array(values, type=arrow_type))
        folder = directory / part
        folder.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(dict(zip(columns, fields))), folder / f"{segment}.parquet")
    return directory / "vehicle_pose" / f"{segment}.parquet"
