"""Log output: one line per event, as text (default) or as JSON objects.

Events that operators count (a session starting or ending, an error sent)
go through :func:`log_event`, which keeps their fields apart: the text
format shows them as ``key=value`` pairs, the JSON format as keys of the
object, beside ``time``, ``level``, ``logger`` and ``message``.
"""

from __future__ import annotations

import datetime
import logging
import sys
from typing import Any

import orjson

__all__ = ["configure_logging", "log_event", "JsonFormatter"]

_FIELDS = "xviz_fields"


def log_event(logger: logging.Logger, event: str, level: int = logging.INFO, **fields: Any) -> None:
    """Log ``event`` with its fields (``remote=...``, ``log=...``)."""
    if logger.isEnabledFor(level):
        text = " ".join([event, *(f"{key}={value}" for key, value in fields.items())])
        logger.log(level, text, extra={_FIELDS: {"event": event, **fields}})


class JsonFormatter(logging.Formatter):
    """One JSON object per line."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "time": datetime.datetime.fromtimestamp(record.created, datetime.timezone.utc).isoformat(timespec="milliseconds"),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        line.update(getattr(record, _FIELDS, {}))
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        return orjson.dumps(line, default=str).decode()


def configure_logging(fmt: str = "text", level: int = logging.INFO) -> None:
    """Send log lines to standard error in ``fmt`` (``text`` or ``json``)."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
    logging.getLogger("websockets").setLevel(logging.WARNING)
