from google.protobuf import any_pb2 as _any_pb2
from google.protobuf import struct_pb2 as _struct_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class TextAnchor(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TEXT_ANCHOR_INVALID: _ClassVar[TextAnchor]
    START: _ClassVar[TextAnchor]
    MIDDLE: _ClassVar[TextAnchor]
    END: _ClassVar[TextAnchor]

class TextAlignmentBaseline(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TEXT_ALIGNMENT_BASELINE_INVALID: _ClassVar[TextAlignmentBaseline]
    TOP: _ClassVar[TextAlignmentBaseline]
    CENTER: _ClassVar[TextAlignmentBaseline]
    BOTTOM: _ClassVar[TextAlignmentBaseline]

class PointColorMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    POINT_COLOR_MODE_INVALID: _ClassVar[PointColorMode]
    ELEVATION: _ClassVar[PointColorMode]
    DISTANCE_TO_VEHICLE: _ClassVar[PointColorMode]
TEXT_ANCHOR_INVALID: TextAnchor
START: TextAnchor
MIDDLE: TextAnchor
END: TextAnchor
TEXT_ALIGNMENT_BASELINE_INVALID: TextAlignmentBaseline
TOP: TextAlignmentBaseline
CENTER: TextAlignmentBaseline
BOTTOM: TextAlignmentBaseline
POINT_COLOR_MODE_INVALID: PointColorMode
ELEVATION: PointColorMode
DISTANCE_TO_VEHICLE: PointColorMode

class Envelope(_message.Message):
    __slots__ = ("type", "data")
    TYPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    type: str
    data: _any_pb2.Any
    def __init__(self, type: _Optional[str] = ..., data: _Optional[_Union[_any_pb2.Any, _Mapping]] = ...) -> None: ...

class MetadataEnvelope(_message.Message):
    __slots__ = ("type", "data")
    TYPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    type: str
    data: MetadataAny
    def __init__(self, type: _Optional[str] = ..., data: _Optional[_Union[MetadataAny, _Mapping]] = ...) -> None: ...

class MetadataAny(_message.Message):
    __slots__ = ("type_url", "value")
    TYPE_URL_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    type_url: str
    value: Metadata
    def __init__(self, type_url: _Optional[str] = ..., value: _Optional[_Union[Metadata, _Mapping]] = ...) -> None: ...

class StateUpdateEnvelope(_message.Message):
    __slots__ = ("type", "data")
    TYPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    type: str
    data: StateUpdateAny
    def __init__(self, type: _Optional[str] = ..., data: _Optional[_Union[StateUpdateAny, _Mapping]] = ...) -> None: ...

class StateUpdateAny(_message.Message):
    __slots__ = ("type_url", "value")
    TYPE_URL_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    type_url: str
    value: StateUpdate
    def __init__(self, type_url: _Optional[str] = ..., value: _Optional[_Union[StateUpdate, _Mapping]] = ...) -> None: ...

class StyleObjectValue(_message.Message):
    __slots__ = ("fill_color", "stroke_color", "stroke_width", "radius", "text_size", "text_rotation", "text_anchor", "text_baseline", "height")
    FILL_COLOR_FIELD_NUMBER: _ClassVar[int]
    STROKE_COLOR_FIELD_NUMBER: _ClassVar[int]
    STROKE_WIDTH_FIELD_NUMBER: _ClassVar[int]
    RADIUS_FIELD_NUMBER: _ClassVar[int]
    TEXT_SIZE_FIELD_NUMBER: _ClassVar[int]
    TEXT_ROTATION_FIELD_NUMBER: _ClassVar[int]
    TEXT_ANCHOR_FIELD_NUMBER: _ClassVar[int]
    TEXT_BASELINE_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    fill_color: bytes
    stroke_color: bytes
    stroke_width: float
    radius: float
    text_size: float
    text_rotation: float
    text_anchor: TextAnchor
    text_baseline: TextAlignmentBaseline
    height: float
    def __init__(self, fill_color: _Optional[bytes] = ..., stroke_color: _Optional[bytes] = ..., stroke_width: _Optional[float] = ..., radius: _Optional[float] = ..., text_size: _Optional[float] = ..., text_rotation: _Optional[float] = ..., text_anchor: _Optional[_Union[TextAnchor, str]] = ..., text_baseline: _Optional[_Union[TextAlignmentBaseline, str]] = ..., height: _Optional[float] = ...) -> None: ...

class StyleStreamValue(_message.Message):
    __slots__ = ("fill_color", "stroke_color", "stroke_width", "radius", "text_size", "text_rotation", "text_anchor", "text_baseline", "height", "radius_min_pixels", "radius_max_pixels", "stroke_width_min_pixels", "stroke_width_max_pixels", "opacity", "stroked", "filled", "extruded", "radius_pixels", "font_weight", "font_family", "point_color_mode", "point_color_domain")
    FILL_COLOR_FIELD_NUMBER: _ClassVar[int]
    STROKE_COLOR_FIELD_NUMBER: _ClassVar[int]
    STROKE_WIDTH_FIELD_NUMBER: _ClassVar[int]
    RADIUS_FIELD_NUMBER: _ClassVar[int]
    TEXT_SIZE_FIELD_NUMBER: _ClassVar[int]
    TEXT_ROTATION_FIELD_NUMBER: _ClassVar[int]
    TEXT_ANCHOR_FIELD_NUMBER: _ClassVar[int]
    TEXT_BASELINE_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    RADIUS_MIN_PIXELS_FIELD_NUMBER: _ClassVar[int]
    RADIUS_MAX_PIXELS_FIELD_NUMBER: _ClassVar[int]
    STROKE_WIDTH_MIN_PIXELS_FIELD_NUMBER: _ClassVar[int]
    STROKE_WIDTH_MAX_PIXELS_FIELD_NUMBER: _ClassVar[int]
    OPACITY_FIELD_NUMBER: _ClassVar[int]
    STROKED_FIELD_NUMBER: _ClassVar[int]
    FILLED_FIELD_NUMBER: _ClassVar[int]
    EXTRUDED_FIELD_NUMBER: _ClassVar[int]
    RADIUS_PIXELS_FIELD_NUMBER: _ClassVar[int]
    FONT_WEIGHT_FIELD_NUMBER: _ClassVar[int]
    FONT_FAMILY_FIELD_NUMBER: _ClassVar[int]
    POINT_COLOR_MODE_FIELD_NUMBER: _ClassVar[int]
    POINT_COLOR_DOMAIN_FIELD_NUMBER: _ClassVar[int]
    fill_color: bytes
    stroke_color: bytes
    stroke_width: float
    radius: float
    text_size: float
    text_rotation: float
    text_anchor: TextAnchor
    text_baseline: TextAlignmentBaseline
    height: float
    radius_min_pixels: int
    radius_max_pixels: int
    stroke_width_min_pixels: int
    stroke_width_max_pixels: int
    opacity: float
    stroked: bool
    filled: bool
    extruded: bool
    radius_pixels: int
    font_weight: int
    font_family: str
    point_color_mode: PointColorMode
    point_color_domain: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, fill_color: _Optional[bytes] = ..., stroke_color: _Optional[bytes] = ..., stroke_width: _Optional[float] = ..., radius: _Optional[float] = ..., text_size: _Optional[float] = ..., text_rotation: _Optional[float] = ..., text_anchor: _Optional[_Union[TextAnchor, str]] = ..., text_baseline: _Optional[_Union[TextAlignmentBaseline, str]] = ..., height: _Optional[float] = ..., radius_min_pixels: _Optional[int] = ..., radius_max_pixels: _Optional[int] = ..., stroke_width_min_pixels: _Optional[int] = ..., stroke_width_max_pixels: _Optional[int] = ..., opacity: _Optional[float] = ..., stroked: _Optional[bool] = ..., filled: _Optional[bool] = ..., extruded: _Optional[bool] = ..., radius_pixels: _Optional[int] = ..., font_weight: _Optional[int] = ..., font_family: _Optional[str] = ..., point_color_mode: _Optional[_Union[PointColorMode, str]] = ..., point_color_domain: _Optional[_Iterable[float]] = ...) -> None: ...

class StyleClass(_message.Message):
    __slots__ = ("name", "style")
    NAME_FIELD_NUMBER: _ClassVar[int]
    STYLE_FIELD_NUMBER: _ClassVar[int]
    name: str
    style: StyleObjectValue
    def __init__(self, name: _Optional[str] = ..., style: _Optional[_Union[StyleObjectValue, _Mapping]] = ...) -> None: ...

class PrimitiveBase(_message.Message):
    __slots__ = ("object_id", "classes", "style")
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    CLASSES_FIELD_NUMBER: _ClassVar[int]
    STYLE_FIELD_NUMBER: _ClassVar[int]
    object_id: str
    classes: _containers.RepeatedScalarFieldContainer[str]
    style: StyleObjectValue
    def __init__(self, object_id: _Optional[str] = ..., classes: _Optional[_Iterable[str]] = ..., style: _Optional[_Union[StyleObjectValue, _Mapping]] = ...) -> None: ...

class Circle(_message.Message):
    __slots__ = ("base", "center", "radius")
    BASE_FIELD_NUMBER: _ClassVar[int]
    CENTER_FIELD_NUMBER: _ClassVar[int]
    RADIUS_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    center: _containers.RepeatedScalarFieldContainer[float]
    radius: float
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., center: _Optional[_Iterable[float]] = ..., radius: _Optional[float] = ...) -> None: ...

class Image(_message.Message):
    __slots__ = ("base", "position", "data", "width_px", "height_px")
    BASE_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    WIDTH_PX_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_PX_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    position: _containers.RepeatedScalarFieldContainer[float]
    data: bytes
    width_px: int
    height_px: int
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., position: _Optional[_Iterable[float]] = ..., data: _Optional[bytes] = ..., width_px: _Optional[int] = ..., height_px: _Optional[int] = ...) -> None: ...

class Point(_message.Message):
    __slots__ = ("base", "points", "colors")
    BASE_FIELD_NUMBER: _ClassVar[int]
    POINTS_FIELD_NUMBER: _ClassVar[int]
    COLORS_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    points: _containers.RepeatedScalarFieldContainer[bytes]
    colors: bytes
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., points: _Optional[_Iterable[bytes]] = ..., colors: _Optional[bytes] = ...) -> None: ...

class Polygon(_message.Message):
    __slots__ = ("base", "vertices")
    BASE_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    vertices: _containers.RepeatedScalarFieldContainer[bytes]
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., vertices: _Optional[_Iterable[bytes]] = ...) -> None: ...

class Polyline(_message.Message):
    __slots__ = ("base", "vertices", "colors")
    BASE_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    COLORS_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    vertices: _containers.RepeatedScalarFieldContainer[bytes]
    colors: bytes
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., vertices: _Optional[_Iterable[bytes]] = ..., colors: _Optional[bytes] = ...) -> None: ...

class Stadium(_message.Message):
    __slots__ = ("base", "start", "end", "radius")
    BASE_FIELD_NUMBER: _ClassVar[int]
    START_FIELD_NUMBER: _ClassVar[int]
    END_FIELD_NUMBER: _ClassVar[int]
    RADIUS_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    start: _containers.RepeatedScalarFieldContainer[float]
    end: _containers.RepeatedScalarFieldContainer[float]
    radius: float
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., start: _Optional[_Iterable[float]] = ..., end: _Optional[_Iterable[float]] = ..., radius: _Optional[float] = ...) -> None: ...

class Text(_message.Message):
    __slots__ = ("base", "position", "text")
    BASE_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    TEXT_FIELD_NUMBER: _ClassVar[int]
    base: PrimitiveBase
    position: _containers.RepeatedScalarFieldContainer[float]
    text: str
    def __init__(self, base: _Optional[_Union[PrimitiveBase, _Mapping]] = ..., position: _Optional[_Iterable[float]] = ..., text: _Optional[str] = ...) -> None: ...

class TreeTableColumn(_message.Message):
    __slots__ = ("display_text", "type", "unit")
    class ColumnType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        TREE_TABLE_COLUMN_COLUMN_TYPE_INVALID: _ClassVar[TreeTableColumn.ColumnType]
        INT32: _ClassVar[TreeTableColumn.ColumnType]
        DOUBLE: _ClassVar[TreeTableColumn.ColumnType]
        STRING: _ClassVar[TreeTableColumn.ColumnType]
        BOOLEAN: _ClassVar[TreeTableColumn.ColumnType]
    TREE_TABLE_COLUMN_COLUMN_TYPE_INVALID: TreeTableColumn.ColumnType
    INT32: TreeTableColumn.ColumnType
    DOUBLE: TreeTableColumn.ColumnType
    STRING: TreeTableColumn.ColumnType
    BOOLEAN: TreeTableColumn.ColumnType
    DISPLAY_TEXT_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    UNIT_FIELD_NUMBER: _ClassVar[int]
    display_text: str
    type: TreeTableColumn.ColumnType
    unit: str
    def __init__(self, display_text: _Optional[str] = ..., type: _Optional[_Union[TreeTableColumn.ColumnType, str]] = ..., unit: _Optional[str] = ...) -> None: ...

class TreeTableNode(_message.Message):
    __slots__ = ("id", "parent", "column_values")
    ID_FIELD_NUMBER: _ClassVar[int]
    PARENT_FIELD_NUMBER: _ClassVar[int]
    COLUMN_VALUES_FIELD_NUMBER: _ClassVar[int]
    id: int
    parent: int
    column_values: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, id: _Optional[int] = ..., parent: _Optional[int] = ..., column_values: _Optional[_Iterable[str]] = ...) -> None: ...

class TreeTable(_message.Message):
    __slots__ = ("columns", "nodes")
    COLUMNS_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    columns: _containers.RepeatedCompositeFieldContainer[TreeTableColumn]
    nodes: _containers.RepeatedCompositeFieldContainer[TreeTableNode]
    def __init__(self, columns: _Optional[_Iterable[_Union[TreeTableColumn, _Mapping]]] = ..., nodes: _Optional[_Iterable[_Union[TreeTableNode, _Mapping]]] = ...) -> None: ...

class MapOrigin(_message.Message):
    __slots__ = ("longitude", "latitude", "altitude")
    LONGITUDE_FIELD_NUMBER: _ClassVar[int]
    LATITUDE_FIELD_NUMBER: _ClassVar[int]
    ALTITUDE_FIELD_NUMBER: _ClassVar[int]
    longitude: float
    latitude: float
    altitude: float
    def __init__(self, longitude: _Optional[float] = ..., latitude: _Optional[float] = ..., altitude: _Optional[float] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("timestamp", "map_origin", "position", "orientation")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    MAP_ORIGIN_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    timestamp: float
    map_origin: MapOrigin
    position: _containers.RepeatedScalarFieldContainer[float]
    orientation: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, timestamp: _Optional[float] = ..., map_origin: _Optional[_Union[MapOrigin, _Mapping]] = ..., position: _Optional[_Iterable[float]] = ..., orientation: _Optional[_Iterable[float]] = ...) -> None: ...

class PrimitiveState(_message.Message):
    __slots__ = ("polygons", "polylines", "texts", "circles", "points", "stadiums", "images")
    POLYGONS_FIELD_NUMBER: _ClassVar[int]
    POLYLINES_FIELD_NUMBER: _ClassVar[int]
    TEXTS_FIELD_NUMBER: _ClassVar[int]
    CIRCLES_FIELD_NUMBER: _ClassVar[int]
    POINTS_FIELD_NUMBER: _ClassVar[int]
    STADIUMS_FIELD_NUMBER: _ClassVar[int]
    IMAGES_FIELD_NUMBER: _ClassVar[int]
    polygons: _containers.RepeatedCompositeFieldContainer[Polygon]
    polylines: _containers.RepeatedCompositeFieldContainer[Polyline]
    texts: _containers.RepeatedCompositeFieldContainer[Text]
    circles: _containers.RepeatedCompositeFieldContainer[Circle]
    points: _containers.RepeatedCompositeFieldContainer[Point]
    stadiums: _containers.RepeatedCompositeFieldContainer[Stadium]
    images: _containers.RepeatedCompositeFieldContainer[Image]
    def __init__(self, polygons: _Optional[_Iterable[_Union[Polygon, _Mapping]]] = ..., polylines: _Optional[_Iterable[_Union[Polyline, _Mapping]]] = ..., texts: _Optional[_Iterable[_Union[Text, _Mapping]]] = ..., circles: _Optional[_Iterable[_Union[Circle, _Mapping]]] = ..., points: _Optional[_Iterable[_Union[Point, _Mapping]]] = ..., stadiums: _Optional[_Iterable[_Union[Stadium, _Mapping]]] = ..., images: _Optional[_Iterable[_Union[Image, _Mapping]]] = ...) -> None: ...

class UIPrimitiveState(_message.Message):
    __slots__ = ("treetable",)
    TREETABLE_FIELD_NUMBER: _ClassVar[int]
    treetable: TreeTable
    def __init__(self, treetable: _Optional[_Union[TreeTable, _Mapping]] = ...) -> None: ...

class Values(_message.Message):
    __slots__ = ("doubles", "int32s", "bools", "strings")
    DOUBLES_FIELD_NUMBER: _ClassVar[int]
    INT32S_FIELD_NUMBER: _ClassVar[int]
    BOOLS_FIELD_NUMBER: _ClassVar[int]
    STRINGS_FIELD_NUMBER: _ClassVar[int]
    doubles: _containers.RepeatedScalarFieldContainer[float]
    int32s: _containers.RepeatedScalarFieldContainer[int]
    bools: _containers.RepeatedScalarFieldContainer[bool]
    strings: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, doubles: _Optional[_Iterable[float]] = ..., int32s: _Optional[_Iterable[int]] = ..., bools: _Optional[_Iterable[bool]] = ..., strings: _Optional[_Iterable[str]] = ...) -> None: ...

class TimeSeriesState(_message.Message):
    __slots__ = ("timestamp", "object_id", "streams", "values")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    STREAMS_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    timestamp: float
    object_id: str
    streams: _containers.RepeatedScalarFieldContainer[str]
    values: Values
    def __init__(self, timestamp: _Optional[float] = ..., object_id: _Optional[str] = ..., streams: _Optional[_Iterable[str]] = ..., values: _Optional[_Union[Values, _Mapping]] = ...) -> None: ...

class FutureInstances(_message.Message):
    __slots__ = ("timestamps", "primitives")
    TIMESTAMPS_FIELD_NUMBER: _ClassVar[int]
    PRIMITIVES_FIELD_NUMBER: _ClassVar[int]
    timestamps: _containers.RepeatedScalarFieldContainer[float]
    primitives: _containers.RepeatedCompositeFieldContainer[PrimitiveState]
    def __init__(self, timestamps: _Optional[_Iterable[float]] = ..., primitives: _Optional[_Iterable[_Union[PrimitiveState, _Mapping]]] = ...) -> None: ...

class VariableBase(_message.Message):
    __slots__ = ("object_id",)
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    object_id: str
    def __init__(self, object_id: _Optional[str] = ...) -> None: ...

class Variable(_message.Message):
    __slots__ = ("base", "values")
    BASE_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    base: VariableBase
    values: Values
    def __init__(self, base: _Optional[_Union[VariableBase, _Mapping]] = ..., values: _Optional[_Union[Values, _Mapping]] = ...) -> None: ...

class VariableState(_message.Message):
    __slots__ = ("variables",)
    VARIABLES_FIELD_NUMBER: _ClassVar[int]
    variables: _containers.RepeatedCompositeFieldContainer[Variable]
    def __init__(self, variables: _Optional[_Iterable[_Union[Variable, _Mapping]]] = ...) -> None: ...

class VisualBase(_message.Message):
    __slots__ = ("object_id",)
    OBJECT_ID_FIELD_NUMBER: _ClassVar[int]
    object_id: str
    def __init__(self, object_id: _Optional[str] = ...) -> None: ...

class Visual(_message.Message):
    __slots__ = ("base", "style_classes", "inline_style")
    BASE_FIELD_NUMBER: _ClassVar[int]
    STYLE_CLASSES_FIELD_NUMBER: _ClassVar[int]
    INLINE_STYLE_FIELD_NUMBER: _ClassVar[int]
    base: VisualBase
    style_classes: _containers.RepeatedScalarFieldContainer[str]
    inline_style: StyleObjectValue
    def __init__(self, base: _Optional[_Union[VisualBase, _Mapping]] = ..., style_classes: _Optional[_Iterable[str]] = ..., inline_style: _Optional[_Union[StyleObjectValue, _Mapping]] = ...) -> None: ...

class AnnotationState(_message.Message):
    __slots__ = ("visuals",)
    VISUALS_FIELD_NUMBER: _ClassVar[int]
    visuals: _containers.RepeatedCompositeFieldContainer[Visual]
    def __init__(self, visuals: _Optional[_Iterable[_Union[Visual, _Mapping]]] = ...) -> None: ...

class Link(_message.Message):
    __slots__ = ("target_pose",)
    TARGET_POSE_FIELD_NUMBER: _ClassVar[int]
    target_pose: str
    def __init__(self, target_pose: _Optional[str] = ...) -> None: ...

class StreamSet(_message.Message):
    __slots__ = ("timestamp", "poses", "primitives", "time_series", "future_instances", "variables", "annotations", "ui_primitives", "no_data_streams", "links")
    class PosesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: Pose
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[Pose, _Mapping]] = ...) -> None: ...
    class PrimitivesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: PrimitiveState
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[PrimitiveState, _Mapping]] = ...) -> None: ...
    class FutureInstancesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: FutureInstances
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[FutureInstances, _Mapping]] = ...) -> None: ...
    class VariablesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: VariableState
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[VariableState, _Mapping]] = ...) -> None: ...
    class AnnotationsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: AnnotationState
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[AnnotationState, _Mapping]] = ...) -> None: ...
    class UiPrimitivesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: UIPrimitiveState
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[UIPrimitiveState, _Mapping]] = ...) -> None: ...
    class LinksEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: Link
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[Link, _Mapping]] = ...) -> None: ...
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    POSES_FIELD_NUMBER: _ClassVar[int]
    PRIMITIVES_FIELD_NUMBER: _ClassVar[int]
    TIME_SERIES_FIELD_NUMBER: _ClassVar[int]
    FUTURE_INSTANCES_FIELD_NUMBER: _ClassVar[int]
    VARIABLES_FIELD_NUMBER: _ClassVar[int]
    ANNOTATIONS_FIELD_NUMBER: _ClassVar[int]
    UI_PRIMITIVES_FIELD_NUMBER: _ClassVar[int]
    NO_DATA_STREAMS_FIELD_NUMBER: _ClassVar[int]
    LINKS_FIELD_NUMBER: _ClassVar[int]
    timestamp: float
    poses: _containers.MessageMap[str, Pose]
    primitives: _containers.MessageMap[str, PrimitiveState]
    time_series: _containers.RepeatedCompositeFieldContainer[TimeSeriesState]
    future_instances: _containers.MessageMap[str, FutureInstances]
    variables: _containers.MessageMap[str, VariableState]
    annotations: _containers.MessageMap[str, AnnotationState]
    ui_primitives: _containers.MessageMap[str, UIPrimitiveState]
    no_data_streams: _containers.RepeatedScalarFieldContainer[str]
    links: _containers.MessageMap[str, Link]
    def __init__(self, timestamp: _Optional[float] = ..., poses: _Optional[_Mapping[str, Pose]] = ..., primitives: _Optional[_Mapping[str, PrimitiveState]] = ..., time_series: _Optional[_Iterable[_Union[TimeSeriesState, _Mapping]]] = ..., future_instances: _Optional[_Mapping[str, FutureInstances]] = ..., variables: _Optional[_Mapping[str, VariableState]] = ..., annotations: _Optional[_Mapping[str, AnnotationState]] = ..., ui_primitives: _Optional[_Mapping[str, UIPrimitiveState]] = ..., no_data_streams: _Optional[_Iterable[str]] = ..., links: _Optional[_Mapping[str, Link]] = ...) -> None: ...

class StateUpdate(_message.Message):
    __slots__ = ("update_type", "updates")
    class UpdateType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STATE_UPDATE_UPDATE_TYPE_INVALID: _ClassVar[StateUpdate.UpdateType]
        SNAPSHOT: _ClassVar[StateUpdate.UpdateType]
        INCREMENTAL: _ClassVar[StateUpdate.UpdateType]
        COMPLETE_STATE: _ClassVar[StateUpdate.UpdateType]
        PERSISTENT: _ClassVar[StateUpdate.UpdateType]
    STATE_UPDATE_UPDATE_TYPE_INVALID: StateUpdate.UpdateType
    SNAPSHOT: StateUpdate.UpdateType
    INCREMENTAL: StateUpdate.UpdateType
    COMPLETE_STATE: StateUpdate.UpdateType
    PERSISTENT: StateUpdate.UpdateType
    UPDATE_TYPE_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    update_type: StateUpdate.UpdateType
    updates: _containers.RepeatedCompositeFieldContainer[StreamSet]
    def __init__(self, update_type: _Optional[_Union[StateUpdate.UpdateType, str]] = ..., updates: _Optional[_Iterable[_Union[StreamSet, _Mapping]]] = ...) -> None: ...

class StreamMetadata(_message.Message):
    __slots__ = ("source", "units", "category", "scalar_type", "primitive_type", "ui_primitive_type", "annotation_type", "stream_style", "style_classes", "coordinate", "transform", "transform_callback")
    class Category(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_CATEGORY_INVALID: _ClassVar[StreamMetadata.Category]
        PRIMITIVE: _ClassVar[StreamMetadata.Category]
        TIME_SERIES: _ClassVar[StreamMetadata.Category]
        VARIABLE: _ClassVar[StreamMetadata.Category]
        ANNOTATION: _ClassVar[StreamMetadata.Category]
        FUTURE_INSTANCE: _ClassVar[StreamMetadata.Category]
        POSE: _ClassVar[StreamMetadata.Category]
        UI_PRIMITIVE: _ClassVar[StreamMetadata.Category]
    STREAM_METADATA_CATEGORY_INVALID: StreamMetadata.Category
    PRIMITIVE: StreamMetadata.Category
    TIME_SERIES: StreamMetadata.Category
    VARIABLE: StreamMetadata.Category
    ANNOTATION: StreamMetadata.Category
    FUTURE_INSTANCE: StreamMetadata.Category
    POSE: StreamMetadata.Category
    UI_PRIMITIVE: StreamMetadata.Category
    class ScalarType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_SCALAR_TYPE_INVALID: _ClassVar[StreamMetadata.ScalarType]
        FLOAT: _ClassVar[StreamMetadata.ScalarType]
        INT32: _ClassVar[StreamMetadata.ScalarType]
        STRING: _ClassVar[StreamMetadata.ScalarType]
        BOOL: _ClassVar[StreamMetadata.ScalarType]
    STREAM_METADATA_SCALAR_TYPE_INVALID: StreamMetadata.ScalarType
    FLOAT: StreamMetadata.ScalarType
    INT32: StreamMetadata.ScalarType
    STRING: StreamMetadata.ScalarType
    BOOL: StreamMetadata.ScalarType
    class PrimitiveType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_PRIMITIVE_TYPE_INVALID: _ClassVar[StreamMetadata.PrimitiveType]
        CIRCLE: _ClassVar[StreamMetadata.PrimitiveType]
        IMAGE: _ClassVar[StreamMetadata.PrimitiveType]
        POINT: _ClassVar[StreamMetadata.PrimitiveType]
        POLYGON: _ClassVar[StreamMetadata.PrimitiveType]
        POLYLINE: _ClassVar[StreamMetadata.PrimitiveType]
        STADIUM: _ClassVar[StreamMetadata.PrimitiveType]
        TEXT: _ClassVar[StreamMetadata.PrimitiveType]
    STREAM_METADATA_PRIMITIVE_TYPE_INVALID: StreamMetadata.PrimitiveType
    CIRCLE: StreamMetadata.PrimitiveType
    IMAGE: StreamMetadata.PrimitiveType
    POINT: StreamMetadata.PrimitiveType
    POLYGON: StreamMetadata.PrimitiveType
    POLYLINE: StreamMetadata.PrimitiveType
    STADIUM: StreamMetadata.PrimitiveType
    TEXT: StreamMetadata.PrimitiveType
    class UIPrimitiveType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_UI_PRIMITIVE_TYPE_INVALID: _ClassVar[StreamMetadata.UIPrimitiveType]
        TREETABLE: _ClassVar[StreamMetadata.UIPrimitiveType]
    STREAM_METADATA_UI_PRIMITIVE_TYPE_INVALID: StreamMetadata.UIPrimitiveType
    TREETABLE: StreamMetadata.UIPrimitiveType
    class AnnotationType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_ANNOTATION_TYPE_INVALID: _ClassVar[StreamMetadata.AnnotationType]
        VISUAL: _ClassVar[StreamMetadata.AnnotationType]
    STREAM_METADATA_ANNOTATION_TYPE_INVALID: StreamMetadata.AnnotationType
    VISUAL: StreamMetadata.AnnotationType
    class CoordinateType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STREAM_METADATA_COORDINATE_TYPE_INVALID: _ClassVar[StreamMetadata.CoordinateType]
        GEOGRAPHIC: _ClassVar[StreamMetadata.CoordinateType]
        IDENTITY: _ClassVar[StreamMetadata.CoordinateType]
        DYNAMIC: _ClassVar[StreamMetadata.CoordinateType]
        VEHICLE_RELATIVE: _ClassVar[StreamMetadata.CoordinateType]
    STREAM_METADATA_COORDINATE_TYPE_INVALID: StreamMetadata.CoordinateType
    GEOGRAPHIC: StreamMetadata.CoordinateType
    IDENTITY: StreamMetadata.CoordinateType
    DYNAMIC: StreamMetadata.CoordinateType
    VEHICLE_RELATIVE: StreamMetadata.CoordinateType
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    UNITS_FIELD_NUMBER: _ClassVar[int]
    CATEGORY_FIELD_NUMBER: _ClassVar[int]
    SCALAR_TYPE_FIELD_NUMBER: _ClassVar[int]
    PRIMITIVE_TYPE_FIELD_NUMBER: _ClassVar[int]
    UI_PRIMITIVE_TYPE_FIELD_NUMBER: _ClassVar[int]
    ANNOTATION_TYPE_FIELD_NUMBER: _ClassVar[int]
    STREAM_STYLE_FIELD_NUMBER: _ClassVar[int]
    STYLE_CLASSES_FIELD_NUMBER: _ClassVar[int]
    COORDINATE_FIELD_NUMBER: _ClassVar[int]
    TRANSFORM_FIELD_NUMBER: _ClassVar[int]
    TRANSFORM_CALLBACK_FIELD_NUMBER: _ClassVar[int]
    source: str
    units: str
    category: StreamMetadata.Category
    scalar_type: StreamMetadata.ScalarType
    primitive_type: StreamMetadata.PrimitiveType
    ui_primitive_type: StreamMetadata.UIPrimitiveType
    annotation_type: StreamMetadata.AnnotationType
    stream_style: StyleStreamValue
    style_classes: _containers.RepeatedCompositeFieldContainer[StyleClass]
    coordinate: StreamMetadata.CoordinateType
    transform: _containers.RepeatedScalarFieldContainer[float]
    transform_callback: str
    def __init__(self, source: _Optional[str] = ..., units: _Optional[str] = ..., category: _Optional[_Union[StreamMetadata.Category, str]] = ..., scalar_type: _Optional[_Union[StreamMetadata.ScalarType, str]] = ..., primitive_type: _Optional[_Union[StreamMetadata.PrimitiveType, str]] = ..., ui_primitive_type: _Optional[_Union[StreamMetadata.UIPrimitiveType, str]] = ..., annotation_type: _Optional[_Union[StreamMetadata.AnnotationType, str]] = ..., stream_style: _Optional[_Union[StyleStreamValue, _Mapping]] = ..., style_classes: _Optional[_Iterable[_Union[StyleClass, _Mapping]]] = ..., coordinate: _Optional[_Union[StreamMetadata.CoordinateType, str]] = ..., transform: _Optional[_Iterable[float]] = ..., transform_callback: _Optional[str] = ...) -> None: ...

class CameraInfo(_message.Message):
    __slots__ = ("human_name", "source", "vehicle_position", "vehicle_orientation", "pixel_width", "pixel_height", "rectification_projection", "gl_projection")
    HUMAN_NAME_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    VEHICLE_POSITION_FIELD_NUMBER: _ClassVar[int]
    VEHICLE_ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    PIXEL_WIDTH_FIELD_NUMBER: _ClassVar[int]
    PIXEL_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    RECTIFICATION_PROJECTION_FIELD_NUMBER: _ClassVar[int]
    GL_PROJECTION_FIELD_NUMBER: _ClassVar[int]
    human_name: str
    source: str
    vehicle_position: _containers.RepeatedScalarFieldContainer[float]
    vehicle_orientation: _containers.RepeatedScalarFieldContainer[float]
    pixel_width: float
    pixel_height: float
    rectification_projection: _containers.RepeatedScalarFieldContainer[float]
    gl_projection: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, human_name: _Optional[str] = ..., source: _Optional[str] = ..., vehicle_position: _Optional[_Iterable[float]] = ..., vehicle_orientation: _Optional[_Iterable[float]] = ..., pixel_width: _Optional[float] = ..., pixel_height: _Optional[float] = ..., rectification_projection: _Optional[_Iterable[float]] = ..., gl_projection: _Optional[_Iterable[float]] = ...) -> None: ...

class UIPanelInfo(_message.Message):
    __slots__ = ("name", "needed_streams", "config")
    NAME_FIELD_NUMBER: _ClassVar[int]
    NEEDED_STREAMS_FIELD_NUMBER: _ClassVar[int]
    CONFIG_FIELD_NUMBER: _ClassVar[int]
    name: str
    needed_streams: _containers.RepeatedScalarFieldContainer[str]
    config: _struct_pb2.Struct
    def __init__(self, name: _Optional[str] = ..., needed_streams: _Optional[_Iterable[str]] = ..., config: _Optional[_Union[_struct_pb2.Struct, _Mapping]] = ...) -> None: ...

class LogInfo(_message.Message):
    __slots__ = ("start_time", "end_time")
    START_TIME_FIELD_NUMBER: _ClassVar[int]
    END_TIME_FIELD_NUMBER: _ClassVar[int]
    start_time: float
    end_time: float
    def __init__(self, start_time: _Optional[float] = ..., end_time: _Optional[float] = ...) -> None: ...

class Metadata(_message.Message):
    __slots__ = ("version", "streams", "cameras", "stream_aliases", "ui_config", "log_info")
    class StreamsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: StreamMetadata
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[StreamMetadata, _Mapping]] = ...) -> None: ...
    class CamerasEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: CameraInfo
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[CameraInfo, _Mapping]] = ...) -> None: ...
    class StreamAliasesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    class UiConfigEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: UIPanelInfo
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[UIPanelInfo, _Mapping]] = ...) -> None: ...
    VERSION_FIELD_NUMBER: _ClassVar[int]
    STREAMS_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    STREAM_ALIASES_FIELD_NUMBER: _ClassVar[int]
    UI_CONFIG_FIELD_NUMBER: _ClassVar[int]
    LOG_INFO_FIELD_NUMBER: _ClassVar[int]
    version: str
    streams: _containers.MessageMap[str, StreamMetadata]
    cameras: _containers.MessageMap[str, CameraInfo]
    stream_aliases: _containers.ScalarMap[str, str]
    ui_config: _containers.MessageMap[str, UIPanelInfo]
    log_info: LogInfo
    def __init__(self, version: _Optional[str] = ..., streams: _Optional[_Mapping[str, StreamMetadata]] = ..., cameras: _Optional[_Mapping[str, CameraInfo]] = ..., stream_aliases: _Optional[_Mapping[str, str]] = ..., ui_config: _Optional[_Mapping[str, UIPanelInfo]] = ..., log_info: _Optional[_Union[LogInfo, _Mapping]] = ...) -> None: ...
