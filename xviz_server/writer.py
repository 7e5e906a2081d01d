"""Write logs in the reference layout, one atomic file at a time.

A log directory holds ``1-frame.glb|json`` (the metadata), one
``<i+2>-frame.glb|json`` per state update ``i`` and ``0-frame.json``, the
index, written last by :meth:`LogWriter.close`::

    with LogWriter(directory, Format.BINARY) as writer:
        writer.write_metadata(metadata)
        for i, source_frame in enumerate(source):
            if not writer.done(i):          # written by an earlier, interrupted run
                writer.write_frame(i, convert(source_frame))

Every file is written by :func:`write_atomically`: to a temporary name in
the same directory, synced, renamed into place, and the directory synced; a
reader never sees half a file, and a crash leaves at most a temporary file.
A writer opened on a directory that already holds frames keeps them and
removes such leftovers, so an interrupted conversion resumes where it
stopped; it removes the index of an earlier run before it changes anything,
since the index marks a finished log.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import orjson

from .codec import Format, decode, detect_format, encode
from .exceptions import DecodeError, LogWriteError
from .layout import (
    INDEX_FILE,
    METADATA_NUMBER,
    file_number,
    frame_files,
    frame_name,
    frame_numbers,
    index_document,
    update_span,
)

__all__ = ["write_atomically", "LogWriter"]

_TEMP_MARK = ".partial-"


def write_atomically(path: str | os.PathLike[str], data: bytes | bytearray | memoryview) -> None:
    """Replace the file at ``path`` with ``data``: readers see the old file or the new one, never a mix.

    The data goes to a temporary file next to ``path`` (``.<name>.partial-<random>``),
    which is flushed, synced and renamed over ``path``; then the directory is
    synced so that the rename survives a power cut. If anything fails, the
    temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}{_TEMP_MARK}{secrets.token_hex(4)}")
    try:
        with open(temporary, "xb") as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _sync_directory(path.parent)


def _sync_directory(directory: Path) -> None:
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


class LogWriter:
    """Writes one log directory in ``fmt`` (GLB by default); :meth:`close`, or leaving a
    ``with`` block without an exception, writes the index.

    Leaving the ``with`` block by an exception writes no index: the frames
    written so far stay, and a new writer on the directory picks up from
    there (:meth:`done`).
    """

    def __init__(self, directory: str | os.PathLike[str], fmt: Format = Format.BINARY) -> None:
        self.directory = Path(directory)
        self.format = Format(fmt)
        self.directory.mkdir(parents=True, exist_ok=True)
        for leftover in self.directory.glob(f".*{_TEMP_MARK}*"):
            leftover.unlink()  # from a run that stopped in the middle of a file
        files = frame_files(self.directory)
        foreign = sorted(name for number, name in files.items() if number > 0 and not name.endswith(self.format.suffix))
        if foreign:
            names = ", ".join(foreign[:3])
            raise self._error(
                f"holds {names}, not {self.format.value} frames; open it with the format it was written in"
            )
        self._stale_index = 0 in files  # an earlier run's index, dropped before the first change
        self._spans: dict[int, tuple[float, float]] = {}  # frame -> (first, last timestamp)
        self._log_times: tuple[float | None, float | None] | None = None  # read from the metadata when needed
        self._closed = False

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: Any) -> None:
        if kind is None:
            self.close()

    def write_metadata(self, data: Mapping[str, Any] | bytes) -> None:
        """Write the metadata: the data of an ``xviz/metadata`` message, or such a message encoded."""
        if isinstance(data, (bytes, bytearray, memoryview)):
            message = self._decode(data, "metadata")
            if message.get("type") != "xviz/metadata":
                raise self._error(f"metadata holds {message.get('type')!r}, not xviz/metadata")
            self._write(METADATA_NUMBER, message, data)
        else:
            self._write(METADATA_NUMBER, {"type": "xviz/metadata", "data": data})
        self._log_times = None

    def write_frame(self, index: int, data: Mapping[str, Any] | bytes) -> None:
        """Write state update ``index`` (file ``<index+2>-frame``): the data of an
        ``xviz/state_update``, or such a message encoded (converted if its format differs).

        Raises :class:`~xviz_server.exceptions.LogWriteError` unless every
        update has a numeric ``timestamp`` and there is an ``update_type``.
        """
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise self._error(f"frame index must be an integer >= 0, not {index!r}")
        encoded = data if isinstance(data, (bytes, bytearray, memoryview)) else None
        if encoded is not None:
            message = self._decode(encoded, f"frame {index}")
        else:
            message = {"type": "xviz/state_update", "data": data}
        self._spans[index] = self._span(index, message)
        self._write(file_number(index), message, encoded)

    def done(self, index: int) -> bool:
        """Whether state update ``index`` is complete on disk (files are written atomically,
        so one that exists is whole)."""
        return self._path(file_number(index)).is_file()

    def write_index(self) -> int:
        """Write ``0-frame.json`` for the frames before the first missing one; return how many.

        For an index while the log is still growing (a recording); a finished
        log gets its index from :meth:`close`.
        """
        frames = frame_numbers(frame_files(self.directory))
        count = next((i for i, frame in enumerate(frames) if frame != i), len(frames))
        document = index_document([self._frame_span(i) for i in range(count)], *self._log_info_times())
        write_atomically(self.directory / INDEX_FILE, orjson.dumps(document))
        self._stale_index = False
        return count

    def close(self) -> None:
        """Write the index, last, and refuse further writes.

        ``startTime``/``endTime`` are the metadata's ``log_info`` times when it
        has them, as the reference tools write them, else the frames' span;
        each timing row is ``[first, last timestamp, i, "<i+2>-frame"]``.
        Raises :class:`~xviz_server.exceptions.LogWriteError`, writing no
        index, if the metadata, every frame, or a frame in the sequence is
        missing. Closing twice does nothing more.
        """
        if self._closed:
            return
        files = frame_files(self.directory)
        if METADATA_NUMBER not in files:
            raise self._error("cannot write the index: no metadata (1-frame); call write_metadata")
        frames = frame_numbers(files)
        if not frames:
            raise self._error("cannot write the index: no frames were written")
        missing = sorted(set(range(frames[-1] + 1)) - set(frames))
        if missing:
            names = ", ".join(f"{frame_name(i)} (frame {i})" for i in missing[:5])
            more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
            raise self._error(f"cannot write the index: missing {names}{more}")
        self.write_index()
        self._closed = True

    # -- helpers ----------------------------------------------------------

    def _path(self, number: int) -> Path:
        return self.directory / f"{number}-frame{self.format.suffix}"

    def _write(
        self, number: int, message: Mapping[str, Any], encoded: bytes | bytearray | memoryview | None = None
    ) -> None:
        """Write file ``number``: ``encoded`` as it is when it is in the log's format, else ``message`` encoded."""
        if self._closed:
            raise self._error("the writer is closed; open a new one to change the log")
        if self._stale_index:
            (self.directory / INDEX_FILE).unlink(missing_ok=True)
            _sync_directory(self.directory)
            self._stale_index = False
        if encoded is None or detect_format(encoded) is not self.format:
            encoded = encode(message, self.format)
        write_atomically(self._path(number), encoded)

    def _error(self, problem: str) -> LogWriteError:
        return LogWriteError(f"{self.directory}: {problem}", directory=self.directory)

    def _decode(self, data: bytes | bytearray | memoryview, what: str) -> dict[str, Any]:
        try:
            message = decode(data)
        except DecodeError as exc:
            raise self._error(f"{what}: {exc}") from exc
        if not isinstance(message, dict) or not isinstance(message.get("data"), dict):
            raise self._error(f"{what} is not an XVIZ envelope")
        return message

    def _span(self, index: int, message: Mapping[str, Any]) -> tuple[float, float]:
        """First and last timestamp of a state update, checking what clients need of it."""
        if message.get("type") != "xviz/state_update":
            raise self._error(f"frame {index} holds {message.get('type')!r}, not xviz/state_update")
        data = message["data"]
        if not isinstance(data, Mapping) or not isinstance(data.get("update_type"), str):
            raise self._error(f"frame {index}: needs an 'update_type' (clients refuse updates without one)")
        span = update_span(data)
        if span is None:
            raise self._error(f"frame {index}: every update needs a numeric 'timestamp'")
        return span

    def _frame_span(self, index: int) -> tuple[float, float]:
        span = self._spans.get(index)
        if span is None:  # written by an earlier run: read it (decoding GLB is cheap)
            message = self._decode(self._path(file_number(index)).read_bytes(), f"frame {index}")
            span = self._spans[index] = self._span(index, message)
        return span

    def _log_info_times(self) -> tuple[float | None, float | None]:
        """The metadata's ``log_info`` start and end times, where it has them (non-zero numbers)."""
        if self._log_times is None:
            name = frame_files(self.directory).get(METADATA_NUMBER)
            metadata = (
                self._decode((self.directory / name).read_bytes(), "metadata")["data"] if name is not None else {}
            )
            info = metadata.get("log_info")
            times = [info.get(key) for key in ("start_time", "end_time")] if isinstance(info, Mapping) else [None, None]
            start, end = (
                float(t) if isinstance(t, (int, float)) and not isinstance(t, bool) and t else None for t in times
            )
            self._log_times = start, end
        return self._log_times
