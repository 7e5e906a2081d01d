"""Recordings the project did not write: the MCAP conformance suite and sample bags of public robotics repositories,
each opened, converted and served (sources, licences and commits in tests/recordings/README.md)."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from helpers import assert_same_message, foxglove_client, running_server
from xviz_server.datasets.ros import RosBag
from xviz_server.datasets.ros.bag import open_bag
from xviz_server.records import unpack

RECORDINGS = Path(__file__).parent / "recordings"
CONFORMANCE = RECORDINGS / "mcap-conformance"
#: Every message of every file of the suite, as its own JSON descriptions list them: (topic, log time, data in hex).
EXPECTED: dict[str, list[list[object]]] = json.loads((CONFORMANCE / "messages.json").read_text())


def test_the_whole_conformance_suite_is_here():
    assert sorted(path.stem for path in CONFORMANCE.glob("*/*.mcap")) == sorted(EXPECTED)
    assert len(EXPECTED) == 416


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_every_conformance_file_opens_with_its_messages(name: str):
    (path,) = CONFORMANCE.glob(f"*/{name}.mcap")
    bag = open_bag(path)
    found = sorted((topic, int(time)) for topic, info in bag.topics.items() for time in info.times)
    assert found == sorted((str(topic), int(time)) for topic, time, _ in EXPECTED[name])  # type: ignore[call-overload]
    for topic, info in bag.topics.items():
        assert list(info.times) == sorted(info.times)  # in time order whatever the file's order
        # The suite's channels have made-up encodings: named per channel, not a refusal of the file.
        assert bag.problems[topic].startswith("no decoder for message encoding ")
    if not found:
        return
    log = RosBag(path)
    assert log.metadata()["streams"].keys() == {"/vehicle_pose"}
    assert log.convert(0)["updates"][0]["poses"]["/vehicle_pose"]["position"] == [0.0, 0.0, 0.0]
    # Every message reaches Foxglove clients as the file holds it, once; but a channel without a schema, which the
    # Foxglove protocol cannot advertise.
    served = [
        (time, bytes(payload).hex())
        for frame in range(len(log))
        for _, time, payload in unpack(log.original_messages(frame))
    ]
    schemaless = name.startswith("OneSchemalessMessage")
    assert sorted(served) == [] if schemaless else sorted((int(t), str(data)) for _, t, data in EXPECTED[name])  # type: ignore[call-overload]


# -- ROS 2 bags of ros2/rosbag2's own tests -------------------------------------------

ROSBAG2 = RECORDINGS / "rosbag2"


def test_service_event_topics_do_not_make_a_ros2_mcap_bag_unreadable():
    log = RosBag(ROSBAG2 / "mcap" / "bag_with_topics_and_service_events")
    assert log.name == "bag_with_topics_and_service_events" and log.bag.container == "ROS 2 mcap"
    events = {"/test_service1/_service_event", "/test_service2/_service_event"}
    # The service event channels decode (their schema is the .srv text), the topics beside them too; XVIZ has no
    # stream for them, which the mapping names.
    assert log.bag.problems == {}
    assert {m.topic: m.describe() for m in log.mappings if m.topic in events} == dict.fromkeys(
        events, "unknown type, not served"
    )
    event = log.bag.message("/test_service1/_service_event", 0)[1]
    assert event.info.event_type == 0 and len(event.request) == 1 and event.response == []
    assert isinstance(event.request[0].string_value, str)
    assert [len(log.bag.topics[t]) for t in ("/test_topic1", "/test_topic2")] == [1, 1]
    strings = log.bag.message("/test_topic1", 0)[1]
    assert isinstance(strings.string_value, str)
    log.convert(0)
    # Foxglove clients get every topic, the service events too, as recorded.
    assert events | {"/test_topic1", "/test_topic2"} <= {o.topic for o in log.originals}


def test_service_events_decode_with_their_requests_and_responses():
    from mcap.reader import make_reader

    path = ROSBAG2 / "mcap" / "only_services.mcap"
    with path.open("rb") as file:  # the events' times and bytes as the file holds them
        recorded = [(m.log_time, m.data) for _, _, m in make_reader(file).iter_messages(log_time_order=True)]
    log = RosBag(path)
    topic = "/add_two_ints/_service_event"
    assert log.bag.problems == {} and log.bag.topics[topic].msgtype == "example_interfaces/srv/AddTwoInts_Event"
    events = [log.bag.message(topic, i) for i in range(len(log.bag.topics[topic]))]
    assert [t for t, _ in events] == [t for t, _ in recorded] and len(events) == 12
    # Each call: the request received (event type 1) and the response sent (2) under one sequence number, the
    # response the sum of the request's operands.
    calls: dict[int, dict[int, object]] = {}
    for _, event in events:
        calls.setdefault(event.info.sequence_number, {})[event.info.event_type] = event
    assert sorted(calls) == [1, 2, 3, 4, 5, 6]
    for call in calls.values():
        (request,), (response,) = call[1].request, call[2].response  # type: ignore[attr-defined]
        assert call[1].response == call[2].request == []  # type: ignore[attr-defined]
        assert response.sum == request.a + request.b
    # Served: no XVIZ stream for them, the original bytes to Foxglove clients.
    served = sorted((t, bytes(p)) for f in range(len(log)) for name, t, p in unpack(log.original_messages(f)))
    assert served == sorted(recorded)


def _text_rows(log: RosBag, stream: str) -> list[list[str]]:
    rows = []
    for frame in range(len(log)):
        table = log.convert(frame)["updates"][0].get("ui_primitives", {}).get(stream)
        rows += [node["column_values"] for node in table["treetable"]["nodes"]] if table else []
    return rows


def test_a_metadata_yaml_without_storage_identifier_and_strings_as_text(tmp_path: Path):
    folder = tmp_path / "talker"
    folder.mkdir()
    (folder / "talker.db3").symlink_to((ROSBAG2 / "sqlite3" / "talker" / "talker.db3").resolve())
    metadata = (ROSBAG2 / "sqlite3" / "talker" / "metadata.yaml").read_text()
    assert "storage_identifier: sqlite3" in metadata
    (folder / "metadata.yaml").write_text(metadata.replace("storage_identifier: sqlite3", 'storage_identifier: ""'))
    log = RosBag(folder)
    assert log.bag.container == "ROS 2 sqlite3" and len(log.bag.topics["/topic"]) == 10
    assert log.metadata()["streams"]["/topic"] == {"category": "UI_PRIMITIVE", "ui_primitive_type": "TREETABLE"}
    shown = {row[3] for row in _text_rows(log, "/topic")}
    assert shown == {log.bag.message("/topic", i)[1].data for i in range(10)}
    assert all(text.startswith("Hello, world! ") for text in shown)
    # rcl_interfaces/Log of 2020 (Eloquent), whose definition rosbags reads wrongly from the bag: the standard one.
    logged = {tuple(row[1:]) for row in _text_rows(log, "/rosout")}
    assert logged == {("INFO", "minimal_publisher", f"Publishing: '{text}'") for text in shown}


def test_a_bare_db3_file_opens():
    log = RosBag(ROSBAG2 / "topics_and_services.db3")
    assert log.name == "topics_and_services" and log.bag.container == "ROS 2 sqlite3"
    assert len(log.bag.topics["/add_two_ints/_service_event"]) == 6
    # rosbags has no definition of the service event type: the topic is named, the rest served.
    assert "AddTwoInts_Event has no definition" in log.bag.problems["/add_two_ints/_service_event"]
    assert [m.role for m in log.mappings if m.topic == "/add_two_ints/_service_event"] == ["unknown"]
    assert [m.role for m in log.mappings if m.topic == "/rosout"] == ["text"]
    log.convert(0)


# -- MCAP as the Foxglove SDK writes it ----------------------------------------------------


@pytest.fixture(scope="module")
def sdk_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from foxglove_sdk_recording import write_sdk_recording

    return write_sdk_recording(tmp_path_factory.mktemp("sdk") / "sdk.mcap")


def test_foxglove_schemas_in_protobuf_and_json_map_like_their_ros_counterparts(sdk_recording: Path):
    from foxglove_sdk_recording import FRAMES, POINTS, QUARTER_LEFT_XYZW, T0

    from xviz_server.datasets.ros.geometry import apply, matrix

    log = RosBag(sdk_recording)
    assert log.bag.problems == {} and log.bag.container == "MCAP"
    roles = {m.topic: m.role for m in log.mappings}
    assert roles == {
        "/camera": "image",
        "/raw": "image",
        "/lidar": "points",
        "/lidar_posed": "points",
        "/scan": "points",
        "/tf": "transforms",
        "/goal": "trajectory",
        "/route": "path",
        "/wheel_odom": "trajectory",  # an Odometry other than the pose: its trajectory and time series
        "/gps": "origin",
        "/fixes": "origin",
        "/scene": "markers",
        "/log": "text",
        "/json_log": "text",
    }
    assert log.pose_source.describe() == "/tf: world -> base_link" and len(log) == FRAMES
    assert log.map_origin == (8.4, 49.0, 110.0)
    fix = log.bag.message("/fixes", 0)[1]  # LocationFixes: its first fix, as a NavSatFix
    assert (fix.latitude, fix.longitude, fix.altitude, fix.header.frame_id) == (49.0, 8.4, 110.0, "gps")
    update = log.convert(1)["updates"][0]
    assert update["timestamp"] == (T0 + 100_000_000) / 1e9
    assert update["poses"]["/vehicle_pose"]["position"] == [1.0, 0.0, 0.0]
    primitives = update["primitives"]
    (cloud,) = primitives["/lidar"]["points"]
    assert np.array_equal(cloud["points"], POINTS[:2])  # the beam without a return left out
    # The same cloud with a pose in its frame: the points moved by it, the beam without a return still left out.
    (posed,) = primitives["/lidar_posed"]["points"]
    sensor = matrix(SimpleNamespace(x=0.0, y=0.0, z=1.0), SimpleNamespace(**dict(zip("xyzw", QUARTER_LEFT_XYZW))))
    np.testing.assert_allclose(posed["points"], apply(sensor, POINTS[:2]), atol=1e-6)
    assert posed["points"][0].tolist() == pytest.approx([-2.0, 1.0, 4.0])
    # PosesInFrame as a nav_msgs/Path (in the vehicle frame), Odometry's twist as time series.
    (route,) = primitives["/route"]["polylines"]
    np.testing.assert_allclose(route["vertices"], [[3.0, 2.0, 0.0], [6.0, 2.0, 0.0]])
    values = {s: v for series in update["time_series"] for s, v in zip(series["streams"], series["values"]["doubles"])}
    assert values == {"/wheel_odom/speed": 10.0, "/wheel_odom/yaw_rate": 0.25}
    (scan,) = primitives["/scan"]["points"]  # the return at infinity left out
    np.testing.assert_allclose(scan["points"], [[2.0, 0.0, 0.0], [0.0, 3.0, 0.0]], atol=1e-6)
    assert [p["base"]["object_id"] for p in primitives["/scene/polygons"]["polygons"]] == ["car/0"]
    # The entity's model (a mesh) is not drawn, as a ROS mesh marker is not; its cube and text are.
    assert [(t["text"], t["base"]["object_id"]) for t in primitives["/scene/texts"]["texts"]] == [("car", "car/2")]
    assert [image["width_px"] for image in primitives["/camera"]["images"]] == [32]
    # /goal is drawn as a trajectory in the vehicle frame: 10 m ahead of a vehicle at x=1, then 11 m.
    (goal,) = primitives["/goal"]["polylines"]
    np.testing.assert_allclose(goal["vertices"], [[9.0, 1.0, 0.0], [10.0, 1.0, 0.0]], atol=1e-6)
    rows = [n["column_values"] for n in update["ui_primitives"]["/log"]["treetable"]["nodes"]]
    assert [r[1:] for r in rows] == [["WARN", "planner", "frame 1"], ["WARN", "planner", "frame 0"]]
    rows = [n["column_values"] for n in update["ui_primitives"]["/json_log"]["treetable"]["nodes"]]
    assert [r[1:] for r in rows] == [["ERROR", "json", "json 1"], ["ERROR", "json", "json 0"]]
    # Foxglove clients get the channels as written: protobuf schemas in base64, JSON as it is.
    originals = {o.topic: o for o in log.originals}
    assert (originals["/lidar"].encoding, originals["/lidar"].schema_name, originals["/lidar"].schema_encoding) == (
        "protobuf",
        "foxglove.PointCloud",
        "protobuf",
    )
    assert (originals["/json_log"].encoding, originals["/json_log"].schema_encoding) == ("json", "jsonschema")


# -- ROS 1 ------------------------------------------------------------------------------


def test_a_turtlesim_recording_shows_its_twist_as_time_series():
    from rosbags.rosbag1 import Reader
    from rosbags.typesys import Stores, get_typestore

    path = RECORDINGS / "ros1" / "turtlesim.bag"
    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(path) as reader:  # the messages as rosbags reads them, to compare with
        recorded = [(t, store.deserialize_ros1(data, c.msgtype)) for c, t, data in reader.messages()]
    log = RosBag(path)
    assert [m.describe() for m in log.mappings] == ["TIME_SERIES /turtle1/cmd_vel/linear_x, /turtle1/cmd_vel/angular_z"]
    shown = 0
    for frame, tick in enumerate(log.clock):
        series = log.convert(frame)["updates"][0].get("time_series", [])
        before = [(t, m) for t, m in recorded if t <= tick and tick - t <= 10**9]
        if not before:
            assert series == []
            continue
        t, message = before[-1]
        values = {stream: value for s in series for stream, value in zip(s["streams"], s["values"]["doubles"])}
        assert values == {
            "/turtle1/cmd_vel/linear_x": message.linear.x,
            "/turtle1/cmd_vel/angular_z": message.angular.z,
        }
        assert {s["timestamp"] for s in series} == {t / 1e9}
        shown += 1
    assert shown > len(log) // 2


EMBAG = RECORDINGS / "ros1" / "embag"


def test_a_truck_recording_cloud_odometry_and_a_scan_without_its_frame(caplog: pytest.LogCaptureFixture):
    from rosbags.rosbag1 import Reader
    from rosbags.typesys import Stores, get_typestore

    path = EMBAG / "test.bag"
    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(path) as reader:  # the clouds as rosbags reads them, to compare with
        clouds = [
            store.deserialize_ros1(data, c.msgtype)
            for c, _, data in reader.messages()
            if c.topic == "/luminar_pointcloud"
        ]
    log = RosBag(path)
    assert {m.topic: m.role for m in log.mappings} == {
        "/base_pose_ground_truth": "pose",
        "/base_scan": "points",
        "/luminar_pointcloud": "points",
    }
    # The PointCloud2 topic is the clock (not the LaserScan beside it, recorded 7 s later).
    assert log.clock.tolist() == log.bag.topics["/luminar_pointcloud"].times.tolist()
    for frame, cloud in enumerate(clouds):
        update = log.convert(frame)["updates"][0]
        records = np.frombuffer(
            bytes(cloud.data),
            np.dtype(
                {"names": ["x", "y", "z"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": cloud.point_step}
            ),
        )
        xyz = np.stack([records[a] for a in "xyz"], axis=1)
        returned = xyz[np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)]
        (points,) = update["primitives"]["/luminar_pointcloud"]["points"]
        assert np.array_equal(points["points"], returned) and len(returned) > 30_000
        assert "/base_scan" not in update["primitives"]  # its frame has no transform to the vehicle's: named once
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        f"{path}: topic /base_scan: frame 'base_laser_link' is not connected to the vehicle frame (left out of the frames)"
    ]


def test_strings_recorded_two_minutes_apart_each_shown():
    log = RosBag(EMBAG / "test_2.bag")
    shown = {
        (row[0], row[3])
        for frame in (0, len(log) - 1)
        for row in _text_rows_of(log.convert(frame)["updates"][0], "/chatter")
    }
    assert shown == {
        (str(t / 1e9), log.bag.message("chatter", i)[1].data) for i, t in enumerate(log.bag.topics["chatter"].times)
    }


def _text_rows_of(update: dict[str, object], stream: str) -> list[list[str]]:
    table = update.get("ui_primitives", {}).get(stream)  # type: ignore[attr-defined]
    return [node["column_values"] for node in table["treetable"]["nodes"]] if table else []


@pytest.mark.parametrize(
    ("relative", "container"),
    [
        ("rosbag2/sqlite3/talker", "ROS 2 sqlite3"),
        ("rosbag2/topics_and_services.db3", "ROS 2 sqlite3"),
        ("rosbag2/mcap/bag_with_topics_and_service_events", "ROS 2 mcap"),
        ("ros1/turtlesim.bag", "ROS 1"),
        ("mcap-conformance/OneMessage/OneMessage-ch-chx-mx.mcap", "MCAP"),
    ],
)
def test_the_catalog_gives_a_recording_its_container_as_format(relative: str, container: str):
    from xviz_server.catalog.facts import facts
    from xviz_server.codec import Format
    from xviz_server.timeindex import TimeIndex

    log = RosBag(RECORDINGS / relative)
    index = TimeIndex.from_spans((float(t), float(t), i) for i, t in enumerate(log.times))
    assert facts("rosbag", Format.BINARY, log.metadata(), index, None, None)["format"] == container


async def foxglove_head(bag: Path, name: str, seconds: float = 8.0) -> dict[str, object]:
    """What the published Foxglove client got of ``bag``'s real-time playback within ``seconds`` (all of a bag that
    ends sooner: the client stops once nothing more comes)."""
    async with running_server(None, dataset=[f"rosbag:{bag}"]) as server:
        out = await foxglove_client(
            f"ws://127.0.0.1:{server.port}/?log={name}",
            "foxglove.websocket.v1",
            options=("--timeout-ms", str(int(seconds * 1000))),
        )
    assert out["errors"] in ([], ["timeout"]) and out["statuses"] == []
    return out


def _recorded(path: Path, topic: str) -> list[tuple[int, object]]:
    """``topic``'s messages as rosbags reads them from a ROS 1 bag: (record time, message)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:  # with the definitions the bag holds
        connections = [c for c in reader.connections if c.topic == topic]
        return [(t, reader.deserialize(data, c.msgtype)) for c, t, data in reader.messages(connections)]


def _assert_the_served_poses_are_the_frames(log: RosBag, out: dict[str, object]) -> None:
    """Each ``/xviz/vehicle_pose`` transform the Foxglove client got is the XVIZ pose of the frame at its time."""
    poses = out["topics"]["/xviz/vehicle_pose"]  # type: ignore[index]
    assert poses["count"] >= 2
    clock = np.asarray(log.clock, np.int64)
    for time, summary in zip(poses["timestamps"], poses["summaries"]):
        frame = int(np.argmin(np.abs(clock - int(time))))
        assert abs(int(clock[frame]) - int(time)) < 1000  # the frame's time, through the XVIZ float seconds
        position = log.convert(frame)["updates"][0]["poses"]["/vehicle_pose"]["position"]
        assert [summary["translation"].get(axis, 0.0) for axis in "xyz"] == pytest.approx(position)


TURTLES = RECORDINGS / "ros1" / "lichtblick" / "example-bz2.bag"


@pytest.mark.slow
def test_a_tf_tree_of_two_turtles_moves_the_vehicle_pose():
    # /tf (tf/tfMessage, bz2 chunks) holds world -> turtle1 and world -> turtle2; /tf_static (tf2_msgs) beside it.
    moves = [
        (t, transform.transform.translation)
        for t, message in _recorded(TURTLES, "/tf")
        for transform in message.transforms  # type: ignore[attr-defined]
        if (transform.header.frame_id, transform.child_frame_id) == ("world", "turtle1")
    ]
    log = RosBag(TURTLES)
    assert log.bag.topics["/tf"].msgtype == "tf/msg/tfMessage" and len(log.bag.topics["/tf"]) == 2688
    assert {"world", "turtle1", "turtle2"} <= log.tree.frames
    assert log.pose_source.describe() == "/tf: world -> turtle1"
    times = np.array([t for t, _ in moves], float)
    positions = []
    for frame, tick in enumerate(log.clock):
        position = log.convert(frame)["updates"][0]["poses"]["/vehicle_pose"]["position"]
        if times[0] <= tick <= times[-1]:  # interpolated between the transforms recorded either side
            expected = [np.interp(tick, times, [getattr(v, axis) for _, v in moves]) for axis in "xy"]
            np.testing.assert_allclose(position[:2], expected, atol=1e-6)
        positions.append(position)
    # The turtle drives over the whole 11 x 11 m field, not a pose stuck at the origin.
    spread = np.ptp(np.array(positions)[:, :2], axis=0)
    assert (spread > 5.0).all(), spread


@pytest.mark.slow
async def test_a_tf_tree_on_the_foxglove_face_the_pose_and_the_original_transforms():
    log = RosBag(TURTLES)
    out = await foxglove_head(TURTLES, "example-bz2")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert (channels["/tf"]["encoding"], channels["/tf"]["schemaName"]) == ("ros1", "tf/tfMessage")
    assert channels["/xviz/vehicle_pose"]["schemaName"] == "foxglove.FrameTransform"
    _assert_the_served_poses_are_the_frames(log, out)
    topics = out["topics"]
    recorded = {str(t) for t, _ in _recorded(TURTLES, "/tf")}
    assert topics["/tf"]["count"] > 0 and set(topics["/tf"]["timestamps"]) <= recorded  # type: ignore[index]


HUSKY = RECORDINGS / "ros1" / "robot_localization" / "test1.bag"


def test_navsat_fixes_give_the_map_origin_beside_odometry():
    fixes = _recorded(HUSKY, "/fix")
    first = fixes[0][1]
    log = RosBag(HUSKY)
    assert {m.topic: m.role for m in log.mappings} == {
        "/fix": "origin",
        "/husky_velocity_controller/odom": "pose",
        "/imu/data": "series",
    }
    assert len(log.bag.topics["/fix"]) == 989
    origin = (first.longitude, first.latitude, first.altitude)  # type: ignore[attr-defined]
    assert log.map_origin == origin
    expected = dict(zip(("longitude", "latitude", "altitude"), origin))
    for frame in (0, len(log) // 2, len(log) - 1):
        assert log.convert(frame)["updates"][0]["poses"]["/vehicle_pose"]["map_origin"] == expected


@pytest.mark.slow
async def test_navsat_fixes_on_the_foxglove_face_as_recorded():
    out = await foxglove_head(HUSKY, "test1")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert (channels["/fix"]["encoding"], channels["/fix"]["schemaName"]) == ("ros1", "sensor_msgs/NavSatFix")
    fixes = out["topics"]["/fix"]  # type: ignore[index]
    recorded = [str(t) for t, _ in _recorded(HUSKY, "/fix")]
    assert fixes["count"] >= 2 and fixes["timestamps"] == recorded[: fixes["count"]]
    assert {"latitude", "longitude", "altitude", "status"} <= set(fixes["summaries"][0])


def _frames_posed_like(
    log: RosBag, recorded: list[tuple[int, Any]], axes: str
) -> Iterator[tuple[int, dict[str, Any], list[float]]]:
    """Each frame's time, update and vehicle position, once its position on ``axes`` is checked to be ``recorded``'s
    positions interpolated at the frame's time (where the frame is within them)."""
    times = np.array([t for t, _ in recorded], float)
    for frame, tick in enumerate(log.clock):
        update = log.convert(frame)["updates"][0]
        position = update["poses"]["/vehicle_pose"]["position"]
        if times[0] <= tick <= times[-1]:
            expected = [np.interp(tick, times, [getattr(p, axis) for _, p in recorded]) for axis in axes]
            np.testing.assert_allclose(position[: len(axes)], expected, atol=1e-6)
        yield int(tick), update, position


EKF = RECORDINGS / "ros1" / "robot_pose_ekf" / "gps_data_10s.bag"


def test_a_robots_own_tf_tree_rides_on_its_odometry_the_other_odometry_a_trajectory(caplog: pytest.LogCaptureFixture):
    # A Husky: /tf holds the robot's joints alone (/base_footprint -> /base_link and its parts, republished), the wheel
    # odometry /encoder (odom_combined -> base_footprint) moves the tree's root, /gps is a second Odometry in /world.
    encoder = [(t, m.pose.pose.position) for t, m in _recorded(EKF, "/encoder")]  # type: ignore[attr-defined]
    log = RosBag(EKF)
    roles = {m.topic: m.role for m in log.mappings}
    assert (roles["/encoder"], roles["/gps"], roles["/tf"], roles["/fix"]) == (
        "pose",
        "trajectory",
        "transforms",
        "origin",
    )
    assert log.pose_source.describe() == "/encoder (odom_combined -> base_link)"
    gps = [t for t, _ in _recorded(EKF, "/gps")]
    positions = []
    for tick, update, position in _frames_posed_like(log, encoder, "xy"):
        positions.append(position)
        series = {stream for s in update.get("time_series", []) for stream in s["streams"]}
        if tick >= gps[0]:  # the other odometry (2.5 Hz): its speed and yaw rate beside the pose's
            assert {"/gps/speed", "/gps/yaw_rate", "/encoder/speed", "/encoder/yaw_rate"} <= series
        assert "/gps" not in update.get("primitives", {})  # /world has no transform to odom_combined: named once
    spread = np.ptp(np.array(positions)[:, :2], axis=0)  # the robot drives about 3 x 2 m, not stuck at the origin
    assert (spread > 1.5).all(), spread
    streams = log.metadata()["streams"]
    assert streams["/gps"]["primitive_type"] == "POLYLINE" and streams["/gps/speed"]["scalar_type"] == "FLOAT"
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        f"{EKF}: topic /gps: frame '/world' is not connected to the vehicle frame (left out of the frames)"
    ]


@pytest.mark.slow
async def test_a_robots_odometry_on_the_foxglove_face_the_pose_and_the_original_odometry():
    log = RosBag(EKF)
    out = await foxglove_head(EKF, "gps_data_10s", seconds=4.0)
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    for topic in ("/encoder", "/gps"):
        assert (channels[topic]["encoding"], channels[topic]["schemaName"]) == ("ros1", "nav_msgs/Odometry")
    assert channels["/xviz/vehicle_pose"]["schemaName"] == "foxglove.FrameTransform"
    _assert_the_served_poses_are_the_frames(log, out)
    topics = out["topics"]
    for topic in ("/encoder", "/gps"):  # as recorded, at their record times
        recorded = [str(t) for t, _ in _recorded(EKF, topic)]
        got = topics[topic]  # type: ignore[index]
        assert got["count"] >= 2 and got["timestamps"] == recorded[: got["count"]]


DRONE = RECORDINGS / "ros1" / "rotors" / "waypoint_example_15s.bag"


def test_a_drone_flies_on_its_ground_truth_pose_stamped():
    # RotorS's simulated quadrotor taking off: geometry_msgs/PoseStamped at 100 Hz, no transform tree.
    recorded = [(t, m.pose.position) for t, m in _recorded(DRONE, "/ground_truth/pose")]  # type: ignore[attr-defined]
    twists = _recorded(DRONE, "/ground_truth/twist")
    log = RosBag(DRONE)
    roles = {m.topic: m.role for m in log.mappings}
    assert (roles["/ground_truth/pose"], roles["/ground_truth/twist"]) == ("pose", "series")
    assert log.pose_source.topic == "/ground_truth/pose" and log.pose_source.kind == "topic"
    heights = []
    for tick, update, position in _frames_posed_like(log, recorded, "xyz"):
        heights.append(position[2])
        t, twist = [(t, m) for t, m in twists if t <= tick][-1]
        values = {
            s: v for series in update["time_series"] for s, v in zip(series["streams"], series["values"]["doubles"])
        }
        assert values == {
            "/ground_truth/twist/linear_x": twist.twist.linear.x,  # type: ignore[attr-defined]
            "/ground_truth/twist/angular_z": twist.twist.angular.z,  # type: ignore[attr-defined]
        }
    assert heights[0] < 0.2 and heights[-1] > 0.9  # it takes off to its first waypoint, 1 m up


@pytest.mark.slow
async def test_a_drone_on_the_foxglove_face_the_pose_and_the_original_pose_stamped():
    log = RosBag(DRONE)
    out = await foxglove_head(DRONE, "waypoint_example_15s", seconds=4.0)
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    pose = channels["/ground_truth/pose"]
    assert (pose["encoding"], pose["schemaName"]) == ("ros1", "geometry_msgs/PoseStamped")
    assert channels["/xviz/vehicle_pose"]["schemaName"] == "foxglove.FrameTransform"
    _assert_the_served_poses_are_the_frames(log, out)
    got = out["topics"]["/ground_truth/pose"]  # type: ignore[index]
    recorded = [str(t) for t, _ in _recorded(DRONE, "/ground_truth/pose")]
    assert got["count"] >= 2 and got["timestamps"] == recorded[: got["count"]]


CUBE = RECORDINGS / "ros1" / "webviz" / "only-a-cube.bag"


def _cube_in_vehicle_frame() -> np.ndarray:
    """The footprint of the recorded cube, from its frame (the tree's root) into the vehicle frame (the tree's child)."""
    ((_, tf),) = _recorded(CUBE, "/tf")
    ((_, marker),) = _recorded(CUBE, "/marker_in_parent_frame")
    edge = tf.transforms[0].transform  # type: ignore[attr-defined]
    x, y, z, w = (getattr(edge.rotation, axis) for axis in "xyzw")
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    translation = np.array([getattr(edge.translation, axis) for axis in "xyz"])
    centre = np.array([getattr(marker.pose.position, axis) for axis in "xyz"])  # type: ignore[attr-defined]
    half = np.array([getattr(marker.scale, axis) for axis in "xyz"]) / 2  # type: ignore[attr-defined]
    corners = [centre + half * [sx, sy, -1] for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return (np.array(corners) - translation) @ rotation  # the inverse of the vehicle's pose in the marker's frame


def test_a_marker_recorded_after_the_last_frame_time_is_drawn():
    log = RosBag(CUBE)
    assert {m.topic: m.role for m in log.mappings} == {"/marker_in_parent_frame": "markers", "/tf": "transforms"}
    # The only transform starts the clock; the cube comes 1 ms later, and a last frame holds it.
    assert log.bag.topics["/marker_in_parent_frame"].times[0] > log.clock[0]
    assert "primitives" not in log.convert(0)["updates"][0]
    (cube,) = log.convert(len(log) - 1)["updates"][0]["primitives"]["/marker_in_parent_frame/polygons"]["polygons"]
    assert cube["base"]["object_id"] == "0" and cube["base"]["style"] == {"fill_color": [0, 0, 255, 128], "height": 1.0}
    drawn, expected = np.asarray(cube["vertices"]), _cube_in_vehicle_frame()
    distances = np.linalg.norm(drawn[:, None, :] - expected[None, :, :], axis=2)  # each corner drawn once
    assert (
        drawn.shape == (4, 3)
        and sorted(distances.argmin(axis=1)) == [0, 1, 2, 3]
        and distances.min(axis=1).max() < 1e-5
    )


@pytest.mark.slow
async def test_a_marker_on_the_foxglove_face_converted_and_as_recorded():
    out = await foxglove_head(CUBE, "only-a-cube")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert channels["/marker_in_parent_frame"]["schemaName"] == "visualization_msgs/Marker"
    assert channels["/xviz/marker_in_parent_frame/polygons"]["schemaName"] == "foxglove.SceneUpdate"
    topics = out["topics"]
    ((recorded, _),) = _recorded(CUBE, "/marker_in_parent_frame")
    assert topics["/marker_in_parent_frame"]["timestamps"] == [str(recorded)]  # type: ignore[index]
    # The last frame's scene: the cube, after a deletion of what the frame before drew.
    assert topics["/xviz/marker_in_parent_frame/polygons"]["summaries"] == [{"entities": 1, "deletions": 1}]  # type: ignore[index]


VOXELS = RECORDINGS / "ros1" / "jsk_recognition" / "bunny_marker_array.bag"
VOXEL_TOPIC = "/octree_voxel_grid/output_marker_array"


def test_a_voxel_grid_marker_array_is_drawn_cube_by_cube_in_its_colours():
    # jsk_pcl_ros's octree voxel grid: 17 MarkerArrays of one CUBE_LIST in /map, 7 cubes of 10 cm, one colour a cube
    # (blue below, red above, alpha 0.8) and the marker's own colour fully transparent.
    recorded = _recorded(VOXELS, VOXEL_TOPIC)
    log = RosBag(VOXELS)
    assert {m.topic: m.role for m in log.mappings} == {VOXEL_TOPIC: "markers"}
    assert log.pose_source.kind == "none"  # no transform tree: /map is the vehicle's frame, at the origin
    assert log.clock[0] == recorded[0][0] and len(log) == 18  # 10 Hz from the first message to past the last
    for frame, tick in enumerate(log.clock):  # each frame draws the latest array
        polygons = log.convert(frame)["updates"][0]["primitives"][f"{VOXEL_TOPIC}/polygons"]
        (marker,) = [m for t, m in recorded if t <= tick][-1].markers  # type: ignore[attr-defined]
        assert (marker.type, marker.color.a, marker.header.frame_id) == (6, 0.0, "/map")  # CUBE_LIST
        drawn = polygons["polygons"]
        assert len(drawn) == len(marker.points) == 7
        for cube, point, color in zip(drawn, marker.points, marker.colors):
            centre = np.array([point.x, point.y, point.z])
            corners = np.asarray(cube["vertices"])
            np.testing.assert_allclose(corners.min(axis=0), centre - [0.05, 0.05, 0.05], atol=1e-6)
            np.testing.assert_allclose(corners.max(axis=0), centre + [0.05, 0.05, -0.05], atol=1e-6)
            rgba = [round(getattr(color, c) * 255) for c in "rgba"]
            assert cube["base"] == {"object_id": "0", "style": {"fill_color": rgba, "height": pytest.approx(0.1)}}
    assert {tuple(c["base"]["style"]["fill_color"]) for c in drawn} == {(0, 0, 255, 204), (255, 0, 0, 204)}


@pytest.mark.slow
async def test_a_marker_array_on_the_foxglove_face_converted_and_as_recorded():
    out = await foxglove_head(VOXELS, "bunny_marker_array")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert (channels[VOXEL_TOPIC]["encoding"], channels[VOXEL_TOPIC]["schemaName"]) == (
        "ros1",
        "visualization_msgs/MarkerArray",
    )
    assert channels[f"/xviz{VOXEL_TOPIC}/polygons"]["schemaName"] == "foxglove.SceneUpdate"
    topics = out["topics"]
    recorded = [str(t) for t, _ in _recorded(VOXELS, VOXEL_TOPIC)]
    assert topics[VOXEL_TOPIC]["timestamps"] == recorded  # type: ignore[index]
    scenes = topics[f"/xviz{VOXEL_TOPIC}/polygons"]["summaries"]  # type: ignore[index]
    assert len(scenes) == len(RosBag(VOXELS)) and all(scene["entities"] == 7 for scene in scenes), (
        scenes
    )  # a frame each


VELODYNE = RECORDINGS / "rosbag2" / "nebula" / "vlp32" / "1713492677464078412"
OUSTER = RECORDINGS / "ros1" / "ouster" / "512x10_raw.bag"
PACKETS = (
    "holds the raw packets of a sensor's driver, not points: record the driver's point cloud topic, "
    "or replay the bag through the driver"
)


@pytest.mark.parametrize(
    ("path", "topics"),
    [
        (VELODYNE, {"/sensing/lidar/front/velodyne_packets": "velodyne_msgs/msg/VelodyneScan"}),
        (
            OUSTER,
            {
                "/os_node0/lidar_packets": "ouster_ros/msg/PacketMsg",
                "/os_node0/imu_packets": "ouster_ros/msg/PacketMsg",
            },
        ),
    ],
    ids=["velodyne-vlp32-sqlite3", "ouster-ros1"],
)
def test_driver_packets_are_named_per_channel(path: Path, topics: dict[str, str]):
    log = RosBag(path)
    assert {t: log.bag.topics[t].msgtype for t in topics} == topics
    assert {t: log.bag.problems[t] for t in topics} == {t: f"{msgtype} {PACKETS}" for t, msgtype in topics.items()}
    assert {m.topic: m.role for m in log.mappings if m.topic in topics} == dict.fromkeys(topics, "unknown")
    # The bag is served: its frames (the packets' times, 10 Hz over the bag), with what else it holds.
    assert len(log) >= 2
    for frame in range(len(log)):
        update = log.convert(frame)["updates"][0]
        assert update["poses"]["/vehicle_pose"]["position"] == [0.0, 0.0, 0.0] and "primitives" not in update


@pytest.mark.slow
async def test_driver_packets_on_the_foxglove_face():
    # Ouster's ROS 1 bag holds the packets' definition: they go to Foxglove clients as recorded, every one.
    out = await foxglove_head(OUSTER, "512x10_raw")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert channels["/os_node0/lidar_packets"]["schemaName"] == "ouster_ros/PacketMsg"
    counts = {t: info["count"] for t, info in out["topics"].items()}  # type: ignore[attr-defined]
    assert (counts["/os_node0/lidar_packets"], counts["/os_node0/imu_packets"]) == (32, 10)
    # The sqlite3 bag holds no definition of VelodyneScan: no channel for it (the protocol needs a schema), the rest
    # of the session goes on.
    out = await foxglove_head(VELODYNE, "1713492677464078412")
    topics = {c["topic"] for c in out["channels"]}  # type: ignore[attr-defined]
    assert "/sensing/lidar/front/velodyne_packets" not in topics and out["topics"]["/vehicle_pose"]["count"] == 5  # type: ignore[index]


# -- an Ouster cloud: the real packets above decoded by the Ouster SDK -------------------

OUSTER_CLOUD = RECORDINGS / "ros1" / "ouster" / "cloud.bag"


def _cloud_fields(cloud: object) -> dict[str, np.ndarray]:
    """Every field of an organised little-endian ``PointCloud2`` as recorded, by its own field list, one row a point."""
    kinds = {2: "u1", 4: "u2", 6: "u4", 7: "f4"}  # the PointField datatypes this cloud uses
    fields = cloud.fields  # type: ignore[attr-defined]
    layout = np.dtype(
        {
            "names": [f.name for f in fields],
            "formats": ["<" + kinds[f.datatype] for f in fields],
            "offsets": [f.offset for f in fields],
            "itemsize": cloud.point_step,  # type: ignore[attr-defined]
        }
    )
    records = np.frombuffer(bytes(cloud.data), layout)  # type: ignore[attr-defined]
    return {name: records[name] for name in layout.names}


def test_an_ouster_cloud_is_served_without_its_no_return_points():
    ((recorded, cloud),) = _recorded(OUSTER_CLOUD, "/ouster/points")
    assert (cloud.height, cloud.width) == (128, 512)  # type: ignore[attr-defined]
    fields = _cloud_fields(cloud)
    xyz = np.stack([fields[axis] for axis in "xyz"], axis=1)
    # A beam without a return is exactly (0, 0, 0), its range 0: more than half of this cloud, as in the issue's.
    missing = (xyz == 0).all(axis=1)
    assert np.array_equal(missing, fields["range"] == 0) and missing.sum() > len(xyz) // 2
    log = RosBag(OUSTER_CLOUD)
    assert {m.topic: m.role for m in log.mappings} == {
        "/ouster/points": "points",
        "/ouster/imu": "series",
        "/ouster/metadata": "text",
    }
    assert log.clock.tolist() == [recorded]
    update = log.convert(0)["updates"][0]
    (points,) = update["primitives"]["/ouster/points"]["points"]
    assert np.array_equal(points["points"], xyz[~missing])  # every return, in the cloud's order; no (0, 0, 0)
    # The IMU beside it: the latest of its messages at the cloud's time.
    imus = _recorded(OUSTER_CLOUD, "/ouster/imu")
    _, imu = [(t, m) for t, m in imus if t <= recorded][-1]
    values = {s: v for series in update["time_series"] for s, v in zip(series["streams"], series["values"]["doubles"])}
    assert values == {
        "/ouster/imu/acceleration": imu.linear_acceleration.x,  # type: ignore[attr-defined]
        "/ouster/imu/yaw_rate": imu.angular_velocity.z,  # type: ignore[attr-defined]
    }


@pytest.mark.slow
async def test_an_ouster_cloud_on_the_foxglove_face_converted_and_as_recorded():
    ((recorded, cloud),) = _recorded(OUSTER_CLOUD, "/ouster/points")
    returns = int((np.stack([_cloud_fields(cloud)[axis] for axis in "xyz"], axis=1) != 0).any(axis=1).sum())
    out = await foxglove_head(OUSTER_CLOUD, "cloud")
    channels = {c["topic"]: c for c in out["channels"]}  # type: ignore[attr-defined]
    assert (channels["/ouster/points"]["encoding"], channels["/ouster/points"]["schemaName"]) == (
        "ros1",
        "sensor_msgs/PointCloud2",
    )
    assert channels["/xviz/ouster/points"]["schemaName"] == "foxglove.PointCloud"
    topics = out["topics"]
    # The original, every point of it; the converted cloud, its returns only.
    (original,) = topics["/ouster/points"]["summaries"]  # type: ignore[index]
    assert topics["/ouster/points"]["timestamps"] == [str(recorded)]  # type: ignore[index]
    assert (original["width"], original["height"], original["bytes"]) == (512, 128, len(cloud.data))  # type: ignore[attr-defined]
    (converted,) = topics["/xviz/ouster/points"]["summaries"]  # type: ignore[index]
    assert converted["points"] == returns < 512 * 128
    assert topics["/ouster/imu"]["count"] == len(_recorded(OUSTER_CLOUD, "/ouster/imu"))  # type: ignore[index]


# -- MCAP of the ros1 profile: real bags as `mcap convert` writes them --------------------


@pytest.mark.parametrize(
    "relative",
    ["ros1/ouster/cloud.bag", "ros1/robot_localization/test1.bag", "ros1/lichtblick/example-bz2.bag"],
    ids=["ouster-cloud", "husky-navsatfix", "turtles-tf-tree"],
)
def test_a_ros1_profile_mcap_serves_like_its_bag(relative: str, tmp_path: Path):
    from mcap.reader import make_reader
    from ros1_profile_mcap import write_ros1_mcap
    from rosbags.rosbag1 import Reader

    bag = RECORDINGS / relative
    path = write_ros1_mcap(bag, tmp_path / f"{bag.stem}.mcap")
    with path.open("rb") as file:  # the file as MCAP's reader sees it: the ros1 profile, the bag's bytes
        reader = make_reader(file)
        assert reader.get_header().profile == "ros1"
        written = [
            (c.topic, s.name, s.encoding, c.message_encoding, m.log_time, m.data) for s, c, m in reader.iter_messages()
        ]
    with Reader(bag) as source:
        recorded = [
            (c.topic, c.msgtype.replace("/msg/", "/"), "ros1msg", "ros1", t, bytes(d)) for c, t, d in source.messages()
        ]
    assert sorted(written) == sorted(recorded)
    # Served as the bag is: the same roles, clock and pose source, and frame for frame the same XVIZ.
    original, converted = RosBag(bag), RosBag(path)
    assert converted.bag.container == "MCAP" and converted.bag.problems == original.bag.problems == {}
    assert [(m.topic, m.role) for m in converted.mappings] == [(m.topic, m.role) for m in original.mappings]
    assert converted.clock.tolist() == original.clock.tolist()
    assert converted.pose_source.describe() == original.pose_source.describe()
    metadata, expected = converted.metadata(), original.metadata()
    assert metadata["log_info"].pop("source") == f"MCAP bag {bag.stem}"  # the container named, the rest the same
    assert expected["log_info"].pop("source") == f"ROS 1 bag {bag.stem}" and metadata == expected
    frames = sorted({*range(0, len(original), max(1, len(original) // 25)), len(original) - 1})
    for frame in frames:
        assert_same_message(converted.convert(frame), original.convert(frame), f"frame {frame}")


def _recorded_channels(out: dict[str, object]) -> dict[str, tuple[str, str, str]]:
    """The channels of the file's own topics a Foxglove client got (not the converted /xviz ones): encoding, schema
    name and schema encoding by topic."""
    channels: list[dict[str, str]] = out["channels"]  # type: ignore[assignment]
    return {
        c["topic"]: (c["encoding"], c["schemaName"], c["schemaEncoding"])
        for c in channels
        if not c["topic"].startswith("/xviz/")
    }


@pytest.mark.slow
async def test_a_ros1_profile_mcap_on_the_foxglove_face(tmp_path: Path):
    from ros1_profile_mcap import write_ros1_mcap

    path = write_ros1_mcap(OUSTER_CLOUD, tmp_path / "ouster.mcap")
    out = await foxglove_head(path, "ouster")
    # The channels as the file declares them: ROS 1 messages, their schemas named as in ROS 1.
    assert _recorded_channels(out) == {
        "/ouster/points": ("ros1", "sensor_msgs/PointCloud2", "ros1msg"),
        "/ouster/imu": ("ros1", "sensor_msgs/Imu", "ros1msg"),
        "/ouster/metadata": ("ros1", "std_msgs/String", "ros1msg"),
    }
    topics = out["topics"]
    recorded = {
        topic: [str(t) for t, _ in _recorded(OUSTER_CLOUD, topic)] for topic in ("/ouster/points", "/ouster/imu")
    }
    assert {t: topics[t]["timestamps"] for t in recorded} == recorded  # type: ignore[index]
    bag = await foxglove_head(OUSTER_CLOUD, "cloud")  # the converted cloud as the bag's
    assert topics["/xviz/ouster/points"]["summaries"] == bag["topics"]["/xviz/ouster/points"]["summaries"]  # type: ignore[index]


# -- MCAP without a profile: foxglove schemas in JSON, as Lichtblick's tests write them ----

LICHTBLICK = RECORDINGS / "mcap" / "lichtblick"


def _json_messages(path: Path, topic: str) -> list[tuple[int, dict[str, object]]]:
    """``topic``'s messages as MCAP's reader reads them from ``path``: (log time, the decoded JSON)."""
    from mcap.reader import make_reader

    with path.open("rb") as file:
        return [(m.log_time, json.loads(m.data)) for _, c, m in make_reader(file).iter_messages() if c.topic == topic]


def test_foxglove_logs_in_json_each_shown_in_the_messages_table():
    path = LICHTBLICK / "example_logs.mcap"
    logs = _json_messages(path, "/rosout")
    log = RosBag(path)
    assert log.bag.container == "MCAP" and log.bag.problems == {}
    assert {m.topic: m.describe() for m in log.mappings} == {
        "/rosout": "UI_PRIMITIVE (a table of the recent messages) /rosout",
        "mouse": "unknown type, not served",
    }
    levels = {1: "DEBUG", 2: "INFO", 3: "WARN", 4: "ERROR", 5: "FATAL"}  # foxglove.LogLevel
    shown: set[tuple[str, str]] = set()
    for frame in range(len(log)):
        rows = _text_rows_of(log.convert(frame)["updates"][0], "/rosout")
        assert 0 < len(rows) <= 200
        shown |= {(level, text) for _, level, _, text in rows}
    # Every one of the 1000 messages is in some frame's table, with its level.
    assert len(logs) == 1000 and shown == {(levels[m["level"]], m["message"]) for _, m in logs}  # type: ignore[index]


def _jpegs(path: Path) -> list[tuple[int, bytes]]:
    """The images of ``/image/compressed``, a JSON channel of ``foxglove.CompressedImage``: (log time, the bytes)."""
    import base64

    return [(t, base64.b64decode(m["data"])) for t, m in _json_messages(path, "/image/compressed")]  # type: ignore[arg-type]


def test_foxglove_compressed_images_in_json_with_their_recorded_times():
    import io

    from PIL import Image

    path = LICHTBLICK / "custom-camera-model.mcap"
    images = _jpegs(path)
    log, wide = RosBag(path), RosBag(path, image_max_width=640)
    assert {m.topic: m.role for m in log.mappings} == {
        "/image/compressed": "image",
        "/camera_calibration": "unknown",
        "/camera_calibration/custom": "unknown",
    }
    # The file's log times are milliseconds written as nanoseconds (1.7e12 ns: 1747 s after the epoch): served as
    # they are, each image in the first frame at or after it (10 Hz over the file).
    assert log.bag.topics["/image/compressed"].times.tolist() == [t for t, _ in images]
    for time, jpeg in images:
        frame = int(np.searchsorted(log.clock, time))
        (served,) = log.convert(frame)["updates"][0]["primitives"]["/image/compressed"]["images"]
        # 520 pixels wide: scaled down to --image-max-width (400), the same picture, still a JPEG ...
        with Image.open(io.BytesIO(jpeg)) as recorded, Image.open(io.BytesIO(bytes(served["data"]))) as shown:
            assert (recorded.size, shown.format, shown.size) == ((520, 360), "JPEG", (400, 276))
            assert (served["width_px"], served["height_px"]) == shown.size
            expected = np.asarray(recorded.convert("RGB").resize(shown.size, Image.Resampling.BILINEAR), float)
            assert np.abs(np.asarray(shown.convert("RGB"), float) - expected).mean() < 8
        # ... and passed through as recorded where 520 pixels fit.
        (whole,) = wide.convert(frame)["updates"][0]["primitives"]["/image/compressed"]["images"]
        assert bytes(whole["data"]) == jpeg


@pytest.mark.slow
async def test_foxglove_json_channels_on_the_foxglove_face():
    path = LICHTBLICK / "custom-camera-model.mcap"
    out = await foxglove_head(path, "custom-camera-model")
    assert _recorded_channels(out) == {
        "/image/compressed": ("json", "foxglove.CompressedImage", "jsonschema"),
        "/camera_calibration": ("json", "foxglove.CameraCalibration", "jsonschema"),
        "/camera_calibration/custom": ("json", "foxglove.CameraCalibration", "jsonschema"),
    }
    topics = out["topics"]
    recorded = [str(t) for t, _ in _json_messages(path, "/image/compressed")]
    assert topics["/image/compressed"]["timestamps"] == recorded  # type: ignore[index]
    # The originals decode as the JSON they are (the JPEG in base64); the converted images are JPEGs too.
    originals = topics["/image/compressed"]["summaries"]  # type: ignore[index]
    assert [s["bytes"] for s in originals] == [len(jpeg) for _, jpeg in _jpegs(path)]
    converted = topics["/xviz/image/compressed"]["summaries"]  # type: ignore[index]
    assert len(converted) == len(RosBag(path))  # one a frame
    assert {(s["format"], s["magic"]) for s in originals + converted} == {("jpeg", "ffd8ffe0")}
