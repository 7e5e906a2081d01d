from collections.abc import Iterable as _Iterable
from collections.abc import Mapping as _Mapping
from typing import (
    ClassVar as _ClassVar,
)

from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper

DESCRIPTOR: _descriptor.FileDescriptor

class MatrixShape(_message.Message):
    __slots__ = ("dims",)
    DIMS_FIELD_NUMBER: _ClassVar[int]
    dims: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, dims: _Iterable[int] | None = ...) -> None: ...

class MatrixFloat(_message.Message):
    __slots__ = ("data", "shape")
    DATA_FIELD_NUMBER: _ClassVar[int]
    SHAPE_FIELD_NUMBER: _ClassVar[int]
    data: bytes
    shape: MatrixShape
    def __init__(self, data: bytes | None = ..., shape: MatrixShape | _Mapping | None = ...) -> None: ...

class CameraName(_message.Message):
    __slots__ = ()
    class Name(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        UNKNOWN: _ClassVar[CameraName.Name]
        FRONT: _ClassVar[CameraName.Name]
        FRONT_LEFT: _ClassVar[CameraName.Name]
        FRONT_RIGHT: _ClassVar[CameraName.Name]
        SIDE_LEFT: _ClassVar[CameraName.Name]
        SIDE_RIGHT: _ClassVar[CameraName.Name]

    UNKNOWN: CameraName.Name
    FRONT: CameraName.Name
    FRONT_LEFT: CameraName.Name
    FRONT_RIGHT: CameraName.Name
    SIDE_LEFT: CameraName.Name
    SIDE_RIGHT: CameraName.Name
    def __init__(self) -> None: ...

class LaserName(_message.Message):
    __slots__ = ()
    class Name(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        UNKNOWN: _ClassVar[LaserName.Name]
        TOP: _ClassVar[LaserName.Name]
        FRONT: _ClassVar[LaserName.Name]
        SIDE_LEFT: _ClassVar[LaserName.Name]
        SIDE_RIGHT: _ClassVar[LaserName.Name]
        REAR: _ClassVar[LaserName.Name]

    UNKNOWN: LaserName.Name
    TOP: LaserName.Name
    FRONT: LaserName.Name
    SIDE_LEFT: LaserName.Name
    SIDE_RIGHT: LaserName.Name
    REAR: LaserName.Name
    def __init__(self) -> None: ...

class Transform(_message.Message):
    __slots__ = ("transform",)
    TRANSFORM_FIELD_NUMBER: _ClassVar[int]
    transform: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, transform: _Iterable[float] | None = ...) -> None: ...

class LaserCalibration(_message.Message):
    __slots__ = ("name", "beam_inclinations", "beam_inclination_min", "beam_inclination_max", "extrinsic")
    NAME_FIELD_NUMBER: _ClassVar[int]
    BEAM_INCLINATIONS_FIELD_NUMBER: _ClassVar[int]
    BEAM_INCLINATION_MIN_FIELD_NUMBER: _ClassVar[int]
    BEAM_INCLINATION_MAX_FIELD_NUMBER: _ClassVar[int]
    EXTRINSIC_FIELD_NUMBER: _ClassVar[int]
    name: LaserName.Name
    beam_inclinations: _containers.RepeatedScalarFieldContainer[float]
    beam_inclination_min: float
    beam_inclination_max: float
    extrinsic: Transform
    def __init__(
        self,
        name: LaserName.Name | str | None = ...,
        beam_inclinations: _Iterable[float] | None = ...,
        beam_inclination_min: float | None = ...,
        beam_inclination_max: float | None = ...,
        extrinsic: Transform | _Mapping | None = ...,
    ) -> None: ...

class Context(_message.Message):
    __slots__ = ("name", "laser_calibrations")
    NAME_FIELD_NUMBER: _ClassVar[int]
    LASER_CALIBRATIONS_FIELD_NUMBER: _ClassVar[int]
    name: str
    laser_calibrations: _containers.RepeatedCompositeFieldContainer[LaserCalibration]
    def __init__(
        self,
        name: str | None = ...,
        laser_calibrations: _Iterable[LaserCalibration | _Mapping] | None = ...,
    ) -> None: ...

class RangeImage(_message.Message):
    __slots__ = ("range_image_compressed", "range_image_pose_compressed")
    RANGE_IMAGE_COMPRESSED_FIELD_NUMBER: _ClassVar[int]
    RANGE_IMAGE_POSE_COMPRESSED_FIELD_NUMBER: _ClassVar[int]
    range_image_compressed: bytes
    range_image_pose_compressed: bytes
    def __init__(
        self, range_image_compressed: bytes | None = ..., range_image_pose_compressed: bytes | None = ...
    ) -> None: ...

class CameraImage(_message.Message):
    __slots__ = ("name", "image")
    NAME_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    name: CameraName.Name
    image: bytes
    def __init__(self, name: CameraName.Name | str | None = ..., image: bytes | None = ...) -> None: ...

class Laser(_message.Message):
    __slots__ = ("name", "ri_return1", "ri_return2")
    NAME_FIELD_NUMBER: _ClassVar[int]
    RI_RETURN1_FIELD_NUMBER: _ClassVar[int]
    RI_RETURN2_FIELD_NUMBER: _ClassVar[int]
    name: LaserName.Name
    ri_return1: RangeImage
    ri_return2: RangeImage
    def __init__(
        self,
        name: LaserName.Name | str | None = ...,
        ri_return1: RangeImage | _Mapping | None = ...,
        ri_return2: RangeImage | _Mapping | None = ...,
    ) -> None: ...

class Label(_message.Message):
    __slots__ = ("box", "type", "id")
    class Type(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        TYPE_UNKNOWN: _ClassVar[Label.Type]
        TYPE_VEHICLE: _ClassVar[Label.Type]
        TYPE_PEDESTRIAN: _ClassVar[Label.Type]
        TYPE_SIGN: _ClassVar[Label.Type]
        TYPE_CYCLIST: _ClassVar[Label.Type]

    TYPE_UNKNOWN: Label.Type
    TYPE_VEHICLE: Label.Type
    TYPE_PEDESTRIAN: Label.Type
    TYPE_SIGN: Label.Type
    TYPE_CYCLIST: Label.Type
    class Box(_message.Message):
        __slots__ = ("center_x", "center_y", "center_z", "width", "length", "height", "heading")
        CENTER_X_FIELD_NUMBER: _ClassVar[int]
        CENTER_Y_FIELD_NUMBER: _ClassVar[int]
        CENTER_Z_FIELD_NUMBER: _ClassVar[int]
        WIDTH_FIELD_NUMBER: _ClassVar[int]
        LENGTH_FIELD_NUMBER: _ClassVar[int]
        HEIGHT_FIELD_NUMBER: _ClassVar[int]
        HEADING_FIELD_NUMBER: _ClassVar[int]
        center_x: float
        center_y: float
        center_z: float
        width: float
        length: float
        height: float
        heading: float
        def __init__(
            self,
            center_x: float | None = ...,
            center_y: float | None = ...,
            center_z: float | None = ...,
            width: float | None = ...,
            length: float | None = ...,
            height: float | None = ...,
            heading: float | None = ...,
        ) -> None: ...

    BOX_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    ID_FIELD_NUMBER: _ClassVar[int]
    box: Label.Box
    type: Label.Type
    id: str
    def __init__(
        self,
        box: Label.Box | _Mapping | None = ...,
        type: Label.Type | str | None = ...,
        id: str | None = ...,
    ) -> None: ...

class Frame(_message.Message):
    __slots__ = ("context", "timestamp_micros", "pose", "images", "lasers", "laser_labels")
    CONTEXT_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_MICROS_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    IMAGES_FIELD_NUMBER: _ClassVar[int]
    LASERS_FIELD_NUMBER: _ClassVar[int]
    LASER_LABELS_FIELD_NUMBER: _ClassVar[int]
    context: Context
    timestamp_micros: int
    pose: Transform
    images: _containers.RepeatedCompositeFieldContainer[CameraImage]
    lasers: _containers.RepeatedCompositeFieldContainer[Laser]
    laser_labels: _containers.RepeatedCompositeFieldContainer[Label]
    def __init__(
        self,
        context: Context | _Mapping | None = ...,
        timestamp_micros: int | None = ...,
        pose: Transform | _Mapping | None = ...,
        images: _Iterable[CameraImage | _Mapping] | None = ...,
        lasers: _Iterable[Laser | _Mapping] | None = ...,
        laser_labels: _Iterable[Label | _Mapping] | None = ...,
    ) -> None: ...
