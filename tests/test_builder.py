"""The builder: what it makes validates and draws; misuse names the stream and the field."""

from __future__ import annotations

import base64
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from helpers import sha, xviz_decode, xviz_validate
from xviz_server.builder import FrameBuilder, MetadataBuilder, ui
from xviz_server.codec import Format, decode, encode
from xviz_server.exceptions import BuilderError
from xviz_server.validation import get_validator

PNG_2X1 = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAIAAAABCAIAAAB7QOjdAAAAEElEQVR4nGP4z8DAwMDAAAAe/wH/mHOF0QAAAABJRU5ErkJggg=="
)
LIDAR_TO_VEHICLE = [[1, 0, 0, 0.81], [0, 1, 0, -0.32], [0, 0, 1, 1.73], [0, 0, 0, 1]]
T = 100.5


def full_metadata() -> dict:
    """Metadata declaring a stream of every kind, a camera and a panel of every component."""
    meta = MetadataBuilder()
    meta.log_info(start_time=100.0, end_time=110.0, description="builder test")
    meta.pose("/vehicle_pose")
    meta.primitive(
        "/lidar/points",
        "POINT",
        coordinate="VEHICLE_RELATIVE",
        transform=LIDAR_TO_VEHICLE,
        style={"radius_pixels": 2, "fill_color": "#00a", "point_color_mode": "ELEVATION"},
    )
    meta.primitive(
        "/objects",
        "POLYGON",
        style={"extruded": True, "fill_color": [0, 0, 0, 128]},
        style_classes={
            "Car": {"fill_color": "#50B3FF80", "stroke_color": "#50B3FF"},
            "Car selected": {"fill_color": "#FFD700"},
        },
    )
    meta.primitive("/trajectory", "POLYLINE", style={"stroke_width": 0.2, "stroke_color": "#47B27580"})
    meta.primitive("/centers", "CIRCLE", style={"radius": 0.2, "stroked": False})
    meta.primitive("/lanes", "STADIUM", coordinate="GEOGRAPHIC")
    meta.primitive("/labels", "TEXT", style={"text_size": 14, "text_anchor": "START"})
    meta.primitive("/camera/front", "IMAGE")
    meta.primitive("/dynamic", "POINT", coordinate="DYNAMIC", transform_callback="lidarTransform")
    meta.future_instances(
        "/objects/futures", "POLYGON", style={"extruded": False}, style_classes={"Car": {"stroke_color": "#50B3FF"}}
    )
    meta.future_instances("/trajectory/futures", "POLYLINE")
    meta.future_instances("/points/futures", "POINT")
    meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
    meta.time_series("/vehicle/acceleration", "FLOAT", units="m/s^2")
    meta.time_series("/vehicle/gear", "INT32")
    meta.time_series("/vehicle/mode", "STRING")
    meta.time_series("/vehicle/braking", "BOOL")
    meta.time_series("/object/speed", "FLOAT", units="m/s")
    meta.variable("/plan/distance", "FLOAT", units="m")
    meta.variable("/plan/speed", "FLOAT", units="m/s")
    meta.variable("/plan/lane", "INT32")
    meta.variable("/plan/actions", "STRING")
    meta.variable("/plan/flags", "BOOL")
    meta.annotation("/highlights")
    meta.ui_primitive("/objects/table")
    meta.camera(
        "front",
        human_name="Front camera",
        vehicle_position=[1.5, 0, 1.2],
        vehicle_orientation=np.eye(3),
        pixel_width=2,
        pixel_height=1,
        rectification_projection=np.eye(3),
        gl_projection=np.eye(4),
    )
    meta.ui_panel(
        ui.panel(
            "Drive",
            ui.container(
                "Vehicle",
                ui.metric(["/vehicle/velocity", "/vehicle/acceleration"], title="Motion"),
                ui.plot("/plan/distance", ["/plan/speed"], title="Plan"),
                ui.plot(regions=[("/plan/distance", "/plan/speed", "/plan/speed")], title="Envelope"),
            ),
            ui.table("/objects/table", title="Objects", display_object_id=True),
            ui.treetable("/objects/table", title="Object tree", description="the same, as a tree"),
            ui.video(["/camera/front", "front"]),
            ui.select("/plan/actions", "/action", title="Action"),
            layout="HORIZONTAL",
        ),
        needed_streams=["/vehicle/velocity"],
    )
    return meta.build()


@pytest.fixture(scope="module")
def metadata() -> dict:
    return full_metadata()


def validate(update: dict) -> None:
    """The update validates as built, and as read back from GLB and from JSON."""
    envelope = {"type": "xviz/state_update", "data": update}
    get_validator().validate_message(envelope)
    for fmt in Format:
        get_validator().validate_message(decode(encode(envelope, fmt)))


def test_metadata_validates(metadata: dict):
    get_validator().validate_message({"type": "xviz/metadata", "data": metadata})
    assert metadata["version"] == "2.0.0"
    assert metadata["log_info"] == {"description": "builder test", "start_time": 100.0, "end_time": 110.0}
    lidar = metadata["streams"]["/lidar/points"]
    assert lidar["transform"] == [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.81, -0.32, 1.73, 1]  # column-major
    assert metadata["streams"]["/objects"]["style_classes"][1] == {
        "name": "Car selected",
        "style": {"fill_color": "#FFD700"},
    }
    assert metadata["cameras"]["front"]["vehicle_orientation"] == np.eye(3).tolist()
    assert set(metadata["ui_config"]) == {"Drive"}


def test_metadata_is_a_copy():
    meta = MetadataBuilder().pose("/vehicle_pose")
    first = meta.build()
    first["streams"]["/vehicle_pose"]["category"] = "changed"
    assert meta.build()["streams"]["/vehicle_pose"] == {"category": "POSE"}


def test_transform_layouts_agree():
    column_major = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.81, -0.32, 1.73, 1]
    meta = MetadataBuilder()
    meta.primitive("/a", "POINT", transform=np.array(LIDAR_TO_VEHICLE))
    meta.primitive("/b", "POINT", transform=column_major)
    streams = meta.build()["streams"]
    assert streams["/a"]["transform"] == streams["/b"]["transform"] == column_major


# Each case adds one kind of data to a frame and names where it lands in the stream set.
DATA_KINDS: dict[str, tuple[Callable[[FrameBuilder], object], str, str]] = {
    "points": (lambda f: f.points("/lidar/points", np.zeros((5, 3), np.float32)), "primitives", "/lidar/points"),
    "points, RGB": (
        lambda f: f.points("/lidar/points", np.ones((5, 3)), np.full((5, 3), 9, np.uint8)),
        "primitives",
        "/lidar/points",
    ),
    "points, RGBA, object": (
        lambda f: f.points("/lidar/points", [[1, 2, 3]], [[1, 2, 3, 4]], id="cloud", style={"fill_color": "#fff"}),
        "primitives",
        "/lidar/points",
    ),
    "polygon": (
        lambda f: f.polygon(
            "/objects",
            [[0, 0, 0], [4, 0, 0], [4, 2, 0]],
            id="car-1",
            classes=["Car", "selected"],
            style={"height": 1.5, "stroke_color": [255, 0, 0]},
        ),
        "primitives",
        "/objects",
    ),
    "polyline": (lambda f: f.polyline("/trajectory", [[0, 0, 0], [10, 0.5, 0]]), "primitives", "/trajectory"),
    "circle": (lambda f: f.circle("/centers", (2, 1, 0), 0.3, id=7, style={"radius": 0.5}), "primitives", "/centers"),
    "stadium": (lambda f: f.stadium("/lanes", (8.4, 49.0, 0), (8.5, 49.0, 0), 0.1), "primitives", "/lanes"),
    "text": (lambda f: f.text("/labels", (2, 1, 2), "car-1", style={"text_rotation": 45}), "primitives", "/labels"),
    "image": (lambda f: f.image("/camera/front", PNG_2X1), "primitives", "/camera/front"),
    "image, sized": (
        lambda f: f.image("/camera/front", b"\xff\xd8raw", width_px=640, height_px=480, position=(0, 0, 0)),
        "primitives",
        "/camera/front",
    ),
    "dynamic points": (lambda f: f.points("/dynamic", [[0, 0, 0]]), "primitives", "/dynamic"),
    "future polygons": (
        lambda f: f.future_instances(
            "/objects/futures",
            [101.0, 102.0],
            [[[0, 0, 0], [4, 0, 0], [4, 2, 0]], [[1, 0, 0], [5, 0, 0], [5, 2, 0]]],
            id="car-1",
            classes=["Car"],
        ),
        "future_instances",
        "/objects/futures",
    ),
    "future polylines": (
        lambda f: f.future_instances("/trajectory/futures", [101.0], [np.zeros((4, 3))]),
        "future_instances",
        "/trajectory/futures",
    ),
    "future points": (
        lambda f: f.future_instances("/points/futures", [101.0], [[[1, 1, 1]]]),
        "future_instances",
        "/points/futures",
    ),
    "time series, float": (lambda f: f.time_series("/vehicle/velocity", T, np.float32(12.5)), "time_series", ""),
    "time series, int": (lambda f: f.time_series("/vehicle/gear", T, 3), "time_series", ""),
    "time series, string": (lambda f: f.time_series("/vehicle/mode", T, "autonomous"), "time_series", ""),
    "time series, bool": (lambda f: f.time_series("/vehicle/braking", T, np.bool_(True)), "time_series", ""),
    "time series, object": (lambda f: f.time_series("/object/speed", T, 3.2, id="car-1"), "time_series", ""),
    "variable, floats": (
        lambda f: f.variable("/plan/speed", np.linspace(10, 12, 5), id="car-1"),
        "variables",
        "/plan/speed",
    ),
    "variable, ints": (lambda f: f.variable("/plan/lane", [1, 1, 2]), "variables", "/plan/lane"),
    "variable, strings": (lambda f: f.variable("/plan/actions", ["keep", "merge"]), "variables", "/plan/actions"),
    "variable, bools": (lambda f: f.variable("/plan/flags", [True, False]), "variables", "/plan/flags"),
    "variable, empty": (lambda f: f.variable("/plan/actions", []), "variables", "/plan/actions"),
    "annotation": (
        lambda f: f.annotation("/highlights", "car-1", classes=["selected"], style={"stroke_color": "#ff0"}),
        "annotations",
        "/highlights",
    ),
    "treetable": (
        lambda f: f.treetable(
            "/objects/table",
            [("id", "STRING"), ("speed", "DOUBLE", "m/s"), ("lane", "INT32"), ("parked", "BOOLEAN")],
            [(0, None, ["car-1", 3.2, 1, False]), (1, 0, ["wheel", None, 1, True]), (2, None, None)],
        ),
        "ui_primitives",
        "/objects/table",
    ),
}


@pytest.mark.parametrize("kind", DATA_KINDS)
def test_every_kind_validates(metadata: dict, kind: str):
    add, field, stream = DATA_KINDS[kind]
    frame = FrameBuilder(metadata)
    add(frame)
    update = frame.build(T)
    validate(update)
    stream_set = update["updates"][0]
    assert stream_set["timestamp"] == T
    assert (stream in stream_set[field]) if stream else stream_set[field]


@pytest.mark.parametrize("map_origin", [None, (8.434, 49.015, 116.4)])
def test_pose_validates_and_times_the_frame(metadata: dict, map_origin):
    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", T, map_origin=map_origin, position=np.array([1, 2, 0]), orientation=(0.01, 0.0, 1.5))
    update = frame.build(update_type="COMPLETE_STATE")
    validate(update)
    assert update["update_type"] == "COMPLETE_STATE"
    stream_set = update["updates"][0]
    assert stream_set["timestamp"] == T  # from the pose
    pose = stream_set["poses"]["/vehicle_pose"]
    assert pose["position"] == [1, 2, 0] and pose["orientation"] == [0.01, 0.0, 1.5]
    assert ("map_origin" in pose) == (map_origin is not None)


def test_a_full_frame_validates(metadata: dict):
    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", T)
    for add, _, _ in DATA_KINDS.values():
        if add is not DATA_KINDS["variable, empty"][0]:
            add(frame)
    validate(frame.build())


def test_time_series_of_one_time_and_type_share_an_entry(metadata: dict):
    frame = FrameBuilder(metadata)
    frame.time_series("/vehicle/velocity", T, 12.5)
    frame.time_series("/vehicle/mode", T, "autonomous")
    frame.time_series("/vehicle/acceleration", T, -0.3)
    frame.time_series("/object/speed", T, 3.0, id="car-1")
    frame.time_series("/vehicle/velocity", T + 0.05, 12.6)
    series = frame.build(T)["updates"][0]["time_series"]
    assert series == [
        {
            "timestamp": T,
            "streams": ["/vehicle/velocity", "/vehicle/acceleration"],
            "values": {"doubles": [12.5, -0.3]},
        },
        {"timestamp": T, "streams": ["/vehicle/mode"], "values": {"strings": ["autonomous"]}},
        {"timestamp": T, "object_id": "car-1", "streams": ["/object/speed"], "values": {"doubles": [3.0]}},
        {"timestamp": T + 0.05, "streams": ["/vehicle/velocity"], "values": {"doubles": [12.6]}},
    ]


def test_future_instances_group_by_time(metadata: dict):
    frame = FrameBuilder(metadata)
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], np.float32)
    frame.future_instances("/objects/futures", [102.0, 101.0], [square, square + 1], id="car-1")
    frame.future_instances("/objects/futures", [101.0], [square + 5], id="car-2")
    futures = frame.build(T)["updates"][0]["future_instances"]["/objects/futures"]
    assert futures["timestamps"] == [101.0, 102.0]
    assert [[p["base"]["object_id"] for p in state["polygons"]] for state in futures["primitives"]] == [
        ["car-1", "car-2"],
        ["car-1"],
    ]


def test_build_starts_the_next_frame_empty(metadata: dict):
    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", T).time_series("/vehicle/velocity", T, 1.0)
    frame.build()
    frame.pose("/vehicle_pose", T + 0.1)
    assert set(frame.build()["updates"][0]) == {"timestamp", "poses"}


def test_arrays_pass_through_without_copies(metadata: dict):
    points = np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)
    colors = np.random.default_rng(1).integers(0, 255, (1000, 4), dtype=np.uint8)
    vertices = np.array([[0, 0, 0], [4, 0, 0], [4, 2, 0]], np.float32)
    frame = FrameBuilder(metadata)
    frame.points("/lidar/points", points, colors)
    frame.polygon("/objects", vertices)
    update = frame.build(T)
    primitives = update["updates"][0]["primitives"]
    cloud = primitives["/lidar/points"]["points"][0]
    assert cloud["points"] is points and cloud["colors"] is colors
    assert primitives["/objects"]["polygons"][0]["vertices"] is vertices
    read = decode(encode({"type": "xviz/state_update", "data": update}, Format.BINARY))
    cloud = read["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    assert sha(cloud["points"]) == sha(points) and sha(cloud["colors"]) == sha(colors)


def test_other_arrays_become_float32_and_uint8(metadata: dict):
    frame = FrameBuilder(metadata)
    frame.points("/lidar/points", [[1, 2, 3]], [[255, 0, 0]])
    cloud = frame.build(T)["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    assert cloud["points"].dtype == np.float32 and cloud["colors"].dtype == np.uint8


FRAME_MISUSE = [
    (lambda f: f.polygon("/objects", [[0, 0, 0], [1, 1, 0]]), "/objects: polygon needs at least 3 vertices, got 2"),
    (lambda f: f.polyline("/trajectory", [[0, 0, 0]]), "/trajectory: polyline needs at least 2 vertices, got 1"),
    (lambda f: f.polygon("/undeclared", [[0, 0, 0]] * 3), "/undeclared: stream not declared in the metadata"),
    (lambda f: f.polyline("/objects", [[0, 0, 0]] * 3), "/objects: declared as POLYGON primitives, not POLYLINE"),
    (lambda f: f.time_series("/lidar/points", T, 2.0), "/lidar/points: declared as PRIMITIVE, not TIME_SERIES"),
    (
        lambda f: f.future_instances("/objects", [T], [[[0, 0, 0]] * 3]),
        "/objects: declared as PRIMITIVE, not FUTURE_INSTANCE",
    ),
    (
        lambda f: f.time_series("/vehicle/velocity", T, "fast"),
        "/vehicle/velocity: value: a FLOAT stream takes finite numbers, not 'fast'",
    ),
    (
        lambda f: f.time_series("/vehicle/velocity", T, float("nan")),
        "/vehicle/velocity: value: a FLOAT stream takes finite numbers, not nan",
    ),
    (lambda f: f.time_series("/vehicle/gear", T, 2**31), "/vehicle/gear: value: an INT32 stream takes whole numbers"),
    (lambda f: f.time_series("/vehicle/braking", T, 1), "/vehicle/braking: value: a BOOL stream cannot take 1"),
    (
        lambda f: f.time_series("/vehicle/velocity", "now", 1.0),
        "/vehicle/velocity: timestamp must be a finite number, not 'now'",
    ),
    (
        lambda f: f.time_series("/vehicle/velocity", T, 1.0).time_series("/vehicle/velocity", T, 2.0),
        "/vehicle/velocity: already has a value at 100.5 in this frame",
    ),
    (lambda f: f.variable("/plan/lane", [1, 2.5]), "/plan/lane: values[1]: an INT32 stream takes whole numbers"),
    (lambda f: f.variable("/plan/lane", "123"), "/plan/lane: values must be a list of INT32 values, not str"),
    (
        lambda f: f.points("/lidar/points", [[0, 0, 0], [0, 0, np.nan]]),
        "/lidar/points: points: row 1 is not finite: [0.0, 0.0, nan]",
    ),
    (
        lambda f: f.points("/lidar/points", np.zeros((4, 2))),
        "/lidar/points: points must be (N, 3) rows of x, y, z, not shape (4, 2)",
    ),
    (
        lambda f: f.points("/lidar/points", np.zeros((4, 3)), np.zeros((3, 3))),
        "/lidar/points: colors must be (4, 3) or (4, 4) rows of RGB(A), not shape (3, 3)",
    ),
    (
        lambda f: f.points("/lidar/points", np.zeros((1, 3)), [[300, 0, 0]]),
        "/lidar/points: colors must be 0-255, got values from 0 to 300",
    ),
    (
        lambda f: f.points("/lidar/points", np.zeros((1, 3)), [[0.5, 0.5, 0.5]]),
        "/lidar/points: colors must be integers 0-255 (uint8), not float64",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"fill_color": "#12"}),
        "/objects: style.fill_color: '#12' is not a colour",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"fill_color": "fast"}),
        "/objects: style.fill_color: 'fast' is not a colour",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"fill_color": [0, 0, 256]}),
        "/objects: style.fill_color: [0, 0, 256] is not a colour",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"extruded": True}),
        "/objects: style: 'extruded' can only be set in the stream's style, not per object or per class",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"hieght": 2}),
        "/objects: style: no style property 'hieght' (did you mean 'height'?)",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, classes="Car"),
        "/objects: classes must be a non-empty list of class names without spaces, not 'Car'",
    ),
    (lambda f: f.pose("/vehicle_pose", -1.0), "/vehicle_pose: timestamp must be seconds >= 0, not -1.0"),
    (
        lambda f: f.time_series("/vehicle/velocity", -0.5, 1.0),
        "/vehicle/velocity: timestamp must be seconds >= 0, not -0.5",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, classes=[]),
        "/objects: classes must be a non-empty list of class names without spaces, not []",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"height": 2.0}),
        "/objects: style: a style needs one of fill_color, stroke_color, stroke_width beside height: the XVIZ schema refuses one without",
    ),
    (
        lambda f: f.annotation("/highlights", "car-1", style={"height": 2.0}),
        "/highlights: style: a style needs one of fill_color, radius,",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, id=None, style={"height": "tall"}),
        "/objects: style.height: 'tall' is not of type 'number'",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"height": True}),
        "/objects: style.height: True is not of type 'number'",
    ),
    (
        lambda f: f.polygon("/objects", [[0, 0, 0]] * 3, style={"stroke_width": -0.5}),
        "/objects: style.stroke_width: -0.5 is less than the minimum of 0",
    ),
    (
        lambda f: f.text("/labels", (0, 0, 0), "x", style={"text_anchor": "LEFT"}),
        "/labels: style.text_anchor: 'LEFT' is not one of",
    ),
    (lambda f: f.circle("/centers", (0, 0, 0), -1), "/centers: radius must be >= 0, not -1"),
    (lambda f: f.circle("/centers", (0, 0), 1), "/centers: center must be three finite numbers (x, y, z), not (0, 0)"),
    (
        lambda f: f.circle("/centers", (0, 0, 0), 1, id=["a"]),
        "/centers: id: an object id is a non-empty string (or an integer), not ['a']",
    ),
    (
        lambda f: f.image("/camera/front", b"not an image"),
        "/camera/front: image is not PNG, JPEG, GIF or BMP; give width_px and height_px",
    ),
    (
        lambda f: f.image("/camera/front", "aGVsbG8="),
        "/camera/front: image data must be the bytes of an encoded image, not str",
    ),
    (
        lambda f: f.pose("/vehicle_pose", T, map_origin=(49.0, 200.0, 0)),
        "/vehicle_pose: map_origin (49.0, 200.0) is not a longitude",
    ),
    (
        lambda f: f.pose("/vehicle_pose", T, orientation=(0, 0)),
        "/vehicle_pose: orientation must be three finite numbers",
    ),
    (lambda f: f.annotation("/highlights", "x"), "/highlights: an annotation needs classes or a style"),
    (
        lambda f: f.future_instances("/objects/futures", [101.0, 102.0], [[[0, 0, 0]] * 3]),
        "/objects/futures: future instances need one shape per timestamp, got 2 timestamps and 1 shapes",
    ),
    (
        lambda f: f.future_instances("/objects/futures", [101.0], [[[0, 0, 0]] * 2]),
        "/objects/futures: shapes[0] needs at least 3 vertices, got 2",
    ),
    (
        lambda f: f.treetable("/objects/table", [("id", "STRING")], [(0, None, ["a", "b"])]),
        "/objects/table: node 0: 2 values for 1 columns",
    ),
    (
        lambda f: f.treetable("/objects/table", [("id", "FLOAT")], []),
        "/objects/table: columns[0] must be (title, type[, unit]) with type one of",
    ),
    (
        lambda f: f.treetable("/objects/table", [("n", "INT32")], [(0, None, ["x"])]),
        "/objects/table: node 0: column 'n' is INT32, not 'x'",
    ),
    (
        lambda f: f.treetable("/objects/table", [("n", "INT32")], [(0, 5, [1])]),
        "/objects/table: node 0: parent 5 is not a node listed before it",
    ),
    (lambda f: f.build(), "frame: give build() a timestamp, or add a pose"),
    (lambda f: f.build(T), "frame: nothing was added"),
    (lambda f: f.pose("/vehicle_pose", T).build(update_type="FULL"), "frame: update_type 'FULL' is not one of"),
]


@pytest.mark.parametrize("call, message", FRAME_MISUSE, ids=[message for _, message in FRAME_MISUSE])
def test_frame_misuse_names_stream_and_field(metadata: dict, call, message: str):
    with pytest.raises(BuilderError) as error:
        call(FrameBuilder(metadata))
    assert message in str(error.value)


METADATA_MISUSE = [
    (lambda m: m.primitive("/x", "SPHERE"), "/x: primitive_type 'SPHERE' is not one of CIRCLE, IMAGE, POINT, POLYGON"),
    (lambda m: m.stream("/x", category="GEOMETRY"), "/x: category 'GEOMETRY' is not one of PRIMITIVE"),
    (lambda m: m.stream("/x", category="PRIMITIVE"), "/x: a PRIMITIVE stream needs primitive_type (CIRCLE, IMAGE"),
    (
        lambda m: m.primitive("/x", "POINT", coordinate="WORLD"),
        "/x: coordinate 'WORLD' is not one of IDENTITY, GEOGRAPHIC",
    ),
    (lambda m: m.primitive("/x", "POINT", coordinate="DYNAMIC"), "/x: transform_callback goes with coordinate DYNAMIC"),
    (
        lambda m: m.primitive("/x", "POINT", units="m"),
        "/x: units is for TIME_SERIES and VARIABLE streams, not PRIMITIVE",
    ),
    (
        lambda m: m.stream("/x", category="TIME_SERIES", scalar_type="FLOAT", style={"opacity": 1}),
        "/x: style is for PRIMITIVE and FUTURE_INSTANCE streams, not TIME_SERIES",
    ),
    (
        lambda m: m.primitive("/x", "POINT", transform=np.eye(3)),
        "/x: transform must have shape (4, 4) or shape (16,), not (3, 3)",
    ),
    (
        lambda m: m.primitive("/x", "POINT", transform=np.array(LIDAR_TO_VEHICLE).T),
        "/x: transform: the bottom row must be 0, 0, 0, 1; a (4, 4) transform is read as rows with the translation in the last column",
    ),
    (
        lambda m: m.primitive("/x", "POINT", transform=np.array(LIDAR_TO_VEHICLE).reshape(-1)),
        "/x: transform: the bottom row must be 0, 0, 0, 1; a (16,) transform is read as column-major",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style={"fill_colour": "#fff"}),
        "/x: style: no style property 'fill_colour' (did you mean 'fill_color'?)",
    ),
    (
        lambda m: m.primitive("/x", "POINT", style={"radius": 2}),
        "/x: style: 'radius' does not apply to POINT primitives (they take fill_color, opacity",
    ),
    (
        lambda m: m.primitive("/x", "IMAGE", style={"opacity": 0.5}),
        "/x: style: 'opacity' does not apply to IMAGE primitives (they take no style properties)",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style={"opacity": 2}),
        "/x: style.opacity: 2 is greater than the maximum of 1",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style={"fill_color": "red"}),
        "/x: style.fill_color: 'red' is not a colour the XVIZ schema takes (the client draws CSS colour names and functions, the schema refuses them)",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style={"fill_color": "rgba(255, 0, 0, 0.5)"}),
        "/x: style.fill_color: 'rgba(255, 0, 0, 0.5)' is not a colour the XVIZ schema takes",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style={"height": 1.5}),
        "/x: style: a style needs one of extruded, fill_color, filled, opacity, stroke_color, stroke_width, stroke_width_max_pixels, "
        "stroke_width_min_pixels, stroked beside height: the XVIZ schema refuses one without",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style_classes={"Car": {"height": 1.5}}),
        "/x: style_classes['Car']: a style needs one of fill_color, stroke_color, stroke_width beside height",
    ),
    (
        lambda m: m.primitive("/x", "TEXT", style={"font_weight": "bold"}),
        "/x: style.font_weight: 'bold' is not of type 'number'",
    ),
    (
        lambda m: m.primitive("/x", "POINT", style={"point_color_mode": "DEFAULT"}),
        "/x: style.point_color_mode: 'DEFAULT' is not one of",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style_classes={"Car": {"fill_color": "#12345"}}),
        "/x: style_classes['Car'].fill_color: '#12345' is not a colour; write '#RRGGBB[AA]', '#RGB[A]' or [r, g, b(, a)]",
    ),
    (
        lambda m: m.primitive("/x", "POLYGON", style_classes={"Car": {"extruded": True}}),
        "/x: style_classes['Car']: 'extruded' can only be set in the stream's style",
    ),
    (lambda m: m.primitive("/x", "POLYGON", style_classes=["Car"]), "/x: style_classes maps class names to styles"),
    (lambda m: m.time_series("/v", "DECIMAL"), "/v: scalar_type 'DECIMAL' is not one of FLOAT, INT32, STRING, BOOL"),
    (lambda m: m.pose("vehicle_pose"), "'vehicle_pose': stream names start with '/'"),
    (lambda m: m.pose("/p").pose("/p"), "/p: stream declared twice"),
    (lambda m: m.log_info(start_time=float("inf")), "log_info: start_time must be a finite number of seconds, not inf"),
    (lambda m: m.log_info(start_time=10, end_time=5), "log_info: end_time 5.0 is before start_time 10.0"),
    (
        lambda m: m.camera("c", vehicle_orientation=np.eye(4)),
        "camera 'c': vehicle_orientation must have shape (3, 3), not (4, 4)",
    ),
    (lambda m: m.camera("c", pixel_width=640), "camera 'c': give pixel_width and pixel_height together"),
    (
        lambda m: m.ui_panel({"type": "PANEL", "name": "p", "children": [{"type": "GAUGE"}]}),
        "ui panel 'p': $.config.children[0].type: 'GAUGE' is not one of",
    ),
    (
        lambda m: m.ui_panel(ui.panel("p", ui.metric([], title="Speed"))),
        "ui panel 'p': $.config.children[0].streams: [] should be non-empty",
    ),
    (
        lambda m: m.ui_panel({"type": "PANEL", "name": "p", "children": [{"type": "METRIC", "streams": ["/speed"]}]}),
        "ui panel 'p': $.config.children[0]: 'title' is a required property",
    ),
    (
        lambda m: m.ui_panel(ui.panel("p", ui.metric(["/speed"], title="Speed"))).build(),
        "ui panel 'p': Speed shows /speed, which is not declared",
    ),
    (
        lambda m: m.ui_panel(ui.panel("p", ui.container("c", ui.video(["/cam"])))).build(),
        "ui panel 'p': VIDEO shows /cam, which is not declared",
    ),
]


@pytest.mark.parametrize("call, message", METADATA_MISUSE, ids=[message for _, message in METADATA_MISUSE])
def test_metadata_misuse_names_stream_and_field(call, message: str):
    with pytest.raises(BuilderError) as error:
        call(MetadataBuilder())
    assert message in str(error.value)


@pytest.mark.parametrize(
    "color",
    [
        "#fff",
        "#ffff",
        "#50B3FF",
        "#50B3FF80",
        [255, 0, 0],
        (255, 0, 0, 128),
        np.array([1, 2, 3], np.uint8),
        [0.5, 10.25, 0],
    ],
    ids=repr,
)
def test_colours_the_schema_takes_are_accepted(color):
    meta = MetadataBuilder().primitive("/x", "POLYGON", style={"fill_color": color})
    written = meta.build()["streams"]["/x"]["stream_style"]["fill_color"]
    assert written == (color if isinstance(color, str) else list(np.asarray(color).tolist()))
    assert isinstance(written, (str, list))  # never a numpy array: it would move into the GLB binary chunk


@pytest.mark.parametrize(
    "color",
    [
        "#12",
        "#1234567",
        "fast",
        "",
        [1, 2],
        [1, 2, 3, 4, 5],
        [-1, 0, 0],
        [0, 0, float("nan")],
        [True, False, True],
        "rgb(1, 2)",
        {"r": 1},
        "red",
        "RED",
        "transparent",
        "rgb(1, 2, 3)",
        "rgba(255, 0, 0, 0.5)",
        "hsl(10, 50%, 50%)",
    ],
    ids=repr,
)
def test_colours_that_are_not_colours_are_refused(color):
    with pytest.raises(BuilderError, match=r"/x: style\.fill_color: .* is not a colour"):
        MetadataBuilder().primitive("/x", "POLYGON", style={"fill_color": color})


@pytest.mark.parametrize("fmt", list(Format))
def test_published_client_reads_a_built_frame(metadata: dict, tmp_path: Path, fmt: Format):
    points = np.random.default_rng(1).uniform(-20, 20, (2000, 3)).astype(np.float32)
    frame = FrameBuilder(metadata)
    frame.pose("/vehicle_pose", T, map_origin=(8.434, 49.015, 116.4), position=(1, 2, 0), orientation=(0.01, 0.0, 1.5))
    frame.points("/lidar/points", points, np.full((2000, 4), 255, np.uint8))
    frame.polygon("/objects", [[0, 0, 0], [4, 0, 0], [4, 2, 0], [0, 2, 0]], id="car-1", classes=["Car"])
    frame.polygon(
        "/objects", [[5, 5, 0], [6, 5, 0], [6, 6, 0]], id="car-2", style={"fill_color": "#ff000080", "height": 1.5}
    )
    frame.circle("/centers", (2, 1, 0), 0.3, id="car-1")
    frame.text("/labels", (2, 1, 2), "car-1", id="car-1")
    frame.image("/camera/front", PNG_2X1)
    frame.time_series("/vehicle/velocity", T, 12.5)
    frame.time_series("/vehicle/acceleration", T, -0.25)
    frame.time_series("/vehicle/mode", T, "autonomous")
    frame.variable("/plan/speed", [12.5, 13.0, 13.5])
    frame.future_instances(
        "/objects/futures", [101.0, 102.0], [[[0, 0, 0], [4, 0, 0], [4, 2, 0]], [[1, 0, 0], [5, 0, 0], [5, 2, 0]]]
    )
    frame.treetable("/objects/table", [("id", "STRING")], [(0, None, ["car-1"])])
    update = frame.build()
    files = []
    for number, message in enumerate(
        [{"type": "xviz/metadata", "data": metadata}, {"type": "xviz/state_update", "data": update}], 1
    ):
        path = tmp_path / f"{number}-frame{fmt.suffix}"
        path.write_bytes(encode(message, fmt))
        files.append(path)
    meta, state = xviz_decode(files)
    assert "error" not in meta and "error" not in state, state.get("error") or meta.get("error")
    assert [line.get("error") or line["errors"] for line in xviz_validate(files)] == [[], []]  # the published validator
    streams = state["parsed"]["streams"]
    assert streams["/lidar/points"]["pointCloud"]["numInstances"] == 2000
    assert [f["id"] for f in streams["/objects"]["features"]] == ["car-1", "car-2"]
    assert streams["/objects"]["features"][0]["vertices"]["values"] == [0, 0, 0, 4, 0, 0, 4, 2, 0, 0, 2, 0]
    assert streams["/objects"]["features"][0]["base"]["classes"] == ["Car"]
    assert streams["/vehicle/velocity"] == [{"time": T, "variable": 12.5}]
    assert streams["/vehicle/acceleration"] == [{"time": T, "variable": -0.25}]
    assert streams["/vehicle/mode"] == [{"time": T, "variable": "autonomous"}]
    assert streams["/plan/speed"]["variable"] == [{"type": "FLOAT", "values": [12.5, 13.0, 13.5]}]
    assert [[p["timestamp"] for p in state] for state in streams["/objects/futures"]["lookAheads"]] == [
        [101.0],
        [102.0],
    ]
    assert streams["/objects/table"]["treetable"]["nodes"] == [{"id": 0, "column_values": ["car-1"]}]
    assert state["parsed"]["poses"]["/vehicle_pose"]["yaw"] == 1.5
    assert meta["parsed"]["ui_config"]["Drive"]["config"]["children"][0]["name"] == "Vehicle"
    assert meta["parsed"]["streams"]["/objects"]["style_classes"][0]["name"] == "Car"
