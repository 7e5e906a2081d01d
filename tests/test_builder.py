"""The builder: what it makes validates and draws; misuse names the stream and the field."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from test_interop import xviz_decode
from xviz_server.builder import FrameBuilder, MetadataBuilder, ui
from xviz_server.codec import Format, encode
from xviz_server.exceptions import BuilderError
from xviz_server.validation import get_validator

PNG_2X1 = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAIAAAABCAIAAAB7QOjdAAAAEElEQVR4nGP4z8DAwMDAAAAe/wH/mHOF0QAAAABJRU5ErkJggg=="
)


def full_metadata() -> dict:
    meta = MetadataBuilder()
    meta.log_info(start_time=100.0, end_time=110.0, description="builder test")
    meta.pose("/vehicle_pose")
    meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE",
                   transform=[[1, 0, 0, 0.81], [0, 1, 0, -0.32], [0, 0, 1, 1.73], [0, 0, 0, 1]],
                   style={"radius_pixels": 2, "fill_color": "#00a"})
    meta.primitive("/objects", "POLYGON", style={"extruded": True, "fill_color": [0, 0, 0, 128]},
                   style_classes={"Car": {"fill_color": "#50B3FF80", "stroke_color": "#50B3FF"}})
    meta.primitive("/trajectory", "POLYLINE", style={"stroke_width": 0.2})
    meta.primitive("/centers", "CIRCLE", style={"radius": 0.2})
    meta.primitive("/lanes", "STADIUM")
    meta.primitive("/labels", "TEXT", style={"text_size": 14})
    meta.primitive("/camera/front", "IMAGE")
    meta.future_instances("/objects/futures", "POLYGON")
    meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
    meta.time_series("/vehicle/acceleration", "FLOAT", units="m/s^2")
    meta.time_series("/vehicle/mode", "STRING")
    meta.variable("/plan/speed", "FLOAT", units="m/s")
    meta.annotation("/highlights")
    meta.ui_primitive("/objects/table")
    meta.camera("/camera/front", vehicle_position=[1.5, 0, 1.2], vehicle_orientation=np.eye(3), pixel_width=2, pixel_height=1)
    meta.ui_panel(ui.panel(
        "Drive",
        ui.container("Vehicle", ui.metric(["/vehicle/velocity", "/vehicle/acceleration"], title="Motion"),
                     ui.plot("/plan/speed", ["/plan/speed"], title="Plan")),
        ui.table("/objects/table", title="Objects", display_object_id=True),
        ui.treetable("/objects/table"),
        ui.video(["/camera/front"]),
        ui.select("/vehicle/mode", "/mode"),
    ), needed_streams=["/vehicle/velocity"])
    return meta.build()


def full_frame(metadata: dict, points: np.ndarray, colors: np.ndarray) -> dict:
    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", 100.5, map_origin=(8.434, 49.015, 116.4), position=(1, 2, 0), orientation=(0.01, 0.0, 1.5))
    frame.points("/lidar/points", points, colors, id="cloud")
    frame.polygon("/objects", [[0, 0, 0], [4, 0, 0], [4, 2, 0], [0, 2, 0]], id="car-1", classes=["Car"])
    frame.polygon("/objects", [[5, 5, 0], [6, 5, 0], [6, 6, 0]], id="car-2", style={"fill_color": "#ff000080", "height": 1.5})
    frame.polyline("/trajectory", [[0, 0, 0], [10, 0.5, 0], [20, 2, 0]])
    frame.circle("/centers", (2, 1, 0), 0.3, id="car-1")
    frame.stadium("/lanes", (0, -2, 0), (30, -2, 0), 0.1)
    frame.text("/labels", (2, 1, 2), "car-1", id="car-1")
    frame.image("/camera/front", PNG_2X1)
    frame.future_instances("/objects/futures", [101.0, 102.0],
                           [[[[0, 0, 0], [4, 0, 0], [4, 2, 0]]], [[[1, 0, 0], [5, 0, 0], [5, 2, 0]]]])
    frame.time_series("/vehicle/velocity", 100.5, 12.5)
    frame.time_series("/vehicle/acceleration", 100.5, -0.3)
    frame.time_series("/vehicle/mode", 100.5, "autonomous")
    frame.variable("/plan/speed", [12.5, 13.0, 13.5], id="car-1")
    frame.annotation("/highlights", "car-1", style_classes=["Car"], inline_style={"stroke_color": "#ffff00"})
    frame.treetable("/objects/table", [("id", "STRING"), ("speed", "DOUBLE", "m/s")], [(0, None, ["car-1", 3.2]), (1, 0, ["car-2", 0.0])])
    return frame.build()


@pytest.fixture
def metadata() -> dict:
    return full_metadata()


def test_everything_built_validates(metadata: dict):
    get_validator().validate("session/metadata", metadata)
    points = np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)
    update = full_frame(metadata, points, np.full((1000, 4), 200, np.uint8))
    get_validator().validate_message({"type": "xviz/state_update", "data": update})
    get_validator().validate_message({"type": "xviz/metadata", "data": metadata})
    stream_set = update["updates"][0]
    assert stream_set["timestamp"] == 100.5  # from the pose
    assert metadata["streams"]["/lidar/points"]["transform"][12:15] == [0.81, -0.32, 1.73]
    # values of one time and kind share a time-series entry, as the official logs do
    assert stream_set["time_series"][0] == {"timestamp": 100.5, "streams": ["/vehicle/velocity", "/vehicle/acceleration"],
                                            "values": {"doubles": [12.5, -0.3]}}
    assert stream_set["primitives"]["/camera/front"]["images"][0]["width_px"] == 2


def test_arrays_pass_through_without_copies(metadata: dict):
    points = np.zeros((10, 3), np.float32)
    colors = np.zeros((10, 3), np.uint8)
    update = full_frame(metadata, points, colors)
    cloud = update["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    assert cloud["points"] is points and cloud["colors"] is colors


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda f: f.polygon("/objects", [[0, 0, 0], [1, 1, 0]]), "/objects: polygon needs at least 3 vertices, got 2"),
        (lambda f: f.polygon("/undeclared", [[0, 0, 0]] * 3), "/undeclared: stream not declared in the metadata"),
        (lambda f: f.polyline("/objects", [[0, 0, 0]] * 3), "/objects: declared as POLYGON primitives, not POLYLINE"),
        (lambda f: f.time_series("/lidar/points", 1.0, 2.0), "/lidar/points: declared as PRIMITIVE, not TIME_SERIES"),
        (lambda f: f.time_series("/vehicle/velocity", 1.0, "fast"), "/vehicle/velocity: a FLOAT stream cannot take 'fast'"),
        (lambda f: f.points("/lidar/points", [[0, 0, np.nan]]), "/lidar/points: points holds a non-finite coordinate"),
        (lambda f: f.points("/lidar/points", np.zeros((4, 2))), "/lidar/points: points must be (N, 3) x, y, z rows, not shape (4, 2)"),
        (lambda f: f.points("/lidar/points", np.zeros((4, 3)), np.zeros((3, 3))), "/lidar/points: colors must be (4, 3) or (4, 4)"),
        (lambda f: f.points("/lidar/points", np.zeros((1, 3)), [[300, 0, 0]]), "/lidar/points: colors are 0-255 integers"),
        (lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"fill_color": "#12"}), "/objects: style $.fill_color: '#12'"),
        (lambda f: f.circle("/centers", (0, 0, 0), -1), "/centers: radius must be a finite number >= 0"),
        (lambda f: f.image("/camera/front", b"not an image"), "/camera/front: image is not PNG, JPEG, GIF or BMP"),
        (lambda f: f.pose("/vehicle_pose", 1.0, map_origin=(49.0, 200.0, 0)), "/vehicle_pose: map_origin (49.0, 200.0)"),
        (lambda f: f.annotation("/highlights", "x"), "/highlights: an annotation needs style_classes or inline_style"),
        (lambda f: f.treetable("/objects/table", [("id", "STRING")], [(0, None, ["a", "b"])]), "/objects/table: node 0 has 2 values for 1 columns"),
        (lambda f: f.build(), "frame: give a timestamp or a pose"),
    ],
)
def test_misuse_names_stream_and_field(metadata: dict, call, message: str):
    with pytest.raises(BuilderError) as error:
        call(FrameBuilder(metadata))
    assert message in str(error.value)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda m: m.primitive("/x", "SPHERE"), "/x: $.primitive_type: 'SPHERE' is not one of"),
        (lambda m: m.primitive("/x", "POINT", coordinate="WORLD"), "/x: $.coordinate: 'WORLD' is not one of"),
        (lambda m: m.primitive("/x", "POINT", transform=np.eye(3)), "/x: transform must be a 4x4 matrix or 16 numbers, not shape (3, 3)"),
        (lambda m: m.primitive("/x", "POLYGON", style={"fill_colour": "#fff"}), "/x: "),
        (lambda m: m.primitive("/x", "POLYGON", style_classes={"Car": {"fill_color": "#12345"}}), "/x: "),
        (lambda m: m.time_series("/v", "DECIMAL"), "/v: $.scalar_type: 'DECIMAL' is not one of"),
        (lambda m: m.pose("vehicle_pose"), "'vehicle_pose': stream names start with '/'"),
        (lambda m: m.ui_panel({"type": "PANEL", "name": "p", "children": [{"type": "GAUGE"}]}), "ui panel 'p': "),
    ],
)
def test_metadata_misuse_names_stream_and_field(call, message: str):
    with pytest.raises(BuilderError) as error:
        call(MetadataBuilder())
    assert message in str(error.value)


def test_published_client_reads_a_built_frame(metadata: dict, tmp_path: Path):
    points = np.random.default_rng(1).uniform(-20, 20, (2000, 3)).astype(np.float32)
    update = full_frame(metadata, points, np.full((2000, 4), 255, np.uint8))
    files = []
    for number, message in enumerate([{"type": "xviz/metadata", "data": metadata}, {"type": "xviz/state_update", "data": update}], 1):
        path = tmp_path / f"{number}-frame.glb"
        path.write_bytes(encode(message, Format.BINARY))
        files.append(path)
    meta, state = xviz_decode(files)
    assert "error" not in state, state.get("error")
    streams = state["parsed"]["streams"]
    assert streams["/lidar/points"]["pointCloud"]["numInstances"] == 2000
    assert [f["id"] for f in streams["/objects"]["features"]] == ["car-1", "car-2"]
    assert streams["/objects"]["features"][0]["vertices"]["values"] == [0, 0, 0, 4, 0, 0, 4, 2, 0, 0, 2, 0]
    assert streams["/vehicle/velocity"] == [{"time": 100.5, "variable": 12.5}]
    assert streams["/vehicle/mode"] == [{"time": 100.5, "variable": "autonomous"}]
    assert state["parsed"]["poses"]["/vehicle_pose"]["yaw"] == 1.5
    assert meta["parsed"]["ui_config"]["Drive"]["config"]["children"][0]["name"] == "Vehicle"
