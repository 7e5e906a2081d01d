"""Foxglove clients on the XVIZ port: the published client (@foxglove/ws-protocol) and scripted sockets."""

from __future__ import annotations

import asyncio
import io
import json
import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader
from websockets.exceptions import InvalidStatus

from xviz_server.codec import decode
from xviz_server.foxglove.wire import SUBPROTOCOLS

from helpers import INTEROP, client, http_get, running_server

DRIVER = INTEROP / "foxglove-client.js"


def kitti_frames(kitti_log: Path) -> list[dict[str, Any]]:
    """The real KITTI log's updates, in time order, decoded here: what each Foxglove message must carry."""
    frames = sorted(kitti_log.glob("*-frame.glb"), key=lambda path: int(path.name.split("-")[0]))[1:]
    return [decode(path.read_bytes())["data"]["updates"][0] for path in frames]


def nanoseconds(seconds: float) -> int:
    return round(seconds * 1e9)


async def published_client(url: str, subprotocol: str, *sends: str) -> dict[str, Any]:
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "@foxglove" / "ws-protocol").is_dir(), "run `npm ci --prefix tests/interop`"
    args = [node, str(DRIVER), url, subprotocol, *(item for text in sends for item in ("--send", text))]
    process = await asyncio.create_subprocess_exec(*args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = await asyncio.wait_for(process.communicate(), 60)
    assert process.returncode == 0, stderr.decode()
    return json.loads(stdout)


@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
async def test_published_client_decodes_every_frame(kitti_root: Path, kitti_log: Path, subprotocol: str) -> None:
    updates = kitti_frames(kitti_log)
    async with running_server(kitti_root) as server:
        out = await published_client(f"ws://127.0.0.1:{server.port}/?log=kitti", subprotocol)
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
        assert [image["bytes"] for image in images] == [len(update["primitives"][camera]["images"][0]["data"]) for update in updates]
    transforms = topics["/vehicle_pose"]["summaries"]
    assert len(transforms) == len(updates) and {(t["parent"], t["child"]) for t in transforms} == {("map", "/vehicle_pose")}
    assert topics["/vehicle/velocity"]["count"] == len(updates)
    assert out["times"] == len(updates)


async def foxglove(server: Any, path: str = "/?log=kitti", subprotocols: list[str] | None = None) -> ClientConnection:
    return await connect(f"ws://127.0.0.1:{server.port}{path}", subprotocols=subprotocols or ["foxglove.websocket.v1"], max_size=None)


async def opened(websocket: ClientConnection) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    info = json.loads(await asyncio.wait_for(websocket.recv(), 10))
    advertise = json.loads(await asyncio.wait_for(websocket.recv(), 10))
    assert info["op"] == "serverInfo" and advertise["op"] == "advertise"
    return info, advertise["channels"]


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
            return status, current, speed, bool(did_seek), data[19:19 + length].decode()


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
                (json.dumps({"op": "getParameters", "parameterNames": []}), "not offered"),
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
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels[0]["id"]}]}))
            subscription, _ = await next_of(websocket, "message")
            assert subscription == 7
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels[1]["id"]}]}))
            assert "subscription id 7 is in use" in (await next_of(websocket, "status"))["message"]


async def test_a_paused_seek_sends_the_frame_at_the_new_time_and_nothing_after(kitti_root: Path, kitti_log: Path) -> None:
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
        one, two = await foxglove(server, subprotocols=["foxglove.sdk.v1"]), await foxglove(server, subprotocols=["foxglove.sdk.v1"])
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


async def test_a_live_session_is_refused_with_a_status(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with await foxglove(server, path="/?session_type=live&log=kitti") as websocket:
            info = json.loads(await websocket.recv())
            assert info["op"] == "serverInfo"
            status = await next_of(websocket, "status")
            assert status["level"] == 2 and "live feeds" in status["message"]


async def test_the_viewer_token_applies_to_foxglove_handshakes(kitti_root: Path) -> None:
    async with running_server(kitti_root, viewer_token="s3cret") as server:
        with pytest.raises(InvalidStatus) as refused:
            await foxglove(server)
        assert refused.value.response.status_code == 401
        async with await foxglove(server, path="/?log=kitti&token=s3cret") as websocket:
            await opened(websocket)


async def test_an_xviz_session_and_a_foxglove_session_share_a_log(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with await foxglove(server) as websocket, client(server, "/?log=kitti") as xviz:
            _, channels = await opened(websocket)
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c["id"]} for i, c in enumerate(channels)]}))
            await xviz.recv()
            await xviz.send("transform_log", {"id": "all"})
            updates = [m for m in await xviz.until("transform_log_done") if m["type"] == "xviz/state_update"]
            assert len(updates) == 25
            assert (await next_of(websocket, "message"))[0] in range(len(channels))


# ----------------------------------------------------------------- clips as MCAP files


async def export(server: Any, query: str, name: str = "kitti") -> tuple[int, dict[str, str], bytes]:
    return await asyncio.to_thread(http_get, server.port, f"/api/logs/{name}/export{query}")


def read_mcap(data: bytes) -> tuple[Any, list[tuple[str, str, int, bytes]]]:
    """The summary of an MCAP file, and its messages as (topic, schema name, log time, payload), read by the published reader."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    messages = [(channel.topic, schema.name, message.log_time, message.data) for schema, channel, message in reader.iter_messages()]
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
    assert sorted(channel.topic for channel in summary.channels.values()) == sorted(channel["topic"] for channel in channels)
    clouds = [(time, PointCloud.FromString(data)) for topic, schema, time, data in messages if topic == "/lidar/points"]
    assert [time for time, _ in clouds] == [nanoseconds(update["timestamp"]) for update in updates[5:11]]
    assert [len(cloud.data) // cloud.point_stride for _, cloud in clouds] == [
        len(update["primitives"]["/lidar/points"]["points"][0]["points"]) for update in updates[5:11]
    ]
    assert {schema for topic, schema, _, _ in messages if topic == "/camera/image_00"} == {"foxglove.CompressedImage"}


async def test_a_bad_export_request_is_refused_naming_the_problem(kitti_root: Path) -> None:
    async with running_server(kitti_root, export_max_mb=1) as server:
        for query, name, expected in [
            ("?format=zip", "kitti", (400, "format='zip'")),
            ("?start=soon", "kitti", (400, "start='soon' is not a number")),
            ("?start=nan", "kitti", (400, "not a finite number")),
            ("?start=10&end=5", "kitti", (400, "start=10.0 is after end=5.0")),
            ("", "nowhere", (404, "nowhere")),
            ("", "..%2Fetc", (404, "not allowed")),
            ("", "kitti", (413, "export_max_mb")),
        ]:
            status, _, body = await export(server, query, name)
            assert (status, expected[1] in body.decode()) == (expected[0], True), (query, name, body)
