"""Static logs: directories of pre-encoded frames in the reference layout.

A log directory holds ``0-frame.json`` (the index), ``1-frame.(json|glb|pbe)``
(the metadata message) and ``<i+2>-frame.(json|glb|pbe)`` (message ``i``, a
state update). Protobuf (PBE) frames are served as GLB: each is transcoded
when read, and the frame cache keeps the GLB. The provider serves every such directory under a root; a
log's name is its path relative to the root, with ``/`` separators (or the
root's own name when the root itself is a log). Symbolic links inside the
root are followed.

An index that is missing, unreadable or disagrees with the frame files is
rebuilt by reading every frame once; the rebuilt index is kept for the life
of the server.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Any

import orjson

from ..codec import Format, decode, detect_format, is_pbe
from ..exceptions import DecodeError, FrameError, LogError, MessageError
from ..frames import is_heavy, render, span
from ..index import TimeIndex
from ..messages import unwrap
from ..work import Workers

__all__ = ["StaticLogProvider", "StaticLog"]

logger = logging.getLogger(__name__)

FRAME_FILE = re.compile(r"(\d+)-frame\.(json|glb|pbe)")
INDEX_FILE = "0-frame.json"
_FORMATS = {"json": Format.JSON, "glb": Format.BINARY, "pbe": Format.BINARY}


def frame_files(directory: str | os.PathLike[str]) -> dict[int, str]:
    """Names of the message files of a log directory by file number (0 index, 1 metadata, 2+ frames).

    Names, not paths: a log can hold 100 000 frames, and making a ``Path``
    for each costs more than listing the directory.
    """
    files = {}
    with os.scandir(directory) as entries:
        for entry in entries:
            match = FRAME_FILE.fullmatch(entry.name)
            if match and entry.is_file():
                files[int(match.group(1))] = entry.name
    return files


class StaticLogProvider:
    """Every log directory under ``root``."""

    def __init__(self, root: Path, workers: Workers) -> None:
        self.root = Path(root)
        self._workers = workers
        self._logs: dict[str, Path] = {}

    def scan(self) -> list[str]:
        logs: dict[str, Path] = {}
        seen: set[str] = set()
        for directory, subdirectories, files in os.walk(self.root, followlinks=True):
            real = os.path.realpath(directory)
            if real in seen:  # a symbolic link loop
                subdirectories.clear()
                continue
            seen.add(real)
            subdirectories[:] = sorted(d for d in subdirectories if not d.startswith("."))
            if any(FRAME_FILE.fullmatch(name) for name in files):
                relative = Path(directory).relative_to(self.root).as_posix()
                logs[self.root.name if relative == "." else relative] = Path(directory)
        self._logs = logs
        return sorted(logs)

    async def open(self, name: str) -> StaticLog:
        directory = self._logs.get(name)
        if directory is None:
            raise LogError(f"log {name!r} is not under {self.root}", log=name)
        files = await self._workers.io(frame_files, directory)
        return StaticLog(name, directory, files, self._workers)


class StaticLog:
    """One log directory."""

    def __init__(self, name: str, directory: Path, files: dict[int, str], workers: Workers) -> None:
        self.name = name
        self.directory = directory
        self._files = files
        self._workers = workers
        metadata_file = files.get(1)
        if metadata_file is None:
            raise LogError(
                f"log {name!r} has no metadata file (1-frame.glb, 1-frame.json or 1-frame.pbe) in {directory}",
                log=name,
            )
        self.format = _FORMATS[metadata_file.rpartition(".")[2]]

    def _read(self, number: int) -> bytes:
        file = self._files.get(number)
        if file is None:
            raise FileNotFoundError(f"{number}-frame file missing")
        with open(os.path.join(self.directory, file), "rb") as stream:
            return stream.read()

    async def metadata(self) -> dict[str, Any]:
        file = self._files[1]
        try:
            data = await self._workers.io(self._read, 1)
            kind, content = unwrap(decode(data))
        except OSError as exc:
            raise LogError(f"log {self.name!r}: cannot read {file}: {exc.strerror or exc}", log=self.name) from None
        except (DecodeError, MessageError) as exc:
            raise LogError(f"log {self.name!r}: {file} is not a readable XVIZ message: {exc}", log=self.name) from None
        if kind != "xviz/metadata" or not isinstance(content, dict):
            raise LogError(f"log {self.name!r}: {file} holds {kind!r}, not xviz/metadata", log=self.name)
        return content

    async def index(self) -> TimeIndex:
        index = await self._workers.io(self._stored_index)
        if index is not None:
            return index
        return await self._build_index(sorted(number - 2 for number in self._files if number >= 2))

    def _stored_index(self) -> TimeIndex | None:
        """The log's ``0-frame.json``, when it is readable and names the frame files there are."""
        if self._files.get(0) != INDEX_FILE:
            return None
        try:
            index = TimeIndex.from_reference(orjson.loads(self._read(0)))
        except (OSError, orjson.JSONDecodeError, DecodeError) as exc:
            logger.warning("log %r: ignoring unreadable %s (%s); rebuilding it from the frames", self.name, INDEX_FILE, exc)
            return None
        frames = {number - 2 for number in self._files if number >= 2}
        if set(index.frames.tolist()) == frames:
            return index
        logger.warning(
            "log %r: %s names %d frames but the directory has %d; rebuilding it from the frames",
            self.name, INDEX_FILE, len(index), len(frames),
        )
        return None

    async def _build_index(self, frames: list[int]) -> TimeIndex:
        spans = []
        for frame in frames:
            try:
                data = await self.read(frame)
                run = self._workers.cpu if is_heavy(detect_format(data)) else self._workers.io
                start, end = await run(span, data)
            except (FrameError, DecodeError) as exc:
                logger.warning("log %r: frame %d left out of the index: %s", self.name, frame, exc)
                continue
            spans.append((start, end, frame))
        return TimeIndex.from_spans(spans)

    async def read(self, frame: int) -> bytes:
        name = self.describe_frame(frame)
        try:
            data = await self._workers.io(self._read, frame + 2)
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
        return self._files.get(frame + 2, f"{frame + 2}-frame")
