"""Rigid transforms of ROS messages as 4x4 matrices, their interpolation, and local east-north-up metres."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..shared import EARTH_RADIUS, pose_angles

__all__ = [
    "IDENTITY",
    "matrix",
    "from_quaternion",
    "from_pose",
    "from_transform",
    "interpolate",
    "rpy",
    "quaternion",
    "enu",
    "apply",
]

IDENTITY = np.eye(4)


def _rotation(x: float, y: float, z: float, w: float) -> np.ndarray:
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not norm or not math.isfinite(norm):
        return np.eye(3)  # an unset quaternion (all zeros) is taken as no rotation, as rviz does
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix(translation: Any, rotation: Any) -> np.ndarray:
    """The 4x4 transform of a translation (``.x .y .z``) and a quaternion (``.x .y .z .w``)."""
    result = np.eye(4)
    result[:3, :3] = _rotation(rotation.x, rotation.y, rotation.z, rotation.w)
    result[:3, 3] = (translation.x, translation.y, translation.z)
    return result


def from_quaternion(rotation: Any) -> np.ndarray:
    """The 4x4 transform of a quaternion (``.x .y .z .w``) alone."""
    result = np.eye(4)
    result[:3, :3] = _rotation(rotation.x, rotation.y, rotation.z, rotation.w)
    return result


def from_pose(pose: Any) -> np.ndarray:
    """A ``geometry_msgs/Pose`` as a 4x4 transform."""
    return matrix(pose.position, pose.orientation)


def from_transform(transform: Any) -> np.ndarray:
    """A ``geometry_msgs/Transform`` as a 4x4 transform."""
    return matrix(transform.translation, transform.rotation)


def quaternion(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a 3x3 rotation, w >= 0."""
    m = rotation
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    q = np.array([x, y, z, w])
    return q / np.linalg.norm(q)


def interpolate(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray:
    """The transform ``fraction`` of the way from ``a`` to ``b``: translation linear, rotation slerp."""
    if fraction <= 0:
        return a
    if fraction >= 1:
        return b
    qa, qb = quaternion(a[:3, :3]), quaternion(b[:3, :3])
    dot = float(qa @ qb)
    if dot < 0:
        qb, dot = -qb, -dot
    if dot > 0.9995:
        q = qa + fraction * (qb - qa)
    else:
        angle = math.acos(dot)
        q = (math.sin((1 - fraction) * angle) * qa + math.sin(fraction * angle) * qb) / math.sin(angle)
    result = np.eye(4)
    result[:3, :3] = _rotation(*q)
    result[:3, 3] = a[:3, 3] + fraction * (b[:3, 3] - a[:3, 3])
    return result


def rpy(transform: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (radians) of a transform's rotation, as XVIZ poses carry them."""
    return pose_angles(transform[:3, :3])


def enu(latitude: float, longitude: float, altitude: float, origin: tuple[float, float, float]) -> np.ndarray:
    """East, north, up metres of a fix from ``origin`` (latitude, longitude, altitude), on the local tangent plane.

    The same flat-earth approximation the KITTI converter's trajectory uses.
    """
    lat0, lon0, alt0 = origin
    east = math.radians(longitude - lon0) * EARTH_RADIUS * math.cos(math.radians(lat0))
    north = math.radians(latitude - lat0) * EARTH_RADIUS
    return np.array([east, north, altitude - alt0])


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) points moved by a 4x4 transform, float32."""
    return (points @ transform[:3, :3].T.astype(np.float32) + transform[:3, 3].astype(np.float32)).astype(
        np.float32, copy=False
    )
