"""The catalog of logs (issue 31): listed, searched and paged from SQLite, kept current, opening no log.

Fleets of small logs in the reference layout (an index document, JSON metadata, two frames: see
``write_fleet``) and hard-linked copies of the real KITTI log, served from real directories and from
moto's S3 server through the counting proxy; the API asked over real HTTP.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from devkit.fleet import FLEET_START, FleetLog, write_fleet
from helpers import (
    client,
    eventually,
    http_get,
    metadata,
    running_server,
    start_serving,
    stop_serving,
    ten_hz,
    write_log,
)
from xviz_server.catalog import indexer
from xviz_server.catalog.db import FILE_NAME, SCHEMA, SORT_INDEXES
from xviz_server.codec import Format, encode
from xviz_server.server import XVIZServer

KITTI_START = 1317042145.964


def fetch(server: XVIZServer, path: str) -> tuple[int, dict[str, Any]]:
    """``GET path``: the status and the JSON body."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}{path}", timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


def cursor_of(fields: list[Any]) -> str:
    """A cursor as the server writes them (its JSON, base64url without padding), holding ``fields``."""
    return base64.urlsafe_b64encode(json.dumps(fields).encode()).decode().rstrip("=")


async def listing(server: XVIZServer, **query: Any) -> dict[str, Any]:
    status, body = await asyncio.to_thread(fetch, server, "/api/logs?" + urllib.parse.urlencode(query))
    assert status == 200, body
    return body


async def every_page(server: XVIZServer, **query: Any) -> list[dict[str, Any]]:
    """Every log the query lists, page after page, by the cursors the server gives."""
    logs: list[dict[str, Any]] = []
    cursor = None
    while True:
        page = await listing(server, **query, **({"cursor": cursor} if cursor else {}))
        logs += page["logs"]
        cursor = page["next"]
        if cursor is None:
            return logs


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory, kitti_log: Path) -> tuple[Path, list[FleetLog]]:
    """300 small logs of 10 cars, and three copies (hard links) of the real KITTI log under ``kitti/``."""
    root = tmp_path_factory.mktemp("fleet")
    logs = write_fleet(root, 300)
    for copy in range(3):
        target = root / "kitti" / f"copy-{copy}"
        target.mkdir(parents=True)
        for file in kitti_log.iterdir():
            os.link(file, target / file.name)
    return root, logs


KITTI_COPIES = ["kitti/copy-0", "kitti/copy-1", "kitti/copy-2"]


async def test_pages_list_every_log_once_in_order_and_open_none(fleet: tuple[Path, list[FleetLog]]):
    root, logs = fleet
    async with running_server(root) as server:
        first = await listing(server, limit=40)
        listed = await every_page(server, limit=40)
        assert len(server.shelf._open) == 0 and len(server.cache) == 0  # no log opened, no frame read
    assert set(first) == {"server", "logs", "live", "next", "indexed", "found"} and first["live"] == []
    assert first["indexed"] == first["found"] == len(logs) + 3
    assert [log["name"] for log in listed] == sorted([log.name for log in logs] + KITTI_COPIES)
    by_name = {log["name"]: log for log in listed}
    some = logs[7]
    entry = by_name[some.name]
    # Today's fields, and the new ones.
    assert {"name", "format", "frames", "start_time", "end_time", "streams"} <= set(entry)
    assert entry["format"] == "JSON" and entry["frames"] == 2 and entry["kind"] == "xviz" and entry["indexed"] is True
    assert (entry["start_time"], entry["end_time"], entry["duration"]) == (some.start, some.end, some.end - some.start)
    assert entry["description"] == some.description and entry["vehicle"] == some.vehicle and entry["tags"] == ["city"]
    assert entry["streams"] == ["/points", "/vehicle_pose"] and entry["bytes"] > 0
    kitti = by_name["kitti/copy-1"]
    assert kitti["frames"] == 25 and kitti["format"] == "BINARY" and kitti["start_time"] == KITTI_START
    assert "/lidar/points" in kitti["streams"]


async def test_searches_filter_and_sort(fleet: tuple[Path, list[FleetLog]]):
    root, logs = fleet
    names = lambda found: [log["name"] for log in found]  # noqa: E731
    async with running_server(root) as server:
        assert names(await every_page(server, q="HIGHWAY")) == sorted(
            log.name for log in logs if "highway" in log.description
        )
        assert names(await every_page(server, q="car-03/")) == sorted(
            log.name for log in logs if log.vehicle == "car-03"
        )
        assert names(await every_page(server, q="%")) == [] and names(await every_page(server, q="_")) == []
        start, end = FLEET_START + 3000, FLEET_START + 3600
        overlapping = sorted(log.name for log in logs if log.end >= start and log.start <= end)
        assert (
            names(await every_page(server, **{"from": start, "to": end}, limit=3)) == overlapping
            and len(overlapping) == 11
        )
        assert names(await every_page(server, q="city", **{"from": start})) == sorted(
            log.name for log in logs if log.end >= start and "city" in log.description
        )
        assert names(await every_page(server, min_duration=55)) == sorted(
            log.name for log in logs if log.end - log.start >= 55
        )
        cameras = sorted(log.name for i, log in enumerate(logs) if i % 3 == 0)
        assert names(await every_page(server, stream="/camera", limit=17)) == cameras
        assert names(await every_page(server, stream="/no/such")) == []
        assert names(await every_page(server, kind="kitti,bag")) == []
        assert len(await every_page(server, kind="xviz", limit=1000)) == len(logs) + 3
        latest_first = await every_page(server, sort="-start_time", q="seg", limit=13)
        assert names(latest_first) == [log.name for log in sorted(logs, key=lambda log: log.start, reverse=True)]
        by_duration = await every_page(server, sort="duration", q="seg", limit=7)
        assert names(by_duration) == [log.name for log in sorted(logs, key=lambda log: (log.end - log.start, log.name))]


async def test_one_log_gives_every_fact(fleet: tuple[Path, list[FleetLog]]):
    root, logs = fleet
    async with running_server(root) as server:
        status, one = await asyncio.to_thread(fetch, server, f"/api/logs/{urllib.parse.quote(logs[3].name)}")
        assert status == 200 and one["name"] == logs[3].name and one["state"] == "indexed"
        assert one["detail"]["streams"]["/camera"] == {"category": "PRIMITIVE", "primitive_type": "IMAGE"}
        assert one["detail"]["log_info"]["description"] == logs[3].description
        status, kitti = await asyncio.to_thread(fetch, server, "/api/logs/kitti/copy-0")
        assert status == 200 and kitti["detail"]["cameras"] == [] and kitti["frames"] == 25
        for path in ["/api/logs/nothing", "/api/logs/kitti/../car-01", "/api/logs/kitti%2F..%2Fx", "/api/logs/"]:
            status, body = await asyncio.to_thread(fetch, server, path)
            assert status == 404 and "error" in body, path


@pytest.mark.parametrize(
    "query, parameter",
    [
        ("limit=0", "limit"),
        ("limit=abc", "limit"),
        ("limit=1001", "limit"),
        ("limit=%EF%BC%95", "limit"),
        ("from=yesterday", "from"),
        ("to=nan", "to"),
        ("from=inf", "from"),
        ("from=10&to=5", "from"),
        ("min_duration=-1", "min_duration"),
        ("sort=colour", "sort"),
        ("sort=--name", "sort"),
        ("kind=tape", "kind"),
        ("kind=xviz,", "kind"),
        ("cursor=garbage", "cursor"),
        ("cursor=WyJuYW1lIiwxLCJ4Il0", "cursor"),
        ("q=a&q=b", "q"),
        ("q=", "q"),
        ("stream=" + "x" * 501, "stream"),
        ("from=1_000", "from"),
        ("to=%205", "to"),
        ("min_duration=%2B5", "min_duration"),
        ("from=0x10", "from"),
        ("from=1&from=2", "from"),
        ("sort=frames&cursor=" + cursor_of(["frames", 2**63, "a"]), "cursor"),
        ("sort=-bytes&cursor=" + cursor_of(["-bytes", 2**64 - 1, "a"]), "cursor"),
    ],
)
async def test_a_malformed_parameter_is_a_400_naming_it(tmp_path: Path, query: str, parameter: str):
    write_fleet(tmp_path, 3)
    async with running_server(tmp_path) as server:
        status, body = await asyncio.to_thread(fetch, server, f"/api/logs?{query}")
    assert status == 400 and body["parameter"] == parameter and body["error"].startswith(f"{parameter}: ")


async def test_a_cursor_pages_only_the_sort_it_was_made_for(tmp_path: Path):
    write_fleet(tmp_path, 5)
    async with running_server(tmp_path) as server:
        page = await listing(server, sort="start_time", limit=2)
        status, body = await asyncio.to_thread(fetch, server, f"/api/logs?sort=-start_time&cursor={page['next']}")
        assert status == 400 and body["parameter"] == "cursor"
        assert len(await every_page(server, sort="start_time", limit=2)) == 5


async def test_a_restart_lists_every_log_from_its_catalog_at_once(tmp_path: Path):
    logs = write_fleet(tmp_path / "logs", 200)
    state = tmp_path / "state"
    async with running_server(tmp_path / "logs", state_dir=state):
        pass
    assert (state / FILE_NAME).is_file()
    with contextlib.closing(sqlite3.connect(state / FILE_NAME)) as built:
        indexes = {name for (name,) in built.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
    assert set(SORT_INDEXES) <= indexes  # made once the first build was done
    async with running_server(tmp_path / "logs", state_dir=state, settled=False) as server:
        page = await listing(server, limit=1000)
        # Listed before the first look at the folders ends, and with nothing to index again.
        assert page["found"] == page["indexed"] == 200
        assert [log["name"] for log in page["logs"]] == sorted(log.name for log in logs)
        await server.indexer.settled()
        assert (await listing(server))["indexed"] == 200


#: What the server imports for sessions only (codecs, numpy, schemas, recordings, stores): none of it on the way to listening.
SESSION_ONLY = (
    "numpy",
    "pygltflib",
    "jsonschema",
    "google.protobuf",
    "PIL",
    "rosbags",
    "mcap",
    "foxglove_schemas_protobuf",
    "xviz_server.codec",
    "xviz_server.messages",
    "xviz_server.xviz.session",
    "xviz_server.xviz.connection",
    "xviz_server.logs",
    "xviz_server.catalog.facts",
)


def test_the_command_and_the_server_import_nothing_that_only_sessions_need():
    found = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, xviz_server.cli, xviz_server.server\n"
            f"print(','.join(name for name in {SESSION_ONLY!r} if name in sys.modules))",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert found.returncode == 0, found.stderr
    assert found.stdout.strip() == ""


async def test_a_restart_answers_its_first_page_and_health_with_no_worker_process(tmp_path: Path):
    write_fleet(tmp_path / "logs", 50)
    state = tmp_path / "state"
    async with running_server(tmp_path / "logs", state_dir=state):
        pass
    process, port, lines = await start_serving(
        "--data-dir", str(tmp_path / "logs"), "--state-dir", str(state), "--host", "127.0.0.1"
    )
    try:
        health = await asyncio.to_thread(http_get, port, "/healthz")
        status, _, body = await asyncio.to_thread(http_get, port, "/api/logs")
        children = Path(f"/proc/{process.pid}/task/{process.pid}/children").read_text().split()
    finally:
        await stop_serving(process, lines)
    assert health[0] == status == 200
    page = json.loads(body)
    assert page["found"] == page["indexed"] == 50 and len(page["logs"]) == 50
    assert children == []  # reading the catalog needs no worker process: they start when a job does


async def test_logs_added_changed_and_removed_while_serving_are_listed_within_seconds(tmp_path: Path):
    root = tmp_path / "logs"
    write_fleet(root, 20)
    async with running_server(root, catalog_poll=0.2) as server:

        async def listed() -> dict[str, dict[str, Any]]:
            return {log["name"]: log for log in await every_page(server)}

        # Copied into a hidden folder, then renamed into place; and into a new car's folder.
        staging = write_log(root / ".incoming", ten_hz(4))
        staging.rename(root / "car-01" / "new")
        (root / "car-99").mkdir()
        write_log(root / "car-99" / "first", ten_hz(6))
        await eventually(lambda: _has(listed, "car-01/new", 4))
        await eventually(lambda: _has(listed, "car-99/first", 6))

        # Changed in place: more frames and a new index (the log's own folder changes, not its parent's).
        write_log(root / "car-01" / "new", ten_hz(9))
        await eventually(lambda: _has(listed, "car-01/new", 9))

        # Written frame by frame, its index last: listed at once, indexed when complete.
        growing = root / "car-02" / "growing"
        write_log(growing, ten_hz(3), index=False)
        await eventually(lambda: _state(listed, "car-02/growing", False))
        write_log(growing, ten_hz(3))
        await eventually(lambda: _has(listed, "car-02/growing", 3))

        shutil.rmtree(root / "car-01" / "new")
        shutil.rmtree(root / "car-03")
        await eventually(lambda: _gone(listed, "car-01/new", "car-03/seg-000003", "car-03/seg-000013"))
        page = await listing(server)
        assert page["found"] == page["indexed"] == 20 + 2 - 2


async def test_a_log_rewritten_in_place_is_found_by_the_sweep_a_page_a_look(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    monkeypatch.setattr(indexer, "SWEEP_PAGE", 4)  # 21 logs: every log compared once in six looks
    root = tmp_path / "logs"
    logs = sorted(log.name for log in write_fleet(root, 21))
    async with running_server(root, catalog_poll=0.2) as server:

        async def size(name: str) -> int:
            return int((await server.indexer.one(name) or {})["bytes"])

        for name in (logs[-1], logs[0]):  # the last page, then the first again
            before, folder = await size(name), os.stat(root / name).st_mtime_ns
            with open(root / name / "0-frame.json", "r+b") as index:  # in place: the folder's time stays
                text = index.read()
                index.seek(0)
                index.write(text + b" " * 100)
            assert os.stat(root / name).st_mtime_ns == folder
            await eventually(lambda: _bytes_are(size, name, before + 100))


async def _bytes_are(size: Callable[[str], Any], name: str, expected: int) -> bool:
    return bool(await size(name) == expected)


async def _has(listed: Callable[[], Any], name: str, frames: int) -> bool:
    log = (await listed()).get(name)
    return log is not None and log.get("frames") == frames


async def _state(listed: Callable[[], Any], name: str, indexed: bool) -> bool:
    log = (await listed()).get(name)
    return log is not None and log["indexed"] is indexed


async def _gone(listed: Callable[[], Any], *names: str) -> bool:
    return not set(names) & set(await listed())


def written_long_ago(root: Path) -> None:
    """Set every folder under ``root`` to an hour old, as a fleet store's logs are: none waits to settle."""
    long_ago = time.time() - 3600
    for folder in [root, *(path for path in root.rglob("*") if path.is_dir())]:
        os.utime(folder, (long_ago, long_ago))


async def test_logs_without_index_documents_are_listed_from_metadata_and_first_and_last_frames(tmp_path: Path):
    logs = write_fleet(tmp_path, 12, index=False)
    write_log(
        tmp_path / "untimed", ten_hz(5, start=100.0), fmt=Format.JSON, index=False
    )  # no log_info: times from frames
    write_log(tmp_path / "untimed-glb", ten_hz(3, start=200.0), index=False)
    corrupt = write_log(tmp_path / "corrupt-last", ten_hz(4, start=300.0), index=False)
    (corrupt / "5-frame.glb").write_bytes(b"\x00not a frame")
    written_long_ago(tmp_path)
    async with running_server(tmp_path) as server:
        listed = {log["name"]: log for log in await every_page(server)}
    assert set(listed) == {log.name for log in logs} | {"untimed", "untimed-glb", "corrupt-last"}
    for log in logs:
        entry = listed[log.name]
        assert entry["indexed"] is True and "error" not in entry and entry["frames"] == 2
        assert (entry["start_time"], entry["end_time"], entry["vehicle"]) == (log.start, log.end, log.vehicle)
        assert entry["streams"] == sorted(
            ["/points", "/vehicle_pose", *(["/camera"] if int(log.name[-6:]) % 3 == 0 else [])]
        )
    untimed = listed["untimed"]
    assert (untimed["format"], untimed["frames"], untimed["start_time"], untimed["end_time"]) == (
        "JSON",
        5,
        100.0,
        100.4,
    )
    assert untimed["streams"] == ["/points", "/speed", "/vehicle_pose"]
    glb = listed["untimed-glb"]
    assert (glb["format"], glb["frames"], glb["start_time"], glb["end_time"]) == ("BINARY", 3, 200.0, 200.2)
    # A corrupt frame is left out of the time range, as a session leaves it out of its index; the log is listed.
    assert listed["corrupt-last"]["frames"] == 4 and listed["corrupt-last"]["start_time"] == 300.0
    assert "error" not in listed["corrupt-last"]


async def test_a_session_opens_a_log_the_catalog_has_not_indexed(tmp_path: Path):
    write_log(tmp_path / "fresh", ten_hz(5), index=False)  # waits for its index
    async with running_server(tmp_path, settled=False) as server:
        await server.indexer.looked.wait()
        (entry,) = (await listing(server))["logs"]
        assert entry == {"name": "fresh", "kind": "xviz", "indexed": False}
        async with client(server, "/?log=fresh") as viewer:
            metadata = await viewer.recv()
    assert metadata["type"] == "xviz/metadata" and metadata["data"]["log_info"]["start_time"] == 100.0


async def test_a_log_that_fails_to_index_is_listed_with_its_error(tmp_path: Path):
    write_fleet(tmp_path, 2)
    broken = write_log(tmp_path / "broken", ten_hz(2))
    (broken / "1-frame.glb").write_bytes(b"\x00not a message")
    async with running_server(tmp_path) as server:
        logs = {log["name"]: log for log in (await listing(server))["logs"]}
        status, one = await asyncio.to_thread(fetch, server, "/api/logs/broken")
    assert logs["broken"]["indexed"] is True and "1-frame.glb is not a readable XVIZ message" in logs["broken"]["error"]
    assert one["state"] == "failed" and one["error"] == logs["broken"]["error"]
    assert "error" not in logs["car-01/seg-000001"]


@pytest.mark.parametrize("damage", ["garbage", "older", "truncated", "a column short"])
async def test_a_corrupt_or_older_catalog_file_is_built_again_with_one_log_line(
    tmp_path: Path, damage: str, caplog: pytest.LogCaptureFixture
):
    write_fleet(tmp_path / "logs", 5)
    state = tmp_path / "state"
    state.mkdir()
    path = state / FILE_NAME
    if damage == "garbage":
        path.write_bytes(b"this is not a database" * 100)
    elif damage == "older":
        with sqlite3.connect(path) as old:
            old.executescript(
                f"CREATE TABLE logs (name TEXT); INSERT INTO logs VALUES ('ghost'); PRAGMA user_version = {SCHEMA - 1};"
            )
    else:
        async with running_server(tmp_path / "logs", state_dir=state):
            pass
        if damage == "truncated":
            data = path.read_bytes()
            path.write_bytes(data[: len(data) // 3] + b"\xff" * 4096)
        else:  # as a file made before a column was added to catalog/columns.py
            with contextlib.closing(sqlite3.connect(path)) as old, old:
                old.execute("ALTER TABLE logs DROP COLUMN vehicle")
    caplog.set_level(logging.INFO, "xviz_server")
    async with running_server(tmp_path / "logs", state_dir=state) as server:
        page = await listing(server)
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING and "catalog" in r.getMessage()]
    assert len(warnings) == 1 and "building it again" in warnings[0], warnings
    assert damage != "a column short" or "columns differ from this server's in vehicle" in warnings[0]
    assert page["found"] == page["indexed"] == 5 and "ghost" not in [log["name"] for log in page["logs"]]
    assert all(log["vehicle"] for log in page["logs"])
    with sqlite3.connect(path) as rebuilt:
        assert rebuilt.execute("PRAGMA user_version").fetchone()[0] == SCHEMA


FULL_DISK = textwrap.dedent(
    """
    import asyncio, json, resource, sys, urllib.request
    from xviz_server.server import XVIZServer
    from xviz_server.settings import Settings

    async def main():
        settings = Settings(host="127.0.0.1", port=0, data_dir=[sys.argv[1]], state_dir=sys.argv[2])
        async with XVIZServer(settings) as server:
            await asyncio.wait_for(server.indexer.settled(), 60)
            def get(path):
                with urllib.request.urlopen(f"http://127.0.0.1:{server.port}{path}", timeout=30) as response:
                    return json.loads(response.read())
            page = await asyncio.to_thread(get, "/api/logs?limit=1000")
            print(json.dumps({"found": page["found"], "indexed": page["indexed"], "listed": len(page["logs"]),
                              "memory": server.indexer.db.fell_back}))

    resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[3]), int(sys.argv[3])))
    asyncio.run(main())
    """
)


@pytest.mark.slow
def test_a_full_disk_keeps_the_catalog_in_memory_and_the_server_serving(tmp_path: Path):
    write_fleet(tmp_path / "logs", 400)
    # Files of the process may not grow past 150 KB: the catalog's database soon cannot.
    result = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(tmp_path / "logs"), str(tmp_path / "state"), str(150_000)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == {"found": 400, "indexed": 400, "listed": 400, "memory": True}
    warnings = [line for line in result.stderr.splitlines() if "catalog" in line and "memory" in line]
    assert len(warnings) == 1 and "cannot be written" in warnings[0], result.stderr


async def test_a_state_directory_that_cannot_be_made_keeps_the_catalog_in_memory(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    write_fleet(tmp_path / "logs", 3)
    (tmp_path / "file").write_text("in the way")
    async with running_server(tmp_path / "logs", state_dir=tmp_path / "file" / "state") as server:
        page = await listing(server)
        assert server.indexer.db is not None and server.indexer.db.fell_back
    assert page["indexed"] == 3
    assert any("in memory" in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)


# ------------------------------------------------------------------ an object store


STORE_LOGS = 250
STORE_FRAMES = 38  # with the index and the metadata: 40 keys a log, 10 000 in all


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """moto's S3 server holding 250 logs of 38 frames each under ``fleet/``: 10 000 keys."""
    from concurrent.futures import ThreadPoolExecutor

    from devkit.s3 import moto_process

    source = write_log(tmp_path_factory.mktemp("frames"), ten_hz(STORE_FRAMES), fmt=Format.JSON)
    files = {path.name: path.read_bytes() for path in source.iterdir()}
    with moto_process() as s3:
        s3.bucket(BUCKET)
        puts = [
            (f"fleet/car-{i % 10}/seg-{i:04d}/{name}", data) for i in range(STORE_LOGS) for name, data in files.items()
        ]
        with ThreadPoolExecutor(10) as pool:  # botocore's pool of connections
            list(pool.map(lambda put: s3.put(BUCKET, *put), puts))
        yield s3, files


BUCKET = "xviz-catalog"


@pytest.mark.slow
async def test_a_store_of_ten_thousand_keys_is_listed_from_one_listing_and_two_gets_a_log(
    store: Any, monkeypatch: pytest.MonkeyPatch
):
    from devkit.s3 import proxied

    s3, files = store
    async with proxied(s3, monkeypatch) as proxy:
        async with running_server([f"s3://{BUCKET}/fleet"], catalog_store_poll=0.5) as server:
            page = await listing(server, limit=1000)
            built = list(proxy.requests)
            listings = [r for r in built if "list-type" in r]
            assert page["found"] == page["indexed"] == STORE_LOGS and len(page["logs"]) == STORE_LOGS
            assert {log["frames"] for log in page["logs"]} == {STORE_FRAMES}
            # Listings of the prefix, a page of 1000 keys a request; the index and metadata of each log once, no frame.
            assert listings and len(listings) % 10 == 0 and len(proxy.gets()) == 2 * STORE_LOGS
            assert all(r.endswith(("/0-frame.json", "/1-frame.json")) for r in proxy.gets())

            # Listed again and again: nothing read again.
            await eventually(lambda: _listed_since(proxy, len(built), 10), timeout=60)
            assert len(proxy.gets()) == 2 * STORE_LOGS

            # A log added, one changed (its metadata written again, with a description), one removed.
            for name, data in files.items():
                s3.put(BUCKET, f"fleet/car-x/new/{name}", data)
            described = metadata(start_time=100.0, end_time=103.7, description="rewritten")
            s3.put(
                BUCKET,
                "fleet/car-1/seg-0001/1-frame.json",
                encode({"type": "xviz/metadata", "data": described}, Format.JSON),
            )
            for name in files:
                s3.delete(BUCKET, f"fleet/car-2/seg-0002/{name}")
            before = len(proxy.gets())

            async def changed() -> bool:
                logs = {log["name"]: log for log in await every_page(server, limit=1000)}
                return (
                    logs.get("car-x/new", {}).get("frames") == STORE_FRAMES
                    and logs["car-1/seg-0001"].get("description") == "rewritten"
                    and "car-2/seg-0002" not in logs
                )

            await eventually(changed, timeout=60)
            assert len(proxy.gets()) - before == 2 * 2  # the new log's and the changed log's index and metadata
            page = await listing(server)
            assert page["found"] == page["indexed"] == STORE_LOGS


async def _listed_since(proxy: Any, start: int, count: int) -> bool:
    """Whether ``count`` listing requests came after the first ``start`` requests."""
    return sum("list-type" in request for request in proxy.requests[start:]) >= count
