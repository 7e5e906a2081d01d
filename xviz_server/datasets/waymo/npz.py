"""Waymo segments as per-frame dictionaries: a folder of ``<frame_timestamp_micros>.npz``.

The folder is what ``waymoframe2dict`` writes (see ``shared/seeds/003``). The
keys of a ``.npz`` frame that are read:

* ``POSE``: (4, 4) vehicle-to-world transform;
* per lidar ``L`` in ``TOP``, ``FRONT``, ``SIDE_LEFT``, ``SIDE_RIGHT``,
  ``REAR``: ``L_RANGE_IMAGE_FIRST_RETURN`` and, if there,
  ``L_RANGE_IMAGE_SECOND_RETURN``, (H, W, 6) float32 with the channels
  range, intensity, elongation, x, y, z (x, y, z in the vehicle frame), and
  optionally ``L_IN_NLZ`` and ``L_IN_NLZ_SECOND_RETURN``, (H, W), 1 where
  the return is in a no-label zone (the original range image's fourth
  channel; -1 or 0 elsewhere). ``L_BEAM_INCLINATION`` and
  ``L_LIDAR_EXTRINSIC`` are not needed, since the points come with vehicle
  coordinates;
* per camera ``C`` in ``FRONT``, ``FRONT_LEFT``, ``FRONT_RIGHT``,
  ``SIDE_LEFT``, ``SIDE_RIGHT``: ``C_IMAGE``, (H, W, 3) uint8 RGB
  (``C_INTRINSIC``, ``C_EXTRINSIC``, ``C_WIDTH``, ``C_HEIGHT`` are not
  needed to draw it);
* the 3D labels: ``LABEL_BOXES``, (N, 7) center x, y, z, length, width,
  height, heading in the vehicle frame; ``LABEL_TYPES``, (N,) integers of
  the Waymo ``Label.Type`` enum (1 vehicle, 2 pedestrian, 3 sign, 4
  cyclist, 0 unknown); ``LABEL_IDS``, (N,) tracking ids (strings).
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path

import numpy as np

from ...exceptions import DatasetError
from .. import DEFAULT_IMAGE_WIDTH
from ..images import jpeg
from .log import CAMERAS, LIDARS, WaymoFrame, WaymoLog

__all__ = ["WaymoSegment", "frame_files", "is_npz_segment"]


def is_npz_segment(path: Path) -> bool:
    """Whether ``path`` is a folder of ``<timestamp_micros>.npz`` frames."""
    return path.is_dir() and any(p.suffix == ".npz" and p.stem.isdigit() for p in path.iterdir())


def frame_files(path: Path) -> list[Path]:
    """The ``.npz`` frames of a segment folder, in time order."""
    files = [p for p in path.glob("*.npz") if p.stem.isdigit()]
    return sorted(files, key=lambda p: int(p.stem))


class WaymoSegment(WaymoLog):
    """A Waymo segment folder of per-frame ``.npz`` dictionaries.

    Camera images are scaled down to ``image_max_width`` and encoded as JPEG.
    """

    path: Path

    def __init__(self, path: Path, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        self.path = Path(path)
        self.image_max_width = image_max_width
        if not is_npz_segment(self.path):
            raise DatasetError(f"{self.path}: not a Waymo segment (no <timestamp_micros>.npz frames)", path=self.path)
        self.name = self.path.name

    @cached_property
    def files(self) -> list[Path]:
        return frame_files(self.path)

    @cached_property
    def times(self) -> np.ndarray:
        """Frame times in seconds, from the file names (no frame read)."""
        return np.array([int(p.stem) / 1e6 for p in self.files])

    def frame(self, index: int) -> dict[str, np.ndarray]:
        """The dictionary of frame ``index``; raises :class:`DatasetError` naming the file."""
        path = self.files[index]
        try:
            with np.load(path, allow_pickle=False) as data:
                return {key: data[key] for key in data.files}
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise DatasetError(f"{path}: not a readable frame dictionary: {exc}", path=path) from None

    def read(self, index: int) -> WaymoFrame:
        data = self.frame(index)
        where = self.files[index]
        points, intensity, in_zone = self._lidar(data, where)
        images = {camera: self._jpeg(data[f"{camera}_IMAGE"], where) for camera in CAMERAS if f"{camera}_IMAGE" in data}
        boxes, types, ids = self._labels_of(data, where)
        pose = self._array(data, "POSE", where, (4, 4)).astype(np.float64)
        return WaymoFrame(float(self.times[index]), pose, points, intensity, in_zone, images, boxes, types, ids)

    @staticmethod
    def _array(data: dict[str, np.ndarray], key: str, where: Path, shape: tuple[int, ...] | None = None) -> np.ndarray:
        if key not in data:
            raise DatasetError(f"{where}: no {key!r} in the frame", path=where)
        array = data[key]
        if shape is not None and array.shape != shape:
            raise DatasetError(f"{where}: {key} has shape {array.shape}, not {shape}", path=where)
        return array

    @staticmethod
    def _lidar(data: dict[str, np.ndarray], where: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns of every lidar with range > 0: xyz (N, 3), intensities, and in-no-label-zone flags."""
        points, intensity, zones = [], [], []
        for lidar in LIDARS:
            for key, zone_key in (
                (f"{lidar}_RANGE_IMAGE_FIRST_RETURN", f"{lidar}_IN_NLZ"),
                (f"{lidar}_RANGE_IMAGE_SECOND_RETURN", f"{lidar}_IN_NLZ_SECOND_RETURN"),
            ):
                if key not in data:
                    continue
                image = data[key]
                if image.ndim != 3 or image.shape[2] < 6:
                    raise DatasetError(f"{where}: {key} has shape {image.shape}, not (H, W, 6)", path=where)
                valid = image[..., 0] > 0
                returns = image[valid]
                points.append(returns[:, 3:6].astype(np.float32))
                intensity.append(returns[:, 1])
                zone = data.get(zone_key)
                zones.append(zone[valid] > 0 if zone is not None else np.zeros(len(returns), dtype=bool))
        if not points:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, dtype=bool)
        return np.concatenate(points), np.concatenate(intensity), np.concatenate(zones)

    def _jpeg(self, image: np.ndarray, where: Path) -> bytes:
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise DatasetError(
                f"{where}: a camera image must be (H, W, 3) uint8, not {image.shape} {image.dtype}", path=where
            )
        return jpeg(image, self.image_max_width)

    @staticmethod
    def _labels_of(data: dict[str, np.ndarray], where: Path) -> tuple[np.ndarray, np.ndarray, Sequence[str]]:
        if "LABEL_BOXES" not in data:
            return np.zeros((0, 7)), np.zeros(0, dtype=int), []
        boxes = data["LABEL_BOXES"].astype(np.float64)
        if boxes.ndim != 2 or boxes.shape[1] != 7:
            raise DatasetError(f"{where}: LABEL_BOXES has shape {boxes.shape}, not (N, 7)", path=where)
        types = data.get("LABEL_TYPES", np.zeros(len(boxes), dtype=int))
        ids = [str(i) for i in data.get("LABEL_IDS", range(len(boxes)))]
        return boxes, types, ids
