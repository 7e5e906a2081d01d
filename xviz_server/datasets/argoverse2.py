"""Argoverse 2 sensor logs to XVIZ: every lidar sweep and every camera image at its own time.

A log is a folder named by its id, in the layout of the Argoverse 2 sensor
dataset (its devkit, ``av2``, documents it):

* ``sensors/lidar/{timestamp_ns}.feather``: a sweep (10 Hz) in the vehicle
  frame: columns ``x``, ``y``, ``z`` (metres, float16), ``intensity`` (uint8),
  ``laser_number``, ``offset_ns``;
* ``sensors/cameras/{camera}/{timestamp_ns}.jpg``: the seven ring cameras
  (``ring_front_center``, ...) and two stereo cameras, 20 Hz;
* ``city_SE3_egovehicle.feather``: the vehicle's pose in the city frame over
  time: ``timestamp_ns``, the rotation ``qw``, ``qx``, ``qy``, ``qz`` and the
  translation ``tx_m``, ``ty_m``, ``tz_m``;
* ``annotations.feather`` (not in the test split): cuboids at the sweeps'
  times, in the vehicle frame of their sweep: ``timestamp_ns``,
  ``track_uuid``, ``category`` (``REGULAR_VEHICLE``, ``PEDESTRIAN``, ...),
  ``length_m``, ``width_m``, ``height_m``, the rotation and translation as in
  the poses.

The frame clock is every sweep and every image of the front ring camera
(20 Hz); each other image is served in the first frame at or after its time,
and one that would share a frame with another of its camera, or comes after
the last, is a frame of its own: every image is served. A frame's pose is the pose at or before its time; its boxes those of the
latest sweep, moved into the frame's vehicle frame.

A log is read from a folder or from an object store (``s3://``, a listing of
its keys, each file one GET). Files larger than :data:`MAX_FILE_BYTES` are
refused before they are read; a missing or corrupt sweep or image is an error
naming its file, and the rest of the log is served.
"""

from __future__ import annotations

import bisect
import io
from functools import cached_property
from pathlib import Path

import numpy as np

from ..exceptions import DatasetError
from ..store.path import StoreTree
from ..unpack import check_frame
from . import DEFAULT_IMAGE_WIDTH, require
from .images import scale_jpegs
from .sensors import (
    SensorFrame,
    SensorLog,
    captures_by_frame,
    check_points,
    columns_of,
    file_size,
    frame_clock,
    quaternion_matrix,
    to_vehicle,
    yaw_of,
)
from .waymo.log import ScaledImages

__all__ = ["Argoverse2Log", "is_argoverse2_log", "MAX_FILE_BYTES", "CAMERAS"]

#: The largest file read (a sweep is about 1 MB, a ring camera's image about 1.5 MB).
MAX_FILE_BYTES = 64 << 20
#: The cameras, in the order their panel shows them; the first is the frame clock's.
CAMERAS = (
    "ring_front_center",
    "ring_front_left",
    "ring_front_right",
    "ring_side_left",
    "ring_side_right",
    "ring_rear_left",
    "ring_rear_right",
    "stereo_front_left",
    "stereo_front_right",
)
_POSE = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
_BOX = ("tx_m", "ty_m", "tz_m", "length_m", "width_m", "height_m")

Where = Path | StoreTree


def is_argoverse2_log(path: Where) -> bool:
    """Whether ``path`` is an Argoverse 2 sensor log: ``city_SE3_egovehicle.feather`` beside ``sensors/lidar``."""
    return (path / "city_SE3_egovehicle.feather").is_file() and (path / "sensors" / "lidar").is_dir()


def _stamps(folder: Where, suffix: str) -> list[tuple[int, Where]]:
    """The files ``{timestamp_ns}{suffix}`` of a folder, in time order."""
    if not folder.is_dir():
        return []
    found = [
        (int(file.name[: -len(suffix)]), file)
        for file in folder.glob(f"*{suffix}")
        if file.name.endswith(suffix) and file.name[: -len(suffix)].isdigit()
    ]
    return sorted(found, key=lambda item: item[0])


class Argoverse2Log(SensorLog):
    """An Argoverse 2 sensor log folder, in a directory or a store, named by its folder (the log id)."""

    path: Path | StoreTree  # type: ignore[assignment]

    def __init__(self, path: Where, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        self.path = path if isinstance(path, StoreTree) else Path(path)
        self.name = self.path.name
        self.image_max_width = image_max_width
        self.source = f"Argoverse 2 log {self.name}"
        if not is_argoverse2_log(self.path):
            raise DatasetError(
                f"{self.path}: not an Argoverse 2 log (no city_SE3_egovehicle.feather beside sensors/lidar)",
                path=self.path,
            )
        self._sweeps = _stamps(self.path / "sensors" / "lidar", ".feather")
        if not self._sweeps:
            raise DatasetError(f"{self.path}: no lidar sweep in sensors/lidar", path=self.path)
        self._images = {
            camera: images
            for camera in CAMERAS
            if (images := _stamps(self.path / "sensors" / "cameras" / camera, ".jpg"))
        }
        self.cameras = list(self._images)

    def _table(self, file: Where, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
        """The columns of a Feather file as arrays; a :class:`DatasetError` naming the file if it lacks one."""
        feather = require("pyarrow.feather", "Argoverse 2 logs", "parquet")
        data = self._bytes(file)
        try:
            table = feather.read_table(io.BytesIO(data))
        except (OSError, ValueError) as exc:  # pyarrow's errors derive from these
            raise DatasetError(f"{file}: not a Feather file: {exc}", path=file) from None
        return dict(zip(columns, columns_of(table, columns, file)))

    def _bytes(self, file: Where) -> bytes:
        try:
            size = file_size(file)
            if size > MAX_FILE_BYTES:
                raise DatasetError(f"{file}: {size} bytes, more than the {MAX_FILE_BYTES} a file may have", path=file)
            return file.read_bytes()
        except (OSError, KeyError) as exc:
            raise DatasetError(f"{file}: cannot read: {exc}", path=file) from None

    @cached_property
    def _clock(self) -> list[int]:
        """The frames' times (nanoseconds): every sweep, every image of the first camera, and the other images that
        need a frame of their own (see :func:`~xviz_server.datasets.sensors.frame_clock`)."""
        first = self._images.get(self.cameras[0], []) if self.cameras else []
        base = [stamp for stamp, _ in self._sweeps] + [stamp for stamp, _ in first]
        return frame_clock(base, {camera: [stamp for stamp, _ in images] for camera, images in self._images.items()})

    @property
    def times(self) -> np.ndarray:
        return np.array(self._clock, dtype=np.float64) / 1e9

    @cached_property
    def _frames(self) -> list[dict[str, Where]]:
        """Per frame, its sweep (``lidar``) if it has one, and the image of each camera served in it."""
        return captures_by_frame(self._clock, {"lidar": self._sweeps, **self._images})

    @cached_property
    def _poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose table's times (ns) and (N, 4, 4) vehicle-to-city transforms, in time order."""
        file = self.path / "city_SE3_egovehicle.feather"
        table = self._table(file, ("timestamp_ns", *_POSE))
        order = np.argsort(table["timestamp_ns"], kind="stable")
        return table["timestamp_ns"][order].astype(np.int64), np.stack(
            [self._transform(row, file) for row in np.column_stack([table[c] for c in _POSE])[order]]
        )

    def _transform(self, row: np.ndarray, file: Where) -> np.ndarray:
        matrix = np.eye(4)
        try:
            matrix[:3, :3] = quaternion_matrix(*row[:4])
        except ValueError as exc:
            raise DatasetError(f"{file}: {exc}", path=file) from None
        matrix[:3, 3] = row[4:7]
        return matrix

    def _pose_at(self, stamp: int) -> np.ndarray:
        times, poses = self._poses
        if not len(times):
            raise DatasetError(f"{self.path}: city_SE3_egovehicle.feather has no pose", path=self.path)
        return poses[max(int(np.searchsorted(times, stamp, side="right")) - 1, 0)]

    def pose(self, index: int) -> np.ndarray:
        return self._pose_at(self._clock[index])

    def read(self, index: int) -> SensorFrame:
        stamp, captures = self._clock[index], self._frames[index]
        check_frame(sum(file_size(file) for file in captures.values()), index, str(self.path), self.path)
        images = {camera: self._bytes(file) for camera, file in captures.items() if camera != "lidar"}
        scaling = scale_jpegs(images, self.image_max_width)  # beside the lidar work
        pose = self._pose_at(stamp)
        points, intensity = (
            self._sweep(captures["lidar"])
            if "lidar" in captures
            else (np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
        )
        boxes, categories, ids = self._boxes(stamp, pose)
        return SensorFrame(
            stamp / 1e9,
            pose,
            points,
            intensity,
            ScaledImages(scaling, f"{self.path}: frame {stamp}", self.path),
            boxes,
            categories,
            ids,
        )

    def _sweep(self, file: Where) -> tuple[np.ndarray, np.ndarray]:
        table = self._table(file, ("x", "y", "z", "intensity"))
        points = check_points(
            np.column_stack([table["x"], table["y"], table["z"]]).astype(np.float32), str(file), self.path
        )
        return points, table["intensity"].astype(np.float32) / np.float32(255)

    @cached_property
    def _annotations(self) -> tuple[list[int], dict[int, tuple[np.ndarray, list[str], list[str]]]]:
        """The annotated sweeps' times, and each one's boxes (vehicle frame of its sweep), categories and tracks."""
        file = self.path / "annotations.feather"
        if not file.is_file():
            return [], {}
        table = self._table(file, ("timestamp_ns", "track_uuid", "category", *_BOX, "qw", "qx", "qy", "qz"))
        by_time: dict[int, tuple[np.ndarray, list[str], list[str]]] = {}
        for stamp in sorted(set(table["timestamp_ns"].tolist())):
            rows = np.flatnonzero(table["timestamp_ns"] == stamp)
            yaws = []
            for row in rows:
                try:
                    yaws.append(yaw_of(quaternion_matrix(*(float(table[c][row]) for c in ("qw", "qx", "qy", "qz")))))
                except ValueError as exc:
                    raise DatasetError(f"{file}: row {row}: {exc}", path=file) from None
            boxes = np.column_stack([np.asarray(table[c][rows], dtype=np.float64) for c in _BOX] + [np.array(yaws)])
            by_time[int(stamp)] = (
                boxes,
                [str(c) for c in table["category"][rows]],
                [str(t)[:8] for t in table["track_uuid"][rows]],
            )
        return sorted(by_time), by_time

    def _boxes(self, stamp: int, pose: np.ndarray) -> tuple[np.ndarray, list[str], list[str]]:
        times, by_time = self._annotations
        if not times:
            return np.zeros((0, 7)), [], []
        when = times[max(bisect.bisect_right(times, stamp) - 1, 0)]
        boxes, categories, ids = by_time[when]
        if when != stamp:  # the latest sweep's boxes, moved into this frame's vehicle frame
            then = self._pose_at(when)
            centers = boxes[:, :3] @ then[:3, :3].T + then[:3, 3]
            moved, yaws = to_vehicle(pose, centers, boxes[:, 6] + yaw_of(then[:3, :3]))
            boxes = np.column_stack([moved, boxes[:, 3:6], yaws])
        return boxes, categories, ids
