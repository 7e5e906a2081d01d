"""MIT VISTA traces to XVIZ: camera video, lidar sweeps, and a pose from odometry.

A trace folder (see ``shared/seeds/004``) holds, per sensor, a
``<sensor>.csv`` mapping the sensor's frame number to a ROS timestamp, and
the sensor data; and odometry. The files read are:

* cameras: ``<camera>.csv`` and ``<camera>.avi`` (any video FFmpeg reads);
  the csv has a header row and the columns ``frame_num, ros_timestamp``
  (seconds), in that order;
* lidars: ``<lidar>.csv`` (same columns) and ``<lidar>.h5`` holding the
  datasets ``xyz`` (sweeps, points, 3) and ``intensity`` (sweeps, points);
  rows whose x, y, z are NaN pad the sweeps shorter than the longest;
* odometry: ``speed.csv`` (columns: time, speed in m/s) and ``imu.csv``
  (time in column 0, yaw rate in rad/s in column 6), or the same under the
  names VISTA's ``TopicNames`` gives them:
  ``lexus/pacmod/parsed_tx/vehicle_speed_rpt.csv`` and
  ``lexus/oxts/imu/data.csv``. Rows that do not start with a number
  (headers) are skipped.

The first camera (by name) is the master sensor: its timestamps are the
frames of the log. The vehicle pose follows VISTA's method: speed and
curvature (yaw rate / speed, kept where |curvature| < 1/3) are linear
functions of time, extrapolated at the ends, and a bicycle model is
integrated from the first timestamp (heading' = speed x curvature,
position' = speed x (cos, sin) heading) in steps of at most 10 ms.

Reading video and HDF5 needs the ``vista`` extra:
``pip install xviz-server[vista]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..exceptions import DatasetError
from ..unpack import check_frame
from . import DEFAULT_IMAGE_WIDTH, require
from .images import jpeg
from .shared import intensity_colors

__all__ = ["VistaTrace", "is_vista_trace", "integrate_pose", "linear_function"]

SPEED_FILES = ("speed.csv", "lexus/pacmod/parsed_tx/vehicle_speed_rpt.csv")
IMU_FILES = ("imu.csv", "lexus/oxts/imu/data.csv")
STEP = 0.01  # seconds, at most, between two steps of the bicycle model
TRAJECTORY_SECONDS = 5.0


def _numbers(path: Path) -> np.ndarray:
    """The numeric rows of a csv file as a 2D float array; rows starting with text are skipped."""
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise DatasetError(f"{path}: {exc.strerror or exc}", path=path) from None
    rows = []
    for number, line in enumerate(lines, 1):
        cells = [cell.strip() for cell in line.split(",")]
        try:
            rows.append([float(cell) for cell in cells])
        except ValueError:
            if rows:  # a header may only come first
                raise DatasetError(f"{path}: line {number} is not numbers: {line!r}", path=path) from None
    if not rows or len({len(row) for row in rows}) != 1:
        raise DatasetError(f"{path}: expected rows of numbers of equal length", path=path)
    return np.array(rows)


def linear_function(x: np.ndarray, y: np.ndarray) -> Any:
    """``f(t)``: linear interpolation through (x, y), extrapolated linearly beyond both ends."""
    order = np.argsort(x)
    x, y = x[order], y[order]

    def f(t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        value = np.interp(t, x, y)
        if len(x) >= 2:
            below, above = t < x[0], t > x[-1]
            value = np.where(below, y[0] + (t - x[0]) * (y[1] - y[0]) / (x[1] - x[0]), value)
            value = np.where(above, y[-1] + (t - x[-1]) * (y[-1] - y[-2]) / (x[-1] - x[-2]), value)
        return value

    return f


def integrate_pose(times: np.ndarray, speed: Any, curvature: Any) -> np.ndarray:
    """Bicycle-model poses (x, y, heading) at ``times``, starting from (0, 0, 0) at ``times[0]``.

    Midpoint integration in steps of at most ``STEP`` seconds.
    """
    start, end = float(times[0]), float(times[-1])
    steps = max(1, math.ceil((end - start) / STEP))
    grid = np.linspace(start, end, steps + 1)
    middle = (grid[:-1] + grid[1:]) / 2
    dt = np.diff(grid)
    v = speed(middle)
    heading = np.concatenate([[0.0], np.cumsum(v * curvature(middle) * dt)])
    mid_heading = (heading[:-1] + heading[1:]) / 2
    x = np.concatenate([[0.0], np.cumsum(v * np.cos(mid_heading) * dt)])
    y = np.concatenate([[0.0], np.cumsum(v * np.sin(mid_heading) * dt)])
    return np.stack([np.interp(times, grid, x), np.interp(times, grid, y), np.interp(times, grid, heading)], axis=1)


class _VideoReader:
    """Decodes one video file forward, frame by frame."""

    def __init__(self, path: Path) -> None:
        av = require("av", "VISTA traces", "vista")
        self.path = path
        self._errors = (OSError, av.error.FFmpegError)
        try:
            self._container = av.open(str(path))
            self._frames = self._container.decode(video=0)
        except self._errors as exc:
            raise DatasetError(f"{path}: cannot open video: {exc}", path=path) from None
        self.position = 0  # number of the next frame the decoder gives

    @property
    def frame_bytes(self) -> int:
        """The size of one decoded frame (RGB, 3 bytes a pixel), as the video's stream declares it."""
        stream = self._container.streams.video[0]
        return int(stream.codec_context.width) * int(stream.codec_context.height) * 3

    def frame(self, number: int) -> np.ndarray:
        try:
            for frame in self._frames:
                self.position += 1
                if self.position - 1 == number:
                    return frame.to_ndarray(format="rgb24")
        except self._errors as exc:
            raise DatasetError(f"{self.path}: cannot decode video: {exc}", path=self.path) from None
        raise DatasetError(f"{self.path}: has no frame {number}", path=self.path)

    def close(self) -> None:
        self._container.close()


def is_vista_trace(path: Path) -> bool:
    """Whether ``path`` has a camera video with its csv and the odometry of a VISTA trace."""
    return (
        path.is_dir()
        and any(p.with_suffix(".csv").is_file() for p in path.glob("*.avi"))
        and any((path / name).is_file() for name in SPEED_FILES)
        and any((path / name).is_file() for name in IMU_FILES)
    )


@dataclass
class VistaTrace:
    """A VISTA trace folder."""

    path: Path
    image_max_width: int = DEFAULT_IMAGE_WIDTH
    name: str = field(init=False)

    def __getstate__(self) -> dict[str, Any]:
        # Open video readers stay in their process; a copy starts without them.
        return {k: v for k, v in self.__dict__.items() if k != "_readers"}

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not is_vista_trace(self.path):
            raise DatasetError(
                f"{self.path}: not a VISTA trace (needs <camera>.avi + .csv, speed and imu csv)", path=self.path
            )
        self.name = self.path.name

    # -- sensors ------------------------------------------------------------

    @cached_property
    def cameras(self) -> list[str]:
        return sorted(p.stem for p in self.path.glob("*.avi") if p.with_suffix(".csv").is_file())

    @cached_property
    def lidars(self) -> list[str]:
        return sorted(p.stem for p in self.path.glob("*.h5") if p.with_suffix(".csv").is_file())

    def _stamps(self, sensor: str) -> np.ndarray:
        """(frame number, ROS time) rows of a sensor, in time order."""
        table = _numbers(self.path / f"{sensor}.csv")
        if table.shape[1] < 2:
            raise DatasetError(
                f"{self.path / f'{sensor}.csv'}: needs columns frame_num, ros_timestamp",
                path=self.path / f"{sensor}.csv",
            )
        return table[np.argsort(table[:, 1]), :2]

    @cached_property
    def _master(self) -> np.ndarray:
        return self._stamps(self.cameras[0])

    @cached_property
    def times(self) -> np.ndarray:
        """The master camera's timestamps: the frames of the log."""
        return self._master[:, 1]

    def __len__(self) -> int:
        return len(self.times)

    # -- odometry -------------------------------------------------------------

    def _odometry(self, names: tuple[str, ...]) -> np.ndarray:
        for name in names:
            if (self.path / name).is_file():
                return _numbers(self.path / name)
        raise DatasetError(f"{self.path}: no {' or '.join(names)}", path=self.path)

    @cached_property
    def _functions(self) -> tuple[Any, Any]:
        speed = self._odometry(SPEED_FILES)
        imu = self._odometry(IMU_FILES)
        if imu.shape[1] < 7:
            raise DatasetError(f"{self.path}: the IMU csv needs the yaw rate in column 6", path=self.path)
        f_speed = linear_function(speed[:, 0], speed[:, 1])
        curvature = imu[:, 6] / np.maximum(f_speed(imu[:, 0]), 1e-10)
        good = np.abs(curvature) < 1 / 3
        return f_speed, linear_function(imu[good, 0], curvature[good])

    @cached_property
    def poses(self) -> np.ndarray:
        """(x, y, heading) of the vehicle at every frame."""
        speed, curvature = self._functions
        return integrate_pose(self.times, speed, curvature)

    # -- data -----------------------------------------------------------------

    def _reader(self, camera: str, number: int) -> _VideoReader:
        """An open reader of a camera's video that has not passed frame ``number``."""
        readers = self.__dict__.setdefault("_readers", {})
        reader: _VideoReader | None = readers.get(camera)
        if reader is None or reader.position > number:
            if reader is not None:
                reader.close()
            reader = readers[camera] = _VideoReader(self.path / f"{camera}.avi")
        return reader

    def video_frame(self, camera: str, number: int) -> np.ndarray:
        """Frame ``number`` (0-based, in the file) of a camera's video, RGB uint8 (H, W, 3).

        Videos are read forward: a reader stays open per camera, so frames
        asked for in order are each decoded once.
        """
        return self._reader(camera, number).frame(number)

    def sweep_bytes(self, lidar: str) -> int:
        """What one sweep of a lidar holds (its ``xyz`` and ``intensity`` rows), as the HDF5 file declares it."""
        h5py = require("h5py", "VISTA traces", "vista")
        path = self.path / f"{lidar}.h5"
        try:
            with h5py.File(path, "r") as file:
                return sum(math.prod(file[name].shape[1:]) * file[name].dtype.itemsize for name in ("xyz", "intensity"))
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise DatasetError(f"{path}: cannot read: {exc}", path=path) from None

    def sweep(self, lidar: str, number: int) -> tuple[np.ndarray, np.ndarray]:
        """Sweep ``number`` of a lidar: xyz float32 (N, 3) and intensity (N,), padding removed."""
        h5py = require("h5py", "VISTA traces", "vista")
        path = self.path / f"{lidar}.h5"
        try:
            with h5py.File(path, "r") as file:
                xyz = np.asarray(file["xyz"][number], dtype=np.float32)
                intensity = np.asarray(file["intensity"][number], dtype=np.float32)
        except (OSError, KeyError, IndexError, ValueError) as exc:
            raise DatasetError(f"{path}: cannot read sweep {number}: {exc}", path=path) from None
        keep = np.isfinite(xyz).all(axis=1)
        return xyz[keep], intensity[keep]

    def _nearest(self, sensor: str, t: float) -> int:
        stamps = self._stamps(sensor)
        return int(stamps[np.argmin(np.abs(stamps[:, 1] - t)), 0])

    # -- XVIZ -------------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        meta = MetadataBuilder()
        meta.log_info(
            start_time=float(self.times[0]), end_time=float(self.times[-1]), source=f"VISTA trace {self.name}"
        )
        meta.pose("/vehicle_pose")
        meta.time_series("/vehicle/speed", "FLOAT", units="m/s")
        meta.time_series("/vehicle/yaw_rate", "FLOAT", units="rad/s")
        meta.primitive(
            "/vehicle/trajectory",
            "POLYLINE",
            coordinate="IDENTITY",
            style={"stroke_color": "#47B27588", "stroke_width": 1.4, "stroke_width_min_pixels": 1},
        )
        for lidar in self.lidars:
            meta.primitive(f"/lidar/{lidar}", "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 1})
        for camera in self.cameras:
            meta.primitive(f"/camera/{camera}", "IMAGE")
        meta.ui_panel(
            ui.panel(
                "Vehicle",
                ui.metric(["/vehicle/speed"], title="Speed"),
                ui.metric(["/vehicle/yaw_rate"], title="Yaw rate"),
            )
        )
        meta.ui_panel(ui.panel("Cameras", ui.video([f"/camera/{c}" for c in self.cameras])))
        return meta.build()

    def convert(self, index: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of frame ``index``.

        Raises :class:`~xviz_server.exceptions.FrameSizeError`, the frame unread, when its lidar sweeps and decoded
        video frames, as the files declare them, are more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` in all.
        """
        metadata = metadata or self.metadata()
        t = float(self.times[index])
        sweeps = {lidar: self._nearest(lidar, t) for lidar in self.lidars}
        pictures = {
            camera: int(self._master[index, 0]) if camera == self.cameras[0] else self._nearest(camera, t)
            for camera in self.cameras
        }
        declared = sum(map(self.sweep_bytes, sweeps)) + sum(
            self._reader(camera, number).frame_bytes for camera, number in pictures.items()
        )
        check_frame(declared, index, str(self.path), self.path)
        builder = FrameBuilder(metadata)
        x, y, heading = self.poses[index]
        builder.pose("/vehicle_pose", t, position=(x, y, 0.0), orientation=(0.0, 0.0, heading))
        speed, curvature = self._functions
        builder.time_series("/vehicle/speed", t, float(speed(t)))
        builder.time_series("/vehicle/yaw_rate", t, float(speed(t) * curvature(t)))
        ahead = (self.times >= t) & (self.times <= t + TRAJECTORY_SECONDS)
        if ahead.sum() >= 2:
            builder.polyline(
                "/vehicle/trajectory", np.column_stack([self.poses[ahead, :2], np.zeros(int(ahead.sum()))])
            )
        for lidar, number in sweeps.items():
            points, intensity = self.sweep(lidar, number)
            if len(points):
                builder.points(f"/lidar/{lidar}", points, intensity_colors(intensity))
        for camera, number in pictures.items():
            builder.image(f"/camera/{camera}", jpeg(self.video_frame(camera, number), self.image_max_width))
        return builder.build(t)
