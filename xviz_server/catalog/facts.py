"""What the catalog knows of a log, read from the cheapest place.

A log folder on disk is read in one go, in a thread
(:func:`read_local_log`): its listing (names and sizes), its index document
``0-frame.json`` and its metadata message ``1-frame.*``, and no frame. A
folder whose index is missing or does not match its frames, a log in an
object store and a raw dataset are opened as a session opens them (see
:meth:`~xviz_server.logs.Catalog.load`), which reads the same two messages
from a store and converts a dataset's metadata.

Facts (:func:`facts`) are what ``GET /api/logs`` lists: format, frames,
time range and duration, streams, and what the metadata's ``log_info``
says of the log (``description``, ``vehicle``, ``tags``; a ``vehicle_info``
``name`` or ``id`` is the vehicle too); and for ``GET /api/logs/NAME`` the
``detail``: each stream's category and type, the cameras and UI panels,
and the whole ``log_info``.
"""

from __future__ import annotations

import os
import stat
from typing import Any

import orjson

from ..codec import Format
from ..exceptions import DecodeError, LogError
from ..index import TimeIndex
from ..layout import FRAME_FILE, INDEX_FILE, INDEX_NUMBER, METADATA_NUMBER, LOG
from ..logs import complete_metadata
from ..messages import is_number
from ..providers.static_log import FORMATS, index_problem, read_metadata

__all__ = ["facts", "read_local_log", "tree_bytes"]

#: Longest ``description`` and ``vehicle`` kept, in characters; most ``tags`` kept, each at most this long.
MAX_TEXT = 1000
MAX_TAGS = 100
MAX_TAG = 100


def _recording_format(info: dict[str, Any]) -> str:
    """The container of a ROS bag or MCAP file, as its ``log_info.source`` names it (``MCAP bag drive``: ``MCAP``)."""
    source = info.get("source")
    return source.rpartition(" bag ")[0] or "ROS bag" if isinstance(source, str) else "ROS bag"


def facts(kind: str, fmt: Format, metadata: dict[str, Any], index: TimeIndex, size: int | None, modified: float | None) -> dict[str, Any]:
    """The catalog's facts of a log of ``kind`` with this metadata and index, ``size`` bytes, modified at ``modified``."""
    metadata = complete_metadata(metadata, index)
    info = metadata.get("log_info") or {}
    given_start, given_end = info.get("start_time"), info.get("end_time")
    start = float(given_start) if isinstance(given_start, (int, float)) and is_number(given_start) else None
    end = float(given_end) if isinstance(given_end, (int, float)) and is_number(given_end) else None
    streams: dict[str, Any] = metadata["streams"] if isinstance(metadata.get("streams"), dict) else {}
    vehicle = info.get("vehicle")
    vehicle_info = metadata.get("vehicle_info")
    if not isinstance(vehicle, str) and isinstance(vehicle_info, dict):
        vehicle = next((vehicle_info[key] for key in ("name", "id") if isinstance(vehicle_info.get(key), str)), None)
    tags = info.get("tags")
    description = info.get("description")
    return {
        "kind": kind,
        "format": _recording_format(info) if kind == "rosbag" else fmt.value,
        "frames": len(index),
        "start_time": start,
        "end_time": end,
        "duration": end - start if start is not None and end is not None else None,
        "bytes": size,
        "modified": modified,
        "description": description[:MAX_TEXT] if isinstance(description, str) else None,
        "vehicle": vehicle[:MAX_TEXT] if isinstance(vehicle, str) else None,
        "tags": [tag[:MAX_TAG] for tag in tags if isinstance(tag, str)][:MAX_TAGS] if isinstance(tags, list) else None,
        "streams": sorted(streams),
        "detail": {
            "log_info": _json_safe(info),
            "streams": {
                name: {key: value for key in ("category", "primitive_type", "scalar_type", "coordinate") if isinstance(value := (stream or {}).get(key), str)}
                for name, stream in streams.items()
                if isinstance(stream, dict) or stream is None
            },
            "cameras": sorted(metadata["cameras"]) if isinstance(metadata.get("cameras"), dict) else [],
            "ui_panels": sorted(metadata["ui_config"]) if isinstance(metadata.get("ui_config"), dict) else [],
        },
    }


def _json_safe(value: Any) -> Any:
    """``value`` as JSON would carry it (numpy arrays of a GLB's metadata as lists), at most 64 KB of it."""
    try:
        text = orjson.dumps(value, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:
        return None
    return orjson.loads(text) if len(text) <= 65536 else None


def read_local_log(name: str, directory: str) -> dict[str, Any] | None:
    """The facts of the log folder ``directory`` from its listing, index and metadata; ``None`` if its index cannot serve.

    Blocks (for a thread). Raises :class:`~xviz_server.exceptions.LogError`
    for a log that cannot be served, :class:`OSError` for a folder that
    cannot be read.
    """
    files: dict[int, str] = {}
    size = 0
    modified = os.stat(directory).st_mtime
    with os.scandir(directory) as entries:
        for entry in entries:
            match = FRAME_FILE.fullmatch(entry.name)
            if match is None:
                continue
            status = entry.stat()
            if not stat.S_ISREG(status.st_mode):
                continue
            files[int(match.group(1))] = entry.name
            size += status.st_size
            modified = max(modified, status.st_mtime)
    metadata_file = files.get(METADATA_NUMBER)
    if metadata_file is None:
        raise LogError(f"log {name!r} has no metadata file (1-frame.glb, 1-frame.json or 1-frame.pbe) in {directory}", log=name)
    if files.get(INDEX_NUMBER) != INDEX_FILE:
        return None
    try:
        with open(os.path.join(directory, INDEX_FILE), "rb") as stream:
            index = TimeIndex.from_reference(orjson.loads(stream.read()))
    except (orjson.JSONDecodeError, DecodeError):
        return None
    if index_problem(index, files) is not None:
        return None
    with open(os.path.join(directory, metadata_file), "rb") as stream:
        metadata = read_metadata(name, metadata_file, stream.read())
    return facts(LOG, FORMATS[metadata_file.rpartition(".")[2]], metadata, index, size, modified)


def tree_bytes(path: str) -> tuple[int, float]:
    """Bytes held by a file or everything below a folder, and the latest modification time among them (blocks)."""
    status = os.stat(path)
    if not stat.S_ISDIR(status.st_mode):
        return status.st_size, status.st_mtime
    size, modified = 0, status.st_mtime
    for directory, _, names in os.walk(path):
        for name in names:
            try:
                status = os.stat(os.path.join(directory, name))
            except OSError:
                continue
            size += status.st_size
            modified = max(modified, status.st_mtime)
    return size, modified
