"""Loopback TCP proxies for tests and benchmarks: one for HTTP/1.1 that adds latency and faults, and a shaped link.

Between a client and a server on this machine, it forwards one request at a
time per connection (as HTTP/1.1 clients send them, without pipelining),
waits ``delay`` seconds before passing each request on, and counts the
requests and how many were in flight at once. :meth:`Proxy.fault` makes
chosen requests answer with an HTTP status, stall, or lose their
connection part way through the response body, or answer with a body
that says it is 1 TiB long and never ends.

:class:`ShapedLink` carries any TCP connection (a WebSocket session) as a
slow network link would: bytes from the server reach the client at most at
:attr:`ShapedLink.mbps` (a token bucket, like ``tc tbf``; changed at any
time), the other way unshaped. Its socket to the server takes only a small
receive buffer, so that, as on a real link, what the link cannot carry yet
waits in the server's send queue, where the server can see it.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import re
import socket
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass

__all__ = ["Fault", "Proxy", "running_proxy", "ShapedLink", "shaped_link"]

_LENGTH = re.compile(rb"\r\ncontent-length:\s*(\d+)", re.IGNORECASE)
_CHUNK = 1 << 20


@dataclass
class Fault:
    """What happens to requests whose target contains ``match``: ``times`` of them (``None``: all)."""

    match: str
    status: int | None = None  # answer this status instead of the server
    cut_after: int | None = None  # reset the connection after this many bytes of the response body
    stall: bool = False  # never answer
    endless: bool = False  # the server's status and headers, but a Content-Length of 1 TiB and zeros that never end
    times: int | None = None
    hits: int = 0


class Proxy:
    """Forwards connections to ``target_port`` on 127.0.0.1 from its own :attr:`port`."""

    def __init__(self, target_port: int, delay: float = 0.0) -> None:
        self.target_port = target_port
        self.delay = delay
        #: ``"METHOD target"`` of every request, in arrival order.
        self.requests: list[str] = []
        #: The head (request line and headers) of every request, in arrival order.
        self.heads: list[bytes] = []
        #: Most requests in flight at once (arrived, response not yet all sent).
        self.most_in_flight = 0
        self.faults: list[Fault] = []
        self._in_flight = 0
        self._server: asyncio.Server | None = None
        self._handlers: set[asyncio.Task[None]] = set()

    @property
    def port(self) -> int:
        assert self._server is not None
        return self._server.sockets[0].getsockname()[1]

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def fault(self, match: str, **what: object) -> Fault:
        """Add a :class:`Fault`; the first whose ``match`` a request's target contains applies."""
        fault = Fault(match, **what)  # type: ignore[arg-type]
        self.faults.append(fault)
        return fault

    def gets(self, match: str = "") -> list[str]:
        """The GET requests whose target contains ``match``."""
        return [r for r in self.requests if r.startswith("GET ") and match in r and "list-type" not in r]

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)

    async def close(self) -> None:
        assert self._server is not None
        self._server.close()
        for task in self._handlers:
            task.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)
        await self._server.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        upstream: asyncio.StreamWriter | None = None
        try:
            server_reader, upstream = await asyncio.open_connection("127.0.0.1", self.target_port)
            while True:
                try:
                    head = await reader.readuntil(b"\r\n\r\n")
                except (asyncio.IncompleteReadError, ConnectionError):
                    return
                method, target = head.split(b" ", 2)[:2]
                body = await reader.readexactly(_length(head))
                request = f"{method.decode()} {target.decode()}"
                self.requests.append(request)
                self.heads.append(head)
                self._in_flight += 1
                self.most_in_flight = max(self.most_in_flight, self._in_flight)
                try:
                    if not await self._exchange(
                        request, head + body, writer, server_reader, upstream, method == b"HEAD"
                    ):
                        return
                finally:
                    self._in_flight -= 1
        except (ConnectionError, asyncio.IncompleteReadError, asyncio.CancelledError):
            return  # cancelled by close()
        finally:
            self._handlers.discard(task)
            writer.transport.abort()
            if upstream is not None:
                upstream.transport.abort()

    async def _exchange(
        self,
        request: str,
        data: bytes,
        client: asyncio.StreamWriter,
        server_reader: asyncio.StreamReader,
        server: asyncio.StreamWriter,
        head_only: bool,
    ) -> bool:
        """Carry one request and its response; whether the connection goes on."""
        await asyncio.sleep(self.delay)
        fault = self._fault(request)
        if fault is not None and fault.stall:
            await asyncio.Event().wait()
        if fault is not None and fault.status is not None:
            text = (
                f'<?xml version="1.0"?><Error><Code>Injected</Code><Message>{fault.status}</Message></Error>'.encode()
            )
            client.write(
                f"HTTP/1.1 {fault.status} Injected\r\nContent-Type: application/xml\r\nContent-Length: {len(text)}\r\n\r\n".encode()
                + text
            )
            await client.drain()
            return True
        server.write(data)
        await server.drain()
        head = await server_reader.readuntil(b"\r\n\r\n")
        length = 0 if head_only else _length(head)
        if fault is not None and fault.endless:
            await server_reader.readexactly(length)
            client.write(_LENGTH.sub(b"\r\ncontent-length: %d" % (1 << 40), head))
            zeros = bytes(_CHUNK)
            while True:  # until the client gives up and the write fails
                client.write(zeros)
                await client.drain()
        client.write(head)
        if fault is not None and fault.cut_after is not None:
            client.write(await server_reader.readexactly(min(fault.cut_after, length)))
            await client.drain()
            return False
        while length:
            chunk = await server_reader.read(min(_CHUNK, length))
            if not chunk:
                return False
            client.write(chunk)
            await client.drain()
            length -= len(chunk)
        return True

    def _fault(self, request: str) -> Fault | None:
        for fault in self.faults:
            if fault.match in request and (fault.times is None or fault.hits < fault.times):
                fault.hits += 1
                return fault
        return None


def _length(head: bytes) -> int:
    match = _LENGTH.search(head)
    return int(match.group(1)) if match else 0


@contextlib.asynccontextmanager
async def running_proxy(target_port: int, delay: float = 0.0) -> AsyncIterator[Proxy]:
    """A started :class:`Proxy`, closed on exit."""
    proxy = Proxy(target_port, delay)
    await proxy.start()
    try:
        yield proxy
    finally:
        await proxy.close()


class ShapedLink:
    """Forwards connections to ``target_port`` on 127.0.0.1 from its own :attr:`port`, the server's bytes at
    :attr:`mbps` Mbit/s at most (``None``: unshaped), with bursts of at most ``burst`` bytes. It notes when each
    burst went (a few bytes a burst, for :meth:`carried_by`): a link for a test, not for hours of traffic."""

    #: Receive buffer of the socket to the server, bytes: how much the link holds in flight.
    RECEIVE_BUFFER = 16 * 1024

    def __init__(self, target_port: int, mbps: float | None, burst: int = 64 * 1024) -> None:
        self.target_port = target_port
        self.mbps = mbps
        self.burst = burst
        #: Bytes carried from the server to clients, in all.
        self.carried = 0
        self._history: list[tuple[float, int]] = []  # (time.time(), carried) after each burst
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @property
    def port(self) -> int:
        assert self._server is not None
        return self._server.sockets[0].getsockname()[1]

    def carried_by(self, when: float) -> int:
        """Bytes carried from the server to clients by ``when`` (seconds since the epoch, as :func:`time.time`: a
        moment another process on this machine tells)."""
        after = bisect.bisect_right(self._history, (when, self.carried))
        return self._history[after - 1][1] if after else 0

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)

    async def close(self) -> None:
        assert self._server is not None
        self._server.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self._server.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        upstream = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        upstream.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.RECEIVE_BUFFER)
        upstream.setblocking(False)
        try:
            await loop.sock_connect(upstream, ("127.0.0.1", self.target_port))
        except OSError:
            upstream.close()
            writer.transport.abort()
            return
        server_reader, server_writer = await asyncio.open_connection(sock=upstream, limit=self.RECEIVE_BUFFER)
        pumps = [
            asyncio.ensure_future(self._pump(reader, server_writer, shaped=False)),
            asyncio.ensure_future(self._pump(server_reader, writer, shaped=True)),
        ]
        self._tasks.update(pumps)
        try:
            await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for pump in pumps:
                pump.cancel()
                self._tasks.discard(pump)
            writer.transport.abort()
            server_writer.transport.abort()

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, shaped: bool) -> None:
        due = time.monotonic()  # when the bytes sent so far have gone through the link
        try:
            while True:
                chunk = await reader.read(self.burst if shaped else 1 << 16)
                if not chunk:
                    return
                if shaped and self.mbps is not None:
                    now = time.monotonic()
                    due = max(due, now - self.burst / (self.mbps * 125_000)) + len(chunk) / (self.mbps * 125_000)
                    if due > now:
                        await asyncio.sleep(due - now)
                writer.write(chunk)
                await writer.drain()
                if shaped:
                    self.carried += len(chunk)
                    self._history.append((time.time(), self.carried))
        except (ConnectionError, asyncio.IncompleteReadError):
            return


@contextlib.asynccontextmanager
async def shaped_link(target_port: int, mbps: float | None) -> AsyncIterator[ShapedLink]:
    """A started :class:`ShapedLink`, closed on exit."""
    link = ShapedLink(target_port, mbps)
    await link.start()
    try:
        yield link
    finally:
        await link.close()
