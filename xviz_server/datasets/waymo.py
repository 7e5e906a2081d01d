"""Waymo Open Dataset segments, as per-frame dictionaries, to XVIZ.

The input is a segment folder written by ``waymoframe2dict`` (see
``shared/seeds/003``): one ``<frame_timestamp_micros>.npz`` per frame. The
keys read are:

* ``POSE``: (4, 4) vehicle-to-world transform;
* per lidar ``L`` in ``TOP``, ``FRONT``, ``SIDE_LEFT``, ``SIDE_RIGHT``,
  ``REAR``: ``L_RANGE_IMAGE_FIRST_RETURN``, (H, W, 6) float32 with the
  channels range, intensity, elongation, x, y, z (x, y, z in the vehicle
  frame), and optionally ``L_IN_NLZ``, (H, W), 1 where the return is in a
  no-label zone (the original range image's fourth channel; -1 or 0
  elsewhere). ``L_BEAM_INCLINATION`` and ``L_LIDAR_EXTRINSIC`` are not
  needed, since the points come with vehicle coordinates;
* per camera ``C`` in ``FRONT``, ``FRONT_LEFT``, ``FRONT_RIGHT``,
  ``SIDE_LEFT``, ``SIDE_RIGHT``: ``C_IMAGE``, (H, W, 3) uint8 RGB
  (``C_INTRINSIC``, ``C_EXTRINSIC``, ``C_WIDTH``, ``C_HEIGHT`` are not
  needed to draw it);
* the 3D labels: ``LABEL_BOXES``, (N, 7) center x, y, z, length, width,
  height, heading in the vehicle frame; ``LABEL_TYPES``, (N,) integers of
  the Waymo ``Label.Type`` enum (1 vehicle, 2 pedestrian, 3 sign, 4
  cyclist, 0 unknown); ``LABEL_IDS``, (N,) tracking ids (strings).

Streams: ``/vehicle_pose`` (the pose's translation and roll, pitch, yaw, in
the world frame), ``/lidar/points`` (returns with range > 0 from every lidar,
vehicle-relative, coloured by intensity), ``/lidar/no_label_zone`` (the
returns flagged as in a no-label zone, grey, so that they can be hidden),
``/camera/<name>`` (JPEG, scaled down), ``/objects/boxes`` (extruded
footprints with the object id and a style class per type) and
``/objects/label``.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..exceptions import DatasetError
from . import DEFAULT_IMAGE_WIDTH
from .images import jpeg
from .kitti import footprints

__all__ = ["WaymoSegment", "is_waymo_segment", "pose_angles", "intensity_colors"]

LIDARS = ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")
CAMERAS = ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT")
TYPES = {0: "Unknown", 1: "Vehicle", 2: "Pedestrian", 3: "Sign", 4: "Cyclist"}
TYPE_COLORS = {"Vehicle": "#50B3FF", "Pedestrian": "#FFC6AF", "Sign": "#F5D24C", "Cyclist": "#957FCE", "Unknown": "#E2E2E2"}


def _frame_files(path: Path) -> list[Path]:
    files = [p for p in path.glob("*.npz") if p.stem.isdigit()]
    return sorted(files, key=lambda p: int(p.stem))


def is_waymo_segment(path: Path) -> bool:
    """Whether ``path`` holds per-frame dictionaries named by their timestamp in microseconds."""
    return path.is_dir() and any(p.suffix == ".npz" and p.stem.isdigit() for p in path.iterdir())


def pose_angles(matrix: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (radians) of a rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(matrix[2, 0]))))
    roll = math.atan2(float(matrix[2, 1]), float(matrix[2, 2]))
    yaw = math.atan2(float(matrix[1, 0]), float(matrix[0, 0]))
    return roll, pitch, yaw


def intensity_colors(intensity: np.ndarray) -> np.ndarray:
    """uint8 RGBA colours of lidar returns by intensity: dim blue to bright yellow.

    Waymo intensities are mostly below 1 with a long tail; tanh compresses
    the tail.
    """
    level = np.tanh(np.clip(intensity, 0, None) * 2.0)[:, None]
    dark, bright = np.array([40, 80, 200, 255]), np.array([255, 230, 60, 255])
    return (dark + (bright - dark) * level).astype(np.uint8)


@dataclass
class WaymoSegment:
    """A Waymo segment folder of per-frame ``.npz`` dictionaries.

    Camera images are scaled down to ``image_max_width`` and encoded as JPEG.
    """

    path: Path
    image_max_width: int = DEFAULT_IMAGE_WIDTH
    name: str = field(init=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not is_waymo_segment(self.path):
            raise DatasetError(f"{self.path}: not a Waymo segment (no <timestamp_micros>.npz frames)", path=self.path)
        self.name = self.path.name

    @cached_property
    def files(self) -> list[Path]:
        return _frame_files(self.path)

    @cached_property
    def times(self) -> np.ndarray:
        """Frame times in seconds, from the file names (no frame read)."""
        return np.array([int(p.stem) / 1e6 for p in self.files])

    def __len__(self) -> int:
        return len(self.files)

    def frame(self, index: int) -> dict[str, np.ndarray]:
        """The dictionary of frame ``index``; raises :class:`DatasetError` naming the file."""
        path = self.files[index]
        try:
            with np.load(path, allow_pickle=False) as data:
                return {key: data[key] for key in data.files}
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise DatasetError(f"{path}: not a readable frame dictionary: {exc}", path=path) from None

    @cached_property
    def _first(self) -> dict[str, np.ndarray]:
        return self.frame(0)

    def metadata(self) -> dict[str, Any]:
        """Metadata from the file names and the keys of the first frame."""
        first = self._first
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
        cameras = [c for c in CAMERAS if f"{c}_IMAGE" in first]
        for camera in cameras:
            meta.primitive(f"/camera/{camera.lower()}", "IMAGE")
        if cameras:
            meta.ui_panel(ui.panel("Cameras", ui.video([f"/camera/{c.lower()}" for c in cameras])))
        return meta.build()

    def convert(self, index: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of frame ``index``."""
        metadata = metadata or self.metadata()
        data = self.frame(index)
        where = self.files[index]
        builder = FrameBuilder(metadata)
        t = float(self.times[index])
        pose = self._array(data, "POSE", where, (4, 4))
        builder.pose("/vehicle_pose", t, position=pose[:3, 3].tolist(), orientation=pose_angles(pose[:3, :3]))
        points, colors, in_zone = self._lidar(data, where)
        if len(points[~in_zone]):
            builder.points("/lidar/points", points[~in_zone], colors[~in_zone])
        if in_zone.any():
            builder.points("/lidar/no_label_zone", points[in_zone])
        for stream in metadata["streams"]:
            if stream.startswith("/camera/"):
                key = stream.removeprefix("/camera/").upper() + "_IMAGE"
                if key in data:
                    builder.image(stream, self._jpeg(self._array(data, key, where), where))
        self._labels(builder, data, where)
        return builder.build(t)

    @staticmethod
    def _array(data: dict[str, np.ndarray], key: str, where: Path, shape: tuple[int, ...] | None = None) -> np.ndarray:
        if key not in data:
            raise DatasetError(f"{where}: no {key!r} in the frame", path=where)
        array = data[key]
        if shape is not None and array.shape != shape:
            raise DatasetError(f"{where}: {key} has shape {array.shape}, not {shape}", path=where)
        return array

    def _lidar(self, data: dict[str, np.ndarray], where: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns of every lidar with range > 0: xyz (N, 3), colours, and in-no-label-zone flags."""
        points, colors, zones = [], [], []
        for lidar in LIDARS:
            key = f"{lidar}_RANGE_IMAGE_FIRST_RETURN"
            if key not in data:
                continue
            image = data[key]
            if image.ndim != 3 or image.shape[2] < 6:
                raise DatasetError(f"{where}: {key} has shape {image.shape}, not (H, W, 6)", path=where)
            valid = image[..., 0] > 0
            returns = image[valid]
            points.append(returns[:, 3:6].astype(np.float32))
            colors.append(intensity_colors(returns[:, 1]))
            zone = data.get(f"{lidar}_IN_NLZ")
            zones.append(zone[valid] > 0 if zone is not None else np.zeros(len(returns), dtype=bool))
        if not points:
            empty = np.zeros((0, 3), np.float32)
            return empty, np.zeros((0, 4), np.uint8), np.zeros(0, dtype=bool)
        return np.concatenate(points), np.concatenate(colors), np.concatenate(zones)

    def _jpeg(self, image: np.ndarray, where: Path) -> bytes:
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise DatasetError(f"{where}: a camera image must be (H, W, 3) uint8, not {image.shape} {image.dtype}", path=where)
        return jpeg(image, self.image_max_width)

    @staticmethod
    def _labels(builder: FrameBuilder, data: dict[str, np.ndarray], where: Path) -> None:
        if "LABEL_BOXES" not in data:
            return
        boxes = data["LABEL_BOXES"].astype(np.float64)
        if boxes.ndim != 2 or boxes.shape[1] != 7:
            raise DatasetError(f"{where}: LABEL_BOXES has shape {boxes.shape}, not (N, 7)", path=where)
        types = data.get("LABEL_TYPES", np.zeros(len(boxes), dtype=int))
        ids = data.get("LABEL_IDS", np.array([str(i) for i in range(len(boxes))]))
        bottoms = boxes[:, :3] - np.stack([np.zeros(len(boxes)), np.zeros(len(boxes)), boxes[:, 5] / 2], axis=1)
        corners = footprints(bottoms, boxes[:, 6], boxes[:, 3], boxes[:, 4])
        for box, kind, object_id, polygon in zip(boxes, types, ids, corners):
            name = TYPES.get(int(kind), "Unknown")
            builder.polygon("/objects/boxes", polygon, id=str(object_id), classes=[name], style={"height": float(box[5])})
            builder.text("/objects/label", box[:3] + [0, 0, box[5] / 2 + 0.5], f"{name} {object_id}", id=str(object_id))
