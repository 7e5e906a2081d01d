"""Each log as a seekable MCAP file over HTTP ranges (``/api/logs/NAME/file.mcap``), read by the published MCAP readers."""

from __future__ import annotations

import asyncio
import email.utils
import io
import json
import logging
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from helpers import INTEROP, eventually, http_get, metric, running_server, update, write_log
from xviz_server.foxglove.translate import plan
from xviz_server.ranges import Representation, decide

FILE = "/api/logs/{}/file.mcap"
REPO = Path(__file__).parent.parent
CHROMIUM = Path("/usr/bin/chromium")


# ---------------------------------------------------------------- the answers, without I/O

ETAG = '"abc"'
WHEN = 1_700_000_000.0
DATE = email.utils.formatdate(WHEN, usegmt=True)
SIZE = 1000


@pytest.mark.parametrize(
    "headers, status, span",
    [
        ({}, 200, (0, 1000)),
        ({"Range": "bytes=0-99"}, 206, (0, 100)),
        ({"range": "bytes=990-"}, 206, (990, 10)),
        ({"Range": "bytes=-10"}, 206, (990, 10)),
        ({"Range": "bytes=-5000"}, 206, (0, 1000)),
        ({"Range": "bytes=900-5000"}, 206, (900, 100)),
        ({"Range": "bytes=1000-"}, 416, None),
        ({"Range": "bytes=5-3"}, 416, None),
        ({"Range": "bytes=-0"}, 416, None),
        ({"Range": "bytes=x-3"}, 416, None),
        ({"Range": "bytes=-"}, 416, None),
        ({"Range": "bytes=1_000-"}, 416, None),
        ({"Range": "bytes=99999999999999999999-"}, 416, None),
        ({"Range": "items=0-5"}, 200, (0, 1000)),  # another unit: ignored
        ({"Range": "bytes=0-1,5-6"}, 200, (0, 1000)),  # several ranges: not served, the whole file is
        ({"Range": "bytes=0-9", "If-Range": ETAG}, 206, (0, 10)),
        ({"Range": "bytes=0-9", "If-Range": '"old"'}, 200, (0, 1000)),
        ({"Range": "bytes=0-9", "If-Range": DATE}, 206, (0, 10)),
        ({"Range": "bytes=0-9", "If-Range": email.utils.formatdate(WHEN - 60, usegmt=True)}, 200, (0, 1000)),
        ({"If-None-Match": ETAG}, 304, None),
        ({"If-None-Match": f'"x", W/{ETAG}'}, 304, None),
        ({"If-None-Match": "*"}, 304, None),
        ({"If-None-Match": '"old"', "If-Modified-Since": DATE}, 200, (0, 1000)),  # If-None-Match decides
        ({"If-Modified-Since": DATE}, 304, None),
        ({"If-Modified-Since": email.utils.formatdate(WHEN - 60, usegmt=True)}, 200, (0, 1000)),
        ({"If-Modified-Since": "yesterday"}, 200, (0, 1000)),
        ({"If-Match": ETAG, "Range": "bytes=1-1"}, 206, (1, 1)),
        ({"If-Match": f"W/{ETAG}"}, 412, None),  # weak tags never match strongly
        ({"If-Match": '"old"', "Range": "bytes=1-1"}, 412, None),
    ],
)
def test_an_answer_follows_the_ranges_and_conditions_of_the_request(
    headers: dict[str, str], status: int, span: Any
) -> None:
    answer = decide(headers.items(), Representation(SIZE, ETAG, WHEN))
    assert answer.status == status
    assert (answer.headers["Accept-Ranges"], answer.headers["ETag"], answer.headers["Last-Modified"]) == (
        "bytes",
        ETAG,
        DATE,
    )
    if span is not None:
        assert (answer.offset, answer.length) == span
    if status == 206:
        assert answer.headers["Content-Range"] == f"bytes {span[0]}-{span[0] + span[1] - 1}/{SIZE}"
    if status == 416:
        assert answer.headers["Content-Range"] == f"bytes */{SIZE}"


# ---------------------------------------------------------------- over HTTP


class RangeFile(io.RawIOBase):
    """A file read over HTTP by byte ranges, ``block`` bytes at least per request (as the apps read ahead).

    ``received`` counts the body bytes the server sent, ``requests`` the GETs.
    """

    def __init__(self, port: int, path: str, block: int = 64 * 1024) -> None:
        self._port, self._path, self._block = port, path, block
        status, headers, _ = http_get(port, path, "HEAD")
        assert status == 200 and headers["Accept-Ranges"] == "bytes", (status, headers)
        self.size = int(headers["Content-Length"])
        self.etag = headers["ETag"]
        self._position = 0
        self._buffer, self._buffered_at = b"", 0
        self.received = self.requests = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        self._position = {io.SEEK_SET: 0, io.SEEK_CUR: self._position, io.SEEK_END: self.size}[whence] + offset
        return self._position

    def readinto(self, target: Any) -> int:
        wanted = min(len(target), self.size - self._position)
        if wanted <= 0:
            return 0
        start = self._position - self._buffered_at
        if start < 0 or start + wanted > len(self._buffer):
            last = min(self.size, self._position + max(wanted, self._block)) - 1
            status, headers, body = http_get(
                self._port, self._path, Range=f"bytes={self._position}-{last}", **{"If-Range": self.etag}
            )
            assert status == 206 and headers["Content-Range"] == f"bytes {self._position}-{last}/{self.size}", (
                status,
                headers,
            )
            self.requests += 1
            self.received += len(body)
            self._buffer, self._buffered_at, start = body, self._position, 0
        target[:wanted] = self._buffer[start : start + wanted]
        self._position += wanted
        return wanted


def middle_seek(file: RangeFile) -> tuple[Any, int, list[tuple[str, int, bytes]]]:
    """Read the summary, then the messages of the frame at the middle of the log; the summary, that time and the
    messages (topic, log time, payload)."""
    reader = make_reader(io.BufferedReader(file, buffer_size=1))
    summary = reader.get_summary()
    assert summary is not None and summary.chunk_indexes
    times = sorted({chunk.message_start_time for chunk in summary.chunk_indexes})
    middle = times[len(times) // 2]
    messages = [
        (channel.topic, message.log_time, message.data)
        for _, channel, message in reader.iter_messages(starting_at=middle, ending_at=middle)
    ]
    return summary, middle, messages


async def sent_bytes(server: Any) -> float:
    """The bytes of logs' files the server has sent, by its ``/metrics``."""
    return metric((await asyncio.to_thread(http_get, server.port, "/metrics"))[2], "xviz_file_bytes_sent_total")


def all_messages(data: bytes) -> list[tuple[str, int, bytes]]:
    reader = make_reader(io.BytesIO(data))
    return [(channel.topic, message.log_time, message.data) for _, channel, message in reader.iter_messages()]


def mcap_ranges(url: str, start: int, end: int, topics: list[str] | None = None) -> dict[str, Any]:
    """What the published TypeScript reader (``@mcap/core``, ``interop/mcap-ranges.js``) read of ``url`` by ranges
    (the messages of ``topics``, else all)."""
    node = shutil.which("node")
    assert node, "node is required for the interop tests"
    assert (INTEROP / "node_modules" / "@mcap" / "core").is_dir(), "run `npm ci --prefix tests/interop`"
    done = subprocess.run(
        [node, str(INTEROP / "mcap-ranges.js"), url, str(start), str(end), *([",".join(topics)] if topics else [])],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    result: dict[str, Any] = json.loads(done.stdout)
    return result


@pytest.mark.slow
async def test_a_seek_to_the_middle_reads_the_summary_and_a_few_chunks_with_the_published_readers(
    kitti_root: Path,
) -> None:
    async with running_server(kitti_root) as server:
        log = await server.shelf.open("kitti")
        topics = sorted(channel.topic for channel in plan(log.metadata, log.originals).channels)
        status, headers, whole = await asyncio.to_thread(http_get, server.port, FILE.format("kitti"))
        assert status == 200 and int(headers["Content-Length"]) == len(whole)
        file = await asyncio.to_thread(RangeFile, server.port, FILE.format("kitti"))
        before = await sent_bytes(server)
        summary, middle, messages = await asyncio.to_thread(middle_seek, file)
        sent = await sent_bytes(server) - before
        node = await asyncio.to_thread(
            mcap_ranges, f"http://127.0.0.1:{server.port}{FILE.format('kitti')}", middle, middle
        )
    # The file: the Foxglove face's channels, an index, every frame of the log.
    assert sorted(channel.topic for channel in summary.channels.values()) == topics
    expected = [message for message in all_messages(whole) if message[1] == middle]
    assert {topic for topic, _, _ in expected} >= {"/lidar/points", "/camera/image_00"}
    assert sorted(messages) == sorted(expected)
    assert len({time for _, time, _ in all_messages(whole)}) == len(log.index)
    # A seek costs the summary and the chunks of that time, not the file.
    chunk_bytes = [chunk.chunk_length + chunk.message_index_length for chunk in summary.chunk_indexes]
    summary_bytes = len(whole) - summary.chunk_indexes[-1].chunk_start_offset - chunk_bytes[-1]
    assert file.received <= summary_bytes + 3 * max(chunk_bytes) + 2 * 64 * 1024, (
        file.received,
        summary_bytes,
        chunk_bytes,
    )
    assert file.received < len(whole) / 5 and sent == file.received  # what the server sent, all received
    # The TypeScript reader, the apps' own, reads the same messages by ranges, as little.
    assert "error" not in node, node["error"]
    assert (node["size"], node["chunks"], sorted(node["channels"])) == (len(whole), len(summary.chunk_indexes), topics)
    assert sorted((m["topic"], int(m["logTime"]), m["bytes"]) for m in node["messages"]) == sorted(
        (topic, time, len(data)) for topic, time, data in expected
    )
    assert node["bytes"] <= summary_bytes + 3 * max(chunk_bytes), (node["bytes"], summary_bytes, chunk_bytes)


def read_topic(file: RangeFile, topic: str) -> tuple[Any, list[tuple[str, int, bytes]], int]:
    """Read the summary, then the messages of ``topic`` over the whole log: the summary, the messages (topic, log
    time, payload) and the bytes received for them (after the summary's)."""
    reader = make_reader(io.BufferedReader(file, buffer_size=1))
    summary = reader.get_summary()
    before = file.received
    messages = [
        (channel.topic, message.log_time, message.data) for _, channel, message in reader.iter_messages(topics=[topic])
    ]
    return summary, messages, file.received - before


@pytest.mark.slow
async def test_a_light_channel_is_read_over_the_whole_log_without_the_heavy_ones(kitti_root: Path) -> None:
    """The file's chunks are cut by weight (each light channel's messages in chunks of their own): the published
    readers read a pose over the whole log (as Lichtblick preloads poses, transforms and plots) for a few kilobytes,
    and every message of the file in log time order."""
    path = FILE.format("kitti")
    async with running_server(kitti_root) as server:
        status, _, whole = await asyncio.to_thread(http_get, server.port, path)
        assert status == 200
        every = all_messages(whole)
        start, end = min(time for _, time, _ in every), max(time for _, time, _ in every)
        file = await asyncio.to_thread(RangeFile, server.port, path, 1024)
        summary, poses, pose_bytes = await asyncio.to_thread(read_topic, file, "/vehicle_pose")
        url = f"http://127.0.0.1:{server.port}{path}"
        node = await asyncio.to_thread(mcap_ranges, url, start, end, ["/vehicle_pose"])
        everything = await asyncio.to_thread(mcap_ranges, url, start, end)
    assert poses == [message for message in every if message[0] == "/vehicle_pose"] and len(poses) == 25
    # Python's reader: after the summary, the pose's chunk and its message index, read by ranges of 1 KiB.
    assert pose_bytes <= 8 * 1024, pose_bytes
    # The TypeScript reader, the apps' own: the same messages, for the summary and a few kilobytes.
    summary_bytes = len(whole) - summary.chunk_indexes[-1].chunk_start_offset - summary.chunk_indexes[-1].chunk_length
    assert [(m["topic"], int(m["logTime"]), m["bytes"]) for m in node["messages"]] == [
        (topic, time, len(data)) for topic, time, data in poses
    ]
    assert node["bytes"] <= summary_bytes + 8 * 1024, (node["bytes"], summary_bytes)
    # Read whole, each reader gives every message in log time order.
    assert [time for _, time, _ in every] == sorted(time for _, time, _ in every)
    assert [(m["topic"], int(m["logTime"]), m["bytes"]) for m in everything["messages"]] == [
        (topic, time, len(data)) for topic, time, data in every
    ]


def random_updates(count: int, points: int = 20_000) -> list[dict[str, Any]]:
    """Ten frames a second, each with a cloud of random points (that compresses as little as a real one)."""
    generator = np.random.default_rng(7)
    updates = []
    for i in range(count):
        data = update(round(100 + i / 10, 3))
        data["updates"][0]["primitives"]["/points"]["points"][0]["points"] = generator.random(
            (points, 3), dtype=np.float32
        )
        updates.append(data)
    return updates


async def test_the_file_is_answered_with_ranges_and_conditions_and_readable_by_other_origins(tmp_path: Path) -> None:
    write_log(tmp_path / "logs" / "drive", random_updates(5))
    async with running_server(tmp_path / "logs") as server:
        path = FILE.format("drive")
        status, headers, whole = await asyncio.to_thread(http_get, server.port, path, Origin="http://app.example")
        assert status == 200 and int(headers["Content-Length"]) == len(whole) and whole.startswith(b"\x89MCAP0\r\n")
        assert (headers["Accept-Ranges"], headers["Access-Control-Allow-Origin"]) == ("bytes", "*")
        exposed = {name.strip().lower() for name in headers["Access-Control-Expose-Headers"].split(",")}
        assert exposed >= {"content-range", "accept-ranges", "etag", "content-length"}
        etag, modified = headers["ETag"], headers["Last-Modified"]
        assert all_messages(whole)  # a whole MCAP file

        async def get(method: str = "GET", **asked: str) -> tuple[int, dict[str, str], bytes]:
            return await asyncio.to_thread(http_get, server.port, path, method, **asked)

        status, headers, body = await get("HEAD")
        assert (status, headers["Content-Length"], headers["ETag"], body) == (200, str(len(whole)), etag, b"")
        status, headers, body = await get(Range="bytes=100-199")
        assert (status, headers["Content-Range"], headers["Content-Length"], body) == (
            206,
            f"bytes 100-199/{len(whole)}",
            "100",
            whole[100:200],
        )
        assert headers["Access-Control-Allow-Origin"] == "*"
        status, headers, body = await get(Range="bytes=-16")
        assert (status, body) == (206, whole[-16:])
        status, headers, _ = await get(Range=f"bytes={len(whole)}-")
        assert (status, headers["Content-Range"]) == (416, f"bytes */{len(whole)}")
        status, _, body = await get(Range="bytes=0-9", **{"If-Range": '"another"'})
        assert (status, body) == (200, whole)
        status, _, body = await get(Range="bytes=0-9", **{"If-Range": etag})
        assert (status, body) == (206, whole[:10])
        status, headers, body = await get(**{"If-None-Match": etag})
        assert (status, body, headers["ETag"]) == (304, b"", etag)
        status, _, _ = await get(**{"If-Modified-Since": modified})
        assert status == 304
        status, _, _ = await get(**{"If-Match": '"another"'})
        assert status == 412
        # A log that is not there, a name that is not allowed.
        status, _, body = await asyncio.to_thread(http_get, server.port, FILE.format("nowhere"))
        assert status == 404 and b"nowhere" in body
        status, _, body = await asyncio.to_thread(http_get, server.port, FILE.format("..%2Fetc"))
        assert status == 404 and b"not allowed" in body
        assert server._open() == 0


@pytest.mark.skipif(
    not (REPO / "viewer" / "node_modules" / "playwright-core").is_dir()
    or not CHROMIUM.is_file()
    or shutil.which("node") is None,
    reason="needs playwright-core and chromium: run scripts/test.sh",
)
@pytest.mark.slow  # a browser
async def test_a_page_of_another_origin_reads_the_file_by_ranges_in_chromium(tmp_path: Path) -> None:
    write_log(tmp_path / "logs" / "drive", random_updates(5))
    async with running_server(tmp_path / "logs") as server:
        url = f"http://127.0.0.1:{server.port}{FILE.format('drive')}"
        size = int((await asyncio.to_thread(http_get, server.port, FILE.format("drive"), "HEAD"))[1]["Content-Length"])
        options = {"url": url, "ranges": [[0, 99], [size - 10, size + 100]]}
        done = await asyncio.to_thread(
            subprocess.run,
            ["node", str(REPO / "tests" / "cross-origin.mjs"), json.dumps(options)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        report = json.loads(done.stdout)
    # What the apps' remote-file reader does: a GET cut short for the size, the ETag and Accept-Ranges, then ranges.
    assert report["open"] == {
        "status": 200,
        "acceptRanges": "bytes",
        "contentLength": str(size),
        "etag": report["open"]["etag"],
    }
    assert report["open"]["etag"].startswith('"')
    assert report["ranges"] == [
        {"status": 206, "contentRange": f"bytes 0-99/{size}", "bytes": 100},
        {"status": 206, "contentRange": f"bytes {size - 10}-{size - 1}/{size}", "bytes": 10},
    ]
    # A header beyond Range makes the browser ask first (OPTIONS): answered, the ranged GET follows.
    assert report["ifRange"] == {"status": 206, "contentRange": f"bytes 0-99/{size}", "bytes": 100}


def options(port: int, path: str, *lines: str) -> tuple[str, dict[str, str]]:
    """An ``OPTIONS`` request sent on a socket as a browser's preflight is: its status line and headers (names in
    lower case)."""
    import socket

    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sock.sendall("\r\n".join([f"OPTIONS {path} HTTP/1.1", "Host: 127.0.0.1", *lines, "", ""]).encode())
        data = b""
        while b"\r\n\r\n" not in data and (chunk := sock.recv(65536)):
            data += chunk
    status, *fields = data.partition(b"\r\n\r\n")[0].decode().split("\r\n")
    return status, {name.lower(): value for name, _, value in (field.partition(": ") for field in fields)}


async def test_a_preflight_for_a_logs_file_is_answered_with_cors_and_nowhere_else(tmp_path: Path) -> None:
    write_log(tmp_path / "logs" / "drive", random_updates(5))
    asking = (
        "Origin: http://app.example",
        "Access-Control-Request-Method: GET",
        "Access-Control-Request-Headers: if-none-match,range",
    )
    file = FILE.format("drive")
    async with running_server(tmp_path / "logs") as server:
        answers = {
            path: await asyncio.to_thread(options, server.port, path, *asking)
            for path in (file, "/", "/api/logs", "/api/logs/drive/export", "/nowhere")
        }
        handshake = await asyncio.to_thread(
            options,
            server.port,
            file,
            *asking,
            "Upgrade: websocket",
            "Connection: Upgrade",
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
            "Sec-WebSocket-Version: 13",
        )
    async with running_server(tmp_path / "logs", allowed_origins=["http://app.example"]) as server:
        allowed = await asyncio.to_thread(options, server.port, file, *asking)
        other = await asyncio.to_thread(options, server.port, file, "Origin: http://other.example", *asking[1:])
    status, headers = answers.pop(file)
    assert status == "HTTP/1.1 204 No Content" and "content-length" not in headers
    assert (headers["allow"], headers["access-control-allow-origin"], headers["access-control-allow-methods"]) == (
        "GET, HEAD",
        "*",
        "GET, HEAD",
    )
    assert {"Range", "If-Range", "If-None-Match", "If-Match", "If-Modified-Since"} == set(
        headers["access-control-allow-headers"].split(", ")
    )
    assert headers["access-control-max-age"] == "7200" and headers["x-content-type-options"] == "nosniff"
    assert headers["access-control-expose-headers"] == (
        "Accept-Ranges, Content-Length, Content-Range, ETag, Last-Modified"
    )  # as the file's own answers
    for status, headers in [*answers.values(), handshake]:  # elsewhere: no CORS; and never a WebSocket session
        assert status == "HTTP/1.1 204 No Content" and headers["allow"] == "GET, HEAD"
    assert not [name for _, headers in answers.values() for name in headers if name.startswith("access-control")]
    assert allowed[1]["access-control-allow-origin"] == "http://app.example" and allowed[1]["vary"] == "Origin"
    assert "access-control-allow-origin" not in other[1] and "access-control-allow-methods" not in other[1]


async def test_a_whole_file_get_cut_short_by_the_client_stops_the_sending(tmp_path: Path) -> None:
    write_log(tmp_path / "logs" / "drive", random_updates(40))
    async with running_server(tmp_path / "logs") as server:
        size = int((await asyncio.to_thread(http_get, server.port, FILE.format("drive"), "HEAD"))[1]["Content-Length"])
        # The apps' remote-file reader: a GET of the whole file, dropped once its head is in.
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(f"GET {FILE.format('drive')} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 10)
        assert head.startswith(b"HTTP/1.1 200 OK") and f"Content-Length: {size}".encode() in head
        writer.transport.abort()
        await eventually(lambda: server._open() == 0)
        assert await sent_bytes(server) < size / 2


async def test_origins_outside_allowed_origins_are_not_let_read_the_file(tmp_path: Path) -> None:
    write_log(tmp_path / "logs" / "drive", random_updates(2, points=10))
    async with running_server(tmp_path / "logs", allowed_origins=["http://app.example"]) as server:
        path = FILE.format("drive")
        _, headers, _ = await asyncio.to_thread(http_get, server.port, path, "HEAD", Origin="http://app.example")
        assert (headers["Access-Control-Allow-Origin"], headers["Vary"]) == ("http://app.example", "Origin")
        _, headers, _ = await asyncio.to_thread(http_get, server.port, path, "HEAD", Origin="http://elsewhere.example")
        assert "Access-Control-Allow-Origin" not in headers and headers["Vary"] == "Origin"


async def test_the_file_is_made_once_per_version_kept_across_restarts_and_made_again_when_the_log_changes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="xviz_server.foxglove.seekable")
    logs, state = tmp_path / "logs", tmp_path / "state"
    write_log(logs / "drive", random_updates(20))
    path = FILE.format("drive")
    async with running_server(logs, state_dir=state) as server:
        # Requests that come together wait for one build.
        answers = await asyncio.gather(*(asyncio.to_thread(http_get, server.port, path, "HEAD") for _ in range(4)))
        assert {status for status, _, _ in answers} == {200}
        assert len({headers["ETag"] for _, headers, _ in answers}) == 1
        etag = answers[0][1]["ETag"]
        made = [record for record in caplog.records if record.getMessage().startswith("made the file of log 'drive'")]
        assert len(made) == 1
        (kept,) = (state / "files").iterdir()  # the file only: no temporary file left
        assert kept.suffix == ".mcap" and etag.strip('"') in kept.name
        status, _, whole = await asyncio.to_thread(http_get, server.port, path)
        assert status == 200 and len(whole) == kept.stat().st_size
    caplog.clear()
    async with running_server(logs, state_dir=state) as server:
        status, headers, body = await asyncio.to_thread(http_get, server.port, path, Range="bytes=0-7")
        assert (status, headers["ETag"], body) == (206, etag, whole[:8])
        assert not [record for record in caplog.records if record.getMessage().startswith("made the file")]
        # The log changes (a frame more, its index written again): a new file, the old one removed.
        write_log(logs / "drive", random_updates(21))
        status, headers, body = await asyncio.to_thread(
            http_get, server.port, path, Range="bytes=0-7", **{"If-Range": etag}
        )
        assert status == 200 and headers["ETag"] != etag  # the range was of the old file: the whole new one is answered
        assert len({time for _, time, _ in all_messages(body)}) == 21
        (kept,) = (state / "files").iterdir()
        assert headers["ETag"].strip('"') in kept.name


async def test_an_unreadable_frame_fails_the_file_and_the_next_request_tries_again(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    write_log(logs / "drive", random_updates(4, points=10))
    frame = sorted((logs / "drive").glob("*-frame.glb"))[2]
    good = frame.read_bytes()
    frame.write_bytes(b"not a frame")
    async with running_server(logs, state_dir=tmp_path / "state") as server:
        status, _, body = await asyncio.to_thread(http_get, server.port, FILE.format("drive"))
        assert status == 422 and b"frame" in body, body
        assert not list((tmp_path / "state" / "files").iterdir())  # the temporary file is removed
        frame.write_bytes(good)
        status, _, body = await asyncio.to_thread(http_get, server.port, FILE.format("drive"))
        assert status == 200 and len({time for _, time, _ in all_messages(body)}) == 4


async def test_a_request_waits_for_the_file_past_the_handshake_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import xviz_server.framing
    import xviz_server.server

    # Making either log's file (48 MB of points) takes far longer than 0.05 s, whatever the machine, and about
    # 1 s on the project's 2-core machine.
    for name in ("first", "second"):
        write_log(tmp_path / "logs" / name, random_updates(40, points=100_000))
    async with running_server(tmp_path / "logs") as server:
        # Allowed no longer than the handshake: the connection is dropped before the file is made.
        monkeypatch.setattr(xviz_server.framing, "OPEN_TIMEOUT", 0.05)  # far less than making a file takes
        monkeypatch.setattr(xviz_server.server, "FILE_WAIT", 0.05)
        with pytest.raises(ConnectionError):
            await asyncio.to_thread(http_get, server.port, FILE.format("first"), "HEAD")
        # Allowed FILE_WAIT: answered once the file is made. The handshake's own limit is less than the making, and
        # long enough that the request always comes within it, however loaded the machine (0.05 s would not be).
        monkeypatch.setattr(xviz_server.framing, "OPEN_TIMEOUT", 0.5)
        monkeypatch.setattr(xviz_server.server, "FILE_WAIT", 600.0)
        status, headers, _ = await asyncio.to_thread(http_get, server.port, FILE.format("second"), "HEAD")
        assert status == 200 and int(headers["Content-Length"]) > 0


async def test_at_most_builds_files_are_made_at_a_time(tmp_path: Path) -> None:
    from xviz_server.foxglove.seekable import BUILDS

    names = [f"drive{i}" for i in range(BUILDS + 2)]
    for name in names:
        write_log(tmp_path / "logs" / name, random_updates(10))
    files = tmp_path / "state" / "files"
    async with running_server(tmp_path / "logs", state_dir=tmp_path / "state") as server:
        asked = asyncio.gather(*(asyncio.to_thread(http_get, server.port, FILE.format(name), "HEAD") for name in names))
        seen = set()
        while not asked.done():  # the files being written, as often as the loop lets us look
            seen.add(len(list(files.glob("*.part"))) if files.is_dir() else 0)
            await asyncio.sleep(0.005)
        assert {status for status, _, _ in await asked} == {200}
    assert max(seen) <= BUILDS and len(list(files.glob("*.mcap"))) == len(names), seen


async def test_the_files_folder_keeps_to_its_cap_removing_the_least_recently_asked_for_never_one_being_read(
    tmp_path: Path,
) -> None:
    import socket

    from helpers import eventually
    from xviz_server.foxglove.seekable import _stem

    logs, state = tmp_path / "logs", tmp_path / "state"
    for name in "abcd":
        write_log(logs / name, random_updates(10))
    write_log(logs / "big", random_updates(20, points=50_000))  # a file of megabytes, over the cap by itself
    files = state / "files"

    def kept() -> set[str]:
        stems = {_stem(name): name for name in [*"abcd", "big"]}
        return {stems[path.name.rpartition("-")[0]] for path in files.glob("*.mcap")}

    async def head(server: Any, name: str) -> None:
        status, _, _ = await asyncio.to_thread(http_get, server.port, FILE.format(name), "HEAD")
        assert status == 200

    async with running_server(logs, state_dir=state) as server:  # the default cap: every file is kept
        for name in "abcd":
            await head(server, name)
        assert kept() == set("abcd")
    cap = 2.5 * max(path.stat().st_size for path in files.glob("*.mcap"))  # two small files, not three
    shutil.rmtree(files)
    async with running_server(logs, state_dir=state, files_gb=cap / 1e9) as server:
        await head(server, "a")
        await head(server, "b")
        await head(server, "a")  # b is now the least recently asked for
        await head(server, "c")
        assert kept() == {"a", "c"}
        # A reader that takes the head and then nothing: its file is being read.
        reader = socket.socket()
        reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        await asyncio.to_thread(reader.connect, ("127.0.0.1", server.port))
        reader.sendall(f"GET {FILE.format('big')} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
        data = b""
        while b"\r\n\r\n" not in data:
            data += await asyncio.to_thread(reader.recv, 4096)
        assert data.startswith(b"HTTP/1.1 200 OK")
        assert kept() == {"big"}  # made, and alone over the cap: the others are removed
        await head(server, "d")
        assert kept() == {"big", "d"}  # big is being read
        reader.close()

        async def let_go() -> bool:
            return not server._files._held  # the answer to the reader has ended

        await eventually(let_go)
        await head(server, "a")
        assert kept() == {"d", "a"}  # big, the least recently asked for, is removed now
        status, _, body = await asyncio.to_thread(http_get, server.port, FILE.format("big"), Range="bytes=0-7")
        assert (status, body) == (206, b"\x89MCAP0\r\n")  # made again on request


def test_the_file_url_names_the_log_percent_decoded() -> None:
    from xviz_server.foxglove.seekable import file_path

    assert file_path("/api/logs/a%2Fb/file.mcap") == "a/b"
    assert file_path("/api/logs/file.mcap") is None
    assert file_path("/api/logs/x/export") is None
