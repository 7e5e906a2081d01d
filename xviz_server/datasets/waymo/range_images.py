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
from collections.abc import Sequence

import numpy as np

__all__ = [
    "row_inclinations",
    "column_azimuths",
    "ray_directions",
    "frame_rays",
    "calibration_rays",
    "range_points",
    "join_points",
]


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
    rays = np.stack(np.broadcast_arrays(np.cos(azimuths) * cos_i, np.sin(azimuths) * cos_i, sin_i), axis=-1)
    return (rays @ rotation.T).astype(np.float32)


def frame_rays(
    directions: np.ndarray, origin: np.ndarray, pixel_poses: np.ndarray, frame_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """The rays of a lidar that moved during its sweep, in the vehicle frame of ``frame_pose``.

    ``directions`` (H * W, 3) and ``origin`` (3,) are the pixels' directions
    and the lidar's position in the vehicle frame of each pixel's own pose;
    ``pixel_poses`` (H, W, 6) are those poses, as roll, pitch, yaw, x, y, z
    of the vehicle-to-world transform, whose rotation is Rz(yaw) Ry(pitch)
    Rx(roll); ``frame_pose`` is the frame's (4, 4) vehicle-to-world
    transform. Returns the pixels' directions (H * W, 3), their origins
    (K, 3) and the period K: pixel ``n`` starts at ``origins[n % K]``.

    When every row of a column has the same pose, as the columns of a
    spinning lidar do, the origins are per column (K = W) and the pose
    arithmetic is done once per column; else per pixel (K = H * W). World
    positions are only ever subtracted from each other, in float64, so the
    results are float32 without losing precision far from the world's
    origin.
    """
    height, width = pixel_poses.shape[:2]
    per_column = bool((pixel_poses == pixel_poses[:1]).all())
    poses = (pixel_poses[0] if per_column else pixel_poses.reshape(-1, 6)).astype(np.float64)
    roll, pitch, yaw = poses[:, 0], poses[:, 1], poses[:, 2]
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    pixel_rotations = np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )  # (K, 3, 3)
    to_frame = frame_pose[:3, :3].T
    rotations = (to_frame @ pixel_rotations).astype(np.float32)  # pixel's vehicle frame -> frame's
    shifts = (poses[:, 3:6] - frame_pose[:3, 3]) @ to_frame.T
    origins = (rotations @ origin + shifts).astype(np.float32)
    if per_column:
        turned = np.einsum("cij,hcj->hci", rotations, directions.reshape(height, width, 3), optimize=True).reshape(
            -1, 3
        )
    else:
        turned = np.einsum("nij,nj->ni", rotations, directions, optimize=True)
    return turned, origins, len(origins)


def calibration_rays(
    extrinsic: np.ndarray,
    beams: Sequence[float],
    low: float,
    high: float,
    height: int,
    width: int,
    where: str,
) -> tuple[np.ndarray, np.ndarray]:
    """(H * W, 3) pixel directions in the vehicle frame and the lidar's position, from a lidar's calibration.

    ``extrinsic`` is the (4, 4) lidar-to-vehicle transform; ``beams`` the
    listed beam inclinations (lowest first, or empty for uniform beams
    between ``low`` and ``high``). Raises :class:`ValueError` naming
    ``where`` when the beams do not fit the range image's rows.
    """
    if len(beams) not in (0, height):
        raise ValueError(f"{where}: {len(beams)} beam inclinations for {height} rows")
    inclinations = row_inclinations(beams, low, high, height)
    directions = ray_directions(inclinations, column_azimuths(extrinsic, width), extrinsic[:3, :3])
    return directions.reshape(-1, 3), extrinsic[:3, 3].astype(np.float32)


def range_points(
    directions: np.ndarray,
    origins: np.ndarray,
    period: int,
    returns: Sequence[np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points of a lidar's returns: (N, 3) float32 in the vehicle frame, (N,) intensities, (N,) no-label-zone flags.

    ``returns`` are range images (H, W, >= 4: range, intensity, elongation,
    in no-label zone) sharing the pixels' ``directions`` (H * W, 3) and
    ``origins`` (K, 3), pixel ``n`` starting at ``origins[n % period]`` (see
    :func:`frame_rays`). Returns with range <= 0 are left out.
    """
    parts = []
    for image in returns:
        channels = image.reshape(-1, image.shape[2])
        valid = np.flatnonzero(channels[:, 0] > 0)
        xyz = directions.take(valid, axis=0)  # take: a few times faster than fancy indexing
        xyz *= channels[:, 0].take(valid)[:, None]
        xyz += origins[0] if period == 1 else origins.take(valid % period, axis=0)
        parts.append((xyz, channels[:, 1].take(valid), channels[:, 3].take(valid) > 0))
    return join_points(parts)


def join_points(
    parts: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points, intensities and flags of several :func:`range_points` as one of each (empty if none)."""
    if not parts:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, dtype=bool)
    return tuple(np.concatenate(arrays) for arrays in zip(*parts))  # type: ignore[return-value]
