"""Where a static log's bytes come from: a folder on disk or a prefix in an object store.

A :class:`Folder` lists a log's message files (named as
:mod:`xviz_server.layout` names them) and reads one whole file at a time.
The static-log provider reads through it and does not care which kind it
has; :class:`LocalFolder` is a directory, and
:class:`~xviz_server.store.StoreFolder` is a key prefix in a bucket.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import Protocol

from .frames import INLINE_BYTES
from .layout import frame_files
from .readahead import ReadAhead
from .work import Workers

__all__ = ["Folder", "LocalFolder"]


class Folder(Protocol):
    """The message files of one log."""

    #: Where the folder is, for messages: a path or an ``s3://`` URL.
    location: str
    #: How far a stream reads ahead from here; ``None`` leaves it to the server's ``read_ahead``.
    read_ahead: ReadAhead | None

    async def files(self) -> dict[int, str]:
        """Names of the message files by file number (see :func:`~xviz_server.layout.frame_files`).

        Raises :class:`OSError` when the folder cannot be listed.
        """
        ...

    async def read(self, name: str) -> bytes:
        """The whole file ``name``; raises :class:`OSError` (a :class:`~xviz_server.exceptions.StoreError` from a store)."""
        ...

    def size(self, name: str) -> int | None:
        """The size of file ``name`` as listed, if known without reading it."""
        ...


class LocalFolder:
    """A log directory on disk.

    A file of at most :data:`~xviz_server.frames.INLINE_BYTES` that is
    wholly in the page cache is read in the event loop, with a read that
    fails rather than wait for the disk (``RWF_NOWAIT``); any other file is
    read in the I/O threads. Opening the file stays in the loop: on a local
    file system it reads no data, but a cold directory may make it wait
    for one metadata read. A file system that cannot read without waiting
    (NFS, FUSE) is read in the threads from its first file on.
    """

    def __init__(self, directory: Path, workers: Workers) -> None:
        self.directory = directory
        self.read_ahead: ReadAhead | None = None
        self.location = str(directory)
        self._workers = workers
        self._read_cached = _NOWAIT is not None

    async def files(self) -> dict[int, str]:
        return await self._workers.io(frame_files, self.directory)

    async def read(self, name: str) -> bytes:
        path = os.path.join(self.directory, name)
        if self._read_cached:
            data, self._read_cached = _read_if_cached(path)
            if data is not None:
                return data
        return await self._workers.io(_read_file, path)

    def size(self, name: str) -> int | None:
        return None


_NOWAIT: int | None = getattr(os, "RWF_NOWAIT", None) if hasattr(os, "preadv") else None


def _read_if_cached(path: str) -> tuple[bytes | None, bool]:
    """The file at ``path`` if it is small and in the page cache, else ``None``; and whether its file system can say.

    Raises :class:`OSError`.
    """
    assert _NOWAIT is not None
    fd, size = _open_file(path)
    try:
        if size > INLINE_BYTES:
            return None, True
        buffer = bytearray(size + 1)  # a byte more: a file that grew since it was opened is read in a thread
        try:
            count = os.preadv(fd, [buffer], 0, _NOWAIT)
        except BlockingIOError:
            return None, True
        except OSError as exc:
            if exc.errno in (errno.EOPNOTSUPP, errno.EINVAL):
                return None, False
            raise
        return (bytes(buffer[:count]) if count == size else None), True
    finally:
        os.close(fd)


def _read_file(path: str) -> bytes:
    fd, _ = _open_file(path)
    with open(fd, "rb") as stream:
        return stream.read()


def _open_file(path: str) -> tuple[int, int]:
    """A descriptor of the regular file at ``path``, and its size; raises :class:`OSError` for anything else.

    Opened without waiting, so that a FIFO put in a frame's place holds no thread.
    """
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    try:
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode):
            raise OSError(errno.EINVAL, "not a regular file", path)
    except BaseException:
        os.close(fd)
        raise
    return fd, status.st_size
