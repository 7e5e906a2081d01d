"""The Foxglove protocol state machine (xviz_server/foxglove/session.py) driven without sockets.

As tests/test_session.py drives the XVIZ session: inputs in, events out, each checked for what it says. Messages
are the bytes the wire module makes and parses, so what is checked here is what a client would get.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Any

import pytest
from websockets.frames import CloseCode

from xviz_server.events import Close, LiveFacts, LookUpLive, OpenLog, Send, SubscribeLive
from xviz_server.exceptions import FrameError, LogError, LogNotFound
from xviz_server.foxglove.protocol import ENDED, PAUSED, PLAYING, time_message
from xviz_server.foxglove.schemas import json_schema
from xviz_server.foxglove.session import (
    CAPABILITIES,
    LIVE_CAPABILITIES,
    MAX_SPEED,
    FoxgloveSession,
    Play,
    SendLatest,
    SendLive,
    Stop,
)
from xviz_server.foxglove.translate import Channel

START, END = 1_000_000_000_000, 1_002_400_000_000  # nanoseconds: a log of 2.4 s


def channel(cid: int, topic: str) -> Channel:
    return Channel(cid, topic, topic, "json", json_schema(topic, {"type": "object"}))


@dataclass
class Log:
    """The part of an open log the session reads (see FoxgloveLog)."""

    name: str = "drive"
    channels: list[Channel] = field(default_factory=lambda: [channel(1, "/a"), channel(2, "/b")])
    start_time: int = START
    end_time: int = END
    frames: int = 25  # a frame every 0.1 s


def op(event: Any) -> dict[str, Any]:
    """A text message's JSON."""
    assert isinstance(event, Send) and event.text, event
    message: dict[str, Any] = json.loads(event.data)
    return message


def status(event: Any) -> tuple[int, str]:
    message = op(event)
    assert message["op"] == "status"
    return message["level"], message["message"]


def state(event: Any) -> tuple[int, int, float, bool, str]:
    """A playback state: status, current time, speed, whether it sought, request id."""
    assert isinstance(event, Send) and not event.text and event.data[0] == 0x05
    code, current, speed, did_seek, length = struct.unpack_from("<BQfBI", event.data, 1)
    return code, current, speed, bool(did_seek), event.data[19 : 19 + length].decode()


def control(play: bool, speed: float = 1.0, seek: int | None = None, request_id: str = "r") -> bytes:
    rid = request_id.encode()
    return struct.pack("<BBfBQI", 0x03, 0 if play else 1, speed, seek is not None, seek or 0, len(rid)) + rid


def subscribe(*pairs: tuple[int, int]) -> str:
    return json.dumps({"op": "subscribe", "subscriptions": [{"id": sid, "channelId": cid} for sid, cid in pairs]})


def opened(query: dict[str, str] | None = None) -> FoxgloveSession:
    session = FoxgloveSession(path="/", query=query or {"log": "drive"}, available=["drive"])
    assert session.connect() == [OpenLog("drive")]
    info, start, advertise = session.log_opened(Log())
    assert op(info)["op"] == "serverInfo" and start.data == time_message(START) and op(advertise)["op"] == "advertise"
    return session


# -- connecting and opening a log --------------------------------------------------


@pytest.mark.parametrize(
    ("path", "query"), [("/", {"log": "drive"}), ("/", {"logGuid": "drive"}), ("/drive", {}), ("/", {})]
)
def test_connect_opens_the_named_or_only_log(path: str, query: dict[str, str]) -> None:
    assert FoxgloveSession(path=path, query=query, available=["drive"]).connect() == [OpenLog("drive")]


def test_connect_without_a_name_among_several_lists_them() -> None:
    info, error = FoxgloveSession(path="/", query={}, available=["a", "b"]).connect()
    assert op(info)["capabilities"] == list(CAPABILITIES)
    level, text = status(error)
    assert level == 2 and "'a', 'b'" in text and error.error == "log"


def test_an_open_log_is_described_and_its_channels_advertised() -> None:
    session = FoxgloveSession(path="/", query={"log": "drive"}, available=["drive"], server_name="test server")
    session.connect()
    info, start, advertise = session.log_opened(Log())
    # The log's start time comes between serverInfo and advertise: the apps start their timeline from it.
    assert start == Send(time_message(START), text=False)
    assert op(info) == {
        "op": "serverInfo",
        "name": "test server",
        "capabilities": list(CAPABILITIES),
        "metadata": {"log": "drive"},
        "dataStartTime": {"sec": 1000, "nsec": 0},
        "dataEndTime": {"sec": 1002, "nsec": 400_000_000},
    }
    assert [c["id"] for c in op(advertise)["channels"]] == [1, 2]
    assert op(advertise)["channels"][0] == Log().channels[0].advertisement()
    assert session.position == START and not session.playing


def test_a_log_that_cannot_be_served_gets_an_error_status() -> None:
    session = FoxgloveSession(path="/", query={"log": "drive"}, available=["drive"])
    session.connect()
    info, error = session.log_failed(LogError("frame index is corrupt", log="drive"))
    assert op(info)["op"] == "serverInfo" and status(error)[0] == 2 and "corrupt" in status(error)[1]


def test_a_name_that_is_no_log_is_followed_as_a_running_live_feed() -> None:
    session = FoxgloveSession(path="/", query={"log": "car"}, available=["drive"])
    assert session.connect() == [OpenLog("car")]
    assert session.log_failed(LogNotFound("no log named 'car'", name="car", available=["drive"])) == [LookUpLive("car")]
    info, follow = session.live_found(LiveFacts(allowed=True, exists=True, started=True, running=("car",)))
    assert op(info)["capabilities"] == list(LIVE_CAPABILITIES) and op(info)["metadata"] == {"live": "car"}
    assert follow == SubscribeLive("car")


def test_a_name_that_is_neither_a_log_nor_a_running_feed_is_refused() -> None:
    session = FoxgloveSession(path="/", query={"log": "car"}, available=["drive"])
    session.connect()
    session.log_failed(LogNotFound("no log named 'car'", name="car", available=["drive"]))
    info, error = session.live_found(LiveFacts(allowed=True, exists=False, started=False, running=()))
    assert "no log named 'car'" in status(error)[1] and error.error == "log"


# -- client messages -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ("{not json", "malformed JSON"),
        ("[1, 2]", "JSON object with a string 'op'"),
        (json.dumps({"op": "launch"}), "unknown op 'launch'"),
        (json.dumps({"op": "subscribeConnectionGraph"}), "'subscribeConnectionGraph' is not offered"),
        (json.dumps({"op": "subscribe", "subscriptions": {"id": 1}}), "must be a list of {id, channelId}"),
        (json.dumps({"op": "unsubscribe", "subscriptionIds": 3}), "'subscriptionIds' must be a list"),
        (b"", "an empty binary message"),
        (b"\x7fgarbage", "unknown binary opcode 0x7f"),
        (b"\x01\x00\x00\x00\x00xyz", "client message data is not offered"),
        (b"\x02\x00\x00\x00\x00", "service call request is not offered"),
        (b"\x03\x00", "playback control request: 2 bytes"),
        (b"\x03" + struct.pack("<BfBQI", 7, 1.0, 0, 0, 0), "unknown command 7"),
        (b"\x03" + struct.pack("<BfBQI", 0, 1.0, 0, 0, 300) + b"x" * 300, "request id of 300 bytes"),
        (b"\x03" + struct.pack("<BfBQI", 0, 1.0, 0, 0, 2) + b"\xff\xfe", "not UTF-8"),
    ],
)
def test_each_bad_message_gets_one_error_status_and_changes_nothing(data: str | bytes, expected: str) -> None:
    session = opened()
    [error] = session.receive(data)
    level, text = status(error)
    assert level == 2 and expected in text and error.error == "invalid"
    assert not session.playing and session.position == START


@pytest.mark.parametrize(
    ("item", "expected"),
    [
        ({"id": -1, "channelId": 1}, "unsigned 32-bit"),
        ({"id": 1, "channelId": 1 << 32}, "unsigned 32-bit"),
        ({"id": 1.0, "channelId": 1}, "unsigned 32-bit"),
        ({"id": True, "channelId": 1}, "unsigned 32-bit"),
        ("1", "unsigned 32-bit"),
        ({"id": 1, "channelId": 99}, "no channel 99 in log 'drive'"),
    ],
)
def test_a_bad_subscription_is_refused_and_the_good_ones_taken(item: Any, expected: str) -> None:
    session = opened()
    message = json.dumps({"op": "subscribe", "subscriptions": [item, {"id": 5, "channelId": 2}]})
    error, play = session.receive(message)
    assert expected in status(error)[1]
    assert play == Play(START, 1.0) and session.playing  # the good one starts playback


def test_subscribing_starts_playback_once_and_later_subscriptions_get_the_frame_on_screen() -> None:
    session = opened()
    assert session.receive(subscribe((10, 1))) == [Play(START, 1.0)]
    assert session.frame(START + 100, 0) == {1: 10}  # the player sends the first frame to subscription 10
    assert session.receive(subscribe((11, 2))) == [SendLatest(0, {2: 11})]
    assert session.frame(START + 200, 1) == {1: 10, 2: 11}


def test_a_subscription_id_or_channel_in_use_is_refused() -> None:
    session = opened()
    session.receive(subscribe((10, 1)))
    [error] = session.receive(subscribe((10, 2)))
    assert "subscription id 10 is in use (channel 1)" in status(error)[1]
    [error] = session.receive(subscribe((12, 1)))
    assert "channel 1 is subscribed already (subscription 10)" in status(error)[1]


def test_unsubscribing_stops_a_channel_and_an_unknown_id_gets_a_warning() -> None:
    session = opened()
    session.receive(subscribe((10, 1), (11, 2)))
    assert session.receive(json.dumps({"op": "unsubscribe", "subscriptionIds": [10]})) == []
    assert session.frame(START, 0) == {2: 11}
    [warning] = session.receive(json.dumps({"op": "unsubscribe", "subscriptionIds": [10, "x"]}))
    assert status(warning) == (1, "unsubscribe: 2 of 2 items refused: no subscription 10; no subscription 'x'")
    assert session.receive(subscribe((10, 1))) == [SendLatest(0, {1: 10})]  # the id is free again


# -- playback ---------------------------------------------------------------------------


def test_pause_then_play_goes_on_after_the_frame_on_screen() -> None:
    session = opened()
    session.receive(subscribe((10, 1)))
    session.frame(START + 500, 3)
    stop, paused = session.receive(control(False, request_id="p"))
    assert stop == Stop() and state(paused) == (PAUSED, START + 500, 1.0, False, "p")
    play, playing = session.receive(control(True, speed=2.0, request_id="q"))
    assert play == Play(START + 501, 2.0) and state(playing) == (PLAYING, START + 500, 2.0, False, "q")


def test_a_seek_while_playing_plays_from_the_new_time_with_its_frame_whole() -> None:
    session = opened()
    session.receive(subscribe((10, 1)))
    play, sought = session.receive(control(True, seek=START + 1_000, request_id="s"))
    assert play == Play(START + 1_000, 1.0, seek=True)
    assert state(sought) == (PLAYING, START + 1_000, 1.0, True, "s")


def test_a_seek_while_paused_shows_one_frame_and_stays() -> None:
    session = opened()
    session.receive(control(False))
    play, sought = session.receive(control(False, seek=END, request_id="s"))
    assert play == Play(END, 1.0, seek=True, once=True) and state(sought)[:4] == (PAUSED, END, 1.0, True)
    assert session.receive(subscribe((10, 1))) == []  # the client controls playback: subscribing starts nothing


@pytest.mark.parametrize(
    ("seek", "speed", "expected"),
    [
        (START - 1, 1.0, "outside the log 'drive'"),
        (END + 1, 1.0, "outside the log 'drive'"),
        (None, 0.0, "speed 0.0 is not in (0, 100.0]"),
        (None, MAX_SPEED * 2, "is not in (0, 100.0]"),
        (None, float("inf"), "speed inf"),
    ],
)
def test_a_bad_playback_request_is_refused_and_playback_unchanged(
    seek: int | None, speed: float, expected: str
) -> None:
    session = opened()
    session.receive(subscribe((10, 1)))
    error, unchanged = session.receive(control(True, speed=speed, seek=seek, request_id="bad"))
    assert expected in status(error)[1] and state(unchanged) == (PLAYING, START, 1.0, False, "bad")
    assert session.playing and session.speed == 1.0


def test_the_end_of_the_log_is_told_only_to_a_client_that_controls_playback() -> None:
    session = opened()
    session.receive(subscribe((10, 1)))
    assert session.ended() == [] and not session.playing
    session.receive(control(True, seek=START))
    session.frame(END, 24)
    [ended] = session.ended()
    assert state(ended)[:2] == (ENDED, END)


def test_a_frame_that_fails_is_a_warning_and_an_internal_error_an_error() -> None:
    session = opened()
    [warning] = session.frame_failed(FrameError("frame 4 is corrupt", log="drive", frame=4))
    assert status(warning) == (1, "frame 4 is corrupt") and warning.notice == "frame"
    [error] = session.internal_error("a message", RuntimeError("bug"))
    assert status(error) == (2, "internal server error while handling a message: RuntimeError('bug')")
    assert error.error == "internal"


# -- live feeds ---------------------------------------------------------------------------

RUNNING = LiveFacts(allowed=True, exists=True, started=True, running=("car",))


def live(query: dict[str, str] | None = None) -> FoxgloveSession:
    session = FoxgloveSession(path="/", query=query or {"session_type": "live", "log": "car"})
    assert session.connect() == [LookUpLive(query.get("log") if query else "car")]
    return session


def test_a_named_feed_is_followed_or_waited_for() -> None:
    info, follow = live().live_found(RUNNING)
    assert op(info)["metadata"] == {"live": "car"} and follow == SubscribeLive("car")
    info, waiting, follow = live().live_found(LiveFacts(allowed=True, exists=False, started=False, running=()))
    assert status(waiting) == (0, "live feed 'car' has not started yet; waiting for it") and follow == SubscribeLive(
        "car"
    )


def test_without_a_name_the_only_running_feed_is_followed_and_several_are_refused() -> None:
    session = live({"session_type": "live"})
    assert session.live_found(RUNNING)[1] == SubscribeLive("car")
    info, error = live({"session_type": "live"}).live_found(LiveFacts(True, False, False, ("car", "bus")))
    assert "no live feed named: add ?log=NAME" in status(error)[1] and "'car', 'bus'" in status(error)[1]


def test_a_name_no_feed_may_have_is_refused() -> None:
    info, error = live().live_found(LiveFacts(allowed=False, exists=False, started=False, running=()))
    assert "no live feed named 'car' can be followed" in status(error)[1] and error.error == "live"


def test_a_feed_advertises_its_channels_once_and_anew_with_new_ids_when_they_change() -> None:
    session = live()
    session.live_found(RUNNING)
    [waiting] = session.live_joined(None)
    assert "has not started" in status(waiting)[1]
    [advertise] = session.live_started([channel(1, "/a"), channel(2, "/b")])
    assert [c["id"] for c in op(advertise)["channels"]] == [1, 2]
    assert session.live_started([channel(1, "/a"), channel(2, "/b")]) == []  # the same: nothing new
    session.receive(subscribe((10, 1)))
    unadvertise, advertise = session.live_started([channel(1, "/a"), channel(2, "/c")])
    assert op(unadvertise) == {"op": "unadvertise", "channelIds": [1, 2]}
    assert [c["id"] for c in op(advertise)["channels"]] == [3, 4]  # never reused on this connection
    assert session.live_update(START, 0, False) == [SendLive({}, START)]  # subscriptions ended with their channels
    session.receive(subscribe((11, 4)))
    assert session.live_update(START + 1, 0, False) == [SendLive({2: 11}, START + 1)]  # by the feed's numbering


def test_a_client_behind_is_told_once_per_run_of_drops_and_closed_when_it_stays_behind() -> None:
    session = live()
    session.live_found(RUNNING)
    session.live_started([channel(1, "/a")])
    warning, send = session.live_update(START, 3, True)
    assert "3 updates were dropped" in status(warning)[1] and send == SendLive({}, START)
    assert session.live_update(START + 1, 2, True) == [SendLive({}, START + 1)]  # still behind: not told again
    assert session.live_update(START + 2, 0, False) == [SendLive({}, START + 2)]
    assert len(session.live_update(START + 3, 1, True)) == 2  # behind again: told again
    assert session.live_lagging(29.0) == []
    assert session.live_lagging(31.0) == [
        Close(CloseCode.TRY_AGAIN_LATER, "too slow: dropped live updates for over 30 s")
    ]


def test_a_feed_gone_is_a_warning_and_playback_control_is_refused_on_a_feed() -> None:
    session = live()
    session.live_found(RUNNING)
    [gone] = session.live_gone()
    assert status(gone)[0] == 1 and "went away" in status(gone)[1]
    error, playing = session.receive(control(False, request_id="p"))
    assert "plays as its source sends" in status(error)[1] and state(playing)[0] == PLAYING and state(playing)[4] == "p"


def test_a_feed_that_cannot_be_waited_for_is_refused() -> None:
    session = live()
    session.live_found(RUNNING)
    info, error = session.live_failed("car")
    assert "no live feed named 'car' can be followed" in status(error)[1]
