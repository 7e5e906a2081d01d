"""The XVIZ session messages a server receives and sends, as pydantic models.

The models follow what real clients send rather than the letter of the
schema: ``session_type`` in any case, numeric request ids, the filter named
either ``desired_streams`` or ``requested_streams``, unknown fields ignored.
State updates are not modelled: they stay plain data (dicts and numpy
arrays) on the hot path.

:func:`parse_client_message` turns a decoded message into a model or raises
:class:`~xviz_server.exceptions.MessageError` with a sentence that names the
message, its request id and the field at fault.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Literal

import pydantic
from pydantic import AliasChoices, ConfigDict, Field, field_validator, model_validator

from .budget import MAX_ITEMS, SHOWN, Problems, shown, too_many
from .codec import Format
from .codec.json import MAX_DEPTH, nested_deeper
from .exceptions import MessageError
from .levels import profile_level

__all__ = [
    "SessionType",
    "Start",
    "TransformLog",
    "TransformPointInTime",
    "Reconfigure",
    "SessionConfig",
    "merge_patch",
    "stream_filter",
    "TransformLogDone",
    "Error",
    "ClientMessage",
    "unwrap",
    "envelope",
    "parse_client_message",
    "describe_validation_error",
    "is_number",
    "XVIZ_VERSION",
]

XVIZ_NAMESPACE = "xviz/"
#: The protocol version this server speaks; metadata without it makes clients fall back to XVIZ v1.
XVIZ_VERSION = "2.0.0"


class SessionType(str, enum.Enum):
    """``LOG`` sessions replay a recorded log on request; ``LIVE`` ones are pushed updates."""

    LOG = "LOG"
    LIVE = "LIVE"


_ENUM_WORDS = frozenset({"LOG", "LIVE", "JSON", "BINARY", "FULL", "DELTA"})


def _upper(value: Any) -> Any:
    """Accept the protocol's enum words in any case (``live``, ``Binary``)."""
    if isinstance(value, str) and value.upper() in _ENUM_WORDS:
        return value.upper()
    return value


class _Message(pydantic.BaseModel):
    """A session message; ``TYPE`` is its name without the ``xviz/`` prefix."""

    model_config = ConfigDict(frozen=True, extra="ignore", coerce_numbers_to_str=True)
    TYPE: ClassVar[str]

    def to_envelope(self) -> dict[str, Any]:
        """This message as an envelope, without the fields that are unset."""
        return envelope(self.TYPE, self.model_dump(mode="json", exclude_none=True))


_Timestamp = Field(default=None, allow_inf_nan=False)
_StreamFilter = Field(default=None, validation_alias=AliasChoices("desired_streams", "requested_streams"))


class Start(_Message):
    """``xviz/start``: opens a session; every field may also come from the URL query."""

    TYPE = "start"
    version: str | None = None
    profile: str | None = None
    session_type: SessionType | None = None
    message_format: Format | None = None
    log: str | None = None

    _case = field_validator("session_type", "message_format", mode="before")(_upper)


class TransformLog(_Message):
    """``xviz/transform_log``: asks for the state updates of a time range."""

    TYPE = "transform_log"
    id: str
    start_timestamp: float | None = _Timestamp
    end_timestamp: float | None = _Timestamp
    desired_streams: list[str] | None = _StreamFilter

    @model_validator(mode="after")
    def _ordered(self) -> TransformLog:
        start, end = self.start_timestamp, self.end_timestamp
        if start is not None and end is not None and start > end:
            raise ValueError(f"start_timestamp {start} is after end_timestamp {end}")
        return self


class TransformPointInTime(_Message):
    """``xviz/transform_point_in_time``: asks for the complete state at one instant."""

    TYPE = "transform_point_in_time"
    id: str
    query_timestamp: float = Field(allow_inf_nan=False)
    desired_streams: list[str] | None = _StreamFilter


class Reconfigure(_Message):
    """``xviz/reconfigure``: changes what the session is sent from now on.

    ``DELTA`` merges ``config_update`` into the current configuration
    (JSON merge patch); ``FULL`` replaces it.
    """

    TYPE = "reconfigure"
    update_type: Literal["FULL", "DELTA"]
    config_update: dict[str, Any]

    _case = field_validator("update_type", mode="before")(_upper)

    @field_validator("config_update")
    @classmethod
    def _shallow(cls, value: dict[str, Any]) -> dict[str, Any]:
        if nested_deeper(value):  # merge_patch recurses as deep as the patch
            raise ValueError(f"nested more than {MAX_DEPTH} lists and objects deep")
        return value


class TransformLogDone(_Message):
    """``xviz/transform_log_done``: ends the reply to the request with this id."""

    TYPE = "transform_log_done"
    id: str


class Error(_Message):
    """``xviz/error``: what went wrong, in a sentence that names the request and log."""

    TYPE = "error"
    message: str


class SessionConfig(pydantic.BaseModel):
    """What a session is sent, changed by ``xviz/reconfigure``.

    ``desired_streams``: streams sent (``None`` or empty: all), applied on top
    of each request's own filter. ``message_format``: format of later
    messages (``None``: the session's start format). ``speed``: pace streams
    at this multiple of the log's rate (``None``: as fast as the client reads).
    Live sessions only: ``decimate``, send every n-th update; ``max_points``,
    thin every point cloud to at most this many points. ``profile``: the
    level of detail (a level's name, or ``auto``), in place of the start's;
    ``max_mbps``: the most Mbit/s the session may take, in place of the URL's.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    desired_streams: list[str] | None = None
    message_format: Format | None = None
    speed: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    decimate: int | None = Field(default=None, ge=1)
    max_points: int | None = Field(default=None, ge=1)
    profile: str | None = None
    max_mbps: float | None = Field(default=None, gt=0, allow_inf_nan=False)

    _case = field_validator("message_format", mode="before")(_upper)

    @field_validator("profile")
    @classmethod
    def _known_profile(cls, value: str | None) -> str | None:
        if value is not None:
            profile_level(value)
        return value


def merge_patch(target: Any, patch: Any) -> Any:
    """RFC 7386 JSON merge patch: ``null`` removes a key, objects merge, the rest replaces."""
    if not isinstance(patch, dict):
        return patch
    result = dict(target) if isinstance(target, dict) else {}
    for key, value in patch.items():
        if value is None:
            result.pop(key, None)
        else:
            result[key] = merge_patch(result.get(key), value)
    return result


def stream_filter(*filters: Sequence[str] | None) -> frozenset[str] | None:
    """Intersect stream filters; ``None`` or empty means every stream."""
    result: frozenset[str] | None = None
    for names in filters:
        if names:
            result = frozenset(names) if result is None else result & frozenset(names)
    return result


ClientMessage = Start | TransformLog | TransformPointInTime | Reconfigure

CLIENT_MESSAGES: dict[str, type[_Message]] = {
    model.TYPE: model for model in (Start, TransformLog, TransformPointInTime, Reconfigure)
}


def envelope(name: str, data: Any) -> dict[str, Any]:
    """Wrap ``data`` as the message ``xviz/<name>``."""
    return {"type": XVIZ_NAMESPACE + name, "data": data}


def unwrap(message: Any) -> tuple[str, Any]:
    """Return the type (``"xviz/..."``) and data of a decoded message.

    Bare messages without an envelope are recognised the way clients do:
    metadata by its ``version``, a state update by ``update_type`` and
    ``updates``.
    """
    if not isinstance(message, Mapping):
        raise MessageError(
            f'a message must be a JSON object like {{"type": "xviz/<name>", "data": {{...}}}}, '
            f"not {type(message).__name__}"
        )
    if "type" in message and "data" in message:
        kind = message["type"]
        if not isinstance(kind, str):
            raise MessageError(f"message 'type' must be a string like \"xviz/transform_log\", not {kind!r}")
        return kind, message["data"]
    if "version" in message:
        return XVIZ_NAMESPACE + "metadata", message
    if "update_type" in message and "updates" in message:
        return XVIZ_NAMESPACE + "state_update", message
    raise MessageError(
        'a message must be an envelope {"type": "xviz/<name>", "data": {...}}; '
        f"this one has the keys {sorted(message)}"
    )


def parse_client_message(message: Any) -> ClientMessage:
    """Parse a decoded message from a client into its model.

    Raises :class:`~xviz_server.exceptions.MessageError` for an unknown type
    or a field that is missing or wrong, naming the message type, the request
    id when there is one, and each field at fault.
    """
    kind, data = unwrap(message)
    name = kind.removeprefix(XVIZ_NAMESPACE)
    model = CLIENT_MESSAGES.get(name) if kind.startswith(XVIZ_NAMESPACE) else None
    if model is None:
        known = ", ".join(XVIZ_NAMESPACE + n for n in CLIENT_MESSAGES)
        raise MessageError(f"unknown message type {kind!r}; a client may send {known}", message_type=kind)
    request_id = data.get("id") if isinstance(data, Mapping) else None
    request_id = (
        None if request_id is None else shown(request_id) if not isinstance(request_id, str) else request_id[:SHOWN]
    )
    subject = kind if request_id is None else f"{kind} (id {request_id!r})"
    if isinstance(data, Mapping) and (crowded := _crowded(data)) is not None:
        raise MessageError(
            f"{subject}: '{crowded}' holds more than the {MAX_ITEMS} items a message may hold: refused whole",
            message_type=name,
            request_id=request_id,
        )
    try:
        return model.model_validate(data)  # type: ignore[return-value]
    except pydantic.ValidationError as exc:
        found = Problems()
        for error in exc.errors(include_url=False):
            found.add(describe_validation_error(error))
        raise MessageError(str(found.summary(subject)), message_type=name, request_id=request_id) from None


def _crowded(data: Mapping[str, Any]) -> str | None:
    """The field of a client message's data that lists more than :data:`~xviz_server.budget.MAX_ITEMS` items."""
    for key in ("desired_streams", "requested_streams"):
        if too_many(data.get(key)):
            return key
    update = data.get("config_update")
    if isinstance(update, Mapping) and too_many(update.get("desired_streams")):
        return "config_update.desired_streams"
    return None


def is_number(value: Any) -> bool:
    """A finite ``int`` or ``float``, not a ``bool`` (nor an int beyond the float range)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def describe_validation_error(error: Mapping[str, Any]) -> str:
    """One pydantic validation error as a phrase: which field, what is wrong, what came."""
    field = ".".join(str(part) for part in error["loc"])
    kind = error["type"]
    if kind == "extra_forbidden":
        return f"unknown key {field!r}"
    if kind == "missing":
        return f"'{field}' is required"
    if kind == "model_type" or (kind == "dict_type" and not field):
        return f"the data must be a JSON object, not {shown(error['input'])}"
    if kind == "value_error":
        message = str(error["ctx"]["error"]) if "ctx" in error else error["msg"]
        return message if not field else f"'{field}': {message}"
    expected = {
        "float_type": "a number",
        "float_parsing": "a number",
        "finite_number": "a finite number",
        "string_type": "a string",
        "list_type": "a list",
        "dict_type": "a JSON object",
        "enum": "one of " + str(error.get("ctx", {}).get("expected", "")),
        "literal_error": "one of " + str(error.get("ctx", {}).get("expected", "")),
    }.get(kind)
    if expected is None:
        return f"'{field}': {error['msg']} (got {shown(error['input'])})"
    return f"'{field}' must be {expected}, not {shown(error['input'])}"
