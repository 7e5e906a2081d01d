"""One connection to the broker that writes commands and reads replies itself.

The two commands that carry a feed's updates between replicas, the owner's
``XADD`` and a reader's ``XREAD``, hold a frame of megabytes. On those two
paths a :class:`Wire` replaces the client: it writes a command's large
argument to the socket as it is (never joined into one buffer with the
rest), starts writing at once (a caller need not wait for its turn in the
event loop), and reads a large bulk string of a reply from the socket
straight into a buffer kept for them (:class:`Replies`) and copies it out
once, where hiredis, fed what the transport read, copies it three times
(see docs/performance.md#the-hop-through-redis).
Everything else goes through :mod:`redis` (see :mod:`.link`).

Replies come back in order: :meth:`Wire.send` returns a future for its
reply. An error reply is a :class:`redis.exceptions.ResponseError`
(:class:`~redis.exceptions.OutOfMemoryError` for ``OOM``); a connection that
closes, or that carries what is not RESP, fails every pending reply with a
:class:`redis.exceptions.ConnectionError`.

To read a broker URL as :mod:`redis` does, :meth:`Wire.open` uses
``parse_url``, the connection classes it names and ``SSLConnection``'s
``ssl_context``, from ``redis.asyncio.connection``, which redis-py does not
document; importing this module raises
:exc:`~xviz_server.exceptions.DependencyError` unless the installed redis-py
is a release it was tested with (:data:`TESTED_REDIS`).
"""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Any, cast

import redis
from redis.asyncio.connection import SSLConnection, UnixDomainSocketConnection, parse_url
from redis.exceptions import ConnectionError, InvalidResponse, OutOfMemoryError, ResponseError

from ..version import require_tested

__all__ = ["TESTED_REDIS", "Wire", "Replies"]

#: The redis-py releases (major, minor) this module was tested with.
TESTED_REDIS = frozenset({(7, 4), (8, 0), (8, 1)})

require_tested(__name__, "redis", redis.__version__, TESTED_REDIS, "pip install 'xviz-server[broker]'")

#: Arguments and bulk strings longer than this go between the socket and their own buffer, not through a shared one.
LARGE = 64 * 1024
#: The longest reply line taken from the broker (a type and a length, a status or an error).
MAX_LINE = 64 * 1024
#: The longest bulk string taken from the broker: Redis's own default ``proto-max-bulk-len``.
MAX_BULK = 512 * 1024 * 1024
#: The largest buffer for large bulk strings kept from one reply to the next.
KEEP = 32 * 1024 * 1024
#: The room first given to a large bulk string, doubled as it fills: what a length costs before its bytes come.
FIRST_ROOM = 1024 * 1024
#: The deepest nesting of arrays taken from the broker (an XREAD reply is 5 deep).
MAX_DEPTH = 16

_KINDS = frozenset(b"$*+-:")  # the first byte of each kind of RESP2 reply
_MORE = object()  # the bytes so far end inside a value
_OPENED = object()  # an array was opened


class Replies:
    """The broker's replies (RESP2), parsed from a buffer the socket reads into.

    Sans I/O: :meth:`buffer` is where the next bytes go, :meth:`received`
    takes how many came and returns the replies they completed. A bulk
    string longer than :data:`LARGE` is read into a buffer kept for them
    (at most :data:`KEEP` bytes are kept between replies), in as many reads
    as it takes, and copied out once; that buffer grows as the bytes come
    (from :data:`FIRST_ROOM`, doubled when full), so a length alone costs
    little. Strings come out as :class:`bytes`,
    integers as :class:`int`, nil as ``None``, arrays as :class:`list` and
    error replies as :class:`~redis.exceptions.ResponseError` instances.
    Bytes that are not RESP2, and arrays nested over :data:`MAX_DEPTH` deep,
    raise :class:`~redis.exceptions.InvalidResponse`.
    """

    def __init__(self) -> None:
        # Room for one unfinished line (at most MAX_LINE) or small bulk string (at most LARGE), and as much to read into.
        self._buffer = bytearray(2 * max(LARGE, MAX_LINE))
        self._start = self._end = 0  # the bytes read and not parsed yet
        self._large = bytearray()  # where a large bulk string is read, with its CRLF
        self._length: int | None = None  # of the large bulk string being read
        self._filled = 0
        self._arrays: list[tuple[list[Any], int]] = []  # the arrays being filled, outermost first

    def buffer(self) -> memoryview:
        """Where the socket puts the next bytes (never empty)."""
        if self._length is not None:
            if self._filled == len(self._large):  # full, and the string goes on: twice the room, at most what is left
                grown = bytearray(min(self._length + 2, 2 * len(self._large)))
                grown[: self._filled] = self._large
                self._large = grown
            return memoryview(self._large)[self._filled : self._length + 2]
        if self._start == self._end:
            self._start = self._end = 0
        elif self._start and len(self._buffer) - self._end < LARGE:  # room for a whole line or small string
            pending = self._end - self._start
            self._buffer[:pending] = self._buffer[self._start : self._end]
            self._start, self._end = 0, pending
        return memoryview(self._buffer)[self._end :]

    def received(self, nbytes: int) -> list[Any]:
        """Take ``nbytes`` more bytes, put by the socket at :meth:`buffer`; the replies they complete."""
        replies: list[Any] = []
        if self._length is not None:
            self._filled += nbytes
            if self._filled < self._length + 2:
                return replies
            self._place(self._take_large(), replies)
        else:
            self._end += nbytes
        while (value := self._value()) is not _MORE:
            self._place(value, replies)
        return replies

    def _place(self, value: Any, replies: list[Any]) -> None:
        """Put a whole ``value`` in the array being filled, or in ``replies`` if none is (or it completes one)."""
        while value is not _OPENED and self._arrays:
            items, count = self._arrays[-1]
            items.append(value)
            if len(items) < count:
                return
            self._arrays.pop()
            value = items
        if value is not _OPENED:
            replies.append(value)

    def _take_large(self) -> bytes:
        """The large bulk string read whole, with its CRLF, copied out."""
        assert self._length is not None
        length, self._length = self._length, None
        _check_end(self._large, length)
        with memoryview(self._large) as whole:
            value = bytes(whole[:length])
        if len(self._large) > KEEP:
            self._large = bytearray()
        return value

    def _value(self) -> Any:
        """The next whole value, ``_OPENED`` after an array's header, ``_MORE`` when the rest is still to come."""
        buffer, start, end = self._buffer, self._start, self._end
        eol = buffer.find(b"\r\n", start, end)
        if eol < 0:
            if end - start > MAX_LINE:
                raise InvalidResponse(f"a line of over {MAX_LINE} bytes from the broker")
            if end > start and buffer[start] not in _KINDS:  # refused at once, as hiredis does, not at the line's end
                raise InvalidResponse(f"not a RESP2 reply from the broker: {bytes(buffer[start : start + 40])!r}")
            return _MORE
        if buffer.find(b"\r", start, eol) >= 0:  # a CR that is not a line's end, as hiredis refuses it
            raise InvalidResponse(
                f"a line from the broker holds a lone CR: {bytes(buffer[start : min(eol, start + 40)])!r}"
            )
        kind, line, after = buffer[start], bytes(buffer[start + 1 : eol]), eol + 2
        if kind == ord("$"):
            length = _length(line)
            if length > MAX_BULK:
                raise InvalidResponse(f"a bulk string of {length} bytes from the broker (at most {MAX_BULK})")
            if length == -1:
                value: Any = None
            elif after + length + 2 <= end:
                _check_end(buffer, after + length)
                value, after = bytes(buffer[after : after + length]), after + length + 2
            elif length > LARGE:  # the rest of it is read into self._large
                here = end - after  # less than the string and its CRLF (else the branch above took it)
                room = min(length + 2, max(here, FIRST_ROOM))
                if len(self._large) < room:
                    self._large = bytearray(room)
                self._large[:here] = memoryview(buffer)[after:end]
                self._start, self._length, self._filled = end, length, here
                return _MORE
            else:
                return _MORE
        elif kind == ord("*"):
            count = _length(line)
            self._start = after
            if count > 0:
                if len(self._arrays) >= MAX_DEPTH:
                    raise InvalidResponse(f"a reply of arrays nested over {MAX_DEPTH} deep from the broker")
                self._arrays.append(([], count))
                return _OPENED
            return None if count == -1 else []
        elif kind == ord("+"):
            value = line
        elif kind == ord("-"):
            value = ResponseError(line.decode(errors="replace"))
        elif kind == ord(":"):
            value = _integer(line)
        else:
            raise InvalidResponse(f"not a RESP2 reply from the broker: {bytes(buffer[start : min(eol, start + 40)])!r}")
        self._start = after
        return value


def _check_end(data: bytearray, at: int) -> None:
    """Raise unless the bulk string whose bytes end at ``at`` in ``data`` is followed by CRLF there."""
    if data[at : at + 2] != b"\r\n":
        raise InvalidResponse("a bulk string from the broker does not end where its length says")


def _integer(line: bytes) -> int:
    """A RESP integer as hiredis reads one: a signed 64-bit decimal, no leading zero, no ``-0``.

    (``int()`` alone would also take ``b" +0_1"``.)
    """
    digits = line[1:] if line[:1] == b"-" else line
    canonical = digits.isdigit() and len(digits) <= 19 and (digits[:1] != b"0" or line == b"0")
    if not canonical or not -(2**63) <= (value := int(line)) < 2**63:
        raise InvalidResponse(f"not an integer from the broker: {line[:40]!r}")
    return value


def _length(line: bytes) -> int:
    length = _integer(line)
    if length < -1:
        raise InvalidResponse(f"a length of {length} from the broker")
    return length


class Wire(asyncio.BufferedProtocol):
    """A connection to the broker, RESP2 written and read by hand."""

    def __init__(self) -> None:
        self._transport: asyncio.Transport | None = None
        self._replies = Replies()
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
            connecting = loop.create_connection(
                lambda: wire, host, port, ssl=tls, server_hostname=host if tls else None
            )
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

    # -- asyncio.BufferedProtocol -------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)

    def get_buffer(self, sizehint: int) -> memoryview:
        return self._replies.buffer()

    def buffer_updated(self, nbytes: int) -> None:
        if self._lost is not None:
            return  # what follows bytes that were not RESP is not read
        try:
            replies = self._replies.received(nbytes)
        except InvalidResponse as exc:
            self._fail(ConnectionError(f"the broker's connection carried what is not RESP: {exc}"))
            assert self._transport is not None
            self._transport.close()
            return
        for reply in replies:
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
        self._fail(ConnectionError(f"the broker closed the connection{f': {exc}' if exc else ''}"))

    def _fail(self, error: Exception) -> None:
        if self._lost is None:
            self._lost = error
        while self._waiting:
            waiting = self._waiting.popleft()
            if not waiting.done():
                waiting.set_exception(self._lost)
