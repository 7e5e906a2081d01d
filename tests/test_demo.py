"""The built-in demo log: complete, valid, deterministic, and read by the published client."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from helpers import assert_same_message
from test_interop import xviz_decode
from xviz_server.check import check_paths
from xviz_server.codec import Format, decode
from xviz_server.demo import ensure_demo_log, generate_demo_log
from xviz_server.state import update_streams


def test_short_demo_is_a_valid_log_in_the_reference_layout(tmp_path: Path):
    log = generate_demo_log(tmp_path / "demo", duration=1.0)
    names = sorted(p.name for p in log.iterdir())
    assert names == sorted(["0-frame.json", "1-frame.glb"] + [f"{i}-frame.glb" for i in range(2, 12)])
    report = check_paths([log])  # schema, layout, index spans, declared streams
    assert report.ok, report.render()
    assert not any(f.warnings for f in report.files), report.render()

    metadata = decode((log / "1-frame.glb").read_bytes())["data"]
    index = json.loads((log / "0-frame.json").read_text())
    info = metadata["log_info"]
    assert (info["start_time"], info["end_time"]) == (index["startTime"], index["endTime"])
    for row in index["timing"]:
        update = decode((log / f"{row[3]}.glb").read_bytes())["data"]["updates"][0]
        assert update["timestamp"] == row[0]
        assert update["poses"]["/vehicle_pose"]["timestamp"] == row[0]
        for name in update_streams({"updates": [update]}):
            assert name in metadata["streams"], name


def test_demo_is_deterministic_and_the_same_in_both_formats(tmp_path: Path):
    glb = generate_demo_log(tmp_path / "a", duration=0.3)
    again = generate_demo_log(tmp_path / "b", duration=0.3)
    as_json = generate_demo_log(tmp_path / "c", duration=0.3, fmt=Format.JSON)
    for i in range(1, 5):
        assert (glb / f"{i}-frame.glb").read_bytes() == (again / f"{i}-frame.glb").read_bytes()
        binary = decode((glb / f"{i}-frame.glb").read_bytes())
        text = decode((as_json / f"{i}-frame.json").read_bytes())
        if i >= 2:
            cloud = text["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
            cloud["points"] = np.asarray(cloud["points"], dtype=np.float32)
            cloud["colors"] = np.asarray(cloud["colors"], dtype=np.uint8)
            for polyline in text["data"]["updates"][0]["primitives"]["/vehicle/trajectory"]["polylines"]:
                polyline["vertices"] = np.asarray(polyline["vertices"], dtype=np.float32)
            for polygon in text["data"]["updates"][0]["primitives"]["/objects/shape"]["polygons"]:
                polygon["vertices"] = np.asarray(polygon["vertices"], dtype=np.float32)
        assert_same_message(text, binary)


def test_ensure_generates_once_and_repairs_an_incomplete_log(tmp_path: Path):
    log = ensure_demo_log(tmp_path)
    index = log / "0-frame.json"
    first = index.stat().st_ino, index.stat().st_mtime_ns
    assert ensure_demo_log(tmp_path) == log
    assert (index.stat().st_ino, index.stat().st_mtime_ns) == first  # reused, not regenerated
    (log / "57-frame.glb").unlink()  # a log missing a frame the index names is incomplete
    ensure_demo_log(tmp_path)
    assert (log / "57-frame.glb").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging left behind


def test_published_client_draws_the_demo(tmp_path: Path):
    log = generate_demo_log(tmp_path / "demo", duration=0.3)
    lines = xviz_decode([log / f"{i}-frame.glb" for i in range(1, 5)])
    assert all("error" not in line for line in lines), lines
    assert lines[0]["parsed"]["type"] == "METADATA"
    for line in lines[1:]:
        parsed = line["parsed"]
        assert parsed["type"] == "TIMESLICE" and "/vehicle_pose" in parsed["poses"]
        streams = parsed["streams"]
        assert streams["/lidar/points"]["pointCloud"]["numInstances"] > 10_000
        assert len(streams["/objects/shape"]["features"]) > 0
        assert streams["/vehicle/velocity"][0]["variable"] > 0
