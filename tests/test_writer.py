"""The log writer: reference layout, atomic files, index last, resumable; real files and processes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from helpers import client, metadata, running_server, ten_hz, timestamps, xviz_decode
from xviz_server.builder import FrameBuilder, MetadataBuilder
from xviz_server.codec import Format, decode, encode
from xviz_server.exceptions import LogWriteError
from xviz_server.validate import check_paths
from xviz_server.writer import LogWriter, write_atomically


def built_log(count: int, start: float = 100.0) -> tuple[dict, list[dict]]:
    """Metadata and ``count`` frames at 10 Hz made with the builder."""
    meta = MetadataBuilder()
    meta.log_info(start_time=start, end_time=start + (count - 1) / 10)
    meta.pose("/vehicle_pose")
    meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 2})
    meta.primitive("/objects", "POLYGON", style_classes={"Car": {"fill_color": "#50B3FF80"}})
    meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
    metadata = meta.build()
    rng = np.random.default_rng(0)
    frames = []
    for i in range(count):
        t = round(start + i / 10, 3)
        frame = FrameBuilder(metadata)
        frame.pose("/vehicle_pose", t, map_origin=(8.43, 49.01, 116.4), position=(i, 0, 0))
        frame.points("/lidar/points", rng.normal(size=(100 + i, 3)).astype(np.float32))
        frame.polygon("/objects", [[i, 0, 0], [i + 4, 0, 0], [i + 4, 2, 0]], id="car-1", classes=["Car"])
        frame.time_series("/vehicle/velocity", t, 10.0 + i)
        frames.append(frame.build())
    return metadata, frames


def files(log: Path) -> dict[str, tuple[int, int]]:
    """Each file of a log directory: (inode, modification time in ns)."""
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in log.iterdir()}


@pytest.mark.parametrize("fmt", list(Format))
def test_writes_the_reference_layout_with_the_index_last(tmp_path: Path, fmt: Format):
    log = tmp_path / "log"
    meta, frames = built_log(3)
    with LogWriter(log, fmt) as writer:
        writer.write_metadata(meta)
        for i, data in enumerate(frames):
            writer.write_frame(i, data)
        assert not (log / "0-frame.json").exists()  # not before close
    names = sorted(p.name for p in log.iterdir())
    assert names == sorted(["0-frame.json", *(f"{n}-frame{fmt.suffix}" for n in range(1, 5))])
    written = files(log)
    assert written["0-frame.json"][1] >= max(mtime for _, mtime in written.values())
    index = json.loads((log / "0-frame.json").read_text())
    assert index == {
        "startTime": 100.0,
        "endTime": 100.2,
        "timing": [[100.0, 100.0, 0, "2-frame"], [100.1, 100.1, 1, "3-frame"], [100.2, 100.2, 2, "4-frame"]],
    }
    assert decode((log / f"3-frame{fmt.suffix}").read_bytes())["data"]["updates"][0]["timestamp"] == 100.1
    assert check_paths([log]).ok


def test_the_index_spans_the_frames_without_log_info(tmp_path: Path):
    """The reference tools take startTime/endTime from log_info; without it they come from the frames."""
    with LogWriter(tmp_path / "log") as writer:
        writer.write_metadata(metadata())
        for i, data in enumerate(ten_hz(3, start=50.0)):
            writer.write_frame(i, data)
    index = json.loads((tmp_path / "log" / "0-frame.json").read_text())
    assert (index["startTime"], index["endTime"]) == (50.0, 50.2)


def test_published_client_reads_the_written_log(tmp_path: Path):
    meta, frames = built_log(3)
    with LogWriter(tmp_path, Format.BINARY) as writer:
        writer.write_metadata(meta)
        for i, data in enumerate(frames):
            writer.write_frame(i, data)
    decoded = xviz_decode([tmp_path / f"{n}-frame.glb" for n in range(1, 5)])
    assert all("error" not in line for line in decoded), decoded
    streams = [line["parsed"]["streams"] for line in decoded[1:]]
    assert [s["/lidar/points"]["pointCloud"]["numInstances"] for s in streams] == [100, 101, 102]
    assert [s["/vehicle/velocity"][0]["variable"] for s in streams] == [10.0, 11.0, 12.0]


def test_an_exception_mid_way_leaves_no_index_and_no_partial_files(tmp_path: Path):
    log = tmp_path / "log"
    meta, frames = built_log(6)
    with pytest.raises(RuntimeError, match="conversion failed"):
        with LogWriter(log) as writer:
            writer.write_metadata(meta)
            for i, data in enumerate(frames[:3]):
                writer.write_frame(i, data)
            raise RuntimeError("conversion failed")
    assert sorted(p.name for p in log.iterdir()) == ["1-frame.glb", "2-frame.glb", "3-frame.glb", "4-frame.glb"]
    for n in range(2, 5):
        assert decode((log / f"{n}-frame.glb").read_bytes())["type"] == "xviz/state_update"  # whole files


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path):
    path = tmp_path / "f.bin"
    write_atomically(path, b"one")
    with pytest.raises(TypeError):
        write_atomically(path, "not bytes")  # fails after the temporary file was created
    assert path.read_bytes() == b"one" and [p.name for p in tmp_path.iterdir()] == ["f.bin"]
    write_atomically(path, memoryview(b"two"))
    assert path.read_bytes() == b"two" and [p.name for p in tmp_path.iterdir()] == ["f.bin"]


WRITE_FOREVER = textwrap.dedent(
    """
    import sys
    import numpy as np
    from xviz_server.writer import LogWriter

    metadata = {"version": "2.0.0", "streams": {"/points": {"category": "PRIMITIVE", "primitive_type": "POINT"}}}
    cloud = np.random.default_rng(0).normal(size=(500_000, 3)).astype(np.float32)  # 6 MB a frame
    writer = LogWriter(sys.argv[1])
    writer.write_metadata(metadata)
    for i in range(10_000):
        update = {"timestamp": 100 + i / 10, "primitives": {"/points": {"points": [{"points": cloud}]}}}
        writer.write_frame(i, {"update_type": "SNAPSHOT", "updates": [update]})
        print(i, flush=True)
    """
)


def test_a_killed_conversion_resumes_where_it_stopped(tmp_path: Path):
    log = tmp_path / "log"
    child = subprocess.Popen([sys.executable, "-c", WRITE_FOREVER, str(log)], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        while child.stdout.readline().strip() != "3":
            assert child.poll() is None, "the writer process ended early"
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert not (log / "0-frame.json").exists()
    complete = sorted(int(p.name.split("-")[0]) - 2 for p in log.glob("*-frame.glb") if p.name != "1-frame.glb")
    assert complete[:4] == [0, 1, 2, 3] and complete == list(range(len(complete)))
    for i in complete:  # every frame file is whole; a kill mid-write leaves only a temporary file
        assert decode((log / f"{i + 2}-frame.glb").read_bytes())["data"]["updates"][0]["timestamp"] == 100 + i / 10
    # what a kill in the middle of a write leaves, to be sure one is there
    (log / f".{len(complete) + 2}-frame.glb.partial-0badf00d").write_bytes(b"glTF half a frame")
    before = files(log)

    writer = LogWriter(log)
    assert [writer.done(i) for i in range(len(complete) + 2)] == [True] * len(complete) + [False, False]
    assert not list(log.glob(".*"))  # leftovers removed
    update = {
        "timestamp": 100 + len(complete) / 10,
        "poses": {"/vehicle_pose": {"position": [0, 0, 0], "orientation": [0, 0, 0]}},
    }
    writer.write_frame(len(complete), {"update_type": "SNAPSHOT", "updates": [update]})
    writer.close()
    after = files(log)
    assert all(after[name] == before[name] for name in before if not name.startswith("."))  # kept, not rewritten
    timing = json.loads((log / "0-frame.json").read_text())["timing"]
    assert [row[2] for row in timing] == list(range(len(complete) + 1))
    assert check_paths([log]).ok


def test_reopening_a_finished_log_drops_its_index_until_closed(tmp_path: Path):
    meta, frames = built_log(4)
    with LogWriter(tmp_path) as writer:
        writer.write_metadata(meta)
        for i, data in enumerate(frames[:2]):
            writer.write_frame(i, data)
    writer = LogWriter(tmp_path)
    assert (tmp_path / "0-frame.json").exists()  # opening changes nothing
    writer.write_frame(2, frames[2])
    assert not (tmp_path / "0-frame.json").exists()  # no longer describes the log
    writer.write_frame(3, frames[3])
    writer.close()
    assert len(json.loads((tmp_path / "0-frame.json").read_text())["timing"]) == 4


def test_close_refuses_a_gap_and_writes_no_index(tmp_path: Path):
    updates = ten_hz(5)
    writer = LogWriter(tmp_path)
    writer.write_metadata(metadata())
    for i in (0, 3, 4):
        writer.write_frame(i, updates[i])
    with pytest.raises(
        LogWriteError, match=r"cannot write the index: missing 3-frame \(frame 1\), 4-frame \(frame 2\)$"
    ) as error:
        writer.close()
    assert error.value.directory == tmp_path
    assert not (tmp_path / "0-frame.json").exists()
    assert writer.write_index() == 1  # an index while a log grows covers the frames before the gap
    writer.write_frame(1, updates[1])
    writer.write_frame(2, updates[2])
    writer.close()
    assert len(json.loads((tmp_path / "0-frame.json").read_text())["timing"]) == 5


def test_close_refuses_a_log_without_metadata_or_frames(tmp_path: Path):
    writer = LogWriter(tmp_path / "a")
    writer.write_frame(0, ten_hz(1)[0])
    with pytest.raises(LogWriteError, match="no metadata"):
        writer.close()
    writer = LogWriter(tmp_path / "b")
    writer.write_metadata(metadata())
    with pytest.raises(LogWriteError, match="no frames were written"):
        writer.close()


def test_a_closed_writer_writes_nothing_more(tmp_path: Path):
    with LogWriter(tmp_path) as writer:
        writer.write_metadata(metadata())
        writer.write_frame(0, ten_hz(1)[0])
    with pytest.raises(LogWriteError, match="the writer is closed"):
        writer.write_frame(1, ten_hz(2)[1])
    writer.close()  # again: nothing happens


def test_a_log_of_the_other_format_is_refused(tmp_path: Path):
    with LogWriter(tmp_path, Format.JSON) as writer:
        writer.write_metadata(metadata())
        writer.write_frame(0, ten_hz(1)[0])
    with pytest.raises(LogWriteError, match=r"holds 1-frame\.json, 2-frame\.json, not BINARY frames"):
        LogWriter(tmp_path, Format.BINARY)


def test_encoded_messages_are_kept_or_converted(tmp_path: Path):
    data = ten_hz(2)
    writer = LogWriter(tmp_path, Format.BINARY)
    glb_metadata = encode({"type": "xviz/metadata", "data": metadata()}, Format.BINARY)
    writer.write_metadata(glb_metadata)
    glb = encode({"type": "xviz/state_update", "data": data[0]}, Format.BINARY)
    writer.write_frame(0, glb)
    writer.write_frame(1, encode({"type": "xviz/state_update", "data": data[1]}, Format.JSON))
    assert (tmp_path / "1-frame.glb").read_bytes() == glb_metadata
    assert (tmp_path / "2-frame.glb").read_bytes() == glb  # the same bytes
    assert (tmp_path / "3-frame.glb").read_bytes()[:4] == b"glTF"  # converted
    writer.close()
    assert check_paths([tmp_path]).ok


@pytest.mark.parametrize(
    "data, message",
    [
        ({"update_type": "SNAPSHOT", "updates": [{"poses": {}}]}, "frame 5: every update needs a numeric 'timestamp'"),
        ({"update_type": "SNAPSHOT", "updates": []}, "frame 5: every update needs a numeric 'timestamp'"),
        ({"updates": [{"timestamp": 1.0}]}, "frame 5: needs an 'update_type'"),
        (
            encode({"type": "xviz/metadata", "data": {"version": "2.0.0"}}, Format.BINARY),
            "frame 5 holds 'xviz/metadata', not xviz/state_update",
        ),
        (b"glTF\x02\x00\x00\x00", "frame 5: "),
    ],
    ids=["no timestamp", "no updates", "no update_type", "metadata", "truncated GLB"],
)
def test_frames_clients_cannot_read_are_refused(tmp_path: Path, data, message: str):
    writer = LogWriter(tmp_path)
    with pytest.raises(LogWriteError, match=message):
        writer.write_frame(5, data)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("fmt", list(Format))
async def test_a_written_log_is_served(tmp_path: Path, fmt: Format):
    meta, frames = built_log(3)
    with LogWriter(tmp_path / "logs" / "written", fmt) as writer:
        writer.write_metadata(meta)
        for i, data in enumerate(frames):
            writer.write_frame(i, data)
    async with running_server(tmp_path / "logs") as server, client(server, "/written") as c:
        first = await c.recv()
        assert first["type"] == "xviz/metadata" and set(first["data"]["streams"]) == set(meta["streams"])
        await c.send("transform_log", {"id": "w"})
        received = await c.until("transform_log_done", "w")
        assert timestamps(received) == [100.0, 100.1, 100.2]
        assert [
            len(m["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]["points"])
            for m in received
            if m["type"] == "xviz/state_update"
        ] == [100, 101, 102]
