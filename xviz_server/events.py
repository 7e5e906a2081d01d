"""The vocabulary both protocol faces share: the events their sessions answer with, and the facts they are told.

The XVIZ session (:mod:`xviz_server.xviz.session`) and the Foxglove session
(:mod:`xviz_server.foxglove.session`) are sans-I/O state machines: fed what
happened on a connection, they answer with events that the asyncio side
(:mod:`xviz_server.face` and each face's connection) carries out. The events
and inputs that mean the same on both faces are declared here, once: send
bytes, close, open a recorded log, look up and follow a live feed, and what
the live feed registry knows (:class:`LiveFacts`). :class:`Variant` says how
an XVIZ live viewer wants a feed's updates; the live side (:mod:`xviz_server.live`)
encodes each update once per variant. Each face declares the events only it
has beside its session. Nothing here does I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

from .codec import Format
from .levels import FULL, Level

__all__ = ["Send", "Close", "OpenLog", "LookUpLive", "LiveFacts", "SubscribeLive", "Variant"]


@dataclass(frozen=True)
class Send:
    """Send ``data``; as a text frame when ``text``.

    ``error`` names the kind of a message that reports a problem (an
    ``xviz/error``, a Foxglove ``status`` of level error), ``notice`` the
    kind of one that only informs (a live feed went away); ``message`` is
    its text, for the server's log.
    """

    data: bytes
    text: bool
    error: str | None = None
    notice: str | None = None
    message: str | None = None


@dataclass(frozen=True)
class Close:
    """Close the connection with ``code`` and ``reason``."""

    code: int
    reason: str


@dataclass(frozen=True)
class OpenLog:
    """Open the recorded log ``name``, then tell the session ``log_opened`` or ``log_failed``."""

    name: str


@dataclass(frozen=True)
class LookUpLive:
    """Tell the session's ``live_found`` what the live feed registry knows of feed ``name`` (``None``: none named)."""

    name: str | None


@dataclass(frozen=True)
class LiveFacts:
    """What the live feed registry knows when a viewer asks for a feed: facts, for the session to decide on."""

    allowed: bool  #: the name asked for could be a feed's (none asked for is allowed)
    exists: bool  #: a source created the feed of that name (it may not have sent its metadata yet)
    started: bool  #: that feed has its metadata
    running: tuple[str, ...]  #: every feed whose source is connected and has sent its metadata


@dataclass(frozen=True)
class SubscribeLive:
    """Follow live feed ``name``, waiting for a source to create it if none has; then tell the session
    ``live_joined`` (or ``live_failed`` if it cannot be waited for)."""

    name: str


@dataclass(frozen=True)
class Variant:
    """How a live viewer wants updates: format, streams (``None``: all), most points per cloud, level of detail."""

    fmt: Format
    streams: frozenset[str] | None = None
    max_points: int | None = None
    level: Level = FULL
