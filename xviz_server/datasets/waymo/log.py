"""Waymo Open Dataset segments to XVIZ: as shipped (``.tfrecord``) or as per-frame dictionaries.

A segment is read from either of two layouts, both of kind ``waymo``:

* a ``.tfrecord`` file of ``Frame`` protocol buffers, as Waymo ships it
  (see :mod:`xviz_server.datasets.waymo_tfrecord`);
* a folder written by ``waymoframe2dict`` (see ``shared/seeds/003``): one
  ``<frame_timestamp_micros>.npz`` per frame, read by :class:`WaymoSegment`.

The keys of a ``.npz`` frame that are read:

* ``POSE``: (4, 4) vehicle-to-world transform;
* per lidar ``L`` in ``TOP``, ``FRONT``, ``SIDE_LEFT``, ``SIDE_RIGHT``,
  ``REAR``: ``L_RANGE_IMAGE_FIRST_RETURN`` and, if there,
  ``L_RANGE_IMAGE_SECOND_RETURN``, (H, W, 6) float32 with the channels
  range, intensity, elongation, x, y, z (x, y, z in the vehicle frame), and
  optionally ``L_IN_NLZ`` and ``L_IN_NLZ_SECOND_RETURN``, (H, W), 1 where
  the return is in a no-label zone (the original range image's fourth
  channel; -1 or 0 elsewhere). ``L_BEAM_INCLINATION`` and
  ``L_LIDAR_EXTRINSIC`` are not needed, since the points come with vehicle
  coordinates;
* per camera ``C`` in ``FRONT``, ``FRONT_LEFT``, ``FRONT_RIGHT``,
  ``SIDE_LEFT``, ``SIDE_RIGHT``: ``C_IMAGE``, (H, W, 3) uint8 RGB
  (``C_INTRINSIC``, ``C_EXTRINSIC``, ``C_WIDTH``, ``C_HEIGHT`` are not
  needed to draw it);
* the 3D labels: ``LABEL_BOXES``, (N, 7) center x, y, z, length, width,
  height, heading in the vehicle frame; ``LABEL_TYPES``, (N,) integers of
  the Waymo ``Label.Type`` enum (1 vehicle, 2 pedestrian, 3 sign, 4
  cyclist, 0 unknown); ``LABEL_IDS``, (N,) tracking ids (strings).

Both layouts give the same log. Streams: ``/vehicle_pose`` (the pose's
translation and roll, pitch, yaw, in the world frame), ``/lidar/points``
(both returns with range > 0 of every lidar, lidar by lidar, vehicle-relative,
coloured by intensity), ``/lidar/no_label_zone`` (the returns flagged as in
a no-label zone, grey, so that they can be hidden), ``/camera/<name>``
(JPEG, scaled down to ``image_max_width``), ``/objects/boxes`` (extruded
footprints with the object id and a style class per type) and
``/objects/label``.
"""

from __future__ import annotations

import abc
import math
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..exceptions import DatasetError
from ..storepath import StorePath
from . import DEFAULT_IMAGE_WIDTH
from .images import jpeg
from .kitti import footprints
from .tfrecord import is_tfrecord

__all__ = [
    "WaymoFrame", "WaymoLog", "WaymoSegment", "open_segment", "is_waymo_segment", "pose_angles", "intensity_colors",
]

LIDARS = ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")
CAMERAS = ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT")
TYPES = {0: "Unknown", 1: "Vehicle", 2: "Pedestrian", 3: "Sign", 4: "Cyclist"}
TYPE_COLORS = {"Vehicle": "#50B3FF", "Pedestrian": "#FFC6AF", "Sign": "#F5D24C", "Cyclist": "#957FCE", "Unknown": "#E2E2E2"}
SUFFIX = ".tfrecord"


def _frame_files(path: Path) -> list[Path]:
    files = [p for p in path.glob("*.npz") if p.stem.isdigit()]
    return sorted(files, key=lambda p: int(p.stem))


def is_waymo_segment(path: Path) -> bool:
    """Whether ``path`` is a segment: a ``.tfrecord`` file, or a folder of ``<timestamp_micros>.npz`` frames."""
    if path.is_file():
        return path.suffix == SUFFIX and is_tfrecord(path)
    return path.is_dir() and any(p.suffix == ".npz" and p.stem.isdigit() for p in path.iterdir())


def open_segment(path: Path | StorePath, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> WaymoLog:
    """The segment at ``path``: a ``.tfrecord`` file (or object in a store) or a folder of ``.npz`` frames."""
    if isinstance(path, StorePath) or Path(path).is_file():
        from .waymo_tfrecord import WaymoRecordSegment

        return WaymoRecordSegment(path, image_max_width)
    return WaymoSegment(path, image_max_width)


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


@dataclass
class WaymoFrame:
    """What a frame of either layout gives, ready to draw."""

    #: UNIX time, seconds.
    time: float
    #: (4, 4) vehicle-to-world transform.
    pose: np.ndarray
    #: (N, 3) float32 returns in the vehicle frame, their (N,) intensities and no-label-zone flags.
    points: np.ndarray
    intensity: np.ndarray
    in_zone: np.ndarray
    #: JPEG image of each camera there is, by name (``FRONT``, ...); an image may still be
    #: in the making, and getting it waits for it.
    images: Mapping[str, bytes]
    #: (N, 7) boxes: center x, y, z, length, width, height, heading; (N,) types; N ids.
    boxes: np.ndarray
    types: np.ndarray
    ids: Sequence[str]


class WaymoLog(abc.ABC):
    """A segment of either layout: metadata and state updates from its :class:`WaymoFrame` s."""

    path: Path | StorePath
    name: str
    image_max_width: int

    @property
    @abc.abstractmethod
    def times(self) -> np.ndarray:
        """Frame times in seconds, without converting a frame."""

    def __len__(self) -> int:
        return len(self.times)

    @abc.abstractmethod
    def read(self, index: int) -> WaymoFrame:
        """Frame ``index``; raises :class:`DatasetError` naming the file (and record) at fault."""

    @cached_property
    def _first(self) -> WaymoFrame:
        """The first frame that reads, which tells the cameras there are."""
        problem: DatasetError | None = None
        for index in range(len(self)):
            try:
                return self.read(index)
            except DatasetError as exc:
                problem = problem or exc
        raise problem or DatasetError(f"{self.path}: no frames", path=self.path)

    def metadata(self) -> dict[str, Any]:
        """Metadata from the frame times and the cameras of the first frame."""
        meta = MetadataBuilder()
        meta.log_info(start_time=float(self.times[0]), end_time=float(self.times[-1]), source=f"Waymo segment {self.name}")
        meta.pose("/vehicle_pose")
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 1})
        meta.primitive("/lidar/no_label_zone", "POINT", coordinate="VEHICLE_RELATIVE",
                       style={"radius_pixels": 1, "fill_color": "#80808080"})
        classes = {name: {"fill_color": color + "80", "stroke_color": color} for name, color in TYPE_COLORS.items()}
        meta.primitive("/objects/boxes", "POLYGON", coordinate="VEHICLE_RELATIVE",
                       style={"extruded": True, "fill_color": "#00000080"}, style_classes=classes)
        meta.primitive("/objects/label", "TEXT", coordinate="VEHICLE_RELATIVE", style={"text_size": 14, "fill_color": "#DCDCCD"})
        cameras = [c for c in CAMERAS if c in self._first.images]
        for camera in cameras:
            meta.primitive(f"/camera/{camera.lower()}", "IMAGE")
        if cameras:
            meta.ui_panel(ui.panel("Cameras", ui.video([f"/camera/{c.lower()}" for c in cameras])))
        return meta.build()

    def convert(self, index: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of frame ``index``."""
        metadata = metadata or self.metadata()
        frame = self.read(index)
        builder = FrameBuilder(metadata)
        builder.pose("/vehicle_pose", frame.time, position=frame.pose[:3, 3].tolist(), orientation=pose_angles(frame.pose[:3, :3]))
        points, intensity = frame.points, frame.intensity
        if frame.in_zone.any():
            builder.points("/lidar/no_label_zone", points[frame.in_zone])
            points, intensity = points[~frame.in_zone], intensity[~frame.in_zone]
        if len(points):
            builder.points("/lidar/points", points, intensity_colors(intensity))
        self._labels(builder, frame)
        for stream in metadata["streams"]:  # last: the images may still be in the making
            camera = stream.removeprefix("/camera/").upper()
            if stream.startswith("/camera/") and camera in frame.images:
                builder.image(stream, frame.images[camera])
        return builder.build(frame.time)

    @staticmethod
    def _labels(builder: FrameBuilder, frame: WaymoFrame) -> None:
        boxes = frame.boxes
        if not len(boxes):
            return
        bottoms = boxes[:, :3] - np.stack([np.zeros(len(boxes)), np.zeros(len(boxes)), boxes[:, 5] / 2], axis=1)
        corners = footprints(bottoms, boxes[:, 6], boxes[:, 3], boxes[:, 4])
        for box, kind, object_id, polygon in zip(boxes, frame.types, frame.ids, corners):
            name = TYPES.get(int(kind), "Unknown")
            # The height is the box's own; the schema wants a colour beside it: the class's outline.
            style = {"stroke_color": TYPE_COLORS[name], "height": float(box[5])}
            builder.polygon("/objects/boxes", polygon, id=str(object_id), classes=[name], style=style)
            builder.text("/objects/label", box[:3] + [0, 0, box[5] / 2 + 0.5], f"{name} {object_id}", id=str(object_id))


class WaymoSegment(WaymoLog):
    """A Waymo segment folder of per-frame ``.npz`` dictionaries.

    Camera images are scaled down to ``image_max_width`` and encoded as JPEG.
    """

    path: Path

    def __init__(self, path: Path, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        self.path = Path(path)
        self.image_max_width = image_max_width
        if not self.path.is_dir() or not is_waymo_segment(self.path):
            raise DatasetError(f"{self.path}: not a Waymo segment (no <timestamp_micros>.npz frames)", path=self.path)
        self.name = self.path.name

    @cached_property
    def files(self) -> list[Path]:
        return _frame_files(self.path)

    @cached_property
    def times(self) -> np.ndarray:
        """Frame times in seconds, from the file names (no frame read)."""
        return np.array([int(p.stem) / 1e6 for p in self.files])

    def frame(self, index: int) -> dict[str, np.ndarray]:
        """The dictionary of frame ``index``; raises :class:`DatasetError` naming the file."""
        path = self.files[index]
        try:
            with np.load(path, allow_pickle=False) as data:
                return {key: data[key] for key in data.files}
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise DatasetError(f"{path}: not a readable frame dictionary: {exc}", path=path) from None

    def read(self, index: int) -> WaymoFrame:
        data = self.frame(index)
        where = self.files[index]
        points, intensity, in_zone = self._lidar(data, where)
        images = {camera: self._jpeg(data[f"{camera}_IMAGE"], where) for camera in CAMERAS if f"{camera}_IMAGE" in data}
        boxes, types, ids = self._labels_of(data, where)
        pose = self._array(data, "POSE", where, (4, 4)).astype(np.float64)
        return WaymoFrame(float(self.times[index]), pose, points, intensity, in_zone, images, boxes, types, ids)

    @staticmethod
    def _array(data: dict[str, np.ndarray], key: str, where: Path, shape: tuple[int, ...] | None = None) -> np.ndarray:
        if key not in data:
            raise DatasetError(f"{where}: no {key!r} in the frame", path=where)
        array = data[key]
        if shape is not None and array.shape != shape:
            raise DatasetError(f"{where}: {key} has shape {array.shape}, not {shape}", path=where)
        return array

    @staticmethod
    def _lidar(data: dict[str, np.ndarray], where: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns of every lidar with range > 0: xyz (N, 3), intensities, and in-no-label-zone flags."""
        points, intensity, zones = [], [], []
        for lidar in LIDARS:
            for key, zone_key in ((f"{lidar}_RANGE_IMAGE_FIRST_RETURN", f"{lidar}_IN_NLZ"),
                                  (f"{lidar}_RANGE_IMAGE_SECOND_RETURN", f"{lidar}_IN_NLZ_SECOND_RETURN")):
                if key not in data:
                    continue
                image = data[key]
                if image.ndim != 3 or image.shape[2] < 6:
                    raise DatasetError(f"{where}: {key} has shape {image.shape}, not (H, W, 6)", path=where)
                valid = image[..., 0] > 0
                returns = image[valid]
                points.append(returns[:, 3:6].astype(np.float32))
                intensity.append(returns[:, 1])
                zone = data.get(zone_key)
                zones.append(zone[valid] > 0 if zone is not None else np.zeros(len(returns), dtype=bool))
        if not points:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, dtype=bool)
        return np.concatenate(points), np.concatenate(intensity), np.concatenate(zones)

    def _jpeg(self, image: np.ndarray, where: Path) -> bytes:
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise DatasetError(f"{where}: a camera image must be (H, W, 3) uint8, not {image.shape} {image.dtype}", path=where)
        return jpeg(image, self.image_max_width)

    @staticmethod
    def _labels_of(data: dict[str, np.ndarray], where: Path) -> tuple[np.ndarray, np.ndarray, Sequence[str]]:
        if "LABEL_BOXES" not in data:
            return np.zeros((0, 7)), np.zeros(0, dtype=int), []
        boxes = data["LABEL_BOXES"].astype(np.float64)
        if boxes.ndim != 2 or boxes.shape[1] != 7:
            raise DatasetError(f"{where}: LABEL_BOXES has shape {boxes.shape}, not (N, 7)", path=where)
        types = data.get("LABEL_TYPES", np.zeros(len(boxes), dtype=int))
        ids = [str(i) for i in data.get("LABEL_IDS", range(len(boxes)))]
        return boxes, types, ids
