"""Frame jobs: pure functions from encoded frames to encoded frames.

They take and return ``bytes`` so that they can run in a worker process as
well as in a thread (see :mod:`xviz_server.work`); :func:`placement` tells
where. A frame's *native* format is the one its source stores it in.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import Any

from .admission import expanded_size
from .codec import Format, decode, detect_format, edit_glb, encode, is_glb
from .exceptions import DecodeError
from .layout import update_span
from .levels import FULL, Level, reduce_message
from .state import complete_state, downsample_points, filter_streams
from .unpack import MAX_FRAME_BYTES, size_text
from .validation import get_validator
from .work import Place

__all__ = [
    "INLINE_BYTES",
    "HEAVY_JSON_BYTES",
    "placement",
    "validate",
    "check",
    "span",
    "render",
    "render_message",
    "merge",
    "relabel_complete",
]


#: Size up to which a job runs in the event loop (see :func:`placement`).
INLINE_BYTES = 8 * 1024

#: Size above which a job on JSON runs in a worker process (see :func:`placement`).
HEAVY_JSON_BYTES = 64 * 1024


def placement(size: int, *formats: Format) -> Place:
    """Where a job on ``size`` bytes of frames, touching these formats, runs.

    A job on at most :data:`INLINE_BYTES` holds the event loop for less
    time than the round trip to a thread costs, and for a small part of a
    millisecond, so it runs there. Decoding
    and encoding GLB is a fraction of a millisecond even for a large frame:
    a thread. Parsing or writing JSON holds the GIL in proportion to its
    size: up to :data:`HEAVY_JSON_BYTES` that costs less than the hop to a
    worker process, so only larger JSON jobs go there.
    See docs/performance.md#point-in-time-on-a-long-json-log.
    """
    if size <= INLINE_BYTES:
        return Place.LOOP
    if size > HEAVY_JSON_BYTES and Format.JSON in formats:
        return Place.PROCESS
    return Place.THREAD


def _decode_update(data: bytes) -> dict[str, Any]:
    message = decode(data)
    if not isinstance(message, dict) or not isinstance(message.get("data"), dict):
        raise DecodeError('frame is not an XVIZ envelope {"type": ..., "data": {...}}')
    if message.get("type") != "xviz/state_update":
        raise DecodeError(f"frame holds {message.get('type')!r}, not xviz/state_update")
    updates = message["data"].get("updates")
    if not isinstance(updates, list) or not updates:
        raise DecodeError("state update has no 'updates'")
    return message


def validate(message: dict[str, Any]) -> None:
    """Check a decoded message against the XVIZ schema.

    Raises :class:`~xviz_server.exceptions.SchemaValidationError`.
    """
    get_validator().validate_message(message)


def check(data: bytes, schema: bool = False) -> tuple[str, int]:
    """The update type of a state-update frame and its number of stream sets.

    Raises :class:`~xviz_server.exceptions.DecodeError` unless ``data`` is a
    readable state update, and with ``schema``
    :class:`~xviz_server.exceptions.SchemaValidationError` unless it matches
    the XVIZ schema, or a GLB frame that expands to more than
    :data:`~xviz_server.unpack.MAX_FRAME_BYTES` when re-encoded, its arrays each
    counted as often as they are referenced (a GLB accessor referenced a
    thousand times costs a few bytes to store and a thousand copies to send).
    """
    message = _decode_update(data)
    size = expanded_size(message["data"]) if is_glb(data) else 0  # JSON references nothing: see admission
    if size > MAX_FRAME_BYTES:
        raise DecodeError(
            f"state update expands to {size_text(size)} when re-encoded (arrays referenced more than once), "
            f"more than the limit of {size_text(MAX_FRAME_BYTES)} for one frame"
        )
    if schema:
        validate(message)
    update_type = message["data"].get("update_type")
    if not isinstance(update_type, str):
        raise DecodeError("state update has no 'update_type' (clients need it)")
    return update_type.upper(), len(message["data"]["updates"])


def span(data: bytes) -> tuple[float, float]:
    """First and last timestamp of a state-update frame."""
    result = update_span(_decode_update(data)["data"])
    if result is None:
        raise DecodeError("every update of a state update needs a numeric 'timestamp'")
    return result


def render(
    data: bytes, fmt: Format, streams: Collection[str] | None, max_points: int | None = None, level: Level = FULL
) -> bytes:
    """Re-encode a frame in ``fmt``, keeping only ``streams`` and at most ``max_points`` points a cloud when given,
    at ``level`` of detail (see :mod:`~xviz_server.levels`)."""
    return render_message(_decode_update(data), fmt, streams, max_points, level)


def render_message(
    message: dict[str, Any],
    fmt: Format,
    streams: Collection[str] | None,
    max_points: int | None = None,
    level: Level = FULL,
) -> bytes:
    """:func:`render` for a decoded state update."""
    if streams is not None:
        message = filter_streams(message, streams)
    if max_points is not None:
        message = downsample_points(message, max_points)
    return encode(reduce_message(message, level), fmt)


def merge(frames: Sequence[bytes], fmt: Format, streams: Collection[str] | None) -> tuple[bytes, bool]:
    """Merge frames, newest first, into one ``COMPLETE_STATE`` message in ``fmt``.

    Returns the message and whether a complete frame was reached (see
    :func:`~xviz_server.state.complete_state`).
    """
    message, reached = complete_state((_decode_update(data) for data in frames), streams)
    return encode(message, fmt), reached


def relabel_complete(data: bytes) -> bytes:
    """A frame of one complete stream set as a ``COMPLETE_STATE`` update, in its own format.

    Such a frame is already the whole state at its time, and this is what
    :func:`merge` would make of it. For GLB it costs the rewriting of the
    JSON chunk only: the arrays are not decoded or copied one by one.
    """

    def edit(message: Any) -> Any:
        return {**message, "data": {**message["data"], "update_type": "COMPLETE_STATE"}}

    if detect_format(data) is Format.BINARY:
        return edit_glb(data, edit)
    return encode(edit(_decode_update(data)), Format.JSON)
