"""Log output: one line per event, as text (default) or as JSON objects.

Events that operators count (a session starting or ending, an error sent)
go through :func:`log_event`, which keeps their fields apart: the text
format shows them as ``key=value`` pairs, the JSON format as keys of the
object, beside ``time``, ``level``, ``logger`` and ``message``.

What clients send reaches the log only through :func:`redact_url` (request
paths lose the values of credential-looking query parameters) and
:func:`printable` (every line is one line, with no terminal escape codes):
both formats escape the non-printable characters of messages and fields.
"""

from __future__ import annotations

import datetime
import logging
import re
import sys
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote_plus, urlsplit, urlunsplit

import orjson

if TYPE_CHECKING:
    from websockets.asyncio.server import ServerConnection

__all__ = [
    "configure_logging",
    "log_event",
    "printable",
    "redact_url",
    "redact_password",
    "peer",
    "ending",
    "JsonFormatter",
    "TextFormatter",
]

_FIELDS = "xviz_fields"

#: Query parameters whose value is a credential: their names contain one of these words.
_CREDENTIAL = re.compile(r"token|auth|key|pass|secret|signature|sig$|credential|session_id", re.IGNORECASE)
REDACTED = "REDACTED"


def redact_url(path: str) -> str:
    """``path`` (a request target) with the value of every credential-looking query parameter replaced.

    ``/?log=demo&token=s3cret`` becomes ``/?log=demo&token=REDACTED``;
    parameter names are matched case-insensitively after percent-decoding
    (``TOKEN``, ``%74oken``, ``access_token``, ``api_key``, ``password`` ...).
    """
    route, separator, query = path.partition("?")
    if not separator:
        return path
    parts = []
    for part in query.split("&"):
        name, equals, _ = part.partition("=")
        parts.append(f"{name}={REDACTED}" if equals and _CREDENTIAL.search(unquote_plus(name)) else part)
    return f"{route}?{'&'.join(parts)}"


def redact_password(url: str) -> str:
    """``url`` (a service's, like ``redis://:s3cret@host:6379/0``) with the password of its user info replaced."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    user = f"{parts.username}:" if parts.username else ":"
    host = parts.netloc.rpartition("@")[2]
    return urlunsplit(parts._replace(netloc=f"{user}{REDACTED}@{host}"))


def printable(text: str) -> str:
    """``text`` with every non-printable character escaped as in Python (``\\x1b``, ``\\r``, ``\\u2028``)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def peer(websocket: ServerConnection) -> str:
    """The client's address as log lines show it: ``host:port`` (``?`` when unknown)."""
    address = websocket.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"


def ending(websocket: ServerConnection) -> dict[str, Any]:
    """How a session's connection ended, as fields of its last log line.

    ``reason`` is the close code and reason of the side that closed first
    (``connection lost`` if neither did), and ``closed_by`` says which side
    that was (``client`` or ``server``), so that a code a client sends (1011
    when its own program failed) is never taken for the server's.
    """
    protocol = websocket.protocol
    first = protocol.close_rcvd if protocol.close_rcvd_then_sent else protocol.close_sent
    if first is None:
        return {"reason": "connection lost"}
    return {
        "reason": f"{first.code} {first.reason}".strip(),
        "closed_by": "client" if protocol.close_rcvd_then_sent else "server",
    }


def log_event(logger: logging.Logger, event: str, level: int = logging.INFO, **fields: Any) -> None:
    """Log ``event`` with its fields (``remote=...``, ``log=...``)."""
    if logger.isEnabledFor(level):
        text = " ".join([event, *(f"{key}={value}" for key, value in fields.items())])  # escaped by the formatters
        logger.log(level, text, extra={_FIELDS: {"event": event, **fields}})


class JsonFormatter(logging.Formatter):
    """One JSON object per line."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "time": datetime.datetime.fromtimestamp(record.created, datetime.timezone.utc).isoformat(
                timespec="milliseconds"
            ),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": printable(record.getMessage()),
        }
        fields = getattr(record, _FIELDS, {})
        line.update((key, printable(value) if isinstance(value, str) else value) for key, value in fields.items())
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        return orjson.dumps(line, default=str).decode()


class TextFormatter(logging.Formatter):
    """``time level logger: message``, one line per record; tracebacks follow, each line escaped."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s")

    def formatMessage(self, record: logging.LogRecord) -> str:
        return printable(super().formatMessage(record))

    def formatException(self, ei: Any) -> str:
        return "\n".join(map(printable, super().formatException(ei).split("\n")))


def configure_logging(fmt: str = "text", level: int = logging.INFO) -> None:
    """Send log lines to standard error in ``fmt`` (``text`` or ``json``)."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(TextFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
    logging.getLogger("websockets").setLevel(logging.WARNING)
