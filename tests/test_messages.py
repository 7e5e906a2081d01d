"""Parsing client messages into models, and the errors a client gets back."""

from __future__ import annotations

import pytest

from xviz_server.codec import Format
from xviz_server.exceptions import MessageError
from xviz_server.messages import (
    Reconfigure,
    SessionType,
    Start,
    TransformLog,
    TransformLogDone,
    TransformPointInTime,
    parse_client_message,
    unwrap,
)


def env(name: str, data) -> dict:
    return {"type": f"xviz/{name}", "data": data}


def test_start_accepts_any_case_and_ignores_unknown_keys():
    start = parse_client_message(
        env("start", {"version": "2.0", "session_type": "live", "message_format": "binary", "worker": True})
    )
    assert start == Start(version="2.0", session_type=SessionType.LIVE, message_format=Format.BINARY)


def test_transform_log_accepts_both_filter_names_and_numeric_ids():
    a = parse_client_message(env("transform_log", {"id": 7, "desired_streams": ["/a"]}))
    b = parse_client_message(env("transform_log", {"id": "7", "requested_streams": ["/a"]}))
    assert a == b == TransformLog(id="7", desired_streams=["/a"])
    assert a.start_timestamp is None and a.end_timestamp is None


def test_point_in_time_and_reconfigure():
    query = parse_client_message(env("transform_point_in_time", {"id": "q", "query_timestamp": 10.5}))
    assert query == TransformPointInTime(id="q", query_timestamp=10.5)
    change = parse_client_message(env("reconfigure", {"update_type": "delta", "config_update": {"x": 1}}))
    assert change == Reconfigure(update_type="DELTA", config_update={"x": 1})


@pytest.mark.parametrize(
    "message, text, request_id",
    [
        (
            env("transform_log", {"id": "r1", "start_timestamp": 5, "end_timestamp": 1}),
            "xviz/transform_log (id 'r1'): start_timestamp 5.0 is after end_timestamp 1.0",
            "r1",
        ),
        (
            env("transform_log", {"id": 9, "start_timestamp": "soon"}),
            "xviz/transform_log (id '9'): 'start_timestamp' must be a number, not 'soon'",
            "9",
        ),
        (env("transform_log", {"start_timestamp": 1}), "xviz/transform_log: 'id' is required", None),
        (env("transform_log", {"id": "x", "desired_streams": "/a"}), "'desired_streams' must be a list, not '/a'", "x"),
        (env("transform_log", [1, 2]), "xviz/transform_log: the data must be a JSON object, not [1, 2]", None),
        (
            env("transform_point_in_time", {"id": "q", "query_timestamp": float("inf")}),
            "'query_timestamp' must be a finite number, not inf",
            "q",
        ),
        (env("start", {"session_type": "replay"}), "'session_type' must be one of 'LOG' or 'LIVE', not 'replay'", None),
        (
            env("reconfigure", {"update_type": "FULL", "config_update": 3}),
            "'config_update' must be a JSON object, not 3",
            None,
        ),
        (env("flush", {}), "unknown message type 'xviz/flush'; a client may send xviz/start, xviz/transform_log", None),
        (env("state_update", {}), "unknown message type 'xviz/state_update'", None),
        ({"type": 5, "data": {}}, "message 'type' must be a string", None),
        ([1, 2], "must be a JSON object like", None),
        ({"hello": 1}, "this one has the keys ['hello']", None),
    ],
)
def test_errors_name_message_request_and_field(message, text, request_id):
    with pytest.raises(MessageError) as info:
        parse_client_message(message)
    assert text in str(info.value)
    assert info.value.request_id == request_id


def test_bare_messages_are_recognised_like_clients_do():
    assert unwrap({"version": "2.0.0", "streams": {}}) == ("xviz/metadata", {"version": "2.0.0", "streams": {}})
    update = {"update_type": "SNAPSHOT", "updates": []}
    assert unwrap(update) == ("xviz/state_update", update)


def test_sent_messages_are_envelopes_without_unset_fields():
    assert TransformLogDone(id="4").to_envelope() == {"type": "xviz/transform_log_done", "data": {"id": "4"}}
    assert Start(session_type=SessionType.LIVE).to_envelope() == {
        "type": "xviz/start",
        "data": {"session_type": "LIVE"},
    }
