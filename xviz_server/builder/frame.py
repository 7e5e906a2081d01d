"""Build the state updates of a log, one frame at a time."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..codec.image import sniff_image
from ..exceptions import BuilderError
from ..messages import is_number
from .styles import check_style

__all__ = ["FrameBuilder"]

#: The ``values`` key of each scalar type.
_VALUE_KEYS = {"FLOAT": "doubles", "INT32": "int32s", "STRING": "strings", "BOOL": "bools"}
#: The key of a primitive state that holds each primitive type.
_PRIMITIVE_KEYS = {
    "POINT": "points",
    "POLYGON": "polygons",
    "POLYLINE": "polylines",
    "CIRCLE": "circles",
    "STADIUM": "stadiums",
    "TEXT": "texts",
    "IMAGE": "images",
}
#: Future instances are built from vertex arrays: the least count each type needs.
_FUTURE_LEAST = {"POINT": 1, "POLYLINE": 2, "POLYGON": 3}
_UPDATE_TYPES = ("SNAPSHOT", "COMPLETE_STATE", "INCREMENTAL", "PERSISTENT")
_COLUMN_TYPES = ("INT32", "DOUBLE", "STRING", "BOOLEAN")
_INT32 = (-(2**31), 2**31 - 1)


def _vertices(where: str, values: Any, least: int) -> np.ndarray:
    """``values`` as a float32 (N, 3) array of at least ``least`` finite rows; a float32 array is kept, not copied."""
    try:
        array = np.asarray(values, dtype=np.float32)
    except (TypeError, ValueError):
        raise BuilderError(f"{where} must be (N, 3) rows of x, y, z numbers") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise BuilderError(f"{where} must be (N, 3) rows of x, y, z, not shape {array.shape}")
    if len(array) < least:
        raise BuilderError(f"{where} needs at least {least} vertices, got {len(array)}")
    if not np.isfinite(array).all():
        row = int(np.flatnonzero(~np.isfinite(array).all(axis=1))[0])
        raise BuilderError(f"{where}: row {row} is not finite: {array[row].tolist()}")
    return array


def _point(where: str, value: Any) -> list[float]:
    """One finite (x, y, z), as Python floats (it stays in the JSON part of a message)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BuilderError(f"{where} must be three numbers (x, y, z), not {value!r}") from None
    if array.shape != (3,) or not np.isfinite(array).all():
        raise BuilderError(f"{where} must be three finite numbers (x, y, z), not {value!r}")
    return array.tolist()


def _number(where: str, value: Any) -> float:
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, (int, float, np.number))
        or not math.isfinite(value)
    ):
        raise BuilderError(f"{where} must be a finite number, not {value!r}")
    return float(value)


def _timestamp(where: str, value: Any) -> float:
    """A time in seconds: a finite number, not negative (the schema refuses negative times of poses and values)."""
    time = _number(where, value)
    if time < 0:
        raise BuilderError(f"{where} must be seconds >= 0, not {value!r}")
    return time


def _colors(where: str, colors: Any, count: int) -> np.ndarray:
    """(N, 3|4) uint8 colours; a uint8 array is kept, not copied, and integers 0-255 are converted."""
    array = np.asarray(colors)
    if array.ndim != 2 or array.shape[1] not in (3, 4) or len(array) != count:
        raise BuilderError(f"{where} must be ({count}, 3) or ({count}, 4) rows of RGB(A), not shape {array.shape}")
    if array.dtype == np.uint8:
        return array
    if not np.issubdtype(array.dtype, np.integer):
        raise BuilderError(f"{where} must be integers 0-255 (uint8), not {array.dtype}; scale 0-1 floats by 255 first")
    if array.min(initial=0) < 0 or array.max(initial=0) > 255:
        raise BuilderError(f"{where} must be 0-255, got values from {array.min()} to {array.max()}")
    return array.astype(np.uint8)


def _classes(stream: str, classes: Any) -> list[str]:
    if isinstance(classes, str) or not classes or not all(isinstance(c, str) and c and " " not in c for c in classes):
        raise BuilderError(f"{stream}: classes must be a non-empty list of class names without spaces, not {classes!r}")
    return list(classes)


def _object_id(where: str, value: Any) -> str:
    if isinstance(value, str) and value:
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(value)
    raise BuilderError(f"{where}: an object id is a non-empty string (or an integer), not {value!r}")


class FrameBuilder:
    """Collects the streams of one frame and builds the data of its ``xviz/state_update``.

    It knows the log's metadata (the dict :class:`MetadataBuilder` builds),
    so a stream that is not declared there, or is declared as something
    else, is refused at once; so are wrong shapes, colours and styles. Every
    error is a :class:`~xviz_server.exceptions.BuilderError` naming the
    stream and the field::

        frame = FrameBuilder(metadata)
        frame.pose("/vehicle_pose", 1317042145.96, map_origin=(8.43, 49.01, 116.4), orientation=(0, 0, -2.6))
        frame.points("/lidar/points", cloud, colors)
        frame.polygon("/objects", footprint, id="car-1", classes=["Car"])
        frame.time_series("/vehicle/velocity", 1317042145.96, 13.2)
        update = frame.build()

    Point clouds and vertices stay numpy arrays (float32 positions, uint8
    colours): arrays already of those types are not copied, so the GLB
    encoder moves them straight into the binary chunk. :meth:`build` empties
    the builder for the next frame.

    ``id`` ties primitives (and values) of different streams to one object;
    ``classes`` picks the stream's ``style_classes``; ``style`` is an inline
    style that wins over both, limited to the properties that may be set per
    object.
    """

    def __init__(self, metadata: Mapping[str, Any]) -> None:
        streams = metadata.get("streams") if isinstance(metadata, Mapping) else None
        if not isinstance(streams, Mapping):
            raise BuilderError(
                "FrameBuilder needs the metadata (what MetadataBuilder.build() returns), with its streams"
            )
        self._streams: Mapping[str, Mapping[str, Any]] = streams
        self._clear()

    def _clear(self) -> None:
        self._poses: dict[str, dict[str, Any]] = {}
        self._primitives: dict[str, dict[str, list[dict[str, Any]]]] = {}
        self._futures: dict[str, dict[float, list[dict[str, Any]]]] = {}
        self._series: dict[tuple[float, str, str | None], dict[str, Any]] = {}
        self._series_seen: set[tuple[str, float, str | None]] = set()
        self._variables: dict[str, list[dict[str, Any]]] = {}
        self._annotations: dict[str, list[dict[str, Any]]] = {}
        self._ui: dict[str, dict[str, Any]] = {}

    def _declared(self, stream: str, category: str, primitive_type: str | None = None) -> Mapping[str, Any]:
        """The metadata of ``stream``, which must be of ``category`` (and ``primitive_type``)."""
        entry = self._streams.get(stream)
        if entry is None:
            raise BuilderError(f"{stream}: stream not declared in the metadata")
        if entry.get("category") != category:
            raise BuilderError(f"{stream}: declared as {entry.get('category')}, not {category}")
        if primitive_type is not None and entry.get("primitive_type") != primitive_type:
            raise BuilderError(f"{stream}: declared as {entry.get('primitive_type')} primitives, not {primitive_type}")
        return entry

    # -- poses ------------------------------------------------------------

    def pose(
        self,
        stream: str,
        timestamp: float,
        *,
        map_origin: Sequence[float] | None = None,
        position: Sequence[float] = (0.0, 0.0, 0.0),
        orientation: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> FrameBuilder:
        """Where the vehicle is at ``timestamp`` (seconds).

        ``map_origin`` is (longitude, latitude, altitude) of the frame the
        data is in, ``position`` the offset from it in metres (x east, y
        north, z up) and ``orientation`` (roll, pitch, yaw) in radians.
        """
        self._declared(stream, "POSE")
        pose: dict[str, Any] = {"timestamp": _timestamp(f"{stream}: timestamp", timestamp)}
        if map_origin is not None:
            longitude, latitude, altitude = _point(f"{stream}: map_origin", map_origin)
            if not (-180 <= longitude <= 180 and -90 <= latitude <= 90):
                raise BuilderError(
                    f"{stream}: map_origin ({longitude}, {latitude}) is not a longitude (-180..180), latitude (-90..90)"
                )
            pose["map_origin"] = {"longitude": longitude, "latitude": latitude, "altitude": altitude}
        pose["position"] = _point(f"{stream}: position", position)
        pose["orientation"] = _point(f"{stream}: orientation", orientation)
        self._poses[stream] = pose
        return self

    # -- primitives -------------------------------------------------------

    def _base(
        self,
        stream: str,
        primitive_type: str,
        object_id: Any,
        classes: Sequence[str] | None,
        style: Mapping[str, Any] | None,
    ) -> dict[str, Any]:
        """The ``base`` of a primitive: its object id, classes and inline style."""
        base: dict[str, Any] = {}
        if object_id is not None:
            base["object_id"] = _object_id(f"{stream}: id", object_id)
        if classes is not None:
            base["classes"] = _classes(stream, classes)
        if style is not None:
            base["style"] = check_style(f"{stream}: style", style, primitive_type, per_object=True)
        return base

    def _add(self, stream: str, primitive_type: str, primitive: dict[str, Any], base: dict[str, Any]) -> FrameBuilder:
        if base:
            primitive["base"] = base
        self._primitives.setdefault(stream, {}).setdefault(_PRIMITIVE_KEYS[primitive_type], []).append(primitive)
        return self

    def points(
        self,
        stream: str,
        points: Any,
        colors: Any = None,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A point cloud: (N, 3) positions and optionally (N, 3) or (N, 4) uint8 colours, one per point."""
        self._declared(stream, "PRIMITIVE", "POINT")
        primitive: dict[str, Any] = {"points": _vertices(f"{stream}: points", points, 1)}
        if colors is not None:
            primitive["colors"] = _colors(f"{stream}: colors", colors, len(primitive["points"]))
        return self._add(stream, "POINT", primitive, self._base(stream, "POINT", id, classes, style))

    def polygon(
        self,
        stream: str,
        vertices: Any,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A polygon of at least 3 (N, 3) vertices; a stream style with ``extruded`` makes it a prism."""
        self._declared(stream, "PRIMITIVE", "POLYGON")
        primitive = {"vertices": _vertices(f"{stream}: polygon", vertices, 3)}
        return self._add(stream, "POLYGON", primitive, self._base(stream, "POLYGON", id, classes, style))

    def polyline(
        self,
        stream: str,
        vertices: Any,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A polyline of at least 2 (N, 3) vertices."""
        self._declared(stream, "PRIMITIVE", "POLYLINE")
        primitive = {"vertices": _vertices(f"{stream}: polyline", vertices, 2)}
        return self._add(stream, "POLYLINE", primitive, self._base(stream, "POLYLINE", id, classes, style))

    def circle(
        self,
        stream: str,
        center: Sequence[float],
        radius: float,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A circle of ``radius`` metres around ``center`` (x, y, z)."""
        self._declared(stream, "PRIMITIVE", "CIRCLE")
        primitive = {"center": _point(f"{stream}: center", center), "radius": self._radius(stream, radius)}
        return self._add(stream, "CIRCLE", primitive, self._base(stream, "CIRCLE", id, classes, style))

    def stadium(
        self,
        stream: str,
        start: Sequence[float],
        end: Sequence[float],
        radius: float,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A stadium: the segment from ``start`` to ``end`` widened by ``radius`` metres, with round ends."""
        self._declared(stream, "PRIMITIVE", "STADIUM")
        primitive = {
            "start": _point(f"{stream}: start", start),
            "end": _point(f"{stream}: end", end),
            "radius": self._radius(stream, radius),
        }
        return self._add(stream, "STADIUM", primitive, self._base(stream, "STADIUM", id, classes, style))

    def text(
        self,
        stream: str,
        position: Sequence[float],
        text: Any,
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A label ``text`` (made a string) at ``position`` (x, y, z)."""
        self._declared(stream, "PRIMITIVE", "TEXT")
        primitive = {"position": _point(f"{stream}: position", position), "text": str(text)}
        return self._add(stream, "TEXT", primitive, self._base(stream, "TEXT", id, classes, style))

    def image(
        self,
        stream: str,
        data: bytes | bytearray | memoryview,
        *,
        width_px: int | None = None,
        height_px: int | None = None,
        position: Sequence[float] | None = None,
        id: Any = None,
    ) -> FrameBuilder:
        """An encoded image (PNG, JPEG, ...); its size is read from its header unless given.

        The bytes are kept as they are: GLB carries them in the binary
        chunk, JSON as base64.
        """
        self._declared(stream, "PRIMITIVE", "IMAGE")
        if not isinstance(data, (bytes, bytearray, memoryview)) or not len(data):
            raise BuilderError(f"{stream}: image data must be the bytes of an encoded image, not {type(data).__name__}")
        if width_px is None or height_px is None:
            info = sniff_image(data)
            if info is None:
                raise BuilderError(f"{stream}: image is not PNG, JPEG, GIF or BMP; give width_px and height_px")
            width_px = info.width if width_px is None else width_px
            height_px = info.height if height_px is None else height_px
        for field, value in (("width_px", width_px), ("height_px", height_px)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise BuilderError(f"{stream}: {field} must be a whole number of pixels, not {value!r}")
        primitive: dict[str, Any] = {"data": data, "width_px": int(width_px), "height_px": int(height_px)}
        if position is not None:
            primitive["position"] = _point(f"{stream}: position", position)
        return self._add(stream, "IMAGE", primitive, self._base(stream, "IMAGE", id, None, None))

    @staticmethod
    def _radius(stream: str, radius: float) -> float:
        value = _number(f"{stream}: radius", radius)
        if value < 0:
            raise BuilderError(f"{stream}: radius must be >= 0, not {radius!r}")
        return value

    def future_instances(
        self,
        stream: str,
        timestamps: Sequence[float],
        shapes: Sequence[Any],
        *,
        id: Any = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """One object's predicted geometry: ``shapes[i]``, an (N, 3) vertex array, expected at ``timestamps[i]``.

        For ``POLYGON``, ``POLYLINE`` and ``POINT`` future-instance streams.
        Call once per object; shapes of the same timestamp are drawn
        together.
        """
        primitive_type = self._declared(stream, "FUTURE_INSTANCE").get("primitive_type")
        if primitive_type not in _FUTURE_LEAST:
            raise BuilderError(
                f"{stream}: future instances are built for POLYGON, POLYLINE or POINT streams, not {primitive_type}"
            )
        if len(timestamps) != len(shapes) or not len(timestamps):
            raise BuilderError(
                f"{stream}: future instances need one shape per timestamp, "
                f"got {len(timestamps)} timestamps and {len(shapes)} shapes"
            )
        base = self._base(stream, primitive_type, id, classes, style)
        key = "points" if primitive_type == "POINT" else "vertices"
        futures = self._futures.setdefault(stream, {})
        for i, (timestamp, shape) in enumerate(zip(timestamps, shapes)):
            primitive: dict[str, Any] = {key: _vertices(f"{stream}: shapes[{i}]", shape, _FUTURE_LEAST[primitive_type])}
            if base:
                primitive["base"] = base
            futures.setdefault(_timestamp(f"{stream}: timestamps[{i}]", timestamp), []).append(primitive)
        return self

    # -- values -----------------------------------------------------------

    def _value(self, where: str, scalar_type: str, value: Any) -> Any:
        """``value`` as a Python value of ``scalar_type``."""
        if isinstance(value, np.generic):
            value = value.item()
        if scalar_type == "FLOAT":
            if is_number(value):
                return float(value)
            raise BuilderError(f"{where}: a FLOAT stream takes finite numbers, not {value!r}")
        if scalar_type == "INT32":
            if isinstance(value, int) and not isinstance(value, bool) and _INT32[0] <= value <= _INT32[1]:
                return value
            raise BuilderError(f"{where}: an INT32 stream takes whole numbers from -2**31 to 2**31-1, not {value!r}")
        if scalar_type == "STRING" and isinstance(value, str):
            return value
        if scalar_type == "BOOL" and isinstance(value, bool):
            return value
        raise BuilderError(f"{where}: a {scalar_type} stream cannot take {value!r}")

    def time_series(self, stream: str, timestamp: float, value: Any, *, id: Any = None) -> FrameBuilder:
        """The value of a time series at ``timestamp``, optionally of object ``id``.

        Values of one timestamp, scalar type and object share one entry, as
        in the official logs; a stream has one value per timestamp and object.
        """
        scalar_type = self._declared(stream, "TIME_SERIES")["scalar_type"]
        time = _timestamp(f"{stream}: timestamp", timestamp)
        object_id = None if id is None else _object_id(f"{stream}: id", id)
        if (stream, time, object_id) in self._series_seen:
            owner = "" if object_id is None else f" for object {object_id!r}"
            raise BuilderError(f"{stream}: already has a value at {time}{owner} in this frame")
        value = self._value(f"{stream}: value", scalar_type, value)
        kind = _VALUE_KEYS[scalar_type]
        entry = self._series.get((time, kind, object_id))
        if entry is None:
            entry = self._series[time, kind, object_id] = {"timestamp": time, "streams": [], "values": {kind: []}}
            if object_id is not None:
                entry["object_id"] = object_id
        entry["streams"].append(stream)
        entry["values"][kind].append(value)
        self._series_seen.add((stream, time, object_id))
        return self

    def variable(self, stream: str, values: Sequence[Any], *, id: Any = None) -> FrameBuilder:
        """A list of values (a plan, a profile; a 1-D numpy array too), optionally of object ``id``."""
        scalar_type = self._declared(stream, "VARIABLE")["scalar_type"]
        items = values.tolist() if isinstance(values, np.ndarray) else values
        if isinstance(items, (str, bytes)) or not isinstance(items, Sequence):
            raise BuilderError(f"{stream}: values must be a list of {scalar_type} values, not {type(values).__name__}")
        checked = [self._value(f"{stream}: values[{i}]", scalar_type, value) for i, value in enumerate(items)]
        variable: dict[str, Any] = {"values": {_VALUE_KEYS[scalar_type]: checked}}
        if id is not None:
            variable["base"] = {"object_id": _object_id(f"{stream}: id", id)}
        self._variables.setdefault(stream, []).append(variable)
        return self

    def annotation(
        self,
        stream: str,
        object_id: Any,
        *,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """Restyle object ``object_id`` of other streams: give it style ``classes``, an inline ``style``, or both."""
        self._declared(stream, "ANNOTATION")
        if not classes and not style:
            raise BuilderError(f"{stream}: an annotation needs classes or a style")
        visual: dict[str, Any] = {"base": {"object_id": _object_id(f"{stream}: object_id", object_id)}}
        if classes:
            visual["style_classes"] = _classes(stream, classes)
        if style:
            visual["inline_style"] = check_style(f"{stream}: style", style, None, per_object=True)
        self._annotations.setdefault(stream, []).append(visual)
        return self

    def treetable(
        self,
        stream: str,
        columns: Sequence[tuple[str, str] | tuple[str, str, str]],
        nodes: Sequence[tuple[int, int | None, Sequence[Any] | None]],
    ) -> FrameBuilder:
        """A tree table: ``columns`` of (title, type[, unit]) with type ``INT32``, ``DOUBLE``,
        ``STRING`` or ``BOOLEAN``, and ``nodes`` of (id, parent id or None, one value per column or None).

        A parent comes before its children. Values are written as the
        strings the table shows (booleans as ``true``/``false``; ``None`` as
        an empty cell).
        """
        self._declared(stream, "UI_PRIMITIVE")
        table_columns = []
        for i, column in enumerate(columns):
            if not 2 <= len(column) <= 3 or column[1] not in _COLUMN_TYPES:
                raise BuilderError(
                    f"{stream}: columns[{i}] must be (title, type[, unit]) with type one of "
                    f"{', '.join(_COLUMN_TYPES)}, not {column!r}"
                )
            table_column = {"display_text": str(column[0]), "type": column[1]}
            if len(column) == 3:
                table_column["unit"] = str(column[2])
            table_columns.append(table_column)
        table_nodes: list[dict[str, Any]] = []
        seen: set[int] = set()
        for node_id, parent, values in nodes:
            where = f"{stream}: node {node_id!r}"
            if (
                isinstance(node_id, bool)
                or not isinstance(node_id, (int, np.integer))
                or node_id < 0
                or node_id in seen
            ):
                raise BuilderError(f"{where}: node ids are distinct whole numbers >= 0")
            node: dict[str, Any] = {"id": int(node_id)}
            if parent is not None:
                if parent not in seen:
                    raise BuilderError(f"{where}: parent {parent!r} is not a node listed before it")
                node["parent"] = int(parent)
            if values is not None:
                if len(values) != len(table_columns):
                    raise BuilderError(f"{where}: {len(values)} values for {len(table_columns)} columns")
                node["column_values"] = [_cell(where, c, v) for c, v in zip(table_columns, values)]
            seen.add(int(node_id))
            table_nodes.append(node)
        self._ui[stream] = {"treetable": {"columns": table_columns, "nodes": table_nodes}}
        return self

    # -- the frame --------------------------------------------------------

    def build(self, timestamp: float | None = None, update_type: str = "SNAPSHOT") -> dict[str, Any]:
        """The data of the ``xviz/state_update`` message; the builder is then empty.

        ``timestamp`` defaults to that of the (first) pose. ``update_type``
        is ``SNAPSHOT`` (what the official logs carry), ``COMPLETE_STATE``,
        ``INCREMENTAL`` or ``PERSISTENT``.
        """
        if update_type not in _UPDATE_TYPES:
            raise BuilderError(f"frame: update_type {update_type!r} is not one of {', '.join(_UPDATE_TYPES)}")
        if timestamp is None:
            if not self._poses:
                raise BuilderError("frame: give build() a timestamp, or add a pose")
            timestamp = next(iter(self._poses.values()))["timestamp"]
        stream_set: dict[str, Any] = {"timestamp": _number("frame: timestamp", timestamp)}
        if self._poses:
            stream_set["poses"] = self._poses
        if self._primitives:
            stream_set["primitives"] = self._primitives
        if self._futures:
            stream_set["future_instances"] = {
                stream: self._future_state(stream, by_time) for stream, by_time in self._futures.items()
            }
        if self._series:
            stream_set["time_series"] = list(self._series.values())
        if self._variables:
            stream_set["variables"] = {stream: {"variables": v} for stream, v in self._variables.items()}
        if self._annotations:
            stream_set["annotations"] = {stream: {"visuals": v} for stream, v in self._annotations.items()}
        if self._ui:
            stream_set["ui_primitives"] = self._ui
        if len(stream_set) == 1:
            raise BuilderError("frame: nothing was added")
        self._clear()
        return {"update_type": update_type, "updates": [stream_set]}

    def _future_state(self, stream: str, by_time: Mapping[float, list[dict[str, Any]]]) -> dict[str, Any]:
        """The future instances of ``stream``: its shapes grouped by timestamp, in time order."""
        key = _PRIMITIVE_KEYS[self._streams[stream]["primitive_type"]]
        times = sorted(by_time)
        return {"timestamps": times, "primitives": [{key: by_time[t]} for t in times]}


def _cell(where: str, column: Mapping[str, Any], value: Any) -> str:
    """A tree-table cell as the string the table shows, checked against its column's type."""
    if isinstance(value, np.generic):
        value = value.item()
    kind = column["type"]
    if value is None:
        return ""
    if kind == "BOOLEAN" and isinstance(value, bool):
        return "true" if value else "false"
    if kind == "INT32" and isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    if kind == "DOUBLE" and is_number(value):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if kind == "STRING":
        return str(value)
    raise BuilderError(f"{where}: column {column['display_text']!r} is {kind}, not {value!r}")
