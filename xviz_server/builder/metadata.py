"""Build the metadata of a log: its streams, styles, cameras and UI panels."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..exceptions import BuilderError
from ..validation import get_validator

__all__ = ["MetadataBuilder", "XVIZ_VERSION"]

XVIZ_VERSION = "2.0.0"


def _problems(name: str, instance: Any) -> list[str]:
    return get_validator().errors(name, instance)


def _matrix4(stream: str, transform: Any) -> list[float]:
    """A 4x4 transform in the 16-number XVIZ order (column-major: translation at 12-14).

    A (4, 4) matrix is taken in the usual mathematical layout (translation in
    the last column); 16 numbers are taken as already in XVIZ order.
    """
    matrix = np.asarray(transform, dtype=np.float64)
    if matrix.shape == (4, 4):
        matrix = matrix.T
    elif matrix.shape != (16,):
        raise BuilderError(f"{stream}: transform must be a 4x4 matrix or 16 numbers, not shape {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise BuilderError(f"{stream}: transform holds a non-finite number")
    return matrix.reshape(-1).tolist()


class MetadataBuilder:
    """Collects the streams of a log and builds its ``xviz/metadata`` data.

    Every method checks its arguments against the XVIZ schema at once and
    raises :class:`~xviz_server.exceptions.BuilderError` naming the stream
    and the field, so a mistake shows where it is made::

        meta = MetadataBuilder()
        meta.pose("/vehicle_pose")
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE",
                       style={"radius_pixels": 2})
        meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
        metadata = meta.build()
    """

    def __init__(self) -> None:
        self._streams: dict[str, dict[str, Any]] = {}
        self._log_info: dict[str, Any] = {}
        self._cameras: dict[str, dict[str, Any]] = {}
        self._ui: dict[str, dict[str, Any]] = {}

    # -- streams ----------------------------------------------------------

    def pose(self, stream: str) -> MetadataBuilder:
        """Declare a pose stream (``/vehicle_pose`` by convention)."""
        return self._stream(stream, {"category": "POSE"})

    def primitive(
        self,
        stream: str,
        primitive_type: str,
        *,
        coordinate: str | None = None,
        transform: Any = None,
        style: Mapping[str, Any] | None = None,
        style_classes: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> MetadataBuilder:
        """Declare a stream of geometry: ``POINT``, ``POLYGON``, ``POLYLINE``, ``CIRCLE``,
        ``STADIUM``, ``TEXT`` or ``IMAGE``.

        ``coordinate`` is ``IDENTITY`` (default), ``GEOGRAPHIC``,
        ``VEHICLE_RELATIVE`` or ``DYNAMIC``; ``transform`` places
        ``VEHICLE_RELATIVE`` data; ``style`` applies to the whole stream and
        ``style_classes`` maps class names to the styles of objects that
        carry them.
        """
        entry = {"category": "PRIMITIVE", "primitive_type": primitive_type}
        return self._stream(stream, self._geometry(stream, entry, coordinate, transform, style, style_classes))

    def future_instances(
        self,
        stream: str,
        primitive_type: str,
        *,
        coordinate: str | None = None,
        transform: Any = None,
        style: Mapping[str, Any] | None = None,
        style_classes: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> MetadataBuilder:
        """Declare a stream of predicted geometry (future instances); arguments as :meth:`primitive`."""
        entry = {"category": "FUTURE_INSTANCE", "primitive_type": primitive_type}
        return self._stream(stream, self._geometry(stream, entry, coordinate, transform, style, style_classes))

    def time_series(self, stream: str, scalar_type: str, *, units: str | None = None) -> MetadataBuilder:
        """Declare a time series: one value (``FLOAT``, ``INT32``, ``STRING``, ``BOOL``) at a time."""
        return self._stream(stream, self._scalar("TIME_SERIES", scalar_type, units))

    def variable(self, stream: str, scalar_type: str, *, units: str | None = None) -> MetadataBuilder:
        """Declare a variable stream: lists of values (a plan, a profile)."""
        return self._stream(stream, self._scalar("VARIABLE", scalar_type, units))

    def ui_primitive(self, stream: str, ui_primitive_type: str = "TREETABLE") -> MetadataBuilder:
        """Declare a stream of UI data (tree tables)."""
        return self._stream(stream, {"category": "UI_PRIMITIVE", "ui_primitive_type": ui_primitive_type})

    def annotation(self, stream: str, annotation_type: str = "VISUAL") -> MetadataBuilder:
        """Declare a stream of annotations (restyling objects of other streams)."""
        return self._stream(stream, {"category": "ANNOTATION", "annotation_type": annotation_type})

    # -- the rest of the metadata -----------------------------------------

    def log_info(self, *, start_time: float | None = None, end_time: float | None = None, **extra: Any) -> MetadataBuilder:
        """Set the log's time span (seconds) and any descriptive fields."""
        info = {**extra, "start_time": start_time, "end_time": end_time}
        self._log_info.update({key: value for key, value in info.items() if value is not None})
        if problems := _problems("session/log_info", self._log_info):
            raise BuilderError(f"log_info: {'; '.join(problems)}")
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
    ) -> MetadataBuilder:
        """Declare a camera: its position and orientation (3x3) on the vehicle and its resolution."""
        camera: dict[str, Any] = {"human_name": human_name or name, "source": source}
        if vehicle_position is not None:
            camera["vehicle_position"] = [float(v) for v in vehicle_position]
        if vehicle_orientation is not None:
            camera["vehicle_orientation"] = np.asarray(vehicle_orientation, dtype=np.float64).reshape(-1).tolist()
        if pixel_width is not None:
            camera["pixel_width"] = pixel_width
        if pixel_height is not None:
            camera["pixel_height"] = pixel_height
        if problems := _problems("session/camera_info", camera):
            raise BuilderError(f"camera {name!r}: {'; '.join(problems)}")
        self._cameras[name] = camera
        return self

    def ui_panel(self, panel: Mapping[str, Any], needed_streams: Sequence[str] | None = None) -> MetadataBuilder:
        """Add a declarative UI panel (see :mod:`xviz_server.builder.ui`)."""
        name = panel.get("name", "")
        info: dict[str, Any] = {"name": name, "config": dict(panel)}
        if needed_streams:
            info["needed_streams"] = list(needed_streams)
        if problems := _problems("session/ui_panel_info", info):
            raise BuilderError(f"ui panel {name!r}: {'; '.join(problems)}")
        self._ui[name] = info
        return self

    def build(self) -> dict[str, Any]:
        """The data of the ``xviz/metadata`` message."""
        metadata: dict[str, Any] = {"version": XVIZ_VERSION, "streams": {k: dict(v) for k, v in self._streams.items()}}
        if self._log_info:
            metadata["log_info"] = dict(self._log_info)
        if self._cameras:
            metadata["cameras"] = dict(self._cameras)
        if self._ui:
            metadata["ui_config"] = dict(self._ui)
        return metadata

    # -- helpers ----------------------------------------------------------

    def _stream(self, stream: str, entry: dict[str, Any]) -> MetadataBuilder:
        if not stream.startswith("/"):
            raise BuilderError(f"{stream!r}: stream names start with '/' (like '/lidar/points')")
        if problems := _problems("session/stream_metadata", entry):
            raise BuilderError(f"{stream}: {'; '.join(problems)}")
        self._streams[stream] = entry
        return self

    @staticmethod
    def _scalar(category: str, scalar_type: str, units: str | None) -> dict[str, Any]:
        entry = {"category": category, "scalar_type": scalar_type}
        if units is not None:
            entry["units"] = units
        return entry

    @staticmethod
    def _geometry(
        stream: str,
        entry: dict[str, Any],
        coordinate: str | None,
        transform: Any,
        style: Mapping[str, Any] | None,
        style_classes: Mapping[str, Mapping[str, Any]] | None,
    ) -> dict[str, Any]:
        if coordinate is not None:
            entry["coordinate"] = coordinate
        if transform is not None:
            entry["transform"] = _matrix4(stream, transform)
        if style:
            entry["stream_style"] = dict(style)
        if style_classes:
            entry["style_classes"] = [{"name": name, "style": dict(value)} for name, value in style_classes.items()]
        return entry
