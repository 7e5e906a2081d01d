"""XVIZ streams as Foxglove channels, and XVIZ frames as Foxglove messages (pure: bytes in, bytes out).

:func:`plan` reads a log's metadata once and gives its channels: a stream
becomes a channel of one of Foxglove's well-known messages where one fits,
and a JSON channel with a JSON Schema otherwise:

============================  ==============================================
XVIZ stream                   Foxglove channels
============================  ==============================================
pose (``/vehicle_pose``)      ``foxglove.FrameTransform`` from ``map`` to the
                              stream's frame (topic: the stream's name),
                              ``foxglove.PoseInFrame`` (``<stream>/pose``),
                              ``foxglove.LocationFix`` of its map origin
                              (``<stream>/location``)
points                        ``foxglove.PointCloud`` (x, y, z as float32 and
                              red, green, blue, alpha as uint8 when coloured)
images                        ``foxglove.CompressedImage``
polygons, polylines, circles, ``foxglove.SceneUpdate``, one entity per object
texts, stadiums               (its XVIZ object id when it has one)
time series                   JSON ``{"timestamp", "value"}``, the value of
                              one JSON type: the stream's ``scalar_type``,
                              else its first value's (:func:`survey`)
anything else                 JSON: the stream's XVIZ content as it is
============================  ==============================================

A pose is placed in ``map``, whose origin is the log's (its first
``map_origin``): a pose's translation is its ``position`` plus the east,
north and up metres of its own ``map_origin`` from the log's, so that the
vehicle moves as in streetscape.gl whether a log moves it by its position
or by its map origin.

A primitive stream's frame is the pose stream's frame when its coordinate
is ``VEHICLE_RELATIVE`` and ``map`` otherwise; its ``transform`` (a 4 x 4
matrix) becomes the pose of each point cloud and primitive in that frame.

:func:`convert` turns one XVIZ state update into the messages of every
channel it has data for, each stamped with the update's timestamp, packed
into one ``bytes`` (see :func:`~xviz_server.records.pack`) so that the frame cache keeps them.

A log read from a ROS bag or an MCAP file also has its original topics
(:attr:`~xviz_server.logs.Log.originals`): :func:`plan` gives each a channel
with the file's own encoding and schema, whose messages are the file's
bytes, unchanged (:meth:`~xviz_server.logs.Log.original_messages`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from ..codec import decode
from ..codec.image import sniff_image
from ..datasets.ros.geometry import enu
from ..exceptions import DecodeError
from ..records import OriginalTopic, pack
from .schemas import Schema, json_schema, protobuf_schema

__all__ = [
    "CONVERTED",
    "CONVERTED_PREFIX",
    "Channel",
    "Plan",
    "plan",
    "Survey",
    "survey",
    "read_survey",
    "first_origin",
    "convert",
    "nanoseconds",
    "ROOT_FRAME",
]

#: The frame cache's name for a frame's Foxglove messages (see :meth:`~xviz_server.logs.Log.derived`).
CONVERTED = "foxglove"

#: What the topics of converted channels start with in a log that also has its original topics.
CONVERTED_PREFIX = "/xviz"

#: The fixed frame every pose is given in.
ROOT_FRAME = "map"

_SCENE_TYPES = frozenset({"POLYGON", "POLYLINE", "CIRCLE", "TEXT", "STADIUM"})
#: The JSON type of a time series' value, by the stream's XVIZ ``scalar_type``.
_SCALAR_TYPES = {"FLOAT": "number", "INT32": "integer", "STRING": "string", "BOOL": "boolean"}


def _time_series_schema(value_type: str) -> dict[str, Any]:
    """A time series channel's JSON Schema: one JSON type for ``value``, as Foxglove's and Lichtblick's parsers need."""
    return {
        "type": "object",
        "properties": {"timestamp": {"type": "number"}, "value": {"type": value_type}},
        "required": ["timestamp", "value"],
    }


@dataclass(frozen=True)
class Channel:
    """One Foxglove channel of a log: what it carries and what it advertises."""

    id: int
    topic: str
    stream: str  #: the XVIZ stream its messages come from (``""`` for an original topic)
    #: how they are made: transform, pose, location, points, image, scene, time_series, json; original: as the file holds them
    kind: str
    schema: Schema

    def advertisement(self) -> dict[str, Any]:
        """The channel as an ``advertise`` message lists it."""
        return {
            "id": self.id,
            "topic": self.topic,
            "encoding": self.schema.encoding,
            "schemaName": self.schema.name,
            "schemaEncoding": self.schema.schema_encoding,
            "schema": self.schema.schema,
        }


@dataclass(frozen=True)
class Plan:
    """A log's channels and what :func:`convert` needs to know of its streams (picklable)."""

    channels: tuple[Channel, ...]
    #: The channel of each of the log's original topics (:attr:`~xviz_server.logs.Log.originals`), in their order.
    originals: tuple[int, ...] = ()
    #: Each stream's channels as (id, kind).
    targets: Mapping[str, tuple[tuple[int, str], ...]] = field(default_factory=dict)
    #: The frame each primitive stream is drawn in, and its pose there (position, quaternion).
    frames: Mapping[str, tuple[str, tuple[float, ...], tuple[float, ...]]] = field(default_factory=dict)
    #: The JSON type of each time series stream's value: ``number``, ``integer``, ``string`` or ``boolean``.
    values: Mapping[str, str] = field(default_factory=dict)
    #: Where ``map`` is: the log's own origin (longitude, latitude, altitude), its first pose's ``map_origin``.
    origin: tuple[float, float, float] | None = None


def plan(metadata: Mapping[str, Any], originals: Sequence[OriginalTopic] = (), first: Survey | None = None) -> Plan:
    """The channels of a log whose XVIZ metadata is ``metadata``, numbered from 1 in stream order.

    ``first`` is what :func:`survey` found in the log's first frame: the
    log's origin, and the kind of each time series' value where the metadata
    does not give its ``scalar_type`` (else ``number``).

    A log read from a recording also has a channel of each of its
    ``originals``, after the converted ones, under the topic's own name and
    with the file's encoding and schema; the converted channels' topics then
    start with :data:`CONVERTED_PREFIX`, so that no two channels share a topic.
    """
    prefix = CONVERTED_PREFIX if originals else ""
    streams = metadata.get("streams") or {}
    poses = sorted(name for name, info in streams.items() if isinstance(info, dict) and info.get("category") == "POSE")
    vehicle = "/vehicle_pose" if "/vehicle_pose" in poses else (poses[0] if poses else ROOT_FRAME)
    channels: list[Channel] = []
    targets: dict[str, tuple[tuple[int, str], ...]] = {}
    frames: dict[str, tuple[str, tuple[float, ...], tuple[float, ...]]] = {}
    values: dict[str, str] = {}
    first = first or Survey()

    def add(stream: str, topic: str, kind: str, schema: Schema) -> None:
        if prefix:
            topic = prefix + topic if topic.startswith("/") else f"{prefix}/{topic}"
        channel = Channel(len(channels) + 1, topic, stream, kind, schema)
        channels.append(channel)
        targets[stream] = (*targets.get(stream, ()), (channel.id, kind))

    for name in sorted(streams):
        info = streams[name] if isinstance(streams[name], dict) else {}
        category = str(info.get("category", "")).upper()
        primitive = str(info.get("primitive_type", "")).upper()
        if category == "POSE":
            add(name, name, "transform", protobuf_schema("FrameTransform"))
            add(name, f"{name}/pose", "pose", protobuf_schema("PoseInFrame"))
            add(name, f"{name}/location", "location", protobuf_schema("LocationFix"))
            continue
        if category == "PRIMITIVE" and primitive in _SCENE_TYPES | {"POINT", "IMAGE"}:
            kind = {"POINT": "points", "IMAGE": "image"}.get(primitive, "scene")
            message = {"points": "PointCloud", "image": "CompressedImage", "scene": "SceneUpdate"}[kind]
            add(name, name, kind, protobuf_schema(message))
            relative = str(info.get("coordinate", "")).upper() == "VEHICLE_RELATIVE"
            frames[name] = (vehicle if relative else ROOT_FRAME, *_matrix_pose(info.get("transform")))
            continue
        if category == "TIME_SERIES":
            scalar = str(info.get("scalar_type", "")).upper()
            values[name] = _SCALAR_TYPES.get(scalar) or first.values.get(name, "number")
            add(name, name, "time_series", json_schema(name, _time_series_schema(values[name])))
            continue
        description = f"the XVIZ {category.lower() or 'unknown'} stream {name} as XVIZ carries it"
        add(name, name, "json", json_schema(name, {"type": "object", "description": description}))
    ids = tuple(range(len(channels) + 1, len(channels) + 1 + len(originals)))
    channels += [
        Channel(
            id,
            original.topic,
            "",
            "original",
            Schema(original.encoding, original.schema_name, original.schema_encoding, original.schema),
        )
        for id, original in zip(ids, originals)
    ]
    return Plan(tuple(channels), ids, targets, frames, values, first.origin)


@dataclass(frozen=True)
class Survey:
    """What a log's first frame tells that its metadata may not (see :func:`survey`)."""

    #: The first ``map_origin`` of a pose (of ``/vehicle_pose`` if it has one): longitude, latitude, altitude.
    origin: tuple[float, float, float] | None = None
    #: The JSON type of each time series' first value.
    values: Mapping[str, str] = field(default_factory=dict)


def survey(data: bytes) -> bytes:
    """What the XVIZ state update ``data`` tells of its log (:class:`Survey`), as JSON (see :func:`read_survey`).

    Raises :class:`~xviz_server.exceptions.DecodeError` for a frame that is
    not a state update.
    """
    updates = _updates(decode(data))
    values: dict[str, str] = {}
    for update in updates:
        for stream, content in _streams(update):
            if isinstance(content, dict) and "value" in content and stream not in values:
                value = content["value"]
                values[stream] = (
                    "boolean" if isinstance(value, bool) else "string" if isinstance(value, str) else "number"
                )
    return orjson.dumps({"origin": first_origin(updates), "values": values})


def first_origin(updates: Sequence[Any]) -> tuple[float, float, float] | None:
    """The first ``map_origin`` of a pose in ``updates`` (an XVIZ state update's), ``/vehicle_pose``'s first:
    longitude, latitude, altitude."""
    for update in updates:
        poses = _mapping(_mapping(update).get("poses"))
        for name in sorted(poses, key=lambda name: name != "/vehicle_pose"):
            found = _mapping(poses[name]).get("map_origin")
            if isinstance(found, dict):
                try:
                    return (
                        float(found.get("longitude") or 0.0),
                        float(found.get("latitude") or 0.0),
                        float(found.get("altitude") or 0.0),
                    )
                except (TypeError, ValueError):
                    return None
    return None


def read_survey(data: bytes) -> Survey:
    """The :class:`Survey` that :func:`survey` wrote."""
    facts = orjson.loads(data)
    origin = facts.get("origin")
    return Survey(None if origin is None else (origin[0], origin[1], origin[2]), facts.get("values") or {})


def convert(data: bytes, plan: Plan) -> bytes:
    """The Foxglove messages of the XVIZ state update ``data``, packed (see :func:`~xviz_server.records.pack`).

    Raises :class:`~xviz_server.exceptions.DecodeError` for a frame that is
    not a state update.
    """
    out: list[tuple[int, int, bytes]] = []
    for update in _updates(decode(data)):
        time = nanoseconds(update["timestamp"])
        for stream, content in _streams(update):
            for channel, kind in plan.targets.get(stream, ()):
                payload = _MAKERS[kind](stream, content, time, plan)
                if payload is not None:
                    out.append((channel, time, payload))
    return pack(out)


# --------------------------------------------------------------- the streams of an update


def _updates(message: Any) -> list[dict[str, Any]]:
    """The updates of a decoded state update, each with a timestamp; raises :class:`DecodeError` otherwise."""
    updates = message.get("data", {}).get("updates") if isinstance(message, dict) else None
    if not isinstance(message, dict) or message.get("type") != "xviz/state_update" or not isinstance(updates, list):
        raise DecodeError("frame is not an xviz/state_update")
    for update in updates:
        if not isinstance(update, dict) or not isinstance(update.get("timestamp"), (int, float)):
            raise DecodeError("a state update's update has no timestamp")
    return updates


def _streams(update: Mapping[str, Any]) -> Iterator[tuple[str, Any]]:
    """(stream, content) for each stream an update carries; a time series value per stream."""
    for group in ("poses", "primitives", "variables", "future_instances", "ui_primitives", "annotations"):
        content = update.get(group)
        if isinstance(content, dict):
            yield from content.items()
    for series in update.get("time_series") or ():
        if not isinstance(series, dict):
            continue
        names = series.get("streams") or ()
        values = next((v for v in (series.get("values") or {}).values() if isinstance(v, (list, np.ndarray))), ())
        stamp = series.get("timestamp", update["timestamp"])
        for name, value in zip(names, values):
            yield name, {"timestamp": stamp, "value": value.item() if isinstance(value, np.generic) else value}


def _transform(stream: str, pose: Any, time: int, plan: Plan) -> bytes | None:
    if not isinstance(pose, dict):
        return None
    return FrameTransform(
        timestamp=_stamp(time),
        parent_frame_id=ROOT_FRAME,
        child_frame_id=stream,
        translation=_translation(pose, plan),
        rotation=_rpy_quaternion(pose.get("orientation")),
    ).SerializeToString()


def _pose(stream: str, pose: Any, time: int, plan: Plan) -> bytes | None:
    if not isinstance(pose, dict):
        return None
    place = Pose(position=_translation(pose, plan), orientation=_rpy_quaternion(pose.get("orientation")))
    return PoseInFrame(timestamp=_stamp(time), frame_id=ROOT_FRAME, pose=place).SerializeToString()


def _translation(pose: Mapping[str, Any], plan: Plan) -> Vector3:
    """Where a pose is in ``map``: its ``position`` from its ``map_origin``, plus that origin's east, north and up
    metres from the log's (:attr:`Plan.origin`), as streetscape.gl places the vehicle."""
    x, y, z = _xyz(pose.get("position")).values()
    origin = pose.get("map_origin")
    if plan.origin is not None and isinstance(origin, dict):
        longitude, latitude, altitude = plan.origin
        try:
            east, north, up = enu(
                float(origin.get("latitude") or 0.0),
                float(origin.get("longitude") or 0.0),
                float(origin.get("altitude") or 0.0),
                (latitude, longitude, altitude),
            ).tolist()
        except (TypeError, ValueError):
            east = north = up = 0.0
        x, y, z = x + east, y + north, z + up
    return Vector3(x=x, y=y, z=z)


def _location(stream: str, pose: Any, time: int, plan: Plan) -> bytes | None:
    origin = pose.get("map_origin") if isinstance(pose, dict) else None
    if not isinstance(origin, dict):
        return None
    return LocationFix(
        timestamp=_stamp(time),
        frame_id=stream,
        latitude=float(origin.get("latitude", 0.0)),
        longitude=float(origin.get("longitude", 0.0)),
        altitude=float(origin.get("altitude", 0.0)),
    ).SerializeToString()


_XYZ = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
_XYZ_RGBA = [*_XYZ, ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
_FIELDS = {
    len(_XYZ): [
        PackedElementField(name=name, offset=4 * i, type=PackedElementField.FLOAT32) for i, (name, _) in enumerate(_XYZ)
    ],
    len(_XYZ_RGBA): [
        *(
            PackedElementField(name=name, offset=4 * i, type=PackedElementField.FLOAT32)
            for i, (name, _) in enumerate(_XYZ)
        ),
        *(
            PackedElementField(name=name, offset=12 + i, type=PackedElementField.UINT8)
            for i, (name, _) in enumerate(_XYZ_RGBA[3:])
        ),
    ],
}


def _points(stream: str, content: Any, time: int, plan: Plan) -> bytes | None:
    objects = (
        [item for item in (content.get("points") or ()) if isinstance(item, dict)] if isinstance(content, dict) else []
    )
    if not objects:
        return None
    xyz = [np.asarray(item.get("points", ()), dtype=np.float32).reshape(-1, 3) for item in objects]
    coloured = all(item.get("colors") is not None for item in objects)
    dtype = np.dtype(_XYZ_RGBA if coloured else _XYZ)
    cloud = np.zeros(sum(len(part) for part in xyz), dtype=dtype)
    position = 0
    for item, part in zip(objects, xyz):
        rows = slice(position, position + len(part))
        for axis, name in enumerate("xyz"):
            cloud[name][rows] = part[:, axis]
        if coloured:
            colors = np.asarray(item["colors"], dtype=np.uint8)
            colors = colors.reshape(len(part), -1) if colors.size else np.zeros((len(part), 4), np.uint8)
            for channel, name in enumerate(("red", "green", "blue")):
                cloud[name][rows] = colors[:, channel]
            cloud["alpha"][rows] = colors[:, 3] if colors.shape[1] > 3 else 255
        position += len(part)
    frame, where, rotation = plan.frames[stream]
    return PointCloud(
        timestamp=_stamp(time),
        frame_id=frame,
        pose=_place(where, rotation),
        point_stride=dtype.itemsize,
        fields=_FIELDS[len(dtype.names or ())],
        data=cloud.tobytes(),
    ).SerializeToString()


def _image(stream: str, content: Any, time: int, plan: Plan) -> bytes | None:
    images = content.get("images") if isinstance(content, dict) else None
    image = images[0] if isinstance(images, list) and images and isinstance(images[0], dict) else None
    data = image.get("data") if image is not None else None
    if not isinstance(data, (bytes, bytearray, memoryview)):
        return None
    info = sniff_image(data)
    return CompressedImage(
        timestamp=_stamp(time),
        frame_id=stream,
        data=bytes(data),
        format="" if info is None else info.mime_type.removeprefix("image/"),
    ).SerializeToString()


def _scene(stream: str, content: Any, time: int, plan: Plan) -> bytes | None:
    if not isinstance(content, dict):
        return None
    frame, where, rotation = plan.frames[stream]
    place = _place(where, rotation)
    update = SceneUpdate(deletions=[SceneEntityDeletion(timestamp=_stamp(time), type=SceneEntityDeletion.ALL)])
    for kind, items in content.items():
        for number, item in enumerate(items if isinstance(items, list) else ()):
            if not isinstance(item, dict):
                continue
            base = _mapping(item.get("base"))
            entity = SceneEntity(
                timestamp=_stamp(time),
                frame_id=frame,
                id=str(base.get("object_id") or f"{kind}/{number}"),
                frame_locked=True,
            )
            color = _color(_mapping(base.get("style")))
            if kind in ("polygons", "polylines"):
                loop = LinePrimitive.LINE_LOOP if kind == "polygons" else LinePrimitive.LINE_STRIP
                points = [Point3(**_xyz(vertex)) for vertex in _rows(item.get("vertices"))]
                entity.lines.append(LinePrimitive(type=loop, pose=place, thickness=0.1, color=color, points=points))
            elif kind == "circles":
                radius = float(item.get("radius", 0.5))
                center = Vector3(**_xyz(item.get("center")))
                sphere_pose = Pose(position=center, orientation=Quaternion(w=1.0))
                entity.spheres.append(
                    SpherePrimitive(pose=sphere_pose, size=Vector3(x=2 * radius, y=2 * radius, z=0.01), color=color)
                )
            elif kind == "texts":
                text_pose = Pose(position=Vector3(**_xyz(item.get("position"))), orientation=Quaternion(w=1.0))
                entity.texts.append(
                    TextPrimitive(
                        pose=text_pose,
                        billboard=True,
                        font_size=14,
                        scale_invariant=True,
                        color=color,
                        text=str(item.get("text", "")),
                    )
                )
            elif kind == "stadiums":
                ends = [Point3(**_xyz(item.get("start"))), Point3(**_xyz(item.get("end")))]
                entity.lines.append(
                    LinePrimitive(
                        type=LinePrimitive.LINE_STRIP,
                        pose=place,
                        thickness=2 * float(item.get("radius", 0.5)),
                        color=color,
                        points=ends,
                    )
                )
            else:
                continue
            update.entities.append(entity)
    return update.SerializeToString()


def _time_series(stream: str, content: Any, time: int, plan: Plan) -> bytes | None:
    """``{"timestamp", "value"}`` with the value as the channel's one JSON type; none for a value that is not one."""
    value = _as_type(content["value"], plan.values.get(stream, "number"))
    if value is None:
        return None
    try:
        stamp = float(content["timestamp"])
    except (TypeError, ValueError):
        return None
    return orjson.dumps({"timestamp": stamp, "value": value})


def _as_type(value: Any, kind: str) -> float | int | str | bool | None:
    """``value`` as the JSON type ``kind`` (numbers and booleans stand for each other), or ``None``."""
    if kind == "string":
        return value if isinstance(value, str) else orjson.dumps(value, option=orjson.OPT_SERIALIZE_NUMPY).decode()
    if isinstance(value, str):
        return value.lower() == "true" if kind == "boolean" and value.lower() in ("true", "false") else None
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    if kind == "boolean":
        return bool(value)
    return int(value) if kind == "integer" else float(value)


def _json(stream: str, content: Any, time: int, plan: Plan) -> bytes | None:
    return orjson.dumps(content, default=_plain, option=orjson.OPT_SERIALIZE_NUMPY)


_MAKERS = {
    "transform": _transform,
    "pose": _pose,
    "location": _location,
    "points": _points,
    "image": _image,
    "scene": _scene,
    "time_series": _time_series,
    "json": _json,
}


# --------------------------------------------------------------- small conversions


def nanoseconds(seconds: float) -> int:
    """``seconds`` as whole nanoseconds (0 for times before 1970)."""
    return max(0, round(seconds * 1e9))


def _stamp(nanoseconds: int) -> Timestamp:
    return Timestamp(seconds=nanoseconds // 1_000_000_000, nanos=nanoseconds % 1_000_000_000)


def _rows(value: Any) -> list[Any]:
    return np.asarray(value, dtype=np.float64).reshape(-1, 3).tolist() if value is not None and len(value) else []


def _xyz(value: Any) -> dict[str, float]:
    values = [float(v) for v in (value if value is not None else ())][:3]
    values += [0.0] * (3 - len(values))
    return dict(zip("xyz", values))


def _rpy_quaternion(value: Any) -> Quaternion:
    """The rotation of XVIZ's [roll, pitch, yaw] (about x, then y, then z; radians)."""
    roll, pitch, yaw = _xyz(value).values()
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return Quaternion(
        x=sr * cp * cy - cr * sp * sy,
        y=cr * sp * cy + sr * cp * sy,
        z=cr * cp * sy - sr * sp * cy,
        w=cr * cp * cy + sr * sp * sy,
    )


def _matrix_pose(matrix: Any) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The translation and rotation (x, y, z, w) of XVIZ's column-major 4 x 4 ``transform``."""
    try:
        m = np.asarray(matrix, dtype=np.float64).reshape(4, 4).T
    except (TypeError, ValueError):
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
    w = math.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    if w < 1e-6:  # a half turn: no stream transform in the wild; keep the translation
        return tuple(m[:3, 3].tolist()), (0.0, 0.0, 0.0, 1.0)
    x, y, z = (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)
    return tuple(m[:3, 3].tolist()), (x, y, z, w)


def _place(position: tuple[float, ...], rotation: tuple[float, ...]) -> Pose:
    x, y, z, w = rotation
    return Pose(position=Vector3(**_xyz(position)), orientation=Quaternion(x=x, y=y, z=z, w=w))


def _color(style: Mapping[str, Any]) -> Color:
    """A primitive's colour: its stroke or fill colour (``#rgb[a]``, ``#rrggbb[aa]`` or a list), else white."""
    value = style.get("stroke_color", style.get("fill_color"))
    rgba = [255, 255, 255, 255]
    if isinstance(value, str) and value.startswith("#") and len(value) in (4, 5, 7, 9):
        digits = value[1:]
        step = 1 if len(digits) <= 4 else 2
        parts = [digits[i : i + step] * (2 if step == 1 else 1) for i in range(0, len(digits), step)]
        try:
            rgba[: len(parts)] = [int(part, 16) for part in parts]
        except ValueError:
            pass
    elif isinstance(value, list) and all(isinstance(v, (int, float)) for v in value):
        rgba[: len(value[:4])] = value[:4]
    return Color(r=rgba[0] / 255, g=rgba[1] / 255, b=rgba[2] / 255, a=rgba[3] / 255)


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, dict) else {}


def _plain(value: Any) -> Any:
    """What orjson cannot write itself: binary as its length (images have their own channels)."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return {"bytes": len(value)}
    raise TypeError(f"{type(value).__name__} is not JSON")
