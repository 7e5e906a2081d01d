"""What a connection is refused before the WebSocket handshake starts.

The port speaks HTTP GET only: WebSocket handshakes and the few HTTP
endpoints. websockets' request parser closes the connection without an
answer on a request it cannot read, such as one with a body; so the first
bytes of each connection are looked at here, before they reach the parser:

* a request with another method (``POST /``, ``PUT``, ``HEAD``) is answered
  ``405 Method Not Allowed`` with ``Allow: GET``, and bytes that are no HTTP
  request ``400 Bad Request``; the connection is then closed;
* a TLS handshake on a port without TLS is logged (it says how to connect)
  and the connection closed: a TLS client cannot read an HTTP answer.
"""

from __future__ import annotations

import logging
from http import HTTPStatus

from websockets.asyncio.server import ServerConnection

__all__ = ["GatedConnection"]

logger = logging.getLogger(__name__)

_GET = b"GET "
_SERVED = "WebSocket sessions, and GET /, /healthz or /metrics"
_TLS_HANDSHAKE = 0x16  # content type of a TLS record carrying a handshake (ClientHello)


class GatedConnection(ServerConnection):
    """A :class:`~websockets.asyncio.server.ServerConnection` that refuses anything but a GET request."""

    _head: bytes | None = b""  # the first bytes received, until they tell a GET from anything else
    _refused = False

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if self._head is not None:
            head = (self._head + data)[: len(_GET)]
            if head == _GET:
                self._head = None
            elif _GET.startswith(head):
                self._head = head  # too few bytes yet to tell
            else:
                self._refused = True
                self._refuse(head)
                return
        super().data_received(data)

    def _refuse(self, head: bytes) -> None:
        assert self.transport is not None
        if head[0] == _TLS_HANDSHAKE and self.transport.get_extra_info("sslcontext") is None:
            logger.warning(
                "a TLS handshake from %s on a port without TLS: connect with ws:// or http://, "
                "or start the server with --certfile and --keyfile", self.remote_address,
            )
        else:
            method = head.partition(b" ")[0]
            if method.isalpha() and method.isupper():
                logger.info("refused a %s request from %s: only GET is served", method.decode(), self.remote_address)
                response = self.respond(HTTPStatus.METHOD_NOT_ALLOWED, f"only GET is served here: {_SERVED}\n")
                response.headers["Allow"] = "GET"
            else:
                response = self.respond(HTTPStatus.BAD_REQUEST, f"not an HTTP request; this port serves {_SERVED}\n")
            self.transport.write(response.serialize())
        self.transport.close()
