"""Hostile recordings played against the real server, run as its own process (issue 35, finding 1).

Real bags written with rosbags' writers from the KITTI excerpt are made into decompression bombs: one chunk's data
replaced by a bomb that unpacks to hundreds of MiB while its header declares the chunk's true size (the header
lies), or the header declaring 3 GiB. The server must refuse each with an error naming the file and the chunk, list
the log with that error in ``GET /api/logs``, send it to a session as ``xviz/error``, keep ``/healthz`` ok and the
other logs served, and no process of it (the server or a worker) may grow by more than a bound while it does.
"""

from __future__ import annotations

import asyncio
import bz2
import sqlite3
import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import lz4.frame
import numpy as np
import pytest
from websockets.asyncio.client import connect

from devkit.rosbag_kitti import RAW, write_bag
from helpers import GROWTH, Client, served, write_log
from xviz_server.codec import edit_glb
from xviz_server.datasets.kitti import KittiDrive
from xviz_server.datasets.waymo.tfrecord import masked_crc
from xviz_server.exceptions import DatasetError
from xviz_server.unpack import MAX_CHUNK_BYTES

#: Servers unpacking hundreds of MB of bombs, their memory measured: each test many seconds on 2 cores.
pytestmark = pytest.mark.slow

FRAMES = 4
BOMB = 512 << 20  # bytes a bomb unpacks to
LIES = 3 << 30  # bytes a header declares
_MiB = 1 << 20


# -- bombs ---------------------------------------------------------------------


def _zeros(compressor: Any, total: int, step: int = 16 * _MiB) -> bytes:
    """``total`` zero bytes through a streaming compressor, ``step`` at a time (never all in memory)."""
    out, zero = [], bytes(step)
    for _ in range(total // step):
        out.append(compressor.compress(zero))
    out.append(compressor.flush())
    return b"".join(out)


def bz2_bomb(total: int = BOMB) -> bytes:
    """Streams of 16 MiB of zeros one after another, as bzip2 writes them: bz2.decompress reads them all."""
    stream = bz2.compress(bytes(16 * _MiB), 9)
    return stream * (total // (16 * _MiB))


def lz4_bomb(total: int) -> bytes:
    compressor = lz4.frame.LZ4FrameCompressor()
    return compressor.begin() + _zeros(compressor, total)


def zstd_bomb(total: int = BOMB) -> bytes:
    from backports import zstd

    return _zeros(zstd.ZstdCompressor(), total)


def ros1_records(data: bytes) -> Iterator[tuple[int, dict[bytes, tuple[int, int]], int, int]]:
    """Each record of a ROS 1 bag: its offset, its header's fields (where each value is), its data's offset and length."""
    position = len(b"#ROSBAG V2.0\n")
    while position < len(data):
        (header_length,) = struct.unpack_from("<I", data, position)
        fields, at = {}, position + 4
        while at < position + 4 + header_length:
            (size,) = struct.unpack_from("<I", data, at)
            name, _, _ = data[at + 4 : at + 4 + size].partition(b"=")
            fields[name] = (at + 4 + len(name) + 1, at + 4 + size)
            at += 4 + size
        (data_length,) = struct.unpack_from("<I", data, at)
        yield position, fields, at + 4, data_length
        position = at + 4 + data_length


def ros1_bomb(bag: Path, bomb: bytes | None) -> tuple[bytes, int]:
    """``bag`` with its largest chunk's data replaced by ``bomb`` (padded to its length), or, with no bomb, that
    chunk's header declaring :data:`LIES` bytes; and the chunk's offset."""
    data = bytearray(bag.read_bytes())
    chunks = [
        (length, position, fields, start)
        for position, fields, start, length in ros1_records(bytes(data))
        if data[fields[b"op"][0]] == 0x05
    ]
    length, position, fields, start = max(chunks)
    if bomb is None:
        at, end = fields[b"size"]
        data[at:end] = struct.pack("<I", LIES)
    else:
        assert len(bomb) <= length, f"a bomb of {len(bomb)} bytes does not fit in a chunk of {length}"
        data[start : start + length] = bomb.ljust(length, b"\0")
    return bytes(data), position


def mcap_records(data: bytes) -> Iterator[tuple[int, int, int]]:
    """Each record of an MCAP file: its opcode, its offset and its content's offset."""
    position = 8
    while position + 9 <= len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, position)
        yield opcode, position, position + 9
        position += 9 + length


def _string(data: bytes, at: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", data, at)
    return data[at + 4 : at + 4 + size].decode(), at + 4 + size


def mcap_bomb(mcap: Path, bomb: bytes | None, compression: str = "zstd") -> tuple[bytes, int]:
    """``mcap`` with its largest chunk's data replaced by ``bomb`` compressed with ``compression`` (the chunk and its
    index say so; the record keeps its length), or, with no bomb, the chunk and its index declaring :data:`LIES`
    bytes uncompressed; and the chunk's offset."""
    data = bytearray(mcap.read_bytes())
    chunks = {position: content for opcode, position, content in mcap_records(bytes(data)) if opcode == 0x06}
    indexes = [content for opcode, _, content in mcap_records(bytes(data)) if opcode == 0x08]
    sizes = {position: struct.unpack_from("<Q", data, position + 1)[0] for position in chunks}
    position = max(sizes, key=sizes.__getitem__)
    content = chunks[position]
    index = next(i for i in indexes if struct.unpack_from("<Q", data, i + 16)[0] == position)
    (offsets_length,) = struct.unpack_from("<I", data, index + 32)
    after_offsets = index + 36 + offsets_length + 8  # message index offsets, then their length
    old, at = _string(bytes(data), after_offsets)
    if bomb is None:
        struct.pack_into("<Q", data, content + 16, LIES)
        struct.pack_into("<Q", data, at + 8, LIES)
        return bytes(data), position
    # The chunk: times and uncompressed size as they were, no CRC, then the compression, the bomb and padding.
    record_end = content + sizes[position]
    name = compression.encode()
    head = bytes(data[content : content + 24]) + struct.pack("<I", 0) + struct.pack("<I", len(name)) + name
    body = head + struct.pack("<Q", len(bomb)) + bomb
    assert len(body) <= record_end - content, (
        f"a bomb of {len(bomb)} bytes does not fit in a chunk of {sizes[position]}"
    )
    data[content:record_end] = body.ljust(record_end - content, b"\0")
    # Its index: the same, with the compression and the compressed size changed; a byte of padding where the name is
    # shorter (readers skip what a record has after its fields).
    (uncompressed,) = struct.unpack_from("<Q", data, at + 8)
    tail = struct.pack("<I", len(name)) + name + struct.pack("<QQ", len(bomb), uncompressed)
    end = at + 16
    assert len(tail) <= end - after_offsets
    data[after_offsets:end] = tail.ljust(end - after_offsets, b"\0")
    assert old == "zstd"
    return bytes(data), position


# -- fixtures ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def bags(shared_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Real bags of the KITTI excerpt: ROS 1 with bz2 and with lz4 chunks, MCAP with zstd chunks."""
    root, drive = tmp_path_factory.mktemp("bags"), KittiDrive(shared_dir / "data" / RAW)
    return {
        # bz2 unpacks slowly, and GET /api/logs opens every log within the HTTP handshake's time limit: fewer frames.
        "bz2": write_bag(root / "bz2.bag", "ros1", drive=drive, frames=2, compression="bz2"),
        "lz4": write_bag(root / "lz4.bag", "ros1", drive=drive, frames=FRAMES, compression="lz4"),
        "zstd": write_bag(root / "zstd.mcap", "mcap", drive=drive, frames=FRAMES, compression="zstd"),
    }


def _bombs() -> dict[str, tuple[str, str, Callable[[dict[str, Path]], tuple[bytes, int]]]]:
    """Each hostile bag: its suffix, what the error says, and how it is made from the real bags."""
    return {
        "ros1-bz2-lies": (".bag", "unpacks to more than", lambda b: ros1_bomb(b["bz2"], bz2_bomb())),
        "ros1-bz2-declares": (".bag", "declares 3 GiB", lambda b: ros1_bomb(b["bz2"], None)),
        "ros1-lz4-lies": (".bag", "unpacks to more than", lambda b: ros1_bomb(b["lz4"], lz4_bomb(320 * _MiB))),
        "mcap-zstd-lies": (".mcap", "unpacks to more than", lambda b: mcap_bomb(b["zstd"], zstd_bomb())),
        "mcap-zstd-declares": (".mcap", "declares 3 GiB", lambda b: mcap_bomb(b["zstd"], None)),
        "mcap-lz4-lies": (".mcap", "unpacks to more than", lambda b: mcap_bomb(b["zstd"], lz4_bomb(320 * _MiB), "lz4")),
    }


BOMBS = _bombs()


@pytest.mark.parametrize("bomb", sorted(BOMBS))
async def test_a_bomb_in_a_bag_is_refused_named_and_the_server_stays_small(
    bomb: str, bags: dict[str, Path], tmp_path: Path
):
    suffix, says, make = BOMBS[bomb]
    root = tmp_path / "data"
    root.mkdir()
    data, chunk = make(bags)
    (root / f"bomb{suffix}").write_bytes(data)
    (root / "good.bag").write_bytes(bags["lz4"].read_bytes())
    async with served(root) as server:
        good = await server.session("good")  # the workers are up and warm
        assert [m for m in good if m["type"] == "xviz/state_update"] and not [
            m for m in good if m["type"] == "xviz/error"
        ]
        before = server.rss()
        logs, healthy, again = await asyncio.gather(server.logs(), server.get("/healthz"), server.session("good"))
        assert healthy == (200, "ok\n")
        assert not [m for m in again if m["type"] == "xviz/error"]
        # The chunk is refused where it is first read: opening the bag (listing it) or playing it.
        errors = [logs["bomb"].get("error", "")] + [
            m["data"]["message"] for m in await server.session("bomb") if m["type"] == "xviz/error"
        ]
        named = f"log 'bomb': chunk at byte {chunk} {says}"  # the log's name and the cause, not the file's path
        assert any(named in error for error in errors), errors
        assert await server.get("/healthz") == (200, "ok\n")
        assert not [m for m in await server.session("good") if m["type"] == "xviz/error"]
        peaks = server.peaks()
        grown = {pid: peaks[pid] - rss for pid, rss in before.items() if pid in peaks}
        assert max(grown.values()) < GROWTH, {pid: f"{g / _MiB:.0f} MiB" for pid, g in grown.items()}


async def test_a_chunk_declared_larger_than_the_limit_is_refused_when_the_bag_opens(
    bags: dict[str, Path], tmp_path: Path
):
    from xviz_server.datasets.ros.bag import Bag
    from xviz_server.exceptions import OversizeError

    data, chunk = ros1_bomb(bags["bz2"], None)
    (tmp_path / "x.bag").write_bytes(data)
    with pytest.raises(OversizeError) as refused:
        Bag(tmp_path / "x.bag")
    assert refused.value.size == LIES and refused.value.limit == MAX_CHUNK_BYTES
    assert str(refused.value).startswith(
        f"{tmp_path / 'x.bag'}: chunk at byte {chunk} declares 3 GiB uncompressed, more than the limit of 256 MiB"
    )


def _varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    return bytes(out + bytes([value]))


def tfrecord_header(length: int) -> bytes:
    size = struct.pack("<Q", length)
    return size + struct.pack("<I", masked_crc(size))


async def test_tfrecords_with_a_huge_length_or_deep_nesting_are_refused_named(bags: dict[str, Path], tmp_path: Path):
    root = tmp_path / "data"
    root.mkdir()
    stamp = _varint(2 << 3) + _varint(1_500_000_000_000_000)  # Frame.timestamp_micros: the record is a frame
    with open(root / "huge.tfrecord", "wb") as file:  # declares 3 GiB, and the (sparse) file holds them
        file.write(tfrecord_header(LIES) + stamp)
        file.truncate(16 + LIES)
    deep = stamp + _varint(999 << 3 | 3) * 200_000  # groups in groups, 200 000 deep
    (root / "deep.tfrecord").write_bytes(tfrecord_header(len(deep)) + deep + struct.pack("<I", masked_crc(deep)))
    (root / "good.bag").write_bytes(bags["lz4"].read_bytes())
    async with served(root) as server:
        await server.session("good")
        before = server.rss()
        logs = await server.logs()
        huge, deep_session, good = await asyncio.gather(
            server.session("huge"), server.session("deep"), server.session("good")
        )
        for log, session, says in (
            ("huge", huge, "declares 3 GiB of data, more than the limit of 256 MiB"),
            ("deep", deep_session, "not a Waymo Frame"),
        ):
            errors = [logs[log]["error"]] + [m["data"]["message"] for m in session if m["type"] == "xviz/error"]
            assert all(f"log '{log}': record 0 at offset 0: {says}" in error for error in errors), errors  # no path
        assert not [m for m in good if m["type"] == "xviz/error"] and await server.get("/healthz") == (200, "ok\n")
        peaks = server.peaks()
        assert max(peaks[pid] - rss for pid, rss in before.items() if pid in peaks) < GROWTH


async def test_sessions_each_opening_a_different_bag_at_once_keep_the_server_bounded(
    bags: dict[str, Path], tmp_path: Path
):
    """Six sessions open six different bags at the same moment (scripts/bench/bomb_sessions.py plays 30): every frame
    is played, /healthz answers meanwhile, and no process grows by more than the bound (the server's frame cache
    holds the frames played: 24 frames of a few MB)."""
    root = tmp_path / "data"
    root.mkdir()
    for number in range(6):
        (root / f"drive-{number}.bag").write_bytes(bags["lz4"].read_bytes())
    async with served(root) as server:
        await server.session("drive-0")
        before = server.rss()
        storm = asyncio.gather(*(server.session(f"drive-{number}") for number in range(6)))
        assert await server.get("/healthz") == (200, "ok\n")
        played = await storm
        assert [sum(m["type"] == "xviz/state_update" for m in messages) for messages in played] == [FRAMES] * 6
        peaks = server.peaks()
        grown = {pid: peaks[pid] - rss for pid, rss in before.items() if pid in peaks}
        assert max(grown.values()) < GROWTH, {pid: f"{g / _MiB:.0f} MiB" for pid, g in grown.items()}


async def test_a_static_frame_whose_cloud_is_referenced_many_times_is_refused_named(kitti_log: Path, tmp_path: Path):
    """A GLB frame of a static log that references one 600 KB cloud 500 times: a few KB more on disk, 290 MiB of
    arrays (and a JSON text of gigabytes) when re-encoded for a JSON client."""
    cloud = np.zeros((50_000, 3), dtype=np.float32)
    data = {
        "update_type": "SNAPSHOT",
        "updates": [{"timestamp": 100.0, "primitives": {"/points": {"points": [{"points": cloud}]}}}],
    }

    def reference_it_500_times(message: Any) -> Any:
        stream = message["data"]["updates"][0]["primitives"]["/points"]
        stream["points"] = stream["points"] * 500
        return message

    root = tmp_path / "data"
    write_log(root / "amplified", [data, data])
    frame = root / "amplified" / "2-frame.glb"
    frame.write_bytes(edit_glb(frame.read_bytes(), reference_it_500_times))
    (root / "kitti").symlink_to(kitti_log)
    async with served(root) as server:
        await server.session("kitti")
        before = server.rss()
        async with connect(
            f"ws://127.0.0.1:{server.port}/?log=amplified&message_format=JSON", max_size=None
        ) as websocket:
            viewer = Client(websocket)
            assert (await viewer.recv(60))["type"] == "xviz/metadata"
            await viewer.send("transform_log", {"id": "all"})
            played = await viewer.until("transform_log_done", "all", timeout=120)
        errors = [m["data"]["message"] for m in played if m["type"] == "xviz/error"]
        assert (
            len(errors) == 1
            and "(2-frame.glb) of log 'amplified' is corrupt: state update expands to 286.1 MiB" in errors[0]
        ), errors
        assert len([m for m in played if m["type"] == "xviz/state_update"]) == 1
        assert await server.get("/healthz") == (200, "ok\n")
        peaks = server.peaks()
        assert max(peaks[pid] - rss for pid, rss in before.items() if pid in peaks) < GROWTH


def test_an_mcap_file_without_a_summary_is_read_through_within_the_bound(bags: dict[str, Path], tmp_path: Path):
    """Such a file is read through at open, each chunk unpacked within the same bound."""
    from xviz_server.datasets.ros.bag import open_bag

    data, _ = mcap_bomb(bags["zstd"], None)
    (data_end,) = [position for opcode, position, _ in mcap_records(data) if opcode == 0x0F]
    footer = struct.pack("<BQQQI", 0x02, 20, 0, 0, 0)  # no summary
    (tmp_path / "x.mcap").write_bytes(data[: data_end + 9 + 4] + footer + b"\x89MCAP0\r\n")
    with pytest.raises(
        DatasetError, match=f"^{tmp_path / 'x.mcap'}: chunk at byte [0-9]+ declares 3 GiB uncompressed, more "
    ):
        open_bag(tmp_path / "x.mcap")


@pytest.mark.parametrize("mode", ["message", "file"])
async def test_a_ros2_bag_compressed_per_message_or_per_file_unpacks_within_the_bound(
    mode: str, shared_dir: Path, bags: dict[str, Path], tmp_path: Path
):
    """rosbags unpacks these itself, declaring no size: a message at most MAX_FRAME_BYTES, a file 100 times its size."""
    root = tmp_path / "data"
    root.mkdir()
    folder = write_bag(
        root / "bomb", "sqlite3", drive=KittiDrive(shared_dir / "data" / RAW), frames=2, compression="zstd", mode=mode
    )
    if mode == "message":  # the largest message becomes a bomb
        with sqlite3.connect(next(folder.glob("*.db3"))) as database:
            (largest,) = database.execute("SELECT id FROM messages ORDER BY length(data) DESC LIMIT 1").fetchone()
            database.execute("UPDATE messages SET data = ? WHERE id = ?", (zstd_bomb(), largest))
        says = "a ROS 2 bag's message compressed with zstd unpacks to more than the limit of 128 MiB"
    else:  # the storage file becomes a bomb
        [storage] = folder.glob("*.zstd")
        storage.write_bytes(zstd_bomb())
        says = f"{storage.name} (compressed with zstd) unpacks to more than the limit of 256 MiB"
    (root / "good.bag").write_bytes(bags["lz4"].read_bytes())
    async with served(root) as server:
        assert not [m for m in await server.session("good") if m["type"] == "xviz/error"]
        before = server.rss()
        logs = await server.logs()
        errors = [logs["bomb"].get("error", "")] + [
            m["data"]["message"] for m in await server.session("bomb") if m["type"] == "xviz/error"
        ]
        assert any(says in error for error in errors), errors
        assert await server.get("/healthz") == (200, "ok\n")
        assert not [m for m in await server.session("good") if m["type"] == "xviz/error"]
        peaks = server.peaks()
        grown = {pid: peaks[pid] - rss for pid, rss in before.items() if pid in peaks}
        # The server process never unpacks; a worker holds at most the limit while it refuses it, twice over (the
        # decompressor's buffer and the bytes made of it).
        assert grown[server.process.pid] < GROWTH, grown
        assert max(grown.values()) < 2 * MAX_CHUNK_BYTES + GROWTH, {
            pid: f"{g / _MiB:.0f} MiB" for pid, g in grown.items()
        }
