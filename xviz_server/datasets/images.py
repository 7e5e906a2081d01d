"""Camera images of raw datasets, scaled down for the viewer."""

from __future__ import annotations

import io

import numpy as np

__all__ = ["jpeg"]


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
