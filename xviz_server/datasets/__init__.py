"""Raw datasets converted to XVIZ: readers and converters by kind.

A dataset is a recording in its own layout (a KITTI raw drive, ...). It
knows its frame times without converting anything, builds its metadata, and
converts one frame at a time, so that a server can serve it on demand and
``xviz-server convert`` can write it out as a static log.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from ..exceptions import DatasetError
from ..records import OriginalTopic
from ..store.path import StorePath, StoreTree

if TYPE_CHECKING:  # imported where frames are made: the server lists datasets, and starts, without numpy and the codecs
    import numpy as np

    from ..codec import Format

__all__ = [
    "Dataset",
    "DATASET_KINDS",
    "FILE_KINDS",
    "SCENE_KINDS",
    "SCENE",
    "scenes",
    "STORE_KINDS",
    "STORE_FOLDER_KINDS",
    "STORE_REFUSED",
    "GENERATED",
    "DEFAULT_IMAGE_WIDTH",
    "open_dataset",
    "require",
    "detect",
    "detect_in_store",
    "file_problem",
    "dataset_problem",
    "dataset_options",
    "describe_dataset",
    "original_messages",
    "convert_frame",
    "OPEN_DATASETS",
]


class Dataset(Protocol):
    """A raw recording that converts to XVIZ frame by frame."""

    #: The log name it is served under by default.
    name: str
    #: Where it is.
    path: Path | StorePath | StoreTree
    #: UNIX time of every frame, in frame order.
    times: np.ndarray

    def __len__(self) -> int: ...

    def metadata(self) -> dict[str, Any]:
        """The data of the log's ``xviz/metadata``."""
        ...

    def convert(self, frame: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The data of frame ``frame``'s ``xviz/state_update``."""
        ...


#: Dataset kinds: the module of each, its class, and the function that
#: recognises its layout. Modules are imported when first needed.
DATASET_KINDS: dict[str, tuple[str, str, str]] = {
    "kitti": ("kitti", "KittiDrive", "is_kitti_drive"),
    "waymo": ("waymo", "open_segment", "is_waymo_segment"),
    "vista": ("vista", "VistaTrace", "is_vista_trace"),
    "demo": ("demo", "DemoDrive", "is_demo"),
    "rosbag": ("ros", "RosBag", "is_rosbag"),
    "nuscenes": ("nuscenes", "NuScenesScene", "is_nuscenes"),
    "argoverse2": ("argoverse2", "Argoverse2Log", "is_argoverse2_log"),
    "pandaset": ("pandaset", "PandaSetSequence", "is_pandaset_sequence"),
}
#: Kinds whose folder may hold several logs (a nuScenes root holds scenes): the function of the kind's module that
#: names them. Each is served as a log of its own, picked by the option :data:`SCENE`.
SCENE_KINDS: dict[str, str] = {"nuscenes": "scenes"}
#: The option that picks one log of a folder of :data:`SCENE_KINDS`.
SCENE = "scene"
#: Kinds made up rather than read: their path is only a name.
GENERATED = frozenset({"demo"})
#: Camera images of datasets are scaled down to this width by default.
DEFAULT_IMAGE_WIDTH = 400


#: Kinds whose datasets are single files, by file suffix: other files are never datasets.
FILE_KINDS: dict[str, str] = {".tfrecord": "waymo", ".parquet": "waymo", ".bag": "rosbag", ".mcap": "rosbag"}
#: Kinds read from an object store: one-file datasets (their suffixes in :data:`FILE_KINDS`), and folders of files.
STORE_KINDS = frozenset({"waymo", "rosbag", "kitti", "argoverse2"})
#: Kinds of :data:`STORE_KINDS` that are folders.
STORE_FOLDER_KINDS = ("kitti", "argoverse2")
#: Files of datasets that are not read from an object store, by suffix: why.
STORE_REFUSED: dict[str, str] = {
    ".db3": "a ROS 2 bag's SQLite file is read from a local file only: serve the bag from a directory, or convert it to MCAP",
}


def _member(kind: str, position: int) -> Callable[..., Any]:
    module = importlib.import_module(f".{DATASET_KINDS[kind][0]}", __name__)
    return getattr(module, DATASET_KINDS[kind][position])


def open_dataset(kind: str, path: Path | StorePath | StoreTree, **options: Any) -> Dataset:
    """Open the dataset of ``kind`` at ``path``; raises :class:`~xviz_server.exceptions.DatasetError`.

    ``path`` is a file or folder, or an object or folder in a store for the
    kinds of :data:`STORE_KINDS`.
    """
    if kind not in DATASET_KINDS:
        raise DatasetError(f"unknown dataset kind {kind!r}; known: {', '.join(sorted(DATASET_KINDS))}", path=path)
    path = _in_store(path)
    if isinstance(path, (StorePath, StoreTree)) and kind not in STORE_KINDS:
        raise DatasetError(f"{path}: a {kind} dataset is not read from an object store", path=path)
    if kind not in GENERATED and not path.exists():
        raise DatasetError(f"{path}: no such file or directory", path=path)
    return _member(kind, 1)(path, **options)


def scenes(kind: str, path: Path) -> list[str]:
    """The logs a dataset of ``kind`` at ``path`` holds, by name, when it holds several (see :data:`SCENE_KINDS`).

    Empty for other kinds, a folder of one scene, and one whose list does not
    read (opening it then says why).
    """
    if kind not in SCENE_KINDS:
        return []
    try:
        names = getattr(importlib.import_module(f".{DATASET_KINDS[kind][0]}", __name__), SCENE_KINDS[kind])(path)
    except DatasetError:
        return []
    return list(names) if len(names) > 1 else []


def require(module: str, what: str, extra: str) -> Any:
    """The module ``module``, imported; a :class:`DatasetError` saying which extra installs it when it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise DatasetError(
            f"reading {what} needs the package {module.partition('.')[0]!r}: pip install 'xviz-server[{extra}]'"
        ) from None


def dataset_options(kind: str) -> frozenset[str]:
    """The options the dataset class of ``kind`` takes besides its path (``image_max_width``, ``config`` ...)."""
    return frozenset(inspect.signature(_member(kind, 1)).parameters) - {"path"}


def detect_in_store(folder: StoreTree) -> str | None:
    """The kind of dataset whose layout a folder in a store has, of :data:`STORE_FOLDER_KINDS`, if any."""
    return next((kind for kind in STORE_FOLDER_KINDS if _member(kind, 2)(folder)), None)


def _in_store(path: Any) -> Path | StorePath | StoreTree:
    return path if isinstance(path, (StorePath, StoreTree)) else Path(path)


def detect(path: Path) -> str | None:
    """The kind of dataset whose layout the folder or file ``path`` has, if any."""
    if path.is_dir():
        return next((kind for kind in DATASET_KINDS if _member(kind, 2)(path)), None)
    kind = FILE_KINDS.get(path.suffix)
    return kind if kind is not None and _member(kind, 2)(path) else None


#: What a dataset of each kind is on disk, for messages.
_WHAT = {
    "kitti": "a KITTI raw drive folder (or its date folder)",
    "waymo": "a Waymo segment (a .tfrecord or .parquet file, or a folder of .npz frames)",
    "vista": "a VISTA trace folder",
    "demo": "the built-in demo",
    "rosbag": "a ROS bag or MCAP file (or a ROS 2 bag folder)",
    "nuscenes": "a nuScenes folder",
    "argoverse2": "an Argoverse 2 sensor log folder",
    "pandaset": "a PandaSet sequence folder",
}
#: What a file of each suffix of :data:`FILE_KINDS` starts with, for messages.
_FILE_WHAT = {".bag": "a ROS 1 bag", ".mcap": "an MCAP file", ".parquet": "a Waymo Open Dataset v2 segment"}
#: Bytes read from each end of a file to tell what is wrong with it.
_PEEK = 16


def file_problem(path: Path) -> str | None:
    """Why the file ``path``, named as a dataset of :data:`FILE_KINDS` (``drive.bag``), cannot be served whole.

    The cause is one phrase: a file that is not of its suffix's format (by
    its first bytes; a ``.tfrecord`` by its first header's CRC, see
    :func:`~xviz_server.datasets.waymo.tfrecord.header_problem`), or an MCAP file without the magic that ends every
    complete one (cut short, or still being written). ``None`` when nothing
    is found wrong, or the file cannot be read.
    """
    kind = FILE_KINDS.get(path.suffix)
    if kind is None:
        return None
    try:
        size = path.stat().st_size
        with path.open("rb") as file:
            head = file.read(_PEEK)
            file.seek(max(0, size - _PEEK))
            tail = file.read(_PEEK)
    except OSError:
        return None
    if not _member(kind, 2)(path):
        if path.suffix == ".tfrecord":
            from .waymo.tfrecord import header_problem

            return header_problem(path) or "not a Waymo segment"
        what = _FILE_WHAT.get(path.suffix, f"a {kind} dataset")
        return f"not {what}: the file is empty" if not head else f"not {what}: it starts with {head!r}"
    if path.suffix == ".mcap":
        from .ros.bag import MCAP_MAGIC

        if not tail.endswith(MCAP_MAGIC):
            return (
                "a truncated MCAP file: it does not end with the MCAP magic (cut short, or still being written), "
                "and opens only once complete"
            )
    return None


def dataset_problem(kind: str, path: Path) -> str | None:
    """Why ``path`` is not a dataset of ``kind`` as ``--dataset KIND:PATH`` names it, with the kind it is if another.

    Cheap (the first and last bytes of a file, the names in a folder): a
    dataset is opened only when a client asks for it. ``None`` when nothing
    is found wrong.
    """
    if kind in GENERATED or kind not in DATASET_KINDS:
        return None
    other = detect(path)
    if other is not None and other != kind:
        return f"{path} is {_what(other)}, not {_what(kind)}: give --dataset {other}:{path}"
    if path.is_file():
        if FILE_KINDS.get(path.suffix) == kind:
            return file_problem(path)
        if kind not in FILE_KINDS.values():
            return f"{path} is a file, and {_what(kind)} is a folder"
    return None


def _what(kind: str) -> str:
    return _WHAT.get(kind, f"a {kind} dataset")


#: The most datasets a worker process keeps open (with what each caches), the least recently used closed first.
OPEN_DATASETS = 8

_opened: dict[tuple[str, str, tuple[tuple[str, Any], ...]], Dataset] = {}


def _dataset(kind: str, path: str | StorePath | StoreTree, options: dict[str, Any]) -> Dataset:
    """The dataset, opened once in this process and kept among the :data:`OPEN_DATASETS` last used."""
    key = (kind, str(path), tuple(sorted(options.items())))
    dataset = _opened.pop(key, None)
    if dataset is None:
        dataset = open_dataset(kind, _in_store(path), **options)
        while len(_opened) >= OPEN_DATASETS:
            _opened.pop(next(iter(_opened)))
    _opened[key] = dataset
    return dataset


def describe_dataset(
    kind: str,
    path: str | StorePath | StoreTree,
    options: dict[str, Any],
) -> tuple[dict[str, Any], np.ndarray, tuple[OriginalTopic, ...]]:
    """A dataset's metadata, frame times and original topics (see :func:`original_messages`); for worker
    processes, so that opening it happens there."""
    import numpy as np

    dataset = _dataset(kind, path, options)
    return dataset.metadata(), np.asarray(dataset.times, dtype=np.float64), tuple(getattr(dataset, "originals", ()))


def original_messages(kind: str, path: str | StorePath | StoreTree, options: dict[str, Any], frame: int) -> bytes:
    """The original messages of frame ``frame`` of a dataset read from a recording that has them (a ROS bag, an
    MCAP file), packed (:func:`~xviz_server.records.pack`); for worker processes."""
    return _dataset(kind, path, options).original_messages(frame)  # type: ignore[attr-defined]


def convert_frame(
    kind: str,
    path: str | StorePath | StoreTree,
    options: dict[str, Any],
    frame: int,
    metadata: dict[str, Any],
    fmt: Format | None = None,
) -> bytes:
    """Frame ``frame`` of a dataset as a message encoded in ``fmt`` (GLB by default); for worker processes.

    Each process opens a dataset once and keeps it, with what it caches
    (and its own client of a store), among the :data:`OPEN_DATASETS` last used.
    """
    from ..codec import Format, encode
    from ..messages import envelope

    dataset = _dataset(kind, path, options)
    return encode(envelope("state_update", dataset.convert(frame, metadata)), fmt or Format.BINARY)
