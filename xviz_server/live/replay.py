"""Replay a static log as a live feed, in real time (for demos and load tests)."""

from __future__ import annotations

import asyncio
import logging

import numpy as np

from ..codec import Format, decode
from ..exceptions import XVIZError
from ..logs import Log
from ..state import shift_times
from .feed import LiveFeed

__all__ = ["replay"]

logger = logging.getLogger(__name__)


async def replay(log: Log, feed: LiveFeed, *, rate: float = 1.0, loop: bool = False) -> None:
    """Publish the frames of ``log`` to ``feed`` at ``rate`` times their own pace.

    With ``loop``, starts over after the last frame, time going on: each lap
    is shifted by the log's length plus one frame interval, so a viewer (and
    a recording) sees time move forward. A frame that cannot be read is
    skipped with a warning.
    """
    clock = asyncio.get_running_loop()
    metadata = log.metadata
    if loop:  # the feed goes on past the log's end: viewers (streetscape.gl) must not stop there
        info = {key: value for key, value in (metadata.get("log_info") or {}).items() if key != "end_time"}
        metadata = {**metadata, "log_info": info}
    feed.set_metadata(metadata)
    starts = log.index.start
    step = float(np.median(np.diff(starts))) if len(starts) > 1 else 0.1
    period = float(starts[-1] - starts[0]) + step if len(starts) else 0.0
    lap = 0
    while True:
        started = clock.time()
        first = log.index.start_time or 0.0
        for position, number in enumerate(log.index.frames.tolist()):
            due = started + (float(starts[position]) - first) / rate
            await asyncio.sleep(max(0.0, due - clock.time()))
            try:
                data = await log.frame(number, Format.BINARY)
            except XVIZError as exc:  # a bad frame must not stop the feed
                logger.warning("replay of %r: skipping frame %d: %s", log.name, number, exc)
                continue
            await feed.publish(data if not lap else shift_times(decode(data), lap * period))
        if not loop:
            break
        lap += 1
    feed.disconnect()
