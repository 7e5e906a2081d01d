"""The Foxglove WebSocket protocol's messages as bytes and text (pure).

Text messages are JSON objects with an ``op``; binary messages start with a
one-byte opcode, and their integers are little-endian. The layouts are
those of ``foxglove.websocket.v1`` (and of ``foxglove.sdk.v1``, which adds
the playback control request and the playback state).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import orjson

from ..exceptions import FoxgloveProtocolError

__all__ = [
    "SUBPROTOCOLS",
    "MESSAGE_DATA",
    "TIME",
    "PLAYBACK_STATE",
    "CLIENT_MESSAGE_DATA",
    "SERVICE_CALL_REQUEST",
    "PLAYBACK_CONTROL_REQUEST",
    "PLAYING",
    "PAUSED",
    "ENDED",
    "PlaybackControl",
    "text",
    "message_header",
    "time_message",
    "playback_state",
    "parse_playback_control",
    "parse_text",
]

#: The subprotocol names this server speaks Foxglove's protocol under, in no order of preference.
SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")

# Server opcodes.
MESSAGE_DATA = 0x01
TIME = 0x02
PLAYBACK_STATE = 0x05
# Client opcodes.
CLIENT_MESSAGE_DATA = 0x01
SERVICE_CALL_REQUEST = 0x02
PLAYBACK_CONTROL_REQUEST = 0x03

# Playback statuses (playback state) and commands (control request).
PLAYING, PAUSED, ENDED = 0, 1, 3
PLAY, PAUSE = 0, 1

_HEADER = struct.Struct("<BIQ")
_TIME = struct.Struct("<BQ")
_STATE = struct.Struct("<BBQfBI")
_CONTROL = struct.Struct("<BfBQI")

#: The longest request id a playback control request may carry.
MAX_REQUEST_ID = 256


@dataclass(frozen=True)
class PlaybackControl:
    """A client's playback control request."""

    play: bool
    speed: float
    seek: int | None  #: nanoseconds, when the request seeks
    request_id: str


def text(op: str, **fields: Any) -> bytes:
    """A text message, UTF-8 encoded."""
    return orjson.dumps({"op": op, **fields})


def message_header(subscription: int, log_time: int) -> bytes:
    """What precedes a message's payload in a message data message."""
    return _HEADER.pack(MESSAGE_DATA, subscription, log_time)


def time_message(nanoseconds: int) -> bytes:
    """A time message."""
    return _TIME.pack(TIME, nanoseconds)


def playback_state(status: int, current: int, speed: float, did_seek: bool, request_id: str | None) -> bytes:
    """A playback state message, answering the request ``request_id`` if given."""
    rid = (request_id or "").encode()
    return _STATE.pack(PLAYBACK_STATE, status, current, speed, did_seek, len(rid)) + rid


def parse_text(data: str | bytes) -> dict[str, Any]:
    """A text message as a dict with a string ``op``; raises :class:`FoxgloveProtocolError`."""
    try:
        message = orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        raise FoxgloveProtocolError(f"malformed JSON: {exc}") from None
    if not isinstance(message, dict) or not isinstance(message.get("op"), str):
        raise FoxgloveProtocolError("a text message must be a JSON object with a string 'op'")
    return message


def parse_playback_control(data: bytes) -> PlaybackControl:
    """A playback control request (its opcode included); raises :class:`FoxgloveProtocolError`."""
    if len(data) < _CONTROL.size + 1:
        raise FoxgloveProtocolError(f"playback control request: {len(data)} bytes, at least {_CONTROL.size + 1} needed")
    command, speed, had_seek, seek, length = _CONTROL.unpack_from(data, 1)
    if command not in (PLAY, PAUSE):
        raise FoxgloveProtocolError(f"playback control request: unknown command {command}")
    if length > MAX_REQUEST_ID or len(data) != 1 + _CONTROL.size + length:
        raise FoxgloveProtocolError(
            f"playback control request: request id of {length} bytes in a message of {len(data)}"
        )
    try:
        request_id = data[1 + _CONTROL.size :].decode()
    except UnicodeDecodeError:
        raise FoxgloveProtocolError("playback control request: request id is not UTF-8") from None
    return PlaybackControl(command == PLAY, speed, seek if had_seek else None, request_id)
