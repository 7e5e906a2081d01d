"""Logs in an S3-compatible object store (AWS S3, MinIO, ...), read with obstore.

A data root ``s3://BUCKET/PREFIX`` serves every static log under the
prefix, named by its key path below it (``s3://b/fleet/kitti/0005/1-frame.glb``
is the log ``kitti/0005`` of the root ``s3://b/fleet``), in the layout of
:mod:`xviz_server.layout`. A log is a :class:`StoreFolder`: the static-log
provider reads it as it reads a directory, one GET per file.

A one-file dataset under the prefix (a Waymo ``.tfrecord`` segment, a ROS 1
``.bag``, an ``.mcap`` file) is served too, named by its key path below the
prefix without its suffix, and so is a dataset that is a folder of files (a
KITTI raw drive), named by its folder's key path; both are read with ranged
GETs (see :mod:`xviz_server.store.path`).

The client, its time limits and retries, and the errors of a failed
request are those of :mod:`xviz_server.store.client`.
"""

from __future__ import annotations

import asyncio
import logging
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

import obstore
from obstore.exceptions import BaseError

from ..exceptions import ConfigError, StoreError
from ..layout import FRAME_FILE, LOG
from ..readahead import ReadAhead
from .client import (
    BACKOFF_MAX,
    CONNECT_TIMEOUT,
    SCHEME,
    failure,
    get_range_async,
    s3_client,
    store_config,
    store_error,
)
from .path import StorePath, StoreTree

if TYPE_CHECKING:
    from obstore import ObjectMeta

    from ..settings import Settings

__all__ = ["is_store_url", "data_roots", "ObjectStore", "StoreFolder", "StoredLog", "StoredDataset"]

logger = logging.getLogger(__name__)

#: S3 bucket names: 3 to 63 lower-case letters, digits, dots and hyphens.
_BUCKET = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")


def is_store_url(text: str) -> bool:
    """Whether a ``--data-dir`` value names an object store rather than a directory."""
    return text.startswith(SCHEME)


def data_roots(settings: Settings) -> list[Path | ObjectStore]:
    """The ``--data-dir`` values: directories, and object stores configured by the settings and the AWS files."""
    read_ahead = ReadAhead(settings.store_read_ahead, int(settings.store_read_ahead_mb * (1 << 20)))
    return [
        ObjectStore(root, timeout=settings.store_timeout, retries=settings.store_retries, read_ahead=read_ahead)
        if is_store_url(root)
        else Path(root)
        for root in settings.data_dir
    ]


@dataclass(frozen=True)
class StoredLog:
    """A log found in a store: its name and its folder (the counterpart of :class:`~xviz_server.layout.Found`)."""

    name: str
    folder: StoreFolder
    kind: str = LOG


@dataclass(frozen=True)
class StoredDataset:
    """A dataset found in a store: its name, its object (or folder) and its kind.

    The counterpart of :class:`~xviz_server.layout.Found`, whose path is a
    file: providers open either.
    """

    name: str
    path: StorePath | StoreTree
    kind: str
    options: tuple[tuple[str, str], ...] = ()


class ObjectStore:
    """One ``s3://BUCKET/PREFIX`` data root.

    ``timeout`` and ``retries`` bound each GET (see the module's
    docstring); ``read_ahead`` is how far a stream reads ahead of a log
    here. Raises :class:`~xviz_server.exceptions.ConfigError` for a URL
    that is not ``s3://BUCKET[/PREFIX]``.
    """

    def __init__(self, url: str, *, timeout: float, retries: int, read_ahead: ReadAhead) -> None:
        self.bucket, self.prefix = _parse(url)
        self.url = f"{SCHEME}{self.bucket}/{self.prefix}".rstrip("/")
        self.read_ahead = read_ahead
        self._timeout = timeout
        # Beyond obstore's own limits: every try, every backoff, and some slack.
        self._deadline = (retries + 1) * (timeout + CONNECT_TIMEOUT) + retries * BACKOFF_MAX + 1
        self.config = store_config(self.bucket, timeout, retries)
        self._store = s3_client(self.config)
        self._warned: set[str] = set()

    def key_url(self, key: str) -> str:
        """The ``s3://`` URL of an object (what errors name)."""
        return f"{SCHEME}{self.bucket}/{key}"

    def _key(self, name: str) -> str:
        """The key of ``name`` below the prefix."""
        return f"{self.prefix}/{name}" if self.prefix else name

    async def discover(
        self, kinds: Mapping[str, str], refused: Mapping[str, str], detect: Callable[[StoreTree], str | None]
    ) -> list[StoredLog | StoredDataset]:
        """Every log and dataset under the prefix, in name order: one listing of the whole prefix.

        A folder holding message files is a log; folders below a log are
        searched too, and hidden ones (a component starting with ``.``) are
        not. The prefix itself is a log named after its last component when
        it holds message files. ``kinds`` maps a file suffix to the kind of
        dataset such a file is (``.tfrecord``: ``waymo``): each one outside a
        log's folder is a dataset, named by its key path below the prefix
        without the suffix. ``refused`` maps the suffixes of datasets that are
        not read from a store to why: each such file is left out with a
        warning, once. ``detect`` names the kind of dataset that a folder
        (a :class:`~xviz_server.store.path.StoreTree` of the listing) is, if
        any; a dataset's folders are not searched further.
        """
        try:
            objects = await self.list_all()
        except StoreError as exc:
            logger.warning("cannot list %s: %s", self.url, exc)
            return []
        return self.found_in(objects, kinds, refused, detect)

    async def list_all(self) -> list[ObjectMeta]:
        """Every object under the prefix (with its size, ETag and time): one listing, in pages of 1000.

        Raises :class:`~xviz_server.exceptions.StoreError`.
        """
        base = self._key("")
        return list(await self._guard(obstore.list(self._store, base or None, chunk_size=1000).collect_async(), base))

    def found_in(
        self,
        objects: list[ObjectMeta],
        kinds: Mapping[str, str],
        refused: Mapping[str, str],
        detect: Callable[[StoreTree], str | None],
    ) -> list[StoredLog | StoredDataset]:
        """The logs and datasets that the listing ``objects`` of the prefix holds, as :meth:`discover` finds them."""
        base = self._key("")
        folders: set[str] = set()
        files: list[tuple[str, int]] = []
        sizes: dict[str, int] = {}
        for meta in objects:
            relative = meta["path"][len(base) :]
            if _hidden(relative):
                continue
            sizes[meta["path"]] = meta["size"]
            folder, _, file = relative.rpartition("/")
            suffix = PurePosixPath(file).suffix
            if FRAME_FILE.fullmatch(file):
                folders.add(folder)
            elif suffix in kinds:
                files.append((relative, meta["size"]))
            elif suffix in refused and meta["path"] not in self._warned:
                self._warned.add(meta["path"])
                logger.warning("%s is not served: %s", self.key_url(meta["path"]), refused[suffix])
        found: list[StoredLog | StoredDataset] = [self._log(folder) for folder in folders]
        found += [
            self._dataset(relative, size, kinds)
            for relative, size in files
            if relative.rpartition("/")[0] not in folders
        ]
        found += self._folder_datasets(sizes, folders, detect)
        return sorted(found, key=lambda entry: entry.name)

    def _folder_datasets(
        self, sizes: dict[str, int], logs: set[str], detect: Callable[[StoreTree], str | None]
    ) -> list[StoredDataset]:
        """The folders of the listing (objects by key: ``sizes``) that ``detect`` finds to be datasets, outside logs."""
        below = len(self._key(""))
        candidates = {
            key[below:].rsplit("/", depth)[0] for key in sizes for depth in range(1, key[below:].count("/") + 1)
        }
        found: list[StoredDataset] = []
        for folder in sorted(candidates):  # a folder before the folders below it
            if folder in logs or any(folder.startswith(f"{taken.name}/") for taken in found):
                continue
            dataset = self._folder_dataset(folder, sizes, detect)
            if dataset is not None:
                found.append(dataset)
        return found

    def _folder_dataset(
        self, name: str, sizes: dict[str, int], detect: Callable[[StoreTree], str | None]
    ) -> StoredDataset | None:
        """The folder ``name`` (below the prefix) as a dataset, if ``detect`` finds it one among the objects ``sizes``.

        The dataset holds the objects below the folder and those beside it
        (a KITTI drive's calibration is in the folder above), not all of ``sizes``.
        """
        key = self._key(name)
        kind = detect(StoreTree(self.config, key, sizes))
        if kind is None:
            return None
        parent = key.rpartition("/")[0]
        files = {k: size for k, size in sizes.items() if k.startswith(f"{key}/") or k.rpartition("/")[0] == parent}
        return StoredDataset(name, StoreTree(self.config, key, files), kind)

    async def lookup(
        self, name: str, kinds: Mapping[str, str], detect: Callable[[StoreTree], str | None]
    ) -> StoredLog | StoredDataset | None:
        """The log or dataset ``name``, as :meth:`discover` would find it, without listing the whole prefix.

        The log ``name`` if its folder holds message files (one listing of
        that folder); else the dataset ``name`` if the folder above holds
        ``name`` with one of the suffixes of ``kinds`` (one more listing);
        else, when that folder holds a folder ``name``, that folder if
        ``detect`` finds it a dataset (one more listing: everything below
        it). A name that is nothing in the store costs two listings.
        """
        key = self._key(name)
        folder = StoreFolder(self, key)
        parent = key.rpartition("/")[0]
        try:
            if await folder.files():
                return self._log(name, folder)
            objects, folders = await self._list_level(parent)
            beside = {meta["path"]: meta["size"] for meta in objects}
            for suffix in kinds:
                if f"{key}{suffix}" in beside:
                    return self._dataset(f"{name}{suffix}", beside[f"{key}{suffix}"], kinds)
            if key not in folders:
                return None
            below = await self._guard(obstore.list(self._store, f"{key}/", chunk_size=1000).collect_async(), key)
        except StoreError as exc:
            logger.warning("cannot look for %r in %s: %s", name, self.url, exc)
            return None
        start = len(self._key(""))
        sizes = {meta["path"]: meta["size"] for meta in [*objects, *below] if not _hidden(meta["path"][start:])}
        return self._folder_dataset(name, sizes, detect)

    def _dataset(self, relative: str, size: int, kinds: Mapping[str, str]) -> StoredDataset:
        """The dataset in the file ``relative`` (below the prefix) of ``size`` bytes, named without its suffix."""
        suffix = PurePosixPath(relative).suffix
        path = StorePath(self.config, self._key(relative), size)
        return StoredDataset(relative.removesuffix(suffix), path, kinds[suffix])

    def _log(self, name: str, folder: StoreFolder | None = None) -> StoredLog:
        own = name or self.prefix.rpartition("/")[2] or self.bucket
        return StoredLog(own, folder or StoreFolder(self, self._key(name)))

    async def list_folder(self, prefix: str) -> list[ObjectMeta]:
        """The objects directly in the folder ``prefix`` (not in folders below it; the bucket's top for ``""``)."""
        return (await self._list_level(prefix))[0]

    async def _list_level(self, prefix: str) -> tuple[list[ObjectMeta], set[str]]:
        """The objects directly in the folder ``prefix``, and the keys of the folders directly in it."""
        listing = self._store.list_with_delimiter_async(prefix.rstrip("/") + "/" if prefix else None)
        result = await self._guard(listing, prefix)
        return list(result["objects"]), {folder.rstrip("/") for folder in result["common_prefixes"]}

    async def get(self, key: str, size: int | None = None) -> bytes:
        """The whole object ``key``, of ``size`` bytes as listed (asked for with a HEAD if not given); raises
        :class:`~xviz_server.exceptions.StoreError` after the retries.

        It is read as the range of that size, and no more of the answer
        (see :func:`~xviz_server.store.client.get_range`): a GET of a whole
        object makes obstore set aside as many bytes as the answer's
        ``Content-Length`` says before reading any, and one that says 1 TiB
        aborts the process.
        """
        return await self._guard(self._fetch(key, size), key)

    async def _fetch(self, key: str, size: int | None) -> bytes:
        if size is None:
            size = (await obstore.head_async(self._store, key))["size"]
        if not size:
            return b""
        return await get_range_async(self._store, key, 0, size)

    async def _guard(self, request: Any, key: str) -> Any:
        """Await an obstore request within the deadline; its failure as a :class:`StoreError`."""
        started = time.monotonic()
        try:
            return await asyncio.wait_for(request, self._deadline)
        except asyncio.TimeoutError:
            raise store_error(self.key_url(key), f"no answer in {self._deadline:g} s") from None
        except (BaseError, OSError) as exc:  # obstore's own classes, and builtins (FileNotFoundError) for some
            raise failure(self.key_url(key), exc, started, self._timeout) from None


class StoreFolder:
    """A log's folder in a store: the objects directly below one key prefix."""

    def __init__(self, store: ObjectStore, prefix: str) -> None:
        self.store = store
        self.prefix = prefix.rstrip("/")
        self.location = store.key_url(self.prefix)
        self.read_ahead: ReadAhead | None = store.read_ahead
        self._sizes: dict[str, int] = {}

    async def files(self) -> dict[int, str]:
        return self.take(await self.store.list_folder(self.prefix))

    def take(self, objects: list[ObjectMeta]) -> dict[int, str]:
        """The message files among ``objects`` (a listing of the folder), by file number, with their sizes kept."""
        files = {}
        for meta in objects:
            name = meta["path"].rpartition("/")[2]
            if match := FRAME_FILE.fullmatch(name):
                files[int(match.group(1))] = name
                self._sizes[name] = meta["size"]
        return files

    def listed(self) -> dict[int, str]:
        """The message files :meth:`take` or :meth:`files` last found, by file number."""
        return {int(match.group(1)): name for name in self._sizes if (match := FRAME_FILE.fullmatch(name))}

    def listed_bytes(self) -> int:
        """The bytes of the message files :meth:`take` or :meth:`files` last found."""
        return sum(self._sizes.values())

    async def read(self, name: str) -> bytes:
        return await self.store.get(f"{self.prefix}/{name}", self._sizes.get(name))

    def size(self, name: str) -> int | None:
        return self._sizes.get(name)


def _hidden(relative: str) -> bool:
    """Whether a key path below the prefix is hidden: one of its components starts with ``.``."""
    return any(part.startswith(".") for part in relative.split("/"))


def _parse(url: str) -> tuple[str, str]:
    """Bucket and prefix (without slashes at its ends) of ``s3://BUCKET[/PREFIX]``."""
    rest = url[len(SCHEME) :] if is_store_url(url) else ""
    bucket, _, prefix = rest.partition("/")
    if not _BUCKET.fullmatch(bucket):
        shown = bucket if "@" not in bucket and ":" not in bucket else "(hidden: it may hold a credential)"
        raise ConfigError(
            f"--data-dir {SCHEME}{shown}...: not an S3 bucket name (3 to 63 lower-case letters, digits, '.' and '-'); "
            "credentials go in the AWS variables or files, not in the URL"
        )
    return bucket, prefix.strip("/")
