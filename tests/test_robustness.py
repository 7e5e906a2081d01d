"""Bad input, misbehaving clients, limits and shutdown: the server keeps serving."""

from __future__ import annotations

import asyncio
import gc
import json
import os
import re
import signal
import sys
import tracemalloc
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from helpers import client, close_received, eventually, running_server, ten_hz, timestamps, write_log
from xviz_server.codec import Format
from xviz_server.server import run
from xviz_server.settings import Settings


@pytest.fixture
def root(tmp_path: Path, kitti_log: Path) -> Path:
    data = tmp_path / "logs"
    data.mkdir()
    (data / "kitti").symlink_to(kitti_log)
    write_log(data / "small", ten_hz(10))
    corrupt = write_log(data / "corrupt", ten_hz(6))
    frame = corrupt / "4-frame.glb"
    frame.write_bytes(frame.read_bytes()[: frame.stat().st_size // 2])  # truncated
    garbage = write_log(data / "garbage", ten_hz(3), fmt=Format.JSON)
    (garbage / "3-frame.json").write_text('{"type": "xviz/state_update", "data": {"updates": [')
    (write_log(data / "no-metadata", ten_hz(3)) / "1-frame.glb").unlink()
    pbe = data / "protobuf"
    pbe.mkdir()
    (pbe / "1-frame.pbe").write_bytes(b"PBE1\x00")
    return data


async def assert_usable(c, log_start: float = 100.0) -> None:
    """The session still answers a good request."""
    await c.send("transform_log", {"id": "check", "start_timestamp": log_start, "end_timestamp": log_start + 0.25})
    messages = await c.until("transform_log_done", "check")
    assert len(timestamps(messages)) == 3


@pytest.mark.parametrize(
    "raw, expected",
    [
        ("{not json", "malformed message: invalid JSON at line 1 column 2"),
        ('["a list"]', "must be a JSON object"),
        ('{"type": "xviz/flush", "data": {}}', "unknown message type 'xviz/flush'"),
        (
            '{"type": "xviz/transform_log", "data": {"id": "t1", "start_timestamp": "yesterday"}}',
            "xviz/transform_log (id 't1'): 'start_timestamp' must be a number, not 'yesterday' (log 'small')",
        ),
        (
            '{"type": "xviz/transform_log", "data": {"id": "t2", "start_timestamp": 5, "end_timestamp": 1}}',
            "xviz/transform_log (id 't2'): start_timestamp 5.0 is after end_timestamp 1.0 (log 'small')",
        ),
        (
            '{"type": "xviz/transform_point_in_time", "data": {"id": "t3"}}',
            "xviz/transform_point_in_time (id 't3'): 'query_timestamp' is required",
        ),
        (
            '{"type": "xviz/reconfigure", "data": {"update_type": "PARTIAL", "config_update": {}}}',
            "'update_type' must be one of 'FULL' or 'DELTA'",
        ),
        (b"\x00\x01binary junk", "malformed message"),
    ],
)
async def test_bad_messages_get_an_error_and_the_session_goes_on(root: Path, raw, expected: str):
    async with running_server(root) as server, client(server, "/small") as c:
        await c.recv()
        await c.websocket.send(raw)
        error = await c.recv()
        assert error["type"] == "xviz/error"
        assert expected in error["data"]["message"]
        await assert_usable(c)


async def test_unknown_log_then_a_good_one(root: Path):
    async with running_server(root) as server, client(server, "/?log=nowhere") as c:
        error = await c.recv()
        assert error["type"] == "xviz/error" and "no log named 'nowhere'" in error["data"]["message"]
        assert "'small'" in error["data"]["message"]
        await c.send("transform_log", {"id": "x"})
        error = await c.recv()
        assert "xviz/transform_log (id 'x'): no log is open" in error["data"]["message"]
        await c.send("start", {"version": "2.0.0", "log": "small"})
        assert (await c.recv())["type"] == "xviz/metadata"
        await assert_usable(c)


@pytest.mark.parametrize(
    "log, expected",
    [
        ("no-metadata", "log 'no-metadata' has no metadata file (1-frame.glb, 1-frame.json or 1-frame.pbe)"),
        ("protobuf", "log 'protobuf': 1-frame.pbe is not a readable XVIZ message: PBE message corrupt at offset 4"),
    ],
)
async def test_logs_that_cannot_be_served_say_why(root: Path, log: str, expected: str):
    async with running_server(root) as server, client(server, f"/{log}") as c:
        error = await c.recv()
        assert error["type"] == "xviz/error" and expected in error["data"]["message"]
        await c.send("start", {"log": "small"})
        assert (await c.recv())["type"] == "xviz/metadata"
        await assert_usable(c)


@pytest.mark.parametrize(
    "log, file, cause",
    [("corrupt", "4-frame.glb", "GLB truncated"), ("garbage", "3-frame.json", "invalid JSON")],
)
async def test_corrupt_frame_is_reported_and_the_rest_is_served(root: Path, log: str, file: str, cause: str):
    async with running_server(root) as server, client(server, f"/{log}") as c:
        await c.recv()
        await c.send("transform_log", {"id": "c1"})
        messages = await c.until("transform_log_done", "c1")
        errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
        assert len(errors) == 1
        assert all(part in errors[0] for part in ("'c1'", f"log {log!r}", file, cause)), errors[0]
        good = len(list((root / log).glob("*-frame.*"))) - 3  # index, metadata, the bad one
        assert len(timestamps(messages)) == good
        # the point-in-time path names it too
        bad_time = 100.2 if file == "4-frame.glb" else 100.1
        await c.send("transform_point_in_time", {"id": "p", "query_timestamp": bad_time})
        error = await c.recv()
        assert error["type"] == "xviz/error" and file in error["data"]["message"] and "'p'" in error["data"]["message"]


async def test_other_sessions_are_unaffected_by_a_bad_one(root: Path):
    async with running_server(root) as server:

        async def bad() -> None:
            async with client(server, "/small") as c:
                await c.recv()
                for i in range(50):
                    await c.websocket.send("{" * (i + 1))
                for _ in range(50):
                    assert (await c.recv())["type"] == "xviz/error"

        async def good() -> int:
            async with client(server, "/kitti") as c:
                await c.recv()
                await c.send("transform_log", {"id": "g"})
                return len(timestamps(await c.until("transform_log_done", "g")))

        _, frames = await asyncio.gather(bad(), good())
        assert frames == 25


def rss_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.slow
async def test_clients_dropping_mid_stream_leak_nothing(root: Path):
    async def cycle(server, abort: bool) -> None:
        websocket = await connect(f"ws://127.0.0.1:{server.port}/kitti", max_size=None)
        await websocket.recv()
        await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "d"}}))
        await websocket.recv()
        if abort:
            websocket.transport.abort()  # vanish without a closing handshake
        else:
            await websocket.close()

    async def settle(server, tasks: int) -> None:
        await eventually(lambda: len(server.sessions) == 0 and len(asyncio.all_tasks()) <= tasks, 60)

    async with running_server(root) as server:
        for i in range(100):  # warm the cache and the allocator
            await cycle(server, abort=i % 2 == 0)
        await asyncio.sleep(0.2)
        tasks, rss = len(asyncio.all_tasks()), rss_bytes()
        for i in range(1000):
            await cycle(server, abort=i % 2 == 0)
        await settle(server, tasks)
        assert len(server.sessions) == 0
        assert len(asyncio.all_tasks()) <= tasks
        # Frames are about 1 MB each: keeping one per session would show
        # here as gigabytes; the allocator alone moves RSS by tens of MB.
        growth = rss_bytes() - rss
        assert growth < 96 * 2**20, f"RSS grew by {growth / 2**20:.1f} MB over 1000 cycles"
        # A session's own objects are kilobytes: count Python allocations exactly.
        tracemalloc.start()
        try:
            before = tracemalloc.take_snapshot()
            for i in range(200):
                await cycle(server, abort=i % 2 == 0)
            await settle(server, tasks)
            gc.collect()
            after = tracemalloc.take_snapshot()
        finally:
            tracemalloc.stop()
        grown = sum(stat.size_diff for stat in after.compare_to(before, "filename"))
        assert grown < 256 * 2**10, f"the Python heap grew by {grown / 2**10:.0f} KiB over 200 cycles"


async def test_a_client_that_stops_reading_costs_bounded_memory(root: Path):
    async with running_server(root, read_ahead=2) as server:
        stalled = await connect(f"ws://127.0.0.1:{server.port}/kitti", max_size=None, max_queue=1)
        await stalled.recv()
        await stalled.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "s"}}))
        stalled.transport.pause_reading()  # and never read again
        await eventually(lambda: any(s.websocket.transport.get_write_buffer_size() for s in server.sessions))

        async with client(server, "/kitti") as c:  # others still get everything
            await c.recv()
            for i in range(3):
                await c.send("transform_log", {"id": f"g{i}"})
                assert len(timestamps(await c.until("transform_log_done", f"g{i}"))) == 25

        largest_frame = max(p.stat().st_size for p in (root / "kitti").glob("*-frame.glb"))
        buffered = [session.websocket.transport.get_write_buffer_size() for session in server.sessions]
        # at most the frame being written plus the socket's high-water mark
        assert 0 < max(buffered) <= largest_frame + 2**16
        stalled.transport.abort()


async def test_oversized_client_message_closes_only_that_connection(root: Path):
    async with running_server(root, max_message_kb=1) as server:
        async with client(server, "/small") as c:
            await c.recv()
            await c.websocket.send("x" * 2048)
            with pytest.raises(ConnectionClosed) as closed:
                await c.recv()
            assert closed.value.rcvd.code == 1009
        async with client(server, "/small") as c:
            await c.recv()
            await assert_usable(c)


async def test_sessions_beyond_the_limit_are_refused_with_503(root: Path):
    async with running_server(root, max_sessions=2) as server:
        async with client(server, "/small"), client(server, "/small"):
            with pytest.raises(InvalidStatus) as refused:
                async with client(server, "/small"):
                    pass
            assert refused.value.response.status_code == 503
        await eventually(lambda: len(server.sessions) < 2)  # the two end as their closing handshakes finish
        async with client(server, "/small") as c:  # room again
            assert (await c.recv())["type"] == "xviz/metadata"


async def test_dead_peer_is_closed_after_idle_timeout(root: Path):
    async with running_server(root, idle_timeout=0.5) as server:
        websocket = await connect(f"ws://127.0.0.1:{server.port}/small", ping_interval=None)
        await websocket.recv()
        websocket.transport.pause_reading()  # pings go unanswered
        await eventually(lambda: not server.sessions)
        websocket.transport.abort()

        async with client(server, "/small") as c:  # a live client answers pings and stays
            await c.recv()
            await asyncio.sleep(1.5)  # three idle timeouts pass: what is tested is that nothing happens
            await assert_usable(c)


async def test_sigterm_closes_sessions_with_1001_and_exits(root: Path):
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "xviz_server",
        "serve",
        "--data-dir",
        str(root),
        "--port",
        "0",
        stderr=asyncio.subprocess.PIPE,
    )
    port = None
    while port is None:
        line = (await asyncio.wait_for(process.stderr.readline(), 30)).decode()
        assert line, "server exited before listening"
        match = re.search(r"listening on ws://127.0.0.1:(\d+)/", line)
        port = int(match.group(1)) if match else None
    websocket = await connect(f"ws://127.0.0.1:{port}/kitti", max_size=None)
    await websocket.recv()
    process.send_signal(signal.SIGTERM)
    assert (await close_received(websocket, 10)).code == 1001
    assert await asyncio.wait_for(process.wait(), 10) == 0


async def test_serving_leaves_what_start_made_out_of_full_collections(root: Path):
    """``run`` freezes the objects made before it listens, so that a full collection goes over what serving made
    only, and gives them back to the collector when it stops."""
    assert gc.get_freeze_count() == 0
    task = asyncio.ensure_future(run(Settings(data_dir=[str(root)], port=0)))
    for _ in range(600):
        if gc.get_freeze_count() or task.done():
            break
        await asyncio.sleep(0.05)
    frozen = gc.get_freeze_count()
    tracked = len(gc.get_objects(generation=2))
    os.kill(os.getpid(), signal.SIGINT)  # run's own handler stops it
    await asyncio.wait_for(task, 30)
    assert frozen > 10 * tracked  # the process's modules and the catalog, against what is left to collect
    assert gc.get_freeze_count() == 0
