"""Encoding and decoding of XVIZ messages: JSON and GLB, and reading protobuf (PBE).

This layer is pure: bytes in, envelopes out, and back. An envelope is a
plain ``dict`` (``{"type": "xviz/<name>", "data": {...}}``) whose large
arrays may be numpy arrays and whose images may be ``bytes`` or
``memoryview`` objects.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from typing import Any

from ..exceptions import DecodeError
from .glb import cut_glb, decode_glb, edit_glb, encode_glb, is_glb
from .json import decode_json, encode_json
from .pbe import decode_pbe, is_pbe

__all__ = [
    "Format",
    "encode",
    "decode",
    "detect_format",
    "encode_glb",
    "decode_glb",
    "edit_glb",
    "cut_glb",
    "encode_json",
    "decode_json",
    "decode_pbe",
    "is_pbe",
]


class Format(str, enum.Enum):
    """Wire format of a message; the values are XVIZ's ``message_format`` names."""

    JSON = "JSON"
    BINARY = "BINARY"

    @property
    def suffix(self) -> str:
        """File extension of a message in this format in a log directory."""
        return ".json" if self is Format.JSON else ".glb"


def detect_format(data: bytes | bytearray | memoryview | str) -> Format:
    """Tell a GLB message from a JSON one by its first bytes.

    Raises :class:`~xviz_server.exceptions.DecodeError` for protobuf (PBE)
    messages: :func:`decode` reads them, but they are never sent as they
    are, so they have no :class:`Format`.
    """
    if isinstance(data, str):
        return Format.JSON
    head = bytes(data[:4])
    if is_glb(head):
        return Format.BINARY
    if is_pbe(head):
        raise DecodeError(
            "a protobuf (PBE1) XVIZ message has no wire format: decode it and encode it as GLB or JSON", offset=0
        )
    return Format.JSON


def encode(message: Mapping[str, Any], fmt: Format) -> bytes:
    """Encode an envelope in the given format."""
    return encode_glb(message) if fmt is Format.BINARY else encode_json(message)


def decode(data: bytes | bytearray | memoryview | str) -> Any:
    """Decode a JSON, GLB or PBE message, told apart by its first bytes."""
    if isinstance(data, str):
        return decode_json(data)
    if is_pbe(data):
        return decode_pbe(data)
    if detect_format(data) is Format.BINARY:
        return decode_glb(data)
    return decode_json(data)
