"""The published client, @xviz/parser 1.0.13 from npm, reads what we encode.

The node script ``tests/interop/xviz-decode.js`` decodes message files with
the real client and prints what it made of them; arrays come back as
SHA-256 digests of their bytes so that large point clouds compare exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helpers import PNG_2X1, assert_same_parse, sha, xviz_decode
from xviz_server.codec import Format, decode_glb, encode

METADATA = {
    "type": "xviz/metadata",
    "data": {
        "version": "2.0.0",
        "log_info": {"start_time": 100.0, "end_time": 101.0},
        "streams": {
            "/vehicle_pose": {"category": "POSE"},
            "/lidar/points": {"category": "PRIMITIVE", "primitive_type": "POINT", "coordinate": "VEHICLE_RELATIVE"},
            "/objects": {"category": "PRIMITIVE", "primitive_type": "POLYGON"},
            "/camera/front": {"category": "PRIMITIVE", "primitive_type": "IMAGE"},
            "/vehicle/velocity": {"category": "TIME_SERIES", "scalar_type": "FLOAT", "units": "m/s"},
        },
    },
}


def sample_update(rng: np.random.Generator) -> dict:
    points = rng.uniform(-50, 50, (5000, 3)).astype(np.float32)
    # Alpha starts at 1: given nested JSON colours, the client turns an alpha
    # of 0 into 255 (`color[3] || 255`), which no server can prevent.
    colors = rng.integers(1, 256, (5000, 4), dtype=np.uint8)
    return (
        {
            "type": "xviz/state_update",
            "data": {
                "update_type": "SNAPSHOT",
                "updates": [
                    {
                        "timestamp": 100.5,
                        "poses": {
                            "/vehicle_pose": {
                                "timestamp": 100.5,
                                "map_origin": {"longitude": 8.43, "latitude": 49.01, "altitude": 116.4},
                                "position": [1.0, 2.0, 0.0],
                                "orientation": [0.0, 0.0, 1.25],
                            }
                        },
                        "primitives": {
                            "/lidar/points": {"points": [{"points": points, "colors": colors}]},
                            "/objects": {
                                "polygons": [
                                    {
                                        "vertices": [[0, 0, 0], [4, 0, 0], [4, 2, 0], [0, 2, 0]],
                                        "base": {"object_id": "car-1"},
                                    }
                                ]
                            },
                            "/camera/front": {"images": [{"data": PNG_2X1, "width_px": 2, "height_px": 1}]},
                        },
                        "time_series": [
                            {"timestamp": 100.5, "streams": ["/vehicle/velocity"], "values": {"doubles": [12.5]}}
                        ],
                    }
                ],
            },
        },
        points,
        colors,
    )


@pytest.mark.parametrize("fmt", [Format.JSON, Format.BINARY])
def test_parser_reads_our_messages(tmp_path: Path, fmt: Format):
    update, points, colors = sample_update(np.random.default_rng(1))
    paths = []
    for index, message in enumerate([METADATA, update]):
        path = tmp_path / f"{index + 1}-frame{fmt.suffix}"
        path.write_bytes(encode(message, fmt))
        paths.append(path)
    metadata, state = xviz_decode(paths)

    assert "error" not in metadata, metadata.get("error")
    assert metadata["parsed"]["type"] == "METADATA"
    assert metadata["parsed"]["version"] == "2.0.0"
    assert metadata["parsed"]["start_time"] == 100.0 and metadata["parsed"]["end_time"] == 101.0

    assert "error" not in state, state.get("error")
    parsed = state["parsed"]
    assert parsed["type"] == "TIMESLICE" and parsed["timestamp"] == 100.5
    cloud = parsed["streams"]["/lidar/points"]["pointCloud"]
    assert cloud["numInstances"] == 5000
    assert cloud["positions"]["sha256"] == sha(points)
    assert cloud["colors"]["length"] == colors.size and cloud["colors"]["sha256"] == sha(colors)
    polygon = parsed["streams"]["/objects"]["features"][0]
    assert polygon["vertices"]["values"] == [0, 0, 0, 4, 0, 0, 4, 2, 0, 0, 2, 0]
    assert polygon["id"] == "car-1"
    image = parsed["streams"]["/camera/front"]["images"][0]
    assert image["imageData"]["sha256"] == sha(PNG_2X1)
    assert (image["width_px"], image["height_px"]) == (2, 1)
    assert parsed["streams"]["/vehicle/velocity"] == [{"time": 100.5, "variable": 12.5}]
    pose = parsed["poses"]["/vehicle_pose"]
    assert (pose["x"], pose["y"], pose["yaw"], pose["latitude"]) == (1.0, 2.0, 1.25, 49.01)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", [Format.JSON, Format.BINARY])
def test_parser_reads_reencoded_kitti_frames_as_it_reads_the_originals(kitti_log: Path, tmp_path: Path, fmt: Format):
    originals = [kitti_log / "1-frame.glb", kitti_log / "2-frame.glb", kitti_log / "26-frame.glb"]
    ours = []
    for path in originals:
        out = tmp_path / path.name.replace(".glb", fmt.suffix)
        out.write_bytes(encode(decode_glb(path.read_bytes()), fmt))
        ours.append(out)
    expected = xviz_decode(originals)
    actual = xviz_decode(ours)
    for theirs, mine in zip(expected, actual):
        assert "error" not in mine, mine.get("error")
        if fmt is Format.BINARY:
            assert mine["parsed"] == theirs["parsed"], mine["file"]
        else:
            assert_same_parse(mine["parsed"], theirs["parsed"], mine["file"])
