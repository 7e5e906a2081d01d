"""Build the state updates of a log, one frame at a time."""

from __future__ import annotations

from collections import defaultdict
from typing import Any, Mapping, Sequence

import numpy as np

from ..codec.image import sniff_image
from ..exceptions import BuilderError
from ..validation import get_validator

__all__ = ["FrameBuilder"]

_VALUE_KINDS = {"FLOAT": "doubles", "INT32": "int32s", "STRING": "strings", "BOOL": "bools"}
_PRIMITIVE_KEYS = {
    "POINT": "points",
    "POLYGON": "polygons",
    "POLYLINE": "polylines",
    "CIRCLE": "circles",
    "STADIUM": "stadiums",
    "TEXT": "texts",
    "IMAGE": "images",
}


def _vertices(stream: str, field: str, values: Any, least: int) -> np.ndarray:
    """``values`` as a float32 (N, 3) array of at least ``least`` finite points."""
    array = np.asarray(values, dtype=np.float32)
    if array.ndim != 2 or array.shape[1] != 3:
        raise BuilderError(f"{stream}: {field} must be (N, 3) x, y, z rows, not shape {array.shape}")
    if len(array) < least:
        raise BuilderError(f"{stream}: {field} needs at least {least} vertices, got {len(array)}")
    if not np.isfinite(array).all():
        raise BuilderError(f"{stream}: {field} holds a non-finite coordinate")
    return array


def _point(stream: str, field: str, value: Any) -> list[float]:
    array = _vertices(stream, field, [value], 1)
    return array[0].astype(np.float64).tolist()


def _colors(stream: str, colors: Any, count: int) -> np.ndarray:
    array = np.asarray(colors)
    if array.ndim != 2 or array.shape[1] not in (3, 4) or len(array) != count:
        raise BuilderError(f"{stream}: colors must be ({count}, 3) or ({count}, 4) RGB(A) rows, not shape {array.shape}")
    if array.dtype != np.uint8:
        if not np.issubdtype(array.dtype, np.number) or array.min(initial=0) < 0 or array.max(initial=0) > 255:
            raise BuilderError(f"{stream}: colors are 0-255 integers")
        array = array.astype(np.uint8)
    return array


def _base(stream: str, object_id: str | None, classes: Sequence[str] | None, style: Mapping[str, Any] | None) -> dict[str, Any]:
    base: dict[str, Any] = {}
    if object_id is not None:
        base["object_id"] = str(object_id)
    if classes:
        base["classes"] = [str(name) for name in classes]
    if style:
        if problems := get_validator().errors("style/object_value", dict(style)):
            raise BuilderError(f"{stream}: style {'; '.join(problems)}")
        base["style"] = dict(style)
    return base


class FrameBuilder:
    """Collects the streams of one frame and builds its ``xviz/state_update`` data.

    It knows the log's metadata, so a stream that is not declared there, or
    declared as something else, is refused at once::

        frame = FrameBuilder(metadata)
        frame.pose("/vehicle_pose", 1317042145.96, map_origin=(8.43, 49.01, 116.4),
                   orientation=(0.03, 0.01, -2.6))
        frame.points("/lidar/points", points, colors)
        frame.polygon("/objects", footprint, id="car-1", classes=["Car"])
        frame.time_series("/vehicle/velocity", 1317042145.96, 13.2)
        update = frame.build()

    Arrays stay numpy (float32 positions, uint8 colours), so that the GLB
    encoder moves them into the binary chunk without copying. After
    :meth:`build` the builder is empty, ready for the next frame.
    """

    def __init__(self, metadata: Mapping[str, Any]) -> None:
        self._streams: Mapping[str, Mapping[str, Any]] = metadata.get("streams") or {}
        self._reset()

    def _reset(self) -> None:
        self._poses: dict[str, dict[str, Any]] = {}
        self._primitives: dict[str, dict[str, list[Any]]] = {}
        self._futures: dict[str, dict[str, Any]] = {}
        self._series: dict[tuple[float, str, str | None], dict[str, Any]] = {}
        self._variables: dict[str, list[dict[str, Any]]] = defaultdict(list)
        self._annotations: dict[str, list[dict[str, Any]]] = defaultdict(list)
        self._ui: dict[str, dict[str, Any]] = {}

    def _declared(self, stream: str, category: str, kind: str | None = None) -> Mapping[str, Any]:
        entry = self._streams.get(stream)
        if entry is None:
            raise BuilderError(f"{stream}: stream not declared in the metadata")
        if entry.get("category") != category:
            raise BuilderError(f"{stream}: declared as {entry.get('category')}, not {category}")
        declared = entry.get("primitive_type") if category in ("PRIMITIVE", "FUTURE_INSTANCE") else None
        if kind is not None and declared is not None and declared != kind:
            raise BuilderError(f"{stream}: declared as {declared} primitives, not {kind}")
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
        """Where the vehicle is: ``map_origin`` (longitude, latitude, altitude), ``position``
        (metres from it) and ``orientation`` (roll, pitch, yaw, radians)."""
        self._declared(stream, "POSE")
        pose: dict[str, Any] = {"timestamp": float(timestamp)}
        if map_origin is not None:
            longitude, latitude, altitude = (float(v) for v in map_origin)
            if not (-180 <= longitude <= 180 and -90 <= latitude <= 90):
                raise BuilderError(f"{stream}: map_origin ({longitude}, {latitude}) is not a longitude, latitude")
            pose["map_origin"] = {"longitude": longitude, "latitude": latitude, "altitude": altitude}
        pose["position"] = _point(stream, "position", position)
        pose["orientation"] = _point(stream, "orientation", orientation)
        self._poses[stream] = pose
        return self

    # -- primitives -------------------------------------------------------

    def _add(self, stream: str, kind: str, primitive: dict[str, Any]) -> FrameBuilder:
        self._primitives.setdefault(stream, {}).setdefault(_PRIMITIVE_KEYS[kind], []).append(primitive)
        return self

    @staticmethod
    def _with_base(primitive: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
        if base:
            primitive["base"] = base
        return primitive

    def points(
        self,
        stream: str,
        points: Any,
        colors: Any = None,
        *,
        id: str | None = None,
        classes: Sequence[str] | None = None,
        style: Mapping[str, Any] | None = None,
    ) -> FrameBuilder:
        """A point cloud: (N, 3) positions and optional (N, 3|4) uint8 colours."""
        self._declared(stream, "PRIMITIVE", "POINT")
        positions = _vertices(stream, "points", points, 1)
        primitive: dict[str, Any] = {"points": positions}
        if colors is not None:
            primitive["colors"] = _colors(stream, colors, len(positions))
        return self._add(stream, "POINT", self._with_base(primitive, _base(stream, id, classes, style)))

    def polygon(self, stream: str, vertices: Any, *, id: str | None = None, classes: Sequence[str] | None = None,
                style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """A polygon: at least 3 vertices (the stream style may extrude it)."""
        self._declared(stream, "PRIMITIVE", "POLYGON")
        primitive = {"vertices": _vertices(stream, "polygon", vertices, 3)}
        return self._add(stream, "POLYGON", self._with_base(primitive, _base(stream, id, classes, style)))

    def polyline(self, stream: str, vertices: Any, *, id: str | None = None, classes: Sequence[str] | None = None,
                 style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """A polyline: at least 2 vertices."""
        self._declared(stream, "PRIMITIVE", "POLYLINE")
        primitive = {"vertices": _vertices(stream, "polyline", vertices, 2)}
        return self._add(stream, "POLYLINE", self._with_base(primitive, _base(stream, id, classes, style)))

    def circle(self, stream: str, center: Sequence[float], radius: float, *, id: str | None = None,
               classes: Sequence[str] | None = None, style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """A circle of ``radius`` metres around ``center``."""
        self._declared(stream, "PRIMITIVE", "CIRCLE")
        primitive = {"center": _point(stream, "center", center), "radius": self._radius(stream, radius)}
        return self._add(stream, "CIRCLE", self._with_base(primitive, _base(stream, id, classes, style)))

    def stadium(self, stream: str, start: Sequence[float], end: Sequence[float], radius: float, *,
                id: str | None = None, classes: Sequence[str] | None = None,
                style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """A stadium (a thick segment with round ends) from ``start`` to ``end``."""
        self._declared(stream, "PRIMITIVE", "STADIUM")
        primitive = {"start": _point(stream, "start", start), "end": _point(stream, "end", end),
                     "radius": self._radius(stream, radius)}
        return self._add(stream, "STADIUM", self._with_base(primitive, _base(stream, id, classes, style)))

    def text(self, stream: str, position: Sequence[float], text: str, *, id: str | None = None,
             classes: Sequence[str] | None = None, style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """A label at ``position``."""
        self._declared(stream, "PRIMITIVE", "TEXT")
        primitive = {"position": _point(stream, "position", position), "text": str(text)}
        return self._add(stream, "TEXT", self._with_base(primitive, _base(stream, id, classes, style)))

    def image(self, stream: str, data: bytes, *, width_px: int | None = None, height_px: int | None = None,
              id: str | None = None) -> FrameBuilder:
        """An encoded image (PNG, JPEG...); its size is read from its header when not given."""
        self._declared(stream, "PRIMITIVE", "IMAGE")
        if not isinstance(data, (bytes, bytearray, memoryview)) or not len(data):
            raise BuilderError(f"{stream}: image data must be the bytes of an encoded image")
        if width_px is None or height_px is None:
            info = sniff_image(data)
            if info is None:
                raise BuilderError(f"{stream}: image is not PNG, JPEG, GIF or BMP; give width_px and height_px")
            width_px, height_px = info.width, info.height
        primitive = {"data": data, "width_px": int(width_px), "height_px": int(height_px)}
        return self._add(stream, "IMAGE", self._with_base(primitive, _base(stream, id, None, None)))

    @staticmethod
    def _radius(stream: str, radius: float) -> float:
        if not (np.isfinite(radius) and radius >= 0):
            raise BuilderError(f"{stream}: radius must be a finite number >= 0, not {radius!r}")
        return float(radius)

    def future_instances(self, stream: str, timestamps: Sequence[float], instances: Sequence[Sequence[Any]]) -> FrameBuilder:
        """Predicted geometry: ``instances[i]`` lists the vertex arrays expected at ``timestamps[i]``."""
        entry = self._declared(stream, "FUTURE_INSTANCE")
        kind = entry.get("primitive_type")
        if kind not in ("POLYGON", "POLYLINE"):
            raise BuilderError(f"{stream}: future instances are built for POLYGON or POLYLINE streams, not {kind}")
        if len(timestamps) != len(instances) or not timestamps:
            raise BuilderError(f"{stream}: future instances need one list of shapes per timestamp")
        least = 3 if kind == "POLYGON" else 2
        key = _PRIMITIVE_KEYS[kind]
        states = [{key: [{"vertices": _vertices(stream, kind.lower(), shape, least)} for shape in shapes]} for shapes in instances]
        self._futures[stream] = {"timestamps": [float(t) for t in timestamps], "primitives": states}
        return self

    # -- values -----------------------------------------------------------

    def _value_kind(self, stream: str, category: str, value: Any) -> str:
        scalar = self._declared(stream, category).get("scalar_type")
        kind = _VALUE_KINDS[scalar]
        valid = {
            "doubles": isinstance(value, (int, float, np.number)) and not isinstance(value, (bool, np.bool_)),
            "int32s": isinstance(value, (int, np.integer)) and not isinstance(value, bool),
            "strings": isinstance(value, str),
            "bools": isinstance(value, (bool, np.bool_)),
        }[kind]
        if not valid:
            raise BuilderError(f"{stream}: a {scalar} stream cannot take {value!r}")
        return kind

    def time_series(self, stream: str, timestamp: float, value: Any, *, id: str | None = None) -> FrameBuilder:
        """One value of a time series; values of one time, kind and object share an entry."""
        kind = self._value_kind(stream, "TIME_SERIES", value)
        key = (float(timestamp), kind, id)
        entry = self._series.get(key)
        if entry is None:
            entry = self._series[key] = {"timestamp": float(timestamp), "streams": [], "values": {kind: []}}
            if id is not None:
                entry["object_id"] = str(id)
        entry["streams"].append(stream)
        entry["values"][kind].append(value.item() if isinstance(value, np.generic) else value)
        return self

    def variable(self, stream: str, values: Sequence[Any], *, id: str | None = None) -> FrameBuilder:
        """A list of values (a plan, a profile), optionally of one object."""
        values = list(values)
        kinds = {self._value_kind(stream, "VARIABLE", value) for value in values} or {self._value_kind(stream, "VARIABLE", 0.0)}
        variable: dict[str, Any] = {"values": {kinds.pop(): [v.item() if isinstance(v, np.generic) else v for v in values]}}
        if id is not None:
            variable["base"] = {"object_id": str(id)}
        self._variables[stream].append(variable)
        return self

    def annotation(self, stream: str, object_id: str, *, style_classes: Sequence[str] | None = None,
                   inline_style: Mapping[str, Any] | None = None) -> FrameBuilder:
        """Restyle an object of another stream: by class, inline, or both."""
        self._declared(stream, "ANNOTATION")
        if not style_classes and not inline_style:
            raise BuilderError(f"{stream}: an annotation needs style_classes or inline_style")
        visual: dict[str, Any] = {"base": {"object_id": str(object_id)}}
        if style_classes:
            visual["style_classes"] = list(style_classes)
        if inline_style:
            visual["inline_style"] = _base(stream, None, None, inline_style)["style"]
        self._annotations[stream].append(visual)
        return self

    def treetable(self, stream: str, columns: Sequence[tuple[str, str] | tuple[str, str, str]],
                  nodes: Sequence[tuple[int, int | None, Sequence[Any]]]) -> FrameBuilder:
        """A tree table: ``columns`` of (title, type[, unit]) and ``nodes`` of (id, parent, values)."""
        self._declared(stream, "UI_PRIMITIVE")
        table = {
            "columns": [
                {"display_text": c[0], "type": c[1], **({"unit": c[2]} if len(c) > 2 else {})} for c in columns
            ],
            "nodes": [],
        }
        for node_id, parent, values in nodes:
            if len(values) != len(columns):
                raise BuilderError(f"{stream}: node {node_id} has {len(values)} values for {len(columns)} columns")
            node: dict[str, Any] = {"id": int(node_id), "column_values": [str(v) for v in values]}
            if parent is not None:
                node["parent"] = int(parent)
            table["nodes"].append(node)
        if problems := get_validator().errors("ui-primitives/treetable", table):
            raise BuilderError(f"{stream}: {'; '.join(problems)}")
        self._ui[stream] = {"treetable": table}
        return self

    # -- the frame --------------------------------------------------------

    def build(self, timestamp: float | None = None, update_type: str = "SNAPSHOT") -> dict[str, Any]:
        """The data of the ``xviz/state_update`` message; the builder starts over empty.

        ``timestamp`` defaults to that of the (first) pose.
        """
        if timestamp is None:
            if not self._poses:
                raise BuilderError("frame: give a timestamp or a pose")
            timestamp = next(iter(self._poses.values()))["timestamp"]
        stream_set: dict[str, Any] = {"timestamp": float(timestamp)}
        if self._poses:
            stream_set["poses"] = self._poses
        if self._primitives:
            stream_set["primitives"] = self._primitives
        if self._futures:
            stream_set["future_instances"] = self._futures
        if self._series:
            stream_set["time_series"] = list(self._series.values())
        if self._variables:
            stream_set["variables"] = {name: {"variables": v} for name, v in self._variables.items()}
        if self._annotations:
            stream_set["annotations"] = {name: {"visuals": v} for name, v in self._annotations.items()}
        if self._ui:
            stream_set["ui_primitives"] = self._ui
        if len(stream_set) == 1:
            raise BuilderError("frame: nothing was added")
        self._reset()
        return {"update_type": update_type, "updates": [stream_set]}
