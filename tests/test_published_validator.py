"""Every message the server sends, from every source it has, is valid to the published validator.

The validator is the published client's own definition of a correct message:
``@xviz/schema`` 1.0.13's ``XVIZValidator``, run by ``tests/interop/validate.js``
inside the published client's session driver (``xviz-session.js --validate``).
For each source in :data:`SOURCES`, a real server serves it over a real
socket, in JSON and in GLB, and the driver validates the metadata and every
state update of a window of :data:`WINDOW` seconds from the start of the log
(two frames: every frame of a source here has the same streams, and the
KITTI ones are 2 MB each). The datasets are also written by ``convert``, in
both formats, and their logs served and validated the same way. A live feed
and its recording are validated in
:func:`test_a_live_feed_and_its_recording_are_valid`.

A provider that adds a stream is covered by its row here; a new source gets a
row of its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from devkit.data import KITTI_LOG, KITTI_RAW
from helpers import require_data, run_xviz_session_async, running_server, write_log, xviz_validate, xviz_write
from xviz_server.codec import Format
from xviz_server.convert import convert
from xviz_server.datasets import open_dataset

#: Seconds of each log validated, from its start: two frames at 10 Hz.
WINDOW = 0.15


@dataclass(frozen=True)
class Served:
    """What a source gives the server: a data directory, or a dataset (``KIND:PATH``) that ``convert`` takes too."""

    data_dir: Path | None = None
    dataset: str | None = None

    @property
    def kind_and_path(self) -> tuple[str, Path] | None:
        if self.dataset is None:
            return None
        kind, _, path = self.dataset.partition(":")
        return kind, Path(path or kind)

    def settings(self) -> dict[str, Any]:
        if self.dataset is not None:
            return {"data_dir": None, "dataset": [self.dataset]}
        return {"data_dir": self.data_dir}


# -- the sources ----------------------------------------------------------------


def _kitti_glb(root: Path) -> Served:
    require_data()
    return Served(data_dir=KITTI_LOG)


def _written_by_xviz_io(fmt: str, source: Callable[[Path], Path]) -> Callable[[Path], Served]:
    """A log re-written by the published writer of ``fmt`` (``JSON_STRING``, ``BINARY_GLB``, ``BINARY_PBE``)."""

    def make(root: Path) -> Served:
        output = root / "log"
        xviz_write(source(root), **{fmt: output})
        return Served(data_dir=output)

    return make


def _kitti_log(root: Path) -> Path:
    """The metadata and first three frames of the real KITTI log (links to them)."""
    require_data()
    head = root / "kitti-head"
    head.mkdir()
    for number in range(1, 5):
        (head / f"{number}-frame.glb").symlink_to(KITTI_LOG / f"{number}-frame.glb")
    return head


def _rich_log(root: Path) -> Path:
    """The log of every kind of XVIZ content of the PBE tests, with values protobuf leaves out (0, "").

    Its polylines lose their colours: the PBE tests keep them to test the
    codec, but the published schema has none (though the client draws them).
    """
    from test_pbe import RICH_METADATA, rich_update

    updates = [rich_update(i) for i in range(4)]
    for update in updates:
        for polyline in update["updates"][0]["primitives"]["/lanes"]["polylines"]:
            del polyline["colors"]
    return write_log(root / "rich-source", updates, fmt=Format.JSON, meta=RICH_METADATA)


def _demo_log(root: Path) -> Path:
    out = root / "demo-source"
    convert("demo", Path("demo"), out, fmt=Format.JSON, frames="0:3", processes=1, out=io.StringIO())
    return out


def _rich_json(root: Path) -> Served:
    return Served(data_dir=_rich_log(root))


def _demo(root: Path) -> Served:
    return Served(dataset="demo")


def _kitti_raw(root: Path) -> Served:
    require_data()
    return Served(dataset=f"kitti:{KITTI_RAW}")


def _kitti_raw_tracklets(root: Path) -> Served:
    """The KITTI excerpt with tracklets (boxes of every class, with their heights), as links to the shared files."""
    from test_kitti import TRACKLETS

    require_data()
    copy = root / "raw"
    shutil.copytree(KITTI_RAW, copy, copy_function=os.symlink)
    drive = copy / "2011_09_26" / "2011_09_26_drive_0001_sync"
    (drive / "tracklet_labels.xml").write_text(TRACKLETS)
    return Served(dataset=f"kitti:{drive}")


def _waymo_npz(root: Path) -> Served:
    from test_waymo import write_segment

    return Served(dataset=f"waymo:{write_segment(root / 'segment-1')}")


def _waymo_tfrecord(root: Path) -> Served:
    from test_waymo_tfrecord import write_scene

    tfrecord, _, _ = write_scene(root / "scene")
    return Served(dataset=f"waymo:{tfrecord}")


def _vista(root: Path) -> Served:
    from test_vista import write_trace

    return Served(dataset=f"vista:{write_trace(root / 'trace-1')}")


def _waymo_v2(root: Path) -> Served:
    from devkit.waymo_scene import write_v2_scene

    return Served(dataset=f"waymo:{write_v2_scene(root / 'training')}")


def _nuscenes(root: Path) -> Served:
    from devkit.nuscenes_scene import write_nuscenes

    return Served(dataset=f"nuscenes:{write_nuscenes(root / 'nuscenes', keys=2).root}")


def _argoverse2(root: Path) -> Served:
    """The real Argoverse 2 log of the av2 devkit's tests (tests/data/argoverse2/README.md)."""
    return Served(dataset=f"argoverse2:{AV2_LOG}")


def _pandaset(root: Path) -> Served:
    from devkit.pandaset_sequence import write_sequence

    return Served(dataset=f"pandaset:{write_sequence(root / '001')}")


AV2_LOG = Path(__file__).parent / "data" / "argoverse2" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"

_BAGS = {"ros1": "drive.bag", "sqlite3": "drive", "mcap": "drive.mcap"}


def _kitti_bag(container: str) -> Callable[[Path], Served]:
    """The KITTI excerpt as a bag: clouds, images (raw and compressed), fix, IMU, /tf, odometry, a MarkerArray."""

    def make(root: Path) -> Served:
        from devkit.rosbag_kitti import write_bag
        from xviz_server.datasets.kitti import KittiDrive

        require_data()
        bag = write_bag(root / _BAGS[container], container, drive=KittiDrive(KITTI_RAW), frames=3)
        return Served(dataset=f"rosbag:{bag}")

    return make


def _viz_bag(container: str, pose_type: str) -> Callable[[Path], Served]:
    """Markers of every kind, a path, numbers, and a pose of ``pose_type``, as a bag."""

    def make(root: Path) -> Served:
        from rosbags.typesys import Stores

        from devkit.rosbag_kitti import Messages, viz_messages, write_bag

        m = Messages(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
        bag = write_bag(root / _BAGS[container], container, viz_messages(m, pose_type))
        return Served(dataset=f"rosbag:{bag}")

    return make


_RECORDINGS = Path(__file__).parent / "recordings"


def _recording(relative: str) -> Callable[[Path], Served]:
    """A recording of another project, as it was published (tests/recordings/README.md)."""

    def make(root: Path) -> Served:
        return Served(dataset=f"rosbag:{_RECORDINGS / relative}")

    return make


def _ros1_profile_mcap(relative: str) -> Callable[[Path], Served]:
    """A recording of another project (a ROS 1 bag) as an MCAP file of the ros1 profile, as ``mcap convert`` makes it."""

    def make(root: Path) -> Served:
        from ros1_profile_mcap import write_ros1_mcap

        bag = _RECORDINGS / relative
        return Served(dataset=f"rosbag:{write_ros1_mcap(bag, root / f'{bag.stem}.mcap')}")

    return make


def _foxglove_sdk_mcap(root: Path) -> Served:
    """Foxglove's schemas in protobuf and JSON, no profile, as the Foxglove SDK writes them."""
    from foxglove_sdk_recording import write_sdk_recording

    return Served(dataset=f"rosbag:{write_sdk_recording(root / 'sdk.mcap')}")


POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"

#: Every source the server has: a name and what makes it in a folder.
SOURCES: dict[str, Callable[[Path], Served]] = {
    "kitti-glb": _kitti_glb,
    "kitti-json-by-xviz-io": _written_by_xviz_io("JSON_STRING", _kitti_log),
    "kitti-pbe-by-xviz-io": _written_by_xviz_io("BINARY_PBE", _kitti_log),
    "rich-json": _rich_json,
    "rich-glb-by-xviz-io": _written_by_xviz_io("BINARY_GLB", _rich_log),
    "rich-pbe-by-xviz-io": _written_by_xviz_io("BINARY_PBE", _rich_log),
    "demo-pbe-by-xviz-io": _written_by_xviz_io("BINARY_PBE", _demo_log),
    "demo": _demo,
    "kitti-raw": _kitti_raw,
    "kitti-raw-tracklets": _kitti_raw_tracklets,
    "waymo-npz": _waymo_npz,
    "waymo-tfrecord": _waymo_tfrecord,
    "vista": _vista,
    "waymo-v2": _waymo_v2,
    "nuscenes": _nuscenes,
    "argoverse2-real": _argoverse2,
    "pandaset": _pandaset,
    **{f"rosbag-{container}-kitti": _kitti_bag(container) for container in _BAGS},
    "rosbag-ros1-viz": _viz_bag("ros1", POSE_WITH_COVARIANCE),
    "rosbag-sqlite3-viz": _viz_bag("sqlite3", POSE_STAMPED),
    "rosbag-mcap-viz": _viz_bag("mcap", POSE_STAMPED),
    "mcap-conformance-ten-messages": _recording(
        "mcap-conformance/TenMessages/TenMessages-ch-chx-pad-rch-rsh-st-sum.mcap"
    ),
    "rosbag2-service-events": _recording("rosbag2/mcap/bag_with_topics_and_service_events"),
    "rosbag2-talker-strings": _recording("rosbag2/sqlite3/talker"),
    "rosbag2-bare-db3": _recording("rosbag2/topics_and_services.db3"),
    "mcap-foxglove-sdk": _foxglove_sdk_mcap,
    "ros1-turtlesim-twist": _recording("ros1/turtlesim.bag"),
    "ros1-embag-truck": _recording("ros1/embag/test.bag"),
    "ros1-embag-strings": _recording("ros1/embag/test_2.bag"),
    "ros1-lichtblick-tf-tree": _recording("ros1/lichtblick/example-bz2.bag"),
    "ros1-robot-localization-navsatfix": _recording("ros1/robot_localization/test1.bag"),
    "ros1-webviz-marker": _recording("ros1/webviz/only-a-cube.bag"),
    "ros1-robot-pose-ekf-odometry": _recording("ros1/robot_pose_ekf/gps_data_10s.bag"),
    "ros1-rotors-pose-stamped": _recording("ros1/rotors/waypoint_example_15s.bag"),
    "ros1-jsk-marker-array": _recording("ros1/jsk_recognition/bunny_marker_array.bag"),
    "rosbag2-nebula-velodyne-packets": _recording("rosbag2/nebula/vlp32/1713492677464078412"),
    "ros1-ouster-packets": _recording("ros1/ouster/512x10_raw.bag"),
    "ros1-ouster-cloud": _recording("ros1/ouster/cloud.bag"),
    "mcap-ros1-ouster-cloud": _ros1_profile_mcap("ros1/ouster/cloud.bag"),
    "mcap-ros1-husky-navsatfix": _ros1_profile_mcap("ros1/robot_localization/test1.bag"),
    "mcap-lichtblick-json-logs": _recording("mcap/lichtblick/example_logs.mcap"),
    "mcap-lichtblick-json-images": _recording("mcap/lichtblick/custom-camera-model.mcap"),
}
#: The sources of a single frame (one lidar sweep): one state update is all their window holds.
ONE_FRAME = {"ros1-ouster-cloud", "mcap-ros1-ouster-cloud"}
#: The sources that ``convert`` takes.
DATASETS = [
    "demo",
    "kitti-raw",
    "kitti-raw-tracklets",
    "waymo-npz",
    "waymo-tfrecord",
    "vista",
    "waymo-v2",
    "nuscenes",
    "argoverse2-real",
    *(source for source in SOURCES if source.startswith("rosbag-")),
]


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[[str], Served]]:
    """Make a source once for the module, when first asked for."""
    cache: dict[str, Served] = {}

    def get(name: str) -> Served:
        if name not in cache:
            cache[name] = SOURCES[name](tmp_path_factory.mktemp(name))
        return cache[name]

    yield get


# -- validating -----------------------------------------------------------------


def window_script(request_id: str = "window") -> list[dict[str, Any]]:
    return [
        {"wait": "metadata"},
        {"send_transform_log": {"id": request_id, "from_start": 0, "to_start": WINDOW}},
        {"wait": "done", "id": request_id},
        {"close": True},
    ]


async def validate_served(settings: dict[str, Any], fmt: Format, query: str = "") -> int:
    """Serve with ``settings``, run a session of the published client in ``fmt``; assert every message is valid.

    Returns the number of state updates received.
    """
    async with running_server(**settings) as server:
        url = f"ws://127.0.0.1:{server.port}/?message_format={fmt.value}{query}"
        result = await run_xviz_session_async(url, window_script(), brief=True, validate=True, timeout=120)
    assert result.summary is not None, result.stderr
    assert result.summary["errors"] == [], result.summary["errors"][:5]
    assert result.ok, result.stderr
    kinds = {"text" if fmt is Format.JSON else "binary"}
    assert {message["kind"] for message in result.messages} == kinds
    return len(result.of_type("xviz/state_update"))


FORMATS = [Format.JSON, Format.BINARY]


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS, ids=lambda f: f.value.lower())
@pytest.mark.parametrize("source", list(SOURCES))
async def test_served_messages_are_valid(source: str, fmt: Format, made: Callable[[str], Served]):
    served = await asyncio.to_thread(made, source)
    assert await validate_served(served.settings(), fmt) >= (1 if source in ONE_FRAME else 2)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS, ids=lambda f: f.value.lower())
@pytest.mark.parametrize("source", DATASETS)
async def test_converted_logs_are_valid(source: str, fmt: Format, made: Callable[[str], Served], tmp_path: Path):
    served = await asyncio.to_thread(made, source)
    assert served.kind_and_path is not None
    kind, path = served.kind_and_path
    output = tmp_path / "log"
    await asyncio.to_thread(convert, kind, path, output, fmt=fmt, frames="0:2", processes=1, out=io.StringIO())
    assert await validate_served({"data_dir": output}, fmt) == 2


@pytest.mark.parametrize("fmt", FORMATS, ids=lambda f: f.value.lower())
async def test_a_live_feed_and_its_recording_are_valid(fmt: Format, tmp_path: Path):
    """The demo's frames pushed into a live feed: what viewers of the feed get, and the recording of it."""
    demo = open_dataset("demo", Path("demo"))
    metadata = demo.metadata()
    record = tmp_path / "record"
    async with running_server(None, record=record) as server:
        feed = server.live.feed("car")
        feed.set_metadata(metadata)

        async def publish() -> None:  # at 10 Hz until the viewer has seen enough (the demo is 200 frames long)
            for frame in range(len(demo)):
                await feed.publish(await asyncio.to_thread(demo.convert, frame, metadata))
                await asyncio.sleep(0.1)

        publisher = asyncio.ensure_future(publish())
        url = f"ws://127.0.0.1:{server.port}/?log=car&session_type=live&message_format={fmt.value}"
        script = [{"wait": "metadata"}, {"wait": "state_updates", "count": 3}, {"close": True}]
        result = await run_xviz_session_async(url, script, brief=True, validate=True)
        publisher.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await publisher
    assert result.summary is not None, result.stderr
    assert result.summary["errors"] == [], result.summary["errors"][:5]
    assert result.ok, result.stderr
    [recording] = list((record / "car").iterdir())
    assert await validate_served({"data_dir": record}, fmt, f"&log=car/{recording.name}") >= 2


def frame(t: float, *, longitude: bool = True, style: dict[str, Any] | None = None) -> dict[str, Any]:
    origin = (
        {"longitude": 8.4, "latitude": 49.0, "altitude": 110.0} if longitude else {"latitude": 49.0, "altitude": 110.0}
    )
    pose = {"timestamp": t, "map_origin": origin, "position": [0, 0, 0], "orientation": [0, 0, 0]}
    polygon = {
        "vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0]],
        "base": {"style": style or {"fill_color": "#FF0000", "height": 2.0}},
    }
    return {
        "update_type": "SNAPSHOT",
        "updates": [
            {"timestamp": t, "poses": {"/vehicle_pose": pose}, "primitives": {"/objects": {"polygons": [polygon]}}}
        ],
    }


@pytest.mark.parametrize("fmt", FORMATS, ids=lambda f: f.value.lower())
async def test_the_validator_refuses_what_the_schema_refuses(fmt: Format, tmp_path: Path):
    """The drivers do validate: a map origin without longitude and a height-only style are refused, with the path."""
    meta = {
        "version": "2.0.0",
        "log_info": {"start_time": 1.0, "end_time": 1.1},
        "streams": {
            "/vehicle_pose": {"category": "POSE"},
            "/objects": {"category": "PRIMITIVE", "primitive_type": "POLYGON"},
        },
    }
    log = write_log(
        tmp_path / "log",
        [frame(1.0), frame(1.05, longitude=False), frame(1.1, style={"height": 2.0})],
        fmt=fmt,
        meta=meta,
    )
    no_longitude = ".updates[0].poses['/vehicle_pose'].map_origin: should have required property 'longitude'"
    height_only = ".updates[0].primitives['/objects'].polygons[0].base.style: "

    files = [log / f"{number}-frame{fmt.suffix}" for number in range(1, 5)]
    lines = await asyncio.to_thread(xviz_validate, files)
    assert [line["type"] for line in lines] == ["xviz/metadata"] + ["xviz/state_update"] * 3
    assert lines[0]["errors"] == lines[1]["errors"] == []
    assert lines[2]["errors"] == [f'{no_longitude} {{"missingProperty":"longitude"}}']
    assert lines[3]["errors"][0].startswith(height_only)

    async with running_server(log) as server:
        url = f"ws://127.0.0.1:{server.port}/?message_format={fmt.value}"
        result = await run_xviz_session_async(url, window_script(), validate=True)
    assert result.ok, result.stderr
    refused = [(error["source"], error["index"], error["message"]) for error in result.summary["errors"]]
    assert {index for _, index, _ in refused} == {2, 3} and {source for source, _, _ in refused} == {
        "schema"
    }  # 0 is the metadata
    assert refused[0][2].startswith(f"xviz/state_update: {no_longitude}") and refused[1][2].startswith(
        f"xviz/state_update: {height_only}"
    )
    assert "invalid" not in result.messages[1] and result.messages[2]["invalid"][0].startswith(no_longitude)
