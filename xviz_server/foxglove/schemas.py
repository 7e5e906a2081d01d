"""The schemas a Foxglove channel advertises: Foxglove's well-known protobuf messages, and JSON Schema.

A protobuf channel advertises its message's ``.proto`` file and every file
it imports, as one serialized ``FileDescriptorSet`` in base64 (schema
encoding ``protobuf``), which is what Foxglove and Lichtblick decode with.
The message classes come from the published ``foxglove-schemas-protobuf``
package.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from functools import cache
from typing import Any

import orjson
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.descriptor_pb2 import FileDescriptorProto, FileDescriptorSet
from google.protobuf.message import Message

__all__ = ["Schema", "protobuf_schema", "json_schema", "WELL_KNOWN"]


@dataclass(frozen=True)
class Schema:
    """What a channel advertises about its messages."""

    encoding: str  #: the message encoding: ``protobuf`` or ``json``; an original topic's: ``ros1``, ``cdr``
    name: str  #: the schema's name: ``foxglove.PointCloud``, the stream's name for JSON, the message type for ROS
    schema_encoding: str  #: ``protobuf`` or ``jsonschema``; ``ros1msg``, ``ros2msg`` or ``ros2idl``
    schema: str  #: base64 ``FileDescriptorSet``, JSON Schema text, or the message definition text

    def data(self) -> bytes:
        """The schema as a file records it (an MCAP schema record, the SDK's ``Schema.data``): bytes, not base64."""
        return base64.b64decode(self.schema) if self.schema_encoding == "protobuf" else self.schema.encode()


#: The Foxglove messages this server converts XVIZ streams into, by their short name.
WELL_KNOWN: dict[str, type[Message]] = {
    cls.DESCRIPTOR.name: cls
    for cls in (PointCloud, CompressedImage, FrameTransform, PoseInFrame, SceneUpdate, LocationFix)
}


@cache
def protobuf_schema(name: str) -> Schema:
    """The schema of the well-known message ``name`` (``"PointCloud"``)."""
    descriptor = WELL_KNOWN[name].DESCRIPTOR
    files = FileDescriptorSet()
    seen: set[str] = set()

    def add(file: Any) -> None:  # a FileDescriptor, from Python or upb
        if file.name in seen:
            return
        seen.add(file.name)
        for dependency in file.dependencies:
            add(dependency)
        proto = FileDescriptorProto()
        file.CopyToProto(proto)
        files.file.append(proto)

    add(descriptor.file)
    encoded = base64.b64encode(files.SerializeToString()).decode("ascii")
    return Schema("protobuf", descriptor.full_name, "protobuf", encoded)


def json_schema(name: str, schema: dict[str, Any]) -> Schema:
    """A JSON channel's schema: ``schema`` (a JSON Schema document) under the name ``name``."""
    return Schema("json", name, "jsonschema", orjson.dumps(schema).decode())
