"""Waymo segments as shipped (.tfrecord): framing, range image geometry, the same log as .npz, serving."""

from __future__ import annotations

import io
import logging
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from devkit.waymo_frames import calibration, frame, jpeg_image, write_segment
from devkit.waymo_scene import LABELS, T0, write_scene
from helpers import client, running_server, timestamps, xviz_decode
from xviz_server.codec import Format, encode
from xviz_server.datasets import detect, open_dataset
from xviz_server.datasets.images import scale_jpegs
from xviz_server.datasets.waymo import WaymoSegment
from xviz_server.datasets.waymo.segment import WaymoRecordSegment
from xviz_server.datasets.waymo.tfrecord import RecordFile, masked_crc, write_records
from xviz_server.exceptions import DatasetError
from xviz_server.messages import envelope
from xviz_server.validate import check_paths


@pytest.fixture
def scene(tmp_path: Path) -> tuple[Path, Path, list]:
    return write_scene(tmp_path / "scene")


def test_masked_crc_of_the_crc32c_check_value():
    crc = 0xE3069283  # CRC32C of b"123456789", the algorithm's published check value
    assert masked_crc(b"123456789") == (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def test_matrix_data_as_bytes_reads_waymos_packed_floats():
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    from xviz_server.datasets.waymo import frame_pb2 as pb

    # Waymo's own definition: proto2, `repeated float data = 1 [packed = true]; optional MatrixShape shape = 2;`
    file = descriptor_pb2.FileDescriptorProto(name="waymo_test.proto", package="waymo_test", syntax="proto2")
    shape = file.message_type.add(name="MatrixShape")
    shape.field.add(
        name="dims",
        number=1,
        type=descriptor_pb2.FieldDescriptorProto.TYPE_INT32,
        label=descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED,
    )
    matrix = file.message_type.add(name="MatrixFloat")
    data = matrix.field.add(
        name="data",
        number=1,
        type=descriptor_pb2.FieldDescriptorProto.TYPE_FLOAT,
        label=descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED,
    )
    data.options.packed = True
    matrix.field.add(
        name="shape",
        number=2,
        type=descriptor_pb2.FieldDescriptorProto.TYPE_MESSAGE,
        label=descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL,
        type_name=".waymo_test.MatrixShape",
    )
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file)
    theirs = message_factory.GetMessageClass(pool.FindMessageTypeByName("waymo_test.MatrixFloat"))()
    values = [1.5, -2.25, 75.0, 0.0, -1.0, 3.0e-3]
    theirs.data.extend(values)
    theirs.shape.dims.extend([1, 2, 3])
    ours = pb.MatrixFloat.FromString(theirs.SerializeToString())
    assert np.frombuffer(ours.data, "<f4").tolist() == pytest.approx(values) and list(ours.shape.dims) == [1, 2, 3]


def test_index_is_one_pass_over_headers(tmp_path: Path):
    payloads = [b"a" * 10, b"", b"b" * 70_000]
    write_records(tmp_path / "x.tfrecord", payloads)
    records = RecordFile(tmp_path / "x.tfrecord")
    assert [(r.offset, r.length) for r in records.records] == [(0, 10), (26, 0), (42, 70_000)]
    assert [records.read(i) for i in range(3)] == payloads


def test_hand_computed_pixels(tmp_path: Path):
    # FRONT lidar at the car's origin, 2 rows (pitches 0.1 and -0.1 rad), 4 columns (azimuths 3/4, 1/4, -1/4, -3/4 pi).
    image = np.full((2, 4, 4), -1, np.float32)
    image[1, 1, :2] = 10.0, 0.5  # row 1 is the lower beam (-0.1 rad), column 1 looks at 45 degrees left
    image[0, 3, :2] = 2.0, 0.5  # row 0 (+0.1 rad), column 3 looks back right (-135 degrees)
    record = frame(T0, np.eye(4), [calibration("FRONT", np.eye(4), (), -0.2, 0.2)], {"FRONT": (image, None, None)})
    segment = WaymoRecordSegment(write_segment(tmp_path / "s.tfrecord", [record]))
    points = segment.read(0).points
    assert points == pytest.approx(
        np.array(
            [
                [-1.4071485, -1.4071485, 0.19966683],  # 2 (cos -3/4 pi cos 0.1, sin -3/4 pi cos 0.1, sin 0.1)
                [7.0357425, 7.0357425, -0.99833417],  # 10 (cos 1/4 pi cos -0.1, sin 1/4 pi cos -0.1, sin -0.1)
            ],
            np.float32,
        ),
        abs=1e-5,
    )


@pytest.mark.parametrize("rows_move", [False, True], ids=["pose-per-column", "pose-per-pixel"])
def test_range_images_give_the_known_points(tmp_path: Path, rows_move: bool):
    tfrecord, _, expectations = write_scene(tmp_path / "scene", rows_move=rows_move)
    segment = open_dataset("waymo", tfrecord)
    assert isinstance(segment, WaymoRecordSegment) and detect(tfrecord) == "waymo"
    assert segment.name == "segment-15" and segment.times.tolist() == [1557000000.0, 1557000000.1, 1557000000.2]
    for index, expected in enumerate(expectations):
        data = segment.read(index)
        # lidar by lidar in Waymo's order (TOP, FRONT), first return then second, row by row
        rows = [row for name in ("TOP", "FRONT") for returns in expected[name] for row in returns]
        assert len(data.points) == len(rows) > 150
        assert np.abs(data.points - np.array([p for p, _, _ in rows])).max() < 1e-4
        assert data.intensity.tolist() == pytest.approx([i for _, i, _ in rows])
        assert data.in_zone.tolist() == [z for _, _, z in rows] and data.in_zone.sum() == 2


def test_npz_and_tfrecord_give_the_same_log(scene):
    tfrecord, npz, _ = scene
    record_log, dict_log = WaymoRecordSegment(tfrecord), WaymoSegment(npz)
    assert record_log.metadata() == dict_log.metadata() | {"log_info": record_log.metadata()["log_info"]}
    assert record_log.metadata()["log_info"]["start_time"] == dict_log.metadata()["log_info"]["start_time"]
    from PIL import Image

    for index in range(3):
        a, b = record_log.convert(index)["updates"][0], dict_log.convert(index)["updates"][0]
        assert a["timestamp"] == b["timestamp"]
        assert a["poses"]["/vehicle_pose"]["position"] == pytest.approx(b["poses"]["/vehicle_pose"]["position"])
        assert a["poses"]["/vehicle_pose"]["orientation"] == pytest.approx(
            b["poses"]["/vehicle_pose"]["orientation"], abs=1e-6
        )
        assert a["primitives"].keys() == b["primitives"].keys()
        for stream in ("/lidar/points", "/lidar/no_label_zone"):
            ours, theirs = a["primitives"][stream]["points"][0], b["primitives"][stream]["points"][0]
            assert np.abs(ours["points"] - theirs["points"]).max() < 1e-4
            assert np.array_equal(ours.get("colors"), theirs.get("colors"))
        for stream in ("/objects/boxes", "/objects/label"):
            assert str(a["primitives"][stream]) == str(b["primitives"][stream])
        ours, theirs = a["primitives"]["/camera/front"]["images"][0], b["primitives"]["/camera/front"]["images"][0]
        assert (ours["width_px"], ours["height_px"]) == (theirs["width_px"], theirs["height_px"]) == (64, 48)
        with Image.open(io.BytesIO(ours["data"])) as x, Image.open(io.BytesIO(theirs["data"])) as y:
            assert np.abs(np.asarray(x, int) - np.asarray(y, int)).mean() < 3


def test_camera_jpeg_passes_through_or_is_scaled_down(tmp_path: Path):
    small, big = jpeg_image(300, 200, (10, 200, 10)), jpeg_image(1920, 1280, (10, 10, 200))
    record = frame(T0, np.eye(4), [], None, {"FRONT": small, "SIDE_LEFT": big}, LABELS)
    record.lasers.add(name="TOP")  # a laser without range images, as stripped releases have them
    segment = WaymoRecordSegment(write_segment(tmp_path / "cams.tfrecord", [record]), image_max_width=400)
    data = segment.read(0)
    assert data.images["FRONT"] == small
    from PIL import Image

    with Image.open(io.BytesIO(data.images["SIDE_LEFT"])) as picture:
        assert picture.format == "JPEG" and picture.size == (400, 267)
        assert np.asarray(picture)[130, 200, 2] > 180
    # No range images: cameras, boxes and pose all the same.
    update = segment.convert(0)["updates"][0]
    assert "/lidar/points" not in update["primitives"]
    assert [p["base"]["object_id"] for p in update["primitives"]["/objects/boxes"]["polygons"]] == ["car-a", "ped-b"]
    assert set(update["primitives"]) >= {"/camera/front", "/camera/side_left"} and "/vehicle_pose" in update["poses"]


def test_a_corrupt_record_is_named_and_the_rest_is_served(scene):
    tfrecord, _, _ = scene
    records = RecordFile(tfrecord).records
    data = bytearray(tfrecord.read_bytes())
    data[records[1].offset + 12 + records[1].length // 2] ^= 0xFF
    tfrecord.write_bytes(bytes(data))
    segment = WaymoRecordSegment(tfrecord)
    assert len(segment) == 3
    with pytest.raises(
        DatasetError, match=rf"segment-15.tfrecord: record 1 at offset {records[1].offset}: data CRC mismatch"
    ):
        segment.convert(1)
    assert len(segment.convert(0)["updates"][0]["primitives"]["/lidar/points"]["points"][0]["points"]) > 100
    assert segment.convert(2)["updates"][0]["timestamp"] == 1557000000.2


def test_a_truncated_segment_serves_the_whole_records(scene):
    tfrecord, _, _ = scene
    records = RecordFile(tfrecord).records
    tfrecord.write_bytes(tfrecord.read_bytes()[: records[2].offset + 1012])
    segment = WaymoRecordSegment(tfrecord)
    assert len(segment) == 3  # the last record's time is in its first 1000 bytes, after the context
    with pytest.raises(
        DatasetError,
        match=rf"record 2 at offset {records[2].offset}: truncated: the record needs \d+ bytes, the file has 1012",
    ):
        segment.read(2)
    assert segment.read(1).time == 1557000000.1


def test_a_corrupt_header_ends_the_index(scene, caplog):
    tfrecord, _, _ = scene
    records = RecordFile(tfrecord).records
    data = bytearray(tfrecord.read_bytes())
    data[records[1].offset + 3] ^= 0x01  # the length of record 1
    tfrecord.write_bytes(bytes(data))
    segment = WaymoRecordSegment(tfrecord)
    assert len(segment) == 2  # record 2 cannot be found without record 1's length
    with pytest.raises(DatasetError, match=rf"record 1 at offset {records[1].offset}: length CRC mismatch"):
        segment.read(1)
    assert segment.read(0).time == 1557000000.0
    garbage = tfrecord.with_name("garbage.tfrecord")
    garbage.write_bytes(b"\x00" * 100)
    assert detect(garbage) is None
    with pytest.raises(DatasetError, match="garbage.tfrecord: not a TFRecord file"):
        open_dataset("waymo", garbage)
    with caplog.at_level(logging.WARNING):
        write_records(garbage, [b"\x0a\x02no", b""])  # framed well, but no timestamps: not Waymo frames
        with pytest.raises(DatasetError, match="garbage.tfrecord: no Waymo frames"):
            open_dataset("waymo", garbage)
    assert "record 1 at offset 20: no timestamp_micros" in caplog.text


def test_a_camera_image_that_is_not_a_jpeg_is_named(tmp_path: Path):
    image = np.full((2, 4, 4), 5.0, np.float32)
    lasers = {"FRONT": (image, None, None)}
    calibrations = [calibration("FRONT", np.eye(4), (), -0.2, 0.2)]
    cameras = {"FRONT": jpeg_image(900, 600, (10, 20, 30)), "SIDE_LEFT": jpeg_image(64, 48, (1, 2, 3))}
    good = frame(T0, np.eye(4), calibrations, lasers, cameras, LABELS)
    bad = frame(
        T0 + 100_000,
        np.eye(4),
        calibrations,
        lasers,
        {"FRONT": jpeg_image(64, 48, (1, 2, 3)), "SIDE_LEFT": b"\xff\xd8 not a JPEG"},
        LABELS,
    )
    segment = WaymoRecordSegment(write_segment(tmp_path / "cams.tfrecord", [good, bad]))
    metadata = segment.metadata()
    assert segment.convert(0, metadata)["updates"][0]["primitives"]["/camera/front"]["images"][0]["width_px"] == 400
    with pytest.raises(
        DatasetError, match=r"cams.tfrecord: record 1 at offset \d+: camera SIDE_LEFT: not a JPEG image"
    ):
        segment.convert(1, metadata)


def test_a_bad_frame_or_range_image_is_named(tmp_path: Path, monkeypatch):
    image = np.full((2, 4, 4), 5.0, np.float32)
    good = frame(T0, np.eye(4), [calibration("FRONT", np.eye(4), (), -0.2, 0.2)], {"FRONT": (image, None, None)})
    bad = frame(
        T0 + 100_000, np.eye(4), [calibration("FRONT", np.eye(4), (0.1,), 0, 0)], {"FRONT": (image, None, None)}
    )
    no_zlib = frame(T0 + 200_000, np.eye(4), [], None)
    no_zlib.lasers.add(name="FRONT").ri_return1.range_image_compressed = b"not zlib"
    cut = frame(
        T0 + 300_000, np.eye(4), [calibration("FRONT", np.eye(4), (), -0.2, 0.2)], {"FRONT": (image, None, None)}
    )
    cut.lasers[0].ri_return1.range_image_compressed = cut.lasers[0].ri_return1.range_image_compressed[:-8]
    records = [f.SerializeToString() for f in (good, bad, no_zlib, cut)]
    records.append(b"\x10\x80\x80\x80\x80\x80\x80\x80\x80\x01\xff")  # timestamp_micros, then a field cut short
    path = tmp_path / "bad.tfrecord"
    write_records(path, records)
    segment = WaymoRecordSegment(path)
    assert len(segment) == 5 and len(segment.read(0).points) == 8
    with pytest.raises(DatasetError, match="record 1 at offset .*: laser FRONT: 1 beam inclinations for 2 rows"):
        segment.read(1)
    with pytest.raises(DatasetError, match="record 2 at offset .*: laser FRONT return 1: not zlib data"):
        segment.read(2)
    with pytest.raises(DatasetError, match="record 3 at offset .*: laser FRONT return 1: the zlib data is cut short"):
        segment.read(3)
    with pytest.raises(DatasetError, match="record 4 at offset .*: not a Waymo Frame"):
        segment.read(4)
    monkeypatch.setattr("xviz_server.datasets.waymo.segment.MAX_MATRIX_BYTES", 100)  # a 2 x 4 x 4 matrix is 140 bytes
    with pytest.raises(
        DatasetError, match="record 0 at offset 0: laser FRONT return 1: more than 100 bytes decompressed"
    ):
        segment.read(0)


def test_convert_command_and_the_client_reads_it(scene, tmp_path: Path):
    tfrecord, _, _ = scene
    command = [
        sys.executable,
        "-m",
        "xviz_server",
        "convert",
        "waymo",
        str(tfrecord),
        str(tmp_path / "log"),
        "--frames",
        "1:3",
    ]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "converting 2 of 2 frames of segment-15 to" in done.stderr
    report = check_paths([tmp_path / "log"])
    assert report.ok, report.render()
    files = sorted((tmp_path / "log").glob("*-frame.glb"), key=lambda p: int(p.name.split("-")[0]))
    assert [f.name for f in files] == ["1-frame.glb", "2-frame.glb", "3-frame.glb"]
    results = xviz_decode(files)
    assert all("error" not in r for r in results)
    streams = results[-1]["parsed"]["streams"]
    assert [f["id"] for f in streams["/objects/boxes"]["features"]] == ["car-a", "ped-b"]
    assert streams["/lidar/points"]["pointCloud"]["numInstances"] > 150


async def test_serve_a_segment_file(scene):
    tfrecord, _, _ = scene
    async with running_server(None, dataset=[f"waymo:{tfrecord}"]) as server, client(server, "/segment-15") as c:
        metadata = await c.recv()
        assert "/lidar/points" in metadata["data"]["streams"]
        await c.send("transform_log", {"id": "w"})
        assert timestamps(await c.until("transform_log_done", "w")) == [1557000000.0, 1557000000.1, 1557000000.2]


async def test_a_corrupt_record_is_an_error_and_the_rest_is_served(scene):
    tfrecord, _, _ = scene
    record = RecordFile(tfrecord).records[1]
    data = bytearray(tfrecord.read_bytes())
    data[record.offset + 12 + record.length - 10] ^= 0x55
    tfrecord.write_bytes(bytes(data))
    async with running_server(None, dataset=[f"waymo:{tfrecord}"]) as server, client(server, "/segment-15") as c:
        await c.recv()
        await c.send("transform_log", {"id": "w"})
        messages = await c.until("transform_log_done", "w")
        errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
        assert timestamps(messages) == [1557000000.0, 1557000000.2]
        # The log's name and the cause; not where the file is.
        assert (
            len(errors) == 1
            and f"of log 'segment-15': record 1 at offset {record.offset}: data CRC mismatch" in errors[0]
        )
        assert str(tfrecord.parent) not in errors[0]


def test_glb_of_a_frame_encodes(scene):
    tfrecord, _, _ = scene
    segment = WaymoRecordSegment(tfrecord)
    assert encode(envelope("state_update", segment.convert(0)), Format.BINARY)[:4] == b"glTF"


async def test_segments_are_found_under_the_data_dir_and_in_a_folder_given(tmp_path: Path):
    record = frame(T0, np.eye(4), [calibration("FRONT", np.eye(4), (), -0.2, 0.2)], {})
    (tmp_path / "store" / "waymo").mkdir(parents=True)
    for name in ("segment-a", "segment-b"):
        write_segment(tmp_path / "store" / "waymo" / f"{name}.tfrecord", [record])
    (tmp_path / "store" / "waymo" / "notes.txt").write_text("not a segment")
    async with running_server(tmp_path / "store") as server:
        assert server.shelf.names() == ["waymo/segment-a", "waymo/segment-b"]
    async with running_server(None, dataset=[f"waymo:{tmp_path / 'store' / 'waymo'}"]) as server:
        assert server.shelf.names() == ["segment-a", "segment-b"]
        async with client(server, "/?log=segment-b") as c:
            assert (await c.recv())["data"]["log_info"]["start_time"] == pytest.approx(T0 / 1e6, abs=1e-6)


def _scale_in_child(data: bytes, queue: Any) -> None:
    queue.put(scale_jpegs({"FRONT": data}, 400)["FRONT"].result(timeout=30)[:2])


def test_images_are_scaled_in_a_process_forked_after_the_parent_scaled_some():
    """The threads scaling a frame's images are the process's own: a forked child makes new ones."""
    import multiprocessing

    data = jpeg_image(1920, 1280, (90, 120, 150))
    assert (
        scale_jpegs({"FRONT": data}, 400)["FRONT"].result(timeout=30)[:2] == b"\xff\xd8"
    )  # the parent's threads start
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_scale_in_child, args=(data, queue))
    child.start()
    try:
        assert queue.get(timeout=60) == b"\xff\xd8"
    finally:
        child.join(10)
        if child.is_alive():
            child.kill()
