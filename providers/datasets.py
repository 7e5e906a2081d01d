"""Raw datasets served as logs, converted on demand.

Datasets are found under a data root by their layout (see
:func:`xviz_server.layout.discover`: a dataset in one file, like a ROS bag,
is named by its path without the suffix) or given explicitly (``--dataset
kitti:PATH``: named by the folder's name, or a file's name without its
suffix; a folder of datasets of that kind serves each of them; ``--dataset
rosbag:PATH?config=FILE`` gives the kind's options). A dataset is opened in
the process pool, never in the server's own process (the first waits for the
pool to start): its metadata and its frame times come back from there (a recording that unpacks to too much, or
kills the worker, fails that log alone). Each frame is converted in the
process pool when first asked for, encoded as GLB once, and kept in the
shared frame cache like any other frame. A frame whose raw files are
missing or corrupt is an error naming the file; the rest of the drive is
served.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..codec import Format
from ..datasets import SCENE, convert_frame, describe_dataset, detect, original_messages, scenes
from ..exceptions import DatasetError, FrameError, LogError, StoreError, WorkerError
from ..layout import Found, discover
from ..records import OriginalTopic
from ..store import StoredDataset
from ..store.path import StorePath, StoreTree
from ..timeindex import TimeIndex
from ..work import Workers

__all__ = ["DatasetProvider", "DatasetLog", "explicit_datasets"]


def explicit_datasets(kind: str, path: Path, options: Mapping[str, str] | None = None) -> list[Found]:
    """The datasets a ``--dataset KIND:PATH?OPTIONS`` names.

    ``path`` itself, named after it (a file without its suffix), when it is
    a dataset (each of its scenes, named by the scene, when it holds several:
    see :data:`~xviz_server.datasets.SCENE_KINDS`); the one dataset of
    ``kind`` under it, named after ``path``; each of several, named by its
    path below it. A folder that holds none is
    named after itself, and opening it says what is wrong.
    """
    path, given = Path(path), tuple(sorted((options or {}).items()))
    name = path.stem if path.is_file() else path.name
    if detect(path) == kind or not path.is_dir():
        several = scenes(kind, path) if SCENE not in dict(given) else []
        return [
            Found(scene, path, kind, tuple(sorted({**dict(given), SCENE: scene}.items()))) for scene in several
        ] or [Found(name, path, kind, given)]
    found = [
        Found(entry.name, entry.path, kind, tuple(sorted({**dict(given), **dict(entry.options)}.items())))
        for entry in discover(path, detect, scenes)
        if entry.kind == kind
    ]
    if len(found) == 1:
        return [Found(name, found[0].path, kind, given)]
    return found or [Found(name, path, kind, given)]


class DatasetProvider:
    """Opens datasets; ``options`` go to every dataset (``image_max_width``)."""

    def __init__(self, workers: Workers, options: dict[str, Any] | None = None) -> None:
        self._workers = workers
        self._options = options or {}

    async def open(self, found: Found | StoredDataset) -> DatasetLog:
        options = {**self._options, **dict(found.options)}
        path = found.path  # an object in a store goes as it is: picklable, without a credential
        where = path if isinstance(path, (StorePath, StoreTree)) else str(path)
        try:
            metadata, times, originals = await self._workers.cpu(
                describe_dataset, found.kind, where, options, isolated=True
            )
        except (DatasetError, StoreError, WorkerError) as exc:
            raise LogError(f"log {found.name!r}: {without_path(exc, where)}", log=found.name) from None
        return DatasetLog(found.name, found.kind, where, metadata, times, options, self._workers, originals)


def without_path(exc: Exception, path: str | StorePath | StoreTree) -> str:
    """The cause of ``exc`` without the local path of the data, which clients are not told (errors of a dataset start
    with its path); an object in a store keeps its key."""
    text = str(exc)
    if not isinstance(path, str):
        return text
    return text.removeprefix(f"{path}: ").replace(path, "the recording")


class DatasetLog:
    """One dataset as a log source: its metadata and frame times, and frames converted in the process pool."""

    format = Format.BINARY

    def __init__(
        self,
        name: str,
        kind: str,
        path: str | StorePath | StoreTree,
        metadata: dict[str, Any],
        times: np.ndarray,
        options: dict[str, Any],
        workers: Workers,
        originals: tuple[OriginalTopic, ...] = (),
    ) -> None:
        self.name = name
        self._kind = kind
        self._path = path
        self._metadata = metadata
        self._times = times
        self._options = options
        self._workers = workers
        #: The topics of the recording it is read from, as the file holds them (a ROS bag, an MCAP file).
        self.originals = originals

    async def metadata(self) -> dict[str, Any]:
        return self._metadata

    async def index(self) -> TimeIndex:
        return TimeIndex.from_spans((float(t), float(t), i) for i, t in enumerate(self._times))

    def describe_frame(self, frame: int) -> str:
        return f"frame {frame} of {self._path}"

    async def read(self, frame: int) -> bytes:
        try:
            return await self._workers.cpu(
                convert_frame, self._kind, self._path, self._options, frame, self._metadata, isolated=True
            )
        except (DatasetError, StoreError) as exc:
            raise FrameError(
                f"frame {frame} of log {self.name!r}: {without_path(exc, self._path)}", log=self.name, frame=frame
            ) from None

    async def read_originals(self, frame: int) -> bytes:
        """The original messages of ``frame``, packed (see :func:`~xviz_server.datasets.original_messages`)."""
        try:
            return await self._workers.cpu(
                original_messages, self._kind, self._path, self._options, frame, isolated=True
            )
        except (DatasetError, StoreError) as exc:
            raise FrameError(
                f"frame {frame} of log {self.name!r}: its original messages: {without_path(exc, self._path)}",
                log=self.name,
                frame=frame,
            ) from None
