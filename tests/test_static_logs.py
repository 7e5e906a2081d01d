"""The static-log provider: layouts, indexes, the catalog, and names that try to escape the root."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from helpers import client, eventually, running_server, ten_hz, timestamps, write_log
from xviz_server.catalog import parse_query
from xviz_server.codec import Format


async def stream_all(server, path: str) -> list[float]:
    async with client(server, path) as c:
        first = await c.recv()
        assert first["type"] == "xviz/metadata", first
        await c.send("transform_log", {"id": "all"})
        return timestamps(await c.until("transform_log_done", "all"))


@pytest.mark.parametrize("fmt", [Format.BINARY, Format.JSON])
async def test_log_without_index_is_indexed_from_its_frames(tmp_path: Path, fmt: Format):
    write_log(tmp_path / "raw", ten_hz(12), fmt=fmt, index=False)
    async with running_server(tmp_path) as server:
        assert await stream_all(server, "/raw") == [round(100 + i / 10, 3) for i in range(12)]
        log = await server.shelf.open("raw")
        assert log.metadata["log_info"] == {"start_time": 100.0, "end_time": 101.1}
        # built once, shared: a second open returns the same log
        assert await server.shelf.open("raw") is log


@pytest.mark.parametrize(
    "index_text",
    [
        "not json at all",
        json.dumps({"timing": "nope"}),
        json.dumps({"timing": [[100.0, 100.0, 0, "2-frame"]]}),  # names 1 frame of 5
        json.dumps({"timing": [[100.0, 100.0, i, f"{i + 2}-frame"] for i in range(9)]}),  # names missing frames
    ],
)
async def test_wrong_index_is_rebuilt(tmp_path: Path, index_text: str):
    log = write_log(tmp_path / "bad-index", ten_hz(5), index=False)
    (log / "0-frame.json").write_text(index_text)
    async with running_server(tmp_path) as server:
        assert await stream_all(server, "/bad-index") == [100.0, 100.1, 100.2, 100.3, 100.4]


async def test_real_index_is_used_as_is(kitti_log: Path, tmp_path: Path):
    (tmp_path / "k").symlink_to(kitti_log)
    async with running_server(tmp_path) as server:
        log = await server.shelf.open("k")
        timing = json.loads((kitti_log / "0-frame.json").read_text())["timing"]
        assert log.index.start.tolist() == [row[0] for row in timing]
        assert log.index.frames.tolist() == list(range(25))
        # metadata's own end_time (the whole drive) is kept: it is finite and set
        assert log.metadata["log_info"]["end_time"] == 1317042157.004


async def test_root_that_is_itself_a_log(tmp_path: Path):
    write_log(tmp_path / "solo", ten_hz(3))
    async with running_server(tmp_path / "solo") as server:
        assert server.shelf.names() == ["solo"]
        assert len(await stream_all(server, "/")) == 3


async def test_log_added_while_serving_is_found(tmp_path: Path):
    write_log(tmp_path / "first", ten_hz(2))
    async with running_server(tmp_path) as server:
        write_log(tmp_path / "later", ten_hz(4))
        assert len(await stream_all(server, "/?log=later")) == 4


async def test_symlink_loops_do_not_hang_the_scan(tmp_path: Path):
    write_log(tmp_path / "a" / "log", ten_hz(2))
    (tmp_path / "a" / "loop").symlink_to(tmp_path / "a")
    async with running_server(tmp_path) as server:
        assert "a/log" in server.shelf.names()


@pytest.mark.parametrize(
    "path",
    [
        "/?log=../outside",
        "/?log=/etc",
        "/?log=city/../../outside",
        "/?log=%2e%2e/outside",  # decoded once by the URL parser: '../outside'
        "/?log=%252e%252e%252foutside",  # double-encoded: '%2e%2e%2foutside' is refused too
        "/?log=..%5Coutside",  # backslash
        "/?log=C:/outside",
        "/..%2Foutside",
        "/%2e%2e/outside",
    ],
)
async def test_names_cannot_leave_the_root(tmp_path: Path, path: str):
    root = tmp_path / "root"
    write_log(root / "city", ten_hz(2))
    write_log(tmp_path / "outside", ten_hz(2))  # a log the client must never reach
    async with running_server(root) as server, client(server, path) as c:
        message = await c.recv()
        assert message["type"] == "xviz/error", message
        assert "not allowed" in message["data"]["message"] or "no log named" in message["data"]["message"]
        # and the session is still usable
        await c.send("start", {"version": "2.0.0", "log": "city"})
        assert (await c.recv())["type"] == "xviz/metadata"


async def test_symlink_placed_by_the_operator_is_followed(tmp_path: Path):
    write_log(tmp_path / "elsewhere" / "drive", ten_hz(3))
    (tmp_path / "root").mkdir()
    (tmp_path / "root" / "linked").symlink_to(tmp_path / "elsewhere" / "drive")
    async with running_server(tmp_path / "root") as server:
        assert len(await stream_all(server, "/linked")) == 3


async def test_a_log_copied_in_while_running_is_served_to_a_logguid_url(tmp_path: Path):
    # streetscape.gl's live loader names its log only by logGuid; a log that arrived after
    # the client's connection was accepted is still a recorded log, not a feed to wait for.
    root = tmp_path / "logs"
    write_log(root / "first", ten_hz(2))
    async with running_server(root) as server:
        write_log(root / "arrived", ten_hz(3))
        async with client(server, "/?logGuid=arrived&worker=true") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
            await c.send("transform_log", {"id": "1"})
            assert len(timestamps(await c.until("transform_log_done", "1"))) == 3


async def _stream_after_frames_deleted(server, root: Path, name: str) -> tuple[list[float], list[dict]]:
    """Open ``name`` in a session, wait for any preload, delete its frame files, stream it in the same session."""
    async with client(server, f"/{name}") as c:
        assert (await c.recv())["type"] == "xviz/metadata"
        preload = server.shelf._preloads.get(name)
        if preload is not None:
            await asyncio.wait_for(asyncio.shield(preload), 10)
        for path in (root / name).glob("*-frame.json"):
            if int(path.name.split("-")[0]) >= 2:
                path.unlink()
        await c.send("transform_log", {"id": "all"})
        messages = await c.until("transform_log_done", "all")
        return timestamps(messages), [m for m in messages if m["type"] == "xviz/error"]


async def test_a_small_log_is_read_into_the_cache_when_opened(tmp_path: Path):
    # Its frames are served from memory once read in: even with the files gone.
    write_log(tmp_path / "small", ten_hz(40), fmt=Format.JSON)
    async with running_server(tmp_path) as server:
        served, errors = await _stream_after_frames_deleted(server, tmp_path, "small")
    assert served == [round(100 + i / 10, 3) for i in range(40)] and errors == []


@pytest.mark.parametrize("preload_mb", [0, 0.001])
async def test_a_log_is_not_read_in_when_preload_is_off_or_it_is_larger(tmp_path: Path, preload_mb: float):
    write_log(tmp_path / "small", ten_hz(40), fmt=Format.JSON)
    async with running_server(tmp_path, preload_mb=preload_mb) as server:
        served, errors = await _stream_after_frames_deleted(server, tmp_path, "small")
    assert served == [] and len(errors) == 40


async def _cache_fills(server, entries: int) -> None:
    """Wait until the frame cache holds ``entries`` entries."""
    await eventually(lambda: len(server.cache) >= entries)


async def test_listing_the_catalog_reads_no_frames(tmp_path: Path):
    # Listing the catalog opens no log; only a session's open reads a log in.
    for name in ("a", "b"):
        write_log(tmp_path / name, ten_hz(20), fmt=Format.JSON)
    async with running_server(tmp_path) as server:
        assert len((await server.indexer.page(parse_query({})))["logs"]) == 2
        await asyncio.sleep(0.5)
        assert len(server.cache) == 0
        async with client(server, "/a") as c:
            assert (await c.recv())["type"] == "xviz/metadata"
            await _cache_fills(server, 20)
        assert len(server.cache) == 20


async def test_logs_opened_together_are_all_read_in(tmp_path: Path):
    for name in ("a", "b", "c"):
        write_log(tmp_path / name, ten_hz(15), fmt=Format.JSON)
    async with running_server(tmp_path) as server:
        async with client(server, "/a") as a, client(server, "/b") as b, client(server, "/c") as c:
            for session in (a, b, c):
                assert (await session.recv())["type"] == "xviz/metadata"
            await _cache_fills(server, 45)
        assert len(server.cache) == 45
