"""xviz-server: an asyncio WebSocket server for the XVIZ v2 protocol.

The public API, importable from here::

    from xviz_server import XVIZServer, Settings

    async with XVIZServer(Settings(port=3000, data_dir=logs)) as server:
        feed = server.live.feed("car")          # a LiveFeed
        feed.set_metadata(MetadataBuilder()...build())
        await feed.publish(FrameBuilder(metadata)...build())

The scripted client is :func:`xviz_server.probe.probe`. Names are imported
on first use, so that ``import xviz_server`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from . import exceptions as _exceptions

_HOMES = {
    "XVIZServer": "server",
    "Settings": "settings",
    "LiveFeed": "live",
    "MetadataBuilder": "builder",
    "FrameBuilder": "builder",
    "LogWriter": "writer",
    "ProbeReport": "probe",
    "__version__": "version",
    **dict.fromkeys(_exceptions.__all__, "exceptions"),
}

__all__ = [
    "XVIZServer",
    "Settings",
    "LiveFeed",
    "MetadataBuilder",
    "FrameBuilder",
    "LogWriter",
    "ProbeReport",
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
    "ConfigError",
    "DependencyError",
    "StoreError",
    "BrokerError",
    "QueryError",
    "FoxgloveProtocolError",
    "ExportError",
    "FrameSizeError",
    "__version__",
]

if TYPE_CHECKING:
    from .builder import FrameBuilder, MetadataBuilder
    from .exceptions import (
        BrokerError,
        BuilderError,
        ConfigError,
        DatasetError,
        DecodeError,
        DependencyError,
        EncodeError,
        ExportError,
        FoxgloveProtocolError,
        FrameError,
        FrameSizeError,
        LogError,
        LogNotFound,
        LogWriteError,
        MessageError,
        OversizeError,
        QueryError,
        SchemaValidationError,
        StoreError,
        UnknownSchemaError,
        WorkerError,
        XVIZError,
    )
    from .live import LiveFeed
    from .probe import ProbeReport
    from .server import XVIZServer
    from .settings import Settings
    from .version import __version__
    from .writer import LogWriter


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'xviz_server' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOMES])
