"""Logs in an object store (issue 14): a real S3 API on loopback (moto's server), through a real proxy.

The proxy (devkit/tcpproxy.py) sits between the server and the store: it
counts GETs and how many were in flight at once, adds latency, and answers
chosen requests with a 403 or a 5xx, stalls them, or cuts their body short.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from devkit.s3 import ACCESS_KEY, SECRET_KEY, MotoS3, moto_process, proxied, store_env
from devkit.tcpproxy import Proxy
from helpers import (
    GROWTH,
    Client,
    client,
    eventually,
    run_cli,
    run_xviz_session_async,
    running_server,
    served,
    start_serving,
    stop_serving,
    ten_hz,
    write_log,
    xviz_decode,
)
from xviz_server.codec import Format

BUCKET = "xviz-logs"
ROOT = f"s3://{BUCKET}/fleet"
KITTI = "kitti/0005"
KITTI_KEY = f"s3://{BUCKET}/fleet/{KITTI}"
START = 1317042145.964  # the KITTI excerpt's start time


@pytest.fixture(scope="module")
def s3(kitti_log: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[MotoS3]:
    """moto's S3 server holding the KITTI excerpt as ``fleet/kitti/0005`` and a short JSON log as ``fleet/json/short``."""
    with moto_process() as store:
        store.bucket(BUCKET)
        store.upload(kitti_log, BUCKET, f"fleet/{KITTI}")
        short = write_log(tmp_path_factory.mktemp("short"), ten_hz(5), fmt=Format.JSON)
        store.upload(short, BUCKET, "fleet/json/short")
        store.put(BUCKET, "fleet/.hidden/1-frame.json", b"{}")
        store.put(BUCKET, "fleet/notes/readme.txt", b"not a log")
        yield store


@pytest.fixture
async def proxy(s3: MotoS3, monkeypatch: pytest.MonkeyPatch) -> Any:
    """A proxy to the store, and the AWS variables pointing at it."""
    async with proxied(s3, monkeypatch) as running:
        yield running


async def stream(server: Any, log: str, **request: Any) -> list[dict[str, Any]]:
    """Open ``log`` and stream all of it; every message after the metadata, up to the done."""
    async with client(server, f"/?log={log}") as viewer:
        assert (await viewer.recv())["type"] == "xviz/metadata"
        await viewer.send("transform_log", {"id": "all", **request})
        return await viewer.until("transform_log_done", "all")


def updates(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [m for m in messages if m["type"] == "xviz/state_update"]


def frame_gets(proxy: Proxy) -> list[str]:
    return [r for r in proxy.gets(f"/fleet/{KITTI}/") if "-frame.glb" in r and "/1-frame" not in r]


async def test_logs_under_the_prefix_are_listed_by_their_path_beside_local_ones(proxy: Proxy, tmp_path: Path):
    write_log(tmp_path / "local" / "drive", ten_hz(3))
    async with running_server([tmp_path / "local", ROOT]) as server:
        assert server.shelf.names() == ["drive", "json/short", KITTI]  # not .hidden, not notes
        short = await stream(server, "json/short")
        local = await stream(server, "drive")
    assert [u["data"]["updates"][0]["timestamp"] for u in updates(short)] == [100.0, 100.1, 100.2, 100.3, 100.4]
    assert len(updates(local)) == 3


async def test_a_name_in_a_directory_wins_over_the_same_name_in_a_store(proxy: Proxy, tmp_path: Path):
    write_log(tmp_path / "local" / "json" / "short", ten_hz(3))
    async with running_server([ROOT, tmp_path / "local"]) as server:
        assert len(updates(await stream(server, "json/short"))) == 3
    assert not proxy.gets("json/short")


@pytest.mark.slow  # moto's S3 server behind a proxy, and node
async def test_the_published_client_reads_a_log_in_the_store(proxy: Proxy, kitti_log: Path):
    """@xviz/parser gets from the store what it gets from the files: the whole log, an instant, a filtered range."""
    files = [kitti_log / f"{i}-frame.glb" for i in range(1, 27)]  # the metadata first, as a client reads them
    originals = {line["parsed"]["timestamp"]: line["parsed"] for line in xviz_decode(files)[1:]}
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "0", "from_start": -1}},
        {"wait": "done", "id": "0"},
        {
            "send": {
                "type": "xviz/transform_point_in_time",
                "data": {"id": "p", "query_timestamp": {"$timestamp": 1.05}},
            }
        },
        {"wait": "state_updates", "count": 26},
        {"close": True},
    ]
    async with running_server([ROOT]) as server:
        url = f"ws://127.0.0.1:{server.port}/?log={KITTI}&worker=true&profile=default&message_format=BINARY"
        result = await run_xviz_session_async(url, script, timeout=180)
    assert result.ok, result.stderr
    assert result.summary is not None and result.summary["errors"] == []
    assert result.messages[0]["parsed"]["start_time"] == START
    received = result.of_type("xviz/state_update")
    assert [u["parsed"] for u in received[:25]] == [originals[t] for t in sorted(originals)]
    frame_time = max(t for t in originals if t <= START + 1.05)
    assert received[25]["parsed"]["streams"] == originals[frame_time]["streams"]


async def test_a_log_uploaded_while_serving_is_found_on_first_request(proxy: Proxy, s3: MotoS3, tmp_path: Path):
    async with running_server([ROOT, f"s3://{BUCKET}/late"]) as server:
        assert "new/drive" not in server.shelf.names()
        s3.upload(write_log(tmp_path / "late", ten_hz(4)), BUCKET, "late/new/drive")
        listings = len(proxy.requests)
        assert len(updates(await stream(server, "new/drive"))) == 4
        assert any("prefix=late%2Fnew%2Fdrive%2F" in r for r in proxy.requests[listings:])
        async with client(server, "/?log=new/nothing") as viewer:
            error = await viewer.recv()
        assert error["type"] == "xviz/error" and "new/nothing" in error["data"]["message"]


async def test_two_sessions_cause_one_get_per_frame_and_the_index_is_read_once(proxy: Proxy):
    async with running_server([ROOT]) as server:
        first, second = await asyncio.gather(stream(server, KITTI), stream(server, KITTI))
        again = await stream(server, KITTI)
    assert len(updates(first)) == len(updates(second)) == len(updates(again)) == 25
    gets = frame_gets(proxy)
    assert sorted(gets) == sorted(set(gets)) and len(gets) == 25
    # Once for the catalog's facts, once for the log the sessions share.
    assert len(proxy.gets(f"{KITTI}/0-frame.json")) == 2
    assert len(proxy.gets(f"{KITTI}/1-frame.glb")) == 2


async def test_a_point_in_time_query_is_one_get(proxy: Proxy):
    async with running_server([ROOT]) as server:
        async with client(server, f"/?log={KITTI}") as viewer:
            await viewer.recv()
            before = len(frame_gets(proxy))
            await viewer.send("transform_point_in_time", {"id": "p", "query_timestamp": START + 1.05})
            answer = await viewer.recv()
    assert answer["type"] == "xviz/state_update"
    assert len(frame_gets(proxy)) - before == 1


async def test_a_stream_keeps_several_gets_in_flight_within_its_count(s3: MotoS3, monkeypatch: pytest.MonkeyPatch):
    async with proxied(s3, monkeypatch, delay=0.05) as slow:
        async with running_server([ROOT], store_read_ahead=6) as server:
            await server.shelf.open(KITTI)
            slow.most_in_flight = 0
            assert len(updates(await stream(server, KITTI))) == 25
    assert 3 <= slow.most_in_flight <= 6


async def test_a_stream_keeps_its_gets_within_its_bytes(s3: MotoS3, monkeypatch: pytest.MonkeyPatch, kitti_log: Path):
    """With room for fewer bytes than one frame holds, each frame loads alone."""
    smallest = min((kitti_log / f"{i}-frame.glb").stat().st_size for i in range(2, 27))
    async with proxied(s3, monkeypatch, delay=0.05) as slow:
        async with running_server([ROOT], store_read_ahead=6, store_read_ahead_mb=smallest / 2 / (1 << 20)) as server:
            await server.shelf.open(KITTI)
            slow.most_in_flight = 0
            assert len(updates(await stream(server, KITTI))) == 25
    assert slow.most_in_flight == 1


FAULTS = {  # what the proxy does to every GET of one frame, what the error says, GETs of it, the server's time limit
    "403": ({"status": 403}, "access denied (403)", 1, 10),
    "404": ({"status": 404}, "no such object (404)", 1, 10),
    "503 each time": ({"status": 503}, "the store answered 503 after 2 retries", 3, 10),
    "body cut each time": ({"cut_after": 1000}, "the connection failed or was cut short", 3, 10),
    "stalled": ({"stall": True}, "timed out (no whole answer within 2 s) after 2 retries", 3, 2),
}


@pytest.mark.parametrize(
    "fault",
    [  # a stalled store is waited for three times (2 s each): the slow tier
        pytest.param(fault, id=name, marks=[pytest.mark.slow] if name == "stalled" else [])
        for name, fault in FAULTS.items()
    ],
)
async def test_a_frame_the_store_fails_is_an_error_naming_log_frame_and_key(
    proxy: Proxy, fault: tuple[dict[str, Any], str, int, float]
):
    what, cause, tries, timeout = fault
    async with running_server([ROOT], store_retries=2, store_timeout=timeout) as server:
        await server.shelf.open(KITTI)
        injected = proxy.fault(f"{KITTI}/5-frame.glb", **what)
        messages = await stream(server, KITTI)
    errors = [m for m in messages if m["type"] == "xviz/error"]
    assert len(errors) == 1 and len(updates(messages)) == 24  # the rest of the log is served
    message = errors[0]["data"]["message"]
    assert f"frame 3 (5-frame.glb) of log {KITTI!r}" in message and f"{KITTI_KEY}/5-frame.glb" in message, message
    assert cause in message, message
    assert injected.hits == tries, (injected.hits, message)


@pytest.mark.parametrize(
    "what", [{"status": 503}, {"status": 500}, {"cut_after": 1000}], ids=["503", "500", "body cut"]
)
async def test_a_failure_that_passes_is_retried(proxy: Proxy, what: dict[str, Any]):
    async with running_server([ROOT], store_retries=2) as server:
        await server.shelf.open(KITTI)
        injected = proxy.fault(f"{KITTI}/5-frame.glb", times=2, **what)
        messages = await stream(server, KITTI)
    assert [m["type"] for m in messages].count("xviz/error") == 0 and len(updates(messages)) == 25
    assert injected.hits == 2 and len(proxy.gets(f"{KITTI}/5-frame.glb")) == 3


async def test_an_object_deleted_from_the_store_is_an_error_and_the_rest_is_served(
    proxy: Proxy, s3: MotoS3, tmp_path: Path
):
    s3.upload(write_log(tmp_path / "gone", ten_hz(4), fmt=Format.JSON), BUCKET, "gone/drive")
    async with running_server([f"s3://{BUCKET}/gone"]) as server:
        await server.shelf.open("drive")
        s3.delete(BUCKET, "gone/drive/3-frame.json")
        messages = await stream(server, "drive")
    errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
    assert len(errors) == 1 and f"s3://{BUCKET}/gone/drive/3-frame.json: no such object (404)" in errors[0]
    assert len(updates(messages)) == 3


async def test_a_store_that_refuses_the_listing_serves_nothing_and_says_so(
    proxy: Proxy, caplog: pytest.LogCaptureFixture
):
    proxy.fault("list-type", status=403)
    async with running_server([ROOT]) as server:
        assert server.shelf.names() == []
        async with client(server, f"/?log={KITTI}") as viewer:
            error = await viewer.recv()
    assert error["type"] == "xviz/error" and KITTI in error["data"]["message"]
    assert f"cannot list {ROOT}: {ROOT}/: access denied (403)" in caplog.text


async def test_credentials_and_endpoint_come_from_the_shared_aws_files(
    proxy: Proxy, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    for name in store_env(""):
        monkeypatch.delenv(name)
    (tmp_path / "credentials").write_text(
        "[fleet]\naws_access_key_id = AKIAFROMTHEFILE00001\naws_secret_access_key = x\n"
    )
    (tmp_path / "config").write_text(f"[profile fleet]\nregion = eu-west-1\nendpoint_url = {proxy.url}\n")
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "credentials"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "config"))
    monkeypatch.setenv("AWS_PROFILE", "fleet")
    async with running_server([ROOT]) as server:
        assert KITTI in server.shelf.names()
    assert b"Credential=AKIAFROMTHEFILE00001/" in proxy.heads[0] and b"/eu-west-1/s3/" in proxy.heads[0]


@pytest.mark.slow  # six xviz-server processes, one of them serving
async def test_secrets_never_show_in_logs_errors_or_config(proxy: Proxy):
    env = {**store_env(proxy.url), "XVIZ_STORE_RETRIES": "1", "XVIZ_STORE_TIMEOUT": "2"}
    shown = run_cli("config", "--data-dir", ROOT, "--data-dir", "/srv/logs", **env)
    assert shown.returncode == 0 and f'data_dir = ["{ROOT}", "/srv/logs"]' in shown.stdout
    proxy.fault("/3-frame.glb", status=403)
    proxy.fault("/4-frame.glb", cut_after=10)
    proxy.fault("/5-frame.glb", stall=True)
    process, port, lines = await start_serving("--data-dir", ROOT, **env)
    try:
        from websockets.asyncio.client import connect

        async with connect(f"ws://127.0.0.1:{port}/?log={KITTI}", max_size=None) as websocket:
            await websocket.recv()
            await websocket.send(json.dumps({"type": "xviz/transform_log", "data": {"id": "a"}}))
            received = await Client(websocket).until("transform_log_done", "a")
    finally:
        output = await stop_serving(process, lines)
    errors = [json.dumps(m["data"]) for m in received if m["type"] == "xviz/error"]
    assert len(errors) == 3 and "access denied" in output and "timed out" in output
    for text in (shown.stdout, shown.stderr, output, *errors):
        assert SECRET_KEY not in text
    assert ACCESS_KEY not in output


@pytest.mark.slow
def test_a_bucket_url_with_a_credential_in_it_is_refused_without_showing_it():
    result = run_cli("serve", "--data-dir", f"s3://AKIA:{SECRET_KEY}@bucket/logs", "--port", "0")
    assert result.returncode == 2 and "not an S3 bucket name" in result.stderr
    assert SECRET_KEY not in result.stderr


def test_data_dirs_come_from_flags_or_one_or_a_json_list_in_the_environment(tmp_path: Path):
    assert 'data_dir = ["/srv/a"]' in run_cli("config", XVIZ_DATA_DIR="/srv/a").stdout
    listed = run_cli("config", XVIZ_DATA_DIR=f'["/srv/a", "{ROOT}"]').stdout
    assert f'data_dir = ["/srv/a", "{ROOT}"]' in listed
    missing = run_cli("serve", "--data-dir", ROOT, "--data-dir", str(tmp_path / "nothing"), "--port", "0")
    assert missing.returncode == 2 and f"--data-dir {tmp_path / 'nothing'} is not a directory" in missing.stderr


async def test_the_catalog_lists_logs_in_the_store_and_forgets_removed_ones(proxy: Proxy, s3: MotoS3, tmp_path: Path):
    import urllib.request

    keys = s3.upload(write_log(tmp_path / "brief", ten_hz(2)), BUCKET, "brief/drive")

    def catalog(server: Any) -> dict[str, Any]:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/") as response:
            return {log["name"]: log for log in json.loads(response.read())["logs"]}

    async with running_server([ROOT, f"s3://{BUCKET}/brief"], catalog_store_poll=0.2) as server:
        listed = await asyncio.to_thread(catalog, server)
        assert listed["drive"]["frames"] == 2 and listed[KITTI]["frames"] == 25
        assert listed[KITTI]["start_time"] == START and "/lidar/points" in listed[KITTI]["streams"]
        for key in keys:
            s3.delete(BUCKET, key)

        async def forgotten() -> bool:  # at the next listing of the store
            return "drive" not in await asyncio.to_thread(catalog, server)

        await eventually(forgotten)
        async with client(server, "/?log=drive") as viewer:
            assert (await viewer.recv())["type"] == "xviz/error"


async def test_a_store_that_went_away_ends_the_stream_with_errors_and_the_server_serves_on(
    proxy: Proxy, tmp_path: Path
):
    write_log(tmp_path / "local" / "drive", ten_hz(3))
    async with running_server([ROOT, tmp_path / "local"], store_retries=1) as server:
        await server.shelf.open(KITTI)
        await proxy.close()  # nothing listens there any more
        messages = await stream(server, KITTI)
        local = await stream(server, "drive")
    errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
    assert len(errors) == 25 and not updates(messages)
    assert all("the connection failed or was cut short after 1 retry" in error for error in errors), errors[0]
    assert len(updates(local)) == 3


@pytest.mark.slow
async def test_an_answer_that_claims_a_terabyte_and_never_ends_fails_that_frame_alone(proxy: Proxy):
    """A store that answers a frame's GET with Content-Length 1 TiB and zeros without end: obstore set aside that
    much for a whole-object GET and the server aborted; the listed range is read, and no more."""
    proxy.fault("/3-frame.glb", endless=True)
    env = {**store_env(proxy.url), "XVIZ_STORE_RETRIES": "0", "XVIZ_STORE_TIMEOUT": "2"}
    async with served(ROOT, **env) as server:
        await server.session("json/short")
        before = server.rss()
        played, health = await asyncio.gather(server.session(KITTI), server.get("/healthz"))
        errors = [m["data"]["message"] for m in played if m["type"] == "xviz/error"]
        # The listed size is read, and no more: zeros, which are not a frame.
        assert len(errors) == 1 and "(3-frame.glb) of log 'kitti/0005' is corrupt: not a GLB" in errors[0], errors
        assert len(updates(played)) > 1 and health == (200, "ok\n")
        assert await server.get("/healthz") == (200, "ok\n") and server.process.returncode is None
        peaks = server.peaks()
        assert max(peaks[pid] - rss for pid, rss in before.items() if pid in peaks) < GROWTH
