"""Waymo Open Dataset v2 segments: one Parquet file per component, ``{component}/{segment}.parquet``.

Waymo ships v2 of its perception dataset as a folder per component, each
holding one file per segment (named by its context name), so that a user
downloads only the components they need. The components read, and their
columns (``key.*`` name the row; ``[Component].field`` its values):

* ``vehicle_pose`` (required): ``key.frame_timestamp_micros`` and
  ``[VehiclePoseComponent].world_from_vehicle.transform`` (16 values, row
  major): the frame times and poses. Every frame is one row here;
* ``lidar``: per frame and ``key.laser_name`` (1 TOP, 2 FRONT, 3 SIDE_LEFT,
  4 SIDE_RIGHT, 5 REAR), ``[LiDARComponent].range_image_return1`` and
  ``range_image_return2``, each ``.values`` (flat float32) and ``.shape``
  ([H, W, 4]: range, intensity, elongation, in no-label zone);
* ``lidar_calibration``: per laser, ``[LiDARCalibrationComponent].extrinsic.transform``
  and ``.beam_inclination.values`` (or ``.min`` and ``.max`` for uniform beams);
* ``lidar_pose``: per frame and laser, ``[LiDARPoseComponent].range_image_return1``
  ([H, W, 6]: the vehicle's pose at each pixel, roll, pitch, yaw, x, y, z;
  the TOP laser's);
* ``camera_image``: per frame and ``key.camera_name`` (1 FRONT, 2 FRONT_LEFT,
  3 FRONT_RIGHT, 4 SIDE_LEFT, 5 SIDE_RIGHT), ``[CameraImageComponent].image`` (JPEG);
* ``lidar_box``: per frame and ``key.laser_object_id``,
  ``[LiDARBoxComponent].box.center.{x,y,z}``, ``.box.size.{x,y,z}`` (length,
  width, height), ``.box.heading`` and ``.type`` (Waymo's ``Label.Type``).

Only ``vehicle_pose`` is needed; a segment without some other component is
served without what it gives. Frames become the same :class:`WaymoFrame` as
the v1 layouts (the range images go through the same geometry,
:mod:`.range_images`), so a segment gives the same log in v1 and v2.

A segment is named by its context name and found by its ``vehicle_pose``
file: the dataset's path is ``ROOT/vehicle_pose/SEGMENT.parquet``, or a
folder ``ROOT`` whose ``vehicle_pose`` folder holds one segment.

Reading is bounded: a file is read one row group at a time, only the row
groups whose statistics say they hold the frame, and a row group larger
than :data:`MAX_ROW_GROUP_BYTES` once decoded (as its footer declares it,
before it is read) is an error naming the file and the group. A range image
whose values do not fit its shape is an error naming the file, the frame and
the laser; every other frame is served.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ...exceptions import DatasetError
from ...unpack import check_frame
from .. import DEFAULT_IMAGE_WIDTH, require
from ..images import scale_jpegs
from .log import CAMERAS, LIDARS, ScaledImages, WaymoFrame, WaymoLog
from .range_images import calibration_rays, frame_rays, join_points, range_points

__all__ = ["WaymoParquetSegment", "is_parquet_segment", "segment_file", "MAX_ROW_GROUP_BYTES", "COMPONENTS"]

#: The component that names a segment and gives its frames.
POSES = "vehicle_pose"
#: Every component read.
COMPONENTS = (POSES, "lidar", "lidar_calibration", "lidar_pose", "camera_image", "lidar_box")
SUFFIX = ".parquet"
#: The largest row group read, decoded, as the file's footer declares it.
MAX_ROW_GROUP_BYTES = 512 << 20

_TIME = "key.frame_timestamp_micros"
_LASER = "key.laser_name"
_CAMERA = "key.camera_name"
_POSE = "[VehiclePoseComponent].world_from_vehicle.transform"
_RETURNS = ("[LiDARComponent].range_image_return1", "[LiDARComponent].range_image_return2")
_PIXEL_POSE = "[LiDARPoseComponent].range_image_return1"
_EXTRINSIC = "[LiDARCalibrationComponent].extrinsic.transform"
_BEAMS = "[LiDARCalibrationComponent].beam_inclination"
_IMAGE = "[CameraImageComponent].image"
_BOX = "[LiDARBoxComponent].box"
_BOX_COLUMNS = tuple(
    f"{_BOX}.{field}" for field in ("center.x", "center.y", "center.z", "size.x", "size.y", "size.z", "heading")
)
_BOX_TYPE = "[LiDARBoxComponent].type"
_OBJECT = "key.laser_object_id"


def segment_file(path: Path) -> Path | None:
    """The ``vehicle_pose`` file of the segment at ``path`` (that file, or a folder holding one segment), if any."""
    if path.is_file():
        return path if path.suffix == SUFFIX and path.parent.name == POSES else None
    folder = path / POSES
    if not folder.is_dir():
        return None
    files = [file for file in folder.iterdir() if file.suffix == SUFFIX and not file.name.startswith(".")]
    return files[0] if len(files) == 1 else None


def is_parquet_segment(path: Path) -> bool:
    """Whether ``path`` is a v2 segment: a ``vehicle_pose/SEGMENT.parquet`` file beside a ``lidar`` or
    ``camera_image`` folder, or a folder holding one such segment. Reads no file."""
    file = segment_file(path)
    return file is not None and any((file.parent.parent / part).is_dir() for part in ("lidar", "camera_image"))


class _Component:
    """One component's file of a segment: its row groups read one at a time, those holding a frame."""

    def __init__(self, path: Path) -> None:
        pq = require("pyarrow.parquet", "Waymo v2 segments", "parquet")
        self.path = path
        try:
            self.file = pq.ParquetFile(path)
        except (OSError, ValueError) as exc:  # pyarrow's errors derive from these
            raise DatasetError(f"{path}: not a Parquet file: {exc}", path=path) from None
        meta = self.file.metadata
        self.columns = set(self.file.schema_arrow.names)
        self.spans: list[tuple[int, int] | None] = []
        time_column = self.file.schema_arrow.get_field_index(_TIME) if _TIME in self.columns else -1
        for group in range(meta.num_row_groups):
            stats = meta.row_group(group).column(time_column).statistics if time_column >= 0 else None
            has = stats is not None and stats.has_min_max
            self.spans.append((int(stats.min), int(stats.max)) if has else None)  # type: ignore[union-attr]

    def _groups(self, micros: int | None) -> list[int]:
        """The row groups that may hold frame ``micros`` (all, for ``None``), by their statistics."""
        return [
            group
            for group, span in enumerate(self.spans)
            if micros is None or span is None or span[0] <= micros <= span[1]
        ]

    def declared(self, micros: int) -> int:
        """What the row groups holding frame ``micros`` declare they decode to, in all."""
        return sum(self.file.metadata.row_group(group).total_byte_size for group in self._groups(micros))

    def read(self, columns: Sequence[str], micros: int | None = None) -> dict[str, list[Any]]:
        """The rows (of frame ``micros``, or all) as lists by column; columns the file lacks are left out."""
        pc = require("pyarrow.compute", "Waymo v2 segments", "parquet")
        wanted = [column for column in columns if column in self.columns]
        names = sorted({*wanted, _TIME} if micros is not None and _TIME in self.columns else wanted)
        rows: dict[str, list[Any]] = {column: [] for column in wanted}
        for group in self._groups(micros):
            declared = self.file.metadata.row_group(group).total_byte_size
            if declared > MAX_ROW_GROUP_BYTES:
                raise DatasetError(
                    f"{self.path}: row group {group} declares {declared} bytes decoded, more than "
                    f"{MAX_ROW_GROUP_BYTES}",
                    path=self.path,
                )
            try:
                table = self.file.read_row_group(group, columns=names)
            except (OSError, ValueError) as exc:
                raise DatasetError(f"{self.path}: row group {group} does not read: {exc}", path=self.path) from None
            if micros is not None and _TIME in table.column_names:
                table = table.filter(pc.equal(table[_TIME], micros))
            for column in wanted:
                rows[column].extend(table[column].to_pylist())
        return rows


class WaymoParquetSegment(WaymoLog):
    """A Waymo v2 segment: the components' Parquet files of one context name."""

    path: Path

    def __init__(self, path: Path, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        file = segment_file(Path(path))
        if file is None:
            raise DatasetError(
                f"{path}: not a Waymo v2 segment (no {POSES}/SEGMENT{SUFFIX}, or several segments: "
                f"name one as {POSES}/SEGMENT{SUFFIX})",
                path=path,
            )
        self.path, self.root, self.name = file, file.parent.parent, file.stem
        self.image_max_width = image_max_width
        self._geometry: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        if not len(self.times):
            raise DatasetError(f"{file}: no frames", path=file)

    def _component(self, name: str) -> _Component | None:
        path = self.root / name / f"{self.name}{SUFFIX}"
        return _Component(path) if path.is_file() else None

    @cached_property
    def _poses(self) -> tuple[np.ndarray, np.ndarray]:
        """The frames' times (microseconds) and (N, 4, 4) poses, in time order."""
        poses = self._component(POSES)
        assert poses is not None  # found by it
        rows = poses.read([_TIME, _POSE])
        if not rows.get(_TIME) or _POSE not in rows:
            raise DatasetError(f"{poses.path}: no {_TIME} and {_POSE} columns", path=self.path)
        micros = np.array(rows[_TIME], dtype=np.int64)
        matrices = [np.asarray(values if values is not None else (), dtype=np.float64) for values in rows[_POSE]]
        bad = next((i for i, matrix in enumerate(matrices) if matrix.size != 16), None)
        if bad is not None:
            raise DatasetError(
                f"{poses.path}: frame {rows[_TIME][bad]}: a pose of {matrices[bad].size} values, not 16", path=self.path
            )
        order = np.argsort(micros, kind="stable")
        return micros[order], np.stack(matrices).reshape(-1, 4, 4)[order]

    @property
    def times(self) -> np.ndarray:
        return self._poses[0] / 1e6

    @cached_property
    def _files(self) -> dict[str, _Component | None]:
        return {name: self._component(name) for name in COMPONENTS[1:]}

    @cached_property
    def _calibrations(self) -> dict[int, tuple[np.ndarray, list[float], float, float]]:
        """Each laser's extrinsic, listed beams, lowest and highest beam."""
        component = self._files["lidar_calibration"]
        if component is None:
            return {}
        rows = component.read([_LASER, _EXTRINSIC, f"{_BEAMS}.values", f"{_BEAMS}.min", f"{_BEAMS}.max"])
        calibrations = {}
        for i, laser in enumerate(rows.get(_LASER, ())):
            extrinsic = np.asarray(rows[_EXTRINSIC][i] or (), dtype=np.float64)
            if extrinsic.size != 16:
                raise DatasetError(
                    f"{component.path}: laser {laser}: an extrinsic of {extrinsic.size} values, not 16", path=self.path
                )
            beams = list(rows.get(f"{_BEAMS}.values", [None] * (i + 1))[i] or ())
            low = rows.get(f"{_BEAMS}.min", [None] * (i + 1))[i] or 0.0
            high = rows.get(f"{_BEAMS}.max", [None] * (i + 1))[i] or 0.0
            calibrations[int(laser)] = (extrinsic.reshape(4, 4), beams, float(low), float(high))
        return calibrations

    def read(self, index: int) -> WaymoFrame:
        micros = int(self._poses[0][index])
        pose = self._poses[1][index]
        where = f"{self.root}: segment {self.name}, frame {micros}"
        check_frame(
            sum(component.declared(micros) for component in self._files.values() if component is not None),
            index,
            f"{self.root}: segment {self.name}",
            self.path,
        )
        images = self._images(micros)
        scaling = scale_jpegs(images, self.image_max_width)  # beside the lidar work
        points, intensity, in_zone = self._lidar(micros, pose, where)
        boxes, types, ids = self._boxes(micros)
        return WaymoFrame(
            micros / 1e6, pose, points, intensity, in_zone, ScaledImages(scaling, where, self.path), boxes, types, ids
        )

    def _images(self, micros: int) -> dict[str, bytes]:
        component = self._files["camera_image"]
        if component is None:
            return {}
        rows = component.read([_CAMERA, _IMAGE], micros)
        return {
            CAMERAS[int(camera) - 1]: image
            for camera, image in zip(rows.get(_CAMERA, ()), rows.get(_IMAGE, ()))
            if 1 <= int(camera) <= len(CAMERAS) and image
        }

    def _lidar(self, micros: int, pose: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        component = self._files["lidar"]
        if component is None:
            return join_points(())
        columns = [_LASER] + [f"{part}.{field}" for part in _RETURNS for field in ("values", "shape")]
        rows = component.read(columns, micros)
        pixel_poses = self._pixel_poses(micros, where)
        parts = []
        for i, laser in sorted(enumerate(rows.get(_LASER, ())), key=lambda item: int(item[1])):
            name = LIDARS[int(laser) - 1] if 1 <= int(laser) <= len(LIDARS) else str(laser)
            returns = [
                image
                for part in _RETURNS
                if (image := _matrix(rows, part, i, 4, f"{where}: laser {name} {part}", self.path)) is not None
            ]
            if not returns:
                continue
            height, width = returns[0].shape[:2]
            if any(image.shape[:2] != (height, width) for image in returns):
                raise DatasetError(f"{where}: laser {name}: returns of different shapes", path=self.path)
            if int(laser) not in self._calibrations:
                raise DatasetError(f"{where}: laser {name} has range images but no calibration", path=self.path)
            directions, origin = self._rays(int(laser), height, width, f"{where}: laser {name}")
            origins, period = origin[None], 1
            pixel_pose = pixel_poses.get(int(laser))
            if pixel_pose is not None:
                if pixel_pose.shape[:2] != (height, width):
                    raise DatasetError(
                        f"{where}: laser {name}: pixel pose is {pixel_pose.shape[:2]}, range image {height, width}",
                        path=self.path,
                    )
                directions, origins, period = frame_rays(directions, origin, pixel_pose[..., :6], pose)
            parts.append(range_points(directions, origins, period, returns))
        return join_points(parts)

    def _pixel_poses(self, micros: int, where: str) -> dict[int, np.ndarray]:
        component = self._files["lidar_pose"]
        if component is None:
            return {}
        rows = component.read([_LASER, f"{_PIXEL_POSE}.values", f"{_PIXEL_POSE}.shape"], micros)
        poses = {}
        for i, laser in enumerate(rows.get(_LASER, ())):
            matrix = _matrix(rows, _PIXEL_POSE, i, 6, f"{where}: laser {laser} pixel pose", self.path)
            if matrix is not None:
                poses[int(laser)] = matrix
        return poses

    def _rays(self, laser: int, height: int, width: int, where: str) -> tuple[np.ndarray, np.ndarray]:
        key = (laser, height, width)
        if key not in self._geometry:
            extrinsic, beams, low, high = self._calibrations[laser]
            try:
                self._geometry[key] = calibration_rays(extrinsic, beams, low, high, height, width, where)
            except ValueError as exc:
                raise DatasetError(str(exc), path=self.path) from None
        return self._geometry[key]

    def _boxes(self, micros: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
        component = self._files["lidar_box"]
        rows = component.read([_OBJECT, _BOX_TYPE, *_BOX_COLUMNS], micros) if component is not None else {}
        ids = [str(object_id) for object_id in rows.get(_OBJECT, ())]
        if not ids or any(column not in rows for column in _BOX_COLUMNS):
            return np.zeros((0, 7)), np.zeros(0, dtype=int), []
        boxes = np.array([rows[column] for column in _BOX_COLUMNS], dtype=np.float64).T.reshape(-1, 7)
        types = np.array([kind or 0 for kind in rows.get(_BOX_TYPE, [0] * len(ids))], dtype=int)
        return boxes, types, ids


def _matrix(
    rows: dict[str, list[Any]], part: str, row: int, channels: int, where: str, path: Path
) -> np.ndarray | None:
    """A range image (or pixel pose) of row ``row`` as a float32 (H, W, C) array; ``None`` if the row has none."""
    values, shape = rows.get(f"{part}.values", ()), rows.get(f"{part}.shape", ())
    if row >= len(values) or not values[row]:
        return None
    dims = tuple(int(d) for d in (shape[row] or ()))
    data = np.asarray(values[row], dtype=np.float32)
    if len(dims) != 3 or dims[2] < channels or min(dims) < 1 or data.size != dims[0] * dims[1] * dims[2]:
        raise DatasetError(f"{where}: {data.size} values for shape {list(dims)}, not [H, W, {channels}]", path=path)
    return data.reshape(dims)
