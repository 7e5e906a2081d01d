"""The asyncio side of :mod:`xviz_server.detail`: sampling a connection's link, for any protocol face.

:func:`sample_link` samples a connection's delivery every
:data:`~xviz_server.detail.SAMPLE_INTERVAL` seconds on average, at jittered
times (so that the samples never keep step with a feed's updates), into
:class:`~xviz_server.detail.Sample` objects that the face's session turns
into its level of detail. It first keeps most of the connection's unsent
bytes where the server sees them (:func:`~xviz_server.flow.limit_unsent`).
A client on this host (:func:`is_loopback`) has no link to fit.
"""

from __future__ import annotations

import asyncio
import ipaddress
import random
import time
from collections.abc import Awaitable, Callable

from websockets.asyncio.server import ServerConnection

from .detail import SAMPLE_INTERVAL, Sample
from .flow import backlog, limit_unsent, link_times

__all__ = ["sample_link", "is_loopback"]


async def sample_link(
    transport: asyncio.WriteTransport,
    written: Callable[[], int],
    sampled: Callable[[Sample], Awaitable[None]],
    measures: Callable[[], bool],
) -> None:
    """Sample ``transport``'s delivery (``written``: the bytes handed to the connection so far) and await
    ``sampled`` with each sample, while ``measures()`` holds and the transport is open."""
    limit_unsent(transport)
    before, times = time.monotonic(), link_times(transport)
    while not transport.is_closing() and measures():
        await asyncio.sleep(SAMPLE_INTERVAL * random.uniform(0.5, 1.5))
        now, previous, times = time.monotonic(), times, link_times(transport)
        # the backlog waited for the peer to read for most of the time since the sample before: not the link's
        reader = times is not None and previous is not None and (times[1] - previous[1]) / 1e6 >= (now - before) / 2
        busy = None if times is None else (times[0] - times[1]) / 1e6
        before = now
        await sampled(Sample(now, written(), backlog(transport), reader, busy))


def is_loopback(websocket: ServerConnection) -> bool:
    """Whether the client is on this host (a loopback address)."""
    address = websocket.remote_address
    try:
        return bool(address) and ipaddress.ip_address(address[0]).is_loopback
    except ValueError:  # a Unix socket's path
        return False
