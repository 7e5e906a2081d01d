"""What a connection is refused before the WebSocket handshake starts, and HEAD requests.

The port speaks HTTP GET (WebSocket handshakes and the few HTTP endpoints),
HEAD and OPTIONS. websockets' request parser reads GET only and closes the
connection without an answer on a request it cannot read, such as one with
a body; so the first bytes of each connection are looked at here, before
they reach the parser:

* ``HEAD`` is read as ``GET`` and answered as GET would be, without the
  body (its ``Content-Length`` is the GET's); a HEAD that asks for a
  WebSocket handshake is answered ``405 Method Not Allowed``;
* ``OPTIONS`` is read as ``GET`` too (:attr:`GatedConnection.preflight`
  set), for ``process_request`` to answer: :meth:`GatedConnection.options`,
  ``204 No Content`` with ``Allow: GET, HEAD``, and CORS headers where the
  server lets pages of other origins read (a log's file); never a handshake;
* a request with another method (``POST /``, ``PUT``) is answered ``405
  Method Not Allowed`` with ``Allow: GET, HEAD``, and bytes that are no HTTP
  request ``400 Bad Request``; the connection is then closed;
* a TLS handshake on a port without TLS is logged (it says how to connect)
  and the connection closed: a TLS client cannot read an HTTP answer.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from http import HTTPStatus

from websockets.asyncio.server import ServerConnection
from websockets.http11 import SERVER, Request, Response

from .framing import close_body

__all__ = ["ALLOW", "GatedConnection"]

logger = logging.getLogger(__name__)

_SERVED = "WebSocket sessions, and GET /, /healthz or /metrics"
#: The methods served: what ``Allow`` says.
ALLOW = "GET, HEAD"
_METHODS = (b"GET", b"HEAD", b"OPTIONS")  # those answered
_TLS_HANDSHAKE = 0x16  # content type of a TLS record carrying a handshake (ClientHello)

ProcessResponse = Callable[[ServerConnection, Request, Response], Awaitable[Response | None] | Response | None]


class GatedConnection(ServerConnection):
    """A :class:`~websockets.asyncio.server.ServerConnection` that answers GET, HEAD and OPTIONS requests only."""

    _head: bytes | None = b""  # the first bytes received, until they tell the method
    _refused = False
    #: Whether the request is a HEAD: its response goes without its body.
    head_only = False
    #: Whether the request is an OPTIONS (a browser's CORS preflight): ``process_request`` answers it, and a
    #: handshake it would accept is answered :meth:`options` instead.
    preflight = False

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if self._head is not None:
            head = self._head + data
            method, space, rest = head.partition(b" ")
            if not space and any(known.startswith(head) for known in _METHODS):
                self._head = head  # too few bytes yet to tell
                return
            self._head = None
            if method == b"HEAD":
                self.head_only = True
                data = b"GET " + rest
            elif method == b"OPTIONS":
                self.preflight = True
                data = b"GET " + rest
            elif method == b"GET" and space:
                data = head
            else:
                self._refused = True
                self._refuse(head[:16])
                return
        super().data_received(data)

    async def handshake(
        self,
        process_request: Callable[[ServerConnection, Request], Awaitable[Response | None] | Response | None]
        | None = None,
        process_response: ProcessResponse | None = None,
        server_header: str | None = SERVER,
    ) -> None:
        async def respond(connection: ServerConnection, request: Request, response: Response) -> Response | None:
            if process_response is not None:
                changed = process_response(connection, request, response)
                if isinstance(changed, Awaitable):
                    changed = await changed
                response = changed or response
            if self.preflight and response.status_code == HTTPStatus.SWITCHING_PROTOCOLS:
                response = self.options()
            if not self.head_only:
                return response
            if response.status_code == HTTPStatus.SWITCHING_PROTOCOLS:
                response = self._method_not_allowed("HEAD")
            await close_body(response)  # a streamed body is not sent
            return Response(
                response.status_code, response.reason_phrase, response.headers
            )  # its head only, whatever its kind

        await super().handshake(process_request, respond, server_header)

    def options(self) -> Response:
        """The answer to an ``OPTIONS`` request: ``204 No Content`` with ``Allow: GET, HEAD``."""
        response = self.respond(HTTPStatus.NO_CONTENT, "")
        del response.headers["Content-Type"], response.headers["Content-Length"]
        response.headers["Allow"] = ALLOW
        return response

    def _method_not_allowed(self, method: str) -> Response:
        logger.info("refused a %s request from %s: only GET and HEAD are served", method, self.remote_address)
        response = self.respond(HTTPStatus.METHOD_NOT_ALLOWED, f"only GET and HEAD are served here: {_SERVED}\n")
        response.headers["Allow"] = ALLOW
        return response

    def _refuse(self, head: bytes) -> None:
        assert self.transport is not None
        if head[0] == _TLS_HANDSHAKE and self.transport.get_extra_info("sslcontext") is None:
            logger.warning(
                "a TLS handshake from %s on a port without TLS: connect with ws:// or http://, "
                "or start the server with --certfile and --keyfile",
                self.remote_address,
            )
        else:
            method = head.partition(b" ")[0]
            if method.isalpha() and method.isupper():
                response = self._method_not_allowed(method.decode())
            else:
                response = self.respond(HTTPStatus.BAD_REQUEST, f"not an HTTP request; this port serves {_SERVED}\n")
            self.transport.write(response.serialize())
        self.transport.close()
