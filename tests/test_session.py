"""The protocol state machine, fed messages directly: no socket, no files."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
import pytest

from xviz_server.codec import Format, decode, encode
from xviz_server.exceptions import LogNotFound
from xviz_server.index import TimeIndex
from xviz_server.messages import envelope
from xviz_server.session import Cancel, OpenLog, QueryInstant, Send, Session, StreamFrames, SubscribeLive


@dataclass
class Log:
    """A minimal log: the part of :class:`xviz_server.logs.Log` a session reads."""

    name: str = "drive"
    format: Format = Format.BINARY
    index: TimeIndex = field(default_factory=lambda: TimeIndex.from_spans((100 + i / 10, 100 + i / 10, i) for i in range(20)))

    def metadata_message(self, fmt: Format) -> bytes:
        return encode(envelope("metadata", {"version": "2.0.0", "log": self.name}), fmt)


def message(kind: str, data) -> str:
    return json.dumps({"type": f"xviz/{kind}", "data": data})


def sent(event: Send) -> dict:
    assert isinstance(event, Send)
    return decode(event.data)


def opened(query: dict | None = None, path: str = "/", available=("drive",), log: Log | None = None) -> Session:
    session = Session(path=path, query=query or {"log": "drive"}, available=list(available))
    events = session.connect()
    assert events == [OpenLog("drive")]
    [metadata] = session.log_opened(log or Log())
    assert sent(metadata)["type"] == "xviz/metadata"
    return session


@pytest.mark.parametrize(
    "path, query",
    [
        ("/", {"worker": "true", "log": "drive", "profile": "default", "duration": "30"}),
        ("/", {"logGuid": "drive", "worker": "true"}),
        ("/drive", {}),
        ("/", {}),  # the only log
    ],
)
def test_connect_opens_the_named_or_only_log(path, query):
    session = Session(path=path, query=query, available=["drive"])
    assert session.connect() == [OpenLog("drive")]


def test_connect_without_a_name_among_several_lists_them():
    session = Session(path="/", query={}, available=["a", "b"])
    [error] = session.connect()
    text = sent(error)["data"]["message"]
    assert "'a', 'b'" in text and error.error == "log"


def test_metadata_in_the_session_format():
    session = Session(path="/", query={"log": "drive", "message_format": "json"}, available=["drive"])
    session.connect()
    [metadata] = session.log_opened(Log())
    assert metadata.text and json.loads(metadata.data)["type"] == "xviz/metadata"


def test_bad_url_parameter_is_reported_and_the_log_still_opens():
    session = Session(path="/", query={"log": "drive", "speed": "fast"}, available=["drive"])
    error, open_log = session.connect()
    assert "speed" in sent(error)["data"]["message"] and open_log == OpenLog("drive")


def test_transform_log_streams_the_range_after_cancelling_the_previous():
    session = opened()
    cancel, stream = session.receive(message("transform_log", {"id": "r", "start_timestamp": 100.25, "end_timestamp": 100.55}))
    assert cancel == Cancel()
    assert isinstance(stream, StreamFrames)
    assert stream.frames.tolist() == [3, 4, 5] and np.allclose(stream.times, [100.3, 100.4, 100.5])
    assert stream.fmt is Format.BINARY and stream.streams is None and stream.speed is None
    assert decode(stream.done.data) == {"type": "xviz/transform_log_done", "data": {"id": "r"}}


def test_filters_of_config_and_request_intersect():
    session = opened()
    session.receive(message("reconfigure", {"update_type": "FULL", "config_update": {"desired_streams": ["/a", "/b"]}}))
    _, stream = session.receive(message("transform_log", {"id": "r", "requested_streams": ["/b", "/c"]}))
    assert stream.streams == frozenset({"/b"})
    _, stream = session.receive(message("transform_log", {"id": "s", "desired_streams": []}))  # empty: all
    assert stream.streams == frozenset({"/a", "/b"})


def test_point_in_time_becomes_a_query():
    session = opened()
    [query] = session.receive(message("transform_point_in_time", {"id": "q", "query_timestamp": 100.5, "desired_streams": ["/a"]}))
    assert isinstance(query, QueryInstant)
    assert (query.request_id, query.instant, query.streams) == ("q", 100.5, frozenset({"/a"}))


def test_reconfigure_delta_full_and_refused():
    session = opened()
    assert session.receive(message("reconfigure", {"update_type": "DELTA", "config_update": {"message_format": "json", "speed": 2}})) == []
    assert session.format is Format.JSON and session.config.speed == 2
    assert session.receive(message("reconfigure", {"update_type": "DELTA", "config_update": {"speed": None}})) == []
    assert session.config.speed is None and session.format is Format.JSON
    [error] = session.receive(message("reconfigure", {"update_type": "DELTA", "config_update": {"speed": -1}}))
    assert "speed" in sent(error)["data"]["message"] and session.format is Format.JSON
    [error] = session.receive(message("reconfigure", {"update_type": "FULL", "config_update": {"rate": 2}}))
    assert "unknown key 'rate'" in json.loads(error.data)["data"]["message"]
    assert session.format is Format.JSON  # unchanged
    assert session.receive(message("reconfigure", {"update_type": "FULL", "config_update": {}})) == []
    assert session.format is Format.BINARY  # the log's own again


def test_start_again_resends_metadata_or_opens_another_log():
    session = opened()
    [metadata] = session.receive(message("start", {"message_format": "JSON"}))
    assert metadata.text  # same log, new format
    assert session.receive(message("start", {"log": "other"})) == [OpenLog("other")]
    [error] = session.receive(message("transform_log", {"id": "r"}))
    assert "no log is open" in json.loads(error.data)["data"]["message"]
    [error] = session.log_failed(LogNotFound("no log named 'other'", name="other", available=[]))
    assert "no log named 'other'" in json.loads(error.data)["data"]["message"]


def test_live_sessions_and_why_transform_requests_fail():
    session = Session(path="/", query={"log": "drive", "session_type": "live"}, available=["drive"])
    assert session.connect() == [SubscribeLive("drive")]
    guid_only = Session(path="/", query={"logGuid": "car", "worker": "true"}, available=["drive"])
    assert guid_only.connect() == [SubscribeLive("car")]  # not a recorded log: live
    recorded = Session(path="/", query={"logGuid": "drive"}, available=["drive"])
    assert recorded.connect() == [OpenLog("drive")]
    anonymous = Session(path="/", query={"session_type": "LIVE"}, available=[])
    assert "no live feeds" in sent(anonymous.connect()[0])["data"]["message"]
    [error] = session.receive(message("transform_log", {"id": "r"}))
    assert "not available in a LIVE session" in sent(error)["data"]["message"]


def test_errors_name_request_and_log():
    session = opened()
    [error] = session.receive(message("transform_log", {"id": "r9", "start_timestamp": 3, "end_timestamp": 1}))
    text = sent(error)["data"]["message"]
    assert "'r9'" in text and "'drive'" in text and "after" in text
