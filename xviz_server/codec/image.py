"""Encoded images: their type and size read from their first bytes, and their decoding.

The GLB writer records ``mimeType``, ``width`` and ``height`` for every image
it moves into the BIN chunk, as ``@xviz/io`` does; :func:`sniff_image` finds
them without decoding the image. :func:`decode_image` decodes one with
Pillow, and PNG images without row filters faster.
"""

from __future__ import annotations

import io
import struct
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..exceptions import DecodeError

if TYPE_CHECKING:
    from PIL.Image import Image as Picture

__all__ = ["ImageInfo", "sniff_image", "decode_image"]


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


def decode_image(data: bytes | bytearray | memoryview, max_pixels: int) -> Picture | None:
    """Decode an encoded image in any format Pillow reads; ``None`` if it has more than ``max_pixels`` pixels.

    Only the header of a larger image is read. A PNG image of 8-bit grey,
    RGB or RGBA pixels that is not interlaced and whose rows are not
    filtered (the default of sharp and libvips; the XVIZ KITTI converter
    scales its camera images with sharp) is inflated with zlib-ng, faster
    than Pillow's zlib, and its rows taken as they are; any other image is
    decoded by Pillow. Raises :class:`~xviz_server.exceptions.DecodeError`
    for bytes that are no image Pillow can decode.
    """
    from PIL import Image

    try:
        opened = Image.open(io.BytesIO(data))  # reads the header only
        if opened.width * opened.height > max_pixels:
            return None
        if opened.format == "PNG" and (picture := _unfiltered_png(memoryview(data), opened.size)) is not None:
            return picture
        opened.load()
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DecodeError(f"an image cannot be decoded: {exc}") from None
    return opened


# The PNG colour types _unfiltered_png reads (at 8 bits a sample): Pillow's mode and bytes a pixel.
_PNG_MODES = {0: ("L", 1), 2: ("RGB", 3), 6: ("RGBA", 4)}


def _unfiltered_png(view: memoryview, size: tuple[int, int]) -> Picture | None:
    """The pixels of a PNG image whose rows have no filter, inflated with zlib-ng; ``None`` for any other.

    The image's data must inflate to ``height`` rows of a zero filter byte
    and ``width`` pixels: any other image is left to Pillow (one whose first
    row is filtered as soon as that row's filter byte is inflated).
    """
    from PIL import Image
    from zlib_ng import zlib_ng

    if len(view) < 33 or bytes(view[12:16]) != b"IHDR" or struct.unpack_from(">II", view, 16) != size:
        return None
    depth, colour, _, _, interlace = view[24:29]
    if depth != 8 or colour not in _PNG_MODES or interlace:
        return None
    mode, channels = _PNG_MODES[colour]
    width, height = size
    row = 1 + width * channels
    chunks: list[memoryview] = []  # the image data: IDAT chunks, one after the other
    offset = 8
    while offset + 12 <= len(view):
        (length,) = struct.unpack_from(">I", view, offset)
        kind = bytes(view[offset + 4 : offset + 8])
        if kind == b"IDAT":
            chunks.append(view[offset + 8 : offset + 8 + length])
        elif chunks:
            break
        offset += 12 + length
    inflate = zlib_ng.decompressobj()
    try:
        first = inflate.decompress(b"".join(chunks), 1)  # the first row's filter byte, alone
        if first != b"\x00":
            return None
        rest = inflate.decompress(inflate.unconsumed_tail, row * height - 1)
    except zlib_ng.error:  # type: ignore[misc]  # its stub declares error an instance
        return None
    if len(rest) != row * height - 1 or np.frombuffer(rest, dtype=np.uint8)[row - 1 :: row].any():  # a filtered row
        return None
    # Rows of ``row`` bytes from the first pixel on: a filter byte follows each, the last one made up.
    return Image.frombuffer(mode, size, rest + b"\x00", "raw", mode, row, 1)
