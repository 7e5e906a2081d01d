"""Argoverse 2 sensor logs: every sweep and camera image at its own time, cuboids moved with the car, disk and store."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyarrow", reason="Argoverse 2 logs need pyarrow: pip install 'xviz-server[parquet]'")

from devkit.argoverse2_log import CAMERAS, ego, sweep, write_av2_log  # noqa: E402
from devkit.s3 import moto_process, proxied  # noqa: E402
from helpers import client, running_server, timestamps  # noqa: E402
from xviz_server.datasets import argoverse2, detect, open_dataset  # noqa: E402
from xviz_server.exceptions import DatasetError, FrameSizeError  # noqa: E402

LOG = "0c6e62d7-bdfa-3061-8d3d-03b13aa21f68"


@pytest.fixture
def written(tmp_path: Path):
    return write_av2_log(tmp_path / "sensor" / "val" / LOG)


def clock(written) -> list[int]:
    """Every sweep and front camera image, and the other camera's images after them (none is left out)."""
    base = {*written.sweeps, *(stamp for camera, stamp in written.images if camera == CAMERAS[0])}
    return sorted(base | {stamp for camera, stamp in written.images if stamp > max(base)})


def test_frames_are_every_sweep_and_every_front_camera_image(written):
    log = open_dataset("argoverse2", written.folder)
    assert log.name == LOG and log.times.tolist() == [stamp / 1e9 for stamp in clock(written)]
    with_points = [i for i in range(len(log)) if "/lidar/points" in log.convert(i)["updates"][0]["primitives"]]
    assert [clock(written)[i] for i in with_points] == written.sweeps


def test_every_camera_image_is_served_once(written):
    log = open_dataset("argoverse2", written.folder)
    served = sorted(
        (camera, int(file.name.removesuffix(".jpg")))
        for frame in log._frames
        for camera, file in frame.items()
        if camera != "lidar"
    )
    assert served == sorted(written.images)  # 20 Hz cameras on a 20 Hz clock: none is lost
    for index in range(len(log)):
        streams = {s for s in log.convert(index)["updates"][0]["primitives"] if s.startswith("/camera/")}
        assert streams == {f"/camera/{camera}" for camera in log._frames[index] if camera != "lidar"}


def test_points_pose_and_cuboids(written):
    log = open_dataset("argoverse2", written.folder)
    index = log.times.tolist().index(written.sweeps[2] / 1e9)
    update = log.convert(index)["updates"][0]
    points = update["primitives"]["/lidar/points"]["points"][0]["points"]
    expected = sweep(2)
    assert np.array_equal(
        np.asarray(points), np.column_stack([expected["x"], expected["y"], expected["z"]]).astype(np.float32)
    )
    (x, y, _), heading = ego(written.sweeps[2])
    assert update["poses"]["/vehicle_pose"]["position"] == pytest.approx([x, y, 0.0])
    assert update["poses"]["/vehicle_pose"]["orientation"] == pytest.approx([0, 0, heading], abs=1e-9)
    labels = {t["text"] for t in update["primitives"]["/objects/label"]["texts"]}
    assert labels == {"REGULAR_VEHICLE 8f4a4fd6", "PEDESTRIAN 0b1c2d3e"}
    styles = {p["base"]["classes"][0] for p in update["primitives"]["/objects/boxes"]["polygons"]}
    assert styles == {"vehicle", "pedestrian"}


def test_between_sweeps_the_cuboids_stay_where_they_are_in_the_world(written):
    log = open_dataset("argoverse2", written.folder)
    after = next(i for i, t in enumerate(clock(written)) if t not in written.sweeps and t > written.sweeps[1])
    stamp = clock(written)[after]
    boxes = log.convert(after)["updates"][0]["primitives"]["/objects/boxes"]["polygons"]
    ped = next(b for b in boxes if b["base"]["object_id"] == "0b1c2d3e")
    # The pedestrian of the latest sweep (1), in that sweep's vehicle frame at (5 - 1, -3), seen from the car now.
    (x1, y1, _), h1 = ego(written.sweeps[1])
    world = (x1 + 4.0 * math.cos(h1) + 3.0 * math.sin(h1), y1 + 4.0 * math.sin(h1) - 3.0 * math.cos(h1))
    (x, y, _), h = ego(stamp)
    dx, dy = world[0] - x, world[1] - y
    centre = np.asarray(ped["vertices"]).mean(axis=0)
    assert centre[:2] == pytest.approx(
        (dx * math.cos(h) + dy * math.sin(h), -dx * math.sin(h) + dy * math.cos(h)), abs=1e-6
    )


def test_found_by_its_layout_and_a_log_without_annotations_is_served(tmp_path: Path, written):
    assert detect(written.folder) == "argoverse2" and detect(written.folder.parent) is None
    bare = write_av2_log(tmp_path / "test" / "other", annotated=False)
    update = open_dataset("argoverse2", bare.folder).convert(0)["updates"][0]
    assert "/objects/boxes" not in update["primitives"]


def test_a_corrupt_sweep_or_a_file_over_the_limit_is_named_and_the_rest_is_served(written, monkeypatch):
    log = open_dataset("argoverse2", written.folder)
    index = log.times.tolist().index(written.sweeps[3] / 1e9)
    (written.folder / "sensors" / "lidar" / f"{written.sweeps[3]}.feather").write_bytes(b"ARROW1\0\0 cut")
    with pytest.raises(DatasetError, match=rf"lidar/{written.sweeps[3]}\.feather: not a Feather file"):
        log.convert(index)
    assert log.convert(log.times.tolist().index(written.sweeps[4] / 1e9))["updates"][0]["primitives"]["/lidar/points"]
    monkeypatch.setattr(argoverse2, "MAX_FILE_BYTES", 100)
    with pytest.raises(DatasetError, match=r"\d+ bytes, more than the 100 a file may have"):
        log.convert(0)


@pytest.mark.slow  # moto's S3 server
async def test_a_log_is_served_from_a_folder_and_from_an_object_store(written, monkeypatch):
    async with running_server(written.folder.parent) as server:
        assert server.shelf.names() == [LOG]
        async with client(server, f"/?log={LOG}") as c:
            assert set(CAMERAS) <= {s.removeprefix("/camera/") for s in (await c.recv())["data"]["streams"]}
            await c.send("transform_log", {"id": "a"})
            on_disk = await c.until("transform_log_done", "a")
    with moto_process() as store:
        store.bucket("av2")
        store.upload(written.folder.parent.parent, "av2", "sensor")
        async with proxied(store, monkeypatch):
            async with running_server(["s3://av2/sensor"]) as server:
                assert server.shelf.names() == [f"val/{LOG}"]
                async with client(server, f"/?log=val/{LOG}") as c:
                    await c.recv()
                    await c.send("transform_log", {"id": "a"})
                    in_store = await c.until("transform_log_done", "a")
    assert timestamps(in_store) == timestamps(on_disk) == [t / 1e9 for t in clock(written)]
    states = [m["data"]["updates"][0] for m in on_disk if m["type"] == "xviz/state_update"]
    assert [s["primitives"].keys() for s in states] == [
        m["data"]["updates"][0]["primitives"].keys() for m in in_store if m["type"] == "xviz/state_update"
    ]


REAL = Path(__file__).parent / "data" / "argoverse2" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def test_a_real_log_of_the_av2_devkit_reads_with_its_cuboids_and_poses():
    import pyarrow.feather as feather

    log = open_dataset("argoverse2", REAL)
    sweeps = sorted(int(f.stem) for f in (REAL / "sensors" / "lidar").glob("*.feather"))
    assert log.times.tolist() == [
        stamp / 1e9 for stamp in sweeps
    ]  # no camera in this excerpt: the sweeps are the clock
    annotations = feather.read_table(REAL / "annotations.feather")
    poses = feather.read_table(REAL / "city_SE3_egovehicle.feather")
    for index, stamp in enumerate(sweeps):
        update = log.convert(index)["updates"][0]
        cloud = feather.read_table(REAL / "sensors" / "lidar" / f"{stamp}.feather")
        points = update["primitives"]["/lidar/points"]["points"][0]["points"]
        assert len(points) == cloud.num_rows and np.isfinite(points).all()
        expected = int((annotations["timestamp_ns"].to_numpy() == stamp).sum())
        assert expected > 0 and len(update["primitives"]["/objects/boxes"]["polygons"]) == expected
        row = int(np.flatnonzero(poses["timestamp_ns"].to_numpy() <= stamp)[-1])
        assert update["poses"]["/vehicle_pose"]["position"] == pytest.approx(
            [poses[c][row].as_py() for c in ("tx_m", "ty_m", "tz_m")]
        )


def test_a_frame_whose_files_pass_the_frame_budget_is_refused_unread(written):
    log = open_dataset("argoverse2", written.folder)
    index = next(i for i, frame in enumerate(log._frames) if "lidar" in frame and len(frame) == 2)
    for file in log._frames[index].values():
        with open(file, "r+b") as opened:  # sparse: 70 MiB each, nothing written
            opened.truncate(70 << 20)
    with pytest.raises(FrameSizeError, match=rf"frame {index}: its messages and images would unpack 140 MiB"):
        log.convert(index)


@pytest.mark.slow
async def test_a_real_log_in_the_store_whose_sweep_fails_mid_log_is_an_error_naming_it_and_served_on(monkeypatch):
    """A 404, then connections cut, on the real log's second sweep in moto's S3: that frame is an error naming the log,
    the frame and the object; the other frame is served; once the store answers again, every frame is."""
    name = f"val/{REAL.name}"
    first, second = sorted((REAL / "sensors" / "lidar").glob("*.feather"))
    with moto_process() as store:
        store.bucket("av2")
        store.upload(REAL.parent.parent, "av2", "sensor")
        async with proxied(store, monkeypatch) as proxy:
            async with running_server(["s3://av2/sensor"], store_retries=1) as server:
                await server.shelf.open(name)

                async def stream() -> list[dict]:
                    async with client(server, f"/?log={name}") as viewer:
                        assert (await viewer.recv())["type"] == "xviz/metadata"
                        await viewer.send("transform_log", {"id": "all"})
                        return await viewer.until("transform_log_done", "all")

                proxy.fault(second.name, status=404, times=1)
                missing = await stream()
                proxy.fault(second.name, cut_after=100)  # every try cut short
                cut = await stream()
                proxy.faults.clear()
                again = await stream()
    key = f"s3://av2/sensor/{name}/sensors/lidar/{second.name}"
    for messages, cause in ((missing, "no such object (404)"), (cut, "the connection failed or was cut short")):
        errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
        assert len(errors) == 1 and f"frame 1 of log {name!r}" in errors[0] and key in errors[0], errors
        assert cause in errors[0], errors
        assert timestamps(messages) == [int(first.stem) / 1e9]
    assert len(timestamps(again)) == 2 and not [m for m in again if m["type"] == "xviz/error"]
