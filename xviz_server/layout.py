"""The reference log layout, and finding logs and datasets under a root.

A log is a directory of message files, numbered as the reference tools
number them::

    0-frame.json            the index: {"startTime", "endTime", "timing": [[t_min, t_max, i, "<i+2>-frame"], ...]}
    1-frame.glb|json|pbe    the metadata message
    <i+2>-frame.glb|json|pbe   state update i

Every module that reads or writes logs (the static-log provider, the log
writer, the checker, the tests and benchmarks) takes file names, the index
document and a frame's time span from here.

:func:`discover` walks a root once and finds both logs in this layout and
raw datasets (by the detectors it is given).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .exceptions import LogNotFound

__all__ = [
    "place_of",
    "split_place",
    "found_at",
    "INDEX_FILE",
    "INDEX_NUMBER",
    "METADATA_NUMBER",
    "FRAME_FILE",
    "LOG",
    "Found",
    "file_number",
    "frame_name",
    "frame_files",
    "frame_bytes",
    "is_log_directory",
    "frame_numbers",
    "index_document",
    "update_span",
    "discover",
    "check_log_name",
    "stamp_of",
    "stamp_from",
    "MAX_NAME_PART",
]

INDEX_FILE = "0-frame.json"
INDEX_NUMBER = 0
METADATA_NUMBER = 1
#: A message file's name: its number and its encoding.
FRAME_FILE = re.compile(r"(\d+)-frame\.(json|glb|pbe)")
#: The kind :func:`discover` gives a directory in the reference layout.
LOG = "xviz"


def file_number(frame: int) -> int:
    """The file number of state update ``frame`` (message ``i`` is file ``i + 2``)."""
    return frame + 2


def frame_name(frame: int) -> str:
    """The index's name for state update ``frame``: ``"<i+2>-frame"``."""
    return f"{file_number(frame)}-frame"


def frame_files(directory: str | os.PathLike[str]) -> dict[int, str]:
    """Names of the message files of a log directory by file number (0 index, 1 metadata, 2+ frames).

    Names, not paths: a log can hold 100 000 frames, and making a ``Path``
    for each costs more than listing the directory.
    """
    return {number: entry.name for number, entry in _message_files(directory)}


def frame_bytes(directory: str | os.PathLike[str]) -> int:
    """How many bytes the state-update files of a log directory hold together (the index and metadata left out)."""
    return sum(entry.stat().st_size for number, entry in _message_files(directory) if number >= 2)


def _message_files(directory: str | os.PathLike[str]) -> list[tuple[int, os.DirEntry[str]]]:
    """The message files of a log directory (named as :data:`FRAME_FILE` says) with their file numbers."""
    with os.scandir(directory) as entries:
        return [
            (int(match.group(1)), entry)
            for entry in entries
            if (match := FRAME_FILE.fullmatch(entry.name)) and entry.is_file()
        ]


def is_log_directory(directory: str | os.PathLike[str]) -> bool:
    """Whether ``directory`` holds message files (stops at the first)."""
    with os.scandir(directory) as entries:
        return any(FRAME_FILE.fullmatch(entry.name) for entry in entries)


def frame_numbers(files: Iterable[int]) -> list[int]:
    """The state-update numbers among file numbers, in order."""
    return sorted(number - 2 for number in files if number >= 2)


def index_document(
    spans: Iterable[tuple[float, float]], start: float | None = None, end: float | None = None
) -> dict[str, Any]:
    """The ``0-frame.json`` document of frames ``0, 1, ...`` with these ``(first, last)`` time spans.

    ``start``/``end`` default to the frames' own span (``startTime`` and
    ``endTime`` are left out of an empty log).
    """
    spans = list(spans)
    timing = [[first, last, i, frame_name(i)] for i, (first, last) in enumerate(spans)]
    if spans:
        start = spans[0][0] if start is None else start
        end = max(last for _, last in spans) if end is None else end
    document: dict[str, Any] = {}
    if start is not None:
        document["startTime"] = start
    if end is not None:
        document["endTime"] = end
    document["timing"] = timing
    return document


def update_span(data: Any) -> tuple[float, float] | None:
    """First and last ``timestamp`` of a state update's data, or ``None`` unless every update has a finite one."""
    updates = data.get("updates") if isinstance(data, Mapping) else None
    if not isinstance(updates, list) or not updates:
        return None
    times = [u.get("timestamp") if isinstance(u, Mapping) else None for u in updates]
    from .messages import is_number  # not at the top: the server lists logs and starts without the message models

    if not all(is_number(t) for t in times):
        return None
    seconds = [float(t) for t in times if t is not None]
    return min(seconds), max(seconds)


# ------------------------------------------------------------- names and versions

#: Longest component of a log or feed name, in UTF-8 bytes (a file name's limit on common file systems).
MAX_NAME_PART = 255


def check_log_name(name: str) -> None:
    """Refuse a log name that could reach outside the data root.

    Names are relative folder paths with ``/`` separators. The name has
    already been percent-decoded once with the rest of the URL; a ``%`` left
    in it, a backslash, an absolute path, a drive letter, an empty, ``.`` or
    ``..`` component, a character that is not printable (control characters,
    DEL, C1 codes), or a component longer than :data:`MAX_NAME_PART` bytes
    (too long for a file system) are all refused.
    """
    parts = name.split("/")
    if (
        not name
        or name.startswith("/")
        or any(part in ("", ".", "..") or len(part.encode()) > MAX_NAME_PART for part in parts)
        or any(c in name for c in "\\%")
        or not name.isprintable()
        or (len(name) >= 2 and name[1] == ":")
    ):
        raise LogNotFound(
            f"log name {name[:300]!r} is not allowed: a log is named by its folder path inside the data root "
            f"(like 'drive-1' or 'kitti/0005'), in printable characters, at most {MAX_NAME_PART} bytes a "
            "component, without '..', '.', '\\', '%', a leading '/' or a drive",
            name=name,
            available=[],
        )


def stamp_of(path: str | os.PathLike[str]) -> tuple[int, ...] | None:
    """What tells that a log or dataset changed on disk, or ``None`` when it is gone.

    For a folder, its modification time (a file added, removed or renamed in
    it) and the time and size of its index file, which writers such as the
    reference tools write last; for a file, its time and size. Two
    ``stat`` calls: cheap enough for every open.
    """
    try:
        own = os.stat(path)
    except OSError:
        return None
    if not stat.S_ISDIR(own.st_mode):
        return stamp_from(own, None)
    try:
        return stamp_from(own, os.stat(os.path.join(path, INDEX_FILE)))
    except OSError:
        return stamp_from(own, None)


def stamp_from(own: os.stat_result, index: os.stat_result | None) -> tuple[int, ...]:
    """The stamp (see :func:`stamp_of`) of a folder or file whose ``stat`` is ``own``, with its index file's if any."""
    if index is None:
        return (own.st_mtime_ns, own.st_size)
    return (own.st_mtime_ns, own.st_size, index.st_mtime_ns, index.st_size)


# ------------------------------------------------------------- discovery


@dataclass(frozen=True)
class Found:
    """A log or dataset: its name, where it is, its kind (:data:`LOG` or a dataset kind), options of its kind."""

    name: str
    path: Path
    kind: str
    options: tuple[tuple[str, str], ...] = ()


def place_of(path: str | os.PathLike[str], options: tuple[tuple[str, str], ...] = ()) -> str:
    """Where a log is, as one string: its path, and the options that pick it in a folder of several
    (``ROOT?scene=scene-0061``; see :func:`split_place`)."""
    return str(path) + ("?" + "&".join(f"{key}={value}" for key, value in options) if options else "")


def split_place(place: str) -> tuple[str, tuple[tuple[str, str], ...]]:
    """The path and options of a :func:`place_of` string."""
    path, mark, query = place.rpartition("?")
    pairs = [pair.partition("=") for pair in query.split("&")] if mark else []
    if not mark or not all(separator and key in PLACE_OPTIONS for key, separator, _ in pairs):
        return place, ()
    return path, tuple((key, value) for key, _, value in pairs)


#: The options a place may carry (see :func:`place_of`).
PLACE_OPTIONS = frozenset({"scene"})


def found_at(name: str, place: str, kind: str) -> Found:
    """The log ``name`` of ``kind`` at a place (see :func:`place_of`)."""
    path, options = split_place(place)
    return Found(name, Path(path), kind, options)


def discover(
    root: Path,
    detect: Callable[[Path], str | None] | None = None,
    scenes: Callable[[str, Path], list[str]] | None = None,
) -> Iterator[Found]:
    """Every log and dataset under ``root``, in name order of the walk.

    A directory holding message files is a log (:data:`LOG`); ``detect``
    names the dataset kind of any other directory or file, if any, and must
    be cheap (it sees every file); ``scenes`` names the logs of a dataset
    folder that holds several (each is found as ``FOLDER/SCENE`` with the
    option ``scene``). A dataset's own folders are not searched
    further. Names are paths relative to ``root``
    with ``/`` separators (the root's own name when the root itself is one);
    a dataset found as a file is named without its suffix (``drive.bag`` is
    ``drive``). Symbolic links are followed, each real directory once, so
    a link loop ends; hidden entries are skipped.
    """
    root = Path(root)
    seen: set[str] = set()
    for directory, subdirectories, files in os.walk(root, followlinks=True):
        real = os.path.realpath(directory)
        if real in seen:
            subdirectories.clear()
            continue
        seen.add(real)
        here = Path(directory)
        relative = here.relative_to(root).as_posix()
        name = root.name if relative == "." else relative
        if any(FRAME_FILE.fullmatch(file) for file in files):
            subdirectories[:] = sorted(d for d in subdirectories if not d.startswith("."))
            yield Found(name, here, LOG)  # its files are its frames: no dataset among them
            continue
        kind = detect(here) if detect is not None else None
        if kind is not None:
            subdirectories.clear()
            several = scenes(kind, here) if scenes is not None else []
            yield from (
                [Found(f"{name}/{scene}", here, kind, (("scene", scene),)) for scene in several]
                or [Found(name, here, kind)]
            )
            continue
        subdirectories[:] = sorted(d for d in subdirectories if not d.startswith("."))
        if detect is not None:
            for file in sorted(f for f in files if not f.startswith(".")):
                kind = detect(here / file)
                if kind is not None:
                    stem = Path(file).stem
                    yield Found(stem if relative == "." else f"{relative}/{stem}", here / file, kind)
