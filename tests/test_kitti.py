"""KITTI raw drives: the conversion reproduces the official XVIZ log, and serves on demand."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from serving import client, running_server, timestamps
from xviz_server.check import check_paths
from xviz_server.codec import decode
from xviz_server.datasets import detect
from xviz_server.datasets.kitti import KittiDrive, footprints, read_tracklets
from xviz_server.exceptions import DatasetError

TRACKLETS = """<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>
<!DOCTYPE boost_serialization>
<boost_serialization signature="serialization::archive" version="9">
<tracklets class_id="0" tracking_level="0" version="0">
	<count>2</count>
	<item_version>1</item_version>
	<item class_id="1" tracking_level="0" version="1">
		<objectType>Car</objectType>
		<h>1.5</h>
		<w>1.8</w>
		<l>4.0</l>
		<first_frame>0</first_frame>
		<poses class_id="2" tracking_level="0" version="0">
			<count>2</count>
			<item_version>2</item_version>
			<item class_id="3" tracking_level="0" version="2">
				<tx>10.0</tx><ty>2.0</ty><tz>-1.7</tz><rx>0.0</rx><ry>0.0</ry><rz>1.5707963267948966</rz>
				<state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation>
				<amt_occlusion>0.0</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
				<amt_border_l>0.0</amt_border_l><amt_border_r>0.0</amt_border_r><amt_border_kf>-1</amt_border_kf>
			</item>
			<item>
				<tx>11.0</tx><ty>2.0</ty><tz>-1.7</tz><rx>0.0</rx><ry>0.0</ry><rz>0.0</rz>
				<state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation>
				<amt_occlusion>0.0</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
				<amt_border_l>0.0</amt_border_l><amt_border_r>0.0</amt_border_r><amt_border_kf>-1</amt_border_kf>
			</item>
		</poses>
		<finished>1</finished>
	</item>
	<item>
		<objectType>Pedestrian</objectType>
		<h>1.8</h>
		<w>0.6</w>
		<l>0.8</l>
		<first_frame>1</first_frame>
		<poses>
			<count>1</count>
			<item_version>2</item_version>
			<item>
				<tx>5.0</tx><ty>-3.0</ty><tz>-1.7</tz><rx>0.0</rx><ry>0.0</ry><rz>0.0</rz>
				<state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation>
				<amt_occlusion>0.0</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
				<amt_border_l>0.0</amt_border_l><amt_border_r>0.0</amt_border_r><amt_border_kf>-1</amt_border_kf>
			</item>
		</poses>
		<finished>1</finished>
	</item>
</tracklets>
</boost_serialization>
"""


@pytest.fixture(scope="module")
def raw(shared_dir: Path) -> Path:
    return shared_dir / "data" / "kitti-raw-2011_09_26_drive_0001-head"


@pytest.fixture(scope="module")
def drive(raw: Path) -> KittiDrive:
    return KittiDrive(raw)


@pytest.fixture
def own_copy(raw: Path, tmp_path: Path) -> Path:
    """The raw data as links, so that a test may add, break or remove files."""
    copy = tmp_path / "raw"
    shutil.copytree(raw, copy, copy_function=os.symlink)
    return copy / "2011_09_26" / "2011_09_26_drive_0001_sync"


def official(kitti_log: Path, frame: int) -> dict:
    return decode((kitti_log / f"{frame + 2}-frame.glb").read_bytes())["data"]["updates"][0]


def test_drive_is_recognised_by_its_layout(raw: Path, drive: KittiDrive, tmp_path: Path):
    assert drive.path.name == "2011_09_26_drive_0001_sync" and len(drive) == 25
    assert detect(drive.path) == "kitti" and detect(raw) is None and detect(tmp_path) is None
    with pytest.raises(DatasetError, match="not a KITTI raw drive"):
        KittiDrive(tmp_path)


def test_times_and_metadata_come_from_timestamps_and_calibration(drive: KittiDrive, kitti_log: Path):
    index = json.loads((kitti_log / "0-frame.json").read_text())
    assert drive.times.tolist() == [row[0] for row in index["timing"]]
    theirs = decode((kitti_log / "1-frame.glb").read_bytes())["data"]
    ours = drive.metadata()
    assert ours["streams"]["/lidar/points"]["transform"] == theirs["streams"]["/lidar/points"]["transform"]
    for stream in ("/vehicle_pose", "/lidar/points", "/vehicle/velocity", "/vehicle/acceleration", "/vehicle/trajectory", "/camera/image_02"):
        assert ours["streams"][stream]["category"] == theirs["streams"][stream]["category"]
    assert ours["log_info"]["start_time"] == index["startTime"]


def test_every_frame_reproduces_the_official_points_and_pose(drive: KittiDrive, kitti_log: Path):
    metadata = drive.metadata()
    for frame in range(len(drive)):
        ours = drive.convert(frame, metadata)["updates"][0]
        theirs = official(kitti_log, frame)
        mine_cloud = ours["primitives"]["/lidar/points"]["points"][0]
        their_cloud = theirs["primitives"]["/lidar/points"]["points"][0]
        assert np.array_equal(mine_cloud["points"], their_cloud["points"])  # exactly
        # red and green are exact; blue was lost to 1/80 steps when the raw files were rebuilt
        assert np.array_equal(mine_cloud["colors"][:, :2], their_cloud["colors"][:, :2])
        assert np.abs(mine_cloud["colors"][:, 2].astype(int) - their_cloud["colors"][:, 2]).max() <= 1
        pose, their_pose = ours["poses"]["/vehicle_pose"], theirs["poses"]["/vehicle_pose"]
        assert pose["timestamp"] == their_pose["timestamp"] == ours["timestamp"]
        for key in ("longitude", "latitude", "altitude"):
            assert pose["map_origin"][key] == pytest.approx(their_pose["map_origin"][key], abs=1e-6)
        assert pose["orientation"] == pytest.approx(their_pose["orientation"], abs=1e-6)
        series = {s: v for e in ours["time_series"] for s, v in zip(e["streams"], e["values"]["doubles"])}
        their_series = {s: v for e in theirs["time_series"] if "doubles" in e["values"] for s, v in zip(e["streams"], e["values"]["doubles"])}
        for stream in ("/vehicle/velocity", "/vehicle/acceleration"):
            assert series[stream] == pytest.approx(their_series[stream], abs=1e-9)
        for camera in ("image_00", "image_01", "image_02", "image_03"):
            image = ours["primitives"][f"/camera/{camera}"]["images"][0]
            assert bytes(image["data"]) == bytes(theirs["primitives"][f"/camera/{camera}"]["images"][0]["data"])
    first = drive.convert(0, metadata)["updates"][0]
    wheel = [v for e in first["time_series"] for s, v in zip(e["streams"], e["values"]["doubles"]) if s == "/vehicle/wheel_angle"]
    assert wheel == pytest.approx([-1.0776952781637164])  # the only frame whose angular rates are real


def test_trajectory_is_the_path_ahead_in_the_vehicle_frame(drive: KittiDrive, kitti_log: Path):
    ours = drive.convert(0)["updates"][0]["primitives"]["/vehicle/trajectory"]["polylines"][0]["vertices"]
    theirs = official(kitti_log, 0)["primitives"]["/vehicle/trajectory"]["polylines"][0]["vertices"]
    assert len(ours) == 25  # the rest of this 25-frame excerpt
    assert np.allclose(ours[:10, :2], theirs[:10, :2], atol=0.05)  # same path within 5 cm


def test_images_are_scaled_down_keeping_the_aspect(raw: Path):
    from PIL import Image

    narrow = KittiDrive(raw, image_max_width=200)
    data = narrow.image("image_02", 0)
    with Image.open(io.BytesIO(data)) as picture:
        assert picture.size == (200, 60)  # from 397 x 120


def test_tracklets_parse_and_draw(own_copy: Path):
    (own_copy / "tracklet_labels.xml").write_text(TRACKLETS)
    tracklets = read_tracklets(own_copy / "tracklet_labels.xml")
    assert [(t.object_type, t.first_frame, len(t.poses)) for t in tracklets] == [("Car", 0, 2), ("Pedestrian", 1, 1)]
    assert (tracklets[0].length, tracklets[0].width, tracklets[0].height) == (4.0, 1.8, 1.5)
    # yaw 90 degrees puts the length along y
    corners = footprints(np.array([[10.0, 2.0, -1.7]]), np.array([np.pi / 2]), np.array([4.0]), np.array([1.8]))[0]
    assert np.allclose(np.ptp(corners[:, 0]), 1.8) and np.allclose(np.ptp(corners[:, 1]), 4.0)
    assert np.allclose(corners[:, 2], -1.7)

    drive = KittiDrive(own_copy)
    metadata = drive.metadata()
    assert {"/tracklets/objects", "/tracklets/label", "/tracklets/tracking_point"} <= set(metadata["streams"])
    frame1 = drive.convert(1, metadata)["updates"][0]["primitives"]
    polygons = frame1["/tracklets/objects"]["polygons"]
    assert [p["base"]["classes"] for p in polygons] == [["Car"], ["Pedestrian"]]
    assert polygons[0]["base"]["style"] == {"height": 1.5}
    assert np.allclose(np.ptp(polygons[0]["vertices"][:, 0]), 4.0)  # yaw 0 in frame 1
    assert [t["text"] for t in frame1["/tracklets/label"]["texts"]] == ["Car-0", "Pedestrian-1"]
    assert "/tracklets/objects" not in drive.convert(2, metadata)["updates"][0]["primitives"]


def test_missing_and_corrupt_raw_files_are_named(own_copy: Path):
    velodyne = own_copy / "velodyne_points" / "data"
    (velodyne / "0000000003.bin").unlink()
    (velodyne / "0000000004.bin").unlink()
    (velodyne / "0000000004.bin").write_bytes(b"\x00" * 10)
    drive = KittiDrive(own_copy)
    with pytest.raises(DatasetError, match=r"0000000003\.bin: No such file"):
        drive.convert(3)
    with pytest.raises(DatasetError, match=r"0000000004\.bin: 10 bytes is not a whole number"):
        drive.convert(4)
    (own_copy / "tracklet_labels.xml").write_text("<tracklets><item>")
    with pytest.raises(DatasetError, match="tracklet_labels.xml: cannot read tracklets"):
        KittiDrive(own_copy).metadata()


def test_convert_command_writes_a_valid_log_and_resumes(raw: Path, tmp_path: Path):
    out = tmp_path / "log"
    command = [sys.executable, "-m", "xviz_server", "convert", "kitti", str(raw), str(out)]
    first = subprocess.run([*command, "--frames", "0:10"], capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    assert f"converting 10 of 10 frames of 2011_09_26_drive_0001_sync to {out} (BINARY) with {os.cpu_count()} processes" in first.stderr
    assert check_paths([out]).ok
    kept = (out / "5-frame.glb").stat().st_ino
    (out / "0-frame.json").unlink()
    (out / "9-frame.glb").unlink()  # as if interrupted before these
    again = subprocess.run([*command, "--frames", "0:10"], capture_output=True, text=True)
    assert "converting 1 of 10 frames" in again.stderr and "9 already written" in again.stderr
    assert (out / "5-frame.glb").stat().st_ino == kept
    report = check_paths([out])
    assert report.ok and len(report.files) == 12
    bad = subprocess.run([*command, "--frames", "x"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--frames 'x': give A:B" in bad.stderr


async def test_served_on_demand_and_errors_name_the_file(own_copy: Path, tmp_path: Path):
    (own_copy / "velodyne_points" / "data" / "0000000002.bin").unlink()
    root = own_copy.parent.parent  # holds 2011_09_26/<drive>
    async with running_server(root) as server:
        name = "2011_09_26/2011_09_26_drive_0001_sync"
        assert name in server.catalog.names()
        async with client(server, f"/?log={name}") as c:
            metadata = await c.recv()
            assert metadata["data"]["log_info"]["start_time"] == 1317042145.964
            await c.send("transform_log", {"id": "all"})
            messages = await c.until("transform_log_done", "all")
            errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
            assert len(timestamps(messages)) == 24
            assert len(errors) == 1 and "0000000002.bin" in errors[0] and "'all'" in errors[0]


async def test_dataset_given_explicitly_is_named_by_its_folder(raw: Path):
    async with running_server(None, dataset=[f"kitti:{raw}"]) as server:
        assert server.catalog.names() == [raw.name]
        async with client(server) as c:  # the only log
            assert (await c.recv())["type"] == "xviz/metadata"
            await c.send("transform_point_in_time", {"id": "p", "query_timestamp": 1317042146.0})
            state = await c.recv()
            assert state["data"]["update_type"] == "COMPLETE_STATE"
            assert state["data"]["updates"][0]["timestamp"] == 1317042145.964
