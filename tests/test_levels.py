"""Levels of detail measured on the real KITTI frames: what each level sends, and how far it is from full detail."""

from __future__ import annotations

import io
import math
import struct
import zlib

import numpy as np
import pytest
from conftest import KITTI_LOG as KITTI
from PIL import Image, PngImagePlugin

from helpers import assert_same_message, require_data
from xviz_server import frames
from xviz_server.codec import Format, decode
from xviz_server.codec.image import decode_image
from xviz_server.exceptions import DecodeError
from xviz_server.levels import FULL, LEVELS, MAX_IMAGE_PIXELS, profile_level, thin_indices

FRAMES = [2, 14, 26]  # first, middle and last state update of the drive
LIDAR = "/lidar/points"
CAMERAS = ["/camera/image_00", "/camera/image_01", "/camera/image_02", "/camera/image_03"]
LEVEL = {level.name: level for level in LEVELS}

#: p99 of the distance from a full-detail point to the nearest point sent, metres, per level (stated in docs/links.md).
P99_METRES = {"high": 0.15, "medium": 0.28, "low": 0.55, "minimal": 1.35, "sparse": 1.35}


def frame(number: int) -> bytes:
    require_data()
    return (KITTI / f"{number}-frame.glb").read_bytes()


def stream_set(message: dict) -> dict:
    return message["data"]["updates"][0]


def cloud(message: dict) -> dict:
    return stream_set(message)["primitives"][LIDAR]["points"][0]


def nearest(sample: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance from each of ``sample`` to the nearest of ``points`` (all pairs, by chunks of ``points``)."""
    best = np.full(len(sample), np.inf)
    squares = (sample**2).sum(1)[:, None]
    for start in range(0, len(points), 8192):
        chunk = points[start : start + 8192]
        distances = squares + (chunk**2).sum(1)[None, :] - 2 * sample @ chunk.T
        best = np.minimum(best, distances.min(1))
    return np.sqrt(np.maximum(best, 0))


@pytest.mark.parametrize("number", FRAMES)
@pytest.mark.parametrize("level", LEVELS[1:], ids=lambda level: level.name)
def test_everything_but_points_and_images_is_what_full_detail_carries(number, level):
    full = decode(frame(number))
    reduced = decode(frames.render(frame(number), Format.BINARY, None, None, level))
    assert reduced["type"] == full["type"] and reduced["data"]["update_type"] == full["data"]["update_type"]
    kept, original = stream_set(reduced), stream_set(full)
    assert kept.keys() == original.keys()
    for key in original:
        if key != "primitives":
            assert_same_message(kept[key], original[key], f"$.{key}")
    assert kept["primitives"].keys() == original["primitives"].keys()
    for name, state in original["primitives"].items():
        if name != LIDAR and name not in CAMERAS:
            assert_same_message(kept["primitives"][name], state, f"$.primitives.{name}")
    # the cloud's other fields (its object id) too
    assert {k: v for k, v in cloud(reduced).items() if k not in ("points", "colors")} == {
        k: v for k, v in cloud(full).items() if k not in ("points", "colors")
    }


@pytest.mark.parametrize("number", [FRAMES[0], FRAMES[-1]])
def test_thinned_clouds_are_full_points_with_their_colours_and_keep_the_scene(number):
    full = cloud(decode(frame(number)))
    points, colors = full["points"], full["colors"]
    rng = np.random.default_rng(number)
    sample = points[rng.choice(len(points), 1000, replace=False)].astype(np.float64)
    counts = []
    for level in LEVELS[1:]:
        sent = cloud(decode(frames.render(frame(number), Format.BINARY, None, None, level)))
        keep = thin_indices(points, level.voxel)
        assert np.array_equal(sent["points"], points[keep]) and np.array_equal(sent["colors"], colors[keep])
        # one point in each occupied cube of the grid, no more
        cells = np.floor(points * np.float32(1 / level.voxel)).astype(np.int64)
        cells -= cells.min(0)
        assert len(keep) == len(np.unique((cells[:, 0] << 40) | (cells[:, 1] << 20) | cells[:, 2]))
        distance = nearest(sample, sent["points"].astype(np.float64))
        assert np.percentile(distance, 99) <= P99_METRES[level.name], level.name
        assert distance.max() <= level.voxel * math.sqrt(3) + 1e-4, level.name
        counts.append(len(keep))
    assert counts == sorted(counts, reverse=True) and counts[0] < len(points)


@pytest.mark.parametrize("level", LEVELS[1:], ids=lambda level: level.name)
def test_camera_images_are_jpeg_at_the_levels_size_and_close_to_the_original(level):
    full = stream_set(decode(frame(14)))["primitives"]
    reduced = stream_set(decode(frames.render(frame(14), Format.BINARY, None, None, level)))["primitives"]
    for name in CAMERAS:
        original, sent = full[name]["images"][0], reduced[name]["images"][0]
        before = Image.open(io.BytesIO(bytes(original["data"]))).convert("RGB")
        after = Image.open(io.BytesIO(bytes(sent["data"])))
        assert after.format == "JPEG"
        assert after.size == (-(-before.width // level.image_reduce), -(-before.height // level.image_reduce))
        assert (sent["width_px"], sent["height_px"]) == (original["width_px"], original["height_px"])
        shown = np.asarray(after.convert("RGB").resize(before.size), dtype=np.float64)
        assert np.abs(shown - np.asarray(before, dtype=np.float64)).mean() < 20
        assert len(sent["data"]) < len(original["data"]) / 3


def test_levels_get_smaller_and_full_is_the_frame_itself():
    data = frame(14)
    sizes = [len(frames.render(data, Format.BINARY, None, None, level)) for level in LEVELS]
    assert sizes[0] == len(data)
    distinct = [size for level, size in zip(LEVELS, sizes) if level.every == 1]
    assert distinct == sorted(distinct, reverse=True) and len(set(distinct)) == len(distinct)
    # each level's share, used before its size is measured, is within 2x of the truth on this drive
    for level, size in zip(LEVELS, sizes):
        assert 0.5 < (size / len(data)) / level.share < 2, level.name


def test_a_level_of_a_json_frame_is_json():
    data = frames.render(frame(14), Format.JSON, None)
    reduced = frames.render(data, Format.JSON, None, None, LEVEL["low"])
    assert reduced.startswith(b"{") and len(cloud(decode(reduced))["points"]) < len(cloud(decode(data))["points"])


def test_thinning_edge_cases():
    assert thin_indices(np.zeros((0, 3), np.float32), 0.5).tolist() == []
    same = np.zeros((5, 3), np.float32)
    assert len(thin_indices(same, 0.5)) == 1
    far = np.array([[-1e9, 0, 0], [1e9, 0, 0], [0, 0, 0], [0.1, 0, 0]], np.float32)
    assert len(thin_indices(far, 0.5)) == 3  # far points share the grid's edge cubes, each side its own
    broken = np.array([[np.nan, 0, 0], [0.1, 0, 0], [np.inf, 0, 0], [-np.inf, 0, 0]], np.float32)
    assert len(thin_indices(broken, 0.5)) == 3  # NaN and -inf at the grid's low edge, inf at its high one
    grid = np.stack(np.meshgrid(*[np.arange(40, dtype=np.float32)] * 3), -1).reshape(-1, 3) * 0.5 + 0.25
    assert len(thin_indices(grid, 0.5)) == len(grid)  # 64 000 cubes, each its own: hash collisions are resolved
    points = cloud(decode(frame(14)))["points"]
    shuffled = points[np.random.default_rng(3).permutation(len(points))]  # no runs of neighbours in one cube
    assert len(thin_indices(shuffled, 0.3)) == len(thin_indices(points, 0.3))


def test_a_camera_image_that_is_not_an_image_is_a_decode_error():
    message = decode(frame(14))
    stream_set(message)["primitives"]["/camera/image_00"]["images"][0]["data"] = b"\x89PNG not really"
    with pytest.raises(DecodeError, match="image cannot be decoded"):
        frames.render_message(message, Format.BINARY, None, None, LEVEL["low"])


def test_profiles():
    assert profile_level("default") is None and profile_level("auto") is None
    assert profile_level("full") is FULL and profile_level("low") is LEVEL["low"]
    with pytest.raises(ValueError, match=r"unknown profile 'ultra'; profiles: auto, default, full, high"):
        profile_level("ultra")


def chunk(kind: bytes, body: bytes) -> bytes:
    """A PNG chunk."""
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png(pixels: np.ndarray, filters: dict[int, int] | None = None, split: int = 8192, depth: int = 8) -> bytes:
    """A PNG of ``pixels`` ((H, W) grey, (H, W, 3) RGB, (H, W, 4) RGBA, uint8), written here: rows unfiltered
    but those ``filters`` names (row: 1, Sub), its data in IDAT chunks of ``split`` bytes."""
    height, width = pixels.shape[:2]
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    rows = pixels.reshape(height, width * channels)
    lines = []
    for y, line in enumerate(rows):
        kind = (filters or {}).get(y, 0)
        if kind == 1:  # Sub: each byte less the byte of the pixel before it
            line = line - np.concatenate([np.zeros(channels, np.uint8), line[:-channels]])
        lines.append(bytes([kind]) + line.astype(np.uint8).tobytes())
    data = zlib.compress(b"".join(lines), 6)
    colour = {1: 0, 3: 2, 4: 6}[channels]
    header = chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0))
    body = b"".join(chunk(b"IDAT", data[i : i + split]) for i in range(0, len(data), split))
    return b"\x89PNG\r\n\x1a\n" + header + body + chunk(b"IEND", b"")


def pillow(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)))


def camera_pngs() -> list[bytes]:
    primitives = stream_set(decode(frame(14)))["primitives"]
    return [bytes(primitives[name]["images"][0]["data"]) for name in CAMERAS]


def test_unfiltered_pngs_are_inflated_here_and_give_pillows_pixels():
    rng = np.random.default_rng(5)
    made = [
        png(rng.integers(0, 256, (37, 53), np.uint8)),
        png(rng.integers(0, 256, (37, 53, 4), np.uint8)),
        png(rng.integers(0, 256, (37, 53, 3), np.uint8), split=1),  # a chunk a byte
        png(rng.integers(0, 256, (37, 53, 3), np.uint8), split=1 << 20),  # one chunk
    ]
    for data in camera_pngs() + made:  # the KITTI drive's camera images are unfiltered PNGs
        picture = decode_image(data, MAX_IMAGE_PIXELS)
        assert not isinstance(picture, PngImagePlugin.PngImageFile)  # not decoded by Pillow
        assert np.array_equal(np.asarray(picture), pillow(data))


def test_other_images_are_decoded_by_pillow():
    rng = np.random.default_rng(6)
    pixels = rng.integers(0, 256, (37, 53, 3), np.uint8)
    by_pillow = io.BytesIO()
    Image.fromarray(pixels).save(by_pillow, "PNG", optimize=True)
    palette, deep = io.BytesIO(), io.BytesIO()
    Image.fromarray(pixels).convert("P").save(palette, "PNG")
    Image.fromarray(rng.integers(0, 65536, (37, 53), np.uint16)).save(deep, "PNG")  # 16 bits a pixel
    for data in [
        png(pixels, {0: 1}),  # the first row filtered: told at once
        png(pixels, {36: 1}),  # only the last
        by_pillow.getvalue(),
        palette.getvalue(),
        deep.getvalue(),
    ]:
        picture = decode_image(data, MAX_IMAGE_PIXELS)
        assert isinstance(picture, PngImagePlugin.PngImageFile)
        assert np.array_equal(np.asarray(picture), pillow(data))
    jpeg = io.BytesIO()
    Image.fromarray(pixels).save(jpeg, "JPEG")
    assert np.array_equal(np.asarray(decode_image(jpeg.getvalue(), MAX_IMAGE_PIXELS)), pillow(jpeg.getvalue()))


@pytest.mark.parametrize("mode", ["P", "I;16", "LA", "RGBA", "L", "1"])
def test_camera_images_of_any_mode_are_sent_as_jpeg_at_the_levels_size(mode):
    message = decode(frame(14))
    image = stream_set(message)["primitives"]["/camera/image_00"]["images"][0]
    original = Image.open(io.BytesIO(bytes(image["data"])))
    stored = io.BytesIO()
    original.convert("L").convert(mode).save(stored, "PNG")
    image["data"] = stored.getvalue()
    for level in (LEVEL["medium"], LEVEL["low"]):
        sent = stream_set(decode(frames.render_message(message, Format.BINARY, None, None, level)))["primitives"]
        after = Image.open(io.BytesIO(bytes(sent["/camera/image_00"]["images"][0]["data"])))
        assert after.format == "JPEG" and after.mode in ("RGB", "L")
        assert after.size == (-(-original.width // level.image_reduce), -(-original.height // level.image_reduce))


def test_a_broken_png_is_a_decode_error_or_what_pillow_makes_of_it():
    """Cut short, or a byte changed anywhere: a real camera image gives Pillow's pixels, or a DecodeError where Pillow fails."""
    original = camera_pngs()[2]
    rng = np.random.default_rng(7)
    broken = [original[:cut] for cut in (40, 60, 4000, len(original) // 2, len(original) - 20)]
    for offset in [*rng.integers(16, len(original), 40), 100, 120]:
        changed = bytearray(original)
        changed[offset] ^= 0xFF
        broken.append(bytes(changed))
    for data in broken:
        try:
            expected = pillow(data)
        except (OSError, ValueError, SyntaxError):
            with pytest.raises(DecodeError, match="image cannot be decoded"):
                decode_image(data, MAX_IMAGE_PIXELS)
        else:
            assert np.array_equal(np.asarray(decode_image(data, MAX_IMAGE_PIXELS)), expected)


def test_a_huge_camera_image_is_sent_as_it_is():
    side = 6000  # 36 million pixels, over MAX_IMAGE_PIXELS: only its header is read
    assert side * side > MAX_IMAGE_PIXELS
    rows = zlib.compress(bytes(side * (3 * side + 1)), 1)
    huge = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", rows)
        + chunk(b"IEND", b"")
    )
    message = decode(frame(14))
    stream_set(message)["primitives"]["/camera/image_00"]["images"][0]["data"] = huge
    reduced = decode(frames.render_message(message, Format.BINARY, None, None, LEVEL["low"]))
    assert bytes(stream_set(reduced)["primitives"]["/camera/image_00"]["images"][0]["data"]) == huge
    assert (
        Image.open(io.BytesIO(bytes(stream_set(reduced)["primitives"]["/camera/image_01"]["images"][0]["data"]))).format
        == "JPEG"
    )
