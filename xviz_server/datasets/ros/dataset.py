"""A bag as a dataset: its clock, its pose, and each frame converted to XVIZ on demand.

Frames are the ticks of a clock: by default each message of the densest
``PointCloud2`` topic (else ``LaserScan``), else 10 Hz over the bag's span
(the last tick at or after the last message). A frame holds, for every
stream, the latest message recorded at or before its tick and not more than
the staleness limit (1 s by default) before it, and the vehicle pose
interpolated at the tick. The first frame also shows what was recorded
before it, however old, and the last what was recorded after it.

The pose comes from, in this order: ``/tf`` or another transform topic (the
vehicle frame in the root of its tree: map, odom, world; a tree whose root
is the child frame of a ``nav_msgs/Odometry`` topic is the robot's alone,
and that topic moves it), a
``nav_msgs/Odometry`` topic, a ``geometry_msgs/PoseStamped`` or
``PoseWithCovarianceStamped`` topic (the earliest of a type; the other pose
topics, Odometry too, are drawn as trajectories), and
last a ``sensor_msgs/NavSatFix`` topic (east-north-up metres from the first
fix, heading from a ``sensor_msgs/Imu`` topic if there is one). The first
fix of a NavSatFix topic is the ``map_origin``: the origin of the pose's
frame is taken to be where that fix was. A bag with no pose source gets the
identity pose. The vehicle frame is ``base_link`` if the transform tree
has it, else the one the pose is given for, else the first cloud's.

Point clouds are drawn in the vehicle frame: a cloud whose frame is fixed
to the vehicle (``/tf_static``) gets that transform in the metadata and
its points as recorded; one whose frame moves is transformed each frame. A
topic whose messages do not decode, or whose frame cannot be resolved, is
left out of the frames it would be in, with a warning naming the file and
topic; the rest of the frame is served.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ...builder import FrameBuilder, MetadataBuilder, ui
from ...exceptions import DatasetError, FrameSizeError, OversizeError
from ...records import RECORD_BYTES, OriginalTopic, pack
from ...store.path import StorePath, data_path
from ...unpack import MAX_FRAME_BYTES, size_text
from .. import DEFAULT_IMAGE_WIDTH
from .bag import is_rosbag, open_bag
from .config import RosConfig, load_config
from .geometry import IDENTITY, apply, enu, from_pose, from_quaternion, interpolate, rpy
from .mapping import (
    CLOUD,
    COMPRESSED_IMAGE,
    IMU,
    LASER_SCAN,
    MARKER_STREAMS,
    NAV_SAT_FIX,
    ODOMETRY,
    POSE_TYPES,
    SERIES,
    Mapping,
    plan,
)
from .markers import draw_marker, live_markers, path_vertices
from .sensors import cloud_points, compressed_image_bytes, image_bytes, scan_points
from .tf import TF, Snapshot, TransformTree, frame_name

__all__ = ["RosBag", "PoseSource", "POSE_STREAM", "MAX_FRAME_MESSAGES"]

logger = logging.getLogger(__name__)

POSE_STREAM = "/vehicle_pose"
DEFAULT_RATE = 10.0  # Hz, when the bag has no point cloud
#: The most original messages a frame may have (each is a message to every client that subscribes to its topic).
MAX_FRAME_MESSAGES = 100_000
_FIXED_FRAMES = ("map", "odom", "world")
#: The most messages a text table or a trajectory shows in a frame (the latest).
MAX_SHOWN = 200
_TEXT_COLUMNS: list[tuple[str, str] | tuple[str, str, str]] = [
    ("time", "DOUBLE", "s"),
    ("level", "STRING"),
    ("node", "STRING"),
    ("text", "STRING"),
]
_LEVELS = {
    1: "DEBUG",
    2: "INFO",
    4: "WARN",
    8: "ERROR",
    16: "FATAL",
    10: "DEBUG",
    20: "INFO",
    30: "WARN",
    40: "ERROR",
    50: "FATAL",
}
_FIRST_FIXES = 100  # fixes looked at for the map origin: the first with a position (status >= 0) wins
_MARKER_STYLES: dict[str, dict[str, Any]] = {
    "polygons": {"extruded": True, "fill_color": "#50B3FF80", "stroke_color": "#50B3FF"},
    "polylines": {"stroke_color": "#FFC043", "stroke_width": 0.2, "stroke_width_min_pixels": 1},
    "points": {"fill_color": "#FFC043", "radius_pixels": 3},
    "circles": {"fill_color": "#FFC04380"},
    "texts": {"fill_color": "#DCDCCD", "text_size": 14},
}


@dataclass(frozen=True)
class PoseSource:
    """Where the vehicle pose comes from: ``kind`` is ``tf``, ``topic``, ``fix`` or ``none``."""

    kind: str
    vehicle_frame: str
    topic: str | None = None
    fixed_frame: str | None = None
    imu_topic: str | None = None

    def describe(self) -> str:
        if self.kind == "tf":
            return f"{self.topic}: {self.fixed_frame} -> {self.vehicle_frame}"
        if self.kind == "fix":
            heading = f", heading from {self.imu_topic}" if self.imu_topic else ", no heading"
            return f"{self.topic}: east-north-up from the first fix{heading}"
        if self.kind == "topic":
            return f"{self.topic} ({self.fixed_frame} -> {self.vehicle_frame})"
        return "none: the vehicle stays at the origin"


@dataclass
class RosBag:
    """A ROS 1 bag, ROS 2 bag or MCAP file served as a log, converted frame by frame.

    ``config`` is the path of a TOML configuration (see
    :mod:`~xviz_server.datasets.ros.config`); its ``image_max_width`` wins
    over the argument. Picklable: a copy reopens the bag from its index.
    Opening a damaged bag raises :class:`~xviz_server.exceptions.DatasetError`
    naming the file.
    """

    path: Path | StorePath
    image_max_width: int = DEFAULT_IMAGE_WIDTH
    config: str | None = None
    name: str = field(init=False)

    def __post_init__(self) -> None:
        self.path = data_path(self.path)
        if not is_rosbag(self.path):
            raise DatasetError(
                f"{self.path}: not a ROS bag (a .bag or .mcap file, or a ROS 2 bag folder with metadata.yaml)",
                path=self.path,
            )
        self.name = self.path.stem if self.path.is_file() else self.path.name
        self.settings: RosConfig = load_config(self.config)
        self.bag = open_bag(self.path)
        self._staleness = int(self.settings.staleness * 1e9)
        self.tree = TransformTree(self.bag, self._staleness)
        self._warned: set[str] = set()
        if not any(len(topic) for topic in self.bag.topics.values()):
            raise DatasetError(f"{self.path}: the bag holds no message", path=self.path)
        if self.settings.clock is not None and self.settings.clock not in self.bag.topics:
            raise DatasetError(f"{self.config}: clock: the bag has no topic {self.settings.clock}", path=self.config)

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "image_max_width": self.image_max_width, "config": self.config}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)  # type: ignore[misc]

    # -- the plan -----------------------------------------------------------

    @cached_property
    def pose_source(self) -> PoseSource:
        """Where the vehicle pose comes from (see the module documentation)."""
        choice = self.settings.pose
        frames = self.tree.frames
        vehicle = (
            frame_name(self.settings.vehicle_frame)
            if self.settings.vehicle_frame
            else ("base_link" if "base_link" in frames else None)
        )
        if choice == "none":
            return PoseSource("none", vehicle or self._first_cloud_frame())
        carrier = None
        if choice in (None, TF):
            source = self._tf_source(vehicle) if self.tree.has_tf else None
            carrier = self._odometry_of(source.fixed_frame) if source is not None and choice is None else None
            if source is not None and carrier is None:
                return source
            if choice == TF:
                raise DatasetError(f"{self.config}: pose: /tf does not move {vehicle or 'any frame'}", path=self.config)
        topics = self.bag.topics
        if carrier is not None:  # the tree is the robot's alone: the odometry moves its root
            candidates = [carrier]
        elif choice not in (None, TF):
            if choice not in topics or topics[choice].msgtype not in POSE_TYPES:
                raise DatasetError(
                    f"{self.config}: pose: {choice} is not a topic of {', '.join(POSE_TYPES)}", path=self.config
                )
            candidates = [choice]
        else:
            candidates = sorted(
                (
                    t
                    for t, info in topics.items()
                    if info.msgtype in POSE_TYPES and len(info) and self.settings.wants(t)
                ),
                key=lambda t: (POSE_TYPES.index(topics[t].msgtype), int(topics[t].times[0])),
            )  # the earliest
        if not candidates:
            return PoseSource("none", vehicle or self._first_cloud_frame())
        topic = candidates[0]
        msgtype = topics[topic].msgtype
        if msgtype == NAV_SAT_FIX:
            imu = next(
                (t for t, info in topics.items() if info.msgtype == IMU and len(info) and self.settings.wants(t)), None
            )
            return PoseSource("fix", vehicle or self._first_cloud_frame(), topic, imu_topic=imu)
        _, first = self.bag.message(topic, 0)
        child = frame_name(first.child_frame_id) if msgtype == ODOMETRY else None
        return PoseSource(
            "topic", vehicle or child or self._first_cloud_frame(), topic, frame_name(first.header.frame_id)
        )

    def _odometry_of(self, frame: str | None) -> str | None:
        """The earliest ``Odometry`` topic whose child frame is ``frame`` (the root of a transform tree), if any."""
        topics = self.bag.topics
        odometry = (
            t for t, info in topics.items() if info.msgtype == ODOMETRY and len(info) and self.settings.wants(t)
        )
        for topic in sorted(odometry, key=lambda t: int(topics[t].times[0])):
            if frame_name(self.bag.message(topic, 0)[1].child_frame_id) == frame:
                return topic
        return None

    def _tf_source(self, vehicle: str | None) -> PoseSource | None:
        moving = self.tree.moving
        if vehicle is None:
            leaves = sorted(set(moving) - set(moving.values()))
            vehicle = next((f for f in leaves if "base" in f), leaves[0] if leaves else None)
        if vehicle is None:
            return None
        parents = {**{c: (p, IDENTITY) for c, p in moving.items()}, **self.tree.static}
        root, _ = Snapshot(parents).to_root(vehicle)
        if self.settings.fixed_frame:  # the pair chosen
            fixed = frame_name(self.settings.fixed_frame)
            if fixed not in self.tree.frames or fixed == vehicle:
                raise DatasetError(
                    f"{self.config}: fixed_frame: the transform tree has no frame {fixed} apart from the vehicle's",
                    path=self.config,
                )
            return PoseSource("tf", vehicle, self.tree.dynamic, fixed_frame=fixed)
        chain, frame = set(), vehicle
        while frame in parents and frame != root:
            chain.add(frame)
            frame = parents[frame][0]
        if root == vehicle or not chain & moving.keys():
            return None
        return PoseSource("tf", vehicle, self.tree.dynamic, fixed_frame=root)

    def _first_cloud_frame(self) -> str:
        clouds = [
            t for t, info in self.bag.topics.items() if info.msgtype == CLOUD and len(info) and self.settings.wants(t)
        ]
        if not clouds:
            return "base_link"
        return frame_name(self._first(clouds[0]).header.frame_id)

    def _first(self, topic: str) -> Any:
        """The first message of ``topic`` (its frame id is the topic's), refused unread if it alone is over the frame budget."""
        total = sum(self.bag.declared(topic, 0, 1).values())
        if total > MAX_FRAME_BYTES:
            raise FrameSizeError(
                f"{self.path}: topic {topic}: its first message would unpack {size_text(total)}, more than the limit of "
                f"{size_text(MAX_FRAME_BYTES)} for one frame: refused unread",
                size=total,
                limit=MAX_FRAME_BYTES,
                frame=0,
                path=self.path,
            )
        return self.bag.message(topic, 0)[1]

    @cached_property
    def mappings(self) -> list[Mapping]:
        """What every topic becomes."""
        source = self.pose_source
        mappings = plan(self.bag, self.settings, source.topic if source.kind in ("topic", "fix") else None)
        streams = [s for m in mappings for s in m.streams()]
        if POSE_STREAM in streams or len(set(streams)) != len(streams):
            twice = sorted({s for s in streams if streams.count(s) > 1 or s == POSE_STREAM})
            raise DatasetError(
                f"{self.config or self.path}: streams named twice: {', '.join(twice)}", path=self.config or self.path
            )
        return mappings

    @cached_property
    def cloud_transforms(self) -> dict[str, np.ndarray | None]:
        """For each mapped cloud topic, its fixed transform into the vehicle frame; ``None`` when it moves."""
        static = self.tree.static_snapshot()
        vehicle = self.pose_source.vehicle_frame
        result: dict[str, np.ndarray | None] = {}
        for mapping in self.mappings:
            if (
                mapping.role == "points"
                and len(self.bag.topics[mapping.topic])
                and mapping.topic not in self.bag.problems
            ):
                frame = frame_name(self._first(mapping.topic).header.frame_id)
                result[mapping.topic] = IDENTITY if frame == vehicle else static.lookup(frame, vehicle)
        return result

    @cached_property
    def clock(self) -> np.ndarray:
        """The tick of every frame, int64 ns of record time."""
        if self.settings.clock is not None:
            return self.bag.topics[self.settings.clock].times
        clouds = [self.bag.topics[m.topic] for m in self.mappings if m.role == "points"]
        if self.settings.rate is None and clouds and max(len(c) for c in clouds):
            return max(clouds, key=lambda c: (c.msgtype == CLOUD, len(c))).times  # PointCloud2 before LaserScan
        mapped = [self.bag.topics[m.topic].times for m in self.mappings if m.role != "excluded"]
        every = np.concatenate([t for t in mapped if len(t)] or [t.times for t in self.bag.topics.values() if len(t)])
        step = int(1e9 / (self.settings.rate or DEFAULT_RATE))
        return np.arange(
            int(every.min()), int(every.max()) + step, step, dtype=np.int64
        )  # the last tick at or after the last message

    @cached_property
    def times(self) -> np.ndarray:
        """UNIX time of every frame, seconds."""
        return self.clock / 1e9

    def __len__(self) -> int:
        return len(self.clock)

    @cached_property
    def map_origin(self) -> tuple[float, float, float] | None:
        """Longitude, latitude and altitude of the first fix (with a position) of the first NavSatFix topic, if any."""
        topics = [
            t
            for t, info in self.bag.topics.items()
            if info.msgtype == NAV_SAT_FIX and len(info) and self.settings.wants(t)
        ]
        if self.pose_source.kind == "fix":
            topics.insert(0, self.pose_source.topic)  # type: ignore[arg-type]
        for topic in topics:
            for index in range(min(len(self.bag.topics[topic]), _FIRST_FIXES)):
                _, fix = self.bag.message(topic, index)
                if np.isfinite([fix.latitude, fix.longitude, fix.altitude]).all() and fix.status.status >= 0:
                    return (float(fix.longitude), float(fix.latitude), float(fix.altitude))
        return None

    # -- the original messages ------------------------------------------------

    @cached_property
    def originals(self) -> tuple[OriginalTopic, ...]:
        """The topics served as the file holds them (every one with messages that the configuration wants)."""
        found = (self.bag.original(t) for t, info in self.bag.topics.items() if len(info) and self.settings.wants(t))
        return tuple(topic for topic in found if topic is not None)

    def original_messages(self, frame: int) -> bytes:
        """The messages of :attr:`originals` recorded from ``frame``'s tick to the next one's, as the file holds
        them, in time order, packed (:func:`~xviz_server.records.pack`; a record's channel is its topic's place
        in :attr:`originals`). The first frame also has every message before its tick, the last every one after.

        Raises :class:`~xviz_server.exceptions.FrameSizeError` when the frame
        would unpack more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES`
        (see :meth:`frame_parts`), :class:`~xviz_server.exceptions.OversizeError`
        when its messages pass it as they are read, and
        :class:`~xviz_server.exceptions.DatasetError` when they are more than
        :data:`MAX_FRAME_MESSAGES` or a message cannot be read.
        """
        self._check_frame(frame)
        start, stop = self._span(frame)
        found: list[tuple[int, int, bytes | memoryview]] = []
        size = 0
        for number, original in enumerate(self.originals):
            for time, _, data in self.bag.serialized(original.topic, start, stop):
                size += RECORD_BYTES + len(data)
                if size > MAX_FRAME_BYTES:
                    raise OversizeError(
                        f"{self.path}: frame {frame}: its original messages pass {MAX_FRAME_BYTES} bytes (at {original.topic})",
                        size=size,
                        limit=MAX_FRAME_BYTES,
                        path=self.path,
                    )
                found.append((number, time, data))
                if len(found) > MAX_FRAME_MESSAGES:
                    raise DatasetError(
                        f"{self.path}: frame {frame}: more than {MAX_FRAME_MESSAGES} original messages", path=self.path
                    )
        found.sort(key=lambda record: (record[1], record[0]))
        return pack(found)

    def _span(self, frame: int) -> tuple[int | None, int | None]:
        """The record times of ``frame``'s original messages, ``[start, stop)`` ns (``None``: unbounded)."""
        start = int(self.clock[frame]) if frame > 0 else None
        stop = int(self.clock[frame + 1]) if frame + 1 < len(self.clock) else None
        return start, stop

    def frame_parts(self, frame: int) -> dict[tuple[Any, ...], int]:
        """The parts of the file (chunks, rows) that serving ``frame`` reads, each with the bytes it declares
        unpacked, from the bag's index alone: those of the latest message of each mapped topic (every marker
        message of the staleness window) and those of its original messages (:meth:`original_messages`)."""
        t = int(self.clock[frame])
        parts: dict[tuple[Any, ...], int] = {}
        for mapping in self.mappings:
            if mapping.stream is None:
                continue
            info = self.bag.topics[mapping.topic]
            if mapping.role in ("markers", "text"):
                first, last = np.searchsorted(info.times, [t - self._staleness, t + 1], side="left").tolist()
            else:
                index = info.at_or_before(t)
                if index < 0 or t - int(info.times[index]) > self._staleness:
                    continue
                first, last = index, index + 1
            parts.update(self.bag.declared(mapping.topic, first, last))
        start, stop = self._span(frame)
        for original in self.originals:
            times = self.bag.topics[original.topic].times
            first = 0 if start is None else int(np.searchsorted(times, start, side="left"))
            last = len(times) if stop is None else int(np.searchsorted(times, stop, side="left"))
            parts.update(self.bag.declared(original.topic, first, last))
        return parts

    def _check_frame(self, frame: int) -> None:
        """Refuse ``frame`` unread if its parts declare more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` in all."""
        total = sum(self.frame_parts(frame).values())
        if total > MAX_FRAME_BYTES:
            raise FrameSizeError(
                f"{self.path}: frame {frame}: its messages and images would unpack {size_text(total)}, more than the "
                f"limit of {size_text(MAX_FRAME_BYTES)} for one frame: refused unread",
                size=total,
                limit=MAX_FRAME_BYTES,
                frame=frame,
                path=self.path,
            )

    # -- XVIZ ---------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """The log's metadata, from the bag's index and the first message of each cloud topic."""
        problems = self.bag.problems
        unknown = sorted(
            f"{m.topic} ({m.msgtype}{': ' + problems[m.topic] if m.topic in problems else ''})"
            for m in self.mappings
            if m.role == "unknown"
        )
        if unknown:
            logger.info("%s: topics of types the mapping does not know, not served: %s", self.path, ", ".join(unknown))
        meta = MetadataBuilder()
        meta.log_info(
            start_time=float(self.times[0]),
            end_time=float(self.times[-1]),
            source=f"{self.bag.container} bag {self.name}",
        )
        meta.pose(POSE_STREAM)
        images, series, texts = [], [], []
        for mapping in self.mappings:
            style = self.settings.stream(mapping.topic).style
            if mapping.role == "points" and mapping.stream:
                transform = self.cloud_transforms.get(mapping.topic)
                meta.primitive(
                    mapping.stream,
                    "POINT",
                    coordinate="VEHICLE_RELATIVE",
                    transform=None if transform is None or transform is IDENTITY else transform,
                    style=style or {"fill_color": "#00a", "radius_pixels": 1},
                )
            elif mapping.role == "image" and mapping.stream:
                meta.primitive(mapping.stream, "IMAGE")
                images.append(mapping.stream)
            elif mapping.role == "text" and mapping.stream:
                meta.ui_primitive(mapping.stream, "TREETABLE")
                texts.append(mapping.stream)
            elif mapping.role in ("path", "trajectory") and mapping.stream:
                meta.primitive(
                    mapping.stream,
                    "POLYLINE",
                    coordinate="VEHICLE_RELATIVE",
                    style=style or {"stroke_color": "#47B27588", "stroke_width": 0.3, "stroke_width_min_pixels": 1},
                )
            elif mapping.role == "markers" and mapping.stream:
                for suffix, primitive_type in MARKER_STREAMS.items():
                    meta.primitive(
                        f"{mapping.stream}/{suffix}",
                        primitive_type,
                        coordinate="VEHICLE_RELATIVE",
                        style=_MARKER_STYLES[suffix],
                    )
            if mapping.msgtype in SERIES and mapping.stream and mapping.role in ("series", "pose", "trajectory"):
                for suffix, scalar_type, units, _ in SERIES[mapping.msgtype]:
                    meta.time_series(mapping.stream + suffix, scalar_type, units=units)
                    series.append(mapping.stream + suffix)
        if series:
            meta.ui_panel(ui.panel("Metrics", *(ui.metric([s], title=s) for s in series)))
        if images:
            meta.ui_panel(ui.panel("Camera", ui.video(images)))
        if texts:
            meta.ui_panel(ui.panel("Messages", *(ui.table(s, title=s) for s in texts)))
        return meta.build()

    def convert(self, frame: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of ``frame`` (the data of an ``xviz/state_update``); raises
        :class:`~xviz_server.exceptions.FrameSizeError` for a frame over the budget (see :meth:`frame_parts`)."""
        self._check_frame(frame)
        metadata = metadata or self.metadata()
        builder = FrameBuilder(metadata)
        t = int(self.clock[frame])
        snapshot = self.tree.at(t)
        pose = self._pose_at(t, snapshot)
        builder.pose(
            POSE_STREAM, t / 1e9, map_origin=self.map_origin, position=pose[:3, 3].tolist(), orientation=rpy(pose)
        )
        for mapping in self.mappings:
            if mapping.stream is None:
                continue
            try:
                self._add(builder, mapping, t, snapshot, pose, frame)
            except DatasetError as exc:
                self._warn(mapping.topic, str(exc))
        return builder.build(t / 1e9)

    def _add(
        self, builder: FrameBuilder, mapping: Mapping, t: int, snapshot: Snapshot, pose: np.ndarray, frame: int
    ) -> None:
        stream, topic = mapping.stream, mapping.topic
        assert stream is not None
        where = f"{self.path}: topic {topic}"
        # The first frame also shows what was recorded before it, the last what was recorded after it.
        info = self.bag.topics[topic]
        reach = int(info.times[-1]) if frame == len(self.clock) - 1 and len(info) and info.times[-1] > t else t
        since = min(t - self._staleness, int(info.times[0])) if frame == 0 and len(info) else t - self._staleness
        if mapping.role == "markers":
            messages = self.bag.messages(topic, since, reach + 1)
            for marker in live_markers(messages, reach):
                to_vehicle = self._resolve(marker.header.frame_id, snapshot, pose)
                if to_vehicle is None:
                    self._warn(
                        topic, f"{where}: frame {marker.header.frame_id!r} is not connected to the vehicle frame"
                    )
                    continue
                draw_marker(builder, stream, marker, to_vehicle)
            return
        if mapping.role == "text":
            rows = list(self.bag.messages(topic, max(since, self._after(topic, reach, MAX_SHOWN)), reach + 1))
            builder.treetable(
                stream, _TEXT_COLUMNS, [(i, None, _text_row(time, m)) for i, (time, m) in enumerate(reversed(rows))]
            )
            return
        if mapping.role == "trajectory":
            self._trajectory(builder, mapping, t, snapshot, pose)
        latest = self._latest(topic, reach, first=frame == 0)
        if latest is None:
            return
        time, message = latest
        if mapping.role == "points":
            config = self.settings.stream(topic)
            if mapping.msgtype == LASER_SCAN:
                points, colors = scan_points(message), None
            else:
                points, colors = cloud_points(
                    message, where, color=config.color, intensity_scale=self.settings.intensity_scale
                )
            if self.cloud_transforms.get(topic) is None:
                to_vehicle = self._resolve(message.header.frame_id, snapshot, pose)
                if to_vehicle is None:
                    self._warn(
                        topic, f"{where}: frame {message.header.frame_id!r} is not connected to the vehicle frame"
                    )
                    return
                points = apply(to_vehicle, points)
            if len(points):  # a cloud of no-return or NaN points alone draws nothing
                builder.points(stream, points, colors)
        elif mapping.role == "image":
            width = self.settings.image_max_width or self.image_max_width
            data = (compressed_image_bytes if mapping.msgtype == COMPRESSED_IMAGE else image_bytes)(
                message, width, where
            )
            builder.image(stream, data)
        elif mapping.role == "path":
            vertices = path_vertices(message, lambda frame: self._resolve(frame, snapshot, pose))
            if vertices is not None and len(vertices) >= 2:
                builder.polyline(stream, vertices)
        if mapping.msgtype in SERIES:
            for suffix, _, _, value in SERIES[mapping.msgtype]:
                builder.time_series(stream + suffix, time / 1e9, value(message))

    def _after(self, topic: str, t: int, count: int) -> int:
        """The record time of the ``count``-th message of ``topic`` before ``t`` (the first one's if fewer)."""
        info = self.bag.topics[topic]
        return int(info.times[max(info.at_or_before(t) - count + 1, 0)]) if len(info) else t + 1

    def _trajectory(
        self, builder: FrameBuilder, mapping: Mapping, t: int, snapshot: Snapshot, pose: np.ndarray
    ) -> None:
        """A pose topic other than the pose source: a polyline of its positions up to ``t`` (at most
        :data:`MAX_SHOWN`, evenly spaced), in the vehicle frame."""
        info = self.bag.topics[mapping.topic]
        last = info.at_or_before(t)
        if last < 1:
            return
        indices = np.unique(np.linspace(0, last, min(last + 1, MAX_SHOWN)).astype(int))
        messages = [self.bag.message(mapping.topic, int(i))[1] for i in indices]
        to_vehicle = self._resolve(messages[-1].header.frame_id, snapshot, pose)
        if to_vehicle is None:
            self._warn(
                mapping.topic,
                f"{self.path}: topic {mapping.topic}: frame {messages[-1].header.frame_id!r} is not connected to the vehicle frame",
            )
            return
        builder.polyline(mapping.stream, apply(to_vehicle, np.array([_message_pose(m)[:3, 3] for m in messages])))  # type: ignore[arg-type]

    def _warn(self, topic: str, message: str) -> None:
        if topic not in self._warned:
            self._warned.add(topic)
            logger.warning("%s (left out of the frames)", message)

    def _latest(self, topic: str, t: int, first: bool = False) -> tuple[int, Any] | None:
        """The message of ``topic`` shown at ``t``: the latest at or before it within the staleness; at the first
        frame, the latest before it however old, else the first one if it comes before the second frame."""
        info = self.bag.topics[topic]
        index = info.at_or_before(t)
        if first and index < 0 and len(info) and (len(self.clock) == 1 or info.times[0] < self.clock[1]):
            index = 0
        if index < 0 or (not first and t - int(info.times[index]) > self._staleness):
            return None
        return self.bag.message(topic, index)

    def _resolve(self, frame_id: str, snapshot: Snapshot, pose: np.ndarray) -> np.ndarray | None:
        """The transform from ``frame_id`` into the vehicle frame at the snapshot's time."""
        frame, source = frame_name(frame_id), self.pose_source
        if frame == source.vehicle_frame:
            return IDENTITY
        found = snapshot.lookup(frame, source.vehicle_frame)
        if found is None and (
            frame == source.fixed_frame or (source.kind in ("fix", "none") and frame in _FIXED_FRAMES)
        ):
            return np.linalg.inv(pose)
        return found

    def _pose_at(self, t: int, snapshot: Snapshot) -> np.ndarray:
        """The vehicle's transform in the pose's fixed frame at ``t`` ns."""
        source = self.pose_source
        if source.kind == "tf":
            found = snapshot.lookup(source.vehicle_frame, source.fixed_frame)  # type: ignore[arg-type]
            return IDENTITY if found is None else found
        if source.kind == "none":
            return IDENTITY
        assert source.topic is not None
        if source.kind == "topic":
            return self._interpolated(source.topic, t, _message_pose)
        origin = self.map_origin
        position = (
            IDENTITY if origin is None else self._interpolated(source.topic, t, lambda fix: _fix_position(fix, origin))
        )
        if source.imu_topic is None:
            return position
        heading = self._interpolated(source.imu_topic, t, _imu_rotation)
        result = heading.copy()
        result[:3, 3] = position[:3, 3]
        return result

    def _interpolated(self, topic: str, t: int, pose_of: Any) -> np.ndarray:
        """A pose topic at ``t``: interpolated between the messages around it, the first or last outside them."""
        info = self.bag.topics[topic]
        index = info.at_or_before(t)
        if index < 0:
            return pose_of(self.bag.message(topic, 0)[1])
        before_time, before = self.bag.message(topic, index)
        if before_time == t or index + 1 >= len(info):
            return pose_of(before)
        after_time, after = self.bag.message(topic, index + 1)
        return interpolate(pose_of(before), pose_of(after), (t - before_time) / (after_time - before_time))


def _text_row(time: int, message: Any) -> list[Any]:
    """A text message as a table row: time (s), level, node and text (``std_msgs/String``: its data alone)."""
    if hasattr(message, "msg"):
        return [time / 1e9, _LEVELS.get(int(message.level), str(message.level)), str(message.name), str(message.msg)]
    return [time / 1e9, "", "", str(message.data)]


def _message_pose(message: Any) -> np.ndarray:
    pose = message.pose.pose if hasattr(message.pose, "pose") else message.pose  # Odometry, WithCovariance
    return from_pose(pose)


def _fix_position(fix: Any, origin: tuple[float, float, float]) -> np.ndarray:
    result = np.eye(4)
    result[:3, 3] = enu(fix.latitude, fix.longitude, fix.altitude, (origin[1], origin[0], origin[2]))
    return result


def _imu_rotation(imu: Any) -> np.ndarray:
    return from_quaternion(imu.orientation)
