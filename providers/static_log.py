"""Static logs: folders of pre-encoded frames in the reference layout.

A log folder (see :mod:`xviz_server.layout`) holds the index, the
metadata message and one file per state update, as JSON, GLB or protobuf
(PBE); it is a directory or a prefix in an object store (see
:mod:`xviz_server.folders`). PBE frames are served as GLB: each is
transcoded when read, and the frame cache keeps the GLB.

An index that is missing, unreadable, disagrees with the frame files or
whose times go back from a frame to the next is rebuilt by reading every
frame once; the rebuilt index is kept while the log is open.
"""

from __future__ import annotations

import logging
from typing import Any

import orjson

from ..codec import Format, decode, detect_format, is_pbe
from ..exceptions import DecodeError, FrameError, LogError, MessageError
from ..folders import Folder, LocalFolder
from ..frames import placement, render, span
from ..layout import INDEX_FILE, INDEX_NUMBER, METADATA_NUMBER, Found, file_number, frame_name, frame_numbers
from ..messages import unwrap
from ..readahead import ReadAhead
from ..timeindex import TimeIndex
from ..work import Workers

__all__ = ["StaticLogProvider", "StaticLog", "FORMATS", "read_metadata", "index_problem"]

logger = logging.getLogger(__name__)

#: The format a log is served in, by the suffix of its metadata file.
FORMATS = {"json": Format.JSON, "glb": Format.BINARY, "pbe": Format.BINARY}


def read_metadata(name: str, file: str, data: bytes) -> dict[str, Any]:
    """The content of the metadata message ``data`` (the file ``file`` of log ``name``); raises :class:`LogError`."""
    try:
        kind, content = unwrap(decode(data))
    except (DecodeError, MessageError) as exc:
        raise LogError(f"log {name!r}: {file} is not a readable XVIZ message: {exc}", log=name) from None
    if kind != "xviz/metadata" or not isinstance(content, dict):
        raise LogError(f"log {name!r}: {file} holds {kind!r}, not xviz/metadata", log=name)
    return content


def index_problem(index: TimeIndex, files: dict[int, str]) -> str | None:
    """Why a log's stored index cannot serve with the message files ``files`` (by file number), or ``None``."""
    frames = set(frame_numbers(files))
    if set(index.frames.tolist()) != frames:
        return f"{INDEX_FILE} names {len(index)} frames but the directory has {len(frames)}"
    if not index.in_frame_order:
        return f"the times of {INDEX_FILE} are not in frame order"
    return None


class StaticLogProvider:
    """Opens log folders."""

    def __init__(self, workers: Workers) -> None:
        self._workers = workers

    async def open(self, found: Found) -> StaticLog:
        return await self.open_folder(found.name, LocalFolder(found.path, self._workers))

    async def open_folder(self, name: str, folder: Folder) -> StaticLog:
        """Open the log ``name`` held by ``folder`` (on disk or in an object store)."""
        try:
            files = await folder.files()
        except OSError as exc:
            raise LogError(f"log {name!r}: cannot list {folder.location}: {exc.strerror or exc}", log=name) from None
        return StaticLog(name, folder, files, self._workers)


class StaticLog:
    """One log folder."""

    def __init__(self, name: str, folder: Folder, files: dict[int, str], workers: Workers) -> None:
        self.name = name
        self.folder = folder
        self._files = files
        self._workers = workers
        metadata_file = files.get(METADATA_NUMBER)
        if metadata_file is None:
            raise LogError(
                f"log {name!r} has no metadata file (1-frame.glb, 1-frame.json or 1-frame.pbe) in {folder.location}",
                log=name,
            )
        self.format = FORMATS[metadata_file.rpartition(".")[2]]

    @property
    def read_ahead(self) -> ReadAhead | None:
        """How far a stream reads ahead of this log (its folder's say), if not the server's default."""
        return self.folder.read_ahead

    def stored_size(self, frame: int) -> int | None:
        """The size of frame ``frame``'s file as listed, if known before reading it."""
        file = self._files.get(file_number(frame))
        return None if file is None else self.folder.size(file)

    async def _read(self, number: int) -> bytes:
        file = self._files.get(number)
        if file is None:
            raise FileNotFoundError(f"{number}-frame file missing")
        return await self.folder.read(file)

    async def metadata(self) -> dict[str, Any]:
        file = self._files[METADATA_NUMBER]
        try:
            data = await self._read(METADATA_NUMBER)
        except OSError as exc:
            raise LogError(f"log {self.name!r}: cannot read {file}: {exc.strerror or exc}", log=self.name) from None
        return await self._workers.io(read_metadata, self.name, file, data)

    async def index(self) -> TimeIndex:
        index = await self._stored_index()
        if index is not None:
            return index
        return await self._build_index(frame_numbers(self._files))

    async def _stored_index(self) -> TimeIndex | None:
        """The log's ``0-frame.json``, when it is readable and names the frame files there are."""
        if self._files.get(INDEX_NUMBER) != INDEX_FILE:
            return None
        try:
            data = await self._read(INDEX_NUMBER)
            index = await self._workers.io(lambda: TimeIndex.from_reference(orjson.loads(data)))
        except (OSError, orjson.JSONDecodeError, DecodeError) as exc:
            logger.warning(
                "log %r: ignoring unreadable %s (%s); rebuilding it from the frames", self.name, INDEX_FILE, exc
            )
            return None
        problem = index_problem(index, self._files)
        if problem is not None:
            logger.warning("log %r: %s; rebuilding it from the frames", self.name, problem)
            return None
        return index

    async def _build_index(self, frames: list[int]) -> TimeIndex:
        spans = []
        for frame in frames:
            try:
                data = await self.read(frame)
                start, end = await self._workers.run(placement(len(data), detect_format(data)), span, data)
            except (FrameError, DecodeError) as exc:
                logger.warning("log %r: frame %d left out of the index: %s", self.name, frame, exc)
                continue
            spans.append((start, end, frame))
        return TimeIndex.from_spans(spans)

    async def read(self, frame: int) -> bytes:
        name = self.describe_frame(frame)
        try:
            data = await self._read(file_number(frame))
        except OSError as exc:
            raise FrameError(
                f"cannot read frame {frame} ({name}) of log {self.name!r}: {exc.strerror or exc}",
                log=self.name,
                frame=frame,
            ) from None
        if not is_pbe(data):
            return data
        try:
            return await self._workers.io(render, data, Format.BINARY, None)
        except DecodeError as exc:
            raise FrameError(
                f"frame {frame} ({name}) of log {self.name!r} is corrupt: {exc}", log=self.name, frame=frame
            ) from None

    def describe_frame(self, frame: int) -> str:
        """How a frame is named in error messages: its file."""
        return self._files.get(file_number(frame), frame_name(frame))
