"""Record live feeds as static logs, as they arrive.

With ``--record DIR``, each feed is written to ``DIR/<feed>/<UTC start
time>/`` in the reference layout, GLB, one atomic file per update; a new
recording starts whenever the feed's metadata changes. The index is
rewritten (atomically) whenever the recorder catches up, at most once a
second, so a recording cut short by a crash is a readable log up to its last
complete frame (and a server rebuilds a stale index from the frames anyway).
Writing happens in the I/O thread pool; the feed never waits for the disk.
"""

from __future__ import annotations

import asyncio
import logging
import time
from pathlib import Path
from typing import Any

from ..codec import Format
from ..session import Variant
from .feed import LiveRegistry, LiveFeed, LiveUpdate
from ..work import Workers
from ..writer import LogWriter

__all__ = ["Recorder"]

logger = logging.getLogger(__name__)

INDEX_INTERVAL = 1.0  # least seconds between two rewrites of a recording's index
GLB = Variant(Format.BINARY)


class _Recording:
    """One feed's current recording: its writer and the updates not yet written."""

    def __init__(self, directory: Path, metadata: dict[str, Any], workers: Workers) -> None:
        self.directory = directory
        self.metadata = metadata
        self._workers = workers
        self._writer = LogWriter(directory, Format.BINARY)
        self._queue: asyncio.Queue[LiveUpdate] = asyncio.Queue()
        self._count = 0
        self._task = asyncio.ensure_future(self._run())

    def add(self, update: LiveUpdate) -> None:
        self._queue.put_nowait(update)

    async def _run(self) -> None:
        await self._workers.io(self._writer.write_metadata, self.metadata)
        indexed_at = 0.0
        while True:
            update = await self._queue.get()
            data = await update.encoded(GLB, self._workers)
            await self._workers.io(self._writer.write_frame, self._count, data)
            self._count += 1
            self._queue.task_done()
            if self._queue.empty() and time.monotonic() - indexed_at >= INDEX_INTERVAL:
                await self._workers.io(self._writer.write_index)
                indexed_at = time.monotonic()

    async def finish(self) -> None:
        """Write what is queued and the final index."""
        await self._queue.join()
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)
        await self._workers.io(self._writer.close)
        logger.info("recorded %d updates in %s", self._count, self.directory)


class Recorder:
    """Records every feed of a registry under ``root``."""

    def __init__(self, root: Path, registry: LiveRegistry, workers: Workers) -> None:
        self.root = Path(root)
        self._workers = workers
        self._recordings: dict[str, _Recording] = {}
        self._finished: list[_Recording] = []
        registry.listeners.append(self._record)

    def _record(self, feed: LiveFeed, update: LiveUpdate) -> None:
        recording = self._recordings.get(feed.name)
        if recording is None or recording.metadata is not feed.metadata:
            if recording is not None:
                self._finished.append(recording)
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            directory = self.root / feed.name / stamp
            suffix = 1
            while directory.exists():
                suffix += 1
                directory = self.root / feed.name / f"{stamp}-{suffix}"
            assert feed.metadata is not None
            recording = self._recordings[feed.name] = _Recording(directory, feed.metadata, self._workers)
            logger.info("recording live feed %r in %s", feed.name, directory)
        recording.add(update)

    async def close(self) -> None:
        """Finish every recording: queued updates written, indexes complete."""
        for recording in [*self._finished, *self._recordings.values()]:
            await recording.finish()
        self._finished.clear()
        self._recordings.clear()
