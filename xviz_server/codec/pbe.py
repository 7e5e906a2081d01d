"""XVIZ messages as protobuf ("PBE"), the way ``@xviz/io``'s protobuf writer stores them.

Layout of a message::

    "PBE1"  xviz.v2.Envelope {type: "xviz/state_update",
                              data: google.protobuf.Any {type_url: "xviz.v2.StateUpdate",
                                                         value: <xviz.v2.StateUpdate>}}

The messages are declared in ``xviz_v2.proto`` beside this module. This
module only reads them: PBE logs are served as GLB or JSON. The envelope's
``type`` is read first, then the whole message is parsed once by the
protobuf runtime, with the ``Any`` read as the message that type names.

Decoding gives the envelope that the same message has as GLB (see
:mod:`~xviz_server.codec.glb`), with what ``@xviz/io`` changes on the way
to protobuf undone where that can be done:

* the float arrays of points, polygons and polylines become float32
  ``(N, 3)`` numpy arrays, read-only views of the message's bytes, and their
  colours uint8 ``(N, 3)`` or ``(N, 4)`` arrays, by how many bytes each point
  has;
* style colours, stored as bytes, become ``[r, g, b]`` or ``[r, g, b, a]``
  lists (the writer turns ``"#RRGGBB"`` strings into bytes, and its reading
  of ``"#RGB"`` is its own: ``"#00a"`` is stored as 0, 0, 10);
* enums become their names; ``float`` values (radii, widths, positions of
  texts and circles) the shortest decimal that reads back as the same
  float32, so ``1.4`` stays ``1.4``;
* images become ``bytes``; ``google.protobuf.Struct`` values (panel
  configurations) plain JSON values.

Protobuf cannot tell a field holding its default (0, ``""``, ``false``,
empty) from a missing one, and the writer drops keys that XVIZ does not
declare: those are absent from the result, except the fields the XVIZ
schema requires, which get their default when absent, as ``@xviz/io``'s
reader gives them (a map origin at longitude 0 keeps its ``longitude: 0``):
the ``timestamp`` of a stream set and of a time series entry, the three
coordinates of a map origin, the ``radius`` of a circle or stadium, the
``text`` of a text, the ``data``, ``width_px`` and ``height_px`` of an
image, and the ``display_text`` of a tree table column and ``id`` of a node.

Errors are :class:`~xviz_server.exceptions.DecodeError` naming the byte
offset in the message and the field at fault.
"""

from __future__ import annotations

import codecs
import functools
from collections.abc import Callable, Iterator
from typing import Any, cast

import numpy as np
from google.protobuf import any_pb2, json_format, struct_pb2  # noqa: F401  (xviz_v2.proto imports any and struct)
from google.protobuf.descriptor import Descriptor, EnumDescriptor, FieldDescriptor
from google.protobuf.message import DecodeError as ProtobufDecodeError
from google.protobuf.message import Message
from google.protobuf.unknown_fields import UnknownFieldSet

from ..exceptions import DecodeError
from .xviz_v2_pb2 import Envelope, MetadataEnvelope, StateUpdateEnvelope

__all__ = ["PBE_MAGIC", "is_pbe", "decode_pbe"]

PBE_MAGIC = b"PBE1"

#: The envelope, read with the message it holds, of each envelope type.
_ENVELOPES: dict[str, type[MetadataEnvelope | StateUpdateEnvelope]] = {
    "xviz/metadata": MetadataEnvelope,
    "xviz/state_update": StateUpdateEnvelope,
}
_ENVELOPE = "xviz.v2.Envelope"  # how errors name the envelope, whichever reading of it is used

_FLOAT32 = np.dtype("<f4")
_UINT8 = np.dtype("<u1")
_FIXED32 = 5  # wire type of one float written unpacked

# Primitives whose x, y, z triples are XVIZ's packed `repeated float`, declared
# `repeated bytes` in xviz_v2.proto, by the field holding them; their colours
# (Point and Polyline) are bytes, 3 or 4 per vertex.
_VERTICES = {"xviz.v2.Point": "points", "xviz.v2.Polygon": "vertices", "xviz.v2.Polyline": "vertices"}
_STYLES = frozenset({"xviz.v2.StyleObjectValue", "xviz.v2.StyleStreamValue"})
_STYLE_COLORS = frozenset({"fill_color", "stroke_color"})
# Scalar fields that the XVIZ schema requires, given their default when absent.
_REQUIRED = {
    "xviz.v2.StreamSet": ("timestamp",),
    "xviz.v2.TimeSeriesState": ("timestamp",),
    "xviz.v2.MapOrigin": ("longitude", "latitude", "altitude"),
    "xviz.v2.Circle": ("radius",),
    "xviz.v2.Stadium": ("radius",),
    "xviz.v2.Text": ("text",),
    "xviz.v2.Image": ("data", "width_px", "height_px"),
    "xviz.v2.TreeTableColumn": ("display_text",),
    "xviz.v2.TreeTableNode": ("id",),
}
# How deep the protobuf runtime reads messages within messages (upb's default); google.protobuf.Struct nests.
_MAX_NESTING = 100


def is_pbe(data: bytes | bytearray | memoryview) -> bool:
    """Tell whether ``data`` starts like a PBE message."""
    return bytes(data[:4]) == PBE_MAGIC


def decode_pbe(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """Decode a PBE message into its envelope.

    Arrays are read-only numpy arrays over bytes of the decoded message, not
    of ``data``.

    Raises :class:`~xviz_server.exceptions.DecodeError` naming the offset and
    field at fault when ``data`` is truncated, corrupt, or holds a message
    other than metadata or a state update.
    """
    buffer = memoryview(data).cast("B")
    if bytes(buffer[:4]) != PBE_MAGIC:
        raise DecodeError(f"not a PBE message: magic {bytes(buffer[:4])!r} at offset 0", offset=0)
    body = buffer[4:]
    kind = _envelope_type(body)
    envelope_class = _ENVELOPES.get(kind)
    if envelope_class is None:
        if not kind:
            raise DecodeError(
                "PBE message has no envelope type: only messages written with an envelope "
                "(@xviz/io's default) can be read",
                offset=4,
            )
        raise DecodeError(f"PBE envelope holds {kind!r}; logs hold only {' and '.join(_ENVELOPES)}", offset=4)
    envelope = envelope_class()
    try:
        envelope.ParseFromString(body)  # type: ignore[arg-type]  # any buffer: a memoryview is not copied
    except ProtobufDecodeError as exc:
        found = _locate(body, cast(Descriptor, envelope.DESCRIPTOR), _ENVELOPE)
        if found is None:  # the wire format holds; the runtime refuses something else
            raise DecodeError(f"PBE message cannot be parsed: {exc}", offset=4) from None
        raise _corrupt(4 + found[0], found[1]) from None
    name = envelope.data.value.DESCRIPTOR.full_name
    type_url = envelope.data.type_url
    if type_url and type_url.rpartition("/")[2] != name:
        raise DecodeError(f"PBE envelope of type {kind!r} holds a {type_url!r}, not a {name}", offset=4)
    try:
        content = _message(envelope.data.value)
    except _FieldError as exc:
        raise DecodeError(f"PBE {name}{''.join(reversed(exc.path))}: {exc}") from None
    return {"type": kind, "data": content}


def _envelope_type(body: memoryview) -> str:
    """The ``type`` of an envelope, read from its first level of fields only."""
    kind, offset = memoryview(b""), 0
    try:
        for number, wire_type, start, end in _fields(body):
            if number == 1 and wire_type == 2:
                kind, offset = body[start:end], start
        return codecs.decode(kind, "utf-8")
    except _WireError as exc:
        raise _corrupt(4 + exc.offset, _wire_problem(exc, cast(Descriptor, Envelope.DESCRIPTOR), _ENVELOPE)) from None
    except UnicodeDecodeError as exc:
        raise _corrupt(4 + offset + exc.start, f"{_ENVELOPE}.type is not UTF-8 text") from None


def _corrupt(offset: int, problem: str) -> DecodeError:
    return DecodeError(f"PBE message corrupt at offset {offset}: {problem}", offset=offset)


# --------------------------------------------------------------------------
# Messages to envelope values


class _FieldError(Exception):
    """A field whose content is inconsistent; carries its path."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.path: list[str] = []


def _message(message: Message) -> dict[str, Any]:
    name = message.DESCRIPTOR.full_name
    result = {field: getattr(message, field) for field in _REQUIRED.get(name, ())}
    for field, value in message.ListFields():
        try:
            result[field.name] = _field(field, value, name)
        except _FieldError as exc:
            exc.path.append(f".{field.name}")
            raise
    vertices = _VERTICES.get(name)
    if vertices is not None:
        try:
            _primitive(message, vertices, result)
        except _FieldError as exc:
            exc.path.append(f".{vertices}")
            raise
    return result


def _field(field: FieldDescriptor, value: Any, owner: str) -> Any:
    repeated = field.is_repeated
    if field.message_type is not None:
        if field.message_type.GetOptions().map_entry:
            return _map(field.message_type, value)
        if field.message_type.full_name == "google.protobuf.Struct":
            return json_format.MessageToDict(value)
        return _items(_message, value) if repeated else _message(value)
    if field.type == FieldDescriptor.TYPE_ENUM:
        names = _enum_names(field.enum_type)
        return [names.get(v, v) for v in value] if repeated else names.get(value, value)
    if field.type == FieldDescriptor.TYPE_FLOAT:
        return [_float32(v) for v in value] if repeated else _float32(value)
    if owner in _STYLES and field.name in _STYLE_COLORS:
        return list(value)
    return list(value) if repeated else value


@functools.cache
def _enum_names(enum: EnumDescriptor) -> dict[int, str]:
    return {value.number: value.name for value in enum.values}


def _float32(value: float) -> float:
    """The shortest decimal that reads back as the float32 ``value``."""
    return float(str(np.float32(value)))


def _items(convert: Callable[[Any], Any], values: Any) -> list[Any]:
    items = []
    for index, value in enumerate(values):
        try:
            items.append(convert(value))
        except _FieldError as exc:
            exc.path.append(f"[{index}]")
            raise
    return items


def _map(entry: Descriptor, values: Any) -> dict[str, Any]:
    scalar = entry.fields_by_name["value"].message_type is None
    result = {}
    for key, value in values.items():
        try:
            result[key] = value if scalar else _message(value)
        except _FieldError as exc:
            exc.path.append(f"[{key!r}]")
            raise
    return result


def _primitive(message: Message, name: str, result: dict[str, Any]) -> None:
    """Put a primitive's vertices, and colours if it has some, in ``result`` as numpy arrays.

    A packed float field may come in several runs, which are joined; floats
    written unpacked, one fixed32 each, are kept by the runtime among the
    unknown fields.
    """
    data = b"".join(getattr(message, name))
    number = message.DESCRIPTOR.fields_by_name[name].number
    unknown = UnknownFieldSet(message)
    unpacked = [
        field.data
        for field in (unknown[i] for i in range(len(unknown)))
        if field.field_number == number and field.wire_type == _FIXED32
    ]
    if unpacked and data:
        raise _FieldError("mixes packed and unpacked floats, whose order protobuf does not keep")
    if len(data) % 4:
        raise _FieldError(f"{len(data)} bytes of packed floats is not a whole number of floats")
    floats = np.array(unpacked, dtype="<u4").view(_FLOAT32) if unpacked else np.frombuffer(data, dtype=_FLOAT32)
    if floats.size % 3:
        raise _FieldError(f"holds {floats.size} floats, not x, y, z triples")
    result.pop(name, None)  # the runs of bytes, as the generic conversion left them
    if floats.size:
        result[name] = floats.reshape(-1, 3)
    colors = result.get("colors")
    if colors is not None:
        count = floats.size // 3
        if len(colors) not in (3 * count, 4 * count):
            raise _FieldError(f"has {count} points but {len(colors)} bytes of colors, not 3 or 4 per point")
        result["colors"] = np.frombuffer(colors, dtype=_UINT8).reshape(count, -1)


# --------------------------------------------------------------------------
# Finding what is wrong with a message that does not parse


class _WireError(Exception):
    """Where and why the wire format of a message breaks, and in which field if known."""

    def __init__(self, offset: int, problem: str, number: int | None = None) -> None:
        super().__init__(problem)
        self.offset = offset
        self.number = number


def _varint(data: memoryview, offset: int) -> tuple[int, int]:
    """The varint at ``offset`` and the offset after it."""
    result = shift = 0
    for position in range(offset, min(len(data), offset + 10)):
        byte = data[position]
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, position + 1
        shift += 7
    raise _WireError(offset, "varint runs past the end" if len(data) - offset < 10 else "varint longer than 10 bytes")


def _fields(data: memoryview) -> Iterator[tuple[int, int, int, int]]:
    """Each field of a serialized message: number, wire type, and where its value starts and ends.

    A length-delimited value's span leaves out its length. Raises
    :class:`_WireError` where the wire format breaks.
    """
    offset = 0
    while offset < len(data):
        start = offset
        key, offset = _varint(data, offset)
        number, wire_type = key >> 3, key & 7
        if number == 0:
            raise _WireError(start, "a field numbered 0")
        try:
            if wire_type == 0:
                _, end = _varint(data, offset)
            elif wire_type == 1:
                end = offset + 8
            elif wire_type == 5:
                end = offset + 4
            elif wire_type == 2:
                length, offset = _varint(data, offset)
                end = offset + length
            else:
                raise _WireError(start, f"wire type {wire_type}, which XVIZ does not use")
        except _WireError as exc:
            raise _WireError(exc.offset, str(exc), number) from None
        if end > len(data):
            raise _WireError(start, f"needs {end - offset} bytes, only {len(data) - offset} remain", number)
        yield number, wire_type, offset, end
        offset = end


def _locate(data: memoryview, descriptor: Descriptor, path: str, depth: int = 0) -> tuple[int, str] | None:
    """The offset and description of the first problem in a message that failed to parse."""
    if depth > _MAX_NESTING:
        return 0, f"{path}: messages nested more than {_MAX_NESTING} deep"
    try:
        for number, wire_type, start, end in _fields(data):
            field = descriptor.fields_by_number.get(number)
            if field is None or wire_type != 2:
                continue
            where = f"{path}.{field.name}"
            if field.message_type is not None:
                found = _locate(data[start:end], field.message_type, where, depth + 1)
                if found is not None:
                    return start + found[0], found[1]
            elif field.type == FieldDescriptor.TYPE_STRING:
                try:
                    codecs.decode(data[start:end], "utf-8")
                except UnicodeDecodeError as exc:
                    return start + exc.start, f"{where} is not UTF-8 text"
    except _WireError as exc:
        return exc.offset, _wire_problem(exc, descriptor, path)
    return None


def _wire_problem(exc: _WireError, descriptor: Descriptor, path: str) -> str:
    if exc.number is None:
        return f"{path}: {exc}"
    field = descriptor.fields_by_number.get(exc.number)
    return f"{path}.{field.name if field else f'<field {exc.number}>'}: {exc}"
