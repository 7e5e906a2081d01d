"""Decompression with a bound: compressed bytes from a recording never unpack to more than they declare, nor
to more than a documented limit.

A recording says how large each compressed part is once unpacked (a ROS 1
chunk's ``size`` field, an MCAP chunk's ``uncompressed_size``). That size
is checked against :data:`MAX_CHUNK_BYTES` before anything is decompressed,
and the decompressor is then asked for at most one byte more than it: a
part that unpacks to more than it declares (a decompression bomb whose
header lies) is refused after that many bytes, never unpacked whole. The
compressions recordings use (bz2, lz4 frames, zstd, zlib, gzip) are all read
through their incremental decompressors, which take such a bound.

What declares no size is bounded by a limit alone: a ROS 2 bag's message
compressed on its own (at most :data:`MAX_CHUNK_BYTES`), a ROS 2 bag's
storage file compressed whole (at most :data:`MAX_FILE_RATIO` times its
compressed size).

A part stored uncompressed (a TFRecord record) is read only if its declared
length fits in the file and in :data:`MAX_RECORD_BYTES`.

Whatever each part's size, one frame may read at most :data:`MAX_FRAME_BYTES`
in all, summed from what its parts declare before any is read (see
:func:`check_frame`); parts that declare no size (a Waymo frame's range
images) are counted as they unpack, on a :class:`FrameTally`.

A refusal is an :class:`~xviz_server.exceptions.OversizeError`; data that
is not what its compression says, or unpacks to fewer bytes than declared,
a :class:`~xviz_server.exceptions.DatasetError`. Both name the part.
"""

from __future__ import annotations

import bz2
import io
import threading
import zlib
from collections.abc import Callable
from typing import Any

from zlib_ng import zlib_ng

from .exceptions import DatasetError, FrameSizeError, OversizeError

__all__ = [
    "MAX_CHUNK_BYTES",
    "MAX_FRAME_BYTES",
    "check_frame",
    "FrameTally",
    "MAX_RECORD_BYTES",
    "MAX_FILE_RATIO",
    "COMPRESSIONS",
    "unpack",
    "unpack_unsized",
    "BoundedReader",
    "check_declared",
    "size_text",
    "zstd_module",
]

#: The most bytes one compressed part of a recording (a ROS 1 or MCAP chunk) may declare once unpacked.
#: Recorders write chunks of a few megabytes (rosbag 768 KiB, MCAP 4 MiB by default); a message larger than
#: that gets a chunk of its own, and a chunk this large holds several uncompressed 8K images.
MAX_CHUNK_BYTES = 256 << 20
#: The most bytes one frame of a recording may unpack, across all its messages and images: the sizes that the
#: parts it reads (chunks, rows) declare, summed before any is read. A frame of several lidars and cameras takes
#: tens of megabytes; a frame over this is refused whole, whatever each part's size.
MAX_FRAME_BYTES = 128 << 20
#: The most bytes of data one record of a TFRecord file (a Waymo frame, some megabytes) may declare.
MAX_RECORD_BYTES = 256 << 20
#: How many times its own size a whole compressed file of a recording (a ROS 2 bag's storage file, which
#: declares no size) may unpack to, and at least :data:`MAX_CHUNK_BYTES`: recordings compress a few times
#: at most, a bomb a thousand times and more.
MAX_FILE_RATIO = 100


def zstd_module() -> Any:
    """The zstd module: the standard library's from Python 3.14, else the backport rosbags installs."""
    try:
        from compression import zstd  # type: ignore[import-not-found]  # Python 3.14
    except ImportError:
        from backports import zstd  # installed with rosbags
    return zstd


def _zstd() -> Any:
    return zstd_module().ZstdDecompressor()


def _lz4() -> Any:
    import lz4.frame  # type: ignore[import-untyped]

    return lz4.frame.LZ4FrameDecompressor()


#: A new incremental decompressor for each compression, by the names ROS 1 and MCAP give them (and gzip files').
COMPRESSIONS: dict[str, Callable[[], Any]] = {
    "bz2": bz2.BZ2Decompressor,
    "lz4": _lz4,
    "zstd": _zstd,
    "zlib": zlib.decompressobj,
    "gzip": lambda: zlib_ng.decompressobj(16 + zlib.MAX_WBITS),  # zlib-ng: the same stream, inflated faster
}


def size_text(size: int) -> str:
    """``size`` bytes for a person: ``3.0 GiB``, ``256 MiB``, ``812 bytes``."""
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if size >= 1 << shift:
            value = size / (1 << shift)
            return f"{value:.0f} {unit}" if value == int(value) else f"{value:.1f} {unit}"
    return f"{size} bytes"


def _inflate(data: bytes | memoryview, compression: str, room: int, where: str) -> bytes:
    """At most ``room`` bytes of ``data`` decompressed, stream after stream."""
    make = COMPRESSIONS.get(compression)
    if make is None:
        raise DatasetError(f"{where}: compression {compression!r} is not supported; known: {', '.join(COMPRESSIONS)}")
    parts: list[bytes] = []
    rest = bytes(data)
    try:
        while rest and room > 0:
            decompressor = make()
            part = decompressor.decompress(rest, room)
            parts.append(part)
            room -= len(part)
            if not decompressor.eof:  # cut short, or stopped at the bound
                break
            rest = decompressor.unused_data
    except (OSError, ValueError, EOFError, RuntimeError, zlib.error, zlib_ng.error) as exc:  # type: ignore[misc]  # what each library raises on bad data (zlib-ng's stub declares its error an instance)
        raise DatasetError(f"{where}: not {compression} data: {exc}") from None
    return b"".join(parts)


def unpack_unsized(data: bytes | memoryview, compression: str, where: str, limit: int = MAX_CHUNK_BYTES) -> bytes:
    """``data`` decompressed with ``compression`` where nothing declares its size (a ROS 2 bag's message):
    at most ``limit`` bytes, else refused after that many."""
    out = _inflate(data, compression, limit + 1, where)
    if len(out) > limit:
        raise OversizeError(
            f"{where} unpacks to more than the limit of {size_text(limit)}: refused after {size_text(len(out))} "
            "(a damaged file or a decompression bomb)",
            size=len(out),
            limit=limit,
        )
    return out


class BoundedReader(io.RawIOBase):
    """A decompressing reader that refuses to give more than ``limit`` bytes (a stream that declares no size)."""

    def __init__(self, inner: Any, limit: int, where: str) -> None:
        super().__init__()
        self._inner, self._limit, self._where, self._given = inner, limit, where, 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        with memoryview(buffer) as view:
            data = self._inner.read(min(len(view), self._limit + 1 - self._given))
            view[: len(data)] = data
        self._given += len(data)
        if self._given > self._limit:
            raise OversizeError(
                f"{self._where} unpacks to more than the limit of {size_text(self._limit)} (a damaged file or a "
                "decompression bomb): refused",
                size=self._given,
                limit=self._limit,
            )
        return len(data)

    def close(self) -> None:
        self._inner.close()
        super().close()


def check_frame(declared: int, frame: int, where: str, path: object = None) -> None:
    """Refuse frame ``frame`` unread if its parts declare more than :data:`MAX_FRAME_BYTES` in all: a
    :class:`~xviz_server.exceptions.FrameSizeError` naming ``where``."""
    if declared > MAX_FRAME_BYTES:
        raise FrameSizeError(
            f"{where}: frame {frame}: its messages and images would unpack {size_text(declared)}, more than the "
            f"limit of {size_text(MAX_FRAME_BYTES)} for one frame: refused unread",
            size=declared,
            limit=MAX_FRAME_BYTES,
            frame=frame,
            path=path,
        )


class FrameTally:
    """What frame ``frame`` has unpacked so far in all, for parts that declare no size: counted as they unpack,
    from threads side by side, starting from ``spent`` (what its parts declared and :func:`check_frame` let
    through).

    :meth:`take` raises a :class:`~xviz_server.exceptions.FrameSizeError` naming ``where`` once the count passes
    :data:`MAX_FRAME_BYTES`.
    """

    def __init__(self, spent: int, frame: int, where: str, path: object = None) -> None:
        self.spent, self._frame, self._where, self._path = spent, frame, where, path
        self._lock = threading.Lock()

    def take(self, size: int) -> None:
        """Count ``size`` more bytes unpacked; refuse the frame if that passes the limit."""
        with self._lock:
            self.spent += size
            spent = self.spent
        if spent > MAX_FRAME_BYTES:
            raise FrameSizeError(
                f"{self._where}: frame {self._frame}: its messages and images unpack more than the limit of "
                f"{size_text(MAX_FRAME_BYTES)} for one frame: refused after {size_text(spent)}",
                size=spent,
                limit=MAX_FRAME_BYTES,
                frame=self._frame,
                path=self._path,
            )


def check_declared(declared: int, where: str, limit: int = MAX_CHUNK_BYTES) -> None:
    """Refuse a part that declares more than ``limit`` bytes unpacked, before anything is read or unpacked.

    ``where`` names it (``FILE: chunk at byte N``).
    """
    if declared > limit:
        raise OversizeError(
            f"{where} declares {size_text(declared)} uncompressed, more than the limit of {size_text(limit)}: "
            "refused unread (a damaged file or a decompression bomb)",
            size=declared,
            limit=limit,
        )


def unpack(
    data: bytes | memoryview, compression: str, declared: int, where: str, limit: int = MAX_CHUNK_BYTES
) -> bytes:
    """``data`` decompressed with ``compression`` (``""`` or ``none``: as it is); it must unpack to exactly
    ``declared`` bytes, at most ``limit``.

    Several compressed streams one after another (as ``bzip2`` and ``zstd``
    write them) are read in turn, within the same bound.
    """
    check_declared(declared, where, limit)
    out = bytes(data) if compression in ("", "none") else _inflate(data, compression, declared + 1, where)
    if len(out) > declared:
        raise OversizeError(
            f"{where} unpacks to more than the {size_text(declared)} it declares: refused after "
            f"{size_text(len(out))} (a decompression bomb)",
            size=len(out),
            limit=declared,
        )
    if len(out) < declared:
        raise DatasetError(
            f"{where} unpacks to {len(out)} bytes, not the {declared} it declares: it is cut short or damaged"
        )
    return out
