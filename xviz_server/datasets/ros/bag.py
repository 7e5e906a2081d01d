"""A bag opened through its own index: its topics, the time of every message, one message at a time.

The three containers are read with ``rosbags``: a ROS 1 bag (``.bag``), a
ROS 2 bag (a folder with ``metadata.yaml`` and ``.db3`` or ``.mcap``
files) and a bare ``.mcap`` file. The record time of each message comes
from the container's index, with no message read:

* ROS 1: the index records after each chunk (``rosbags`` reads them at open);
* ROS 2 sqlite3: the ``timestamp`` column of the ``messages`` table;
* MCAP: the message index records after each chunk, located by the
  summary's chunk indexes (one read per chunk). An MCAP file without a
  summary (a recording cut short) is read through once at open instead.

ROS 1 and MCAP messages are then read at the offset their index gives,
through a small cache of decompressed chunks; sqlite3 messages through
rosbags' query by time.

Every chunk is unpacked with a bound (see :mod:`xviz_server.unpack`):
one that declares more than :data:`~xviz_server.unpack.MAX_CHUNK_BYTES`
uncompressed, or unpacks to more than it declares, is an
:class:`~xviz_server.exceptions.OversizeError` naming the file and the
chunk; rosbags' own MCAP reader (an MCAP file without a summary, a ROS 2
bag folder of MCAP files) unpacks through the same bound. At most
:data:`CHUNK_CACHE_BYTES` of unpacked chunks are kept per bag.

A ROS 1 bag whose recording was cut short has no readable index: it is
indexed in memory at open, by one read of the whole file (see
:mod:`.reindex`), and a warning says so.

A ROS 1 bag or an MCAP file may be an object in a store
(:class:`~xviz_server.store.path.StorePath`): it is read with ranged GETs, a
chunk with one GET, and the message indexes of a topic's MCAP chunks all at
once. A ROS 2 bag folder is read from disk only (SQLite reads a local
file).
"""

from __future__ import annotations

import abc
import logging
import struct
import threading
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...exceptions import DatasetError, StoreError
from ...records import OriginalTopic
from ...store.path import RangedFile, StorePath, data_path
from ...unpack import (
    MAX_CHUNK_BYTES,
    MAX_FILE_RATIO,
    MAX_FRAME_BYTES,
    BoundedReader,
    check_declared,
    unpack,
    unpack_unsized,
    zstd_module,
)

if TYPE_CHECKING:
    from rosbags.rosbag1 import Reader

__all__ = [
    "Bag",
    "Recording",
    "Topic",
    "open_bag",
    "reason",
    "is_rosbag",
    "ROS1_MAGIC",
    "MCAP_MAGIC",
    "ROS2_KEY",
    "CHUNK_CACHE_BYTES",
]

logger = logging.getLogger(__name__)

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS2_KEY = b"rosbag2_bagfile_information"  # the top key of a ROS 2 bag's metadata.yaml
SQLITE_MAGIC = b"SQLite format 3\x00"  # a ROS 2 storage file without its metadata.yaml
_MESSAGE = 0x05  # MCAP opcodes
_MESSAGE_INDEX = 0x07
_ROS1_MESSAGE = 0x02  # ROS 1 record ops
_ROS1_CONNECTION = 0x07
#: Message types of raw sensor packets, which only their driver turns into points.
DRIVER_PACKETS = frozenset(
    {
        "velodyne_msgs/msg/VelodyneScan",
        "velodyne_msgs/msg/VelodynePacket",
        "ouster_msgs/msg/PacketMsg",
        "ouster_ros/msg/PacketMsg",
        "hesai_msgs/msg/PandarScan",
        "pandar_msgs/msg/PandarScan",
        "livox_ros_driver/msg/CustomMsg",
    }
)
#: The most bytes of unpacked chunks a bag keeps: a frame reads a few neighbouring chunks (the last one read is
#: always kept, even if larger).
CHUNK_CACHE_BYTES = 32 << 20


def is_rosbag(path: Path | StorePath) -> bool:
    """Whether ``path`` is a ROS 1 bag, an MCAP file or a ROS 2 sqlite3 file (``.db3``, by their first bytes), or a
    ROS 2 bag folder (by the top key of its ``metadata.yaml``).

    Raises :class:`~xviz_server.exceptions.StoreError` when an object in a
    store cannot be read.
    """
    magic = {".bag": ROS1_MAGIC, ".mcap": MCAP_MAGIC, ".db3": SQLITE_MAGIC}.get(path.suffix)
    target: Path | StorePath
    if magic is not None:
        start, target = len(magic), path
    elif isinstance(path, StorePath):  # a ROS 2 bag folder is read from disk only
        return False
    else:
        start, target = 256, path / "metadata.yaml"
    try:
        with target.open("rb") as file:
            head = file.read(start)
    except StoreError:
        raise
    except OSError:  # no such file, a folder named like a bag, unreadable
        return False
    return head == magic if magic is not None else ROS2_KEY in head


@dataclass(frozen=True)
class Topic:
    """A topic of the bag: its message type (``sensor_msgs/msg/PointCloud2``) and record times."""

    name: str
    msgtype: str
    #: Record time of every message, int64 nanoseconds, sorted.
    times: np.ndarray
    connections: tuple[Any, ...]
    #: Where each message is, int64 (N, 3): storage, chunk, offset in the decompressed chunk; ``None`` when
    #: messages are read through rosbags (sqlite3, MCAP without a summary, ROS 2 compressed per message).
    places: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.times)

    def at_or_before(self, t: int) -> int:
        """The index of the last message recorded at or before ``t`` (ns); -1 if none."""
        return int(np.searchsorted(self.times, t, side="right")) - 1


class Recording(abc.ABC):
    """What :class:`Bag` and :class:`~.mcapbag.McapBag` share: topics indexed by record time, read one message at a
    time. A subclass locates a message's bytes (:meth:`_payload`, for a topic with ``places``) and decodes them;
    every failure of a reader on a damaged file is a :class:`~xviz_server.exceptions.DatasetError` naming the file
    and the topic. Safe to use from several threads."""

    path: Path | StorePath
    #: ``ROS 1``, ``ROS 2 sqlite3``, ``ROS 2 mcap`` or ``MCAP``.
    container: str
    topics: dict[str, Topic]
    #: Topics that cannot be decoded: the reason, by topic.
    problems: dict[str, str]
    _lock: threading.Lock

    @abc.abstractmethod
    def _payload(self, place: np.ndarray, topic: str) -> memoryview:
        """The serialized bytes of the message at ``place`` (a row of :attr:`Topic.places`)."""

    @abc.abstractmethod
    def _decode(self, topic: str, msgtype: str, time: int, data: bytes | memoryview) -> Any:
        """One message of ``topic`` decoded, or a :class:`~xviz_server.exceptions.DatasetError` saying why not."""

    @abc.abstractmethod
    def declared(self, topic: str, first: int, last: int) -> dict[tuple[Any, ...], int]:
        """What reading messages ``[first, last)`` of ``topic`` unpacks, read from the index alone: each part that
        holds them with the bytes it declares."""

    @abc.abstractmethod
    def original(self, topic: str) -> OriginalTopic | None:
        """How the file holds ``topic``'s messages (encoding, schema); ``None`` when it cannot be said."""

    @abc.abstractmethod
    def close(self) -> None:
        """Let go of what is kept in memory."""

    def _unplaced(self, topic: str, start: int | None, stop: int | None) -> list[tuple[int, bytes]]:
        """The messages of a topic without ``places`` recorded in ``[start, stop)`` ns, in any order."""
        raise DatasetError(f"{self.path}: topic {topic}: its messages are not indexed", path=self.path)

    def message(self, topic: str, index: int) -> tuple[int, Any]:
        """Message ``index`` of ``topic`` (in record-time order), with its record time in ns."""
        info = self.topics[topic]
        t = int(info.times[index])
        if info.places is not None:
            with self._lock:
                data = self._guard(topic, lambda: self._payload(info.places[index], topic))
            return t, self._decode(topic, info.msgtype, t, data)
        skip = index - int(np.searchsorted(info.times, t, side="left"))
        for time, message in self.messages(topic, t, t + 1):
            if skip == 0:
                return time, message
            skip -= 1
        raise DatasetError(
            f"{self.path}: topic {topic}: message {index} is in the index but not in the bag", path=self.path
        )

    def messages(self, topic: str, start: int | None, stop: int | None) -> Iterator[tuple[int, Any]]:
        """The messages of ``topic`` recorded in ``[start, stop)`` ns (``None``: unbounded), decoded, in time order."""
        for time, msgtype, data in self.serialized(topic, start, stop):
            yield time, self._decode(topic, msgtype, time, data)

    def serialized(
        self, topic: str, start: int | None, stop: int | None
    ) -> Iterator[tuple[int, str, bytes | memoryview]]:
        """The messages of ``topic`` recorded in ``[start, stop)`` ns (``None``: unbounded) as the file holds them:
        (record time, message type, serialized bytes), in time order."""
        info = self.topics[topic]
        if info.places is not None:
            first = 0 if start is None else int(np.searchsorted(info.times, start, side="left"))
            last = len(info) if stop is None else int(np.searchsorted(info.times, stop, side="left"))
            for index in range(first, last):
                with self._lock:
                    data = self._guard(topic, partial(self._payload, info.places[index], topic))
                yield int(info.times[index]), info.msgtype, data
            return
        with self._lock:
            raw = self._guard(topic, lambda: self._unplaced(topic, start, stop))
        raw.sort(key=lambda message: message[0])
        for time, data in raw:
            yield time, info.msgtype, data

    def _guard(self, topic: str, read: Any) -> Any:
        try:
            return read()
        except (DatasetError, StoreError):  # a store that fails is not a damaged bag: the frame fails, not the topic
            raise
        except Exception as exc:  # noqa: BLE001 - the reader fails in many ways on a damaged file
            raise DatasetError(f"{self.path}: topic {topic}: cannot read: {reason(exc)}", path=self.path) from None


def _import_rosbags() -> Any:
    try:
        import rosbags.highlevel
    except ImportError:
        raise DatasetError("reading ROS bags needs the rosbags package: pip install 'xviz-server[ros]'") from None
    _bound_rosbags()
    return rosbags


class Bag(Recording):
    """A bag opened through rosbags (see :class:`Recording`)."""

    def __init__(self, path: Path | StorePath) -> None:
        self.path = data_path(path)
        rosbags = _import_rosbags()
        from rosbags.typesys import Stores, get_typestore

        self._lock = threading.Lock()
        from .reindex import MemoryIndexedReader

        try:
            self._standard = get_typestore(Stores.ROS2_HUMBLE)
            reader = rosbags.highlevel.AnyReader([self.path], default_typestore=self._standard)
            if not reader.is2:
                reader.readers = [MemoryIndexedReader(self.path)]
            for ros2 in reader.readers if reader.is2 else ():  # storage_identifier "": the storage of its files
                ros2.storage.STORAGE_PLUGINS = {**getattr(ros2.storage, "STORAGE_PLUGINS", {}), "": _storage_by_suffix}
            reader.open()
        except DatasetError as exc:  # a chunk refused; one that rosbags' reader unpacks does not say whose
            if not str(exc).startswith(str(self.path)):
                exc.args, exc.path = (f"{self.path}: {exc}",), self.path
            raise
        except StoreError:
            raise
        except Exception as exc:  # noqa: BLE001 - the reader fails in many ways on a damaged file
            raise DatasetError(f"{self.path}: cannot open the bag: {reason(exc)}", path=self.path) from None
        self._reader = reader
        self.problems = {}  # (rosbags refuses a bag whose types do not parse)
        for ros1 in reader.readers:
            if getattr(ros1, "reindexed", False):
                cut = f"; the last {ros1.lost} bytes, a record cut short, are left out" if ros1.lost else ""
                logger.warning(
                    "%s has no readable index (its recording was cut short): indexed in memory by reading "
                    "the whole bag once, as rosbag reindex would (the file is not changed)%s",
                    self.path,
                    cut,
                )
        by_topic: dict[str, list[Any]] = {}
        for connection in reader.connections:
            by_topic.setdefault(connection.topic, []).append(connection)
        self._storages: dict[int, Any] = {}  # by number: the rosbags storage readers messages are read from directly
        self._chunks: dict[tuple[int, int], bytes] = {}
        self.topics = {}
        for name, connections in sorted(by_topic.items()):
            try:
                indexes = [self._index(c) for c in connections]
            except DatasetError:
                raise
            except Exception as exc:  # noqa: BLE001
                raise DatasetError(
                    f"{self.path}: topic {name}: cannot read its index: {reason(exc)}", path=self.path
                ) from None
            times = np.concatenate([i[0] for i in indexes])
            order = np.argsort(times, kind="stable")
            places = [i[1] for i in indexes if i[1] is not None]
            located = np.concatenate(places)[order] if len(places) == len(indexes) else None
            self.topics[name] = Topic(name, connections[0].msgtype, times[order], tuple(connections), located)
            if connections[0].msgtype in DRIVER_PACKETS:
                self.problems[name] = (
                    f"{connections[0].msgtype} holds the raw packets of a sensor's driver, not points: "
                    "record the driver's point cloud topic, or replay the bag through the driver"
                )
            elif connections[0].msgtype not in reader.typestore.fielddefs:
                self.problems[name] = (
                    f"its type {connections[0].msgtype} has no definition in the bag or rosbags' type store"
                )
        self.container = self._container()

    def _container(self) -> str:
        if self.path.suffix == ".bag":
            return "ROS 1"
        if self.path.suffix == ".mcap":
            return "MCAP"
        storages = {type(s).__name__ for r in self._reader.readers for s in getattr(r.storage, "storages", [r.storage])}
        return "ROS 2 mcap" if storages == {"McapReader"} else "ROS 2 sqlite3"

    def close(self) -> None:
        with self._lock:
            self._reader.close()

    # -- the index ----------------------------------------------------------

    def _index(self, connection: Any) -> tuple[np.ndarray, np.ndarray | None]:
        """Record times of a connection's messages and, for MCAP, where each is: (file, chunk, offset)."""
        owner = connection.owner
        kind = type(owner).__name__
        if isinstance(owner, _ros1_reader()):  # its index, read at open or made in memory
            entries = np.array(owner.indexes[connection.id], dtype=np.int64).reshape(-1, 3)  # time, chunk_pos, offset
            place = entries.copy()
            place[:, 0] = self._number(owner)
            return entries[:, 0].copy(), place
        if kind == "Sqlite3Reader":
            rows = owner.dbconn.execute("SELECT timestamp FROM messages WHERE topic_id = ?", (connection.id,))
            return np.fromiter((row[0] for row in rows), np.int64), None
        if kind == "McapReader":
            return self._mcap_index(owner, connection)
        if kind == "DirectoryReader":  # a ROS 2 bag folder: the same topic in each of its storage files
            parts = [
                self._index(c)
                for storage in owner.storages
                for c in storage.connections
                if c.topic == connection.topic and c.msgtype == connection.msgtype
            ]
            times = np.concatenate([p[0] for p in parts]) if parts else np.empty(0, np.int64)
            places = [p[1] for p in parts if p[1] is not None]
            direct = parts and len(places) == len(parts) and owner.metadata.compression_mode != "message"
            return times, (np.concatenate(places) if direct else None)  # compressed messages: through rosbags
        raise DatasetError(f"{self.path}: unknown storage {kind}", path=self.path)

    def _mcap_index(self, owner: Any, connection: Any) -> tuple[np.ndarray, np.ndarray | None]:
        if not owner.chunks:  # no summary: read through once
            return np.fromiter((t for _, t, _ in owner.messages([connection])), np.int64), None
        number = self._number(owner)
        times: list[np.ndarray] = []
        places: list[np.ndarray] = []
        with owner.path.open("rb") as file:
            if isinstance(file, RangedFile):  # an object in a store: every index of the topic in one call
                file.prefetch(
                    [
                        (o, o + c.message_index_length)
                        for c in owner.chunks
                        if (o := c.message_index_offsets.get(connection.id)) is not None
                    ]
                )
            for chunk_number, chunk in enumerate(owner.chunks):
                offset = chunk.message_index_offsets.get(connection.id)
                if offset is None:
                    continue
                file.seek(offset)
                head = file.read(15)
                if len(head) < 15 or head[0] != _MESSAGE_INDEX:
                    raise DatasetError(f"{owner.path}: no message index at byte {offset}", path=owner.path)
                _, _, channel, size = struct.unpack("<BQHI", head)
                body = file.read(size)
                if channel != connection.id or len(body) != size or size % 16:
                    raise DatasetError(f"{owner.path}: damaged message index at byte {offset}", path=owner.path)
                entries = np.frombuffer(body, "<u8").reshape(-1, 2).astype(np.int64)
                times.append(entries[:, 0])
                place = np.empty((len(entries), 3), np.int64)
                place[:, 0], place[:, 1], place[:, 2] = number, chunk_number, entries[:, 1]
                places.append(place)
        if not times:
            return np.empty(0, np.int64), np.empty((0, 3), np.int64)
        return np.concatenate(times), np.concatenate(places)

    def _number(self, owner: Any) -> int:
        number = next((n for n, known in self._storages.items() if known is owner), len(self._storages))
        self._storages[number] = owner
        return number

    # -- messages -----------------------------------------------------------

    def _payload(self, place: np.ndarray, topic: str) -> memoryview:
        """The serialized message at ``place``, through a cache of recently decompressed chunks."""
        storage, chunk, offset = (int(v) for v in place)
        owner = self._storages[storage]
        data = self._chunks.pop((storage, chunk), None)
        if data is None:
            data = _read_chunk(owner, chunk)
            kept = sum(map(len, self._chunks.values()))
            while self._chunks and kept + len(data) > CHUNK_CACHE_BYTES:
                kept -= len(self._chunks.pop(next(iter(self._chunks))))
        self._chunks[(storage, chunk)] = data
        found = (_ros1_record if isinstance(owner, _ros1_reader()) else _mcap_record)(data, offset)
        if found is None:
            raise DatasetError(
                f"{self.path}: topic {topic}: no message record at offset {offset} of chunk {chunk}", path=self.path
            )
        return found

    def declared(self, topic: str, first: int, last: int) -> dict[tuple[Any, ...], int]:
        """What reading messages ``[first, last)`` of ``topic`` unpacks, read from the index alone: each part that
        holds them (a chunk, a ROS 2 sqlite3 row) with the bytes it declares. A part read through rosbags that
        declares nothing (an MCAP file without a summary, a ROS 2 message compressed on its own) counts its
        stored bytes where they are known, else nothing."""
        info = self.topics[topic]
        if last <= first:
            return {}
        if info.places is not None:
            from .reindex import MemoryIndexedReader

            parts: dict[tuple[Any, ...], int] = {}
            for storage, chunk in {(int(s), int(c)) for s, c in info.places[first:last, :2].tolist()}:
                owner = self._storages[storage]
                size = (
                    owner.declared.get(chunk, 0)
                    if isinstance(owner, MemoryIndexedReader)
                    else owner.chunks[chunk].uncompressed_size
                )
                parts[(storage, chunk)] = int(size)
            return parts
        owners = [c.owner for c in info.connections]
        if len(owners) != 1 or type(owners[0]).__name__ != "Sqlite3Reader":
            return {}
        start, stop = int(info.times[first]), int(info.times[last - 1]) + 1
        with self._lock:
            rows = (
                owners[0]
                .dbconn.execute(
                    "SELECT id, length(data) FROM messages WHERE topic_id = ? AND timestamp >= ? AND timestamp < ?",
                    (info.connections[0].id, start, stop),
                )
                .fetchall()
            )
        return {(topic, row): int(size) for row, size in rows}

    def _unplaced(self, topic: str, start: int | None, stop: int | None) -> list[tuple[int, bytes]]:
        return [m for c in self.topics[topic].connections for m in _storage_messages(c, start, stop)]

    def original(self, topic: str) -> OriginalTopic | None:
        """How the file holds ``topic``'s messages: their encoding and schema, the definition as recorded (or,
        for a ROS 2 bag that recorded none, made from the type store); ``None`` when its connections disagree on
        the type or its definition cannot be had."""
        info = self.topics[topic]
        first = info.connections[0]
        if any(c.msgtype != info.msgtype for c in info.connections):
            return None
        definition, ros1 = first.msgdef.data, isinstance(first.owner, _ros1_reader())
        idl = not ros1 and first.msgdef.format.name == "IDL"
        if not definition:
            try:
                definition, _ = self._reader.typestore.generate_msgdef(info.msgtype, ros_version=1 if ros1 else 2)
            except Exception:  # noqa: BLE001 - a type the store does not know
                return None
        if ros1:
            return OriginalTopic(topic, "ros1", info.msgtype.replace("/msg/", "/", 1), "ros1msg", definition)
        encoding = getattr(first.ext, "serialization_format", "cdr")
        return OriginalTopic(topic, encoding, info.msgtype, "ros2idl" if idl else "ros2msg", definition)

    def _decode(self, topic: str, msgtype: str, time: int, data: bytes | memoryview) -> Any:
        try:
            return self._reader.deserialize(data, msgtype)
        except Exception as exc:  # noqa: BLE001 - a message that does not match its type
            if self._reader.is2 and msgtype in self._standard.fielddefs:  # a definition the bag holds wrongly
                try:  # (rosbags makes "uint8 level" of an old sqlite3 bag's rcl_interfaces/Log): the standard one
                    return self._standard.deserialize_cdr(bytes(data), msgtype)
                except Exception:  # noqa: BLE001, S110 - the first reason is the one to give
                    pass
            raise DatasetError(
                f"{self.path}: topic {topic}: a {msgtype} message at {time} ns does not decode: {reason(exc)}",
                path=self.path,
            ) from None


def _storage_messages(connection: Any, start: int | None, stop: int | None) -> Iterator[tuple[int, bytes]]:
    """The messages of a connection, read from the storage files of a ROS 2 bag folder by topic and type (rosbags'
    folder reader also matches their QoS profiles, which older bags write differently in metadata.yaml and the
    database, and then finds no message)."""
    owner = connection.owner
    if type(owner).__name__ != "DirectoryReader":
        yield from ((time, data) for _, time, data in owner.messages([connection], start, stop))
        return
    compressed = owner.metadata.compression_mode == "message"
    for storage in owner.storages:
        mine = [c for c in storage.connections if c.topic == connection.topic and c.msgtype == connection.msgtype]
        for _, time, data in storage.messages(mine, start, stop) if mine else ():
            yield time, _BoundedZstd.decompress(data) if compressed else data


def open_bag(path: Path | StorePath) -> Recording:
    """The bag at ``path``: an MCAP file, or a ROS 2 bag folder of MCAP files not compressed by rosbag2, with the
    format's own reader (:class:`~.mcapbag.McapBag`); the rest with rosbags (:class:`Bag`)."""
    path = data_path(path)
    from .mcapbag import McapBag

    if path.suffix == ".mcap":
        return McapBag(path)
    files = _mcap_files(path) if isinstance(path, Path) and path.is_dir() else None
    return Bag(path) if files is None else McapBag(path, files)


def _mcap_files(folder: Path) -> list[Path] | None:
    """The storage files of a ROS 2 bag folder if they are MCAP files not compressed by rosbag2, else ``None``."""
    from ruamel.yaml import YAML, YAMLError  # rosbags reads metadata.yaml with it

    try:
        metadata = YAML(typ="safe").load((folder / "metadata.yaml").read_text("utf-8"))[ROS2_KEY.decode()]
        files = [folder / Path(name).name for name in metadata["relative_file_paths"]]
        compressed = str(metadata.get("compression_mode") or "").lower() not in ("", "none")
    except (OSError, UnicodeDecodeError, YAMLError, KeyError, TypeError, AttributeError):
        return None  # rosbags names what is wrong
    if compressed or not files or any(f.suffix != ".mcap" or not f.is_file() for f in files):
        return None
    if metadata.get("storage_identifier") not in ("mcap", "", None):
        return None
    return files


def _storage_by_suffix(path: Path) -> Any:
    """rosbags' storage reader of a file of a ROS 2 bag whose ``storage_identifier`` is empty, by its suffix."""
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    return (McapReader if path.suffix == ".mcap" else Sqlite3Reader)(path)


def _read_chunk(owner: Any, key: int) -> bytes:
    """The decompressed records of a chunk: MCAP chunk number ``key``, or the ROS 1 chunk at byte ``key``."""
    with owner.path.open("rb") as file:
        if isinstance(owner, _ros1_reader()):
            chunk = owner.chunks[key]
            file.seek(chunk.datapos)
            return bytes(chunk.decompressor(file.read(chunk.datasize)))  # bounded by MemoryIndexedReader
        info = owner.chunks[key]
        where = f"{owner.path}: chunk at byte {info.chunk_start_offset}"
        check_declared(info.uncompressed_size, where)
        # The chunk record in one read: opcode, length, two times, uncompressed size, CRC, compression, records.
        start = 9 + 40 + len(info.compression)
        end = info.chunk_start_offset + start + info.compressed_size
        if end > file.seek(0, 2):
            raise DatasetError(f"{where} is cut short: it needs the file's bytes up to {end}", path=owner.path)
        file.seek(info.chunk_start_offset)
        record = file.read(start + info.compressed_size)
        if len(record) < start + info.compressed_size:
            raise DatasetError(f"{where} is cut short", path=owner.path)
        (crc,) = struct.unpack_from("<I", record, 9 + 24)
        data = unpack(memoryview(record)[start:], info.compression, info.uncompressed_size, where)
        if crc and zlib.crc32(data) != crc:
            raise DatasetError(f"{where}: CRC mismatch: the chunk is damaged", path=owner.path)
        return data


def _bound_rosbags() -> None:
    """Make rosbags unpack what it unpacks itself within :mod:`xviz_server.unpack`'s bounds.

    Its own MCAP reader reads chunks where messages are not read by their
    index here (an MCAP file without a summary, at open; a ROS 2 bag
    folder), and looks its decompressors up in a table, each called with the
    chunk's declared size: they become :func:`~xviz_server.unpack.unpack`.
    Its ROS 2 bag reader unpacks a bag compressed per message, or per
    storage file (into a temporary folder, at open), with zstd, declaring no
    size: it is given :class:`_BoundedZstd` in place of the zstd module.
    """
    from rosbags.rosbag2 import reader, storage_mcap

    for name in ("lz4", "zstd"):
        storage_mcap.DECOMPRESSORS[name] = partial(_unpack_mcap, name)
    reader.zstd = _BoundedZstd  # type: ignore[assignment]


class _BoundedZstd:
    """What rosbags' ROS 2 bag reader takes from the zstd module, bounded."""

    @staticmethod
    def decompress(data: bytes) -> bytes:
        """A message compressed on its own: at most :data:`~xviz_server.unpack.MAX_FRAME_BYTES` unpacked (more
        than one frame may take; its stored size declares nothing)."""
        return unpack_unsized(data, "zstd", "a ROS 2 bag's message compressed with zstd", MAX_FRAME_BYTES)

    @staticmethod
    def open(file: Any, mode: str = "rb") -> BoundedReader:
        """A storage file compressed whole: at most :data:`~xviz_server.unpack.MAX_FILE_RATIO` times its size."""
        size = Path(getattr(file, "name", "")).stat().st_size if getattr(file, "name", None) else 0
        where = f"{getattr(file, 'name', 'a ROS 2 bag storage file')} (compressed with zstd)"
        return BoundedReader(zstd_module().open(file, mode), max(MAX_CHUNK_BYTES, MAX_FILE_RATIO * size), where)


def _unpack_mcap(compression: str, data: bytes, declared: int) -> bytes:
    return unpack(data, compression, declared, "an MCAP chunk read by rosbags")


def _ros1_reader() -> type[Reader]:
    from rosbags.rosbag1 import Reader

    return Reader


def _mcap_record(data: bytes, offset: int) -> memoryview | None:
    """The payload of the MCAP message record at ``offset``: after opcode, length, channel, sequence and two times."""
    if offset + 31 > len(data) or data[offset] != _MESSAGE:
        return None
    (length,) = struct.unpack_from("<Q", data, offset + 1)
    return memoryview(data)[offset + 31 : offset + 9 + length]


def _ros1_record(data: bytes, offset: int) -> memoryview | None:
    """The data of the ROS 1 message record at ``offset`` (connection records before it are skipped)."""
    while offset + 4 <= len(data):
        (header_length,) = struct.unpack_from("<I", data, offset)
        header, end = data[offset + 4 : offset + 4 + header_length], offset + 4 + header_length
        if end + 4 > len(data):
            return None
        (data_length,) = struct.unpack_from("<I", data, end)
        op = _ros1_op(header)
        if op == _ROS1_MESSAGE:
            return memoryview(data)[end + 4 : end + 4 + data_length]
        if op != _ROS1_CONNECTION:
            return None
        offset = end + 4 + data_length
    return None


def _ros1_op(header: bytes) -> int | None:
    """The ``op`` field of a ROS 1 record header (fields ``name=value``, each after its uint32 length)."""
    position = 0
    while position + 4 <= len(header):
        (size,) = struct.unpack_from("<I", header, position)
        name, _, value = header[position + 4 : position + 4 + size].partition(b"=")
        if name == b"op":
            return value[0] if value else None
        position += 4 + size
    return None


def reason(exc: BaseException) -> str:
    return " ".join(str(arg) for arg in exc.args) or type(exc).__name__
