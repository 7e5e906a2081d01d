"""The default mapping: what each topic of a bag becomes, by its message type.

:func:`plan` decides it from the bag's topic list alone (no message is
read), as adjusted by a :class:`~.config.RosConfig`; ``xviz-server
inspect`` shows the same plan.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .config import RosConfig
from .tf import TF_TYPES

if TYPE_CHECKING:
    from .bag import Recording

__all__ = ["Mapping", "plan", "SERIES", "MARKER_STREAMS", "POSE_TYPES"]

CLOUD = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
MARKER = "visualization_msgs/msg/Marker"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
PATH = "nav_msgs/msg/Path"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
#: Messages shown as text in a table: (time, level, node, text) rows of the staleness window.
TEXT_TYPES = ("std_msgs/msg/String", "rosgraph_msgs/msg/Log", "rcl_interfaces/msg/Log")

#: Pose sources in the order of preference after /tf.
POSE_TYPES = (ODOMETRY, POSE_STAMPED, POSE_WITH_COVARIANCE, NAV_SAT_FIX)
#: The streams of a marker topic, by XVIZ primitive type: ``<stream>/<suffix>``.
MARKER_STREAMS = {
    "polygons": "POLYGON",
    "polylines": "POLYLINE",
    "points": "POINT",
    "circles": "CIRCLE",
    "texts": "TEXT",
}

Getter = Callable[[Any], Any]


def _norm(vector: Any) -> float:
    return math.sqrt(vector.x * vector.x + vector.y * vector.y + vector.z * vector.z)


def _numbers() -> dict[str, list[tuple[str, str, str | None, Getter]]]:
    table: dict[str, list[tuple[str, str, str | None, Getter]]] = {}
    for name in ("Float32", "Float64", "Int64", "UInt32", "UInt64"):
        table[f"std_msgs/msg/{name}"] = [("", "FLOAT", None, lambda m: float(m.data))]
    for name in ("Int8", "Int16", "Int32", "UInt8", "UInt16"):
        table[f"std_msgs/msg/{name}"] = [("", "INT32", None, lambda m: int(m.data))]
    table["std_msgs/msg/Bool"] = [("", "BOOL", None, lambda m: bool(m.data))]
    return table


#: Time series by message type: (stream suffix, scalar type, units, value of a message).
SERIES: dict[str, list[tuple[str, str, str | None, Getter]]] = {
    ODOMETRY: [
        ("/speed", "FLOAT", "m/s", lambda m: _norm(m.twist.twist.linear)),
        ("/yaw_rate", "FLOAT", "rad/s", lambda m: float(m.twist.twist.angular.z)),
    ],
    TWIST: [
        ("/linear_x", "FLOAT", "m/s", lambda m: float(m.linear.x)),
        ("/angular_z", "FLOAT", "rad/s", lambda m: float(m.angular.z)),
    ],
    TWIST_STAMPED: [
        ("/linear_x", "FLOAT", "m/s", lambda m: float(m.twist.linear.x)),
        ("/angular_z", "FLOAT", "rad/s", lambda m: float(m.twist.angular.z)),
    ],
    IMU: [
        ("/acceleration", "FLOAT", "m/s^2", lambda m: float(m.linear_acceleration.x)),
        ("/yaw_rate", "FLOAT", "rad/s", lambda m: float(m.angular_velocity.z)),
    ],
    **_numbers(),
}


@dataclass(frozen=True)
class Mapping:
    """What one topic becomes: ``role`` and the XVIZ streams it makes.

    Roles: ``points`` (``PointCloud2``, ``LaserScan``), ``image``, ``markers``, ``path``, ``series``, ``text``,
    ``trajectory`` (a pose topic other than the pose source),
    ``pose`` (the pose source), ``origin`` (NavSatFix: the map origin),
    ``transforms`` (/tf, /tf_static), ``unused`` (a known type not needed),
    ``unknown`` (a type the mapping does not know) and ``excluded`` (by the
    configuration).
    """

    topic: str
    msgtype: str
    role: str
    stream: str | None = None

    def streams(self) -> list[str]:
        """The streams this topic makes, besides the pose."""
        if self.stream is None:
            return []
        if self.role == "markers":
            return [f"{self.stream}/{suffix}" for suffix in MARKER_STREAMS]
        if self.role == "series" or (self.role == "pose" and self.msgtype in SERIES):
            return [self.stream + suffix for suffix, *_ in SERIES[self.msgtype]]
        if self.role == "trajectory":
            return [self.stream] + [self.stream + suffix for suffix, *_ in SERIES.get(self.msgtype, [])]
        if self.role in ("points", "image", "path", "text"):
            return [self.stream]
        return []

    def describe(self) -> str:
        """The mapping in a few words, for ``inspect``: ``POINT /velodyne_points``."""
        words = {
            "points": "POINT",
            "image": "IMAGE",
            "markers": "POLYGON/POLYLINE/POINT/CIRCLE/TEXT",
            "path": "POLYLINE",
            "series": "TIME_SERIES",
            "text": "UI_PRIMITIVE (a table of the recent messages)",
            "pose": "pose source of /vehicle_pose",
            "trajectory": "POLYLINE (the trajectory so far)",
            "origin": "map_origin",
            "transforms": "transform tree",
            "unused": "not used",
            "unknown": "unknown type, not served",
            "excluded": "excluded by the configuration",
        }[self.role]
        made = ", ".join(self.streams())
        if self.role == "pose" and made:
            return f"{words}; TIME_SERIES {made}"
        return f"{words} {made}".rstrip()


def _stream_name(topic: str, config: RosConfig) -> str:
    name = config.stream(topic).name
    return name if name is not None else topic if topic.startswith("/") else "/" + topic


def plan(bag: Recording, config: RosConfig, pose_topic: str | None) -> list[Mapping]:
    """The mapping of every topic of ``bag``; ``pose_topic`` is the topic the pose comes from, if one does."""
    mappings = []
    for topic, info in bag.topics.items():
        msgtype = info.msgtype
        if not config.wants(topic):
            mappings.append(Mapping(topic, msgtype, "excluded"))
            continue
        stream = _stream_name(topic, config)
        if topic == pose_topic:
            role = "pose"
        elif topic in bag.problems:
            role = "unknown"
        elif msgtype in (CLOUD, LASER_SCAN):
            role = "points"
        elif msgtype in (IMAGE, COMPRESSED_IMAGE):
            role = "image"
        elif msgtype in (MARKER, MARKER_ARRAY):
            role = "markers"
        elif msgtype == PATH:
            role = "path"
        elif msgtype in POSE_TYPES and msgtype != NAV_SAT_FIX:  # Odometry too: a trajectory and its time series
            role = "trajectory"
        elif msgtype in SERIES:
            role = "series"
        elif msgtype in TEXT_TYPES:
            role = "text"
        elif msgtype == NAV_SAT_FIX:
            role = "origin"
        elif msgtype in TF_TYPES:
            role = "transforms"
        else:
            role = "unknown"
        mappings.append(
            Mapping(
                topic,
                msgtype,
                role,
                stream
                if role in ("points", "image", "markers", "path", "series", "pose", "text", "trajectory")
                else None,
            )
        )
    return mappings
