"""The built-in demo log: its layout, its content, its cache, and the published client reading it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import assert_same_message, client, running_server, timestamps, write_demo, xviz_decode
from xviz_server.codec import Format, decode, decode_json, encode
from xviz_server.datasets.demo import DemoDrive
from xviz_server.validate import check_paths
from xviz_server.validation import get_validator

START = 1_600_000_000.0
SHORT = 0.5  # seconds: five frames at the default rate

PRIMITIVE_TYPES = {
    "points": "POINT",
    "polygons": "POLYGON",
    "polylines": "POLYLINE",
    "circles": "CIRCLE",
    "texts": "TEXT",
    "stadiums": "STADIUM",
    "images": "IMAGE",
}
SCALAR_TYPES = {"doubles": "FLOAT", "int32s": "INT32", "bools": "BOOL", "strings": "STRING"}


@pytest.fixture(scope="module")
def glb_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_demo(tmp_path_factory.mktemp("glb"))


@pytest.fixture(scope="module")
def json_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_demo(tmp_path_factory.mktemp("json"), fmt=Format.JSON)


def read_log(directory: Path) -> tuple[dict[str, Any], dict[str, Any], list[dict[str, Any]]]:
    """Return the index, the metadata and the frames of a log, in index order."""
    index = decode_json((directory / "0-frame.json").read_bytes())
    (metadata_file,) = directory.glob("1-frame.*")
    suffix = metadata_file.suffix
    frames = [decode((directory / f"{entry[3]}{suffix}").read_bytes()) for entry in index["timing"]]
    return index, decode(metadata_file.read_bytes()), frames


def only_update(frame: dict[str, Any]) -> dict[str, Any]:
    (update,) = frame["data"]["updates"]
    return update


# --------------------------------------------------------------------------
# Layout


def test_log_has_the_reference_layout(glb_log: Path):
    names = {path.name for path in glb_log.iterdir()}
    assert names == {"0-frame.json", "1-frame.glb", *(f"{n}-frame.glb" for n in range(2, 7))}


def test_index_times_the_frames(glb_log: Path):
    index, metadata, frames = read_log(glb_log)
    timestamps = [only_update(frame)["timestamp"] for frame in frames]
    assert timestamps == [START + k / 10 for k in range(5)]
    assert index["timing"] == [[t, t, i, f"{i + 2}-frame"] for i, t in enumerate(timestamps)]
    assert (index["startTime"], index["endTime"]) == (timestamps[0], timestamps[-1])
    log_info = metadata["data"]["log_info"]
    assert (log_info["start_time"], log_info["end_time"]) == (timestamps[0], timestamps[-1])


def test_log_passes_the_checker(glb_log: Path, json_log: Path):
    report = check_paths([glb_log, json_log])  # schema, layout, index spans, declared streams
    assert report.ok, report.render()
    assert not any(file.warnings for file in report.files), report.render()


def test_frames_are_the_same_in_any_order(glb_log: Path, tmp_path: Path):
    write_demo(tmp_path)
    for path in glb_log.iterdir():
        assert (tmp_path / path.name).read_bytes() == path.read_bytes(), path.name
    drive = DemoDrive(duration=SHORT)
    metadata = drive.metadata()
    alone = encode({"type": "xviz/state_update", "data": drive.convert(3, metadata)}, Format.BINARY)
    assert alone == (glb_log / "5-frame.glb").read_bytes()


@pytest.mark.parametrize(("duration", "rate"), [(0.0, 10.0), (-1.0, 10.0), (1.0, 0.0), (math.nan, 10.0)])
def test_rejects_a_duration_or_rate_that_is_not_positive(duration: float, rate: float):
    with pytest.raises(ValueError, match="must be positive"):
        DemoDrive(duration=duration, rate=rate)


def test_default_demo_is_twenty_seconds_at_ten_hertz():
    drive = DemoDrive()
    assert len(drive) == 200
    assert drive.times[-1] == pytest.approx(START + 19.9)
    assert drive.metadata()["log_info"]["end_time"] == pytest.approx(START + 19.9)


async def test_served_on_demand_as_the_log_demo():
    async with running_server(None, dataset=["demo"]) as server:
        assert server.shelf.names() == ["demo"]
        async with client(server, "/?log=demo") as c:
            metadata = await c.recv()
            assert metadata["type"] == "xviz/metadata" and metadata["data"]["log_info"]["start_time"] == START
            await c.send("transform_log", {"id": "1", "start_timestamp": START, "end_timestamp": START + 0.25})
            messages = await c.until("transform_log_done", "1")
            assert timestamps(messages) == [START, START + 0.1, START + 0.2]


# --------------------------------------------------------------------------
# Content


def test_every_message_validates(glb_log: Path):
    _, metadata, frames = read_log(glb_log)
    validator = get_validator()
    for message in [metadata, *frames]:
        validator.validate_message(message)


def test_metadata_is_xviz_2(glb_log: Path):
    _, metadata, _ = read_log(glb_log)
    assert metadata["type"] == "xviz/metadata"
    assert metadata["data"]["version"] == "2.0.0"
    ui = metadata["data"]["ui_config"]
    components = [child for panel in ui.values() for child in panel["config"]["children"]]
    assert {"METRIC", "TABLE"} <= {component["type"] for component in components}
    assert ["/vehicle/velocity"] in [component.get("streams") for component in components]


def test_frames_carry_the_pose_at_their_own_time(glb_log: Path):
    _, _, frames = read_log(glb_log)
    for frame in frames:
        assert frame["type"] == "xviz/state_update"
        assert frame["data"]["update_type"] == "SNAPSHOT"
        update = only_update(frame)
        pose = update["poses"]["/vehicle_pose"]
        assert pose["timestamp"] == update["timestamp"]
        assert set(pose["map_origin"]) == {"longitude", "latitude", "altitude"}
        assert len(pose["position"]) == len(pose["orientation"]) == 3
        assert all(series["timestamp"] == update["timestamp"] for series in update["time_series"])


def test_every_stream_is_declared_with_its_category(glb_log: Path):
    _, metadata, frames = read_log(glb_log)
    streams = metadata["data"]["streams"]
    carried = set()
    for frame in frames:
        update = only_update(frame)
        for name in update["poses"]:
            assert streams[name]["category"] == "POSE", name
        for name, primitives in update["primitives"].items():
            (kind,) = primitives
            assert streams[name]["category"] == "PRIMITIVE", name
            assert streams[name]["primitive_type"] == PRIMITIVE_TYPES[kind], name
            assert streams[name]["coordinate"] in ("IDENTITY", "VEHICLE_RELATIVE"), name
        for series in update["time_series"]:
            (kind,) = series["values"]
            for name in series["streams"]:
                assert streams[name]["category"] == "TIME_SERIES", name
                assert streams[name]["scalar_type"] == SCALAR_TYPES[kind], name
        for name, primitives in update["ui_primitives"].items():
            assert streams[name] == {"category": "UI_PRIMITIVE", "ui_primitive_type": "TREETABLE"}
            assert set(primitives) == {"treetable"}
        carried |= {*update["poses"], *update["primitives"], *update["ui_primitives"]}
        carried |= {name for series in update["time_series"] for name in series["streams"]}
    assert carried == set(streams)


def test_vehicle_drives_at_about_ten_metres_per_second(glb_log: Path):
    _, _, frames = read_log(glb_log)
    updates = [only_update(frame) for frame in frames]
    positions = np.array([update["poses"]["/vehicle_pose"]["position"] for update in updates])
    headings = np.array([update["poses"]["/vehicle_pose"]["orientation"][2] for update in updates])
    steps = np.diff(positions[:, :2], axis=0)
    speeds = np.hypot(*steps.T) / np.diff([update["timestamp"] for update in updates])
    series = [update["time_series"] for update in updates]
    assert all(s[0]["streams"] == ["/vehicle/velocity", "/vehicle/acceleration"] for s in series)
    reported = np.array([s[0]["values"]["doubles"][0] for s in series])
    assert np.allclose(speeds, 10.0, atol=1.0)
    assert np.allclose(speeds, (reported[1:] + reported[:-1]) / 2, atol=0.05)
    assert np.allclose(np.arctan2(steps[:, 1], steps[:, 0]), headings[:-1], atol=0.05)
    assert series[-1][1] == {
        "timestamp": updates[-1]["timestamp"],
        "streams": ["/vehicle/autonomy_state"],
        "values": {"strings": ["manual"]},
    }


def test_lidar_sweep_is_a_point_cloud_with_colours(glb_log: Path):
    _, _, frames = read_log(glb_log)
    for frame in frames:
        (cloud,) = only_update(frame)["primitives"]["/lidar/points"]["points"]
        points, colors = cloud["points"], cloud["colors"]
        assert points.dtype == np.float32 and points.shape[1] == 3
        assert 15_000 < len(points) < 40_000
        assert colors.dtype == np.uint8 and colors.shape == (len(points), 4)
        ground = np.abs(points[:, 2]) < 0.05
        assert 0.2 < ground.mean() < 0.9  # rings on the road, and walls, poles and road users
        assert np.hypot(points[:, 0], points[:, 1]).max() <= 70.1


def test_road_users_are_styled_by_class_and_labelled(glb_log: Path):
    _, metadata, frames = read_log(glb_log)
    streams = metadata["data"]["streams"]
    styled = {style["name"] for style in streams["/objects/shape"]["style_classes"]}
    assert streams["/objects/shape"]["stream_style"]["extruded"] is True
    classes = set()
    for frame in frames:
        primitives = only_update(frame)["primitives"]
        polygons = primitives["/objects/shape"]["polygons"]
        ids = [polygon["base"]["object_id"] for polygon in polygons]
        for polygon in polygons:
            (category,) = polygon["base"]["classes"]
            classes.add(category)
            assert polygon["vertices"].dtype == np.float32 and polygon["vertices"].shape == (4, 3)
            assert polygon["base"]["style"]["height"] > 0
        assert [text["text"] for text in primitives["/objects/label"]["texts"]] == ids
        circles = primitives["/objects/tracking_point"]["circles"]
        assert [circle["base"]["object_id"] for circle in circles] == ids
    assert classes == styled == {"Car", "Cyclist", "Pedestrian"}


def test_road_user_table_lists_the_road_users_nearest_first(glb_log: Path):
    _, _, frames = read_log(glb_log)
    update = only_update(frames[0])
    table = update["ui_primitives"]["/objects/table"]["treetable"]
    ids = [polygon["base"]["object_id"] for polygon in update["primitives"]["/objects/shape"]["polygons"]]
    assert [node["column_values"][0] for node in table["nodes"]] == ids
    distances = [float(node["column_values"][2]) for node in table["nodes"]]
    assert distances == sorted(distances) and distances[-1] < 60


def test_trajectory_leads_ahead_of_the_vehicle(glb_log: Path):
    _, _, frames = read_log(glb_log)
    (path,) = only_update(frames[0])["primitives"]["/vehicle/trajectory"]["polylines"]
    vertices = path["vertices"]
    assert vertices.dtype == np.float32 and vertices.shape == (21, 3)
    assert np.array_equal(vertices[0], [0, 0, 0])
    assert np.all(np.diff(vertices[:, 0]) > 0) and 40 < vertices[-1, 0] < 60


def test_glb_and_json_logs_hold_the_same_data(glb_log: Path, json_log: Path):
    glb_index, *glb_messages = read_log(glb_log)
    json_index, *json_messages = read_log(json_log)
    assert glb_index == json_index
    assert_same_message(json_messages, glb_messages, lists_as_arrays=True)


# --------------------------------------------------------------------------
# The published client


@pytest.mark.slow
@pytest.mark.parametrize("fmt", [Format.BINARY, Format.JSON])
def test_published_client_reads_the_demo(glb_log: Path, json_log: Path, fmt: Format):
    log_dir = glb_log if fmt is Format.BINARY else json_log
    names = ["1-frame", "2-frame", "4-frame", "6-frame"]
    results = xviz_decode([log_dir / f"{name}{fmt.suffix}" for name in names])
    _, _, frames = read_log(log_dir)

    for result in results:
        assert "error" not in result, result.get("error")
    metadata, *states = (result["parsed"] for result in results)
    assert metadata["type"] == "METADATA" and metadata["version"] == "2.0.0"
    assert (metadata["start_time"], metadata["end_time"]) == (START, START + 0.4)

    for parsed, frame in zip(states, [frames[0], frames[2], frames[4]]):
        update = only_update(frame)
        assert parsed["type"] == "TIMESLICE" and parsed["timestamp"] == update["timestamp"]
        streams = parsed["streams"]
        (cloud,) = update["primitives"]["/lidar/points"]["points"]
        drawn = streams["/lidar/points"]["pointCloud"]
        assert drawn["numInstances"] == len(cloud["points"]) > 15_000
        assert drawn["colors"]["length"] == np.size(cloud["colors"]) == 4 * len(cloud["points"])
        polygons = update["primitives"]["/objects/shape"]["polygons"]
        features = streams["/objects/shape"]["features"]
        assert [feature["id"] for feature in features] == [p["base"]["object_id"] for p in polygons]
        assert all(feature["type"] == "polygon" for feature in features)
        assert all(feature["vertices"]["length"] == 12 for feature in features)  # 4 corners, x y z
        velocity, acceleration = update["time_series"][0]["values"]["doubles"]
        assert streams["/vehicle/velocity"] == [{"time": update["timestamp"], "variable": velocity}]
        assert streams["/vehicle/acceleration"] == [{"time": update["timestamp"], "variable": acceleration}]
        assert streams["/vehicle/autonomy_state"] == [{"time": update["timestamp"], "variable": "manual"}]
        assert len(streams["/objects/table"]["treetable"]["nodes"]) == len(polygons)
        assert parsed["poses"]["/vehicle_pose"]["x"] == update["poses"]["/vehicle_pose"]["position"][0]
