"""The built-in demo: a simulated drive around a city block, as a dataset.

``xviz-server serve`` without ``--data-dir`` serves it (converted on demand,
like any dataset), so that a new user sees something at once; ``xviz-server
convert demo demo OUT`` writes it as a static log::

    from xviz_server.datasets.demo import DemoDrive

    drive = DemoDrive()
    metadata = drive.metadata()
    first = drive.convert(0, metadata)

The vehicle laps a block at about 10 m/s among oncoming and parked cars,
cyclists and pedestrians, past street lights and buildings, while a 32-beam
lidar on its roof sweeps the scene. Everything follows from a fixed seed and
the frame number: a frame is the same whenever and in whatever order it is
made. Every frame carries these streams:

- ``/vehicle_pose``: position and heading in the map frame, whose origin
  is :data:`MAP_ORIGIN`;
- ``/lidar/points``: about 20 000 to 27 000 returns, float32 (N, 3) in the
  vehicle frame, with uint8 (N, 4) colours by height;
- ``/objects/shape``: the footprint of every road user within 60 m, a
  polygon in the map frame, extruded to its height and styled by its class
  (``Car``, ``Cyclist`` or ``Pedestrian``);
- ``/objects/label`` and ``/objects/tracking_point``: its id above it and a
  circle at its centre, in the map frame;
- ``/objects/table``: a table of the same road users, nearest first;
- ``/vehicle/trajectory``: the vehicle's path over the next 5 s, a polyline
  in the vehicle frame;
- ``/vehicle/velocity``, ``/vehicle/acceleration`` and
  ``/vehicle/autonomy_state``: time series.

The map frame has x east, y north and z up, in metres. The vehicle frame has
x forward, y left and z up, from the middle of the vehicle's footprint.
Headings are in radians, counter-clockwise from x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..builder import FrameBuilder, MetadataBuilder, ui

__all__ = ["DemoDrive", "MAP_ORIGIN", "is_demo"]

#: Where the map frame's origin is: a street corner in San Francisco.
MAP_ORIGIN = {"longitude": -122.39913, "latitude": 37.78862, "altitude": 12.5}
SEED = 20_110_926

POSE = "/vehicle_pose"
LIDAR = "/lidar/points"
OBJECT_SHAPES = "/objects/shape"
OBJECT_LABELS = "/objects/label"
OBJECT_CENTERS = "/objects/tracking_point"
OBJECT_TABLE = "/objects/table"
TRAJECTORY = "/vehicle/trajectory"
VELOCITY = "/vehicle/velocity"
ACCELERATION = "/vehicle/acceleration"
AUTONOMY_STATE = "/vehicle/autonomy_state"

#: Colour of each class of road user, as in the KITTI logs of streetscape.gl.
CLASS_COLORS = {"Car": "#50B3FF", "Cyclist": "#957FCE", "Pedestrian": "#FFC6AF"}


def is_demo(path: Path) -> bool:
    """Never: the demo is only served when asked for (``--dataset demo``), never found on disk."""
    return False


@dataclass
class DemoDrive:
    """The simulated drive as a dataset: ``duration`` seconds at ``rate`` frames a second from ``start_time``.

    ``path`` is only the name it is served under. Frame ``k`` has the
    timestamp ``start_time + k / rate``, for every ``k / rate < duration``:
    200 frames by default.
    """

    path: Path = Path("demo")
    duration: float = 20.0
    rate: float = 10.0
    start_time: float = 1_600_000_000.0
    image_max_width: int | None = None  # accepted like every dataset's option; the demo has no images

    def __post_init__(self) -> None:
        if not (self.duration > 0 and self.rate > 0):
            raise ValueError(f"duration and rate must be positive, not {self.duration!r} and {self.rate!r}")
        self.path = Path(self.path)
        self.name = self.path.name

    @cached_property
    def times(self) -> np.ndarray:
        """UNIX time of every frame."""
        count = max(1, math.ceil(self.duration * self.rate - 1e-9))  # k / rate < duration, forgiving rounding
        return self.start_time + np.arange(count) / self.rate

    def __len__(self) -> int:
        return len(self.times)

    def metadata(self) -> dict[str, Any]:
        """The data of the demo's ``xviz/metadata``: every stream, styles and two UI panels."""
        meta = MetadataBuilder()
        meta.log_info(
            start_time=float(self.times[0]),
            end_time=float(self.times[-1]),
            description="xviz-server demo: a simulated drive around a city block",
        )
        meta.pose(POSE)
        meta.primitive(LIDAR, "POINT", coordinate="VEHICLE_RELATIVE", style={"radius_pixels": 2})
        meta.primitive(
            OBJECT_SHAPES,
            "POLYGON",
            coordinate="IDENTITY",
            style={"extruded": True, "fill_color": "#FFFFFF40", "stroke_width": 0.1},
            style_classes={
                name: {"fill_color": f"{color}80", "stroke_color": color} for name, color in CLASS_COLORS.items()
            },
        )
        meta.primitive(
            OBJECT_LABELS,
            "TEXT",
            coordinate="IDENTITY",
            style={"text_size": 14, "fill_color": "#DCDCCD", "text_anchor": "MIDDLE"},
        )
        meta.primitive(OBJECT_CENTERS, "CIRCLE", coordinate="IDENTITY", style={"radius": 0.2, "fill_color": "#FFC043"})
        meta.ui_primitive(OBJECT_TABLE)
        meta.primitive(
            TRAJECTORY,
            "POLYLINE",
            coordinate="VEHICLE_RELATIVE",
            style={"stroke_color": "#47B27588", "stroke_width": 1.4, "stroke_width_min_pixels": 1},
        )
        meta.time_series(VELOCITY, "FLOAT", units="m/s")
        meta.time_series(ACCELERATION, "FLOAT", units="m/s^2")
        meta.time_series(AUTONOMY_STATE, "STRING")
        meta.ui_panel(
            ui.panel(
                "Metrics",
                ui.metric([VELOCITY], title="Velocity", description="The vehicle's speed"),
                ui.metric(
                    [ACCELERATION],
                    title="Acceleration",
                    description="The acceleration of the vehicle along its heading",
                ),
            ),
            needed_streams=[VELOCITY, ACCELERATION],
        )
        meta.ui_panel(
            ui.panel(
                "Road users",
                ui.table(
                    OBJECT_TABLE,
                    title="Road users",
                    description=f"Every road user within {PERCEPTION_RANGE:.0f} m, nearest first",
                ),
            ),
            needed_streams=[OBJECT_TABLE],
        )
        return meta.build()

    def convert(self, frame: int, metadata: dict[str, Any] | None = None) -> dict[str, Any]:
        """The data of frame ``frame``'s ``xviz/state_update``."""
        t = frame / self.rate
        return _drive().frame(FrameBuilder(metadata or self.metadata()), t, float(self.times[frame]), frame)


# --------------------------------------------------------------------------
# The world


@dataclass(frozen=True)
class _Route:
    """A closed loop of straights and arcs, looked up by distance along it."""

    distance: np.ndarray  # (n,) from 0 to the length of the loop
    xy: np.ndarray  # (n, 2) position at each distance
    heading: np.ndarray  # (n,) heading at each distance
    straights: tuple[tuple[float, float], ...]  # (start, end) distance of each straight

    @classmethod
    def around_block(cls, half_x: float, half_y: float, radius: float, step: float = 0.05) -> _Route:
        """Lap a rectangle with rounded corners counter-clockwise, from its bottom left."""
        long_side, short_side, corner = 2 * (half_x - radius), 2 * (half_y - radius), math.pi / 2 * radius
        lengths = np.array([long_side, corner, short_side, corner] * 2)
        knots = np.concatenate([[0.0], np.cumsum(lengths)])
        turns = np.concatenate([[0.0], np.cumsum(lengths * ([0.0, 1 / radius] * 4))])
        distance = np.linspace(0.0, knots[-1], math.ceil(knots[-1] / step) + 1)
        heading = np.interp(distance, knots, turns)
        # Integrate the unit tangent with the trapezoidal rule.
        tangent = np.column_stack([np.cos(heading), np.sin(heading)])
        steps = (tangent[1:] + tangent[:-1]) / 2 * np.diff(distance)[:, None]
        xy = np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + [radius - half_x, -half_y]
        straights = tuple((float(knots[i]), float(knots[i + 1])) for i in range(0, 8, 2))
        return cls(distance, xy, heading, straights)

    @property
    def length(self) -> float:
        return float(self.distance[-1])

    def at(self, s: Any, offset: Any = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Return the position *offset* metres left of the route at distance *s*, and the heading there.

        *s* and *offset* are numbers or arrays; *s* may run over several laps.
        """
        laps, s = np.divmod(s, self.length)
        heading = np.interp(s, self.distance, self.heading) + 2 * math.pi * laps
        x = np.interp(s, self.distance, self.xy[:, 0]) - np.sin(heading) * offset
        y = np.interp(s, self.distance, self.xy[:, 1]) + np.cos(heading) * offset
        return np.stack([x, y], axis=-1), heading


@dataclass(frozen=True)
class _Boxes:
    """Upright boxes standing on the ground: buildings, poles and road users."""

    center: np.ndarray  # (n, 2)
    heading: np.ndarray  # (n,)
    half_size: np.ndarray  # (n, 2): half the length, half the width
    height: np.ndarray  # (n,)

    @classmethod
    def concatenate(cls, parts: Sequence[_Boxes]) -> _Boxes:
        return cls(
            np.concatenate([part.center for part in parts]),
            np.concatenate([part.heading for part in parts]),
            np.concatenate([part.half_size for part in parts]),
            np.concatenate([part.height for part in parts]),
        )

    def __len__(self) -> int:
        return len(self.heading)

    def __getitem__(self, index: Any) -> _Boxes:
        return _Boxes(self.center[index], self.heading[index], self.half_size[index], self.height[index])

    def within(self, point: np.ndarray, distance: float) -> _Boxes:
        """Return the boxes that may have a part within *distance* of *point*."""
        reach = np.hypot(*self.half_size.T)
        return self[np.hypot(*(self.center - point).T) - reach < distance]

    def corners(self) -> np.ndarray:
        """Return the corners of the footprints, (n, 4, 2), counter-clockwise."""
        forward = np.column_stack([np.cos(self.heading), np.sin(self.heading)]) * self.half_size[:, :1]
        left = np.column_stack([-np.sin(self.heading), np.cos(self.heading)]) * self.half_size[:, 1:]
        signs = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]])[:, :, None]
        return self.center[:, None] + signs[:, 0] * forward[:, None] + signs[:, 1] * left[:, None]


@dataclass(frozen=True)
class _RoadUser:
    """A road user that keeps to its lane of the route at a constant speed."""

    object_id: str
    category: str  # a key of SIZES
    lane: float  # metres left of the route
    start: float  # distance along the route at t = 0
    speed: float = 0.0  # metres per second
    direction: int = 1  # 1 along the route, -1 against it


BLOCK_HALF_X, BLOCK_HALF_Y, CORNER_RADIUS = 70.0, 40.0, 14.0  # the route, 416 m a lap

# Lanes, in metres left of the route, the centre of the vehicle's lane. The
# vehicle laps the block counter-clockwise: the block is on its left.
ONCOMING_LANE, PARKING_LANE, INNER_POLES, INNER_SIDEWALK, INNER_FACADE = 3.5, 6.5, 8.0, 9.0, 11.5
BIKE_LANE, OUTER_POLES, OUTER_SIDEWALK, OUTER_FACADE = -2.6, -4.0, -5.3, -8.5

#: Length, width and height of each class of road user, in metres.
SIZES = {"Car": (4.6, 1.9, 1.5), "Cyclist": (1.8, 0.6, 1.7), "Pedestrian": (0.6, 0.6, 1.75)}

ROAD_USERS = (
    _RoadUser("car-1", "Car", 0.0, start=81.0, speed=10.0),
    _RoadUser("car-2", "Car", 0.0, start=36.0, speed=9.8),
    _RoadUser("car-3", "Car", ONCOMING_LANE, start=200.0, speed=11.0, direction=-1),
    _RoadUser("car-4", "Car", ONCOMING_LANE, start=270.0, speed=10.0, direction=-1),
    _RoadUser("car-5", "Car", ONCOMING_LANE, start=330.0, speed=9.0, direction=-1),
    _RoadUser("car-6", "Car", PARKING_LANE, start=95.0, direction=-1),
    _RoadUser("car-7", "Car", PARKING_LANE, start=101.5, direction=-1),
    _RoadUser("car-8", "Car", PARKING_LANE, start=150.0, direction=-1),
    _RoadUser("car-9", "Car", PARKING_LANE, start=230.0, direction=-1),
    _RoadUser("car-10", "Car", PARKING_LANE, start=236.5, direction=-1),
    _RoadUser("cyclist-1", "Cyclist", BIKE_LANE, start=110.0, speed=5.0),
    _RoadUser("cyclist-2", "Cyclist", BIKE_LANE, start=150.0, speed=4.5),
    _RoadUser("pedestrian-1", "Pedestrian", OUTER_SIDEWALK, start=75.0, speed=1.4),
    _RoadUser("pedestrian-2", "Pedestrian", OUTER_SIDEWALK, start=140.0, speed=1.3, direction=-1),
    _RoadUser("pedestrian-3", "Pedestrian", OUTER_SIDEWALK, start=205.0, speed=1.2),
    _RoadUser("pedestrian-4", "Pedestrian", INNER_SIDEWALK, start=120.0, speed=1.5, direction=-1),
    _RoadUser("pedestrian-5", "Pedestrian", INNER_SIDEWALK, start=250.0, speed=1.3),
)

# The vehicle starts halfway along the first long side. Its speed swings
# around MEAN_SPEED, by SPEED_SWING, over SPEED_PERIOD seconds.
EGO_START, MEAN_SPEED, SPEED_SWING, SPEED_PERIOD = 56.0, 10.0, 1.5, 16.0
AUTONOMY_ENGAGED = 2.0  # seconds into the drive
PLAN_HORIZON, PLAN_STEP = 5.0, 0.25  # seconds
PERCEPTION_RANGE = 60.0  # metres


def _ego_distance(t: Any) -> Any:
    """Return how far along the route the vehicle is at time *t* (a number or an array)."""
    omega = 2 * math.pi / SPEED_PERIOD
    return EGO_START + MEAN_SPEED * t + SPEED_SWING / omega * (1 - np.cos(omega * t))


def _ego_speed(t: float) -> float:
    return MEAN_SPEED + SPEED_SWING * math.sin(2 * math.pi / SPEED_PERIOD * t)


def _ego_acceleration(t: float) -> float:
    omega = 2 * math.pi / SPEED_PERIOD
    return SPEED_SWING * omega * math.cos(omega * t)


def _buildings(route: _Route, rng: np.random.Generator) -> _Boxes:
    """Line both sides of every straight with buildings, with gaps between them."""
    rows = ((OUTER_FACADE, -14.0), (INNER_FACADE, 10.0))  # facade, and depth away from the road
    along, lane, size = [], [], []
    for start, end in route.straights:
        for facade, depth in rows:
            s = start + rng.uniform(2.0, 6.0)
            while s + (length := rng.uniform(14.0, 32.0)) < end - 2.0:
                along.append(s + length / 2)
                lane.append(facade + depth / 2)
                size.append((length, abs(depth)))
                s += length + rng.uniform(3.0, 9.0)
    center, heading = route.at(np.array(along), np.array(lane))
    return _Boxes(center, heading, np.array(size) / 2, rng.uniform(7.0, 24.0, len(along)))


def _poles(route: _Route) -> _Boxes:
    """Place street lights every 24 m along both sidewalks."""
    s = np.arange(0.0, route.length, 12.0)
    lane = np.where(np.arange(len(s)) % 2, INNER_POLES, OUTER_POLES)
    center, heading = route.at(s, lane)
    return _Boxes(center, heading, np.full((len(s), 2), 0.12), np.full(len(s), 6.0))


# --------------------------------------------------------------------------
# The lidar
#
# Arrays are float32: it halves the work, and a lidar is no more precise.

LIDAR_HEIGHT = 1.9  # metres above the ground
# The elevations of the beams of a Velodyne VLP-32C, in degrees: densest
# near the horizon, where road users are.
ELEVATIONS = [
    -25.0,
    -15.639,
    -11.31,
    -8.843,
    -7.254,
    -6.148,
    -5.333,
    -4.667,
    -4.0,
    -3.667,
    -3.333,
    -3.0,
    -2.667,
    -2.333,
    -2.0,
    -1.667,
    -1.333,
    -1.0,
    -0.667,
    -0.333,
    0.0,
    0.333,
    0.667,
    1.0,
    1.333,
    1.667,
    2.333,
    3.333,
    4.667,
    7.0,
    10.333,
    15.0,
]
SLOPES = np.tan(np.radians(ELEVATIONS))[:, None].astype(np.float32)  # (beams, 1)
AZIMUTHS = np.linspace(0.0, 2 * math.pi, 900, endpoint=False)
AZIMUTH_COS, AZIMUTH_SIN = np.cos(AZIMUTHS).astype(np.float32), np.sin(AZIMUTHS).astype(np.float32)
MAX_RANGE, RANGE_NOISE, DROPOUT = 70.0, 2, 0.02  # metres, centimetres either way, share of returns lost
NO_HIT = np.float32(1e4)  # a distance beyond any return
with np.errstate(divide="ignore"):
    GROUND_DISTANCE = np.where(SLOPES < 0, -LIDAR_HEIGHT / SLOPES, NO_HIT).astype(np.float32)


def _color_table(step: float) -> np.ndarray:
    """Return RGBA colours for the heights 0, *step*, 2 *step* ... 15 m, uint8 (n, 4)."""
    stops = [0.0, 0.3, 1.0, 2.0, 5.0, 15.0]
    colors = [(45, 75, 140), (0, 160, 200), (60, 215, 120), (245, 220, 60), (245, 130, 40), (215, 50, 60)]
    heights = np.arange(0.0, stops[-1] + step / 2, step)
    table = np.full((len(heights), 4), 255, dtype=np.uint8)
    for channel, values in enumerate(zip(*colors)):
        table[:, channel] = np.interp(heights, stops, values).round()
    return table


COLOR_STEP = 0.05  # metres
COLORS = _color_table(COLOR_STEP)


def _lidar_sweep(
    position: np.ndarray, heading: float, boxes: _Boxes, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Cast one sweep of rays at the ground and *boxes*; return the returns.

    All obstacles are upright boxes, so where a ray meets one depends on the
    ray's azimuth only: each azimuth is traced against each box on the
    ground, then each beam at that azimuth hits the box's side, its roof, or
    the ground first. Returns points, float32 (N, 3) in the vehicle frame to
    the centimetre, and their colours, uint8 (N, 4).
    """
    distance = np.repeat(GROUND_DISTANCE, len(AZIMUTHS), axis=1)  # (beams, azimuths)
    near, far = _ray_box_distances(position, heading, boxes)
    azimuth, box = np.nonzero((near < NO_HIT).T)  # the boxes each azimuth meets, by azimuth
    if azimuth.size:
        height = boxes.height[box].astype(np.float32)
        hits = _beam_box_distances(near[box, azimuth], far[box, azimuth], height)
        first = np.flatnonzero(np.diff(azimuth, prepend=-1))
        azimuth = azimuth[first]
        distance[:, azimuth] = np.minimum(distance[:, azimuth], np.minimum.reduceat(hits, first, axis=1))

    beam, azimuth = np.nonzero(distance <= MAX_RANGE)
    kept = rng.random(beam.size, dtype=np.float32) >= DROPOUT
    beam, azimuth = beam[kept], azimuth[kept]
    noise = rng.integers(-RANGE_NOISE, RANGE_NOISE + 1, beam.size, dtype=np.int8) / np.float32(100)
    distance = distance[beam, azimuth] + noise
    points = np.empty((beam.size, 3), dtype=np.float32)
    points[:, 0] = distance * AZIMUTH_COS[azimuth]
    points[:, 1] = distance * AZIMUTH_SIN[azimuth]
    points[:, 2] = LIDAR_HEIGHT + distance * SLOPES[beam, 0]
    points.round(2, out=points)
    shades = np.clip(points[:, 2] / COLOR_STEP, 0, len(COLORS) - 1).astype(np.intp)
    return points, np.take(COLORS, shades, axis=0)


def _ray_box_distances(position: np.ndarray, heading: float, boxes: _Boxes) -> tuple[np.ndarray, np.ndarray]:
    """Return where each azimuth's ray enters and leaves each box, along the ground.

    Uses the slab method in each box's frame. Both arrays are float32
    (boxes, azimuths), NO_HIT where the ray misses the box.
    """
    turn = boxes.heading - heading
    cos, sin = np.cos(turn).astype(np.float32)[:, None], np.sin(turn).astype(np.float32)[:, None]
    dx = cos * AZIMUTH_COS + sin * AZIMUTH_SIN  # ray directions in the frames of the boxes
    dy = cos * AZIMUTH_SIN - sin * AZIMUTH_COS
    offset = position - boxes.center
    box_cos, box_sin = np.cos(boxes.heading), np.sin(boxes.heading)
    x = offset[:, 0] * box_cos + offset[:, 1] * box_sin  # the lidar in the frames of the boxes
    y = offset[:, 1] * box_cos - offset[:, 0] * box_sin
    low = (-boxes.half_size - np.column_stack([x, y])).astype(np.float32)
    high = (boxes.half_size - np.column_stack([x, y])).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        x1, x2 = low[:, :1] / dx, high[:, :1] / dx
        y1, y2 = low[:, 1:] / dy, high[:, 1:] / dy
    near = np.maximum(np.minimum(x1, x2), np.minimum(y1, y2))
    far = np.minimum(np.maximum(x1, x2), np.maximum(y1, y2))
    hit = (near <= far) & (near > 0)
    return np.where(hit, near, NO_HIT), np.where(hit, far, NO_HIT)


def _beam_box_distances(near: np.ndarray, far: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Return where each beam hits a box, as a distance along the ground.

    *near*, *far* and *height* describe the boxes that rays meet, one per
    ray and box. The result is float32 (beams, len(near)), NO_HIT where the
    beam passes over the box or meets the ground before it.
    """
    z = LIDAR_HEIGHT + near * SLOPES  # height of each beam at the side of the box
    side = (z >= 0) & (z <= height)
    with np.errstate(divide="ignore"):
        roof = (height - LIDAR_HEIGHT) / SLOPES  # where a beam is at the height of the roof
    on_roof = (z > height) & (SLOPES < 0) & (roof <= far)
    return np.where(side, near, np.where(on_roof, roof, NO_HIT))


# --------------------------------------------------------------------------
# Frames


class _Drive:
    """The simulated drive: the state update at any time."""

    def __init__(self) -> None:
        self._route = _Route.around_block(BLOCK_HALF_X, BLOCK_HALF_Y, CORNER_RADIUS)
        scenery = np.random.default_rng(SEED)
        self._scenery = _Boxes.concatenate([_buildings(self._route, scenery), _poles(self._route)])

    def frame(self, frame: FrameBuilder, t: float, timestamp: float, number: int) -> dict[str, Any]:
        """The data of the state update *t* seconds into the drive, frame *number* (which seeds its lidar noise)."""
        position, headings = self._route.at(_ego_distance(t))
        heading = float(headings)
        traffic = self._traffic(t)
        distance = np.hypot(*(traffic.center - position).T)
        nearby = [int(i) for i in np.argsort(distance, kind="stable") if distance[i] < PERCEPTION_RANGE]
        users = [ROAD_USERS[i] for i in nearby]
        obstacles = _Boxes.concatenate([self._scenery, traffic]).within(position, MAX_RANGE)
        points, colors = _lidar_sweep(position, heading, obstacles, np.random.default_rng((SEED, number)))
        frame.pose(
            POSE,
            timestamp,
            map_origin=(MAP_ORIGIN["longitude"], MAP_ORIGIN["latitude"], MAP_ORIGIN["altitude"]),
            position=(float(position[0]), float(position[1]), 0.0),
            orientation=(0.0, 0.0, heading),
        )
        frame.points(LIDAR, points, colors)
        _road_users(frame, users, traffic[nearby], distance[nearby])
        frame.polyline(TRAJECTORY, self._plan(t, position, heading))
        frame.time_series(VELOCITY, timestamp, round(_ego_speed(t), 3))
        frame.time_series(ACCELERATION, timestamp, round(_ego_acceleration(t), 3))
        frame.time_series(AUTONOMY_STATE, timestamp, "autonomous" if t >= AUTONOMY_ENGAGED else "manual")
        return frame.build(timestamp)

    def _traffic(self, t: float) -> _Boxes:
        """Return the boxes of ROAD_USERS at time *t*, in order."""
        along = [user.start + user.direction * user.speed * t for user in ROAD_USERS]
        center, heading = self._route.at(np.array(along), np.array([user.lane for user in ROAD_USERS]))
        heading = heading + np.array([0.0 if user.direction > 0 else math.pi for user in ROAD_USERS])
        sizes = np.array([SIZES[user.category] for user in ROAD_USERS])
        return _Boxes(center, heading, sizes[:, :2] / 2, sizes[:, 2])

    def _plan(self, t: float, position: np.ndarray, heading: float) -> np.ndarray:
        """Return the vehicle's path over the next PLAN_HORIZON seconds, float32 (n, 3) in its frame."""
        path, _ = self._route.at(_ego_distance(t + np.arange(0.0, PLAN_HORIZON + PLAN_STEP / 2, PLAN_STEP)))
        offset = path - position
        cos, sin = math.cos(heading), math.sin(heading)
        forward, left = offset @ [cos, sin], offset @ [-sin, cos]
        return np.column_stack([forward, left, np.zeros(len(path))]).round(2).astype(np.float32)


_shared_drive: _Drive | None = None


def _drive() -> _Drive:
    """The world, made once per process (its scenery is the same for every frame)."""
    global _shared_drive
    if _shared_drive is None:
        _shared_drive = _Drive()
    return _shared_drive


def _road_users(frame: FrameBuilder, users: list[_RoadUser], boxes: _Boxes, distances: np.ndarray) -> None:
    """Add the footprints, labels, centres and table of *users*, in the map frame, at these *distances*."""
    footprints = np.concatenate([boxes.corners(), np.zeros((len(boxes), 4, 1))], axis=2)
    footprints = footprints.round(2).astype(np.float32)
    centers = boxes.center.round(2).tolist()
    for user, footprint, (x, y), height in zip(users, footprints, centers, boxes.height.tolist()):
        # The height is the object's own; the schema wants a colour beside it: the class's outline.
        style = {"stroke_color": CLASS_COLORS[user.category], "height": height}
        frame.polygon(OBJECT_SHAPES, footprint, id=user.object_id, classes=[user.category], style=style)
        frame.text(OBJECT_LABELS, (x, y, height + 0.5), user.object_id, id=user.object_id)
        frame.circle(OBJECT_CENTERS, (x, y, 0.0), 0.2, id=user.object_id)
    columns: list[tuple[str, str] | tuple[str, str, str]] = [
        ("Object", "STRING"),
        ("Class", "STRING"),
        ("Distance", "DOUBLE", "m"),
        ("Speed", "DOUBLE", "m/s"),
    ]
    nodes = [
        (i, None, [user.object_id, user.category, round(float(distance), 1), round(user.speed, 1)])
        for i, (user, distance) in enumerate(zip(users, distances))
    ]
    frame.treetable(OBJECT_TABLE, columns, nodes)
