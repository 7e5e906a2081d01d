"""Sensor messages as arrays and images: ``PointCloud2`` read from its raw buffer, camera images encoded for XVIZ."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...codec.image import sniff_image
from ...exceptions import DatasetError
from ..images import encode_like, fit_width
from ..shared import reflectance_colors

__all__ = ["byte_array", "cloud_points", "scan_points", "image_bytes", "compressed_image_bytes", "IMAGE_ENCODINGS"]

# sensor_msgs/PointField datatypes.
_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_BAYER = {
    "rggb": (0, 1, 1, 2),
    "bggr": (2, 1, 1, 0),
    "gbrg": (1, 2, 0, 1),
    "grbg": (1, 0, 2, 1),
}  # channel of each 2x2 cell
#: Images are first shrunk by a whole factor with a box filter, then resampled (see ``fit_width``).
_REDUCING_GAP = 1.0
IMAGE_ENCODINGS = (
    "rgb8",
    "bgr8",
    "rgba8",
    "bgra8",
    "mono8",
    "8uc1",
    "mono16",
    "16uc1",
    "8uc3",
    *(f"bayer_{pattern}8" for pattern in _BAYER),
)


def byte_array(data: Any) -> np.ndarray:
    """A ``uint8[]`` field as a numpy array, whichever decoder made it: an array (rosbags) or ``bytes`` (the MCAP
    decoders, the Foxglove schemas)."""
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8)


def cloud_points(
    message: Any, where: str, *, color: str = "auto", intensity_scale: float | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The finite points of a ``PointCloud2``, float32 (N, 3), and their uint8 colours or ``None``; points at
    exactly (0, 0, 0), which drivers write for a beam with no return (an Ouster cloud keeps every beam), are left out.

    x, y and z may be of any type, offset and byte order; other fields are
    ignored except ``rgb``/``rgba`` (packed 0x00RRGGBB in a float32 or
    uint32) and ``intensity``. ``color`` is ``auto`` (rgb, else intensity,
    else none), ``rgb``, ``intensity`` or ``none``. Intensities are coloured
    like the KITTI stream's reflectances, after multiplying by
    ``intensity_scale``: by default 1 for floats (reflectances in 0..1) and
    one over the type's largest value for integers. ``where`` names the
    file and topic in errors.
    """
    fields = {f.name: f for f in message.fields}
    missing = [axis for axis in "xyz" if axis not in fields]
    if missing:
        raise DatasetError(
            f"{where}: PointCloud2 has no {', '.join(missing)} field (fields: {', '.join(fields) or 'none'})"
        )
    order = ">" if message.is_bigendian else "<"
    wanted = [name for name in ("x", "y", "z", "rgb", "rgba", "intensity") if name in fields]
    try:
        dtype = np.dtype(
            {
                "names": wanted,
                "formats": [order + _FIELD_TYPES[fields[name].datatype] for name in wanted],
                "offsets": [fields[name].offset for name in wanted],
                "itemsize": message.point_step,
            }
        )
    except (KeyError, ValueError) as exc:
        raise DatasetError(
            f"{where}: PointCloud2 field layout does not fit point_step {message.point_step}: {exc}"
        ) from None
    count = message.width * message.height
    data = byte_array(message.data)
    row = message.width * message.point_step
    if len(data) < (message.height - 1) * message.row_step + row or (message.height > 1 and message.row_step < row):
        raise DatasetError(
            f"{where}: PointCloud2 data holds {len(data)} bytes, too few for {message.width}x{message.height} points"
        )
    if message.height > 1 and message.row_step != row:
        data = data[: message.height * message.row_step].reshape(message.height, message.row_step)[:, :row]
    records = np.frombuffer(np.ascontiguousarray(data[: count * message.point_step]).data, dtype=dtype, count=count)
    points = np.empty((count, 3), dtype=np.float32)
    finite = np.ones(count, dtype=bool)
    returned = np.zeros(count, dtype=bool)
    for column, axis in enumerate("xyz"):
        points[:, column] = records[axis]
        finite &= np.isfinite(points[:, column])
        returned |= points[:, column] != 0
    finite &= returned
    keep = None if finite.all() else finite
    if keep is not None:
        points = points[keep]
    packed = "rgb" if "rgb" in fields else "rgba" if "rgba" in fields else None
    if color in ("auto", "rgb") and packed is not None:
        values = records[packed]
        values = values.view(values.dtype.str[0] + "u4") if values.dtype.itemsize == 4 else values
        values = (values if keep is None else values[keep]).astype(np.uint32)
        colors = np.empty((len(points), 3), dtype=np.uint8)
        for channel, shift in enumerate((16, 8, 0)):
            colors[:, channel] = (values >> shift) & 0xFF
        return points, colors
    if color in ("auto", "intensity") and "intensity" in fields:
        intensity = records["intensity"] if keep is None else records["intensity"][keep]
        if intensity_scale is None and intensity.dtype.kind in "iu":
            intensity_scale = 1 / np.iinfo(intensity.dtype).max
        return points, reflectance_colors(intensity if intensity_scale is None else intensity * intensity_scale)
    return points, None


def scan_points(message: Any) -> np.ndarray:
    """The returns of a ``sensor_msgs/LaserScan`` as points in its frame, float32 (N, 3): ranges outside
    ``[range_min, range_max]`` and not finite are no returns, left out."""
    ranges = np.asarray(message.ranges, dtype=np.float64)
    angles = float(message.angle_min) + float(message.angle_increment) * np.arange(len(ranges))
    keep = (
        np.isfinite(ranges) & (ranges >= float(message.range_min)) & (ranges <= float(message.range_max)) & (ranges > 0)
    )
    points = np.zeros((int(keep.sum()), 3), dtype=np.float32)
    points[:, 0] = ranges[keep] * np.cos(angles[keep])
    points[:, 1] = ranges[keep] * np.sin(angles[keep])
    return points


def _pixels(message: Any, where: str) -> np.ndarray:
    encoding = message.encoding.lower()
    height, width, step = message.height, message.width, message.step
    channels = {"rgb8": 3, "bgr8": 3, "8uc3": 3, "rgba8": 4, "bgra8": 4, "mono16": 2, "16uc1": 2}.get(encoding, 1)
    data = byte_array(message.data)
    if encoding not in IMAGE_ENCODINGS:
        raise DatasetError(f"{where}: image encoding {message.encoding!r} is not one of {', '.join(IMAGE_ENCODINGS)}")
    if step < width * channels or len(data) < height * step:
        raise DatasetError(
            f"{where}: {encoding} image of {width}x{height} needs {height * step} bytes of rows of {width * channels}, has {len(data)}"
        )
    rows = data[: height * step].reshape(height, step)[:, : width * channels]
    if channels == 2:  # 16-bit mono: keep the high byte
        order = ">" if message.is_bigendian else "<"
        return (np.ascontiguousarray(rows).view(order + "u2") >> 8).astype(np.uint8)
    pixels = rows.reshape(height, width, channels) if channels > 1 else rows
    if encoding in ("bgr8", "bgra8"):
        pixels = pixels[..., [2, 1, 0, 3][:channels]]
    if encoding.startswith("bayer_"):
        pixels = _debayer(pixels, _BAYER[encoding[6:10]])
    return np.ascontiguousarray(pixels)


def _debayer(raw: np.ndarray, pattern: tuple[int, int, int, int]) -> np.ndarray:
    """RGB at half resolution: each 2x2 cell of the mosaic gives one pixel (its two greens averaged)."""
    height, width = raw.shape[0] // 2 * 2, raw.shape[1] // 2 * 2
    cells = [raw[dy:height:2, dx:width:2].astype(np.uint16) for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1))]
    rgb = np.zeros((height // 2, width // 2, 3), dtype=np.uint16)
    counts = np.zeros(3, dtype=np.uint16)
    for cell, channel in zip(cells, pattern):
        rgb[..., channel] += cell
        counts[channel] += 1
    return (rgb // counts).astype(np.uint8)


def image_bytes(message: Any, max_width: int, where: str) -> bytes:
    """A ``sensor_msgs/Image`` as PNG, scaled down to ``max_width`` (height rounded down, as KITTI's)."""
    from PIL import Image

    return encode_like("image/png", fit_width(Image.fromarray(_pixels(message, where)), max_width, _REDUCING_GAP))


def compressed_image_bytes(message: Any, max_width: int, where: str) -> bytes:
    """A ``sensor_msgs/CompressedImage``: its bytes as they are if narrow enough, else scaled down in the same format."""
    data = bytes(message.data)
    info = sniff_image(data)
    if info is None:
        raise DatasetError(f"{where}: CompressedImage ({message.format!r}) is not PNG, JPEG, GIF or BMP")
    if info.width <= max_width:
        return data
    import io

    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as picture:
            return encode_like(info.mime_type, fit_width(picture, max_width, _REDUCING_GAP))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{where}: cannot decode the {info.mime_type} image: {exc}") from None
