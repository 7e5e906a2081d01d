"""MCAP files of any profile, read with the format's own reader and decoders.

An MCAP file holds channels of any message encoding: ``ros1`` (profile
``ros1``, what ``mcap convert`` makes of a ROS 1 bag), ``cdr`` (profile
``ros2``), ``protobuf`` and ``json`` (the Foxglove SDK and Lichtblick, no
profile). The schemas, channels and summary are read with ``mcap``, the
messages decoded with its decoders (``mcap-ros1-support``,
``mcap-ros2-support``, ``mcap-protobuf-support``; JSON with the standard
library), and messages of Foxglove's well-known schemas become their ROS
counterparts (see :mod:`.wellknown`).

The record time of every message comes from the file's index where it has
one: the message index records after each chunk, located by the summary's
chunk indexes. A chunk without message index records is unpacked once at
open and its records walked; a file without chunk indexes (no summary, a
recording cut short, an unchunked file) is walked once from its start, and
a record cut off by the end of the file ends the walk with one warning.
Messages are sorted by record time whatever their order in the file.
Repeated schema, channel and statistics records are read as one.

A ROS 2 service event channel (``pkg/srv/Name_Event``, recorded with service
introspection on) has the service's ``.srv`` text as its schema, which is no
message definition: it is decoded with the event's definition built from it
(:func:`service_event_schema`). A channel that cannot be decoded (an
encoding without a decoder, a schema that does not parse, no schema) is
named in :attr:`McapBag.problems` with the reason; its messages are still
served as the file holds them.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import logging
import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...exceptions import DatasetError, StoreError
from ...records import OriginalTopic
from ...store.path import StorePath
from ...unpack import MAX_CHUNK_BYTES, check_declared, unpack
from .bag import CHUNK_CACHE_BYTES, MCAP_MAGIC, Recording, Topic, reason
from .wellknown import ROS_OF, adapt, attributes

__all__ = ["McapBag", "ros_type", "service_event_schema"]

logger = logging.getLogger(__name__)

_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _FOOTER, _DATA_END = 0x03, 0x04, 0x05, 0x06, 0x07, 0x02, 0x0F
_TEXT_SCHEMAS = ("ros1msg", "ros2msg", "ros2idl", "jsonschema", "omgidl")
_SEPARATOR = "=" * 80
#: service_msgs/msg/ServiceEventInfo, the header of every ROS 2 service event.
_SERVICE_EVENT_INFO = """uint8 REQUEST_SENT = 0
uint8 REQUEST_RECEIVED = 1
uint8 RESPONSE_SENT = 2
uint8 RESPONSE_RECEIVED = 3
uint8 event_type
builtin_interfaces/Time stamp
char[16] client_gid
int64 sequence_number"""


@dataclass(frozen=True)
class _Chunk:
    """Where a chunk record is and how to unpack it."""

    start: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    crc: int

    @property
    def records(self) -> int:
        """The file offset of the chunk's records: after opcode, length, two times, size, CRC and compression."""
        return self.start + 9 + 28 + 4 + len(self.compression) + 8


@dataclass
class _Channel:
    id: int
    topic: str
    message_encoding: str
    schema: Any  # mcap.records.Schema or None
    storage: int


def _rows(entries: list[tuple[int, int, int, int, int]]) -> np.ndarray:
    """Index rows (storage, channel, time, chunk, offset) as an int64 (N, 5) array."""
    return np.array(entries, dtype=np.int64).reshape(-1, 5)


def ros_type(name: str) -> str:
    """A ROS type name as rosbags writes it: ``sensor_msgs/PointCloud2`` -> ``sensor_msgs/msg/PointCloud2``."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


def service_event_schema(schema: Any) -> Any | None:
    """The decodable schema of a ROS 2 service event channel whose schema is its service's ``.srv`` text, else None.

    A ``pkg/srv/Name_Event`` message is the event's ``service_msgs/ServiceEventInfo``,
    then at most one request and at most one response. The types are named
    without underscores (``NameEvent``, ``NameRequest``), which the ROS 2
    parser requires; the bytes do not depend on the names.
    """
    from mcap.records import Schema

    parts = schema.name.split("/")
    text = bytes(schema.data).decode("utf-8", "replace")
    if schema.encoding != "ros2msg" or len(parts) != 3 or parts[1] != "srv" or not parts[2].endswith("_Event"):
        return None
    request, separator, response = text.partition("\n---\n")
    if not separator and text.startswith("---\n"):
        request, separator, response = "", "---", text[4:]
    if not separator:
        return None
    package, service = parts[0], parts[2][: -len("_Event")]
    definition = "\n".join(
        [
            "service_msgs/ServiceEventInfo info",
            f"{service}Request[<=1] request",
            f"{service}Response[<=1] response",
            _SEPARATOR,
            "MSG: service_msgs/ServiceEventInfo",
            _SERVICE_EVENT_INFO,
            _SEPARATOR,
            f"MSG: {package}/{service}Request",
            request,
            _SEPARATOR,
            f"MSG: {package}/{service}Response",
            response,
        ]
    )
    return Schema(id=schema.id, name=f"{package}/{service}Event", encoding=schema.encoding, data=definition.encode())


def _decoder_factories() -> list[Any]:
    from mcap_protobuf.decoder import DecoderFactory as Protobuf
    from mcap_ros1.decoder import DecoderFactory as Ros1
    from mcap_ros2.decoder import DecoderFactory as Ros2

    return [Ros1(), Ros2(), Protobuf()]


class McapBag(Recording):
    """MCAP files read as one bag (a bare ``.mcap`` file, or the files of a ROS 2 bag folder) with the format's own
    reader (see :class:`~.bag.Recording`)."""

    def __init__(self, path: Path | StorePath, files: Sequence[Path | StorePath] | None = None) -> None:
        try:
            import mcap.reader  # noqa: F401
        except ImportError:
            raise DatasetError("reading MCAP files needs the ros extra: pip install 'xviz-server[ros]'") from None
        self.path = path
        self.container = "MCAP" if files is None else "ROS 2 mcap"
        self._files = list(files) if files is not None else [path]
        self._lock = threading.Lock()
        self._chunks: list[list[_Chunk]] = []
        self._cache: dict[tuple[int, int], bytes] = {}
        self.problems = {}
        channels: dict[tuple[int, int], _Channel] = {}
        entries: list[np.ndarray] = []  # rows of storage, channel, time, chunk (-1: top level), offset
        for storage, file_path in enumerate(self._files):
            try:
                entries.append(self._open(storage, file_path, channels))
            except (DatasetError, StoreError):
                raise
            except Exception as exc:  # noqa: BLE001 - the reader fails in many ways on a damaged file
                raise DatasetError(f"{self.path}: cannot open the MCAP file: {reason(exc)}", path=self.path) from None
        self._decoders: dict[str, Callable[[bytes], Any]] = {}
        factories = _decoder_factories()
        table = np.concatenate(entries)
        by_topic: dict[str, list[_Channel]] = {}
        for channel in channels.values():
            by_topic.setdefault(self._topic_name(channel, by_topic), []).append(channel)
        self.topics = {}
        for name, members in sorted(by_topic.items()):
            mine = np.zeros(len(table), dtype=bool)
            for channel in members:
                mine |= (table[:, 0] == channel.storage) & (table[:, 1] == channel.id)
            rows = table[mine]
            order = np.argsort(rows[:, 2], kind="stable")
            rows = rows[order]
            first = members[0]
            msgtype = self._prepare(name, first, factories)
            places = np.stack([rows[:, 0], rows[:, 3], rows[:, 4]], axis=1) if len(rows) else np.empty((0, 3), np.int64)
            self.topics[name] = Topic(name, msgtype, rows[:, 2].copy(), tuple(members), places)

    @staticmethod
    def _topic_name(channel: _Channel, known: dict[str, list[_Channel]]) -> str:
        """The channel's topic; a second channel of the same topic with another schema or encoding gets its id."""
        same = known.get(channel.topic)
        if not same:
            return channel.topic
        first = same[0]
        schema, other = channel.schema, first.schema
        if channel.message_encoding == first.message_encoding and (schema.name if schema else None) == (
            other.name if other else None
        ):
            return channel.topic
        return f"{channel.topic} (channel {channel.id})"

    def _prepare(self, topic: str, channel: _Channel, factories: list[Any]) -> str:
        """The topic's message type, and its decoder if it has one (else its problem is recorded)."""
        schema, encoding = channel.schema, channel.message_encoding
        name = schema.name if schema is not None else ""
        if encoding == "json":
            self._decoders[topic] = lambda data: attributes(json.loads(bytes(data)))
        else:
            event = service_event_schema(schema) if schema is not None and encoding == "cdr" else None
            for factory in factories:
                try:
                    with contextlib.redirect_stderr(io.StringIO()):  # the ROS 2 parser prints what it fails on
                        decoder = factory.decoder_for(encoding, event or schema)
                except Exception as exc:  # noqa: BLE001 - a schema that does not parse
                    self.problems[topic] = f"its {schema.encoding} schema {name} does not parse, at {reason(exc)!r}"
                    return name
                if decoder is not None:
                    self._decoders[topic] = decoder
                    break
        if topic not in self._decoders:
            schema_encoding = schema.encoding if schema is not None else "no schema"
            self.problems[topic] = f"no decoder for message encoding {encoding!r} ({schema_encoding})"
            return name
        if name in ROS_OF:
            return ROS_OF[name]
        return ros_type(name) if encoding in ("ros1", "cdr") else name

    # -- the index ----------------------------------------------------------

    def _open(self, storage: int, path: Path | StorePath, channels: dict[tuple[int, int], _Channel]) -> np.ndarray:
        from mcap.exceptions import McapError
        from mcap.reader import SeekingReader

        with path.open("rb") as file:
            if file.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise DatasetError(f"{path}: not an MCAP file", path=self.path)
            file.seek(0)
            try:
                summary = SeekingReader(file, record_size_limit=MAX_CHUNK_BYTES).get_summary()
            except (McapError, ValueError, struct.error, EOFError):  # no footer: cut short
                summary = None
            self._chunks.append([])
            if summary is None or not summary.chunk_indexes:
                return self._walk(storage, path, file, channels)
            schemas = dict(summary.schemas)
            for schema_channel in summary.channels.values():
                channels[(storage, schema_channel.id)] = _Channel(
                    schema_channel.id,
                    schema_channel.topic,
                    schema_channel.message_encoding,
                    summary.schemas.get(schema_channel.schema_id),
                    storage,
                )
            entries: list[np.ndarray] = []
            for number, index in enumerate(sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)):
                chunk = _Chunk(
                    index.chunk_start_offset, index.compression, index.compressed_size, index.uncompressed_size, 0
                )
                self._chunks[storage].append(chunk)
                if index.message_index_offsets:
                    entries.append(self._message_indexes(storage, number, file, index, path))
                else:
                    entries.append(
                        self._chunk_entries(storage, number, self._read_chunk(storage, number, file), channels, schemas)
                    )
            table = np.concatenate(entries)
            if set(np.unique(table[:, 1]).tolist()) - {
                c for s, c in channels if s == storage
            }:  # channels only in chunks
                for number in range(len(self._chunks[storage])):
                    self._chunk_entries(storage, number, self._read_chunk(storage, number, file), channels, schemas)
            return table

    def _message_indexes(self, storage: int, number: int, file: Any, index: Any, path: Any) -> np.ndarray:
        start = min(index.message_index_offsets.values())
        if index.message_index_length > MAX_CHUNK_BYTES:
            raise DatasetError(
                f"{path}: the message indexes of the chunk at byte {index.chunk_start_offset} are too large",
                path=self.path,
            )
        file.seek(start)
        data = file.read(index.message_index_length)
        entries: list[np.ndarray] = [_rows([])]
        position = 0
        while position + 15 <= len(data):
            opcode, length, channel, size = struct.unpack_from("<BQHI", data, position)
            if opcode != _MESSAGE_INDEX or size % 16 or position + 15 + size > len(data):
                raise DatasetError(f"{path}: damaged message index at byte {start + position}", path=self.path)
            pairs = np.frombuffer(data, "<u8", count=size // 8, offset=position + 15).reshape(-1, 2).astype(np.int64)
            rows = np.empty((len(pairs), 5), np.int64)
            rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4] = (
                storage,
                channel,
                pairs[:, 0],
                number,
                pairs[:, 1],
            )
            entries.append(rows)
            position += 9 + length
        return np.concatenate(entries)

    def _walk(self, storage: int, path: Any, file: Any, channels: dict[tuple[int, int], _Channel]) -> np.ndarray:
        """Every message of a file read from its start; schemas and channels are learnt on the way."""
        size = file.seek(0, 2)
        position = len(MCAP_MAGIC)
        entries: list[np.ndarray] = [_rows([])]
        top: list[tuple[int, int, int, int, int]] = []  # messages outside chunks
        schemas: dict[int, Any] = {}
        while position + 9 <= size:
            file.seek(position)
            opcode, length = struct.unpack("<BQ", file.read(9))
            end = position + 9 + length
            if opcode in (_FOOTER, _DATA_END):
                break
            if end > size:
                logger.warning(
                    "%s: a record at byte %d is cut off by the end of the file: the %d bytes from there are left out",
                    self.path,
                    position,
                    size - position,
                )
                break
            if opcode in (_SCHEMA, _CHANNEL):
                self._learn(opcode, file.read(length), storage, schemas, channels)
            elif opcode == _MESSAGE and length >= 22:
                channel, _, time = struct.unpack("<HIQ", file.read(14))
                top.append((storage, channel, time, -1, position))
            elif opcode == _CHUNK:
                head = file.read(32)
                _, _, uncompressed, crc, name_length = struct.unpack_from("<QQQII", head)
                compression = file.read(name_length).decode()
                (compressed,) = struct.unpack("<Q", file.read(8))
                self._chunks[storage].append(_Chunk(position, compression, compressed, uncompressed, crc))
                number = len(self._chunks[storage]) - 1
                data = self._read_chunk(storage, number, file)
                entries.append(self._chunk_entries(storage, number, data, channels, schemas))
            position = end
        return np.concatenate([*entries, _rows(top)])

    def _learn(
        self, opcode: int, body: bytes, storage: int, schemas: dict[int, Any], channels: dict[tuple[int, int], _Channel]
    ) -> None:
        from mcap.data_stream import ReadDataStream
        from mcap.records import Channel, Schema

        stream = ReadDataStream(io.BytesIO(body))
        if opcode == _SCHEMA:
            schema = Schema.read(stream)
            schemas.setdefault(schema.id, schema)
        else:
            record = Channel.read(stream)
            channels.setdefault(
                (storage, record.id),
                _Channel(record.id, record.topic, record.message_encoding, schemas.get(record.schema_id), storage),
            )

    def _chunk_entries(
        self,
        storage: int,
        number: int,
        data: bytes,
        channels: dict[tuple[int, int], _Channel],
        schemas: dict[int, Any] | None = None,
    ) -> np.ndarray:
        """The messages of an unpacked chunk, by walking its records."""
        entries = []
        schemas = {} if schemas is None else schemas
        position = 0
        while position + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, position)
            body = position + 9
            if body + length > len(data):
                raise DatasetError(f"{self.path}: a record of chunk {number} runs past its end", path=self.path)
            if opcode == _MESSAGE and length >= 22:
                channel, _, time = struct.unpack_from("<HIQ", data, body)
                entries.append((storage, channel, time, number, position))
            elif opcode in (_SCHEMA, _CHANNEL):
                self._learn(opcode, data[body : body + length], storage, schemas, channels)
            position = body + length
        return _rows(entries)

    def _read_chunk(self, storage: int, number: int, file: Any) -> bytes:
        chunk = self._chunks[storage][number]
        where = f"{self.path}: chunk at byte {chunk.start}"
        check_declared(chunk.uncompressed_size, where)
        if chunk.records + chunk.compressed_size > file.seek(0, 2):
            raise DatasetError(f"{where} is cut short", path=self.path)
        file.seek(chunk.records)
        return unpack(file.read(chunk.compressed_size), chunk.compression, chunk.uncompressed_size, where)

    # -- messages -----------------------------------------------------------

    def _payload(self, place: np.ndarray, topic: str) -> memoryview:
        storage, chunk, offset = (int(v) for v in place)
        if chunk < 0:  # a message outside chunks: read where it is
            with self._files[storage].open("rb") as file:
                file.seek(offset)
                opcode, length = struct.unpack("<BQ", file.read(9))
                if opcode != _MESSAGE or length > MAX_CHUNK_BYTES:
                    raise DatasetError(
                        f"{self.path}: topic {topic}: no message record at byte {offset}", path=self.path
                    )
                return memoryview(file.read(length))[22:]
        data = self._cache.pop((storage, chunk), None)
        if data is None:
            with self._files[storage].open("rb") as file:
                data = self._read_chunk(storage, chunk, file)
            kept = sum(map(len, self._cache.values()))
            while self._cache and kept + len(data) > CHUNK_CACHE_BYTES:
                kept -= len(self._cache.pop(next(iter(self._cache))))
        self._cache[(storage, chunk)] = data
        if offset + 31 > len(data) or data[offset] != _MESSAGE:
            raise DatasetError(
                f"{self.path}: topic {topic}: no message record at offset {offset} of chunk {chunk}", path=self.path
            )
        (length,) = struct.unpack_from("<Q", data, offset + 1)
        return memoryview(data)[offset + 31 : offset + 9 + length]

    def declared(self, topic: str, first: int, last: int) -> dict[tuple[Any, ...], int]:
        """What reading messages ``[first, last)`` of ``topic`` unpacks, from the index alone: each chunk that holds
        them with the bytes it declares (a message outside chunks unpacks nothing)."""
        info = self.topics[topic]
        if last <= first or info.places is None:
            return {}
        parts = {(int(s), int(c)) for s, c in info.places[first:last, :2].tolist() if c >= 0}
        return {(storage, chunk): int(self._chunks[storage][chunk].uncompressed_size) for storage, chunk in parts}

    def original(self, topic: str) -> OriginalTopic | None:
        """How the file holds ``topic``: its channel's encoding and schema (binary schemas in base64, as the
        Foxglove WebSocket protocol carries them); ``None`` for a channel without a schema."""
        channel = self.topics[topic].connections[0]
        schema = channel.schema
        if schema is None:
            return None
        if schema.encoding in _TEXT_SCHEMAS:
            try:
                text = bytes(schema.data).decode()
            except UnicodeDecodeError:
                return None
        else:
            text = base64.b64encode(bytes(schema.data)).decode()
        return OriginalTopic(topic, channel.message_encoding, schema.name, schema.encoding, text)

    def close(self) -> None:
        with self._lock:
            self._cache.clear()

    def _decode(self, topic: str, msgtype: str, time: int, data: bytes | memoryview) -> Any:
        decoder = self._decoders.get(topic)
        if decoder is None:
            raise DatasetError(f"{self.path}: topic {topic}: {self.problems.get(topic, 'no decoder')}", path=self.path)
        try:
            schema = self.topics[topic].connections[0].schema
            return adapt(schema.name if schema is not None else "", decoder(bytes(data)))
        except Exception as exc:  # noqa: BLE001 - a message that does not match its schema
            raise DatasetError(
                f"{self.path}: topic {topic}: a {msgtype} message at {time} ns does not decode: {reason(exc)}",
                path=self.path,
            ) from None
