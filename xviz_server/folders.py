"""Where a static log's bytes come from: a folder on disk or a prefix in an object store.

A :class:`Folder` lists a log's message files (named as
:mod:`xviz_server.layout` names them) and reads one whole file at a time.
The static-log provider reads through it and does not care which kind it
has; :class:`LocalFolder` is a directory, and
:class:`~xviz_server.store.StoreFolder` is a key prefix in a bucket.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

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
    """A log directory on disk; files are read in the I/O threads."""

    def __init__(self, directory: Path, workers: Workers) -> None:
        self.directory = directory
        self.read_ahead: ReadAhead | None = None
        self.location = str(directory)
        self._workers = workers

    async def files(self) -> dict[int, str]:
        return await self._workers.io(frame_files, self.directory)

    async def read(self, name: str) -> bytes:
        return await self._workers.io(_read_file, os.path.join(self.directory, name))

    def size(self, name: str) -> int | None:
        return None


def _read_file(path: str) -> bytes:
    with open(path, "rb") as stream:
        return stream.read()
