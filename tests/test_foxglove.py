"""Foxglove clients on the XVIZ port: the published client (@foxglove/ws-protocol) and scripted sockets."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import socket
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import InvalidStatus

from devkit.rosbag_kitti import (
    CLOUD_TOPIC,
    COLOR_TOPIC,
    COMPRESSED_TOPIC,
    GRAY_TOPIC,
    RAW,
    Messages,
    kitti_messages,
    write_bag,
)
from helpers import (
    client,
    close_received,
    eventually,
    foxglove_client,
    foxglove_opened,
    http_get,
    metric,
    running_server,
)
from xviz_server.codec import decode
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.ros import RosBag
from xviz_server.datasets.ros import dataset as ros_dataset
from xviz_server.exceptions import DatasetError, FrameSizeError
from xviz_server.foxglove.protocol import SUBPROTOCOLS
from xviz_server.records import unpack


def kitti_frames(kitti_log: Path) -> list[dict[str, Any]]:
    """The real KITTI log's updates, in time order, decoded here: what each Foxglove message must carry."""
    frames = sorted(kitti_log.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))[1:]
    return [decode(path.read_bytes())["data"]["updates"][0] for path in frames]


def nanoseconds(seconds: float) -> int:
    return round(seconds * 1e9)


@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
async def test_published_client_decodes_every_frame(kitti_root: Path, kitti_log: Path, subprotocol: str) -> None:
    updates = kitti_frames(kitti_log)
    async with running_server(kitti_root) as server:
        # It stops once the last frame's time came and its messages after it, not at a pause in playback.
        options = ("--times", str(len(updates)))
        out = await foxglove_client(f"ws://127.0.0.1:{server.port}/?log=kitti", subprotocol, options=options)
    assert out["errors"] == [] and out["statuses"] == []
    assert out["subprotocol"] == subprotocol
    assert {"time", "playbackControl"} <= set(out["serverInfo"]["capabilities"])
    assert out["serverInfo"]["dataStartTime"]["sec"] == int(updates[0]["timestamp"])
    schemas = {channel["topic"]: channel["schemaName"] for channel in out["channels"]}
    assert schemas["/lidar/points"] == "foxglove.PointCloud"
    assert schemas["/camera/image_00"] == "foxglove.CompressedImage"
    assert schemas["/vehicle_pose"] == "foxglove.FrameTransform"
    assert schemas["/vehicle_pose/pose"] == "foxglove.PoseInFrame"
    assert schemas["/vehicle_pose/location"] == "foxglove.LocationFix"
    assert schemas["/vehicle/trajectory"] == "foxglove.SceneUpdate"
    topics = out["topics"]
    # Every frame's cloud with its point count, at the frame's XVIZ time.
    clouds = topics["/lidar/points"]
    assert [summary["points"] for summary in clouds["summaries"]] == [
        len(update["primitives"]["/lidar/points"]["points"][0]["points"]) for update in updates
    ]
    assert clouds["timestamps"] == [str(nanoseconds(update["timestamp"])) for update in updates]
    assert {summary["frame_id"] for summary in clouds["summaries"]} == {"/vehicle_pose"}
    for camera in ("/camera/image_00", "/camera/image_01", "/camera/image_02", "/camera/image_03"):
        images = topics[camera]["summaries"]
        assert len(images) == len(updates)
        assert {image["format"] for image in images} == {"png"} and {image["magic"] for image in images} == {"89504e47"}
        assert [image["bytes"] for image in images] == [
            len(update["primitives"][camera]["images"][0]["data"]) for update in updates
        ]
    transforms = topics["/vehicle_pose"]["summaries"]
    assert len(transforms) == len(updates) and {(t["parent"], t["child"]) for t in transforms} == {
        ("map", "/vehicle_pose")
    }
    assert topics["/vehicle/velocity"]["count"] == len(updates)
    assert out["times"] == 1 + len(updates)  # the start time before the channels, then one per frame


async def foxglove(server: Any, path: str = "/?log=kitti", subprotocols: list[str] | None = None) -> ClientConnection:
    return await connect(
        f"ws://127.0.0.1:{server.port}{path}", subprotocols=subprotocols or ["foxglove.websocket.v1"], max_size=None
    )


async def opened(websocket: ClientConnection) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    return await foxglove_opened(websocket)


async def next_of(websocket: ClientConnection, want: str, timeout: float = 10) -> Any:
    """The next status (``want="status"``), message data (``"message"``) or playback state (``"state"``)."""
    while True:
        data = await asyncio.wait_for(websocket.recv(), timeout)
        if isinstance(data, str):
            if want == "status" and json.loads(data)["op"] == "status":
                return json.loads(data)
        elif want == "message" and data[0] == 0x01:
            return struct.unpack_from("<IQ", data, 1)
        elif want == "state" and data[0] == 0x05:
            status, current, speed, did_seek, length = struct.unpack_from("<BQfBI", data, 1)
            return status, current, speed, bool(did_seek), data[19 : 19 + length].decode()


def control(play: bool, speed: float = 1.0, seek: int | None = None, request_id: str = "r") -> bytes:
    rid = request_id.encode()
    return struct.pack("<BBfBQI", 0x03, 0 if play else 1, speed, seek is not None, seek or 0, len(rid)) + rid


async def test_first_offered_foxglove_subprotocol_is_chosen_and_xviz_is_unchanged(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        websocket = await foxglove(server, subprotocols=["xviz", "foxglove.sdk.v1", "foxglove.websocket.v1"])
        async with websocket:
            assert websocket.subprotocol == "foxglove.sdk.v1"
            await opened(websocket)
        async with client(server, "/?log=kitti") as xviz:
            assert xviz.websocket.subprotocol is None
            assert (await xviz.recv())["type"] == "xviz/metadata"


async def test_bad_input_gets_a_status_and_the_connection_goes_on(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with await foxglove(server) as websocket:
            _, channels = await opened(websocket)
            problems = [
                ("{not json", "malformed JSON"),
                (json.dumps({"op": "launch"}), "unknown op 'launch'"),
                (json.dumps([1, 2]), "JSON object"),
                (json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 999}]}), "no channel 999"),
                (json.dumps({"op": "subscribe", "subscriptions": [{"id": -1, "channelId": 1}]}), "unsigned 32-bit"),
                (json.dumps({"op": "fetchAsset", "uri": "x", "requestId": 1}), "not offered"),
                (
                    json.dumps(
                        {"op": "setParameters", "parameters": [{"name": "/xviz_server/profile", "value": "ultra"}]}
                    ),
                    "unknown profile 'ultra'",
                ),
                (b"\x7fgarbage", "unknown binary opcode 0x7f"),
                (b"", "empty binary message"),
                (b"\x01\x00\x00\x00\x00xyz", "client message data is not offered"),
                (b"\x03\x00", "playback control request: 2 bytes"),
                (control(True, speed=float("nan")), "speed nan"),
                (control(True, seek=1), "outside the log 'kitti'"),
            ]
            for data, expected in problems:
                await websocket.send(data)
                status = await next_of(websocket, "status")
                assert status["level"] == 2 and expected in status["message"], (data, status)
            # Still serving: a subscription gets its messages.
            await websocket.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels[0]["id"]}]})
            )
            subscription, _ = await next_of(websocket, "message")
            assert subscription == 7
            await websocket.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels[1]["id"]}]})
            )
            assert "subscription id 7 is in use" in (await next_of(websocket, "status"))["message"]


async def test_a_paused_seek_sends_the_frame_at_the_new_time_and_nothing_after(
    kitti_root: Path, kitti_log: Path
) -> None:
    times = [nanoseconds(update["timestamp"]) for update in kitti_frames(kitti_log)]
    async with running_server(kitti_root) as server:
        async with await foxglove(server, subprotocols=["foxglove.sdk.v1"]) as websocket:
            _, channels = await opened(websocket)
            pose = next(channel["id"] for channel in channels if channel["topic"] == "/vehicle_pose")
            await websocket.send(control(False, request_id="pause"))
            assert await next_of(websocket, "state") == (1, times[0], 1.0, False, "pause")
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 3, "channelId": pose}]}))
            await websocket.send(control(False, seek=times[12] + 1000, request_id="seek"))
            assert await next_of(websocket, "state") == (1, times[12] + 1000, 1.0, True, "seek")
            assert await next_of(websocket, "message") == (3, times[12])
            with pytest.raises(asyncio.TimeoutError):
                await next_of(websocket, "message", timeout=0.5)


async def test_clients_seek_in_the_same_log_each_to_its_own_time(kitti_root: Path, kitti_log: Path) -> None:
    times = [nanoseconds(update["timestamp"]) for update in kitti_frames(kitti_log)]
    async with running_server(kitti_root) as server:
        one, two = (
            await foxglove(server, subprotocols=["foxglove.sdk.v1"]),
            await foxglove(server, subprotocols=["foxglove.sdk.v1"]),
        )
        async with one, two:
            for websocket, target in ((one, 20), (two, 4)):
                _, channels = await opened(websocket)
                pose = next(channel["id"] for channel in channels if channel["topic"] == "/vehicle_pose")
                await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": pose}]}))
                await websocket.send(control(True, seek=times[target], request_id=f"to {target}"))
            for websocket, target in ((one, 20), (two, 4)):
                state = await next_of(websocket, "state")
                assert state[3:] == (True, f"to {target}")
                # After the seek, messages go on from the client's own time.
                while (message := await next_of(websocket, "message"))[1] < times[target]:
                    pass
                assert message[1] == times[target]
                assert (await next_of(websocket, "message"))[1] == times[target + 1]


async def test_the_viewer_token_applies_to_foxglove_handshakes(kitti_root: Path) -> None:
    async with running_server(kitti_root, viewer_token="s3cret") as server:
        with pytest.raises(InvalidStatus) as refused:
            await foxglove(server)
        assert refused.value.response.status_code == 401
        async with await foxglove(server, path="/?log=kitti&token=s3cret") as websocket:
            await opened(websocket)


# ----------------------------------------------------------------- ROS bags and MCAP files: their original topics

BAG_FRAMES = 4
#: Each container of the KITTI bags: its file name, its message and schema encoding.
CONTAINERS = {
    "ros1": ("drive.bag", "ros1", "ros1msg"),
    "sqlite3": ("drive", "cdr", "ros2msg"),
    "mcap": ("drive.mcap", "cdr", "ros2msg"),
}


@pytest.fixture(scope="module")
def kitti_bags(shared_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[KittiDrive, dict[str, Path]]:
    """The real KITTI raw excerpt's first frames, and the bag of each container holding them, by container."""
    drive, root = KittiDrive(shared_dir / "data" / RAW), tmp_path_factory.mktemp("original-bags")
    return drive, {
        container: write_bag(root / container / name, container, drive=drive, frames=BAG_FRAMES)
        for container, (name, _, _) in CONTAINERS.items()
        if (root / container).mkdir() is None
    }


def recorded(drive: KittiDrive, container: str) -> dict[str, list[tuple[int, bytes, Any]]]:
    """What the bag holds, by topic: (record time, serialized bytes, message), made by the generator that wrote it."""
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    topics: dict[str, list[tuple[int, bytes, Any]]] = {}
    for topic, msgtype, time, message in kitti_messages(drive, m, BAG_FRAMES):
        topics.setdefault(topic, []).append((time, m.serialize(message, msgtype), message))
    return topics


def schema_name(msgtype: str, container: str) -> str:
    return msgtype.replace("/msg/", "/") if container == "ros1" else msgtype


@pytest.mark.slow
@pytest.mark.parametrize("container", CONTAINERS)
async def test_the_published_client_decodes_the_original_messages_with_their_own_definitions(
    container: str,
    kitti_bags: tuple[KittiDrive, dict[str, Path]],
) -> None:
    drive, bags = kitti_bags
    expected = recorded(drive, container)
    encoding, schema_encoding = CONTAINERS[container][1:]
    async with running_server(None, dataset=[f"rosbag:{bags[container]}"]) as server:
        out = await foxglove_client(f"ws://127.0.0.1:{server.port}/?log=drive", "foxglove.websocket.v1")
    assert out["errors"] == [] and out["statuses"] == []
    channels = {channel["topic"]: channel for channel in out["channels"]}
    # One channel per original topic, under its own name, with the file's encoding and schema.
    for topic in expected:
        assert (channels[topic]["encoding"], channels[topic]["schemaEncoding"]) == (encoding, schema_encoding), topic
    assert channels[CLOUD_TOPIC]["schemaName"] == schema_name("sensor_msgs/msg/PointCloud2", container)
    assert channels["/tf"]["schemaName"] == schema_name("tf2_msgs/msg/TFMessage", container)
    # The converted channels beside them, under /xviz.
    assert channels["/xviz" + CLOUD_TOPIC]["schemaName"] == "foxglove.PointCloud"
    assert channels["/xviz/vehicle_pose"]["schemaName"] == "foxglove.FrameTransform"
    topics = out["topics"]
    for topic, messages in expected.items():
        assert topics[topic]["timestamps"] == [str(time) for time, _, _ in messages], topic
    assert len(topics["/xviz" + CLOUD_TOPIC]["timestamps"]) == BAG_FRAMES
    # All in time order, the converted and the original messages together.
    arrivals = [int(time) for time in out["arrivals"]]
    assert arrivals == sorted(arrivals) and len(arrivals) == sum(topic["count"] for topic in topics.values())
    # What each message holds, decoded with its own definition, is what the file holds.
    clouds = topics[CLOUD_TOPIC]["summaries"]
    assert [(c["width"], c["height"], c["point_step"], c["bytes"]) for c in clouds] == [
        (len(drive.velodyne(i)), 1, 16, 16 * len(drive.velodyne(i))) for i in range(BAG_FRAMES)
    ]
    assert {tuple(c["fields"]) for c in clouds} == {("x", "y", "z", "intensity")} and {
        c["frame_id"] for c in clouds
    } == {"/velo_link"}
    for topic in (GRAY_TOPIC, COLOR_TOPIC):
        images = [message for _, _, message in expected[topic]]
        assert topics[topic]["summaries"] == [
            {"encoding": image.encoding, "width": image.width, "height": image.height, "bytes": len(image.data)}
            for image in images
        ]
    assert [(image["format"], image["magic"], image["bytes"]) for image in topics[COMPRESSED_TOPIC]["summaries"]] == [
        ("png", "89504e47", drive.image_path("image_03", i).stat().st_size) for i in range(BAG_FRAMES)
    ]
    for topic in ("/tf", "/tf_static"):
        assert [summary["transforms"] for summary in topics[topic]["summaries"]] == [
            [
                {
                    "parent": t.header.frame_id,
                    "child": t.child_frame_id,
                    "translation": {axis: getattr(t.transform.translation, axis) for axis in "xyz"},
                    "rotation": {axis: getattr(t.transform.rotation, axis) for axis in "xyzw"},
                }
                for t in message.transforms
            ]
            for _, _, message in expected[topic]
        ]


async def message_data(websocket: ClientConnection, timeout: float = 10) -> tuple[int, int, bytes]:
    """The next message data message: subscription, log time, payload."""
    while True:
        data = await asyncio.wait_for(websocket.recv(), timeout)
        if isinstance(data, bytes) and data[0] == 0x01:
            subscription, time = struct.unpack_from("<IQ", data, 1)
            return subscription, time, data[13:]


async def test_original_bytes_arrive_unchanged_and_follow_subscriptions_and_seeks(
    kitti_bags: tuple[KittiDrive, dict[str, Path]],
) -> None:
    drive, bags = kitti_bags
    expected = recorded(drive, "ros1")
    times = [time for time, _, _ in expected[CLOUD_TOPIC]]
    async with running_server(None, dataset=[f"rosbag:{bags['ros1']}"]) as server:
        async with await foxglove(server, path="/?log=drive", subprotocols=["foxglove.sdk.v1"]) as websocket:
            _, advertised = await opened(websocket)
            ids = {channel["topic"]: channel["id"] for channel in advertised}
            await websocket.send(control(False, request_id="pause"))
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ids["/tf"]}]}))
            await websocket.send(control(False, seek=times[2] + 1000, request_id="seek"))
            assert await message_data(websocket) == (1, times[2], expected["/tf"][2][1])
            with pytest.raises(asyncio.TimeoutError):
                await message_data(websocket, timeout=0.5)
            # Another channel instead: only its messages come, the bytes the file holds.
            await websocket.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [1]}))
            await websocket.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 2, "channelId": ids[CLOUD_TOPIC]}]})
            )
            # A new subscription gets the frame on screen, then the seek plays on from its time.
            assert await message_data(websocket) == (2, times[2], expected[CLOUD_TOPIC][2][1])
            await websocket.send(control(True, speed=4.0, seek=times[1], request_id="play"))
            received = [await message_data(websocket) for _ in range(BAG_FRAMES - 1)]
            assert received == [(2, time, data) for time, data, _ in expected[CLOUD_TOPIC][1:]]


async def test_the_export_has_the_original_channels(kitti_bags: tuple[KittiDrive, dict[str, Path]]) -> None:
    drive, bags = kitti_bags
    expected = recorded(drive, "sqlite3")
    async with running_server(None, dataset=[f"rosbag:{bags['sqlite3']}"]) as server:
        status, _, body = await asyncio.to_thread(http_get, server.port, "/api/logs/drive/export?format=mcap")
    assert status == 200, body
    summary, messages = read_mcap(body)
    channels = {channel.topic: channel for channel in summary.channels.values()}
    for topic, records in expected.items():
        schema = summary.schemas[channels[topic].schema_id]
        assert (channels[topic].message_encoding, schema.encoding) == ("cdr", "ros2msg")
        assert summary.statistics.channel_message_counts[channels[topic].id] == len(records)
        assert [(time, data) for name, _, time, data in messages if name == topic] == [
            (time, data) for time, data, _ in records
        ]
    clouds = [PointCloud.FromString(data) for name, _, _, data in messages if name == "/xviz" + CLOUD_TOPIC]
    assert [len(cloud.data) // cloud.point_stride for cloud in clouds] == [
        len(drive.velodyne(i)) for i in range(BAG_FRAMES)
    ]


def test_the_original_messages_of_a_frame_are_bounded(
    kitti_bags: tuple[KittiDrive, dict[str, Path]], monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = RosBag(kitti_bags[1]["ros1"])
    records = list(unpack(bag.original_messages(1)))
    assert len(records) == len(bag.originals) - 1  # every topic but /tf_static, once
    monkeypatch.setattr(ros_dataset, "MAX_FRAME_MESSAGES", 3)
    with pytest.raises(DatasetError, match="frame 1: more than 3 original messages"):
        bag.original_messages(1)
    monkeypatch.undo()
    monkeypatch.setattr(ros_dataset, "MAX_FRAME_BYTES", 1 << 20)  # the chunks it reads declare more: refused unread
    with pytest.raises(
        FrameSizeError,
        match="frame 1: its messages and images would unpack .* more than the limit of 1 MiB for one frame",
    ):
        bag.original_messages(1)


@pytest.mark.slow
async def test_a_frame_with_too_many_original_messages_gets_a_status_and_the_rest_goes_on(tmp_path: Path) -> None:
    from rosbags.typesys import Stores

    m = Messages(Stores.ROS1_NOETIC)
    t0, second = 1_700_000_000 * 10**9, 10**9
    flood = ros_dataset.MAX_FRAME_MESSAGES + 1
    flag = m.std_msgs__Bool(data=True)

    def messages() -> Iterator[tuple[str, str, int, Any]]:
        point = np.ones((1, 4), np.float32)  # a point with a return (no-return points at the origin are dropped)
        yield "/cloud", "sensor_msgs/msg/PointCloud2", t0, m.cloud(t0, point, "base_link")
        for i in range(flood):  # all in the first frame's span
            yield "/flag", "std_msgs/msg/Bool", t0 + 1 + i, flag
        yield "/cloud", "sensor_msgs/msg/PointCloud2", t0 + second, m.cloud(t0 + second, point, "base_link")

    bag = write_bag(tmp_path / "flood.bag", "ros1", messages())
    async with running_server(None, dataset=[f"rosbag:{bag}"]) as server:
        out = await foxglove_client(f"ws://127.0.0.1:{server.port}/?log=flood", "foxglove.websocket.v1")
    assert out["errors"] == []
    assert [
        (s["level"], f"more than {ros_dataset.MAX_FRAME_MESSAGES} original messages" in s["message"])
        for s in out["statuses"]
    ] == [(1, True)]
    topics = out["topics"]
    assert topics["/xviz/cloud"]["timestamps"] == [str(t0), str(t0 + second)]  # both frames, converted
    assert topics["/cloud"]["timestamps"] == [str(t0 + second)]  # the second frame's original messages
    assert topics["/flag"]["count"] == 0


@pytest.mark.slow
async def test_an_xviz_session_and_a_foxglove_session_share_a_log(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with await foxglove(server) as websocket, client(server, "/?log=kitti") as xviz:
            _, channels = await opened(websocket)
            await websocket.send(
                json.dumps(
                    {
                        "op": "subscribe",
                        "subscriptions": [{"id": i, "channelId": c["id"]} for i, c in enumerate(channels)],
                    }
                )
            )
            await xviz.recv()
            await xviz.send("transform_log", {"id": "all"})
            updates = [m for m in await xviz.until("transform_log_done") if m["type"] == "xviz/state_update"]
            assert len(updates) == 25
            assert (await next_of(websocket, "message"))[0] in range(len(channels))


# ----------------------------------------------------------------- live feeds


def kitti_source(kitti_log: Path) -> tuple[dict[str, Any], list[bytes]]:
    """The KITTI log as a live source sends it: its metadata, and its updates as GLB bytes in time order."""
    frames = sorted(kitti_log.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))
    return decode(frames[0].read_bytes())["data"], [path.read_bytes() for path in frames[1:]]


async def foxglove_subscribed(server: Any, count: int = 1, every: bool = False) -> None:
    """Wait until ``count`` Foxglove connections follow a live feed with subscriptions (to ``every`` channel)."""
    for _ in range(300):
        following = [
            s
            for s in server.sessions
            if getattr(getattr(s, "session", None), "feed", None) is not None
            and s.session._subscriptions
            and (not every or len(s.session._subscriptions) == len(s.session._channels))
        ]
        if len(following) >= count:
            return
        await asyncio.sleep(0.05)
    raise AssertionError("no Foxglove client subscribed")


async def xviz_updates(xviz: Any, count: int) -> list[float]:
    """The timestamps of the next ``count`` state updates an XVIZ live viewer gets."""
    times: list[float] = []
    while len(times) < count:
        message = await xviz.recv()
        if message["type"] == "xviz/state_update":
            times.append(message["data"]["updates"][0]["timestamp"])
    return times


@pytest.mark.slow  # the feed published at 10 Hz, as a source sends it
@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
async def test_published_client_follows_a_live_feed_beside_an_xviz_viewer(
    kitti_root: Path, kitti_log: Path, subprotocol: str
) -> None:
    updates = kitti_frames(kitti_log)
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(metadata)
        url = f"ws://127.0.0.1:{server.port}/?session_type=live&log=car"
        reading = asyncio.ensure_future(foxglove_client(url, subprotocol, options=("--times", str(len(frames)))))
        async with client(server, "/?session_type=live&log=car") as xviz:
            assert (await xviz.recv())["type"] == "xviz/metadata"
            await foxglove_subscribed(server, every=True)
            for frame in frames:  # as an ingest source sends them: GLB, at 10 Hz
                await feed.publish(frame)
                await asyncio.sleep(0.1)
            assert await xviz_updates(xviz, len(frames)) == [update["timestamp"] for update in updates]
        out = await reading
    assert out["errors"] == [] and out["statuses"] == []
    assert "playbackControl" not in out["serverInfo"]["capabilities"] and out["serverInfo"]["metadata"] == {
        "live": "car"
    }
    # The channels of a log with the same metadata, converted the same way.
    async with running_server(kitti_root) as server:
        async with await foxglove(server) as websocket:
            _, recorded = await opened(websocket)
    assert [(c["topic"], c["schemaName"]) for c in out["channels"]] == [(c["topic"], c["schemaName"]) for c in recorded]
    topics = out["topics"]
    clouds = topics["/lidar/points"]
    assert [summary["points"] for summary in clouds["summaries"]] == [
        len(update["primitives"]["/lidar/points"]["points"][0]["points"]) for update in updates
    ]
    assert clouds["timestamps"] == [str(nanoseconds(update["timestamp"])) for update in updates]
    assert [int(t) for t in clouds["timestamps"]] == sorted({int(t) for t in clouds["timestamps"]})
    images = topics["/camera/image_00"]["summaries"]
    assert len(images) == len(updates) and {image["magic"] for image in images} == {"89504e47"}
    assert len(topics["/vehicle_pose"]["summaries"]) == len(updates)
    assert out["times"] == len(updates)


async def test_each_live_update_is_converted_once_for_every_foxglove_client(kitti_root: Path, kitti_log: Path) -> None:
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(metadata)
        clients = [await foxglove(server, path="/?session_type=live&log=car") for _ in range(3)]
        for websocket in clients:
            _, channels = await opened(websocket)
            await websocket.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels[0]["id"]}]})
            )
        await foxglove_subscribed(server, 3)
        update = await feed.publish(frames[0])
        received = [await next_of(websocket, "message") for websocket in clients]
        assert received == [(1, nanoseconds(kitti_frames(kitti_log)[0]["timestamp"]))] * 3
        assert len(update._derived) == 1  # one conversion, shared
        for websocket in clients:
            await websocket.close()


async def stalled_live_client(server: Any, metadata: dict[str, Any]) -> tuple[Any, ClientConnection]:
    """The live feed ``car`` with ``metadata``, and a Foxglove client of it subscribed to every channel that then
    stopped reading its socket."""
    feed = server.live.feed("car")
    feed.set_metadata(metadata)
    stalled = await foxglove(server, path="/?session_type=live&log=car")
    _, channels = await opened(stalled)
    await stalled.send(
        json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]})
    )
    await foxglove_subscribed(server)
    stalled.transport.pause_reading()
    return feed, stalled


@pytest.mark.slow  # 50 frames of 1.5 MB to two clients: 3 s on a quiet machine, 13 s at load 6
async def test_a_stalled_live_client_stays_bounded_and_is_told_it_fell_behind(
    kitti_root: Path, kitti_log: Path
) -> None:
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root, live_queue=4, live_lag_timeout=60) as server:
        feed, stalled = await stalled_live_client(server, metadata)
        [connection] = [s for s in server.sessions if getattr(getattr(s, "session", None), "feed", None) == "car"]
        async with client(server, "/?session_type=live&log=car") as xviz:
            await xviz.recv()
            # The XVIZ viewer of the same feed gets every update.
            reading = asyncio.ensure_future(xviz_updates(xviz, 2 * len(frames)))
            buffered = []
            for frame in frames * 2:
                await feed.publish(frame)
                await asyncio.sleep(0.05)
                buffered.append(connection.websocket.transport.get_write_buffer_size())
            assert len(await reading) == 2 * len(frames)
        queued = [len(subscription._queue) for subscription in feed._subscribers]
        assert queued and max(queued) <= 4  # bounded by live_queue, not by what was published
        # The socket holds at most its high-water mark and the message on its way (a frame's point cloud: 1.5 MB).
        assert max(buffered) < 4_000_000
        status, _, page = await asyncio.to_thread(http_get, server.port, "/metrics")
        assert status == 200 and metric(page, "xviz_live_dropped_updates_total") > 0
        stalled.transport.resume_reading()
        notice = await next_of(stalled, "status", timeout=30)
        assert (
            notice["level"] == 1
            and "this client is behind" in notice["message"]
            and "updates were dropped" in notice["message"]
        )
        await stalled.close()


async def test_a_live_client_hopelessly_behind_is_closed_with_a_reason(kitti_root: Path, kitti_log: Path) -> None:
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root, live_queue=2, live_lag_timeout=0.5) as server:
        feed, slow = await stalled_live_client(server, metadata)
        for frame in frames * 2:
            await feed.publish(frame)
            await asyncio.sleep(0.05)
        slow.transport.resume_reading()
        close = await close_received(slow)
        assert close.code == 1013 and "too slow: dropped live updates" in close.reason


async def test_a_live_feed_is_found_waited_for_and_refuses_playback_control(kitti_root: Path, kitti_log: Path) -> None:
    metadata, frames = kitti_source(kitti_log)
    async with running_server(kitti_root) as server:
        # Named before its source comes: waited for.
        async with await foxglove(
            server, path="/?session_type=live&log=truck", subprotocols=["foxglove.sdk.v1"]
        ) as waiting:
            info = json.loads(await waiting.recv())
            assert info["op"] == "serverInfo" and "playbackControl" not in info["capabilities"]
            assert "has not started yet" in (await next_of(waiting, "status"))["message"]
            feed = server.live.feed("truck")
            feed.set_metadata(metadata)
            advertise = json.loads(await asyncio.wait_for(waiting.recv(), 10))
            assert advertise["op"] == "advertise" and len(advertise["channels"]) > 5
            await waiting.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 9, "channelId": 999}]}))
            assert "no channel 999 in live feed 'truck'" in (await next_of(waiting, "status"))["message"]
            # A live feed plays as its source sends.
            await waiting.send(control(False, seek=1, request_id="p"))
            status = await next_of(waiting, "status")
            assert status["level"] == 2 and "cannot be paused, sought or sped up" in status["message"]
            assert (await next_of(waiting, "state"))[3:] == (False, "p")
            # New metadata: the old channels go, the new ones come with new ids.
            pose = next(c["id"] for c in advertise["channels"] if c["topic"] == "/vehicle_pose")
            await waiting.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": pose}]}))
            await foxglove_subscribed(server)
            feed.set_metadata({**metadata, "streams": {"/vehicle_pose": metadata["streams"]["/vehicle_pose"]}})
            gone = json.loads(await asyncio.wait_for(waiting.recv(), 10))
            assert gone == {"op": "unadvertise", "channelIds": [c["id"] for c in advertise["channels"]]}
            again = json.loads(await asyncio.wait_for(waiting.recv(), 10))
            assert [c["topic"] for c in again["channels"]] == [
                "/vehicle_pose",
                "/vehicle_pose/pose",
                "/vehicle_pose/location",
            ]
            assert min(c["id"] for c in again["channels"]) > max(c["id"] for c in advertise["channels"])
            await waiting.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 2, "channelId": again["channels"][0]["id"]}]})
            )
            [session] = [s.session for s in server.sessions if getattr(getattr(s, "session", None), "feed", None)]
            await eventually(lambda: 2 in session._subscriptions)
            await feed.publish(frames[3])
            assert await next_of(waiting, "message") == (2, nanoseconds(kitti_frames(kitti_log)[3]["timestamp"]))
            feed.disconnect()
            assert "went away" in (await next_of(waiting, "status"))["message"]
        # No name and one running feed, or a log name that is a running feed's: that feed.
        feed.set_metadata(metadata)
        for path in ("/?session_type=live", "/?log=truck"):
            async with await foxglove(server, path=path) as websocket:
                info = json.loads(await websocket.recv())
                assert info["metadata"] == {"live": "truck"}, path
        # A name that is neither a log nor a running feed.
        async with await foxglove(server, path="/?log=nowhere") as websocket:
            await websocket.recv()
            assert "nowhere" in (await next_of(websocket, "status"))["message"]


# ----------------------------------------------------------------- clips as MCAP files


async def export(server: Any, query: str, name: str = "kitti") -> tuple[int, dict[str, str], bytes]:
    return await asyncio.to_thread(http_get, server.port, f"/api/logs/{name}/export{query}")


def read_mcap(data: bytes) -> tuple[Any, list[tuple[str, str, int, bytes]]]:
    """The summary of an MCAP file, and its messages as (topic, schema name, log time, payload), read by the published reader."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    messages = [
        (channel.topic, schema.name, message.log_time, message.data)
        for schema, channel, message in reader.iter_messages()
    ]
    return summary, messages


async def test_a_clip_exports_as_an_indexed_mcap_file_with_the_same_channels(kitti_root: Path, kitti_log: Path) -> None:
    updates = kitti_frames(kitti_log)
    start, end = updates[5]["timestamp"], updates[10]["timestamp"]
    async with running_server(kitti_root) as server:
        status, headers, body = await export(server, f"?start={start}&end={end}&format=mcap")
        async with await foxglove(server) as websocket:
            _, channels = await opened(websocket)
    assert status == 200, body
    assert headers["Content-Disposition"] == 'attachment; filename="kitti.mcap"'
    summary, messages = read_mcap(body)
    assert summary.chunk_indexes and summary.statistics.message_count == len(messages)
    assert sorted(channel.topic for channel in summary.channels.values()) == sorted(
        channel["topic"] for channel in channels
    )
    clouds = [(time, PointCloud.FromString(data)) for topic, schema, time, data in messages if topic == "/lidar/points"]
    assert [time for time, _ in clouds] == [nanoseconds(update["timestamp"]) for update in updates[5:11]]
    assert [len(cloud.data) // cloud.point_stride for _, cloud in clouds] == [
        len(update["primitives"]["/lidar/points"]["points"][0]["points"]) for update in updates[5:11]
    ]
    assert {schema for topic, schema, _, _ in messages if topic == "/camera/image_00"} == {"foxglove.CompressedImage"}
    # The index: every channel's count in the statistics, chunks that cover the range, each channel's in order.
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts == {topic: sum(1 for t, _, _, _ in messages if t == topic) for topic in counts}
    assert counts["/lidar/points"] == counts["/camera/image_00"] == 6
    spans = [(chunk.message_start_time, chunk.message_end_time) for chunk in summary.chunk_indexes]
    assert (min(spans)[0], max(end for _, end in spans)) == (nanoseconds(start), nanoseconds(end))
    for channel in summary.channels:
        held = [span for span, chunk in zip(spans, summary.chunk_indexes) if channel in chunk.message_index_offsets]
        assert held == sorted(held) and all(a[1] <= b[0] for a, b in zip(held, held[1:])), held


def test_the_chunks_are_cut_by_weight_and_the_messages_held_are_bounded() -> None:
    """Light messages go in chunks of their channel alone, heavy ones share theirs; what is held before it is written
    stays within ``HELD_BYTES`` and a frame, however many light channels, and makes no host of tiny chunks (the
    light channels held are written together then); the reader gets every message in time order."""
    from mcap.writer import CompressionType, Writer

    from xviz_server.foxglove.export import _SMALLEST, HELD_BYTES, LIGHT_BYTES, _Chunks

    out = io.BytesIO()
    writer = Writer(out, chunk_size=1 << 62, compression=CompressionType.ZSTD)
    writer.start()
    schema = writer.register_schema("blob", "jsonschema", b"{}")
    channels = {i: writer.register_channel(f"/c{i}", "json", schema) for i in range(202)}  # 0, 1 heavy; 200 light
    chunks = _Chunks(writer, channels)
    generator = np.random.default_rng(3)  # random bytes: the chunks are no smaller than their messages
    added: list[tuple[str, int, bytes]] = []
    sequence = 0
    for frame in range(150):  # the light channels' 6 MB would all be held until the end without the bound
        time = 1_000_000_000 + frame * 100_000_000
        messages = [(i, time, memoryview(generator.bytes(6 * LIGHT_BYTES if i < 2 else 200))) for i in channels]
        sequence = chunks.add(messages, sequence)
        added += [(f"/c{i}", time, bytes(data)) for i, time, data in messages]
        frame_bytes = sum(len(data) for _, _, data in messages)
        assert sum(len(data) for _, _, data in added) - out.tell() <= HELD_BYTES + frame_bytes
    chunks.close()
    writer.finish()
    reader = make_reader(io.BytesIO(out.getvalue()))
    summary = reader.get_summary()
    assert summary is not None
    ids = {channel.topic: channel.id for channel in summary.channels.values()}
    heavy = {ids["/c0"], ids["/c1"]}
    groups = [set(chunk.message_index_offsets) for chunk in summary.chunk_indexes]
    assert all(group == heavy or not group & heavy for group in groups), groups
    assert len({channel for group in groups for channel in group}) == 202
    # The light chunks written before a channel's last one, for the bound: none of them small.
    last = {channel: n for n, group in enumerate(groups) for channel in group}
    early = [
        chunk.uncompressed_size
        for n, (chunk, group) in enumerate(zip(summary.chunk_indexes, groups))
        if not group & heavy and any(last[channel] > n for channel in group)
    ]
    assert early and min(early) >= _SMALLEST, early
    read = [(channel.topic, message.log_time, message.data) for _, channel, message in reader.iter_messages()]
    assert [time for _, time, _ in read] == sorted(time for _, time, _ in read) and sorted(read) == sorted(added)


async def test_a_clip_may_be_given_in_seconds_after_the_log_start(kitti_root: Path, kitti_log: Path) -> None:
    updates = kitti_frames(kitti_log)
    first = updates[0]["timestamp"]
    async with running_server(kitti_root) as server:
        # "+" as such in the query, and as %2B: both are an offset, not a space.
        for query in ("?start=+0.5&end=+1.0", "?start=%2B0.5&end=%2B1.0", f"?start=%2B0.5&end={first + 1.0!r}"):
            status, _, body = await export(server, query)
            assert status == 200, (query, body)
            _, messages = read_mcap(body)
            times = sorted({time for topic, _, time, _ in messages if topic == "/lidar/points"})
            assert times == [
                nanoseconds(u["timestamp"]) for u in updates if first + 0.5 <= u["timestamp"] <= first + 1.0
            ], query
            assert len(times) == 5


async def get_raw(port: int, path: str) -> tuple[asyncio.StreamReader, asyncio.StreamWriter, bytes]:
    """Send ``GET path``; the reader, writer and response head."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    return reader, writer, await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 10)


async def test_a_whole_log_export_is_sent_in_chunks_as_it_is_written(kitti_root: Path, kitti_log: Path) -> None:
    updates = kitti_frames(kitti_log)
    async with running_server(kitti_root) as server:
        reader, writer, head = await get_raw(server.port, "/api/logs/kitti/export")
        lines = head.decode().lower().split("\r\n")
        assert lines[0] == "http/1.1 200 ok" and "transfer-encoding: chunked" in lines
        assert not any(line.startswith("content-length") for line in lines)
        sizes, body = [], bytearray()
        while size := int((await asyncio.wait_for(reader.readline(), 10)).strip(), 16):
            body += await reader.readexactly(size)
            assert await reader.readexactly(2) == b"\r\n"
            sizes.append(size)
        assert await reader.readexactly(2) == b"\r\n"
        assert await asyncio.wait_for(reader.read(), 10) == b""  # and the server ends the connection
        writer.close()
    assert sizes[0] < 100 and len(sizes) > 5 and max(sizes) < len(body) / 4  # the start at once, then piece by piece
    summary, messages = read_mcap(bytes(body))
    assert summary.statistics.message_count == len(messages)
    assert [time for topic, _, time, _ in messages if topic == "/lidar/points"] == [
        nanoseconds(u["timestamp"]) for u in updates
    ]


async def test_an_export_to_a_client_that_stops_reading_holds_a_bounded_buffer_and_is_dropped(kitti_root: Path) -> None:
    async with running_server(kitti_root, idle_timeout=2) as server:
        total = len((await export(server, ""))[2])
        sock = socket.socket()  # a client that reads nothing, with a small receive buffer
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 32 * 1024)
        sock.settimeout(10)
        await asyncio.to_thread(sock.connect, ("127.0.0.1", server.port))
        sock.sendall(b"GET /api/logs/kitti/export HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert server._server is not None
        while not server._server.all_connections:
            await asyncio.sleep(0.01)
        (connection,) = server._server.all_connections
        while not connection.transport.get_write_buffer_size():  # the kernel's buffers fill first
            await asyncio.sleep(0.05)
        held = [connection.transport.get_write_buffer_size()]

        async def steady() -> bool:  # what the server holds for it stops growing
            await asyncio.sleep(0.25)
            held.append(connection.transport.get_write_buffer_size())
            return len(set(held[-4:])) == 1 and len(held) >= 4 or not server._server.all_connections

        await eventually(steady)
        assert 0 < max(held) < total / 4, (held, total)
        # The stall timeout drops it: the body ends without its last chunk, and nothing is left open.
        await eventually(lambda: not server._server.all_connections and server._open() == 0)

        def rest() -> bytes:
            data = bytearray()
            try:
                while more := sock.recv(1 << 20):
                    data += more
            except ConnectionResetError:
                pass
            return bytes(data)

        data = await asyncio.to_thread(rest)
        sock.close()
        assert b"200 OK" in data[:100] and not data.endswith(b"0\r\n\r\n") and len(data) < total


async def test_an_export_counts_as_a_session_and_is_cut_short_when_the_server_stops(
    kitti_root: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="xviz_server")
    async with running_server(kitti_root, max_sessions=1) as server:
        reader, writer, head = await get_raw(server.port, "/api/logs/kitti/export")
        assert b"200 OK" in head
        await reader.readexactly(1 << 16)  # under way
        status, _, body = await export(server, "")
        assert (status, body) == (503, b"too many sessions, try again later\n")
        with pytest.raises(InvalidStatus) as refused:
            await foxglove(server)
        assert refused.value.response.status_code == 503

        data = bytearray()

        async def slowly() -> bytes:  # a client that goes on reading, slower than the server writes
            while more := await reader.read(1 << 16):
                data.extend(more)
                await asyncio.sleep(0.02)
            return bytes(data)

        reading = asyncio.ensure_future(slowly())
        await eventually(lambda: data)
        await server.close()
        # Ended by the server, not aborted when SHUTDOWN_TIMEOUT ran out.
        assert not [r.message for r in caplog.records if "shutdown: aborting" in r.message]
        assert not (await asyncio.wait_for(reading, 10)).endswith(b"0\r\n\r\n")
        writer.close()


async def test_a_head_request_for_an_export_gets_its_head_only(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        status, headers, body = await asyncio.to_thread(http_get, server.port, "/api/logs/kitti/export", "HEAD")
        assert (status, headers["Transfer-Encoding"], body) == (200, "chunked", b"")

        async def released() -> bool:  # counted from its admission until its connection ends
            return server._open() == 0

        await eventually(released)


async def test_a_bad_export_request_is_refused_naming_the_problem(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        for query, name, expected in [
            ("?format=zip", "kitti", (400, "format='zip'")),
            ("?start=soon", "kitti", (400, "start: give a finite number of seconds")),
            ("?start=nan", "kitti", (400, "not 'nan'")),
            ("?start=10&end=5", "kitti", (400, "start=10.0 is after end=5.0")),
            ("?start=%2B2&end=%2B1", "kitti", (400, "start=+2 is after end=+1")),
            # The catalog's reader (xviz_server.params): a parameter given twice, numbers in plain decimal.
            ("?start=1&start=2", "kitti", (400, "start: give it at most once")),
            ("?end=3&format=mcap&end=4", "kitti", (400, "end: give it at most once")),
            ("?format=mcap&format=zip", "kitti", (400, "format: give it at most once")),
            ("?start=1_000", "kitti", (400, "not '1_000'")),
            ("?start=+1_000", "kitti", (400, "not '1_000'")),
            ("?start=++5", "kitti", (400, "not '+5'")),
            ("?end=%205", "kitti", (400, "not ' 5'")),
            ("?start=0x10", "kitti", (400, "not '0x10'")),
            # Times outside the log: its span is told, never an empty clip.
            (
                "?start=0&end=2",
                "kitti",
                (
                    400,
                    "no frame of log 'kitti' starts in [0.0, 2.0]: its frames start from "
                    "1317042145.964 to 1317042148.444 s (+0 to +2.48 s after its start)",
                ),
            ),
            ("?start=+5", "kitti", (400, "starts in [+5, its end]")),
            ("?end=1000", "kitti", (400, "starts in [its start, 1000.0]")),
            ("", "nowhere", (404, "nowhere")),
            ("", "..%2Fetc", (404, "not allowed")),
        ]:
            status, _, body = await export(server, query, name)
            assert (status, expected[1] in body.decode()) == (expected[0], True), (query, name, body)
