"""What the drive datasets of today give: a :class:`SensorFrame` per lidar sweep, and the log made of them.

nuScenes, Argoverse 2 and PandaSet each read their own layout into
:class:`SensorFrame` s; :class:`SensorLog` makes the metadata and state
updates, the same streams for each:

* ``/vehicle_pose``: the vehicle's position and roll, pitch, yaw in the
  dataset's world frame;
* ``/lidar/points``: the sweep in the vehicle frame, coloured by intensity;
* ``/objects/boxes``: each annotated object's footprint, extruded to its
  height, with its track id and a style class per category, and
  ``/objects/label``, its category and id above it;
* ``/vehicle/trajectory``: the vehicle's path over the next frames, in the
  vehicle frame;
* ``/camera/<name>``: each camera's latest image (JPEG, scaled down to
  ``image_max_width``).
"""

from __future__ import annotations

import abc
import bisect
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..exceptions import DatasetError
from ..store.path import StorePath, StoreTree
from .shared import footprints, intensity_colors, pose_angles

__all__ = [
    "DriveLog",
    "SensorFrame",
    "SensorLog",
    "draw_boxes",
    "declare_boxes",
    "frame_clock",
    "frame_of",
    "captures_by_frame",
    "moved",
    "file_size",
    "declare_cameras",
    "posed",
    "quaternion_matrix",
    "yaw_of",
    "TRAJECTORY_FRAMES",
]

#: How many frames ahead ``/vehicle/trajectory`` reaches.
TRAJECTORY_FRAMES = 20
#: Colours of object categories by a word of their name (see :func:`category_style`).
CATEGORY_COLORS = {
    "vehicle": "#50B3FF",
    "car": "#50B3FF",
    "truck": "#50B3FF",
    "bus": "#50B3FF",
    "pedestrian": "#FFC6AF",
    "human": "#FFC6AF",
    "cyclist": "#957FCE",
    "bicycle": "#957FCE",
    "motorcycle": "#957FCE",
    "animal": "#7FCE8A",
    "sign": "#F5D24C",
    "bicyclist": "#957FCE",
    "motorcyclist": "#957FCE",
    "movable_object": "#E2E2E2",
    "static_object": "#E2E2E2",
}
_OTHER = "#E2E2E2"


def quaternion_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The (3, 3) rotation of a unit quaternion (normalised first)."""
    q = np.array([w, x, y, z], dtype=np.float64)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"not a rotation: quaternion {q.tolist()}")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_of(rotation: np.ndarray) -> float:
    """The heading (radians about z) of a rotation matrix."""
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


def category_style(category: str) -> str:
    """The class name a category is styled by: its first word that has a colour (``vehicle`` for nuScenes'
    ``vehicle.car`` and Argoverse's ``REGULAR_VEHICLE``), or ``other``."""
    words = category.replace(".", " ").replace("_", " ").lower().split()
    return next((word for word in words if word in CATEGORY_COLORS), "other")


@dataclass
class SensorFrame:
    """One lidar sweep of a drive, with what was seen by then, ready to draw."""

    #: UNIX time, seconds.
    time: float
    #: (4, 4) vehicle-to-world transform.
    pose: np.ndarray
    #: (N, 3) float32 returns in the vehicle frame and their (N,) intensities.
    points: np.ndarray
    intensity: np.ndarray
    #: JPEG image of each camera that has one for this frame, by name; getting one may wait for it to be scaled.
    images: Mapping[str, bytes]
    #: (N, 7) boxes in the vehicle frame: centre x, y, z, length, width, height, yaw.
    boxes: np.ndarray
    #: N category names and N track ids.
    categories: Sequence[str]
    ids: Sequence[str]


Frame = TypeVar("Frame")
T = TypeVar("T")


class DriveLog(abc.ABC, Generic[Frame]):
    """A drive read frame by frame: its frame times without reading a frame, and each frame when asked for."""

    path: Path | StorePath
    name: str

    @property
    @abc.abstractmethod
    def times(self) -> np.ndarray:
        """Frame times in seconds, without reading a frame."""

    def __len__(self) -> int:
        return len(self.times)

    @abc.abstractmethod
    def read(self, index: int) -> Frame:
        """Frame ``index``; raises :class:`DatasetError` naming the file (and record) at fault."""


class SensorLog(DriveLog[SensorFrame]):
    """A drive of a dataset: metadata and state updates from its :class:`SensorFrame` s."""

    path: Path
    #: Where the data comes from, for the log's info (``nuScenes scene-0061``).
    source: str
    #: The cameras, in the order their panel shows them.
    cameras: Sequence[str]

    @abc.abstractmethod
    def pose(self, index: int) -> np.ndarray:
        """The (4, 4) vehicle-to-world transform of frame ``index``, without reading its sweep."""

    @cached_property
    def categories(self) -> list[str]:
        """The style classes of the objects (see :func:`category_style`)."""
        return sorted({*CATEGORY_COLORS, "other"})

    def metadata(self) -> dict[str, Any]:
        meta = MetadataBuilder()
        meta.log_info(start_time=float(self.times[0]), end_time=float(self.times[-1]), source=self.source)
        meta.pose("/vehicle_pose")
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 1})
        declare_boxes(meta, {**CATEGORY_COLORS, "other": _OTHER})
        meta.primitive(
            "/vehicle/trajectory",
            "POLYLINE",
            coordinate="VEHICLE_RELATIVE",
            style={"stroke_color": "#47B27588", "stroke_width": 1.4, "stroke_width_min_pixels": 1},
        )
        declare_cameras(meta, self.cameras)
        return meta.build()

    def convert(self, index: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of frame ``index``."""
        metadata = metadata or self.metadata()
        frame = self.read(index)
        builder = posed(metadata, frame.time, frame.pose)
        if len(frame.points):
            builder.points("/lidar/points", frame.points, intensity_colors(frame.intensity))
        self._draw_boxes(builder, frame)
        trajectory = self._trajectory(index, frame.pose)
        if len(trajectory) >= 2:
            builder.polyline("/vehicle/trajectory", trajectory)
        for stream in metadata["streams"]:  # last: the images may still be in the making
            camera = stream.removeprefix("/camera/")
            name = next((c for c in frame.images if c.lower() == camera), None)
            if stream.startswith("/camera/") and name is not None:
                builder.image(stream, frame.images[name])
        return builder.build(frame.time)

    def _trajectory(self, index: int, pose: np.ndarray) -> np.ndarray:
        """The vehicle's positions over the next frames, in the vehicle frame of ``pose``."""
        ahead = range(index, min(len(self), index + TRAJECTORY_FRAMES + 1))
        world = np.array([self.pose(i)[:3, 3] for i in ahead], dtype=np.float64).reshape(-1, 3)
        return (world - pose[:3, 3]) @ pose[:3, :3]

    @staticmethod
    def _draw_boxes(builder: FrameBuilder, frame: SensorFrame) -> None:
        classes = [category_style(category) for category in frame.categories]
        draw_boxes(
            builder,
            frame.boxes,
            classes,
            [CATEGORY_COLORS.get(c, _OTHER) for c in classes],
            frame.ids,
            [f"{category} {object_id}" for category, object_id in zip(frame.categories, frame.ids)],
        )


def declare_boxes(meta: MetadataBuilder, colors: Mapping[str, str]) -> None:
    """The streams :func:`draw_boxes` draws on, with a style class per name of ``colors`` (a colour each)."""
    classes = {name: {"fill_color": color + "80", "stroke_color": color} for name, color in colors.items()}
    meta.primitive(
        "/objects/boxes",
        "POLYGON",
        coordinate="VEHICLE_RELATIVE",
        style={"extruded": True, "fill_color": "#00000080"},
        style_classes=classes,
    )
    meta.primitive(
        "/objects/label", "TEXT", coordinate="VEHICLE_RELATIVE", style={"text_size": 14, "fill_color": "#DCDCCD"}
    )


def declare_cameras(meta: MetadataBuilder, cameras: Sequence[str]) -> None:
    """An image stream per camera (``/camera/<name in lower case>``) and a panel showing them."""
    for camera in cameras:
        meta.primitive(f"/camera/{camera.lower()}", "IMAGE")
    if cameras:
        meta.ui_panel(ui.panel("Cameras", ui.video([f"/camera/{c.lower()}" for c in cameras])))


def posed(metadata: dict[str, Any], time: float, pose: np.ndarray) -> FrameBuilder:
    """A frame's builder, with ``/vehicle_pose`` at ``time`` from a (4, 4) vehicle-to-world transform."""
    builder = FrameBuilder(metadata)
    builder.pose("/vehicle_pose", time, position=pose[:3, 3].tolist(), orientation=pose_angles(pose[:3, :3]))
    return builder


def draw_boxes(
    builder: FrameBuilder,
    boxes: np.ndarray,
    classes: Sequence[str],
    colors: Sequence[str],
    ids: Sequence[str],
    texts: Sequence[str],
) -> None:
    """Boxes (N, 7: centre x, y, z, length, width, height, yaw) on ``/objects/boxes`` as footprints extruded to their
    height, outlined in their colour and styled by their class, and their texts above them on ``/objects/label``."""
    if not len(boxes):
        return
    bottoms = boxes[:, :3] - np.stack([np.zeros(len(boxes)), np.zeros(len(boxes)), boxes[:, 5] / 2], axis=1)
    corners = footprints(bottoms, boxes[:, 6], boxes[:, 3], boxes[:, 4])
    for box, style_class, color, object_id, text, polygon in zip(boxes, classes, colors, ids, texts, corners):
        # The height is the box's own; the schema wants a colour beside it: the class's outline.
        style = {"stroke_color": color, "height": float(box[5])}
        builder.polygon("/objects/boxes", polygon, id=str(object_id), classes=[style_class], style=style)
        builder.text("/objects/label", box[:3] + [0, 0, box[5] / 2 + 0.5], text, id=str(object_id))


def frame_clock(base: Sequence[int], captures: Mapping[str, Sequence[int]]) -> list[int]:
    """Frame times that serve every capture: ``base`` (each sweep, say), and the time of each capture that would
    otherwise share a frame with another of its sensor, or come after the last frame.

    A capture is served in the first frame at or after its time (:func:`frame_of`); so every capture of
    ``captures`` (each sensor's times) has a frame, and no frame has two of one sensor.
    """
    times = sorted(set(base))
    for stamps in captures.values():
        while True:
            added: set[int] = set()
            taken: dict[int, int] = {}
            for stamp in sorted(stamps):
                index = bisect.bisect_left(times, stamp)
                if index == len(times):
                    added.add(stamp)
                elif index in taken:
                    added.add(taken[index])  # the earlier of the two gets a frame of its own
                taken[index] = stamp
            if not added:
                break
            times = sorted(set(times) | added)
    return times


def frame_of(times: Sequence[int], stamp: int) -> int:
    """The frame a capture at ``stamp`` is served in: the first at or after it (see :func:`frame_clock`)."""
    return bisect.bisect_left(times, stamp)


def captures_by_frame(times: Sequence[int], captures: Mapping[str, Sequence[tuple[int, T]]]) -> list[dict[str, T]]:
    """Per frame of a :func:`frame_clock`, what each sensor captured that is served in it (see :func:`frame_of`);
    ``captures`` are each sensor's (time, what) in time order."""
    frames: list[dict[str, T]] = [{} for _ in times]
    for sensor, items in captures.items():
        for stamp, item in items:
            frames[frame_of(times, stamp)][sensor] = item
    return frames


def moved(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(N, 3) points turned by ``rotation`` (3, 3) then shifted by ``translation``, as float32.

    Column by column rather than a matrix product: for a few columns and many
    rows, numpy's element-wise work is several times faster than a BLAS call,
    and keeps to one thread.
    """
    columns = [np.asarray(points[:, k], dtype=np.float64) for k in range(3)]
    out = np.empty((len(points), 3), np.float32)
    for row in range(3):
        out[:, row] = (
            columns[0] * rotation[row, 0]
            + columns[1] * rotation[row, 1]
            + columns[2] * rotation[row, 2]
            + translation[row]
        )
    return out


def to_vehicle(pose: np.ndarray, centers: np.ndarray, yaws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World box centres (N, 3) and headings (N,) in the vehicle frame of ``pose``."""
    centers = (np.asarray(centers, dtype=np.float64).reshape(-1, 3) - pose[:3, 3]) @ pose[:3, :3]
    return centers, np.asarray(yaws, dtype=np.float64) - yaw_of(pose[:3, :3])


def file_size(file: Path | StoreTree) -> int:
    """The size of a file a frame reads, as its folder or its store's listing says (0 if it has none: reading it then
    fails by name)."""
    try:
        return file.stat().st_size if isinstance(file, Path) else file.files.get(file.key, 0)
    except OSError:
        return 0


def columns_of(table: Any, names: Sequence[str], where: object) -> list[np.ndarray]:
    """The columns ``names`` of a table (a pyarrow Table or a pandas DataFrame) as arrays; a
    :class:`DatasetError` naming ``where`` and every column it lacks."""
    have = set(table.column_names if hasattr(table, "column_names") else table.columns)
    missing = [name for name in names if name not in have]
    if missing:
        raise DatasetError(f"{where}: no column {', '.join(missing)}", path=where)
    return [table[name].to_numpy() for name in names]


def check_points(data: np.ndarray, where: str, path: object) -> np.ndarray:
    """``data`` if every value is finite; else a :class:`DatasetError` naming ``where``."""
    if not np.isfinite(data).all():
        raise DatasetError(f"{where}: points that are not finite numbers", path=path)
    return data
