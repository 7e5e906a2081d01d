"""What one client message may cost the server: the items it may list, the problems named, the lines logged.

A client's message is answered within these bounds whatever it holds, on
both faces (XVIZ and Foxglove):

* a list in a message (a Foxglove ``subscribe``'s subscriptions or an
  ``unsubscribe``'s ids, an XVIZ ``desired_streams``) holds at most
  :data:`MAX_ITEMS` items, else the message is refused whole, unread;
* the problems of one message are answered with one error (an
  ``xviz/error``, a Foxglove ``status``) that names the first
  :data:`NAMED` of them and counts the rest (:class:`Problems`), each value
  shown in at most :data:`SHOWN` characters (:func:`shown`);
* a connection logs at most :data:`LOG_LINES` lines about what its client
  sent wrong in :data:`LOG_WINDOW` seconds (:class:`LogThrottle`); the
  next line it logs says how many were left out.
"""

from __future__ import annotations

import logging
import reprlib
import time
from typing import Any

from .logfmt import log_event

__all__ = ["MAX_ITEMS", "NAMED", "SHOWN", "LOG_LINES", "LOG_WINDOW", "shown", "too_many", "Problems", "LogThrottle"]

#: The most items a list in one client message may hold (a log has tens to hundreds of streams and channels).
MAX_ITEMS = 10_000
#: Problems of one message named in its error; the others are counted.
NAMED = 3
#: The most characters of a client's value shown in an error.
SHOWN = 60
#: Lines a connection may log about its client's mistakes in :data:`LOG_WINDOW` seconds.
LOG_LINES = 10
LOG_WINDOW = 10.0

_repr = reprlib.Repr()
_repr.maxlevel, _repr.maxlist, _repr.maxdict, _repr.maxtuple = 2, 4, 4, 4
_repr.maxstring = _repr.maxother = _repr.maxlong = SHOWN


def shown(value: Any) -> str:
    """``value`` as Python writes it, cut to at most :data:`SHOWN` characters; it costs as much whatever its size."""
    text = _repr.repr(value)
    return text if len(text) <= SHOWN else text[: SHOWN - 3] + "..."


def too_many(items: Any) -> bool:
    """Whether ``items`` is a list of more than :data:`MAX_ITEMS` items."""
    return isinstance(items, list) and len(items) > MAX_ITEMS


class Problems:
    """The problems found in one message: the first :data:`NAMED` kept, the others counted."""

    def __init__(self) -> None:
        self.count = 0
        self._named: list[str] = []

    def add(self, problem: str) -> None:
        self.count += 1
        if len(self._named) < NAMED:
            self._named.append(problem)

    def summary(self, what: str, of: int | None = None) -> str | None:
        """One sentence for all of them (``None`` if none): ``"{what}: A"`` for one, else ``"{what}: 524000 of
        524288 items refused: A; B; C; and 523997 more"`` (``of``: the items the message held) or ``"{what}: 5
        problems: A; B; C; and 2 more"``."""
        if not self.count:
            return None
        if self.count == 1:
            return f"{what}: {self._named[0]}"
        counted = f"{self.count} of {of} items refused" if of is not None else f"{self.count} problems"
        rest = f"; and {self.count - len(self._named)} more" if self.count > len(self._named) else ""
        return f"{what}: {counted}: {'; '.join(self._named)}{rest}"


class LogThrottle:
    """Whether a connection may log one more line about its client's mistakes: at most :data:`LOG_LINES`
    lines a :data:`LOG_WINDOW`-second window (sans-I/O: the caller gives the time)."""

    def __init__(self, lines: int = LOG_LINES, window: float = LOG_WINDOW) -> None:
        self._lines, self._window = lines, window
        self._start = -window
        self._logged = 0
        self.left_out = 0  # lines not logged since the last one that was

    def allow(self, now: float) -> bool:
        """Whether a line may be logged at ``now`` (seconds, monotonic); :attr:`left_out` then counts those that were not."""
        if now - self._start >= self._window:
            self._start, self._logged = now, 0
        if self._logged >= self._lines:
            self.left_out += 1
            return False
        self._logged += 1
        return True

    def log(self, logger: logging.Logger, event: str, **fields: Any) -> None:
        """:func:`~xviz_server.logfmt.log_event` unless over the budget; a line logged after some were left out
        says how many (``left_out=N``)."""
        if self.allow(time.monotonic()):
            if self.left_out:
                fields["left_out"], self.left_out = self.left_out, 0
            log_event(logger, event, **fields)
