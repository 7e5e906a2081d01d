"""Read the type and size of an encoded image from its first bytes.

The GLB writer records ``mimeType``, ``width`` and ``height`` for every image
it moves into the BIN chunk, as ``@xviz/io`` does; this module finds them
without decoding the image.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

__all__ = ["ImageInfo", "sniff_image"]


class ImageInfo(NamedTuple):
    mime_type: str
    width: int
    height: int


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers carry the image size; C4 (DHT), C8 (JPG) and
# CC (DAC) share the range but are not frames.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def sniff_image(data: bytes | bytearray | memoryview) -> ImageInfo | None:
    """Return the type and size of a PNG, JPEG, GIF or BMP image, or ``None``."""
    head = bytes(data[:32])
    if head.startswith(_PNG_SIGNATURE) and len(head) >= 24:
        width, height = struct.unpack_from(">II", head, 16)
        return ImageInfo("image/png", width, height)
    if head.startswith(b"\xff\xd8"):
        return _sniff_jpeg(data)
    if head[:6] in (b"GIF87a", b"GIF89a") and len(head) >= 10:
        width, height = struct.unpack_from("<HH", head, 6)
        return ImageInfo("image/gif", width, height)
    if head.startswith(b"BM") and len(head) >= 26:
        width, height = struct.unpack_from("<ii", head, 18)
        return ImageInfo("image/bmp", width, abs(height))
    return None


def _sniff_jpeg(data: bytes | bytearray | memoryview) -> ImageInfo | None:
    view = memoryview(data)
    offset = 2
    while offset + 9 <= len(view):
        if view[offset] != 0xFF:
            return None
        marker = view[offset + 1]
        if marker == 0xFF:  # fill byte
            offset += 1
            continue
        (length,) = struct.unpack_from(">H", view, offset + 2)
        if marker in _JPEG_SOF:
            height, width = struct.unpack_from(">HH", view, offset + 5)
            return ImageInfo("image/jpeg", width, height)
        offset += 2 + length
    return None
