"""ROS 1 bags whose recording was cut short, indexed in memory.

``rosbag record`` writes a bag's index (its connection and chunk-info
records) at the end of the file when it stops, and the header's
``index_pos`` says where. A recording killed before that leaves
``index_pos`` 0; one whose file was cut afterwards leaves it pointing past
the end. rosbags refuses both. :class:`MemoryIndexedReader` reads them: at
open it walks the bag's records once, decompressing every chunk to find its
connection and message records, and builds in memory the index that
``rosbag reindex`` would write into the file (the file is not changed).
A chunk cut off by the end of the file is left out, and :attr:`lost` says
how many bytes that was.

Opening such a bag reads all of it, where an indexed bag needs only its
index: :attr:`~MemoryIndexedReader.reindexed` tells which happened.

An indexed bag's index is not all at its end: each chunk is followed by
the index records of its messages. For a bag in an object store
(:class:`~xviz_server.store.path.RangedFile`), the reader fetches the
headers of every chunk in one batch of parallel ranged GETs, and then every
chunk's index records in another, where rosbags would make two GETs per
chunk one after another.

Every chunk is unpacked with a bound (see :mod:`xviz_server.unpack`): its
header's ``size``, which rosbags does not check, must be at most
:data:`~xviz_server.unpack.MAX_CHUNK_BYTES`, and it must unpack to exactly
that many bytes. A chunk that declares more is refused when the bag is
opened, one that unpacks to more after ``size`` bytes, each with an
:class:`~xviz_server.exceptions.OversizeError` naming the file and the
chunk's byte offset.
"""

from __future__ import annotations

import io
import os
from collections import defaultdict
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection
from rosbags.rosbag1 import Reader, ReaderError
from rosbags.rosbag1.reader import Chunk, ChunkInfo, Header, IndexData, RecordType, read_uint32

from ...store.path import RangedFile
from ...unpack import check_declared, unpack

__all__ = ["MemoryIndexedReader"]

# Bytes fetched for a chunk record's header (its length, op, compression, size fields and data length: about 60).
_CHUNK_HEADER = 256
# Bytes of an index data record besides its entries (the header of fixed fields, lengths), and of each entry.
_INDEX_HEADER, _INDEX_ENTRY = 55, 12


class _CappedFile(io.BufferedReader):
    """A file whose reads ask for no more than it holds: rosbags reads a record of the length its header declares
    in one call, and a read allocates what it asks for before it finds the file shorter (1 GiB for 4 bytes that
    lie)."""

    def __init__(self, raw: io.FileIO) -> None:
        super().__init__(raw)
        self._size = os.fstat(raw.fileno()).st_size

    def read(self, size: int | None = -1) -> bytes:
        if size is not None and size > 0:
            size = min(size, max(0, self._size - self.tell()))
        return super().read(size)


class _CappedPath(type(Path())):  # type: ignore[misc]  # Path's concrete class for this system
    """A local bag whose :meth:`open` gives a :class:`_CappedFile`."""

    def open(self, mode: str = "rb", *args: Any, **kwargs: Any) -> Any:
        return _CappedFile(io.FileIO(self, mode)) if mode == "rb" else super().open(mode, *args, **kwargs)


class MemoryIndexedReader(Reader):
    """rosbags' ROS 1 reader, which also opens a bag without a readable index by indexing it in memory, and reads
    the index of a bag in a store in two batches of GETs."""

    #: Whether the bag had no readable index and was indexed in memory at open.
    reindexed = False
    #: Bytes at the end of the file not read: a record cut short.
    lost = 0
    _size = 0  # of the file, found at open

    def __init__(self, path: Any) -> None:
        super().__init__(path)
        #: What each chunk (by its byte position) declares it unpacks to.
        self.declared: dict[int, int] = {}
        if isinstance(self.path, Path):  # an object in a store reads only what it has (RangedFile)
            self.path = _CappedPath(self.path)

    def open(self) -> None:
        size = self._size = self.path.stat().st_size
        with self.path.open("rb") as file:
            file.readline()  # the magic line, checked by Reader.open
            try:
                index_pos = Header.read(file, RecordType.BAGHEADER).get_uint64("index_pos")
            except ReaderError:
                index_pos = None  # Reader.open says what is wrong with the header
        if index_pos is None or 0 < index_pos < size:
            super().open()
            return
        self.bio = self.path.open("rb")
        try:
            self._index_in_memory(size)
        except BaseException:
            self.close()
            raise
        self.reindexed = True

    def read_chunk(self) -> Chunk:
        if not self.chunks and isinstance(self.bio, RangedFile):  # the first chunk Reader.open reads
            self._prefetch_index(self.bio)
        return self._chunk_record()

    def _chunk_record(self) -> Chunk:
        """The chunk record at the current position, its data skipped, with a bounded decompressor."""
        bio = self.bio
        assert bio is not None
        position = bio.tell()
        header = Header.read(bio, RecordType.CHUNK)
        datasize = read_uint32(bio)
        datapos = bio.tell()
        if datapos + datasize > self._size:
            raise ReaderError(
                f"the chunk at byte {position} needs {datasize} bytes, the file ends {self._size - datapos} after"
            )
        bio.seek(datasize, os.SEEK_CUR)
        return Chunk(datasize, datapos, self._unpacker(header, position))

    def _unpacker(self, header: Header, position: int) -> Callable[[bytes], bytes]:
        """What unpacks the data of the chunk at ``position``: its compression, bounded by its declared size."""
        compression = header.get_string("compression")
        if compression not in ("none", "bz2", "lz4"):
            raise ReaderError(f"Compression {compression!r} is not supported.")
        where = f"{self.path}: chunk at byte {position}"
        declared = header.get_uint32("size")
        check_declared(declared, where)
        self.declared[position] = declared
        return partial(unpack, compression=compression, declared=declared, where=where)

    def _prefetch_index(self, bio: RangedFile) -> None:
        """Fetch the header and the index records of every chunk, in two batches; what is not fetched is read later."""
        position = bio.tell()
        bio.prefetch([(info.pos, info.pos + _CHUNK_HEADER) for info in self.chunk_infos])
        ranges = []
        for info in self.chunk_infos:
            bio.seek(info.pos)
            chunk = self._chunk_record()
            end = chunk.datapos + chunk.datasize
            ranges.append(
                (end, end + sum(_INDEX_HEADER + _INDEX_ENTRY * count for count in info.connection_counts.values()))
            )
        bio.prefetch(ranges)
        bio.seek(position)

    def _index_in_memory(self, size: int) -> None:
        """Read every record after the bag header; index the messages of every whole chunk."""
        bio = self.bio
        assert bio is not None
        bio.readline()
        Header.read(bio, RecordType.BAGHEADER)
        bio.seek(read_uint32(bio), os.SEEK_CUR)  # the header record's padding
        connections: dict[int, Connection] = {}
        indexes: dict[int, list[IndexData]] = defaultdict(list)
        while (position := bio.tell()) < size:
            try:
                header = Header.read(bio)
                length = read_uint32(bio)
            except ReaderError:
                self.lost = size - position
                break
            if bio.tell() + length > size:
                self.lost = size - position
                break
            if header.get_uint8("op") != RecordType.CHUNK:  # index data, or records of an index cut short
                bio.seek(length, os.SEEK_CUR)
                continue
            chunk = Chunk(length, bio.tell(), self._unpacker(header, position))
            records = chunk.decompressor(bio.read(length))
            counts, first, last = self._index_chunk(records, position, connections, indexes)
            self.chunks[position] = chunk
            if counts:
                self.chunk_infos.append(ChunkInfo(position, first, last + 1, counts))
        for entries in indexes.values():
            entries.sort()
        self.indexes = {id: indexes[id] for id in connections}
        self.connections = [
            Connection(*connection[0:5], len(self.indexes[connection.id]), *connection[6:])
            for connection in connections.values()
        ]

    def _index_chunk(
        self, records: bytes, position: int, connections: dict[int, Connection], indexes: dict[int, list[IndexData]]
    ) -> tuple[dict[int, int], int, int]:
        """Index the message records of the chunk at ``position`` and keep its connection records.

        Returns the count of messages per connection, and the first and last record time.
        """
        chunk = io.BytesIO(records)
        counts: dict[int, int] = defaultdict(int)
        first, last = 2**63 - 1, 0
        outer, self.bio = self.bio, chunk  # read_connection reads from self.bio
        try:
            while (offset := chunk.tell()) < len(records):
                header = Header.read(chunk)
                op = header.get_uint8("op")
                if op == RecordType.CONNECTION:
                    chunk.seek(offset)
                    connection = self.read_connection()
                    connections.setdefault(connection.id, connection)
                    continue
                if op == RecordType.MSGDATA:
                    conn, time = header.get_uint32("conn"), header.get_time("time")
                    indexes[conn].append(IndexData(time, position, offset))
                    counts[conn] += 1
                    first, last = min(first, time), max(last, time)
                chunk.seek(read_uint32(chunk), os.SEEK_CUR)
        finally:
            self.bio = outer
        return dict(counts), first, last
