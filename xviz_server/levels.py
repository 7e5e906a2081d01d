"""Levels of detail of a state update, and their making (pure: numpy and Pillow, no I/O).

A :class:`Level` says what a session whose link cannot carry every byte is
sent instead. It changes only two things: point clouds, thinned on a voxel
grid (one point, with its colour, is kept in each occupied cube of
``voxel`` metres: the scene keeps its shape, its density evens out), and
camera images, re-encoded as JPEG, at a smaller size. A level may also
send a live session every ``every``-th update only. Everything else in an
update (poses, objects and their ids, polygons, time series, variables, UI
primitives, every timestamp) is left as it is: the level's message holds
the very same values as the full one.

:data:`LEVELS` goes from the most detail to the least; index 0,
:data:`FULL`, is every byte.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np

from .codec.image import decode_image

__all__ = [
    "Level",
    "LEVELS",
    "FULL",
    "AUTO_PROFILES",
    "MAX_IMAGE_PIXELS",
    "profile_level",
    "thin_indices",
    "reduce_message",
]


@dataclass(frozen=True)
class Level:
    """One level of detail.

    ``voxel``: edge of the thinning grid's cubes in metres (``None``: every
    point). ``image_quality``: camera images re-encoded as JPEG at this
    quality (``None``: as they are), their sides first divided by
    ``image_reduce`` (each pixel the mean of a block of ``image_reduce``
    by ``image_reduce``; a part block at an edge makes a pixel too).
    ``every``: a live session gets every ``every``-th update.
    ``share``: the part of a full update's bytes the level is expected to
    take before any of its updates were measured (from the KITTI drive).
    """

    name: str
    voxel: float | None = None
    image_reduce: int = 1
    image_quality: int | None = None
    every: int = 1
    share: float = 1.0


#: Every level, from the most detail to the least.
LEVELS: tuple[Level, ...] = (
    Level("full"),
    Level("high", voxel=0.15, image_quality=85, share=0.35),
    Level("medium", voxel=0.3, image_quality=70, share=0.15),
    Level("low", voxel=0.6, image_reduce=2, image_quality=60, share=0.065),
    Level("minimal", voxel=1.5, image_reduce=2, image_quality=50, share=0.02),
    Level("sparse", voxel=1.5, image_reduce=2, image_quality=50, every=2, share=0.02),
)
FULL = LEVELS[0]
_BY_NAME = {level.name: level for level in LEVELS}


#: ``profile`` values that leave the level to the server: streetscape.gl sends ``default``.
AUTO_PROFILES = ("auto", "default")


def profile_level(profile: str) -> Level | None:
    """The level a session's ``profile`` names, ``None`` for :data:`AUTO_PROFILES`.

    Raises :class:`ValueError` naming the profiles there are.
    """
    if profile in AUTO_PROFILES:
        return None
    level = _BY_NAME.get(profile)
    if level is None:
        shown = ", ".join(AUTO_PROFILES + tuple(_BY_NAME))
        raise ValueError(f"unknown profile {profile[:60]!r}; profiles: {shown}")
    return level


#: Larger camera images are sent as they are at every level (decoding them would take too long and too much memory).
MAX_IMAGE_PIXELS = 32 * 2**20

# Coordinates within this many voxels of the origin get exact keys (21 bits a coordinate).
_KEY_BITS = 21
_KEY_HALF = 1 << (_KEY_BITS - 1)
_HASH = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing's multiplier


def thin_indices(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices, ascending, of one point in each occupied cube of a grid of ``voxel`` metres.

    ``points`` is an ``(n, 3)`` array. Points beyond about a million
    voxels from the origin share the cubes at the grid's edge; a NaN
    coordinate counts as the grid's lowest. Of a run of points in the same
    cube (a lidar sweep's neighbours often are) only the first is looked at
    further; the cubes of those are told apart by an exact key through a
    hash table (numpy scatter and gather), without sorting: points whose
    slot another cube took go round again with another hash.
    """
    count = len(points)
    if count == 0:
        return np.arange(0, dtype=np.intp)
    keys = _cell_keys(np.asarray(points, dtype=np.float32), voxel)
    firsts = np.empty(count, dtype=bool)  # the first point of each run in one cube
    firsts[0] = True
    np.not_equal(keys[1:], keys[:-1], out=firsts[1:])
    pending = np.flatnonzero(firsts)
    bits = max(10, len(pending).bit_length() + 1)
    table = np.empty(1 << bits, dtype=np.intp)  # only slots written in a round are read in it
    kept = np.zeros(count, dtype=bool)
    for round_ in range(64):
        if not len(pending):
            break
        key = keys[pending]
        multiplier = _HASH + np.uint64(2 * round_)
        slots = ((key.view(np.uint64) * multiplier) >> np.uint64(64 - bits)).astype(np.intp)
        table[slots] = pending  # one point of those that share a slot wins it
        winner = table[slots]
        kept[winner] = True
        pending = pending[keys[winner] != key]  # another cube holds the slot: try again
    kept[pending] = True  # none left in practice; kept exact regardless
    return np.flatnonzero(kept)


def _cell_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """The key (21 bits a coordinate) of the grid cube each of ``points`` (float32, ``(n, 3)``) is in."""
    cells = points * np.float32(1.0 / voxel)
    np.floor(cells, out=cells)
    if not (cells.min() >= -_KEY_HALF and cells.max() < _KEY_HALF):  # so too with a NaN
        np.fmax(cells, -_KEY_HALF, out=cells)  # a NaN gives way to the bound
        np.fmin(cells, _KEY_HALF - 1, out=cells)
    cells += _KEY_HALF
    keys = cells[:, 0].astype(np.int64)  # column by column: fewer passes over the cloud than converting it whole
    keys <<= 2 * _KEY_BITS
    part = cells[:, 1].astype(np.int64)
    part <<= _KEY_BITS
    keys |= part
    np.copyto(part, cells[:, 2], casting="unsafe")
    keys |= part
    return keys


def _thin_cloud(cloud: dict[str, Any], voxel: float) -> dict[str, Any]:
    """A point primitive thinned (points as an ``(n, 3)`` array, or as the list of ``[x, y, z]`` of JSON)."""
    points = _as_array(cloud.get("points"))
    if points is None or points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        return cloud
    keep = thin_indices(points, voxel)
    if len(keep) == len(points):
        return cloud
    result = {**cloud, "points": np.take(points, keep, axis=0)}  # take: rows copied whole, faster than indexing
    colors = _as_array(cloud.get("colors"))
    if colors is not None and len(colors) == len(points):
        result["colors"] = np.take(colors, keep, axis=0)
    return result


def _as_array(value: Any) -> np.ndarray | None:
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, list):
        try:
            return np.asarray(value)
        except (ValueError, TypeError):  # ragged: not a cloud this can thin
            return None
    return None


def _reduce_image(image: dict[str, Any], level: Level) -> dict[str, Any]:
    """``image`` (an image primitive) re-encoded for ``level``."""
    data = image.get("data")
    if level.image_quality is None or not isinstance(data, (bytes, bytearray, memoryview)):
        return image
    picture = decode_image(data, MAX_IMAGE_PIXELS)
    if picture is None:
        return image
    width, height = picture.size
    if picture.mode not in ("RGB", "L"):  # JPEG holds no alpha, palette or 16-bit samples
        picture = picture.convert("RGB")
    if level.image_reduce != 1:
        picture = picture.reduce(level.image_reduce)
    out = io.BytesIO()
    picture.save(out, "JPEG", quality=level.image_quality)
    result = {**image, "data": out.getvalue()}
    # What the client shows the image as stays the size the full level says.
    result.setdefault("width_px", width)
    result.setdefault("height_px", height)
    return result


def _reduce_primitives(primitives: dict[str, Any], level: Level) -> dict[str, Any]:
    result = {}
    for name, state in primitives.items():
        if not isinstance(state, dict):
            result[name] = state
            continue
        changed = dict(state)
        if level.voxel is not None and isinstance(state.get("points"), list):
            changed["points"] = [_thin_cloud(c, level.voxel) if isinstance(c, dict) else c for c in state["points"]]
        if level.image_quality is not None and isinstance(state.get("images"), list):
            changed["images"] = [_reduce_image(i, level) if isinstance(i, dict) else i for i in state["images"]]
        result[name] = changed
    return result


def reduce_message(message: dict[str, Any], level: Level) -> dict[str, Any]:
    """A state-update envelope at ``level``; arrays it does not change are shared, not copied.

    Raises :class:`~xviz_server.exceptions.DecodeError` for an image that
    cannot be decoded.
    """
    if level.voxel is None and level.image_quality is None:
        return message
    updates = []
    for stream_set in message["data"].get("updates") or ():
        primitives = stream_set.get("primitives")
        if isinstance(primitives, dict) and primitives:
            stream_set = {**stream_set, "primitives": _reduce_primitives(primitives, level)}
        updates.append(stream_set)
    return {**message, "data": {**message["data"], "updates": updates}}
