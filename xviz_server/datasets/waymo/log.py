"""What both layouts of a Waymo segment give: a :class:`WaymoFrame` per frame, and the log made of them.

:class:`WaymoLog` makes the metadata and state updates (see
:mod:`xviz_server.datasets.waymo` for the streams); a layout only reads its
frames: :class:`~xviz_server.datasets.waymo.npz.WaymoSegment` and
:class:`~xviz_server.datasets.waymo.segment.WaymoRecordSegment`.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ...builder import FrameBuilder, MetadataBuilder, ui
from ...exceptions import DatasetError
from ...storepath import StorePath
from ..shared import footprints, intensity_colors, pose_angles

__all__ = ["LIDARS", "CAMERAS", "TYPES", "TYPE_COLORS", "SUFFIX", "WaymoFrame", "WaymoLog"]

LIDARS = ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")
CAMERAS = ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT")
TYPES = {0: "Unknown", 1: "Vehicle", 2: "Pedestrian", 3: "Sign", 4: "Cyclist"}
TYPE_COLORS = {"Vehicle": "#50B3FF", "Pedestrian": "#FFC6AF", "Sign": "#F5D24C", "Cyclist": "#957FCE", "Unknown": "#E2E2E2"}
SUFFIX = ".tfrecord"



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
