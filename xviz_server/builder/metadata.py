"""Build the metadata of a log: its streams, styles, time span, cameras and UI panels."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from ..exceptions import BuilderError
from ..messages import XVIZ_VERSION
from ..validation import get_validator
from .styles import check_style

__all__ = ["MetadataBuilder"]

#: The protocol version the builder writes; without it clients fall back to XVIZ v1.

# Which categories each optional field of a stream belongs to.
_GEOMETRY = ("PRIMITIVE", "FUTURE_INSTANCE")
_FIELD_CATEGORIES = {
    "primitive_type": _GEOMETRY,
    "scalar_type": ("TIME_SERIES", "VARIABLE"),
    "ui_primitive_type": ("UI_PRIMITIVE",),
    "annotation_type": ("ANNOTATION",),
    "units": ("TIME_SERIES", "VARIABLE"),
    "coordinate": _GEOMETRY,
    "transform": _GEOMETRY,
    "transform_callback": _GEOMETRY,
    "style": _GEOMETRY,
    "style_classes": _GEOMETRY,
}
_TYPE_FIELD = {
    "PRIMITIVE": "primitive_type",
    "FUTURE_INSTANCE": "primitive_type",
    "TIME_SERIES": "scalar_type",
    "VARIABLE": "scalar_type",
    "UI_PRIMITIVE": "ui_primitive_type",
    "ANNOTATION": "annotation_type",
}


@cache
def _choices(field: str) -> tuple[str, ...]:
    """The values the schema allows for a field of a stream's metadata."""
    path = resources.files("xviz_server.schema") / "session" / "stream_metadata.json"
    return tuple(json.loads(path.read_text("utf-8"))["properties"][field]["enum"])


def _one_of(where: str, field: str, value: Any) -> str:
    if value not in _choices(field):
        raise BuilderError(f"{where}: {field} {value!r} is not one of {', '.join(_choices(field))}")
    return value


def _finite_matrix(where: str, value: Any, shapes: Sequence[tuple[int, ...]]) -> np.ndarray:
    try:
        matrix = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BuilderError(f"{where}: {value!r} is not a matrix of numbers") from None
    if matrix.shape not in shapes:
        wanted = " or ".join(f"shape {shape}" for shape in shapes)
        raise BuilderError(f"{where} must have {wanted}, not {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise BuilderError(f"{where} holds a number that is not finite")
    return matrix


def _transform(where: str, transform: Any) -> list[float]:
    """A 4x4 affine transform as the 16 numbers XVIZ carries: column-major, translation at 12-14.

    A (4, 4) matrix is read as written on paper: rows, translation in the
    last column. Sixteen numbers are read as already column-major. Either
    way the bottom row must be ``0, 0, 0, 1``, which catches a matrix given
    in the other layout.
    """
    matrix = _finite_matrix(where, transform, [(4, 4), (16,)])
    columns = matrix.T.reshape(-1) if matrix.shape == (4, 4) else matrix
    if columns[[3, 7, 11, 15]].tolist() != [0.0, 0.0, 0.0, 1.0]:
        layout = (
            "rows with the translation in the last column"
            if matrix.shape == (4, 4)
            else ("column-major, the translation at positions 12-14")
        )
        raise BuilderError(
            f"{where}: the bottom row must be 0, 0, 0, 1; a {matrix.shape} transform is read as {layout}"
        )
    return columns.tolist()


class MetadataBuilder:
    """Declares the streams of a log and builds the data of its ``xviz/metadata`` message.

    Each declaration is checked at once, and a mistake raises
    :class:`~xviz_server.exceptions.BuilderError` naming the stream and the
    field::

        meta = MetadataBuilder()
        meta.log_info(start_time=100.0, end_time=160.0)
        meta.pose("/vehicle_pose")
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE",
                       transform=lidar_to_vehicle, style={"radius_pixels": 2})
        meta.primitive("/objects", "POLYGON", style={"extruded": True},
                       style_classes={"Car": {"fill_color": "#50B3FF80"}})
        meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
        metadata = meta.build()

    :meth:`stream` takes every field; :meth:`pose`, :meth:`primitive`,
    :meth:`future_instances`, :meth:`time_series`, :meth:`variable`,
    :meth:`annotation` and :meth:`ui_primitive` fill in the category.
    """

    def __init__(self) -> None:
        self._streams: dict[str, dict[str, Any]] = {}
        self._log_info: dict[str, Any] = {}
        self._cameras: dict[str, dict[str, Any]] = {}
        self._panels: dict[str, dict[str, Any]] = {}

    # -- streams ----------------------------------------------------------

    def stream(
        self,
        name: str,
        *,
        category: str,
        primitive_type: str | None = None,
        scalar_type: str | None = None,
        ui_primitive_type: str | None = None,
        annotation_type: str | None = None,
        units: str | None = None,
        coordinate: str | None = None,
        transform: Any = None,
        transform_callback: str | None = None,
        style: Mapping[str, Any] | None = None,
        style_classes: Mapping[str, Mapping[str, Any]] | None = None,
        source: str | None = None,
    ) -> MetadataBuilder:
        """Declare stream ``name`` (``/lidar/points``); each name is declared once.

        ``category`` is ``PRIMITIVE``, ``FUTURE_INSTANCE``, ``TIME_SERIES``,
        ``VARIABLE``, ``POSE``, ``ANNOTATION`` or ``UI_PRIMITIVE``, and the
        matching type field is required: ``primitive_type`` (``POINT``,
        ``POLYGON``, ``POLYLINE``, ``CIRCLE``, ``STADIUM``, ``TEXT``,
        ``IMAGE``), ``scalar_type`` (``FLOAT``, ``INT32``, ``STRING``,
        ``BOOL``), ``ui_primitive_type`` (``TREETABLE``) or
        ``annotation_type`` (``VISUAL``).

        Geometry streams (``PRIMITIVE``, ``FUTURE_INSTANCE``) may give
        ``coordinate`` (``IDENTITY``, the default, ``GEOGRAPHIC``,
        ``VEHICLE_RELATIVE`` or ``DYNAMIC`` with ``transform_callback``),
        ``transform`` (a 4x4 matrix, see below), ``style`` (the default style
        of every object) and ``style_classes`` (class name, or space-separated
        names, to the style of the objects that carry them; later classes
        win). Value streams may give ``units``.

        ``transform`` is a (4, 4) matrix written as on paper (translation in
        the last column) or 16 numbers already in XVIZ's column-major order
        (translation at 12-14).
        """
        if not isinstance(name, str) or not name.startswith("/"):
            raise BuilderError(f"{name!r}: stream names start with '/' (like '/lidar/points')")
        if name in self._streams:
            raise BuilderError(f"{name}: stream declared twice")
        entry: dict[str, Any] = {"category": _one_of(name, "category", category)}
        given = {
            "primitive_type": primitive_type,
            "scalar_type": scalar_type,
            "ui_primitive_type": ui_primitive_type,
            "annotation_type": annotation_type,
            "units": units,
            "coordinate": coordinate,
            "transform": transform,
            "transform_callback": transform_callback,
            "style": style,
            "style_classes": style_classes,
        }
        for field, value in given.items():
            if value is not None and category not in _FIELD_CATEGORIES[field]:
                categories = " and ".join(_FIELD_CATEGORIES[field])
                raise BuilderError(f"{name}: {field} is for {categories} streams, not {category}")
        type_field = _TYPE_FIELD.get(category)
        if type_field is not None:
            if given[type_field] is None:
                raise BuilderError(
                    f"{name}: a {category} stream needs {type_field} ({', '.join(_choices(type_field))})"
                )
            entry[type_field] = _one_of(name, type_field, given[type_field])
        if source is not None:
            entry["source"] = str(source)
        if units is not None:
            entry["units"] = str(units)
        if coordinate is not None:
            entry["coordinate"] = _one_of(name, "coordinate", coordinate)
        if (coordinate == "DYNAMIC") != (transform_callback is not None):
            raise BuilderError(f"{name}: transform_callback goes with coordinate DYNAMIC, and DYNAMIC needs one")
        if transform_callback is not None:
            entry["transform_callback"] = str(transform_callback)
        if transform is not None:
            entry["transform"] = _transform(f"{name}: transform", transform)
        if style is not None:
            entry["stream_style"] = check_style(f"{name}: style", style, primitive_type, per_object=False)
        if style_classes is not None:
            entry["style_classes"] = list(self._style_classes(name, primitive_type, style_classes))
        if problems := get_validator().errors("session/stream_metadata", entry):
            raise BuilderError(f"{name}: {'; '.join(problems)}")  # a gap in the checks above
        self._streams[name] = entry
        return self

    def pose(self, name: str) -> MetadataBuilder:
        """Declare a pose stream (``/vehicle_pose`` by convention): where the vehicle is."""
        return self.stream(name, category="POSE")

    def primitive(self, name: str, primitive_type: str, **fields: Any) -> MetadataBuilder:
        """Declare a geometry stream of ``primitive_type``; ``fields`` as in :meth:`stream`."""
        return self.stream(name, category="PRIMITIVE", primitive_type=primitive_type, **fields)

    def future_instances(self, name: str, primitive_type: str, **fields: Any) -> MetadataBuilder:
        """Declare a stream of predicted geometry of ``primitive_type``; ``fields`` as in :meth:`stream`."""
        return self.stream(name, category="FUTURE_INSTANCE", primitive_type=primitive_type, **fields)

    def time_series(self, name: str, scalar_type: str, *, units: str | None = None) -> MetadataBuilder:
        """Declare a time series: one ``FLOAT``, ``INT32``, ``STRING`` or ``BOOL`` value at a time."""
        return self.stream(name, category="TIME_SERIES", scalar_type=scalar_type, units=units)

    def variable(self, name: str, scalar_type: str, *, units: str | None = None) -> MetadataBuilder:
        """Declare a variable: a list of values per frame (a plan, a profile)."""
        return self.stream(name, category="VARIABLE", scalar_type=scalar_type, units=units)

    def annotation(self, name: str, annotation_type: str = "VISUAL") -> MetadataBuilder:
        """Declare a stream of annotations, which restyle objects of other streams."""
        return self.stream(name, category="ANNOTATION", annotation_type=annotation_type)

    def ui_primitive(self, name: str, ui_primitive_type: str = "TREETABLE") -> MetadataBuilder:
        """Declare a stream of UI data (tree tables) for the declarative UI."""
        return self.stream(name, category="UI_PRIMITIVE", ui_primitive_type=ui_primitive_type)

    # -- the rest of the metadata -----------------------------------------

    def log_info(
        self, *, start_time: float | None = None, end_time: float | None = None, **fields: Any
    ) -> MetadataBuilder:
        """Set the log's time span, in seconds like the frames' timestamps, and descriptive ``fields``.

        streetscape.gl needs both times (it seeks to ``start_time``); a
        server fills them in from the frames when a log lacks them.
        """
        for field, value in (("start_time", start_time), ("end_time", end_time)):
            if value is not None:
                if (
                    isinstance(value, bool)
                    or not isinstance(value, (int, float, np.number))
                    or not math.isfinite(value)
                ):
                    raise BuilderError(f"log_info: {field} must be a finite number of seconds, not {value!r}")
                fields[field] = float(value)
        info = {**self._log_info, **fields}
        if "start_time" in info and "end_time" in info and info["end_time"] < info["start_time"]:
            raise BuilderError(f"log_info: end_time {info['end_time']} is before start_time {info['start_time']}")
        if problems := get_validator().errors("session/log_info", info):
            raise BuilderError(f"log_info: {'; '.join(problems)}")
        self._log_info = info
        return self

    def camera(
        self,
        name: str,
        *,
        human_name: str | None = None,
        source: str = "",
        vehicle_position: Sequence[float] | None = None,
        vehicle_orientation: Any = None,
        pixel_width: int | None = None,
        pixel_height: int | None = None,
        rectification_projection: Any = None,
        gl_projection: Any = None,
    ) -> MetadataBuilder:
        """Declare a camera: where it sits on the vehicle, its resolution and projections.

        ``vehicle_position`` is (x, y, z) in metres, ``vehicle_orientation``
        and ``rectification_projection`` are 3x3 matrices and
        ``gl_projection`` a 4x4 one; matrices are written as rows.
        """
        where = f"camera {name!r}"
        camera: dict[str, Any] = {"human_name": human_name or name, "source": source}
        if vehicle_position is not None:
            camera["vehicle_position"] = _finite_matrix(f"{where}: vehicle_position", vehicle_position, [(3,)]).tolist()
        for field, value, shape in (
            ("vehicle_orientation", vehicle_orientation, (3, 3)),
            ("rectification_projection", rectification_projection, (3, 3)),
            ("gl_projection", gl_projection, (4, 4)),
        ):
            if value is not None:
                camera[field] = _finite_matrix(f"{where}: {field}", value, [shape]).tolist()
        if (pixel_width is None) != (pixel_height is None):
            raise BuilderError(f"{where}: give pixel_width and pixel_height together")
        if pixel_width is not None:
            camera["pixel_width"], camera["pixel_height"] = pixel_width, pixel_height
        if problems := get_validator().errors("session/camera_info", camera):
            raise BuilderError(f"{where}: {'; '.join(problems)}")
        self._cameras[name] = camera
        return self

    def ui_panel(self, panel: Mapping[str, Any], needed_streams: Sequence[str] | None = None) -> MetadataBuilder:
        """Add a declarative UI panel, made with :mod:`xviz_server.builder.ui`.

        The streams its components show must be declared by the time of
        :meth:`build`. ``needed_streams`` tells a server which streams the
        panel needs.
        """
        name = panel.get("name") if isinstance(panel, Mapping) else None
        if not isinstance(name, str) or not name:
            raise BuilderError("ui panel: make it with ui.panel(name, ...)")
        if name in self._panels:
            raise BuilderError(f"ui panel {name!r}: declared twice")
        info: dict[str, Any] = {"name": name, "config": dict(panel)}
        if needed_streams is not None:
            info["needed_streams"] = list(needed_streams)
        if problems := get_validator().errors("session/ui_panel_info", info):
            raise BuilderError(f"ui panel {name!r}: {'; '.join(problems)}")
        self._panels[name] = info
        return self

    def build(self) -> dict[str, Any]:
        """The data of the ``xviz/metadata`` message, a new dict on every call.

        Raises :class:`~xviz_server.exceptions.BuilderError` if a UI panel
        names a stream (or a video a camera) that was not declared.
        """
        self._check_panel_streams()
        metadata: dict[str, Any] = {"version": XVIZ_VERSION, "streams": copy.deepcopy(self._streams)}
        if self._log_info:
            metadata["log_info"] = copy.deepcopy(self._log_info)
        if self._cameras:
            metadata["cameras"] = copy.deepcopy(self._cameras)
        if self._panels:
            metadata["ui_config"] = copy.deepcopy(self._panels)
        return metadata

    # -- helpers ----------------------------------------------------------

    @staticmethod
    def _style_classes(
        name: str, primitive_type: str | None, style_classes: Mapping[str, Mapping[str, Any]]
    ) -> Iterator[dict[str, Any]]:
        if not isinstance(style_classes, Mapping):
            raise BuilderError(
                f"{name}: style_classes maps class names to styles, like {{'Car': {{'fill_color': '#f00'}}}}"
            )
        for selector, style in style_classes.items():
            if not isinstance(selector, str) or not selector.split():
                raise BuilderError(f"{name}: style_classes: {selector!r} is not a class name")
            where = f"{name}: style_classes[{selector!r}]"
            yield {"name": selector, "style": check_style(where, style, primitive_type, per_object=True)}

    def _check_panel_streams(self) -> None:
        for name, info in self._panels.items():
            for component, streams in _panel_references(info["config"]):
                known = self._cameras.keys() | self._streams.keys() if component["type"] == "VIDEO" else self._streams
                for stream in streams:
                    if stream not in known:
                        label = component.get("title") or component["type"]
                        raise BuilderError(f"ui panel {name!r}: {label} shows {stream}, which is not declared")


def _panel_references(element: Mapping[str, Any]) -> Iterator[tuple[Mapping[str, Any], list[str]]]:
    """Each component below ``element`` with the streams (or cameras) it shows."""
    for child in element.get("children", ()):
        if child["type"] == "CONTAINER":
            yield from _panel_references(child)
            continue
        streams = [*child.get("streams", ()), *child.get("dependentVariables", ()), *child.get("cameras", ())]
        streams += [child[key] for key in ("stream", "independentVariable") if key in child]
        streams += [region[key] for region in child.get("regions", ()) for key in ("x", "yMin", "yMax")]
        yield child, streams
