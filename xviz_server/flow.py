"""Connections that stop reading: how long a send may make no progress, and closing that cannot hang.

A client that stops reading fills the socket's buffers; then every send on
its connection waits, and so does the keepalive ping queued behind them and
the closing handshake. :func:`watch_progress` ends such a connection when its
write buffer has not shrunk for ``timeout`` seconds; :func:`close` closes
with a code and reason, and aborts the transport when the closing frame
cannot be written within the time given. :func:`backlog` tells how many
bytes written are not delivered yet, :func:`link_times` how long the link
was busy with them and how long they waited for the peer to read; :func:`limit_unsent`
keeps most of them where the server sees them.
"""

from __future__ import annotations

import asyncio
import fcntl
import logging
import socket
import struct
import termios
from collections.abc import Callable

from websockets.asyncio.connection import Connection

__all__ = ["watch_progress", "close", "backlog", "limit_unsent", "link_times"]

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
            logger.warning(
                "%s stopped reading: %d bytes unsent for %g s; aborting the connection", address, waiting, timeout
            )
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


def backlog(transport: asyncio.WriteTransport) -> int:
    """Bytes written to ``transport`` and not yet delivered: those in its write buffer and in the kernel's
    send queue (not sent, or not acknowledged by the peer: ``TIOCOUTQ``; 0 where the system does not tell)."""
    queued = transport.get_write_buffer_size()
    sock = _socket(transport)
    if sock is None:
        return queued
    try:
        answer = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0")
    except OSError:  # not a stream socket
        return queued
    return queued + struct.unpack("i", answer)[0]


#: Most bytes a connection's kernel send queue holds that are not yet sent (see :func:`limit_unsent`).
UNSENT_LIMIT = 256 * 1024


def limit_unsent(transport: asyncio.WriteTransport, limit: int = UNSENT_LIMIT) -> None:
    """Let the kernel hold at most ``limit`` bytes of ``transport``'s not yet sent (``TCP_NOTSENT_LOWAT``).

    The bytes in flight on the link are not limited: throughput stays what
    the link carries. Over a slow link the rest wait in the transport's
    write buffer, so that sending waits, frames are not made far ahead of
    the link, and a change of level of detail reaches the link within
    about ``limit`` bytes. Nothing is done where the system has no such
    option.
    """
    option = getattr(socket, "TCP_NOTSENT_LOWAT", None)
    sock = _socket(transport)
    if option is None or sock is None:
        return
    try:
        sock.setsockopt(socket.IPPROTO_TCP, option, limit)
    except OSError:  # not TCP
        pass


# struct tcp_info (linux/tcp.h): the u64s tcpi_busy_time and tcpi_rwnd_limited, microseconds, since Linux 4.10
_TIMES = struct.Struct("QQ")
_BUSY_TIME_OFFSET = 168


def link_times(transport: asyncio.WriteTransport) -> tuple[int, int] | None:
    """Microseconds so far that ``transport``'s connection had data unsent or unacknowledged in the kernel
    (busy), and of them those it could not send because the peer's receive window was full (a peer that
    reads slower than the link carries), from ``TCP_INFO``; ``None`` where the system does not tell.
    The kernel counts them in its clock ticks (4 ms at 250 Hz)."""
    option = getattr(socket, "TCP_INFO", None)
    sock = _socket(transport)
    if option is None or sock is None:
        return None
    try:
        info = sock.getsockopt(socket.IPPROTO_TCP, option, _BUSY_TIME_OFFSET + _TIMES.size)
    except OSError:  # not TCP
        return None
    if len(info) < _BUSY_TIME_OFFSET + _TIMES.size:
        return None
    busy, receiver = _TIMES.unpack_from(info, _BUSY_TIME_OFFSET)
    return int(busy), int(receiver)


def _socket(transport: asyncio.BaseTransport) -> socket.socket | None:
    """``transport``'s socket while it is open; ``None`` once the transport closed it, or for one without a socket.

    A closed socket has no file descriptor (``fileno()`` is -1): the standard
    library's sockets raise :exc:`OSError` when asked about it, uvloop's
    raise :exc:`ValueError` ("negative file descriptor"); a socket looked at
    after its connection ended is simply not there.
    """
    sock: socket.socket | None = transport.get_extra_info("socket")
    if sock is None or sock.fileno() < 0:
        return None
    return sock
