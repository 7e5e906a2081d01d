"""The session protocol over real sockets, against static logs."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.client import connect

from helpers import assert_same_message, client, metric, running_server, ten_hz, timestamps, update, write_log
from xviz_server import frames
from xviz_server.codec import Format, decode

KITTI = "kitti"


@pytest.fixture
def root(tmp_path: Path, kitti_log: Path) -> Path:
    """A data root with the real KITTI log (by symlink) and a small JSON log."""
    data = tmp_path / "logs"
    data.mkdir()
    (data / KITTI).symlink_to(kitti_log)
    write_log(data / "city" / "json-drive", ten_hz(30), fmt=Format.JSON)
    return data


# ------------------------------------------------------------------ start


@pytest.mark.parametrize(
    "path",
    [
        "/?worker=true&log=kitti&profile=default&duration=30&timestamp=1317042145.96",  # XVIZStreamLoader
        "/?logGuid=kitti&worker=true&profile=default",  # XVIZLiveLoader's URL
        "/?version=2.0&log=kitti",  # xviz CLI
        "/kitti",  # log named by the path
        "/kitti?profile=default&foo=bar",
    ],
)
async def test_real_client_urls_get_metadata_at_once(root: Path, path: str):
    async with running_server(root) as server, client(server, path) as c:
        message = await c.recv()
        assert message["type"] == "xviz/metadata"
        data = message["data"]
        assert data["version"] == "2.0.0"
        assert data["log_info"]["start_time"] == 1317042145.964
        assert "/lidar/points" in data["streams"]
        assert not message["_text"]  # the KITTI log is GLB, so is its session by default


async def test_nested_log_name_by_path_and_query(root: Path):
    async with running_server(root) as server:
        for path in ("/city/json-drive", "/?log=city/json-drive"):
            async with client(server, path) as c:
                message = await c.recv()
                assert message["type"] == "xviz/metadata" and message["_text"]
                # log_info was missing: filled in from the index
                assert message["data"]["log_info"] == {"start_time": 100.0, "end_time": 102.9}


async def test_unnamed_log_is_the_only_one_or_a_listed_choice(root: Path, tmp_path: Path):
    async with running_server(root) as server, client(server) as c:
        message = await c.recv()
        assert message["type"] == "xviz/error"
        assert "'city/json-drive'" in message["data"]["message"] and "'kitti'" in message["data"]["message"]
        # the session stays open and can choose with xviz/start
        await c.send("start", {"version": "2.0.0", "log": "kitti"})
        assert (await c.recv())["type"] == "xviz/metadata"

    single = tmp_path / "single"
    write_log(single / "only", ten_hz(3))
    async with running_server(single) as server, client(server) as c:
        message = await c.recv()
        assert message["type"] == "xviz/metadata"


@pytest.mark.parametrize("value", ["live", "LIVE", "Live"])
async def test_session_type_in_any_case(root: Path, value: str):
    async with running_server(root) as server, client(server, f"/?log=kitti&session_type={value}") as c:
        message = await c.recv()  # a live session, waiting for a feed called kitti
        assert message["type"] == "xviz/error" and "live feed 'kitti' has not started yet" in message["data"]["message"]


async def test_message_format_from_url_and_start(root: Path):
    async with running_server(root) as server:
        async with client(server, "/?log=kitti&message_format=JSON") as c:
            message = await c.recv()
            assert message["type"] == "xviz/metadata" and message["_text"]
            await c.send("start", {"version": "2.0.0", "message_format": "BINARY"})
            again = await c.recv()
            assert again["type"] == "xviz/metadata" and not again["_text"]
            assert again["data"] == {k: v for k, v in message["data"].items()}


# ----------------------------------------------------------- transform_log


async def test_transform_log_sends_range_in_order_then_done(root: Path, kitti_log: Path):
    async with running_server(root) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send("transform_log", {"id": "r1", "start_timestamp": 1317042146.0, "end_timestamp": 1317042147.0})
        messages = await c.until("transform_log_done", "r1")
        timing = json.loads((kitti_log / "0-frame.json").read_text())["timing"]
        assert timestamps(messages) == [row[0] for row in timing if 1317042146.0 <= row[0] <= 1317042147.0]
        assert messages[-1]["data"] == {"id": "r1"}
        # GLB served as stored: the bytes of 3-frame.glb
        first = messages[0]
        assert first["_bytes"] == (kitti_log / "3-frame.glb").stat().st_size

        await c.send("transform_log", {"id": 7})  # whole log, numeric id
        messages = await c.until("transform_log_done")
        assert len(timestamps(messages)) == 25 and messages[-1]["data"] == {"id": "7"}


@pytest.mark.parametrize("key", ["desired_streams", "requested_streams"])
async def test_stream_filter_by_either_name(root: Path, key: str):
    async with running_server(root) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send("transform_log", {"id": "f", key: ["/vehicle_pose", "/vehicle/velocity"]})
        messages = await c.until("transform_log_done", "f")
        updates = [m["data"]["updates"][0] for m in messages[:-1]]
        assert len(updates) == 25
        for u in updates:
            assert set(u) == {"timestamp", "poses", "time_series"}
            assert [s for entry in u["time_series"] for s in entry["streams"]] == ["/vehicle/velocity"]
        assert all(m["_bytes"] < 5000 for m in messages[:-1])


async def test_newer_request_cancels_older_which_still_gets_done_first(root: Path):
    async with running_server(root, read_ahead=1) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send("transform_log", {"id": "old"})
        first = await c.recv()
        assert first["type"] == "xviz/state_update"
        await c.send("transform_log", {"id": "new", "start_timestamp": 1317042148.0})
        messages = [first] + await c.until("transform_log_done", "new")
        kinds = [(m["type"], m["data"].get("id")) for m in messages]
        done_old = kinds.index(("xviz/transform_log_done", "old"))
        old_frames = timestamps(messages[:done_old])
        new_frames = timestamps(messages[done_old:])
        assert len(old_frames) < 25  # cut short
        assert new_frames == [t for t in new_frames if t >= 1317042148.0] and len(new_frames) == 5


async def test_transcoding_both_ways(root: Path, kitti_log: Path):
    async with running_server(root) as server:
        async with client(server, "/?log=kitti&message_format=JSON") as c:
            await c.recv()
            await c.send("transform_log", {"id": "j", "end_timestamp": 1317042146.0})
            messages = await c.until("transform_log_done", "j")
            assert all(m["_text"] for m in messages)
            cloud = messages[0]["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
            assert len(cloud["points"]) == 121015 and isinstance(cloud["points"][0], list)
        async with client(server, "/city/json-drive?message_format=binary") as c:
            await c.recv()
            await c.send("transform_log", {"id": "b"})
            messages = await c.until("transform_log_done", "b")
            assert not any(m["_text"] for m in messages)
            points = messages[0]["data"]["updates"][0]["primitives"]["/points"]["points"][0]["points"]
            assert isinstance(points, np.ndarray) and points.dtype == np.float32 and points.shape == (10, 3)


async def test_pacing_at_speed(root: Path):
    async with running_server(root) as server, client(server, "/city/json-drive?speed=4") as c:
        await c.recv()
        loop = asyncio.get_running_loop()
        started = loop.time()
        await c.send("transform_log", {"id": "p", "start_timestamp": 100.0, "end_timestamp": 100.8})
        messages = await c.until("transform_log_done", "p")
        elapsed = loop.time() - started
        assert len(timestamps(messages)) == 9
        assert elapsed >= 0.8 / 4 * 0.95  # 0.8 s of log at 4x


# ------------------------------------------------------- point in time


async def test_point_in_time_gives_complete_state(root: Path):
    async with running_server(root) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send("transform_point_in_time", {"id": "q", "query_timestamp": 1317042147.05})
        message = await c.recv()
        assert message["type"] == "xviz/state_update"
        data = message["data"]
        assert data["update_type"] == "COMPLETE_STATE"
        state = data["updates"][0]
        assert state["timestamp"] == 1317042147.004  # the last frame at or before the query
        assert state["primitives"]["/lidar/points"]["points"][0]["points"].shape[1] == 3
        await c.send(
            "transform_point_in_time",
            {"id": "q2", "query_timestamp": 1317042147.05, "desired_streams": ["/vehicle_pose"]},
        )
        only_pose = (await c.recv())["data"]["updates"][0]
        assert set(only_pose) == {"timestamp", "poses"}
        await c.send("transform_point_in_time", {"id": "early", "query_timestamp": 10.0})
        error = await c.recv()
        assert error["type"] == "xviz/error"
        assert "'early'" in error["data"]["message"] and "'kitti'" in error["data"]["message"]


async def test_point_in_time_merges_incremental_updates(tmp_path: Path):
    updates = [update(100.0)] + [
        update(100.0 + i / 10, update_type="INCREMENTAL", streams=("/vehicle_pose",)) for i in range(1, 5)
    ]
    write_log(tmp_path / "inc", updates)
    async with running_server(tmp_path) as server, client(server, "/inc") as c:
        await c.recv()
        await c.send("transform_point_in_time", {"id": "q", "query_timestamp": 100.35})
        state = (await c.recv())["data"]["updates"][0]
        assert state["timestamp"] == 100.3
        assert state["poses"]["/vehicle_pose"]["position"][0] == 100.3  # newest pose
        assert state["primitives"]["/points"]["points"][0]["points"][0, 0] == np.float32(100.0)  # from the snapshot
        assert state["time_series"][0]["values"]["doubles"] == [200.0]


async def test_point_in_time_of_a_frame_that_is_a_whole_state(root: Path, kitti_log: Path, tmp_path: Path):
    # KITTI frames are SNAPSHOTs of one stream set: the answer is the frame, relabelled.
    async with running_server(root) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send("transform_point_in_time", {"id": "q", "query_timestamp": 1317042147.05})
        answer = await c.recv()
        stored = {
            decode(path.read_bytes())["data"]["updates"][0]["timestamp"]: path.read_bytes()
            for path in kitti_log.glob("*-frame.glb")
            if path.name != "1-frame.glb"
        }
        frame = stored[1317042147.004]  # the last at or before the query
        expected = decode(frame)
        expected["data"]["update_type"] = "COMPLETE_STATE"
        assert_same_message({k: answer[k] for k in ("type", "data")}, expected)
        # ... which is what merging the frame would give
        merged = decode(frames.merge([frame], Format.BINARY, None)[0])
        assert_same_message(answer["data"]["updates"][0], merged["data"]["updates"][0])
        # and answers take no place in the cache beside the frames themselves
        await c.send("transform_log", {"id": "all"})
        await c.until("transform_log_done", "all")
        entries = len(server.cache)
        for instant in (1317042146.5, 1317042147.05, 1317042147.5, 1317042148.0):
            await c.send("transform_point_in_time", {"id": "again", "query_timestamp": instant})
            assert (await c.recv())["data"]["update_type"] == "COMPLETE_STATE"
        assert len(server.cache) == entries

    # A COMPLETE_STATE frame in the session's format is sent as stored.
    stored = write_log(tmp_path / "complete" / "log", ten_hz(5, update_type="COMPLETE_STATE"))
    async with running_server(tmp_path / "complete") as server:
        websocket = await connect(f"ws://127.0.0.1:{server.port}/log", max_size=None)
        await websocket.recv()
        await websocket.send(
            json.dumps({"type": "xviz/transform_point_in_time", "data": {"id": "q", "query_timestamp": 100.25}})
        )
        assert await websocket.recv() == (stored / "4-frame.glb").read_bytes()  # the frame at 100.2
        await websocket.close()


# --------------------------------------------------------------- reconfigure


async def test_reconfigure_full_and_delta(root: Path):
    async with running_server(root) as server, client(server, "/?log=kitti") as c:
        await c.recv()
        await c.send(
            "reconfigure",
            {"update_type": "DELTA", "config_update": {"desired_streams": ["/vehicle_pose"], "message_format": "JSON"}},
        )
        await c.send("transform_log", {"id": "a", "end_timestamp": 1317042146.0})
        messages = await c.until("transform_log_done", "a")
        assert all(m["_text"] for m in messages)
        assert set(messages[0]["data"]["updates"][0]) == {"timestamp", "poses"}

        await c.send("reconfigure", {"update_type": "DELTA", "config_update": {"desired_streams": None}})
        await c.send("transform_log", {"id": "b", "end_timestamp": 1317042146.0})
        messages = await c.until("transform_log_done", "b")
        assert messages[0]["_text"] and "primitives" in messages[0]["data"]["updates"][0]

        await c.send("reconfigure", {"update_type": "FULL", "config_update": {}})
        await c.send("transform_log", {"id": "c", "end_timestamp": 1317042146.0})
        messages = await c.until("transform_log_done", "c")
        assert not messages[0]["_text"]  # back to the log's own format

        await c.send(
            "reconfigure", {"update_type": "DELTA", "config_update": {"message_format": "JSON", "frame_skip": 2}}
        )
        error = await c.recv()
        assert (
            error["type"] == "xviz/error"
            and "'frame_skip'" in error["data"]["message"]
            and "unchanged" in error["data"]["message"]
        )
        await c.send("transform_log", {"id": "d", "end_timestamp": 1317042146.0})
        messages = await c.until("transform_log_done", "d")
        assert not messages[0]["_text"]  # the rejected update changed nothing


# ------------------------------------------------------------------ HTTP


async def test_catalog_health_and_metrics(root: Path):
    import urllib.request

    async with running_server(root) as server:
        async with client(server, "/?log=kitti") as c:
            await c.recv()
            await c.send("transform_log", {"id": "m"})
            await c.until("transform_log_done", "m")

        def get(path: str) -> tuple[int, str, bytes]:
            with urllib.request.urlopen(f"http://127.0.0.1:{server.port}{path}") as response:
                return response.status, response.headers["Content-Type"], response.read()

        status, kind, body = await asyncio.to_thread(get, "/")
        assert status == 200 and kind == "application/json"
        logs = {log["name"]: log for log in json.loads(body)["logs"]}
        assert set(logs) == {"kitti", "city/json-drive"}
        assert logs["city/json-drive"]["frames"] == 30 and logs["city/json-drive"]["start_time"] == 100.0
        assert "/lidar/points" in logs["kitti"]["streams"]

        assert (await asyncio.to_thread(get, "/healthz"))[2] == b"ok\n"
        status, kind, body = await asyncio.to_thread(get, "/metrics")
        assert kind.startswith("text/plain")
        assert metric(body, "xviz_frames_sent_total", format="BINARY") == 25
        assert metric(body, "xviz_sessions_total") == 1
        assert metric(body, "xviz_cache_misses_total") >= 25
