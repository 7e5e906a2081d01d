"""XVIZ messages as JSON.

Encoding uses orjson, which writes numpy arrays natively (far faster than
the standard library on a point cloud: see docs/performance.md#codecs). Binary image data (``bytes`` or ``memoryview``,
as the GLB decoder returns it) becomes base64 text, which is how XVIZ JSON
carries images.
"""

from __future__ import annotations

import base64
import re
from typing import Any

import numpy as np
import orjson

from ..exceptions import DecodeError, EncodeError

__all__ = ["encode_json", "decode_json", "MAX_DEPTH", "nested_deeper"]

#: The deepest nesting of lists and objects in a message that the GLB codec reads and writes (XVIZ's own is
#: about 15 levels; orjson writes at most 254, and Python recursion ends near 1 000).
MAX_DEPTH = 128

_OPTIONS = orjson.OPT_SERIALIZE_NUMPY
_JSON_START = re.compile(rb"[ \t\r\n]*[{\[]")  # how JSON text of an object or array starts


def _default(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(value).decode("ascii")
    if isinstance(value, np.ndarray):
        # orjson handles contiguous arrays of the common dtypes itself and
        # hands everything else (views with strides, object arrays) to us.
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError  # orjson reports the type itself


def nested_deeper(value: Any, limit: int = MAX_DEPTH) -> bool:
    """Whether lists and objects in ``value`` nest more than ``limit`` deep (read level by level, without recursion)."""
    level: list[Any] = [value]
    for _ in range(limit):
        level = [
            item
            for container in level
            if isinstance(container, (dict, list))
            for item in (container.values() if isinstance(container, dict) else container)
        ]
        if not level:
            return False
    return any(isinstance(item, (dict, list)) for item in level)


def encode_json(message: Any) -> bytes:
    """Encode a message as compact UTF-8 JSON.

    Raises :class:`~xviz_server.exceptions.EncodeError` for values that JSON
    cannot represent.
    """
    try:
        return orjson.dumps(message, default=_default, option=_OPTIONS)
    except orjson.JSONEncodeError as exc:
        raise EncodeError(f"cannot encode message as JSON: {exc}") from None


def decode_json(data: bytes | bytearray | memoryview | str) -> Any:
    """Decode UTF-8 JSON text.

    Raises :class:`~xviz_server.exceptions.DecodeError` with the offset of
    the first invalid character, or, for bytes that do not start as an XVIZ
    JSON message does (``{``), saying that they are no XVIZ frame at all
    (:func:`~xviz_server.codec.decode` has told them from GLB already).
    """
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        if not isinstance(data, str) and not _JSON_START.match(data):
            raise DecodeError(f"not a GLB or JSON frame: it starts with {bytes(data[:8])!r}", offset=0) from None
        raise DecodeError(
            f"invalid JSON at line {exc.lineno} column {exc.colno} (offset {exc.pos}): {exc.msg}",
            offset=exc.pos,
        ) from None
