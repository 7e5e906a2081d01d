"""JSON and GLB codecs against the golden files, the real KITTI log and bad input."""

from __future__ import annotations

import base64
import json
import random
import struct
from pathlib import Path

import numpy as np
import pytest

from helpers import assert_same_message
from xviz_server.codec import (
    Format,
    decode,
    decode_glb,
    decode_json,
    detect_format,
    edit_glb,
    encode,
    encode_glb,
    encode_json,
)
from xviz_server.exceptions import DecodeError, EncodeError

# A 2x1 PNG: signature, IHDR (width 2, height 1), IDAT, IEND.
PNG_2X1 = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAIAAAABCAIAAAB7QOjdAAAAEElEQVR4nGP4z8DAwMDAAAAe/wH/mHOF0QAAAABJRU5ErkJggg=="
)


def glb_parts(data: bytes) -> tuple[dict, bytes]:
    """Split a GLB file into its JSON document and BIN chunk, independently of the codec."""
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A
    document = json.loads(data[20 : 20 + json_length])
    bin_at = 20 + ((json_length + 3) & ~3)
    bin_length, bin_type = struct.unpack_from("<II", data, bin_at)
    assert bin_type == 0x004E4942
    assert bin_at + 8 + bin_length == total
    return document, data[bin_at + 8 :]


# ---------------------------------------------------------------- golden files


@pytest.mark.parametrize(
    "name, expected",
    [
        (
            "minimal-metadata.glb",
            {"type": "xviz/metadata", "data": {"log_info": {"start_time": 1, "end_time": 2}}},
        ),
        (
            "minimal-state-update.glb",
            {"type": "xviz/state_update", "data": {"updates": [{"timestamp": 100}]}},
        ),
    ],
)
def test_golden_files_decode_and_reencode_byte_identical(shared_dir: Path, name, expected):
    data = (shared_dir / "conformance" / "fixtures" / name).read_bytes()
    message = decode(data)
    assert message == expected
    assert encode(message, Format.BINARY) == data


# ------------------------------------------------------------- real KITTI log


def kitti_frames(log: Path) -> list[Path]:
    return sorted(log.glob("*-frame.glb"), key=lambda p: int(p.name.split("-")[0]))


def test_every_kitti_frame_round_trips_through_glb(kitti_log: Path):
    frames = kitti_frames(kitti_log)
    assert len(frames) == 26  # metadata + 25 state updates
    for path in frames:
        data = path.read_bytes()
        first = decode_glb(data)
        again = decode_glb(encode_glb(first))
        assert_same_message(again, first, path.name)


def test_kitti_frame_decodes_to_numpy_views_without_copy(kitti_log: Path):
    data = (kitti_log / "2-frame.glb").read_bytes()
    message = decode_glb(data)
    update = message["data"]["updates"][0]
    cloud = update["primitives"]["/lidar/points"]["points"][0]
    whole = np.frombuffer(data, dtype=np.uint8)

    assert cloud["points"].dtype == np.float32 and cloud["points"].shape == (121015, 3)
    assert cloud["colors"].dtype == np.uint8 and cloud["colors"].shape == (121015, 3)
    assert np.shares_memory(cloud["points"], whole)
    assert np.shares_memory(cloud["colors"], whole)
    assert not cloud["points"].flags.writeable

    image = update["primitives"]["/camera/image_00"]["images"][0]["data"]
    assert isinstance(image, memoryview)
    assert bytes(image[:8]) == b"\x89PNG\r\n\x1a\n"
    assert np.shares_memory(np.frombuffer(image, dtype=np.uint8), whole)
    # float64 values stay in the JSON.
    assert update["timestamp"] == 1317042145.964


def test_kitti_frame_survives_glb_json_glb(kitti_log: Path):
    original = decode_glb((kitti_log / "3-frame.glb").read_bytes())
    via_json = decode_json(encode_json(original))
    cloud = via_json["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]
    count = len(original["data"]["updates"][0]["primitives"]["/lidar/points"]["points"][0]["points"])
    assert isinstance(cloud["points"], list) and len(cloud["points"]) == count
    image = via_json["data"]["updates"][0]["primitives"]["/camera/image_00"]["images"][0]["data"]
    assert isinstance(image, str)  # base64 in JSON

    back = decode_glb(encode_glb(via_json))
    assert_same_message(back, original)


def test_encoded_kitti_frame_has_xviz_io_layout(kitti_log: Path):
    data = encode_glb(decode_glb((kitti_log / "2-frame.glb").read_bytes()))
    document, binary = glb_parts(data)
    assert list(document) == ["buffers", "bufferViews", "accessors", "images", "meshes", "xviz"]
    assert document["buffers"] == [{"byteLength": len(binary)}]
    assert len(binary) % 4 == 0
    end = 0
    for view in document["bufferViews"]:
        assert view["buffer"] == 0 and view["byteOffset"] % 4 == 0
        assert binary[end : view["byteOffset"]] == bytes(view["byteOffset"] - end)  # zero-filled gaps
        end = view["byteOffset"] + view["byteLength"]
    kinds = [(a["type"], a["componentType"], a["count"]) for a in document["accessors"]]
    assert kinds == [("VEC3", 5126, 50), ("VEC3", 5121, 121015), ("VEC3", 5126, 121015)]
    assert [i["mimeType"] for i in document["images"]] == ["image/png"] * 4
    assert all((i["width"], i["height"]) == (397, 120) for i in document["images"])


# --------------------------------------------------------------- encoding rules


def state_update(primitives: dict) -> dict:
    return {
        "type": "xviz/state_update",
        "data": {"update_type": "SNAPSHOT", "updates": [{"timestamp": 1.5, "primitives": primitives}]},
    }


def test_numpy_arrays_go_to_bin_by_key_and_dtype():
    points = np.arange(12, dtype=np.float64).reshape(4, 3) / 7
    colors = np.array([[1, 2, 3, 4]] * 4)
    ids = np.array([1, 2, 3], dtype=np.uint16)
    precise = np.array([0.1, 0.2], dtype=np.float64)
    message = state_update({"/p": {"points": [{"points": points, "colors": colors, "ids": ids, "precise": precise}]}})
    data = encode_glb(message)
    document, _ = glb_parts(data)
    assert [(a["type"], a["componentType"]) for a in document["accessors"]] == [
        ("VEC3", 5126),
        ("VEC4", 5121),
        ("SCALAR", 5123),
    ]
    cloud = decode_glb(data)["data"]["updates"][0]["primitives"]["/p"]["points"][0]
    assert np.array_equal(cloud["points"], points.astype(np.float32))
    assert np.array_equal(cloud["colors"], colors.astype(np.uint8))
    assert cloud["ids"].dtype == np.uint16 and cloud["ids"].tolist() == [1, 2, 3]
    assert cloud["precise"] == [0.1, 0.2]  # float64 stayed in the JSON, exactly


def test_json_lists_are_packed_like_xviz_io():
    message = state_update(
        {
            "/poly": {"polygons": [{"vertices": [[0, 0], [1, 0], [1, 1]]}]},
            "/flat": {"polylines": [{"vertices": [0, 0, 0, 1, 1, 1]}]},
            "/ragged": {"polylines": [{"vertices": [[0, 0, 0], [1, 1]]}]},
            "/bad_colors": {"points": [{"points": [[0, 0, 0]], "colors": [[300, 0, 0]]}]},
        }
    )
    primitives = decode_glb(encode_glb(message))["data"]["updates"][0]["primitives"]
    polygon = primitives["/poly"]["polygons"][0]["vertices"]
    assert polygon.dtype == np.float32 and polygon.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    assert primitives["/flat"]["polylines"][0]["vertices"].shape == (2, 3)
    assert primitives["/ragged"]["polylines"][0]["vertices"] == [[0, 0, 0], [1, 1]]
    assert primitives["/bad_colors"]["points"][0]["colors"] == [[300, 0, 0]]


def test_images_move_to_bin_with_type_and_size():
    message = state_update(
        {
            "/cam/raw": {"images": [{"data": PNG_2X1, "width_px": 2, "height_px": 1}]},
            "/cam/b64": {"images": [{"data": base64.b64encode(PNG_2X1).decode()}]},
        }
    )
    data = encode_glb(message)
    document, _ = glb_parts(data)
    assert document["images"] == [
        {"bufferView": 0, "mimeType": "image/png", "width": 2, "height": 1},
        {"bufferView": 1, "mimeType": "image/png", "width": 2, "height": 1},
    ]
    primitives = decode_glb(data)["data"]["updates"][0]["primitives"]
    assert bytes(primitives["/cam/raw"]["images"][0]["data"]) == PNG_2X1
    assert bytes(primitives["/cam/b64"]["images"][0]["data"]) == PNG_2X1
    as_json = decode_json(encode_json(decode_glb(data)))
    assert base64.b64decode(as_json["data"]["updates"][0]["primitives"]["/cam/raw"]["images"][0]["data"]) == PNG_2X1


def test_strings_that_look_like_pointers_are_escaped():
    message = state_update({"/t": {"texts": [{"text": "#/accessors/0", "position": [0, 0, 0]}]}})
    data = encode_glb(message)
    assert b'"##/accessors/0"' in data
    assert decode_glb(data) == message


def test_misshapen_arrays_are_refused_with_the_key():
    with pytest.raises(EncodeError, match="'points'.*shape \\(4, 4\\)"):
        encode_glb(state_update({"/p": {"points": [{"points": np.zeros((4, 4), np.float32)}]}}))
    with pytest.raises(EncodeError, match="'colors'.*0-255"):
        encode_glb(state_update({"/p": {"points": [{"points": np.zeros((1, 3)), "colors": np.full((1, 3), 256)}]}}))


def test_json_encodes_numpy_and_non_contiguous_views():
    points = np.arange(18, dtype=np.float32).reshape(6, 3)[::2]  # strided view
    text = encode_json({"points": points, "n": np.int64(3), "u": np.arange(3, dtype=np.uint8)})
    assert json.loads(text) == {"points": points.tolist(), "n": 3, "u": [0, 1, 2]}


def test_json_encoding_refuses_unknown_objects():
    with pytest.raises(EncodeError, match="cannot encode message as JSON: .*object"):
        encode_json({"x": object()})


# ------------------------------------------------------------ decoder variants


def build_glb(
    document: dict, binary: bytes = b"", *, magic=b"glTF", json_type=0x4E4F534A, bin_type=0x004E4942
) -> bytes:
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary += bytes(-len(binary) % 4)
    body = struct.pack("<II", len(text), json_type) + text + struct.pack("<II", len(binary), bin_type) + binary
    return struct.pack("<4sII", magic, 2, 12 + len(body)) + body


def test_decoder_reads_extension_form_legacy_magic_and_chunk_types():
    floats = np.array([1, 2, 3], dtype=np.float32).tobytes()
    document = {
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "type": "VEC3", "componentType": 5126, "count": 1}],
        "extensionsUsed": ["AVS_xviz"],
        "extensions": {"AVS_xviz": state_update({"/v": {"polylines": [{"vertices": "#/accessors/0"}]}})},
    }
    for data in (
        build_glb(document, floats),
        build_glb(document, floats, magic=b"XVIZ"),
        build_glb(document, floats, json_type=0, bin_type=1),
    ):
        decoded = decode_glb(data)
        assert decoded["data"]["updates"][0]["primitives"]["/v"]["polylines"][0]["vertices"].tolist() == [[1, 2, 3]]


def test_edit_glb_replaces_the_envelope_and_keeps_the_bin_chunk(kitti_log: Path):
    data = (kitti_log / "5-frame.glb").read_bytes()

    def relabel(envelope):
        return {**envelope, "data": {**envelope["data"], "update_type": "COMPLETE_STATE"}}

    edited = edit_glb(data, relabel)
    document, binary = glb_parts(edited)
    original_document, original_binary = glb_parts(data)
    assert binary == original_binary
    assert document["accessors"] == original_document["accessors"]
    expected = decode(data)
    expected["data"]["update_type"] = "COMPLETE_STATE"
    assert_same_message(decode(edited), expected)


def test_edit_glb_writes_the_current_form_of_legacy_files():
    floats = np.array([1, 2, 3], dtype=np.float32).tobytes()
    document = {
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "type": "VEC3", "componentType": 5126, "count": 1}],
        "extensionsUsed": ["AVS_xviz", "OTHER"],
        "extensionsRequired": ["AVS_xviz"],
        "extensions": {
            "AVS_xviz": state_update({"/v": {"polylines": [{"vertices": "#/accessors/0"}]}}),
            "OTHER": {"a": 1},
        },
    }
    edited = edit_glb(build_glb(document, floats, magic=b"XVIZ", json_type=0, bin_type=1), lambda envelope: envelope)
    written, binary = glb_parts(edited)  # current magic and chunk types
    assert binary == floats
    assert written["extensions"] == {"OTHER": {"a": 1}}
    assert written["extensionsUsed"] == ["OTHER"] and "extensionsRequired" not in written
    assert written["xviz"] == document["extensions"]["AVS_xviz"]
    assert decode_glb(edited)["data"]["updates"][0]["primitives"]["/v"]["polylines"][0]["vertices"].tolist() == [
        [1, 2, 3]
    ]
    with pytest.raises(DecodeError, match="declares"):
        edit_glb(edited[:-4], lambda envelope: envelope)


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "data, message",
    [
        (b"glT", "header truncated"),
        (b"abcd" + bytes(20), "magic b'abcd' at offset 0"),
        (struct.pack("<4sII", b"glTF", 1, 20) + bytes(8), "version 1 at offset 4"),
        (struct.pack("<4sII", b"glTF", 2, 500) + bytes(8), "declares 500 bytes, only 20 present"),
        (
            struct.pack("<4sII", b"glTF", 2, 28) + struct.pack("<II", 100, 0x4E4F534A) + bytes(8),
            "chunk at offset 12 declares 100 bytes",
        ),
        (build_glb({"xviz": {}}, json_type=7), "no JSON chunk"),
        (build_glb({"no": "xviz"}), "no 'xviz' key"),
        (
            build_glb({"bufferViews": [{"byteOffset": 0, "byteLength": 64}], "xviz": {}}),
            "bufferViews\\[0\\] spans bytes 0-64 of a 0-byte BIN chunk",
        ),
        (
            build_glb({"bufferViews": [{"byteLength": -1}], "xviz": {}}),
            "bufferViews\\[0\\].byteLength must be a non-negative integer",
        ),
        (
            build_glb(
                {"accessors": [{"bufferView": 3, "type": "VEC3", "componentType": 5126, "count": 1}], "xviz": {}}
            ),
            "accessors\\[0\\].bufferView 3 is out of range",
        ),
        (
            build_glb(
                {
                    "bufferViews": [{"byteLength": 4}],
                    "accessors": [{"bufferView": 0, "type": "VEC3", "componentType": 5126, "count": 1}],
                    "xviz": {},
                },
                bytes(4),
            ),
            "accessors\\[0\\] needs 12 bytes",
        ),
        (
            build_glb(
                {
                    "bufferViews": [{"byteLength": 4}],
                    "accessors": [{"bufferView": 0, "type": "MAT9", "componentType": 5126, "count": 1}],
                    "xviz": {},
                },
                bytes(4),
            ),
            "accessors\\[0\\].type 'MAT9'",
        ),
        (
            build_glb(
                {
                    "bufferViews": [{"byteLength": 4}],
                    "accessors": [{"bufferView": 0, "type": "SCALAR", "componentType": 5130, "count": 1}],
                    "xviz": {},
                },
                bytes(4),
            ),
            "componentType 5130",
        ),
        (
            build_glb({"xviz": {"data": {"updates": [{"points": "#/accessors/4"}]}}}),
            "'#/accessors/4' at \\$.data.updates\\[0\\].points names nothing",
        ),
    ],
)
def test_bad_glb_is_refused_with_offset_or_field(data, message):
    with pytest.raises(DecodeError, match=message):
        decode_glb(data)


def test_bad_json_chunk_reports_its_offset():
    data = bytearray(build_glb({"xviz": {"a": 1}}))
    data[20] = ord("!")
    with pytest.raises(DecodeError, match="not valid JSON at offset 20") as info:
        decode_glb(bytes(data))
    assert info.value.offset == 20


def test_truncated_or_corrupt_real_frames_never_decode_silently(kitti_log: Path):
    data = (kitti_log / "4-frame.glb").read_bytes()
    rng = random.Random(4)
    cuts = list(range(0, 2200, 37)) + [len(data) - 1, len(data) // 2]
    for cut in cuts:
        with pytest.raises(DecodeError):
            decode_glb(data[:cut])
    # The container's own bytes (file header, both chunk headers): any change is an error.
    json_length = struct.unpack_from("<I", data, 12)[0]
    bin_header = 20 + -(-json_length // 4) * 4
    framing = [*range(20), *range(bin_header, bin_header + 8)]
    for _ in range(300):
        corrupt = bytearray(data)
        position = rng.choice(framing)
        corrupt[position] = rng.choice([value for value in range(256) if value != data[position]])
        with pytest.raises(DecodeError):
            decode_glb(bytes(corrupt))
    # Inside the JSON chunk: an error, or still a JSON object; never another exception.
    for _ in range(300):
        corrupt = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            corrupt[rng.randrange(20, 20 + json_length)] = rng.randrange(256)
        try:
            message = decode_glb(bytes(corrupt))
        except DecodeError:
            continue
        assert isinstance(message, dict)


def test_invalid_json_text_reports_line_and_column():
    with pytest.raises(DecodeError, match="line 2 column 5"):
        decode_json('{"a":\n    x}')


def test_format_detection():
    assert detect_format(b"glTF....") is Format.BINARY
    assert detect_format(b"XVIZ....") is Format.BINARY
    assert detect_format(b'{"type"') is Format.JSON
    assert detect_format('{"type"') is Format.JSON
    with pytest.raises(DecodeError, match="PBE1"):
        detect_format(b"PBE1\x00\x00")
