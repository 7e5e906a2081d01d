"""Record live feeds as static logs, as they arrive.

With ``--record DIR``, each feed is written to ``DIR/<feed>/<UTC start
time>/`` in the reference layout, GLB, one atomic file per update; a new
recording starts whenever the feed's metadata changes or the recording
reaches ``--record-rotate-mb``. The index is rewritten (atomically) whenever
the recorder catches up, at most once a second, so a recording cut short by
a crash is a readable log up to its last complete frame.

Writing happens in the I/O thread pool; the feed never waits for the disk,
and nothing the disk does reaches the feed: updates wait in a bounded queue
(:data:`QUEUE`; when the disk cannot keep up, the newest are dropped and
counted); a write error, a disk whose free space falls below
``--record-min-free-mb``, or the total of ``--record-max-mb`` reached ends
the recording as a valid log, logged and counted in ``/metrics``. Files are
created with the process's umask.
"""

from __future__ import annotations

import asyncio
import logging
import shutil
import time
from pathlib import Path
from typing import Any

from ..codec import Format
from ..events import Variant
from ..exceptions import LogWriteError
from ..metrics import Metrics
from ..work import Workers
from ..writer import LogWriter
from .feed import LiveFeed, LiveRegistry, LiveUpdate

__all__ = ["Recorder", "QUEUE"]

logger = logging.getLogger(__name__)

INDEX_INTERVAL = 1.0  # least seconds between two rewrites of a recording's index
#: Updates of one feed that may wait for the disk.
QUEUE = 64
#: Seconds that finishing a recording may wait for its queue to be written.
FINISH_TIMEOUT = 5.0
GLB = Variant(Format.BINARY)
MB = 1 << 20


class _Recording:
    """One feed's current recording: its writer and the updates not yet written."""

    def __init__(self, recorder: Recorder, directory: Path, metadata: dict[str, Any]) -> None:
        self.directory = directory
        self.metadata = metadata
        self.size = 0
        self.ended: str | None = None  # why it ended early
        self._recorder = recorder
        self._queue: asyncio.Queue[LiveUpdate] = asyncio.Queue(QUEUE)
        self._count = 0
        self._task = asyncio.ensure_future(self._run())

    def add(self, update: LiveUpdate) -> None:
        if self.ended is None:
            try:
                self._queue.put_nowait(update)
            except asyncio.QueueFull:
                self._recorder.metrics.record_dropped.inc()

    async def _run(self) -> None:
        io, writer = self._recorder.workers.io, None
        try:
            writer = await io(LogWriter, self.directory, Format.BINARY)
            await io(writer.write_metadata, self.metadata)
            indexed_at = 0.0
            while True:
                update = await self._queue.get()
                data = await update.encoded(GLB, self._recorder.workers)
                if (problem := await io(self._recorder.room_for, len(data))) is not None:
                    self._end(problem)
                    break
                await io(writer.write_frame, self._count, data)
                self._count, self.size = self._count + 1, self.size + len(data)
                self._recorder.written += len(data)
                self._queue.task_done()
                if self._queue.empty() and time.monotonic() - indexed_at >= INDEX_INTERVAL:
                    await io(writer.write_index)
                    indexed_at = time.monotonic()
        except (OSError, LogWriteError) as exc:
            self._end(f"cannot write: {exc}")
            self._recorder.metrics.record_errors.inc()
        finally:
            if writer is not None and self._count:
                try:
                    await io(writer.close)
                except (OSError, LogWriteError) as exc:
                    logger.error("recording of %s: cannot write its index: %s", self.directory, exc)

    def _end(self, problem: str) -> None:
        self.ended = problem
        logger.error("recording in %s ended after %d updates: %s", self.directory, self._count, problem)

    async def finish(self) -> None:
        """Write what is queued and the final index."""
        written = asyncio.ensure_future(self._queue.join())
        await asyncio.wait([written, self._task], timeout=FINISH_TIMEOUT, return_when=asyncio.FIRST_COMPLETED)
        written.cancel()
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)
        logger.info("recorded %d updates in %s", self._count, self.directory)


class Recorder:
    """Records every feed of a registry under ``root``.

    ``rotate_mb``: start a new recording of a feed past this size;
    ``max_mb``: record at most this much in all; ``min_free_mb``: stop
    recording when the disk has less free space than this.
    """

    def __init__(
        self,
        root: Path,
        registry: LiveRegistry,
        workers: Workers,
        metrics: Metrics,
        *,
        rotate_mb: float = 1024,
        max_mb: float | None = None,
        min_free_mb: float = 1024,
    ) -> None:
        self.root = Path(root)
        self.workers = workers
        self.metrics = metrics
        self.written = 0
        self._rotate = rotate_mb * MB
        self._max = None if max_mb is None else max_mb * MB
        self._min_free = min_free_mb * MB
        self._recordings: dict[str, _Recording] = {}
        self._finished: list[_Recording] = []
        registry.listeners.append(self._record)

    def room_for(self, size: int) -> str | None:
        """Why ``size`` more bytes may not be recorded, or ``None``; runs in the I/O pool (it asks the disk)."""
        if self._max is not None and self.written + size > self._max:
            return f"--record-max-mb {self._max / MB:g} reached"
        free = shutil.disk_usage(self.root).free
        if free - size < self._min_free:
            return f"the disk has {free / MB:.0f} MB free, less than --record-min-free-mb {self._min_free / MB:g}"
        return None

    def _record(self, feed: LiveFeed, update: LiveUpdate) -> None:
        """Queue ``update`` of ``feed``; never raises, never waits (it runs inside the feed's publish)."""
        if feed.origin is not None:
            return  # a mirror: its own replica records it
        try:
            recording = self._recordings.get(feed.name)
            if recording is not None and recording.ended is not None and recording.metadata is feed.metadata:
                return  # ended early: the feed is recorded again when its metadata changes
            if recording is None or recording.metadata is not feed.metadata or recording.size >= self._rotate:
                if recording is not None:
                    self._finished.append(recording)
                assert feed.metadata is not None
                recording = self._recordings[feed.name] = _Recording(self, self._directory(feed.name), feed.metadata)
                logger.info("recording live feed %r in %s", feed.name, recording.directory)
            recording.add(update)
        except Exception:  # a recorder must never stop the feed
            logger.exception("cannot record live feed %r", feed.name)
            self.metrics.record_errors.inc()

    def _directory(self, name: str) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        directory, suffix = self.root / name / stamp, 1
        while directory.exists():
            suffix += 1
            directory = self.root / name / f"{stamp}-{suffix}"
        return directory

    async def close(self) -> None:
        """Finish every recording: queued updates written, indexes complete."""
        for recording in [*self._finished, *self._recordings.values()]:
            await recording.finish()
        self._finished.clear()
        self._recordings.clear()
