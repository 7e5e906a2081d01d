"""One connection to the broker that writes commands and reads replies itself.

The two commands that carry a feed's updates between replicas, the owner's
``XADD`` and a reader's ``XREAD``, hold a frame of megabytes. On those two
paths a :class:`Wire` replaces the client: it writes a command's large
argument to the socket as it is (never joined into one buffer with the
rest), starts writing at once (a caller need not wait for its turn in the
event loop), and hands the bytes it receives to hiredis's parser as they
come. Everything else goes through :mod:`redis` (see :mod:`.link`).

Replies come back in order: :meth:`Wire.send` returns a future for its
reply. An error reply is a :class:`redis.exceptions.ResponseError`
(:class:`~redis.exceptions.OutOfMemoryError` for ``OOM``); a connection that
closes fails every pending reply with a
:class:`redis.exceptions.ConnectionError`.
"""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Any, cast

import hiredis
from redis.asyncio.connection import SSLConnection, UnixDomainSocketConnection, parse_url
from redis.exceptions import ConnectionError, OutOfMemoryError, ResponseError

__all__ = ["Wire"]

#: Arguments longer than this are written to the socket on their own, not copied into the command's buffer.
LARGE = 64 * 1024


class Wire(asyncio.Protocol):
    """A connection to the broker, RESP2 written by hand and parsed by hiredis."""

    def __init__(self) -> None:
        self._transport: asyncio.Transport | None = None
        self._parser = hiredis.Reader(replyError=ResponseError)
        self._waiting: deque[asyncio.Future[Any]] = deque()
        self._lost: Exception | None = None

    @classmethod
    async def open(cls, url: str, name: str, timeout: float) -> Wire:
        """Connect to the broker at ``url`` (``redis://``, ``rediss://`` or ``unix://``, as :mod:`redis` reads it),
        log in, select the database and name the connection ``name`` (``CLIENT LIST`` shows it), within ``timeout`` s."""
        options = parse_url(url)
        loop = asyncio.get_running_loop()
        wire = cls()
        if options.get("connection_class") is UnixDomainSocketConnection:
            connecting = loop.create_unix_connection(lambda: wire, str(options["path"]))
        else:
            host, port = str(options.get("host", "localhost")), int(options.get("port", 6379))
            tls = None
            if options.get("connection_class") is SSLConnection:
                settings = {key: value for key, value in options.items() if key.startswith("ssl_")}
                tls = SSLConnection(host=host, port=port, **settings).ssl_context.get()  # type: ignore[arg-type]
            connecting = loop.create_connection(lambda: wire, host, port, ssl=tls, server_hostname=host if tls else None)
        await asyncio.wait_for(connecting, timeout)
        try:
            hello: list[asyncio.Future[Any]] = []
            if options.get("password") is not None:
                login = [str(options["username"])] if options.get("username") else []
                hello.append(wire.send(b"AUTH", *(part.encode() for part in [*login, str(options["password"])])))
            if database := int(options.get("db") or 0):
                hello.append(wire.send(b"SELECT", b"%d" % database))
            hello.append(wire.send(b"CLIENT", b"SETNAME", name.encode()))
            await asyncio.wait_for(asyncio.gather(*hello), timeout)
        except BaseException:
            wire.close()
            raise
        return wire

    def send(self, *args: bytes) -> asyncio.Future[Any]:
        """Write the command ``args`` now; a future for its reply."""
        reply = asyncio.get_running_loop().create_future()
        if self._transport is None or self._lost is not None:
            reply.set_exception(self._lost or ConnectionError("not connected to the broker"))
            return reply
        head = [b"*%d\r\n" % len(args)]
        for arg in args:
            if len(arg) > LARGE:
                head.append(b"$%d\r\n" % len(arg))
                self._transport.write(b"".join(head))
                self._transport.write(arg)
                head = [b"\r\n"]
            else:
                head.append(b"$%d\r\n%s\r\n" % (len(arg), arg))
        self._transport.write(b"".join(head))
        self._waiting.append(reply)
        return reply

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    @property
    def closed(self) -> bool:
        """Whether the connection is down (closed, or not made yet)."""
        return self._transport is None or self._lost is not None

    # -- asyncio.Protocol ---------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)

    def data_received(self, data: bytes) -> None:
        self._parser.feed(data)
        while (reply := self._parser.gets()) is not False:
            if not self._waiting:
                continue  # a reply nobody waits for (its caller was cancelled): dropped
            waiting = self._waiting.popleft()
            if waiting.done():
                continue
            if isinstance(reply, ResponseError):
                waiting.set_exception(OutOfMemoryError(str(reply)) if str(reply).startswith("OOM") else reply)
            else:
                waiting.set_result(reply)

    def connection_lost(self, exc: Exception | None) -> None:
        self._lost = ConnectionError(f"the broker closed the connection{f': {exc}' if exc else ''}")
        while self._waiting:
            waiting = self._waiting.popleft()
            if not waiting.done():
                waiting.set_exception(self._lost)
