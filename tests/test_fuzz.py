"""Fuzzing every parser of untrusted bytes, seeded with real files and mutated.

Each parser of bytes that a client, a live source, a recording or the broker
controls is fed its real inputs changed the way damage and attackers change
them: bytes flipped, files cut short, length fields set to 0, 1, 2**31 or
past the end, ranges deleted, repeated or spliced in from another seed, and,
for JSON (and a GLB's JSON chunk), any value of the tree replaced by another
JSON value (deep nesting, huge integers, pointers to nothing). The property
is the same everywhere: the parser returns a value or raises the package's
own named error (the RESP reader: redis-py's ``InvalidResponse``, which its
wire turns into a dropped connection), never another exception; and its
Python memory peak stays within :func:`memory_limit` of the input's size.

The seeds are real: the KITTI frames as XVIZ GLB and the conformance
corpus's golden GLB and JSON files; PBE written by the published ``@xviz/io``
writer (node); ROS 1 bags written by rosbags (plain, bz2 and lz4 chunks, and
the same cut short before their index, read by our reindexer); Waymo
segments framed by our TFRecord writer around generated frames; and replies
captured from a real ``redis-server``.

How long it runs is chosen by ``XVIZ_FUZZ``: ``ci`` (the default: a few
dozen examples per parser, the same on every run, a few seconds in all) or
``long`` (new examples on every run, ``XVIZ_FUZZ_EXAMPLES`` of them per parser:
``scripts/bench/fuzz.py --minutes N`` runs it again and again for N minutes). What a run found
is kept below as explicit regression cases (``@example``).
"""

from __future__ import annotations

import copy
import functools
import itertools
import json
import os
import re
import shutil
import struct
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import orjson
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from devkit.data import FIXTURES, KITTI_LOG, SCHEMA_EXAMPLES
from helpers import INTEROP, PNG_2X1, metadata, needs_data, update, write_log, xviz_write
from xviz_server.admission import admit
from xviz_server.codec import Format, decode, decode_glb, decode_json, decode_pbe, encode
from xviz_server.events import Send
from xviz_server.exceptions import DatasetError, DecodeError, EncodeError, MessageError
from xviz_server.layout import METADATA_NUMBER
from xviz_server.timeindex import TimeIndex
from xviz_server.xviz.session import Session

pytestmark = [pytest.mark.slow, needs_data]

PROFILES = {
    # The same examples on every run (no flaky CI), few enough for a few seconds per parser.
    "ci": settings(
        max_examples=30,
        derandomize=True,
        deadline=None,
        database=None,
        print_blob=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example],
    ),
    # New examples on every run (XVIZ_FUZZ_EXAMPLES per parser, scripts/bench/fuzz.py runs it again until its time
    # is up); an example that takes over 10 s is a failure.
    "long": settings(
        max_examples=int(os.environ.get("XVIZ_FUZZ_EXAMPLES", "1000")),
        derandomize=False,
        deadline=10_000,
        print_blob=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example],
    ),
}
FUZZ = PROFILES[os.environ.get("XVIZ_FUZZ", "ci")]

T = TypeVar("T")


# --------------------------------------------------------------------------
# The property


def memory_limit(size: int) -> int:
    """The most Python memory a parser may hold at once for ``size`` bytes of input."""
    return 64 * 2**20 + 8 * size


def refuses_by_name(parse: Callable[[], T], size: int, errors: tuple[type[BaseException], ...]) -> T | None:
    """``parse()``, or ``None`` when it raised one of ``errors`` (``()``: none may be raised); its memory bounded."""
    tracemalloc.start()
    try:
        return parse()
    except errors:
        return None
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak <= memory_limit(size), f"peak of {peak} bytes for {size} bytes of input"


# --------------------------------------------------------------------------
# Mutations


INTERESTING = (
    0,
    1,
    2,
    3,
    4,
    7,
    8,
    12,
    16,
    0x7F,
    0x80,
    0xFF,
    0x100,
    0xFFFF,
    0x10000,
    0x7FFFFFFF,
    0x80000000,
    0xFFFFFFFF,
)
MUTATIONS = ("flip", "truncate", "length", "u32", "u64", "insert", "delete", "repeat", "splice")


def positions(size: int) -> st.SearchStrategy[int]:
    """A position in ``size`` bytes, more often near the start and the end, where headers and indexes are."""
    return st.one_of(st.integers(0, min(size, 512)), st.integers(max(0, size - 512), size), st.integers(0, size))


def length(size: int) -> st.SearchStrategy[int]:
    """A value for a length field: a small or boundary number, or near the size of the input."""
    return st.one_of(st.sampled_from(INTERESTING), st.integers(max(0, size - 16), size + 16), st.integers(0, 2**32 - 1))


@st.composite
def mutated(draw: st.DrawFn, seeds: list[bytes]) -> bytes:
    """One of ``seeds`` after one to four mutations."""
    data = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 4))):
        size = len(data)
        at = draw(positions(size))
        kind = draw(st.sampled_from(MUTATIONS))
        if kind == "flip" and at < size:
            data[at] ^= draw(st.sampled_from([0x01, 0x80, 0xFF])) if draw(st.booleans()) else draw(st.integers(1, 255))
        elif kind == "truncate":
            del data[at:]
        elif kind == "length":  # the first u32 from ``at`` that may be a length (at most the size) gets another value
            for start in range(at, min(at + 256, size - 3)):
                if 0 < struct.unpack_from("<I", data, start)[0] <= size:
                    data[start : start + 4] = struct.pack("<I", draw(length(size)) & 0xFFFFFFFF)
                    break
        elif kind in ("u32", "u64") and at < size:
            width = 4 if kind == "u32" else 8
            value = draw(st.one_of(length(size), st.integers(0, 2 ** (8 * width) - 1))) % 2 ** (8 * width)
            data[at : at + width] = value.to_bytes(width, draw(st.sampled_from(["little", "big"])))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 64))]
        elif kind == "repeat":
            span = draw(st.integers(1, 256))
            data[at:at] = data[at : at + span] * draw(st.integers(1, 4))
        elif kind == "splice":  # bytes from another seed, at any place of its
            other = draw(st.sampled_from(seeds))
            start = draw(positions(len(other)))
            data[at : at + draw(st.integers(0, 64))] = other[start : start + draw(st.integers(1, 512))]
    return bytes(data)


_DEEP = "\x00deep"  # replaced by arrays nested as deep as orjson reads (1024 levels with the envelope)
_HUGE = "\x00huge"  # replaced by an integer of 5 000 digits
JSON_ATOMS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=False),
    st.text(max_size=12),
    st.sampled_from(
        [
            "#/accessors/0",
            "#/accessors/99",
            "#/images/0",
            "#/accessors/" + "9" * 5000,
            "##/a",
            "#/buffers/0",
            "xviz/state_update",
            "xviz/metadata",
            "COMPLETE_STATE",
            "",
            _DEEP,
            _HUGE,
        ]
    ),
)
JSON_KEYS = st.one_of(
    st.text(max_size=8),
    st.sampled_from(
        [
            "type",
            "data",
            "updates",
            "timestamp",
            "primitives",
            "points",
            "colors",
            "vertices",
            "images",
            "buffers",
            "bufferViews",
            "accessors",
            "bufferView",
            "byteOffset",
            "byteLength",
            "count",
            "componentType",
            "extensions",
            "AVS_xviz",
            "xviz",
            "version",
            "streams",
            "id",
            "update_type",
            "config_update",
            "desired_streams",
            "query_timestamp",
            "poses",
            "time_series",
        ]
    ),
)
JSON_VALUES = st.recursive(
    JSON_ATOMS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(JSON_KEYS, inner, max_size=4), max_leaves=8
)


def json_text(document: Any) -> bytes:
    """``document`` as JSON text, with its placeholders for deep nesting and huge integers filled in."""
    text = json.dumps(document, separators=(",", ":"))
    return text.replace(json.dumps(_DEEP), "[" * 1000 + "]" * 1000).replace(json.dumps(_HUGE), "7" * 5000).encode()


def _mutate_node(draw: st.DrawFn, node: Any, depth: int = 0) -> Any:
    if isinstance(node, (dict, list)) and node and depth < 16 and draw(st.integers(0, 3)):
        key = draw(st.sampled_from(list(node) if isinstance(node, dict) else range(len(node))))
        node[key] = _mutate_node(draw, node[key], depth + 1)
        return node
    if isinstance(node, dict) and draw(st.booleans()):
        node[draw(JSON_KEYS)] = draw(JSON_VALUES)
        if node and draw(st.booleans()):
            del node[draw(st.sampled_from(list(node)))]
        return node
    return draw(JSON_VALUES)


@st.composite
def tree_mutated(draw: st.DrawFn, documents: list[Any]) -> Any:
    """One of ``documents`` (JSON trees) with one to three of its values replaced, added or removed."""
    document = copy.deepcopy(draw(st.sampled_from(documents)))
    for _ in range(draw(st.integers(1, 3))):
        document = _mutate_node(draw, document)
    return document


# --------------------------------------------------------------------------
# Seeds


def glb_parts(data: bytes) -> tuple[Any, bytes]:
    """The JSON document and BIN chunk of a well-formed GLB file."""
    (json_length,) = struct.unpack_from("<I", data, 12)
    document = orjson.loads(data[20 : 20 + json_length])
    start = 20 + (json_length + 3) // 4 * 4
    binary = data[start + 8 :] if start < len(data) else b""
    return document, binary


def glb_file(document_text: bytes, binary: bytes) -> bytes:
    """A GLB file of a JSON chunk and a BIN chunk, as the decoder expects them."""
    text = document_text + b" " * (-len(document_text) % 4)
    body = binary + bytes(-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(body)
    return (
        b"glTF"
        + struct.pack("<II", 2, total)
        + struct.pack("<I", len(text))
        + b"JSON"
        + text
        + struct.pack("<I", len(body))
        + b"BIN\0"
        + body
    )


KITTI_GLB = [(KITTI_LOG / f"{n}-frame.glb").read_bytes() for n in (1, 2)] if KITTI_LOG.is_dir() else []
GOLDEN_GLB = sorted(FIXTURES.glob("*.glb")) if FIXTURES.is_dir() else []
GLB_SEEDS = KITTI_GLB + [path.read_bytes() for path in GOLDEN_GLB]
GLB_TREES = [glb_parts(seed) for seed in GLB_SEEDS]
JSON_SEEDS = [path.read_bytes() for path in sorted(FIXTURES.glob("*.json"))] if FIXTURES.is_dir() else []
ENVELOPES = sorted((SCHEMA_EXAMPLES / "valid" / "envelope").glob("*.json"))
CLIENT_SEEDS = [path.read_bytes() for path in ENVELOPES] + [
    b'{"type":"xviz/start","data":{"version":"2.0.0","session_type":"LOG","message_format":"BINARY","log":"drive"}}',
    b'{"type":"xviz/transform_log","data":{"id":"1","start_timestamp":100.5,"end_timestamp":101,"desired_streams":["/points"]}}',
    b'{"type":"xviz/transform_point_in_time","data":{"id":2,"query_timestamp":100.7}}',
    b'{"type":"xviz/reconfigure","data":{"update_type":"DELTA","config_update":{"speed":2,"desired_streams":["/a"]}}}',
]


def trees(seeds: list[bytes]) -> list[Any]:
    return [orjson.loads(seed) for seed in seeds]


@st.composite
def glb_messages(draw: st.DrawFn) -> bytes:
    """A real GLB message with bytes mutated or with its JSON chunk's tree mutated."""
    if draw(st.booleans()):
        return draw(mutated(GLB_SEEDS))
    document, binary = draw(st.sampled_from(GLB_TREES))
    return glb_file(json_text(draw(tree_mutated([document]))), binary)


def json_messages(seeds: list[bytes]) -> st.SearchStrategy[bytes]:
    return st.one_of(mutated(seeds), tree_mutated(trees(seeds)).map(json_text))


# --------------------------------------------------------------------------
# GLB, JSON, PBE


def decodes_or_refuses(data: bytes, parse: Callable[[bytes], Any]) -> None:
    message = refuses_by_name(lambda: parse(data), len(data), (DecodeError,))
    if message is not None:  # what decoded is encoded again (a GLB log is served as JSON), or refused by name
        for fmt in Format:
            refuses_by_name(lambda: encode(message, fmt), len(data), (EncodeError,))


DEEP_JSON = b"[" * 1000 + b"]" * 1000


@FUZZ
@given(glb_messages())
# What the fuzzing found: lists, objects and pointers of the wrong kind; nesting that ran out of Python's stack.
@example(glb_file(b'{"bufferViews":5,"xviz":{}}', b""))
@example(glb_file(b'{"accessors":true,"xviz":{}}', b""))
@example(
    glb_file(
        b'{"bufferViews":[{"byteLength":0}],"accessors":[{"bufferView":0,"componentType":[5126],"type":"VEC3","count":0}],"xviz":{}}',
        b"",
    )
)
@example(
    glb_file(
        b'{"bufferViews":[{"byteLength":0}],"accessors":[{"bufferView":0,"componentType":5126,"type":["VEC3"],"count":0}],"xviz":{}}',
        b"",
    )
)
@example(glb_file(b'{"extensions":[1]}', b""))
@example(glb_file(b'{"extensions":true}', b""))
@example(glb_file(b'{"xviz":{"data":"#/accessors/' + b"9" * 5000 + b'"}}', b""))
@example(glb_file(b'{"xviz":' + DEEP_JSON + b"}", b""))
@example(glb_file(b'{"xviz":' + b"[" * 200 + b"]" * 200 + b"}", b""))
def test_glb(data: bytes):
    decodes_or_refuses(data, decode_glb)


@FUZZ
@given(json_messages(JSON_SEEDS + CLIENT_SEEDS))
@example(b'{"type":"xviz/state_update","data":' + b"[" * 200 + b"]" * 200 + b"}")  # decodes; too deep to encode as GLB
def test_json(data: bytes):
    decodes_or_refuses(data, decode_json)


@pytest.fixture(scope="module")
def pbe_seeds(tmp_path_factory: pytest.TempPathFactory) -> list[bytes]:
    """PBE messages written by the published @xviz/io writer: the KITTI metadata and a frame, and small updates."""
    if shutil.which("node") is None or not (INTEROP / "node_modules" / "@xviz" / "io").is_dir():
        pytest.skip("needs node and tests/interop's packages: npm ci --prefix tests/interop")
    root = tmp_path_factory.mktemp("pbe")
    kitti = root / "kitti"
    kitti.mkdir()
    for n, seed in enumerate(KITTI_GLB, start=1):
        (kitti / f"{n}-frame.glb").write_bytes(seed)
    small = [update(10 + i / 10, points=5, update_type="COMPLETE_STATE") for i in range(2)]
    small[1]["updates"][0]["primitives"]["/camera"] = {"images": [{"data": PNG_2X1, "width_px": 2, "height_px": 1}]}
    write_log(root / "small", small, meta=metadata())
    seeds = []
    for name in ("kitti", "small"):
        xviz_write(root / name, BINARY_PBE=root / "pbe" / name)
        seeds += [path.read_bytes() for path in sorted((root / "pbe" / name).glob("*-frame.pbe"))]
    assert len(seeds) == 5 and all(seed.startswith(b"PBE1") for seed in seeds)
    return seeds


def _field(number: int, value: bytes) -> bytes:
    """A length-delimited protobuf field."""
    key, length = bytes([number << 3 | 2]), bytearray()
    size = len(value)
    while True:
        length.append(size & 0x7F | (0x80 if size > 0x7F else 0))
        size >>= 7
        if not size:
            return key + bytes(length) + value


def nested_struct_pbe(depth: int) -> bytes:
    """A PBE metadata message whose panel configuration (a google.protobuf.Struct) nests lists ``depth`` deep."""
    value = b""
    for _ in range(depth):
        value = _field(6, _field(1, value))  # Value.list_value, ListValue.values
    config = _field(1, _field(1, b"k") + _field(2, value))  # Struct.fields: key, value
    metadata = _field(5, _field(1, b"panel") + _field(2, _field(3, config)))  # ui_config: name, UIPanelInfo.config
    return b"PBE1" + _field(1, b"xviz/metadata") + _field(2, _field(1, b"xviz.v2.Metadata") + _field(2, metadata))


def test_pbe(pbe_seeds: list[bytes]):
    @FUZZ
    @given(mutated(pbe_seeds))
    @example(nested_struct_pbe(2000))  # found: finding what protobuf refused recursed past Python's stack
    def fuzz(data: bytes) -> None:
        decodes_or_refuses(data, decode_pbe)

    fuzz()


INDEX_SEEDS = [(KITTI_LOG / "0-frame.json").read_bytes()] if KITTI_LOG.is_dir() else []


@FUZZ
@given(json_messages(INDEX_SEEDS))
@example(b'{"timing":[[0,1,1e300,"2-frame"]]}')  # found: cast to int64 as a negative frame number
@example(b'{"timing":[[0,1,1180591620717411303424,"2-frame"]]}')
def test_log_index(data: bytes):
    # A recorded log's index file (0-frame.json): a value, or a DecodeError naming the row.
    index = refuses_by_name(lambda: TimeIndex.from_reference(decode_json(data)), len(data), (DecodeError,))
    if index is not None:
        assert (index.frames >= 0).all() and len(index.start) == len(index.end) == len(index.frames)


# --------------------------------------------------------------------------
# Client messages through the session


class _Log:
    """An open log, as far as a session sees it: 20 frames at 10 Hz from 100 s."""

    name = "drive"
    format = Format.BINARY
    index = TimeIndex.from_spans((100 + i / 10, 100 + i / 10, i) for i in range(20))

    def metadata_message(self, fmt: Format) -> bytes:
        return encode({"type": "xviz/metadata", "data": {"version": "2.0.0"}}, fmt)


def _client_glb(seed: bytes) -> bytes:
    return encode(orjson.loads(seed), Format.BINARY)


@FUZZ
@given(
    st.one_of(json_messages(CLIENT_SEEDS), mutated([_client_glb(seed) for seed in CLIENT_SEEDS])),
    st.booleans(),
    st.booleans(),
)
@example(
    b'{"type":"xviz/reconfigure","data":{"update_type":"DELTA","config_update":{"a":'
    + b'{"a":' * 900
    + b"1"
    + b"}" * 901
    + b"}}",
    False,
    False,
)  # merge_patch recursed as deep as the patch
def test_session_answers_every_client_message(data: bytes, text: bool, live: bool):
    # The session never raises on what a client sends: it answers with events, errors as xviz/error messages.
    session = Session(
        path="/", query={"log": "drive", **({"session_type": "live"} if live else {})}, available=["drive"]
    )
    session.connect()
    if not live:
        session.log_opened(_Log())
    received = data.decode("utf-8", errors="replace") if text else data  # a text frame is valid UTF-8
    for event in refuses_by_name(lambda: session.receive(received), len(data), ()) or []:
        if isinstance(event, Send):
            decode(event.data)


@FUZZ
@given(
    st.dictionaries(
        st.sampled_from(["log", "logGuid", "session_type", "message_format", "version", "profile", "speed"]),
        st.one_of(st.text(max_size=20), st.sampled_from(["live", "LOG", "binary", "json", "1e309", "nan", "-1", "0"])),
    ),
    st.text(max_size=20),
)
def test_session_answers_every_connection_url(query: dict[str, str], path: str):
    session = Session(path=path, query=query, available=["drive"])
    for event in refuses_by_name(session.connect, 0, ()) or []:
        if isinstance(event, Send):
            decode(event.data)


# --------------------------------------------------------------------------
# Foxglove client messages through the Foxglove session, and an export's parameters


class _FoxgloveLog:
    """An open log, as far as a Foxglove session sees it: the KITTI log's channels, 2 s long."""

    name = "drive"
    start_time = 100 * 10**9
    end_time = 102 * 10**9
    frames = 20  # a frame every 0.1 s

    @functools.cached_property
    def channels(self) -> Any:
        from xviz_server.foxglove.translate import plan

        return plan(decode((KITTI_LOG / f"{METADATA_NUMBER}-frame.glb").read_bytes())["data"]).channels


FOXGLOVE_TEXT_SEEDS = [
    b'{"op":"subscribe","subscriptions":[{"id":1,"channelId":1},{"id":2,"channelId":2},{"id":3,"channelId":999}]}',
    b'{"op":"unsubscribe","subscriptionIds":[1,2,77]}',
    b'{"op":"advertise","channels":[{"id":1,"topic":"/a","encoding":"json","schemaName":"x","schema":"{}"}]}',
    b'{"op":"unadvertise","channelIds":[1]}',
    b'{"op":"getParameters","parameterNames":["a"],"id":"r"}',
    b'{"op":"setParameters","parameters":[{"name":"a","value":1}]}',
    b'{"op":"subscribeConnectionGraph"}',
    b'{"op":"fetchAsset","uri":"package://x","requestId":1}',
]
FOXGLOVE_BINARY_SEEDS = [
    struct.pack("<BBfBQI", 0x03, 0, 2.0, 1, 101 * 10**9, 2) + b"r1",  # playback control: play at 2x, seek
    struct.pack("<BBfBQI", 0x03, 1, 1.0, 0, 0, 0),  # pause
    b"\x01" + struct.pack("<I", 1) + b"{}",  # client message data
    b"\x02" + struct.pack("<III", 1, 1, 4) + b"json{}",  # service call request
]


@FUZZ
@given(
    st.one_of(
        json_messages(FOXGLOVE_TEXT_SEEDS).map(lambda data: data.decode("utf-8", errors="replace")),
        mutated(FOXGLOVE_BINARY_SEEDS),
    )
)
@example('{"op":"subscribe","subscriptions":[' + ",".join(["0"] * 20_000) + "]}")  # one status, not 20 000 (issue 39)
@example('{"op":"unsubscribe","subscriptionIds":[' + ",".join(["[[[]]]"] * 5000) + "]}")
def test_foxglove_session_answers_every_client_message(data: str | bytes):
    from xviz_server.foxglove.session import FoxgloveSession

    session = FoxgloveSession(path="/", query={"log": "drive"}, available=["drive"])
    session.connect()
    session.log_opened(_FoxgloveLog())
    events = refuses_by_name(lambda: session.receive(data), len(data), ()) or []
    answers = [json.loads(event.data) for event in events if isinstance(event, Send) and event.text]
    statuses = [answer for answer in answers if answer.get("op") == "status"]  # besides answers (parameterValues)
    assert len(statuses) <= 1 and all(len(status["message"]) < 1000 for status in statuses), statuses


@FUZZ
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["start", "end", "format", "token", "x"]),
            st.one_of(
                st.text(max_size=12), st.sampled_from(["1_000", " 5", "+5", "1e309", "-0", ".5", "5.", "1e-3", "mcap"])
            ),
        ),
        max_size=6,
    )
)
def test_export_parameters_are_read_or_refused_by_name(pairs: list[tuple[str, str]]):
    from urllib.parse import parse_qs, urlencode

    from xviz_server.exceptions import QueryError
    from xviz_server.foxglove.export import parse_range

    parameters = parse_qs(urlencode(pairs), keep_blank_values=True)
    span = refuses_by_name(lambda: parse_range(parameters), 0, (QueryError,))
    if span is not None:
        for key in ("start", "end"):
            assert len(parameters.get(key, [])) <= 1
            value = getattr(span, key)
            assert value is None or re.fullmatch(r"\+?-?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?", parameters[key][0])


# --------------------------------------------------------------------------
# Live-source admission


@FUZZ
@given(
    st.one_of(glb_messages(), json_messages(JSON_SEEDS + [seed for seed in CLIENT_SEEDS if b"state_update" in seed]))
)
@example(
    b'{"type":"xviz/state_update","data":{"updates":[{"timestamp":1,"x":' + DEEP_JSON + b"}]}}"
)  # _expanded_size's recursion
@example(
    glb_file(b'{"xviz":{"type":"xviz/state_update","data":{"updates":[{"timestamp":1,"x":' + DEEP_JSON + b"}]}}}", b"")
)
def test_admission(data: bytes):
    admitted = refuses_by_name(lambda: admit(data, 64 * 2**20), len(data), (MessageError,))
    if admitted is not None:  # what is let in is a GLB message that decodes
        decode_glb(admitted[1])


# --------------------------------------------------------------------------
# Waymo segments: TFRecord framing and Frame records


def _range_image(height: int, width: int, channels: int, rng: np.random.Generator) -> np.ndarray:
    image = rng.uniform(1, 40, (height, width, channels)).astype(np.float32)
    image[0, 0, 0] = -1  # a pixel with no return
    return image


def waymo_frames(
    rng: np.random.Generator,
    lasers: list[int],
    cameras: list[int],
    dims: list[int] | None = None,
    beams: int = 4,
    pose_values: int = 16,
) -> list[bytes]:
    """Two serialized Frames: the TOP laser's range images 4 x 8 with pixel poses, the others plain; a JPEG per camera."""
    from devkit.waymo_frames import calibration, frame, jpeg_image, pose_matrix
    from xviz_server.datasets.waymo import frame_pb2 as pb

    records = []
    for i in range(2):
        message = frame(
            1_557_000_000_000_000 + i * 100_000,
            pose_matrix(0.1 * i, (5.0, 1.0, 0.0)),
            [calibration("TOP", pose_matrix(0.2, (1.0, 0.0, 2.0)), np.linspace(-0.3, 0.05, beams).tolist())],
            {"TOP": (_range_image(4, 8, 4, rng), _range_image(4, 8, 4, rng), _range_image(4, 8, 6, rng))},
            {"FRONT": jpeg_image(32, 24, (200, 30, 30))},
            [((10.0, 5.0, 1.0, 4.0, 2.0, 1.6, 0.5), 1, "car")],
        )
        for name in lasers:  # lasers and cameras by number (the UNKNOWN 0 too), the same one twice too
            laser = message.lasers.add()
            laser.name = name  # type: ignore[assignment]
            laser.ri_return1.range_image_compressed = _matrix(_range_image(3, 5, 4, rng), dims)
            message.context.laser_calibrations.add(
                name=name, extrinsic=pb.Transform(transform=np.eye(4).reshape(-1).tolist())
            )  # type: ignore[arg-type]
        for name in cameras:
            message.images.add(name=name, image=jpeg_image(16, 8, (10, 200, 30)))  # type: ignore[arg-type]
        del message.pose.transform[pose_values:]
        records.append(message.SerializeToString())
    return records


def _matrix(array: np.ndarray, dims: list[int] | None) -> bytes:
    import zlib

    from xviz_server.datasets.waymo import frame_pb2 as pb

    message = pb.MatrixFloat(data=array.astype("<f4").tobytes())
    message.shape.dims.extend(array.shape if dims is None else dims)
    return zlib.compress(message.SerializeToString())


def tfrecord(records: list[bytes]) -> bytes:
    from xviz_server.datasets.waymo.tfrecord import masked_crc

    return b"".join(
        struct.pack("<Q", len(r))
        + struct.pack("<I", masked_crc(struct.pack("<Q", len(r))))
        + r
        + struct.pack("<I", masked_crc(r))
        for r in records
    )


WAYMO_SEEDS = waymo_frames(np.random.default_rng(35), [], [])


@st.composite
def waymo_segments(draw: st.DrawFn) -> bytes:
    """A segment of two frames: its file's bytes mutated, or its records' bytes mutated with sound framing, or frames
    whose lasers, cameras, shapes and calibrations are drawn."""
    mode = draw(st.integers(0, 2))
    if mode == 0:
        return draw(mutated([tfrecord(WAYMO_SEEDS)]))
    if mode == 1:
        return tfrecord([draw(mutated(WAYMO_SEEDS)), WAYMO_SEEDS[1]])
    names = st.lists(st.integers(0, 5), max_size=2)
    dims = st.one_of(st.none(), st.lists(st.integers(-2, 2**31 - 1), max_size=4))  # int32, as MatrixShape declares
    return tfrecord(
        waymo_frames(
            np.random.default_rng(0),
            draw(names),
            draw(names),
            draw(dims),
            draw(st.integers(0, 6)),
            draw(st.sampled_from([16, 15, 0])),
        )
    )


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def read_waymo(path: Path) -> None:
    from xviz_server.datasets.waymo.segment import WaymoRecordSegment

    segment = WaymoRecordSegment(path)
    for index in range(len(segment.times)):
        try:
            frame = segment.read(index)
            for camera in frame.images:
                frame.images[camera]
        except DatasetError:
            continue


def test_waymo_tfrecord(scratch: Path):
    @FUZZ
    @given(waymo_segments())
    def fuzz(data: bytes) -> None:
        path = scratch / "segment.tfrecord"
        path.write_bytes(data)
        refuses_by_name(lambda: read_waymo(path), len(data), (DatasetError,))

    fuzz()


# --------------------------------------------------------------------------
# ROS 1 bags, through rosbags and our reindexer


def ros1_bags(directory: Path) -> list[bytes]:
    """Small bags written by rosbags, in chunks of about 2 kB: plain, bz2 and lz4; each also as a recording cut short
    before its index (``index_pos`` 0), which our reindexer reads."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores

    from devkit.rosbag_kitti import Messages

    m = Messages(Stores.ROS1_NOETIC)
    t0, rng = 1_700_000_000 * 10**9, np.random.default_rng(35)
    messages = []
    for i in range(6):
        t = t0 + i * 100_000_000
        pose = m.geometry_msgs__Pose(
            position=m.geometry_msgs__Point(x=float(i), y=0.0, z=0.0), orientation=m.rotation((0.0, 0.0, 0.0, 1.0))
        )
        messages += [
            (
                "/pose",
                "geometry_msgs/msg/PoseStamped",
                t,
                m.geometry_msgs__PoseStamped(header=m.header(t, "map"), pose=pose),
            ),
            ("/speed", "std_msgs/msg/Float64", t, m.std_msgs__Float64(data=1.5 * i)),
            (
                "/tf",
                "tf2_msgs/msg/TFMessage",
                t,
                m.tf2_msgs__TFMessage(transforms=[m.transform(t, "map", "base_link", (i, 0, 0), (0, 0, 0, 1))]),
            ),
            ("/points", "sensor_msgs/msg/PointCloud2", t, m.cloud(t, rng.uniform(-5, 5, (20, 4)), "base_link")),
        ]
    seeds = []
    for compression in (None, "bz2", "lz4"):
        path = directory / f"{compression}.bag"
        writer = Writer(path)
        writer.chunk_threshold = 2048
        if compression:
            writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
        with writer:
            connections: dict[str, Any] = {}
            for topic, msgtype, t, message in messages:
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=m.store)
                writer.write(connections[topic], t, m.serialize(message, msgtype))
        data = bytearray(path.read_bytes())
        field = data.index(b"index_pos=") + len(b"index_pos=")
        (index_pos,) = struct.unpack_from("<Q", data, field)
        seeds.append(bytes(data))
        data[field : field + 8] = bytes(8)
        seeds.append(bytes(data[:index_pos]))
    return seeds


@pytest.fixture(scope="module")
def bag_seeds(scratch: Path) -> list[bytes]:
    pytest.importorskip("rosbags", reason="needs the ros extra: pip install -e '.[ros]'")
    seeds = ros1_bags(scratch)
    read_bag(scratch / "None.bag")  # rosbags' type store is built on first use: not memory of any one bag
    return seeds


def read_bag(path: Path) -> None:
    from xviz_server.datasets.ros.bag import Bag

    bag = Bag(path)
    try:
        for name, topic in bag.topics.items():
            for index in range(len(topic)):
                try:
                    bag.message(name, index)
                except DatasetError:
                    continue
    finally:
        bag.close()


def test_a_ros1_record_header_that_lies_about_its_length_costs_no_memory(bag_seeds: list[bytes], scratch: Path):
    # Found by the fuzzing: rosbags reads a record header of its declared length in one read, which allocated
    # 1 GiB for a 9 kB bag before it found the file shorter; indexed and cut short (our reindexer) alike.
    for seed in bag_seeds[:2]:
        data = bytearray(seed)
        position = len(b"#ROSBAG V2.0\n")
        for _ in range(2):  # the bag header record, its padding: then the first chunk's header length
            position += 4 + struct.unpack_from("<I", data, position)[0]
        data[position : position + 4] = struct.pack("<I", 2**30 - 1)
        path = scratch / "lying.bag"
        path.write_bytes(bytes(data))
        refuses_by_name(lambda: read_bag(path), len(data), (DatasetError,))


def test_ros1_bag(bag_seeds: list[bytes], scratch: Path):
    @FUZZ
    @given(mutated(bag_seeds))
    def fuzz(data: bytes) -> None:
        path = scratch / "fuzzed.bag"
        path.write_bytes(data)
        refuses_by_name(lambda: read_bag(path), len(data), (DatasetError,))

    fuzz()


# --------------------------------------------------------------------------
# RESP replies from the broker


@pytest.fixture(scope="module")
def resp_seeds(scratch: Path) -> list[bytes]:
    pytest.importorskip("hiredis", reason="needs the broker extra: pip install -e '.[broker]'")
    from redis_replies import capture, have_redis_server

    if not have_redis_server():
        pytest.skip("needs redis-server: run scripts/test.sh")
    replies = capture(KITTI_GLB[1])
    small = [reply for reply in replies if len(reply) < 4096]
    return small + [b"".join(small), b"".join(replies)]


def parse_replies(data: bytes, sizes: Iterator[int]) -> list[Any]:
    from xviz_server.live.redis_wire import Replies

    replies, parsed, at = Replies(), [], 0
    while at < len(data):
        room = replies.buffer()
        count = min(len(room), next(sizes), len(data) - at)
        room[:count] = data[at : at + count]
        at += count
        parsed += replies.received(count)
    return parsed


def outcome(parse: Callable[[], list[Any]]) -> Any:
    """What a parse gave: its replies (errors as their text), or the exception it raised, by type."""
    from redis.exceptions import InvalidResponse

    def plain(value: Any) -> Any:
        return (
            [plain(item) for item in value]
            if isinstance(value, list)
            else str(value)
            if isinstance(value, Exception)
            else value
        )

    try:
        return plain(parse())
    except InvalidResponse:
        return InvalidResponse


def test_resp_replies(resp_seeds: list[bytes]):
    @FUZZ
    @given(mutated(resp_seeds), st.lists(st.integers(1, 70_000), min_size=1, max_size=20))
    @example(b"*1\r\n$536870912\r\n", [1])  # found: 512 MB allocated for a length, before any byte of the string
    def fuzz(data: bytes, sizes: list[int]) -> None:
        from redis.exceptions import InvalidResponse

        whole = refuses_by_name(
            lambda: outcome(lambda: parse_replies(data, itertools.repeat(len(data) or 1))),
            len(data),
            (InvalidResponse,),
        )
        fewest = len(data) // 2000  # at most some 2 000 reads of a large reply: the property, not the loop, is tested
        split = outcome(lambda: parse_replies(data, itertools.cycle([max(size, fewest) for size in sizes])))
        assert split == whole  # the same replies, or the same refusal, however the socket splits the bytes

    fuzz()


def hiredis_replies(data: bytes) -> tuple[list[Any], bool]:
    """The replies hiredis reads from ``data``, and whether it refused what came after them."""
    import hiredis

    reader, replies = hiredis.Reader(), []
    reader.feed(data)
    try:
        while (reply := reader.gets()) is not False:
            replies.append(reply)
    except hiredis.ProtocolError:
        return replies, True
    return replies, False


def test_resp_replies_as_hiredis_reads_them(resp_seeds: list[bytes]):
    # What the RESP reader takes, hiredis takes too, as the same replies; where they part, the reader refuses.
    @FUZZ
    @given(mutated(resp_seeds))
    @example(b":1_0\r\n")  # found: int() takes underscores, spaces, a plus sign, leading zeros, -0, any size
    @example(b"$ +03\r\nabc\r\n")
    @example(b":-0\r\n")
    @example(b":99999999999999999999999\r\n")
    @example(b"+PONG\r+PONG\r\n")  # found: a lone CR inside a line was taken as part of it
    @example(b"\x00\x00")  # found: a byte that starts no reply waited for a line's end before it was refused
    @example(b"$3\r\n\r\n\r\n1-1\r\n")  # hiredis skips the two bytes after a bulk string unread; the reader checks them
    @example(b"=")  # found: hiredis waits for the rest of a RESP3 verbatim string; the reader speaks RESP2 only
    def fuzz(data: bytes) -> None:
        from redis.exceptions import InvalidResponse

        theirs, refused = hiredis_replies(data)
        try:
            mine, error = parse_replies(data, itertools.repeat(len(data) or 1)), None
        except InvalidResponse as exc:
            mine, error = None, exc
        if error is None:  # the reader took all of it (and may wait for more)
            assert not refused, f"hiredis refused what the reader took as {mine!r}"
            assert outcome(lambda: mine) == outcome(lambda: theirs)
        elif not refused:  # hiredis took it all: the reader refused for a check of its own, which hiredis lacks
            resp3 = re.search(
                r"not a RESP2 reply from the broker: b'([_,=(~%|>#!])", str(error)
            )  # hiredis reads RESP3 too
            assert resp3 or re.search(
                r"over \d+ bytes|at most \d+|a length of|does not end where its length says", str(error)
            ), error

    fuzz()
