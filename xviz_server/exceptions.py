"""Every exception that xviz-server raises on purpose.

All of them derive from :class:`XVIZError`, so a caller can catch the whole
family in one place. Each message is written for the person who has to act on
it: it names the file, offset, field or request that is wrong and says why.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "XVIZError",
    "DecodeError",
    "EncodeError",
    "MessageError",
    "SchemaValidationError",
    "UnknownSchemaError",
    "LogNotFound",
    "LogError",
    "FrameError",
    "WorkerError",
    "BuilderError",
    "LogWriteError",
    "DatasetError",
    "OversizeError",
    "FrameSizeError",
    "ConfigError",
    "DependencyError",
    "StoreError",
    "BrokerError",
    "QueryError",
    "FoxgloveProtocolError",
    "ExportError",
]


class XVIZError(Exception):
    """Base class of every error raised by xviz-server."""


class DecodeError(XVIZError):
    """Bytes or text could not be decoded as an XVIZ message.

    ``offset`` is the byte offset of the problem when it is known.
    """

    def __init__(self, message: str, *, offset: int | None = None) -> None:
        super().__init__(message)
        self.offset = offset


class EncodeError(XVIZError):
    """A message could not be encoded (for example an unsupported value type)."""


class MessageError(XVIZError):
    """A session message from a client is malformed or has a wrong field.

    ``message_type`` is the XVIZ type (``"transform_log"`` ...) when known and
    ``request_id`` the id the client gave its request, so that the error sent
    back can name both.
    """

    def __init__(
        self,
        message: str,
        *,
        message_type: str | None = None,
        request_id: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message_type = message_type
        self.request_id = request_id


class SchemaValidationError(XVIZError):
    """A message does not conform to the XVIZ v2 JSON schema.

    ``problems`` lists one human-readable line per violation, each starting
    with the JSON path of the offending value.
    """

    def __init__(self, schema: str, problems: list[str]) -> None:
        lines = "\n".join(f"  {p}" for p in problems)
        super().__init__(f"does not match XVIZ schema {schema!r}:\n{lines}")
        self.schema = schema
        self.problems = problems


class UnknownSchemaError(XVIZError, KeyError):
    """No XVIZ schema has the requested name; the message suggests close names."""

    def __str__(self) -> str:
        return str(self.args[0])


class LogNotFound(XVIZError):
    """A client named a log that the server does not serve (or may not name)."""

    def __init__(self, message: str, *, name: str, available: list[str]) -> None:
        super().__init__(message)
        self.name = name
        self.available = available


class LogError(XVIZError):
    """A log exists but cannot be served: no metadata, unreadable, unsupported format."""

    def __init__(self, message: str, *, log: str) -> None:
        super().__init__(message)
        self.log = log


class FrameError(XVIZError):
    """One frame of a log cannot be read or decoded; the rest of the log may be fine."""

    def __init__(self, message: str, *, log: str, frame: int) -> None:
        super().__init__(message)
        self.log = log
        self.frame = frame


class WorkerError(XVIZError):
    """A job's worker process died twice: once in the pool it was sent to, once in the pool that replaced it."""


class BuilderError(XVIZError):
    """The builder was given something XVIZ cannot carry; the message names the stream and field."""


class DatasetError(XVIZError):
    """A raw dataset file is missing or unreadable; ``path`` names it."""

    def __init__(self, message: str, *, path: object = None) -> None:
        super().__init__(message)
        self.path = path


class OversizeError(DatasetError):
    """A recording declares, or unpacks to, more bytes than it may: a damaged file or a decompression bomb.

    ``size`` is what it declared (or the bytes it had unpacked to when
    refused) and ``limit`` the bound it broke; the message names the file
    and the part (``FILE: chunk at byte N``).
    """

    def __init__(self, message: str, *, size: int, limit: int, path: object = None) -> None:
        super().__init__(message, path=path)
        self.size = size
        self.limit = limit

    def __reduce__(self) -> tuple[Any, ...]:  # from a worker process: the fields are keyword-only
        return _rebuild_oversize_error, (str(self), self.size, self.limit, self.path)


def _rebuild_oversize_error(message: str, size: int, limit: int, path: object) -> OversizeError:
    return OversizeError(message, size=size, limit=limit, path=path)


class FrameSizeError(OversizeError):
    """One frame of a recording would unpack to more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` across all
    its messages and images (summed from what its parts declare): it is refused unread. ``frame`` is its number."""

    def __init__(self, message: str, *, size: int, limit: int, frame: int, path: object = None) -> None:
        super().__init__(message, size=size, limit=limit, path=path)
        self.frame = frame

    def __reduce__(self) -> tuple[Any, ...]:  # from a worker process: the fields are keyword-only
        return _rebuild_frame_size_error, (str(self), self.size, self.limit, self.frame, self.path)


def _rebuild_frame_size_error(message: str, size: int, limit: int, frame: int, path: object) -> FrameSizeError:
    return FrameSizeError(message, size=size, limit=limit, frame=frame, path=path)


class LogWriteError(XVIZError):
    """A log directory cannot be written as asked; ``directory`` names it.

    The message says why: a frame or the metadata is missing, a frame is not
    a state update, the directory holds a log of the other format.
    """

    def __init__(self, message: str, *, directory: object) -> None:
        super().__init__(message)
        self.directory = directory


class ConfigError(XVIZError, ValueError):
    """A setting cannot be used as given: the message names the setting or file and says why.

    It is a :class:`ValueError` too, so that settings validation reports it
    beside the setting's other errors.
    """


class DependencyError(XVIZError, ImportError):
    """An installed library is a version that xviz-server was not tested with."""


class StoreError(XVIZError, OSError):
    """A request to an object store failed after its retries; ``key`` is the object's ``s3://`` URL.

    It is an :class:`OSError` too, like a file that cannot be read, since a
    log's bytes come from either.
    """

    def __init__(self, message: str, *, key: str) -> None:
        super().__init__(message)
        self.key = key

    def __reduce__(self) -> tuple[Any, ...]:  # from a worker process: ``key`` is keyword-only
        return _rebuild_store_error, (str(self), self.key)


def _rebuild_store_error(message: str, key: str) -> StoreError:
    return StoreError(message, key=key)


class BrokerError(XVIZError):
    """An entry read from the broker (Redis) between replicas is not one that xviz-server writes."""


class QueryError(XVIZError, ValueError):
    """A parameter of an HTTP query (the catalog's ``GET /api/logs``, an export's) cannot be used; ``parameter`` names it."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter


class FoxgloveProtocolError(XVIZError):
    """A Foxglove client sent a message that the Foxglove WebSocket protocol does not allow."""


class ExportError(QueryError):
    """A clip of a log cannot be exported as asked (a bad range or format); ``parameter`` names the one at fault."""
