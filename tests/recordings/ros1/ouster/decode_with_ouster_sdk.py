"""Decode ``512x10_raw.bag``'s real Ouster packets into the topics a driver publishes: ``cloud.bag``.

Run once, in a virtual environment of its own (the SDK pins its own rosbags):

    python -m venv /tmp/ouster && /tmp/ouster/bin/pip install ouster-sdk==1.0.1
    /tmp/ouster/bin/python tests/recordings/ros1/ouster/decode_with_ouster_sdk.py

The points are the published SDK's: ``ouster.sdk.open_source`` collates the bag's 32 lidar packets into one frame
(an OS-0-128, 512 columns, profile RNG15_RFL8_NIR8), ``ouster.sdk.core.XYZLut`` turns its ranges into x, y, z in the
sensor frame (a beam without a return is exactly (0, 0, 0): the SDK's ``cartesian`` writes zeros where the range is 0)
and ``ouster.sdk.core.destagger`` aligns the columns. They are written as an organised ``sensor_msgs/PointCloud2``
(height 128 beams, width 512 columns, row major) in the point layout of ouster-ros's default point type: x, y, z
(float32 at 0, 4, 8), intensity (float32 at 16: 0, this profile has no signal), t (uint32 at 20: ns since the frame's
first column), reflectivity (uint16 at 24), ring (uint16 at 26: the beam), ambient (uint16 at 28: near infrared),
range (uint32 at 32: mm), 48 bytes a point. Each IMU packet becomes a ``sensor_msgs/Imu`` (the SDK's acceleration in m/s² and
angular velocity in rad/s, no orientation: covariance[0] = -1). Record times are the bag's: the cloud
at its frame's last lidar packet, each Imu at its packet. The metadata topic is copied as recorded. The bag is written
by rosbags (the version the SDK brings) with bz2 chunks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import ouster.sdk.core as core
from ouster.sdk import open_source
from ouster.sdk.bag import BagPacketSource
from rosbags.rosbag1 import Reader, Writer
from rosbags.typesys import Stores, get_typestore

HERE = Path(__file__).parent
SOURCE = HERE / "512x10_raw.bag"
TARGET = HERE / "cloud.bag"
LIDAR, IMU, METADATA = "/os_node0/lidar_packets", "/os_node0/imu_packets", "/os_node0/metadata"

store = get_typestore(Stores.ROS1_NOETIC)
PointCloud2, PointField = store.types["sensor_msgs/msg/PointCloud2"], store.types["sensor_msgs/msg/PointField"]
Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
Imu, Vector3 = store.types["sensor_msgs/msg/Imu"], store.types["geometry_msgs/msg/Vector3"]
Quaternion = store.types["geometry_msgs/msg/Quaternion"]

#: ouster-ros's default point: (name, offset, PointField datatype, numpy type).
LAYOUT = [
    ("x", 0, PointField.FLOAT32, "<f4"),
    ("y", 4, PointField.FLOAT32, "<f4"),
    ("z", 8, PointField.FLOAT32, "<f4"),
    ("intensity", 16, PointField.FLOAT32, "<f4"),
    ("t", 20, PointField.UINT32, "<u4"),
    ("reflectivity", 24, PointField.UINT16, "<u2"),
    ("ring", 26, PointField.UINT16, "<u2"),
    ("ambient", 28, PointField.UINT16, "<u2"),
    ("range", 32, PointField.UINT32, "<u4"),
]
POINT_STEP = 48


def stamp(ns: int) -> object:
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


def cloud(info: core.SensorInfo, frame: core.LidarFrame, header: object) -> object:
    xyz = core.destagger(info, core.XYZLut(info)(frame))
    height, width = xyz.shape[:2]
    dtype = np.dtype(
        {"names": [n for n, *_ in LAYOUT], "formats": [t for *_, t in LAYOUT], "offsets": [o for _, o, *_ in LAYOUT]}
        | {"itemsize": POINT_STEP}
    )
    points = np.zeros((height, width), dtype)
    for axis, name in enumerate("xyz"):
        points[name] = xyz[:, :, axis]
    first = frame.timestamp[frame.get_first_valid_column()]
    times = np.where(frame.timestamp > 0, frame.timestamp.astype(np.int64) - int(first), 0)
    points["t"] = np.broadcast_to(times, (height, width))
    points["reflectivity"] = core.destagger(info, frame.field("REFLECTIVITY"))
    points["ring"] = np.arange(height)[:, None]
    points["ambient"] = core.destagger(info, frame.field("NEAR_IR"))
    points["range"] = core.destagger(info, frame.field("RANGE"))
    fields = [PointField(name=n, offset=o, datatype=d, count=1) for n, o, d, _ in LAYOUT]
    return PointCloud2(
        header=header,
        height=height,
        width=width,
        fields=fields,
        is_bigendian=False,
        point_step=POINT_STEP,
        row_step=POINT_STEP * width,
        data=np.frombuffer(points.tobytes(), np.uint8),
        is_dense=True,
    )


def main() -> None:
    with Reader(SOURCE) as reader:
        times = {topic: [t for c, t, _ in reader.messages() if c.topic == topic] for topic in (LIDAR, IMU, METADATA)}
        (metadata_connection,) = [c for c in reader.connections if c.topic == METADATA]
        metadata = [(t, data) for c, t, data in reader.messages([metadata_connection])]
    source = open_source(str(SOURCE))
    info = source.sensor_info[0]
    ((frame,),) = list(source)
    assert frame.complete() and len(times[LIDAR]) == frame.packet_count == 32
    imus = [packet for _, packet in BagPacketSource(str(SOURCE)) if isinstance(packet, core.ImuPacket)]
    assert len(imus) == len(times[IMU])

    TARGET.unlink(missing_ok=True)
    writer = Writer(TARGET)
    writer.set_compression(Writer.CompressionFormat.BZ2)
    with writer:
        points = writer.add_connection("/ouster/points", PointCloud2.__msgtype__, typestore=store)
        imu = writer.add_connection("/ouster/imu", Imu.__msgtype__, typestore=store)
        meta = writer.add_connection(
            "/ouster/metadata",
            "std_msgs/msg/String",
            msgdef=metadata_connection.msgdef,
            md5sum=metadata_connection.digest,
        )
        for time, data in metadata:
            writer.write(meta, time, data)
        first = int(frame.timestamp[frame.get_first_valid_column()])
        header = Header(seq=0, stamp=stamp(first), frame_id="os_sensor")
        writer.write(
            points, times[LIDAR][-1], store.serialize_ros1(cloud(info, frame, header), PointCloud2.__msgtype__)
        )
        for seq, (time, packet) in enumerate(zip(times[IMU], imus)):
            ((ax, ay, az),), ((gx, gy, gz),) = packet.accel().tolist(), packet.gyro().tolist()
            message = Imu(
                header=Header(seq=seq, stamp=stamp(int(packet.sys_ts())), frame_id="os_imu"),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=0.0),
                orientation_covariance=np.array([-1.0] + [0.0] * 8),
                angular_velocity=Vector3(x=gx, y=gy, z=gz),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=Vector3(x=ax, y=ay, z=az),
                linear_acceleration_covariance=np.zeros(9),
            )
            writer.write(imu, time, store.serialize_ros1(message, Imu.__msgtype__))


if __name__ == "__main__":
    main()
