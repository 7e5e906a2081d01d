"""Bags written with rosbags' own writers from the real KITTI raw excerpt, for the rosbag tests.

Every message of KITTI frame ``i`` is recorded (and stamped) at that
frame's time in the KITTI converter (the OXTS time, in whole
milliseconds), so that a bag's frame ``i`` is KITTI's frame ``i``:

* ``/kitti/velo/pointcloud``: the velodyne sweep as ``PointCloud2`` (x, y,
  z, intensity float32) in frame ``/velo_link`` (a ROS 1 style leading slash);
* ``/kitti/camera_gray_left/image_raw`` (mono8) and
  ``/kitti/camera_color_left/image_raw`` (rgb8): the PNGs' pixels as
  ``Image``; ``/kitti/camera_color_right/image_raw/compressed``: the PNG
  file as ``CompressedImage``;
* ``/kitti/oxts/gps/fix`` (``NavSatFix``), ``/kitti/oxts/imu`` (``Imu``:
  orientation from roll, pitch, yaw; accelerations; angular rates) and
  ``/tf`` ``world`` -> ``base_link``: east-north-up metres from the first
  OXTS record and the OXTS orientation;
* ``/tf_static``: ``base_link`` (the IMU) -> ``velo_link`` -> ``camera_gray_left``
  from the calibration files;
* ``/odom`` (``Odometry``, the same pose, forward speed ``vf`` and yaw rate ``wu``);
* ``/markers`` (``MarkerArray``): a DELETEALL, then a 4 x 2 x 1.5 m box
  ``i`` metres ahead of ``base_link`` and a text above it.
"""

from __future__ import annotations

import io
import math
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.shared import EARTH_RADIUS

RAW = "kitti-raw-2011_09_26_drive_0001-head"
CLOUD_TOPIC = "/kitti/velo/pointcloud"
GRAY_TOPIC = "/kitti/camera_gray_left/image_raw"
COLOR_TOPIC = "/kitti/camera_color_left/image_raw"
COMPRESSED_TOPIC = "/kitti/camera_color_right/image_raw/compressed"
FIX_TOPIC = "/kitti/oxts/gps/fix"
IMU_TOPIC = "/kitti/oxts/imu"


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def rotation_quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    return ((r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w), w)


def enu(here: Any, origin: Any) -> tuple[float, float, float]:
    lat0 = math.radians(origin.lat)
    east = math.radians(here.lon - origin.lon) * EARTH_RADIUS * math.cos(lat0)
    north = math.radians(here.lat - origin.lat) * EARTH_RADIUS
    return east, north, here.alt - origin.alt


class Messages:
    """Builds the messages of one typestore (ROS 1 noetic or ROS 2 humble)."""

    def __init__(self, store: Stores) -> None:
        self.store = get_typestore(store)
        if "tf2_msgs/msg/TFMessage" not in self.store.types:  # noetic's store lacks it; its definition is one line
            self.store.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        self.types = self.store.types
        self.ros1 = store == Stores.ROS1_NOETIC

    def __getattr__(self, name: str) -> Any:
        package, message = name.split("__")
        return self.types[f"{package}/msg/{message}"]

    def header(self, t: int, frame: str) -> Any:
        stamp = self.builtin_interfaces__Time(sec=t // 10**9, nanosec=t % 10**9)
        if self.ros1:
            return self.std_msgs__Header(seq=0, stamp=stamp, frame_id=frame)
        return self.std_msgs__Header(stamp=stamp, frame_id=frame)

    def vector(self, x: float, y: float, z: float) -> Any:
        return self.geometry_msgs__Vector3(x=x, y=y, z=z)

    def rotation(self, q: tuple[float, float, float, float]) -> Any:
        return self.geometry_msgs__Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])

    def transform(self, t: int, parent: str, child: str, translation: Any, rotation: Any) -> Any:
        return self.geometry_msgs__TransformStamped(
            header=self.header(t, parent),
            child_frame_id=child,
            transform=self.geometry_msgs__Transform(
                translation=self.vector(*translation), rotation=self.rotation(rotation)
            ),
        )

    def cloud(self, t: int, sweep: np.ndarray, frame: str = "velo_link") -> Any:
        fields = [self.sensor_msgs__PointField(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
        fields.append(self.sensor_msgs__PointField(name="intensity", offset=12, datatype=7, count=1))
        return self.sensor_msgs__PointCloud2(
            header=self.header(t, frame),
            height=1,
            width=len(sweep),
            fields=fields,
            is_bigendian=False,
            point_step=16,
            row_step=16 * len(sweep),
            data=np.frombuffer(sweep.astype("<f4").tobytes(), np.uint8),
            is_dense=True,
        )

    def image(self, t: int, png: bytes, frame: str) -> Any:
        with Image.open(io.BytesIO(png)) as picture:
            pixels = np.asarray(picture)
        encoding = "mono8" if pixels.ndim == 2 else "rgb8"
        height, width = pixels.shape[:2]
        return self.sensor_msgs__Image(
            header=self.header(t, frame),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=0,
            step=pixels.strides[0],
            data=pixels.reshape(-1).copy(),
        )

    def compressed(self, t: int, png: bytes, frame: str) -> Any:
        return self.sensor_msgs__CompressedImage(
            header=self.header(t, frame), format="png", data=np.frombuffer(png, np.uint8)
        )

    def serialize(self, message: Any, msgtype: str) -> bytes:
        return bytes(
            self.store.serialize_ros1(message, msgtype) if self.ros1 else self.store.serialize_cdr(message, msgtype)
        )


def kitti_messages(drive: KittiDrive, m: Messages, frames: int | None = None) -> Iterator[tuple[str, str, int, Any]]:
    """(topic, type, record time ns, message) of the drive, in time order."""
    count = len(drive) if frames is None else frames
    times = [int(round(t * 1000)) * 1_000_000 for t in drive.times[:count]]
    imu_to_velo = drive.calibration("imu_to_velo")
    velo_to_cam = drive.calibration("velo_to_cam")

    def inverse(calibration: dict[str, np.ndarray]) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        r, translation = calibration["R"], calibration["T"]
        return -r.T @ translation, rotation_quaternion(r.T)

    static = [
        m.transform(times[0], "base_link", "velo_link", *inverse(imu_to_velo)),
        m.transform(times[0], "velo_link", "camera_gray_left", *inverse(velo_to_cam)),
    ]
    yield "/tf_static", "tf2_msgs/msg/TFMessage", times[0], m.tf2_msgs__TFMessage(transforms=static)
    origin = drive.oxts(0)
    for i, t in enumerate(times):
        oxts = drive.oxts(i)
        position, rotation = enu(oxts, origin), quaternion(oxts.roll, oxts.pitch, oxts.yaw)
        world = m.transform(t, "world", "base_link", position, rotation)
        yield "/tf", "tf2_msgs/msg/TFMessage", t, m.tf2_msgs__TFMessage(transforms=[world])
        fix = m.sensor_msgs__NavSatFix(
            header=m.header(t, "base_link"),
            status=m.sensor_msgs__NavSatStatus(status=0, service=1),
            latitude=oxts.lat,
            longitude=oxts.lon,
            altitude=oxts.alt,
            position_covariance=np.zeros(9),
            position_covariance_type=0,
        )
        yield FIX_TOPIC, "sensor_msgs/msg/NavSatFix", t, fix
        imu = m.sensor_msgs__Imu(
            header=m.header(t, "base_link"),
            orientation=m.rotation(rotation),
            orientation_covariance=np.zeros(9),
            angular_velocity=m.vector(oxts.wx, oxts.wy, oxts.wz),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=m.vector(oxts.ax, oxts.ay, oxts.az),
            linear_acceleration_covariance=np.zeros(9),
        )
        yield IMU_TOPIC, "sensor_msgs/msg/Imu", t, imu
        pose = m.geometry_msgs__Pose(
            position=m.geometry_msgs__Point(x=position[0], y=position[1], z=position[2]),
            orientation=m.rotation(rotation),
        )
        odometry = m.nav_msgs__Odometry(
            header=m.header(t, "world"),
            child_frame_id="base_link",
            pose=m.geometry_msgs__PoseWithCovariance(pose=pose, covariance=np.zeros(36)),
            twist=m.geometry_msgs__TwistWithCovariance(
                twist=m.geometry_msgs__Twist(linear=m.vector(oxts.vf, 0.0, 0.0), angular=m.vector(0.0, 0.0, oxts.wu)),
                covariance=np.zeros(36),
            ),
        )
        yield "/odom", "nav_msgs/msg/Odometry", t, odometry
        yield CLOUD_TOPIC, "sensor_msgs/msg/PointCloud2", t, m.cloud(t, np.array(drive.velodyne(i)), "/velo_link")
        yield (
            GRAY_TOPIC,
            "sensor_msgs/msg/Image",
            t,
            m.image(t, drive.image_path("image_00", i).read_bytes(), "camera_gray_left"),
        )
        yield (
            COLOR_TOPIC,
            "sensor_msgs/msg/Image",
            t,
            m.image(t, drive.image_path("image_02", i).read_bytes(), "camera_color_left"),
        )
        yield (
            COMPRESSED_TOPIC,
            "sensor_msgs/msg/CompressedImage",
            t,
            m.compressed(t, drive.image_path("image_03", i).read_bytes(), "camera_color_right"),
        )
        yield (
            "/markers",
            "visualization_msgs/msg/MarkerArray",
            t,
            m.visualization_msgs__MarkerArray(
                markers=[
                    marker(m, t, action=3, kind=1, id=0, x=0.0, text=""),
                    marker(m, t, action=0, kind=1, id=i, x=float(i), text=""),
                    marker(m, t, action=0, kind=9, id=100 + i, x=float(i), text=f"box {i}"),
                ]
            ),
        )


def viz_messages(m: Messages, pose_type: str = "geometry_msgs/msg/PoseStamped") -> Iterator[tuple[str, str, int, Any]]:
    """Five frames at 10 Hz in the ``map`` frame, in time order: the pose (``pose_type``: ``PoseStamped`` or
    ``PoseWithCovarianceStamped``) on ``/pose`` moving 1 m along x a frame, numbers (``Float64`` on ``/speed``,
    ``Int32`` on ``/gear``, ``Bool`` on ``/engaged``), ``Marker``s on ``/viz`` (a SPHERE, LINE_STRIP, POINTS, ARROW,
    LINE_LIST and CUBE_LIST; the LINE_STRIP deleted in the second frame, the ARROW expiring after 0.15 s) and on
    ``/shapes`` (a CUBE, CYLINDER and SPHERE_LIST), and a ``Path`` on ``/plan`` along x.
    """
    t0, tick = 1_700_000_000 * 10**9, 100_000_000
    ahead = [(0.0, 0.0, 0.0), (0.0, 5.0, 0.0)]
    messages: list[tuple[str, str, int, Any]] = []
    for i in range(5):
        pose = m.geometry_msgs__Pose(
            position=m.geometry_msgs__Point(x=float(i), y=0.0, z=0.0), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
        )
        if pose_type.endswith("PoseWithCovarianceStamped"):
            stamped_pose = m.geometry_msgs__PoseWithCovarianceStamped(
                header=m.header(t0, "map"), pose=m.geometry_msgs__PoseWithCovariance(pose=pose, covariance=np.zeros(36))
            )
        else:
            stamped_pose = m.geometry_msgs__PoseStamped(header=m.header(t0, "map"), pose=pose)
        messages.append(("/pose", pose_type, t0 + i * tick, stamped_pose))
        messages.append(("/speed", "std_msgs/msg/Float64", t0 + i * tick, m.std_msgs__Float64(data=1.5 * i)))
        messages.append(("/gear", "std_msgs/msg/Int32", t0 + i * tick, m.std_msgs__Int32(data=i)))
        messages.append(("/engaged", "std_msgs/msg/Bool", t0 + i * tick, m.std_msgs__Bool(data=i % 2 == 0)))
    marker_type = "visualization_msgs/msg/Marker"
    messages += [
        ("/viz", marker_type, t0, marker(m, t0, action=0, kind=2, id=1, x=10.0, frame="map", scale=2.0)),  # SPHERE
        (
            "/viz",
            marker_type,
            t0,
            marker(m, t0, action=0, kind=4, id=2, x=0.0, frame="map", points=ahead),
        ),  # LINE_STRIP
        ("/viz", marker_type, t0, marker(m, t0, action=0, kind=8, id=3, x=0.0, frame="map", points=ahead)),  # POINTS
        (
            "/viz",
            marker_type,
            t0,
            marker(m, t0, action=0, kind=0, id=4, x=0.0, frame="map", lifetime=150_000_000),
        ),  # ARROW
        (
            "/viz",
            marker_type,
            t0,
            marker(m, t0, action=0, kind=5, id=5, x=0.0, frame="map", points=ahead * 2),
        ),  # LINE_LIST
        ("/viz", marker_type, t0, marker(m, t0, action=0, kind=6, id=6, x=0.0, frame="map", points=ahead)),  # CUBE_LIST
        ("/shapes", marker_type, t0, marker(m, t0, action=0, kind=1, id=7, x=3.0, frame="map")),  # CUBE
        ("/shapes", marker_type, t0, marker(m, t0, action=0, kind=3, id=8, x=6.0, frame="map")),  # CYLINDER
        (
            "/shapes",
            marker_type,
            t0,
            marker(m, t0, action=0, kind=7, id=9, x=0.0, frame="map", points=ahead),
        ),  # SPHERE_LIST
        ("/viz", marker_type, t0 + tick, marker(m, t0, action=2, kind=4, id=2, x=0.0, frame="map")),  # DELETE the strip
    ]
    stamped = [
        m.geometry_msgs__PoseStamped(
            header=m.header(t0, "map"),
            pose=m.geometry_msgs__Pose(
                position=m.geometry_msgs__Point(x=x, y=0.0, z=0.0), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
            ),
        )
        for x in (0.0, 5.0, 10.0)
    ]
    messages.append(("/plan", "nav_msgs/msg/Path", t0, m.nav_msgs__Path(header=m.header(t0, "map"), poses=stamped)))
    return iter(sorted(messages, key=lambda e: e[2]))


def marker(
    m: Messages,
    t: int,
    *,
    action: int,
    kind: int,
    id: int,
    x: float,
    text: str = "",
    frame: str = "base_link",
    points: list[tuple[float, float, float]] | None = None,
    lifetime: int = 0,
    scale: float = 4.0,
) -> Any:
    """A Marker: namespace ``boxes``, orange, at (x, 0, 0.75), scaled (scale, 2, 1.5); ``lifetime`` in ns."""
    pose = m.geometry_msgs__Pose(
        position=m.geometry_msgs__Point(x=x, y=0.0, z=0.75), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
    )
    lifetime_message = m.builtin_interfaces__Duration(sec=lifetime // 10**9, nanosec=lifetime % 10**9)
    color = m.std_msgs__ColorRGBA(r=1.0, g=0.5, b=0.0, a=1.0)
    fields: dict[str, Any] = dict(
        header=m.header(t, frame),
        ns="boxes",
        id=id,
        type=kind,
        action=action,
        pose=pose,
        scale=m.vector(scale, 2.0, 1.5),
        color=color,
        lifetime=lifetime_message,
        frame_locked=False,
        points=[m.geometry_msgs__Point(x=p[0], y=p[1], z=p[2]) for p in points or []],
        colors=[color for _ in points or []],
        text=text,
        mesh_resource="",
        mesh_use_embedded_materials=False,
    )
    if not m.ros1:
        fields["texture_resource"] = ""
        fields["texture"] = m.sensor_msgs__CompressedImage(
            header=m.header(t, ""), format="", data=np.zeros(0, np.uint8)
        )
        fields["uv_coordinates"] = []
        fields["mesh_file"] = m.visualization_msgs__MeshFile(filename="", data=np.zeros(0, np.uint8))
    return m.visualization_msgs__Marker(**fields)


def write_bag(
    path: Path,
    container: str,
    messages: Iterator[tuple[str, str, int, Any]] | None = None,
    *,
    drive: KittiDrive | None = None,
    compression: str | None = None,
    frames: int | None = None,
    mode: str = "storage",
) -> Path:
    """Write a bag of ``container`` (``ros1``, ``sqlite3``, ``mcap``: a bare .mcap file) at ``path``; return it.

    ``compression``: ``bz2`` or ``lz4`` chunks for ROS 1, ``zstd`` for ROS 2 and MCAP: of MCAP chunks
    (``mode`` ``storage``), of each message (``message``) or of each storage file (``file``).
    """
    m = Messages(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    source = messages if messages is not None else kitti_messages(drive, m, frames)  # type: ignore[arg-type]
    if container == "ros1":
        writer: Any = Writer1(path)
        if compression:
            writer.set_compression(getattr(Writer1.CompressionFormat, compression.upper()))
    else:
        folder = path if container == "sqlite3" else path.with_suffix("")
        writer = Writer2(
            folder, version=9, storage_plugin=StoragePlugin.SQLITE3 if container == "sqlite3" else StoragePlugin.MCAP
        )
        if compression:
            writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    connections: dict[str, Any] = {}
    with writer:
        for topic, msgtype, t, message in source:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=m.store)
            writer.write(connections[topic], t, m.serialize(message, msgtype))
    if container == "mcap":
        folder = path.with_suffix("")
        shutil.move(folder / f"{folder.name}.mcap", path)
        shutil.rmtree(folder)
    return path
