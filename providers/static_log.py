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
from ..index import TimeIndex
from ..layout import INDEX_FILE, INDEX_NUMBER, METADATA_NUMBER, Found, file_number, frame_name, frame_numbers
from ..messages import unwrap
from ..readahead import ReadAhead
from ..work import Workers

__all__ = ["StaticLogProvider", "StaticLog"]

logger = logging.getLogger(__name__)

_FORMATS = {"json": Format.JSON, "glb": Format.BINARY, "pbe": Format.BINARY}


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
        self.format = _FORMATS[metadata_file.rpartition(".")[2]]

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
            kind, content = await self._workers.io(lambda: unwrap(decode(data)))
        except OSError as exc:
            raise LogError(f"log {self.name!r}: cannot read {file}: {exc.strerror or exc}", log=self.name) from None
        except (DecodeError, MessageError) as exc:
            raise LogError(f"log {self.name!r}: {file} is not a readable XVIZ message: {exc}", log=self.name) from None
        if kind != "xviz/metadata" or not isinstance(content, dict):
            raise LogError(f"log {self.name!r}: {file} holds {kind!r}, not xviz/metadata", log=self.name)
        return content

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
            logger.warning("log %r: ignoring unreadable %s (%s); rebuilding it from the frames", self.name, INDEX_FILE, exc)
            return None
        frames = set(frame_numbers(self._files))
        if set(index.frames.tolist()) != frames:
            logger.warning(
                "log %r: %s names %d frames but the directory has %d; rebuilding it from the frames",
                self.name, INDEX_FILE, len(index), len(frames),
            )
            return None
        if not index.in_frame_order:
            logger.warning("log %r: the times of %s are not in frame order; rebuilding it from the frames", self.name, INDEX_FILE)
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
