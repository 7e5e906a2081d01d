"""Waymo segments as per-frame dictionaries: geometry, streams, conversion and serving."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from helpers import client, running_server, timestamps, xviz_decode
from xviz_server.codec import Format, encode
from xviz_server.convert import convert
from xviz_server.datasets import detect, open_dataset
from xviz_server.datasets.shared import pose_angles
from xviz_server.datasets.waymo import WaymoSegment
from xviz_server.exceptions import DatasetError
from xviz_server.messages import envelope
from xviz_server.validate import check_paths
from xviz_server.validation import get_validator

HEADING = math.radians(30)


def rotation(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def write_segment(directory: Path, frames: int = 3) -> Path:
    """A segment in the waymoframe2dict layout with known points and boxes."""
    directory.mkdir(parents=True)
    rng = np.random.default_rng(3)
    for i in range(frames):
        pose = np.eye(4, dtype=np.float32)
        pose[:3, :3] = rotation(0.1 * i)
        pose[:3, 3] = [100.0 + i, 50.0, 2.0]
        top = np.zeros((4, 8, 6), np.float32)
        top[..., 0] = 10.0
        top[0, :, 0] = 0.0  # no return: left out
        top[..., 1] = rng.uniform(0, 1, (4, 8))
        top[..., 3:6] = rng.uniform(-20, 20, (4, 8, 3))
        nlz = -np.ones((4, 8), np.float32)
        nlz[3, :2] = 1  # two returns in a no-label zone
        front = np.zeros((2, 4, 6), np.float32)
        front[..., 0] = 3.0
        front[..., 3:6] = 1.0
        image = np.zeros((40, 60, 3), np.uint8)
        image[:, :, 0] = 200
        np.savez(
            directory / f"{1_557_000_000_000_000 + i * 100_000}.npz",
            POSE=pose,
            TOP_RANGE_IMAGE_FIRST_RETURN=top,
            TOP_IN_NLZ=nlz,
            TOP_BEAM_INCLINATION=np.linspace(-0.3, 0.04, 4).astype(np.float32),
            TOP_LIDAR_EXTRINSIC=np.eye(4, dtype=np.float32),
            FRONT_RANGE_IMAGE_FIRST_RETURN=front,
            FRONT_IMAGE=image,
            FRONT_INTRINSIC=np.zeros(9, np.float32),
            FRONT_EXTRINSIC=np.eye(4, dtype=np.float32),
            FRONT_WIDTH=np.int64(60),
            FRONT_HEIGHT=np.int64(40),
            LABEL_BOXES=np.array([[10.0, 5.0, 1.0, 4.0, 2.0, 1.6, HEADING], [3.0, -2.0, 0.9, 0.8, 0.6, 1.8, 0.0]]),
            LABEL_TYPES=np.array([1, 2]),
            LABEL_IDS=np.array(["car-a", "ped-b"]),
        )
    return directory


@pytest.fixture
def segment(tmp_path: Path) -> Path:
    return write_segment(tmp_path / "segment-1")


def test_points_come_from_the_xyz_channels_where_range_is_positive(segment: Path):
    waymo = WaymoSegment(segment)
    assert detect(segment) == "waymo" and len(waymo) == 3
    assert waymo.times.tolist() == [1557000000.0, 1557000000.1, 1557000000.2]
    update = waymo.convert(0)["updates"][0]
    with np.load(segment / "1557000000000000.npz") as data:
        top, nlz, front = (
            data["TOP_RANGE_IMAGE_FIRST_RETURN"],
            data["TOP_IN_NLZ"],
            data["FRONT_RANGE_IMAGE_FIRST_RETURN"],
        )
    valid = top[..., 0] > 0
    outside = valid & (nlz <= 0)
    expected = np.concatenate([top[outside][:, 3:6], front.reshape(-1, 6)[:, 3:6]])
    points = update["primitives"]["/lidar/points"]["points"][0]["points"]
    assert np.array_equal(points, expected.astype(np.float32))
    zone = update["primitives"]["/lidar/no_label_zone"]["points"][0]["points"]
    assert np.array_equal(zone, top[valid & (nlz > 0)][:, 3:6])
    assert len(points) + len(zone) == valid.sum() + front.shape[0] * front.shape[1]


def test_box_footprints_are_rotated_by_their_heading(segment: Path):
    update = WaymoSegment(segment).convert(1)["updates"][0]
    car, pedestrian = update["primitives"]["/objects/boxes"]["polygons"]
    assert car["base"]["object_id"] == "car-a" and car["base"]["classes"] == ["Vehicle"]
    assert pedestrian["base"]["classes"] == ["Pedestrian"] and car["base"]["style"] == {
        "stroke_color": "#50B3FF",
        "height": 1.6,
    }
    corners = car["vertices"].astype(np.float64)
    assert np.allclose(corners.mean(axis=0)[:2], [10.0, 5.0], atol=1e-5)
    assert np.allclose(corners[:, 2], 1.0 - 0.8, atol=1e-5)  # the box bottom
    front_edge = corners[0] - corners[3]  # from the back-right to the front-right corner
    length_edge = corners[0] - corners[1]
    assert math.atan2(length_edge[1], length_edge[0]) == pytest.approx(HEADING, abs=1e-5)
    assert np.linalg.norm(length_edge[:2]) == pytest.approx(4.0, abs=1e-5)
    assert np.linalg.norm(front_edge[:2]) == pytest.approx(2.0, abs=1e-5)


def test_pose_and_camera(segment: Path):
    update = WaymoSegment(segment, image_max_width=30).convert(2)["updates"][0]
    pose = update["poses"]["/vehicle_pose"]
    assert pose["position"] == pytest.approx([102.0, 50.0, 2.0])
    assert pose["orientation"] == pytest.approx([0.0, 0.0, 0.2], abs=1e-6)
    assert pose_angles(rotation(-2.0)) == pytest.approx((0.0, 0.0, -2.0))
    from PIL import Image

    image = update["primitives"]["/camera/front"]["images"][0]
    with Image.open(io.BytesIO(bytes(image["data"]))) as picture:
        assert picture.format == "JPEG" and picture.size == (30, 20)
        assert picture.getpixel((15, 10))[0] > 180


def test_everything_validates_and_the_client_reads_it(segment: Path, tmp_path: Path):
    waymo = WaymoSegment(segment)
    metadata = waymo.metadata()
    files = [tmp_path / "1-frame.glb", tmp_path / "2-frame.glb"]
    files[0].write_bytes(encode(envelope("metadata", metadata), Format.BINARY))
    files[1].write_bytes(encode(envelope("state_update", waymo.convert(0, metadata)), Format.BINARY))
    get_validator().validate_message(envelope("metadata", metadata))
    get_validator().validate_message(envelope("state_update", waymo.convert(0, metadata)))
    _, state = xviz_decode(files)
    assert "error" not in state
    streams = state["parsed"]["streams"]
    assert [f["id"] for f in streams["/objects/boxes"]["features"]] == ["car-a", "ped-b"]
    assert (
        streams["/lidar/points"]["pointCloud"]["numInstances"] == 3 * 8 - 2 + 2 * 4
    )  # TOP rows with returns, outside the zone, and FRONT


def test_corrupt_frame_is_named(segment: Path):
    bad = segment / "1557000000100000.npz"
    bad.write_bytes(b"not a zip")
    waymo = open_dataset("waymo", segment)
    with pytest.raises(DatasetError, match="1557000000100000.npz: not a readable frame dictionary"):
        waymo.convert(1)


async def test_convert_and_serve(segment: Path, tmp_path: Path):
    convert("waymo", segment, tmp_path / "log", processes=1)
    report = check_paths([tmp_path / "log"])
    assert report.ok, report.render()
    async with running_server(None, dataset=[f"waymo:{segment}"]) as server, client(server, "/segment-1") as c:
        await c.recv()
        await c.send("transform_log", {"id": "w"})
        assert timestamps(await c.until("transform_log_done", "w")) == [1557000000.0, 1557000000.1, 1557000000.2]
