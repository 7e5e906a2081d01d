"""Write logs in the reference layout, one atomic file at a time.

A log directory holds ``1-frame.glb|json`` (the metadata), one
``<i+2>-frame.glb|json`` per state update ``i`` and ``0-frame.json``, the
index, written last. Every file is written to a temporary name in the same
directory, synced and renamed into place, so a reader (or a crash) never
sees half a file. A writer opened on a directory that already holds frames
keeps them: an interrupted conversion resumes where it stopped.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import Any, Mapping

import orjson

from .codec import Format, decode, detect_format, encode
from .exceptions import XVIZError
from .providers.static_log import INDEX_FILE, frame_files

__all__ = ["write_atomically", "LogWriter"]

_TEMP_MARK = ".partial-"


def write_atomically(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` so that readers see the old file or the new one, never a mix."""
    temporary = path.with_name(f".{path.name}{_TEMP_MARK}{secrets.token_hex(4)}")
    try:
        with open(temporary, "wb") as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


class LogWriter:
    """Writes one log directory; use :meth:`close` (or ``with``) to write the index.

    Frames already in the directory are kept, and :meth:`done` tells which,
    so a conversion that was interrupted can skip them.
    """

    def __init__(self, directory: Path, fmt: Format = Format.BINARY) -> None:
        self.directory = Path(directory)
        self.format = fmt
        self.directory.mkdir(parents=True, exist_ok=True)
        for leftover in self.directory.glob(f".*{_TEMP_MARK}*"):
            leftover.unlink()  # from a run that stopped mid-write
        self._spans: dict[int, tuple[float, float]] = {}

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, kind: Any, *_: Any) -> None:
        if kind is None:
            self.close()

    def write_metadata(self, data: Mapping[str, Any]) -> None:
        """Write the metadata message (the data of an ``xviz/metadata``)."""
        self._write(1, {"type": "xviz/metadata", "data": data})

    def write_frame(self, index: int, data: Mapping[str, Any] | bytes) -> None:
        """Write state update ``index``: its data, or a message already encoded in the log's format."""
        if isinstance(data, (bytes, bytearray, memoryview)):
            message = decode(data)
            self._check_span(index, message)
            if detect_format(data) is self.format:
                self._write_bytes(index + 2, bytes(data))
            else:
                self._write(index + 2, message)
            return
        message = {"type": "xviz/state_update", "data": data}
        self._check_span(index, message)
        self._write(index + 2, message)

    def done(self, index: int) -> bool:
        """Whether state update ``index`` is already complete on disk."""
        return self._file(index + 2).is_file()

    def write_index(self) -> int:
        """Write ``0-frame.json`` for the frames present, up to the first gap; return how many."""
        present = sorted(n - 2 for n in frame_files(self.directory) if n >= 2)
        count = next((i for i, n in enumerate(present) if n != i), len(present))
        timing = []
        for index in range(count):
            start, end = self._spans.get(index) or self._read_span(index)
            timing.append([start, end, index, f"{index + 2}-frame"])
        document: dict[str, Any] = {"timing": timing}
        if timing:
            document = {"startTime": timing[0][0], "endTime": max(row[1] for row in timing), **document}
        write_atomically(self.directory / INDEX_FILE, orjson.dumps(document))
        return count

    def close(self) -> None:
        """Write the index; raises :class:`~xviz_server.exceptions.XVIZError` if a frame is missing."""
        present = sorted(n - 2 for n in frame_files(self.directory) if n >= 2)
        missing = sorted(set(range(len(present))) - set(present))
        if missing:
            raise XVIZError(
                f"{self.directory}: cannot write the index, frames are missing: "
                + ", ".join(f"{n + 2}-frame" for n in missing[:10])
            )
        self.write_index()

    # -- helpers --------------------------------------------------------

    def _file(self, number: int) -> Path:
        return self.directory / f"{number}-frame{self.format.suffix}"

    def _write(self, number: int, message: dict[str, Any]) -> None:
        self._write_bytes(number, encode(message, self.format))

    def _write_bytes(self, number: int, data: bytes) -> None:
        write_atomically(self._file(number), data)

    def _check_span(self, index: int, message: dict[str, Any]) -> None:
        updates = message.get("data", {}).get("updates") or []
        times = [u.get("timestamp") for u in updates if isinstance(u, dict)]
        if not times or not all(isinstance(t, (int, float)) and not isinstance(t, bool) for t in times):
            raise XVIZError(f"frame {index}: every update needs a numeric 'timestamp'")
        self._spans[index] = (float(min(times)), float(max(times)))

    def _read_span(self, index: int) -> tuple[float, float]:
        path = frame_files(self.directory)[index + 2]
        updates = decode(path.read_bytes())["data"]["updates"]
        times = [u["timestamp"] for u in updates]
        self._spans[index] = span = (float(min(times)), float(max(times)))
        return span
