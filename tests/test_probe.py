"""`xviz-server probe`: a scripted session that tells a clean server from a broken one."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import sys
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.server import ServerConnection, serve

from helpers import metadata, running_server, ten_hz, update, write_log
from xviz_server.codec import Format, encode
from xviz_server.probe import Instant, ProbeReport, Problem, probe, with_format
from xviz_server.probe import client as probe_module

KITTI_START, KITTI_END = 1317042145.964, 1317042148.444  # first and last frame


@pytest.fixture
def root(tmp_path: Path, kitti_log: Path) -> Path:
    """A data root with the real KITTI log and small broken logs."""
    data = tmp_path / "logs"
    data.mkdir()
    (data / "kitti").symlink_to(kitti_log)
    write_log(data / "no-pose", ten_hz(3, streams=("/points", "/speed")))
    corrupt = write_log(data / "corrupt", ten_hz(4))
    frame = corrupt / "3-frame.glb"
    frame.write_bytes(frame.read_bytes()[:100])
    write_log(data / "undeclared", ten_hz(3), meta=metadata({"/vehicle_pose": {"category": "POSE"}}))
    return data


@pytest.fixture
def quick_give_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """Wait less for more after an xviz/error."""
    monkeypatch.setattr(probe_module, "AFTER_ERROR", 0.2)


def errors(report: ProbeReport) -> str:
    return "\n".join(map(str, report.errors))


# ------------------------------------------------------------ the real log


@pytest.mark.parametrize(
    "fmt, start, end, frames",
    [
        (Format.BINARY, None, None, 25),  # the whole log
        (Format.JSON, "+1", "+1.5", 5),  # JSON frames take ~0.2 s each to decode and validate
    ],
)
@pytest.mark.slow
async def test_clean_run_on_the_real_log(root: Path, fmt: Format, start: str | None, end: str | None, frames: int):
    async with running_server(root) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=kitti"
        report = await probe(
            url,
            fmt=fmt,
            start=start and Instant.parse(start),
            end=end and Instant.parse(end),
            point_in_time=Instant.parse("+1.2"),
            validate=True,
        )
    assert report.clean, report.render()
    assert report.url == f"{url}&message_format={fmt.value}"
    assert report.frames == frames
    assert report.messages == {"xviz/metadata": 1, "xviz/state_update": frames + 1, "xviz/transform_log_done": 1}
    first, last = (KITTI_START, KITTI_END) if start is None else (1317042147.004, 1317042147.414)
    assert (report.first_time, report.last_time) == (first, last)
    assert (report.log_info["start_time"], report.log_info["end_time"]) == (KITTI_START, 1317042157.004)
    assert report.declared_streams == 16 and len(report.streams) == 11 and "/lidar/points" in report.streams
    assert report.total_bytes > frames * 2_000_000 and report.warnings == []


async def test_stream_filter_and_offsets(root: Path):
    async with running_server(root) as server:
        report = await probe(
            f"ws://127.0.0.1:{server.port}/kitti",
            start=Instant.parse("+0.5"),
            end=Instant.parse("+1.0"),
            streams=["/vehicle_pose", "/vehicle/velocity"],
            point_in_time=Instant.parse(str(KITTI_START + 2)),
        )
    assert report.clean, report.render()
    assert report.streams == {"/vehicle_pose", "/vehicle/velocity"}  # the point-in-time answer's too
    assert (report.frames, report.first_time, report.last_time) == (5, 1317042146.484, 1317042146.894)
    assert report.total_bytes < 20_000  # no point clouds, no images


async def test_a_filter_without_poses_expects_none(root: Path):
    async with running_server(root) as server:
        url = f"ws://127.0.0.1:{server.port}/kitti"
        report = await probe(url, end=Instant.parse("+0.2"), streams=["/lidar/points"])
    assert report.clean, report.render()
    assert report.streams == {"/lidar/points"}


# ------------------------------------------------------------ broken logs


@pytest.mark.parametrize(
    "path, expected",
    [
        ("/?log=nowhere", "metadata: xviz/error: no log named 'nowhere'"),
        ("/corrupt", ": xviz/error: xviz/transform_log (id '"),
        ("/corrupt", "is corrupt: GLB truncated"),
        ("/no-pose", "state_update #1: no pose within 0.4 s of timestamp 100.0: streetscape.gl draws nothing"),
    ],
)
async def test_broken_sessions_are_unclean(root: Path, path: str, expected: str, quick_give_up: None):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}{path}")
    assert not report.clean
    assert expected in errors(report)


async def test_the_rest_of_a_log_after_a_bad_frame_is_checked(root: Path):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}/corrupt")
    assert report.frames == 3 and report.messages["xviz/transform_log_done"] == 1
    assert len(report.errors) == 1


async def test_undeclared_streams_are_warnings(root: Path):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}/undeclared")
    assert report.clean, report.render()
    assert report.warnings == [
        Problem("state_update #1", "stream '/points' is not declared in the metadata"),
        Problem("state_update #1", "stream '/speed' is not declared in the metadata"),
    ]


async def test_a_rejected_request_ends_when_the_server_falls_silent(root: Path, quick_give_up: None):
    async with running_server(root) as server:
        # Only the server can tell that +5 s from the start is after this instant.
        url = f"ws://127.0.0.1:{server.port}/kitti"
        report = await probe(url, start=Instant.parse("+5"), end=Instant.parse("1317042146"))
    assert report.frames == 0
    [error] = report.errors  # the server's, and no timeout
    assert error.where.startswith("transform_log ") and "is after end_timestamp" in error.what


async def test_nothing_listening(unused_tcp_port: int):
    report = await probe(f"ws://127.0.0.1:{unused_tcp_port}/", timeout=2)
    [error] = report.errors
    assert error.where == "connect" and error.what.startswith(f"cannot connect to ws://127.0.0.1:{unused_tcp_port}/")


# ------------------------------------------------- servers that break the rules


Script = Callable[[ServerConnection], Awaitable[None]]


@contextlib.asynccontextmanager
async def scripted_server(script: Script) -> AsyncIterator[str]:
    """A WebSocket server that plays ``script`` on every connection; yields its URL."""
    async with serve(script, "127.0.0.1", 0) as server:
        yield f"ws://127.0.0.1:{server.sockets[0].getsockname()[1]}/"


def message(kind: str, data: Any, fmt: Format = Format.BINARY) -> bytes:
    return encode({"type": f"xviz/{kind}", "data": data}, fmt)


async def rule_breaker(websocket: ServerConnection) -> None:
    await websocket.send(message("metadata", metadata(start_time=100.0, end_time=101.0)))
    await websocket.recv()  # transform_log
    untyped, untimed = update(100.3), update(100.95)
    del untyped["update_type"], untimed["updates"][0]["timestamp"]
    for data in (update(100.2), update(100.1), untyped, update(100.9)):  # disordered, then after the end
        await websocket.send(message("state_update", data))
    await websocket.send(b"glTF\x02\x00\x00\x00")  # truncated
    await websocket.send(message("state_update", untimed))
    await websocket.send(message("transform_log_done", {"id": "someone-else"}))
    await websocket.recv()  # transform_point_in_time
    await websocket.send(message("state_update", update(100.7, update_type="INCREMENTAL")))


async def bad_metadata(websocket: ServerConnection) -> None:
    data = metadata(end_time=0.0)
    del data["version"]
    await websocket.send(message("metadata", data, Format.JSON))


async def hang_up(websocket: ServerConnection) -> None:
    await websocket.send(message("metadata", metadata(start_time=100.0, end_time=101.0)))
    await websocket.recv()


async def silence(websocket: ServerConnection) -> None:
    await websocket.send(message("metadata", metadata(start_time=100.0, end_time=101.0)))
    await websocket.wait_closed()


@pytest.mark.parametrize(
    "script, options, expected",
    [
        (
            rule_breaker,
            {"end": Instant.parse("+0.5"), "point_in_time": Instant.parse("100.5")},
            [
                r"state_update #2: timestamp 100.1 comes after 100.2: out of time order",
                r"state_update #3: no 'update_type': the client throws on such an update",
                r"state_update #4: timestamp 100.9 is outside the range asked for, the start to 100.5",
                r"message #6: the message does not decode: GLB header truncated: 8 of 12 bytes",
                r"state_update #5: 'timestamp' must be a finite number in every stream set, not \[None\]",
                r"transform_log_done #1: the done is for request 'someone-else', not '\w{8}'",
                r"state_update #6: update_type is 'INCREMENTAL', not 'COMPLETE_STATE'",
                r"state_update #6: the state at 100.7 is after the instant asked for, 100.5",
            ],
        ),
        (
            bad_metadata,
            {"start": Instant.parse("+1")},
            [
                r"metadata #1: no 'version': clients then read the log as XVIZ v1 and fail on every update",
                r"metadata #1: log_info.start_time is None: streetscape.gl needs finite, non-zero times",
                r"metadata #1: log_info.end_time is 0.0: streetscape.gl needs finite, non-zero times",
                r"metadata: \+1 needs the log's start_time, which the metadata lacks; give absolute times",
            ],
        ),
        (hang_up, {}, [r"transform_log \w{8}: the server closed the connection: "]),
        (silence, {"timeout": 0.3}, [r"transform_log \w{8}: timed out after 0.3 s"]),
    ],
)
async def test_rule_breaking_servers(script: Script, options: dict[str, Any], expected: list[str]):
    async with scripted_server(script) as url:
        report = await probe(url, **options)
    assert len(report.errors) == len(expected), errors(report)
    for error, pattern in zip(report.errors, expected):
        assert re.match(pattern, str(error)), str(error)


# ------------------------------------------------------------ pieces


def test_format_is_added_to_the_url_as_written():
    url = "ws://host:3000/?worker=true&log=city/drive-1&message_format=json&duration=30"
    expected = "ws://host:3000/?worker=true&log=city/drive-1&duration=30&message_format=BINARY"
    assert with_format(url, Format.BINARY) == expected
    assert with_format("ws://host:3000/kitti", Format.JSON) == "ws://host:3000/kitti?message_format=JSON"
    assert with_format("ws://host:3000/kitti", None) == "ws://host:3000/kitti"
    with pytest.raises(ValueError, match="'http://host/' is not a WebSocket URL like ws://HOST:PORT/"):
        with_format("http://host/", None)


def test_instants():
    assert Instant.parse("+1.5") == Instant(1.5, relative=True)
    assert Instant.parse("1317042146.5").resolve(None) == 1317042146.5
    assert Instant.parse("+0.3").resolve(100.1) == 100.4  # not 100.39999999999999
    for text in ("soon", "nan", "+inf", ""):
        with pytest.raises(ValueError, match="is not a time"):
            Instant.parse(text)


async def test_a_backwards_range_is_refused_before_connecting():
    with pytest.raises(ValueError, match=r"the range starts at \+2, after its end at \+1"):
        await probe("ws://127.0.0.1:1/", start=Instant.parse("+2"), end=Instant.parse("+1"))


def test_text_summary_is_aligned():
    report = ProbeReport("ws://h/?log=x", log_info={"start_time": 1.0, "end_time": 2.0}, declared_streams=2)
    report.messages.update({"xviz/metadata": 1, "xviz/state_update": 2})
    report.bytes_by_type.update({"xviz/metadata": 900, "xviz/state_update": 1_234_567})
    report.frames, report.first_time, report.last_time, report.elapsed = 2, 1.0, 1.1, 0.5
    report.streams = {"/b", "/a"}
    report.errors.append(Problem("state_update #2", "no 'update_type': the client throws on such an update"))
    assert report.render() == "\n".join(
        [
            "probe     ws://h/?log=x: UNCLEAN",
            "log       1.0 to 2.0, 2 streams declared",
            "frames    2 from 1.0 to 1.1 (0.100 s)",
            "streams   2 seen: /a, /b",
            "received  3 messages, 1,235,467 bytes in 0.500 s (2.5 MB/s)",
            "          xviz/metadata          1            900",
            "          xviz/state_update      2      1,234,567",
            "errors    state_update #2: no 'update_type': the client throws on such an update",
            "warnings  none",
        ]
    )


# ------------------------------------------------------------ command line


async def run_cli(*args: str) -> tuple[int, str, str]:
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "xviz_server",
        "probe",
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    out, err = await process.communicate()
    return process.returncode, out.decode(), err.decode()


@pytest.mark.slow
async def test_command_line(root: Path):
    async with running_server(root) as server:
        url = f"ws://127.0.0.1:{server.port}"
        runs = await asyncio.gather(
            run_cli(f"{url}/?log=kitti", "--json", "--end", "+0.3", "--format", "json", "--validate"),
            run_cli(f"{url}/no-pose"),
            run_cli(f"{url}/kitti", "--start", "soon"),
            run_cli("localhost:3000"),
        )
    (clean, summary, _), (unclean, text, _), (bad_time, _, time_error), (bad_url, _, url_error) = runs
    assert clean == 0
    data = json.loads(summary)
    assert set(data) == {
        "url",
        "clean",
        "log_info",
        "declared_streams",
        "messages",
        "frames",
        "bytes",
        "time_range",
        "streams",
        "elapsed_s",
        "mb_per_s",
        "errors",
        "warnings",
    }
    assert data["clean"] and data["frames"] == 3 and data["url"].endswith("&message_format=JSON")
    assert data["time_range"] == {"first": KITTI_START, "last": 1317042146.174}
    assert data["bytes"]["total"] == sum(data["bytes"]["by_type"].values()) > 3 * 4_000_000
    assert data["errors"] == data["warnings"] == []

    assert unclean == 1
    assert "UNCLEAN" in text and "errors    state_update #1: no pose within 0.4 s" in text
    assert bad_time == 2 and time_error == (
        "xviz-server probe: 'soon' is not a time: give seconds, or +seconds after the log's start\n"
    )
    assert bad_url == 2 and url_error.startswith("xviz-server probe: 'localhost:3000' is not a WebSocket URL")
