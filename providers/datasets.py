"""Raw datasets served as logs, converted on demand.

Datasets are found under the data root by their layout (a KITTI drive
folder is named by its path below the root, a dataset in one file, like a
ROS bag, by its path without the suffix) or given explicitly
(``--dataset kitti:PATH``, named by the folder's base name or the file's
name without its suffix; ``--dataset rosbag:PATH?config=FILE`` gives the
kind's options). The metadata
and the index come from the dataset's timestamps at once; each frame is
converted in the process pool when first asked for, encoded as GLB once,
and kept in the shared frame cache like any other frame. A frame whose raw
files are missing or corrupt is an error naming the file; the rest of the
drive is served.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

from ..codec import Format
from ..datasets import Dataset, convert_frame, detect, open_dataset
from ..exceptions import DatasetError, FrameError, LogError
from ..index import TimeIndex
from ..work import Workers

__all__ = ["DatasetProvider", "DatasetLog"]


class DatasetProvider:
    """Datasets found under ``root`` and those given as ``(kind, path)``."""

    def __init__(
        self,
        root: Path | None,
        explicit: Sequence[tuple[str, Path] | tuple[str, Path, dict[str, Any]]],
        workers: Workers,
        options: dict[str, Any] | None = None,
    ) -> None:
        self.root = Path(root) if root is not None else None
        self._explicit = [(entry[0], Path(entry[1]), entry[2] if len(entry) > 2 else {}) for entry in explicit]
        self._workers = workers
        self._options = options or {}
        self._found: dict[str, tuple[str, Path, dict[str, Any]]] = {}

    @property
    def names(self) -> list[str]:
        """The datasets found by the last :meth:`scan`."""
        return sorted(self._found)

    def scan(self) -> list[str]:
        found: dict[str, tuple[str, Path, dict[str, Any]]] = {}
        if self.root is not None:
            for directory, subdirectories, files in os.walk(self.root, followlinks=True):
                kind = detect(Path(directory))
                if kind is not None:
                    relative = Path(directory).relative_to(self.root).as_posix()
                    found[self.root.name if relative == "." else relative] = (kind, Path(directory), {})
                    subdirectories.clear()  # a dataset's own folders are not datasets
                    continue
                subdirectories[:] = sorted(d for d in subdirectories if not d.startswith("."))
                for file in sorted(f for f in files if not f.startswith(".")):  # a dataset in one file: drive.bag
                    path = Path(directory) / file
                    kind = detect(path)
                    if kind is not None:
                        found[path.relative_to(self.root).with_suffix("").as_posix()] = (kind, path, {})
        for kind, path, options in self._explicit:
            found[path.stem if path.is_file() else path.name] = (kind, path, options)
        self._found = found
        return sorted(found)

    async def open(self, name: str) -> DatasetLog:
        kind, path, own = self._found[name]
        options = {**self._options, **own}
        try:
            dataset = await self._workers.io(lambda: open_dataset(kind, path, **options))
        except DatasetError as exc:
            raise LogError(f"log {name!r}: {exc}", log=name) from None
        return DatasetLog(name, kind, dataset, options, self._workers)


class DatasetLog:
    """One dataset as a log source: frames converted in the process pool."""

    format = Format.BINARY

    def __init__(self, name: str, kind: str, dataset: Dataset, options: dict[str, Any], workers: Workers) -> None:
        self.name = name
        self._kind = kind
        self._dataset = dataset
        self._options = options
        self._workers = workers
        self._metadata: dict[str, Any] | None = None

    async def metadata(self) -> dict[str, Any]:
        if self._metadata is None:
            try:
                self._metadata = await self._workers.io(self._dataset.metadata)
            except DatasetError as exc:
                raise LogError(f"log {self.name!r}: {exc}", log=self.name) from None
        return self._metadata

    async def index(self) -> TimeIndex:
        times = await self._workers.io(lambda: self._dataset.times)
        return TimeIndex.from_spans((float(t), float(t), i) for i, t in enumerate(times))

    async def read(self, frame: int) -> bytes:
        metadata = await self.metadata()
        try:
            return await self._workers.cpu(convert_frame, self._kind, str(self._dataset.path), self._options, frame, metadata)
        except DatasetError as exc:
            raise FrameError(f"frame {frame} of log {self.name!r}: {exc}", log=self.name, frame=frame) from None
