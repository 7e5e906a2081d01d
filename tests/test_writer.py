"""The log writer: reference layout, atomic files, index last, resumable."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from serving import client, metadata, running_server, ten_hz, timestamps
from xviz_server.check import check_paths
from xviz_server.codec import Format, encode
from xviz_server.exceptions import XVIZError
from xviz_server.writer import LogWriter, write_atomically


@pytest.mark.parametrize("fmt", [Format.BINARY, Format.JSON])
def test_writes_the_reference_layout_with_the_index_last(tmp_path: Path, fmt: Format):
    log = tmp_path / "log"
    updates = ten_hz(3)
    with LogWriter(log, fmt) as writer:
        writer.write_metadata(metadata())
        for i, data in enumerate(updates):
            writer.write_frame(i, data)
        assert not (log / "0-frame.json").exists()  # not before close
    names = sorted(p.name for p in log.iterdir())
    assert names == sorted(["0-frame.json", *(f"{n}-frame{fmt.suffix}" for n in range(1, 5))])
    index = json.loads((log / "0-frame.json").read_text())
    assert index == {"startTime": 100.0, "endTime": 100.2,
                     "timing": [[100.0, 100.0, 0, "2-frame"], [100.1, 100.1, 1, "3-frame"], [100.2, 100.2, 2, "4-frame"]]}
    assert check_paths([log]).ok


def test_interrupted_run_leaves_no_index_and_no_partial_files_then_resumes(tmp_path: Path):
    log = tmp_path / "log"
    updates = ten_hz(6)
    with pytest.raises(RuntimeError):
        with LogWriter(log) as writer:
            writer.write_metadata(metadata())
            for i, data in enumerate(updates[:3]):
                writer.write_frame(i, data)
            raise RuntimeError("killed")
    assert not (log / "0-frame.json").exists()
    (log / ".5-frame.glb.partial-deadbeef").write_bytes(b"half a frame")  # what a crash mid-write leaves
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in log.glob("*-frame.glb")}

    with LogWriter(log) as writer:
        assert [writer.done(i) for i in range(6)] == [True, True, True, False, False, False]
        for i, data in enumerate(updates):
            if not writer.done(i):
                writer.write_frame(i, data)
    after = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in log.glob("*-frame.glb")}
    assert all(after[name] == before[name] for name in before)  # not rewritten
    assert not list(log.glob(".*"))  # no temporary files
    assert len(json.loads((log / "0-frame.json").read_text())["timing"]) == 6


def test_close_refuses_a_gap(tmp_path: Path):
    writer = LogWriter(tmp_path / "log")
    writer.write_metadata(metadata())
    writer.write_frame(0, ten_hz(1)[0])
    writer.write_frame(2, ten_hz(3)[2])
    with pytest.raises(XVIZError, match="frames are missing: 3-frame"):
        writer.close()
    assert writer.write_index() == 1  # an interim index covers what comes before the gap


def test_encoded_frames_are_kept_or_converted(tmp_path: Path):
    data = ten_hz(2)
    writer = LogWriter(tmp_path / "log", Format.BINARY)
    glb = encode({"type": "xviz/state_update", "data": data[0]}, Format.BINARY)
    writer.write_frame(0, glb)
    writer.write_frame(1, encode({"type": "xviz/state_update", "data": data[1]}, Format.JSON))
    assert (tmp_path / "log" / "2-frame.glb").read_bytes() == glb
    assert (tmp_path / "log" / "3-frame.glb").read_bytes()[:4] == b"glTF"
    with pytest.raises(XVIZError, match="frame 5: every update needs a numeric 'timestamp'"):
        writer.write_frame(5, {"update_type": "SNAPSHOT", "updates": [{"poses": {}}]})


def test_write_atomically_replaces_whole_files(tmp_path: Path):
    path = tmp_path / "f.bin"
    write_atomically(path, b"one")
    write_atomically(path, b"two")
    assert path.read_bytes() == b"two" and [p.name for p in tmp_path.iterdir()] == ["f.bin"]


async def test_a_written_log_is_served(tmp_path: Path):
    with LogWriter(tmp_path / "logs" / "written") as writer:
        writer.write_metadata(metadata())
        for i, data in enumerate(ten_hz(4)):
            writer.write_frame(i, data)
    async with running_server(tmp_path / "logs") as server, client(server, "/written") as c:
        await c.recv()
        await c.send("transform_log", {"id": "w"})
        assert timestamps(await c.until("transform_log_done", "w")) == [100.0, 100.1, 100.2, 100.3]
