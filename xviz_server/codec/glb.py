"""XVIZ messages as GLB (binary glTF), the way ``@xviz/io`` writes them.

Layout of a message::

    header   "glTF"  u32 version (2)  u32 total length
    chunk    u32 length  u32 "JSON"   {"buffers": [...], "bufferViews": [...],
                                       "accessors": [...], "images": [...],
                                       "meshes": [], "xviz": <envelope>}
    chunk    u32 length  u32 "BIN\\0"  array and image bytes, 4-byte aligned

All integers are little-endian. Large arrays live in the BIN chunk and the
envelope refers to them with JSON pointers, ``"#/accessors/<i>"`` for
numeric arrays and ``"#/images/<i>"`` for encoded images. A string that
itself starts with ``#/`` is escaped as ``##/``.

What goes into the BIN chunk:

* numpy arrays: under ``points`` and ``vertices`` as float32 ``VEC3``, under
  ``colors`` as uint8 ``VEC3``/``VEC4``; anywhere else as an accessor of their
  own dtype when glTF has a component type for it (int8, uint8, int16, uint16,
  uint32, float32). float64 and other dtypes stay in the JSON, so timestamps
  and poses never lose precision.
* lists of numbers under ``points``, ``vertices`` and ``colors`` (what a JSON
  message holds), converted like numpy arrays. Lists that are ragged, hold
  non-numbers, or colours outside 0-255 stay in the JSON unchanged.
* ``bytes``, ``bytearray`` and ``memoryview`` values: encoded images
  (PNG, JPEG...), with their type and size read from their header; and
  base64 ``data`` strings of image primitives, which are decoded first.

The JSON chunk's length field holds the length of the JSON text before its
space padding, exactly as in the golden files that ``@xviz/io`` wrote; every
reader, this one and ``@xviz/parser`` included, starts the next chunk at the
next multiple of four.

Decoding returns the envelope with numpy arrays that are read-only views
into the given buffer and images as ``memoryview`` slices of it: nothing is
copied. The decoder also reads the ``extensions.AVS_xviz`` form, the legacy
``XVIZ`` magic and the legacy chunk types 0 (JSON) and 1 (BIN).

The container code is written here rather than on pygltflib: pygltflib is
far slower on a point-cloud frame (see docs/performance.md#codecs), drops the ``xviz`` key, and cannot read the golden files.
pygltflib still provides the glTF constants.
"""

from __future__ import annotations

import base64
import binascii
import re
import struct
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import orjson
from pygltflib import (
    BYTE,
    FLOAT,
    SCALAR,
    SHORT,
    UNSIGNED_BYTE,
    UNSIGNED_INT,
    UNSIGNED_SHORT,
    VEC2,
    VEC3,
    VEC4,
)

from ..exceptions import DecodeError, EncodeError
from .image import sniff_image
from .json import MAX_DEPTH

__all__ = ["encode_glb", "decode_glb", "edit_glb", "cut_glb", "is_glb"]

MAGIC_GLTF = b"glTF"
MAGIC_XVIZ = b"XVIZ"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
LEGACY_CHUNK_JSON = 0
LEGACY_CHUNK_BIN = 1
EXTENSION = "AVS_xviz"

_HEADER = struct.Struct("<4sII")
_CHUNK = struct.Struct("<II")

# glTF component types and their little-endian numpy dtypes.
_DTYPES: dict[int, np.dtype] = {
    BYTE: np.dtype("<i1"),
    UNSIGNED_BYTE: np.dtype("<u1"),
    SHORT: np.dtype("<i2"),
    UNSIGNED_SHORT: np.dtype("<u2"),
    UNSIGNED_INT: np.dtype("<u4"),
    FLOAT: np.dtype("<f4"),
}
_COMPONENT_TYPES = {dtype: ctype for ctype, dtype in _DTYPES.items()}
_TYPES = {SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4}
_TYPE_OF_WIDTH = {1: SCALAR, 2: VEC2, 3: VEC3, 4: VEC4}
_FLOAT32 = np.dtype("<f4")
_UINT8 = np.dtype("<u1")
_VERTEX_KEYS = frozenset({"points", "vertices"})
_POINTER = re.compile(r"#/(accessors|images)/(\d+)")


def _pad4(n: int) -> int:
    return (n + 3) & ~3


def is_glb(data: bytes | bytearray | memoryview) -> bool:
    """Tell whether ``data`` starts like a GLB message (current or legacy magic)."""
    return bytes(data[:4]) in (MAGIC_GLTF, MAGIC_XVIZ)


def cut_glb(data: bytes) -> bytes:
    """A GLB message without what follows the length its header declares; ``data`` itself when nothing does.

    Anything else (a header too short to declare a length) is returned as it
    is, for :func:`decode_glb` to report.
    """
    if len(data) < _HEADER.size:
        return data
    _, _, total = _HEADER.unpack_from(data, 0)
    return data[:total] if len(data) > total else data


# --------------------------------------------------------------------------
# Encoding


class _Packer:
    """Move the arrays and images of an envelope into a BIN chunk."""

    def __init__(self) -> None:
        self.views: list[dict[str, int]] = []
        self.accessors: list[dict[str, Any]] = []
        self.images: list[dict[str, Any]] = []
        self.chunks: list[Any] = []  # buffers and zero padding, in order
        self.length = 0

    def pack(self, value: Any, key: str | None = None, depth: int = 0) -> Any:
        if isinstance(value, Mapping):
            _deep_enough(depth)
            return {k: self.pack(v, k, depth + 1) for k, v in value.items()}
        if isinstance(value, list):
            _deep_enough(depth)
            if key in ("points", "vertices", "colors") and value:
                array = _array_from_list(value, key)
                if array is not None:
                    return self._add_array(array, key)
            if key == "images":
                return [self._pack_image_primitive(v, depth + 1) for v in value]
            return [self.pack(v, None, depth + 1) for v in value]
        if isinstance(value, np.ndarray):
            return self._add_array(value, key)
        if isinstance(value, (bytes, bytearray, memoryview)):
            return self._add_image(value)
        if isinstance(value, str) and value.startswith("#/"):
            return "#" + value
        return value

    def _pack_image_primitive(self, primitive: Any, depth: int) -> Any:
        if isinstance(primitive, Mapping):
            data = primitive.get("data")
            if isinstance(data, str) and not data.startswith("#/"):
                try:
                    blob = base64.b64decode(data, validate=True)
                except binascii.Error:
                    pass
                else:
                    return self.pack({**primitive, "data": blob}, None, depth)
        return self.pack(primitive, None, depth)

    def _add_view(self, buffer: Any, nbytes: int) -> int:
        self.views.append({"buffer": 0, "byteOffset": self.length, "byteLength": nbytes})
        self.chunks.append(buffer)
        padded = _pad4(nbytes)
        if padded != nbytes:
            self.chunks.append(bytes(padded - nbytes))
        self.length += padded
        return len(self.views) - 1

    def _add_array(self, array: np.ndarray, key: str | None) -> Any:
        if key in _VERTEX_KEYS:
            array = _as_vertices(array, key)
        elif key == "colors":
            array = _as_colors(array)
        elif array.dtype.newbyteorder("<") not in _COMPONENT_TYPES or not (
            array.ndim == 1 or (array.ndim == 2 and array.shape[1] in _TYPE_OF_WIDTH)
        ):
            return array  # no glTF accessor for it: it stays in the JSON
        array = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<"))
        width = 1 if array.ndim == 1 else array.shape[1]
        view = self._add_view(array.data.cast("B"), array.nbytes)
        self.accessors.append(
            {
                "bufferView": view,
                "type": _TYPE_OF_WIDTH[width],
                "componentType": _COMPONENT_TYPES[array.dtype],
                "count": array.shape[0],
            }
        )
        return f"#/accessors/{len(self.accessors) - 1}"

    def _add_image(self, data: bytes | bytearray | memoryview) -> str:
        blob = memoryview(data).cast("B")
        view = self._add_view(blob, blob.nbytes)
        image: dict[str, Any] = {"bufferView": view}
        info = sniff_image(blob)
        if info is not None:
            image.update(mimeType=info.mime_type, width=info.width, height=info.height)
        self.images.append(image)
        return f"#/images/{len(self.images) - 1}"


def _deep_enough(depth: int) -> None:
    if depth >= MAX_DEPTH:
        raise EncodeError(f"message nested more than {MAX_DEPTH} lists and objects deep")


def _array_from_list(value: list[Any], key: str) -> np.ndarray | None:
    """Convert a JSON list under ``points``/``vertices``/``colors``, or give up."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if array.ndim == 1:
        if array.size % 3:
            return None
        array = array.reshape(-1, 3)
    if array.ndim != 2 or not np.isfinite(array).all():
        return None
    if key == "colors":
        if array.shape[1] not in (3, 4) or array.min() < 0 or array.max() > 255:
            return None
        return array.astype(_UINT8)
    if array.shape[1] not in (2, 3):
        return None
    return array


def _as_vertices(array: np.ndarray, key: str) -> np.ndarray:
    """Shape an array of positions as float32 (N, 3); 2D positions get z = 0."""
    if array.ndim == 1 and array.size % 3 == 0:
        array = array.reshape(-1, 3)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise EncodeError(
            f"{key!r} must be an (N, 3) array of positions or a flat array of x, y, z triples, not shape {array.shape}"
        )
    if array.shape[1] == 2:
        array = np.concatenate([array, np.zeros((len(array), 1))], axis=1)
    return array.astype(_FLOAT32, copy=False)


def _as_colors(array: np.ndarray) -> np.ndarray:
    """Shape an array of colours as uint8 (N, 3) or (N, 4)."""
    if array.ndim == 1 and array.size % 3 == 0:
        array = array.reshape(-1, 3)
    if array.ndim != 2 or array.shape[1] not in (3, 4):
        raise EncodeError(f"'colors' must be an (N, 3) or (N, 4) array of 0-255 values, not shape {array.shape}")
    if array.dtype != _UINT8:
        if array.size and (array.min() < 0 or array.max() > 255):
            raise EncodeError("'colors' values must lie in 0-255")
        array = array.astype(_UINT8)
    return array


def encode_glb(message: Mapping[str, Any]) -> bytes:
    """Encode an XVIZ envelope as a GLB message.

    Raises :class:`~xviz_server.exceptions.EncodeError` if an array cannot be
    stored or a value cannot be written as JSON.
    """
    packer = _Packer()
    envelope = packer.pack(message)
    document = {
        "buffers": [{"byteLength": packer.length}],
        "bufferViews": packer.views,
        "accessors": packer.accessors,
        "images": packer.images,
        "meshes": [],
        "xviz": envelope,
    }
    return _write(document, packer.chunks, packer.length)


def _write(document: dict[str, Any], body: list[bytes | memoryview], body_length: int) -> bytes:
    """A GLB file of ``document`` (JSON chunk) and the parts of ``body`` (BIN chunk).

    ``body_length`` is their total size, a multiple of 4.
    """
    try:
        text = orjson.dumps(document, option=orjson.OPT_SERIALIZE_NUMPY)
    except orjson.JSONEncodeError as exc:
        raise EncodeError(f"cannot encode message as GLB JSON: {exc}") from None
    json_padded = _pad4(len(text))
    total = _HEADER.size + 2 * _CHUNK.size + json_padded + body_length
    return b"".join(
        [
            _HEADER.pack(MAGIC_GLTF, 2, total),
            _CHUNK.pack(len(text), CHUNK_JSON),
            text,
            b" " * (json_padded - len(text)),
            _CHUNK.pack(body_length, CHUNK_BIN),
            *body,
        ]
    )


# --------------------------------------------------------------------------
# Decoding


class _EnvelopeError(Exception):
    """A JSON pointer that names no accessor or image, or a value nested too deep; carries its path."""

    def __init__(self, subject: str, problem: str) -> None:
        self.subject, self.problem = subject, problem
        self.path: list[str] = []


def decode_glb(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """Decode a GLB message into its envelope.

    Arrays are read-only numpy views into ``data`` and images ``memoryview``
    slices of it, so ``data`` must stay unchanged while they are in use.

    Raises :class:`~xviz_server.exceptions.DecodeError` naming the offset or
    field at fault when ``data`` is truncated or inconsistent.
    """
    document, envelope, binary = _read_document(data)
    views = _read_views(document, binary)
    resolved: dict[str, list[Any]] = {
        "accessors": _read_accessors(document, views),
        "images": _read_images(document, views),
    }
    try:
        return _unpack(envelope, resolved)
    except _EnvelopeError as exc:
        where = "".join(reversed(exc.path))
        raise DecodeError(f"{exc.subject} at ${where} {exc.problem}") from None


def edit_glb(data: bytes | bytearray | memoryview, edit: Callable[[Any], Any]) -> bytes:
    """``data`` with its envelope replaced by ``edit(envelope)``; the BIN chunk is kept as it is.

    ``edit`` sees the envelope as stored, with its ``#/accessors/N`` and
    ``#/images/N`` pointers, and must keep those it wants to keep: no array
    is decoded or encoded again, so the cost is that of the JSON chunk. The
    result has the current magic and chunk types, and the envelope under
    the ``xviz`` key.

    Raises :class:`~xviz_server.exceptions.DecodeError` as :func:`decode_glb`.
    """
    document, envelope, binary = _read_document(data)
    document.pop("xviz", None)
    extensions = document.pop("extensions", None)
    extensions = extensions if isinstance(extensions, dict) else {}
    extensions.pop(EXTENSION, None)
    if extensions:
        document["extensions"] = extensions
    for key in ("extensionsUsed", "extensionsRequired"):
        names = document.pop(key, None)
        if isinstance(names, list):
            names = [name for name in names if name != EXTENSION]
        if names:
            document[key] = names
    document["xviz"] = edit(envelope)
    body = binary[1] if binary is not None else memoryview(b"")
    body_padded = _pad4(len(body))
    return _write(document, [body, bytes(body_padded - len(body))], body_padded)


def _read_document(
    data: bytes | bytearray | memoryview,
) -> tuple[dict[str, Any], Any, tuple[int, memoryview] | None]:
    """The JSON document of a GLB message, its XVIZ envelope, and its BIN chunk with its offset."""
    buffer = memoryview(data).cast("B")
    size = len(buffer)
    if size < _HEADER.size:
        raise DecodeError(f"GLB header truncated: {size} of 12 bytes", offset=0)
    magic, version, total = _HEADER.unpack_from(buffer, 0)
    if magic not in (MAGIC_GLTF, MAGIC_XVIZ):
        raise DecodeError(f"not a GLB message: magic {magic!r} at offset 0", offset=0)
    if version != 2:
        raise DecodeError(f"unsupported GLB version {version} at offset 4 (expected 2)", offset=4)
    if total > size:
        raise DecodeError(
            f"GLB truncated: header at offset 8 declares {total} bytes, only {size} present",
            offset=size,
        )
    json_chunk, binary = _read_chunks(buffer, total)
    if json_chunk is None:
        raise DecodeError("GLB has no JSON chunk", offset=_HEADER.size)
    json_offset, json_bytes = json_chunk
    try:
        document = orjson.loads(json_bytes)
    except orjson.JSONDecodeError as exc:
        raise DecodeError(
            f"GLB JSON chunk is not valid JSON at offset {json_offset + exc.pos}: {exc.msg}",
            offset=json_offset + exc.pos,
        ) from None
    if not isinstance(document, dict):
        raise DecodeError("GLB JSON chunk is not an object", offset=json_offset)
    envelope = document.get("xviz")
    extensions = document.get("extensions")
    if envelope is None and isinstance(extensions, dict):
        envelope = extensions.get(EXTENSION)
    if envelope is None:
        raise DecodeError(
            f"GLB JSON chunk holds no XVIZ message (no 'xviz' key, no extensions.{EXTENSION})",
            offset=json_offset,
        )
    return document, envelope, binary


def _read_chunks(buffer: memoryview, total: int) -> tuple[tuple[int, memoryview] | None, tuple[int, memoryview] | None]:
    json_chunk = binary = None
    offset = _HEADER.size
    while offset + _CHUNK.size <= total:
        length, kind = _CHUNK.unpack_from(buffer, offset)
        start = offset + _CHUNK.size
        if start + length > total:
            raise DecodeError(
                f"GLB chunk at offset {offset} declares {length} bytes, only {total - start} remain",
                offset=offset,
            )
        chunk = buffer[start : start + length]
        if kind in (CHUNK_JSON, LEGACY_CHUNK_JSON) and json_chunk is None:
            json_chunk = (start, chunk)
        elif kind in (CHUNK_BIN, LEGACY_CHUNK_BIN) and binary is None:
            binary = (start, chunk)
        offset = start + _pad4(length)
    return json_chunk, binary


def _list_field(document: dict[str, Any], field: str) -> list[Any]:
    value = document.get(field)
    if value is None:
        return []
    if not isinstance(value, list):
        raise DecodeError(f"GLB {field} must be a list, not {type(value).__name__}")
    return value


def _int_field(item: Any, field: str, where: str, default: int | None = None) -> int:
    value = item.get(field, default) if isinstance(item, dict) else None
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise DecodeError(f"GLB {where}.{field} must be a non-negative integer, not {value!r}")
    return value


def _read_views(document: dict[str, Any], binary: tuple[int, memoryview] | None) -> list[memoryview]:
    bin_offset, bin_bytes = binary if binary is not None else (0, memoryview(b""))
    views = []
    for i, view in enumerate(_list_field(document, "bufferViews")):
        where = f"bufferViews[{i}]"
        start = _int_field(view, "byteOffset", where, 0)
        length = _int_field(view, "byteLength", where)
        if start + length > len(bin_bytes):
            raise DecodeError(
                f"GLB {where} spans bytes {start}-{start + length} of a {len(bin_bytes)}-byte BIN chunk",
                offset=bin_offset + start,
            )
        views.append(bin_bytes[start : start + length])
    return views


def _read_accessors(document: dict[str, Any], views: list[memoryview]) -> list[np.ndarray]:
    arrays = []
    for i, accessor in enumerate(_list_field(document, "accessors")):
        where = f"accessors[{i}]"
        view_index = _int_field(accessor, "bufferView", where)
        if view_index >= len(views):
            raise DecodeError(f"GLB {where}.bufferView {view_index} is out of range ({len(views)} views)")
        ctype = accessor.get("componentType")
        dtype = _DTYPES.get(ctype) if isinstance(ctype, int) else None
        if dtype is None:
            raise DecodeError(f"GLB {where}.componentType {accessor.get('componentType')!r} is not supported")
        kind = accessor.get("type")
        width = _TYPES.get(kind) if isinstance(kind, str) else None
        if width is None:
            raise DecodeError(f"GLB {where}.type {accessor.get('type')!r} is not supported")
        count = _int_field(accessor, "count", where)
        start = _int_field(accessor, "byteOffset", where, 0)
        view = views[view_index]
        nbytes = count * width * dtype.itemsize
        if start + nbytes > len(view):
            raise DecodeError(
                f"GLB {where} needs {nbytes} bytes from offset {start} of "
                f"bufferViews[{view_index}], which has {len(view)}"
            )
        array = np.frombuffer(view, dtype=dtype, count=count * width, offset=start)
        arrays.append(array if width == 1 else array.reshape(count, width))
    return arrays


def _read_images(document: dict[str, Any], views: list[memoryview]) -> list[memoryview]:
    images = []
    for i, image in enumerate(_list_field(document, "images")):
        view_index = _int_field(image, "bufferView", f"images[{i}]")
        if view_index >= len(views):
            raise DecodeError(f"GLB images[{i}].bufferView {view_index} is out of range ({len(views)} views)")
        images.append(views[view_index])
    return images


def _unpack(value: Any, resolved: dict[str, list[Any]], depth: int = 0) -> Any:
    if isinstance(value, dict):
        if depth >= MAX_DEPTH:
            raise _EnvelopeError("an object", f"is nested more than {MAX_DEPTH} lists and objects deep")
        result = {}
        for key, item in value.items():
            try:
                result[key] = _unpack(item, resolved, depth + 1)
            except _EnvelopeError as exc:
                exc.path.append(f".{key}" if key.isidentifier() else f"[{key!r}]")
                raise
        return result
    if isinstance(value, list):
        if depth >= MAX_DEPTH:
            raise _EnvelopeError("a list", f"is nested more than {MAX_DEPTH} lists and objects deep")
        items = []
        for index, item in enumerate(value):
            try:
                items.append(_unpack(item, resolved, depth + 1))
            except _EnvelopeError as exc:
                exc.path.append(f"[{index}]")
                raise
        return items
    if isinstance(value, str) and value.startswith("#"):
        if value.startswith("##/"):
            return value[1:]
        match = _POINTER.fullmatch(value)
        if match:
            table, digits = resolved[match.group(1)], match.group(2)
            if len(digits) > 9 or int(digits) >= len(table):  # more digits than any table has rows: not read as an int
                raise _EnvelopeError(f"JSON pointer {value[:40]!r}", "names nothing")
            return table[int(digits)]
    return value
