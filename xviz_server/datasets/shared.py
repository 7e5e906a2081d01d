"""What the dataset kinds share: geometry and the colours of points.

The Earth's radius for local east-north-up offsets, the angles of a
rotation, the footprints of boxes, and colours of lidar returns by
reflectance (KITTI's converter's) or by intensity.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EARTH_RADIUS", "pose_angles", "footprints", "reflectance_colors", "intensity_colors"]

#: WGS 84's equatorial radius, metres (for east-north-up offsets of nearby positions).
EARTH_RADIUS = 6378137.0


def pose_angles(matrix: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (radians) of a rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(matrix[2, 0]))))
    roll = math.atan2(float(matrix[2, 1]), float(matrix[2, 2]))
    yaw = math.atan2(float(matrix[1, 0]), float(matrix[0, 0]))
    return roll, pitch, yaw


_DARK = np.array([40, 80, 200], np.float32)
_SPAN = np.array([255, 230, 60], np.float32) - _DARK


def intensity_colors(intensity: np.ndarray) -> np.ndarray:
    """uint8 RGBA colours of lidar returns by intensity: dim blue to bright yellow.

    Waymo intensities are mostly below 1 with a long tail; tanh compresses
    the tail.
    """
    level = np.tanh(np.maximum(intensity, 0, dtype=np.float32) * np.float32(2.0))
    colors = np.full((len(level), 4), 255, np.uint8)
    for channel in range(3):  # a channel at a time, in float32: a few times faster than (N, 4) float64
        colors[:, channel] = _DARK[channel] + _SPAN[channel] * level
    return colors


def footprints(centers: np.ndarray, yaws: np.ndarray, lengths: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """The four ground corners of each box, (N, 4, 3), rotated by its yaw about its centre.

    ``centers`` are (N, 3) box bottoms; the length lies along x before
    rotation. Corners run counter-clockwise from front left.
    """
    half = np.stack([lengths / 2, widths / 2], axis=1)
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
    local = signs[None, :, :] * half[:, None, :]  # (N, 4, 2)
    cos, sin = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    x = cos * local[..., 0] - sin * local[..., 1] + centers[:, None, 0]
    y = sin * local[..., 0] + cos * local[..., 1] + centers[:, None, 1]
    z = np.broadcast_to(centers[:, None, 2], x.shape)
    return np.stack([x, y, z], axis=-1)


_COLOR_CHANNELS = ((80.0, 80.0), (80.0, 0.0), (60.0, 0.0))  # red, green, blue: (scale, offset)


def reflectance_colors(reflectance: np.ndarray) -> np.ndarray:
    """The official converter's colour of each point, uint8 (N, 3), from its reflectance.

    ``(80 + 80 r, 80 r, 60 r)`` with ``r = min(reflectance, 3)``, in double
    precision from the float32 values, stored as a JavaScript ``Uint8Array``
    stores numbers (truncated, modulo 256): bit for bit what the converter
    wrote. KITTI reflectances are hundredths in float32, so the double
    arithmetic matters: ``float32(0.35) * 80`` is 27.9999995, green 27.
    """
    r = np.minimum(reflectance.astype(np.float64), 3.0)
    colors = np.empty((len(r), 3), dtype=np.uint8)
    for channel, (scale, offset) in enumerate(
        _COLOR_CHANNELS
    ):  # a channel at a time: faster than broadcasting over all three
        colors[:, channel] = (r * scale + offset).astype(np.int32)  # truncated; uint8 keeps it modulo 256
    return colors
