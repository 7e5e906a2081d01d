"""TFRecord files: an index of the records, and reading one with its checksums.

A TFRecord file is a sequence of records, each framed as:

* the length of the data, uint64 little-endian;
* the masked CRC32C of those 8 bytes, uint32 little-endian;
* the data;
* the masked CRC32C of the data, uint32 little-endian.

A masked CRC is ``((crc >> 15 | crc << 17) + 0xA282EAD8) mod 2**32``.

:class:`RecordFile` indexes a file in one pass over the record headers,
seeking past the data, and checks the length's CRC on the way, since a wrong
length would lose every record after it. The data's CRC is checked when the
record is read. The index ends at the first record whose header is corrupt
or whose data runs past the end of the file or declares more than
:data:`~xviz_server.unpack.MAX_RECORD_BYTES`: that record stays in the index,
and reading it raises :class:`~xviz_server.exceptions.DatasetError` naming
the file, the record and its offset, as does reading a record whose data's
CRC does not match. Every other record reads as usual.

The framing is read here, not with TensorFlow's ``tf.data.TFRecordDataset``
(which the Waymo Open Dataset's own tools use): TensorFlow is a dependency of
hundreds of megabytes, with wheels for few platforms and Python releases,
for a format of four fields; and its reader goes through a file from the
start, where serving needs any record at once by its offset, from a file or
an object store (:class:`~xviz_server.store.path.StorePath`), and an error
that names the bad record while the others are served. The CRC32C is
google-crc32c's (C, with the processor's CRC instructions).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import google_crc32c

from ...exceptions import DatasetError, StoreError
from ...store.path import StorePath, data_path
from ...unpack import MAX_RECORD_BYTES, size_text

__all__ = ["Record", "RecordFile", "is_tfrecord", "header_problem", "masked_crc", "write_records"]

_HEADER = struct.Struct("<QI")
_FOOTER = struct.Struct("<I")
_MASK_DELTA = 0xA282EAD8


def masked_crc(data: bytes) -> int:
    """The masked CRC32C of ``data``, as TFRecord framing stores it."""
    crc = google_crc32c.value(data)
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


@dataclass(frozen=True)
class Record:
    """Where a record is in its file, and what is wrong with its framing, if anything."""

    #: Position in the file, from 0.
    number: int
    #: Byte offset of the record's header.
    offset: int
    #: Length of the data, as the header says.
    length: int
    #: Why the record cannot be read (a corrupt header, data cut short), or ``None``.
    problem: str | None = None

    @property
    def data_offset(self) -> int:
        return self.offset + _HEADER.size


def is_tfrecord(path: Path | StorePath) -> bool:
    """Whether ``path`` is a file that starts with a TFRecord header whose CRC matches (see :func:`header_problem`).

    Raises :class:`~xviz_server.exceptions.StoreError` when an object in a
    store cannot be read.
    """
    return header_problem(path) is None


def header_problem(path: Path | StorePath) -> str | None:
    """Why ``path`` does not start as a TFRecord file does (a length and its matching masked CRC), or ``None``.

    Raises :class:`~xviz_server.exceptions.StoreError` when an object in a
    store cannot be read.
    """
    try:
        with path.open("rb") as file:
            header = file.read(_HEADER.size)
    except StoreError:
        raise
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if len(header) < _HEADER.size:
        return f"{len(header)} bytes, shorter than a TFRecord header ({_HEADER.size})"
    length, crc = _HEADER.unpack(header)
    if masked_crc(header[:8]) != crc:
        return f"the CRC of its first record's length ({length}) does not match: a damaged file, or not TFRecord"
    return None


class RecordFile:
    """The records of a TFRecord file; indexed at once, read on demand.

    ``path`` is a file, or an object in a store (each read one ranged GET).
    With ``peek``, the index keeps the first ``peek`` bytes of each
    record's data, read with its header, for :meth:`head`, until
    :meth:`forget_heads`. Raises :class:`~xviz_server.exceptions.DatasetError`
    if the file cannot be read.
    """

    def __init__(self, path: Path | StorePath, peek: int = 0) -> None:
        self.path = data_path(path)
        self._peek = peek
        self._heads: dict[int, bytes] = {}
        self.records = self._index()

    def __len__(self) -> int:
        return len(self.records)

    def where(self, number: int) -> str:
        """``FILE: record N at offset O``, to start an error message about record ``number``."""
        return f"{self.path}: record {number} at offset {self.records[number].offset}"

    def read(self, number: int) -> bytes:
        """The data of record ``number``, its CRC checked; raises :class:`DatasetError` naming it."""
        record = self.records[number]
        if record.problem is not None:
            raise DatasetError(f"{self.where(number)}: {record.problem}", path=self.path)
        try:
            with self.path.open("rb", buffering=0) as file:
                file.seek(record.data_offset)
                blob = file.read(record.length + _FOOTER.size)  # one read: one GET from a store
        except OSError as exc:
            raise DatasetError(f"{self.where(number)}: cannot read: {exc}", path=self.path) from None
        data, footer = blob[: record.length], blob[record.length :]
        if len(data) < record.length or len(footer) < _FOOTER.size:
            raise DatasetError(
                f"{self.where(number)}: truncated: the file is shorter than when it was indexed", path=self.path
            )
        if masked_crc(data) != _FOOTER.unpack(footer)[0]:
            raise DatasetError(f"{self.where(number)}: data CRC mismatch: the record is corrupt", path=self.path)
        return data

    def head(self, number: int, size: int) -> bytes:
        """Up to ``size`` first bytes of record ``number``'s data, unchecked: to peek at a field.

        For a record whose header is corrupt, the bytes after the header,
        whatever its length says.
        """
        record = self.records[number]
        kept = self._heads.get(number)
        if kept is not None and (size <= len(kept) or (record.problem is None and len(kept) == record.length)):
            return kept[:size]
        try:
            with self.path.open("rb", buffering=0) as file:
                file.seek(record.data_offset)
                return file.read(size if record.problem is not None else min(size, record.length))
        except OSError as exc:
            raise DatasetError(f"{self.where(number)}: cannot read: {exc}", path=self.path) from None

    def forget_heads(self) -> None:
        """Drop the first bytes kept by the index (see ``peek``)."""
        self._heads.clear()

    def _index(self) -> list[Record]:
        records: list[Record] = []
        try:
            with self.path.open("rb", buffering=0) as file:
                size = file.seek(0, 2)
                offset = 0
                while offset < size:
                    file.seek(offset)
                    read = file.read(_HEADER.size + self._peek)
                    record = self._header(len(records), offset, read[: _HEADER.size], size)
                    if self._peek:
                        self._heads[record.number] = (
                            read[_HEADER.size :]
                            if record.problem
                            else read[_HEADER.size : _HEADER.size + record.length]
                        )
                    records.append(record)
                    if record.problem is not None:
                        break
                    offset = record.data_offset + record.length + _FOOTER.size
        except OSError as exc:
            raise DatasetError(f"{self.path}: cannot read: {exc}", path=self.path) from None
        return records

    @staticmethod
    def _header(number: int, offset: int, header: bytes, size: int) -> Record:
        if len(header) < _HEADER.size:
            return Record(number, offset, 0, f"truncated header: {len(header)} of {_HEADER.size} bytes")
        length, crc = _HEADER.unpack(header)
        if masked_crc(header[:8]) != crc:
            return Record(
                number, offset, 0, "length CRC mismatch: the header is corrupt; records after it cannot be found"
            )
        if length > MAX_RECORD_BYTES:
            return Record(
                number,
                offset,
                length,
                f"declares {size_text(length)} of data, more than the limit of {size_text(MAX_RECORD_BYTES)}",
            )
        end = offset + _HEADER.size + length + _FOOTER.size
        if end > size:
            return Record(
                number,
                offset,
                length,
                f"truncated: the record needs {end - offset} bytes, the file has {size - offset}",
            )
        return Record(number, offset, length)


def write_records(path: Path, records: Iterable[bytes]) -> None:
    """Write ``records`` to a TFRecord file at ``path``."""
    with open(path, "wb") as file:
        for data in records:
            length = struct.pack("<Q", len(data))
            file.write(length + _FOOTER.pack(masked_crc(length)))
            file.write(data)
            file.write(_FOOTER.pack(masked_crc(data)))
