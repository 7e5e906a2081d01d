"""KITTI raw drives as XVIZ, with the streams of the official KITTI converter.

A drive is ``<date>/<date>_drive_<nnnn>_sync/`` with ``oxts/``,
``velodyne_points/`` and ``image_00`` .. ``image_03`` (each a
``timestamps.txt`` and a ``data/`` folder) and optionally
``tracklet_labels.xml``; the calibration files ``calib_*.txt`` are in the
date folder.

Conventions, found by reproducing the official converter's output
(``shared/data/kitti-2011_09_26_drive_0001-head``):

* **Time**: ``timestamps.txt`` holds UTC wall-clock times with nanoseconds;
  the log uses UNIX seconds truncated to the millisecond. Frame ``i`` takes
  the time of OXTS record ``i``.
* **Pose**: ``map_origin`` is the OXTS latitude, longitude and altitude,
  ``position`` is zero and ``orientation`` the OXTS roll, pitch and yaw.
* **Lidar**: points are the velodyne x, y, z as stored; the colour of a
  point of reflectance ``r`` (0..1) is ``(80 + 80 r, 80 r, 60 r)``,
  truncated. The stream is ``VEHICLE_RELATIVE`` with a translation only:
  the velodyne's offset from the IMU (minus the translation of
  ``calib_imu_to_velo.txt``, its rotation of under a degree dropped), raised
  by the IMU's 0.93 m above the ground, in centimetres: (0.81, -0.32, 1.73).
* **Time series**: ``/vehicle/velocity`` is the forward velocity ``vf``,
  ``/vehicle/acceleration`` the forward acceleration ``af``,
  ``/vehicle/wheel_angle`` the upward angular rate ``wu`` in degrees per
  second.
* **Trajectory**: the vehicle's next 50 positions, in its own frame.
* **Tracklets**: boxes from ``tracklet_labels.xml`` (velodyne frame, ``tz``
  at the bottom of the box), drawn as extruded footprints with their class,
  a label and a tracking point.
"""

from __future__ import annotations

import datetime
import io
import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..codec.image import sniff_image
from ..exceptions import DatasetError

__all__ = ["KittiDrive", "Tracklet", "is_kitti_drive", "read_tracklets", "footprints", "reflectance_colors"]

CAMERAS = ("image_00", "image_01", "image_02", "image_03")
IMU_HEIGHT = 0.93  # metres above the ground, from the KITTI sensor set-up
EARTH_RADIUS = 6378137.0
TRAJECTORY_LENGTH = 50
CLASS_COLORS = {
    "Car": "#50B3FF",
    "Cyclist": "#957FCE",
    "Pedestrian": "#FFC6AF",
    "Van": "#5B91F4",
    "Unknown": "#E2E2E2",
}


def is_kitti_drive(path: Path) -> bool:
    """Whether ``path`` is a KITTI raw drive folder (``oxts`` and ``velodyne_points`` with timestamps)."""
    return (path / "oxts" / "timestamps.txt").is_file() and (path / "velodyne_points" / "data").is_dir()


def _unix_ms(text: str, where: Path) -> float:
    """``2011-09-26 13:02:25.964389445`` (UTC) as UNIX seconds truncated to the millisecond."""
    try:
        whole, _, fraction = text.strip().partition(".")
        stamp = datetime.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=datetime.timezone.utc)
        return (int(stamp.timestamp()) * 1000 + int((fraction + "000")[:3])) / 1000
    except ValueError:
        raise DatasetError(f"{where}: {text.strip()!r} is not a KITTI timestamp", path=where) from None


def reflectance_colors(reflectance: np.ndarray) -> np.ndarray:
    """The official converter's colour of each point, uint8 (N, 3), from reflectance 0..1.

    The small offset absorbs float32 rounding of values stored as k/80.
    """
    r = reflectance.astype(np.float64)[:, None] * np.array([80.0, 80.0, 60.0]) + np.array([80.0, 0.0, 0.0])
    return np.clip(np.trunc(r + 1e-4), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Oxts:
    """One OXTS record (see ``oxts/dataformat.txt``)."""

    lat: float
    lon: float
    alt: float
    roll: float
    pitch: float
    yaw: float
    vf: float
    af: float
    wu: float


@dataclass(frozen=True)
class Tracklet:
    """One tracked object: class, box size, first frame and a pose per frame."""

    object_type: str
    height: float
    width: float
    length: float
    first_frame: int
    poses: np.ndarray  # (frames, 4): tx, ty, tz, rz (yaw) in the velodyne frame


def read_tracklets(path: Path) -> list[Tracklet]:
    """Parse a ``tracklet_labels.xml`` (the devkit's boost serialisation XML)."""
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise DatasetError(f"{path}: cannot read tracklets: {exc}", path=path) from None
    tracklets = []
    for index, item in enumerate(root.iterfind("./tracklets/item")):
        try:
            poses = [
                [float(pose.findtext(key)) for key in ("tx", "ty", "tz", "rz")]  # type: ignore[arg-type]
                for pose in item.iterfind("./poses/item")
            ]
            tracklets.append(
                Tracklet(
                    object_type=item.findtext("objectType") or "Unknown",
                    height=float(item.findtext("h")),  # type: ignore[arg-type]
                    width=float(item.findtext("w")),  # type: ignore[arg-type]
                    length=float(item.findtext("l")),  # type: ignore[arg-type]
                    first_frame=int(item.findtext("first_frame")),  # type: ignore[arg-type]
                    poses=np.array(poses, dtype=np.float64).reshape(-1, 4),
                )
            )
        except (TypeError, ValueError):
            raise DatasetError(f"{path}: tracklet {index} is missing a field or has a bad number", path=path) from None
    return tracklets


def footprints(centers: np.ndarray, yaws: np.ndarray, lengths: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """The four ground corners of each box, (N, 4, 3), rotated by its yaw about its centre.

    ``centers`` are (N, 3) box bottoms; the length lies along x before rotation.
    """
    half = np.stack([lengths / 2, widths / 2], axis=1)
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
    local = signs[None, :, :] * half[:, None, :]  # (N, 4, 2)
    cos, sin = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    x = cos * local[..., 0] - sin * local[..., 1] + centers[:, None, 0]
    y = sin * local[..., 0] + cos * local[..., 1] + centers[:, None, 1]
    z = np.broadcast_to(centers[:, None, 2], x.shape)
    return np.stack([x, y, z], axis=-1)


@dataclass
class KittiDrive:
    """A KITTI raw drive, converted to XVIZ frame by frame.

    ``path`` is the drive folder, or a folder holding one date folder with
    one drive. Images wider than ``image_max_width`` are scaled down (aspect
    kept) and re-encoded as PNG. Small and picklable: worker processes get a
    copy and read the files themselves.
    """

    path: Path
    image_max_width: int = 400
    name: str = field(init=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not is_kitti_drive(self.path):
            drives = [p for p in self.path.glob("*/*_sync") if is_kitti_drive(p)]
            if len(drives) != 1:
                raise DatasetError(f"{self.path}: not a KITTI raw drive (no oxts/ and velodyne_points/)", path=self.path)
            self.path = drives[0]
        self.name = self.path.name

    # -- raw data ---------------------------------------------------------

    def _file(self, *parts: str) -> Path:
        return self.path.joinpath(*parts)

    def _read(self, path: Path) -> bytes:
        try:
            return path.read_bytes()
        except OSError as exc:
            raise DatasetError(f"{path}: {exc.strerror or exc}", path=path) from None

    @cached_property
    def times(self) -> np.ndarray:
        """UNIX time of every frame, from the OXTS timestamps (no frame data read)."""
        path = self._file("oxts", "timestamps.txt")
        lines = [line for line in self._read(path).decode().splitlines() if line.strip()]
        return np.array([_unix_ms(line, path) for line in lines])

    def __len__(self) -> int:
        return len(self.times)

    def oxts(self, frame: int) -> Oxts:
        path = self._file("oxts", "data", f"{frame:010d}.txt")
        try:
            values = [float(v) for v in self._read(path).split()]
            return Oxts(*values[:6], vf=values[8], af=values[14], wu=values[22])
        except (ValueError, IndexError):
            raise DatasetError(f"{path}: not an OXTS record of 30 numbers", path=path) from None

    def _oxts_cached(self, frame: int) -> Oxts:
        """OXTS records are read once per process: each frame's trajectory needs the next 50."""
        cache = self.__dict__.setdefault("_oxts", {})
        if frame not in cache:
            cache[frame] = self.oxts(frame)
        return cache[frame]

    def velodyne(self, frame: int) -> np.ndarray:
        """The velodyne sweep of a frame, float32 (N, 4): x, y, z, reflectance."""
        path = self._file("velodyne_points", "data", f"{frame:010d}.bin")
        data = self._read(path)
        if len(data) % 16:
            raise DatasetError(f"{path}: {len(data)} bytes is not a whole number of (x, y, z, r) float32 points", path=path)
        return np.frombuffer(data, dtype="<f4").reshape(-1, 4)

    def image(self, camera: str, frame: int) -> bytes:
        """A camera's image of a frame, encoded, at most ``image_max_width`` pixels wide."""
        path = self._file(camera, "data", f"{frame:010d}.png")
        data = self._read(path)
        info = sniff_image(data)
        if info is None:
            raise DatasetError(f"{path}: not a PNG image", path=path)
        if info.width <= self.image_max_width:
            return data
        from PIL import Image  # only needed to scale down

        with Image.open(io.BytesIO(data)) as picture:
            height = max(1, round(info.height * self.image_max_width / info.width))
            scaled = picture.resize((self.image_max_width, height), Image.Resampling.BILINEAR)
            out = io.BytesIO()
            scaled.save(out, format="PNG")
        return out.getvalue()

    @cached_property
    def lidar_transform(self) -> list[float]:
        """Velodyne to vehicle, in XVIZ's 16-number order (see the module docstring)."""
        path = self.path.parent / "calib_imu_to_velo.txt"
        translation = None
        for line in self._read(path).decode().splitlines():
            key, _, values = line.partition(":")
            if key.strip() == "T":
                translation = [float(v) for v in values.split()]
        if translation is None or len(translation) != 3:
            raise DatasetError(f"{path}: no 'T:' translation of 3 numbers", path=path)
        x, y, z = (-v for v in translation)
        offset = [round(x, 2), round(y, 2), round(z + IMU_HEIGHT, 2)]
        return [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, *offset, 1]

    @cached_property
    def tracklets(self) -> list[Tracklet]:
        path = self._file("tracklet_labels.xml")
        return read_tracklets(path) if path.is_file() else []

    # -- XVIZ ---------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """The log's metadata, from the timestamps and calibration alone."""
        meta = MetadataBuilder()
        meta.log_info(start_time=float(self.times[0]), end_time=float(self.times[-1]), source=f"KITTI raw {self.name}")
        meta.pose("/vehicle_pose")
        meta.time_series("/vehicle/acceleration", "FLOAT", units="m/s^2")
        meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
        meta.time_series("/vehicle/wheel_angle", "FLOAT", units="deg/s")
        meta.primitive("/vehicle/trajectory", "POLYLINE", coordinate="VEHICLE_RELATIVE",
                       style={"stroke_color": "#47B27588", "stroke_width": 1.4, "stroke_width_min_pixels": 1})
        transform = self.lidar_transform
        meta.primitive("/lidar/points", "POINT", coordinate="VEHICLE_RELATIVE", transform=transform,
                       style={"fill_color": "#00a", "radius_pixels": 1})
        if self.tracklets:
            classes = {name: {"fill_color": color + "80", "stroke_color": color} for name, color in CLASS_COLORS.items()}
            meta.primitive("/tracklets/objects", "POLYGON", coordinate="VEHICLE_RELATIVE", transform=transform,
                           style={"extruded": True, "fill_color": "#00000080"}, style_classes=classes)
            meta.primitive("/tracklets/tracking_point", "CIRCLE", coordinate="VEHICLE_RELATIVE", transform=transform,
                           style={"radius": 0.2, "stroke_width": 0, "fill_color": "#FFC043"})
            meta.primitive("/tracklets/label", "TEXT", coordinate="VEHICLE_RELATIVE", transform=transform,
                           style={"text_size": 18, "fill_color": "#DCDCCD"})
        cameras = [camera for camera in CAMERAS if self._file(camera, "data").is_dir()]
        for camera in cameras:
            meta.primitive(f"/camera/{camera}", "IMAGE")
        meta.ui_panel(ui.panel(
            "Metrics",
            ui.metric(["/vehicle/velocity"], title="Velocity"),
            ui.metric(["/vehicle/acceleration"], title="Acceleration"),
            ui.metric(["/vehicle/wheel_angle"], title="Wheel"),
        ))
        if cameras:
            meta.ui_panel(ui.panel("Camera", ui.video([f"/camera/{c}" for c in cameras])))
        return meta.build()

    def convert(self, frame: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of ``frame`` (the data of an ``xviz/state_update``)."""
        metadata = metadata or self.metadata()
        builder = FrameBuilder(metadata)
        t = float(self.times[frame])
        oxts = self._oxts_cached(frame)
        builder.pose("/vehicle_pose", t, map_origin=(oxts.lon, oxts.lat, oxts.alt), orientation=(oxts.roll, oxts.pitch, oxts.yaw))
        sweep = self.velodyne(frame)
        builder.points("/lidar/points", np.ascontiguousarray(sweep[:, :3]), reflectance_colors(sweep[:, 3]))
        trajectory = self._trajectory(frame, oxts)
        if len(trajectory) >= 2:
            builder.polyline("/vehicle/trajectory", trajectory)
        for stream in metadata["streams"]:
            if stream.startswith("/camera/"):
                camera = stream.removeprefix("/camera/")
                builder.image(stream, self.image(camera, frame))
        if self.tracklets:
            self._add_tracklets(builder, frame)
        builder.time_series("/vehicle/velocity", t, oxts.vf)
        builder.time_series("/vehicle/acceleration", t, oxts.af)
        builder.time_series("/vehicle/wheel_angle", t, math.degrees(oxts.wu))
        return builder.build()

    def _trajectory(self, frame: int, here: Oxts) -> np.ndarray:
        """The next positions of the vehicle in its frame now (x forward, y left)."""
        records = [self._oxts_cached(i) for i in range(frame, min(len(self), frame + TRAJECTORY_LENGTH))]
        lat0 = math.radians(here.lat)
        east = np.array([math.radians(r.lon - here.lon) * EARTH_RADIUS * math.cos(lat0) for r in records])
        north = np.array([math.radians(r.lat - here.lat) * EARTH_RADIUS for r in records])
        up = np.array([r.alt - here.alt for r in records])
        cos, sin = math.cos(here.yaw), math.sin(here.yaw)
        return np.stack([cos * east + sin * north, -sin * east + cos * north, up], axis=1)

    def _add_tracklets(self, builder: FrameBuilder, frame: int) -> None:
        visible = [(i, t) for i, t in enumerate(self.tracklets) if t.first_frame <= frame < t.first_frame + len(t.poses)]
        if not visible:
            return
        poses = np.array([t.poses[frame - t.first_frame] for _, t in visible])
        lengths = np.array([t.length for _, t in visible])
        widths = np.array([t.width for _, t in visible])
        corners = footprints(poses[:, :3], poses[:, 3], lengths, widths)
        for (number, tracklet), pose, polygon in zip(visible, poses, corners):
            object_id = f"{tracklet.object_type}-{number}"
            object_class = tracklet.object_type if tracklet.object_type in CLASS_COLORS else "Unknown"
            builder.polygon("/tracklets/objects", polygon, id=object_id, classes=[object_class], style={"height": tracklet.height})
            builder.circle("/tracklets/tracking_point", pose[:3], 0.2, id=object_id)
            builder.text("/tracklets/label", (pose[0], pose[1], pose[2] + tracklet.height + 0.5), object_id, id=object_id)
