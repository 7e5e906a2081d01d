"""Finding the logs under a directory, and later what changed there, from modification times.

The first look (:meth:`LocalScan.walk`) lists every folder under the root,
as :func:`~xviz_server.layout.discover` does (the same logs and datasets,
named the same way). It remembers each folder that holds other folders
(not the log folders themselves), with its modification time and what it
held. A later look (:meth:`LocalScan.changes`) lists again only the
folders whose modification time changed: a log copied or renamed in, or
removed, changes its parent's. A log whose own files change (its index
written last, frames added) changes its own folder's time, which the
catalog's sweep of every log's version (:func:`~xviz_server.layout.stamp_of`)
finds.

Every method blocks (for a thread).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from ..datasets import DATASET_KINDS, FILE_KINDS, file_problem
from ..layout import FRAME_FILE, INDEX_FILE, LOG, place_of, split_place, stamp_from, stamp_of
from .db import Row

__all__ = ["LocalScan", "source_kind", "listed_kinds", "version_of"]

logger = logging.getLogger(__name__)

#: Rows handed over at a time by :meth:`LocalScan.walk`.
BATCH = 1000


#: Dataset kinds whose logs are listed under another kind by the suffix of their place (the first: any other).
_BY_SUFFIX: dict[str, tuple[tuple[str, str], ...]] = {"rosbag": (("", "bag"), (".mcap", "mcap"))}


def source_kind(kind: str, place: str) -> str:
    """The kind a log is listed as (one of :func:`listed_kinds`).

    ``kind`` is the kind discovery gave (:data:`~xviz_server.layout.LOG`
    or a dataset kind); ROS recordings are told apart by ``place``'s suffix.
    """
    listed = kind
    for suffix, name in _BY_SUFFIX.get(kind, ()):
        if place.endswith(suffix):
            listed = name
    return listed


def listed_kinds() -> tuple[str, ...]:
    """Every kind the catalog lists logs as: static logs, then each dataset kind registered in
    :data:`xviz_server.datasets.DATASET_KINDS` (ROS recordings as ``bag`` and ``mcap``)."""
    return tuple(
        name
        for kind in (LOG, *DATASET_KINDS)
        for name in ([n for _, n in _BY_SUFFIX[kind]] if kind in _BY_SUFFIX else [kind])
    )


def version_of(path: str) -> str | None:
    """A log's or dataset's version on disk (see :func:`~xviz_server.layout.stamp_of`), ``None`` when it is gone;
    ``path`` is a place (see :func:`~xviz_server.layout.place_of`)."""
    stamp = stamp_of(split_place(path)[0])
    return None if stamp is None else ",".join(map(str, stamp))


def _version(own: os.stat_result, index: os.stat_result | None) -> str:
    """:func:`version_of` from the ``stat`` of a folder and of its index file, taken already."""
    return ",".join(map(str, stamp_from(own, index)))


@dataclass
class _Folder:
    """A folder that holds folders: its modification time and the names of what it holds that is searched."""

    mtime: int
    children: set[str] = field(default_factory=set)


class LocalScan:
    """The logs and datasets under ``root``; ``detect`` names a dataset's kind (see :func:`~xviz_server.datasets.detect`)."""

    def __init__(
        self,
        root: Path,
        detect: Callable[[Path], str | None],
        scenes: Callable[[str, Path], list[str]] | None = None,
    ) -> None:
        self.root = str(root)
        self._name = Path(root).name
        self._detect = detect
        self._scenes = scenes
        self._folders: dict[str, _Folder] = {}
        self._real: dict[str, str] = {}  # the folders of _folders by real path: a link loop ends
        self._looked: dict[str, str] = {}  # the version of each dataset file looked at for problems
        self._reported: dict[str, str | None] = {}  # the problem of each, as last logged

    def walk(self) -> Iterator[list[Row]]:
        """Everything under the root, in batches of rows."""
        self._folders.clear()
        self._real.clear()
        rows: list[Row] = []
        for row in self._look(""):
            rows.append(row)
            if len(rows) >= BATCH:
                yield rows
                rows = []
        if rows:
            yield rows

    def changes(self) -> tuple[list[Row], list[str]]:
        """What the folders whose modification time changed since the last look hold now; and the names (prefixes) gone."""
        rows: list[Row] = []
        gone: list[str] = []
        for relative in list(self._folders):
            folder = self._folders.get(relative)
            if folder is None:
                continue  # below one that went
            try:
                mtime: int | None = os.stat(self._path(relative)).st_mtime_ns
            except OSError:
                mtime = None
            if mtime == folder.mtime:
                continue
            if mtime is None:
                self._forget(relative)
                gone.append(relative)
                continue
            before = {self._join(relative, child) for child in folder.children}
            rows.extend(self._look(relative, known=before))
            now = self._folders.get(relative)
            after = (
                {self._join(relative, child) for child in now.children}
                if now is not None and now is not folder
                else set()
            )
            for child in sorted(before - after):
                self._forget(child)
                gone.append(child)
        return rows, gone

    def _path(self, relative: str) -> str:
        return os.path.join(self.root, relative) if relative else self.root

    @staticmethod
    def _join(relative: str, child: str) -> str:
        return f"{relative}/{child}" if relative else child

    def _report(self, path: str, version: str | None, *, listed: bool) -> None:
        """Log at WARNING what is wrong with the dataset file ``path`` (see :func:`~xviz_server.datasets.file_problem`),
        and whether it is listed all the same: once for each problem (a file still being written stays truncated
        through many versions)."""
        if version is None or self._looked.get(path) == version:
            return
        self._looked[path] = version
        problem = file_problem(Path(path))
        self._warn_once(
            path, problem and (f"{problem}; listed all the same" if listed else f"left out of the catalog: {problem}")
        )

    def _warn_once(self, path: str, problem: str | None) -> None:
        """Log ``path: problem`` at WARNING unless it was the last problem logged for ``path``."""
        if problem is not None and self._reported.get(path) != problem:
            logger.warning("%s: %s", path, problem)
        self._reported[path] = problem

    def _forget(self, relative: str) -> None:
        """Forget the folder ``relative`` and every folder below it."""
        below = f"{relative}/"
        for other in [key for key in self._folders if key == relative or not relative or key.startswith(below)]:
            del self._folders[other]
        self._real = {real: key for real, key in self._real.items() if key in self._folders}

    def _look(self, relative: str, known: Collection[str] = frozenset()) -> Iterator[Row]:
        """The rows of the folder ``relative`` and of the folders below it not in ``known`` (looked at before)."""
        stack: list[tuple[str, str | None]] = [(relative, None)]
        while stack:
            current, real = stack.pop()
            path = self._path(current)
            try:
                # A link (or the first folder) is resolved; a folder's other folders are at its real path.
                real = real or os.path.realpath(path)
                if self._real.get(real, current) != current:
                    continue
                own = os.stat(path)
                with os.scandir(path) as listing:
                    entries = sorted(
                        (entry for entry in listing if not entry.name.startswith(".")), key=lambda e: e.name
                    )
            except OSError:
                continue
            name = current or self._name
            kinds = [(entry, _is_dir(entry)) for entry in entries]
            files = [entry for entry, is_dir in kinds if not is_dir]
            folders = [entry for entry, is_dir in kinds if is_dir]
            if any(FRAME_FILE.fullmatch(entry.name) for entry in files):
                index = next((entry for entry in files if entry.name == INDEX_FILE), None)
                try:
                    yield Row(name, self.root, path, _version(own, index.stat() if index is not None else None), LOG)
                except OSError:
                    pass  # gone meanwhile
                files = []  # a log's files are its frames: no dataset among them
                if not folders:
                    continue
            else:
                kind = self._detect(Path(path))
                if kind is not None:
                    version = version_of(path)
                    if version is not None:
                        several = self._scenes(kind, Path(path)) if self._scenes is not None else []
                        yield from [
                            Row(self._join(name, scene), self.root, place_of(path, (("scene", scene),)), version, kind)
                            for scene in several
                        ] or [Row(name, self.root, path, version, source_kind(kind, path))]
                    continue
            folder = _Folder(own.st_mtime_ns)
            self._folders[current] = folder
            self._real[real] = current
            for entry in folders:
                folder.children.add(entry.name)
                child = self._join(current, entry.name)
                if child not in known:
                    stack.append((child, None if entry.is_symlink() else os.path.join(real, entry.name)))
            named: dict[str, str] = {}  # the path of the file each name was given to, in this folder
            for entry in files:
                stem, suffix = os.path.splitext(entry.name)
                if suffix not in FILE_KINDS:
                    continue
                kind = self._detect(Path(entry.path))
                version = version_of(entry.path)
                self._report(entry.path, version, listed=kind is not None)
                if kind is not None and version is not None:
                    if stem in named:  # the later file is served under the name, as in discovery
                        self._warn_once(named[stem], f"{entry.name} has its name, {stem!r}, and is served under it")
                    named[stem] = entry.path
                    folder.children.add(stem)
                    yield Row(self._join(current, stem), self.root, entry.path, version, source_kind(kind, entry.path))


def _is_dir(entry: os.DirEntry[str]) -> bool:
    try:
        return entry.is_dir()  # follows links
    except OSError:
        return False
