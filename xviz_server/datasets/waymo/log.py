"""What both layouts of a Waymo segment give: a :class:`WaymoFrame` per frame, and the log made of them.

:class:`WaymoLog` makes the metadata and state updates (see
:mod:`xviz_server.datasets.waymo` for the streams); a layout only reads its
frames: :class:`~xviz_server.datasets.waymo.npz.WaymoSegment` and
:class:`~xviz_server.datasets.waymo.segment.WaymoRecordSegment`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from ...builder import FrameBuilder, MetadataBuilder
from ...exceptions import DatasetError
from ..sensors import DriveLog, declare_boxes, declare_cameras, draw_boxes, posed
from ..shared import intensity_colors

__all__ = ["LIDARS", "CAMERAS", "TYPES", "TYPE_COLORS", "SUFFIX", "WaymoFrame", "WaymoLog", "ScaledImages"]

LIDARS = ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")
CAMERAS = ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT")
TYPES = {0: "Unknown", 1: "Vehicle", 2: "Pedestrian", 3: "Sign", 4: "Cyclist"}
TYPE_COLORS = {
    "Vehicle": "#50B3FF",
    "Pedestrian": "#FFC6AF",
    "Sign": "#F5D24C",
    "Cyclist": "#957FCE",
    "Unknown": "#E2E2E2",
}
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


class WaymoLog(DriveLog[WaymoFrame]):
    """A segment of any layout: metadata and state updates from its :class:`WaymoFrame` s."""

    image_max_width: int

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
        meta.log_info(
            start_time=float(self.times[0]), end_time=float(self.times[-1]), source=f"Waymo segment {self.name}"
        )
        meta.pose("/vehicle_pose")
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 1})
        meta.primitive(
            "/lidar/no_label_zone",
            "POINT",
            coordinate="VEHICLE_RELATIVE",
            style={"radius_pixels": 1, "fill_color": "#80808080"},
        )
        declare_boxes(meta, TYPE_COLORS)
        declare_cameras(meta, [c for c in CAMERAS if c in self._first.images])
        return meta.build()

    def convert(self, index: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of frame ``index``."""
        metadata = metadata or self.metadata()
        frame = self.read(index)
        builder = posed(metadata, frame.time, frame.pose)
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
        names = [TYPES.get(int(kind), "Unknown") for kind in frame.types]
        draw_boxes(
            builder,
            frame.boxes,
            names,
            [TYPE_COLORS[name] for name in names],
            frame.ids,
            [f"{name} {object_id}" for name, object_id in zip(names, frame.ids)],
        )


class ScaledImages(Mapping[str, bytes]):
    """A frame's camera images while they are scaled: the cameras at once, an image when it is done.

    Getting an image whose scaling failed raises
    :class:`~xviz_server.exceptions.DatasetError` naming the record and the
    camera.
    """

    def __init__(self, scaling: dict[str, Future[bytes]], where: str, path: object) -> None:
        self._scaling, self._where, self._path = scaling, where, path

    def __getitem__(self, camera: str) -> bytes:
        try:
            return self._scaling[camera].result()
        except DatasetError as exc:
            raise DatasetError(f"{self._where}: camera {camera}: {exc}", path=self._path) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._scaling)

    def __len__(self) -> int:
        return len(self._scaling)
