"""Live feeds across replicas through a real redis-server: server processes with --broker, a source on one
(network ingest of the real KITTI frames), viewers on the others, and the broker's faults.

Each test starts Debian's redis-server (``scripts/test.sh`` installs it) on a free loopback port, with a
password that must never reach a log line, and ``xviz-server serve`` processes on free ports.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import orjson
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from devkit.data import KITTI_LOG
from helpers import client, metadata, metric, needs_data, run_xviz_session_async, running_server, update
from xviz_server.codec import decode
from xviz_server.viewer import STATIC_DIR

KITTI = KITTI_LOG
BROWSER = Path(__file__).with_name("browser.mjs")
PASSWORD = "pa55-for-the-broker"
TTL = 2.0  # --broker-ttl of the replicas here

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("redis-server") is None, reason="needs redis-server: run scripts/test.sh"),
    needs_data,
]
redis = pytest.importorskip("redis.asyncio", reason="needs the broker extra: pip install -e '.[broker]'")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def frames() -> list[bytes]:
    """The KITTI state updates, 2.1 MB GLB each, in order."""
    return [(KITTI / f"{number}-frame.glb").read_bytes() for number in range(2, 27)]


METADATA = (KITTI / "1-frame.glb").read_bytes() if KITTI.is_dir() else b""


class Broker:
    """A redis-server of our own, on a free port, no persistence; killed and started again at will."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.port = free_port()
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://:{PASSWORD}@127.0.0.1:{self.port}/0"

    def client(self) -> Any:
        return redis.Redis(host="127.0.0.1", port=self.port, password=PASSWORD)

    async def start(self) -> None:
        self.process = subprocess.Popen(
            [
                "redis-server",
                "--port",
                str(self.port),
                "--bind",
                "127.0.0.1",
                "--save",
                "",
                "--appendonly",
                "no",
                "--requirepass",
                PASSWORD,
                "--dir",
                str(self.directory),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        client = self.client()
        for _ in range(600):  # up to 30 s: a loaded machine starts it slowly
            try:
                await client.ping()
                break
            except (redis.ConnectionError, OSError):
                await asyncio.sleep(0.05)
        await client.aclose()

    def kill(self) -> None:
        """SIGKILL, by the server's own PID."""
        assert self.process is not None
        os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait()


class Replica:
    """``xviz-server serve --broker ...`` in a process of its own; its log lines are kept."""

    def __init__(self, process: asyncio.subprocess.Process) -> None:
        self.process = process
        self.lines: list[str] = []
        self.port = 0

    @classmethod
    async def start(cls, directory: Path, broker: Broker, *flags: str) -> Replica:
        directory.mkdir(exist_ok=True)
        env = {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_") and "proxy" not in k.lower()}
        process = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "xviz_server",
            "serve",
            "--data-dir",
            str(directory),
            "--port",
            "0",
            "--broker",
            broker.url,
            "--broker-ttl",
            str(TTL),
            *flags,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.PIPE,
            env=env,
        )
        replica = cls(process)
        assert process.stderr is not None
        while not replica.port:
            line = (await asyncio.wait_for(process.stderr.readline(), 60)).decode()
            assert line, "the replica exited:\n" + "".join(replica.lines)
            replica.lines.append(line)
            if match := re.search(r"listening on ws://127\.0\.0\.1:(\d+)/", line):
                replica.port = int(match.group(1))
        replica._drain = asyncio.ensure_future(replica._read(process.stderr))
        return replica

    async def _read(self, stream: asyncio.StreamReader) -> None:
        async for line in stream:
            self.lines.append(line.decode())

    def log(self, pattern: str) -> list[str]:
        return [line for line in self.lines if re.search(pattern, line)]

    def url(self, path: str) -> str:
        return f"ws://127.0.0.1:{self.port}{path}"

    async def get(self, path: str) -> tuple[int, str]:
        def fetch() -> tuple[int, str]:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=10) as response:
                    return response.status, response.read().decode()
            except urllib.error.HTTPError as error:
                return error.code, error.read().decode()

        return await asyncio.to_thread(fetch)

    async def live(self) -> dict[str, bool]:
        """The live feeds of its catalog (GET /api/logs): name and whether their source is connected."""
        _, body = await self.get("/api/logs")
        return {feed["name"]: feed["connected"] for feed in json.loads(body)["live"]}

    async def metric(self, name: str, **labels: str) -> float:
        _, body = await self.get("/metrics")
        return metric(body, name, **labels)

    async def stop(self) -> None:
        """SIGTERM; raises AssertionError if the replica does not exit in time (it is killed then)."""
        if self.process.returncode is None:
            self.process.terminate()
            try:
                await asyncio.wait_for(self.process.wait(), 20)
            except asyncio.TimeoutError:
                self.process.kill()
                raise AssertionError("the replica did not stop on SIGTERM:\n" + "".join(self.lines[-20:])) from None
            finally:
                await self._drain


async def until(condition: Any, timeout: float = 20, what: str = "") -> float:
    """Wait for the async ``condition()`` to hold; the seconds it took."""
    started = time.monotonic()
    while not await condition():
        assert time.monotonic() - started < timeout, f"timed out waiting for {what}"
        await asyncio.sleep(0.05)
    return time.monotonic() - started


@pytest.fixture
async def broker(tmp_path: Path) -> AsyncIterator[Broker]:
    server = Broker(tmp_path)
    await server.start()
    yield server
    if server.process is not None and server.process.poll() is None:
        server.kill()


@contextlib.asynccontextmanager
async def replicas(tmp_path: Path, broker: Broker, count: int, *flags: str) -> AsyncIterator[list[Replica]]:
    started = await asyncio.gather(*(Replica.start(tmp_path / f"logs-{i}", broker, *flags) for i in range(count)))
    try:
        yield list(started)
    finally:
        stopped = await asyncio.gather(*(replica.stop() for replica in started), return_exceptions=True)
        for problem in stopped:
            if problem is not None:
                raise problem
        for replica in started:  # the broker's password never reaches a log line
            assert not [line for line in replica.lines if PASSWORD in line]


@contextlib.asynccontextmanager
async def source(replica: Replica, name: str = "car", query: str = "") -> AsyncIterator[ClientConnection]:
    """A live source on ``replica`` that sent the KITTI metadata."""
    async with connect(replica.url(f"/ingest/{name}{query}"), max_size=None) as websocket:
        await websocket.send(METADATA)

        await until(lambda: _started(replica, name), what=f"the feed {name!r} to start")
        yield websocket


async def push(websocket: ClientConnection, updates: list[bytes], rate: float = 10.0) -> None:
    for data in updates:
        await websocket.send(data)
        await asyncio.sleep(1 / rate)


class Viewer:
    """A live viewer over a raw WebSocket: the bytes of every state update, and every notice's text."""

    def __init__(self, websocket: ClientConnection) -> None:
        self.websocket = websocket
        self.updates: list[bytes] = []
        self.notices: list[str] = []
        self.metadata = 0

    @classmethod
    async def join(cls, replica: Replica, name: str = "car") -> Viewer:
        viewer = cls(await connect(replica.url(f"/?log={name}&session_type=live"), max_size=None))
        viewer._task = asyncio.ensure_future(viewer._read())
        return viewer

    async def _read(self) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for data in self.websocket:
                message = decode(data)
                if message["type"] == "xviz/state_update":
                    assert isinstance(data, bytes)
                    self.updates.append(data)
                elif message["type"] == "xviz/metadata":
                    self.metadata += 1
                elif message["type"] == "xviz/error":
                    self.notices.append(message["data"]["message"])

    async def count(self, updates: int, timeout: float = 30) -> None:
        async def enough() -> bool:
            return len(self.updates) >= updates

        await until(enough, timeout, f"{updates} updates (got {len(self.updates)})")

    async def close(self) -> None:
        await self.websocket.close()
        await self._task


def timestamp(data: bytes) -> float:
    return float(decode(data)["data"]["updates"][0]["timestamp"])


async def test_a_feed_on_one_replica_reaches_viewers_on_the_others_as_on_its_own(tmp_path: Path, broker: Broker):
    updates = frames()[:20]
    async with replicas(tmp_path, broker, 3) as (a, b, c):
        async with source(a) as car:
            for replica in (b, c):
                await until(lambda: _listed(replica, "car"), what="B and C to list A's feed")
            viewers = [await Viewer.join(replica) for replica in (a, b, c, b)]
            published = asyncio.ensure_future(
                run_xviz_session_async(
                    b.url("/?logGuid=car&worker=true&profile=default"),  # the URL of streetscape.gl's XVIZLiveLoader
                    [{"wait": "metadata"}, {"wait": "state_updates", "count": len(updates)}],
                    brief=True,
                )
            )
            await until(lambda: _sessions(b, 3), what="the viewers on B")
            await push(car, updates)
            for viewer in viewers:
                await viewer.count(len(updates))
            # Every update once, in order, the very bytes A's own viewer got.
            assert [timestamp(data) for data in viewers[0].updates] == [timestamp(data) for data in updates]
            for viewer in viewers[1:]:
                assert viewer.updates == viewers[0].updates and viewer.metadata == 1 and not viewer.notices
            result = await published
            assert result.ok, result.stderr
            assert [m["timestamp"] for m in result.of_type("xviz/state_update")] == [timestamp(d) for d in updates]
            metadata = result.of_type("xviz/metadata")[0]["parsed"]
            assert "/lidar/points" in metadata["streams"]

            # A late joiner on B draws at once: metadata and the complete state, without waiting for an update.
            started = time.perf_counter()
            async with connect(b.url("/?log=car&session_type=live"), max_size=None) as late:
                assert decode(await late.recv())["type"] == "xviz/metadata"
                state = decode(await late.recv())
                waited = time.perf_counter() - started
            assert state["data"]["update_type"] == "COMPLETE_STATE"
            assert state["data"]["updates"][0]["timestamp"] == timestamp(updates[-1])
            print(f"late joiner on B: metadata and complete state after {waited * 1000:.1f} ms")

            assert await a.metric("xviz_broker_writes_total") >= len(updates) + 1
            assert await b.metric("xviz_broker_reads_total") == len(updates)
            assert await b.metric("xviz_broker_lag_seconds_count") == len(updates)
            assert await a.metric("xviz_broker_dropped_updates_total") == 0
            status, health = await b.get("/healthz")
            assert status == 200 and re.search(r"broker redis://:REDACTED@127\.0\.0\.1:\d+/0: up", health)

            # A killed -9: its feed leaves B's catalog within the TTL (and a poll), and B's viewers are told.
            a.process.kill()
            gone = await until(lambda: _unlisted(b, "car"), what="B to drop the feed of the killed replica")
            print(f"feed of the killed replica gone from B's catalog after {gone:.2f} s (TTL {TTL:g} s)")
            await until(lambda: _unlisted(c, "car"), what="C to drop it too")
            await until(lambda: _told(viewers[1], "went away"), what="B's viewer to be told")
            assert b.log(r"live feed 'car': replica \S+ stopped renewing it")

        # The feed comes back on a new replica: the viewers who stayed on B and C resume.
        again = await Replica.start(tmp_path / "logs-again", broker)
        try:
            async with source(again) as car:
                await until(lambda: _started(b, "car"), what="B to list the feed again")
                await push(car, updates[:3])
                for viewer in viewers[1:]:
                    # From the newest complete state when B started reading again (each KITTI frame is one).
                    await until(lambda: _got(viewer, updates[2]), what="the viewers who stayed to resume")
                    resumed = viewer.updates[len(updates) :]
                    assert resumed == updates[3 - len(resumed) : 3] and viewer.metadata == 1
        finally:
            await again.stop()
        for viewer in viewers[1:]:
            await viewer.close()


async def test_reconfigure_passes_through_the_broker_and_a_second_source_is_refused(tmp_path: Path, broker: Broker):
    updates = frames()[:6]
    async with replicas(tmp_path, broker, 2) as (a, b):
        async with source(a, query="?reconfigure=1") as car:
            # Started, not only listed: a viewer of a feed listed before its metadata came is told it has not started.
            await until(lambda: _started(b, "car"), what="B to list A's feed, its source connected")
            async with connect(b.url("/?log=car&session_type=live"), max_size=None) as viewer:
                assert decode(await viewer.recv())["type"] == "xviz/metadata"
                change = {"desired_streams": ["/vehicle_pose", "/lidar/points"], "message_format": "JSON"}
                await viewer.send(
                    json.dumps({"type": "xviz/reconfigure", "data": {"update_type": "DELTA", "config_update": change}})
                )
                reconfigure = json.loads(await asyncio.wait_for(car.recv(), 10))
                assert reconfigure == {
                    "type": "xviz/reconfigure",
                    "data": {"update_type": "DELTA", "config_update": change},
                }
                # Reconfigures that no viewer sends: skipped, and the next one still reaches the source.
                client = broker.client()
                for data in (orjson.dumps({"pad": "x" * 100_000}), b"[1, 2]", b"not json"):
                    await client.xadd(
                        "xviz:control:car", {"v": "1", "t": "reconfigure", "o": "intruder", "n": "0", "d": data}
                    )
                await client.aclose()
                await viewer.send(
                    json.dumps({"type": "xviz/reconfigure", "data": {"update_type": "DELTA", "config_update": change}})
                )
                assert json.loads(await asyncio.wait_for(car.recv(), 10))["data"]["config_update"] == change
                assert len(a.log("skipped a reconfigure entry")) == 3
                await push(car, updates[:1])
                message = await asyncio.wait_for(viewer.recv(), 10)
                assert isinstance(message, str)  # JSON, as this viewer asked, made on B
                update = decode(message)["data"]["updates"][0]
                assert set(update.get("primitives", {})) | set(update.get("poses", {})) == {
                    "/vehicle_pose",
                    "/lidar/points",
                }

            # A second source for the same name, on the other replica: refused as on one replica.
            async with connect(b.url("/ingest/car"), max_size=None) as second:
                with pytest.raises(ConnectionClosed):
                    await asyncio.wait_for(second.recv(), 10)
            assert second.close_code == 1008 and "already has a source, on replica" in (second.close_reason or "")

            # Garbage and foreign entries in the feed's stream: skipped with one log line, the feed goes on.
            viewer_b = await Viewer.join(b)
            await until(lambda: _sessions(b, 1), what="the viewer on B")
            client = broker.client()
            await client.xadd("xviz:updates:car", {"hello": "world"})
            await client.xadd(
                "xviz:updates:car", {"v": "1", "t": "update", "o": "intruder", "n": "7", "d": b"glTF not really"}
            )
            await client.aclose()
            await push(car, updates[1:])
            await viewer_b.count(len(updates))  # the complete state it joined with, then the updates
            assert [timestamp(d) for d in viewer_b.updates] == [timestamp(d) for d in updates]
            assert len(b.log("skipped entry")) == 1
            assert await b.metric("xviz_broker_dropped_updates_total", reason="garbage") == 2
            await viewer_b.close()


async def test_a_replica_reads_a_feed_only_while_it_has_viewers_there(tmp_path: Path, broker: Broker):
    """One reader per feed on B, started by B's first viewer, stopped after its last left, started again."""
    updates = frames()[:12]
    client = broker.client()

    async def readers() -> list[str]:
        return [entry["name"] for entry in await client.client_list() if entry["name"].startswith("xviz-reader:")]

    async def no_reader() -> bool:
        return await readers() == [] and await b.metric("xviz_broker_readers") == 0

    async with replicas(tmp_path, broker, 2) as (a, b):
        async with source(a) as car:
            await push(car, updates[:2])
            await until(lambda: _started(b, "car"), what="B to list A's feed, its source connected")
            await asyncio.sleep(1.5)  # B polls the broker every 0.5 s: it would have started a reader by now
            assert await no_reader() and await b.metric("xviz_broker_reads_total") == 0

            # The first viewer starts the one reader, and draws at once: metadata, then the newest frame.
            first = await Viewer.join(b)
            await first.count(1, timeout=10)
            assert first.metadata == 1 and first.updates == [updates[1]]
            second = await Viewer.join(b)
            await until(lambda: _sessions(b, 2), what="the second viewer on B")
            await push(car, updates[2:5])
            for viewer in (first, second):
                await viewer.count(4 if viewer is first else 3)
            assert first.updates[1:] == updates[2:5] and second.updates[-3:] == updates[2:5]
            assert await readers() == ["xviz-reader:car"] and await b.metric("xviz_broker_readers") == 1

            # The last viewer leaves: the reader stops a little later, and B reads nothing more.
            await first.close()
            await second.close()
            assert await readers() == ["xviz-reader:car"]  # not at once: a viewer reloading the page finds it read
            await until(no_reader, timeout=10, what="B's reader to stop")
            read = await b.metric("xviz_broker_reads_total")
            await push(car, updates[5:8])
            await asyncio.sleep(0.5)
            assert await b.metric("xviz_broker_reads_total") == read and await _started(b, "car")

            # A viewer joining later starts it again, from the newest frame, and follows the feed.
            third = await Viewer.join(b)
            await third.count(1, timeout=10)
            assert third.updates == [updates[7]] and third.metadata == 1
            await push(car, updates[8:])
            await third.count(1 + len(updates[8:]))
            assert third.updates[1:] == updates[8:] and not third.notices
            assert await readers() == ["xviz-reader:car"]
            await third.close()
    await client.aclose()


async def test_the_broker_down_at_start_then_restarted_mid_feed(tmp_path: Path):
    broker = Broker(tmp_path)  # not started: the replicas start without it
    updates = (frames() * 2)[:50]
    async with replicas(tmp_path, broker, 2) as (a, b):
        for replica in (a, b):
            status, health = await replica.get("/healthz")
            assert status == 200 and "down" in health and "retrying" in health
            assert len(replica.log("unreachable")) == 1
        try:
            async with source(a) as car:  # while the broker is down: A serves it to its own viewers
                here = await Viewer.join(a)
                await until(lambda: _sessions(a, 1), what="the viewer on A")
                await push(car, updates[:3])
                await broker.start()
                await until(lambda: _up(a), what="A to reach the broker")
                await until(lambda: _up(b), what="B to reach the broker")
                await push(car, updates[3:5])
                await until(lambda: _started(b, "car"), what="B to list A's feed, started")
                there = await Viewer.join(b)  # a late joiner: the complete state first
                await until(lambda: _sessions(b, 1), what="the viewer on B")
                await push(car, updates[5:10])
                await there.count(6)
                broker.kill()
                await push(car, updates[10:40])  # 3 s without the broker
                await broker.start()
                await until(lambda: _up(a), what="A to reach the broker again")
                await push(car, updates[40:])
                await here.count(len(updates))

                async def resumed() -> bool:
                    return there.updates[-1] == updates[-1]

                await until(resumed, what="B's viewer to get the last update")
                # A's own viewer never noticed; B's missed what the broker lost, was told how many, and resumed.
                assert here.updates == updates and not here.notices
                assert timestamp(there.updates[0]) == timestamp(updates[4]) and there.updates[1:6] == updates[5:10]
                missed = 1 + len(updates[5:]) - len(there.updates)
                assert missed > 0
                told = [int(m) for notice in there.notices for m in re.findall(r"(\d+) updates were dropped", notice)]
                assert sum(told) == missed, (told, missed)
                assert len(a.log("unreachable")) == 2 and a.log("connected again")
                await here.close()
                await there.close()
        finally:
            if broker.process is not None and broker.process.poll() is None:
                broker.kill()


async def test_a_full_broker_costs_the_owner_its_broker_writes_only(tmp_path: Path, broker: Broker):
    updates = frames()[:12]
    async with replicas(tmp_path, broker, 1) as (a,):
        async with source(a) as car:
            viewer = await Viewer.join(a)
            await until(lambda: _sessions(a, 1), what="the viewer")
            client = broker.client()
            used = (await client.info("memory"))["used_memory"]
            await client.config_set("maxmemory", used + 3 * 2**20)  # one frame and a bit
            await push(car, updates[:8])
            await viewer.count(8)
            assert len(a.log("refuses writes of live feed 'car'")) == 1
            assert await a.metric("xviz_broker_dropped_updates_total", reason="full") >= 5
            await client.config_set("maxmemory", 0)
            await push(car, updates[8:])
            await viewer.count(len(updates))
            assert viewer.updates == updates and not viewer.notices
            await until(lambda: _logged(a, "writing live feed 'car' again"), what="A to write again")
            assert await client.xlen("xviz:updates:car") >= 1
            await client.aclose()
            await viewer.close()


@pytest.mark.skipif(
    not (STATIC_DIR / "index.html").is_file() or shutil.which("chromium") is None or shutil.which("node") is None,
    reason="needs the viewer bundle and chromium: run scripts/test.sh",
)
async def test_the_built_in_viewer_on_another_replica_lists_and_plays_the_feed(tmp_path: Path, broker: Broker):
    """streetscape.gl's XVIZLiveLoader, in the built-in viewer in headless Chromium, on B; the source on A.

    A software-rendered page on a busy machine may fall behind: a queue that holds the whole run keeps it
    from being told so (which the page would show as an alert)."""
    async with replicas(tmp_path, broker, 2, "--live-queue", "128") as (a, b):
        async with source(a) as car:
            await until(lambda: _listed(b, "car"), what="B to list A's feed")
            pushing = asyncio.ensure_future(push(car, frames() * 4))
            options = {
                "url": f"http://127.0.0.1:{b.port}/",
                "click": "car",
                "frames": 10,
                "timeout": 90_000,
                "screenshot": str(tmp_path / "viewer-on-b.png"),
            }
            process = await asyncio.create_subprocess_exec(
                "node",
                str(BROWSER),
                json.dumps(options),
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
            )
            stdout, stderr = await process.communicate()
            pushing.cancel()
    assert process.returncode == 0, stderr.decode()
    report = json.loads(stdout)
    assert "car" in report["catalogText"] and "source connected" in report["catalogText"]
    assert report["pageErrors"] == [] and report["alerts"] == [] and report["failedRequests"] == []
    assert report["frames"] >= 10 and report["drawn"], report
    print(f"the viewer on B drew A's feed {report['firstDrawnMs']} ms after opening the page")


async def test_an_in_process_feed_of_incremental_updates_reaches_a_replica_started_later(
    tmp_path: Path, broker: Broker
):
    """``server.live.feed(...)`` is shared too; a replica that starts reading begins at a keyframe, which the
    owner writes for a source of incremental updates (every few updates when the stream is short)."""
    settings = {"broker": broker.url, "broker_ttl": TTL, "broker_max_mb": 0.002}  # ~5 entries of the updates here

    def written(server: Any) -> float:
        return sum(
            float(line.rsplit(" ", 1)[1])
            for line in server.metrics.exposition().decode().splitlines()
            if line.startswith("xviz_broker_writes_total")
        )

    async with running_server(tmp_path, **settings) as a:
        feed = a.live.feed("sim")
        feed.set_metadata(metadata())
        await feed.publish(update(1.0, points=50))
        for i in range(1, 13):
            await asyncio.sleep(0.05)  # the owner's queue to the broker holds 4 updates
            await feed.publish(update(1 + i / 10, update_type="INCREMENTAL", streams=("/vehicle_pose",)))

        async def all_written() -> bool:
            return written(a) >= 1 + 13 + 2  # the metadata, the updates and two keyframes

        await until(all_written, what="A to write the feed")
        async with running_server(tmp_path, **settings) as c:

            async def listed() -> bool:
                found = c.live.get("sim")
                return found is not None and found.metadata is not None

            await until(listed, what="C to list the feed")
            assert c.live.get("sim").state() is None  # not read: no viewer on C yet
            async with client(c, "/?log=sim&session_type=live") as viewer:
                assert (await viewer.recv())["type"] == "xviz/metadata"
                state = await viewer.recv()
                assert state["data"]["update_type"] == "COMPLETE_STATE"  # the keyframe the reader starts at
                assert state["data"]["updates"][0]["primitives"]["/points"]["points"][0]["points"].shape == (50, 3)
                poses = [state["data"]["updates"][0]["poses"]["/vehicle_pose"]["position"][0]]
                while poses[-1] != 2.2:  # then the updates after it, up to the newest
                    poses.append(
                        (await asyncio.wait_for(viewer.recv(), 10))["data"]["updates"][0]["poses"]["/vehicle_pose"][
                            "position"
                        ][0]
                    )
            assert poses == sorted(poses) and poses[0] >= 1.9, poses
            assert c.live.get("sim").origin == a.broker.link.id.decode()


def poisoned(frame: bytes) -> dict[str, bytes]:
    """Updates that ingest refuses, each made from the real ``frame``: a stream map that is a number, and the
    lidar cloud referenced 60 times (a few KB more to send, 104 MB to re-encode, over ingest's 64 MB)."""
    from xviz_server.codec import edit_glb

    def poses_a_number(message: Any) -> Any:
        message["data"]["updates"][0]["poses"] = 5
        return message

    def cloud_sixty_times(message: Any) -> Any:
        stream = message["data"]["updates"][0]["primitives"]["/lidar/points"]
        stream["points"] = stream["points"] * 60
        return message

    return {"poses": edit_glb(frame, poses_a_number), "expands to": edit_glb(frame, cloud_sixty_times)}


async def test_entries_that_ingest_would_refuse_are_skipped_and_the_feed_goes_on(tmp_path: Path, broker: Broker):
    """Entries XADDed into the feed's stream under the owner's id and numbered as its next update (a shape
    ingest refuses, an expansion bomb, a number 10^15 ahead): each is refused, counted and logged once, and
    B's viewers get every genuine update after it, the very bytes A's viewer gets."""
    updates = frames()[:6]
    async with replicas(tmp_path, broker, 2) as (a, b):
        async with source(a) as car:
            await until(lambda: _listed(b, "car"), what="B to list A's feed")
            here, there = await Viewer.join(a), await Viewer.join(b)
            await until(lambda: _sessions(b, 1), what="the viewer on B")
            await push(car, updates[:1])
            await there.count(1)
            client = broker.client()
            owner = await client.hget("xviz:reg:car", "owner")
            attacks = [*poisoned(updates[1]).items(), ("not the owner's next", updates[1])]
            for sent, (problem, data) in enumerate(attacks, start=1):
                number = 10**15 if problem == "not the owner's next" else sent  # the owner's next is `sent`
                await client.xadd(
                    "xviz:updates:car", {"v": "1", "t": "update", "o": owner, "n": str(number), "d": data}
                )
                await push(car, updates[sent : sent + 1])
                await there.count(1 + sent)
                assert len(b.log(r"skipped entry .*" + re.escape(problem))) == 1, b.lines[-5:]
            await push(car, updates[len(attacks) + 1 :])
            await here.count(len(updates))
            await there.count(len(updates))
            assert there.updates == here.updates == updates and not there.notices
            assert len(b.log("skipped entry")) == len(attacks)
            assert await b.metric("xviz_broker_dropped_updates_total", reason="garbage") == len(attacks)
            assert await b.metric("xviz_broker_dropped_updates_total", reason="gap") == 0
            assert await b.metric("xviz_broker_reader_restarts_total") == 0
            await client.aclose()
            for viewer in (here, there):
                await viewer.close()


async def test_a_reader_that_fails_is_restarted_and_reported(tmp_path: Path, broker: Broker):
    """A registration whose newest complete state is no stream id: B's reader fails as it starts, again and
    again (with backoff; /healthz says so), until A writes the feed's next update; then B's viewer follows."""
    updates = frames()[:4]
    async with replicas(tmp_path, broker, 2) as (a, b):
        async with source(a) as car:
            await push(car, updates[:1])
            await until(lambda: _started(b, "car"), what="B to list A's feed, started")
            client = broker.client()
            await client.hset("xviz:reg:car", "key", "not-an-id")
            viewer = await Viewer.join(b)

            async def failing() -> bool:
                return await b.metric("xviz_broker_reader_restarts_total") >= 3

            await until(failing, what="B's reader to fail three times")
            status, health = await b.get("/healthz")
            assert status == 200 and re.search(
                r"degraded: the reader of live feed 'car' failed \d+ times in a row", health
            ), health
            assert "b'not-an-id' is not a stream id" in health
            assert (
                len(b.log(r"live feed 'car': reading it from the broker failed")) == 1
            )  # said once, counted each time
            await push(car, updates[1:2])  # A writes the registration's key again
            await viewer.count(1)
            await push(car, updates[2:])
            await viewer.count(len(updates) - 1)
            assert viewer.updates == updates[1:] and not viewer.notices
            assert len(b.log(r"live feed 'car': reading it from the broker again \(it failed \d+ times before\)")) == 1
            status, health = await b.get("/healthz")
            assert "degraded" not in health
            await client.aclose()
            await viewer.close()


def test_the_broker_url_is_shown_without_its_password():
    env = {k: v for k, v in os.environ.items() if not k.startswith("XVIZ_")}
    shown = subprocess.run(
        [sys.executable, "-m", "xviz_server", "config", "--broker", "rediss://app:s3cr3t@cache.example:6380/2"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert shown.returncode == 0 and "s3cr3t" not in shown.stdout + shown.stderr
    assert 'broker = "rediss://app:REDACTED@cache.example:6380/2"' in shown.stdout
    wrong = subprocess.run(
        [sys.executable, "-m", "xviz_server", "config", "--broker", "http://:s3cr3t@cache.example"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert wrong.returncode == 2 and "s3cr3t" not in wrong.stderr and "redis://, rediss:// or unix://" in wrong.stderr


async def _listed(replica: Replica, name: str) -> bool:
    return name in await replica.live()


async def _got(viewer: Viewer, update: bytes) -> bool:
    return viewer.updates[-1:] == [update]


async def _started(replica: Replica, name: str) -> bool:
    return (await replica.live()).get(name, False)


async def _unlisted(replica: Replica, name: str) -> bool:
    return name not in await replica.live()


async def _sessions(replica: Replica, count: int) -> bool:
    return await replica.metric("xviz_sessions_open") >= count


async def _up(replica: Replica) -> bool:
    return "up for" in (await replica.get("/healthz"))[1]


async def _told(viewer: Viewer, text: str) -> bool:
    return any(text in notice for notice in viewer.notices)


async def _logged(replica: Replica, text: str) -> bool:
    return bool(replica.log(re.escape(text)))


def test_entries_round_trip_and_anything_else_is_refused_by_name():
    from xviz_server.exceptions import BrokerError
    from xviz_server.live.streams import Entry, before

    entry = Entry(b"update", b"host:1:abc", 41, b"glTF...", complete=True)
    assert Entry.parse(entry.fields()) == entry
    assert Entry.parse(Entry(b"gone", b"host:1:abc").fields()).kind == b"gone"
    for fields, problem in [
        ({b"hello": b"world"}, "not an entry of layout version 1"),
        ({b"v": b"1", b"t": b"update", b"o": b"x", b"n": b"seven", b"d": b"glTF"}, "number b'seven'"),
        ({b"v": b"1", b"t": b"delete-all", b"o": b"x", b"n": b"1", b"d": b"x"}, "kind b'delete-all'"),
        ({b"v": b"1", b"t": b"update", b"o": b"x", b"n": b"1"}, "update entry without data"),
    ]:
        with pytest.raises(BrokerError, match=re.escape(problem)):
            Entry.parse(fields)
    with pytest.raises(BrokerError, match="meta entry holding a JSON list"):
        Entry(b"meta", b"x", data=b"[1, 2]").json()
    assert before(b"1700000000123-3") == b"1700000000123-2"
    assert before(b"1700000000123-0") == b"1700000000122-18446744073709551615"
    assert before(b"0-0") == b"0-0"


async def test_a_broker_that_answers_what_is_not_resp_fails_the_wire_at_once():
    # A peer on the broker's address that answers garbage: the connection is dropped and its replies fail, no hang.
    from redis.exceptions import ConnectionError as BrokerConnectionError

    from xviz_server.live.redis_wire import Wire

    async def garbage(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read(100)
        writer.write(b"!not RESP at all\r\n")
        await writer.drain()
        await asyncio.sleep(10)
        writer.close()

    server = await asyncio.start_server(garbage, "127.0.0.1", 0)
    try:
        with pytest.raises(
            BrokerConnectionError,
            match="carried what is not RESP: not a RESP2 reply from the broker: b'!not RESP at all'",
        ):
            await Wire.open(f"redis://127.0.0.1:{server.sockets[0].getsockname()[1]}/0", "xviz-test", timeout=5)
    finally:
        server.close()


async def test_the_wire_reads_a_frame_from_the_broker_as_written(broker: Broker):
    # XADD and XREAD of real frames through a real redis-server: a value as large as LARGE, one byte over it, 2.1 MB.
    from xviz_server.live.redis_wire import LARGE, Wire

    frame = frames()[0]
    wire = await Wire.open(broker.url, "xviz-test", timeout=5)
    try:
        values = [frame[:LARGE], frame[: LARGE + 1], frame]
        ids = [await wire.send(b"XADD", b"s", b"*", b"d", value, b"n", b"%d" % len(value)) for value in values]
        assert await wire.send(b"PEXPIRE", b"s", b"60000") == 1
        answer = await wire.send(b"XREAD", b"COUNT", b"10", b"STREAMS", b"s", b"0-0")
        assert answer[0][0] == b"s"
        assert [entry_id for entry_id, _ in answer[0][1]] == ids
        assert [fields for _, fields in answer[0][1]] == [[b"d", value, b"n", b"%d" % len(value)] for value in values]
        assert await wire.send(b"XREAD", b"BLOCK", b"50", b"STREAMS", b"s", ids[-1]) is None  # nothing new: nil
        with pytest.raises(redis.ResponseError, match="WRONGTYPE"):
            await wire.send(b"HGET", b"s", b"d")
    finally:
        wire.close()


def test_an_update_is_taken_as_the_owner_s_next_within_a_bounded_gap():
    from xviz_server.exceptions import BrokerError
    from xviz_server.live.mirror import MAX_GAP, Numbering

    numbering = Numbering()
    assert numbering.missing(b"a", 41) == 0  # the first one read
    numbering.take(b"a", 41)
    assert numbering.missing(b"a", 41) is None  # a keyframe of it
    assert numbering.missing(b"a", 42) == 0 and numbering.missing(b"a", 45) == 3
    assert numbering.missing(b"a", 41 + MAX_GAP + 1) == MAX_GAP
    for number in (41 + MAX_GAP + 2, 10**15, 40, 0):
        with pytest.raises(
            BrokerError, match=f"update {number} of replica a is not the owner's next \\(its newest is 41"
        ):
            numbering.missing(b"a", number)
    assert numbering.missing(b"a", 42) == 0  # refused ones move nothing
    assert numbering.missing(b"a", 1) == 0  # follows the one refused last: the owner numbers afresh
    numbering.take(b"a", 1)
    assert numbering.missing(b"b", 7) == 0  # another owner
