"""VISTA traces: the bicycle-model pose, video frames by timestamp, lidar sweeps, serving."""

from __future__ import annotations

import io
import math
from pathlib import Path

import av
import h5py
import numpy as np
import pytest

from helpers import client, running_server, timestamps
from xviz_server.convert import convert
from xviz_server.datasets import detect, require
from xviz_server.datasets.vista import VistaTrace, integrate_pose, linear_function
from xviz_server.exceptions import DatasetError
from xviz_server.validate import check_paths

SPEED, YAW_RATE = 5.0, 0.5  # a circle of radius 10 m
START = 1_600_000_000.0
FRAMES = 12


def shade(number: int) -> int:
    return 20 + 18 * number


def write_trace(directory: Path) -> Path:
    """A trace in VISTA's layout: camera video with its csv, a lidar, speed and IMU odometry."""
    directory.mkdir(parents=True)
    # Video frame k is a flat grey of shade(k); the csv lists frames out of time order on purpose.
    with av.open(str(directory / "camera_front.avi"), "w", format="avi") as container:
        stream = container.add_stream("mjpeg", rate=10)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuvj420p"
        for number in range(FRAMES):
            image = np.full((48, 64, 3), shade(number), np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    rows = [(number, START + 0.1 * number) for number in range(FRAMES)]
    order = [3, 0, 1, 2, *range(4, FRAMES)]
    (directory / "camera_front.csv").write_text(
        "frame_num,ros_timestamp\n" + "".join(f"{rows[i][0]},{rows[i][1]:.3f}\n" for i in order)
    )
    with h5py.File(directory / "lidar_3d.h5", "w") as file:
        xyz = np.full((FRAMES, 6, 3), np.nan, np.float32)
        for sweep in range(FRAMES):
            xyz[sweep, : 3 + sweep % 3] = sweep  # sweeps of 3 to 5 points, NaN-padded
        file["xyz"] = xyz
        file["intensity"] = np.full((FRAMES, 6), 0.5, np.float32)
    (directory / "lidar_3d.csv").write_text(
        "frame_num,ros_timestamp\n" + "".join(f"{n},{START + 0.1 * n + 0.01:.3f}\n" for n in range(FRAMES))
    )
    t = START + np.arange(-10, 30) * 0.05
    (directory / "speed.csv").write_text("".join(f"{x:.3f},{SPEED}\n" for x in t))
    (directory / "imu.csv").write_text("".join(f"{x:.3f},0,0,0,0,0,{YAW_RATE},0\n" for x in t))
    return directory


@pytest.fixture
def trace(tmp_path: Path) -> Path:
    return write_trace(tmp_path / "trace-1")


def test_constant_speed_and_yaw_rate_drive_a_circle(trace: Path):
    vista = VistaTrace(trace)
    assert detect(trace) == "vista" and len(vista) == FRAMES
    radius = SPEED / YAW_RATE
    x, y, heading = vista.poses.T
    assert np.allclose(np.hypot(x, y - radius), radius, atol=1e-3)  # on the circle through the start
    elapsed = vista.times - vista.times[0]
    assert np.allclose(heading, YAW_RATE * elapsed, atol=1e-6)
    # a longer run: half a turn comes back at (0, 2r)
    half_turn = integrate_pose(
        np.array([0.0, math.pi / YAW_RATE]),
        lambda t: np.full_like(t, SPEED),
        lambda t: np.full_like(t, YAW_RATE / SPEED),
    )
    assert half_turn[-1, :2] == pytest.approx([0.0, 2 * radius], abs=1e-3)


def test_curvature_is_filtered_and_functions_extrapolate():
    f = linear_function(np.array([0.0, 1.0, 2.0]), np.array([0.0, 2.0, 4.0]))
    assert f(np.array([-1.0, 0.5, 3.0])).tolist() == [-2.0, 1.0, 6.0]


def test_video_frames_come_out_in_timestamp_order(trace: Path):
    vista = VistaTrace(trace, image_max_width=32)
    from PIL import Image

    shades = []
    for frame in range(FRAMES):
        update = vista.convert(frame)["updates"][0]
        assert update["timestamp"] == pytest.approx(START + 0.1 * frame)
        image = update["primitives"]["/camera/camera_front"]["images"][0]
        with Image.open(io.BytesIO(bytes(image["data"]))) as picture:
            assert picture.size == (32, 24)
            shades.append(picture.convert("L").getpixel((16, 12)))
    assert all(abs(got - shade(frame)) <= 4 for frame, got in enumerate(shades)), shades


def test_lidar_sweeps_time_series_and_trajectory(trace: Path):
    update = VistaTrace(trace).convert(4)["updates"][0]
    points = update["primitives"]["/lidar/lidar_3d"]["points"][0]["points"]
    assert points.shape == (3 + 4 % 3, 3) and np.all(points == 4)  # the padding is gone
    values = {s: v for e in update["time_series"] for s, v in zip(e["streams"], e["values"]["doubles"])}
    assert values["/vehicle/speed"] == pytest.approx(SPEED) and values["/vehicle/yaw_rate"] == pytest.approx(YAW_RATE)
    trajectory = update["primitives"]["/vehicle/trajectory"]["polylines"][0]["vertices"]
    assert len(trajectory) == FRAMES - 4


def test_missing_pieces_are_named(trace: Path):
    (trace / "imu.csv").unlink()
    with pytest.raises(DatasetError, match="not a VISTA trace"):
        VistaTrace(trace)
    with pytest.raises(DatasetError, match=r"pip install 'xviz-server\[vista\]'"):
        require("no_such_video_library", "VISTA traces", "vista")


async def test_convert_and_serve(trace: Path, tmp_path: Path):
    convert("vista", trace, tmp_path / "log", processes=1)
    assert check_paths([tmp_path / "log"]).ok
    async with running_server(None, dataset=[f"vista:{trace}"]) as server, client(server, "/trace-1") as c:
        await c.recv()
        await c.send("transform_log", {"id": "v"})
        assert len(timestamps(await c.until("transform_log_done", "v"))) == FRAMES


def test_published_client_reads_a_converted_trace(trace: Path, tmp_path: Path):
    from helpers import xviz_decode

    convert("vista", trace, tmp_path / "log", frames="0:3", processes=1)
    lines = xviz_decode([tmp_path / "log" / f"{n}-frame.glb" for n in range(1, 5)])
    assert all("error" not in line for line in lines)
    for line in lines[1:]:
        parsed = line["parsed"]
        assert "/vehicle_pose" in parsed["poses"]
        assert parsed["streams"]["/camera/camera_front"]["images"][0]["imageData"]["$bytes"] > 0
        assert parsed["streams"]["/lidar/lidar_3d"]["pointCloud"]["numInstances"] >= 3
