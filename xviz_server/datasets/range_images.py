"""Waymo lidar range images to points in the vehicle frame.

A range image has one row per beam and one column per azimuth step. The
conventions are those of the Waymo Open Dataset:

* row 0 is the highest beam: the row pitches are the calibration's
  ``beam_inclinations`` (lowest first) reversed or, for uniform beams,
  ``H`` pitches spread evenly between ``beam_inclination_min`` and
  ``beam_inclination_max``, each at the centre of its interval;
* column ``c`` of ``W`` looks at azimuth
  ``((W - c - 0.5) / W * 2 - 1) * pi - atan2(E[1, 0], E[0, 0])`` in the
  lidar frame, ``E`` being the lidar-to-vehicle extrinsic: column 0 looks
  backwards on the left, the middle column forwards;
* a return at range ``r`` is at ``r * (cos a cos i, sin a cos i, sin i)`` in
  the lidar frame, and at ``E`` applied to that in the vehicle frame.

Where the range image comes with a per-pixel pose (the vehicle-to-world pose
at the time each pixel was measured, as roll, pitch, yaw, x, y, z: the TOP
lidar's), each point is moved to the world with its pixel's pose and back
to the vehicle frame of the frame's own pose, which removes the distortion
of the vehicle moving during the sweep.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = ["row_inclinations", "column_azimuths", "ray_directions", "to_frame_vehicle"]


def row_inclinations(beams: Sequence[float], low: float, high: float, height: int) -> np.ndarray:
    """The pitch (radians) of every row, row 0 first; ``beams`` may be empty for uniform beams."""
    if len(beams):
        return np.asarray(beams, dtype=np.float64)[::-1]
    return (low + (np.arange(height) + 0.5) / height * (high - low))[::-1]


def column_azimuths(extrinsic: np.ndarray, width: int) -> np.ndarray:
    """The azimuth (radians, lidar frame) of every column."""
    correction = math.atan2(extrinsic[1, 0], extrinsic[0, 0])
    return ((width - np.arange(width) - 0.5) / width * 2 - 1) * math.pi - correction


def ray_directions(inclinations: np.ndarray, azimuths: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 unit direction of every pixel, turned by ``rotation`` (lidar to vehicle)."""
    cos_i, sin_i = np.cos(inclinations)[:, None], np.sin(inclinations)[:, None]
    rays = np.stack(
        np.broadcast_arrays(np.cos(azimuths) * cos_i, np.sin(azimuths) * cos_i, sin_i), axis=-1
    )
    return (rays @ rotation.T).astype(np.float32)


def to_frame_vehicle(points: np.ndarray, pixel_poses: np.ndarray, frame_pose: np.ndarray) -> np.ndarray:
    """Points in the vehicle frame of their pixels' poses, (N, 3), to that of ``frame_pose``.

    ``pixel_poses`` is (N, 6): roll, pitch, yaw, x, y, z of each point's
    vehicle-to-world pose, whose rotation is Rz(yaw) Ry(pitch) Rx(roll);
    ``frame_pose`` the frame's (4, 4) vehicle-to-world transform. The world
    positions are only ever subtracted from each other, in float64, so the
    rest is computed in float32 without losing precision far from the
    world's origin.
    """
    x, y, z = points.T
    roll, pitch, yaw = (pixel_poses[:, i] for i in range(3))
    cos, sin = np.cos(roll), np.sin(roll)
    y, z = cos * y - sin * z, sin * y + cos * z
    cos, sin = np.cos(pitch), np.sin(pitch)
    x, z = cos * x + sin * z, cos * z - sin * x
    cos, sin = np.cos(yaw), np.sin(yaw)
    x, y = cos * x - sin * y, sin * x + cos * y
    shift = (pixel_poses[:, 3:6] - frame_pose[:3, 3]).astype(np.float32)
    x, y, z = x + shift[:, 0], y + shift[:, 1], z + shift[:, 2]
    # The inverse rotation, R^T, spelled out: numpy's (N, 3) @ (3, 3) is many times slower.
    rotation = frame_pose[:3, :3].astype(np.float32)
    return np.stack([x * rotation[0, j] + y * rotation[1, j] + z * rotation[2, j] for j in range(3)], axis=1)
