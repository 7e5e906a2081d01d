"""Log providers: where the frames a session serves come from.

A provider knows a set of logs by name and opens one as a
:class:`LogSource`. Sources hand out frames as encoded bytes; everything
above them (the shared frame cache, transcoding, stream filtering, the time
index queries) is common to every provider and lives in
:mod:`xviz_server.logs`.
"""

from __future__ import annotations

from typing import Any, Protocol

from ..codec import Format
from ..index import TimeIndex

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


class Provider(Protocol):
    """A set of logs."""

    def scan(self) -> list[str]:
        """Names of the logs it serves now; may touch the file system (run it in a thread)."""
        ...

    async def open(self, name: str) -> LogSource:
        """Open a log that :meth:`scan` listed.

        Raises :class:`~xviz_server.exceptions.LogError` when it cannot be served.
        """
        ...
