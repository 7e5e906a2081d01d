"""The XVIZ v2 JSON Schema files and the validator built on them."""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from devkit.data import MISSING, SCHEMA_EXAMPLES
from helpers import assert_same_message, needs_data, xviz_validate_instances
from xviz_server.codec import decode_glb
from xviz_server.exceptions import SchemaValidationError, UnknownSchemaError, XVIZError
from xviz_server.validation import ARRAY_ROWS, XVIZValidator, get_validator

SCHEMA_DIR = Path(__file__).resolve().parents[1] / "schema"
CORPUS = SCHEMA_EXAMPLES

#: A problem line: a JSON path, a colon, a description.
PROBLEM = re.compile(r"^\$(\.\w+|\[\d+\]|\['[^']*'\])*: \S")


def corpus_cases(kind: str) -> list[Any]:
    """Every example under ``valid/`` or ``invalid/``, with the name of its schema.

    The schema is named by the folder of the example or, for a file lying
    among schema folders (``core/annotation_visual.json``), by the file.
    Without the corpus, one case that skips saying how to get it (test_corpus_is_present fails in CI).
    """
    if not CORPUS.is_dir():
        return [pytest.param("", CORPUS, id=f"{kind}/no-corpus", marks=pytest.mark.skip(reason=MISSING))]
    names = set(get_validator().names())
    cases = []
    for path in sorted((CORPUS / kind).rglob("*")):
        if path.is_file():
            relative = path.relative_to(CORPUS / kind)
            name = relative.parent.as_posix()
            if name not in names:
                name = relative.with_suffix("").as_posix()
            cases.append(pytest.param(name, path, id=f"{kind}/{relative.as_posix()}"))
    return cases


def load(path: Path) -> Any:
    return json.loads(path.read_text("utf-8"))


@pytest.fixture(scope="module")
def validator() -> XVIZValidator:
    return get_validator()


# Schema files


SCHEMA_FILES = {path.relative_to(SCHEMA_DIR).with_suffix("").as_posix(): path for path in SCHEMA_DIR.rglob("*.json")}


@pytest.mark.parametrize("name", sorted(SCHEMA_FILES))
def test_schema_file_is_a_documented_2020_12_schema(name: str) -> None:
    schema = load(SCHEMA_FILES[name])
    Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] == f"https://xviz-server.dev/schema/{name}.json"
    assert schema["title"] and schema["description"]


def test_names_are_the_schema_files(validator: XVIZValidator) -> None:
    assert validator.names() == sorted(SCHEMA_FILES)
    assert {"envelope", "session/start", "core/pose", "declarative-ui/panel"}.issubset(SCHEMA_FILES)


def test_get_validator_is_shared() -> None:
    assert get_validator() is get_validator()


# Conformance corpus


def test_corpus_is_present(shared_dir: Path) -> None:
    assert CORPUS.is_relative_to(shared_dir)
    assert len(corpus_cases("valid")) > 100 and len(corpus_cases("invalid")) > 50


@pytest.mark.parametrize(("name", "path"), corpus_cases("valid"))
def test_valid_example(validator: XVIZValidator, name: str, path: Path) -> None:
    assert validator.errors(name, load(path)) == []


@pytest.mark.parametrize(("name", "path"), corpus_cases("invalid"))
def test_invalid_example(validator: XVIZValidator, name: str, path: Path) -> None:
    problems = validator.errors(name, load(path))
    assert problems
    for line in problems:
        assert PROBLEM.match(line), line


# Where our schema and the published one (@xviz/schema 1.0.13) part, the published one is followed: these
# instances are valid to one of them only if to both.
AGREEMENT = [
    ("style/object_value", {"height": 1.5}),
    ("style/object_value", {}),
    ("style/object_value", {"fill_color": "#FF000080", "height": 1.5}),
    ("style/object_value", {"stroke_width": 0.2}),
    ("style/object_value", {"fill_color": "red"}),
    ("style/object_value", {"fill_color": "rgba(255, 0, 0, 0.5)"}),
    ("style/object_value", {"fill_color": [255, 0, 0]}),
    ("style/object_value", {"fill_color": "#f00", "opacity": 0.5}),
    ("style/stream_value", {"height": 1.5}),
    ("style/stream_value", {"extruded": True}),
    ("style/stream_value", {"fill_color": "#fff", "font_weight": "bold"}),
    ("style/stream_value", {"font_weight": 700}),
    ("style/stream_value", {"point_color_mode": "DEFAULT"}),
    ("style/stream_value", {"point_color_mode": "elevation"}),
    ("style/stream_value", {"point_color_mode": "ELEVATION", "point_color_domain": [0, 3]}),
    ("style/class", {"name": "Car", "style": {"height": 2.0}}),
    ("style/class", {"name": "Car", "style": {"stroke_color": "#50B3FF", "height": 2.0}}),
    ("primitives/polygon", {"vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0]], "base": {"classes": []}}),
    (
        "primitives/polygon",
        {"vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0]], "base": {"classes": ["Car"], "style": {"height": 2.0}}},
    ),
    ("primitives/polyline", {"vertices": [[0, 0, 0], [1, 1, 1]], "colors": [[255, 0, 0], [0, 255, 0]]}),
    ("primitives/polyline", {"vertices": [[0, 0, 0], [1, 1, 1]]}),
    (
        "core/pose",
        {
            "timestamp": 1.0,
            "map_origin": {"latitude": 49.0, "altitude": 0.0},
            "position": [0, 0, 0],
            "orientation": [0, 0, 0],
        },
    ),
    (
        "core/pose",
        {
            "timestamp": 1.0,
            "map_origin": {"longitude": 0.0, "latitude": 49.0, "altitude": 0.0},
            "position": [0, 0, 0],
            "orientation": [0, 0, 0],
        },
    ),
    ("core/annotation_visual", {"base": {"object_id": "car-1"}, "inline_style": {"height": 2.0}}),
    ("core/pose", {"timestamp": -1.0, "position": [0, 0, 0], "orientation": [0, 0, 0]}),
    ("core/timeseries_state", {"timestamp": -1.0, "streams": ["/speed"], "values": {"doubles": [1.0]}}),
    (
        "core/future_instances",
        {"timestamps": [-1.0], "primitives": [{"polygons": [{"vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0]]}]}]},
    ),
    ("core/stream_set", {"timestamp": 1.0, "no_data_streams": ["/points"]}),
    ("core/stream_set", {"timestamp": 1.0, "links": {"/points": {"target_pose": "/vehicle_pose"}}}),
    ("core/stream_set", {"timestamp": 1.0, "time_series": []}),
    ("session/camera_info", {"human_name": "Front", "source": "/camera", "gl_projection": [[1, 0, 0, 0]] * 4}),
    ("declarative-ui/components/metric", {"type": "METRIC", "streams": ["/speed"]}),
    ("declarative-ui/components/table", {"type": "TABLE", "stream": "/objects"}),
    ("declarative-ui/components/plot", {"type": "PLOT", "independentVariable": "/a", "dependentVariables": ["/b"]}),
    ("declarative-ui/components/video", {"type": "VIDEO", "cameras": ["/camera"]}),
]


@needs_data
def test_our_validator_agrees_with_the_published_one(validator: XVIZValidator, tmp_path: Path) -> None:
    """On the conformance corpus and on the cases where the two schemas used to part (see AGREEMENT)."""
    corpus = [(param.values[0], load(param.values[1])) for kind in ("valid", "invalid") for param in corpus_cases(kind)]
    cases = [*corpus, *AGREEMENT]
    published = xviz_validate_instances(cases, tmp_path)
    compared = [
        (name, instance, bool(validator.errors(name, instance)), bool(theirs["errors"]))
        for (name, instance), theirs in zip(cases, published)
        if "error" not in theirs  # a schema the published validator names otherwise (style/color is its style/_color)
    ]
    assert len(compared) >= len(AGREEMENT) + 100
    assert [case for case in compared if case[2] != case[3]] == []


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("bad_name", "$.name: 1 is not of type 'string'"),
        ("missing_name", "$: 'name' is a required property"),
        ("missing_container_name", "$.children[0]: 'name' is a required property"),
        ("wrong_type", "$.children[0].type: 'BAR' is not one of"),
        ("bad_type_children", "$.children[0].children[0].type: 'DOESNOTEXIST' is not one of"),
    ],
)
@needs_data
def test_invalid_panel_is_rejected_for_its_own_defect(validator: XVIZValidator, case: str, expected: str) -> None:
    # These examples also spell the element types in lower case, which is
    # wrong on its own; upper-case them to see the defect each one is named for.
    def upper_types(element: dict[str, Any]) -> dict[str, Any]:
        element = {**element, "type": element["type"].upper()}
        if "children" in element:
            element["children"] = [upper_types(child) for child in element["children"]]
        return element

    panel = upper_types(load(CORPUS / f"invalid/declarative-ui/panel/{case}.json"))
    problems = validator.errors("declarative-ui/panel", panel)
    assert len(problems) == 1 and problems[0].startswith(expected), problems


@pytest.mark.parametrize(
    ("name", "instance", "expected"),
    [
        ("session/start", {"version": "2", "session_type": "LIVE", "log": "x"}, "$.log: 'x' is not allowed"),
        ("session/start", {"version": "1.0"}, "$.version: '1.0' is not a valid XVIZ 2 version"),
        ("core/stream_set", {"timestamp": 1.0}, "$: needs one of 'poses', 'primitives'"),
        ("core/stream_set", {"primitives": {}}, "$: 'timestamp' is a required property"),
        ("style/object_value", {"fill_color": [255, 0]}, "$.fill_color: [255, 0] is too short"),
        ("style/object_value", {"fill_color": "#12"}, "$.fill_color: '#12' is not a valid hex string"),
        ("style/object_value", {"fill_color": "red"}, "$.fill_color: 'red' is not a valid hex string"),
        (
            "style/object_value",
            {"height": 1.5},
            "$: needs one of 'fill_color', 'stroke_color', 'stroke_width', 'radius',",
        ),
        (
            "style/stream_value",
            {"height": 1.5},
            "$: needs one of 'fill_color', 'stroke_color', 'stroke_width', 'radius',",
        ),
        (
            "style/stream_value",
            {"fill_color": "#fff", "font_weight": "bold"},
            "$.font_weight: 'bold' is not of type 'number'",
        ),
        (
            "primitives/polyline",
            {"vertices": [[0, 0, 0], [1, 1, 1]], "colors": [[255, 0, 0], [0, 255, 0]]},
            "$: Additional properties are not allowed ('colors' was unexpected)",
        ),
        ("primitives/point", {"points": [[1, 2, 3], [1, 2]]}, "$.points[1]: [1, 2] is too short"),
        ("primitives/polygon", {"vertices": [0, 0, 0, 1, 1, 1]}, "$.vertices: [0, 0, 0, 1, 1, 1] is too"),
        ("math/matrix3x3", [[1, 0, 0], [0, 1, 0, 0], [0, 0, 1]], "$[1]: [0, 1, 0, 0] is too long"),
    ],
)
def test_problem_names_the_offending_value(validator: XVIZValidator, name: str, instance: Any, expected: str) -> None:
    problems = validator.errors(name, instance)
    assert any(line.startswith(expected) for line in problems), problems


def test_problem_lines_stay_short(validator: XVIZValidator) -> None:
    update = {"update_type": "SNAPSHOT", "updates": [list(range(10_000))]}
    (line,) = validator.errors("session/state_update", update)
    assert line.startswith("$.updates[0]: [0, 1, 2, ...] is not of type 'object'")
    assert len(line) < 100


# Real data: the official KITTI log


def json_chunk(path: Path) -> dict[str, Any]:
    """The JSON chunk of a GLB file, read without the codec."""
    data = path.read_bytes()
    length, _ = struct.unpack_from("<II", data, 12)
    return json.loads(data[20 : 20 + length])


def inline_pointers(value: Any, document: dict[str, Any]) -> Any:
    """Replace ``#/accessors/N`` by a two-row list of the accessor's type, ``#/images/N`` by base64."""
    if isinstance(value, dict):
        return {key: inline_pointers(item, document) for key, item in value.items()}
    if isinstance(value, list):
        return [inline_pointers(item, document) for item in value]
    if isinstance(value, str) and value.startswith("#/accessors/"):
        accessor = document["accessors"][int(value.rsplit("/", 1)[1])]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[accessor["type"]]
        component = 200 if accessor["componentType"] == 5121 else 1.5
        return [[component] * width] * 2 if width > 1 else [component] * 2
    if isinstance(value, str) and value.startswith("#/images/"):
        return "iVBORw0KGgo="
    return value


@pytest.mark.parametrize("frame", ["1-frame.glb", "2-frame.glb"])
def test_kitti_json_chunk_validates(validator: XVIZValidator, kitti_log: Path, frame: str) -> None:
    document = json_chunk(kitti_log / frame)
    envelope = inline_pointers(document["xviz"], document)
    assert validator.errors("envelope", envelope) == []


def test_kitti_metadata_is_checked_deeply(validator: XVIZValidator, kitti_log: Path) -> None:
    envelope = json_chunk(kitti_log / "1-frame.glb")["xviz"]
    envelope["data"]["ui_config"]["Metrics"]["config"]["children"][0]["layout"] = "diagonal"
    envelope["data"]["streams"]["/lidar/points"]["stream_style"]["opacity"] = 2
    assert validator.errors("envelope", envelope) == [
        "$.data.streams['/lidar/points'].stream_style.opacity: 2 is greater than the maximum of 1",
        "$.data.ui_config.Metrics.config.children[0].layout: 'diagonal' is not one of "
        "['VERTICAL', 'HORIZONTAL', 'vertical', 'horizontal']",
    ]


@pytest.mark.parametrize("index", range(1, 27))
def test_kitti_decoded_frame_validates(validator: XVIZValidator, kitti_log: Path, index: int) -> None:
    envelope = decode_glb((kitti_log / f"{index}-frame.glb").read_bytes())
    validator.validate_message(envelope)


# Values decoded from GLB


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def point_cloud_update(points: np.ndarray, colors: np.ndarray) -> dict[str, Any]:
    return {
        "update_type": "SNAPSHOT",
        "updates": [
            {
                "timestamp": 1317042145.964,
                "primitives": {
                    "/lidar/points": {"points": [{"points": points, "colors": colors}]},
                    "/camera/image_00": {
                        "images": [{"data": memoryview(PNG_MAGIC), "width_px": 397, "height_px": 120}],
                    },
                },
            }
        ],
    }


def test_numpy_arrays_and_memoryviews_are_accepted_unchanged(validator: XVIZValidator) -> None:
    points = np.arange(3000, dtype=np.float32).reshape(1000, 3)
    colors = np.full((1000, 4), 255, dtype=np.uint8)
    update = point_cloud_update(points, colors)
    assert validator.errors("session/state_update", update) == []
    assert_same_message(update, point_cloud_update(points.copy(), colors.copy()))
    point = update["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    assert point["points"] is points and point["colors"] is colors


def test_numpy_arrays_are_checked_by_their_first_rows(validator: XVIZValidator) -> None:
    assert ARRAY_ROWS == 64
    update = point_cloud_update(np.zeros((1000, 2), dtype=np.float32), np.zeros((1000, 5), dtype=np.uint8))
    problems = validator.errors("session/state_update", update)
    where = "$.updates[0].primitives['/lidar/points'].points[0]"
    assert f"{where}.points[0]: [0.0, 0.0] is too short" in problems
    assert f"{where}.colors[0]: [0, 0, 0, 0, 0] is too long" in problems
    assert len(problems) == 2 * ARRAY_ROWS


def test_non_finite_numpy_value_is_reported_at_its_path(validator: XVIZValidator) -> None:
    points = np.zeros((1000, 3), dtype=np.float32)
    points[500, 1] = np.nan
    points[700, 2] = np.inf
    update = point_cloud_update(points, np.zeros((1000, 3), np.uint8))
    problems = validator.errors("session/state_update", update)
    assert problems == [
        "$.updates[0].primitives['/lidar/points'].points[0].points[500][1]: "
        "nan is not a finite number (2 non-finite values in this array)"
    ]
    assert not np.isfinite(points).all(), "the caller's array must not be touched"


def test_long_json_number_lists_are_checked_like_arrays(validator: XVIZValidator) -> None:
    """A point cloud decoded from JSON: its first rows and its finiteness are checked."""
    points = np.zeros((1000, 3)).tolist()
    points[500][1] = float("nan")
    colors = [[0, 0, 0, 0, 0]] * 1000
    update = point_cloud_update(points, colors)
    where = "$.updates[0].primitives['/lidar/points'].points[0]"
    problems = validator.errors("session/state_update", update)
    assert f"{where}.points[500][1]: nan is not a finite number" in problems
    assert f"{where}.colors[0]: [0, 0, 0, 0, 0] is too long" in problems
    assert len(problems) == 1 + ARRAY_ROWS
    ragged = [[0.0, 0.0, 0.0]] * 999 + [[0.0, 0.0]]  # not a block: every row is checked
    assert validator.errors("session/state_update", point_cloud_update(ragged, [[0, 0, 0]] * 1000)) == [
        f"{where}.points[999]: [0.0, 0.0] is too short"
    ]


def test_non_finite_float_is_reported(validator: XVIZValidator) -> None:
    pose = {"timestamp": float("inf"), "position": [0, 0, 0], "orientation": [0.0, float("nan"), 0]}
    assert validator.errors("core/pose", pose) == [
        "$.orientation[1]: nan is not a finite number",
        "$.timestamp: inf is not a finite number",
    ]


def test_numpy_scalars_and_tuples_are_accepted(validator: XVIZValidator) -> None:
    pose = {"timestamp": np.float64(1.5), "position": (np.float32(1), 2, 3), "orientation": np.zeros(3)}
    assert validator.errors("core/pose", pose) == []


# API


def test_unknown_schema_name_suggests_close_names(validator: XVIZValidator) -> None:
    with pytest.raises(UnknownSchemaError) as caught:
        validator.errors("session/strat", {})
    assert isinstance(caught.value, KeyError) and isinstance(caught.value, XVIZError)
    message = str(caught.value)
    assert message.startswith("no XVIZ schema named 'session/strat'; did you mean 'session/start', "), message


def test_unknown_schema_name_without_close_names(validator: XVIZValidator) -> None:
    with pytest.raises(KeyError, match=r"no XVIZ schema named 'zzz'; see XVIZValidator.names\(\)"):
        validator.validate("zzz", {})


def test_validate_raises_with_every_problem(validator: XVIZValidator) -> None:
    with pytest.raises(SchemaValidationError) as caught:
        validator.validate("session/start", {"session_type": "foo"})
    assert caught.value.schema == "session/start"
    assert caught.value.problems == [
        "$: 'version' is a required property",
        "$.session_type: 'foo' is not one of ['LOG', 'LIVE']",
    ]
    validator.validate("session/start", {"version": "2.0.0"})


@pytest.mark.parametrize(
    "envelope",
    [
        {
            "type": "xviz/state_update",
            "data": point_cloud_update(np.zeros((10, 3), np.float32), np.zeros((10, 3), np.uint8)),
        },
        {"type": "xviz/transform_log_done", "data": {"id": "1"}},
        {"type": "other/subtype", "data": {"any": "thing"}},
    ],
    ids=["state_update", "transform_log_done", "other-namespace"],
)
def test_validate_message_accepts(validator: XVIZValidator, envelope: dict[str, Any]) -> None:
    validator.validate_message(envelope)


@pytest.mark.parametrize(
    ("envelope", "problems"),
    [
        ({"type": "xviz/foo", "data": {}}, ["$.type: 'xviz/foo' is not one of ['xviz/start',"]),
        ({"type": "xviz/transform_log", "data": {"end_timestamp": 1}}, ["$.data: 'id' is a required"]),
        ({"type": "xviz/error", "data": {"message": "x"}, "id": 1}, ["$: Additional properties are not"]),
        ({"data": {}}, ["$: 'type' is a required property"]),
    ],
    ids=["unknown-xviz-type", "bad-data", "extra-key", "no-type"],
)
def test_validate_message_rejects(validator: XVIZValidator, envelope: dict[str, Any], problems: list[str]) -> None:
    with pytest.raises(SchemaValidationError) as caught:
        validator.validate_message(envelope)
    assert caught.value.schema == "envelope"
    assert len(caught.value.problems) == len(problems)
    for line, start in zip(caught.value.problems, problems):
        assert line.startswith(start), line
