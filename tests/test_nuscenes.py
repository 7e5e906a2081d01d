"""nuScenes scenes: every sweep a frame, every camera image served once, boxes interpolated, scenes found and served."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import numpy as np
import pytest

from devkit.nuscenes_scene import LIDAR_ON_CAR, car, ego, sweep_points, write_nuscenes
from helpers import client, foxglove_client, http_get, running_server, timestamps
from xviz_server.datasets import detect, nuscenes, open_dataset
from xviz_server.exceptions import DatasetError, FrameSizeError


@pytest.fixture
def root(tmp_path: Path):
    return write_nuscenes(tmp_path / "nuscenes", scenes=("scene-0061", "scene-0103"))


def frame_times(root, scene: str) -> list[int]:
    """Every sweep, and the camera images before the first sweep or after the last."""
    sweeps = root.lidar[scene]
    return sorted({*sweeps, *(t for _, t in root.images[scene] if not sweeps[0] <= t <= sweeps[-1])})


def test_every_lidar_sweep_is_a_frame_at_its_own_time(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0103")
    assert scene.name == "scene-0103"
    assert (
        sum(root.keys["scene-0103"]) == 3 and len(root.lidar["scene-0103"]) == 25
    )  # 3 key frames, 22 sweeps around them
    assert scene.times.tolist() == [t / 1e6 for t in frame_times(root, "scene-0103")]
    assert len(scene) == 26  # and the cameras' images after the last sweep, taken at once
    last = scene.convert(len(scene) - 1)["updates"][0]
    assert "/lidar/points" not in last["primitives"] and "/camera/cam_back" in last["primitives"]


def test_every_camera_image_is_served_once_in_the_first_frame_at_or_after_it(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    lidar = frame_times(root, "scene-0061")
    served = []
    for index in range(len(scene)):
        for camera, capture in scene._images[index].items():
            served.append((camera, int(capture["timestamp"])))
            assert capture["timestamp"] <= lidar[index]
            assert index == 0 or capture["timestamp"] > lidar[index - 1]
    images = root.images["scene-0061"]
    # Cameras at 12 Hz, sweeps at 20 Hz: no frame holds two images of a camera, so every image is served.
    assert sorted(served) == sorted(images)
    for index in range(len(scene)):
        cameras = {f"/camera/{c.lower()}" for c in scene._images[index]}
        assert cameras == {
            stream for stream in scene.convert(index)["updates"][0]["primitives"] if stream.startswith("/camera/")
        }


def test_points_are_in_the_vehicle_frame_by_the_sensors_calibration(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    update = scene.convert(4)["updates"][0]
    points = update["primitives"]["/lidar/points"]["points"][0]["points"]
    cloud = sweep_points(4)
    # LIDAR_TOP is turned by 90 degrees on the car: the sensor's x is the car's y.
    expected = np.column_stack(
        [-cloud[:, 1] + LIDAR_ON_CAR[0], cloud[:, 0] + LIDAR_ON_CAR[1], cloud[:, 2] + LIDAR_ON_CAR[2]]
    )
    assert np.abs(np.asarray(points) - expected).max() < 1e-4


def test_the_pose_is_the_captures_ego_pose(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    micros = root.lidar["scene-0061"][7]
    pose = scene.convert(7)["updates"][0]["poses"]["/vehicle_pose"]
    position, heading = ego(micros, root.starts["scene-0061"])
    assert pose["position"] == pytest.approx(position)
    assert pose["orientation"] == pytest.approx([0, 0, heading], abs=1e-9)


def _box(update: dict, instance: str) -> tuple[np.ndarray, str]:
    boxes = update["primitives"]["/objects/boxes"]["polygons"]
    polygon = next(b for b in boxes if b["base"]["object_id"] == instance)
    label = next(t for t in update["primitives"]["/objects/label"]["texts"] if t["base"]["object_id"] == instance)
    return np.asarray(polygon["vertices"]).mean(axis=0), label["text"]


@pytest.mark.parametrize("index", [2, 5, 12, 22])  # a key frame, sweeps between key frames, the last key frame
def test_boxes_are_the_key_frames_interpolated_to_each_sweep(root, index: int):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    start, micros = root.starts["scene-0061"], root.lidar["scene-0061"][index]
    update = scene.convert(index)["updates"][0]
    centre, text = _box(update, "scene-00")  # instance tokens are shortened to their first 8 characters
    (x, y, z), _ = car(micros, start)  # the car drives straight at a steady speed: interpolation is exact
    position, heading = ego(micros, start)
    dx, dy = x - position[0], y - position[1]
    expected = (dx * math.cos(heading) + dy * math.sin(heading), -dx * math.sin(heading) + dy * math.cos(heading))
    assert centre[:2] == pytest.approx(expected, abs=1e-6)
    assert text == "vehicle.car scene-00"


def test_an_object_in_one_key_frame_only_is_kept_from_the_nearer(tmp_path: Path):
    written = write_nuscenes(tmp_path / "n", keys=3)
    scene = open_dataset("nuscenes", written.root)
    categories = [
        sorted(
            label["text"].split()[0]
            for label in scene.convert(i)["updates"][0]["primitives"]["/objects/label"]["texts"]
        )
        for i in range(len(scene))
    ]
    # The pedestrian is annotated in key frames 0 and 1 (sweeps 2 and 12), not 2 (sweep 22): it is shown up to the
    # middle between key frames 1 and 2, and not after.
    assert all("human.pedestrian.adult" in c for c in categories[:17])
    assert all("human.pedestrian.adult" not in c for c in categories[18:])


def test_a_root_with_several_scenes_needs_one_named(root):
    with pytest.raises(DatasetError, match=r"2 scenes; name one with \?scene=NAME: scene-0061, scene-0103"):
        open_dataset("nuscenes", root.root)
    with pytest.raises(DatasetError, match=r"no scene 'scene-9999'"):
        open_dataset("nuscenes", root.root, scene="scene-9999")
    assert nuscenes.scenes(root.root) == ["scene-0061", "scene-0103"]


def test_found_by_its_layout(root, tmp_path: Path):
    assert detect(root.root) == "nuscenes"
    assert detect(root.root / "samples") is None
    (tmp_path / "other" / "samples").mkdir(parents=True)
    assert detect(tmp_path / "other") is None


def test_a_missing_or_corrupt_sweep_is_named_and_the_rest_is_served(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    sweep = root.root / scene._frames[3]["filename"]
    sweep.write_bytes(sweep.read_bytes()[:-6])
    with pytest.raises(DatasetError, match=r"\.pcd\.bin: 7194 bytes, not whole points of 5 float32"):
        scene.convert(3)
    sweep.unlink()
    with pytest.raises(DatasetError, match=r"\.pcd\.bin: cannot read"):
        scene.convert(3)
    assert scene.convert(4)["updates"][0]["primitives"]["/lidar/points"]


def test_a_table_over_the_limit_is_refused_before_it_is_read(root, monkeypatch):
    monkeypatch.setattr(nuscenes, "MAX_TABLE_BYTES", 100)
    with pytest.raises(DatasetError, match=r"scene\.json: \d+ bytes, more than the 100 a table may have"):
        open_dataset("nuscenes", root.root, scene="scene-0061")


async def test_each_scene_is_a_log_served_over_the_protocol(root):
    async with running_server(None, dataset=[f"nuscenes:{root.root}"]) as server:
        assert server.shelf.names() == ["scene-0061", "scene-0103"]
        async with client(server, "/?log=scene-0103") as c:
            metadata = (await c.recv())["data"]
            assert {
                "/vehicle_pose",
                "/lidar/points",
                "/objects/boxes",
                "/vehicle/trajectory",
                "/camera/cam_front",
            } <= set(metadata["streams"])
            await c.send("transform_log", {"id": "n"})
            assert timestamps(await c.until("transform_log_done", "n")) == [
                t / 1e6 for t in frame_times(root, "scene-0103")
            ]


async def test_the_scenes_of_a_root_in_a_data_dir_are_listed_and_served(tmp_path: Path):
    written = write_nuscenes(tmp_path / "store" / "nuscenes-mini", scenes=("scene-0061", "scene-0103"))
    (tmp_path / "store" / "one").mkdir()
    write_nuscenes(tmp_path / "store" / "one" / "nuscenes", scenes=("scene-0553",))
    async with running_server(tmp_path / "store") as server:
        assert server.shelf.names() == ["nuscenes-mini/scene-0061", "nuscenes-mini/scene-0103", "one/nuscenes"]
        async with client(server, "/?log=nuscenes-mini/scene-0103") as c:
            metadata = (await c.recv())["data"]
            assert metadata["log_info"]["start_time"] == pytest.approx(written.lidar["scene-0103"][0] / 1e6)
        for _ in range(300):  # the catalog reads each scene's facts in the background
            status, _, body = await asyncio.to_thread(http_get, server.port, "/api/logs/nuscenes-mini/scene-0103")
            one = json.loads(body)
            if one.get("state") != "found":
                break
            await asyncio.sleep(0.1)
        assert status == 200 and one["state"] == "indexed" and one["kind"] == "nuscenes"
        assert one["frames"] == len(frame_times(written, "scene-0103"))


async def test_the_published_foxglove_client_gets_every_sweep_and_image_as_channels(root):
    async with running_server(None, dataset=[f"nuscenes:{root.root}?scene=scene-0061"]) as server:
        out = await foxglove_client(f"ws://127.0.0.1:{server.port}/?log=nuscenes", "foxglove.websocket.v1")
    assert out["errors"] == [] and out["statuses"] == []
    schemas = {channel["topic"]: channel["schemaName"] for channel in out["channels"]}
    assert (
        schemas["/lidar/points"] == "foxglove.PointCloud" and schemas["/camera/cam_front"] == "foxglove.CompressedImage"
    )
    assert schemas["/objects/boxes"] == "foxglove.SceneUpdate"
    clouds = out["topics"]["/lidar/points"]
    sent = [
        int(t) for t in clouds["timestamps"]
    ]  # each sweep at its own time (XVIZ times are float seconds: to the µs)
    assert len(sent) == len(root.lidar["scene-0061"])
    assert all(abs(ns - t * 1000) < 1000 for ns, t in zip(sent, root.lidar["scene-0061"]))
    assert len(out["topics"]["/camera/cam_front"]["summaries"]) == sum(
        c == "CAM_FRONT" for c, _ in root.images["scene-0061"]
    )


def test_a_frame_whose_files_pass_the_frame_budget_is_refused_unread(root):
    scene = open_dataset("nuscenes", root.root, scene="scene-0061")
    index = next(i for i in range(len(scene)) if len(scene._images[i]) == 2 and scene._is_sweep(scene._frames[i]))
    for capture in [*scene._images[index].values(), scene._frames[index]]:
        with open(root.root / capture["filename"], "r+b") as file:  # sparse: 60 MiB each, nothing written
            file.truncate(60 << 20)
    with pytest.raises(
        FrameSizeError, match=rf"scene-0061: frame {index}: its messages and images would unpack 180 MiB"
    ):
        scene.convert(index)
    assert scene.convert(index + 1)
