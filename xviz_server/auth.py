"""Shared-token checks of WebSocket handshakes and HTTP requests."""

from __future__ import annotations

import hmac
from urllib.parse import parse_qsl, urlsplit

from websockets.http11 import Request

__all__ = ["given_token", "token_matches"]


def given_token(request: Request) -> str | None:
    """The token of a request: ``Authorization: Bearer <token>``, else the ``token`` query parameter."""
    authorization = request.headers.get("Authorization", "")
    if authorization.startswith("Bearer "):
        return authorization.removeprefix("Bearer ")
    return dict(parse_qsl(urlsplit(request.path).query)).get("token")


def token_matches(request: Request, token: str) -> bool:
    """Whether the request gives ``token`` (compared in constant time)."""
    given = given_token(request)
    return given is not None and hmac.compare_digest(given.encode(), token.encode())
