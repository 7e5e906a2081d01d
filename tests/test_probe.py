"""`xviz-server probe`: a scripted session that tells a clean server from a broken one."""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

import pytest

from serving import running_server, ten_hz, write_log
from xviz_server.codec import Format
from xviz_server.probe import Instant, probe


@pytest.fixture
def root(tmp_path: Path, kitti_log: Path) -> Path:
    data = tmp_path / "logs"
    data.mkdir()
    (data / "kitti").symlink_to(kitti_log)
    write_log(data / "no-pose", ten_hz(3, streams=("/points", "/speed")))
    corrupt = write_log(data / "corrupt", ten_hz(4))
    frame = corrupt / "3-frame.glb"
    frame.write_bytes(frame.read_bytes()[:100])
    return data


@pytest.mark.parametrize("fmt", [Format.BINARY, Format.JSON])
async def test_clean_run_on_the_real_log(root: Path, fmt: Format):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}/?log=kitti", fmt=fmt, validate=True,
                             point_in_time=Instant.parse("+1"))
    assert report.clean, report.render()
    assert report.updates == 25  # the frames; the point-in-time state counts as a message
    assert report.messages == {"xviz/metadata": 1, "xviz/state_update": 26, "xviz/transform_log_done": 1}
    assert (report.first_time, report.last_time) == (1317042145.964, 1317042148.444)
    assert "/lidar/points" in report.streams and report.declared_streams == 16
    assert report.url.endswith(f"message_format={fmt.value}")


async def test_streams_and_relative_range(root: Path):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}/kitti", start=Instant.parse("+0.5"), end=Instant.parse("+1.0"),
                             streams=["/vehicle_pose", "/vehicle/velocity"])
    assert report.clean, report.render()
    assert report.streams == {"/vehicle_pose", "/vehicle/velocity"}
    assert report.updates == 5 and 1317042146.464 <= report.first_time <= report.last_time <= 1317042146.964


@pytest.mark.parametrize(
    "path, expected",
    [
        ("/?log=nowhere", "server error: no log named 'nowhere'"),
        ("/corrupt", "is corrupt: GLB truncated"),
        ("/no-pose", "no pose within 0.4 s of 100.0"),
    ],
)
async def test_broken_sessions_are_unclean(root: Path, path: str, expected: str):
    async with running_server(root) as server:
        report = await probe(f"ws://127.0.0.1:{server.port}{path}", timeout=10)
    assert not report.clean
    assert any(expected in error for error in report.errors), report.errors


async def test_nothing_listening_is_reported(unused_tcp_port: int):
    report = await probe(f"ws://127.0.0.1:{unused_tcp_port}/", timeout=2)
    assert not report.clean and report.errors[0].startswith("cannot connect")


async def test_command_line_exit_status_and_json(root: Path):
    async def run(*args: str) -> tuple[int, str, str]:
        process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "xviz_server", "probe", *args,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )
        out, err = await process.communicate()
        return process.returncode, out.decode(), err.decode()

    async with running_server(root) as server:
        url = f"ws://127.0.0.1:{server.port}"
        code, out, _ = await run(f"{url}/kitti", "--json", "--end", "+0.3")
        assert code == 0
        summary = json.loads(out)
        assert summary["clean"] and summary["state_updates"] == 3 and summary["bytes"]["total"] > 6_000_000
        code, out, _ = await run(f"{url}/no-pose")
        assert code == 1 and "UNCLEAN" in out and "no pose" in out
        code, _, err = await run(f"{url}/kitti", "--start", "soon")
        assert code == 2 and "'soon' is not a time" in err
        code, _, err = await run("http://example/")
        assert code == 2 and "not a WebSocket URL" in err
