"""Camera images of raw datasets, scaled down for the viewer."""

from __future__ import annotations

import io
from collections.abc import Mapping
from concurrent.futures import Future
from typing import TYPE_CHECKING

import numpy as np

from ..codec.image import sniff_image
from ..exceptions import DatasetError
from . import threads

if TYPE_CHECKING:
    from PIL.Image import Image as Picture

__all__ = ["jpeg", "scaled_jpeg", "scale_jpegs", "fit_width", "encode_like"]


def _height(width: int, height: int, max_width: int) -> int:
    return max(1, round(height * max_width / width))


def _encode(picture: Picture, quality: int) -> bytes:
    out = io.BytesIO()
    picture.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def jpeg(image: np.ndarray, max_width: int, quality: int = 85) -> bytes:
    """An (H, W, 3) uint8 RGB image as JPEG, scaled down to ``max_width`` pixels if wider (aspect kept)."""
    from PIL import Image

    picture = Image.fromarray(image)
    if picture.width > max_width:
        picture = picture.resize(
            (max_width, _height(picture.width, picture.height, max_width)), Image.Resampling.BILINEAR
        )
    return _encode(picture, quality)


def scaled_jpeg(data: bytes, max_width: int, quality: int = 85) -> bytes:
    """A JPEG image as it is if at most ``max_width`` pixels wide, else scaled down to it (aspect kept).

    Scaling decodes the image at the smallest of 1/2, 1/4, 1/8 of its size
    that is still as wide as ``max_width`` (JPEG decoders do this for a
    fraction of the cost of a full decode), resizes it and encodes it again.
    Raises :class:`~xviz_server.exceptions.DatasetError` if ``data`` is not
    a JPEG image, or cannot be decoded when it has to be scaled.
    """
    info = sniff_image(data)
    if info is None or info.mime_type != "image/jpeg":
        raise DatasetError("not a JPEG image")
    if info.width <= max_width:
        return data
    from PIL import Image

    size = (max_width, _height(info.width, info.height, max_width))
    try:
        with Image.open(io.BytesIO(data)) as picture:
            picture.draft("RGB", size)
            return _encode(picture.convert("RGB").resize(size, Image.Resampling.BILINEAR), quality)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DatasetError(f"not a decodable JPEG image: {exc}") from None


def scale_jpegs(images: Mapping[str, bytes], max_width: int) -> dict[str, Future[bytes]]:
    """Start :func:`scaled_jpeg` on each image, side by side (see :mod:`.threads`); the futures of the results."""
    return {name: threads.submit(scaled_jpeg, data, max_width) for name, data in images.items()}


def fit_width(picture: Picture, max_width: int, reducing_gap: float = 2.0) -> Picture:
    """``picture`` scaled to ``max_width`` if wider, its height rounded down, bilinear.

    With the default ``reducing_gap`` this is the official KITTI converter's
    scaling; a smaller one first shrinks by a whole factor with a box filter
    (see Pillow's ``Image.resize``), which is several times faster for large
    reductions (see docs/performance.md#ros-bags-and-mcap).
    """
    if picture.width <= max_width:
        return picture
    from PIL import Image

    size = (max_width, max(1, picture.height * max_width // picture.width))
    return picture.resize(size, Image.Resampling.BILINEAR, reducing_gap=reducing_gap)


def encode_like(mime_type: str, picture: Picture, quality: int = 85) -> bytes:
    """``picture`` encoded as ``image/jpeg`` (at ``quality``) or else as PNG (fast, level 1)."""
    out = io.BytesIO()
    if mime_type == "image/jpeg":
        picture.convert("RGB").save(out, format="JPEG", quality=quality)
    else:
        picture.save(out, format="PNG", compress_level=1)
    return out.getvalue()
