"""What a live source may push: messages checked at the door, before any viewer sees them.

A source is as hostile as any client. :func:`admit` reads one message from
it and returns it as GLB bytes, or raises
:class:`~xviz_server.exceptions.MessageError` naming the field at fault:

* the message must decode (JSON or GLB) to ``xviz/metadata`` or
  ``xviz/state_update``;
* JSON may hold at most :data:`MAX_CONTAINERS` lists and objects (counted
  before parsing: a small message of millions of empty lists would
  otherwise cost gigabytes), nested at most
  :data:`~xviz_server.codec.json.MAX_DEPTH` deep, as in GLB;
* a state update must have the shape the server and viewers rely on: an
  ``update_type`` the protocol knows, a list of stream sets each with a
  finite ``timestamp``, stream maps of objects, primitive lists of objects,
  point clouds that are arrays;
* what a GLB message expands to when re-encoded (every array as many times
  as it is referenced) must fit in ``max_bytes``: a GLB accessor referenced
  a thousand times costs a few bytes to send and a thousand copies to
  re-encode. JSON references nothing: it expands to about its own size,
  which ``max_bytes`` bounds already, so its values are not walked.

It is a pure function of bytes to bytes, for a worker process when the
message is large JSON. :func:`check` makes the same checks of a message
decoded already. Entries read from the broker between replicas pass them
too (:mod:`xviz_server.live.mirror`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .codec import Format, decode, detect_format, encode
from .codec.json import MAX_DEPTH, nested_deeper
from .exceptions import DecodeError, MessageError
from .messages import envelope, is_number, unwrap
from .state import STREAM_MAPS

__all__ = ["MAX_CONTAINERS", "UPDATE_TYPES", "admit", "check", "expanded_size"]

#: Most JSON lists and objects one message may hold.
MAX_CONTAINERS = 2_000_000
#: The update types of the protocol (``SNAPSHOT`` is the legacy name of ``COMPLETE_STATE``).
UPDATE_TYPES = frozenset({"COMPLETE_STATE", "INCREMENTAL", "PERSISTENT", "SNAPSHOT"})


def admit(data: bytes, max_bytes: int) -> tuple[str, bytes]:
    """The type (``xviz/metadata`` or ``xviz/state_update``) of a source's message and the message as GLB.

    A GLB message comes back as it is. Raises
    :class:`~xviz_server.exceptions.MessageError`.
    """
    try:
        binary = detect_format(data) is Format.BINARY
        if not binary and data.count(b"[") + data.count(b"{") > MAX_CONTAINERS:
            raise MessageError(f"more than {MAX_CONTAINERS} JSON lists and objects in one message")
        message = decode(data)
    except DecodeError as exc:
        raise MessageError(f"not a GLB or JSON message: {exc}") from None
    if not binary and nested_deeper(message):  # GLB's decoder refuses them itself
        raise MessageError(f"lists and objects nested more than {MAX_DEPTH} deep")
    kind, content = unwrap(message)
    check(kind, content, max_bytes, from_glb=binary)
    if binary:
        return kind, data
    return kind, encode(envelope(kind.removeprefix("xviz/"), content), Format.BINARY)


def check(kind: str, content: Any, max_bytes: int, *, from_glb: bool = True) -> None:
    """Raise :class:`~xviz_server.exceptions.MessageError` unless ``content`` (decoded) is an admissible message of
    type ``kind``: what :func:`admit` checks once the message is decoded. ``from_glb``: ``content`` was decoded from
    GLB, so its arrays may be referenced more than once."""
    if kind == "xviz/metadata":
        _require(isinstance(content, Mapping), "metadata", "must be an object", content)
        _require(
            isinstance(content.get("streams", {}), Mapping),
            "metadata.streams",
            "must be an object",
            content.get("streams"),
        )
    elif kind == "xviz/state_update":
        _check_update(content)
        size = expanded_size(content) if from_glb else 0
        if size > max_bytes:
            raise MessageError(
                f"state update expands to {size / 2**20:.1f} MB when re-encoded (arrays referenced more than once), "
                f"over the limit of {max_bytes / 2**20:.1f} MB"
            )
    else:
        raise MessageError(f"a live source sends xviz/metadata and xviz/state_update, not {kind!r}")


def _require(condition: bool, where: str, what: str, value: Any) -> None:
    if not condition:
        shown = repr(value) if not isinstance(value, (dict, list)) else type(value).__name__
        raise MessageError(f"{where}: {what}, not {shown[:60]}")


def _check_update(data: Any) -> None:
    _require(isinstance(data, Mapping), "state_update", "must be an object", data)
    update_type = data.get("update_type", "INCREMENTAL")
    _require(
        isinstance(update_type, str) and update_type.upper() in UPDATE_TYPES,
        "update_type",
        f"must be one of {', '.join(sorted(UPDATE_TYPES))}",
        update_type,
    )
    updates = data.get("updates")
    _require(isinstance(updates, list) and len(updates) > 0, "updates", "must be a non-empty list", updates)
    for i, stream_set in enumerate(updates):
        where = f"updates[{i}]"
        _require(isinstance(stream_set, Mapping), where, "must be an object", stream_set)
        _require(
            is_number(stream_set.get("timestamp")),
            f"{where}.timestamp",
            "must be a finite number",
            stream_set.get("timestamp"),
        )
        for key in STREAM_MAPS:
            streams = stream_set.get(key)
            if streams is None:
                continue
            _require(isinstance(streams, Mapping), f"{where}.{key}", "must be an object of streams", streams)
            for name, state in streams.items():
                _require(isinstance(state, Mapping), f"{where}.{key}[{name!r}]", "must be an object", state)
                if key == "primitives":
                    _check_primitives(f"{where}.primitives[{name!r}]", state)
        series = stream_set.get("time_series")
        if series is not None:
            _require(isinstance(series, list), f"{where}.time_series", "must be a list", series)
            for j, entry in enumerate(series):
                _require(
                    isinstance(entry, Mapping)
                    and isinstance(entry.get("streams"), list)
                    and isinstance(entry.get("values"), Mapping),
                    f"{where}.time_series[{j}]",
                    "must be an object with 'streams' and 'values'",
                    entry,
                )


def _check_primitives(where: str, state: Mapping[str, Any]) -> None:
    for kind, primitives in state.items():
        _require(isinstance(primitives, list), f"{where}.{kind}", "must be a list", primitives)
        for k, primitive in enumerate(primitives):
            _require(isinstance(primitive, Mapping), f"{where}.{kind}[{k}]", "must be an object", primitive)
            for key in ("points", "vertices"):
                if key in primitive:
                    value = primitive[key]
                    _require(
                        isinstance(value, (np.ndarray, list)), f"{where}.{kind}[{k}].{key}", "must be an array", value
                    )


_CONTAINERS = (Mapping, list, np.ndarray, bytes, bytearray, memoryview)


def expanded_size(value: Any) -> int:
    """Bytes of the arrays and binary data in ``value`` (a decoded GLB message), each counted as often as it is
    referenced, and 8 bytes for each number or string in a list.

    Every item of a list is looked at: an array may hide behind a first item that is a number. The walk is one
    step per value of the message's JSON part, which in GLB is small (its clouds and images are arrays).
    """
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (bytes, bytearray, memoryview)):
        return len(value)
    if isinstance(value, Mapping):
        return sum(expanded_size(item) for item in value.values())
    if isinstance(value, list):
        return sum(expanded_size(item) if isinstance(item, _CONTAINERS) else 8 for item in value)
    return 0
