"""Objects in an object store opened like files, for dataset readers: reads are ranged GETs.

(:class:`StoreTree` does the same for a dataset that is a folder of files,
a KITTI drive: a key in a listing, which goes down by ``/`` as a path does.)

A :class:`StorePath` names one object, ``s3://BUCKET/KEY``, and does the
few things of :class:`pathlib.Path` that the dataset readers of one-file
datasets (Waymo ``.tfrecord`` segments, ROS 1 bags, MCAP files) and
rosbags' readers do with a path: ``name``, ``stem``, ``suffix``,
``exists``, ``is_file``, ``is_dir``, ``stat().st_size``, ``read_bytes``,
``read_text`` and ``open("rb")``. Its size is the one the listing gave;
an object deleted or replaced since is found out when read.

A path pickles as its key, its size and its store's
:class:`~xviz_server.store.client.StoreConfig` (bucket, time limits, and the
endpoint, region and credentials the server resolved at start), and a
worker process that unpickles one makes its own client of the store from
it, once. ``repr`` and ``str`` show the ``s3://`` URL only.

``open("rb")`` gives a :class:`RangedFile`, a seekable read-only binary file.
A read it does not hold fetches the bytes asked for with one ranged GET,
and at least :data:`MIN_FETCH` of them, so that a reader walking small
records (headers, an index) makes one GET per :data:`MIN_FETCH` bytes rather
than one per record; what it fetched is kept, at most :data:`CACHE_BYTES`,
the least recently used dropped first, and a read larger than half of that
is not kept. :meth:`RangedFile.prefetch` fetches many ranges in one call,
in parallel, near ones in one request.

Every request blocks: call them from a thread or a process, never from the
event loop. A GET is retried and time-limited as in
:mod:`xviz_server.store`; one that still fails raises
:class:`~xviz_server.exceptions.StoreError` (an :class:`OSError`) naming the
object's URL and the cause.
"""

from __future__ import annotations

import bisect
import errno
import io
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, BinaryIO, NamedTuple, TypeVar, cast

from obstore.exceptions import BaseError

from .client import SCHEME, StoreConfig, failure, get_range, s3_client, store_error

if TYPE_CHECKING:
    from obstore.store import S3Store

__all__ = ["StorePath", "StoreTree", "RangedFile", "data_path", "MIN_FETCH", "CACHE_BYTES"]

#: Fewest bytes a read that misses the cache fetches.
MIN_FETCH = 64 << 10
#: Most bytes an open :class:`RangedFile` keeps.
CACHE_BYTES = 8 << 20
_PARALLEL_GETS = 8  # GETs of one read_ranges at once

_T = TypeVar("_T")
_clients: dict[StoreConfig, S3Store] = {}
_clients_lock = threading.Lock()


def _client(config: StoreConfig) -> S3Store:
    """This process's client of a store, made once."""
    with _clients_lock:
        if config not in _clients:
            _clients[config] = s3_client(config)
        return _clients[config]


class _Stat(NamedTuple):
    st_size: int


@dataclass(frozen=True)
class StorePath:
    """The object ``key`` of the store ``config``, ``size`` bytes as listed."""

    config: StoreConfig
    key: str
    size: int

    def __str__(self) -> str:
        return f"{SCHEME}{self.config.bucket}/{self.key}"

    def __repr__(self) -> str:
        return f"StorePath({str(self)!r})"

    @property
    def name(self) -> str:
        return self.key.rpartition("/")[2]

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix

    @property
    def stem(self) -> str:
        return Path(self.name).stem

    def exists(self) -> bool:
        """True: the object was listed."""
        return True

    def is_file(self) -> bool:
        return True

    def is_dir(self) -> bool:
        return False

    def stat(self, *, follow_symlinks: bool = True) -> _Stat:
        return _Stat(self.size)

    def __truediv__(self, name: object) -> StorePath:
        """Nothing is below an object: raises :class:`NotADirectoryError` (rosbags asks it of folders only)."""
        raise NotADirectoryError(f"{self}: an object, not a folder")

    def open(self, mode: str = "rb", buffering: int = -1) -> BinaryIO:
        """The object as a seekable binary file (a :class:`RangedFile`); only reading (``rb``) is possible."""
        if mode != "rb":
            raise ValueError(f"{self}: an object in a store opens for reading only ('rb'), not {mode!r}")
        return cast(BinaryIO, RangedFile(self))  # typed as open() types a file, for the readers that take one

    def read_bytes(self) -> bytes:
        """The whole object, as listed: one GET of that range (a store that answers more is not read past it)."""
        return self.read_range(0, self.size) if self.size else b""

    def read_text(self, encoding: str | None = None) -> str:
        return self.read_bytes().decode(encoding or "utf-8")

    def read_range(self, start: int, end: int) -> bytes:
        """Bytes ``[start, end)``, which must lie within the object: one GET."""
        return self._request(lambda store: get_range(store, self.key, start, end))

    def read_ranges(self, ranges: Sequence[tuple[int, int]]) -> list[bytes]:
        """Bytes ``[start, end)`` of each range, which must lie within the object: GETs in parallel, one for
        ranges less than :data:`MIN_FETCH` apart."""
        spans: list[list[int]] = []  # the GETs: [start, end), ranges less than MIN_FETCH apart in one
        for start, end in sorted(ranges):
            if spans and start - spans[-1][1] < MIN_FETCH:
                spans[-1][1] = max(spans[-1][1], end)
            else:
                spans.append([start, end])
        with ThreadPoolExecutor(max_workers=min(len(spans), _PARALLEL_GETS) or 1) as pool:
            fetched = list(pool.map(lambda span: self.read_range(*span), spans))
        firsts = [start for start, _ in spans]
        parts = []
        for start, end in ranges:
            index = bisect.bisect_right(firsts, start) - 1
            parts.append(fetched[index][start - firsts[index] : end - firsts[index]])
        return parts

    def _request(self, call: Callable[[S3Store], _T]) -> _T:
        started = time.monotonic()
        try:
            return call(_client(self.config))
        except (BaseError, OSError) as exc:  # obstore's own classes, and builtins for some
            raise failure(str(self), exc, started, self.config.timeout) from None


def data_path(path: Any) -> Path | StorePath:
    """``path`` as a :class:`StorePath` if it is one, else as a :class:`~pathlib.Path`."""
    return path if isinstance(path, StorePath) else Path(path)


@dataclass(frozen=True)
class StoreTree:
    """A key in a listing of a store: an object if the listing has it, a folder if objects lie below it.

    For datasets that are folders of files (a KITTI drive): ``files`` is
    the size of every object listed, by key, and a tree goes down by ``/``
    and up by ``parent`` as a :class:`~pathlib.Path` does, answers
    ``is_file``, ``is_dir`` and ``glob`` from the listing, and reads an
    object with ranged GETs as :class:`StorePath` does. An object added
    after the listing is not seen; one deleted since is a 404 when read.
    """

    config: StoreConfig
    key: str
    files: Mapping[str, int] = field(repr=False, compare=False)

    def __str__(self) -> str:
        return f"{SCHEME}{self.config.bucket}/{self.key}"

    def __repr__(self) -> str:
        return f"StoreTree({str(self)!r})"

    def __truediv__(self, name: str) -> StoreTree:
        return StoreTree(self.config, f"{self.key}/{name}" if self.key else name, self.files)

    @property
    def parent(self) -> StoreTree:
        return StoreTree(self.config, self.key.rpartition("/")[0], self.files)

    @property
    def name(self) -> str:
        return self.key.rpartition("/")[2]

    def exists(self) -> bool:
        return self.is_file() or self.is_dir()

    def is_file(self) -> bool:
        return self.key in self.files

    def is_dir(self) -> bool:
        below = f"{self.key}/" if self.key else ""
        return any(key.startswith(below) for key in self.files)

    def glob(self, pattern: str) -> list[StoreTree]:
        """The files and folders below whose path relative to this one matches ``pattern`` (``*``, ``*/*``)."""
        depth, below = pattern.count("/") + 1, f"{self.key}/" if self.key else ""
        found = {
            "/".join(key[len(below) :].split("/")[:depth])
            for key in self.files
            if key.startswith(below) and key[len(below) :].count("/") + 1 >= depth
        }
        return [self / relative for relative in sorted(found) if PurePosixPath(relative).match(pattern)]

    def open(self, mode: str = "rb") -> BinaryIO:
        return self._object().open(mode)

    def read_bytes(self) -> bytes:
        return self._object().read_bytes()

    def _object(self) -> StorePath:
        if not self.is_file():
            raise FileNotFoundError(errno.ENOENT, "no such object in the store's listing", str(self))
        return StorePath(self.config, self.key, self.files[self.key])


class RangedFile(io.RawIOBase):
    """An object of a store read as a seekable binary file, through a bounded cache of fetched ranges."""

    def __init__(self, path: StorePath) -> None:
        super().__init__()
        self.path = path
        self._position = 0
        self._cache: OrderedDict[int, bytes] = OrderedDict()  # fetched ranges by start, least recently used first
        self._starts: list[int] = []  # the same starts, sorted: a read looks at the range starting last before it
        self._cached = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._position

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        if whence not in (io.SEEK_SET, io.SEEK_CUR, io.SEEK_END):
            raise ValueError(f"invalid whence ({whence})")
        base = (0, self._position, self.path.size)[whence]
        if base + offset < 0:
            raise OSError(f"{self.path}: seek to {base + offset}, before the start")
        self._position = base + offset
        return self._position

    def read(self, size: int | None = -1) -> bytes:
        end = self.path.size if size is None or size < 0 else min(self.path.size, self._position + size)
        if end <= self._position:
            return b""
        data = self._bytes(self._position, end)
        self._position = end
        return data

    def readall(self) -> bytes:
        return self.read()

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        data = self.read(len(view))
        view[: len(data)] = data
        return len(data)

    def prefetch(self, ranges: Sequence[tuple[int, int]]) -> None:
        """Fetch the ranges ``[start, end)`` at once and keep them, as far as the cache holds them.

        Ranges are cut at the end of the object; empty ones, and ones held
        already, are left out.
        """
        wanted = sorted(
            {(start, min(end, self.path.size)) for start, end in ranges if start < min(end, self.path.size)}
        )
        wanted = [(start, end) for start, end in wanted if self._held(start, end) is None]
        if wanted:
            for (start, _), data in zip(wanted, self.path.read_ranges(wanted)):
                self._keep(start, data)

    def _held(self, start: int, end: int) -> bytes | None:
        """``[start, end)`` if the range that starts last at or before ``start`` holds it (ranges seldom overlap)."""
        index = bisect.bisect_right(self._starts, start) - 1
        if index < 0:
            return None
        first = self._starts[index]
        data = self._cache[first]
        if end > first + len(data):
            return None
        self._cache.move_to_end(first)
        return data if (first, end - start) == (start, len(data)) else data[start - first : end - first]

    def _bytes(self, start: int, end: int) -> bytes:
        held = self._held(start, end)
        if held is not None:
            return held
        fetch = min(self.path.size, max(end, start + MIN_FETCH))
        data = self.path.read_range(start, fetch)
        if len(data) < end - start:
            raise store_error(
                str(self.path),
                f"{len(data)} bytes at {start}, not {end - start}: the object is shorter than when listed",
            )
        self._keep(start, data)
        return data if len(data) == end - start else data[: end - start]

    def _keep(self, start: int, data: bytes) -> None:
        if len(data) > CACHE_BYTES // 2:
            return
        old = self._cache.pop(start, None)
        if old is not None:
            self._cached -= len(old)
        else:
            bisect.insort(self._starts, start)
        while self._cache and self._cached + len(data) > CACHE_BYTES:
            first, dropped = self._cache.popitem(last=False)
            self._starts.pop(bisect.bisect_left(self._starts, first))
            self._cached -= len(dropped)
        self._cache[start] = data
        self._cached += len(data)

    def close(self) -> None:
        self._cache.clear()
        self._starts.clear()
        self._cached = 0
        super().close()
