"""An MCAP file as the Foxglove SDK writes it: Foxglove's well-known schemas in protobuf, no profile, plus a JSON
channel written with the mcap package's own writer (as Lichtblick and the JSON examples do)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

T0 = 1_700_000_000 * 10**9
STEP = 100_000_000
FRAMES = 4
#: The points of each cloud: the third is a beam without a return.
POINTS = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [0.0, 0.0, 0.0]], np.float32)
#: A quarter turn left about z, as /lidar_posed's pose: the sensor's x is the vehicle's y.
QUARTER_LEFT_XYZW = (0.0, 0.0, float(np.sqrt(0.5)), float(np.sqrt(0.5)))


def _png(width: int, height: int) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.full((height, width, 3), 200, np.uint8)).save(out, "PNG")
    return out.getvalue()


def write_sdk_recording(path: Path) -> Path:
    """``path``: /lidar (PointCloud), /lidar_posed (the same cloud with a pose in its frame), /camera
    (CompressedImage), /raw (RawImage), /tf (FrameTransforms: base_link 1 m further along x a frame), /goal
    (PoseInFrame), /route (PosesInFrame), /wheel_odom (Odometry), /gps (LocationFix), /fixes (LocationFixes), /scene
    (SceneUpdate: a cube, a model and a text), /scan (LaserScan), /log (Log), and /json_log (foxglove.Log in JSON)."""
    import foxglove
    from foxglove import channels as ch
    from foxglove import messages as fm

    context = foxglove.Context()
    channels = {
        name: kind(name, context=context)
        for name, kind in (
            ("/lidar", ch.PointCloudChannel),
            ("/camera", ch.CompressedImageChannel),
            ("/raw", ch.RawImageChannel),
            ("/tf", ch.FrameTransformsChannel),
            ("/goal", ch.PoseInFrameChannel),
            ("/gps", ch.LocationFixChannel),
            ("/scene", ch.SceneUpdateChannel),
            ("/scan", ch.LaserScanChannel),
            ("/log", ch.LogChannel),
            ("/lidar_posed", ch.PointCloudChannel),
            ("/route", ch.PosesInFrameChannel),
            ("/wheel_odom", ch.OdometryChannel),
            ("/fixes", ch.LocationFixesChannel),
        )
    }
    identity = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    quarter_left = fm.Quaternion(**dict(zip("xyzw", QUARTER_LEFT_XYZW)))
    float32 = fm.PackedElementFieldNumericType.Float32
    with foxglove.open_mcap(path, allow_overwrite=True, context=context):
        for i in range(FRAMES):
            t = T0 + i * STEP
            stamp = fm.Timestamp(sec=t // 10**9, nsec=t % 10**9)
            at = {"log_time": t}
            # The same points twice: in the vehicle frame, and seen by a sensor 1 m up turned a quarter left.
            for topic, z, turn in (("/lidar", 0.0, identity), ("/lidar_posed", 1.0, quarter_left)):
                channels[topic].log(
                    fm.PointCloud(
                        timestamp=stamp,
                        frame_id="base_link",
                        pose=fm.Pose(position=fm.Vector3(x=0.0, y=0.0, z=z), orientation=turn),
                        point_stride=12,
                        fields=[fm.PackedElementField(name=a, offset=4 * k, type=float32) for k, a in enumerate("xyz")],
                        data=POINTS.tobytes(),
                    ),
                    **at,
                )
            channels["/route"].log(
                fm.PosesInFrame(
                    timestamp=stamp,
                    frame_id="base_link",
                    poses=[
                        fm.Pose(position=fm.Vector3(x=float(x), y=2.0, z=0.0), orientation=identity) for x in (3, 6)
                    ],
                ),
                **at,
            )
            channels["/wheel_odom"].log(
                fm.Odometry(
                    timestamp=stamp,
                    frame_id="world",
                    body_frame_id="base_link",
                    pose=fm.Pose(position=fm.Vector3(x=float(i), y=0.5, z=0.0), orientation=identity),
                    linear_velocity=fm.Vector3(x=10.0, y=0.0, z=0.0),
                    angular_velocity=fm.Vector3(x=0.0, y=0.0, z=0.25),
                ),
                **at,
            )
            channels["/fixes"].log(
                fm.LocationFixes(
                    fixes=[
                        fm.LocationFix(timestamp=stamp, frame_id="gps", latitude=49.0, longitude=8.4, altitude=110.0),
                        fm.LocationFix(timestamp=stamp, frame_id="gps2", latitude=0.0, longitude=0.0, altitude=0.0),
                    ]
                ),
                **at,
            )
            channels["/camera"].log(
                fm.CompressedImage(timestamp=stamp, frame_id="camera", data=_png(32, 16), format="png"), **at
            )
            channels["/raw"].log(
                fm.RawImage(
                    timestamp=stamp,
                    frame_id="camera",
                    width=4,
                    height=2,
                    encoding="rgb8",
                    step=12,
                    data=bytes(range(24)),
                ),
                **at,
            )
            channels["/tf"].log(
                fm.FrameTransforms(
                    transforms=[
                        fm.FrameTransform(
                            timestamp=stamp,
                            parent_frame_id="world",
                            child_frame_id="base_link",
                            translation=fm.Vector3(x=float(i), y=0.0, z=0.0),
                            rotation=identity,
                        )
                    ]
                ),
                **at,
            )
            channels["/goal"].log(
                fm.PoseInFrame(
                    timestamp=stamp,
                    frame_id="world",
                    pose=fm.Pose(position=fm.Vector3(x=10.0 + i, y=1.0, z=0.0), orientation=identity),
                ),
                **at,
            )
            channels["/gps"].log(
                fm.LocationFix(
                    timestamp=stamp, frame_id="gps", latitude=49.0, longitude=8.4 + i * 1e-5, altitude=110.0
                ),
                **at,
            )
            channels["/scene"].log(
                fm.SceneUpdate(
                    entities=[
                        fm.SceneEntity(
                            timestamp=stamp,
                            frame_id="base_link",
                            id="car",
                            cubes=[
                                fm.CubePrimitive(
                                    pose=fm.Pose(position=fm.Vector3(x=5.0, y=0.0, z=0.0), orientation=identity),
                                    size=fm.Vector3(x=4.0, y=2.0, z=1.5),
                                    color=fm.Color(r=1.0, g=0.0, b=0.0, a=1.0),
                                )
                            ],
                            models=[  # a mesh: not drawn, as a ROS mesh marker
                                fm.ModelPrimitive(
                                    pose=fm.Pose(position=fm.Vector3(x=5.0, y=0.0, z=0.0), orientation=identity),
                                    scale=fm.Vector3(x=1.0, y=1.0, z=1.0),
                                    url="package://car/car.dae",
                                )
                            ],
                            texts=[
                                fm.TextPrimitive(
                                    pose=fm.Pose(position=fm.Vector3(x=5.0, y=0.0, z=2.0), orientation=identity),
                                    text="car",
                                    color=fm.Color(r=1.0, g=1.0, b=1.0, a=1.0),
                                )
                            ],
                        )
                    ]
                ),
                **at,
            )
            channels["/scan"].log(
                fm.LaserScan(
                    timestamp=stamp,
                    frame_id="base_link",
                    start_angle=0.0,
                    end_angle=np.pi / 2,
                    ranges=[2.0, float("inf"), 3.0],
                    intensities=[],
                ),
                **at,
            )
            channels["/log"].log(
                fm.Log(
                    timestamp=stamp,
                    level=fm.LogLevel.Warning,
                    message=f"frame {i}",
                    name="planner",
                    file="plan.py",
                    line=7,
                ),
                **at,
            )
    _add_json_channel(path)
    return path


def _add_json_channel(path: Path) -> None:
    """Rewrite ``path`` with the mcap package's writer, adding /json_log: foxglove.Log messages in JSON."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with path.open("rb") as source:
        reader = make_reader(source)
        records = list(reader.iter_messages())
    out = io.BytesIO()
    writer = Writer(out)
    writer.start()
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    for schema, channel, message in records:
        if schema.id not in schemas:
            schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schemas[schema.id])
        writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
    log_schema = writer.register_schema("foxglove.Log", "jsonschema", json.dumps({"type": "object"}).encode())
    json_log = writer.register_channel("/json_log", "json", log_schema)
    for i in range(FRAMES):
        t = T0 + i * STEP
        document = {
            "timestamp": {"sec": t // 10**9, "nsec": t % 10**9},
            "level": 4,
            "message": f"json {i}",
            "name": "json",
            "file": "",
            "line": 0,
        }
        writer.add_message(json_log, t, json.dumps(document).encode(), t)
    writer.finish()
    path.write_bytes(out.getvalue())
