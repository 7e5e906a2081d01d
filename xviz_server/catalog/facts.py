"""What the catalog knows of a log, read from the cheapest place.

A log folder on disk is read in one go, in a worker process
(:func:`read_local_log`): its listing (names and sizes), its index document
``0-frame.json`` and its metadata message ``1-frame.*``, and no frame. A
folder whose index is missing or does not match its frames (fleets are often
written without one) is read the same way with ``unindexed``: its frames are
counted from the listing, and its time range is the metadata's ``log_info``
times, or else the first frame's start and the last frame's end, reading
those two frames only, each if it is at most :data:`MAX_SPAN_READ` bytes
(a bigger one leaves that end of the range unknown). A session that opens
such a log reads every frame and may count fewer (a corrupt frame is left
out of its index). A log in an object store and a raw dataset are opened as
a session opens them (see :meth:`~xviz_server.logs.LogShelf.load`), which
reads the same two messages from a store and converts a dataset's metadata.

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
from ..frames import span
from ..layout import FRAME_FILE, INDEX_FILE, INDEX_NUMBER, LOG, METADATA_NUMBER, file_number, frame_numbers
from ..logs import complete_metadata
from ..messages import is_number
from ..providers.static_log import FORMATS, index_problem, read_metadata
from ..timeindex import TimeIndex

__all__ = ["facts", "read_local_log", "tree_bytes", "MAX_SPAN_READ"]

#: Longest ``description`` and ``vehicle`` kept, in characters; most ``tags`` kept, each at most this long.
MAX_TEXT = 1000
MAX_TAGS = 100
MAX_TAG = 100
#: Largest frame file read to learn a log's start or end when it has no index document and its metadata gives no times.
MAX_SPAN_READ = 16 * 2**20


def _recording_format(info: dict[str, Any]) -> str:
    """The container of a ROS bag or MCAP file, as its ``log_info.source`` names it (``MCAP bag drive``: ``MCAP``)."""
    source = info.get("source")
    return source.rpartition(" bag ")[0] or "ROS bag" if isinstance(source, str) else "ROS bag"


def facts(
    kind: str,
    fmt: Format,
    metadata: dict[str, Any],
    index: TimeIndex,
    size: int | None,
    modified: float | None,
    frames: int | None = None,
) -> dict[str, Any]:
    """The catalog's facts of a log of ``kind`` with this metadata and index, ``size`` bytes, modified at ``modified``.

    One value for each of :data:`~xviz_server.catalog.columns.COLUMNS` but
    ``error`` (``None`` where it is not known), and the ``kind``.

    ``frames`` is the log's number of frames when ``index`` holds only some of them (see :func:`read_local_log`).
    """
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
        "frames": len(index) if frames is None else frames,
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
                name: {
                    key: value
                    for key in ("category", "primitive_type", "scalar_type", "coordinate")
                    if isinstance(value := (stream or {}).get(key), str)
                }
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


def read_local_log(name: str, directory: str, *, unindexed: bool = False) -> dict[str, Any] | None:
    """The facts of the log folder ``directory`` from its listing, index and metadata.

    ``None`` if its index document is missing or cannot serve, unless
    ``unindexed``: then its facts are read without it (see the module).
    Blocks (for a worker). Raises :class:`~xviz_server.exceptions.LogError`
    for a log that cannot be served, :class:`OSError` for a folder that
    cannot be read.
    """
    files: dict[int, str] = {}
    sizes: dict[int, int] = {}
    modified = os.stat(directory).st_mtime
    with os.scandir(directory) as entries:
        for entry in entries:
            match = FRAME_FILE.fullmatch(entry.name)
            if match is None:
                continue
            status = entry.stat()
            if not stat.S_ISREG(status.st_mode):
                continue
            number = int(match.group(1))
            files[number] = entry.name
            sizes[number] = status.st_size
            modified = max(modified, status.st_mtime)
    metadata_file = files.get(METADATA_NUMBER)
    if metadata_file is None:
        raise LogError(
            f"log {name!r} has no metadata file (1-frame.glb, 1-frame.json or 1-frame.pbe) in {directory}", log=name
        )
    index = _stored_index(directory, files)
    if index is None and not unindexed:
        return None
    with open(os.path.join(directory, metadata_file), "rb") as stream:
        metadata = read_metadata(name, metadata_file, stream.read())
    fmt, size = FORMATS[metadata_file.rpartition(".")[2]], sum(sizes.values())
    if index is not None:
        return facts(LOG, fmt, metadata, index, size, modified)
    frames = frame_numbers(files)
    return facts(
        LOG, fmt, metadata, _ends(directory, files, sizes, frames, metadata), size, modified, frames=len(frames)
    )


def _stored_index(directory: str, files: dict[int, str]) -> TimeIndex | None:
    """The log's index document, if it is readable and names its frame files."""
    if files.get(INDEX_NUMBER) != INDEX_FILE:
        return None
    try:
        with open(os.path.join(directory, INDEX_FILE), "rb") as stream:
            index = TimeIndex.from_reference(orjson.loads(stream.read()))
    except (orjson.JSONDecodeError, DecodeError):
        return None
    return None if index_problem(index, files) is not None else index


def _ends(
    directory: str, files: dict[int, str], sizes: dict[int, int], frames: list[int], metadata: dict[str, Any]
) -> TimeIndex:
    """An index of the first and last of ``frames`` (the time range of a log without index), of none when the metadata gives both times."""
    info = metadata.get("log_info")
    if isinstance(info, dict) and all(
        is_number(value := info.get(key)) and value != 0 for key in ("start_time", "end_time")
    ):
        return TimeIndex.from_spans([])  # the metadata's times are the log's (see complete_metadata)
    spans = []
    for frame in dict.fromkeys(frames[:1] + frames[-1:]):
        number = file_number(frame)
        if sizes[number] > MAX_SPAN_READ:
            continue
        try:
            with open(os.path.join(directory, files[number]), "rb") as stream:
                start, end = span(stream.read(MAX_SPAN_READ))
        except DecodeError:
            continue  # a session leaves it out of its index too
        spans.append((start, end, frame))
    return TimeIndex.from_spans(spans)


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
