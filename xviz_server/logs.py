"""Logs as sessions see them, whatever provider they come from.

:class:`LogShelf` names every log the providers serve and opens each one
once; the :class:`Log` it returns is shared by every session. A log's frames
go through the shared :class:`~xviz_server.cache.FrameCache`: the bytes read
from the source, checked once, and each rendering of them (another format,
a stream filter) are encoded once and kept as immutable bytes. Blocking work
runs in :class:`~xviz_server.work.Workers`.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from . import frames
from .cache import FrameCache
from .codec import Format, cut_glb, detect_format, encode
from .datasets import FILE_KINDS, GENERATED, STORE_REFUSED, detect, detect_in_store, scenes
from .exceptions import DecodeError, FrameError, LogError, LogNotFound, SchemaValidationError, XVIZError
from .layout import LOG, Found, check_log_name, discover, frame_bytes, is_log_directory, stamp_of
from .levels import FULL, Level
from .messages import XVIZ_VERSION, envelope, is_number
from .providers import LogSource
from .providers.datasets import DatasetProvider, explicit_datasets
from .providers.static_log import StaticLogProvider
from .readahead import ReadAhead
from .records import OriginalTopic
from .state import COMPLETE_TYPES
from .store import ObjectStore, StoredDataset, StoredLog
from .timeindex import TimeIndex
from .work import Place, Workers

__all__ = ["LogShelf", "Known", "Log", "complete_metadata"]

logger = logging.getLogger(__name__)

_openings = itertools.count()


class Log:
    """One open log: metadata, time index and frames, shared by every session."""

    def __init__(
        self,
        source: LogSource,
        metadata: dict[str, Any],
        index: TimeIndex,
        cache: FrameCache,
        workers: Workers,
        validate: bool = False,
    ) -> None:
        self.name = source.name
        self.format = source.format
        # Frames are cached under this key: a log read again after a change
        # on disk never gets the frames of the log it replaces.
        self._key = (source.name, next(_openings))
        self.index = index
        self.metadata = complete_metadata(metadata, index)
        self._source = source
        self._cache = cache
        self._workers = workers
        self._validate = validate
        #: How far a stream reads ahead of this log, when its source says (a log in an object store).
        self.read_ahead: ReadAhead | None = getattr(source, "read_ahead", None)
        #: The topics of the recording the log is read from, as the file holds them (a ROS bag, an MCAP file); their
        #: messages come from :meth:`original_messages`.
        self.originals: tuple[OriginalTopic, ...] = tuple(getattr(source, "originals", ()))
        self._read_originals: Callable[[int], Awaitable[bytes]] | None = getattr(source, "read_originals", None)
        self._metadata_messages = {fmt: encode(envelope("metadata", self.metadata), fmt) for fmt in Format}
        # Update type of each frame checked so far, to know where a complete
        # state starts without decoding frames again; and the frames that
        # alone are a complete state (a complete type, one stream set).
        self._update_types: dict[int, str] = {}
        self._whole: set[int] = set()

    @classmethod
    async def open(cls, source: LogSource, cache: FrameCache, workers: Workers, validate: bool = False) -> Log:
        """Read a source's metadata and index; raises :class:`~xviz_server.exceptions.LogError`.

        With ``validate``, the metadata and every frame when first loaded are
        checked against the XVIZ schema.
        """
        metadata = await source.metadata()
        if validate:
            try:
                await workers.io(frames.validate, envelope("metadata", metadata))
            except SchemaValidationError as exc:
                raise LogError(f"log {source.name!r}: metadata {exc}", log=source.name) from None
        index = await source.index()
        return cls(source, metadata, index, cache, workers, validate)

    @property
    def streams(self) -> list[str]:
        """Names of the streams the metadata declares."""
        return sorted(self.metadata.get("streams") or ())

    def stored_size(self, number: int) -> int | None:
        """The size of frame ``number`` as its source stores it, when known before reading it."""
        size = getattr(self._source, "stored_size", None)
        return None if size is None else size(number)

    def metadata_message(self, fmt: Format) -> bytes:
        """The ``xviz/metadata`` message, encoded in ``fmt``."""
        return self._metadata_messages[fmt]

    async def frame(
        self, number: int, fmt: Format, streams: frozenset[str] | None = None, level: Level = FULL
    ) -> bytes:
        """Frame ``number`` encoded in ``fmt``, with only ``streams`` if given, at ``level`` of detail.

        A level below full is made once, by the first request for it, and
        kept in the frame cache. Raises
        :class:`~xviz_server.exceptions.FrameError` naming the frame.
        """
        if level is not FULL:
            return await self._cache.get(
                (self._key, number, fmt, streams, level.name), lambda: self._render_level(number, fmt, streams, level)
            )
        if streams is None and fmt is self.format:
            data = await self._checked(number)
            if detect_format(data) is fmt:
                return data
        return await self._cache.get((self._key, number, fmt, streams), lambda: self._render(number, fmt, streams))

    async def derived(
        self, number: int, name: str, job: Callable[..., bytes], *args: Any, level: Level = FULL
    ) -> bytes:
        """Frame ``number`` made into something else by ``job(data, *args)``, made once and kept in the frame cache.

        ``name`` tells what ``job`` makes (frames of one log made by the same
        ``name`` are the same bytes); ``job`` runs where a frame job of that
        size runs (:func:`~xviz_server.frames.placement`). Below full
        detail, ``data`` is the frame at ``level`` as GLB (:meth:`frame`,
        the same bytes that XVIZ sessions at that level are sent). Raises
        :class:`~xviz_server.exceptions.FrameError` naming the frame.
        """

        async def make() -> bytes:
            data = await (self._checked(number) if level is FULL else self.frame(number, Format.BINARY, None, level))
            try:
                return await self._workers.run(frames.placement(len(data), detect_format(data)), job, data, *args)
            except DecodeError as exc:
                raise self._corrupt(number, exc) from None

        key = (self._key, number, name) if level is FULL else (self._key, number, name, level.name)
        return await self._cache.get(key, make)

    async def original_messages(self, number: int) -> bytes:
        """The original messages of frame ``number`` (see :attr:`originals`), packed, each record's channel its
        topic's place in :attr:`originals`: read once, in a worker process, and kept in the frame cache.

        Raises :class:`~xviz_server.exceptions.FrameError` naming the frame.
        """
        read = self._read_originals
        if not self.originals or read is None:
            return b""
        return await self._cache.get((self._key, number, "originals"), lambda: read(number))

    async def preload(self) -> int:
        """Load every frame into the frame cache, in frame order, one at a time; how many were read.

        Each is loaded as a session's first request would load it, so that
        later requests find it there. A frame that cannot be read is skipped:
        a session that asks for it gets the error.
        """
        loaded = 0
        for number in self.index.frames.tolist():
            try:
                await self._checked(number)
            except XVIZError:
                continue
            loaded += 1
        return loaded

    async def _checked(self, number: int) -> bytes:
        """The frame as the source stores it, checked to be a readable state update."""
        return await self._cache.get((self._key, number, None, None), lambda: self._read(number))

    async def _read(self, number: int) -> bytes:
        data = await self._source.read(number)
        try:
            fmt = detect_format(data)
            if fmt is Format.BINARY and len(cut := cut_glb(data)) < len(data):
                logger.warning(
                    "log %r: frame %d has %d bytes after its GLB end; they are not served",
                    self.name,
                    number,
                    len(data) - len(cut),
                )
                data = cut
            # Schema checks take long at any size.
            place = Place.THREAD if self._validate else frames.placement(len(data), fmt)
            update_type, stream_sets = await self._workers.run(place, frames.check, data, self._validate)
        except (DecodeError, SchemaValidationError) as exc:
            raise self._corrupt(number, exc) from None
        self._update_types[number] = update_type
        if update_type in COMPLETE_TYPES and stream_sets == 1:
            self._whole.add(number)
        return data

    async def _render(self, number: int, fmt: Format, streams: frozenset[str] | None) -> bytes:
        data = await self._checked(number)
        try:
            place = frames.placement(len(data), detect_format(data), fmt)
            return await self._workers.run(place, frames.render, data, fmt, streams)
        except DecodeError as exc:
            raise self._corrupt(number, exc) from None

    async def _render_level(self, number: int, fmt: Format, streams: frozenset[str] | None, level: Level) -> bytes:
        data = await self._checked(number)
        try:
            place = (
                Place.PROCESS if len(data) > frames.HEAVY_JSON_BYTES else Place.THREAD
            )  # numpy and Pillow: CPU-heavy
            return await self._workers.run(place, frames.render, data, fmt, streams, None, level)
        except DecodeError as exc:
            raise self._corrupt(number, exc) from None

    async def complete_state(self, instant: float, fmt: Format, streams: frozenset[str] | None, lookback: int) -> bytes:
        """The latest state of each stream at or before ``instant``, as one message.

        Found through the index: the last frame at or before ``instant``, and
        before it only as many frames as it takes to reach one whose update
        type is complete (``COMPLETE_STATE``/``SNAPSHOT``), at most
        ``lookback``. Raises :class:`~xviz_server.exceptions.XVIZError` when
        the log has no state at that time.

        Every instant between two frames has the same answer. When the frame
        it ends at is a complete state of its own in ``fmt`` and every stream
        is wanted, the answer is that frame, relabelled ``COMPLETE_STATE`` if
        needed. Where that is cheap (a GLB frame, whose JSON chunk is
        rewritten and arrays are not, or a JSON frame of at most
        :data:`~xviz_server.frames.INLINE_BYTES`), it is made again each
        time, so that it takes no second place in the cache. Other answers
        are merged once and kept in the frame cache by the frame they end at.
        """
        position = self.index.at(instant)
        if position is None:
            raise XVIZError(f"the log has no state at or before {instant} (it starts at {self.index.start_time})")
        number = int(self.index.frames[position])
        # A frame known not to be whole is not read here: its answer may be cached.
        if streams is None and (number in self._whole or number not in self._update_types):
            data = await self._checked(number)
            if number in self._whole and detect_format(data) is fmt:
                if self._update_types[number] == "COMPLETE_STATE":
                    return data
                if fmt is Format.BINARY or len(data) <= frames.INLINE_BYTES:
                    return await self._workers.run(frames.placement(len(data), fmt), frames.relabel_complete, data)
        key = (self._key, "state", position, fmt, streams, lookback)
        return await self._cache.get(key, lambda: self._merge(position, fmt, streams, lookback))

    async def _merge(self, position: int, fmt: Format, streams: frozenset[str] | None, lookback: int) -> bytes:
        numbers = []
        for back in range(position, max(-1, position - lookback), -1):
            number = int(self.index.frames[back])
            await self._checked(number)  # loads it and learns its update type
            numbers.append(number)
            if self._update_types.get(number) in COMPLETE_TYPES:
                break
        data = [await self._checked(number) for number in numbers]
        place = frames.placement(sum(map(len, data)), fmt, *map(detect_format, data))
        message, _ = await self._workers.run(place, frames.merge, data, fmt, streams)
        return message

    def _corrupt(self, number: int, exc: Exception) -> FrameError:
        where = getattr(self._source, "describe_frame", lambda n: f"frame {n}")(number)
        return FrameError(
            f"frame {number} ({where}) of log {self.name!r} is corrupt: {exc}", log=self.name, frame=number
        )


def complete_metadata(metadata: dict[str, Any], index: TimeIndex) -> dict[str, Any]:
    """Metadata with what clients need: ``version``, and ``log_info`` times from the index if missing."""
    result = dict(metadata)
    result.setdefault("version", XVIZ_VERSION)
    info = dict(result.get("log_info") or {})
    for key, value in (("start_time", index.start_time), ("end_time", index.end_time)):
        current = info.get(key)
        if not (is_number(current) and current != 0) and value is not None:
            info[key] = value
    result["log_info"] = info
    return result


class Known(Protocol):
    """What knows every log served, when a :class:`LogShelf` does not scan for them itself."""

    def available(self) -> Sequence[str]:
        """The names of the logs, in order."""
        ...

    async def locate(self, name: str) -> Found | StoredDataset | None:
        """Where the log or dataset ``name`` is, if known."""
        ...

    def notice(self, name: str, found: Found | StoredLog | StoredDataset | None = None) -> None:
        """A session found the log ``name`` new (``found``: where), changed or gone."""
        ...


class LogShelf:
    """Every log under the data roots and every dataset named, by name; each is opened once and shared.

    ``roots`` are directories and object stores; a name found in a
    directory or among the datasets is served from there rather than from a
    store. ``datasets`` are ``(kind, path, options)`` (``--dataset``);
    ``options`` go to every dataset (``image_max_width``).

    A log folder on disk whose frames take at most ``preload_bytes`` is
    read into the frame cache in the background when a session first opens
    it (see :meth:`Log.preload`), so that seeking in it soon never waits
    for the disk; listing the catalog reads no frames, and logs are read in
    one at a time, in the order sessions opened them. Logs in a store (a
    billed request a frame) and datasets (a conversion a frame) are read
    only as sessions ask.
    """

    def __init__(
        self,
        roots: Sequence[Path | ObjectStore],
        cache: FrameCache,
        workers: Workers,
        *,
        datasets: Sequence[tuple[str, Path, dict[str, str]]] = (),
        options: dict[str, Any] | None = None,
        validate: bool = False,
        preload_bytes: int = 0,
    ) -> None:
        self._roots = [Path(root) for root in roots if not isinstance(root, ObjectStore)]
        self._stores = [root for root in roots if isinstance(root, ObjectStore)]
        self._datasets = [(kind, Path(path), options) for kind, path, options in datasets]
        self._logs = StaticLogProvider(workers)
        self._converted = DatasetProvider(workers, options)
        self._cache = cache
        self._workers = workers
        self._validate = validate
        self._found: dict[str, Found | StoredLog | StoredDataset] = {}
        self._open: dict[str, asyncio.Task[Log]] = {}
        self._stamps: dict[str, tuple[int, ...]] = {}  # what stamp_of() said when each was opened
        self._failed: dict[str, tuple[int, ...]] = {}  # the version of each log whose failure to open was logged
        self._preload_bytes = preload_bytes
        self._preloads: dict[str, asyncio.Task[None]] = {}
        self._preloading = asyncio.Lock()  # one log read in at a time, however many sessions open
        #: What knows the logs when :meth:`scan` is not used: the persistent catalog.
        self.known: Known | None = None

    def names(self) -> list[str]:
        """Names of every log known, in order (read all at once: see :meth:`available`)."""
        return list(self.available())

    def available(self) -> Sequence[str]:
        """Names of the logs known, in order: those :attr:`known` gives when set, else those of the last scan."""
        return self.known.available() if self.known is not None else sorted(self._found)

    async def find_datasets(self) -> list[Found]:
        """Find the datasets named on the command line (``--dataset``), for :meth:`open`; what they are."""
        found = await self._workers.io(self._named_datasets)
        for entry in found:
            self._found.setdefault(entry.name, entry)
        return found

    def kinds(self) -> set[str]:
        """The kinds of what the last scan found (:data:`~xviz_server.layout.LOG`, dataset kinds)."""
        return {found.kind for found in self._found.values()}

    async def scan(self) -> list[str]:
        """Look for logs again (a log added to a data directory appears, a removed one goes)."""
        found: dict[str, Found | StoredLog | StoredDataset] = {**await self._workers.io(self._discover)}
        for store in self._stores:
            for stored in await store.discover(FILE_KINDS, STORE_REFUSED, detect_in_store):
                found.setdefault(stored.name, stored)
        self._found = found
        for gone in self._open.keys() - self._found.keys():
            del self._open[gone]
            self._stamps.pop(gone, None)
            self._stop_preload(gone)
        return self.names()

    def _discover(self) -> dict[str, Found]:
        found: dict[str, Found] = {}
        for root in self._roots:
            for entry in discover(root, detect, scenes):
                found.setdefault(entry.name, entry)
        for entry in self._named_datasets():
            found.setdefault(entry.name, entry)
        return found

    def _named_datasets(self) -> list[Found]:
        return [entry for kind, path, given in self._datasets for entry in explicit_datasets(kind, path, given)]

    def _lookup(self, name: str) -> Found | None:
        """Look for the log or dataset ``name`` under each root, without a whole scan."""
        for root in self._roots:
            path = root / name
            if path.is_dir():
                kind = LOG if is_log_directory(path) else detect(path)
                if kind is not None:
                    return Found(name, path, kind)
            for suffix in FILE_KINDS:
                candidate = path.with_name(path.name + suffix)
                if candidate.is_file() and detect(candidate) is not None:
                    return Found(name, candidate, FILE_KINDS[suffix])
        return None

    async def open(self, name: str, *, preload: bool = True) -> Log:
        """The open log called ``name``; with ``preload``, read into the frame cache if it may be (see the class).

        Raises :class:`~xviz_server.exceptions.LogNotFound` for a name that is
        not allowed or not served, and :class:`~xviz_server.exceptions.LogError`
        for a log that cannot be served. A failed open is tried again next time.

        An open log is read again when its folder or file has changed since
        (see :func:`~xviz_server.layout.stamp_of`); sessions that have it keep the one they have.
        """
        check_log_name(name)
        found = self._found.get(name)
        if found is None and self.known is not None:
            found = await self.known.locate(name)
        if found is None:
            found = await self._workers.io(self._lookup, name)
            for store in self._stores:
                found = found or await store.lookup(name, FILE_KINDS, detect_in_store)
            if found is not None:
                self._found[name] = found
                self._notice(name, found)
        if found is None:
            available = list(self.available()[:20])
            shown = ", ".join(repr(n) for n in available) or "none"
            raise LogNotFound(f"no log named {name!r}; available: {shown}", name=name, available=available)
        # A log in a store is read once; a scan finds the logs added or removed since.
        where = None if isinstance(found, (StoredLog, StoredDataset)) or found.kind in GENERATED else found.path
        stamp = () if where is None else await self._workers.io(stamp_of, where)
        if stamp is None:
            self._found.pop(name, None)
            self._open.pop(name, None)
            self._stamps.pop(name, None)
            self._notice(name)
            raise LogNotFound(
                f"log {name!r} is gone: {where} was removed", name=name, available=list(self.available()[:20])
            )
        task = self._open.get(name)
        if task is not None and self._stamps.get(name) != stamp:
            logger.info("log %r changed on disk; reading it again", name)
            self._stop_preload(name)
            self._notice(name)
            task = None
        if task is None or (task.done() and (task.cancelled() or task.exception() is not None)):
            task = asyncio.ensure_future(self.load(found))
            self._open[name] = task
            self._stamps[name] = stamp
        try:
            log = await asyncio.shield(task)
        except XVIZError as exc:
            if self._failed.get(name) != stamp:  # once per version of the log
                self._failed[name] = stamp
                logger.warning("log %r (%s) cannot be opened: %s", name, getattr(found, "path", found.name), exc)
            raise
        if (
            preload
            and name not in self._preloads
            and isinstance(found, Found)
            and found.kind == LOG
            and self._preload_bytes > 0
        ):
            self._preloads[name] = asyncio.ensure_future(self._preload(log, found.path))
        return log

    def stamp(self, name: str) -> tuple[int, ...] | None:
        """What :func:`~xviz_server.layout.stamp_of` said of log ``name`` when :meth:`open` last read it: empty for a
        log in a store or a generated one, ``None`` for one not open."""
        return self._stamps.get(name)

    def _notice(self, name: str, found: Found | StoredLog | StoredDataset | None = None) -> None:
        if self.known is not None:
            self.known.notice(name, found)

    async def load(self, found: Found | StoredLog | StoredDataset) -> Log:
        """A new :class:`Log` of what ``found`` names, shared with no one; raises :class:`~xviz_server.exceptions.XVIZError`."""
        started = time.perf_counter()
        source: LogSource
        if isinstance(found, StoredLog):
            source = await self._logs.open_folder(found.name, found.folder)
        elif isinstance(found, StoredDataset) or found.kind != LOG:
            source = await self._converted.open(found)
        else:
            source = await self._logs.open(found)
        log = await Log.open(source, self._cache, self._workers, self._validate)
        logger.info(
            "opened log %r: %d frames, %s, in %.3f s",
            found.name,
            len(log.index),
            log.format.value,
            time.perf_counter() - started,
        )
        return log

    async def _preload(self, log: Log, directory: Path) -> None:
        async with self._preloading:
            try:
                size = await self._workers.io(frame_bytes, directory)
            except OSError:
                return  # whoever opens it next is told why
            if size > self._preload_bytes:
                return
            started = time.perf_counter()
            try:
                loaded = await log.preload()
            except Exception:
                logger.exception("log %r: reading it into the frame cache failed", log.name)
                return
        logger.info(
            "read log %r into the frame cache: %d of %d frames, %.1f MB, in %.1f s",
            log.name,
            loaded,
            len(log.index),
            size / 2**20,
            time.perf_counter() - started,
        )

    def _stop_preload(self, name: str) -> None:
        task = self._preloads.pop(name, None)
        if task is not None:
            task.cancel()

    def close(self) -> None:
        """Stop reading logs into the frame cache."""
        for name in list(self._preloads):
            self._stop_preload(name)
