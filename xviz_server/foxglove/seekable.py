"""Each log as a file the Foxglove and Lichtblick apps seek in: a whole-log MCAP file, made once per version and kept.

``GET /api/logs/NAME/file.mcap`` answers with the log as an indexed, chunked
MCAP file holding what a whole-log export holds (see
:mod:`~xviz_server.foxglove.export`: the channels a Foxglove client is
offered, their messages at the XVIZ times), served with byte ranges (see
:mod:`xviz_server.ranges`). The apps open it by URL
(``?ds=remote-file&ds.url=...``) and read its summary, then only the chunks
that what they show needs: a seek costs a few chunks, not the file.

:class:`LogFiles` makes each file on first request and keeps it in a
folder (``files/`` in the state directory, else a temporary folder removed
when the server stops). A file is named by its log and its version: the
log's version on disk or in its store, its frame times, this server's
version and the channels' schemas, so that a log that changed, or a server
that converts differently, gets a new file, and the old one is removed. The
file is written frame by frame into a temporary file renamed into place once
complete (what a build holds in memory is a chunk of messages, whatever the
log's length); requests that come while it is made wait for that same build.
At most :data:`BUILDS` files are made at a time; the others wait their turn.

The folder holds at most ``limit`` bytes of files (``--files-gb``): once a
build has put it over, the files least recently asked for (their access time,
set at each request) are removed until it is under, never one being read
(from the request to the end of its answer, or of a ``HEAD``'s) nor the one
just made. A file removed is made again on its next request.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import shutil
import tempfile
import time
from collections import Counter
from collections.abc import AsyncGenerator, Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from ..logs import Log
from ..ranges import Representation
from ..version import __version__
from ..work import Workers
from .export import ExportRange, export, log_path
from .translate import Plan

__all__ = ["FILE_SUFFIX", "BUILDS", "READ_BYTES", "BuiltFile", "LogFiles", "file_path", "read_file"]

logger = logging.getLogger(__name__)

#: What ends the path of a log's file: ``/api/logs/NAME/file.mcap``.
FILE_SUFFIX = "/file.mcap"
#: Files made at a time: requests for more logs' files wait (each build takes a worker's CPU and the disk).
BUILDS = 2
#: What ends a file being written, before it is renamed into place.
_PARTIAL = ".part"


def file_path(path: str) -> str | None:
    """The log a file URL path (``/api/logs/NAME/file.mcap``, percent-decoded) names, or ``None``."""
    return log_path(path, FILE_SUFFIX)


@dataclass(frozen=True)
class BuiltFile:
    """A log's file, complete: where it is, and what an HTTP answer tells of it."""

    path: Path
    representation: Representation


class LogFiles:
    """The MCAP files of the logs, in ``folder`` (made if missing; ``None``: a temporary folder, removed by
    :meth:`close`), at most ``limit`` bytes of them (see the module's docstring)."""

    def __init__(self, folder: Path | None, workers: Workers, limit: int) -> None:
        self._given = folder
        self._folder: Path | None = folder
        self._workers = workers
        self._limit = limit
        self._building: dict[Path, asyncio.Task[BuiltFile]] = {}
        self._swept = False
        self._turns = asyncio.Semaphore(BUILDS)
        self._held: Counter[Path] = Counter()  # the files being read: answers under way
        self._lock = asyncio.Lock()  # taking a file to read, and removing files, one at a time

    async def get(self, log: Log, plan: Plan, version: str) -> BuiltFile:
        """The file of ``log`` at ``version`` (its version on disk or in its store), made now if it is not yet,
        held until :meth:`release` or the end of :meth:`read`: no file is removed while held.

        Raises what making it raises (a frame that cannot be read or
        converted: its :class:`~xviz_server.exceptions.XVIZError`; the disk:
        :class:`OSError`); the next request tries again.
        """
        folder = await self._workers.io(self._ready_folder)
        stem = _stem(log.name)
        path = (
            folder
            / f"{stem}-{_digest(version.encode(), log.index.start.tobytes(), __version__.encode(), repr(plan).encode())}.mcap"
        )
        for _ in range(3):  # another build may remove it before it is held: make it again
            task = self._building.get(path)  # no await from this look to the task's registration: one build a file
            if task is None:
                task = asyncio.ensure_future(self._find_or_build(log, plan, path, stem))
                self._building[path] = task
                task.add_done_callback(lambda _: self._building.pop(path, None))
            await asyncio.shield(task)
            async with self._lock:
                built = await self._workers.io(_used, path)
                if built is not None:
                    self._held[path] += 1
                    return built
        raise OSError(f"the files' folder is full: the file of log {log.name!r} was removed as soon as it was made")

    def release(self, built: BuiltFile) -> None:
        """Let a file :meth:`get` gave be removed again (its answer is sent, or will not be)."""
        self._held[built.path] -= 1
        if self._held[built.path] <= 0:
            del self._held[built.path]

    def read(
        self, built: BuiltFile, offset: int, length: int, count: Callable[[int], object]
    ) -> AsyncGenerator[bytes, None]:
        """:func:`read_file` of a file :meth:`get` gave, released once the pieces are closed, started or not."""
        return _Released(read_file(built.path, offset, length, self._workers, count), lambda: self.release(built))

    async def _evict(self, made: Path) -> None:
        """Remove the files least recently asked for until the folder is within its limit, but those held and
        ``made``."""
        async with self._lock:
            removed = await self._workers.io(_evict, made.parent, self._limit, {made, *self._held})
        for path in removed:
            logger.info("removed %s: the files' folder was over its %d bytes", path.name, self._limit)

    async def close(self) -> None:
        """Stop the builds under way (their temporary files removed); remove the folder if it was a temporary one."""
        for task in list(self._building.values()):
            task.cancel()
        await asyncio.gather(*self._building.values(), return_exceptions=True)
        if self._given is None and self._folder is not None:
            await self._workers.io(shutil.rmtree, self._folder, True)
            self._folder = None

    def _ready_folder(self) -> Path:
        """The folder, made on first use; files left half-written by a server that stopped are removed then (it blocks)."""
        if self._folder is None:
            self._folder = Path(tempfile.mkdtemp(prefix="xviz-files-"))
        elif not self._folder.is_dir():
            self._folder.mkdir(parents=True, exist_ok=True)
        if not self._swept:
            self._swept = True
            for partial in self._folder.glob(f"*{_PARTIAL}"):
                _remove(partial)
        return self._folder

    async def _find_or_build(self, log: Log, plan: Plan, path: Path, stem: str) -> BuiltFile:
        found = await self._workers.io(_built, path)
        if found is not None:
            return found
        async with self._turns:
            return await self._build(log, plan, path, stem)

    async def _build(self, log: Log, plan: Plan, path: Path, stem: str) -> BuiltFile:
        began = asyncio.get_running_loop().time()
        handle, partial = await self._workers.io(tempfile.mkstemp, _PARTIAL, f"{stem}-", str(path.parent))
        out: IO[bytes] = os.fdopen(handle, "wb")
        try:
            pieces = export(log, plan, ExportRange(None, None).frames(log), self._workers, strict=True)
            try:
                async for piece in pieces:
                    await self._workers.io(out.write, piece)
            finally:
                await pieces.aclose()
            await self._workers.io(_finish, out, Path(partial), path, stem)
        except BaseException:
            out.close()
            await self._workers.io(_remove, Path(partial))
            raise
        found = await self._workers.io(_built, path)
        assert found is not None
        logger.info(
            "made the file of log %r: %.1f MB in %.1f s",
            log.name,
            found.representation.size / 2**20,
            asyncio.get_running_loop().time() - began,
        )
        await self._evict(path)
        return found


def _stem(name: str) -> str:
    """The start of the file names of log ``name``: a digest (names may hold ``/`` and any character)."""
    return hashlib.blake2b(name.encode(), digest_size=10).hexdigest()


def _digest(*parts: bytes) -> str:
    """A digest of what names a version of a log's file."""
    digest = hashlib.blake2b(digest_size=12)
    for part in parts:
        digest.update(len(part).to_bytes(8, "little") + part)
    return digest.hexdigest()


def _built(path: Path) -> BuiltFile | None:
    """The file at ``path`` if it is there (it blocks)."""
    try:
        stat = path.stat()
    except FileNotFoundError:
        return None
    return BuiltFile(path, Representation(stat.st_size, f'"{path.stem.rpartition("-")[2]}"', stat.st_mtime))


def _used(path: Path) -> BuiltFile | None:
    """The file at ``path`` if it is there, its access time set to now: the time it was last asked for (it blocks)."""
    try:
        stat = path.stat()
        os.utime(path, ns=(time.time_ns(), stat.st_mtime_ns))  # its time of modification, which answers tell, kept
    except FileNotFoundError:
        return None
    return _built(path)


def _evict(folder: Path, limit: int, kept: Collection[Path]) -> list[Path]:
    """Remove files of ``folder``, least recently asked for first, but ``kept``, until they take at most ``limit``
    bytes; the files removed (it blocks)."""
    files = []
    for path in folder.glob("*.mcap"):
        try:
            files.append((path.stat(), path))
        except FileNotFoundError:
            continue
    total = sum(stat.st_size for stat, _ in files)
    removed = []
    for stat, path in sorted(files, key=lambda item: item[0].st_atime_ns):
        if total <= limit:
            break
        if path in kept:
            continue
        _remove(path)
        total -= stat.st_size
        removed.append(path)
    return removed


class _Released(AsyncGenerator[bytes, None]):
    """``pieces``, calling ``release`` once when closed, whether they were started or not (a generator that
    never started runs no ``finally``)."""

    def __init__(self, pieces: AsyncGenerator[bytes, None], release: Callable[[], None]) -> None:
        self._pieces, self._release = pieces, release

    async def asend(self, value: None) -> bytes:
        return await self._pieces.asend(value)

    async def athrow(self, *args: Any) -> bytes:
        return await self._pieces.athrow(*args)

    async def aclose(self) -> None:
        try:
            await self._pieces.aclose()
        finally:
            release, self._release = self._release, lambda: None
            release()


def _finish(out: IO[bytes], partial: Path, path: Path, stem: str) -> None:
    """Write ``out`` to disk, rename it to ``path``, and remove the log's other files (older versions; it blocks)."""
    with out:
        out.flush()
        os.fsync(out.fileno())
    os.replace(partial, path)
    for other in path.parent.glob(f"{stem}-*.mcap"):
        if other != path:
            _remove(other)


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass


#: Bytes of a file read and sent at a time.
READ_BYTES = 256 * 1024


async def read_file(
    path: Path, offset: int, length: int, workers: Workers, count: Callable[[int], object]
) -> AsyncGenerator[bytes, None]:
    """The bytes ``[offset, offset + length)`` of the file at ``path``, :data:`READ_BYTES` at a time, read in the I/O threads;
    ``count`` is called with the length of each piece.

    The file is opened at the first piece (an answer that is never sent opens
    nothing); one that is gone by then (a newer version of its log replaced
    it) raises :class:`FileNotFoundError`.
    """
    handle = await workers.io(os.open, path, os.O_RDONLY)
    try:
        end = offset + length
        while offset < end:
            piece = await workers.io(os.pread, handle, min(READ_BYTES, end - offset), offset)
            if not piece:
                raise EOFError(f"{path} ended at byte {offset}, before {end}")
            offset += len(piece)
            count(len(piece))
            yield piece
    finally:
        os.close(handle)
