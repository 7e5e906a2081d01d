"""ROS bags served as logs: the real KITTI excerpt written as ROS 1, ROS 2 sqlite3 and MCAP bags with rosbags' writers,
converted on demand and checked against the KITTI converter's own output, read by @xviz/parser, served over a socket."""

from __future__ import annotations

import io
import json
import logging
import math
import re
import shutil
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from devkit.rosbag_kitti import (
    CLOUD_TOPIC,
    COLOR_TOPIC,
    COMPRESSED_TOPIC,
    FIX_TOPIC,
    GRAY_TOPIC,
    IMU_TOPIC,
    RAW,
    Messages,
    kitti_messages,
    viz_messages,
    write_bag,
)
from helpers import client, run_xviz_session_async, running_server, sha, timestamps, xviz_decode
from xviz_server.cli import main
from xviz_server.convert import convert
from xviz_server.datasets import detect, open_dataset
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.ros import RosBag, is_rosbag
from xviz_server.datasets.ros.bag import ROS1_MAGIC
from xviz_server.datasets.ros.inspect import inspect_bag
from xviz_server.datasets.ros.sensors import cloud_points, compressed_image_bytes, image_bytes
from xviz_server.datasets.shared import EARTH_RADIUS
from xviz_server.exceptions import DatasetError
from xviz_server.server import parse_dataset

FRAMES = 8
CONTAINERS = {"ros1": "drive.bag", "sqlite3": "drive", "mcap": "drive.mcap"}


@pytest.fixture(scope="module")
def drive(shared_dir: Path) -> KittiDrive:
    return KittiDrive(shared_dir / "data" / RAW)


@pytest.fixture(scope="module")
def bags(drive: KittiDrive, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bags")
    bags = {}
    for container, name in CONTAINERS.items():
        (root / container).mkdir()
        bags[container] = write_bag(root / container / name, container, drive=drive, frames=FRAMES)
    return bags


def kitti_only(drive: KittiDrive, container: str, keep: set[str]) -> Iterator[tuple[str, str, int, Any]]:
    m = Messages(_store(container))
    return (entry for entry in kitti_messages(drive, m, FRAMES) if entry[0] in keep)


def _store(container: str) -> Any:
    from rosbags.typesys import Stores

    return Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE


def pixels(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as picture:
        assert picture.format == "PNG"
        return np.asarray(picture)


def geographic(pose: dict[str, Any]) -> tuple[float, float]:
    """Longitude and latitude of a pose's position, undoing the flat-earth east-north offset from its map origin."""
    origin = pose["map_origin"]
    east, north = pose["position"][:2]
    latitude = origin["latitude"] + math.degrees(north / EARTH_RADIUS)
    longitude = origin["longitude"] + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(origin["latitude"]))))
    return longitude, latitude


# -- detection and naming -----------------------------------------------------


def test_detects_the_three_containers_by_their_first_bytes(bags: dict[str, Path], tmp_path: Path):
    for path in bags.values():
        assert is_rosbag(path) and detect(path) == "rosbag"
    (tmp_path / "notes.bag").write_text("a shopping bag")
    (tmp_path / "folder.mcap").mkdir()
    (tmp_path / "metadata.yaml").write_text("title: a static site\n")
    assert not is_rosbag(tmp_path / "notes.bag") and not is_rosbag(tmp_path / "folder.mcap") and not is_rosbag(tmp_path)
    assert [open_dataset("rosbag", p).name for p in bags.values()] == ["drive", "drive", "drive"]


# -- the default mapping against the KITTI converter ------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("container", CONTAINERS)
def test_frames_match_the_kitti_converter(container: str, bags: dict[str, Path], drive: KittiDrive):
    bag = open_dataset("rosbag", bags[container])
    assert len(bag) == FRAMES and bag.times.tolist() == drive.times[:FRAMES].tolist()
    metadata = bag.metadata()
    kitti_metadata = drive.metadata()
    streams = metadata["streams"]
    # The velodyne frame is resolved through /tf_static to base_link (the IMU): the exact calibration.
    calibration = drive.calibration("imu_to_velo")
    transform = np.array(streams[CLOUD_TOPIC]["transform"]).reshape(4, 4).T
    np.testing.assert_allclose(transform[:3, :3], calibration["R"].T, atol=1e-9)
    np.testing.assert_allclose(transform[:3, 3], -calibration["R"].T @ calibration["T"], atol=1e-9)
    assert streams[CLOUD_TOPIC]["coordinate"] == "VEHICLE_RELATIVE"
    assert {GRAY_TOPIC, COLOR_TOPIC, COMPRESSED_TOPIC} <= {
        s for s, e in streams.items() if e.get("primitive_type") == "IMAGE"
    }
    assert metadata["ui_config"]["Camera"]["config"]["children"][0]["cameras"] == [
        COLOR_TOPIC,
        COMPRESSED_TOPIC,
        GRAY_TOPIC,
    ]
    for frame in range(FRAMES):
        ours = bag.convert(frame, metadata)["updates"][0]
        theirs = drive.convert(frame, kitti_metadata)["updates"][0]
        assert ours["timestamp"] == theirs["timestamp"]
        # Points exactly, colours bit for bit (intensity coloured like KITTI's reflectance).
        cloud = ours["primitives"][CLOUD_TOPIC]["points"][0]
        kitti_cloud = theirs["primitives"]["/lidar/points"]["points"][0]
        assert np.array_equal(cloud["points"], kitti_cloud["points"]) and np.array_equal(
            cloud["colors"], kitti_cloud["colors"]
        )
        # The pose: orientation and where on earth, to 1e-6 (radians, degrees).
        pose, kitti_pose = ours["poses"]["/vehicle_pose"], theirs["poses"]["/vehicle_pose"]
        np.testing.assert_allclose(pose["orientation"], kitti_pose["orientation"], atol=1e-6)
        kitti_origin = kitti_pose["map_origin"]
        np.testing.assert_allclose(geographic(pose), (kitti_origin["longitude"], kitti_origin["latitude"]), atol=1e-6)
        assert pose["position"][2] + pose["map_origin"]["altitude"] == pytest.approx(kitti_origin["altitude"], abs=1e-6)
        # The excerpt's images are 397 pixels wide: not scaled. Image pixels as KITTI's PNGs (our PNG is
        # encoded anew), the CompressedImage's PNG byte for byte.
        images = {s: p["images"][0]["data"] for s, p in ours["primitives"].items() if "images" in p}
        kitti_images = {s: p["images"][0]["data"] for s, p in theirs["primitives"].items() if "images" in p}
        assert np.array_equal(pixels(images[GRAY_TOPIC]), pixels(kitti_images["/camera/image_00"]))
        assert np.array_equal(pixels(images[COLOR_TOPIC]), pixels(kitti_images["/camera/image_02"]))
        assert images[COMPRESSED_TOPIC] == kitti_images["/camera/image_03"]
        # Odometry and Imu numbers as time series.
        series = {s: v for entry in ours["time_series"] for s, v in zip(entry["streams"], entry["values"]["doubles"])}
        oxts = drive.oxts(frame)
        assert series["/odom/speed"] == pytest.approx(oxts.vf, abs=1e-9)
        assert series[f"{IMU_TOPIC}/acceleration"] == pytest.approx(oxts.ax, abs=1e-9)
        assert series[f"{IMU_TOPIC}/yaw_rate"] == pytest.approx(oxts.wz, abs=1e-9)
        # MarkerArray: DELETEALL, then box `frame` metres ahead and its label.
        boxes = ours["primitives"]["/markers/polygons"]["polygons"]
        assert [b["base"]["object_id"] for b in boxes] == [f"boxes/{frame}"]
        vertices = np.asarray(boxes[0]["vertices"])
        np.testing.assert_allclose(
            vertices, [[frame + 2, 1, 0], [frame - 2, 1, 0], [frame - 2, -1, 0], [frame + 2, -1, 0]], atol=1e-6
        )
        assert boxes[0]["base"]["style"] == {"fill_color": [255, 128, 0, 255], "height": 1.5}
        assert [t["text"] for t in ours["primitives"]["/markers/texts"]["texts"]] == [f"box {frame}"]


@pytest.mark.parametrize("container", ["ros1", "mcap"])
def test_fixes_and_imu_alone_give_the_pose(container: str, drive: KittiDrive, tmp_path: Path):
    """No /tf and no odometry: east-north-up metres from the first fix, heading from the Imu."""
    path = write_bag(
        tmp_path / CONTAINERS[container], container, kitti_only(drive, container, {CLOUD_TOPIC, FIX_TOPIC, IMU_TOPIC})
    )
    bag = RosBag(path)
    assert bag.pose_source.kind == "fix" and bag.pose_source.imu_topic == IMU_TOPIC
    metadata = bag.metadata()
    assert "transform" not in metadata["streams"][CLOUD_TOPIC]  # no tree: points drawn in the cloud's own frame
    for frame in (0, 3, FRAMES - 1):
        pose = bag.convert(frame, metadata)["updates"][0]["poses"]["/vehicle_pose"]
        kitti = drive.convert(frame)["updates"][0]["poses"]["/vehicle_pose"]
        np.testing.assert_allclose(pose["orientation"], kitti["orientation"], atol=1e-6)
        np.testing.assert_allclose(
            geographic(pose), (kitti["map_origin"]["longitude"], kitti["map_origin"]["latitude"]), atol=1e-6
        )


def test_pose_is_interpolated_between_messages(drive: KittiDrive, tmp_path: Path):
    """A clock of its own (a rate) falls between odometry messages: the pose is interpolated, slerp for the rotation."""
    path = write_bag(tmp_path / "odom.bag", "ros1", kitti_only(drive, "ros1", {"/odom"}))
    config = tmp_path / "map.toml"
    config.write_text("rate = 20.0\npose = '/odom'\n")
    bag = RosBag(path, config=str(config))
    last = bag.bag.topics["/odom"].times[-1]  # ticks from the first message to one at or after the last
    assert bag.clock[0] == bag.bag.topics["/odom"].times[0] and bag.clock[-2] < last <= bag.clock[-1]
    assert set(np.diff(bag.clock)) == {50_000_000}
    metadata = bag.metadata()
    between = bag.convert(1, metadata)["updates"][0]
    odometry = [bag.bag.message("/odom", i)[1].pose.pose.position for i in (0, 1)]
    fraction = (bag.clock[1] - bag.bag.topics["/odom"].times[0]) / np.diff(bag.bag.topics["/odom"].times[:2])[0]
    expected = [a + fraction * (b - a) for a, b in ((odometry[0].x, odometry[1].x), (odometry[0].y, odometry[1].y))]
    np.testing.assert_allclose(between["poses"]["/vehicle_pose"]["position"][:2], expected, atol=1e-9)
    yaws = [drive.oxts(i).yaw for i in (0, 1)]
    assert min(yaws) - 1e-9 <= between["poses"]["/vehicle_pose"]["orientation"][2] <= max(yaws) + 1e-9


def test_no_pose_source_and_no_cloud(drive: KittiDrive, tmp_path: Path):
    """Only images: the clock is 10 Hz over the bag's span and the vehicle stays at the origin."""
    path = write_bag(tmp_path / "images.mcap", "mcap", kitti_only(drive, "mcap", {GRAY_TOPIC}))
    bag = RosBag(path)
    assert bag.pose_source.kind == "none"
    last = bag.bag.topics[GRAY_TOPIC].times[-1]
    assert bag.clock[-2] < last <= bag.clock[-1] and np.allclose(np.diff(bag.times), 0.1)
    update = bag.convert(len(bag) - 1)["updates"][0]
    assert update["poses"]["/vehicle_pose"]["position"] == [0.0, 0.0, 0.0]
    assert GRAY_TOPIC in update["primitives"]


def test_markers_paths_numbers_in_the_map_frame(tmp_path: Path):
    """A PoseStamped pose in ``map``; markers and a path in ``map`` are drawn relative to the vehicle."""
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS2_HUMBLE)
    bag = RosBag(write_bag(tmp_path / "viz.mcap", "mcap", viz_messages(m)))
    assert bag.pose_source.kind == "topic" and bag.pose_source.fixed_frame == "map" and len(bag) == 5
    metadata = bag.metadata()
    frames = [bag.convert(i, metadata)["updates"][0] for i in range(5)]
    first, third = frames[0]["primitives"], frames[2]["primitives"]
    assert (
        first["/viz/circles"]["circles"][0]["center"] == [10.0, 0.0, 0.75]
        and first["/viz/circles"]["circles"][0]["radius"] == 1.0
    )
    assert third["/viz/circles"]["circles"][0]["center"] == [8.0, 0.0, 0.75]  # the vehicle moved 2 m along x
    assert [p["base"]["object_id"] for p in first["/viz/polylines"]["polylines"]] == [
        "boxes/2",
        "boxes/4",
        "boxes/5",
        "boxes/5",
    ]
    assert [p["base"]["object_id"] for p in third["/viz/polylines"]["polylines"]] == [
        "boxes/5",
        "boxes/5",
    ]  # deleted, expired
    np.testing.assert_allclose(third["/viz/points"]["points"][0]["points"], [[-2, 0, 0.75], [-2, 5, 0.75]])
    assert third["/viz/points"]["points"][0]["colors"].tolist() == [[255, 128, 0, 255]] * 2
    assert len(third["/viz/polygons"]["polygons"]) == 2
    np.testing.assert_allclose(third["/plan"]["polylines"][0]["vertices"], [[-2, 0, 0], [3, 0, 0], [8, 0, 0]])
    speeds = [
        entry["values"]["doubles"][0] for f in frames for entry in f["time_series"] if entry["streams"] == ["/speed"]
    ]
    assert speeds == [0.0, 1.5, 3.0, 4.5, 6.0]


# -- point clouds of any layout -------------------------------------------------


def _cloud(
    m: Messages, fields: list[tuple[str, int, int]], step: int, data: bytes, count: int, bigendian: bool = False
) -> Any:
    return m.sensor_msgs__PointCloud2(
        header=m.header(0, "lidar"),
        height=1,
        width=count,
        is_bigendian=bigendian,
        point_step=step,
        row_step=step * count,
        fields=[m.sensor_msgs__PointField(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
        data=np.frombuffer(data, np.uint8),
        is_dense=False,
    )


def test_messages_before_the_first_and_after_the_last_frame_are_shown(tmp_path: Path):
    """Frames are the cloud's two messages; a marker 1 ms after the last, a string 5 s before the first (older than
    the staleness) and an image between the frames only once: none is lost."""
    from rosbags.typesys import Stores

    from devkit.rosbag_kitti import marker

    m = Messages(Stores.ROS2_HUMBLE)
    t0 = 1_700_000_000 * 10**9
    xyz = np.array([[1.0, 2.0, 3.0]], np.float32)
    cloud = _cloud(m, [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], 12, xyz.tobytes(), 1)
    messages = [
        ("/early", "std_msgs/msg/String", t0 - 5 * 10**9, m.std_msgs__String(data="before the first frame")),
        ("/points", "sensor_msgs/msg/PointCloud2", t0, cloud),
        ("/points", "sensor_msgs/msg/PointCloud2", t0 + 10**8, cloud),
        (
            "/late",
            "visualization_msgs/msg/Marker",
            t0 + 10**8 + 10**6,
            marker(m, t0, action=0, kind=1, id=1, x=3.0, frame="lidar"),
        ),
    ]
    bag = RosBag(write_bag(tmp_path / "edges.mcap", "mcap", iter(messages)))
    assert bag.clock.tolist() == [t0, t0 + 10**8]
    first, last = (bag.convert(i)["updates"][0] for i in range(2))
    assert [row["column_values"][3] for row in first["ui_primitives"]["/early"]["treetable"]["nodes"]] == [
        "before the first frame"
    ]
    assert "/late/polygons" not in first.get("primitives", {})
    assert [p["base"]["object_id"] for p in last["primitives"]["/late/polygons"]["polygons"]] == ["boxes/1"]


def test_a_ros1_tf_tree_of_two_turtles_gives_the_detected_or_chosen_pose(tmp_path: Path):
    """Legacy tf/tfMessage on /tf: world -> turtle1 and world -> turtle2 moving; one turtle is the vehicle."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    types = store.types
    t0 = 1_700_000_000 * 10**9

    def edge(t: int, child: str, x: float) -> Any:
        header = types["std_msgs/msg/Header"](
            seq=0, stamp=types["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9), frame_id="world"
        )
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
            rotation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        return types["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=transform)

    path = tmp_path / "turtles.bag"
    with Writer(path) as writer:
        connection = writer.add_connection("/tf", "tf/msg/tfMessage", typestore=store)
        for i in range(5):
            t = t0 + i * 10**8
            message = types["tf/msg/tfMessage"](transforms=[edge(t, "turtle1", float(i)), edge(t, "turtle2", 10.0 - i)])
            writer.write(connection, t, store.serialize_ros1(message, "tf/msg/tfMessage"))
    detected = RosBag(path)
    assert detected.pose_source.describe() == "/tf: world -> turtle1"
    assert [detected.convert(i)["updates"][0]["poses"]["/vehicle_pose"]["position"][0] for i in range(5)] == [
        0.0,
        1.0,
        2.0,
        3.0,
        4.0,
    ]
    config = tmp_path / "turtle2.toml"
    config.write_text('vehicle_frame = "turtle2"\nfixed_frame = "turtle1"\n')
    chosen = RosBag(path, config=str(config))
    assert chosen.pose_source.describe() == "/tf: turtle1 -> turtle2"
    assert [chosen.convert(i)["updates"][0]["poses"]["/vehicle_pose"]["position"][0] for i in range(5)] == [
        10.0,
        8.0,
        6.0,
        4.0,
        2.0,
    ]
    config.write_text('fixed_frame = "sea"\n')
    with pytest.raises(DatasetError, match="fixed_frame: the transform tree has no frame sea"):
        _ = RosBag(path, config=str(config)).pose_source


def test_several_pose_topics_the_earliest_is_the_pose_the_others_trajectories(tmp_path: Path):
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS2_HUMBLE)
    t0 = 1_700_000_000 * 10**9
    messages = []
    for topic, start, y in (("/late", 9_500_000_000, 5.0), ("/first", 0, 0.0), ("/second", 1_000_000_000, -5.0)):
        for i in range(3):
            t = t0 + start + i * 10**9
            pose = m.geometry_msgs__Pose(
                position=m.geometry_msgs__Point(x=float(i), y=y, z=0.0), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
            )
            messages.append(
                (
                    topic,
                    "geometry_msgs/msg/PoseStamped",
                    t,
                    m.geometry_msgs__PoseStamped(header=m.header(t, "map"), pose=pose),
                )
            )
    path = write_bag(tmp_path / "poses.mcap", "mcap", iter(sorted(messages, key=lambda e: e[2])))
    bag = RosBag(path)
    assert bag.pose_source.topic == "/first"
    assert {m.topic: m.role for m in bag.mappings} == {"/first": "pose", "/second": "trajectory", "/late": "trajectory"}
    last = bag.convert(len(bag) - 1)["updates"][0]
    assert last["poses"]["/vehicle_pose"]["position"][:2] == [2.0, 0.0]
    for topic, y in (("/second", -5.0), ("/late", 5.0)):  # each drawn so far, in the vehicle frame (at x=2, y=0)
        (line,) = last["primitives"][topic]["polylines"]
        np.testing.assert_allclose(
            np.asarray(line["vertices"]).reshape(-1, 3)[:, :2], [[-2.0, y], [-1.0, y], [0.0, y]], atol=1e-6
        )
    config = tmp_path / "late.toml"
    config.write_text('pose = "/late"\n')
    assert RosBag(path, config=str(config)).pose_source.topic == "/late"


def test_a_robots_own_tf_tree_rides_on_the_odometry_of_its_root_the_other_odometry_a_trajectory(tmp_path: Path):
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS1_NOETIC)
    t0 = 1_700_000_000 * 10**9
    messages = []
    for i in range(4):
        t = t0 + i * 10**9
        joint = m.transform(t, "base_footprint", "base_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0))
        messages.append(("/tf", "tf2_msgs/msg/TFMessage", t, m.tf2_msgs__TFMessage(transforms=[joint])))
        for topic, y, delay in (("/wheel", 0.0, 0), ("/fused", 3.0, 10**6)):
            pose = m.geometry_msgs__Pose(
                position=m.geometry_msgs__Point(x=float(i), y=y, z=0.0), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
            )
            twist = m.geometry_msgs__Twist(linear=m.vector(1.0, 0.0, 0.0), angular=m.vector(0.0, 0.0, 0.0))
            odometry = m.nav_msgs__Odometry(
                header=m.header(t + delay, "odom"),
                child_frame_id="base_footprint",
                pose=m.geometry_msgs__PoseWithCovariance(pose=pose, covariance=np.zeros(36)),
                twist=m.geometry_msgs__TwistWithCovariance(twist=twist, covariance=np.zeros(36)),
            )
            messages.append((topic, "nav_msgs/msg/Odometry", t + delay, odometry))
    path = write_bag(tmp_path / "husky.bag", "ros1", iter(sorted(messages, key=lambda e: e[2])))
    bag = RosBag(path)
    # /tf moves base_link in base_footprint alone; the odometry whose child is that root moves the robot.
    assert bag.pose_source.describe() == "/wheel (odom -> base_link)"
    assert {m.topic: m.role for m in bag.mappings} == {"/wheel": "pose", "/fused": "trajectory", "/tf": "transforms"}
    last = bag.convert(len(bag) - 1)["updates"][0]
    assert last["poses"]["/vehicle_pose"]["position"][:2] == [3.0, 0.0]
    (line,) = last["primitives"]["/fused"]["polylines"]  # drawn so far, in the vehicle frame (at x=3, y=0)
    np.testing.assert_allclose(
        np.asarray(line["vertices"]).reshape(-1, 3)[:, :2], [[-3.0, 3.0], [-2.0, 3.0], [-1.0, 3.0], [0.0, 3.0]]
    )
    series = {stream for entry in last["time_series"] for stream in entry["streams"]}
    assert {"/wheel/speed", "/fused/speed", "/fused/yaw_rate"} <= series


def test_list_markers_take_one_colour_a_point_when_given_one_for_each(tmp_path: Path):
    from dataclasses import replace

    from rosbags.typesys import Stores

    from devkit.rosbag_kitti import marker

    m = Messages(Stores.ROS2_HUMBLE)
    t0 = 1_700_000_000 * 10**9
    points = [(1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]
    each = [m.std_msgs__ColorRGBA(r=0.0, g=0.0, b=1.0, a=1.0), m.std_msgs__ColorRGBA(r=1.0, g=0.0, b=0.0, a=0.5)]
    kinds = {"/spheres": 7, "/cubes": 6, "/points": 8}  # SPHERE_LIST, CUBE_LIST, POINTS
    messages = [
        (
            topic,
            "visualization_msgs/msg/Marker",
            t0,
            replace(marker(m, t0, action=0, kind=kind, id=1, x=0.0, points=points), colors=each),
        )
        for topic, kind in kinds.items()
    ]
    short = replace(
        marker(m, t0, action=0, kind=7, id=2, x=0.0, points=points), colors=each[:1]
    )  # one colour, two points
    messages.append(("/fallback", "visualization_msgs/msg/Marker", t0, short))
    primitives = RosBag(write_bag(tmp_path / "lists.mcap", "mcap", iter(messages))).convert(0)["updates"][0][
        "primitives"
    ]
    blue, red = [0, 0, 255, 255], [255, 0, 0, 128]
    assert [c["base"]["style"]["fill_color"] for c in primitives["/spheres/circles"]["circles"]] == [blue, red]
    assert [c["base"]["style"]["fill_color"] for c in primitives["/cubes/polygons"]["polygons"]] == [blue, red]
    assert np.asarray(primitives["/points/points"]["points"][0]["colors"]).reshape(-1, 4).tolist() == [blue, red]
    orange = [255, 128, 0, 255]  # the marker's own colour
    assert [c["base"]["style"]["fill_color"] for c in primitives["/fallback/circles"]["circles"]] == [orange, orange]


def test_velodyne_driver_packets_are_named_as_such(tmp_path: Path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(
        {
            **get_types_from_msg("time stamp\nuint8[1206] data", "velodyne_msgs/msg/VelodynePacket"),
            **get_types_from_msg(
                "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets", "velodyne_msgs/msg/VelodyneScan"
            ),
        }
    )
    types = store.types
    t0 = 1_700_000_000 * 10**9
    header = types["std_msgs/msg/Header"](
        seq=0, stamp=types["builtin_interfaces/msg/Time"](sec=t0 // 10**9, nanosec=0), frame_id="velodyne"
    )
    packet = types["velodyne_msgs/msg/VelodynePacket"](stamp=header.stamp, data=np.zeros(1206, np.uint8))
    path = tmp_path / "packets.bag"
    with Writer(path) as writer:
        connection = writer.add_connection("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan", typestore=store)
        for i in range(3):
            scan = types["velodyne_msgs/msg/VelodyneScan"](header=header, packets=[packet] * 2)
            writer.write(connection, t0 + i * 10**8, store.serialize_ros1(scan, "velodyne_msgs/msg/VelodyneScan"))
    bag = RosBag(path)
    assert bag.bag.problems == {
        "/velodyne_packets": "velodyne_msgs/msg/VelodyneScan holds the raw packets of a sensor's driver, "
        "not points: record the driver's point cloud topic, or replay the bag through the driver"
    }
    assert [m.role for m in bag.mappings] == ["unknown"] and len(bag) == 3
    assert [t["note"] for t in inspect_bag(path)["topics"]] == [bag.bag.problems["/velodyne_packets"]]


def test_cloud_layouts_endianness_nan_and_colours():
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS2_HUMBLE)
    rng = np.random.default_rng(7)
    xyz = rng.normal(size=(50, 3))
    xyz[[3, 9]] = np.nan
    xyz[[5, 20]] = 0.0  # beams without a return, as drivers write them: left out
    xyz[30, :2] = 0.0  # a real point on the z axis: kept
    # Big-endian float64 x, y, z after a ring field, rgb packed in a float32, and a trailing time field.
    dtype = np.dtype(
        [("ring", ">u2"), ("pad", "V6"), ("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("rgb", ">f4"), ("t", ">f4")]
    )
    records = np.zeros(50, dtype)
    records["x"], records["y"], records["z"] = xyz.T
    packed = rng.integers(0, 2**24, 50, dtype=np.uint32)
    records["rgb"] = packed.view(np.float32).astype(">f4")
    message = _cloud(
        m,
        [("ring", 0, 4), ("x", 8, 8), ("y", 16, 8), ("z", 24, 8), ("rgb", 32, 7), ("t", 36, 7)],
        dtype.itemsize,
        records.tobytes(),
        50,
        bigendian=True,
    )
    points, colors = cloud_points(message, "test")
    keep = np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)
    assert keep.sum() == 46 and np.array_equal(points, xyz[keep].astype(np.float32))
    assert colors is not None and np.array_equal(colors, np.stack([(packed >> s) & 255 for s in (16, 8, 0)], 1)[keep])
    # uint8 intensity is scaled to 0..1, then coloured like KITTI's reflectance; colour "none" gives none.
    small = np.zeros(4, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1")])
    small["intensity"] = [0, 85, 170, 255]
    small["x"] = 1.0
    message = _cloud(
        m, [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 2)], small.itemsize, small.tobytes(), 4
    )
    _, colors = cloud_points(message, "test")
    assert colors is not None and colors[:, 0].tolist() == [80, 106, 133, 160]
    assert cloud_points(message, "test", color="none")[1] is None
    no_z = _cloud(m, [("x", 0, 7), ("y", 4, 7)], 8, bytes(16), 2)
    with pytest.raises(DatasetError, match="test: PointCloud2 has no z field"):
        cloud_points(no_z, "test")
    short = _cloud(m, [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], 12, bytes(20), 2)
    with pytest.raises(DatasetError, match="holds 20 bytes, too few"):
        cloud_points(short, "test")


def test_image_encodings_and_compressed_passthrough(drive: KittiDrive):
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS2_HUMBLE)
    png = drive.image_path("image_02", 0).read_bytes()
    rgb = pixels(png)
    height, width = rgb.shape[:2]

    def image(encoding: str, array: np.ndarray, pad: int = 0, bigendian: bool = False) -> Any:
        rows = array.reshape(height, -1).view(np.uint8)
        padded = np.zeros((height, rows.shape[1] + pad), np.uint8)
        padded[:, : rows.shape[1]] = rows
        return m.sensor_msgs__Image(
            header=m.header(0, "camera"),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=bigendian,
            step=padded.shape[1],
            data=padded.reshape(-1),
        )

    def decoded(message: Any) -> np.ndarray:
        return pixels(image_bytes(message, 400, "test"))

    assert np.array_equal(decoded(image("rgb8", rgb, pad=5)), rgb)
    assert np.array_equal(decoded(image("bgr8", np.ascontiguousarray(rgb[..., ::-1]))), rgb)
    rgba = np.dstack([rgb, np.full((height, width), 200, np.uint8)])
    assert np.array_equal(decoded(image("bgra8", np.ascontiguousarray(rgba[..., [2, 1, 0, 3]]))), rgba)
    gray = np.ascontiguousarray(rgb[..., 1])
    assert np.array_equal(decoded(image("mono8", gray)), gray)
    assert np.array_equal(decoded(image("mono16", (gray.astype(">u2") * 257).astype(">u2"), bigendian=True)), gray)
    mosaic = np.empty((height, width), np.uint8)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = rgb[0::2, 0::2, 0], rgb[0::2, 1::2, 1]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = rgb[1::2, 0::2, 1], rgb[1::2, 1::2, 2]
    half = decoded(image("bayer_rggb8", mosaic))
    h, w = height // 2 * 2, width // 2 * 2
    greens = (mosaic[0:h:2, 1:w:2].astype(int) + mosaic[1:h:2, 0:w:2]) // 2
    assert np.array_equal(half, np.dstack([mosaic[0:h:2, 0:w:2], greens, mosaic[1:h:2, 1:w:2]]))
    with pytest.raises(DatasetError, match="test: image encoding '32FC1' is not one of"):
        image_bytes(image("32FC1", gray), 400, "test")
    compressed = m.sensor_msgs__CompressedImage(
        header=m.header(0, "camera"), format="png", data=np.frombuffer(png, np.uint8)
    )
    assert compressed_image_bytes(compressed, 400, "test") == png  # fits: the recorded bytes, not re-encoded
    # Scaled down: height rounded down, close to the KITTI converter's scaling (box reduce first, then bilinear).
    kitti = pixels(KittiDrive(drive.path, image_max_width=200).image("image_02", 0)).astype(int)
    for scaled in (
        pixels(compressed_image_bytes(compressed, 200, "test")),
        pixels(image_bytes(image("rgb8", rgb), 200, "test")),
    ):
        assert scaled.shape == (60, 200, 3) and np.abs(scaled - kitti).mean() < 4


# -- configuration -----------------------------------------------------------------


def test_configuration_renames_picks_and_styles(bags: dict[str, Path], tmp_path: Path):
    config = tmp_path / "map.toml"
    config.write_text(f"""
topics = ["{CLOUD_TOPIC}", "/odom", "/tf", "/tf_static", "{FIX_TOPIC}"]
pose = "/odom"
[streams."{CLOUD_TOPIC}"]
name = "/lidar/points"
color = "none"
style = {{ radius_pixels = 3, fill_color = "#ff0000" }}
[streams."/odom"]
name = "/vehicle"
""")
    bag = RosBag(bags["mcap"], config=str(config))
    metadata = bag.metadata()
    assert sorted(metadata["streams"]) == ["/lidar/points", "/vehicle/speed", "/vehicle/yaw_rate", "/vehicle_pose"]
    assert metadata["streams"]["/lidar/points"]["stream_style"] == {"radius_pixels": 3, "fill_color": "#ff0000"}
    assert bag.pose_source.kind == "topic" and bag.pose_source.topic == "/odom"
    update = bag.convert(2, metadata)["updates"][0]
    assert "colors" not in update["primitives"]["/lidar/points"]["points"][0]
    bad = tmp_path / "bad.toml"
    bad.write_text("rate = -1\n[streams.'/x']\ncolour = 'rgb'\n")
    with pytest.raises(DatasetError, match=r"bad.toml: rate: .*greater than 0.*streams\./x\.colour: Extra inputs"):
        RosBag(bags["mcap"], config=str(bad))
    clash = tmp_path / "clash.toml"
    clash.write_text(f"[streams.'{GRAY_TOPIC}']\nname = '{COLOR_TOPIC}'\n")
    with pytest.raises(DatasetError, match=f"streams named twice: {COLOR_TOPIC}"):
        RosBag(bags["mcap"], config=str(clash)).metadata()


def test_dataset_option_in_the_path(bags: dict[str, Path], tmp_path: Path):
    assert parse_dataset(f"rosbag:{bags['ros1']}?config=/x.toml") == ("rosbag", bags["ros1"], {"config": "/x.toml"})
    with pytest.raises(ValueError, match="kitti takes no option config; it takes: image_max_width"):
        parse_dataset(f"kitti:{tmp_path}?config=/x.toml")
    with pytest.raises(ValueError, match="no such file or directory"):
        parse_dataset(f"rosbag:{tmp_path / 'nope.bag'}")


# -- bad input ----------------------------------------------------------------------


def test_truncated_bag_is_an_error_naming_the_file(bags: dict[str, Path], tmp_path: Path):
    cut = tmp_path / bags["sqlite3"].name
    shutil.copytree(bags["sqlite3"], cut)  # a folder: cut its database file
    (database,) = cut.glob("*.db3")
    database.write_bytes(database.read_bytes()[: database.stat().st_size // 2])
    with pytest.raises(DatasetError, match=f"{cut}: cannot open the bag: "):
        RosBag(cut)


def test_an_mcap_file_cut_short_serves_its_whole_records(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    whole = RosBag(bags["mcap"])
    cut = tmp_path / "drive.mcap"
    cut.write_bytes(bags["mcap"].read_bytes()[: bags["mcap"].stat().st_size // 2])
    with caplog.at_level(logging.WARNING):
        bag = RosBag(cut)
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warning.startswith(f"{cut}: a record at byte ") and "is cut off by the end of the file" in warning
    kept = {name: len(topic) for name, topic in bag.bag.topics.items()}
    assert 0 < sum(kept.values()) < sum(len(topic) for topic in whole.bag.topics.values())
    for name, count in kept.items():  # the messages before the cut, the same as the whole file's
        assert [bag.bag.message(name, i)[0] for i in range(count)] == whole.bag.topics[name].times[:count].tolist()
    assert frame_digests(bag, 1) == frame_digests(whole, 1)


def cut_recording(bag: Path, to: Path, keep: int | None = None) -> Path:
    """``bag`` as a recording killed before it wrote its index: the index gone, ``index_pos`` 0; cut to ``keep`` bytes."""
    data = bytearray(bag.read_bytes())
    field = data.index(b"index_pos=") + len(b"index_pos=")
    (index_pos,) = struct.unpack_from("<Q", data, field)
    data[field : field + 8] = struct.pack("<Q", 0)
    to.write_bytes(bytes(data[: index_pos if keep is None else keep]))
    return to


def frame_digests(bag: RosBag, frames: int) -> list[str]:
    metadata = bag.metadata()
    return [
        sha(json.dumps(bag.convert(frame, metadata), sort_keys=True, default=lambda a: sha(np.asarray(a))).encode())
        for frame in range(frames)
    ]


def ros1_profile_mcap(bag: Path, to: Path) -> Path:
    """``bag`` (ROS 1) as ``mcap convert`` makes it: profile ros1, ros1msg schemas, ros1 messages, with mcap's writer."""
    from mcap.writer import Writer
    from rosbags.rosbag1 import Reader

    with Reader(bag) as reader, to.open("wb") as out:
        writer = Writer(out)
        writer.start(profile="ros1", library="tests")
        channels = {}
        for connection in reader.connections:
            schema = writer.register_schema(
                connection.msgtype.replace("/msg/", "/"), "ros1msg", connection.msgdef.data.encode()
            )
            channels[connection.id] = writer.register_channel(connection.topic, "ros1", schema)
        for connection, time, data in reader.messages():
            writer.add_message(channels[connection.id], time, data, time)
        writer.finish()
    return to


def test_an_mcap_file_of_the_ros1_profile_serves_the_same_frames_as_its_bag(bags: dict[str, Path], tmp_path: Path):
    converted = RosBag(ros1_profile_mcap(bags["ros1"], tmp_path / "drive.mcap"))
    assert converted.bag.container == "MCAP" and converted.bag.problems == {}
    assert frame_digests(converted, FRAMES) == frame_digests(RosBag(bags["ros1"]), FRAMES)


def test_unindexed_ros1_bag_is_indexed_in_memory(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    """A recording killed before it wrote its index: every message read, the frames those of the indexed bag."""
    unindexed = cut_recording(bags["ros1"], tmp_path / "unindexed.bag")
    with caplog.at_level(logging.WARNING):
        bag = RosBag(unindexed)
    assert f"{unindexed} has no readable index (its recording was cut short): indexed in memory" in caplog.text
    indexed = RosBag(bags["ros1"])
    assert bag.times.tolist() == indexed.times.tolist() and len(bag) == FRAMES
    assert {name: len(topic) for name, topic in bag.bag.topics.items()} == {
        name: len(topic) for name, topic in indexed.bag.topics.items()
    }
    assert frame_digests(bag, FRAMES) == frame_digests(indexed, FRAMES)


def test_unindexed_ros1_bag_with_a_garbled_chunk_is_an_error_naming_the_file(bags: dict[str, Path], tmp_path: Path):
    """Indexing in memory reads every chunk's records: a record header that lies about its length is refused."""
    data = bytearray(cut_recording(bags["ros1"], tmp_path / "plain.bag").read_bytes())
    position = len(ROS1_MAGIC)
    (header,) = struct.unpack_from("<I", data, position)  # the bag header record: header, then its padding
    position += 4 + header
    (padding,) = struct.unpack_from("<I", data, position)
    position += 4 + padding
    (header,) = struct.unpack_from("<I", data, position)  # the first chunk record
    assert b"op=\x05" in data[position + 4 : position + 4 + header]
    first_record = position + 4 + header + 4  # after the chunk's header and its data length (no compression)
    data[first_record : first_record + 4] = struct.pack("<I", 0xFFFFFFF0)
    garbled = tmp_path / "garbled.bag"
    garbled.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=f"{garbled}: cannot open the bag: "):
        RosBag(garbled)


def test_ros1_bag_cut_inside_a_chunk_serves_the_whole_chunks(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    """A bag cut at half its size (its index gone, its last chunk cut short): what the whole chunks hold, and a warning."""
    size = bags["ros1"].stat().st_size
    half = tmp_path / "half.bag"
    half.write_bytes(bags["ros1"].read_bytes()[: size // 2])  # index_pos now points past the end
    killed = cut_recording(bags["ros1"], tmp_path / "killed.bag", keep=size // 2)  # index_pos 0
    indexed = RosBag(bags["ros1"])
    for path in (half, killed):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            bag = RosBag(path)
        assert re.search(
            rf"{path} has no readable index .* the last \d+ bytes, a record cut short, are left out", caplog.text
        )
        clouds = len(bag.bag.topics[CLOUD_TOPIC])
        assert 1 < clouds < FRAMES
        assert len(bag) == clouds and bag.times.tolist() == indexed.times[:clouds].tolist()
        # The last frame's other messages may have been written after the cut.
        assert frame_digests(bag, clouds - 1) == frame_digests(indexed, clouds - 1)


@pytest.mark.slow
@pytest.mark.parametrize(("container", "compression"), [("ros1", "bz2"), ("ros1", "lz4"), ("mcap", "zstd")])
def test_compressed_chunks_read_the_same(
    container: str, compression: str, bags: dict[str, Path], drive: KittiDrive, tmp_path: Path
):
    path = write_bag(
        tmp_path / CONTAINERS[container],
        container,
        kitti_only(drive, container, {CLOUD_TOPIC, "/tf", "/tf_static"}),
        compression=compression,
    )
    plain, packed = RosBag(bags[container]), RosBag(path)
    ours = packed.convert(4)["updates"][0]["primitives"][CLOUD_TOPIC]["points"][0]["points"]
    assert np.array_equal(ours, plain.convert(4)["updates"][0]["primitives"][CLOUD_TOPIC]["points"][0]["points"])


def test_a_topic_that_does_not_decode_is_left_out_with_a_warning(
    drive: KittiDrive, tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    from rosbags.rosbag2 import StoragePlugin, Writer

    m = Messages(_store("mcap"))
    folder = tmp_path / "broken"
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        cloud = writer.add_connection(CLOUD_TOPIC, "sensor_msgs/msg/PointCloud2", typestore=m.store)
        broken = writer.add_connection("/broken", "sensor_msgs/msg/Image", typestore=m.store)
        for i, t in enumerate(int(round(t * 1000)) * 1_000_000 for t in drive.times[:3]):
            writer.write(cloud, t, m.serialize(m.cloud(t, np.array(drive.velodyne(i))), "sensor_msgs/msg/PointCloud2"))
            writer.write(broken, t, b"\x00\x01\x00\x00garbage")
    bag = RosBag(folder)
    metadata = bag.metadata()
    with caplog.at_level(logging.WARNING):
        updates = [bag.convert(i, metadata)["updates"][0] for i in range(3)]
    assert all(CLOUD_TOPIC in u["primitives"] and "/broken" not in u["primitives"] for u in updates)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and f"{folder}: topic /broken: a sensor_msgs/msg/Image message at" in warnings[0]


def test_a_bag_without_messages_is_an_error(tmp_path: Path):
    from rosbags.rosbag1 import Writer

    with Writer(tmp_path / "empty.bag"):
        pass
    with pytest.raises(DatasetError, match="empty.bag: the bag holds no message"):
        RosBag(tmp_path / "empty.bag")


# -- the published client, the converter, the server ---------------------------------


def test_converted_log_reads_in_the_published_client(bags: dict[str, Path], drive: KittiDrive, tmp_path: Path):
    out = tmp_path / "log"
    assert convert("rosbag", bags["sqlite3"], out, frames="0:3", processes=1) == 3
    results = xviz_decode([out / "1-frame.glb", out / "2-frame.glb", out / "4-frame.glb"])
    assert all("error" not in r for r in results), results
    metadata = results[0]["parsed"]
    assert metadata["type"] == "METADATA" and CLOUD_TOPIC in metadata["streams"]
    for result, frame in zip(results[1:], (0, 2)):
        parsed = result["parsed"]
        assert parsed["type"] == "TIMESLICE" and parsed["timestamp"] == drive.times[frame]
        sweep = drive.velodyne(frame)
        cloud = parsed["streams"][CLOUD_TOPIC]["pointCloud"]
        assert cloud["numInstances"] == len(sweep) and cloud["positions"]["sha256"] == sha(
            np.ascontiguousarray(sweep[:, :3])
        )
        oxts = drive.oxts(frame)
        pose = parsed["poses"]["/vehicle_pose"]
        assert pose["yaw"] == pytest.approx(oxts.yaw, abs=1e-6) and pose["roll"] == pytest.approx(oxts.roll, abs=1e-6)
        assert (pose["longitude"], pose["latitude"]) == (drive.oxts(0).lon, drive.oxts(0).lat)  # the first fix
        assert parsed["streams"][COMPRESSED_TOPIC]["images"][0]["width_px"] == 397
        assert [b["id"] for b in parsed["streams"]["/markers/polygons"]["features"]] == [f"boxes/{frame}"]
        assert parsed["streams"]["/odom/speed"] == [{"time": drive.times[frame], "variable": pytest.approx(oxts.vf)}]


async def test_served_over_a_socket_beside_a_broken_bag(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    root = tmp_path / "data"
    root.mkdir()
    (root / "good.mcap").write_bytes(bags["mcap"].read_bytes())
    (root / "cut.bag").write_bytes(bags["ros1"].read_bytes()[:100_000])
    async with running_server(root, dataset=[f"rosbag:{bags['ros1']}"]) as server:
        assert {"good", "cut", "drive"} <= set(server.shelf.names())
        for _ in range(2):  # the client is told the log's name and the cause, never where the file is
            async with client(server, "/?log=cut") as c:
                error = await c.recv()
                assert (
                    error["type"] == "xviz/error" and error["data"]["message"] == "log 'cut': the bag holds no message"
                )
        # The server's log has one warning for this version of the file, with its path.
        warnings = [
            r.getMessage()
            for r in caplog.records
            if r.levelno == logging.WARNING and "cannot be opened" in r.getMessage()
        ]
        assert warnings == [f"log 'cut' ({root / 'cut.bag'}) cannot be opened: log 'cut': the bag holds no message"]
        for name in ("good", "drive"):
            async with client(server, f"/?log={name}") as c:
                metadata = await c.recv()
                assert metadata["type"] == "xviz/metadata" and CLOUD_TOPIC in metadata["data"]["streams"]
                await c.send("transform_log", {"id": "all"})
                messages = await c.until("transform_log_done", "all")
                assert len(timestamps(messages)) == FRAMES
                assert not [m for m in messages if m["type"] == "xviz/error"]


async def test_streetscape_session_against_a_served_bag(bags: dict[str, Path], drive: KittiDrive):
    """The node driver talks to the server as streetscape.gl does and parses every frame with @xviz/parser."""
    session = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "0", "from_start": -1}},
        {"wait": "done", "id": "0"},
        {"close": True},
    ]
    async with running_server(None, dataset=[f"rosbag:{bags['ros1']}"]) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=drive&profile=default&message_format=BINARY"
        result = await run_xviz_session_async(url, session, timeout=180)
    assert result.ok, result.stderr
    assert result.summary["errors"] == []
    assert result.messages[0]["parsed"]["start_time"] == drive.times[0]
    updates = result.of_type("xviz/state_update")
    assert [u["parsed"]["timestamp"] for u in updates] == drive.times[:FRAMES].tolist()
    for frame, update in enumerate(updates):
        cloud = update["parsed"]["streams"][CLOUD_TOPIC]["pointCloud"]
        assert cloud["positions"]["sha256"] == sha(np.ascontiguousarray(drive.velodyne(frame)[:, :3]))
        assert update["parsed"]["poses"]["/vehicle_pose"]["yaw"] == pytest.approx(drive.oxts(frame).yaw, abs=1e-6)


# -- inspect --------------------------------------------------------------------------


def test_inspect_lists_topics_rates_and_mapping(
    bags: dict[str, Path], drive: KittiDrive, capsys: pytest.CaptureFixture[str]
):
    assert main(["inspect", str(bags["ros1"]), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    topics = {t["topic"]: t for t in report["topics"]}
    assert report["container"] == "ROS 1" and report["frames"] == FRAMES
    assert report["pose"] == "/tf: world -> base_link"
    cloud = topics[CLOUD_TOPIC]
    assert cloud["type"] == "sensor_msgs/msg/PointCloud2" and cloud["count"] == FRAMES
    assert cloud["rate_hz"] == pytest.approx((FRAMES - 1) / (drive.times[FRAMES - 1] - drive.times[0]), rel=1e-6)
    assert cloud["maps_to"] == f"POINT {CLOUD_TOPIC}" and topics["/tf"]["maps_to"] == "transform tree"
    assert report["start_time"] == drive.times[0] and report["end_time"] == drive.times[FRAMES - 1]
    assert main(["inspect", str(bags["mcap"])]) == 0
    table = capsys.readouterr().out
    assert "MCAP" in table and CLOUD_TOPIC in table and "POINT" in table
    assert main(["inspect", str(bags["mcap"].parent / "nope.bag")]) == 1
    assert "nope.bag" in capsys.readouterr().err


def test_inspect_points_out_topics_on_another_clock(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
):
    """Header stamps in simulation time beside a wall-clock recording: reported, and served on record time."""
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS2_HUMBLE)
    wall = 1_700_000_000 * 10**9
    messages = []
    for i in range(3):
        t = wall + i * 100_000_000
        simulated = m.std_msgs__Header(stamp=m.builtin_interfaces__Time(sec=100 + i, nanosec=0), frame_id="base_link")
        messages.append(
            (
                "/sim/odom",
                "nav_msgs/msg/Odometry",
                t,
                m.nav_msgs__Odometry(
                    header=simulated,
                    child_frame_id="base_link",
                    pose=m.geometry_msgs__PoseWithCovariance(
                        pose=m.geometry_msgs__Pose(
                            position=m.geometry_msgs__Point(x=float(i), y=0.0, z=0.0),
                            orientation=m.rotation((0.0, 0.0, 0.0, 1.0)),
                        ),
                        covariance=np.zeros(36),
                    ),
                    twist=m.geometry_msgs__TwistWithCovariance(
                        twist=m.geometry_msgs__Twist(linear=m.vector(1.0, 0.0, 0.0), angular=m.vector(0.0, 0.0, 0.0)),
                        covariance=np.zeros(36),
                    ),
                ),
            )
        )
        messages.append(("/wall/speed", "std_msgs/msg/Float32", t, m.std_msgs__Float32(data=float(i))))
        messages.append(
            ("/diagnostics_blob", "std_msgs/msg/ColorRGBA", t, m.std_msgs__ColorRGBA(r=0.0, g=0.0, b=0.0, a=1.0))
        )
    path = write_bag(tmp_path / "clocks.mcap", "mcap", iter(messages))
    bag = RosBag(path)
    with caplog.at_level(logging.INFO, logger="xviz_server.datasets.ros.dataset"):
        bag.metadata()
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: topics of types the mapping does not know, not served: /diagnostics_blob (std_msgs/msg/ColorRGBA)"
    ]
    assert main(["inspect", str(path), "--json"]) == 0
    topics = {t["topic"]: t for t in json.loads(capsys.readouterr().out)["topics"]}
    assert topics["/sim/odom"]["note"].startswith("header stamps on another clock (-1699999900.0 s")
    assert topics["/wall/speed"]["note"] == ""  # no header
    assert topics["/diagnostics_blob"]["maps_to"] == "unknown type, not served"
    metadata = bag.metadata()
    positions = [
        bag.convert(i, metadata)["updates"][0]["poses"]["/vehicle_pose"]["position"][0] for i in range(len(bag))
    ]
    assert positions == [0.0, 1.0, 2.0]
    config = tmp_path / "tf.toml"
    config.write_text("pose = '/tf'\n")
    with pytest.raises(DatasetError, match="tf.toml: pose: /tf does not move any frame"):
        _ = RosBag(path, config=str(config)).pose_source
