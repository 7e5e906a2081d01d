"""Sessions over slow links: a real server, a real client, and a link shaped to 5, 20 and 100 Mbit/s between them.

The links are real: the client's socket lives in a network namespace of its
own behind a veth pair whose way out is shaped with ``tc tbf`` (root only;
the tests skip elsewhere). A rate-limited TCP proxy (``devkit/tcpproxy.py``)
is no such link to the server: it reads like a slow client, whose backlog
waits for it to read; a viewer that reads slowly keeps full detail.

The frames a client receives are recognised by their bytes: each is the
frame file itself (full detail) or exactly what :func:`xviz_server.frames.render`
makes of it at one level.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import struct
import time
import urllib.request
from collections import Counter
from functools import cache

import pytest
from conftest import KITTI_LOG
from websockets.asyncio.client import connect

from devkit.tclink import can_shape_links, tc_link
from devkit.tcpproxy import shaped_link
from helpers import foxglove_opened, metric, require_data, running_server, xviz_decode
from xviz_server import frames
from xviz_server.codec import Format, decode
from xviz_server.detail import START
from xviz_server.levels import LEVELS
from xviz_server.server import XVIZServer
from xviz_server.settings import Settings

LOG = KITTI_LOG.name
NUMBERS = list(range(2, 27))  # the frames of the log, in order
SPAN = 2.5  # seconds of the log
LEVEL = {level.name: level for level in LEVELS}


@cache
def made(number: int, level_name: str) -> bytes:
    data = (KITTI_LOG / f"{number}-frame.glb").read_bytes()
    return data if level_name == "full" else frames.render(data, Format.BINARY, None, None, LEVEL[level_name])


def level_of(number: int, data: bytes) -> str:
    """The level frame ``number`` was sent at, from its bytes."""
    for level in LEVELS:
        if level.every == 1 and made(number, level.name) == data:
            return level.name
    raise AssertionError(f"frame {number} ({len(data)} bytes) is no level of the frame")


async def whole_log(websocket, request_id: str, **request: float) -> tuple[list[bytes], tuple[float, float]]:
    """Every frame of the log (or of the ``request``'s range), and the seconds it took to get the first and all."""
    started = time.monotonic()
    await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": request_id, **request}}))
    received, first = [], math.inf
    while True:
        data = await asyncio.wait_for(websocket.recv(), 30)
        if isinstance(data, bytes) and len(data) > 10_000:
            received.append(data)
            first = min(first, time.monotonic() - started)
        elif decode(data)["type"] == "xviz/transform_log_done":
            return received, (first, time.monotonic() - started)


def metrics(server) -> str:
    return urllib.request.urlopen(f"http://{server.settings.host}:{server.port}/metrics").read().decode()


shaped = pytest.mark.skipif(not can_shape_links(), reason="shaping a link with tc needs root, ip and tc")


async def connect_through(link, server, path: str):
    """A client session to ``path`` of ``server``, from the far side of ``link``."""
    sock = await asyncio.to_thread(link.connect, server.port)
    return connect(f"ws://{link.host}:{server.port}{path}", sock=sock, max_size=None)


async def test_loopback_gets_every_byte(kitti_root):
    async with running_server(kitti_root) as server:
        async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti&profile=default", max_size=None) as websocket:
            await websocket.recv()
            for request in "ab":
                received, _ = await whole_log(websocket, request)
                assert received == [made(number, "full") for number in NUMBERS]
            assert 'xviz_sessions_by_detail{level="full"} 1.0' in await asyncio.to_thread(metrics, server)


async def test_each_level_of_a_frame_is_made_once_whatever_the_viewers_at_it(kitti_root):
    """Five viewers at one level, all at once, cost the cache's loads and makings of one viewer: never one per viewer."""

    async def loads(viewers: int) -> float:
        async with running_server(kitti_root) as server:

            async def view() -> list[bytes]:
                async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti&profile=low", max_size=None) as websocket:
                    await websocket.recv()
                    return (await whole_log(websocket, "all"))[0]

            for received in await asyncio.gather(*(view() for _ in range(viewers))):
                assert received == [made(number, "low") for number in NUMBERS]
            return metric(await asyncio.to_thread(metrics, server), "xviz_cache_misses_total")

    one = await loads(1)
    assert one >= len(NUMBERS)  # each frame was made at the level once, at least
    assert await loads(5) == one


@pytest.mark.slow
@shaped
@pytest.mark.parametrize("mbps, expected", [(100, {"high"}), (20, {"low"}), (5, {"minimal"})])
async def test_a_log_over_a_slow_link_starts_with_a_frame_that_fits_and_plays_in_real_time_at_the_level_the_link_carries(
    kitti_root, caplog, mbps, expected
):
    caplog.set_level(logging.INFO, "xviz_server.session")
    with tc_link(mbps, prefix="xl-") as link:
        async with XVIZServer(Settings(host=link.host, port=0, data_dir=kitti_root)) as server:
            async with await connect_through(link, server, "/?log=kitti&profile=default") as websocket:
                await websocket.recv()
                started = time.monotonic()
                first, _ = await whole_log(websocket, "first")
                more = first
                while level_of(NUMBERS[-1], more[-1]) not in expected and time.monotonic() - started < 8:  # a climb
                    more, _ = await whole_log(websocket, "more")
                again, (_, seconds) = await whole_log(websocket, "again")
                text = await asyncio.to_thread(metrics, server)
    # Nothing is known of the link before the first frame: it is sent at a level that arrives within 0.5 s at 5 Mbit/s.
    assert level_of(NUMBERS[0], first[0]) == LEVELS[START].name and len(first[0]) <= 0.5 * 5 * 125_000
    levels = [level_of(number, data) for number, data in zip(NUMBERS, again)]
    assert set(levels) == expected, levels
    if mbps <= 20:  # at 100 Mbit/s the server and this client, one process, may not keep up on a shared machine
        assert seconds <= SPAN, f"{seconds:.2f} s for a log of {SPAN} s"
    assert f'xviz_sessions_by_detail{{level="{levels[-1]}"}} 1.0' in text
    changes = [r.getMessage() for r in caplog.records if r.getMessage().startswith("detail changed")]
    if expected == {LEVELS[START].name}:
        assert changes == []
    else:  # a climb to the level the link carries: every change a step up, none back down
        names = [LEVELS[START].name] + [change.split()[3].removeprefix("detail=") for change in changes]
        assert all(LEVEL[a].share < LEVEL[b].share for a, b in zip(names, names[1:])) and names[-1] == levels[-1], (
            changes
        )


@pytest.mark.slow
async def test_a_slow_reader_is_no_slow_link(kitti_root):
    # The proxy reads 20 Mbit/s: the server's backlog waits for it to read (its receive window is full).
    async with running_server(kitti_root) as server, shaped_link(server.port, 20) as link:
        async with connect(f"ws://127.0.0.1:{link.port}/?log=kitti&profile=default", max_size=None) as websocket:
            start = decode(await websocket.recv())["data"]["log_info"]["start_time"]
            received, _ = await whole_log(websocket, "a", end_timestamp=start + 0.65)
    assert received == [made(number, "full") for number in NUMBERS[:7]]


FOXGLOVE = "foxglove.websocket.v1"


class LiveViewer:
    """What a live viewer behind a link received: (seconds since it connected, bytes) of each update.

    An XVIZ viewer's update is a state update; a Foxglove client (subscribed
    to every channel) has an update in the messages before each ``time`` message.
    """

    def __init__(self, websocket) -> None:
        self.websocket = websocket
        self.start = time.monotonic()
        self.updates: list[tuple[float, int]] = []
        self._bytes = 0  # of a Foxglove update's messages so far

    async def read(self, until: float) -> None:
        """Read until ``until`` seconds since the start."""
        while (now := time.monotonic() - self.start) < until:
            try:
                data = await asyncio.wait_for(self.websocket.recv(), until - now)
            except asyncio.TimeoutError:
                return
            if self.websocket.subprotocol == FOXGLOVE:
                await self._foxglove(data)
            elif isinstance(data, bytes) and decode(data)["type"] == "xviz/state_update":
                self.updates.append((time.monotonic() - self.start, len(data)))

    async def _foxglove(self, data: str | bytes) -> None:
        if isinstance(data, str):
            message = json.loads(data)
            if message["op"] == "advertise":
                subscriptions = [{"id": channel["id"], "channelId": channel["id"]} for channel in message["channels"]]
                await self.websocket.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        elif data[0] == 0x01:
            self._bytes += len(data)
        elif data[0] == 0x02 and self._bytes:
            self.updates.append((time.monotonic() - self.start, self._bytes))
            self._bytes = 0

    def runs_above(self, size: int, start: float = 0.0, end: float = math.inf) -> list[int]:
        """How many updates larger than ``size`` bytes came in a row, for each run of them from ``start`` to ``end``."""
        runs: list[int] = []
        before = False
        for t, n in self.updates:
            above = start <= t < end and n > size
            if above and before:
                runs[-1] += 1
            elif above:
                runs.append(1)
            before = above
        return runs


def level_changes(caplog, since: float) -> list[tuple[float, str]]:
    """The changes of level logged after the wall clock's ``since``: (seconds after it, level)."""
    found = []
    for record in caplog.records:
        if record.getMessage().startswith("detail changed") and record.created >= since:
            found.append((record.created - since, record.getMessage().split()[3].removeprefix("detail=")))
    return found


async def connect_live(link, server, face: str):
    """A live session of ``face`` (XVIZ or Foxglove) from the far side of ``link``."""
    sock = await asyncio.to_thread(link.connect, server.port)
    url = f"ws://{link.host}:{server.port}/?session_type=live&profile=default"
    return connect(url, sock=sock, max_size=None, subprotocols=[FOXGLOVE] if face == FOXGLOVE else None)


@shaped
@pytest.mark.slow
@pytest.mark.parametrize("face", ["xviz", FOXGLOVE])
@pytest.mark.parametrize("bucket", [32_000, 64_000, 256_000])
async def test_a_live_session_behind_a_5_mbps_token_bucket_starts_with_a_frame_that_fits_and_takes_no_level_that_stalls(
    kitti_log, caplog, bucket, face
):
    """Frames smaller than the bucket leave at the wire's speed: no measure of the link, and no reason to step up."""
    caplog.set_level(logging.INFO, "xviz_server.session")
    with tc_link(5, latency=0.2, bucket=bucket, prefix="xl-") as link:
        settings = Settings(host=link.host, port=0, live_from=kitti_log, loop=True)
        async with XVIZServer(settings) as server, await connect_live(link, server, face) as websocket:
            since = time.time()
            viewer = LiveViewer(websocket)
            await viewer.read(12)
    first = viewer.updates[0]
    assert first[1] <= 0.5 * 5 * 125_000  # the first update arrives within half a second on the link
    changes = level_changes(caplog, since)
    # A probe finds the level up too slow, and it is not taken; if one lets it through (a bucket larger than a
    # probe; on a loaded machine, seldom, a probe misread), the level is undone within 2 s.
    ups = [t for t, level in changes if level != "minimal"]
    downs = [t for t, level in changes if level == "minimal"]
    assert all(a < b for a, b in zip(ups, downs)), changes
    # each undone, but one in the last 2 s, which the end of the session may cut short
    assert len(downs) == len(ups) or (len(downs) == len(ups) - 1 and ups[-1] >= 10), changes
    for up, down in zip(ups, downs):  # undone within 2 s of its updates reaching the viewer (not of their making)
        reached = [t for t, n in viewer.updates if t >= up and n > 2 * first[1]]
        assert not reached or down - reached[0] <= 2, (changes, viewer.updates)
    if bucket < 200_000:
        assert len(ups) <= 1, changes
    # No step up that stalls: the level up is sent one update at a time (a probe), but while a step up lasts; the
    # probes that fail wait 5 s, then 10 s, before the next.
    runs = viewer.runs_above(2 * first[1])
    assert len([run for run in runs if run > 1]) <= len(ups) and len(runs) <= 3, (runs, changes, viewer.updates)


@shaped
@pytest.mark.slow
@pytest.mark.parametrize("face", ["xviz", FOXGLOVE])
async def test_a_live_link_from_20_to_5_to_20_mbps(kitti_log, caplog, face):
    """A token bucket of 64 KB with a queue of 200 ms, as many shapers have, whose rate changes twice."""
    caplog.set_level(logging.INFO, "xviz_server.session")
    with tc_link(20, latency=0.2, bucket=64_000, prefix="xl-") as link:
        settings = Settings(host=link.host, port=0, live_from=kitti_log, loop=True)
        async with XVIZServer(settings) as server, await connect_live(link, server, face) as websocket:
            since = time.time()
            viewer = LiveViewer(websocket)
            await viewer.read(8)
            assert [level for _, level in level_changes(caplog, since)] == ["low"]  # a climb from the start
            link.shape(5)
            slower = time.time() - since
            await viewer.read(20)
            down = level_changes(caplog, since)[1:]
            # down within 2 s (and a tick), to the level that fits: minimal, which sends every update
            assert down and down[0][1] == "minimal" and down[0][0] - slower <= 2.5, (slower, down)
            faster = time.monotonic() - viewer.start
            link.shape(20)
            await viewer.read(45)
    changes = level_changes(caplog, since)
    assert [level for _, level in changes] == ["low", "minimal", "low"], changes  # back up, once
    times = [t for t, _ in changes]
    assert all(b - a >= 5 for a, b in zip(times, times[1:])), changes  # at most one change in 5 s
    # No stall at 5 Mbit/s: once down (and the updates sent before arrived), low is only probed, one update at a time.
    minimal = viewer.updates[0][1]  # the first update's level
    assert all(run == 1 for run in viewer.runs_above(2 * minimal, down[0][0] + 1, faster)), viewer.updates


async def test_the_user_picks_a_level_or_a_cap_and_bad_ones_are_named(kitti_root):
    async with running_server(kitti_root) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=kitti&profile=ultra&max_mbps=fast"
        async with connect(url, max_size=None) as websocket:
            errors = " ".join([decode(await websocket.recv())["data"]["message"] for _ in range(2)])
            assert "profile: unknown profile 'ultra'; profiles: auto, default, full" in errors
            assert "'max_mbps': 'fast' is not a positive number of Mbit/s" in errors
            assert decode(await websocket.recv())["type"] == "xviz/metadata"  # the session goes on, in auto
            received, _ = await whole_log(websocket, "auto")
            assert {level_of(n, d) for n, d in zip(NUMBERS, received)} == {"full"}
            reconfigure = {
                "type": "xviz/reconfigure",
                "data": {"update_type": "DELTA", "config_update": {"profile": "x"}},
            }
            await websocket.send(json.dumps(reconfigure))
            assert "'profile': unknown profile 'x'" in decode(await websocket.recv())["data"]["message"]
            reconfigure["data"]["config_update"] = {"profile": "medium"}
            await websocket.send(json.dumps(reconfigure))
            received, _ = await whole_log(websocket, "medium")
            assert {level_of(n, d) for n, d in zip(NUMBERS, received)} == {"medium"}
            reconfigure["data"]["config_update"] = {"profile": "auto", "max_mbps": 20}
            await websocket.send(json.dumps(reconfigure))
            received, _ = await whole_log(websocket, "capped")
            assert {level_of(n, d) for n, d in zip(NUMBERS[-10:], received[-10:])} == {"low"}
        async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti&profile=low", max_size=None) as websocket:
            await websocket.recv()
            received, _ = await whole_log(websocket, "low")
            assert {level_of(n, d) for n, d in zip(NUMBERS, received)} == {"low"}


@pytest.mark.slow
@shaped
async def test_detail_off_sends_every_byte_over_a_slow_link(kitti_root):
    with tc_link(50) as link:
        async with XVIZServer(Settings(host=link.host, port=0, data_dir=kitti_root, detail="off")) as server:
            async with await connect_through(link, server, "/?log=kitti&profile=low") as websocket:
                start = decode(await websocket.recv())["data"]["log_info"]["start_time"]
                received, _ = await whole_log(websocket, "a", end_timestamp=start + 0.45)
    assert received == [made(number, "full") for number in NUMBERS[:5]]


def test_the_published_client_reads_every_level(tmp_path):
    require_data()
    paths = [KITTI_LOG / "1-frame.glb"]
    for level in LEVELS[1:]:
        path = tmp_path / f"{level.name}.glb"
        path.write_bytes(made(14, level.name))
        paths.append(path)
    results = xviz_decode(paths)
    assert all("error" not in result for result in results), results
    for level, result in zip(LEVELS[1:], results[1:]):
        cloud = decode(made(14, level.name))["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
        parsed = json.dumps(result["parsed"])
        assert f'"length": {3 * len(cloud["points"])}' in parsed, level.name  # the positions, as drawn
        assert parsed.count("$bytes") >= 4  # the four camera images
    assert Counter(result["raw"]["type"] for result in results[1:]) == {"xviz/state_update": len(LEVELS) - 1}


@cache
def points_at(number: int, level_name: str) -> int:
    """How many lidar points frame ``number`` has at a level."""
    return len(
        decode(made(number, level_name))["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]["points"]
    )


async def foxglove_clouds(websocket, count: int) -> list[tuple[int, int]]:
    """(frame number, points) of the next ``count`` point clouds a Foxglove client subscribed to the lidar gets."""
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    by_time = {round(decode(made(n, "full"))["data"]["updates"][0]["timestamp"] * 1e9): n for n in NUMBERS}
    clouds = []
    while len(clouds) < count:
        data = await asyncio.wait_for(websocket.recv(), 30)
        if isinstance(data, bytes) and data[0] == 0x01:
            stamp = int.from_bytes(data[5:13], "little")
            cloud = PointCloud.FromString(data[13:])
            clouds.append((by_time[stamp], len(cloud.data) // cloud.point_stride))
    return clouds


async def test_a_foxglove_client_pins_a_level_by_url_and_by_parameter(kitti_root):
    async with running_server(kitti_root) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=kitti&profile=low"
        async with connect(url, subprotocols=[FOXGLOVE], max_size=None) as websocket:
            info, channels = await foxglove_opened(websocket)
            assert {"parameters", "parametersSubscribe"} <= set(info["capabilities"])
            lidar = next(channel["id"] for channel in channels if channel["topic"] == "/lidar/points")
            await websocket.send(
                json.dumps({"op": "subscribeParameterUpdates", "parameterNames": ["/xviz_server/level"]})
            )
            await websocket.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": lidar}]}))
            for number, points in await foxglove_clouds(websocket, 3):
                assert points == points_at(number, "low")  # the very cloud an XVIZ session at low gets
            await websocket.send(json.dumps({"op": "getParameters", "parameterNames": [], "id": "g"}))
            set_ = {
                "op": "setParameters",
                "parameters": [{"name": "/xviz_server/profile", "value": "medium"}],
                "id": "s",
            }
            await websocket.send(json.dumps(set_))
            answers = []
            while len(answers) < 3:
                data = await asyncio.wait_for(websocket.recv(), 10)
                if isinstance(data, str) and json.loads(data)["op"] == "parameterValues":
                    answers.append(json.loads(data))
            values = {answer.get("id"): {p["name"]: p["value"] for p in answer["parameters"]} for answer in answers}
            assert values["g"] == {"/xviz_server/profile": "low", "/xviz_server/level": "low"}
            assert values[None] == {"/xviz_server/level": "medium"}  # told, as subscribed
            assert values["s"] == {"/xviz_server/profile": "medium"}
            clouds = await foxglove_clouds(websocket, 6)
            assert all(points == points_at(number, "medium") for number, points in clouds[-3:]), clouds


@pytest.mark.slow
async def test_a_foxglove_client_shares_each_level_of_a_frame_with_xviz_sessions_at_it(kitti_root):
    """The Foxglove messages of a level are made of the frame XVIZ sessions at that level get, made once for both."""

    async def misses(faces: list[str]) -> float:
        async with running_server(kitti_root) as server:
            for face in faces:
                url = f"ws://127.0.0.1:{server.port}/?log=kitti&profile=minimal"
                async with connect(
                    url, subprotocols=[FOXGLOVE] if face == FOXGLOVE else None, max_size=None
                ) as websocket:
                    if face == FOXGLOVE:
                        _, channels = await foxglove_opened(websocket)
                    else:
                        await websocket.recv()
                    if face == FOXGLOVE:
                        lidar = next(channel["id"] for channel in channels if channel["topic"] == "/lidar/points")
                        await websocket.send(
                            json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": lidar}]})
                        )
                        speed = struct.pack("<BBfBQI", 0x03, 0, 100.0, 0, 0, 1) + b"r"  # play, at 100 times real time
                        await websocket.send(speed)
                        clouds = await foxglove_clouds(websocket, len(NUMBERS))
                        assert [points for _, points in clouds] == [points_at(number, "minimal") for number in NUMBERS]
                    else:
                        assert (await whole_log(websocket, "all"))[0] == [made(number, "minimal") for number in NUMBERS]
            return metric(await asyncio.to_thread(metrics, server), "xviz_cache_misses_total")

    xviz = await misses(["xviz"])
    both = await misses(["xviz", FOXGLOVE])
    # One conversion a frame, of the level XVIZ made (not the level again), and the Foxglove plan's survey of the
    # first frame's value types (foxglove.translate.survey), kept in the cache like a frame.
    assert both == xviz + len(NUMBERS) + 1
