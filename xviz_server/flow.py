"""Connections that stop reading: how long a send may make no progress, and closing that cannot hang.

A client that stops reading fills the socket's buffers; then every send on
its connection waits, and so does the keepalive ping queued behind them and
the closing handshake. :func:`watch_progress` ends such a connection when its
write buffer has not shrunk for ``timeout`` seconds; :func:`close` closes
with a code and reason, and aborts the transport when the closing frame
cannot be written within the time given.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from websockets.asyncio.connection import Connection

__all__ = ["watch_progress", "close"]

logger = logging.getLogger(__name__)


async def watch_progress(
    websocket: Connection, timeout: float, sent: Callable[[], int] = lambda: 0, checks: int = 4
) -> None:
    """Abort ``websocket`` once its write buffer has stayed full, not shrinking, for ``timeout`` seconds.

    Full: above the transport's high-water mark, so that every send waits
    (writing is paused). While paused nothing is added but small control
    frames, so a buffer that does not shrink is a client that does not read.
    ``sent`` counts the messages whose sending has completed (also progress).
    The buffer is looked at ``checks`` times per ``timeout``; returns when
    the connection ends.
    """
    interval = timeout / checks
    stalled = 0.0
    before, count = 0, sent()
    transport = websocket.transport
    while not transport.is_closing():
        await asyncio.sleep(interval)
        waiting, done = transport.get_write_buffer_size(), sent()
        stalled = stalled + interval if websocket.paused and waiting >= before and done == count else 0.0
        before, count = waiting, done
        if stalled >= timeout:
            address = websocket.remote_address
            logger.warning("%s stopped reading: %d bytes unsent for %g s; aborting the connection", address, waiting, timeout)
            transport.abort()
            return


async def close(websocket: Connection, code: int, reason: str, timeout: float | None = None) -> None:
    """Close ``websocket`` with ``code`` and ``reason``; abort it if that takes over ``timeout`` seconds
    (by default the connection's own close timeout, else 10 s)."""
    try:
        await asyncio.wait_for(websocket.close(code, reason), timeout or websocket.close_timeout or 10.0)
    except (asyncio.TimeoutError, OSError):
        websocket.transport.abort()
        task = asyncio.current_task()
        if task is not None and getattr(task, "cancelling", lambda: 0)():
            raise asyncio.CancelledError from None  # the timeout was the cancellation of this task
