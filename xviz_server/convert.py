"""``xviz-server convert``: write a raw dataset out as a static log, on every core.

Frames are converted and encoded in a process pool (one process per core)
and written by :class:`~xviz_server.writer.LogWriter`: each file atomically,
the index last. Frames already written are skipped, so a conversion that
was interrupted resumes where it stopped.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from .codec import Format
from .datasets import convert_frame, open_dataset
from .writer import LogWriter

__all__ = ["Progress", "convert", "parse_frames"]


def parse_frames(text: str | None, count: int) -> range:
    """``A:B`` (either side may be empty, B excluded) as a range of frames; raises :class:`ValueError`."""
    if text is None:
        return range(count)
    start, separator, stop = text.partition(":")
    if not separator:
        raise ValueError(f"--frames {text!r}: give A:B, like 0:100 or 50:")
    try:
        frames = range(count)[slice(int(start) if start else None, int(stop) if stop else None)]
    except ValueError:
        raise ValueError(f"--frames {text!r}: A and B are frame numbers") from None
    if not frames:
        raise ValueError(f"--frames {text!r} selects no frame of the {count}")
    return frames


@dataclass
class Progress:
    """Reports frames done, rate and time left: a live line on a terminal, plain lines elsewhere."""

    total: int
    out: TextIO = sys.stderr
    every: float = 2.0

    def __post_init__(self) -> None:
        self.done = 0
        self.started = time.perf_counter()
        self._shown = 0.0
        self._live = self.out.isatty()

    def advance(self, frames: int = 1) -> None:
        self.done += frames
        now = time.perf_counter()
        if self._live or now - self._shown >= self.every or self.done == self.total:
            self._shown = now
            self._show(now)

    def _show(self, now: float) -> None:
        elapsed = max(now - self.started, 1e-9)
        rate = self.done / elapsed
        left = (self.total - self.done) / rate if rate else float("inf")
        text = f"{self.done}/{self.total} frames, {rate:.1f} frames/s, ETA {left:.0f} s"
        if self._live:
            width = 30
            filled = width * self.done // max(self.total, 1)
            end = "\n" if self.done == self.total else ""
            print(f"\r[{'#' * filled}{'.' * (width - filled)}] {text}   ", end=end, file=self.out, flush=True)
        else:
            print(text, file=self.out, flush=True)


def convert(
    kind: str,
    source: Path,
    output: Path,
    *,
    fmt: Format = Format.BINARY,
    frames: str | None = None,
    options: dict[str, Any] | None = None,
    processes: int | None = None,
    out: TextIO = sys.stderr,
) -> int:
    """Convert ``source`` into a log at ``output``; return the number of frames written now."""
    options = options or {}
    dataset = open_dataset(kind, source, **options)
    selected = parse_frames(frames, len(dataset))
    metadata = dataset.metadata()
    first, last = float(dataset.times[selected[0]]), float(dataset.times[selected[-1]])
    metadata["log_info"] = {**metadata.get("log_info", {}), "start_time": first, "end_time": last}
    writer = LogWriter(output, fmt)
    writer.write_metadata(metadata)
    todo = [(index, frame) for index, frame in enumerate(selected) if not writer.done(index)]
    processes = processes or os.cpu_count() or 1
    print(
        f"converting {len(todo)} of {len(selected)} frames of {dataset.name} to {output} "
        f"({fmt.value}) with {processes} processes"
        + (f"; {len(selected) - len(todo)} already written" if len(todo) < len(selected) else ""),
        file=out,
        flush=True,
    )
    progress = Progress(len(todo), out)
    path = str(dataset.path)
    with ProcessPoolExecutor(max_workers=processes) as pool:
        # A bounded window keeps memory flat while every process stays busy.
        window = processes * 4
        pending: dict[int, Any] = {}
        queue = iter(todo)
        for index, frame in queue:
            pending[index] = pool.submit(convert_frame, kind, path, options, frame, metadata, fmt)
            if len(pending) >= window:
                _write_oldest(pending, writer, progress)
        while pending:
            _write_oldest(pending, writer, progress)
    writer.close()
    return len(todo)


def _write_oldest(pending: dict[int, Any], writer: LogWriter, progress: Progress) -> None:
    index = min(pending)
    writer.write_frame(index, pending.pop(index).result())
    progress.advance()
