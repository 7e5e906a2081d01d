"""nuScenes scenes to XVIZ: every lidar sweep a frame, every camera image in the frame of its time.

A nuScenes root holds its tables in a version folder (``v1.0-mini``,
``v1.0-trainval``, ...) beside ``samples/`` (key frames, 2 Hz) and ``sweeps/``
(the sensors' other captures: lidar at 20 Hz, cameras at 12 Hz). The tables
read, as the devkit documents them:

* ``scene``: ``name`` (``scene-0061``), ``first_sample_token``, ``description``;
* ``sample``: the key frames, ``scene_token``, ``timestamp`` (microseconds);
* ``sample_data``: every capture, key frame or sweep: ``sample_token``,
  ``ego_pose_token``, ``calibrated_sensor_token``, ``timestamp``,
  ``filename`` (below the root), ``is_key_frame``;
* ``ego_pose``: ``translation`` and ``rotation`` (quaternion w, x, y, z) of the
  vehicle in the world at a capture;
* ``calibrated_sensor`` and ``sensor``: each sensor's ``translation`` and
  ``rotation`` on the vehicle, its ``channel`` (``LIDAR_TOP``, ``CAM_FRONT``,
  ...) and ``modality``;
* ``sample_annotation``, ``instance``, ``category``: each key frame's boxes
  (``translation`` of the centre and ``rotation`` in the world, ``size`` as
  width, length, height), their track (instance) and category name.

Frames are the ``LIDAR_TOP`` captures, key frames and sweeps alike, each at its
own time with its own ego pose; its points (``.pcd.bin``: float32 x, y, z,
intensity, ring) turned into the vehicle frame by the sensor's calibration. A
camera image is served in the first frame at or after its time; an image that
would share a frame with another of its camera, or comes after the last sweep,
is a frame of its own (without points): every image of the scene is served. Boxes are the key frames' annotations; between two key frames each
object seen in both is interpolated to the sweep's time (as the devkit's
``get_boxes`` does), the others kept from the nearer key frame.

A root holds many scenes: each is a log of its own (option ``scene``, the
scene's name); a root holding one scene is that scene. Tables larger than
:data:`MAX_TABLE_BYTES` and sweeps larger than :data:`MAX_SWEEP_BYTES` are
refused by name before they are read; a missing or corrupt sweep or image is an
error naming its file, and the rest of the scene is served.
"""

from __future__ import annotations

import bisect
import os
from collections import defaultdict
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from ..exceptions import DatasetError
from ..unpack import check_frame
from . import DEFAULT_IMAGE_WIDTH
from .images import scale_jpegs
from .sensors import (
    SensorFrame,
    SensorLog,
    check_points,
    file_size,
    frame_clock,
    frame_of,
    moved,
    quaternion_matrix,
    to_vehicle,
    yaw_of,
)
from .waymo.log import ScaledImages

__all__ = ["NuScenesScene", "is_nuscenes", "scenes", "MAX_TABLE_BYTES", "MAX_SWEEP_BYTES", "LIDAR"]

#: The largest table read (``sample_data.json`` of the full dataset is about 600 MB).
MAX_TABLE_BYTES = 2 << 30
#: The largest lidar sweep read (a sweep is about 35 000 points, 700 KB).
MAX_SWEEP_BYTES = 64 << 20
#: The channel whose captures are the frames.
LIDAR = "LIDAR_TOP"
#: The cameras, in the order their panel shows them.
CAMERAS = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT")
_TABLES = (
    "scene",
    "sample",
    "sample_data",
    "ego_pose",
    "calibrated_sensor",
    "sensor",
    "sample_annotation",
    "instance",
    "category",
)


def _versions(root: Path) -> list[Path]:
    """The version folders of a root (those holding ``scene.json``), in name order."""
    try:
        entries = sorted(os.scandir(root), key=lambda entry: entry.name)
    except OSError:
        return []
    return [
        Path(entry.path)
        for entry in entries
        if entry.name.startswith("v") and entry.is_dir() and os.path.isfile(os.path.join(entry.path, "scene.json"))
    ]


def is_nuscenes(path: Path) -> bool:
    """Whether ``path`` is a nuScenes root: a version folder with ``scene.json`` beside ``samples/``."""
    return path.is_dir() and (path / "samples").is_dir() and bool(_versions(path))


def _table(folder: Path, name: str) -> list[dict[str, Any]]:
    path = folder / f"{name}.json"
    try:
        size = path.stat().st_size
        if size > MAX_TABLE_BYTES:
            raise DatasetError(f"{path}: {size} bytes, more than the {MAX_TABLE_BYTES} a table may have", path=path)
        rows = orjson.loads(path.read_bytes())
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing: a nuScenes version folder has a {name}.json table", path=path) from None
    except (OSError, orjson.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: not a JSON table: {exc}", path=path) from None
    if not isinstance(rows, list) or not all(isinstance(row, dict) for row in rows):
        raise DatasetError(f"{path}: not a list of records", path=path)
    return rows


@lru_cache(maxsize=2)
def _tables(folder: Path, stamp: tuple[int, ...]) -> dict[str, dict[str, dict[str, Any]]]:
    """A version folder's tables, each by token; kept for the last two folders (``stamp``: their files' times)."""
    return {name: {row["token"]: row for row in _table(folder, name) if "token" in row} for name in _TABLES}


def _stamp(folder: Path) -> tuple[int, ...]:
    return tuple(
        (folder / f"{name}.json").stat().st_mtime_ns if (folder / f"{name}.json").exists() else 0 for name in _TABLES
    )


def scenes(path: Path) -> list[str]:
    """The names of the scenes of a root, in name order (reads only the ``scene`` tables)."""
    return sorted(str(row.get("name")) for folder in _versions(path) for row in _table(folder, "scene"))


def _field(row: dict[str, Any], field: str, table: str, folder: Path) -> Any:
    try:
        return row[field]
    except KeyError:
        raise DatasetError(
            f"{folder / table}.json: record {row.get('token')!r} has no {field!r}", path=folder
        ) from None


class NuScenesScene(SensorLog):
    """One scene of a nuScenes root, named ``scene`` (optional when the root holds one scene)."""

    def __init__(self, path: Path, image_max_width: int = DEFAULT_IMAGE_WIDTH, scene: str | None = None) -> None:
        self.path = self.root = Path(path)
        self.image_max_width = image_max_width
        versions = _versions(self.root)
        if not versions:
            raise DatasetError(f"{self.root}: not a nuScenes root (no version folder with scene.json)", path=self.root)
        found = [
            (folder, row)
            for folder in versions
            for row in _table(folder, "scene")
            if scene is None or row.get("name") == scene
        ]
        if len(found) != 1:
            names = [str(row.get("name")) for folder in versions for row in _table(folder, "scene")]
            why = f"no scene {scene!r}" if scene is not None else f"{len(names)} scenes"
            raise DatasetError(
                f"{self.root}: {why}; name one with ?scene=NAME: {', '.join(names[:20])}", path=self.root
            )
        self.folder, self._scene = found[0]
        self.name = str(_field(self._scene, "name", "scene", self.folder))
        self.source = f"nuScenes {self.folder.name} {self.name}"
        self.cameras = [camera for camera in CAMERAS if camera in self._captures]
        if not self._captures.get(LIDAR):
            raise DatasetError(f"{self.root}: {self.name} has no {LIDAR} capture", path=self.root)

    @cached_property
    def _db(self) -> dict[str, dict[str, dict[str, Any]]]:
        return _tables(self.folder, _stamp(self.folder))

    def _get(self, table: str, token: str) -> dict[str, Any]:
        try:
            return self._db[table][token]
        except KeyError:
            raise DatasetError(f"{self.folder / table}.json: no record {token!r}", path=self.folder) from None

    @cached_property
    def _samples(self) -> list[dict[str, Any]]:
        """The scene's key frames, in time order."""
        token = self._scene.get("token")
        rows = [row for row in self._db["sample"].values() if row.get("scene_token") == token]
        return sorted(rows, key=lambda row: int(_field(row, "timestamp", "sample", self.folder)))

    @cached_property
    def _captures(self) -> dict[str, list[dict[str, Any]]]:
        """The scene's captures (``sample_data``) by channel, each in time order."""
        samples = {row["token"] for row in self._samples}
        by_channel: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for row in self._db["sample_data"].values():
            if row.get("sample_token") in samples:
                calibration = self._get(
                    "calibrated_sensor", _field(row, "calibrated_sensor_token", "sample_data", self.folder)
                )
                sensor = self._get("sensor", _field(calibration, "sensor_token", "calibrated_sensor", self.folder))
                by_channel[str(sensor.get("channel"))].append(row)
        for rows in by_channel.values():
            rows.sort(key=lambda row: int(_field(row, "timestamp", "sample_data", self.folder)))
        return dict(by_channel)

    @cached_property
    def _frames(self) -> list[dict[str, Any]]:
        """The frames, each the capture at its time: every sweep, and the camera images that need a frame of their
        own (see :func:`~xviz_server.datasets.sensors.frame_clock`)."""
        sweeps = self._captures.get(LIDAR, [])
        by_time = {int(row["timestamp"]): row for camera in reversed(self.cameras) for row in self._captures[camera]}
        by_time.update((int(row["timestamp"]), row) for row in sweeps)
        clock = frame_clock(
            [int(row["timestamp"]) for row in sweeps],
            {camera: [int(row["timestamp"]) for row in self._captures[camera]] for camera in self.cameras},
        )
        return [by_time[stamp] for stamp in clock]

    def _is_sweep(self, row: dict[str, Any]) -> bool:
        return row.get("calibrated_sensor_token") in self._lidar_calibrations

    @cached_property
    def _lidar_calibrations(self) -> set[str]:
        return {row["calibrated_sensor_token"] for row in self._captures.get(LIDAR, [])}

    @property
    def times(self) -> np.ndarray:
        return np.array([int(row["timestamp"]) for row in self._frames], dtype=np.float64) / 1e6

    @cached_property
    def _images(self) -> list[dict[str, dict[str, Any]]]:
        """Per frame, the image of each camera served in it: every image is in one frame, none has two of a camera."""
        stamps = [int(row["timestamp"]) for row in self._frames]
        frames: list[dict[str, dict[str, Any]]] = [{} for _ in stamps]
        for camera in self.cameras:
            for row in self._captures[camera]:
                frames[frame_of(stamps, int(row["timestamp"]))][camera] = row
        return frames

    def _transform(self, translation: Any, rotation: Any, where: str) -> np.ndarray:
        try:
            matrix = np.eye(4)
            matrix[:3, :3] = quaternion_matrix(*map(float, rotation))
            matrix[:3, 3] = [float(v) for v in translation]
        except (TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: not a pose: {exc}", path=self.folder) from None
        return matrix

    def pose(self, index: int) -> np.ndarray:
        row = self._frames[index]
        ego = self._get("ego_pose", _field(row, "ego_pose_token", "sample_data", self.folder))
        return self._transform(
            ego.get("translation"), ego.get("rotation"), f"{self.folder / 'ego_pose'}.json: {ego.get('token')}"
        )

    def read(self, index: int) -> SensorFrame:
        row = self._frames[index]
        files = [*self._images[index].values(), *([row] if self._is_sweep(row) else [])]
        check_frame(
            sum(file_size(self.root / str(capture.get("filename"))) for capture in files),
            index,
            f"{self.root}: {self.name}",
            self.root,
        )
        images = {camera: self._image(capture) for camera, capture in self._images[index].items()}
        scaling = scale_jpegs(images, self.image_max_width)  # beside the lidar work
        pose = self.pose(index)
        points, intensity = (
            self._sweep(row) if self._is_sweep(row) else (np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
        )
        boxes, categories, ids = self._boxes(int(row["timestamp"]), pose)
        where = f"{self.root}: {self.name}, sweep {row.get('filename')}"
        return SensorFrame(
            int(row["timestamp"]) / 1e6,
            pose,
            points,
            intensity,
            ScaledImages(scaling, where, self.root),
            boxes,
            categories,
            ids,
        )

    def _file(self, row: dict[str, Any], limit: int) -> bytes:
        path = self.root / str(_field(row, "filename", "sample_data", self.folder))
        try:
            size = path.stat().st_size
            if size > limit:
                raise DatasetError(f"{path}: {size} bytes, more than the {limit} a capture may have", path=path)
            return path.read_bytes()
        except OSError as exc:
            raise DatasetError(f"{path}: cannot read: {exc.strerror or exc}", path=path) from None

    def _image(self, row: dict[str, Any]) -> bytes:
        return self._file(row, MAX_SWEEP_BYTES)

    def _sweep(self, row: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        data = self._file(row, MAX_SWEEP_BYTES)
        where = str(self.root / str(row["filename"]))
        if len(data) % 20:
            raise DatasetError(f"{where}: {len(data)} bytes, not whole points of 5 float32", path=self.root)
        cloud = check_points(np.frombuffer(data, dtype="<f4").reshape(-1, 5), where, self.root)
        calibration = self._get("calibrated_sensor", row["calibrated_sensor_token"])
        sensor = self._transform(
            calibration.get("translation"),
            calibration.get("rotation"),
            f"{self.folder / 'calibrated_sensor'}.json: {calibration.get('token')}",
        )
        points = moved(cloud, sensor[:3, :3], sensor[:3, 3])
        return points, cloud[:, 3] / np.float32(255)  # intensities are 0-255

    @cached_property
    def _annotations(self) -> list[tuple[int, dict[str, tuple[np.ndarray, float, np.ndarray, str]]]]:
        """Each key frame's time and boxes: by instance, the world centre, heading, size (w, l, h) and category."""
        by_sample: dict[str, dict[str, tuple[np.ndarray, float, np.ndarray, str]]] = {
            row["token"]: {} for row in self._samples
        }
        for row in self._db["sample_annotation"].values():
            boxes = by_sample.get(row.get("sample_token", ""))
            if boxes is None:
                continue
            instance = self._get("instance", _field(row, "instance_token", "sample_annotation", self.folder))
            category = self._get("category", _field(instance, "category_token", "instance", self.folder))
            where = f"{self.folder / 'sample_annotation'}.json: {row.get('token')}"
            rotation = self._transform((0, 0, 0), _field(row, "rotation", "sample_annotation", self.folder), where)
            try:
                center = np.array([float(v) for v in _field(row, "translation", "sample_annotation", self.folder)])
                size = np.array([float(v) for v in _field(row, "size", "sample_annotation", self.folder)])
            except (TypeError, ValueError) as exc:
                raise DatasetError(f"{where}: {exc}", path=self.folder) from None
            if center.shape != (3,) or size.shape != (3,):
                raise DatasetError(f"{where}: a translation and a size of 3 values each", path=self.folder)
            boxes[str(instance["token"])] = (center, yaw_of(rotation[:3, :3]), size, str(category.get("name", "")))
        return [(int(sample["timestamp"]), by_sample[sample["token"]]) for sample in self._samples]

    def _boxes(self, micros: int, pose: np.ndarray) -> tuple[np.ndarray, list[str], list[str]]:
        keys = self._annotations
        if not keys:
            return np.zeros((0, 7)), [], []
        after = bisect.bisect_left([t for t, _ in keys], micros)
        if after < len(keys) and keys[after][0] == micros or after == 0:
            boxes = dict(keys[min(after, len(keys) - 1)][1])
        elif after == len(keys):
            boxes = dict(keys[-1][1])
        else:
            (t0, first), (t1, second) = keys[after - 1], keys[after]
            share = (micros - t0) / (t1 - t0)
            near = first if share < 0.5 else second
            boxes = {}
            for instance in {*first, *second}:
                if instance in first and instance in second:
                    (c0, y0, s0, category), (c1, y1, _, _) = first[instance], second[instance]
                    turn = (y1 - y0 + np.pi) % (2 * np.pi) - np.pi
                    boxes[instance] = (c0 + (c1 - c0) * share, y0 + turn * share, s0, category)
                elif instance in near:
                    boxes[instance] = near[instance]
        if not boxes:
            return np.zeros((0, 7)), [], []
        instances = sorted(boxes)
        centers, yaws = to_vehicle(
            pose, np.array([boxes[i][0] for i in instances]), np.array([boxes[i][1] for i in instances])
        )
        sizes = np.array([boxes[i][2] for i in instances])  # width, length, height
        table = np.column_stack([centers, sizes[:, 1], sizes[:, 0], sizes[:, 2], yaws])
        return table, [boxes[i][3] for i in instances], [i[:8] for i in instances]
