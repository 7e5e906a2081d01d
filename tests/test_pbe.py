"""XVIZ protobuf (PBE) logs, as the published @xviz/io 1.0.13 writes them, are served as GLB and JSON.

Every log here is written by @xviz/io itself (``tests/interop/xviz-write.js``):
the same messages once with its ``XVIZProtobufWriter`` and once with its
``XVIZBinaryWriter``. What we serve from the PBE log must be what we serve
from the GLB log, and what @xviz/parser makes of it what it makes of the
GLB writer's files.
"""

from __future__ import annotations

import base64
import os
import shutil
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import (
    PNG_2X1,
    assert_same_message,
    client,
    run_xviz_session_async,
    running_server,
    timestamps,
    write_log,
    xviz_decode,
    xviz_write,
)
from xviz_server import frames
from xviz_server.codec import Format, decode, decode_pbe
from xviz_server.codec.xviz_v2_pb2 import Envelope, StateUpdate
from xviz_server.exceptions import DecodeError
from xviz_server.validate import check_paths

# --------------------------------------------------------------------------
# A log with every kind of XVIZ content, next to the KITTI excerpt

RICH_METADATA = {
    "version": "2.0.0",
    "log_info": {"start_time": 10.0, "end_time": 10.3},
    "streams": {
        "/vehicle_pose": {"category": "POSE"},
        "/other_pose": {"category": "POSE"},
        "/points": {
            "category": "PRIMITIVE",
            "primitive_type": "POINT",
            "coordinate": "VEHICLE_RELATIVE",
            "stream_style": {
                "radius_pixels": 2,
                "point_color_mode": "ELEVATION",
                "point_color_domain": [0, 3.5],
                "opacity": 0.8,
            },
        },
        "/objects": {
            "category": "PRIMITIVE",
            "primitive_type": "POLYGON",
            "coordinate": "IDENTITY",
            "stream_style": {"fill_color": "#50B3FF80", "stroke_color": "#FF0000", "extruded": True, "height": 1.5},
            "style_classes": [{"name": "Car", "style": {"fill_color": "#00FF00", "stroke_width": 0.2}}],
        },
        "/lanes": {
            "category": "PRIMITIVE",
            "primitive_type": "POLYLINE",
            "stream_style": {"stroke_width": 0.1, "stroke_width_min_pixels": 1},
        },
        "/labels": {
            "category": "PRIMITIVE",
            "primitive_type": "TEXT",
            "stream_style": {
                "text_size": 14,
                "text_anchor": "MIDDLE",
                "text_baseline": "CENTER",
                "font_family": "Arial",
                "font_weight": 700,
            },
        },
        "/markers": {"category": "PRIMITIVE", "primitive_type": "CIRCLE", "stream_style": {"radius": 0.3}},
        "/paths": {"category": "PRIMITIVE", "primitive_type": "STADIUM"},
        "/camera": {"category": "PRIMITIVE", "primitive_type": "IMAGE"},
        "/speed": {"category": "TIME_SERIES", "scalar_type": "FLOAT", "units": "m/s"},
        "/gear": {"category": "TIME_SERIES", "scalar_type": "INT32"},
        "/engaged": {"category": "TIME_SERIES", "scalar_type": "BOOL"},
        "/plan": {"category": "VARIABLE", "scalar_type": "FLOAT"},
        "/highlight": {"category": "ANNOTATION", "annotation_type": "VISUAL"},
        "/futures": {"category": "FUTURE_INSTANCE", "primitive_type": "POLYGON"},
        "/table": {"category": "UI_PRIMITIVE", "ui_primitive_type": "TREETABLE"},
    },
    "ui_config": {
        "Panel": {
            "name": "Panel",
            "needed_streams": ["/speed"],
            "config": {
                "type": "PANEL",
                "name": "Panel",
                "children": [{"type": "METRIC", "streams": ["/speed"], "title": "Speed"}],
            },
        }
    },
}


def rich_update(i: int) -> dict[str, Any]:
    """Frame ``i`` of the rich log; frame 0 holds zeros where XVIZ requires a value (protobuf leaves zeros out)."""
    t = 10.0 + i / 10
    zero = i == 0
    rng = np.random.default_rng(i)
    points = rng.uniform(-20, 20, (300, 3)).astype(np.float32)
    colors = rng.integers(0, 256, (300, 4), dtype=np.uint8)
    return {
        "update_type": ["SNAPSHOT", "INCREMENTAL", "COMPLETE_STATE", "PERSISTENT"][i % 4],
        "updates": [
            {
                "timestamp": t,
                "poses": {
                    "/vehicle_pose": {
                        "timestamp": t,
                        "map_origin": {
                            "longitude": 0.0 if zero else 8.4,
                            "latitude": 49.0,
                            "altitude": 0.0 if zero else 110.25,
                        },
                        "position": [t, 1.5, 0.25],
                        "orientation": [0.0, 0.01, 1.25],
                    }
                },
                "primitives": {
                    "/points": {
                        "points": [
                            {"points": points.tolist(), "colors": colors.tolist(), "base": {"object_id": "cloud"}}
                        ]
                    },
                    "/objects": {
                        "polygons": [
                            {
                                "vertices": [[0, 0, 0], [4, 0, 0], [4, 2, 0], [0, 2, 0]],
                                "base": {
                                    "object_id": f"car-{i}",
                                    "classes": ["Car"],
                                    "style": {"fill_color": "#FF000080", "height": 2.5},
                                },
                            }
                        ]
                    },
                    "/lanes": {
                        "polylines": [
                            {
                                "vertices": [[0, 0, 0], [10, 0.5, 0], [20, 1.5, 0]],
                                "colors": [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]],
                            }
                        ]
                    },
                    "/labels": {"texts": [{"position": [1.5, 2.25, 0.5], "text": "" if zero else f"frame {i}"}]},
                    "/markers": {"circles": [{"center": [3.0, 4.0, 0.0], "radius": 0.0 if zero else 1.1}]},
                    "/paths": {"stadiums": [{"start": [0, 0, 0], "end": [5, 5, 0], "radius": 0.7}]},
                    "/camera": {
                        "images": [{"data": base64.b64encode(PNG_2X1).decode(), "width_px": 2, "height_px": 1}]
                    },
                },
                "time_series": [
                    {"timestamp": t, "streams": ["/speed"], "values": {"doubles": [12.5 + i]}},
                    {"timestamp": t, "streams": ["/gear"], "values": {"int32s": [3]}},
                    {"timestamp": t, "streams": ["/engaged"], "values": {"bools": [True]}, "object_id": "ego"},
                ],
                "variables": {
                    "/plan": {"variables": [{"values": {"doubles": [1.0, 2.0, 3.5]}, "base": {"object_id": "route"}}]}
                },
                "annotations": {
                    "/highlight": {
                        "visuals": [
                            {
                                "base": {"object_id": f"car-{i}"},
                                "style_classes": ["Car"],
                                "inline_style": {"stroke_color": "#FFFF00"},
                            }
                        ]
                    }
                },
                "future_instances": {
                    "/futures": {
                        "timestamps": [t + 0.5, t + 1.0],
                        "primitives": [
                            {"polygons": [{"vertices": [[1, 1, 0], [2, 1, 0], [2, 2, 0]]}]},
                            {"polygons": [{"vertices": [[2, 2, 0], [3, 2, 0], [3, 3, 0]]}]},
                        ],
                    }
                },
                "ui_primitives": {
                    "/table": {
                        "treetable": {
                            "columns": [
                                {"display_text": "Name", "type": "STRING"},
                                {"display_text": "Value", "type": "DOUBLE", "unit": "m"},
                            ],
                            "nodes": [
                                {"id": 1, "column_values": ["a", "1.5"]},
                                {"id": 0, "parent": 1, "column_values": ["b", "2"]},
                            ],
                        }
                    }
                },
                "links": {"/other_pose": {"target_pose": "/vehicle_pose"}},
                "no_data_streams": ["/gear"],
            }
        ],
    }


@pytest.fixture(scope="session")
def written(tmp_path_factory: pytest.TempPathFactory, kitti_log: Path) -> Path:
    """A data root: ``pbe/<log>`` and ``glb/<log>`` for the KITTI excerpt and the rich log, written by @xviz/io."""
    root = tmp_path_factory.mktemp("written")
    rich = write_log(root / "source" / "rich", [rich_update(i) for i in range(4)], fmt=Format.JSON, meta=RICH_METADATA)
    for name, source in (("kitti", kitti_log), ("rich", rich)):
        xviz_write(source, BINARY_PBE=root / "pbe" / name, BINARY_GLB=root / "glb" / name)
    shutil.rmtree(root / "source")
    return root


# --------------------------------------------------------------------------
# Comparing what we read with what the GLB writer wrote


def writer_color(hex_color: str) -> list[int]:
    """A style colour as @xviz/io's protobuf writer stores it: one byte per hex digit pair, or per digit in #RGB(A)."""
    digits = hex_color[1:]
    step = 1 if len(digits) in (3, 4) else 2
    return [int(digits[i : i + step], 16) for i in range(0, len(digits), step)]


def as_written_by_protobuf(value: Any, key: str | None = None) -> Any:
    """A message decoded from the GLB writer's file, with the style colours as the protobuf writer stores them."""
    if isinstance(value, dict):
        return {k: as_written_by_protobuf(v, k) for k, v in value.items()}
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return [as_written_by_protobuf(v) for v in value]
    if key in ("fill_color", "stroke_color") and isinstance(value, str):
        return writer_color(value)
    return value


def image_bytes(value: Any, key: str | None = None) -> Any:
    """A message with the base64 text of its images decoded.

    The GLB writer keeps the base64 text of a JSON source as it is, and our
    JSON encoder writes image bytes as base64 text.
    """
    if isinstance(value, dict):
        return {k: image_bytes(v, k) for k, v in value.items()}
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return [image_bytes(v) for v in value]
    if key == "data" and isinstance(value, str):
        return base64.b64decode(value)
    return value


def ordered_like(actual: Any, expected: Any) -> Any:
    """``actual`` with the keys of its objects in the order of ``expected``'s (protobuf orders fields by number)."""
    if isinstance(actual, dict) and isinstance(expected, dict):
        order = [k for k in expected if k in actual] + [k for k in actual if k not in expected]
        return {k: ordered_like(actual[k], expected.get(k)) for k in order}
    if isinstance(actual, list) and isinstance(expected, list) and actual and isinstance(actual[0], dict):
        return [ordered_like(a, e) for a, e in zip(actual, expected)] + actual[len(expected) :]
    return actual


def assert_same_as_glb(actual: Any, expected: Any) -> None:
    """Assert that a message read from PBE holds what the GLB writer wrote of the same message.

    Messages decoded from JSON (no numpy arrays) compare with ``==`` first:
    comparing point clouds of nested lists one value at a time is slow.
    """
    actual, expected = image_bytes(actual), image_bytes(as_written_by_protobuf(expected))
    if not any_array(expected) and actual == expected:
        return
    assert_same_message(ordered_like(actual, expected), expected)


def any_array(value: Any) -> bool:
    if isinstance(value, np.ndarray):
        return True
    if isinstance(value, dict):
        return any(any_array(v) for v in value.values())
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return any(any_array(v) for v in value)
    return False


def frame_files(directory: Path, suffix: str) -> list[Path]:
    return sorted(directory.glob(f"*-frame{suffix}"), key=lambda p: int(p.name.partition("-")[0]))


# --------------------------------------------------------------------------
# The codec


@pytest.mark.parametrize("log", ["kitti", "rich"])
def test_state_updates_decode_as_the_binary_writer_wrote_them(written: Path, log: str):
    pbe = frame_files(written / "pbe" / log, ".pbe")[1:]
    glb = frame_files(written / "glb" / log, ".glb")[1:]
    assert [p.stem for p in pbe] == [g.stem for g in glb] and len(pbe) == (25 if log == "kitti" else 4)
    for p, g in zip(pbe, glb):
        assert_same_as_glb(decode(p.read_bytes()), decode(g.read_bytes()))


def test_kitti_points_are_float32_views_as_from_glb(written: Path):
    message = decode((written / "pbe" / "kitti" / "2-frame.pbe").read_bytes())
    cloud = message["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    assert cloud["points"].dtype == np.float32 and cloud["points"].shape == (121015, 3)
    assert cloud["colors"].dtype == np.uint8 and cloud["colors"].shape == (121015, 3)
    assert not cloud["points"].flags.writeable


def drop_protobuf_defaults(value: Any) -> Any:
    """What survives proto3: values equal to 0, false, "" or empty are not written."""
    if isinstance(value, dict):
        kept = {k: drop_protobuf_defaults(v) for k, v in value.items()}
        return {k: v for k, v in kept.items() if v not in (0, "", [], {}) or isinstance(v, bool) and v}
    if isinstance(value, list):
        return [drop_protobuf_defaults(v) for v in value]
    return value


@pytest.mark.parametrize("log", ["kitti", "rich"])
def test_metadata_keeps_what_protobuf_can_hold(written: Path, log: str):
    actual = decode((written / "pbe" / log / "1-frame.pbe").read_bytes())
    expected = decode((written / "glb" / log / "1-frame.glb").read_bytes())
    # LogInfo has the two times only: KITTI's description, license... are not written.
    expected["data"]["log_info"] = {k: expected["data"]["log_info"][k] for k in ("start_time", "end_time")}
    assert_same_as_glb(actual, drop_protobuf_defaults(expected))


def test_kitti_metadata_values(written: Path):
    streams = decode((written / "pbe" / "kitti" / "1-frame.pbe").read_bytes())["data"]["streams"]
    assert streams["/lidar/points"]["coordinate"] == "VEHICLE_RELATIVE"
    assert streams["/tracklets/objects"]["stream_style"]["fill_color"] == [0, 0, 0, 128]
    assert streams["/lidar/points"]["stream_style"]["fill_color"] == [0, 0, 10]  # "#00a", as the writer stored it
    assert streams["/vehicle/trajectory"]["stream_style"]["stroke_width"] == 1.4  # a float32, given back as 1.4
    assert streams["/tracklets/objects"]["transform"][12:15] == [0.81, -0.32, 1.73]  # doubles, exact


def points_message(*chunks: bytes, unpacked: tuple[float, ...] = (), colors: bytes = b"") -> bytes:
    """A PBE state update with one point primitive whose floats are written as given.

    ``chunks`` are runs of packed floats (field 2, length-delimited), ``unpacked``
    floats written one fixed32 each (field 2, wire type 5).
    """
    point = b"".join(b"\x12" + bytes([len(c)]) + c for c in chunks)
    point += b"".join(b"\x15" + struct.pack("<f", v) for v in unpacked)
    if colors:
        point += b"\x1a" + bytes([len(colors)]) + colors
    update = StateUpdate(update_type=StateUpdate.SNAPSHOT)
    stream_set = update.updates.add(timestamp=5.0)
    stream_set.primitives["/p"].points.add().MergeFromString(point)
    envelope = Envelope(type="xviz/state_update")
    envelope.data.type_url = "xviz.v2.StateUpdate"  # as @xviz/io writes it, with no prefix
    envelope.data.value = update.SerializeToString()
    return b"PBE1" + envelope.SerializeToString()


def cloud_of(data: bytes) -> dict[str, Any]:
    return decode_pbe(data)["data"]["updates"][0]["primitives"]["/p"]["points"][0]


def test_points_in_several_packed_runs_or_unpacked():
    floats = np.arange(12, dtype="<f4")
    runs = cloud_of(points_message(floats[:5].tobytes(), floats[5:].tobytes(), colors=bytes(range(16))))
    assert np.array_equal(runs["points"], floats.reshape(4, 3))
    assert runs["colors"].shape == (4, 4) and runs["colors"].tobytes() == bytes(range(16))
    unpacked = cloud_of(points_message(unpacked=tuple(floats.tolist()), colors=bytes(range(12))))
    assert np.array_equal(unpacked["points"], floats.reshape(4, 3)) and unpacked["colors"].shape == (4, 3)
    assert cloud_of(points_message(b"")) == {}  # one empty run: no points


def test_any_type_url_with_the_standard_prefix_is_read():
    envelope = Envelope()
    envelope.ParseFromString(points_message(np.zeros(3, "<f4").tobytes())[4:])
    envelope.data.type_url = "type.googleapis.com/xviz.v2.StateUpdate"
    assert decode_pbe(b"PBE1" + envelope.SerializeToString())["type"] == "xviz/state_update"


@pytest.mark.parametrize(
    "data, message",
    [
        (
            points_message(np.zeros(4, "<f4").tobytes()),
            r"StateUpdate\.updates\[0\]\.primitives\['/p'\]\.points\[0\]\.points: holds 4 floats",
        ),
        (points_message(b"\x00" * 6), r"\.points: 6 bytes of packed floats"),
        (points_message(np.zeros(3, "<f4").tobytes(), unpacked=(1.0, 2.0, 3.0)), r"mixes packed and unpacked"),
        (points_message(np.zeros(6, "<f4").tobytes(), colors=b"\x01" * 7), r"has 2 points but 7 bytes of colors"),
        (b"PBE1" + StateUpdate(update_type=StateUpdate.SNAPSHOT).SerializeToString(), "has no envelope type"),
        (b"PBE1" + Envelope(type="xviz/transform_log").SerializeToString(), "holds 'xviz/transform_log'"),
        (
            b"PBE1" + Envelope(type="xviz/metadata", data={"type_url": "xviz.v2.StateUpdate"}).SerializeToString(),
            r"holds a 'xviz\.v2\.StateUpdate', not a xviz\.v2\.Metadata",
        ),
        (b"PBE1\x0a\x09xviz/", r"offset 4: xviz\.v2\.Envelope\.type: needs 9 bytes, only 5 remain"),
        (b"PBE1\x0a\x02\xff\xfe", r"offset 6: xviz\.v2\.Envelope\.type is not UTF-8 text"),
    ],
)
def test_inconsistent_messages_name_the_field(data: bytes, message: str):
    with pytest.raises(DecodeError, match=message):
        decode_pbe(data)


def test_every_truncation_and_corruption_is_a_decode_error():
    data = points_message(np.arange(30, dtype="<f4").tobytes(), colors=bytes(40))
    frames.check(data)
    for end in range(len(data)):
        with pytest.raises(DecodeError):
            frames.check(data[:end])
    rng = np.random.default_rng(7)
    for _ in range(500):
        corrupt = bytearray(data)
        for position in rng.integers(4, len(data), 3):
            corrupt[position] = rng.integers(0, 256)
        try:
            frames.check(bytes(corrupt))
        except DecodeError:
            pass


# --------------------------------------------------------------------------
# Serving


def strip(message: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in message.items() if not k.startswith("_")}


async def whole_log(
    server: Any, log: str, query: str = "", **window: float
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The metadata and every state update a client gets for ``log`` (in a ``window``), with the other messages."""
    async with client(server, f"/{log}{query}") as c:
        metadata = await c.recv()
        await c.send("transform_log", {"id": "all", **window})
        messages = await c.until("transform_log_done", "all")
    return metadata, messages


# KITTI in JSON: the first 4 frames only, the JSON of 121k-point clouds being slow to compare.
@pytest.mark.parametrize(
    "log, query, window, count",
    [
        ("kitti", "", {}, 25),
        pytest.param(  # four KITTI clouds as JSON text: seconds of encoding and decoding
            "kitti",
            "?message_format=JSON",
            {"start_timestamp": 1317042145.9, "end_timestamp": 1317042146.3},
            4,
            marks=pytest.mark.slow,
        ),
        ("rich", "", {}, 4),
        ("rich", "?message_format=JSON", {}, 4),
    ],
)
async def test_pbe_log_serves_the_state_updates_of_the_glb_log(
    written: Path, log: str, query: str, window: dict[str, float], count: int
):
    text = bool(query)
    async with running_server(written) as server:
        pbe_metadata, pbe = await whole_log(server, f"pbe/{log}", query, **window)
        _, glb = await whole_log(server, f"glb/{log}", query, **window)
    assert pbe_metadata["type"] == "xviz/metadata" and pbe_metadata["_text"] is text  # GLB unless asked otherwise
    assert [m["type"] for m in pbe] == [m["type"] for m in glb]
    updates = [(strip(p), strip(g)) for p, g in zip(pbe, glb) if g["type"] == "xviz/state_update"]
    assert len(updates) == count
    assert all(m["_text"] is text for m in pbe)
    for p, g in updates:
        assert_same_as_glb(p, g)


async def test_published_client_reads_the_pbe_log_as_the_binary_writer_files(written: Path):
    directory = written / "glb" / "kitti"
    expected = {line["parsed"]["timestamp"]: line["parsed"] for line in xviz_decode(frame_files(directory, ".glb"))[1:]}
    script = [
        {"wait": "metadata"},
        {"send_transform_log": {"id": "0", "from_start": -1}},
        {"wait": "done", "id": "0"},
        {"close": True},
    ]
    async with running_server(written) as server:
        url = f"ws://127.0.0.1:{server.port}/?log=pbe/kitti"
        result = await run_xviz_session_async(url, script, timeout=180)
    assert result.ok, result.stderr
    assert result.summary["errors"] == []
    assert result.messages[0]["parsed"]["type"] == "METADATA"
    updates = result.of_type("xviz/state_update")
    assert [u["parsed"]["timestamp"] for u in updates] == sorted(expected)
    for update in updates:
        assert update["kind"] == "binary"
        assert update["parsed"] == expected[update["parsed"]["timestamp"]]


def copy_log(source: Path, target: Path, *, index: bool = True) -> Path:
    """Link a log's files into ``target``, with or without its index; files to corrupt are copied later."""
    target.mkdir(parents=True)
    for file in source.iterdir():
        if index or file.name != "0-frame.json":
            os.symlink(file, target / file.name)
    return target


def replace(file: Path, data: bytes) -> None:
    file.unlink()
    file.write_bytes(data)


async def test_index_is_built_from_pbe_frames_when_missing(written: Path, tmp_path: Path):
    copy_log(written / "pbe" / "kitti", tmp_path / "no-index", index=False)
    (tmp_path / "glb").symlink_to(written / "glb" / "kitti")
    async with running_server(tmp_path) as server:
        _, built = await whole_log(server, "no-index")
        _, stored = await whole_log(server, "glb")
    assert timestamps(built) == timestamps(stored) and len(timestamps(built)) == 25


@pytest.fixture
def damaged(written: Path, tmp_path: Path) -> Path:
    """The KITTI PBE log with three bad frames: truncated, a broken length, the metadata in a frame's place."""
    log = copy_log(written / "pbe" / "kitti", tmp_path / "logs" / "damaged")
    truncated = (log / "5-frame.pbe").read_bytes()
    replace(log / "5-frame.pbe", truncated[: len(truncated) // 2])
    broken = bytearray((log / "7-frame.pbe").read_bytes())
    at = broken.index(b"/lidar/points") + len(b"/lidar/points") + 1  # the length of the primitive state
    broken[at : at + 11] = b"\xff" * 11
    replace(log / "7-frame.pbe", bytes(broken))
    replace(log / "9-frame.pbe", (log / "1-frame.pbe").read_bytes())
    return tmp_path / "logs"


async def test_damaged_pbe_frames_are_named_and_the_rest_is_served(damaged: Path):
    async with running_server(damaged) as server:
        _, messages = await whole_log(server, "damaged")
        errors = [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]
        assert len(timestamps(messages)) == 25 - 3
        assert len(errors) == 3, errors
        five, seven, nine = (
            [e for e in errors if f"({name})" in e] for name in ("5-frame.pbe", "7-frame.pbe", "9-frame.pbe")
        )
        # 23 = "PBE1", then the type's tag, length and 17 letters: where the truncated data field starts
        assert "PBE message corrupt at offset 23: xviz.v2.Envelope.data: needs" in five[0]
        assert "xviz.v2.Envelope.data.value.updates.primitives.value: varint longer than 10 bytes" in seven[0]
        assert "holds 'xviz/metadata', not xviz/state_update" in nine[0]
        # the log stays usable: a point-in-time query after the bad frames
        async with client(server, "/damaged") as c:
            await c.recv()
            await c.send("transform_point_in_time", {"id": "p", "query_timestamp": 1317042147.0})
            answer = await c.recv()
            assert answer["type"] == "xviz/state_update" and answer["data"]["update_type"] == "COMPLETE_STATE"


def test_validate_reads_pbe_logs(written: Path, damaged: Path):
    report = check_paths([written / "pbe" / "kitti"])
    assert report.ok and len(report.files) == 27, report.render()
    assert {f.kind for f in report.files} == {"xviz/metadata", "xviz/state_update", "index"}
    bad = {f.path.name: f.problems for f in check_paths([damaged / "damaged"]).files if not f.ok}
    assert set(bad) == {"5-frame.pbe", "7-frame.pbe", "9-frame.pbe"}
    assert "offset 23" in bad["5-frame.pbe"][0]
