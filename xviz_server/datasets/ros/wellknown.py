"""Foxglove's well-known schemas as their ROS counterparts, so that the default mapping serves them the same way.

A message of a Foxglove schema (``foxglove.PointCloud``, in protobuf or JSON)
becomes an object with the fields of the ROS message the mapping knows
(``sensor_msgs/msg/PointCloud2``): :data:`ROS_OF` names the type, :func:`adapt`
makes the object. JSON messages are first given attribute access
(:func:`attributes`); their ``bytes`` fields are base64, their times
``{sec, nsec}``, as the JSON schemas say. What a Foxglove message has that
its ROS counterpart lacks is left out: the pose of a ``LaserScan`` within
its frame, the colour of each ``SceneUpdate`` vertex, the velocity covariance
of an ``Odometry``. A ``PointCloud``'s pose within its frame is applied to its
points (when x, y and z are floating point; integer coordinates are left as
they are); a ``LocationFixes`` message is its first fix; a ``SceneUpdate``
model becomes a mesh marker (which, as in ROS, is not drawn).
"""

from __future__ import annotations

import base64
import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from .geometry import apply, from_pose

__all__ = ["ROS_OF", "adapt", "attributes", "nanoseconds"]

#: The ROS type each Foxglove schema becomes.
ROS_OF = {
    "foxglove.PointCloud": "sensor_msgs/msg/PointCloud2",
    "foxglove.CompressedImage": "sensor_msgs/msg/CompressedImage",
    "foxglove.RawImage": "sensor_msgs/msg/Image",
    "foxglove.FrameTransform": "tf2_msgs/msg/TFMessage",
    "foxglove.FrameTransforms": "tf2_msgs/msg/TFMessage",
    "foxglove.PoseInFrame": "geometry_msgs/msg/PoseStamped",
    "foxglove.PosesInFrame": "nav_msgs/msg/Path",
    "foxglove.Odometry": "nav_msgs/msg/Odometry",
    "foxglove.LocationFix": "sensor_msgs/msg/NavSatFix",
    "foxglove.LocationFixes": "sensor_msgs/msg/NavSatFix",
    "foxglove.SceneUpdate": "visualization_msgs/msg/MarkerArray",
    "foxglove.LaserScan": "sensor_msgs/msg/LaserScan",
    "foxglove.Log": "rcl_interfaces/msg/Log",
}

# foxglove.NumericType (by number and by name) to sensor_msgs/PointField datatypes.
_NUMERIC = {1: 2, 2: 1, 3: 4, 4: 3, 5: 6, 6: 5, 7: 7, 8: 8}
_NUMERIC_NAMES = {"UINT8": 1, "INT8": 2, "UINT16": 3, "INT16": 4, "UINT32": 5, "INT32": 6, "FLOAT32": 7, "FLOAT64": 8}
_LINE_STRIP, _LINE_LOOP, _LINE_LIST = 0, 1, 2
# visualization_msgs/Marker types and actions (see .markers).
_ARROW, _CUBE, _SPHERE, _CYLINDER, _M_LINE_STRIP, _M_LINE_LIST, _TEXT, _MESH = 0, 1, 2, 3, 4, 5, 9, 10
# sensor_msgs/PointField FLOAT32 and FLOAT64, as numpy types.
_FLOATS = {7: "f4", 8: "f8"}
_DELETEALL = 3


def attributes(value: Any) -> Any:
    """A JSON document with attribute access (objects become namespaces, recursively)."""
    if isinstance(value, dict):
        return SimpleNamespace(**{str(k): attributes(v) for k, v in value.items()})
    if isinstance(value, list):
        return [attributes(v) for v in value]
    return value


def nanoseconds(duration: Any) -> int:
    """A ROS 2 (``sec``, ``nanosec``), ROS 1 (``secs``, ``nsecs``) or Foxglove time or duration, in ns."""
    for seconds, fraction in (("sec", "nanosec"), ("secs", "nsecs"), ("sec", "nsec"), ("seconds", "nanos")):
        if hasattr(duration, seconds) and hasattr(duration, fraction):
            return int(getattr(duration, seconds)) * 1_000_000_000 + int(getattr(duration, fraction))
    return 0


def _get(message: Any, name: str, default: Any = None) -> Any:
    value = getattr(message, name, default)
    return default if value is None else value


def _bytes(value: Any) -> bytes:
    return base64.b64decode(value) if isinstance(value, str) else bytes(value or b"")


def _header(message: Any, frame: str = "frame_id") -> SimpleNamespace:
    stamp = nanoseconds(_get(message, "timestamp"))
    return SimpleNamespace(
        frame_id=str(_get(message, frame, "")), stamp=SimpleNamespace(sec=stamp // 10**9, nanosec=stamp % 10**9)
    )


def _vector(value: Any, w: float | None = None) -> SimpleNamespace:
    result = SimpleNamespace(
        x=float(_get(value, "x", 0.0)), y=float(_get(value, "y", 0.0)), z=float(_get(value, "z", 0.0))
    )
    if w is not None:
        result.w = float(_get(value, "w", w))
    return result


def _pose(value: Any) -> SimpleNamespace:
    return SimpleNamespace(
        position=_vector(_get(value, "position")), orientation=_vector(_get(value, "orientation"), 1.0)
    )


def _color(value: Any) -> SimpleNamespace:
    return SimpleNamespace(**{c: float(_get(value, c, 1.0 if c == "a" else 0.0)) for c in "rgba"})


def _numeric(value: Any) -> int:
    number = _NUMERIC_NAMES.get(value, 0) if isinstance(value, str) else int(value)
    return _NUMERIC.get(number, 0)


def _posed(data: bytes, stride: int, fields: list[SimpleNamespace], pose: Any) -> bytes:
    """``data`` with the x, y, z of each point moved by ``pose`` (the cloud's pose in its frame), if they are floats.

    Points at exactly (0, 0, 0), beams without a return, are not moved.
    """
    transform = from_pose(_pose(pose))
    xyz = {f.name: f for f in fields if f.name in ("x", "y", "z")}
    count = len(data) // stride if stride else 0
    if np.allclose(transform, np.eye(4)) or len(xyz) < 3 or not count:
        return data
    if any(f.datatype not in _FLOATS or f.offset + int(_FLOATS[f.datatype][1]) > stride for f in xyz.values()):
        return data
    layout = np.dtype(
        {
            "names": ["x", "y", "z"],
            "formats": ["<" + _FLOATS[xyz[a].datatype] for a in "xyz"],
            "offsets": [xyz[a].offset for a in "xyz"],
            "itemsize": stride,
        }
    )
    records = np.frombuffer(bytearray(data[: count * stride]), layout)
    records.flags.writeable = True
    points = np.stack([records[a] for a in "xyz"], axis=1).astype(np.float32)
    returned = (points != 0).any(axis=1)  # a beam without a return stays at (0, 0, 0), to be left out as one
    moved = apply(transform, points[returned])
    for i, axis in enumerate("xyz"):
        records[axis][returned] = moved[:, i]
    return records.tobytes()


def _cloud(m: Any) -> SimpleNamespace:
    data, stride = _bytes(_get(m, "data")), int(_get(m, "point_stride", 0))
    fields = [
        SimpleNamespace(name=f.name, offset=int(_get(f, "offset", 0)), datatype=_numeric(_get(f, "type", 0)), count=1)
        for f in _get(m, "fields", [])
    ]
    data = _posed(data, stride, fields, _get(m, "pose"))
    width = len(data) // stride if stride else 0
    return SimpleNamespace(
        header=_header(m),
        fields=fields,
        point_step=stride,
        width=width,
        height=1,
        row_step=width * stride,
        is_bigendian=False,
        is_dense=True,
        data=data,
    )


def _transform(t: Any) -> SimpleNamespace:
    return SimpleNamespace(
        header=_header(t, "parent_frame_id"),
        child_frame_id=str(_get(t, "child_frame_id", "")),
        transform=SimpleNamespace(
            translation=_vector(_get(t, "translation")), rotation=_vector(_get(t, "rotation"), 1.0)
        ),
    )


def _laser(m: Any) -> SimpleNamespace:
    ranges = list(_get(m, "ranges", []))
    start, end = float(_get(m, "start_angle", 0.0)), float(_get(m, "end_angle", 0.0))
    step = (end - start) / (len(ranges) - 1) if len(ranges) > 1 else 0.0
    return SimpleNamespace(
        header=_header(m),
        angle_min=start,
        angle_max=end,
        angle_increment=step,
        range_min=0.0,
        range_max=math.inf,
        ranges=ranges,
        intensities=list(_get(m, "intensities", [])),
    )


def _marker(
    entity: Any,
    frame: SimpleNamespace,
    number: int,
    kind: int,
    pose: Any,
    scale: Any,
    color: Any,
    points: list[Any] | None = None,
    text: str = "",
) -> SimpleNamespace:
    return SimpleNamespace(
        header=frame,
        ns=str(_get(entity, "id", "")),
        id=number,
        type=kind,
        action=0,
        pose=_pose(pose),
        scale=scale,
        color=_color(color),
        points=points or [],
        colors=[],
        text=text,
        lifetime=SimpleNamespace(sec=0, nanosec=nanoseconds(_get(entity, "lifetime"))),
    )


def _scene(m: Any) -> SimpleNamespace:
    markers = []
    for deletion in _get(m, "deletions", []):
        every = _get(deletion, "type", 0) in (1, "ALL")
        markers.append(SimpleNamespace(ns="" if every else str(_get(deletion, "id", "")), id=0, action=_DELETEALL))
    for entity in _get(m, "entities", []):
        frame = _header(entity)
        parts: list[SimpleNamespace] = []
        for cube in _get(entity, "cubes", []):
            parts.append(
                _marker(
                    entity,
                    frame,
                    len(parts),
                    _CUBE,
                    _get(cube, "pose"),
                    _vector(_get(cube, "size")),
                    _get(cube, "color"),
                )
            )
        for kind, primitives in ((_SPHERE, "spheres"), (_CYLINDER, "cylinders")):
            for shape in _get(entity, primitives, []):
                parts.append(
                    _marker(
                        entity,
                        frame,
                        len(parts),
                        kind,
                        _get(shape, "pose"),
                        _vector(_get(shape, "size")),
                        _get(shape, "color"),
                    )
                )
        for line in _get(entity, "lines", []):
            kind = _get(line, "type", 0)
            points = [_vector(p) for p in _get(line, "points", [])]
            if kind in (_LINE_LOOP, "LINE_LOOP") and points:
                points.append(points[0])
            marker_type = _M_LINE_LIST if kind in (_LINE_LIST, "LINE_LIST") else _M_LINE_STRIP
            parts.append(
                _marker(
                    entity,
                    frame,
                    len(parts),
                    marker_type,
                    _get(line, "pose"),
                    SimpleNamespace(x=float(_get(line, "thickness", 0.0)), y=0.0, z=0.0),
                    _get(line, "color"),
                    points,
                )
            )
        for arrow in _get(entity, "arrows", []):
            length = float(_get(arrow, "shaft_length", 0.0)) + float(_get(arrow, "head_length", 0.0))
            parts.append(
                _marker(
                    entity,
                    frame,
                    len(parts),
                    _ARROW,
                    _get(arrow, "pose"),
                    SimpleNamespace(x=length, y=0.0, z=0.0),
                    _get(arrow, "color"),
                )
            )
        for model in _get(entity, "models", []):
            parts.append(
                _marker(
                    entity,
                    frame,
                    len(parts),
                    _MESH,
                    _get(model, "pose"),
                    _vector(_get(model, "scale")),
                    _get(model, "color"),
                )
            )
        for text in _get(entity, "texts", []):
            parts.append(
                _marker(
                    entity,
                    frame,
                    len(parts),
                    _TEXT,
                    _get(text, "pose"),
                    SimpleNamespace(x=0.0, y=0.0, z=0.0),
                    _get(text, "color"),
                    text=str(_get(text, "text", "")),
                )
            )
        markers += parts
    return SimpleNamespace(markers=markers)


def _adapt(name: str, m: Any) -> Any:
    if name == "foxglove.PointCloud":
        return _cloud(m)
    if name == "foxglove.CompressedImage":
        return SimpleNamespace(header=_header(m), format=str(_get(m, "format", "")), data=_bytes(_get(m, "data")))
    if name == "foxglove.RawImage":
        return SimpleNamespace(
            header=_header(m),
            width=int(_get(m, "width", 0)),
            height=int(_get(m, "height", 0)),
            encoding=str(_get(m, "encoding", "")),
            step=int(_get(m, "step", 0)),
            is_bigendian=False,
            data=_bytes(_get(m, "data")),
        )
    if name == "foxglove.FrameTransform":
        return SimpleNamespace(transforms=[_transform(m)])
    if name == "foxglove.FrameTransforms":
        return SimpleNamespace(transforms=[_transform(t) for t in _get(m, "transforms", [])])
    if name == "foxglove.PoseInFrame":
        return SimpleNamespace(header=_header(m), pose=_pose(_get(m, "pose")))
    if name == "foxglove.PosesInFrame":
        header = _header(m)
        return SimpleNamespace(
            header=header, poses=[SimpleNamespace(header=header, pose=_pose(p)) for p in _get(m, "poses", [])]
        )
    if name == "foxglove.Odometry":
        return SimpleNamespace(
            header=_header(m),
            child_frame_id=str(_get(m, "body_frame_id", "")),
            pose=SimpleNamespace(pose=_pose(_get(m, "pose"))),
            twist=SimpleNamespace(
                twist=SimpleNamespace(
                    linear=_vector(_get(m, "linear_velocity")), angular=_vector(_get(m, "angular_velocity"))
                )
            ),
        )
    if name == "foxglove.LocationFixes":
        fixes = _get(m, "fixes", [])
        return _adapt("foxglove.LocationFix", fixes[0] if fixes else SimpleNamespace())
    if name == "foxglove.LocationFix":
        return SimpleNamespace(
            header=_header(m),
            latitude=float(_get(m, "latitude", math.nan)),
            longitude=float(_get(m, "longitude", math.nan)),
            altitude=float(_get(m, "altitude", 0.0)),
            status=SimpleNamespace(status=0),
        )
    if name == "foxglove.SceneUpdate":
        return _scene(m)
    if name == "foxglove.LaserScan":
        return _laser(m)
    if name == "foxglove.Log":
        level = _get(m, "level", 0)
        level = (
            {"DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "FATAL": 5}.get(level, 0)
            if isinstance(level, str)
            else int(level)
        )
        return SimpleNamespace(
            stamp=_header(m).stamp,
            level=level * 10,
            name=str(_get(m, "name", "")),
            msg=str(_get(m, "message", "")),
            file=str(_get(m, "file", "")),
            function="",
            line=int(_get(m, "line", 0)),
        )
    return m


def adapt(schema_name: str, message: Any) -> Any:
    """``message`` as its ROS counterpart if ``schema_name`` is a Foxglove schema of :data:`ROS_OF`, else as it is."""
    return _adapt(schema_name, message) if schema_name in ROS_OF else message
