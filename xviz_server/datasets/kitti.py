"""KITTI raw drives as XVIZ, with the streams of the official KITTI converter.

A drive is ``<date>/<date>_drive_<nnnn>_sync/`` with ``oxts/``,
``velodyne_points/`` and ``image_00`` .. ``image_03`` (each a
``timestamps.txt`` and a ``data/`` folder) and optionally
``tracklet_labels.xml``; the calibration files ``calib_*.txt`` are in the
date folder.

Conventions, found by reproducing the official converter's output
(``shared/data/kitti-2011_09_26_drive_0001-head``):

* **Time**: ``timestamps.txt`` holds UTC wall-clock times with nanoseconds;
  the log uses UNIX seconds truncated to the millisecond (JavaScript's
  ``Date.parse`` of the line with ``GMT`` appended). Frame ``i`` takes the
  time of OXTS record ``i``.
* **Pose**: ``map_origin`` is the OXTS latitude, longitude and altitude,
  ``position`` is zero and ``orientation`` the OXTS roll, pitch and yaw.
* **Lidar colour**: a point of reflectance ``r`` is coloured
  ``(80 + 80 r, 80 r, 60 r)``, computed in double precision from the float32
  reflectance and truncated to uint8 (see
  :func:`~xviz_server.datasets.shared.reflectance_colors`).
* **Lidar placement**: the stream is ``VEHICLE_RELATIVE`` with a translation
  only, (0.81, -0.32, 1.73) for every 2011_09_26 drive. The official
  converter typed in the numbers of the KITTI set-up page; they follow from
  ``calib_imu_to_velo.txt`` (``p_velo = R p_imu + T``) as minus ``T``
  rounded to the centimetre, (0.81, -0.32, 0.80), raised by the IMU's
  0.93 m above the ground, which puts the velodyne at its 1.73 m above the
  ground. The rotation ``R`` (under a degree) is dropped, and with it the
  exact offset ``-R^T T`` = (0.8105, -0.3071, 0.8027), which would round to
  -0.31 in y.
* **Images**: scaled down to fit ``image_max_width``, the height rounded
  down, as the official converter's ``Math.floor``; narrower images pass
  through as the file's bytes.
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

import io
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui
from ..codec.image import sniff_image
from ..exceptions import DatasetError
from ..store.path import StoreTree
from ..unpack import check_frame
from . import DEFAULT_IMAGE_WIDTH
from .images import encode_like, fit_width
from .sensors import file_size
from .shared import EARTH_RADIUS, footprints, reflectance_colors

__all__ = [
    "FrameObjects",
    "KittiDrive",
    "Oxts",
    "Tracklet",
    "find_drive",
    "is_kitti_drive",
    "read_calibration",
    "read_timestamps",
    "read_tracklets",
    "visible_objects",
]

CAMERAS = ("image_00", "image_01", "image_02", "image_03")
CALIBRATION = "calib_imu_to_velo.txt"  # the one calibration file the conversion reads
IMU_HEIGHT = 0.93  # metres above the ground, from the KITTI set-up page
TRAJECTORY_LENGTH = 50
CLASS_COLORS = {
    "Car": "#50B3FF",
    "Cyclist": "#957FCE",
    "Pedestrian": "#FFC6AF",
    "Van": "#5B91F4",
    "Unknown": "#E2E2E2",
}


def is_kitti_drive(path: Path | StoreTree) -> bool:
    """Whether ``path`` is a KITTI raw drive folder (``oxts`` and ``velodyne_points`` with timestamps)."""
    return (path / "oxts" / "timestamps.txt").is_file() and (path / "velodyne_points" / "data").is_dir()


def find_drive(path: Path | StoreTree) -> Path | StoreTree:
    """The KITTI raw drive folder that ``path`` names, with the calibration beside it.

    ``path`` is a drive folder, a date folder (``2011_09_26``, holding the
    drives and the ``calib_*.txt`` files) or the folder above date folders.
    Raises :class:`~xviz_server.exceptions.DatasetError` when it holds no
    drive, several (listing them, to give one), or when the calibration is
    not in the drive's parent folder (a drive folder given alone).
    """
    if is_kitti_drive(path):
        drive = path
    else:
        drives = sorted((p for p in [*path.glob("*"), *path.glob("*/*")] if p.is_dir() and is_kitti_drive(p)), key=str)
        if not drives:
            raise DatasetError(
                f"{path}: not a KITTI raw drive, date folder or folder of dates (no drive with oxts/ and velodyne_points/)",
                path=path,
            )
        if len(drives) > 1:
            listed = ", ".join(str(p) for p in drives)
            raise DatasetError(f"{path}: {len(drives)} KITTI drives, give one of them: {listed}", path=path)
        (drive,) = drives
    calibration = drive.parent / CALIBRATION
    if not calibration.is_file():
        raise DatasetError(
            f"{calibration} not found: KITTI keeps the calibration files in the date folder above each drive; "
            f"give (or mount) the date folder, or the drive inside it",
            path=calibration,
        )
    return drive


def _read_bytes(path: Path | StoreTree) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path}: {exc.strerror or exc}", path=path) from None


def _read_text(path: Path | StoreTree) -> str:
    try:
        return _read_bytes(path).decode("ascii")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: byte {exc.start} is not ASCII; not a KITTI text file", path=path) from None


def _png_size(head: bytes, path: Path | StoreTree) -> tuple[int, int]:
    info = sniff_image(head)
    if info is None or info.mime_type != "image/png":
        raise DatasetError(f"{path}: not a PNG image", path=path)
    return info.width, info.height


def read_timestamps(path: Path | StoreTree) -> np.ndarray:
    """The times of a ``timestamps.txt``, float64 UNIX seconds truncated to the millisecond.

    Each line is a UTC time with nanoseconds, ``2011-09-26 13:02:25.964389445``;
    blank lines are skipped.
    """
    milliseconds: list[int] = []
    for number, line in enumerate(_read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            nanoseconds = int(np.datetime64(line.strip(), "ns").astype(np.int64))
        except ValueError:
            raise DatasetError(f"{path}, line {number}: {line.strip()!r} is not a KITTI timestamp", path=path) from None
        milliseconds.append(nanoseconds // 1_000_000)
    return np.array(milliseconds, dtype=np.int64) / 1000


def read_calibration(path: Path | StoreTree) -> dict[str, np.ndarray]:
    """The numeric entries of a KITTI ``calib_*.txt``, by name (``R``, ``T``, ``P_rect_02`` ...).

    Entries of 9 numbers (rotations, camera matrices) are (3, 3), of 12
    numbers (projections) (3, 4), others flat; ``calib_time`` is skipped.
    """
    entries: dict[str, np.ndarray] = {}
    for line in _read_text(path).splitlines():
        key, _, values = line.partition(":")
        if key.strip() == "calib_time" or not values.strip():
            continue
        try:
            numbers = np.array([float(v) for v in values.split()])
        except ValueError:
            raise DatasetError(f"{path}: {key.strip()!r} is not a list of numbers", path=path) from None
        entries[key.strip()] = numbers.reshape({9: (3, 3), 12: (3, 4)}.get(len(numbers), -1))
    return entries


@dataclass(frozen=True, slots=True)
class Oxts:
    """One OXTS record, the 30 fields of ``oxts/dataformat.txt`` in its order.

    Angles are radians, velocities m/s, accelerations m/s², angular rates
    rad/s; ``f``, ``l``, ``u`` are forward, left and up parallel or normal
    to the earth's surface, ``x``, ``y``, ``z`` the vehicle's axes.
    """

    lat: float
    lon: float
    alt: float
    roll: float
    pitch: float
    yaw: float
    vn: float
    ve: float
    vf: float
    vl: float
    vu: float
    ax: float
    ay: float
    az: float
    af: float
    al: float
    au: float
    wx: float
    wy: float
    wz: float
    wf: float
    wl: float
    wu: float
    pos_accuracy: float
    vel_accuracy: float
    navstat: int
    numsats: int
    posmode: int
    velmode: int
    orimode: int

    @classmethod
    def parse(cls, text: str, path: Path | StoreTree) -> Oxts:
        """The record in the text of ``oxts/data/<frame>.txt``; ``path`` names the file in errors."""
        values = text.split()
        try:
            if len(values) != 30:
                raise ValueError
            return cls(*[float(v) for v in values[:25]], *[int(float(v)) for v in values[25:]])  # type: ignore[arg-type]
        except ValueError:
            raise DatasetError(f"{path}: not an OXTS record of 30 numbers", path=path) from None


@dataclass(frozen=True)
class Tracklet:
    """One tracked object: class, box size, first frame and a pose per frame."""

    object_type: str
    height: float
    width: float
    length: float
    first_frame: int
    poses: np.ndarray  # (frames, 4): tx, ty, tz, rz (yaw) in the velodyne frame; tz is the box's bottom


@dataclass(frozen=True)
class FrameObjects:
    """The tracklets present in one frame, as parallel arrays (velodyne frame).

    ``ids`` are the tracklets' positions in ``tracklet_labels.xml``,
    ``sizes`` their length, width and height, ``positions`` the centres of
    their bottoms, ``yaws`` their rotations about z.
    """

    ids: np.ndarray  # (N,) int
    classes: tuple[str, ...]
    sizes: np.ndarray  # (N, 3)
    positions: np.ndarray  # (N, 3)
    yaws: np.ndarray  # (N,)

    def __len__(self) -> int:
        return len(self.ids)

    def footprints(self) -> np.ndarray:
        """The four ground corners of each box, (N, 4, 3); see :func:`footprints`."""
        return footprints(self.positions, self.yaws, self.sizes[:, 0], self.sizes[:, 1])


def _number(element: ElementTree.Element, key: str, path: Path | StoreTree, where: str) -> float:
    text = element.findtext(key)
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        problem = "is missing" if text is None else f"is {text.strip()!r}, not a number"
        raise DatasetError(f"{path}: {where}: <{key}> {problem}", path=path) from None


def _count(element: ElementTree.Element, items: list[ElementTree.Element], path: Path | StoreTree, what: str) -> None:
    """Check a boost ``<count>`` against the items present (a file cut short has fewer)."""
    count = element.findtext("count")
    if count is not None and count.strip() != str(len(items)):
        raise DatasetError(f"{path}: {what} says {count.strip()} items but has {len(items)}", path=path)


def read_tracklets(path: Path | StoreTree) -> list[Tracklet]:
    """Parse a ``tracklet_labels.xml`` (the devkit's boost serialisation XML)."""
    try:
        with path.open("rb") as file:
            root = ElementTree.parse(file).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise DatasetError(f"{path}: cannot read tracklets: {exc}", path=path) from None
    container = root.find("tracklets")
    if container is None:
        raise DatasetError(f"{path}: no <tracklets> element", path=path)
    items = container.findall("item")
    _count(container, items, path, "<tracklets>")
    tracklets: list[Tracklet] = []
    for index, item in enumerate(items):
        where = f"tracklet {index}"
        poses = item.find("poses")
        pose_items = [] if poses is None else poses.findall("item")
        if poses is not None:
            _count(poses, pose_items, path, f"{where}'s <poses>")
        tracklets.append(
            Tracklet(
                object_type=(item.findtext("objectType") or "Unknown").strip(),
                height=_number(item, "h", path, where),
                width=_number(item, "w", path, where),
                length=_number(item, "l", path, where),
                first_frame=int(_number(item, "first_frame", path, where)),
                poses=np.array(
                    [
                        [_number(pose, key, path, f"{where}, pose {j}") for key in ("tx", "ty", "tz", "rz")]
                        for j, pose in enumerate(pose_items)
                    ],
                    dtype=np.float64,
                ).reshape(-1, 4),
            )
        )
    return tracklets


def visible_objects(tracklets: list[Tracklet], frame: int) -> FrameObjects:
    """The tracklets that have a pose in ``frame``, with that pose."""
    present = [(i, t) for i, t in enumerate(tracklets) if t.first_frame <= frame < t.first_frame + len(t.poses)]
    poses = np.array([t.poses[frame - t.first_frame] for _, t in present]).reshape(-1, 4)
    return FrameObjects(
        ids=np.array([i for i, _ in present], dtype=np.int64),
        classes=tuple(t.object_type for _, t in present),
        sizes=np.array([(t.length, t.width, t.height) for _, t in present], dtype=np.float64).reshape(-1, 3),
        positions=poses[:, :3],
        yaws=poses[:, 3],
    )


@dataclass
class KittiDrive:
    """A KITTI raw drive: its raw data by frame, and each frame converted to XVIZ.

    ``path`` is the drive folder inside its date folder, the date folder
    (holding one drive), or the folder above date folders (holding one drive
    in all); see :func:`find_drive`; or such a folder in an object store (a
    :class:`~xviz_server.store.path.StoreTree`, each file one GET). Images wider than ``image_max_width`` are scaled down (aspect
    kept) and re-encoded as PNG. Small and picklable: worker processes get a
    copy and read the files themselves. Every missing or unreadable file
    raises :class:`~xviz_server.exceptions.DatasetError` naming it.
    """

    path: Path | StoreTree
    image_max_width: int = DEFAULT_IMAGE_WIDTH
    name: str = field(init=False)
    _oxts_cache: dict[int, Oxts] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.path = find_drive(self.path if isinstance(self.path, StoreTree) else Path(self.path))
        self.name = self.path.name

    # -- raw data ---------------------------------------------------------

    def timestamps(self, sensor: str) -> np.ndarray:
        """UNIX times of a sensor's records (``oxts``, ``velodyne_points``, ``image_02`` ...)."""
        return read_timestamps(self.path / sensor / "timestamps.txt")

    @cached_property
    def times(self) -> np.ndarray:
        """UNIX time of every frame, from the OXTS timestamps (no frame data read)."""
        return self.timestamps("oxts")

    def __len__(self) -> int:
        return len(self.times)

    def oxts(self, frame: int) -> Oxts:
        """The OXTS record of a frame (position, orientation, velocities ...)."""
        path = self.path / "oxts" / "data" / f"{frame:010d}.txt"
        return Oxts.parse(_read_text(path), path)

    def velodyne_path(self, frame: int) -> Path | StoreTree:
        """Where the velodyne sweep of a frame is (``velodyne_points/data/0000000007.bin``)."""
        return self.path / "velodyne_points" / "data" / f"{frame:010d}.bin"

    def velodyne(self, frame: int) -> np.ndarray:
        """The velodyne sweep of a frame, read-only float32 (N, 4): x, y, z, reflectance."""
        path = self.velodyne_path(frame)
        data = _read_bytes(path)
        if len(data) % 16:
            raise DatasetError(
                f"{path}: {len(data)} bytes is not a whole number of (x, y, z, r) float32 points", path=path
            )
        return np.frombuffer(data, dtype="<f4").reshape(-1, 4)

    @cached_property
    def cameras(self) -> tuple[str, ...]:
        """The camera folders the drive has, of ``image_00`` .. ``image_03``."""
        return tuple(camera for camera in CAMERAS if (self.path / camera / "data").is_dir())

    def image_path(self, camera: str, frame: int) -> Path | StoreTree:
        """Where a camera's image of a frame is (``image_02/data/0000000007.png``)."""
        return self.path / camera / "data" / f"{frame:010d}.png"

    def image_size(self, camera: str, frame: int) -> tuple[int, int]:
        """Width and height of a camera's image of a frame, from its PNG header alone."""
        path = self.image_path(camera, frame)
        try:
            with path.open("rb") as file:
                head = file.read(32)
        except OSError as exc:
            raise DatasetError(f"{path}: {exc.strerror or exc}", path=path) from None
        return _png_size(head, path)

    def image(self, camera: str, frame: int) -> bytes:
        """A camera's image of a frame as PNG, at most ``image_max_width`` pixels wide.

        An image that fits is the file's bytes, not decoded; a wider one is
        scaled to that width with its height rounded down, as the official
        converter did.
        """
        path = self.image_path(camera, frame)
        data = _read_bytes(path)
        width, _ = _png_size(data, path)
        if width <= self.image_max_width:
            return data
        from PIL import Image  # only needed to scale down

        try:
            with Image.open(io.BytesIO(data)) as picture:
                scaled = fit_width(picture, self.image_max_width)
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{path}: cannot decode the PNG: {exc}", path=path) from None
        return encode_like("image/png", scaled)

    def calibration(self, name: str) -> dict[str, np.ndarray]:
        """The date folder's ``calib_<name>.txt`` (``imu_to_velo``, ``velo_to_cam``, ``cam_to_cam``)."""
        return read_calibration(self.path.parent / f"calib_{name}.txt")

    @cached_property
    def lidar_transform(self) -> list[float]:
        """Velodyne to vehicle as the official metadata has it: XVIZ's 16 numbers, a translation.

        See the module docstring for how (0.81, -0.32, 1.73) follows from
        ``calib_imu_to_velo.txt``.
        """
        path = self.path.parent / CALIBRATION
        translation = self.calibration("imu_to_velo").get("T")
        if translation is None or translation.shape != (3,):
            raise DatasetError(f"{path}: no 'T:' translation of 3 numbers", path=path)
        x, y, z = (-float(v) for v in translation)
        offset = [round(x, 2), round(y, 2), round(z + IMU_HEIGHT, 2)]
        return [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, *offset, 1]

    @cached_property
    def tracklets(self) -> list[Tracklet]:
        """The drive's tracklets; none without ``tracklet_labels.xml``."""
        path = self.path / "tracklet_labels.xml"
        return read_tracklets(path) if path.is_file() else []

    def objects(self, frame: int) -> FrameObjects:
        """The tracklets present in a frame."""
        return visible_objects(self.tracklets, frame)

    # -- XVIZ ---------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """The log's metadata, from the timestamps, the calibration and the tracklets: no frame is read."""
        meta = MetadataBuilder()
        meta.log_info(start_time=float(self.times[0]), end_time=float(self.times[-1]), source=f"KITTI raw {self.name}")
        meta.pose("/vehicle_pose")
        meta.time_series("/vehicle/acceleration", "FLOAT", units="m/s^2")
        meta.time_series("/vehicle/velocity", "FLOAT", units="m/s")
        meta.time_series("/vehicle/wheel_angle", "FLOAT", units="deg/s")
        meta.primitive(
            "/vehicle/trajectory",
            "POLYLINE",
            coordinate="VEHICLE_RELATIVE",
            style={"stroke_color": "#47B27588", "stroke_width": 1.4, "stroke_width_min_pixels": 1},
        )
        transform = self.lidar_transform
        meta.primitive(
            "/lidar/points",
            "POINT",
            coordinate="VEHICLE_RELATIVE",
            transform=transform,
            style={"fill_color": "#00a", "radius_pixels": 1},
        )
        if self.tracklets:
            classes = {
                name: {"fill_color": color + "80", "stroke_color": color} for name, color in CLASS_COLORS.items()
            }
            meta.primitive(
                "/tracklets/objects",
                "POLYGON",
                coordinate="VEHICLE_RELATIVE",
                transform=transform,
                style={"extruded": True, "fill_color": "#00000080"},
                style_classes=classes,
            )
            meta.primitive(
                "/tracklets/tracking_point",
                "CIRCLE",
                coordinate="VEHICLE_RELATIVE",
                transform=transform,
                style={"radius": 0.2, "stroke_width": 0, "fill_color": "#FFC043"},
            )
            meta.primitive(
                "/tracklets/label",
                "TEXT",
                coordinate="VEHICLE_RELATIVE",
                transform=transform,
                style={"text_size": 18, "fill_color": "#DCDCCD"},
            )
        for camera in self.cameras:
            meta.primitive(f"/camera/{camera}", "IMAGE")
        meta.ui_panel(
            ui.panel(
                "Metrics",
                ui.metric(["/vehicle/velocity"], title="Velocity"),
                ui.metric(["/vehicle/acceleration"], title="Acceleration"),
                ui.metric(["/vehicle/wheel_angle"], title="Wheel"),
            )
        )
        if self.cameras:
            meta.ui_panel(ui.panel("Camera", ui.video([f"/camera/{c}" for c in self.cameras])))
        return meta.build()

    def convert(self, frame: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The state update of ``frame`` (the data of an ``xviz/state_update``).

        Raises :class:`~xviz_server.exceptions.FrameSizeError`, the frame unread, when its sweep and images
        are more than :data:`~xviz_server.unpack.MAX_FRAME_BYTES` in all (see :func:`~xviz_server.unpack.check_frame`).
        """
        metadata = metadata or self.metadata()
        cameras = [stream.removeprefix("/camera/") for stream in metadata["streams"] if stream.startswith("/camera/")]
        files = [self.velodyne_path(frame), *(self.image_path(camera, frame) for camera in cameras)]
        check_frame(sum(map(file_size, files)), frame, str(self.path), self.path)
        builder = FrameBuilder(metadata)
        t = float(self.times[frame])
        oxts = self._oxts_cached(frame)
        builder.pose(
            "/vehicle_pose", t, map_origin=(oxts.lon, oxts.lat, oxts.alt), orientation=(oxts.roll, oxts.pitch, oxts.yaw)
        )
        sweep = self.velodyne(frame)
        builder.points("/lidar/points", np.ascontiguousarray(sweep[:, :3]), reflectance_colors(sweep[:, 3]))
        trajectory = self._trajectory(frame, oxts)
        if len(trajectory) >= 2:
            builder.polyline("/vehicle/trajectory", trajectory)
        for camera in cameras:
            builder.image(f"/camera/{camera}", self.image(camera, frame))
        if self.tracklets:
            self._add_tracklets(builder, frame)
        builder.time_series("/vehicle/velocity", t, oxts.vf)
        builder.time_series("/vehicle/acceleration", t, oxts.af)
        builder.time_series("/vehicle/wheel_angle", t, math.degrees(oxts.wu))
        return builder.build()

    def _oxts_cached(self, frame: int) -> Oxts:
        """OXTS records are read once per process: each frame's trajectory needs the next 50."""
        if frame not in self._oxts_cache:
            self._oxts_cache[frame] = self.oxts(frame)
        return self._oxts_cache[frame]

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
        objects = self.objects(frame)
        corners = objects.footprints()
        for number, object_type, size, position, polygon in zip(
            objects.ids, objects.classes, objects.sizes, objects.positions, corners
        ):
            object_id = f"{object_type}-{number}"
            object_class = object_type if object_type in CLASS_COLORS else "Unknown"
            height = float(size[2])
            # The height is the object's own; the schema wants a colour beside it: the class's outline.
            style = {"stroke_color": CLASS_COLORS[object_class], "height": height}
            builder.polygon("/tracklets/objects", polygon, id=object_id, classes=[object_class], style=style)
            builder.circle("/tracklets/tracking_point", position, 0.2, id=object_id)
            builder.text(
                "/tracklets/label", (position[0], position[1], position[2] + height + 0.5), object_id, id=object_id
            )
