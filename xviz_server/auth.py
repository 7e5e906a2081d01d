"""Who may connect where: shared-token checks of WebSocket handshakes and HTTP requests.

Live sources push to ``/ingest/<name>``: with an ingest token configured, a
source must give it (header ``Authorization: Bearer <token>`` or query
``token=``); without one, only sources on the loopback interface are accepted.
"""

from __future__ import annotations

import hmac
import ipaddress
from collections.abc import Sequence
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

from websockets.http11 import Request

from .exceptions import XVIZError
from .layout import check_log_name

__all__ = ["INGEST_PREFIX", "given_token", "token_matches", "feed_name", "ingest_refusal"]


def given_token(request: Request) -> str | None:
    """The token of a request: ``Authorization: Bearer <token>``, else the ``token`` query parameter.

    A query that repeats ``token`` gives none (a proxy or a log in front of the
    server may take another of its values than the server would): the request
    is refused as one without a token.
    """
    authorization = request.headers.get("Authorization", "")
    if authorization.startswith("Bearer "):
        return authorization.removeprefix("Bearer ")
    values = [value for key, value in parse_qsl(urlsplit(request.path).query, keep_blank_values=True) if key == "token"]
    return values[0] if len(values) == 1 else None


def token_matches(request: Request, token: str) -> bool:
    """Whether the request gives ``token`` (compared in constant time)."""
    given = given_token(request)
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


INGEST_PREFIX = "/ingest/"


def feed_name(path: str) -> str | None:
    """The feed named by an ingest URL path, or ``None`` if it is not one."""
    route = unquote(urlsplit(path).path)
    return route[len(INGEST_PREFIX) :] if route.startswith(INGEST_PREFIX) else None


def ingest_refusal(request: Request, remote: Any, token: str | None, origins: Sequence[str] = ()) -> str | None:
    """Why an ingest connection is refused, or ``None`` if it is allowed.

    A browser page (a request with an ``Origin``) may push only from one of
    ``origins``: otherwise any page open on the server's host could.
    """
    name = feed_name(request.path) or ""
    try:
        check_log_name(name)
    except XVIZError as exc:
        return f"bad feed name: {exc}"
    origin = request.headers.get("Origin")
    if origin is not None and origin not in origins:
        return f"browser pages may not push live feeds (Origin {origin[:100]!r}); allow it with --allowed-origins"
    if token is None:
        host = remote[0] if remote else ""
        try:
            if ipaddress.ip_address(host.split("%")[0]).is_loopback:
                return None
        except ValueError:
            pass
        return "ingest from other hosts needs a token; start the server with --ingest-token"
    if not token_matches(request, token):
        return "wrong or missing ingest token"
    return None
