"""Live feeds: in-process and network sources, fan-out, slow viewers, reconfigure."""

from __future__ import annotations

import asyncio
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from helpers import Client, client, close_received, eventually, paused_viewer, running_server, ten_hz, update, write_log
from xviz_server.auth import ingest_refusal as refusal
from xviz_server.codec import Format, decode, encode
from xviz_server.framing import ready_to_write
from xviz_server.layout import frame_name
from xviz_server.state import downsample_points

META = {
    "version": "2.0.0",
    "streams": {
        "/vehicle_pose": {"category": "POSE"},
        "/points": {"category": "PRIMITIVE", "primitive_type": "POINT"},
        "/speed": {"category": "TIME_SERIES", "scalar_type": "FLOAT"},
    },
}


@pytest.fixture
def root(tmp_path: Path) -> Path:
    write_log(tmp_path / "logs" / "recorded", ten_hz(5))
    return tmp_path / "logs"


async def next_update(c: Client, timeout: float = 10) -> dict:
    while True:
        message = await c.recv(timeout)
        if message["type"] == "xviz/state_update":
            return message


async def test_live_session_gets_metadata_state_then_every_update(root: Path):
    async with running_server(root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        await feed.publish(update(1.0))
        await feed.publish(update(1.1, update_type="INCREMENTAL", streams=("/vehicle_pose",)))
        async with client(server, "/?log=car&session_type=live") as c:
            metadata = await c.recv()
            assert metadata["type"] == "xviz/metadata" and not metadata["_text"]  # GLB by default
            state = await c.recv()
            assert state["data"]["update_type"] == "COMPLETE_STATE"
            merged = state["data"]["updates"][0]
            assert merged["poses"]["/vehicle_pose"]["position"][0] == 1.1  # newest pose
            assert merged["primitives"]["/points"]["points"][0]["points"].shape == (10, 3)  # from the snapshot
            for t in (1.2, 1.3):
                await feed.publish(update(t))
                assert (await next_update(c))["data"]["updates"][0]["timestamp"] == t
            await c.send("transform_log", {"id": "r"})
            error = await c.recv()
            assert error["type"] == "xviz/error" and "not available in a LIVE session" in error["data"]["message"]


@pytest.mark.slow
async def test_ten_hz_to_twenty_viewers_one_of_them_stalled(root: Path):
    async with running_server(root, live_queue=8, live_lag_timeout=60) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        stalled = await paused_viewer(server, "/?log=car&session_type=live")
        viewers = [await connect(f"ws://127.0.0.1:{server.port}/?logGuid=car", max_size=None) for _ in range(19)]
        for viewer in viewers:
            assert decode(await viewer.recv())["type"] == "xviz/metadata"

        async def read(viewer, count: int) -> list[float]:
            times = []
            while len(times) < count:
                message = decode(await asyncio.wait_for(viewer.recv(), 10))
                if message["type"] == "xviz/state_update":
                    times.append(message["data"]["updates"][0]["timestamp"])
            return times

        readers = [asyncio.ensure_future(read(v, 30)) for v in viewers]
        expected = [round(2 + i / 10, 3) for i in range(30)]
        for t in expected:
            await feed.publish(update(t, points=60_000))  # 720 KB each: the stalled socket fills up
            await asyncio.sleep(0.1)
        results = await asyncio.gather(*readers)
        assert all(times == expected for times in results)

        port = stalled.local_address[1]
        [stalled_session] = [s for s in server.sessions if s.websocket.remote_address[1] == port]
        assert stalled_session.frames_sent < 30
        subscription = stalled_session._subscription
        assert len(subscription._queue) <= 8  # bounded by live_queue, not by what was published
        assert subscription.lagging_since is not None
        stalled.transport.resume_reading()
        notices = []
        while not notices:  # what the socket held comes first, then the notice
            message = decode(await asyncio.wait_for(stalled.recv(), 10))
            if message["type"] == "xviz/error":
                notices.append(message["data"]["message"])
        assert "this viewer is behind" in notices[0] and "updates were dropped" in notices[0]
        for ws in [stalled, *viewers]:
            await ws.close()


async def test_late_joiner_draws_at_once_and_feeds_are_found_by_any_name(root: Path):
    async with running_server(root) as server:
        feed = server.live.feed("mock-car")
        feed.set_metadata(META)
        await feed.publish(update(5.0))
        # streetscape.gl's XVIZLiveLoader URL, naming a feed that is not there: the only feed is served
        async with client(server, "/?logGuid=mock&worker=true&profile=default") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
            state = await c.recv()
            assert state["data"]["updates"][0]["timestamp"] == 5.0


async def test_source_leaving_and_coming_back(root: Path):
    async with running_server(root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        async with client(server, "/?log=car&session_type=LIVE") as c:
            await c.recv()
            feed.disconnect()
            notice = await c.recv()
            assert notice["type"] == "xviz/error" and "went away" in notice["data"]["message"]
            changed = {**META, "log_info": {"start_time": 9.0, "end_time": 99.0}}
            feed.set_metadata(changed)
            again = await c.recv()
            assert again["type"] == "xviz/metadata" and again["data"]["log_info"]["start_time"] == 9.0
            await feed.publish(update(9.5))
            assert (await next_update(c))["data"]["updates"][0]["timestamp"] == 9.5


async def test_reconfigure_filter_decimation_downsampling_and_format(root: Path):
    async with running_server(root) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        received_config = []

        async def accept(config_update):
            received_config.append(config_update)

        feed.on_reconfigure = accept
        async with client(server, "/?log=car&session_type=live") as c:
            await c.recv()
            await c.send(
                "reconfigure",
                {
                    "update_type": "DELTA",
                    "config_update": {
                        "desired_streams": ["/points"],
                        "decimate": 2,
                        "max_points": 100,
                        "message_format": "JSON",
                    },
                },
            )
            await eventually(lambda: received_config)  # the session took it, then forwarded it to the feed
            for i in range(6):
                await feed.publish(update(10 + i, points=1000))
            got = [await next_update(c) for _ in range(3)]
            assert [m["data"]["updates"][0]["timestamp"] for m in got] == [10, 12, 14]
            for message in got:
                assert message["_text"]
                stream_set = message["data"]["updates"][0]
                assert set(stream_set) == {"timestamp", "primitives"}
                assert len(stream_set["primitives"]["/points"]["points"][0]["points"]) == 100
            await c.send("reconfigure", {"update_type": "DELTA", "config_update": {"rate_hz": 5}})
            error = await c.recv()
            assert "unknown key 'rate_hz'" in error["data"]["message"]
        assert received_config == [
            {"desired_streams": ["/points"], "decimate": 2, "max_points": 100, "message_format": "JSON"}
        ]


def test_downsampling_keeps_every_kth_point_with_its_colour():
    points = np.arange(30, dtype=np.float32).reshape(10, 3)
    colors = np.arange(40, dtype=np.uint8).reshape(10, 4)
    message = {
        "type": "xviz/state_update",
        "data": {
            "updates": [{"timestamp": 1, "primitives": {"/p": {"points": [{"points": points, "colors": colors}]}}}]
        },
    }
    thinned = downsample_points(message, 4)["data"]["updates"][0]["primitives"]["/p"]["points"][0]
    assert thinned["points"].tolist() == points[::3].tolist() and thinned["colors"].tolist() == colors[::3].tolist()


async def test_viewer_hopelessly_behind_is_disconnected_with_a_reason(root: Path):
    async with running_server(root, live_queue=2, live_lag_timeout=0.5) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        slow = await paused_viewer(server, "/?log=car&session_type=live")
        for i in range(40):
            await feed.publish(update(float(i), points=50_000))
            await asyncio.sleep(0.05)
        slow.transport.resume_reading()
        close = await close_received(slow)
        assert close.code == 1013 and "too slow: dropped live updates" in close.reason
        await eventually(lambda: not server.sessions)


# ------------------------------------------------------------------ ingest


async def test_network_ingest_with_reconfigure_forwarding(root: Path):
    async with running_server(root, ingest_token="s3cret") as server:
        with pytest.raises(InvalidStatus) as refused:
            await connect(f"ws://127.0.0.1:{server.port}/ingest/truck?token=wrong")
        assert refused.value.response.status_code == 403
        async with connect(
            f"ws://127.0.0.1:{server.port}/ingest/truck?reconfigure=1",
            additional_headers={"Authorization": "Bearer s3cret"},
            max_size=None,
        ) as source:
            await source.send(json.dumps({"type": "xviz/metadata", "data": META}))
            await source.send(encode({"type": "xviz/state_update", "data": update(3.0)}, Format.BINARY))
            await eventually(lambda: (feed := server.live.get("truck")) is not None and feed.state() is not None)
            async with client(server, "/?logGuid=truck") as viewer:
                assert (await viewer.recv())["type"] == "xviz/metadata"
                assert (await viewer.recv())["data"]["updates"][0]["timestamp"] == 3.0
                await source.send(encode({"type": "xviz/state_update", "data": update(3.1)}, Format.JSON))
                assert (await next_update(viewer))["data"]["updates"][0]["timestamp"] == 3.1
                await viewer.send("reconfigure", {"update_type": "DELTA", "config_update": {"max_points": 5}})
                forwarded = json.loads(await asyncio.wait_for(source.recv(), 30))
                assert forwarded == {
                    "type": "xviz/reconfigure",
                    "data": {"update_type": "DELTA", "config_update": {"max_points": 5}},
                }
                await source.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "x"}}))
                error = json.loads(await asyncio.wait_for(source.recv(), 30))
                assert error["type"] == "xviz/error" and "not 'xviz/transform_log'" in error["data"]["message"]
            async with connect(f"ws://127.0.0.1:{server.port}/ingest/truck?token=s3cret") as second:
                with pytest.raises(ConnectionClosed) as closed:
                    await second.recv()
                assert "already has a source" in closed.value.rcvd.reason


def test_ingest_without_token_is_loopback_only():
    from websockets.datastructures import Headers
    from websockets.http11 import Request

    request = Request("/ingest/car", Headers())
    assert refusal(request, ("127.0.0.1", 5000), None) is None
    assert refusal(request, ("::1", 5000, 0, 0), None) is None
    assert "needs a token" in refusal(request, ("10.1.2.3", 5000), None)
    assert "bad feed name" in refusal(Request("/ingest/../x", Headers()), ("127.0.0.1", 1), None)


async def test_an_update_published_as_a_viewer_joins_comes_once(root: Path):
    # The viewer's session subscribes, then sends the metadata and the latest
    # state; an update published in between is in that state and in the
    # subscription's queue, and must reach the viewer once.
    async with running_server(root) as server:
        feed = server.live.feed("busy")
        feed.set_metadata(META)
        await feed.publish(update(1.0))
        subscribe = feed.subscribe

        def subscribe_then_publish(*args, **kwargs):
            subscription = subscribe(*args, **kwargs)
            publishing = feed.publish(encode({"type": "xviz/state_update", "data": update(1.1)}, Format.BINARY))
            with pytest.raises(StopIteration):  # an update given as GLB bytes is published without waiting
                publishing.send(None)
            return subscription

        feed.subscribe = subscribe_then_publish
        async with client(server, "/?log=busy&session_type=live") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
            state = await next_update(c)
            await feed.publish(update(1.2))
            following = await next_update(c)
    assert state["data"]["updates"][0]["timestamp"] == 1.1
    assert following["data"]["updates"][0]["timestamp"] == 1.2


async def test_replay_of_a_log_as_a_live_feed(root: Path, tmp_path: Path):
    write_log(tmp_path / "drive-7", ten_hz(10))
    async with running_server(root, live_from=tmp_path / "drive-7", rate=2.0) as server:
        async with client(server, "/?logGuid=drive-7") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
            times = [(await next_update(c))["data"]["updates"][0]["timestamp"] for _ in range(4)]
            assert times == sorted(times) and len(set(times)) == 4


async def test_streetscape_live_loader_url_through_the_published_client(root: Path):
    from helpers import run_xviz_session_async

    async with running_server(root) as server:
        feed = server.live.feed("mock")
        feed.set_metadata({**META, "log_info": {"start_time": 20.0, "end_time": 30.0}})

        async def publish() -> None:
            for i in range(100):
                await feed.publish(update(round(20 + i / 10, 3), points=500))
                await asyncio.sleep(0.1)

        publisher = asyncio.ensure_future(publish())
        url = f"ws://127.0.0.1:{server.port}/?logGuid=mock&worker=true&profile=default"
        result = await run_xviz_session_async(
            url, [{"wait": "metadata"}, {"wait": "state_updates", "count": 5}, {"close": True}]
        )
        publisher.cancel()
    assert result.ok, result.stderr
    assert result.summary["errors"] == []
    metadata = result.messages[0]
    assert metadata["type"] == "xviz/metadata" and metadata["parsed"]["start_time"] == 20.0
    updates = result.of_type("xviz/state_update")
    times = [u["parsed"]["timestamp"] for u in updates]
    assert times == sorted(times) and len(times) >= 5
    for u in updates:
        assert u["parsed"]["type"] == "TIMESLICE" and "/vehicle_pose" in u["parsed"]["poses"]
        assert u["parsed"]["streams"]["/points"]["pointCloud"]["numInstances"] == 500


async def test_record_then_replay_gives_the_same_frames(root: Path, tmp_path: Path):
    record = tmp_path / "record"
    published = [update(round(50 + i / 10, 3)) for i in range(12)]
    async with running_server(root, record=record) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        for data in published:
            await feed.publish(data)
    [recording] = list((record / "car").iterdir())
    async with running_server(record) as server:
        name = f"car/{recording.name}"
        async with client(server, f"/?log={name}") as c:
            assert (await c.recv())["data"]["streams"] == META["streams"]
            await c.send("transform_log", {"id": "r"})
            messages = await c.until("transform_log_done", "r")
    frames = [m for m in messages if m["type"] == "xviz/state_update"]
    assert [f["data"]["updates"][0]["timestamp"] for f in frames] == [d["updates"][0]["timestamp"] for d in published]
    for frame, data in zip(frames, published):
        points = frame["data"]["updates"][0]["primitives"]["/points"]["points"][0]["points"]
        assert np.array_equal(points, data["updates"][0]["primitives"]["/points"]["points"][0]["points"])


async def test_a_recording_cut_short_is_still_a_readable_log(root: Path, tmp_path: Path):
    record = tmp_path / "record"
    async with running_server(root, record=record) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        for i in range(5):
            await feed.publish(update(float(i)))
        await eventually(lambda: any(record.glob(f"car/*/{frame_name(4)}.glb")))  # the last, written atomically
        [recording] = list((record / "car").iterdir())
        # as a crash would leave it: frames so far, an index that may lag behind
        snapshot = tmp_path / "crashed" / "car"
        snapshot.parent.mkdir()
        shutil.copytree(recording, snapshot)
    async with running_server(snapshot.parent) as server, client(server, "/car") as c:
        await c.recv()
        await c.send("transform_log", {"id": "x"})
        frames = [m for m in await c.until("transform_log_done", "x") if m["type"] == "xviz/state_update"]
        assert [f["data"]["updates"][0]["timestamp"] for f in frames] == [0.0, 1.0, 2.0, 3.0, 4.0]


async def test_one_publish_writes_to_every_viewer_that_keeps_up_and_queues_for_one_that_does_not(root: Path):
    """Viewers waiting for the next update are sent it within the publish call, with no task switch per
    viewer; a viewer whose socket is full gets its updates through its queue, with the usual limits."""
    async with running_server(root, live_queue=4) as server:
        feed = server.live.feed("car")
        feed.set_metadata(META)
        await feed.publish(update(0.0))
        fast = [
            await connect(f"ws://127.0.0.1:{server.port}/?log=car&session_type=live", max_size=None) for _ in range(3)
        ]
        slow = await paused_viewer(server, "/?log=car&session_type=live")
        try:
            for websocket in fast:
                await websocket.recv(), await websocket.recv()  # metadata, state
            ports = {websocket.local_address[1] for websocket in fast}
            sessions = {session.websocket.remote_address[1] in ports: session for session in server.sessions}
            slow_session = sessions[False]
            fast_sessions = [s for s in server.sessions if s is not slow_session]
            await eventually(lambda: all(s._live_idle for s in fast_sessions))  # each waits for the next update
            published = 8
            for t in range(1, 30):  # large updates until the paused viewer's socket is full
                published += 1
                before = {s: s.frames_sent for s in server.sessions}
                await feed.publish(
                    encode({"type": "xviz/state_update", "data": update(float(t), points=50_000)}, Format.BINARY)
                )
                assert all(s.frames_sent == before[s] + 1 for s in fast_sessions)  # sent before publish returned
                for websocket in fast:
                    assert decode(await websocket.recv())["data"]["updates"][0]["timestamp"] == float(t)
                # Full: not sent, and the server's buffer for it past its mark (a viewer whose task was still
                # busy with the last update, its socket not full, would take the next ones).
                if slow_session.frames_sent == before[slow_session] and not ready_to_write(slow_session.websocket):
                    break
            else:
                pytest.fail("the paused viewer's socket never filled")
            for t in range(100, 108):  # the paused viewer's queue (4) overflows; the others keep up
                await feed.publish(
                    encode({"type": "xviz/state_update", "data": update(float(t), points=50_000)}, Format.BINARY)
                )
                for websocket in fast:
                    assert decode(await websocket.recv())["data"]["updates"][0]["timestamp"] == float(t)
            slow.transport.resume_reading()
            stamps, notices = [], []
            while not stamps or stamps[-1] != 107.0:
                message = decode(await asyncio.wait_for(slow.recv(), 10))
                if message["type"] == "xviz/state_update":
                    stamps.append(message["data"]["updates"][0]["timestamp"])
                elif message["type"] == "xviz/error":
                    notices.append(message["data"]["message"])
            assert stamps == sorted(stamps) and len(stamps) < published  # in order, some dropped
            assert any("this viewer is behind" in notice for notice in notices)
        finally:
            for websocket in [*fast, slow]:
                await websocket.close()
