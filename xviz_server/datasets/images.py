"""Camera images of raw datasets, scaled down for the viewer."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from PIL.Image import Image as Picture

__all__ = ["jpeg", "fit_width", "encode_like"]


def jpeg(image: np.ndarray, max_width: int, quality: int = 85) -> bytes:
    """An (H, W, 3) uint8 RGB image as JPEG, scaled down to ``max_width`` pixels if wider (aspect kept)."""
    from PIL import Image

    picture = Image.fromarray(image)
    if picture.width > max_width:
        height = max(1, round(picture.height * max_width / picture.width))
        picture = picture.resize((max_width, height), Image.Resampling.BILINEAR)
    out = io.BytesIO()
    picture.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def fit_width(picture: Picture, max_width: int, reducing_gap: float = 2.0) -> Picture:
    """``picture`` scaled to ``max_width`` if wider, its height rounded down, bilinear.

    With the default ``reducing_gap`` this is the official KITTI converter's
    scaling; a smaller one first shrinks by a whole factor with a box filter
    (see Pillow's ``Image.resize``), which is several times faster for large
    reductions.
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
