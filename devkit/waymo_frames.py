"""Synthetic Waymo ``Frame`` records for scripts/bench/datasets.py and the tests: range images, poses, cameras, labels.

Everything is built here from arrays with the protobuf runtime and written
with the TFRecord framing, CRCs included, as Waymo's files are.
"""

from __future__ import annotations

import io
import math
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from xviz_server.datasets.waymo import frame_pb2 as pb
from xviz_server.datasets.waymo.tfrecord import write_records


def matrix(array: np.ndarray, level: int = 6) -> bytes:
    """A float array as a zlib-compressed MatrixFloat, as ``range_image_compressed`` holds it."""
    message = pb.MatrixFloat(data=np.ascontiguousarray(array, dtype="<f4").tobytes())
    message.shape.dims.extend(array.shape)
    return zlib.compress(message.SerializeToString(), level)


def transform(values: np.ndarray) -> pb.Transform:
    return pb.Transform(transform=np.asarray(values, dtype=np.float64).reshape(16).tolist())


def pose_matrix(yaw: float, translation: Sequence[float], roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """(4, 4) transform with rotation Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    matrix4 = np.eye(4)
    matrix4[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    matrix4[:3, 3] = translation
    return matrix4


def calibration(
    laser: str, extrinsic: np.ndarray, beams: Sequence[float] = (), low: float = 0.0, high: float = 0.0
) -> pb.LaserCalibration:
    return pb.LaserCalibration(
        name=laser,
        beam_inclinations=list(beams),
        beam_inclination_min=low,
        beam_inclination_max=high,
        extrinsic=transform(extrinsic),
    )


def jpeg_image(width: int, height: int, color: tuple[int, int, int]) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (width, height), color).save(out, format="JPEG", quality=95)
    return out.getvalue()


def frame(
    micros: int,
    pose: np.ndarray,
    calibrations: Sequence[pb.LaserCalibration],
    lasers: dict[str, tuple[np.ndarray, np.ndarray | None, np.ndarray | None]] | None = None,
    images: dict[str, bytes] | None = None,
    labels: Sequence[tuple[Sequence[float], int, str]] = (),
) -> pb.Frame:
    """A Frame: ``lasers`` maps a laser to its first return, second return and pixel pose (H, W, 4/6)."""
    message = pb.Frame(timestamp_micros=micros, pose=transform(pose))
    message.context.name = "test-segment"
    message.context.laser_calibrations.extend(calibrations)
    for name, (first, second, pixel_pose) in (lasers or {}).items():
        laser = message.lasers.add(name=name)
        laser.ri_return1.range_image_compressed = matrix(first)
        if pixel_pose is not None:
            laser.ri_return1.range_image_pose_compressed = matrix(pixel_pose)
        if second is not None:
            laser.ri_return2.range_image_compressed = matrix(second)
    for name, data in (images or {}).items():
        message.images.add(name=name, image=data)
    for (x, y, z, length, width, height, heading), kind, object_id in labels:
        label = message.laser_labels.add(type=kind, id=object_id)
        label.box.center_x, label.box.center_y, label.box.center_z = x, y, z
        label.box.length, label.box.width, label.box.height, label.box.heading = length, width, height, heading
    return message


def write_segment(path: Path, frames: Sequence[pb.Frame]) -> Path:
    write_records(path, [f.SerializeToString() for f in frames])
    return path


def real_size_frame(
    micros: int,
    rng: np.random.Generator,
    cameras: dict[str, bytes],
    returns_top: tuple[float, float],
    returns_short: tuple[float, float],
) -> pb.Frame:
    """A frame at the sizes of the real data: a 64 x 2650 TOP range image with pixel poses,
    four 200 x 600 short-range ones, the given camera images, 60 labels.

    ``returns_top`` and ``returns_short`` are the shares of the pixels with a
    first and a second return, for the TOP and the short-range lidars.
    """
    calibrations, lasers = [], {}
    for name, (height, width) in {
        "TOP": (64, 2650),
        "FRONT": (200, 600),
        "SIDE_LEFT": (200, 600),
        "SIDE_RIGHT": (200, 600),
        "REAR": (200, 600),
    }.items():
        calibrations.append(
            calibration(
                name,
                pose_matrix(0.1, (1.0, 0.0, 2.0)),
                np.linspace(-0.3, 0.04, height).tolist() if name == "TOP" else [],
                -1.5,
                0.5,
            )
        )
        returns: list[Any] = []
        for share in returns_top if name == "TOP" else returns_short:
            image = np.zeros((height, width, 4), np.float32)
            hit = rng.uniform(size=(height, width)) < share
            image[..., 0] = np.where(hit, np.round(rng.uniform(2, 75, (height, width)) / 0.0058) * 0.0058, -1)
            image[..., 1] = np.where(hit, rng.uniform(0, 1, (height, width)), 0)
            image[..., 3] = -1
            returns.append(image)
        pixel_pose = None
        if name == "TOP":
            pixel_pose = np.zeros((height, width, 6), np.float32)
            pixel_pose[..., 2] = np.linspace(0.0, 0.01, width)
            pixel_pose[..., 3] = 5000.0 + np.linspace(0.0, 1.0, width)
            pixel_pose[..., 4] = -3000.0
        lasers[name] = (returns[0], returns[1], pixel_pose)
    labels = [
        ((float(x), float(y), 1.0, 4.0, 2.0, 1.6, 0.3), 1, f"obj-{k}")
        for k, (x, y) in enumerate(rng.uniform(-40, 40, (60, 2)))
    ]
    return frame(micros, pose_matrix(0.0, (5000.0, -3000.0, 0.0)), calibrations, lasers, cameras, labels)
