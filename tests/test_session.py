"""The protocol state machine, fed messages directly: no socket, no files."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
import pytest

from xviz_server.codec import Format, decode, encode
from xviz_server.events import Close, LiveFacts, LookUpLive, OpenLog, Send, SubscribeLive, Variant
from xviz_server.exceptions import FrameError, LogNotFound
from xviz_server.messages import envelope
from xviz_server.timeindex import TimeIndex
from xviz_server.xviz.session import (
    CancelStream,
    ConfigureLive,
    QueryInstant,
    SendLiveMetadata,
    SendLiveUpdate,
    Session,
    SkipToState,
    StreamFrames,
)


@dataclass
class Log:
    """A minimal log: the part of :class:`xviz_server.logs.Log` a session reads."""

    name: str = "drive"
    format: Format = Format.BINARY
    index: TimeIndex = field(
        default_factory=lambda: TimeIndex.from_spans((100 + i / 10, 100 + i / 10, i) for i in range(20))
    )

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


def test_transform_log_streams_the_range_then_done():
    session = opened()
    [stream] = session.receive(
        message("transform_log", {"id": "r", "start_timestamp": 100.25, "end_timestamp": 100.55})
    )
    assert isinstance(stream, StreamFrames) and stream.log == "drive"
    assert stream.frames.tolist() == [3, 4, 5] and np.allclose(stream.times, [100.3, 100.4, 100.5])
    assert stream.fmt is Format.BINARY and stream.streams is None and stream.speed is None
    [error] = session.frame_failed("r", FrameError("frame 4 is corrupt", log="drive", frame=4))
    assert "'r'" in sent(error)["data"]["message"] and "'drive'" in sent(error)["data"]["message"]
    [done] = session.stream_ended("r")
    assert sent(done) == {"type": "xviz/transform_log_done", "data": {"id": "r"}}
    assert session.stream_ended("r") == []  # told twice: nothing more


def test_newer_request_cancels_the_older_whose_done_comes_before_the_newer_frames():
    session = opened()
    [first] = session.receive(message("transform_log", {"id": "a"}))
    assert session.receive(message("transform_log", {"id": "b"})) == [CancelStream("a")]
    assert session.receive(message("transform_log", {"id": "c", "start_timestamp": 101})) == []  # a is still stopping
    done_a, done_b, third = session.stream_ended("a")
    assert [sent(done_a)["data"]["id"], sent(done_b)["data"]["id"]] == ["a", "b"]  # b never started: done, no frames
    assert isinstance(third, StreamFrames) and third.request_id == "c" and third.frames.tolist()[0] == 10
    [done_c] = session.stream_ended("c")
    assert sent(done_c)["data"]["id"] == "c"


def test_filters_of_config_and_request_intersect():
    session = opened()
    session.receive(message("reconfigure", {"update_type": "FULL", "config_update": {"desired_streams": ["/a", "/b"]}}))
    [stream] = session.receive(message("transform_log", {"id": "r", "requested_streams": ["/b", "/c"]}))
    assert stream.streams == frozenset({"/b"})
    session.stream_ended("r")
    [stream] = session.receive(message("transform_log", {"id": "s", "desired_streams": []}))  # empty: all
    assert stream.streams == frozenset({"/a", "/b"})


def test_point_in_time_becomes_a_query():
    session = opened()
    [query] = session.receive(
        message("transform_point_in_time", {"id": "q", "query_timestamp": 100.5, "desired_streams": ["/a"]})
    )
    assert isinstance(query, QueryInstant)
    assert (query.request_id, query.instant, query.streams) == ("q", 100.5, frozenset({"/a"}))


def test_reconfigure_delta_full_and_refused():
    session = opened()
    assert (
        session.receive(
            message("reconfigure", {"update_type": "DELTA", "config_update": {"message_format": "json", "speed": 2}})
        )
        == []
    )
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
    assert session.connect() == [LookUpLive("drive")]
    anonymous = Session(path="/", query={"session_type": "LIVE"}, available=[])
    assert "no live feeds" in sent(anonymous.connect()[0])["data"]["message"]
    [error] = session.receive(message("transform_log", {"id": "r"}))
    assert "not available in a LIVE session" in sent(error)["data"]["message"]


def test_a_logguid_is_a_recorded_log_if_one_opens_else_a_live_feed():
    # Decided when the log is opened, not from the names known when the client connected:
    # a log copied in since then is found.
    recorded = Session(path="/", query={"logGuid": "new-log", "worker": "true"}, available=["drive"])
    assert recorded.connect() == [OpenLog("new-log")]
    [metadata] = recorded.log_opened(Log(name="new-log"))
    assert sent(metadata)["type"] == "xviz/metadata" and not recorded.is_live
    live = Session(path="/", query={"logGuid": "car", "worker": "true"}, available=["drive"])
    assert live.connect() == [OpenLog("car")]
    assert live.log_failed(LogNotFound("no log named 'car'", name="car", available=["drive"])) == [LookUpLive("car")]
    assert live.is_live and live.format is Format.BINARY
    named = Session(path="/", query={"log": "car"}, available=["drive"])  # named as a log: an error, not live
    named.connect()
    [error] = named.log_failed(LogNotFound("no log named 'car'", name="car", available=["drive"]))
    assert "no log named 'car'" in sent(error)["data"]["message"] and not named.is_live


def live_session(**query: str) -> Session:
    """A live session of a viewer on this host (full detail, whatever its link)."""
    session = Session(path="/", query={"log": "car", "session_type": "live", **query}, lag_timeout=5, local=True)
    session.connect()
    return session


def test_live_viewer_gets_metadata_then_state_then_what_the_state_does_not_hold():
    session = live_session()
    variant = Variant(Format.BINARY)
    assert session.live_joined("car", state=7, started=True) == [
        SendLiveMetadata(Format.BINARY),
        SendLiveUpdate(7, variant),
    ]
    assert session.live_update(6, dropped=0, behind=False) == []  # queued before the state was taken: in it
    assert session.live_update(7, dropped=0, behind=False) == []
    assert session.live_update(8, dropped=0, behind=False) == [SendLiveUpdate(8, variant)]


def test_live_viewer_waits_for_a_feed_not_started_and_is_told_when_it_goes_and_comes_back():
    session = live_session()
    [waiting] = session.live_joined("car", state=None, started=False)
    assert (
        waiting.notice == "waiting" and waiting.error is None and "has not started" in sent(waiting)["data"]["message"]
    )
    assert session.live_started(None) == [SendLiveMetadata(Format.BINARY)]
    assert session.live_update(0, dropped=0, behind=False) == [SendLiveUpdate(0, Variant(Format.BINARY))]
    [gone] = session.live_gone()
    assert gone.notice == "gone" and gone.error is None and "went away" in sent(gone)["data"]["message"]
    assert session.live_started(4) == [SendLiveMetadata(Format.BINARY), SendLiveUpdate(4, Variant(Format.BINARY))]
    assert session.live_update(4, dropped=0, behind=False) == []


def test_live_viewer_behind_is_told_once_per_run_then_closed_after_the_lag_timeout():
    session = live_session()
    session.live_joined("car", state=None, started=True)
    notice, update = session.live_update(10, dropped=3, behind=True)
    assert notice.notice == "behind" and "3 updates were dropped" in sent(notice)["data"]["message"]
    assert update == SendLiveUpdate(10, Variant(Format.BINARY))
    assert session.live_update(14, dropped=3, behind=True) == [
        SendLiveUpdate(14, Variant(Format.BINARY))
    ]  # told already
    assert session.live_update(15, dropped=0, behind=False) == [SendLiveUpdate(15, Variant(Format.BINARY))]
    [again, _] = session.live_update(20, dropped=4, behind=True)  # a new run of drops: told again
    assert "4 updates" in sent(again)["data"]["message"]
    assert session.live_lagging(4.0) == []
    [close] = session.live_lagging(5.5)
    assert close == Close(1013, "too slow: dropped live updates for over 5 s")


def test_live_reconfigure_changes_the_variant_and_is_forwarded():
    session = live_session()
    session.live_joined("car", state=None, started=True)
    update = {"desired_streams": ["/points"], "decimate": 2, "max_points": 100, "message_format": "json"}
    [configure] = session.receive(message("reconfigure", {"update_type": "DELTA", "config_update": update}))
    assert configure == ConfigureLive(decimate=2, forward=update)
    [send] = session.live_update(1, dropped=0, behind=False)
    assert send == SendLiveUpdate(1, Variant(Format.JSON, frozenset({"/points"}), 100))


def test_a_live_viewer_whose_level_went_down_skips_what_queued_up_for_the_latest_state():
    session = live_session()
    session.live_joined("car", state=None, started=True)
    assert session.live_update(1, dropped=0, behind=False, queued=5) == [SendLiveUpdate(1, Variant(Format.BINARY))]
    session.receive(message("reconfigure", {"update_type": "DELTA", "config_update": {"profile": "low"}}))
    low = Variant(Format.BINARY, level=session.level)
    assert session.level.name == "low"
    assert session.live_update(2, dropped=0, behind=False, queued=5) == [
        SkipToState()
    ]  # 0.5 s of updates meant for full
    assert session.live_skipped(7) == [SendLiveUpdate(7, low)]  # the latest complete state, up to update 7
    assert [session.live_update(n, dropped=0, behind=False, queued=7 - n) for n in range(3, 8)] == [[]] * 5
    assert session.live_update(8, dropped=0, behind=False, queued=4) == [SendLiveUpdate(8, low)]  # once only
    assert session.live_skipped(None) == []


def facts(
    exists: bool = False, started: bool = False, running: tuple[str, ...] = (), allowed: bool = True
) -> LiveFacts:
    return LiveFacts(allowed=allowed, exists=exists, started=started, running=running)


def test_a_feed_named_explicitly_is_followed_or_waited_for_never_substituted():
    assert live_session().connect() == [LookUpLive("car")]
    assert live_session().live_found(facts(exists=True, started=True, running=("car", "bus"))) == [SubscribeLive("car")]
    assert live_session().live_found(facts(exists=True, running=("bus",))) == [SubscribeLive("car")]
    waiting, subscribe = live_session().live_found(facts(running=("bus",)))
    assert waiting.notice == "waiting" and "'car' has not started yet" in sent(waiting)["data"]["message"]
    assert subscribe == SubscribeLive("car")
    [error] = live_session().live_found(facts(allowed=False))
    assert error.error == "live" and "no live feed named 'car'" in sent(error)["data"]["message"]


def test_a_feed_named_by_logguid_or_not_named_may_be_the_only_running_one():
    def by_guid(found: LiveFacts) -> list:
        session = Session(path="/", query={"logGuid": "mock"})
        session.connect()
        assert session.log_failed(LogNotFound("no log named 'mock'", name="mock", available=[])) == [LookUpLive("mock")]
        return session.live_found(found)

    assert by_guid(facts(exists=True, started=True, running=("mock", "car"))) == [SubscribeLive("mock")]
    assert by_guid(facts(exists=True, running=("car",))) == [SubscribeLive("car")]  # not started: the running one
    assert by_guid(facts(running=("car",))) == [SubscribeLive("car")]
    waiting, subscribe = by_guid(facts(running=("car", "bus")))  # two run: wait for the one asked for
    assert waiting.notice == "waiting" and subscribe == SubscribeLive("mock")
    anonymous = Session(path="/", query={"session_type": "live"}, live=["a"])
    assert anonymous.connect() == [LookUpLive(None)]
    assert anonymous.live_found(facts(running=("a",))) == [SubscribeLive("a")]
    [error] = anonymous.live_found(facts(running=("a", "b")))
    assert "no live feed to serve (several are running; name one); live feeds: 'a'" in sent(error)["data"]["message"]


def test_errors_name_request_and_log():
    session = opened()
    [error] = session.receive(message("transform_log", {"id": "r9", "start_timestamp": 3, "end_timestamp": 1}))
    text = sent(error)["data"]["message"]
    assert "'r9'" in text and "'drive'" in text and "after" in text
