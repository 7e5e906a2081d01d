"""Waymo Open Dataset segments to XVIZ: v1 as shipped (``.tfrecord``) or as per-frame dictionaries, and v2.

A segment is read from any of three layouts, all of kind ``waymo``:

* a ``.tfrecord`` file of ``Frame`` protocol buffers, as Waymo ships it
  (:mod:`.segment`, with the TFRecord framing in :mod:`.tfrecord`, the
  range images in :mod:`.range_images` and the fields read in
  ``frame.proto``);
* a folder written by ``waymoframe2dict``: one
  ``<frame_timestamp_micros>.npz`` per frame (:mod:`.npz`);
* v2 of the dataset: a Parquet file per component and segment,
  ``{component}/{segment}.parquet`` (:mod:`.parquet`; reading it needs
  pyarrow, the ``parquet`` extra).

The layouts give the same log. Streams: ``/vehicle_pose`` (the pose's
translation and roll, pitch, yaw, in the world frame), ``/lidar/points``
(both returns with range > 0 of every lidar, lidar by lidar, vehicle-relative,
coloured by intensity), ``/lidar/no_label_zone`` (the returns flagged as in
a no-label zone, grey, so that they can be hidden), ``/camera/<name>``
(JPEG, scaled down to ``image_max_width``), ``/objects/boxes`` (extruded
footprints with the object id and a style class per type) and
``/objects/label`` (:mod:`.log` makes them).
"""

from __future__ import annotations

from pathlib import Path

from ...store.path import StorePath
from .. import DEFAULT_IMAGE_WIDTH
from .log import SUFFIX, WaymoLog
from .npz import WaymoSegment, is_npz_segment
from .parquet import is_parquet_segment
from .tfrecord import is_tfrecord

__all__ = ["WaymoLog", "WaymoSegment", "open_segment", "is_waymo_segment"]


def is_waymo_segment(path: Path) -> bool:
    """Whether ``path`` is a segment: a ``.tfrecord`` file, a folder of ``<timestamp_micros>.npz`` frames, or a
    v2 segment (its ``vehicle_pose/SEGMENT.parquet`` file, or a folder of components holding one segment)."""
    if is_parquet_segment(path):
        return True
    if path.is_file():
        return path.suffix == SUFFIX and is_tfrecord(path)
    return is_npz_segment(path)


def open_segment(path: Path | StorePath, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> WaymoLog:
    """The segment at ``path``: a ``.tfrecord`` file (or object in a store), a folder of ``.npz`` frames, or a v2
    segment (see :func:`is_waymo_segment`)."""
    if not isinstance(path, StorePath) and is_parquet_segment(Path(path)):
        from .parquet import WaymoParquetSegment  # pyarrow: imported when a v2 segment is opened

        return WaymoParquetSegment(Path(path), image_max_width)
    if isinstance(path, StorePath) or Path(path).is_file():
        from .segment import WaymoRecordSegment  # protobuf: imported when a file is opened

        return WaymoRecordSegment(path, image_max_width)
    return WaymoSegment(path, image_max_width)
