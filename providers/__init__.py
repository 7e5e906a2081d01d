"""Log providers: where the frames a session serves come from.

A provider opens what :func:`xviz_server.layout.discover` found (or what the
command line named) as a :class:`LogSource`. Sources hand out frames as
encoded bytes; everything above them (the shared frame cache, transcoding,
stream filtering, the time index queries) is common to every provider and
lives in :mod:`xviz_server.logs`.
"""

from __future__ import annotations

from typing import Any, Protocol

from ..codec import Format
from ..layout import Found
from ..timeindex import TimeIndex

__all__ = ["LogSource", "Provider"]


class LogSource(Protocol):
    """One log of a provider."""

    #: The log's name, as clients ask for it.
    name: str
    #: Format of its frames as stored; sessions get it unless they ask otherwise.
    format: Format

    async def metadata(self) -> dict[str, Any]:
        """The data of the log's ``xviz/metadata`` message."""
        ...

    async def index(self) -> TimeIndex:
        """The time span of every frame."""
        ...

    async def read(self, frame: int) -> bytes:
        """Frame number ``frame`` (its message index) as encoded bytes.

        Raises :class:`~xviz_server.exceptions.FrameError` naming the file or
        record at fault.
        """
        ...

    def describe_frame(self, frame: int) -> str:
        """How a frame is named in error messages (its file or record)."""
        ...


class Provider(Protocol):
    """Opens the logs of some kinds of :class:`~xviz_server.layout.Found` entries."""

    async def open(self, found: Found) -> LogSource:
        """Open a log; raises :class:`~xviz_server.exceptions.LogError` when it cannot be served."""
        ...
