"""Waymo Open Dataset segments as shipped: a ``.tfrecord`` file of ``Frame`` protocol buffers.

Each record of the file is one ``Frame`` (see ``frame.proto`` for the
fields read). Opening a segment indexes its records (see
:mod:`xviz_server.datasets.waymo.tfrecord`) and peeks at each record's
``timestamp_micros``, found in its first bytes, so that the frame times are
known without reading the frames. A frame is read and its checksum checked
when it is converted:

* lidar: both returns of every laser's range image (zlib-compressed
  ``MatrixFloat`` [H, W, 4]: range, intensity, elongation, in no-label zone)
  become points in the vehicle frame with the laser's calibration from the
  frame's context, and, where the first return carries a per-pixel pose
  (the TOP laser), that pose (see :mod:`xviz_server.datasets.waymo.range_images`);
  returns with range <= 0 are left out. A frame whose lasers carry no range
  images has no points, and the rest of it is served;
* cameras: the JPEG images, as they are if at most ``image_max_width``
  wide, else scaled down;
* labels: the 3D laser labels; pose: ``Frame.pose``; time:
  ``timestamp_micros``.

A corrupt or truncated record, or a frame that does not parse or holds
inconsistent range images, raises :class:`~xviz_server.exceptions.DatasetError`
naming the file, the record and its offset; every other frame is served. A
record whose time cannot be found at all is left out of the segment, with a
warning.

Decompressing a matrix is bounded: a range image larger than
:data:`MAX_MATRIX_BYTES` once decompressed is an error. A frame is bounded
in all: a record longer than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` is
refused unread, and its range images are counted on a
:class:`~xviz_server.unpack.FrameTally` as they decompress, from the
record's length: either raises :class:`~xviz_server.exceptions.FrameSizeError`.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future
from functools import cached_property
from pathlib import Path

import numpy as np
from google.protobuf.message import DecodeError
from zlib_ng import zlib_ng

from ...exceptions import DatasetError, FrameSizeError
from ...store.path import StorePath, data_path
from ...unpack import FrameTally, check_frame
from .. import DEFAULT_IMAGE_WIDTH, threads
from ..images import scale_jpegs
from . import frame_pb2 as pb
from .log import LIDARS, SUFFIX, ScaledImages, WaymoFrame, WaymoLog
from .range_images import calibration_rays, frame_rays, join_points, range_points
from .tfrecord import RecordFile, is_tfrecord

__all__ = ["WaymoRecordSegment", "MAX_MATRIX_BYTES"]

logger = logging.getLogger(__name__)

#: The largest decompressed matrix accepted (a TOP range image is 2.7 MB).
MAX_MATRIX_BYTES = 64 << 20
#: How much of a matrix is decompressed at a time, each step counted on the frame's tally.
_STEP = 4 << 20

# The field number of Frame.timestamp_micros, and the protobuf wire types.
_TIMESTAMP_FIELD = 2
_VARINT, _FIXED64, _LENGTH_DELIMITED, _FIXED32 = 0, 1, 2, 5
# How much of a record to read first when looking for its timestamp: fields
# are written in number order, so only the Frame's context, a few kilobytes,
# comes before it (more is read, up to the whole record, if not).
_PEEK = 16 << 10


def _varint(data: bytes, position: int) -> tuple[int, int]:
    """The varint at ``position`` and the position after it; IndexError if cut short."""
    value = shift = 0
    while True:
        byte = data[position]
        position += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, position
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 10 bytes")


def _timestamp(head: bytes) -> int | None:
    """``timestamp_micros`` from the first bytes of a serialized Frame, or ``None`` if not in them.

    Walks the top-level fields, skipping each by its wire type; raises
    :class:`ValueError` at a wire type protobuf does not have.
    """
    position = 0
    try:
        while position < len(head):
            key, position = _varint(head, position)
            field, wire = key >> 3, key & 7
            if wire == _VARINT:
                value, position = _varint(head, position)
                if field == _TIMESTAMP_FIELD:
                    return value - (1 << 64) if value >= 1 << 63 else value
            elif wire == _LENGTH_DELIMITED:
                length, position = _varint(head, position)
                position += length
            elif wire in (_FIXED64, _FIXED32):
                position += 8 if wire == _FIXED64 else 4
            else:
                raise ValueError(f"wire type {wire}")
    except IndexError:
        pass
    return None


class WaymoRecordSegment(WaymoLog):
    """A Waymo segment ``.tfrecord`` file, named by its file name without ``.tfrecord``.

    ``path`` is a file, or an object in a store: opening it then reads each
    record's header and first bytes with one ranged GET, and reading a
    frame is one ranged GET.
    """

    def __init__(self, path: Path | StorePath, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        self.path = data_path(path)
        self.image_max_width = image_max_width
        self.name = self.path.name.removesuffix(SUFFIX)
        try:
            if not is_tfrecord(self.path):
                raise DatasetError(
                    f"{self.path}: not a TFRecord file (no record header with a matching CRC at its start)",
                    path=self.path,
                )
        except OSError as exc:  # an object the store fails
            raise DatasetError(f"{self.path}: cannot read: {exc}", path=self.path) from None
        self.records = RecordFile(self.path, peek=_PEEK)
        self._geometry: dict[tuple[int, int, int, bytes], tuple[np.ndarray, np.ndarray]] = {}
        if not len(self.times):
            raise DatasetError(f"{self.path}: no Waymo frames (no record with a timestamp)", path=self.path)

    @cached_property
    def _frames(self) -> tuple[list[int], np.ndarray]:
        """The records that are frames, and their times in seconds."""
        numbers, times = [], []
        for number in range(len(self.records)):
            micros = self._peek_time(number)
            if micros is None:
                logger.warning("%s: no timestamp_micros in its first bytes; left out", self.records.where(number))
                continue
            numbers.append(number)
            times.append(micros / 1e6)
        self.records.forget_heads()
        return numbers, np.array(times, dtype=np.float64)

    @property
    def times(self) -> np.ndarray:
        return self._frames[1]

    def _peek_time(self, number: int) -> int | None:
        size, length = _PEEK, self.records.records[number].length
        while True:
            head = self.records.head(number, size)
            try:
                micros = _timestamp(head)
            except ValueError:
                return None
            if micros is not None or len(head) < size or size >= length:  # found, or the whole record looked at
                return micros
            size *= 4

    def read(self, index: int) -> WaymoFrame:
        number = self._frames[0][index]
        where = self.records.where(number)
        record = self.records.records[number]
        if record.problem is None:  # a record the framing finds bad is refused by name when read, below
            check_frame(record.length, index, str(self.path), self.path)
        tally = FrameTally(record.length, index, str(self.path), self.path)
        frame = pb.Frame()
        try:
            frame.ParseFromString(self.records.read(number))
        except DecodeError as exc:
            raise DatasetError(f"{where}: not a Waymo Frame: {exc}", path=self.path) from None
        if len(frame.pose.transform) != 16:
            raise DatasetError(f"{where}: Frame.pose has {len(frame.pose.transform)} values, not 16", path=self.path)
        pose = np.array(frame.pose.transform, dtype=np.float64).reshape(4, 4)
        matrices = self._inflate_all(frame, where, tally)  # first: the lidar work below waits for them
        scaling = scale_jpegs(
            {pb.CameraName.Name.Name(image.name): image.image for image in frame.images if image.name},
            self.image_max_width,
        )  # beside the lidar work
        for future in matrices.values():  # a frame over the limit is refused whole, whichever part passed it
            if isinstance(error := future.exception(), FrameSizeError):
                raise error
        points, intensity, in_zone = self._lidar(frame, pose, matrices, where)
        boxes = np.array(
            [
                [b.center_x, b.center_y, b.center_z, b.length, b.width, b.height, b.heading]
                for b in (label.box for label in frame.laser_labels)
            ],
            dtype=np.float64,
        ).reshape(-1, 7)
        types = np.array([label.type for label in frame.laser_labels], dtype=int)
        ids = [label.id for label in frame.laser_labels]
        images = ScaledImages(scaling, where, self.path)
        return WaymoFrame(frame.timestamp_micros / 1e6, pose, points, intensity, in_zone, images, boxes, types, ids)

    def _lidar(
        self, frame: pb.Frame, pose: np.ndarray, matrices: dict[tuple[int, str], Future[np.ndarray]], where: str
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        calibrations = {c.name: c for c in frame.context.laser_calibrations}
        lidar_points = []
        for laser in sorted(frame.lasers, key=lambda laser: laser.name):
            if not laser.ri_return1.range_image_compressed:
                continue
            lidar = pb.LaserName.Name.Name(laser.name)
            first = matrices[laser.name, "return 1"].result()
            height, width = first.shape[:2]
            if laser.name not in calibrations:
                raise DatasetError(
                    f"{where}: laser {lidar} has range images but no calibration in the context", path=self.path
                )
            directions, translation = self._rays(calibrations[laser.name], height, width, f"laser {lidar}", where)
            returns = [first]
            if laser.ri_return2.range_image_compressed:
                second = matrices[laser.name, "return 2"].result()
                if second.shape[:2] != (height, width):
                    raise DatasetError(
                        f"{where}: laser {lidar}: return 2 is {second.shape[:2]}, return 1 {height, width}",
                        path=self.path,
                    )
                returns.append(second)
            origins, period = translation[None], 1
            if laser.ri_return1.range_image_pose_compressed:
                pixel_pose = matrices[laser.name, "pixel pose"].result()
                if pixel_pose.shape[:2] != (height, width):
                    raise DatasetError(
                        f"{where}: laser {lidar}: pixel pose is {pixel_pose.shape[:2]}, range image {height, width}",
                        path=self.path,
                    )
                directions, origins, period = frame_rays(directions, translation, pixel_pose[..., :6], pose)
            lidar_points.append(range_points(directions, origins, period, returns))
        return join_points(lidar_points)

    def _inflate_all(self, frame: pb.Frame, where: str, tally: FrameTally) -> dict[tuple[int, str], Future[np.ndarray]]:
        """Start decoding every range image and pixel pose of ``frame``, side by side (see :mod:`xviz_server.datasets.threads`),
        each counted on ``tally``."""
        matrices: dict[tuple[int, str], Future[np.ndarray]] = {}
        for laser in frame.lasers:
            lidar = pb.LaserName.Name.Name(laser.name)
            for part, compressed, channels in (
                ("return 1", laser.ri_return1.range_image_compressed, 4),
                ("return 2", laser.ri_return2.range_image_compressed, 4),
                ("pixel pose", laser.ri_return1.range_image_pose_compressed, 6),
            ):
                if compressed:
                    matrices[laser.name, part] = threads.submit(
                        self._matrix, compressed, channels, f"laser {lidar} {part}", where, tally
                    )
        return matrices

    def _rays(
        self, calibration: pb.LaserCalibration, height: int, width: int, what: str, where: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """(H * W, 3) pixel directions in the vehicle frame and the lidar's position; kept per calibration."""
        key = (calibration.name, height, width, calibration.SerializeToString(deterministic=True))
        if key not in self._geometry:
            if len(calibration.extrinsic.transform) != 16:
                raise DatasetError(
                    f"{where}: {what}: the extrinsic has {len(calibration.extrinsic.transform)} values, not 16",
                    path=self.path,
                )
            extrinsic = np.array(calibration.extrinsic.transform, dtype=np.float64).reshape(4, 4)
            try:
                rays = calibration_rays(
                    extrinsic,
                    calibration.beam_inclinations,
                    calibration.beam_inclination_min,
                    calibration.beam_inclination_max,
                    height,
                    width,
                    f"{where}: {what}",
                )
            except ValueError as exc:
                raise DatasetError(str(exc), path=self.path) from None
            if len(self._geometry) >= 2 * len(LIDARS):  # calibrations that change within a segment: keep a few
                self._geometry.clear()
            self._geometry[key] = rays
        return self._geometry[key]

    def _matrix(self, compressed: bytes, channels: int, what: str, where: str, tally: FrameTally) -> np.ndarray:
        """A zlib-compressed MatrixFloat [H, W, channels] as a float32 array, decompressed a step at a time onto
        ``tally``."""
        inflate = zlib_ng.decompressobj()  # zlib-ng: the same stream, inflated faster
        parts: list[bytes] = []
        rest, size = compressed, 0
        while not inflate.eof:
            room = min(_STEP, MAX_MATRIX_BYTES + 1 - size)
            try:
                part = inflate.decompress(rest, room)
            except zlib_ng.error as exc:  # type: ignore[misc]  # its stub declares error an instance
                raise DatasetError(f"{where}: {what}: not zlib data: {exc}", path=self.path) from None
            tally.take(len(part))
            parts.append(part)
            size, rest = size + len(part), inflate.unconsumed_tail
            if size > MAX_MATRIX_BYTES:
                raise DatasetError(f"{where}: {what}: more than {MAX_MATRIX_BYTES} bytes decompressed", path=self.path)
            if len(part) < room and not rest:  # every byte in, and what it gave out
                break
        if not inflate.eof:
            raise DatasetError(f"{where}: {what}: the zlib data is cut short", path=self.path)
        matrix = pb.MatrixFloat()
        try:
            matrix.ParseFromString(b"".join(parts))
        except DecodeError as exc:
            raise DatasetError(f"{where}: {what}: not a MatrixFloat: {exc}", path=self.path) from None
        dims = tuple(matrix.shape.dims)
        if len(dims) != 3 or dims[2] < channels or min(dims) < 1:
            raise DatasetError(f"{where}: {what}: shape {list(dims)}, not [H, W, {channels}]", path=self.path)
        data = np.frombuffer(matrix.data, dtype="<f4")
        if data.size != dims[0] * dims[1] * dims[2]:
            raise DatasetError(f"{where}: {what}: {data.size} values for shape {list(dims)}", path=self.path)
        return data.reshape(dims)
