"""Waymo Open Dataset v2 (a Parquet file per component): the same log as v1, found by its layout, bounded, served."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyarrow", reason="Waymo v2 segments need pyarrow: pip install 'xviz-server[parquet]'")

import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

from devkit.waymo_scene import T0, write_scene, write_v2_scene  # noqa: E402
from helpers import client, running_server, timestamps  # noqa: E402
from xviz_server.datasets import detect, open_dataset  # noqa: E402
from xviz_server.datasets.waymo import parquet  # noqa: E402
from xviz_server.datasets.waymo.segment import WaymoRecordSegment  # noqa: E402
from xviz_server.exceptions import DatasetError, FrameSizeError  # noqa: E402

SEGMENT = "15_000_020_000"


@pytest.fixture
def v2(tmp_path: Path) -> Path:
    return write_v2_scene(tmp_path / "training", segment=SEGMENT)


@pytest.mark.parametrize("rows_move", [False, True], ids=["columns-move", "rows-move"])
def test_v2_and_tfrecord_give_the_same_log(tmp_path: Path, rows_move: bool):
    tfrecord, _, expectations = write_scene(tmp_path / "v1", rows_move=rows_move)
    v1 = WaymoRecordSegment(tfrecord)
    segment = open_dataset("waymo", write_v2_scene(tmp_path / "training", rows_move=rows_move, segment=SEGMENT))
    assert segment.name == SEGMENT
    assert np.array_equal(segment.times, v1.times)
    assert segment.metadata()["streams"] == v1.metadata()["streams"]
    for index in range(3):
        ours, theirs = segment.convert(index)["updates"][0], v1.convert(index)["updates"][0]
        assert ours["timestamp"] == theirs["timestamp"]
        assert ours["poses"] == theirs["poses"]
        assert ours["primitives"].keys() == theirs["primitives"].keys()
        for stream in ("/lidar/points", "/lidar/no_label_zone"):
            a, b = ours["primitives"][stream]["points"][0], theirs["primitives"][stream]["points"][0]
            assert np.array_equal(a["points"], b["points"]) and np.array_equal(a.get("colors"), b.get("colors"))
        for stream in ("/objects/boxes", "/objects/label", "/camera/front"):
            assert str(ours["primitives"][stream]) == str(theirs["primitives"][stream])
        # and the points are those the scene's rays hit, computed independently of the server's geometry
        points = ours["primitives"]["/lidar/points"]["points"][0]["points"]
        zone = ours["primitives"]["/lidar/no_label_zone"]["points"][0]["points"]
        expected = [p for laser in ("TOP", "FRONT") for returns in expectations[index][laser] for p, _, _ in returns]
        assert len(points) + len(zone) == len(expected)


def test_a_segment_is_found_by_its_layout_and_several_are_listed(tmp_path: Path, v2: Path):
    assert detect(v2) == "waymo"
    assert detect(tmp_path / "training") == "waymo"  # a folder of components holding one segment
    assert detect(tmp_path / "training" / "lidar" / f"{SEGMENT}.parquet") is None  # found by its vehicle_pose file
    write_v2_scene(tmp_path / "training", frames=2, segment="16_000_020_000")
    assert detect(tmp_path / "training") is None  # two segments: each is found by its own file
    assert detect(tmp_path / "training" / "vehicle_pose" / "16_000_020_000.parquet") == "waymo"


async def test_every_segment_of_a_data_dir_is_served(tmp_path: Path):
    write_v2_scene(tmp_path / "store" / "training", segment=SEGMENT)
    write_v2_scene(tmp_path / "store" / "training", frames=2, segment="16_000_020_000")
    async with running_server(tmp_path / "store") as server:
        names = server.shelf.names()
        assert names == [f"training/vehicle_pose/{SEGMENT}", "training/vehicle_pose/16_000_020_000"]
        async with client(server, f"/?log=training/vehicle_pose/{SEGMENT}") as c:
            metadata = await c.recv()
            assert {"/vehicle_pose", "/lidar/points", "/objects/boxes", "/camera/front"} <= set(
                metadata["data"]["streams"]
            )
            await c.send("transform_log", {"id": "w"})
            assert timestamps(await c.until("transform_log_done", "w")) == [T0 / 1e6, T0 / 1e6 + 0.1, T0 / 1e6 + 0.2]


def test_a_segment_without_some_components_is_served_without_what_they_give(v2: Path):
    root = v2.parent.parent
    for part in ("lidar_box", "camera_image", "lidar_pose"):
        (root / part / f"{SEGMENT}.parquet").unlink()
    segment = open_dataset("waymo", v2)
    update = segment.convert(1)["updates"][0]
    assert "/camera/front" not in segment.metadata()["streams"] and "/objects/boxes" not in update["primitives"]
    assert len(update["primitives"]["/lidar/points"]["points"][0]["points"]) > 0


def test_a_range_image_that_lies_about_its_shape_is_named_and_the_rest_is_served(v2: Path):
    lidar = v2.parent.parent / "lidar" / f"{SEGMENT}.parquet"
    table = pq.read_table(lidar)
    shapes = table["[LiDARComponent].range_image_return1.shape"].to_pylist()
    shapes[2] = [6, 25, 4]  # frame 1's TOP laser: one column more than its values hold
    column = table.schema.get_field_index("[LiDARComponent].range_image_return1.shape")
    pq.write_table(
        table.set_column(column, "[LiDARComponent].range_image_return1.shape", pa.array(shapes, pa.list_(pa.int32()))),
        lidar,
    )
    segment = open_dataset("waymo", v2)
    with pytest.raises(
        DatasetError, match=rf"segment {SEGMENT}, frame {T0 + 100_000}: laser TOP .*576 values for shape \[6, 25, 4\]"
    ):
        segment.convert(1)
    assert segment.convert(0) and segment.convert(2)


def test_a_row_group_declaring_more_than_the_limit_is_refused_before_it_is_read(v2: Path, monkeypatch):
    lidar = v2.parent.parent / "lidar" / f"{SEGMENT}.parquet"
    declared = pq.ParquetFile(lidar).metadata.row_group(0).total_byte_size
    monkeypatch.setattr(parquet, "MAX_ROW_GROUP_BYTES", declared - 1)
    segment = open_dataset("waymo", v2)
    with pytest.raises(DatasetError, match=rf"lidar/{SEGMENT}.parquet: row group 0 declares {declared} bytes"):
        segment.convert(0)


def test_a_file_that_is_not_parquet_is_named(v2: Path):
    (v2.parent.parent / "lidar" / f"{SEGMENT}.parquet").write_bytes(b"PAR1 but not really")
    with pytest.raises(DatasetError, match=rf"lidar/{SEGMENT}.parquet: not a Parquet file"):
        open_dataset("waymo", v2).convert(0)


def test_without_pyarrow_the_error_names_the_extra(v2: Path):
    script = (
        "import sys; sys.modules['pyarrow'] = None\n"  # as if pyarrow were not installed
        "from xviz_server.datasets import open_dataset\n"
        "from xviz_server.exceptions import DatasetError\n"
        f"try:\n    open_dataset('waymo', {str(v2)!r})\nexcept DatasetError as exc:\n    print(exc)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert (
        out.stdout.strip()
        == "reading Waymo v2 segments needs the package 'pyarrow': pip install 'xviz-server[parquet]'"
    ), out.stderr


def test_a_frame_whose_row_groups_declare_more_than_the_frame_budget_is_refused_unread(v2: Path, monkeypatch):
    from xviz_server import unpack

    root = v2.parent.parent
    declared = sum(
        pq.ParquetFile(root / part / f"{SEGMENT}.parquet").metadata.row_group(0).total_byte_size
        for part in parquet.COMPONENTS[1:]
    )
    monkeypatch.setattr(unpack, "MAX_FRAME_BYTES", declared - 1)
    with pytest.raises(FrameSizeError, match=rf"segment {SEGMENT}: frame \d: its messages and images would unpack"):
        open_dataset("waymo", v2).convert(1)
