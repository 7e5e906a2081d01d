"""PandaSet sequences: sweeps and cuboids moved into the vehicle frame, every image served, pickles that run code refused."""

from __future__ import annotations

import gzip
import math
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pandas", reason="PandaSet sequences need pandas: pip install 'xviz-server[pandaset]'")

from devkit.pandaset_sequence import CAMERAS, PARKED_POSITION, T0, local_points, pose, write_sequence  # noqa: E402
from helpers import client, running_server, timestamps  # noqa: E402
from xviz_server.datasets import detect, open_dataset, pandaset  # noqa: E402
from xviz_server.exceptions import DatasetError, FrameSizeError  # noqa: E402


@pytest.fixture
def sequence(tmp_path: Path) -> Path:
    return write_sequence(tmp_path / "pandaset" / "001")


def test_sweeps_are_frames_and_every_camera_image_is_served(sequence: Path):
    log = open_dataset("pandaset", sequence)
    assert log.name == "001" and log.cameras == ["front_camera", "back_camera"]
    sweeps = [T0 + i * 0.1 for i in range(4)]
    assert log.times.tolist() == pytest.approx(
        sweeps + [sweeps[-1] + 0.02]
    )  # the last images come after the last sweep
    served = [(camera, file.name) for frame in log._frames for camera, file in frame.items() if camera != "lidar"]
    assert sorted(served) == sorted((camera, f"{i:02d}.jpg") for camera in CAMERAS for i in range(4))


def test_points_and_cuboids_are_in_the_vehicle_frame(sequence: Path):
    log = open_dataset("pandaset", sequence)
    update = log.convert(2)["updates"][0]
    assert (
        np.abs(np.asarray(update["primitives"]["/lidar/points"]["points"][0]["points"]) - local_points(2)).max() < 1e-4
    )
    (x, y, _), yaw = pose(2)
    px, py, _ = PARKED_POSITION
    dx, dy = px - x, py - y
    polygon = update["primitives"]["/objects/boxes"]["polygons"][0]
    centre = np.asarray(polygon["vertices"]).mean(axis=0)
    assert centre[:2] == pytest.approx(
        (dx * math.cos(yaw) + dy * math.sin(yaw), -dx * math.sin(yaw) + dy * math.cos(yaw)), abs=1e-5
    )
    assert update["primitives"]["/objects/label"]["texts"][0]["text"] == "Car 2a1e8b0c"
    assert polygon["base"]["classes"] == ["car"]


class Boom:
    def __reduce__(self):
        return (os.system, ("touch /tmp/pandaset-pwned",))


def test_a_pickle_that_names_anything_but_a_frame_is_refused_before_it_runs(sequence: Path, tmp_path: Path):
    marker = Path("/tmp/pandaset-pwned")
    marker.unlink(missing_ok=True)
    sweep = sequence / "lidar" / "01.pkl.gz"
    sweep.write_bytes(gzip.compress(pickle.dumps(Boom())))
    log = open_dataset("pandaset", sequence)
    with pytest.raises(
        DatasetError, match=r"01\.pkl\.gz: not a pickled DataFrame: refused: the pickle names posix\.system"
    ):
        log.convert(1)
    assert not marker.exists()
    sweep.write_bytes(gzip.compress(pickle.dumps({"x": [1.0]})))
    with pytest.raises(DatasetError, match=r"a pickled dict, not a DataFrame"):
        log.convert(1)
    assert log.convert(2)["updates"][0]["primitives"]["/lidar/points"]  # the rest is served


def test_a_gzip_bomb_is_refused(sequence: Path, monkeypatch):
    monkeypatch.setattr(pandaset, "MAX_PICKLE_BYTES", 4096)
    with pytest.raises(DatasetError, match=r"00\.pkl\.gz unpacks to more than the limit of 4 KiB"):
        open_dataset("pandaset", sequence).convert(0)


async def test_found_and_served(sequence: Path):
    assert detect(sequence) == "pandaset" and detect(sequence.parent) is None
    async with running_server(sequence.parent) as server:
        assert server.shelf.names() == ["001"]
        async with client(server, "/?log=001") as c:
            assert "/camera/front_camera" in (await c.recv())["data"]["streams"]
            await c.send("transform_log", {"id": "p"})
            assert len(timestamps(await c.until("transform_log_done", "p"))) == 5


def test_a_frame_whose_files_declare_more_than_the_frame_budget_is_refused_unread(sequence: Path):
    sweep = sequence / "lidar" / "02.pkl.gz"
    data = bytearray(sweep.read_bytes())
    data[-4:] = (200 << 20).to_bytes(4, "little")  # the gzip trailer says 200 MiB
    sweep.write_bytes(bytes(data))
    log = open_dataset("pandaset", sequence)
    with pytest.raises(
        FrameSizeError,
        match=r"frame 2: its messages and images would unpack 200\.\d MiB, more than the limit of 128 MiB",
    ):
        log.convert(2)
    assert log.convert(3)["updates"][0]["primitives"]["/lidar/points"]
