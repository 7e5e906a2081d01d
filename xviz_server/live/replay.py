"""Replay a static log as a live feed, in real time (for demos and load tests)."""

from __future__ import annotations

import asyncio
import logging

from ..exceptions import XVIZError
from .feed import LiveFeed
from ..logs import Log

__all__ = ["replay"]

logger = logging.getLogger(__name__)


async def replay(log: Log, feed: LiveFeed, *, rate: float = 1.0, loop: bool = False) -> None:
    """Publish the frames of ``log`` to ``feed`` at ``rate`` times their own pace.

    With ``loop``, starts over after the last frame (timestamps repeat). A
    frame that cannot be read is skipped with a warning.
    """
    clock = asyncio.get_running_loop()
    feed.set_metadata(log.metadata)
    while True:
        started = clock.time()
        first = log.index.start_time or 0.0
        for position, number in enumerate(log.index.frames.tolist()):
            due = started + (float(log.index.start[position]) - first) / rate
            await asyncio.sleep(max(0.0, due - clock.time()))
            try:
                data = await log.frame(number, log.format)
            except XVIZError as exc:  # a bad frame must not stop the feed
                logger.warning("replay of %r: skipping frame %d: %s", log.name, number, exc)
                continue
            await feed.publish(data)
        if not loop:
            break
    feed.disconnect()
