"""Raw datasets served as logs, converted on demand.

Datasets are found under a data root by their layout (see
:func:`xviz_server.layout.discover`: a dataset in one file, like a ROS bag,
is named by its path without the suffix) or given explicitly (``--dataset
kitti:PATH``: named by the folder's name, or a file's name without its
suffix; a folder of datasets of that kind serves each of them; ``--dataset
rosbag:PATH?config=FILE`` gives the kind's options). The metadata and the
index come from the dataset's timestamps at once; each frame is converted
in the process pool when first asked for, encoded as GLB once, and kept in
the shared frame cache like any other frame. A frame whose raw files are
missing or corrupt is an error naming the file; the rest of the drive is
served.
"""

from __future__ import annotations

from pathlib import Path
from collections.abc import Mapping
from typing import Any

from ..codec import Format
from ..datasets import Dataset, convert_frame, detect, open_dataset
from ..exceptions import DatasetError, FrameError, LogError, StoreError
from ..index import TimeIndex
from ..layout import Found, discover
from ..store import StoredDataset
from ..storepath import StorePath, StoreTree
from ..work import Workers

__all__ = ["DatasetProvider", "DatasetLog", "explicit_datasets"]


def explicit_datasets(kind: str, path: Path, options: Mapping[str, str] | None = None) -> list[Found]:
    """The datasets a ``--dataset KIND:PATH?OPTIONS`` names.

    ``path`` itself, named after it (a file without its suffix), when it is
    a dataset; the one dataset of ``kind`` under it, named after ``path``;
    each of several, named by its path below it. A folder that holds none is
    named after itself, and opening it says what is wrong.
    """
    path, given = Path(path), tuple(sorted((options or {}).items()))
    name = path.stem if path.is_file() else path.name
    if detect(path) == kind or not path.is_dir():
        return [Found(name, path, kind, given)]
    found = [Found(entry.name, entry.path, kind, given) for entry in discover(path, detect) if entry.kind == kind]
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
        try:
            dataset = await self._workers.io(lambda: open_dataset(found.kind, found.path, **options))
        except DatasetError as exc:
            raise LogError(f"log {found.name!r}: {exc}", log=found.name) from None
        return DatasetLog(found.name, found.kind, dataset, options, self._workers)


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

    def describe_frame(self, frame: int) -> str:
        return f"frame {frame} of {self._dataset.path}"

    async def read(self, frame: int) -> bytes:
        metadata = await self.metadata()
        try:
            path = self._dataset.path  # an object in a store goes as it is: picklable, without a credential
            where = path if isinstance(path, (StorePath, StoreTree)) else str(path)
            return await self._workers.cpu(convert_frame, self._kind, where, self._options, frame, metadata)
        except (DatasetError, StoreError) as exc:
            raise FrameError(f"frame {frame} of log {self.name!r}: {exc}", log=self.name, frame=frame) from None
