"""PandaSet sequences to XVIZ: lidar sweeps, six cameras and cuboids, read through a restricted unpickler.

A sequence is a folder (``001``, ``002``, ...) in PandaSet's layout, as its
devkit documents it:

* ``lidar/{NN}.pkl.gz``: each sweep (10 Hz) as a gzipped pickle of a pandas
  DataFrame with columns ``x``, ``y``, ``z`` (world frame, metres), ``i``
  (intensity, 0-255), ``t`` (each point's time), ``d`` (0 the 360° Pandar64,
  1 the forward PandarGT); ``lidar/timestamps.json`` (seconds) and
  ``lidar/poses.json`` (the lidar's pose in the world per sweep:
  ``position`` x, y, z and ``heading`` quaternion w, x, y, z);
* ``camera/{name}/{NN}.jpg`` with ``timestamps.json`` for the six cameras
  (``front_camera``, ``front_left_camera``, ...);
* ``annotations/cuboids/{NN}.pkl.gz``: a DataFrame per sweep with ``uuid``,
  ``label``, ``yaw`` and ``position.{x,y,z}``, ``dimensions.{x,y,z}`` in the
  world frame (``dimensions.x`` along the cuboid's own x axis, which ``yaw``
  turns);
* ``meta/gps.json`` and ``meta/timestamps.json``.

The vehicle frame is the lidar's: points and cuboids are moved from the world
into it by the sweep's pose. Frames are the sweeps; each camera image goes to
the first frame at or after it (see :func:`~xviz_server.datasets.sensors.frame_clock`).

Pickles can run code, so they are read only through :class:`FrameUnpickler`,
which builds pandas DataFrames and their parts and nothing else: any other
class or function a pickle names is refused by name before it is called. A
gzip file unpacking to more than :data:`MAX_PICKLE_BYTES` is refused, and a frame
whose files declare more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` in all
is refused unread. Reading
needs pandas (``pip install 'xviz-server[pandaset]'``).
"""

from __future__ import annotations

import io
import os
import pickle
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from ..exceptions import DatasetError
from ..unpack import MAX_FRAME_BYTES, check_frame, unpack_unsized
from . import DEFAULT_IMAGE_WIDTH, require
from .images import scale_jpegs
from .sensors import (
    SensorFrame,
    SensorLog,
    captures_by_frame,
    check_points,
    columns_of,
    file_size,
    frame_clock,
    frame_of,
    moved,
    quaternion_matrix,
    to_vehicle,
)
from .waymo.log import ScaledImages

__all__ = ["PandaSetSequence", "FrameUnpickler", "is_pandaset_sequence", "MAX_PICKLE_BYTES", "CAMERAS"]

#: The most a gzipped pickle may unpack to (a sweep is about 170 000 points, 8 MB), at most a frame's budget.
MAX_PICKLE_BYTES = MAX_FRAME_BYTES
#: The largest camera image read.
MAX_IMAGE_BYTES = 64 << 20
CAMERAS = ("front_left_camera", "front_camera", "front_right_camera", "left_camera", "right_camera", "back_camera")

#: What a pickle of a pandas DataFrame may name, by module: its classes and the functions that rebuild them
#: (pandas, NumPy and pyarrow's, in the places pandas 1 and 2 write them). Nothing else is looked up.
ALLOWED: dict[str, frozenset[str]] = {
    "pandas": frozenset({"DataFrame", "Index", "RangeIndex", "StringDtype", "CategoricalDtype", "Categorical"}),
    "pandas.core.frame": frozenset({"DataFrame"}),
    "pandas.core.internals.managers": frozenset({"BlockManager"}),
    "pandas.core.internals.blocks": frozenset(
        {"new_block", "Block", "ObjectBlock", "FloatBlock", "IntBlock", "BoolBlock"}
    ),
    "pandas._libs.internals": frozenset({"_unpickle_block"}),
    "pandas.core.indexes.base": frozenset({"_new_Index", "Index"}),
    "pandas.core.indexes.range": frozenset({"RangeIndex"}),
    "pandas.core.indexes.numeric": frozenset({"Int64Index", "Float64Index"}),
    "pandas.arrays": frozenset({"ArrowStringArray", "StringArray"}),
    "pandas.core.arrays.string_": frozenset({"StringDtype", "StringArray"}),
    "pandas.core.arrays.string_arrow": frozenset({"ArrowStringArray"}),
    "pandas.core.arrays.categorical": frozenset({"Categorical"}),
    "pandas.core.dtypes.dtypes": frozenset({"CategoricalDtype"}),
    "pyarrow.lib": frozenset({"_restore_array", "type_for_alias", "py_buffer"}),
    "numpy": frozenset({"ndarray", "dtype"}),
    "numpy.core.multiarray": frozenset({"_reconstruct", "scalar"}),
    "numpy._core.multiarray": frozenset({"_reconstruct", "scalar"}),
    "numpy.core.numeric": frozenset({"_frombuffer"}),
    "numpy._core.numeric": frozenset({"_frombuffer"}),
    "builtins": frozenset({"slice", "bytearray"}),
    "__builtin__": frozenset({"slice", "bytearray"}),
    "_codecs": frozenset({"encode"}),
}


class FrameUnpickler(pickle.Unpickler):
    """An unpickler that builds pandas DataFrames and refuses everything else a pickle may name (see :data:`ALLOWED`).

    Old pickles name pandas' classes where pandas 0.x and 1.x kept them;
    they are looked up where pandas keeps them now (pandas' own map of moved
    names), and checked there.
    """

    def find_class(self, module: str, name: str) -> Any:
        try:
            from pandas.compat.pickle_compat import _class_locations_map as moved
        except ImportError:  # pandas moved its map: old pickles then name what must be allowed as it is
            moved = {}
        module, name = moved.get((module, name), (module, name))
        if name not in ALLOWED.get(module, frozenset()):
            raise pickle.UnpicklingError(f"refused: the pickle names {module}.{name}, and only pandas frames are read")
        return super().find_class(module, name)


def read_frame(path: Path) -> Any:
    """The pandas DataFrame of a gzipped pickle, read through :class:`FrameUnpickler`."""
    pandas = require("pandas", "PandaSet sequences", "pandaset")
    try:
        data = unpack_unsized(path.read_bytes(), "gzip", str(path), MAX_PICKLE_BYTES)
        frame = FrameUnpickler(io.BytesIO(data)).load()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read: {exc.strerror or exc}", path=path) from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, KeyError, IndexError) as exc:
        raise DatasetError(f"{path}: not a pickled DataFrame: {exc}", path=path) from None
    if not isinstance(frame, pandas.DataFrame):
        raise DatasetError(f"{path}: a pickled {type(frame).__name__}, not a DataFrame", path=path)
    return frame


def unpacked_size(path: Path) -> int:
    """What a gzip file declares it unpacks to (its trailer's size, modulo 4 GiB; 0 if it has none): a declaration,
    which :func:`read_frame` holds it to."""
    try:
        with path.open("rb") as file:
            file.seek(-4, os.SEEK_END)
            return int.from_bytes(file.read(4), "little")
    except OSError:
        return 0


def is_pandaset_sequence(path: Path) -> bool:
    """Whether ``path`` is a PandaSet sequence: ``lidar/poses.json`` and ``lidar/timestamps.json`` beside ``meta``."""
    return (
        (path / "lidar" / "poses.json").is_file()
        and (path / "lidar" / "timestamps.json").is_file()
        and (path / "meta").is_dir()
    )


def _json(path: Path) -> Any:
    try:
        if path.stat().st_size > MAX_IMAGE_BYTES:
            raise DatasetError(f"{path}: {path.stat().st_size} bytes, too large for a PandaSet JSON file", path=path)
        return orjson.loads(path.read_bytes())
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read: {exc.strerror or exc}", path=path) from None
    except orjson.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not JSON: {exc}", path=path) from None


class PandaSetSequence(SensorLog):
    """A PandaSet sequence folder, named after it (``001``)."""

    def __init__(self, path: Path, image_max_width: int = DEFAULT_IMAGE_WIDTH) -> None:
        self.path = Path(path)
        self.name = self.path.name
        self.image_max_width = image_max_width
        self.source = f"PandaSet sequence {self.name}"
        if not is_pandaset_sequence(self.path):
            raise DatasetError(
                f"{self.path}: not a PandaSet sequence (no lidar/poses.json and lidar/timestamps.json beside meta/)",
                path=self.path,
            )
        stamps = _json(self.path / "lidar" / "timestamps.json")
        poses = _json(self.path / "lidar" / "poses.json")
        if not isinstance(stamps, list) or not isinstance(poses, list) or len(stamps) != len(poses) or not stamps:
            raise DatasetError(
                f"{self.path / 'lidar'}: timestamps.json and poses.json are lists of one entry a sweep", path=self.path
            )
        try:
            self._sweep_times = [int(round(float(t) * 1e6)) for t in stamps]
            self._poses = [self._pose(pose) for pose in poses]
        except (TypeError, ValueError, KeyError) as exc:
            raise DatasetError(
                f"{self.path / 'lidar'}: a timestamp or pose that is not one: {exc}", path=self.path
            ) from None
        self._images = {}
        for camera in CAMERAS:
            folder = self.path / "camera" / camera
            if (folder / "timestamps.json").is_file():
                times = _json(folder / "timestamps.json")
                self._images[camera] = [
                    (int(round(float(t) * 1e6)), folder / f"{n:02d}.jpg")
                    for n, t in enumerate(times)
                    if (folder / f"{n:02d}.jpg").is_file()
                ]
        self.cameras = [camera for camera in CAMERAS if self._images.get(camera)]

    @staticmethod
    def _pose(pose: dict[str, Any]) -> np.ndarray:
        matrix = np.eye(4)
        heading, position = pose["heading"], pose["position"]
        matrix[:3, :3] = quaternion_matrix(*(float(heading[k]) for k in "wxyz"))
        matrix[:3, 3] = [float(position[k]) for k in "xyz"]
        return matrix

    @cached_property
    def _clock(self) -> list[int]:
        return frame_clock(
            self._sweep_times, {camera: [t for t, _ in images] for camera, images in self._images.items()}
        )

    @property
    def times(self) -> np.ndarray:
        return np.array(self._clock, dtype=np.float64) / 1e6

    @cached_property
    def _frames(self) -> list[dict[str, Any]]:
        """Per frame, its sweep's number (``lidar``) if it has one, and the image of each camera served in it."""
        return captures_by_frame(
            self._clock, {"lidar": [(t, n) for n, t in enumerate(self._sweep_times)], **self._images}
        )

    def _sweep_number(self, index: int) -> int:
        """The sweep of frame ``index``, or the latest before it."""
        return max(0, frame_of(self._sweep_times, self._clock[index] + 1) - 1)

    def pose(self, index: int) -> np.ndarray:
        return self._poses[self._sweep_number(index)]

    def read(self, index: int) -> SensorFrame:
        captures = self._frames[index]
        number = self._sweep_number(index)
        pickles = [self.path / "annotations" / "cuboids" / f"{number:02d}.pkl.gz"]
        if "lidar" in captures:
            pickles.append(self.path / "lidar" / f"{captures['lidar']:02d}.pkl.gz")
        declared = sum(file_size(file) for camera, file in captures.items() if camera != "lidar")
        check_frame(declared + sum(map(unpacked_size, pickles)), index, str(self.path), self.path)
        images = {camera: self._image(file) for camera, file in captures.items() if camera != "lidar"}
        scaling = scale_jpegs(images, self.image_max_width)  # beside the lidar work
        pose = self.pose(index)
        if "lidar" in captures:
            points, intensity = self._sweep(captures["lidar"], pose)
        else:
            points, intensity = np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        boxes, categories, ids = self._boxes(self._sweep_number(index), pose)
        where = f"{self.path}: frame {index}"
        return SensorFrame(
            self._clock[index] / 1e6,
            pose,
            points,
            intensity,
            ScaledImages(scaling, where, self.path),
            boxes,
            categories,
            ids,
        )

    def _image(self, file: Path) -> bytes:
        try:
            if file.stat().st_size > MAX_IMAGE_BYTES:
                raise DatasetError(f"{file}: more than the {MAX_IMAGE_BYTES} bytes an image may have", path=file)
            return file.read_bytes()
        except OSError as exc:
            raise DatasetError(f"{file}: cannot read: {exc.strerror or exc}", path=file) from None

    def _sweep(self, number: int, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        path = self.path / "lidar" / f"{number:02d}.pkl.gz"
        x, y, z, i = columns_of(read_frame(path), ("x", "y", "z", "i"), path)
        world = check_points(np.column_stack([x, y, z]), str(path), self.path)
        points = moved(world, pose[:3, :3].T, -pose[:3, :3].T @ pose[:3, 3])  # world to vehicle: the pose's inverse
        return points, np.asarray(i, dtype=np.float32) / np.float32(255)

    def _boxes(self, number: int, pose: np.ndarray) -> tuple[np.ndarray, list[str], list[str]]:
        path = self.path / "annotations" / "cuboids" / f"{number:02d}.pkl.gz"
        if not path.is_file():
            return np.zeros((0, 7)), [], []
        columns = (
            "uuid",
            "label",
            "yaw",
            "position.x",
            "position.y",
            "position.z",
            "dimensions.x",
            "dimensions.y",
            "dimensions.z",
        )
        uuid, label, yaw, *numbers = columns_of(read_frame(path), columns, path)
        px, py, pz, dx, dy, dz = (np.asarray(values, dtype=np.float64) for values in numbers)
        centers, yaws = to_vehicle(pose, np.column_stack([px, py, pz]), np.asarray(yaw, dtype=np.float64))
        boxes = np.column_stack([centers, dx, dy, dz, yaws])
        return boxes, [str(name) for name in label], [str(object_id)[:8] for object_id in uuid]
