"""What one client, one message or one request may cost the server (issue 39), against the server run as a process.

A message listing half a million bad items gets one answer and no memory; clients that send big messages and
never read hold a bounded queue each and are closed; a burst of exports is admitted up to
``--max-sessions``; every HTTP answer carries the same headers and says what was asked. The server runs as its own
process (``helpers.served``) where its memory is the point, its peak RSS and its workers' read from ``/proc``.
"""

from __future__ import annotations

import asyncio
import io
import json
import socket
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from websockets.asyncio.client import ClientConnection, connect

from helpers import (
    Client,
    Served,
    client,
    eventually,
    foxglove_opened,
    http_get,
    running_server,
    served,
    ten_hz,
    timestamps,
    write_log,
)
from xviz_server.budget import LOG_LINES, MAX_ITEMS, NAMED
from xviz_server.unpack import size_text

pytestmark = pytest.mark.slow

_MiB = 1 << 20
#: What serving one hostile message may cost a process of the server: tens of MB, not the gigabytes it did.
TENS_OF_MB = 48 * _MiB
#: The longest silence a watching client may see while another client attacks (it was 10 s and more).
QUIET = 2.0


def grown(server: Served, before: dict[int, int]) -> dict[int, int]:
    """How far each process's peak RSS rose over its RSS in ``before``."""
    peaks = server.peaks()
    return {pid: peaks[pid] - rss for pid, rss in before.items() if pid in peaks}


async def foxglove(server: Served, log: str = "kitti") -> ClientConnection:
    websocket = await connect(
        f"ws://127.0.0.1:{server.port}/?log={log}", subprotocols=["foxglove.websocket.v1"], max_size=None
    )  # type: ignore[list-item]
    _, websocket.channels = await foxglove_opened(websocket, 30)  # type: ignore[attr-defined]
    return websocket


async def subscribe_all(websocket: ClientConnection) -> None:
    """Subscribe ``websocket`` (from :func:`foxglove`) to every channel it was advertised."""
    channels = websocket.channels  # type: ignore[attr-defined]
    await websocket.send(
        json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]})
    )


async def status(websocket: ClientConnection) -> str:
    """The message of the next ``status``, other messages skipped."""
    while True:
        data = await asyncio.wait_for(websocket.recv(), 30)
        if isinstance(data, str) and json.loads(data)["op"] == "status":
            return str(json.loads(data)["message"])


async def arrivals(websocket: ClientConnection, quiet: float = 5.0) -> list[float]:
    """When each message came, until none came for ``quiet`` seconds (the log has played to its end)."""
    times = []
    try:
        while True:
            await asyncio.wait_for(websocket.recv(), quiet)
            times.append(time.monotonic())
    except asyncio.TimeoutError:
        return times


async def healthz(server: Served) -> None:
    assert await asyncio.wait_for(server.get("/healthz"), 10) == (200, "ok\n")


# -- one message, many items ---------------------------------------------------------------------------------------


async def test_a_foxglove_message_of_half_a_million_bad_items_gets_one_status_and_costs_nothing(
    kitti_root: Path,
) -> None:
    async with served(kitti_root) as server:
        async with await foxglove(server) as warm:  # the workers are up and the log's frames cached
            await subscribe_all(warm)
            await arrivals(warm, 2.0)
        before = server.rss()
        watcher, attacker = await foxglove(server), await foxglove(server)
        await subscribe_all(watcher)
        await watcher.recv()
        watching = asyncio.ensure_future(arrivals(watcher))
        # 524 000 items in 1 MB: refused whole, unread, in one status.
        for op, key in (("subscribe", "subscriptions"), ("unsubscribe", "subscriptionIds")):
            await attacker.send('{{"op":"{}","{}":[{}]}}'.format(op, key, ",".join(["0"] * 524_000)))
            said = await status(attacker)
            assert said == f"{op}: 524000 items, more than the {MAX_ITEMS} one message may hold: refused whole"
        # Under the limit: every item looked at, one status naming the first few and counting the rest.
        items = [{"id": 1000 + i, "channelId": 99_999} for i in range(MAX_ITEMS)]
        await attacker.send(json.dumps({"op": "subscribe", "subscriptions": items}))
        said = await status(attacker)
        assert said.startswith(
            f"subscribe: {MAX_ITEMS} of {MAX_ITEMS} items refused: no channel 99999 in log 'kitti'; "
        )
        assert said.endswith(f"; and {MAX_ITEMS - NAMED} more") and len(said) < 500
        # Many bad messages: a status each, but a bounded number of log lines.
        for _ in range(100):
            await attacker.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": 99_999}]}))
        assert [await status(attacker) for _ in range(100)] == ["subscribe: no channel 99999 in log 'kitti'"] * 100
        await healthz(server)
        times = await watching
        await watcher.close()
        await attacker.close()
        growth = grown(server, before)
    gaps = [later - earlier for earlier, later in zip(times, times[1:])]
    assert len(times) > 100 and max(gaps) < QUIET, max(gaps)
    assert max(growth.values()) < TENS_OF_MB, {pid: f"{g / _MiB:.0f} MiB" for pid, g in growth.items()}
    logged = [line for line in server.lines if "error sent" in line]
    assert 0 < len(logged) <= 2 * LOG_LINES, len(logged)  # at most two windows of the test's length
    assert sum(map(len, server.lines)) < 200_000


async def test_a_transform_log_of_209000_bad_streams_gets_one_short_error(kitti_root: Path) -> None:
    async with served(kitti_root) as server:
        await server.session("kitti")
        before = server.rss()
        async with connect(f"ws://127.0.0.1:{server.port}/?log=kitti", max_size=None) as websocket:
            viewer = Client(websocket)
            assert (await viewer.recv(30))["type"] == "xviz/metadata"
            for kind, data in (
                ("transform_log", {"id": "many", "desired_streams": [[]] * 209_000}),
                ("reconfigure", {"update_type": "DELTA", "config_update": {"desired_streams": [[]] * 209_000}}),
            ):
                await viewer.send(kind, data)
                error = await viewer.recv(30)
                assert error["type"] == "xviz/error" and error["_bytes"] < 1000, error["_bytes"]
                assert (
                    f"holds more than the {MAX_ITEMS} items a message may hold: refused whole"
                    in error["data"]["message"]
                )
            # Under the limit: the first few named, the rest counted.
            await viewer.send("transform_log", {"id": "some", "desired_streams": [[]] * MAX_ITEMS})
            error = await viewer.recv(30)
            message = error["data"]["message"]
            assert error["type"] == "xviz/error" and error["_bytes"] < 1000, error["_bytes"]
            assert message.startswith(
                f"xviz/transform_log (id 'some'): {MAX_ITEMS} problems: 'desired_streams.0' must be a string, not []; "
            )
            assert message.endswith(f"; and {MAX_ITEMS - NAMED} more (log 'kitti')")
            # The session goes on.
            await viewer.send("transform_log", {"id": "good"})
            assert [m for m in await viewer.until("transform_log_done", "good") if m["type"] == "xviz/state_update"]
        growth = grown(server, before)
        await healthz(server)
    assert max(growth.values()) < TENS_OF_MB, {pid: f"{g / _MiB:.0f} MiB" for pid, g in growth.items()}
    assert max(map(len, server.lines)) < 2000


# -- one frame, many bytes ----------------------------------------------------------------------------------------

#: Each large cloud: a valid message under the 256 MiB a chunk may declare, three of them far over what a frame may.
CLOUD_BYTES = 250 * _MiB


def _clouds(m: Any) -> Any:
    """A small cloud at 0.1 s (the topic's first message, which the metadata reads: just over the 1 MiB after
    which rosbags' writer closes a chunk, so that it has a chunk of its own), then three clouds of
    :data:`CLOUD_BYTES` of zeros at 0.2, 0.3 and 0.4 s, made one at a time."""
    base = 1_700_000_000 * 10**9
    for number, size in enumerate([16 * 70_000] + [CLOUD_BYTES] * 3):
        t = base + (number + 1) * 10**8
        fields = [m.sensor_msgs__PointField(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
        cloud = m.sensor_msgs__PointCloud2(
            header=m.header(t, "base_link"),
            height=1,
            width=size // 16,
            fields=fields,
            is_bigendian=False,
            point_step=16,
            row_step=size,
            data=np.zeros(size, np.uint8),
            is_dense=True,
        )
        yield "/points", "sensor_msgs/msg/PointCloud2", t, cloud


@pytest.fixture(scope="module")
def clouds(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A bare MCAP file (ROS 2 messages, zstd chunks) of a few megabytes holding the clouds of :func:`_clouds`."""
    from rosbags.typesys import Stores

    from devkit.rosbag_kitti import Messages, write_bag

    path = write_bag(
        tmp_path_factory.mktemp("clouds") / "clouds.mcap",
        "mcap",
        _clouds(Messages(Stores.ROS2_HUMBLE)),
        compression="zstd",
    )
    assert path.stat().st_size < 16 * _MiB
    return path


async def test_a_frame_of_huge_valid_clouds_is_refused_unread_on_both_faces(clouds: Path, kitti_root: Path) -> None:
    (kitti_root / "clouds.mcap").symlink_to(clouds)
    async with served(kitti_root) as server:
        # The workers are up, with rosbags imported; a peak RSS is the highest since the process started.
        await asyncio.gather(server.session("kitti"), server.session("clouds"))
        before = server.rss()
        xviz, good = await asyncio.gather(server.session("clouds"), server.session("kitti"))
        async with await foxglove(server, "clouds") as websocket:
            await subscribe_all(websocket)
            statuses = [await status(websocket) for _ in range(3)]
        await healthz(server)
        growth = grown(server, before)
    refused = "would unpack 250.0 MiB, more than the limit of 128 MiB for one frame: refused unread"
    errors = [m["data"]["message"] for m in xviz if m["type"] == "xviz/error"]
    assert [m["data"]["updates"][0]["timestamp"] for m in xviz if m["type"] == "xviz/state_update"] == [
        1_700_000_000.1
    ], errors
    assert len(errors) == 3 and all(
        f"frame {n} of log 'clouds': frame {n}: its messages and images {refused}" in e
        for n, e in zip((1, 2, 3), errors)
    ), errors
    assert len(statuses) == 3 and all(refused in said for said in statuses), statuses
    assert [m for m in good if m["type"] == "xviz/state_update"] and not [m for m in good if m["type"] == "xviz/error"]
    assert max(growth.values()) < TENS_OF_MB, {pid: f"{g / _MiB:.0f} MiB" for pid, g in growth.items()}


#: Over the 128 MiB one frame may read in all, in what a frame's files declare: the file is sparse, never written.
OVER = 130 * _MiB
REFUSED = "more than the limit of 128 MiB for one frame: refused"


async def both_faces(server: Served, log: str) -> tuple[list[dict[str, Any]], list[str], list[int]]:
    """A log played whole on each face: the XVIZ session's messages; the Foxglove session's statuses and the log
    times (nanoseconds) of the messages it sent, until it fell quiet."""
    xviz = await server.session(log)
    statuses: list[str] = []
    stamps: list[int] = []
    async with await foxglove(server, log) as websocket:
        await subscribe_all(websocket)
        try:
            while True:
                data = await asyncio.wait_for(websocket.recv(), 5)
                if isinstance(data, bytes) and data[0] == 0x01:  # messageData: subscription, log time, payload
                    stamps.append(struct.unpack_from("<Q", data, 5)[0])
                elif isinstance(data, str) and json.loads(data)["op"] == "status":
                    statuses.append(json.loads(data)["message"])
        except asyncio.TimeoutError:
            pass
    return xviz, statuses, stamps


async def only_log(server: Served) -> str:
    """The name of the one log the server serves, once its catalog has it."""

    async def listed() -> bool:
        return bool(await server.logs())

    await eventually(listed, 60)
    (log,) = await server.logs()
    return log


def frame_errors(messages: list[dict[str, Any]]) -> list[str]:
    return [m["data"]["message"] for m in messages if m["type"] == "xviz/error"]


async def test_a_kitti_frame_whose_files_pass_the_frame_limit_is_refused_unread_on_both_faces(
    shared_dir: Path, tmp_path: Path
) -> None:
    import os
    import shutil

    data = tmp_path / "data"
    shutil.copytree(
        shared_dir / "data" / "kitti-raw-2011_09_26_drive_0001-head", data / "raw", copy_function=os.symlink
    )
    drive = data / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    sweep = drive / "velodyne_points" / "data" / "0000000003.bin"
    sweep.unlink()
    with sweep.open("wb") as file:
        file.truncate(OVER)  # with frame 3's four images, over the limit
    async with served(data) as server:
        log = await only_log(server)
        xviz, statuses, stamps = await both_faces(server, log)
        await healthz(server)
    images = sum((drive / f"image_0{n}" / "data" / "0000000003.png").stat().st_size for n in range(4))
    refused = f"frame 3: its messages and images would unpack {size_text(OVER + images)}, {REFUSED} unread"
    assert len(timestamps(xviz)) == 24 and [
        error.endswith(f"of log '{log}': {refused}") for error in frame_errors(xviz)
    ] == [True], frame_errors(xviz)
    assert len(statuses) == 1 and statuses[0].endswith(refused), statuses
    assert len(set(stamps)) == 24 and str(drive) not in statuses[0] + frame_errors(xviz)[0]


async def test_a_waymo_frame_whose_record_or_range_images_pass_the_frame_limit_is_refused_on_both_faces(
    tmp_path: Path,
) -> None:
    import zlib

    from devkit.waymo_scene import T0, write_scene
    from xviz_server.datasets.waymo import frame_pb2 as pb
    from xviz_server.datasets.waymo.segment import MAX_MATRIX_BYTES
    from xviz_server.datasets.waymo.tfrecord import RecordFile, masked_crc, write_records

    scene, _, _ = write_scene(tmp_path / "scene")
    first, _, last = (RecordFile(scene).read(n) for n in range(3))
    # Frame 2: fifteen range images of 60 MiB each, each under the 64 MiB a matrix may be, 900 MiB in all.
    bomb = pb.Frame(timestamp_micros=T0 + 200_000)
    bomb.pose.transform.extend(np.eye(4).flatten())
    zeros = zlib.compress(bytes(60 * _MiB), 9)
    assert 60 * _MiB < MAX_MATRIX_BYTES
    for name in range(1, 6):
        laser = bomb.lasers.add(name=name)
        laser.ri_return1.range_image_compressed = laser.ri_return2.range_image_compressed = zeros
        laser.ri_return1.range_image_pose_compressed = zeros
    later = pb.Frame.FromString(last)
    later.timestamp_micros = T0 + 300_000
    segment = tmp_path / "data" / "segment-15.tfrecord"
    segment.parent.mkdir()
    write_records(segment, [first])
    # Frame 1: a record of 130 MiB that begins with its time, the rest a hole in the file (never read).
    length = struct.pack("<Q", OVER)
    with segment.open("r+b") as file:  # not "ab": a file opened to append writes at its end, wherever it seeks
        file.seek(0, io.SEEK_END)
        file.write(length + struct.pack("<I", masked_crc(length)))
        start = file.tell()
        file.write(pb.Frame(timestamp_micros=T0 + 100_000).SerializeToString())
        file.seek(start + OVER)  # the rest of the data: zeros
        file.write(b"\0" * 4)  # its CRC
    with segment.open("ab") as file:
        rest = tmp_path / "rest.tfrecord"
        write_records(rest, [bomb.SerializeToString(), later.SerializeToString()])
        file.write(rest.read_bytes())
    assert segment.stat().st_blocks * 512 < 16 * _MiB
    async with served(tmp_path / "data") as server:
        log = await only_log(server)
        xviz, statuses, stamps = await both_faces(server, log)
        await healthz(server)
    unread = f"frame 1: its messages and images would unpack 130 MiB, {REFUSED} unread"
    inflated = f"frame 2: its messages and images unpack {REFUSED.replace('refused', '')}refused after"
    errors = frame_errors(xviz)
    assert timestamps(xviz) == [T0 / 1e6, (T0 + 300_000) / 1e6], errors
    assert len(errors) == 2 and unread in errors[0] and inflated in errors[1], errors
    assert len(statuses) == 2 and unread in statuses[0] and inflated in statuses[1], statuses
    assert sorted(set(stamps)) == [T0 * 1000, (T0 + 300_000) * 1000]


async def test_a_vista_frame_whose_sweep_and_video_pass_the_frame_limit_is_refused_unread_on_both_faces(
    tmp_path: Path,
) -> None:
    import h5py
    from test_vista import FRAMES, write_trace

    write_trace(tmp_path / "data" / "good")
    large = write_trace(tmp_path / "data" / "large")
    points = 12_000_000  # a sweep's rows declare 12 M points: 183.1 MiB of xyz and intensity, none of it written
    (large / "lidar_3d.h5").unlink()
    with h5py.File(large / "lidar_3d.h5", "w") as file:
        file.create_dataset("xyz", (FRAMES, points, 3), np.float32, chunks=(1, 1 << 16, 3))
        file.create_dataset("intensity", (FRAMES, points), np.float32, chunks=(1, 1 << 16))
    assert (large / "lidar_3d.h5").stat().st_size < _MiB
    async with served(tmp_path / "data") as server:

        async def listed() -> bool:
            return len(await server.logs()) == 2

        await eventually(listed, 60)
        xviz, statuses, stamps = await both_faces(server, "large")
        good_xviz, good_statuses, good_stamps = await both_faces(server, "good")
        await healthz(server)
    declared = size_text(points * 16 + 64 * 48 * 3)  # the sweep's rows and a decoded video frame
    refused = [f"frame {n}: its messages and images would unpack {declared}, {REFUSED} unread" for n in range(FRAMES)]
    assert (
        not timestamps(xviz)
        and [error.endswith(f"of log 'large': {text}") for error, text in zip(frame_errors(xviz), refused)]
        == [True] * FRAMES
    ), frame_errors(xviz)
    assert [said.endswith(text) for said, text in zip(statuses, refused)] == [True] * FRAMES and not stamps, statuses
    assert len(timestamps(good_xviz)) == FRAMES and not frame_errors(good_xviz) and not good_statuses
    assert len(set(good_stamps)) == FRAMES


# -- exports ------------------------------------------------------------------------------------------------------


async def test_a_burst_of_exports_is_admitted_up_to_max_sessions(kitti_root: Path) -> None:
    async with served(kitti_root, "--max-sessions", "5") as server:
        await healthz(server)

        def head(_: int) -> bytes:  # the answer's head; the body, if any, is left unread, so that the export stays open
            sock = socket.create_connection(("127.0.0.1", server.port), timeout=30)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.sendall(b"GET /api/logs/kitti/export HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            data = b""
            while b"\r\n\r\n" not in data:
                data += sock.recv(4096)
            sockets.append(sock)
            return data.split(b"\r\n", 1)[0]

        sockets: list[socket.socket] = []
        heads = await asyncio.gather(*(asyncio.to_thread(head, n) for n in range(60)))
        for sock in sockets:
            sock.close()
    assert heads.count(b"HTTP/1.1 200 OK") == 5, heads
    assert heads.count(b"HTTP/1.1 503 Service Unavailable") == 55, heads


async def test_an_export_that_meets_a_corrupt_frame_says_so(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from xviz_server.foxglove.export import CUT_SHORT
    from xviz_server.layout import file_number

    log = write_log(tmp_path / "data" / "cars", ten_hz(10))
    (log / f"{file_number(6)}-frame.glb").write_bytes(b"glTF" + bytes(40))  # frame 6 is corrupt
    async with served(tmp_path / "data") as server:
        status, _, body = await asyncio.to_thread(http_get, server.port, "/api/logs/cars/export")
        first, _, refused = await asyncio.to_thread(http_get, server.port, "/api/logs/cars/export?start=100.6")
        await healthz(server)
    # Met on the way: the file ends before it, readable, and says where and why in a metadata record.
    assert status == 200
    reader = make_reader(io.BytesIO(body))
    stamps = sorted({message.log_time for _, _, message in reader.iter_messages()})
    assert stamps == [int(round((100 + i / 10) * 1e9)) for i in range(6)]
    (cut,) = [record.metadata for record in reader.iter_metadata() if record.name == CUT_SHORT]
    assert cut["frame"] == "6" and "cars" in cut["error"], cut
    assert any("the export of log 'cars' ends before frame 6, which cannot be read" in line for line in server.lines)
    # The clip's first frame: refused before the head.
    assert first == 422 and refused.startswith(b"the clip's first frame cannot be read: "), refused


async def test_a_session_url_parameter_given_twice_is_refused_and_ignored(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with client(server, "/?log=kitti&max_mbps=5&max_mbps=1000&speed=1&speed=2") as viewer:
            first, second, third = [await viewer.recv(30) for _ in range(3)]
    assert [first["type"], second["type"], third["type"]] == ["xviz/error", "xviz/error", "xviz/metadata"]
    assert first["data"]["message"].endswith(
        "bad connection URL parameter 'max_mbps': give it at most once; it is ignored"
    )
    assert second["data"]["message"].endswith(
        "bad connection URL parameter 'speed': give it at most once; it is ignored"
    )


async def test_a_url_parameter_given_twice_gets_the_same_refusal_on_the_foxglove_face(kitti_root: Path) -> None:
    async with running_server(kitti_root) as server:
        async with client(server, "/?log=kitti&log=other") as viewer:
            xviz = [await viewer.recv(30) for _ in range(2)]
        async with connect(
            f"ws://127.0.0.1:{server.port}/?log=kitti&log=other&max_mbps=5&max_mbps=6&speed=1&speed=2",
            subprotocols=["foxglove.websocket.v1"],  # type: ignore[list-item]
        ) as websocket:
            info = json.loads(await asyncio.wait_for(websocket.recv(), 30))
            said = [json.loads(await asyncio.wait_for(websocket.recv(), 30)) for _ in range(2)]
            _, channels = await foxglove_opened_after(websocket)
    refusal = "bad connection URL parameter 'log': give it at most once; it is ignored"
    # XVIZ: an error, then the only log, as if no log were named.
    assert [m["type"] for m in xviz] == ["xviz/error", "xviz/metadata"] and xviz[0]["data"]["message"].endswith(refusal)
    # Foxglove: the server's info, an error status for each parameter it reads (speed is not one), then the only log.
    assert info["op"] == "serverInfo"
    assert said == [
        {"op": "status", "level": 2, "message": refusal},
        {"op": "status", "level": 2, "message": refusal.replace("'log'", "'max_mbps'")},
    ]
    assert channels


async def foxglove_opened_after(websocket: ClientConnection) -> tuple[int, list[dict[str, Any]]]:
    """The rest of a Foxglove log's opening once ``serverInfo`` and the statuses are read: its start, its channels."""
    start = await asyncio.wait_for(websocket.recv(), 30)
    assert isinstance(start, bytes) and start[0] == 0x02
    advertise = json.loads(await asyncio.wait_for(websocket.recv(), 30))
    assert advertise["op"] == "advertise"
    return struct.unpack_from("<Q", start, 1)[0], advertise["channels"]


# -- the catalog ---------------------------------------------------------------------------------------------------


async def test_a_tfrecord_whose_first_length_crc_is_wrong_is_left_out_with_a_warning(kitti_root: Path) -> None:
    header = struct.pack("<QI", 1000, 12345)  # a length and a CRC that is not its masked CRC32C
    (kitti_root / "segment.tfrecord").write_bytes(header + bytes(1004))
    async with served(kitti_root) as server:

        async def listed() -> bool:
            return "kitti" in await server.logs()

        await eventually(listed)
        logs = await server.logs()
    assert "segment" not in logs
    warned = [line for line in server.lines if "segment.tfrecord: left out of the catalog" in line]
    assert warned and "WARNING" in warned[0].upper(), server.lines
    assert "the CRC of its first record's length (1000) does not match" in warned[0]


# -- HTTP answers ---------------------------------------------------------------------------------------------------


def raw(port: int, request: bytes) -> tuple[bytes, dict[str, str], bytes]:
    """Send ``request`` as it is; the status line, the headers (lower-case names) and the body, until the server closes."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sock.sendall(request)
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    status, *lines = head.split(b"\r\n")
    headers = {name.decode().lower(): value.decode() for name, _, value in (line.partition(b": ") for line in lines)}
    return status, headers, body


async def test_every_http_answer_carries_the_same_headers_and_says_what_was_asked(kitti_root: Path) -> None:
    async with served(kitti_root) as server:
        await healthz(server)
        answers: dict[str, tuple[bytes, dict[str, str], bytes]] = {}
        for name, request in {
            "200": b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
            "404": b"GET /nowhere HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
            "405": b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n",
            "204": b"OPTIONS / HTTP/1.1\r\nHost: x\r\n\r\n",
            "400": b"\x01\x02\x03 garbage\r\n\r\n",
            "414": b"GET /" + b"a" * 10_000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",
            "head 405": b"HEAD / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
            "export 400": b"GET /api/logs/kitti/export?start=1&start=2 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
        }.items():
            answers[name] = await asyncio.to_thread(raw, server.port, request)
    for name, (status, headers, body) in answers.items():
        assert status.split(b" ")[1].decode() == name.split(" ")[-1], (name, status)
        assert headers.get("x-content-type-options") == "nosniff", (name, headers)
        assert headers.get("referrer-policy") == "strict-origin", (name, headers)
        assert b"WebSocket connection" not in body, (name, body)
    assert answers["414"][2] == b"cannot read this request: read 10016 bytes, expected no more than 8192 bytes.\n"


async def test_a_header_given_on_two_lines_is_read_as_one_list_not_answered_500(kitti_root: Path) -> None:
    """Two ``Range`` lines made the file's answer fail (a 500): they are one list of ranges, as RFC 9110 reads them."""
    async with served(kitti_root) as server:
        await healthz(server)
        head = b"GET /api/logs/kitti/file.mcap HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
        status, headers, whole = await asyncio.to_thread(raw, server.port, head + b"\r\n")
        answers = [
            await asyncio.to_thread(raw, server.port, head + lines + b"\r\n")
            for lines in (
                b"Range: bytes=0-1\r\nRange: bytes=2-3\r\n",  # two ranges: not served, the whole file is
                b'If-None-Match: "old"\r\nIf-None-Match: ' + headers["etag"].encode() + b"\r\n",  # one list of tags
                b"Range: bytes=0-9\r\nAccept: */*\r\nAccept: text/plain\r\n",  # another header twice
            )
        ]
        await healthz(server)
    assert status == b"HTTP/1.1 200 OK" and len(whole) == int(headers["content-length"]) > 0
    assert [(answer[0], answer[2]) for answer in answers] == [
        (b"HTTP/1.1 200 OK", whole),
        (b"HTTP/1.1 304 Not Modified", b""),
        (b"HTTP/1.1 206 Partial Content", whole[:10]),
    ]
    assert not [line for line in server.lines if "failed" in line], server.lines


async def test_a_header_read_as_one_value_given_twice_is_a_400_naming_it(kitti_root: Path) -> None:
    """A header sent on two lines that the server reads as one value (``Accept`` on the page, ``Upgrade``, ``Origin``
    on the file) is the client's error, not the server's: a 400 naming it, with every answer's headers."""
    async with served(kitti_root) as server:
        await healthz(server)
        answers = [
            await asyncio.to_thread(raw, server.port, request)
            for request in (
                b"GET / HTTP/1.1\r\nHost: x\r\nAccept: text/html\r\nAccept: text/html\r\n\r\n",
                b"GET /api/logs HTTP/1.1\r\nHost: x\r\nUpgrade: a\r\nUpgrade: b\r\n\r\n",
                b"HEAD /api/logs/kitti/file.mcap HTTP/1.1\r\nHost: x\r\nOrigin: http://a\r\nOrigin: http://b\r\n\r\n",
            )
        ]
        await healthz(server)
    for (status, headers, body), name in zip(answers, ("Accept", "Upgrade", "Origin")):
        assert status == b"HTTP/1.1 400 Bad Request", (status, body)
        assert headers.get("x-content-type-options") == "nosniff" and headers.get("referrer-policy") == "strict-origin"
        assert body.lower() in (f"the header {name!r} is given more than once\n".lower().encode(), b""), body
    assert not [line for line in server.lines if "failed" in line]


# -- clients that send and never read --------------------------------------------------------------------------------

_FOXGLOVE = "foxglove.websocket.v1"
_FLOOD = 512 * 1024


def _frame(opcode: int, payload: bytes) -> bytes:
    """One client frame of ``payload``, masked with a zero key (so the payload is sent as it is)."""
    return struct.pack(">BBQ", 0x80 | opcode, 0x80 | 127, len(payload)) + b"\0\0\0\0" + payload


def _padded(text: str) -> bytes:
    """``text``, a JSON object, padded with spaces inside to 512 KB: valid, and as big as the attack's messages."""
    return (text[:-1] + " " * (_FLOOD - len(text)) + "}").encode()


#: Per face, what three clients send as fast as they can: binary junk, malformed JSON, valid ops that are answered.
FLOODS = {
    _FOXGLOVE: [
        _frame(0x2, b"\xfe" * _FLOOD),
        _frame(0x1, b"{" * _FLOOD),
        _frame(0x1, _padded(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": 99_999}]}))),
    ],
    "": [
        _frame(0x2, b"\xfe" * _FLOOD),
        _frame(0x1, b"{" * _FLOOD),
        _frame(0x1, _padded(json.dumps({"type": "xviz/transform_log", "data": {"id": "again"}}))),
    ],
}


async def flood(port: int, subprotocol: str, frame: bytes, sent: list[int], local: list[int]) -> None:
    """Send ``frame`` over and over on a WebSocket session and never read, until the connection fails or the task is
    cancelled.

    Past the handshake nothing is read: the socket's receive buffer is small, so that
    the server's answers stay in the server. ``sent[0]`` counts the bytes written,
    ``local`` gets the socket's port.
    """
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
    local.append(sock.getsockname()[1])
    reader, writer = await asyncio.open_connection(sock=sock)
    protocol = f"Sec-WebSocket-Protocol: {subprotocol}\r\n" if subprotocol else ""
    writer.write(
        f"GET /?log=kitti HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: AAAAAAAAAAAAAAAAAAAAAA==\r\nSec-WebSocket-Version: 13\r\n{protocol}\r\n".encode()
    )
    assert (await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 30)).startswith(b"HTTP/1.1 101")
    try:
        while True:
            writer.write(frame)
            await writer.drain()
            sent[0] += len(frame)
    except OSError:
        pass
    finally:
        writer.transport.abort()


async def test_clients_that_send_512_kb_messages_and_never_read_cost_tens_of_mb(kitti_root: Path) -> None:
    async with served(kitti_root, XVIZ_IDLE_TIMEOUT="10") as server:
        async with await foxglove(server) as warm:  # the workers are up and the log's frames cached
            await subscribe_all(warm)
            await arrivals(warm, 2.0)
        before = server.rss()
        watcher = await foxglove(server)
        counts = [[0] for _ in range(6)]
        ports: list[int] = []
        started = time.monotonic()
        floods = [
            asyncio.ensure_future(flood(server.port, subprotocol, frame, count, ports))
            for (subprotocol, frame), count in zip(((p, f) for p, frames in FLOODS.items() for f in frames), counts)
        ]

        async def under_way() -> bool:
            return all(count[0] >= 2 * _FLOOD or future.done() for count, future in zip(counts, floods))

        await eventually(under_way, 30)
        await subscribe_all(watcher)
        watching = asyncio.ensure_future(arrivals(watcher))
        await healthz(server)

        async def let_go() -> bool:  # the server closed all six (the kernel may still owe a client that never reads)
            return not any(server.holds(port) for port in ports)

        await eventually(let_go, 60)
        ended = time.monotonic()
        for future in floods:
            future.cancel()
        await asyncio.gather(*floods, return_exceptions=True)
        times = await watching
        await healthz(server)
        await watcher.close()
        growth = grown(server, before)
    gaps = [later - earlier for earlier, later in zip(times, times[1:])]
    assert len(times) > 100 and max(gaps) < QUIET, max(gaps)
    assert max(growth.values()) < TENS_OF_MB, {pid: f"{g / _MiB:.0f} MiB" for pid, g in growth.items()}
    assert ended - started < 35  # the keepalive ping (10 s), its timeout (10 s) and closing (10 s)
