"""Keeping the catalog current: finding logs, and reading their facts in the background.

:class:`Indexer` runs two tasks beside the server:

* the **looker** finds logs: first every folder under each directory root
  (:class:`~xviz_server.catalog.scan.LocalScan`), each object store's whole
  listing and the datasets named by ``--dataset``; then, every ``poll``
  seconds, only the folders whose modification time changed, the logs
  waiting for their index, the logs sessions found changed, and the
  version on disk (two ``stat`` calls each) of the next
  :data:`SWEEP_PAGE` logs in name order (the sweep: every log once in so
  many looks, wherever its files changed); and every ``store_poll``
  seconds each store's listing again,
  whose ETags (or times and sizes) are the versions of its logs. A log
  whose version is new or changed is marked found; one gone is removed.
* the **indexer** reads the facts of the logs marked found, a batch at a
  time: log folders on disk in the worker processes, :data:`CHUNK` a job,
  from their index document and metadata
  (:func:`~xviz_server.catalog.facts.read_local_log`); logs in a store
  (their index and metadata: two GETs) and datasets as sessions open them,
  at most :data:`CONCURRENCY` at a time. A log that fails is kept with its
  error. A log folder with frames and no index yet is waiting: it is
  indexed once its index is written, or once its folder has not changed
  for :data:`SETTLE` seconds (then without its index: its metadata, its
  listing and at most its first and last frames).

What is listed is answered from the database at once, whatever the
indexer has done so far; ``indexed`` of ``found`` says how far it is.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..datasets import FILE_KINDS, GENERATED, STORE_REFUSED, detect, detect_in_store, scenes
from ..exceptions import XVIZError
from ..layout import LOG, Found, found_at
from ..store import ObjectStore, StoredDataset, StoredLog
from ..store.path import StoreTree
from ..work import Workers
from .columns import COLUMNS
from .db import FILE_NAME, FOUND, WAITING, CatalogDB, Row
from .query import Query
from .scan import LocalScan, source_kind, version_of

if (
    TYPE_CHECKING
):  # reading logs (.facts, the providers) is imported once there is one to read: the listing answers without it
    from ..logs import LogShelf

__all__ = ["Indexer", "SETTLE", "CONCURRENCY", "SWEEP_PAGE"]

logger = logging.getLogger(__name__)

#: Logs on disk whose version each look compares with the catalog's: a log changed where only its own
#: folder or index file tells it is found within ``ceil(logs / SWEEP_PAGE)`` looks.
SWEEP_PAGE = 1000
#: Seconds a log folder without an index must stay unchanged before it is indexed from its frames.
SETTLE = 10.0
#: Logs read at once from a store or as datasets.
CONCURRENCY = 8
#: Logs taken from the database at a time to index.
BATCH = 4096
#: Log folders on disk read by one job in the worker processes; the facts of each job are stored in one transaction.
CHUNK = 512
#: Such jobs given to the worker processes at once: the facts of one are stored while others are read.
READING = 3
#: The version of a log in a store that a session found before the store's next listing told its version.
NOTICED = "noticed"
#: The root of the datasets named by ``--dataset``.
DATASETS = "--dataset"
#: Catalog kinds of the discovery kinds they come from.
_DISCOVERY_KINDS = {"bag": "rosbag", "mcap": "rosbag"}


class Names(Sequence[str]):
    """The names of the catalog in order, read from the database as they are asked for."""

    def __init__(self, db: CatalogDB, count: int) -> None:
        self._db = db
        self._count = count

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, item: Any) -> Any:
        if isinstance(item, slice):
            start, stop, step = item.indices(self._count)
            return self._db.names(start, max(0, stop - start))[::step]
        names = self._db.names(item % self._count if self._count else item, 1)
        if not names:
            raise IndexError(item)
        return names[0]

    def __iter__(self) -> Iterator[str]:
        return iter(self._db.names(0, -1))


class Indexer:
    """The persistent catalog of every log the server serves (see the module).

    ``roots`` are the data roots. The database is
    ``state_dir``/:data:`~xviz_server.catalog.db.FILE_NAME`, or memory
    without a ``state_dir``; :meth:`open` opens it, and from then on
    :meth:`page` and :meth:`one` answer from it; :meth:`start` starts
    keeping it current.
    """

    def __init__(
        self,
        roots: Sequence[Path | ObjectStore],
        workers: Workers,
        *,
        state_dir: Path | None,
        poll: float,
        store_poll: float,
    ) -> None:
        self._scans = [LocalScan(Path(root), detect, scenes) for root in roots if not isinstance(root, ObjectStore)]
        self._stores = [root for root in roots if isinstance(root, ObjectStore)]
        self._local_roots = {scan.root for scan in self._scans}
        # Where a name is in several roots, the first of these serves it.
        self._rank = {
            root: rank
            for rank, root in enumerate(
                [*(scan.root for scan in self._scans), DATASETS, *(store.url for store in self._stores)]
            )
        }
        self._shelf: LogShelf  # given to start()
        self._workers = workers
        self._path = None if state_dir is None else Path(state_dir) / FILE_NAME
        self._poll = poll
        self._store_poll = store_poll
        self._swept: dict[str, str] = {}  # by root: the last log name of the sweep's last page
        self.db: CatalogDB | None = None
        self._count = 0
        self._datasets: dict[str, Found] = {}
        self._stored: dict[str, StoredLog | StoredDataset] = {}  # store entries found, until indexed
        self._store_datasets: dict[str, StoredDataset] = {}  # the datasets of the stores' last listings (few)
        self._noticed: dict[str, Found | StoredLog | StoredDataset | None] = {}
        self._looking = False  # a look for changes is under way
        self._wake = asyncio.Event()
        self._work = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        #: Set once every root has been looked at the first time.
        self.looked = asyncio.Event()
        self._idle = asyncio.Event()

    async def open(self) -> None:
        """Open the database (a file of another version or unreadable is built again): no log is looked at."""
        self.db = await self._workers.io(CatalogDB, self._path)

    async def start(self, shelf: LogShelf) -> None:
        """Start the tasks; ``shelf`` opens logs (datasets and logs that need it) and is told where names come from."""
        await self._counted()
        self._shelf = shelf
        shelf.known = self
        self._tasks = [asyncio.ensure_future(self._look()), asyncio.ensure_future(self._index())]

    async def close(self) -> None:
        """Stop the tasks and close the database."""
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._tasks = []
        if self.db is not None:
            await self._workers.io(self.db.close)
            self.db = None

    @property
    def _db(self) -> CatalogDB:
        assert self.db is not None, "the catalog is not started"
        return self.db

    async def settled(self) -> None:
        """Wait until the first look is done, every log found is indexed and the sorts' indexes are made (for tests and tools).

        A log folder waiting for its index (see the module) is left waiting:
        it is indexed once its writer is done, which nothing here can hasten.
        """
        await self.looked.wait()
        while True:
            self._idle.clear()
            indexed, found = await self._counted()
            waiting = len(await self._workers.io(self._db.waiting)) if indexed < found else 0
            if indexed + waiting == found and not self._looking and not self._noticed and self._db.sorted:
                return
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._idle.wait(), self._poll)

    async def _counted(self) -> tuple[int, int]:
        indexed, found = await self._workers.io(self._db.counts)
        self._count = found
        return indexed, found

    def available(self) -> Names:
        """The names of the catalog in order, each read when asked for."""
        return Names(self._db, self._count)

    async def locate(self, name: str) -> Found | StoredDataset | None:
        """Where the log ``name`` is, when it is a log or dataset under a directory root, or a dataset in a store."""
        return await self._workers.io(self._locate, name)

    def _locate(self, name: str) -> Found | StoredDataset | None:
        where = self._db.place(name)
        if where is None:
            return None
        if where[0] not in self._local_roots:
            return self._store_datasets.get(name)
        rows = self._db.select("name = ?", [name], "name", 1)
        kind = rows[0]["kind"] if rows else LOG
        return found_at(name, where[1], _DISCOVERY_KINDS.get(kind, kind))

    async def version(self, name: str) -> str | None:
        """The version of log ``name`` the catalog last found (on disk, or in its store's listing), if it holds it."""
        where = await self._workers.io(self._db.place, name)
        return None if where is None else where[2]

    def notice(self, name: str, found: Found | StoredLog | StoredDataset | None = None) -> None:
        """A session found ``name`` new (``found``: where), changed or gone: look at it soon."""
        self._noticed[name] = found
        self._wake.set()

    # -- questions ----------------------------------------------------------

    async def page(self, query: Query) -> dict[str, Any]:
        """One page of the listing: ``logs``, ``next`` (the cursor of the next page, or ``None``), ``indexed``, ``found``."""
        return await self._workers.io(self._page, query)

    def _page(self, query: Query) -> dict[str, Any]:
        db = self._db
        stream_id = db.stream_id(query.stream) if query.stream is not None else None
        where, parameters = query.where(stream_id, db.longest() if query.start is not None else None)
        rows = db.select(where, parameters, query.order(), query.limit + 1)
        indexed, found = db.counts()
        self._count = found
        more = len(rows) > query.limit
        rows = rows[: query.limit]
        return {
            "logs": [summary(row) for row in rows],
            "next": query.cursor(rows[-1]) if more else None,
            "indexed": indexed,
            "found": found,
        }

    async def one(self, name: str) -> dict[str, Any] | None:
        """Every fact of the log ``name``, or ``None`` if the catalog does not hold it."""
        rows = await self._workers.io(self._db.select, "name = ?", [name], "name", 1)
        if not rows:
            return None
        (row,) = rows
        shown = {column.name: row[column.name] for column in COLUMNS if not column.listed and row.get(column.name)}
        return {**summary(row), "state": row["state"], **shown}

    # -- finding logs -------------------------------------------------------

    async def _look(self) -> None:
        started = time.perf_counter()
        try:
            await self._first_look()
        except Exception:
            logger.exception("catalog: looking for logs failed")
        indexed, found = await self._counted()
        logger.info(
            "catalog: %d logs found in %.1f s, %d of them indexed", found, time.perf_counter() - started, indexed
        )
        roots = [*(scan.root for scan in self._scans), *(store.url for store in self._stores)]
        if roots and not found:
            logger.warning(
                "no logs under %s yet: put logs in the reference layout or datasets there (mounted, in a container); "
                "one added later is listed within seconds, and served on the first request that names it",
                ", ".join(roots),
            )
        self.looked.set()
        self._work.set()  # the indexer makes the sorts' indexes once it has nothing left to read
        last_list = time.monotonic()
        while True:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._wake.wait(), self._poll)
            self._wake.clear()
            self._looking = True
            try:
                await self._look_again()
                if time.monotonic() - last_list >= self._store_poll:
                    last_list = time.monotonic()
                    for store in self._stores:
                        await self._list_store(store)
            except Exception:
                logger.exception("catalog: looking for changes failed")
            finally:
                self._looking = False
                self._idle.set()

    async def _first_look(self) -> None:
        removed = await self._workers.io(self._db.keep_roots, list(self._rank))
        if removed:
            logger.info("catalog: %d logs of data roots no longer served left the catalog", removed)
        datasets = await self._shelf.find_datasets()
        self._datasets = {found.name: found for found in datasets}
        rows = [
            Row(
                found.name, DATASETS, str(found.path), _dataset_version(found), source_kind(found.kind, str(found.path))
            )
            for found in datasets
        ]
        await self._found(rows)
        await self._keep_only(DATASETS, {row.name for row in rows})
        for scan in self._scans:
            seen: set[str] = set()
            batches = await self._workers.io(scan.walk)
            while (batch := await self._workers.io(next, batches, None)) is not None:
                await self._found(batch)
                seen.update(row.name for row in batch)
            await self._keep_only(scan.root, seen)
        for store in self._stores:
            await self._list_store(store)

    async def _found(self, rows: list[Row]) -> None:
        """Record rows found: new ones and those of another version are marked found (to index)."""
        if not rows:
            return
        known = await self._workers.io(self._db.versions, [row.name for row in rows])
        changed = [row for row in rows if self._takes(row, known.get(row.name))]
        if changed:
            await self._workers.io(self._db.found, changed)
            await self._counted()
            self._work.set()
        if any(row.kind not in (LOG,) for row in changed):
            asyncio.ensure_future(self._workers.warm())  # datasets convert in the process pool

    def _takes(self, row: Row, known: tuple[str, str] | None) -> bool:
        """Whether ``row`` is new or changed, and not a name that a root served first holds (see :class:`~xviz_server.logs.LogShelf`)."""
        if known is None:
            return True
        root, version = known
        if root != row.root:
            return self._rank.get(row.root, len(self._rank)) < self._rank.get(root, len(self._rank))
        return version != row.version

    async def _keep_only(self, root: str, names: set[str]) -> None:
        """Remove the logs of ``root`` not among ``names``."""
        gone: list[str] = []
        after = ""
        while page := await self._workers.io(self._db.places, root, after):
            gone += [name for name, *_ in page if name not in names]
            after = page[-1][0]
        if gone:
            await self._workers.io(self._db.remove, gone)
            await self._counted()

    async def _look_again(self) -> None:
        for scan in self._scans:
            rows, gone = await self._workers.io(scan.changes)
            await self._found(rows)
            for prefix in gone:
                await self._workers.io(self._db.remove_below, scan.root, prefix)
            if gone:
                await self._counted()
        waiting = await self._workers.io(self._db.waiting)
        if waiting:
            await self._workers.io(self._recheck, waiting)
            self._work.set()
        noticed, self._noticed = self._noticed, {}
        for name, found in noticed.items():
            if isinstance(found, (StoredLog, StoredDataset)):
                await self._found_in_store(found)
            else:
                await self._recheck_one(name)
        for scan in self._scans:
            await self._sweep(scan.root)

    def _recheck(self, waiting: list[tuple[str, str, str]]) -> None:
        """Mark found again the waiting logs that changed, or that stayed unchanged for :data:`SETTLE` seconds."""
        due = []
        for name, place, version in waiting:
            now = version_of(place)
            if now is None:
                self._db.remove([name])
            elif (where := self._db.place(name)) is not None and now != version:
                self._db.found([Row(name, where[0], place, now, LOG)])
            elif time.time() - int(version.split(",")[0]) / 1e9 >= SETTLE:
                due.append(name)
        self._db.mark(due, FOUND)

    async def _recheck_one(self, name: str) -> None:
        where = await self._workers.io(self._db.place, name)
        if where is None or where[0] not in self._local_roots:
            return  # a log the looks have not found yet (they will), or one in a store (its listing tells)
        root, place, version = where
        now = await self._workers.io(version_of, place)
        if now is None:
            await self._workers.io(self._db.remove, [name])
            await self._counted()
        elif now != version:
            kind = (await self._workers.io(self._db.select, "name = ?", [name], "name", 1))[0]["kind"]
            await self._found([Row(name, root, place, now, kind)])

    async def _found_in_store(self, entry: StoredLog | StoredDataset) -> None:
        """A log or dataset a session found in a store before its next listing: indexed now, its version told by that listing."""
        key = entry.folder.prefix if isinstance(entry, StoredLog) else entry.path.key
        store = next((store for store in self._stores if store.key_url(key).startswith(f"{store.url}/")), None)
        if store is not None and not await self._workers.io(
            self._db.versions, [entry.name]
        ):  # unknown to the listings so far
            self._stored[entry.name] = entry
            await self._found([Row(entry.name, store.url, store.key_url(key), NOTICED, source_kind(entry.kind, key))])

    async def _sweep(self, root: str) -> None:
        """Compare the version on disk of the next :data:`SWEEP_PAGE` logs of ``root`` with the catalog's (two ``stat`` calls a log)."""
        page = await self._workers.io(self._db.places, root, self._swept.get(root, ""), SWEEP_PAGE)
        self._swept[root] = page[-1][0] if len(page) == SWEEP_PAGE else ""  # from the first again after the last
        if page:
            changed, gone = await self._workers.io(_versions_now, page)
            if gone:
                await self._workers.io(self._db.remove, gone)
                await self._counted()
            kinds = (
                {
                    row["name"]: row["kind"]
                    for row in await self._workers.io(
                        self._db.select,
                        f"name IN ({','.join('?' * len(changed))})",
                        [name for name, _, _ in changed],
                        "name",
                        len(changed),
                    )
                }
                if changed
                else {}
            )
            await self._found(
                [Row(name, root, place, version, kinds[name]) for name, place, version in changed if name in kinds]
            )

    async def _list_store(self, store: ObjectStore) -> None:
        """List a store's prefix; its logs' versions come from their objects' ETags (or times and sizes)."""
        try:
            objects = await store.list_all()
        except XVIZError as exc:
            logger.warning("catalog: cannot list %s: %s", store.url, exc)
            return
        entries = store.found_in(objects, FILE_KINDS, STORE_REFUSED, detect_in_store)
        by_folder: dict[str, list[Any]] = {}
        for meta in objects:
            by_folder.setdefault(meta["path"].rpartition("/")[0], []).append(meta)
        rows = []
        for entry in entries:
            if isinstance(entry, StoredLog):
                key = entry.folder.prefix
                version = _digest(f"{meta['path']}\0{_etag(meta)}" for meta in by_folder.get(key, ()))
            else:
                key = entry.path.key
                version = _digest(
                    f"{meta['path']}\0{_etag(meta)}"
                    for meta in objects
                    if meta["path"] == key or meta["path"].startswith(f"{key}/")
                )
            rows.append(Row(entry.name, store.url, store.key_url(key), version, source_kind(entry.kind, key)))
        for entry in entries:
            if isinstance(entry, StoredDataset):
                self._store_datasets[entry.name] = entry
        known = await self._workers.io(self._db.versions, [row.name for row in rows])
        for entry, row in zip(entries, rows):
            if self._takes(row, known.get(row.name)):
                self._stored[row.name] = entry
                if isinstance(entry, StoredLog):
                    entry.folder.take(by_folder.get(entry.folder.prefix, []))
        await self._found(rows)
        await self._keep_only(store.url, {row.name for row in rows})

    # -- reading facts ------------------------------------------------------

    async def _index(self) -> None:
        while True:
            self._work.clear()
            batch = await self._workers.io(self._db.pending, BATCH)
            if not batch:
                if self.looked.is_set():
                    started = time.perf_counter()
                    if await self._workers.io(self._db.sort_indexes):
                        logger.info("catalog: the indexes of its sorts made in %.1f s", time.perf_counter() - started)
                self._idle.set()
                await self._work.wait()
                continue
            try:
                await self._index_batch(batch)
            except Exception:
                logger.exception("catalog: indexing failed")
                await asyncio.sleep(self._poll)
            await self._counted()
            self._idle.set()

    async def _index_batch(self, batch: list[tuple[str, str, str, str, str]]) -> None:
        local_roots = self._local_roots
        on_disk = [
            (name, place, version) for name, root, place, version, kind in batch if root in local_roots and kind == LOG
        ]
        others = [row for row in batch if not (row[1] in local_roots and row[4] == LOG)]
        now, reading = time.time(), asyncio.Semaphore(READING)

        async def read_folders(chunk: list[tuple[str, str, str]]) -> None:
            async with reading:
                results, waiting = await self._workers.cpu(_read_local, chunk, now)
            if waiting:
                await self._workers.io(self._db.mark, waiting, WAITING)
            await self._workers.io(self._db.indexed, results)

        await asyncio.gather(*(read_folders(on_disk[start : start + CHUNK]) for start in range(0, len(on_disk), CHUNK)))
        gate = asyncio.Semaphore(CONCURRENCY)
        places = {name: (root, place, kind) for name, root, place, version, kind in batch}

        async def read(name: str, version: str) -> tuple[str, str, dict[str, Any]]:
            root, place, kind = places[name]
            async with gate:
                try:
                    return name, version, await self._read(name, root, place, kind)
                except XVIZError as exc:
                    return name, version, {"kind": kind, "error": str(exc)}
                except OSError as exc:
                    return name, version, {"kind": kind, "error": f"cannot read {place}: {exc.strerror or exc}"}

        jobs = [read(name, version) for name, _, _, version, _ in others]
        if jobs:
            await self._workers.io(self._db.indexed, await asyncio.gather(*jobs))

    async def _read(self, name: str, root: str, place: str, kind: str) -> dict[str, Any]:
        """The facts of a log in a store or of a dataset, opened as a session opens it."""
        from ..providers.static_log import StaticLog
        from .facts import facts, tree_bytes

        entry: Found | StoredLog | StoredDataset | None
        if root == DATASETS:
            entry = self._datasets.get(name)
        elif root in {store.url for store in self._stores}:
            entry = self._stored.pop(name, None)
        else:
            entry = found_at(name, place, _DISCOVERY_KINDS.get(kind, kind))
        if entry is None:
            raise XVIZError(f"log {name!r} is no longer where it was found: {place}")
        if isinstance(entry, StoredLog):  # its files and their sizes are those of the listing
            log = StaticLog(name, entry.folder, entry.folder.listed(), self._workers)
            metadata, index = await log.metadata(), await log.index()
            return facts(kind, log.format, metadata, index, entry.folder.listed_bytes(), None)
        opened = await self._shelf.load(entry)
        size, modified = None, None
        if isinstance(entry, Found) and entry.kind not in GENERATED:
            size, modified = await self._workers.io(tree_bytes, str(entry.path))
        elif isinstance(entry, StoredDataset):
            size = sum(entry.path.files.values()) if isinstance(entry.path, StoreTree) else entry.path.size
        return facts(kind, opened.format, opened.metadata, opened.index, size, modified)


def _read_local(
    logs: list[tuple[str, str, str]], now: float
) -> tuple[list[tuple[str, str, dict[str, Any]]], list[str]]:
    """Facts of log folders on disk, at ``now``, for a worker process: those read, and those waiting for their index."""
    from .facts import read_local_log

    results: list[tuple[str, str, dict[str, Any]]] = []
    waiting: list[str] = []
    for name, place, version in logs:
        try:
            found = read_local_log(name, place, unindexed=now - int(version.split(",")[0]) / 1e9 >= SETTLE)
        except XVIZError as exc:
            results.append((name, version, {"kind": LOG, "error": str(exc)}))
            continue
        except OSError as exc:
            results.append((name, version, {"kind": LOG, "error": f"cannot read {place}: {exc.strerror or exc}"}))
            continue
        if found is not None:
            results.append((name, version, found))
        else:
            waiting.append(name)
    return results, waiting


def _versions_now(page: list[tuple[str, str, str, str]]) -> tuple[list[tuple[str, str, str]], list[str]]:
    """Of the logs ``page`` (name, place, version, state): those whose version changed (with the new one), and those gone."""
    changed, gone = [], []
    for name, place, version, _ in page:
        now = version_of(place)
        if now is None:
            gone.append(name)
        elif now != version:
            changed.append((name, place, now))
    return changed, gone


def _dataset_version(found: Found) -> str:
    if found.kind in GENERATED:
        return found.kind
    return version_of(str(found.path)) or ""


def _etag(meta: Any) -> str:
    return str(meta.get("e_tag") or f"{meta.get('last_modified')}:{meta.get('size')}")


def _digest(parts: Any) -> str:
    return hashlib.blake2b("\n".join(sorted(parts)).encode(), digest_size=12).hexdigest()


def summary(row: dict[str, Any]) -> dict[str, Any]:
    """A log as a listing shows it: name, kind, whether it is indexed, and its listed columns that are known."""
    shown: dict[str, Any] = {"name": row["name"], "kind": row["kind"], "indexed": row["state"] not in (FOUND, WAITING)}
    for column in COLUMNS:
        if column.listed and row.get(column.name) is not None:
            shown[column.name] = row[column.name]
    return shown
